"""The daemon's pure cycle: samples → estimators (E_tr, D_od, thrust_ratio, nav health) → mode authority (whose
mode is it) → supervisor (Γ, Ω, the keep-out discs) → the actors that may want a mode (offboard guidance, the
calibration plan's hold legs, the shutdown) → the mode authority's arbitration → one `Outbox`. No I/O:
`take(sample)` feeds it, `step(...)` returns the `Inputs` it judged, the supervisor's frozen `Decision` and the
cycle's `Outbox` (everything to send, log and say), which MAVLink-out applies in one call.

It also keeps what the decisions depend on between cycles: whether the vehicle was first seen flying (a restart
in flight never engages until asked anew), and the shutdown's progress (stop means stop).
"""

from __future__ import annotations

import math
from dataclasses import replace

from contracts.errors import ContractError
from contracts.flat import horizontal_accel_limit
from contracts.online_planner import load_solver, offboard_cap
from contracts.stop import airframe_decel, braking_decel, stop_jerk
from contracts.table import THRUST_AXIS_TOL, ContractTable

from .authority import HOLD, ModeAuthority, ModeRequest, ModeView, Requester
from .autopilot_base import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_DO_SET_MODE
from .calibration_holds import CalibrationHolds, read_legs
from .config import Config
from .detection_range import DetectionRange, DetectionRangeParams
from .estimators import SETTLE_S, AccelEstimator, DodEstimator, EtrEstimator, NavHealth, ThrustEstimator, Timeliness
from .guidance import OffboardGuidance, Route, obstacle_discs
from .mavlink_in import SENSOR_MSGS
from .mission import Home
from .no_speed import diagnose
from .offboard import OffboardActions, OffboardController
from .outbox import Outbox
from .samples import (
    AutopilotParam,
    Heading,
    Implausible,
    MissionMessage,
    NavStatus,
    PathTarget,
    Position,
    Scan,
    Throttle,
)
from .states import BRAKE_STOP_CAUSES, FINISHED, Cause, OffboardState, State
from .supervisor import RAMP_WINDOW_S, Decision, Inputs, Supervisor
from .telemetry import Telemetry

SHUTDOWN_WAIT_S = 1.0  # stop means stop: the shutdown waits this long at most for the autopilot to show its Hold
A0_S = 0.1  # [s] the recovery brake's stop starts from the acceleration measured over this long (Δv/Δt)
RECHECK_FAILED = "start-up checks failed in flight"  # a failed re-check while engaged in flight: Hold


def e_tr_floor(cfg: Config, table: ContractTable) -> float:
    """The smallest E_tr the contract may use: the configured floor, and without a controller contract in
    the table at least the configured assumption (without either, the start-up checks refuse)."""
    assumed = cfg.contract.e_tr_assumed_m if table.e_pred is None else None
    return max(cfg.contract.e_tr_floor_m, assumed or 0.0)


def controller_contract(cfg: Config, table: ContractTable) -> str:
    """In words: where the contract's E_tr comes from (the start banner, the `start` record)."""
    if table.e_pred is not None:
        flown = table.etr_offboard_cap
        return ("E_tr_pred from the table (the controller contract)" + ("" if not cfg.daemon_mode.flies_route else
                f"; offboard flies {offboard_cap(flown):.2f} x V_safe (its online plans were flown at "
                f"{'an unrecorded cap' if flown is None else f'{flown:.2f}'} x V_safe)"))
    if cfg.contract.e_tr_assumed_m is not None:
        return f"no E_tr_pred in the table: E_tr assumed {e_tr_floor(cfg, table):.2f} m (contract.e_tr_assumed_m)"
    return "no E_tr_pred in the table and no contract.e_tr_assumed_m: refuses to engage"


def start_thrust(table: ContractTable, contract: str) -> tuple[float, dict]:
    """The thrust ratio the contract takes before the hover estimate settles, and the `thrust_start` event's fields.
    The bottom of the vehicle's `thrust_ratio_range` is what it may have until measured (a tired battery, a
    damaged propeller); where the table covers it, the start is the lowest thrust the table's lookup answers for
    (`ContractTable.thrust_floor`: the axis' own first value, never NONE at the start). A table whose thrust axis
    starts above that bottom (`table build --partial-grid`) cannot vouch for the vehicle until it is measured: the
    start stays at the bottom, where there is no safe speed, and says so."""
    lo, floor = table.vehicle.thrust_ratio_range[0], table.thrust_floor(contract)
    covered = floor <= lo + THRUST_AXIS_TOL
    start = floor if covered else lo
    until = f"until the hover estimate settles (airborne and steady for {SETTLE_S:g} s)"
    reason = (f"thrust_ratio taken as {start:.2f} {until}: the lowest the vehicle may have" if covered else
              f"thrust_ratio not yet estimated: the vehicle may have {lo:.2f} (its thrust_ratio_range) and the table "
              f"covers {floor:.2f} and up: no safe speed {until} at {floor:.2f} or more")
    return start, {"thrust_ratio": start, "vehicle_min": lo, "table_min": floor, "covered": covered, "reason": reason}


