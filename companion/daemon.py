"""The on-board daemon: one loop (default 50 Hz) over one MAVLink connection (DESIGN.md §5).

    MAVLink in → telemetry → estimators (E_tr, D_od, thrust_ratio, nav health) → supervisor (Γ, Ω)
              → commands (speed limit, Hold) → MAVLink out; every step → event log

`Daemon.poll()` drains the link, `Daemon.step()` runs one cycle at the injected clock's time. The
real-time runner (`run`) calls both at `loop_hz`; lock-step tests call them between simulator steps.
Nothing here raises on bad input: a malformed message is counted and dropped, a failed log write is
the log's problem, a missing stream leads to the supervisor's safe action.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from contracts.flat import horizontal_accel_limit
from contracts.table import ContractTable

from contracts.errors import ContractError

from .autopilot_base import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_DO_SET_MODE, adapter_for
from .config import Config
from .estimators import DodEstimator, EtrEstimator, NavHealth, ThrustEstimator
from .guidance import InlinePlanning, OffboardGuidance, Route, ThreadedPlanning, inflated, obstacle_discs
from .offboard import OffboardController
from .link import mavlink
from .mission import MissionSource
from .supervisor import Decision, Inputs, Supervisor
from .telemetry import Telemetry

UINT16_MAX = 65535
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_STANDBY, MAV_STATE_ACTIVE, MAV_STATE_CRITICAL = 3, 4, 5
MAV_PARAM_TYPE_REAL32 = 9

# message id → interval [µs] the daemon asks for (SET_MESSAGE_INTERVAL)
STREAMS = {
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 20_000,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 20_000,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 50_000,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 100_000,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 500_000,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 200_000,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 500_000,
    mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR: 50_000,
    mavlink.MAVLINK_MSG_ID_OBSTACLE_DISTANCE: 50_000,
}
PARAMS = ("CG_ENGAGE", "CG_MODE", "CG_R_OBST")
MISSION_MSGS = ("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_ACK", "HOME_POSITION")
MODES = ("shadow", "governor", "offboard")


def sensor_orientation(yaw_deg_clockwise: float) -> int:
    """MAV_SENSOR_ORIENTATION of a horizontal sensor. The spec's yaw rotations turn to the left
    (left-facing = ROTATION_YAW_90, right-facing = ROTATION_YAW_270), our yaw turns clockwise."""
    return round((-yaw_deg_clockwise % 360) / 45) % 8


class VehicleClock:
    """Daemon time runs at the vehicle's rate: its own monotonic clock, scaled by how fast the vehicle's
    `time_boot_ms` advances against it (1 for a real aircraft, K for a SITL sped up K times). Never
    jumps and never runs backwards, with or without a vehicle (a reboot of the autopilot only resets
    the rate estimate)."""

    def __init__(self, local=time.monotonic):
        self.local = local
        self.rate = 1.0
        self._anchor = (0.0, local())  # (daemon s, local s) where the current rate began
        self._ref: tuple[float, float] | None = None  # (vehicle s, local s) of the rate window's start

    def observe(self, time_boot_ms: int) -> None:
        tv, tl = time_boot_ms / 1000.0, self.local()
        if self._ref is None or tv < self._ref[0]:
            self._ref = (tv, tl)
            return
        if tl - self._ref[1] >= 1.0:
            r = min(max((tv - self._ref[0]) / (tl - self._ref[1]), 0.01), 1000.0)
            self._anchor = (self(), tl)
            self.rate += 0.5 * (r - self.rate) if abs(r / self.rate - 1) < 0.5 else (r - self.rate)
            self._ref = (tv, tl)

    def __call__(self) -> float:
        return self._anchor[0] + (self.local() - self._anchor[1]) * self.rate


@dataclass
class Counters:
    messages: int = 0
    bad_packets: int = 0
    rejected_signature: int = 0
    commands_sent: int = 0
    log_errors: int = 0
    loop_errors: int = 0
    setpoints_sent: int = 0
    setpoint_gap_max_s: float = 0.0  # longest gap between offboard setpoints while streaming (daemon time)


class Daemon:
    def __init__(self, cfg: Config, table: ContractTable, conn, log, clock=None, wall=time.time, signing_clock=None,
                 planning: str = "thread", contract: str | None = None):
        """`planning`: "thread" (the avoidance planner beside the loop, so the setpoint stream keeps its
        rate) or "inline" (in the loop: deterministic lock-step tests). `contract`: the one to enforce
        (default: "avoid" in offboard mode, else "stop"; a replay names the one the flight flew under)."""
        self.cfg, self.table, self.conn, self.log, self.wall = cfg, table, conn, log, wall
        if planning not in ("thread", "inline"):
            raise ValueError(f"planning must be 'thread' or 'inline', not {planning!r}")
        self._planning = ThreadedPlanning if planning == "thread" else InlinePlanning  # one per guidance
        self.signing_clock = signing_clock
        self._t_signing_saved = -math.inf
        self.vclock = VehicleClock() if clock is None else None
        self.clock = clock or self.vclock
        self.adapter = adapter_for(cfg.link.autopilot)
        self.tel = Telemetry()
        veh = table.vehicle
        self.dod = DodEstimator(cfg.sensors, cfg.contract, cfg.timeouts.obstacle_s)
        self.etr = EtrEstimator(cfg.contract)
        hover = cfg.thrust.hover_throttle_nominal or veh.controller.thr_hover
        self.thrust = ThrustEstimator(cfg.thrust, hover, veh.thrust_ratio_range[0], veh.thrust_ratio_range[1])
        self.nav = NavHealth(cfg.timeouts.nav_s)
        contract = contract or ("avoid" if cfg.mode == "offboard" else "stop")
        self.sup = Supervisor(table, cfg.mode, contract=contract, dwell_s=cfg.contract.dwell_s,
                              speed_margin=cfg.speed_margin_m_s, loop_dt=1.0 / cfg.loop_hz)
        self.params = {"CG_ENGAGE": float(cfg.engage), "CG_MODE": float(MODES.index(cfg.mode)),
                       "CG_R_OBST": cfg.contract.r_obst_m}
        self.counters = Counters()
        self._text_id = 0  # STATUSTEXT.id of the last chunked text
        self.startup_ok: bool | None = None
        self._first_seen_in_air: bool | None = None  # restart in flight ⇒ no engagement until asked anew
        self._commanded_mode: tuple[str, float, bool] | None = None
        self._link_up = False
        self._t_hb_out = -math.inf
        self._t_state_log = -math.inf
        self._t_nvf = -math.inf
        self.last: Decision | None = None
        self._sensor_of = self._sensor_index()
        self.checks = StartupChecks(self.adapter, table.vehicle, cfg)
        self.offboard = None
        self.mission: MissionSource | None = None  # route.source: mission — the route comes from the autopilot
        if cfg.mode == "offboard":
            if cfg.route is None:
                raise ContractError("mode offboard needs a route (config key route.waypoints or route.source: mission)")
            guidance = None  # mission: set once a downloaded route is held (engaging waits for it)
            if cfg.route.source == "mission":
                lk = cfg.link
                self.mission = MissionSource(lk.autopilot, lk.target_system, lk.target_component, lk.target_system,
                                             lk.component_id, cfg.route.level_tolerance_m,
                                             corner_cut_m=cfg.route.corner_cut_m)
            else:
                route = Route(cfg.route.waypoints, cfg.route.altitude_m, cfg.route.corner_cut_m)
                guidance = OffboardGuidance(route, planning=self._planning())
            self.offboard = OffboardController(guidance, cfg.offboard_entry_s)
        self._stopping = False
        self._discs: list = []  # obstacle discs from the current beams (un-inflated)
        self._t_last_sp: float | None = None  # when the last offboard setpoint went out
        self._t_checks: float | None = None

    # ------------------------------------------------------------------ input
    def _sensor_index(self):
        """(message kind, id, orientation) → configured sensor index."""
        out = {}
        for i, s in enumerate(self.cfg.sensors):
            out[(s.kind, s.id)] = i
        return out

    def poll(self) -> int:
        """Drain the link; returns the number of messages taken."""
        n = 0
        while True:
            try:
                msg = self.conn.recv_msg()
            except Exception:  # a transport hiccup (e.g. serial unplugged): try again next cycle
                break
            if msg is None:
                break
            n += 1
            self._dispatch(msg)
        return n

    def _dispatch(self, msg) -> None:
        kind = msg.get_type()
        if self.cfg.log.tlog and kind != "BAD_DATA":
            self.log.raw(int(self.wall() * 1e6), msg.get_msgbuf())
        if kind == "BAD_DATA":
            self.counters.bad_packets += 1
            if "signature" in str(getattr(msg, "reason", "")).lower():
                self.counters.rejected_signature += 1  # unsigned or wrongly signed
            return
        self.counters.messages += 1
        if kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            self._param_protocol(msg)  # from any ground station, if addressed to us
            return
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        if src_sys != self.cfg.link.target_system:
            return
        if src_comp != self.cfg.link.target_component and kind not in ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"):
            return
        tb = getattr(msg, "time_boot_ms", None)
        if self.vclock is not None and tb:
            self.vclock.observe(tb)
        t = self.clock()
        try:
            self._take(t, kind, msg)
        except (ValueError, TypeError, OverflowError):
            self.counters.bad_packets += 1  # decoded but nonsensical: drop it

    def _take(self, t: float, kind: str, msg) -> None:
        used = self.tel.update(t, msg)
        if kind == "LOCAL_POSITION_NED":
            self.etr.measure(t, msg.x, msg.y)
        elif kind == "ATTITUDE":
            self.dod.add_heading(t, msg.yaw)
            self.dod.set_speed(self.tel.ground_speed)
        elif kind == "POSITION_TARGET_LOCAL_NED" and self.tel.target is not None and self.tel.t_target == t:
            if self.offboard is None or not self.offboard.streaming:  # offboard: our own setpoints are the path
                self.etr.command(t, *self.tel.target)
        elif kind == "VFR_HUD" and math.isfinite(self.tel.vz):
            self.thrust.add(t, self.tel.throttle, self.tel.roll, self.tel.pitch, self.tel.vz, self.tel.in_air)
        elif kind in ("ESTIMATOR_STATUS", "EKF_STATUS_REPORT"):
            self.nav.update(t, kind, msg.flags)
        elif kind == "DISTANCE_SENSOR":
            i = self._sensor_of.get(("distance_sensor", msg.id), self._sensor_of.get(("distance_sensor", None)))
            if i is not None and msg.orientation == sensor_orientation(self.cfg.sensors[i].orientation_deg):
                self.dod.add_range(i, t, msg.current_distance / 100, msg.min_distance / 100,
                                   msg.max_distance / 100, getattr(msg, "signal_quality", 0))
        elif kind == "OBSTACLE_DISTANCE":
            i = self._sensor_of.get(("obstacle_distance", None))
            if i is not None:
                self._take_bins(i, t, msg)
        elif kind == "COMMAND_ACK":
            if msg.command in (MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_DO_SET_MODE):
                self._event(t, "command_ack", command=msg.command, result=msg.result)
        elif kind == "PARAM_VALUE":
            self._autopilot_param(t, msg)
        elif kind in MISSION_MSGS and self.mission is not None:
            self._mission_actions(t, self.mission.take(t, msg))
        elif used is None:
            return

    def _take_bins(self, i: int, t: float, msg) -> None:
        inc = msg.increment_f if getattr(msg, "increment_f", 0) else float(msg.increment)
        if inc <= 0:
            return  # PX4 ignores increment 0 too
        d = np.asarray(msg.distances, dtype=float)
        used = d != UINT16_MAX
        # body bearing of bin k: angle_offset + k·increment (clockwise); MAV_FRAME_GLOBAL is north-aligned
        ang = np.radians(getattr(msg, "angle_offset", 0.0) + inc * np.arange(len(d)))
        if getattr(msg, "frame", 12) != 12:  # not MAV_FRAME_BODY_FRD: rotate into the body frame
            ang = ang - self.tel.yaw
        rng = np.where(d > msg.max_distance, np.inf, d / 100.0)
        self.dod.add_bins(i, t, ang[used], rng[used], msg.max_distance / 100.0, math.radians(inc))

    # ------------------------------------------------------------------ our parameters
    def _param_protocol(self, msg) -> None:
        if msg.target_system not in (self.cfg.link.target_system, 0) or \
                msg.target_component not in (self.cfg.link.component_id, 0):
            return
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            for name in PARAMS:
                self._send_param(name)
        elif kind == "PARAM_REQUEST_READ":
            name = msg.param_id if msg.param_index < 0 else PARAMS[msg.param_index] if msg.param_index < len(PARAMS) else None
            if name in self.params:
                self._send_param(name)
        elif kind == "PARAM_SET" and msg.param_id in self.params:
            v = float(msg.param_value)
            if msg.param_id == "CG_MODE" and v not in (0.0, 1.0, 2.0) or not math.isfinite(v) or v < 0:
                self._send_param(msg.param_id)  # refused: echo the current value
                return
            old = self.params[msg.param_id]
            self.params[msg.param_id] = v
            if msg.param_id == "CG_ENGAGE" and v >= 0.5 and old < 0.5:
                self._first_seen_in_air = False  # asked anew: a restart in flight may engage now
                if self.offboard is not None and self.offboard.state in ("done", "stood_down"):
                    self.offboard.state = "off"  # … and offboard may be entered again
                if self.mission is not None:  # fly the mission as it is now (it may have been edited)
                    self._mission_actions(self.clock(), self.mission.request(self.clock(), "engage requested"))
            self._event(self.clock(), "param_set", param=msg.param_id, old=old, new=v)
            self._send_param(msg.param_id)

    def _send_param(self, name: str) -> None:
        self._send(self.conn.mav.param_value_encode(name.encode(), self.params[name], MAV_PARAM_TYPE_REAL32,
                                                    len(PARAMS), PARAMS.index(name)))

    def _autopilot_param(self, t: float, msg) -> None:
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else str(msg.param_id)
        if self.checks.take(name, self.adapter.decode_param(msg.param_value, msg.param_type)):
            self._finish_checks(t)

    def _finish_checks(self, t: float) -> None:
        ok, reason = self.checks.verdict()
        self.startup_ok = ok
        self._event(t, "startup_check", ok=ok, reason=reason)
        if not ok:
            self._statustext(3, f"CG: refusing to engage: {reason}")

    # ------------------------------------------------------------------ output
    def _send(self, msg) -> None:
        try:
            self.conn.mav.send(msg)
        except Exception:
            pass  # the link is down; the supervisor sees the heartbeat time out

    def _command(self, t: float, cmd: int, params: tuple[float, ...], what: str) -> None:
        self.counters.commands_sent += 1
        self._send(self.conn.mav.command_long_encode(self.cfg.link.target_system, self.cfg.link.target_component,
                                                     cmd, 0, *params))
        self._event(t, "command", cmd=what, params=[p if math.isfinite(p) else None for p in params])

    def _event(self, t: float, name: str, **fields) -> None:
        try:
            self.log.event(t, name, **fields)
        except Exception:
            self.counters.log_errors += 1

    def _statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT; longer than 50 bytes, in chunks (MAVLink 2 `id`, `chunk_seq`; a chunk shorter
        than 50 bytes ends the text)."""
        data = text.encode()
        if len(data) <= 50:
            self._send(self.conn.mav.statustext_encode(severity, data))
            return
        self._text_id = self._text_id % 65535 + 1
        for k in range(len(data) // 50 + 1):
            self._send(self.conn.mav.statustext_encode(severity, data[50 * k:50 * k + 50], self._text_id, k))

    def _mission_actions(self, t: float, acts) -> None:
        for msg in acts.send:
            self._send(msg)
        for name, fields in acts.events:
            self._event(t, name, **fields)
        for sev, text in acts.texts:
            self._statustext(sev, text)

    # ------------------------------------------------------------------ the cycle
    def inputs(self, t: float) -> Inputs:
        tel, to = self.tel, self.cfg.timeouts
        link_ok = t - tel.t_heartbeat <= to.heartbeat_s
        telemetry_ok = t - tel.t_local <= to.telemetry_s
        speed = tel.ground_speed if telemetry_ok else math.nan
        # along the velocity; below 1 m/s (drift, stopping within ~0.3 m, inside the E_tr floor) along the heading
        beta = math.atan2(tel.vy, tel.vx) - tel.yaw if telemetry_ok and speed > 1.0 else 0.0
        r_obst = self.params["CG_R_OBST"]
        e_tr = self.etr.value
        corridor = 2 * r_obst + e_tr + self.table.vehicle.r_body_m
        dod = self.dod.estimate(t, beta, corridor)
        thrust_ratio, _ = self.thrust.value(t)
        self._discs, width = obstacle_discs(self.dod.fresh_hits(t), (tel.x, tel.y), tel.yaw, r_obst)
        mode = self.adapter.mode_name(tel.base_mode, tel.custom_mode) if link_ok else "other"
        by_daemon = False
        if self._commanded_mode is not None:  # (mode, when commanded, seen in a heartbeat yet)
            want, t_cmd, seen = self._commanded_mode
            if mode == want:
                self._commanded_mode, by_daemon = (want, t_cmd, True), True
            elif seen or t - t_cmd > 3.0:  # left it since, or never took it (heartbeats are 1 Hz)
                self._commanded_mode = None
        if self._first_seen_in_air is None and tel.landed_state:
            self._first_seen_in_air = tel.in_air
        engaged = (self.params["CG_ENGAGE"] >= 0.5 and self.startup_ok is not False
                   and self._first_seen_in_air is False
                   and (self.mission is None or self.mission.route is not None)
                   and not (self.offboard is not None and self.offboard.state in ("done", "stood_down")))
        applies = self.adapter.limit_applies(mode) or (self.offboard is not None and mode == "offboard")
        return Inputs(t=t, link_ok=link_ok, telemetry_ok=telemetry_ok, nav_ok=self.nav.healthy(t), armed=tel.armed,
                      in_air=tel.in_air, mode=mode, limit_applies=applies,
                      mode_by_daemon=by_daemon, ground_speed=speed, dod=dod, e_tr=e_tr,
                      thrust_ratio=thrust_ratio, r_obst=r_obst, engaged=engaged, mission_seq=tel.mission_seq,
                      obstacle_width=width)

    def step(self) -> Decision:
        t = self.clock()
        if self.mission is not None:
            self._mission_actions(t, self.mission.poll(t))
        i = self.inputs(t)
        d = self.sup.step(i)
        self.last = d
        self._link_events(t, i)
        if d.hold and self.sup.mode != "shadow":
            self._commanded_mode = (self.adapter.hold_mode(), t, False)
            self._command(t, MAV_CMD_DO_SET_MODE, self.adapter.set_mode_params(self.adapter.hold_mode(), True), "hold")
        if d.send_speed is not None and self.sup.mode == "governor":
            self._command(t, MAV_CMD_DO_CHANGE_SPEED, self.adapter.speed_params(d.send_speed), "change_speed")
        if self.offboard is not None and i.link_ok:
            self._fly_offboard(t, i, d)
        for name, fields in d.events:
            self._event(t, name, **fields)
        for sev, text in d.statustext:
            self._statustext(sev, text)
        self._periodic(t, i, d)
        return d

    def _e_tr_flown(self, i: Inputs, d: Decision) -> float:
        """E_tr of the virtual obstacle (Figure 13): the measured error, or the controller contract at the
        speed actually commanded if larger — while a higher V_max waits out its dwell, the vehicle still
        flies the lower limit, and E_tr_pred is non-decreasing in speed."""
        if self.table.e_pred is not None and d.v_cmd:
            return max(i.e_tr, self.table.e_tr_pred(d.v_cmd, d.omega.tilt, i.thrust_ratio))
        return max(i.e_tr, d.omega.e_tr) if math.isfinite(d.omega.e_tr) else i.e_tr

    def _fly_offboard(self, t: float, i: Inputs, d: Decision) -> None:
        """Offboard mode: enter, stream the guidance's setpoints, leave (DESIGN.md §5)."""
        tel, veh = self.tel, self.table.vehicle
        if self.mission is not None and not self.offboard.streaming and self.mission.route is not None \
                and (self.offboard.guidance is None or self.offboard.guidance.route is not self.mission.route):
            self.offboard.guidance = OffboardGuidance(self.mission.route, planning=self._planning())  # from the next entry
        a_max = horizontal_accel_limit(d.omega.tilt, veh.t_max(min(i.thrust_ratio, veh.thrust_ratio_range[1])),
                                       veh.mass_kg)
        discs = inflated(self._discs, self._e_tr_flown(i, d), veh.r_body_m)
        acts = self.offboard.step(
            t, engaged=i.engaged and self.startup_ok is not False and d.state == "active", flying=i.armed and i.in_air,
            mode=i.mode, by_daemon=i.mode_by_daemon, p=(tel.x, tel.y), v=(tel.vx, tel.vy), z=tel.z, yaw=tel.yaw,
            v_max=d.v_cmd or 0.0, a_max=a_max, discs=discs, stop=d.hold or self._stopping or d.state != "active")
        for name, fields in acts.events:
            self._event(t, name, **fields)
        if not self.offboard.streaming and getattr(self, "_was_streaming", False):
            self.etr.reset()  # our setpoints are no longer the commanded path
            self._t_last_sp = None
        self._was_streaming = self.offboard.streaming
        if acts.hold:
            self._commanded_mode = (self.adapter.hold_mode(), t, False)
            self._command(t, MAV_CMD_DO_SET_MODE, self.adapter.set_mode_params(self.adapter.hold_mode(), True), "hold")
        if acts.enter:
            self._commanded_mode = ("offboard", t, False)
            self._command(t, MAV_CMD_DO_SET_MODE, self.adapter.set_mode_params("offboard", True), "offboard")
        sp = acts.setpoint
        if sp is not None:
            if self._t_last_sp is not None:
                self.counters.setpoint_gap_max_s = max(self.counters.setpoint_gap_max_s, t - self._t_last_sp)
            self._t_last_sp = t
            self.counters.setpoints_sent += 1
            self.etr.command(t, float(sp.p[0]), float(sp.p[1]))
            self._send(self.conn.mav.set_position_target_local_ned_encode(
                int(t * 1000) & 0xFFFFFFFF, self.cfg.link.target_system, self.cfg.link.target_component,
                mavlink.MAV_FRAME_LOCAL_NED, 2048,  # position, velocity, acceleration and yaw; no yaw rate
                float(sp.p[0]), float(sp.p[1]), float(sp.z), float(sp.v[0]), float(sp.v[1]), 0.0,
                float(sp.a[0]), float(sp.a[1]), 0.0, float(sp.yaw), 0.0))

    def _link_events(self, t: float, i: Inputs) -> None:
        if i.link_ok != self._link_up:
            self._link_up = i.link_ok
            self._event(t, "link", status="up" if i.link_ok else "down")
            if i.link_ok:
                self._t_checks = t if self.startup_ok is None else self._t_checks
                if self.mission is not None and self.mission.status in ("idle", "refused"):
                    why = "start-up" if self.mission.status == "idle" else "link up"
                    self._mission_actions(t, self.mission.request(t, why))
                for name in self.checks.wanted():
                    self._send(self.conn.mav.param_request_read_encode(
                        self.cfg.link.target_system, self.cfg.link.target_component, name.encode(), -1))
                for msg_id, interval in STREAMS.items():
                    self._command(t, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(msg_id), float(interval), 0, 0, 0, 0, 0),
                                  "set_message_interval")

    def _periodic(self, t: float, i: Inputs, d: Decision) -> None:
        if self.signing_clock is not None and abs(t - self._t_signing_saved) >= 10.0:
            self._t_signing_saved = t
            self.signing_clock.save(self.conn.mav.signing.timestamp)
        if self.startup_ok is None and self._t_checks is not None and t - self._t_checks > 5.0:
            self._finish_checks(t)  # what did not answer in 5 s counts as missing
        if t - self._t_hb_out >= 1.0 or t < self._t_hb_out:
            self._t_hb_out = t
            status = {"holding": MAV_STATE_CRITICAL, "failsafe": MAV_STATE_CRITICAL, "active": MAV_STATE_ACTIVE}
            self._send(self.conn.mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0,
                                                      status.get(d.state, MAV_STATE_STANDBY)))
        if t - self._t_nvf >= 0.5 or t < self._t_nvf:
            self._t_nvf = t
            tb = int(t * 1000) & 0xFFFFFFFF
            for name, v in (("CG_VMAX", d.omega.v_max), ("CG_GAMMA", d.omega.gamma), ("CG_DOD", i.dod.d_od),
                            ("CG_ETR", d.omega.e_tr)):
                self._send(self.conn.mav.named_value_float_encode(tb, name.encode(), v if math.isfinite(v) else -1.0))
        if t - self._t_state_log >= 1.0 / self.cfg.log.state_hz or t < self._t_state_log:
            self._t_state_log = t
            tel = self.tel
            try:
                self.log.state(
                    t, state=d.state, mode=i.mode, contract=self.sup.contract, engaged=i.engaged,
                    x=tel.x, y=tel.y, z=tel.z, vx=tel.vx, vy=tel.vy, vz=tel.vz, ground_speed=i.ground_speed,
                    d_od=i.dod.d_od, e_tr=d.omega.e_tr, e_tr_measured=i.e_tr, r_obst=i.r_obst,
                    thrust_ratio=i.thrust_ratio, v_max=d.omega.v_max, tilt_deg=math.degrees(d.omega.tilt),
                    v_safe=d.omega.v_safe, gamma=(d.v_cmd if d.v_cmd is not None else d.omega.v_max) - d.omega.v_safe,
                    gamma_flown=i.ground_speed - d.omega.v_safe, v_cmd=d.v_cmd, obstacle_m=i.dod.obstacle_m,
                )
            except Exception:
                self.counters.log_errors += 1

    def shutdown(self) -> None:
        """Leave cleanly: offboard hands over to Hold; persist the signing timestamp; say so."""
        if self.offboard is not None and self.offboard.streaming:
            t = self.clock()
            self._commanded_mode = (self.adapter.hold_mode(), t, False)
            self._command(t, MAV_CMD_DO_SET_MODE, self.adapter.set_mode_params(self.adapter.hold_mode(), True), "hold")
            self._stopping = True
        if self.signing_clock is not None:
            self.signing_clock.save(self.conn.mav.signing.timestamp)
        self._statustext(5, "CG: contract-guard stopping")

    # ------------------------------------------------------------------ real time
    def run(self, should_stop, notifier=None) -> None:
        """Poll and step at `loop_hz` until `should_stop()`. An exception inside a cycle is logged and
        counted, never fatal; the systemd watchdog is fed only while cycles complete on time."""
        from .service import WatchdogFeeder

        feeder = WatchdogFeeder(notifier, time.monotonic) if notifier is not None else None
        period = 1.0 / self.cfg.loop_hz
        next_t = time.monotonic()
        bad_cycles = 0
        while not should_stop():
            started = time.monotonic()
            try:
                self.poll()
                self.step()
                bad_cycles = 0
            except Exception as err:  # a bug must not take the loop down: log it, the next cycle retries
                bad_cycles += 1
                self.counters.loop_errors += 1
                if bad_cycles in (1, 10, 100) or bad_cycles % 1000 == 0:
                    self._event(self.clock(), "loop_error", error=f"{type(err).__name__}: {err}"[:200],
                                consecutive=bad_cycles)
            if feeder is not None:
                feeder.tick(bad_cycles < 10 and time.monotonic() - started < 5 * period)
            if hasattr(self.log, "tick"):
                self.log.tick()
            # the loop rate is in vehicle time: against a SITL sped up k times, cycle k times as often
            rate = min(max(self.vclock.rate, 1.0), 10.0) if self.vclock is not None else 1.0
            next_t += period / rate
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()


