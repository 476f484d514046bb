"""The actors that fly the daemon's own setpoints (DESIGN.md §5): offboard mode's flight along its route round the
keep-out discs, and governor mode's recovery brake. Each reads the cycle's `Turn` and returns its `Part`
(companion/onboard/turn.py); the stream itself is an `OffboardController`'s (companion/onboard/offboard.py).

Both fly a stop the decision calls for themselves when the daemon's own state is sound (`brakeable`): a braking
stop from the measured state, then Hold at rest; a cause they cannot fly out holds at once.
"""

from __future__ import annotations

import math
from dataclasses import replace

from contracts.flat import horizontal_accel_limit
from contracts.stop import braking_decel, recovery_brake_stop, stop_jerk
from contracts.vehicle import Vehicle

from .authority import HOLD, ModeRequest, Requester
from .guidance import OffboardGuidance, Setpoint, reference_jump
from .offboard import Ask, OffboardController
from .states import BRAKE_STOP_CAUSES, FINISHED, REFERENCE_ON, OffboardState, State, Subsystem
from .turn import Part, Turn

ENTRY = "offboard"  # the mode the flying actors ask for (OFFBOARD / GUIDED: the adapter's name)
FAILSAFE_LATCH = "fail-safe stop: held until the pilot or CG_ENGAGE decides"
DEAD_END_LATCH = "dead end: held until the pilot or CG_ENGAGE decides"
BRAKE_LATCH = "recovery brake: held until the pilot or the ground station changes the mode"
REFERENCE_JUMP_M = 0.5  # [m] a setpoint this much farther from the vehicle than the last one flown on breaks REFERENCE_ON
NOT_COVERED = "the table carries no E_tr_pred for the brake's own stop (contract-guard table etr --brake)"


def brakeable(turn: Turn) -> bool:
    """The daemon can fly this Hold out itself as a braking stop: its state sound, not stopping, every cause one of
    BRAKE_STOP_CAUSES."""
    return not turn.stopping and turn.i.telemetry_ok and all(c in BRAKE_STOP_CAUSES for c in turn.d.hold_causes)


def thrust_in_range(vehicle: Vehicle, thrust_ratio: float) -> float:
    """The thrust estimate within the vehicle file's range (its lowest while unknown): what a stop brakes on."""
    lo, hi = vehicle.thrust_ratio_range
    return min(max(thrust_ratio, lo), hi) if math.isfinite(thrust_ratio) else lo


def _or_inf(v: float) -> float:
    """A speed, an unknown one (NaN) as faster than any limit."""
    return v if math.isfinite(v) else math.inf


class Flying:
    """What both flying actors share: the controller that streams, the mode authority's answer to its switch, the
    part it makes of the controller's actions."""

    within_s: float | None = None  # the entry's own delivery budget (None: the authority's t_mode_s)

    def __init__(self, controller: OffboardController, vehicle: Vehicle):
        self.controller, self.vehicle = controller, vehicle
        self._was_streaming = False
        self._last: tuple[float, Setpoint] | None = None  # the last setpoint streamed, and when
        self._jumped = False  # that setpoint broke `REFERENCE_ON`

    @property
    def streaming(self) -> bool:
        return self.controller.streaming

    def step(self, turn: Turn) -> Part:
        refused = turn.view.undelivered(Requester.OFFBOARD_ENTRY)
        if refused is not None:
            self.controller.refuse(refused)
        else:
            self._settled(turn)
        if not turn.i.link_ok:
            return Part()
        return self._judge_reference(turn, self._fly(turn))

    def _judge_reference(self, turn: Turn, part: Part) -> Part:
        """Guidance's own guarantee, judged on the setpoints streamed: each goes on from where the last was. One farther
        from the vehicle than the last one flown on would be, by more than REFERENCE_JUMP_M (`reference_jump`), breaks
        it — a violation from that setpoint to the next that does not."""
        sp, last = part.setpoint, self._last
        self._last = None if sp is None else (turn.t, sp)
        jump = 0.0 if sp is None or last is None else \
            reference_jump(last[1], turn.t - last[0], sp, (turn.tel.x, turn.tel.y))
        if (jump > REFERENCE_JUMP_M) == self._jumped:
            return part
        self._jumped = not self._jumped
        said = ("violation_start", {"subsystem": Subsystem.GUIDANCE, "guarantee": REFERENCE_ON,
                                    "assumed": REFERENCE_JUMP_M, "observed": round(jump, 3), "action": "flown"}) \
            if self._jumped else ("violation_end", {"subsystem": Subsystem.GUIDANCE, "guarantee": REFERENCE_ON})
        return replace(part, events=(*part.events, said))

    def _settled(self, turn: Turn) -> None:
        """The switch was shown (the mode authority's delivery settled)."""

    def _fly(self, turn: Turn) -> Part:
        raise NotImplementedError

    def _ask(self, turn: Turn, **kw) -> Ask:
        tel, i = turn.tel, turn.i
        return Ask(t=turn.t, mode=i.mode, p=(tel.x, tel.y), v=(tel.vx, tel.vy), z=tel.z, yaw=tel.yaw,
                   taken_over=i.taken_over, **kw)

    def _part(self, acts, braking: bool, **kw) -> Part:
        streaming = self.controller.streaming
        ended, self._was_streaming = not streaming and self._was_streaming, streaming
        requests = ((ModeRequest(HOLD, Requester.OFFBOARD_STOP),) if acts.hold else ()) + \
            ((ModeRequest(ENTRY, Requester.OFFBOARD_ENTRY, self.within_s),) if acts.enter else ())
        return Part(requests=requests, events=tuple(acts.events), texts=tuple(acts.texts), setpoint=acts.setpoint,
                    end_stream=ended, braking=braking, **kw)

    def close(self) -> None:
        self.controller.close()


