"""The daemon's pure cycle: samples → estimators (E_tr, D_od, thrust_ratio, nav health) → supervisor
(Γ, Ω, the keep-out discs) → offboard guidance. No I/O: `take(sample)` feeds it, `step(...)` returns the
`Inputs` it judged and the `Decision` (what to command, log and say), which MAVLink-out carries out.

It also keeps what the decisions depend on between cycles: which mode the daemon itself commanded (so a
mode change by someone else is told apart), and whether the vehicle was first seen flying (a restart in
flight never engages until asked anew).
"""

from __future__ import annotations

import math

from contracts.errors import ContractError
from contracts.flat import horizontal_accel_limit
from contracts.online_planner import load_solver, offboard_cap
from contracts.stop import braking_decel, stop_jerk
from contracts.table import ContractTable

from .config import Config
from .estimators import DodEstimator, EtrEstimator, NavHealth, ThrustEstimator, Timeliness
from .guidance import OffboardGuidance, Route, obstacle_discs
from .mavlink_in import SENSOR_MSGS
from .offboard import OffboardController
from .samples import AutopilotParam, Heading, Implausible, NavStatus, PathTarget, Position, Scan, Throttle
from .supervisor import BRAKE_STOP_CAUSES, Decision, Inputs, Supervisor
from .telemetry import Telemetry


def e_tr_floor(cfg: Config, table: ContractTable) -> float:
    """The smallest E_tr the contract may use: the configured floor, and without a controller contract in
    the table at least the configured assumption (without either, the start-up checks refuse)."""
    assumed = cfg.contract.e_tr_assumed_m if table.e_pred is None else None
    return max(cfg.contract.e_tr_floor_m, assumed or 0.0)


def controller_contract(cfg: Config, table: ContractTable) -> str:
    """In words: where the contract's E_tr comes from (the start banner, the `start` record)."""
    if table.e_pred is not None:
        flown = table.etr_offboard_cap
        return ("E_tr_pred from the table (the controller contract)" + ("" if cfg.mode != "offboard" else
                f"; offboard flies {offboard_cap(flown):.2f} x V_safe (its online plans were flown at "
                f"{'an unrecorded cap' if flown is None else f'{flown:.2f}'} x V_safe)"))
    if cfg.contract.e_tr_assumed_m is not None:
        return f"no E_tr_pred in the table: E_tr assumed {e_tr_floor(cfg, table):.2f} m (contract.e_tr_assumed_m)"
    return "no E_tr_pred in the table and no contract.e_tr_assumed_m: refuses to engage"


# the samples only the estimators take (by type: `Daemon.take` sends them here first, the others by isinstance)
CYCLE_SAMPLES = frozenset((Position, Heading, PathTarget, Throttle, NavStatus, Scan))