# the samples only the estimators take (by type: `Daemon.take` sends them here first, the others by isinstance)
CYCLE_SAMPLES = frozenset((Position, Heading, PathTarget, Throttle, NavStatus, Scan))


class Cycle:
    def __init__(self, cfg: Config, table: ContractTable, adapter, contract: str, planning, policy=None):
        """`planning`: a factory of the planning runner (one per guidance: inline, in a worker process or on a worker thread);
        `policy`: the speed policy flown (companion/onboard/supervisor.py ContractSpeed by default)."""
        self.cfg, self.table, self.adapter, self._planning = cfg, table, adapter, planning
        veh = table.vehicle
        self.dod = DodEstimator(cfg.sensors, cfg.contract, cfg.timeouts.obstacle_s)
        # D_od from evidence: what the sensors' claim cannot say
        self.truth = DetectionRange(cfg.sensors, params=DetectionRangeParams.of(cfg.detection))
        self.etr = EtrEstimator(cfg.contract, e_tr_floor(cfg, table))
        hover = cfg.thrust.hover_throttle_nominal or veh.controller.thr_hover
        start, self._thrust_start = start_thrust(table, contract)
        self.thrust = ThrustEstimator(cfg.thrust, hover, start, veh.thrust_ratio_range[1])
        self._thrust_said = False  # the start value in force in the air has been said (`thrust_start`)
        self.nav = NavHealth(cfg.timeouts.nav_s)
        self.timing = Timeliness(1.0 / cfg.loop_hz, cfg.timeouts.cycle_jitter_s)
        self.sup = Supervisor(table, cfg.daemon_mode, contract=contract, dwell_s=cfg.contract.dwell_s,
                              speed_margin=cfg.speed_margin_m_s, loop_dt=1.0 / cfg.loop_hz,
                              late_hold_s=cfg.timeouts.cycle_late_s, late_allowance_s=cfg.timeouts.cycle_jitter_s,
                              policy=policy, e_tr_window_s=cfg.contract.e_tr_window_s,
                              e_tr_floor_m=self.etr.floor, ramp_m_s=cfg.governor.approach_ramp_m_s,
                              t_cmd_s=cfg.delivery.t_cmd_s)
        self.view: ModeView | None = None  # this cycle's mode, as the authority judged it
        self.authority = ModeAuthority(adapter.hold_mode(), cfg.delivery.t_cmd_s, cfg.delivery.t_mode_s,
                                       adapter.hold_fallbacks)
        self.offboard: OffboardController | None = None
        if cfg.daemon_mode.flies_route:
            if cfg.route is None:
                raise ContractError("mode offboard needs a route (config key route.waypoints or route.source: mission)")
            load_solver()  # now, not at the first plan (a route from the mission makes its planner in the loop)
            guidance = None  # route from the mission: set once a downloaded route is held (engaging waits for it)
            if cfg.route.source != "mission":
                route = Route(cfg.route.waypoints, cfg.route.altitude_m, cfg.route.corner_cut_m)
                guidance = OffboardGuidance(route, planning=planning())
            self.offboard = OffboardController(guidance, cfg.offboard_entry_s)
        # governor.recovery_brake: the daemon's own stop, offboard's braking stop flown from the
        # mission; available while its start-up checks (`checks.brake`: the daemon's StartupChecks) pass and the
        # autopilot has not refused its switch
        self.brake = OffboardController(None) if cfg.daemon_mode.governs and cfg.governor.recovery_brake else None
        self.checks = None
        self._brake_said: tuple[bool, bool, str] | None = None
        self._brake_ready = False  # the recovery brake flies a stop the stop contract calls for
        self._brake_v0 = 0.0  # [m/s] the ground speed when the recovery brake was last called
        # the acceleration flown: the speed limit's check (its slow-down starts from it), the approach ramp's, and the
        # recovery brake's start
        self._accel = AccelEstimator(max(RAMP_WINDOW_S, A0_S))
        self._jerk_heard: float | None = None  # the autopilot's jerk last given to the approach ramp
        self.first_seen_in_air: bool | None = None  # restart in flight ⇒ no engagement until asked anew
        self.v_cruise = math.nan  # the autopilot's cruise-speed parameter [m/s] (Adapter.cruise_param)
        # calibration.legs: the calibration plan's hold legs, flown by the daemon (governor mode only: config.py)
        self.calibration: CalibrationHolds | None = None
        if cfg.calibration is not None:
            self.calibration = CalibrationHolds(read_legs(cfg.calibration.legs), adapter.mission_item0_is_home)
        self.shutdown: Shutdown | None = None  # the daemon is stopping (`stop`)
        self._was_streaming = False
        self._engaged_in_flight = False  # last cycle: engaged, flying, not shadow (a failed re-check then holds)
        self._takers = {Position: self._position, Heading: self._heading, PathTarget: self._path_target,
                        Throttle: self._throttle, NavStatus: self._nav_status, Scan: self._scan}

    # ------------------------------------------------------------------ samples
    def take(self, s) -> None:
        """One sample to the estimators that take it (the 50 Hz kinds by their type, the rest in `_take_other`)."""
        own = self._takers.get(type(s))
        if own is not None:
            own(s)
        else:
            self._take_other(s)
        self.sup.policy.take(s)  # as received: a baseline law builds its own map, as its firmware does

    def _position(self, s: Position) -> None:
        self.etr.measure(s.t, s.x, s.y)
        self.dod.add_position(s.t, s.x, s.y)
        self.truth.add_position(s.t, s.x, s.y)

    def _heading(self, s: Heading) -> None:
        self.dod.add_heading(s.t, s.yaw)
        self.truth.add_heading(s.t, s.yaw)
        self.dod.set_speed(s.ground_speed)

    def _path_target(self, s: PathTarget) -> None:
        if not self._flying_ours:  # offboard (or the recovery brake) shown: our own setpoints are the path
            self.etr.command(s.t, s.x, s.y)

    def _throttle(self, s: Throttle) -> None:
        self.thrust.add(s.t, s.throttle, s.roll, s.pitch, s.vz_down, s.in_air)

    def _nav_status(self, s: NavStatus) -> None:
        self.nav.update(s.t, s.source, s.flags)

    def _scan(self, s: Scan) -> None:  # every return to the obstacle logic; the medium's are D_od's evidence as well
        self.truth.add_scan(s)
        self.dod.add_scan(s)

    def _take_other(self, s) -> None:
        if isinstance(s, AutopilotParam) and self.adapter.cruise_param and s.name == self.adapter.cruise_param[0]:
            v = s.value * self.adapter.cruise_param[1]
            self.v_cruise = v if 0 < v < 100 else math.nan  # nonsense is not a cruise speed
        elif isinstance(s, Implausible) and s.kind not in SENSOR_MSGS:  # a sensor's: its scan covers nothing
            self.nav.fault(s.t, f"{s.kind}: {s.why}")
        elif isinstance(s, MissionMessage) and self.calibration is not None and s.msg.get_type() == "HOME_POSITION":
            self.calibration.take_home(Home.from_msg(s.msg))  # the hold legs' waypoints are placed from it

    def engage_requested(self) -> None:
        """CG_ENGAGE set anew: a restart in flight may engage now, and offboard may be entered again."""
        self.first_seen_in_air = False
        if self.offboard is not None and self.offboard.state in FINISHED:
            self.offboard.state = OffboardState.OFF
        self.sup.latched = False

    def close(self) -> None:
        """The daemon ends: the planning worker too."""
        if self.offboard is not None and self.offboard.guidance is not None:
            self.offboard.guidance.planning.close()

    def stop(self, t: float) -> None:
        """The daemon is stopping: from the next cycle on, stop flying (a shutdown Hold if engaged in flight)."""
        if self.shutdown is None:
            self.shutdown = Shutdown(t)

    def failed_hold(self, t: float) -> Outbox:
        """A cycle that raised: the failsafe Hold, through the authority, as an outbox of its own."""
        return Outbox(mode=self.authority.arbitrate(t, [ModeRequest(HOLD, Requester.FAILSAFE)]))

    @property
    def mission_speed(self):
        """The speed the mission's own speed items set at an item (seq → m/s, NaN: unknown): the calibration plan's."""
        return self.calibration.mission_speed if self.calibration is not None else None

    # ------------------------------------------------------------------ the cycle
    def inputs(self, t: float, tel: Telemetry, r_obst: float, engage: bool, startup_ok: bool | None,
               route_ready: bool) -> Inputs:
        to = self.cfg.timeouts
        link_ok = t - tel.t_heartbeat <= to.heartbeat_s
        late = self.timing.tick(t, link_ok)
        telemetry_ok = t - tel.t_local <= to.telemetry_s
        speed = tel.ground_speed if telemetry_ok else math.nan
        # along the velocity; below 1 m/s (drift, stopping within ~0.3 m, inside the E_tr floor) along the heading
        beta = math.atan2(tel.vy, tel.vx) - tel.yaw if telemetry_ok and speed > 1.0 else 0.0
        e_tr = self.etr.value
        corridor = 2 * r_obst + e_tr + self.table.vehicle.r_body_m
        self.dod.r_obst = r_obst
        dod = self.dod.estimate(t, beta, corridor)
        truth = self.truth.estimate(t, dod.d_od)
        if truth.d_od < dod.d_od:  # the evidence allows less than the claim (fog that hides, not tells)
            dod = replace(dod, d_od=truth.d_od, lowered=True,
                          reason=f"detection range from evidence ({truth.confidence:.0%} confidence): {truth.reason}")
        thrust_ratio, _ = self.thrust.value(t)
        self._accel.add(tel.t_local, tel.vx, tel.vy)
        accel = self._accel.over(RAMP_WINDOW_S) if telemetry_ok else None
        if accel is None:
            accel_along = math.nan
        else:  # along the velocity; its magnitude from near rest (any direction is "ahead" then)
            accel_along = float(accel @ (tel.vx, tel.vy)) / speed if speed > 0.5 else float(math.hypot(*accel))
        discs, width = obstacle_discs(self.dod.fresh_hits(t), (tel.x, tel.y), tel.yaw, r_obst)
        mode = self.adapter.mode_name(tel.base_mode, tel.custom_mode) if link_ok else "other"
        self.view = view = self.authority.observe(t, mode, link_ok)
        if self.first_seen_in_air is None and tel.landed_state:
            self.first_seen_in_air = tel.in_air
        engaged = (engage and startup_ok is not False and self.first_seen_in_air is False and route_ready
                   and not (self.offboard is not None and self.offboard.state in (OffboardState.DONE,
                                                                                   OffboardState.STOOD_DOWN)))
        applies = self.adapter.limit_applies(mode) or (self.offboard is not None and mode == "offboard")
        return Inputs(t=t, link_ok=link_ok, telemetry_ok=telemetry_ok, nav_ok=self.nav.healthy(t), armed=tel.armed,
                      in_air=tel.in_air, mode=mode, limit_applies=applies, mode_by_daemon=view.by_daemon,
                      mode_changed=view.event is not None, taken_over=view.taken_over,
                      ground_speed=speed, dod=dod, e_tr_measured=e_tr, thrust_ratio=thrust_ratio, r_obst=r_obst,
                      engaged=engaged, mission_seq=tel.mission_seq, obstacle_width=width, discs=tuple(discs),
                      v_cruise=self.v_cruise, late_s=late, late_unbudgeted_s=self.timing.unbudgeted_s,
                      late_within_s=self.timing.within_s, accel_along=accel_along, delivery_late=view.late,
                      v_mission=self.mission_speed(tel.mission_seq) if self.mission_speed is not None else math.nan)

    def step(self, t: float, tel: Telemetry, *, r_obst: float, engage: bool, startup_ok: bool | None,
             mission_route: Route | None = None, route_ready: bool = True, protocol=None
             ) -> tuple[Inputs, Decision, Outbox]:
        """`mission_route`: the route downloaded from the autopilot, if the route comes from its mission;
        `protocol`: what the daemon's protocols want sent this cycle (companion/onboard/mission.py `Actions`)."""
        if self.sup.ramp is not None and (jerk := self._autopilot_jerk()) != self._jerk_heard:
            self._jerk_heard = jerk  # (looked up every cycle; the bound recomputed only when it changes)
            self.sup.ramp.autopilot_jerk(jerk)
        i = self.inputs(t, tel, r_obst, engage, startup_ok, route_ready)
        requests, events, texts = [], [], []
        if self.brake is not None:
            self._recovery_available(events, texts)
        d = self.sup.step(i)
        messages = list(protocol.send) if protocol is not None else []
        if protocol is not None:
            events += protocol.events
            texts += protocol.texts
        if self.view.event is not None:
            events.append(self.view.event)
        events += self.view.events
        acts, ended, fail_hold = None, False, d.hold
        ctl = self._controller
        settled, refused = self.view.settled, self.view.undelivered(Requester.OFFBOARD_ENTRY)
        if ctl is not None and refused is not None:
            ctl.refuse(refused)
        elif self.brake is not None and settled is not None and settled.by == Requester.OFFBOARD_ENTRY:
            self.brake.proven = True  # shown within its budget: the brake's own contract may set the limit
        if ctl is not None and i.link_ok:
            fly = self._fly_offboard if self.offboard is not None else self._recover
            acts, d, braking = fly(t, tel, i, d, startup_ok, mission_route)
            fail_hold = d.hold and not braking  # a fail-safe the daemon flies out itself: its Hold comes at rest
            if acts.hold:
                requests.append(ModeRequest(HOLD, Requester.OFFBOARD_STOP))
            if acts.enter:  # the recovery brake's switch is shown within its contract's budget, or it is refused
                requests.append(ModeRequest("offboard", Requester.OFFBOARD_ENTRY,
                                            self._switch_budget if self.brake is not None else None))
            ended = not ctl.streaming and self._was_streaming
            self._was_streaming = ctl.streaming
            if ended:
                self.etr.reset()  # our setpoints are no longer the commanded path
        events += d.events
        texts += d.statustext
        if acts is not None:
            events += acts.events
        engaged_flying = i.engaged and i.armed and i.in_air and self.cfg.daemon_mode.commands
        if startup_ok is False and self._engaged_in_flight and i.link_ok:  # a failed re-check in flight: Hold
            requests.append(ModeRequest(HOLD, Requester.FAILSAFE))
            events.append(("failsafe", {"cause": RECHECK_FAILED, "action": "hold"}))
            texts.append((2, f"CG: {RECHECK_FAILED}: holding"))
        self._engaged_in_flight = engaged_flying
        if self.calibration is not None:
            self._calibration(t, tel, i, d, requests, events, texts)
        if self.shutdown is not None:
            self.shutdown.step(t, i, d, self.authority, engaged_flying, requests, events, texts)
        if fail_hold:
            requests.append(ModeRequest(HOLD, Requester.FAILSAFE))
        self._say(t, tel, i, events, texts)
        cmd = self.authority.arbitrate(t, requests)
        sp = acts.setpoint if acts is not None else None
        if sp is not None and self._flying_ours:
            self.etr.command(t, float(sp.p[0]), float(sp.p[1]))
        speed = d.send_speed if self.cfg.daemon_mode.governs else None
        return i, d, Outbox(mode=cmd, speed=speed, messages=tuple(messages), setpoint=sp, end_stream=ended,
                            events=tuple(events), texts=tuple(texts))

    def _say(self, t: float, tel: Telemetry, i: Inputs, events: list, texts: list) -> None:
        """Say what the contract took and why it stops: the start thrust ratio when it is in force in the air
        (`thrust_start`: once per flight, and again if the hover estimate goes stale), and for a `no safe speed` Hold (or a shadow flight's would-be Hold) the input that caused
        it and how the flight resumes (companion/onboard/no_speed.py), on the hold event and in a STATUSTEXT."""
        basis = self.thrust.basis(t)
        if not tel.in_air or basis != "start":  # said again after a landing, or an estimate lost in flight
            self._thrust_said = False
        elif not self._thrust_said:
            self._thrust_said = True
            events.insert(0, ("thrust_start", dict(self._thrust_start)))  # before what it explains
        why = None
        for k, (name, f) in enumerate(events):
            if not (name == "failsafe" and f.get("cause") == Cause.NO_SAFE_SPEED
                    or name == "would_hold" and Cause.NO_SAFE_SPEED in f.get("causes", ())):
                continue
            if why is None:
                why = diagnose(self.table, self.sup.contract, i, e_tr_floor=self.etr.floor, thrust_basis=basis,
                               policy=getattr(self.sup.policy, "name", "contract"), t_cmd=self.sup.t_cmd)
            events[k] = (name, {**f, **why.fields(self.cfg.daemon_mode)})
            if name == "failsafe" and f.get("action") == "hold":
                texts.append((2, why.statustext(self.cfg.daemon_mode)))

    def _calibration(self, t: float, tel: Telemetry, i: Inputs, d: Decision, requests, events, texts) -> None:
        """The calibration plan's hold legs (companion/onboard/calibration_holds.py): Hold, at rest `rest_s`, the mission.
        A hold or failsafe of the supervisor's own this cycle wins (the leg is abandoned)."""
        cal = self.calibration
        safety = (d.hold_causes[0] if d.hold_causes else "hold") if d.hold else \
            (f"state {d.state}" if d.state in (State.HOLDING, State.FAILSAFE) else None)
        acts = cal.step(t, mode=i.mode, taken_over=i.taken_over, mission_seq=tel.mission_seq, x=tel.x, y=tel.y,
                        speed=i.ground_speed, telemetry_ok=i.telemetry_ok, active=d.state == State.ACTIVE,
                        safety=safety, undelivered=self.view.undelivered(Requester.CALIBRATION))
        if acts.command is not None:
            requests.append(ModeRequest(HOLD if acts.command == "hold" else acts.command, Requester.CALIBRATION))
        events += acts.events
        texts += acts.texts

    def _fly_offboard(self, t: float, tel: Telemetry, i: Inputs, d: Decision, startup_ok: bool | None,
                      mission_route: Route | None) -> tuple[OffboardActions, Decision, bool]:
        """Offboard mode: enter, fly the guidance's setpoints round the keep-out discs, leave (DESIGN.md §5). Its
        actions, the decision (latched when offboard enters its fail-safe hold) and whether the supervisor's Hold
        is flown as a braking stop (the Hold then comes at rest, asked by offboard)."""
        off, veh = self.offboard, self.table.vehicle
        if mission_route is not None and not off.streaming and \
                (off.guidance is None or off.guidance.route is not mission_route):
            if off.guidance is not None:
                off.guidance.planning.close()
            off.guidance = OffboardGuidance(mission_route, planning=self._planning())  # from the next entry
        hi = veh.thrust_ratio_range[1]
        a_max = horizontal_accel_limit(d.omega.tilt, veh.t_max(min(i.thrust_ratio, hi)), veh.mass_kg)
        # a fail-safe the daemon can fly out itself: it streams a braking stop (the stop contract's
        # deceleration, from the measured state) and hands over to Hold at rest
        # (another cause — stale or bad state, Ctrl-C — ends it in Hold at once)
        stopping = self.shutdown is not None
        brakeable = self._brakeable(i, d)
        brake_stop = brakeable and (bool(d.hold_causes) or off.state == OffboardState.BRAKING)
        braking = brake_stop and off.state in (OffboardState.FLYING, OffboardState.BRAKING)
        # the stop brakes at the tilt flown (Ω's of the last cycle with a speed: a Ω with none has no tilt of
        # its own), and at least as hard as the autopilot's own braking would (the stop contract's)
        tr = self._thrust_in_range(i)
        tilt = self.sup.tilt_in_force if self.sup.tilt_in_force is not None else veh.tilt_max
        stop_decel = braking_decel(veh, tr)
        a_stop = max(horizontal_accel_limit(tilt, veh.t_max(tr), veh.mass_kg), stop_decel)
        hold = d.hold and not braking
        stop = hold or stopping or d.state != State.ACTIVE or (off.state == OffboardState.BRAKING and not brake_stop)
        acts = off.step(
            t, engaged=i.engaged and startup_ok is not False and d.state == State.ACTIVE, flying=i.armed and i.in_air,
            mode=i.mode, by_daemon=i.mode_by_daemon, taken_over=i.taken_over, p=(tel.x, tel.y), v=(tel.vx, tel.vy),
            z=tel.z, yaw=tel.yaw, v_max=d.v_cmd or 0.0, a_max=a_max, discs=d.discs, stop=stop, brake_stop=brake_stop,
            a_stop=a_stop, stop_decel=stop_decel, jerk=veh.braking.jerk_max_m_s3, failsafe=d.state == State.HOLDING,
            track_jerk=stop_jerk(veh))
        if any(name == "offboard" and f["to"] == OffboardState.HELD for name, f in acts.events):  # on entering it:
            # a fail-safe Hold is latched (offboard.py) until someone else's mode change or CG_ENGAGE clears it
            d = self.sup.latch_hold(d, "fail-safe stop: held until the pilot or CG_ENGAGE decides")
        return acts, d, braking


    @property
    def _controller(self) -> OffboardController | None:
        """What streams the daemon's setpoints: offboard's controller, or the recovery brake's (governor mode)."""
        return self.offboard if self.offboard is not None else self.brake

    @property
    def streaming(self) -> bool:
        """The daemon streams setpoints (offboard, or the recovery brake): they are the commanded path."""
        ctl = self._controller
        return ctl is not None and ctl.streaming

    @property
    def _flying_ours(self) -> bool:
        """The autopilot flies the daemon's setpoints: they stream and it shows OFFBOARD / GUIDED (until it does,
        it flies its own path, and the contour error is measured against that)."""
        return self.streaming and self.view is not None and self.view.mode == "offboard"

    def _brakeable(self, i: Inputs, d: Decision) -> bool:
        """The daemon can fly this Hold out itself as a braking stop (its state sound, not stopping, every cause
        one of BRAKE_STOP_CAUSES): offboard's fail-safe stop and the recovery brake."""
        return self.shutdown is None and i.telemetry_ok and all(c in BRAKE_STOP_CAUSES for c in d.hold_causes)

    def _thrust_in_range(self, i: Inputs) -> float:
        """The thrust estimate within the vehicle file's range (its lowest while unknown): what a stop brakes on."""
        lo, hi = self.table.vehicle.thrust_ratio_range
        return min(max(i.thrust_ratio, lo), hi) if math.isfinite(i.thrust_ratio) else lo

    def command_ack(self, command: int, result: int) -> None:
        """A COMMAND_ACK: DO_SET_MODE's answer goes to the mode authority, DO_CHANGE_SPEED's to the supervisor
        (each re-sends its command every cycle until answered)."""
        if command == MAV_CMD_DO_SET_MODE:
            self.authority.answer(result)
        elif command == MAV_CMD_DO_CHANGE_SPEED:
            self.sup.speed_answered()

    def _recovery_available(self, events: list, texts: list) -> None:
        """The recovery brake's availability, said when it changes (DESIGN.md §5: the brake's own start-up checks
        and fallback). It flies a stop once its start-up checks pass, until the autopilot refuses its switch or does
        not show it within the brake's contract's budget. Its own (higher) stop contract sets the limit only once
        its switch has been shown within that budget in this flight; before, the autopilot's Hold's does, so a
        first switch refused or late still stops from within the Hold's limit."""
        br = self.brake
        checks = self.checks.brake if self.checks is not None else None
        ready, why = (False, f"the switch to offboard was refused: {br.refused}") if br.refused else \
            (False, "its start-up checks are pending") if checks is None else checks
        proven = ready and br.proven
        self._brake_ready = ready
        self.sup.recovery_dt = 1.0 / self.cfg.loop_hz if proven else None
        now = (ready, proven, why)
        if now != self._brake_said:
            self._brake_said = now
            limit = "its own stop contract" if proven else "the autopilot's Hold's stop contract" + \
                (" until its switch is shown in time in this flight" if ready else "")
            events.append(("recovery_brake", {"available": ready, "proven": proven, "reason": why, "limit": limit}))
            texts.append((5, "CG: recovery brake available" + ("" if proven else ": Hold's limit until its switch "
                                                               "is shown")) if ready else
                         (4, f"CG: recovery brake unavailable: {why}"))

    def _recover(self, t: float, tel: Telemetry, i: Inputs, d: Decision, startup_ok, mission_route
                 ) -> tuple[OffboardActions, Decision, bool]:
        """Governor mode's recovery brake: a stop the stop contract calls for, flown by the
        daemon in offboard at the airframe's braking from the measured state, then Hold (`OffboardController.
        recover`); a cause it cannot fly out, or the shutdown, holds at once. Its actions, the decision (latched
        while it brakes: the supervisor holds in offboard) and whether it brakes (the Hold then comes at rest)."""
        br, veh = self.brake, self.table.vehicle
        if br.state in FINISHED and d.state == State.ACTIVE:  # someone else resumed: ready for the next stop
            br.state = OffboardState.OFF
        sound, tr = self._brakeable(i, d), self._thrust_in_range(i)
        a0 = self._accel.over(A0_S)  # the measured acceleration: Δv over ≥ A0_S
        a_stop = airframe_decel(veh, tr)
        was_refused, was_braking = br.refused is not None, br.state == OffboardState.BRAKING
        acts = br.recover(t, start=d.hold and sound and self._brake_ready, abort=not sound,
                          mode=i.mode, taken_over=i.taken_over, p=(tel.x, tel.y), v=(tel.vx, tel.vy), z=tel.z,
                          yaw=tel.yaw, a_stop=a_stop, jerk=stop_jerk(veh), a0=a0)
        braking = br.state == OffboardState.BRAKING
        if braking and not was_braking:  # the speed the brake was called at: a refusal judged on it too
            self._brake_v0 = i.ground_speed
        if braking and not self.sup.latched:
            d = self.sup.latch_hold(d, "recovery brake: held until the pilot or the ground station changes the mode")
        # the brake's assumption, checked: refused above the autopilot's Hold's limit, the autopilot broke it (an
        # unknown speed counts as above it; judged at the speed when called as well: a switch never shown is found
        # refused `delivery.t_mode_s` later, by when a vehicle stopped by a collision reads no speed)
        d = self.sup.switch_refused(d, i, refused=br.refused is not None and not was_refused,
                                    speed=max(_or_inf(i.ground_speed), _or_inf(self._brake_v0)))
        return acts, d, braking

    @property
    def _switch_budget(self) -> float:
        """[s] how long after asking the recovery brake's stop contract allows its switch to show: the switch
        (`hold_switch_s`), one cycle and the delivery budget (contracts/stop.py `recovery_brake`)."""
        return self.table.vehicle.braking.hold_switch_s + 1.0 / self.cfg.loop_hz + self.cfg.delivery.t_cmd_s

    def _autopilot_jerk(self) -> float | None:
        """The jerk of the autopilot's approach smoothing as it reported it (the start-up checks' parameter for
        braking.jerk_max_m_s3) [m/s³], None until reported."""
        for c in self.adapter.param_checks if self.checks is not None else ():
            if c.what == "braking.jerk_max_m_s3" and c.name in self.checks.values:
                return self.checks.values[c.name] * c.scale
        return None

    def state_record(self, i: Inputs, d: Decision, tel: Telemetry) -> dict:
        """The cycle's state sample (companion/onboard/logschema.py: STATE says what each value means)."""
        om = d.omega
        return dict(
            state=d.state, mode=i.mode, contract=self.sup.contract, engaged=i.engaged,
            x=tel.x, y=tel.y, z=tel.z, vx=tel.vx, vy=tel.vy, vz=tel.vz, ground_speed=i.ground_speed,
            d_od=i.dod.d_od, d_od_stated=i.dod.stated_m, e_tr=om.e_tr, e_tr_measured=i.e_tr_measured, r_obst=i.r_obst,
            thrust_ratio=i.thrust_ratio, v_max=om.v_max, tilt_deg=math.degrees(om.tilt), v_safe=om.v_safe,
            gamma=(d.v_cmd if d.v_cmd is not None else om.v_max) - om.v_safe,
            gamma_flown=i.ground_speed - om.v_safe, v_cmd=d.v_cmd, obstacle_m=i.dod.obstacle_m)