class OffboardFlight(Flying):
    """Offboard mode: enter, fly the guidance's setpoints round the keep-out discs, leave (DESIGN.md §5); a stop the
    daemon can fly out itself is a braking stop (the stop contract's deceleration, from the measured state) handed
    over to Hold at rest; another cause (stale or bad state, the shutdown) ends it in Hold at once."""

    def __init__(self, controller: OffboardController, vehicle: Vehicle, planning):
        super().__init__(controller, vehicle)
        self._planning = planning

    def _fly(self, turn: Turn) -> Part:
        off, veh, i, d = self.controller, self.vehicle, turn.i, turn.d
        route = turn.mission_route
        if route is not None and not off.streaming and (off.guidance is None or off.guidance.route is not route):
            off.follow(OffboardGuidance(route, planning=self._planning()))  # from the next entry
        hi = veh.thrust_ratio_range[1]
        a_max = horizontal_accel_limit(d.omega.tilt, veh.t_max(min(i.thrust_ratio, hi)), veh.mass_kg)
        brake_stop = brakeable(turn) and (bool(d.hold_causes) or off.state == OffboardState.BRAKING)
        braking = brake_stop and off.state in (OffboardState.FLYING, OffboardState.BRAKING)
        # the stop brakes at the tilt flown, and at least as hard as the autopilot's own braking would (the stop
        # contract's)
        tr = thrust_in_range(veh, i.thrust_ratio)
        tilt = turn.tilt if turn.tilt is not None else veh.tilt_max
        stop_decel = braking_decel(veh, tr)
        a_stop = max(horizontal_accel_limit(tilt, veh.t_max(tr), veh.mass_kg), stop_decel)
        hold = d.hold and not braking
        stop = hold or turn.stopping or d.state != State.ACTIVE or \
            (off.state == OffboardState.BRAKING and not brake_stop)
        acts = off.step(self._ask(
            turn, by_daemon=i.mode_by_daemon, engaged=i.engaged and turn.startup_ok is not False and
            d.state == State.ACTIVE, flying=i.armed and i.in_air, v_max=d.v_cmd or 0.0, a_max=a_max, discs=d.discs,
            walls=d.walls, stop=stop, brake_stop=brake_stop, a_stop=a_stop, stop_decel=stop_decel,
            jerk=veh.braking.jerk_max_m_s3,
            failsafe=d.state == State.HOLDING, track_jerk=stop_jerk(veh)))
        # a fail-safe stop latches its Hold from the braking on, until someone else's mode change or CG_ENGAGE clears
        # it: a cause that clears while the vehicle brakes (an obstacle out of the Hold's reach as it slows) and comes
        # back is the same stop, not a second one
        held = any(name == "offboard" and f["to"] in (OffboardState.HELD, OffboardState.BRAKING) for name, f in acts.events)
        dead_end = any(name == "dead_end" for name, _ in acts.events)
        return self._part(acts, braking, latch=(DEAD_END_LATCH if dead_end else FAILSAFE_LATCH) if held else None)