class Cycle:
    def __init__(self, cfg: Config, table: ContractTable, adapter, contract: str, planning):
        """`planning`: a factory of the planning runner (one per guidance: inline or on a worker thread)."""
        self.cfg, self.table, self.adapter, self._planning = cfg, table, adapter, planning
        veh = table.vehicle
        self.dod = DodEstimator(cfg.sensors, cfg.contract, cfg.timeouts.obstacle_s)
        self.etr = EtrEstimator(cfg.contract, e_tr_floor(cfg, table))
        hover = cfg.thrust.hover_throttle_nominal or veh.controller.thr_hover
        self.thrust = ThrustEstimator(cfg.thrust, hover, veh.thrust_ratio_range[0], veh.thrust_ratio_range[1])
        self.nav = NavHealth(cfg.timeouts.nav_s)
        self.timing = Timeliness(1.0 / cfg.loop_hz, cfg.timeouts.cycle_jitter_s)
        self.sup = Supervisor(table, cfg.mode, contract=contract, dwell_s=cfg.contract.dwell_s,
                              speed_margin=cfg.speed_margin_m_s, loop_dt=1.0 / cfg.loop_hz,
                              late_hold_s=cfg.timeouts.cycle_late_s)
        self.offboard: OffboardController | None = None
        if cfg.mode == "offboard":
            if cfg.route is None:
                raise ContractError("mode offboard needs a route (config key route.waypoints or route.source: mission)")
            load_solver()  # now, not at the first plan (a route from the mission makes its planner in the loop)
            guidance = None  # route from the mission: set once a downloaded route is held (engaging waits for it)
            if cfg.route.source != "mission":
                route = Route(cfg.route.waypoints, cfg.route.altitude_m, cfg.route.corner_cut_m)
                guidance = OffboardGuidance(route, planning=planning())
            self.offboard = OffboardController(guidance, cfg.offboard_entry_s)
        self.first_seen_in_air: bool | None = None  # restart in flight ⇒ no engagement until asked anew
        self.commanded_mode: tuple[str, float, bool] | None = None  # (mode, when, seen in a heartbeat yet)
        self.stopping = False  # the daemon is shutting down: stop flying
        self.v_cruise = math.nan  # the autopilot's cruise-speed parameter [m/s] (Adapter.cruise_param)
        # the speed the mission's own speed items set at an item (seq → m/s, NaN: unknown): the calibration plan's
        self.mission_speed = None
        self._was_streaming = False

    # ------------------------------------------------------------------ samples
    def take(self, s) -> None:
        if isinstance(s, Position):
            self.etr.measure(s.t, s.x, s.y)
            self.dod.add_position(s.t, s.x, s.y)
        elif isinstance(s, Heading):
            self.dod.add_heading(s.t, s.yaw)
            self.dod.set_speed(s.ground_speed)
        elif isinstance(s, PathTarget):
            if self.offboard is None or not self.offboard.streaming:  # offboard: our own setpoints are the path
                self.etr.command(s.t, s.x, s.y)
        elif isinstance(s, Throttle):
            self.thrust.add(s.t, s.throttle, s.roll, s.pitch, s.vz_down, s.in_air)
        elif isinstance(s, NavStatus):
            self.nav.update(s.t, s.source, s.flags)
        elif isinstance(s, Scan):
            self.dod.add_scan(s)
        elif isinstance(s, AutopilotParam) and self.adapter.cruise_param and s.name == self.adapter.cruise_param[0]:
            v = s.value * self.adapter.cruise_param[1]
            self.v_cruise = v if 0 < v < 100 else math.nan  # nonsense is not a cruise speed
        elif isinstance(s, Implausible) and s.kind not in SENSOR_MSGS:  # a sensor's: its scan covers nothing
            self.nav.fault(s.t, f"{s.kind}: {s.why}")

    def engage_requested(self) -> None:
        """CG_ENGAGE set anew: a restart in flight may engage now, and offboard may be entered again."""
        self.first_seen_in_air = False
        if self.offboard is not None and self.offboard.state in ("done", "stood_down", "held"):
            self.offboard.state = "off"
        self.sup.latched = False

    def hold_commanded(self, t: float) -> None:
        self.commanded_mode = (self.adapter.hold_mode(), t, False)

    def shutdown(self, t: float) -> bool:
        """Stop flying; True when the autopilot must be handed over to Hold (offboard was streaming)."""
        if self.offboard is not None and self.offboard.streaming:
            self.hold_commanded(t)
            self.stopping = True
            return True
        return False

    # ------------------------------------------------------------------ the cycle
    def inputs(self, t: float, tel: Telemetry, r_obst: float, engage: bool, startup_ok: bool | None,
               route_ready: bool) -> Inputs:
        to = self.cfg.timeouts
        late = self.timing.tick(t)
        link_ok = t - tel.t_heartbeat <= to.heartbeat_s
        telemetry_ok = t - tel.t_local <= to.telemetry_s
        speed = tel.ground_speed if telemetry_ok else math.nan
        # along the velocity; below 1 m/s (drift, stopping within ~0.3 m, inside the E_tr floor) along the heading
        beta = math.atan2(tel.vy, tel.vx) - tel.yaw if telemetry_ok and speed > 1.0 else 0.0
        e_tr = self.etr.value
        corridor = 2 * r_obst + e_tr + self.table.vehicle.r_body_m
        self.dod.r_obst = r_obst
        dod = self.dod.estimate(t, beta, corridor)
        thrust_ratio, _ = self.thrust.value(t)
        discs, width = obstacle_discs(self.dod.fresh_hits(t), (tel.x, tel.y), tel.yaw, r_obst)
        mode = self.adapter.mode_name(tel.base_mode, tel.custom_mode) if link_ok else "other"
        by_daemon = False
        if self.commanded_mode is not None:
            want, t_cmd, seen = self.commanded_mode
            if mode == want:
                self.commanded_mode, by_daemon = (want, t_cmd, True), True
            elif seen or t - t_cmd > 3.0:  # left it since, or never took it (heartbeats are 1 Hz)
                self.commanded_mode = None
        if self.first_seen_in_air is None and tel.landed_state:
            self.first_seen_in_air = tel.in_air
        engaged = (engage and startup_ok is not False and self.first_seen_in_air is False and route_ready
                   and not (self.offboard is not None and self.offboard.state in ("done", "stood_down")))
        applies = self.adapter.limit_applies(mode) or (self.offboard is not None and mode == "offboard")
        return Inputs(t=t, link_ok=link_ok, telemetry_ok=telemetry_ok, nav_ok=self.nav.healthy(t), armed=tel.armed,
                      in_air=tel.in_air, mode=mode, limit_applies=applies, mode_by_daemon=by_daemon,
                      ground_speed=speed, dod=dod, e_tr_measured=e_tr, thrust_ratio=thrust_ratio, r_obst=r_obst,
                      engaged=engaged, mission_seq=tel.mission_seq, obstacle_width=width, discs=tuple(discs),
                      v_cruise=self.v_cruise, late_s=late, late_unbudgeted_s=self.timing.unbudgeted_s,
                      v_mission=self.mission_speed(tel.mission_seq) if self.mission_speed is not None else math.nan)

    def step(self, t: float, tel: Telemetry, *, r_obst: float, engage: bool, startup_ok: bool | None,
             mission_route: Route | None = None, route_ready: bool = True) -> tuple[Inputs, Decision]:
        """`mission_route`: the route downloaded from the autopilot, if the route comes from its mission."""
        i = self.inputs(t, tel, r_obst, engage, startup_ok, route_ready)
        d = self.sup.step(i)
        if self.offboard is not None and i.link_ok:
            self._fly_offboard(t, tel, i, d, startup_ok, mission_route)  # may defer the Hold (a braking stop)
        if d.hold:
            self.hold_commanded(t)
        return i, d

    def _fly_offboard(self, t: float, tel: Telemetry, i: Inputs, d: Decision, startup_ok: bool | None,
                      mission_route: Route | None) -> None:
        """Offboard mode: enter, fly the guidance's setpoints round the keep-out discs, leave (DESIGN.md §5)."""
        off, veh = self.offboard, self.table.vehicle
        if mission_route is not None and not off.streaming and \
                (off.guidance is None or off.guidance.route is not mission_route):
            off.guidance = OffboardGuidance(mission_route, planning=self._planning())  # from the next entry
        lo, hi = veh.thrust_ratio_range
        a_max = horizontal_accel_limit(d.omega.tilt, veh.t_max(min(i.thrust_ratio, hi)), veh.mass_kg)
        # a fail-safe the daemon can fly out itself: it streams a braking stop (the stop contract's
        # deceleration, from the measured state) and hands over to Hold at rest (issue 19 item 1)
        # (another cause — stale or bad state, Ctrl-C — ends it in Hold at once, as before)
        brakeable = not self.stopping and i.telemetry_ok and all(c in BRAKE_STOP_CAUSES for c in d.hold_causes)
        brake_stop = brakeable and (bool(d.hold_causes) or off.state == "braking")
        if brake_stop and off.state in ("flying", "braking"):
            d.hold = False  # deferred: offboard commands Hold once stopped
        # the stop brakes at the tilt flown (Ω's of the last cycle with a speed: a Ω with none has no tilt of
        # its own), and at least as hard as the autopilot's own braking would (the stop contract's)
        tr = min(max(i.thrust_ratio, lo), hi) if math.isfinite(i.thrust_ratio) else lo
        tilt = self.sup.tilt_in_force if self.sup.tilt_in_force is not None else veh.tilt_max
        stop_decel = braking_decel(veh, tr)
        a_stop = max(horizontal_accel_limit(tilt, veh.t_max(tr), veh.mass_kg), stop_decel)
        stop = d.hold or self.stopping or d.state != "active" or (off.state == "braking" and not brake_stop)
        acts = off.step(
            t, engaged=i.engaged and startup_ok is not False and d.state == "active", flying=i.armed and i.in_air,
            mode=i.mode, by_daemon=i.mode_by_daemon, p=(tel.x, tel.y), v=(tel.vx, tel.vy), z=tel.z, yaw=tel.yaw,
            v_max=d.v_cmd or 0.0, a_max=a_max, discs=d.discs, stop=stop, brake_stop=brake_stop, a_stop=a_stop,
            stop_decel=stop_decel, jerk=veh.braking.jerk_max_m_s3, failsafe=d.state == "holding",
            track_jerk=stop_jerk(veh))
        d.offboard = acts
        if any(name == "offboard" and f["to"] == "held" for name, f in acts.events):  # on entering it only:
            # a fail-safe Hold is latched (offboard.py) until someone else's mode change or CG_ENGAGE clears it
            self.sup.latch_hold(d, "fail-safe stop: held until the pilot or CG_ENGAGE decides")
        if not off.streaming and self._was_streaming:
            self.etr.reset()  # our setpoints are no longer the commanded path
            d.stream_ended = True
        self._was_streaming = off.streaming
        if acts.hold:
            self.hold_commanded(t)
        if acts.enter:
            self.commanded_mode = ("offboard", t, False)
        if acts.setpoint is not None:
            self.etr.command(t, float(acts.setpoint.p[0]), float(acts.setpoint.p[1]))