class Shutdown:
    """Stop means stop: a daemon that stops while engaged in flight asks for Hold (the mode authority delivers it),
    waits until the autopilot shows it, SHUTDOWN_WAIT_S at most, and says so; on the ground, or not engaged, it
    just stops. `done` once decided."""

    def __init__(self, t: float):
        self.t0 = t
        self.hold: bool | None = None  # a Hold was needed (None: not decided yet)
        self.confirmed = False
        self.done = False

    def step(self, t: float, i: Inputs, d: Decision, authority: ModeAuthority, engaged_flying: bool, requests,
             events, texts) -> None:
        if self.done:
            return
        if self.hold is None:
            self.hold = engaged_flying and i.link_ok
            if not self.hold:
                self.done = True
                events.append(("shutdown", {"hold": False, "reason": "not engaged in flight" if i.link_ok
                                            else "no autopilot link"}))
                return
            texts.append((2, "CG: stopping in flight: Hold"))
            requests.append(ModeRequest(HOLD, Requester.SHUTDOWN))
        if i.mode == authority.hold_mode:  # the autopilot shows Hold (ours, or already someone else's)
            self.confirmed = True
        elif t - self.t0 < SHUTDOWN_WAIT_S:
            return
        self.done = True
        events.append(("shutdown", {"hold": True, "confirmed": self.confirmed, "waited_s": t - self.t0}))
        if not self.confirmed:
            texts.append((2, f"CG: Hold not confirmed in {SHUTDOWN_WAIT_S:g} s: the autopilot's own failsafe applies"))


def _or_inf(v: float) -> float:
    """A speed, an unknown one (NaN) as faster than any limit."""
    return v if math.isfinite(v) else math.inf