class RecoveryBrake(Flying):
    """Governor mode's recovery brake: a stop the stop contract calls for, flown by the daemon in offboard at the
    airframe's braking from the measured state, then Hold (`OffboardController.recover`); a cause it cannot fly
    out, or the shutdown, holds at once. Available while its start-up checks pass, until the autopilot refuses its
    switch or does not show it within the brake's contract's budget (`switch_budget_s`). Its own (higher) stop
    contract sets the limit only once its switch has been shown within that budget in this flight (`proven`);
    before, the autopilot's Hold's does, so a first switch refused or late still stops from within the Hold's
    limit."""

    def __init__(self, vehicle: Vehicle, switch_budget_s: float, covered: bool = True):
        """`covered`: the table carries the brake's controller contract (`e_tr_pred_brake`); without it the brake is
        unavailable (no E_tr_pred bounds the stop it flies)."""
        super().__init__(OffboardController(None), vehicle)
        self.within_s = switch_budget_s
        self.covered = covered
        self.ready = False  # the brake flies a stop the stop contract calls for
        self._said: tuple[bool, bool, str] | None = None
        self._v0 = 0.0  # [m/s] the ground speed when the brake was last called

    @property
    def proven(self) -> bool:
        """Its switch was shown within its budget in this flight: its own stop contract may set the limit."""
        return self.ready and self.controller.proven

    def available(self, checks: tuple[bool, str] | None) -> Part:
        """Its availability from its start-up checks (None: pending), said when it changes (DESIGN.md §5: the
        brake's own start-up checks and fallback)."""
        br = self.controller
        ready, why = (False, f"the switch to offboard was refused: {br.refused}") if br.refused else \
            (False, NOT_COVERED) if not self.covered else \
            (False, "its start-up checks are pending") if checks is None else checks
        self.ready = ready
        now = (ready, self.proven, why)
        if now == self._said:
            return Part()
        self._said = now
        limit = "its own stop contract" if self.proven else "the autopilot's Hold's stop contract" + \
            (" until its switch is shown in time in this flight" if ready else "")
        text = (5, "CG: recovery brake available" + ("" if self.proven else ": Hold's limit until its switch is "
                                                     "shown")) if ready else \
            (4, f"CG: recovery brake unavailable: {why}")
        return Part(events=(("recovery_brake", {"available": ready, "proven": self.proven, "reason": why,
                                                "limit": limit}),), texts=(text,))

    def _settled(self, turn: Turn) -> None:
        settled = turn.view.settled
        if settled is not None and settled.by == Requester.OFFBOARD_ENTRY:
            self.controller.shown()

    def _fly(self, turn: Turn) -> Part:
        br, veh, i, d = self.controller, self.vehicle, turn.i, turn.d
        if br.state in FINISHED and d.state == State.ACTIVE:  # someone else resumed: ready for the next stop
            br.rearm()
        sound = brakeable(turn)
        was_refused, was_braking = br.refused is not None, br.state == OffboardState.BRAKING
        a_stop, jerk = recovery_brake_stop(veh, thrust_in_range(veh, i.thrust_ratio))
        acts = br.recover(self._ask(turn, start=d.hold and sound and self.ready, abort=not sound, a_stop=a_stop,
                                    track_jerk=jerk, a0=turn.a0))
        braking = br.state == OffboardState.BRAKING
        if braking and not was_braking:  # the speed the brake was called at: a refusal judged on it too
            self._v0 = i.ground_speed
        # the brake's assumption, checked: refused above the autopilot's Hold's limit, the autopilot broke it (an
        # unknown speed counts as above it; judged at the speed when called as well: a switch never shown is found
        # refused `delivery.t_mode_s` later, by when a vehicle stopped by a collision reads no speed)
        refused = (br.refused is not None and not was_refused, max(_or_inf(i.ground_speed), _or_inf(self._v0)))
        return self._part(acts, braking, latch=BRAKE_LATCH if braking else None, switch_refused=refused)