class StartupChecks:
    """DESIGN.md §5 start-up checks: the autopilot's tilt limit and braking limits must be at least what
    the contract assumes (else its braking or swerving is weaker than the table's), a companion-only
    offboard flight needs Land or Hold as offboard-loss action, and the configured sensors must cover
    the direction of flight. Any mismatch refuses to engage (shadow mode still runs)."""

    def __init__(self, adapter, vehicle, cfg: Config):
        self.adapter, self.vehicle, self.cfg = adapter, vehicle, cfg
        self.values: dict[str, float] = {}

    def wanted(self) -> list[str]:
        return [c.name for c in self.adapter.param_checks]

    def take(self, name: str, value: float) -> bool:
        """Record one parameter; True when all wanted ones are in."""
        if name in self.wanted():
            self.values[name] = value
        return set(self.values) >= set(self.wanted())

    def verdict(self) -> tuple[bool, str]:
        v = self.vehicle
        if not any(abs(((s.orientation_deg + 180) % 360) - 180) <= s.h_fov_deg / 2 for s in self.cfg.sensors):
            return False, "no configured sensor looks forward"
        needs = {"tilt_max_deg": v.tilt_max_deg, "braking.accel_max_m_s2": v.braking.accel_max_m_s2,
                 "braking.jerk_max_m_s3": v.braking.jerk_max_m_s3}
        for c in self.adapter.param_checks:
            if c.name not in self.values:
                return False, f"autopilot did not report {c.name}"
            got = self.values[c.name] * c.scale
            if c.what in needs and got < needs[c.what] * 0.999:
                return False, f"{c.name} = {got:g} below the vehicle file's {c.what} = {needs[c.what]:g}"
            if c.name == "COM_OBL_RC_ACT" and self.cfg.mode == "offboard" and int(got) not in (4, 5):
                return False, f"COM_OBL_RC_ACT = {int(got)}: a companion-only aircraft needs 4 (Land) or 5 (Hold)"
        return True, "ok"
