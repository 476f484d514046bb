"""The daemon's pure cycle: samples → estimators (E_tr, D_od, thrust_ratio, nav health) → mode authority (whose
mode is it) → supervisor (Γ, Ω, the keep-out discs) → the actors that may want a mode, each `step(turn) -> Part`
(companion/onboard/turn.py: offboard flight or the recovery brake, the calibration plan's hold legs, the failed
re-check in flight, the shutdown) → the mode authority's arbitration → one `Outbox`. No I/O: `take(sample)` feeds
it, `step(given)` returns the `Inputs` it judged, the supervisor's frozen `Decision` and the cycle's `Outbox`
(everything to send, log and say), which MAVLink-out applies in one call.

It also keeps what the decisions depend on between cycles: whether the vehicle was first seen flying (a restart
in flight never engages until asked anew).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from contracts.errors import ContractError
from contracts.online_planner import load_solver
from contracts.table import ContractTable

from .authority import HOLD, ModeAuthority, ModeRequest, ModeView, Requester
from .autopilot_base import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_DO_SET_MODE
from .calibration_holds import CalibrationHolds, read_legs
from .contract_in_force import fallback_for
from .config import Config
from .flying import OffboardFlight, RecoveryBrake
from .guidance import OffboardGuidance, Route, seen_obstacles
from .holds import Recheck, Shutdown
from .mission import Home
from .no_speed import diagnose
from .offboard import OffboardController
from .outbox import Outbox
from .samples import (
    MissionMessage,
)
from .sensing import A0_S, Sensing
from .startup import StartupChecks
from .states import Cause, OffboardState
from .supervisor import RAMP_WINDOW_S, Decision, Inputs, Supervisor
from .telemetry import Telemetry
from .turn import Part, Turn


@dataclass(frozen=True, slots=True)
class Given:
    """What the daemon hands the cycle: the clock, the vehicle as reported, its own parameters and protocols."""

    t: float
    tel: Telemetry
    r_obst: float  # CG_R_OBST
    engage: bool  # CG_ENGAGE set
    startup_ok: bool | None  # the start-up checks (None: pending)
    mission_route: Route | None = None  # the route downloaded from the autopilot, if the route comes from its mission
    route_ready: bool = True  # the route is held (from the mission: once downloaded)
    protocol: object | None = None  # what the daemon's protocols want sent this cycle (mission.py `Actions`)


class Cycle:
    def __init__(self, cfg: Config, table: ContractTable, adapter, contract: str, planning, policy=None):
        """`planning`: a factory of the planning runner (one per guidance: inline, in a worker process or on a worker
        thread); `policy`: the speed policy flown (companion/onboard/supervisor.py ContractSpeed by default)."""
        self.cfg, self.table, self.adapter = cfg, table, adapter
        veh = table.vehicle
        self.sensing = sensing = Sensing(cfg, table, adapter, contract)
        self._thrust_said = False  # the start value in force in the air has been said (`thrust_start`)
        self.sup = Supervisor(table, cfg.daemon_mode, contract=contract, dwell_s=cfg.contract.dwell_s,
                              overshoot=cfg.speed_overshoot.budget(), loop_dt=1.0 / cfg.loop_hz,
                              late_hold_s=cfg.timeouts.cycle_late_s, late_allowance_s=cfg.timeouts.cycle_jitter_s,
                              policy=policy, e_tr_window_s=cfg.contract.e_tr_window_s,
                              e_tr_floor_m=sensing.etr.floor, ramp_m_s=cfg.governor.approach_ramp_m_s,
                              t_cmd_s=cfg.delivery.t_cmd_s, fallback=fallback_for(cfg, contract))
        self.checks = StartupChecks(adapter, veh, cfg, table.e_pred is not None)
        self.view: ModeView | None = None  # this cycle's mode, as the authority judged it
        self.authority = ModeAuthority(adapter.hold_mode(), cfg.delivery.t_cmd_s, cfg.delivery.t_mode_s,
                                       adapter.hold_fallbacks)
        # what flies the daemon's own setpoints: offboard mode's flight, or governor mode's recovery brake
        self.flying: OffboardFlight | RecoveryBrake | None = None
        if cfg.daemon_mode.flies_route:
            if cfg.route is None:
                raise ContractError("mode offboard needs a route (config key route.waypoints or route.source: mission)")
            load_solver()  # now, not at the first plan (a route from the mission makes its planner in the loop)
            guidance = None  # route from the mission: set once a downloaded route is held (engaging waits for it)
            if cfg.route.source != "mission":
                route = Route(cfg.route.waypoints, cfg.route.altitude_m, cfg.route.corner_cut_m)
                guidance = OffboardGuidance(route, planning=planning())
            self.flying = OffboardFlight(OffboardController(guidance, cfg.offboard_entry_s), veh, planning)
        elif cfg.daemon_mode.governs and cfg.governor.recovery_brake:
            # its stop contract allows its switch the switch itself, one cycle and the delivery budget
            # (contracts/stop.py `recovery_brake`)
            budget = veh.braking.hold_switch_s + 1.0 / cfg.loop_hz + cfg.delivery.t_cmd_s
            self.flying = RecoveryBrake(veh, budget, covered=getattr(table, "e_pred_brake", None) is not None)
        self._jerk_heard: float | None = None  # the autopilot's jerk last given to the approach ramp
        self.first_seen_in_air: bool | None = None  # restart in flight ⇒ no engagement until asked anew
        # calibration.legs: the calibration plan's hold legs, flown by the daemon (governor mode only: config.py)
        self.calibration: CalibrationHolds | None = None
        if cfg.calibration is not None:
            self.calibration = CalibrationHolds(read_legs(cfg.calibration.legs), adapter.mission_item0_is_home)
        self.recheck = Recheck()
        self.shutdown: Shutdown | None = None  # the daemon is stopping (`stop`)

    offboard = property(lambda self: self.flying.controller if isinstance(self.flying, OffboardFlight) else None)
    brake = property(lambda self: self.flying.controller if isinstance(self.flying, RecoveryBrake) else None)

    def take(self, s) -> None:
        """One sample to the estimators that take it; HOME_POSITION to the hold legs (their waypoints are placed from
        it); every sample to the speed policy as received (a baseline law builds its own map, as its firmware does)."""
        if not self.sensing.take(s, self._flying_ours) and isinstance(s, MissionMessage) and self.calibration is not None and \
                s.msg.get_type() == "HOME_POSITION":
            self.calibration.take_home(Home.from_msg(s.msg))
        self.sup.policy.take(s)

    def engage_requested(self) -> None:
        """CG_ENGAGE set anew: a restart in flight may engage now, and offboard may be entered again."""
        self.first_seen_in_air = False
        if self.offboard is not None:
            self.offboard.rearm()
        self.sup.unlatch()

    def close(self) -> None:
        """The daemon ends: the planning worker too."""
        if self.flying is not None:
            self.flying.close()

    def stop(self, t: float) -> None:
        """The daemon is stopping: from the next cycle on, stop flying (a shutdown Hold if engaged in flight)."""
        if self.shutdown is None:
            self.shutdown = Shutdown(t, self.authority.hold_mode)

    def failed_hold(self, t: float) -> Outbox:
        """A cycle that raised: the failsafe Hold, through the authority, as an outbox of its own."""
        return Outbox(mode=self.authority.arbitrate(t, [ModeRequest(HOLD, Requester.FAILSAFE)]))

    def command_ack(self, command: int, result: int) -> None:
        """A COMMAND_ACK: DO_SET_MODE's answer goes to the mode authority, DO_CHANGE_SPEED's to the supervisor
        (each re-sends its command every cycle until answered)."""
        if command == MAV_CMD_DO_SET_MODE:
            self.authority.answer(result)
        elif command == MAV_CMD_DO_CHANGE_SPEED:
            self.sup.speed_answered()

    # ------------------------------------------------------------------ the cycle
    def inputs(self, g: Given) -> Inputs:
        """What the supervisor judges: the estimators' values at `g.t`, the mode as the authority judges it."""
        t, tel, to, s = g.t, g.tel, self.cfg.timeouts, self.sensing
        link_ok = t - tel.t_heartbeat <= to.heartbeat_s
        late = s.timing.tick(t, link_ok)
        telemetry_ok = t - tel.t_local <= to.telemetry_s
        speed = tel.ground_speed if telemetry_ok else math.nan
        e_tr = s.etr.value
        beta = s.creep.bearing(t, tel.vx, tel.vy, tel.yaw, lambda b: s.dod.in_view(t, b), e_tr) if telemetry_ok \
            else 0.0
        corridor = 2 * g.r_obst + e_tr + self.table.vehicle.r_body_m
        dod = s.dod.estimate(t, beta, corridor, g.r_obst)
        truth = s.truth.estimate(t, dod.d_od)
        if truth.d_od < dod.d_od:  # the evidence allows less than the claim (fog that hides, not tells)
            dod = replace(dod, d_od=truth.d_od, lowered=True,
                          reason=f"detection range from evidence ({truth.confidence:.0%} confidence): {truth.reason}")
        thrust_ratio, _ = s.thrust.value(t)
        s.accel.add(tel.t_local, tel.vx, tel.vy)
        accel = s.accel.over(RAMP_WINDOW_S) if telemetry_ok else None
        if accel is None:
            accel_along = math.nan
        else:  # along the velocity; its magnitude from near rest (any direction is "ahead" then)
            accel_along = float(accel @ (tel.vx, tel.vy)) / speed if speed > 0.5 else float(math.hypot(*accel))
        hits = tuple(s.dod.fresh_hits(t))
        seen = seen_obstacles(hits, (tel.x, tel.y), tel.yaw, g.r_obst)
        mode = self.adapter.mode_name(tel.base_mode, tel.custom_mode) if link_ok else "other"
        self.view = view = self.authority.observe(t, mode, link_ok)
        if self.first_seen_in_air is None and tel.landed_state:
            self.first_seen_in_air = tel.in_air
        off = self.offboard
        engaged = (g.engage and g.startup_ok is not False and self.first_seen_in_air is False and g.route_ready
                   and not (off is not None and off.state in (OffboardState.DONE, OffboardState.STOOD_DOWN)))
        applies = (self.adapter.limit_applies(mode) or (off is not None and mode == "offboard")) and \
            not (off is not None and off.backing_off)
        v_mission = self.calibration.mission_speed(tel.mission_seq) if self.calibration is not None else math.nan
        return Inputs(t=t, link_ok=link_ok, telemetry_ok=telemetry_ok, nav_ok=s.nav.healthy(t), armed=tel.armed,
                      in_air=tel.in_air, mode=mode, limit_applies=applies, mode_by_daemon=view.by_daemon,
                      mode_changed=view.event is not None, taken_over=view.taken_over,
                      ground_speed=speed, dod=dod, e_tr_measured=e_tr, thrust_ratio=thrust_ratio, r_obst=g.r_obst,
                      engaged=engaged, mission_seq=tel.mission_seq, obstacle_width=seen.width,
                      obstacles=len(seen.obstacles), places=seen.obstacles, discs=tuple(seen.discs),
                      hits=hits, hit_ends=tuple(s.dod.hit_ends(t)), beta=beta,
                      pose=(tel.x, tel.y, tel.yaw),
                      path=off.path_ahead(t) if off is not None else (),
                      v_cruise=s.v_cruise, late_s=late, late_unbudgeted_s=s.timing.unbudgeted_s,
                      late_within_s=s.timing.within_s, accel_along=accel_along, delivery_late=view.late,
                      v_mission=v_mission)

    def step(self, g: Given) -> tuple[Inputs, Decision, Outbox]:
        """One cycle: the estimators' inputs, the supervisor's decision, the actors' parts, the authority's winner."""
        if self.sup.ramp is not None and (jerk := self._autopilot_jerk()) != self._jerk_heard:
            self._jerk_heard = jerk  # (looked up every cycle; the bound recomputed only when it changes)
            self.sup.ramp.autopilot_jerk(jerk)
        i = self.inputs(g)
        brake = self.flying if isinstance(self.flying, RecoveryBrake) else None
        first = Part()
        if brake is not None:  # its availability, before the decision (its own stop contract sets the limit)
            first = brake.available(self.checks.brake)
            self.sup.use_recovery_brake(1.0 / self.cfg.loop_hz if brake.proven else None, flies=brake.ready)
        d = self.sup.step(i)
        protocol, view = g.protocol, self.view
        events = [*first.events, *(protocol.events if protocol is not None else ()),
                  *(() if view.event is None else (view.event,)), *view.events]
        texts = [*first.texts, *(protocol.texts if protocol is not None else ())]
        turn = self._turn(g, i, d)
        flown = self.flying.step(turn) if self.flying is not None else Part()
        if flown.latch is not None:
            d = self.sup.latch_hold(d, flown.latch)
        if flown.switch_refused is not None:
            d = self.sup.switch_refused(d, i, *flown.switch_refused)
        if flown.end_stream:
            self.sensing.etr.reset()  # our setpoints are no longer the commanded path
        turn = replace(turn, d=d)
        parts = [flown] + [actor.step(turn) for actor in (self.recheck, self.calibration, self.shutdown)
                           if actor is not None]
        events += d.events
        texts += d.statustext
        requests = []
        for part in parts:
            events += part.events
            texts += part.texts
            requests += part.requests
        if d.hold and not flown.braking:  # a fail-safe the daemon flies out itself: its Hold comes at rest
            requests.append(ModeRequest(HOLD, Requester.FAILSAFE))
        self._explain(turn, events, texts)
        cmd = self.authority.arbitrate(g.t, requests)
        sp = flown.setpoint
        if sp is not None and self._flying_ours:
            self.sensing.etr.command(g.t, float(sp.p[0]), float(sp.p[1]))
        speed = d.send_speed if self.cfg.daemon_mode.governs else None
        return i, d, Outbox(mode=cmd, speed=speed, messages=tuple(protocol.send) if protocol is not None else (),
                            setpoint=sp, end_stream=flown.end_stream, events=tuple(events), texts=tuple(texts))

    def _turn(self, g: Given, i: Inputs, d: Decision) -> Turn:
        engaged_flying = i.engaged and i.armed and i.in_air and self.cfg.daemon_mode.commands
        a0 = self.sensing.accel.over(A0_S) if isinstance(self.flying, RecoveryBrake) else None  # Δv over ≥ A0_S
        return Turn(t=g.t, tel=g.tel, i=i, d=d, view=self.view, startup_ok=g.startup_ok,
                    engaged_flying=engaged_flying, stopping=self.shutdown is not None, tilt=self.sup.tilt_in_force,
                    mission_route=g.mission_route, a0=a0)

    def _explain(self, turn: Turn, events: list, texts: list) -> None:
        """Say what the contract took and why it stops: the start thrust ratio when it is in force in the air
        (`thrust_start`: once per flight, and again if the hover estimate goes stale), and for a `no safe speed`
        Hold (or a shadow flight's would-be Hold) the input that caused it and how the flight resumes
        (companion/onboard/no_speed.py), on the hold event and in a STATUSTEXT."""
        basis = self.sensing.thrust.basis(turn.t)
        if not turn.tel.in_air or basis != "start":  # said again after a landing, or an estimate lost in flight
            self._thrust_said = False
        elif not self._thrust_said:
            self._thrust_said = True
            events.insert(0, ("thrust_start", dict(self.sensing.thrust_start)))  # before what it explains
        why = None
        for k, (name, f) in enumerate(events):
            if not (name == "failsafe" and f.get("cause") == Cause.NO_SAFE_SPEED
                    or name == "would_hold" and Cause.NO_SAFE_SPEED in f.get("causes", ())):
                continue
            if why is None:
                why = diagnose(self.table, self.sup.contract, turn.i, e_tr_floor=self.sensing.etr.floor, thrust_basis=basis,
                               policy=getattr(self.sup.policy, "name", "contract"), t_cmd=self.sup.t_cmd)
            events[k] = (name, {**f, **why.fields(self.cfg.daemon_mode)})
            if name == "failsafe" and f.get("action") == "hold":
                texts.append((2, why.statustext(self.cfg.daemon_mode)))

    @property
    def streaming(self) -> bool:
        """The daemon streams setpoints (offboard, or the recovery brake): they are the commanded path."""
        return self.flying is not None and self.flying.streaming

    @property
    def _flying_ours(self) -> bool:
        """The autopilot flies the daemon's setpoints: they stream and it shows OFFBOARD / GUIDED (until it does,
        it flies its own path, and the contour error is measured against that)."""
        return self.streaming and self.view is not None and self.view.mode == "offboard"

    def _autopilot_jerk(self) -> float | None:
        """The jerk of the autopilot's approach smoothing as it reported it (the start-up checks' parameter for
        braking.jerk_max_m_s3) [m/s³], None until reported."""
        for c in self.adapter.param_checks:
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
            gamma_flown=i.ground_speed - om.v_safe, v_cmd=d.v_cmd, obstacle_m=i.dod.obstacle_m,
            withheld=i.dod.withheld)
