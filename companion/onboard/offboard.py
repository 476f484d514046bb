"""Offboard mode's control of the autopilot: entering, flying, leaving. Pure: returns actions.

    off ──engaged, flying──▶ entering (stream setpoints at the current position for `entry_s`,
                                        then ask for OFFBOARD / GUIDED)
        entering ──heartbeat shows it──▶ flying (guidance setpoints every cycle, ≥ 20 Hz)
        flying ──mode changed by someone else──▶ stood_down (stop streaming; never re-enter by itself)
        flying ──route flown──▶ done (Hold)        done / stood_down ──disengaged──▶ off
        flying ──at rest on a stop short of what is in the way for DEAD_END_S (no pass), held still SETTLE_S──▶ held
                                                                                         (Hold: a dead end)
        flying ──fail-safe the daemon can fly out itself (no safe speed, limit not in force)──▶ braking
        braking (stream the best stop at the tilt's full deceleration from the measured state, its
                 acceleration turned from the last setpoint's at the attitude-rate limit: straight, or a
                 braking swerve off the keep-out discs last seen when straight would enter one)
                ──at rest at its end point──▶ held (Hold)         braking ──mode changed by someone else──▶ stood_down
                (at rest inside a keep-out disc it first backs off, in a straight line, to a point of the path flown
                 outside every disc: `back_off`)
        entering / flying ──a fail-safe Hold (the supervisor holds)──▶ held (ask for Hold, stop streaming)
        entering / flying ──stop asked otherwise (not engaged, Ctrl-C)──▶ off
        held ──CG_ENGAGE off and on (`Cycle.engage_requested`)──▶ off

Authority after a fail-safe (its cause seen to clear, the vehicle left alone): a fail-safe Hold is latched.
The daemon never re-enters offboard by itself after it (it did, 2–5 s later, as soon as the cause had cleared:
repeated Hold/re-enter cycles); the pilot or the ground station decides — another mode, or CG_ENGAGE toggled to
resume the route. A cause that clears is no evidence that the next pass will not raise it again.

Why the daemon brakes itself before handing over: PX4's Hold (FlightTaskAuto::activate
resets its jerk-limited position smoothing to the last setpoint's acceleration and velocity) and
ArduPilot's Brake (AC_PosControl::init_xy_controller starts from the current velocity and lean angles)
both begin from the acceleration the vehicle has and ramp it out at the jerk limit, so a Hold commanded
mid-swerve carries the manoeuvre on; a stop the daemon streams takes the acceleration out at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from contracts.online_planner import BACK_OFF_MAX_M, BACK_OFF_STEP_M, Plan, back_off, best_stop
from contracts.stop import stop_path_budget

from .contract_in_force import DEAD_END
from .guidance import OffboardGuidance, Setpoint
from .states import AT_REST_M_S, FINISHED, STREAMING, SetpointKind
from .states import OffboardState as S

HELD = "fail-safe Hold, held until the pilot or the ground station decides (CG_ENGAGE off and on to resume)"
RECOVERED = "the recovery brake's Hold, held until the pilot or the ground station changes the mode"
SEEN_S = 5.0  # [s] keep-out discs seen this recently shape a fail-safe stop when the sensor sees none now
# [s] a fail-safe stop hands over to Hold once the vehicle has stayed below 0.3 m/s this long at the stop's end:
# a vehicle that overran the stop is still accelerating back at ~g·tan(tilt) as its speed crosses zero, and
# ArduPilot's Brake (AC_PosControl::init_xy_controller: the current lean angles) carries that acceleration on
SETTLE_S = 0.5
# ... and within AT_END_M of the stop's end point (after a hard stop the autopilot's velocity
# integrator still holds the drag it learnt at speed, ~1.3 m/s² on the Mambo at 5.3 m/s; it holds the vehicle
# ~0.7 m past the end against the position loop, and Hold, which restarts at the current position, let it push
# on another 0.45 m into the column; held at the end point, the integrator bleeds off); at most END_WAIT_S
AT_END_M = 0.2
END_WAIT_S = 10.0
# [s] at rest this long on a stop short of what is in the way (the planner proves no pass from where the vehicle sees
# it): a dead end, said and handed to Hold — a vehicle hovering on, replanning the same stop, tells no one why
DEAD_END_S = 3.0
DEAD_END_HELD = "dead end: no pass the contract can prove round what is in the way; held until the pilot or the " \
                "ground station decides (CG_ENGAGE off and on to resume)"


@dataclass(frozen=True, slots=True)
class Ask:
    """One cycle's input to the controller: the vehicle's state as measured, the mode as the mode authority judged
    it, and what the decision asks of the stream."""

    t: float
    mode: str
    p: tuple[float, float]
    v: tuple[float, float]
    z: float
    yaw: float
    taken_over: bool = False  # someone else changed the mode this cycle: stand down, never fight
    by_daemon: bool = False  # the mode shown is one the daemon asked for
    engaged: bool = False
    flying: bool = False
    v_max: float = 0.0  # the speed the route may be flown at [m/s]
    a_max: float = 0.0  # the horizontal acceleration limit [m/s²]
    discs: tuple = ()  # the keep-out discs seen now
    walls: tuple | None = None  # discs a plan round `discs` keeps out of too (None: not swerving, stop contract)
    stop: bool = False  # the decision stops the flight
    brake_stop: bool = False  # (with `stop`) the daemon may fly the stop out itself, braking at `a_stop`
    a_stop: float = 0.0  # [m/s²] the stop's deceleration (the tilt's horizontal acceleration limit)
    stop_decel: float = 0.0  # [m/s²] the stop contract's braking deceleration (the stop's length budget)
    jerk: float = math.inf  # [m/s³] the stop contract's jerk
    track_jerk: float = math.inf  # [m/s³] the stop's acceleration turned from the last setpoint's at this
    failsafe: bool = False  # (with `stop`) the stop is a fail-safe Hold, which is latched
    start: bool = False  # the recovery brake: the stop contract calls for a stop
    abort: bool = False  # the recovery brake: a cause the daemon cannot fly out: Hold now
    a0: tuple | None = None  # the acceleration measured at the recovery brake's start [m/s²]


@dataclass
class OffboardActions:
    setpoint: Setpoint | None = None
    enter: bool = False  # ask the autopilot for OFFBOARD / GUIDED now
    hold: bool = False  # ask the autopilot for Hold now (the route is complete, or the braking stop is over)
    events: list[tuple[str, dict]] = field(default_factory=list)
    texts: list[tuple[int, str]] = field(default_factory=list)  # STATUSTEXTs (severity, text)


@dataclass
class OffboardController:
    guidance: OffboardGuidance
    entry_s: float = 1.0
    state: S = S.OFF
    _t_state: float = 0.0
    _hold_here: np.ndarray | None = None
    _t_last: float | None = None
    _refusal: str | None = None  # the autopilot refused, or did not show, the OFFBOARD / GUIDED asked (`refuse`)
    _braking: bool = False
    _seen: tuple | None = None  # (t, the keep-out discs last seen)
    _slow_since: float | None = None  # braking: since when the vehicle is below 0.3 m/s at the stop's end
    _rest_since: float | None = None  # flying: since when the vehicle rests on a stop short of what is in the way
    _a_last: np.ndarray | None = None  # the acceleration of the last setpoint streamed while flying
    # the route flown, or a dead end: (since when, where, z, yaw, the dead end's room or None) the daemon holds the
    # vehicle before Hold
    _done_at: tuple | None = None
    _switch: bool = False  # the recovery brake awaits its switch to offboard
    refused: str | None = None  # why the recovery brake's switch was refused (it is then unavailable)
    proven: bool = False  # the recovery brake's switch was shown within its contract's budget in this flight
    held: str = HELD  # what the Hold at the end of the braking stop waits for
    _track: list = field(default_factory=list)  # the positions flown in offboard, BACK_OFF_STEP_M apart (newest last)
    _stop_known: list = field(default_factory=list)  # the keep-out discs the braking stop was planned round
    _backed: bool = False  # the braking stop has backed off out of a keep-out disc

    def _go(self, t, new, why, acts):
        acts.events.append(("offboard", {"from": self.state, "to": new, "reason": why}))
        self.state, self._t_state = new, t

    def step(self, ask: Ask) -> OffboardActions:
        """Offboard mode's cycle. A stop the daemon may fly itself (`ask.brake_stop`) brakes at `ask.a_stop` before
        it hands over to Hold; never longer than the stop contract's braking (`stop_decel`, `jerk`), its acceleration
        turned from the last setpoint's at `track_jerk`. A fail-safe stop (`ask.failsafe`) is latched (`held`).
        Someone else's mode change (`ask.taken_over`): offboard stands down, never fights."""
        acts, t, p, v = OffboardActions(), ask.t, ask.p, ask.v
        dt = 0.02 if self._t_last is None else min(max(t - self._t_last, 1e-3), 0.2)
        self._t_last = t
        self._flown(p)
        if self.state == S.BRAKING:
            return self._brake(ask, ask.stop and not ask.brake_stop, acts)
        if ask.discs:
            self._seen = (t, list(ask.discs))  # the obstacle is static: remembered if the sensor goes blind
        if ask.stop and self.state == S.FLYING and ask.brake_stop and ask.a_stop > 0:
            known = list(ask.discs) or (self._seen[1] if self._seen is not None and t - self._seen[0] < SEEN_S else [])
            known += ask.walls or ()
            # braking at the tilt's full deceleration (the avoid contract's stop branch); a swerve off the
            # discs may lengthen it to at most 0.9 × the stop contract's braking distance (the rest is for the
            # vehicle's lag behind the stop it is given), from the acceleration last commanded (what the vehicle
            # is turning to; PX4's Hold restarts from it too): a stop the vehicle can track
            budget = stop_path_budget(float(np.hypot(*v)), ask.stop_decel, ask.jerk)
            self._plan_stop(ask, known, budget, self._a_last)
            self._go(t, S.BRAKING, "fail-safe: the daemon brakes to a stop, then Hold", acts)
            return self._brake(replace(ask, taken_over=False), False, acts)
        if ask.stop and self.state in (S.ENTERING, S.FLYING):
            self._go(t, S.HELD if ask.failsafe else S.OFF, HELD if ask.failsafe else "hold requested", acts)
            return acts
        if self.state in (S.DONE, S.STOOD_DOWN, S.HELD):  # until asked again (CG_ENGAGE off and on)
            return acts
        if self.state == S.OFF:
            if ask.engaged and ask.flying and not ask.stop:
                self._refusal = None
                self._hold_here = np.asarray(p, float).copy()
                self._hold_z, self._hold_yaw = ask.z, ask.yaw
                self._go(t, S.ENTERING, "engaged", acts)
            else:
                return acts
        if self.state == S.ENTERING and not self._entered(ask, acts):
            return acts
        if self.state == S.FLYING:
            if ask.taken_over:
                self._go(t, S.STOOD_DOWN, f"{ask.mode} set by someone else", acts)
                return acts
            if self._done_at is not None:
                return self._finish(t, acts)
            acts.setpoint = self.guidance.step(t, dt, p, v, ask.v_max, ask.a_max, ask.discs, yaw=ask.yaw,
                                                 walls=ask.walls)
            if acts.setpoint.mode == SetpointKind.DONE and float(np.hypot(*v)) < AT_REST_M_S:
                # the route is flown: hold the vehicle where it is for SETTLE_S, then hand over to Hold, so
                # that the last setpoint is where it rests (PX4's Hold restarts from the last setpoint: handed
                # over 1.5 m past it, the vehicle flew back there, 1.3 m/s backwards, unseen by its sensors)
                self._done_at = (t, np.asarray(p, float).copy(), ask.z, ask.yaw, None)
                return self._finish(t, acts)
            if acts.setpoint.mode == SetpointKind.BRAKE and not self._braking:
                acts.events.append(("no_avoiding_plan", {"notes": self.guidance.last_notes[:3]}))
            self._braking = acts.setpoint.mode == SetpointKind.BRAKE
            self._a_last = np.asarray(acts.setpoint.a, float)
            return self._dead_end(ask, acts)
        return acts

    def _dead_end(self, ask: Ask, acts: OffboardActions) -> OffboardActions:
        """A dead end: at rest for DEAD_END_S on a stop short of what is in the way — held where it rests for
        SETTLE_S (`_finish`), then said (`dead_end`, STATUSTEXT) and handed to Hold, held until the pilot or the
        ground station decides."""
        t = ask.t
        room = self.guidance.stopped_short(ask.p)
        if room is None or float(np.hypot(*ask.v)) >= AT_REST_M_S:
            self._rest_since = None
            return acts
        if self._rest_since is None:
            self._rest_since = t
        if t - self._rest_since >= DEAD_END_S:
            self._done_at = (t, np.asarray(ask.p, float).copy(), ask.z, ask.yaw, room)
            return self._finish(t, acts)
        return acts

    def _entered(self, ask: Ask, acts: OffboardActions) -> bool:
        """Entering: a setpoint where the vehicle was when engaged, OFFBOARD / GUIDED asked every cycle from
        `entry_s` on (the mode authority delivers it, and says when it failed); flying (True) once the autopilot
        shows it."""
        t = ask.t
        if ask.mode == "offboard" and ask.by_daemon:
            self.guidance.start(ask.p, ask.v)
            self._track = [np.asarray(ask.p, float)]
            self._done_at = self._rest_since = None
            self._go(t, S.FLYING, "autopilot in offboard", acts)
            return True
        acts.setpoint = Setpoint(self._hold_here, np.zeros(2), np.zeros(2), self._hold_z, self._hold_yaw,
                                 SetpointKind.HOLD)
        acts.enter = t - self._t_state >= self.entry_s
        if self._refusal is not None:
            self._go(t, S.OFF, f"autopilot did not enter offboard: {self._refusal}", acts)
            acts.setpoint, acts.enter = None, False
        return False

    def _plan_stop(self, ask: Ask, known, budget: float, a0) -> None:
        """The stop to stream: `best_stop` from the measured state at `ask.a_stop`, its acceleration from `a0` at
        `ask.track_jerk`."""
        if a0 is not None and float(np.hypot(*a0)) > ask.a_stop:  # no vehicle turns to more than its tilt allows
            a0 = np.asarray(a0, float) * ask.a_stop / float(np.hypot(*a0))
        bp, bv, ba, bts, _ = best_stop(np.asarray(ask.p, float), np.asarray(ask.v, float), ask.a_stop, known, 40,
                                       max_path_m=budget, a0=a0, jerk=ask.track_jerk)
        self._stop_plan = Plan("brake", np.arange(len(bp)) * bts, bp, bv, ba, True, -np.inf)
        self._stop_z, self._stop_yaw, self._slow_since = ask.z, ask.yaw, None
        self._stop_known, self._backed = list(known), False

    def _flown(self, p) -> None:
        """Keep the path flown (for `back_off`): a point each BACK_OFF_STEP_M, twice BACK_OFF_MAX_M of it."""
        if self.state not in (S.FLYING, S.BRAKING) or not all(math.isfinite(x) for x in p):
            return
        if not self._track or math.dist(self._track[-1], p) >= BACK_OFF_STEP_M:
            self._track.append(np.asarray(p, float))
            del self._track[:-int(2 * BACK_OFF_MAX_M / BACK_OFF_STEP_M)]

    def recover(self, ask: Ask) -> OffboardActions:
        """Governor mode's recovery brake (ASTM F3269's recovery function, the stop contract its
        monitor). `ask.start`: the stop contract calls for a stop: the straight jerk-limited stop at `ask.a_stop` (the
        airframe's braking, jerk `ask.track_jerk`) from the measured state (acceleration `ask.a0`), streamed from
        this cycle, OFFBOARD / GUIDED asked the next (PX4 refuses offboard without a stream); from there as
        offboard's fail-safe stop (`_brake`: at rest, Hold).
        The switch refused or not shown in time (`refuse`: the mode authority's delivery): Hold at once, and
        `refused` says why. `ask.abort`: a cause the daemon cannot fly out (its state not to be trusted): Hold now."""
        acts = OffboardActions()
        self._t_last = ask.t
        if self.state == S.BRAKING:
            return self._brake(ask, ask.abort, acts)
        if ask.start and not ask.abort:
            self._plan_stop(ask, [], math.inf, ask.a0)
            self._switch, self._refusal, self.held = True, None, RECOVERED
            self._go(ask.t, S.BRAKING, "recovery brake: the daemon brakes to a stop, then Hold", acts)
            return self._brake(replace(ask, taken_over=False), False, acts)
        return acts

    def shown(self) -> None:
        """The recovery brake's switch was shown within its contract's budget: its own stop contract may set the
        limit from now on in this flight."""
        self.proven = True

    def rearm(self) -> None:
        """Ready for the next stop or entry once a finished one is over (resumed by someone else, or CG_ENGAGE
        set anew)."""
        if self.state in FINISHED:
            self.state = S.OFF

    def path_ahead(self, t: float) -> tuple:
        """The points the plan in force still flies through while flying the route (guidance's), () where none is."""
        return self.guidance.path_ahead(t) if self.state == S.FLYING and self.guidance is not None else ()

    def follow(self, guidance: OffboardGuidance) -> None:
        """The route to fly from the next entry on (a route downloaded anew); the old guidance's planner ends."""
        if self.guidance is not None:
            self.guidance.planning.close()
        self.guidance = guidance

    def close(self) -> None:
        """The daemon ends: the planning worker too."""
        if self.guidance is not None:
            self.guidance.planning.close()

    def refuse(self, why: str) -> None:
        """The autopilot refused the OFFBOARD / GUIDED asked, or did not show it in time (the mode authority's
        delivery): entering, offboard is not entered; braking, the recovery brake holds at the next cycle."""
        self._refusal = why

    def _switched(self, ask: Ask, acts) -> bool:
        """The recovery brake's switch to offboard: asked from the cycle after the first setpoint until shown, or
        refused / not shown in time (False: Hold now). Shown, the autopilot flies the stream from now on: the stop
        is planned again from the state measured now (the one streamed before was planned from the state at the
        call, behind a vehicle that flew on under the autopilot's mission meanwhile), so the stop it tracks is the
        one its controller contract flew (sitl_harness/etr_sweep.py ``brake``) and starts within the brake's dead
        time (contracts/stop.py `recovery_brake`)."""
        t, mode = ask.t, ask.mode
        if mode == "offboard":
            self._switch = False
            self._plan_stop(ask, [], math.inf, ask.a0)
            self._t_state = t
        elif self._refusal is not None:
            self.refused = self._refusal
            acts.hold = True
            self._go(t, S.HELD, f"recovery brake refused ({self.refused}): Hold", acts)
            return False
        else:
            acts.enter = t > self._t_state  # (the first setpoint streamed the cycle before)
        return True

    def _finish(self, t, acts) -> OffboardActions:
        """The route's end, or a dead end: a setpoint at rest where the vehicle stopped, then Hold after SETTLE_S.
        PX4's Hold restarts its smoothing from the last setpoint, its velocity and acceleration as well
        (FlightTaskAuto::activate): handed over on a stop that had begun to lead back out of a keep-out disc, the
        vehicle flew on backwards under Hold at up to 5.9 m/s, out of its sensor's view."""
        since, here, z, yaw, room = self._done_at
        acts.setpoint = Setpoint(here, np.zeros(2), np.zeros(2), z, yaw, SetpointKind.HOLD)
        if t - since < SETTLE_S:
            return acts
        acts.hold = True
        if room is None:
            self._go(t, S.DONE, "route complete", acts)
        else:
            acts.events.append(("dead_end", {"reason": DEAD_END, "obstacle_m": round(room, 3)}))
            acts.texts.append((2, f"CG: {DEAD_END}"))
            self._go(t, S.HELD, DEAD_END_HELD, acts)
        return acts

    def _brake(self, ask: Ask, abort: bool, acts) -> OffboardActions:
        """Stream the fail-safe stop; at rest (or well past its end) hand over to Hold (handing over while
        the vehicle still moves lets Hold carry on from its acceleration: measured, 16–18 m for 8 m)."""
        t, mode, p, v = ask.t, ask.mode, ask.p, ask.v
        if ask.taken_over:
            self._go(t, S.STOOD_DOWN, f"{mode} set by someone else", acts)
            return acts
        if abort:  # a fail-safe the daemon cannot fly out (its own state is not to be trusted): Hold now
            acts.hold = True
            self._go(t, S.HELD, HELD, acts)
            return acts
        if self._switch and not self._switched(ask, acts):
            return acts
        tau = t - self._t_state
        plan = self._stop_plan
        near = float(np.hypot(*(np.asarray(p, float) - plan.p[-1]))) <= AT_END_M
        slow = tau >= plan.t[-1] and float(np.hypot(*v)) < AT_REST_M_S and near
        self._slow_since = (self._slow_since if self._slow_since is not None else t) if slow else None
        if slow and t - self._slow_since >= SETTLE_S and not self._backed:
            self._backed = True
            back = back_off([*self._track, np.asarray(p, float)], [*self._stop_known, *ask.discs, *(ask.walls or ())])
            if back is not None:  # at rest inside a keep-out disc: back out to a point of the path flown, then Hold
                acts.events.append(("back_off", {"inside_m": round(-back.min_clearance, 3),
                                                 "path_m": round(math.dist(back.p[0], back.p[-1]), 3)}))
                self._stop_plan, self._t_state, self._slow_since = back, t, None
                plan, tau, slow = back, 0.0, False
        if (slow and t - self._slow_since >= SETTLE_S) or tau > plan.t[-1] + END_WAIT_S:
            acts.hold = True
            self._go(t, S.HELD, "stopped: " + self.held, acts)
            return acts
        pos, vel, acc = plan.sample(tau)
        acts.setpoint = Setpoint(pos, vel, acc, self._stop_z, self._stop_yaw, SetpointKind.BRAKE)
        return acts

    @property
    def backing_off(self) -> bool:
        """Backing off out of a keep-out disc (`back_off`): the daemon's own slow setpoints, not bound by the limit."""
        return self.state == S.BRAKING and self._stop_plan.kind == "back_off"

    @property
    def streaming(self) -> bool:
        return self.state in STREAMING

