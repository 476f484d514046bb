"""The contract supervisor: each cycle, evaluate Γ, choose Ω, and decide what to tell the autopilot.

Pure: `Supervisor.step(Inputs) -> Decision`, no I/O. The daemon turns decisions into MAVLink and
event-log records. States (an explicit machine):

    standby   not engaged, not flying, or shadow mode (shadow still computes and logs everything)
    active    the speed limit is commanded and checked
    holding   the daemon commanded Hold (obstacle inside the stop distance, limit not in force,
              no safe speed, failsafe); it stays there until someone else changes the mode
    failsafe  the link to the autopilot is lost: nothing can be commanded

Authority (DESIGN.md §5): the pilot and the ground station outrank the daemon. It engages only when
asked, never fights a mode change it did not make — after someone else leaves its Hold it logs it and
stands down from that cause (a trigger must clear and fire anew before it holds again).
Limits move one way fast: a lower limit takes effect at once, a higher one after `dwell_s`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from contracts.online_planner import Disc, offboard_cap
from contracts.stop import braking_decel, measured_stopping_distance, ramp_accel, slowdown_speed, stop_dead_time
from contracts.table import ContractTable, Omega
from contracts.window import WindowMax

from .authority import GUARANTEE_ANSWERED, Late
from .ahead import stop_obstacle_m
from .contract_in_force import (
    DEAD_END,
    SEVERAL,
    WIDE,
    Apart,
    LastFrame,
    OutOfView,
    Split,
    WIDE_TOL_M,
    ContractInForce,
    InForce,
    fallback_omega,
    path_obstacle_m,
    swerve_discs,
    swerve_omega,
    unplanned,
    wall_discs,
)
from .estimators import DodEstimate
from .guidance import inflated, new_obstacles
from .modes import Mode, mode_of
from .overshoot import DEFAULT as DEFAULT_OVERSHOOT
from .overshoot import OvershootBudget, OvershootWatch, ramped_out
from .states import (  # noqa: F401 (re-exported)
    AT_REST_M_S,
    BRAKE_STOP_CAUSES,
    BRAKE_SWITCH,
    FAILSAFE_CAUSES,
    RAMP_FOLLOWED,
    Cause,
    State,
    Subsystem,
)

STOP_MODES = ("hold", "land")  # the daemon's Hold, and its fallback where Hold is refused (companion/onboard/authority.py)
MIN_SPEED_CMD = 0.2  # below this a speed command is pointless: Hold instead (never send ≤ 0)
VIEW_SPEED_TOL_M_S = 0.01  # [m/s] the avoid contract's speed that keeps its pass in view is found to within this
# the approach ramp (`ApproachRamp`): a ramp command standing this far above speed + ramp is lowered at once …
RAMP_SLACK_M_S = 0.05
RAMP_A_TOL = 0.3  # [m/s²] … and the stop contract's Hold-start acceleration allows this beside `ramp_accel`, for the
# measured acceleration's noise and lag (the check judges the measurement against the contract's own bound)
RAMP_WINDOW_S = 0.3  # [s] the acceleration the check judges is Δv/Δt over this long
RAMP_REARM_S = 3.0  # [s] the ramp followed this long (measured) before its bound is in force, at first and again
# [s] a lower limit is flown within the autopilot's slow-down (`slowdown_speed`) from its dead time plus this: the
# vehicle's velocity lags its autopilot's smooth slow-down by its velocity loop (PX4 MPC_XY_VEL_P_ACC 1.8/s: ~0.5 s)
SLOWDOWN_LAG_S = 0.6
SLOWDOWN_NEAR_M_S = 0.3  # [m/s] flying within this of the old limit's tolerance when a lower one comes: complying
LIMIT_FLOWN = "a speed limit is flown within the autopilot's slow-down"  # the delivery subsystem's guarantee
# E_tr_pred is judged at the speeds flown over E_tr's window and the path span before it, in windows: the error
# measured at a time is the distance to the path commanded over the span before that (estimators.EtrEstimator)
PRED_WINDOWS = 2.0
# the autopilot's guarantee the stop contract budgets (companion/onboard/overshoot.py): the limit sent is V_max − δ_v
SPEED_OVERSHOOT = "the ground speed stays within δ_v of the speed limit sent"
# the navigation subsystem's guarantee of each obstacle sensor: it reports within its silence budget, which the stop and
# avoid contracts take as dead time (companion/onboard/estimators.py SilenceBudget)
SENSOR_SILENCE = "an obstacle sensor reports within its silence budget"
ONE_AT_A_TIME = "one obstacle in view at a time"  # the environment's guarantee the avoid contract's swerve assumes


@dataclass(frozen=True, slots=True)
class Inputs:
    """Everything the supervisor may look at, all derived from MAVLink samples."""

    t: float
    link_ok: bool  # autopilot heartbeat fresh
    telemetry_ok: bool  # position and velocity fresh
    nav_ok: bool  # the autopilot's estimator is healthy
    armed: bool
    in_air: bool
    mode: str  # adapter's name: mission, hold, takeoff, land, rtl, position, offboard, manual, other
    limit_applies: bool  # the autopilot applies DO_CHANGE_SPEED in this mode
    mode_by_daemon: bool  # the current mode is one the daemon commanded (companion/onboard/authority.py)
    ground_speed: float
    dod: DodEstimate
    e_tr_measured: float  # the worst contour error measured over the window (with its floor)
    thrust_ratio: float
    r_obst: float
    engaged: bool
    mission_seq: int = -1  # the autopilot's current mission item (a speed item may reset the limit)
    v_cruise: float = math.nan  # the autopilot's own auto-mode cruise speed (its parameter), NaN: not heard
    v_mission: float = math.nan  # the speed the mission's own speed items set at this item, NaN: not known
    obstacle_width: float = 0.0  # widest obstacle half-width the beams measured now [m] (0: none)
    obstacles: int = 0  # how many obstacles the beams tell apart now (as the avoid contract counts them: `Apart`)
    places: tuple = ()  # each of them, where it is and which bins saw it (`guidance.Place`)
    discs: tuple[Disc, ...] = ()  # the obstacles the beams see now, as discs of radius ≥ R_obst (not inflated)
    hits: tuple = ()  # the fresh sensors' hits: (body bearing, range, bearing uncertainty ±, from bins)
    hit_ends: tuple = ()  # for each hit, how far past it the bins beside it saw [m] (`DodEstimator.hit_ends`)
    beta: float = 0.0  # the direction of travel in the body frame [rad] (along the heading below 1 m/s)
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the vehicle's (x, y, yaw), local NED, the hits are seen from
    path: tuple = ()  # the points (x, y) the plan in force still flies through, () where none is (offboard's guidance)
    late_s: float = 0.0  # the daemon's own worst lateness, beyond t_react's budget, of the last 10 s (Timeliness)
    late_unbudgeted_s: float = 0.0  # this cycle's lateness where it exceeds what was counted before it, else 0
    late_within_s: float = 0.0  # this cycle's lateness inside the jitter allowance, to be said (an event), else 0
    mode_changed: bool = False  # the mode changed this cycle
    taken_over: bool = False  # someone else changed the mode this cycle (the authority's one rule: stand down)
    accel_along: float = math.nan  # the horizontal acceleration flown along the velocity over RAMP_WINDOW_S (its
    # magnitude below 0.5 m/s) [m/s²], NaN: not measured yet
    delivery_late: Late | None = None  # a mode command past its delivery budget (companion/onboard/authority.py)


@dataclass
class _Draft:
    """A decision while the supervisor makes it (`Decision` is what it hands on, frozen)."""

    state: State
    omega: Omega
    v_cmd: float | None
    send_speed: float | None = None
    hold: bool = False
    events: list[tuple[str, dict]] = field(default_factory=list)
    statustext: list[tuple[int, str]] = field(default_factory=list)
    hold_causes: list[Cause] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class Decision:
    """One cycle's decision of the supervisor (frozen: the cycle builds its outbox from it, never rewrites it)."""

    state: State
    omega: Omega
    v_cmd: float | None  # the limit in force (after hysteresis), None when nothing is commanded
    send_speed: float | None = None  # send DO_CHANGE_SPEED with this now
    hold: bool = False  # the supervisor asks for Hold/Brake now (the mode authority's failsafe request)
    events: tuple[tuple[str, dict], ...] = ()
    statustext: tuple[tuple[int, str], ...] = ()  # (MAV_SEVERITY, text)
    e_tr_virtual: float = 0.0  # E_tr of the virtual obstacle (Figure 13): measured, or E_tr_pred flown if larger
    discs: tuple[Disc, ...] = ()  # the keep-out discs: the obstacles grown by E_tr + r_body
    hold_causes: tuple[Cause, ...] = ()  # why it holds this cycle (fresh causes)
    # keep-out discs a plan round `discs` keeps out of too (grown as they are), while offboard swerves under the stop
    # contract (None: not swerving)
    walls: tuple[Disc, ...] | None = None


class ContractSpeed:
    """The default speed policy: the contract's own Ω, optionally scaled by `k` (k > 1 only as a negative control
    of a campaign: companion/ground/baselines.py `Scaled`). A speed policy (`Supervisor(policy=...)`; the baselines and
    negative controls in companion/ground/baselines.py) has `omega(inputs, sup) -> Omega` (`sup.contract_omega(inputs)`:
    the contract's Ω, `sup.table`: its table), `take(sample)` (every sample the cycle takes), `stop_hold` (the
    stop-distance Hold applies: False for a law that is its own whole answer to an obstacle) and `inflate_e_tr`
    (the keep-out discs are grown by E_tr)."""

    name = "contract"
    stop_hold = True
    inflate_e_tr = True

    def __init__(self, k: float = 1.0):
        self.k = k

    def omega(self, i: "Inputs", sup: "Supervisor") -> Omega:
        om = sup.contract_omega(i)
        return om if self.k == 1.0 else replace(om, v_max=om.v_max * self.k, v_safe=om.v_safe * self.k)

    def take(self, sample) -> None:
        pass


class OneSidedLimit:
    """A limit that drops at once and rises only after the higher value has held for `dwell_s`:
    value = min(now, max(current, min of the candidates over the last dwell))."""

    def __init__(self, dwell_s: float):
        self.dwell_s = dwell_s
        self.reset()

    def reset(self) -> None:
        self.value: float | None = None
        self._t0: float | None = None
        self._win: deque[tuple[float, float]] = deque()  # increasing candidates (monotonic min queue)

    def update(self, t: float, candidate: float) -> float:
        if self._t0 is None:
            self._t0 = t
        while self._win and self._win[-1][1] >= candidate:
            self._win.pop()
        self._win.append((t, candidate))
        while self._win[0][0] < t - self.dwell_s:
            self._win.popleft()
        if self.value is None or candidate < self.value:
            self.value = candidate
        elif t - self._t0 >= self.dwell_s and self._win[0][1] > self.value:
            self.value = self._win[0][1]  # every candidate of the last dwell was at least this
        return self.value


class ApproachRamp:
    """Governor mode's approach ramp (DESIGN.md §1 stop contract). Up to the contract's limit for any approach
    (`free`) the autopilot speeds up as it likes (that contract covers a Hold in any state of it); above it the
    speed command is raised no more than `gap` above the speed flown, so an autopilot whose velocity smoothing never
    overshoots its target accelerates there at most `ramp_accel(jerk, gap + RAMP_SLACK_M_S)` (also where it passes
    `free − gap`: it was approaching `free` without overshooting). The stop contract then takes the Hold-start
    acceleration at most `a0_max` (that plus RAMP_A_TOL) instead of the worst of any approach — a higher V_max.
    The assumption is checked: in force only once the autopilot has reported its jerk and after RAMP_REARM_S flown
    on the ramp (at least `free − gap`, judged once the measurement's window lies on it) with the measured
    acceleration ≤ a0_max; the speed flown never above the command by more than the autopilot's overshoot budget
    (`OvershootBudget.top`) while speeding up. Broken while in force (the autopilot accelerates harder or flies faster: it ignores
    or overshoots the command), it is out of force at once and for the rest of the flight (until on the ground),
    the limit falls to the any-approach contract's, and the autopilot's violation lasts while the excess does."""

    def __init__(self, gap_m_s: float, jerk: float):
        self.gap = gap_m_s
        self.jerk_file = jerk  # the vehicle file's (braking.jerk_max_m_s3)
        self.a0_max = math.inf  # not in force before the autopilot reports its own jerk (`autopilot_jerk`)
        self.free = 0.0  # [m/s] the last command's any-approach limit (`command`)
        self.in_force = False
        self.broken = False  # broken this flight: not in force again until on the ground
        self._since: float | None = None  # followed on the ramp since
        self._ramp_t: float | None = None  # on the ramp (at least free − gap) since
        self.excess: tuple[str, str, float, float] | None = None  # (what, unit, allowed, measured) above the ramp

    def autopilot_jerk(self, jerk: float | None) -> None:
        """The jerk the autopilot reports it smooths its approach with (MPC_JERK_AUTO, WPNAV_JERK; None: not
        reported): the bound takes the larger of it and the vehicle file's (the start-up checks refuse a smaller)."""
        ok = jerk is not None and math.isfinite(jerk) and jerk > 0
        self.a0_max = ramp_accel(max(jerk, self.jerk_file), self.gap + RAMP_SLACK_M_S) + RAMP_A_TOL if ok else math.inf

    def judge(self, t: float, ramping: bool, accel: float, speed: float, v_top: float, in_air: bool
              ) -> tuple[bool, bool]:
        """One cycle: `ramping`, the daemon's commands reach the autopilot; `accel`, the acceleration measured along
        the velocity (NaN: unknown); `speed` the ground speed and `v_top` the most the last speed commanded allows
        (with the autopilot's overshoot budget; inf: none commanded). (changed,
        over): whether `in_force` changed, and whether the measured acceleration (on the ramp) or speed is above
        what the ramp allows (with `changed`: it broke the ramp in force)."""
        was = self.in_force
        # on the ramp (at least free − gap) for the measurement's whole window: its acceleration is judged
        self._ramp_t = (self._ramp_t if self._ramp_t is not None else t) if speed >= self.free - self.gap else None
        on_ramp = self._ramp_t is not None and t - self._ramp_t >= RAMP_WINDOW_S
        # (above the command while still speeding up: a command just lowered — fog, a nearer obstacle — is not
        # overshot by a vehicle slowing down to it)
        self.excess = (("acceleration", "m/s²", self.a0_max, accel) if on_ramp and accel > self.a0_max else
                       ("speed", "m/s", v_top, speed) if speed > v_top and accel > RAMP_A_TOL else None)
        over = ramping and self.excess is not None
        if not in_air:
            self.broken = False
        if over and was:
            self.broken = True
        if self.broken or not ramping or over or not math.isfinite(accel) or self.a0_max == math.inf:
            self._since, self.in_force = None, False
        elif on_ramp:
            self._since = t if self._since is None else self._since
            self.in_force = self.in_force or t - self._since >= RAMP_REARM_S
        return self.in_force != was, over

    def command(self, v_target: float, v_flown: float, free: float) -> float:
        """The speed to command toward `v_target`: the any-approach limit `free`, above it at most `gap` above
        the speed flown."""
        self.free = min(free, v_target)
        return min(v_target, max(self.free, max(v_flown, 0.0) + self.gap))


class Supervisor:
    """Governor and shadow modes under the stop contract; offboard reuses Ω under the avoid contract."""

    def __init__(self, table: ContractTable, mode: str | Mode, *, contract: str, dwell_s: float, loop_dt: float,
                 overshoot: OvershootBudget = DEFAULT_OVERSHOOT, late_hold_s: float = math.inf,
                 late_allowance_s: float = 0.0, policy=None,
                 e_tr_window_s: float = 2.0, e_tr_floor_m: float = 0.0, ramp_m_s: float | None = None,
                 fallback: ContractInForce | None = None,
                 t_cmd_s: float = 0.0):
        """`contract`: "stop" (governor, shadow) or "avoid" (offboard; or a replay of an offboard flight);
        `late_hold_s`: a cycle this late breaks the daemon's own guarantee outright (Hold); `late_allowance_s`: the
        jitter allowance t_react budgets beside one loop period (`timeouts.cycle_jitter_s`); `policy`: the speed
        policy flown (default `ContractSpeed()`; a campaign's baselines and negative controls: companion/ground/baselines.py);
        `e_tr_window_s`, `e_tr_floor_m`: the window E_tr is measured over and the floor it never reads below
        (`contract.e_tr_window_s`, `contract.e_tr_floor_m`), so also what its prediction is judged over;
        `ramp_m_s`: governor mode's approach ramp (`governor.approach_ramp_m_s`, `ApproachRamp`), None: none;
        `t_cmd_s`: the command-delivery budget the stop contract adds to its dead time (`delivery.t_cmd_s`);
        `fallback`: under the avoid contract, which contract is in force each cycle (the stop contract where the
        avoid contract's assumptions are not there: companion/onboard/contract_in_force.py), None: always `contract`;
        `overshoot`: the autopilot's speed overshoot δ_v the stop contract's limit leaves room for, and the one
        tolerance a limit is judged flown with (`speed_overshoot`, companion/onboard/overshoot.py)."""
        if contract not in ("stop", "avoid"):
            raise ValueError(f"contract must be 'stop' or 'avoid', not {contract!r}")
        self.table = table
        self.mode = mode_of(mode)
        self.contract = self.configured = contract  # `contract`: the one in force this cycle
        self.fallback = fallback if contract == "avoid" else None
        self._planned_round: tuple = ()  # (discs, walls) guidance was given to swerve round under the stop contract
        self._swerve_frames = LastFrame()  # the swerve's discs of the frame before (`_seen_again`)
        self._out_of_view = OutOfView()  # the swerve's discs seen before, out of view now, on the path ahead
        self._apart = Apart()  # how many obstacles in view the avoid contract counts
        self._split: Split | None = None  # this frame's runs counted as one while the stop contract stops short
        # offboard flies the avoid contract only as fast as its own planner is shown to achieve it
        # (and never faster than the E_tr sweep flew those plans: the table records that cap)
        self.cap = offboard_cap(table.etr_offboard_cap) if self.contract == "avoid" else 1.0
        self.limit = OneSidedLimit(dwell_s)
        self.overshoot0 = self.overshoot = overshoot  # as configured; as measured this flight (raised, never lowered)
        self._overshoot_watch = OvershootWatch()
        self.loop_dt = loop_dt
        self.late_hold_s = late_hold_s
        self.late_allowance_s = late_allowance_s
        self._late_counted = 0.0  # the lateness Ω counts as reaction time (last said in a `reaction_time` event)
        self.state = State.STANDBY
        self._last_sent: float | None = None
        self._last_sent_t = -math.inf
        self._speed_answered = True  # the autopilot answered the last speed command (COMMAND_ACK)
        self._speed_t0 = -math.inf  # the first send of the speed command on its way
        self._target_sent = math.nan  # what the last command sent was toward (the limit, or the autopilot's own speed)
        self._last_in_air = False
        self._linked = False  # an autopilot heartbeat has been seen (the first link is "up", not "restored")
        self._last_seq = -1
        # above the limit since: (when, speed, limit, acceleration, the most it may fly) then
        self._over_since: tuple[float, float, float, float, float] | None = None
        self._recent_limits: deque[tuple[float, float]] = deque()  # (t, limit): the limits of the last dead time
        self.t_cmd = t_cmd_s
        self._suppressed: set[Cause] = set()  # hold causes stood down from after an override
        self._violations: dict[str, dict] = {}
        self._dod_swept = False  # the last D_od was the swept coverage (dod_coverage events)
        self._no_limit_mode_warned: str | None = None
        self._held_for: list[Cause] = []  # the causes of the daemon's current Hold
        self._would: tuple[Cause, ...] = ()
        self._tilt_in_force: float | None = None  # the tilt of the last Ω with a speed to fly
        self._e_pred_at: tuple | None = None  # (v, tilt, thrust, surface, E_tr_pred)
        self._e_pred_window = WindowMax(PRED_WINDOWS * e_tr_window_s)
        self.e_tr_floor = e_tr_floor_m
        self._omega_at: dict[tuple, Omega] = {}  # (d_od, r_obst, e_tr measured, thrust, brake, ramp) → Ω
        self._decel_at: tuple[float, float] | None = None  # (thrust ratio, braking deceleration)
        self._stop_at: tuple[float, float, float] | None = None  # (speed, thrust ratio, stopping distance)
        # never fly a speed the controller contract does not cover: the top of E_tr_pred's speed axis
        # (above it E_tr_pred has no answer and the keep-out disc would be unbounded)
        e_pred = getattr(table, "e_pred", None)
        self.v_covered = float(e_pred.axes[0][-1]) if e_pred is not None else math.inf
        self.policy = policy if policy is not None else ContractSpeed()
        self.latched = False  # offboard's fail-safe Hold is latched (`latch_hold`)
        # the stop contract's brake: None, the autopilot's Hold; the loop period, the daemon's recovery brake
        # (set by the cycle while the brake is available, contracts/stop.py `recovery_brake`)
        self.recovery_dt: float | None = None
        # the E_tr_pred surface of the stop contract: the recovery brake's while it flies the stops (its controller
        # contract covers its own stop as well as what the autopilot flies), else the contract's own
        self.e_surface = contract
        self.ramp = ApproachRamp(ramp_m_s, table.vehicle.braking.jerk_max_m_s3) \
            if ramp_m_s is not None and self.mode.governs else None

    def latch_hold(self, d: Decision, reason: str) -> Decision:
        """Offboard's fail-safe Hold (or the recovery brake's) is latched: holding until someone else changes the
        mode or CG_ENGAGE is toggled, whether or not its cause has cleared (`companion/onboard/offboard.py`,
        authority). The decision, so said (unchanged when already latched)."""
        if self.latched:
            return d
        self.latched = True
        draft = _Draft(d.state, d.omega, d.v_cmd)
        self._set_state(draft, State.HOLDING, reason)
        return self._amended(d, draft)

    def unlatch(self) -> None:
        """CG_ENGAGE set anew: a latched Hold is the pilot's to resume."""
        self.latched = False

    def use_recovery_brake(self, loop_dt: float | None, flies: bool = False) -> None:
        """The stop contract's brake from this cycle on: the daemon's recovery brake, flown at `loop_dt` (its switch
        shown in time in this flight), or None: the autopilot's Hold. `flies`: the recovery brake flies the stops
        (available, its switch shown or not), so the controller contract is the brake's (`e_tr_pred_brake`): the
        tracking error of the stop it flies is predicted and judged against the surface that flew it."""
        self.recovery_dt = loop_dt
        self.e_surface = "brake" if flies and self.contract == "stop" else self.contract

    def switch_refused(self, d: Decision, i: Inputs, refused: bool, speed: float) -> Decision:
        """The recovery brake's assumption: the autopilot accepts its switch to offboard when called, within the
        time the brake's contract budgets. `refused`: the autopilot refused it this cycle (its answer, or the mode
        not shown within that budget); `speed`: the ground speed it is judged at (the larger of now and when the
        brake was called). Refused while the vehicle flew faster
        than the autopilot's Hold's stop contract allows here (`hold_omega`: the limit a refusal falls back to), the
        autopilot broke that assumption: the daemon holds at once (the cycle) and that stop
        is not guaranteed. Logged as the autopilot's violation (a critical STATUSTEXT) until the vehicle is at
        rest. Refused below that limit: nothing here (the Hold's own contract covers the stop). The decision, so
        amended."""
        key = Subsystem.AUTOPILOT
        if key in self._violations:
            on, v_hold = not i.ground_speed < AT_REST_M_S, math.nan  # (an unknown speed: not at rest)
        elif refused:  # above the Hold's limit as the limit itself is judged flown (`_judge_limit`)
            v_hold = self.hold_omega(i).v_max
            on = speed > self.overshoot.top(v_hold)
        else:
            return d
        draft = _Draft(d.state, d.omega, d.v_cmd)
        self._violation(draft, key, on, lambda: dict(
                        subsystem=key, guarantee=BRAKE_SWITCH, assumed=v_hold, observed=speed, action="Hold"),
                        text=(2, "CG: recovery brake REFUSED above the Hold's limit: stop not guaranteed"))
        return self._amended(d, draft)

    def speed_answered(self) -> None:
        """The autopilot answered DO_CHANGE_SPEED (its COMMAND_ACK, whatever the result: a refusal shows in the speed
        flown, which `_judge_limit` judges): it is not sent again until it changes."""
        self._speed_answered = True

    @staticmethod
    def _amended(d: Decision, draft: _Draft) -> Decision:
        """`d` after a draft made from it: its state, and its events and STATUSTEXTs added."""
        return replace(d, state=draft.state, events=d.events + tuple(draft.events),
                       statustext=d.statustext + tuple(draft.statustext))

    @property
    def tilt_in_force(self) -> float | None:
        """The tilt of the last Ω with a speed to fly (the one being flown), None before the first."""
        return self._tilt_in_force

    # ------------------------------------------------------------------ helpers
    def _set_state(self, d: _Draft, new: State, reason: str) -> None:
        if new != self.state:
            d.events.append(("state_change", {"from": self.state, "to": new, "reason": reason}))
            d.statustext.append((5 if new != State.HOLDING else 2, f"CG: {new} ({reason})"))
            self.state = new
        d.state = new

    def _violation(self, d: _Draft, key: Subsystem, on: bool, info, text: tuple[int, str] | None = None) -> None:
        """Track one guarantee: emit violation_start/end on transitions (`info()`: the start's fields, made
        only then; `text`: its STATUSTEXT, by default an error naming the subsystem)."""
        if on and key not in self._violations:
            self._violations[key] = info = info()
            d.events.append(("violation_start", info))
            d.statustext.append(text or (3, f"CG: {info['subsystem']} violation"))
        elif not on and key in self._violations:
            info0 = self._violations.pop(key)
            d.events.append(("violation_end", {k: info0[k] for k in ("subsystem", "guarantee")}))

    def _lasting(self, key, what: str) -> bool:
        """A violation of the world already said goes on while the fallback holds on to `what` it says (WIDE,
        SEVERAL: `ContractInForce.within_reach`)."""
        return key in self._violations and self.fallback is not None and self.fallback.within_reach(what)

    @property
    def _limit_dead_time(self) -> float:
        """[s] from a speed command sent to the vehicle's speed following the autopilot's slow-down: reaction, the
        switch, the delivery budget and the velocity loop's lag (SLOWDOWN_LAG_S)."""
        return stop_dead_time(self.table.vehicle) + self.t_cmd + SLOWDOWN_LAG_S

    def _braking_decel(self, thrust_ratio: float) -> float:
        """The autopilot's braking deceleration at this thrust ratio (`contracts.stop.braking_decel` of the
        table's vehicle, a pure function of it): one evaluation per value, as `e_tr_pred_flown`."""
        if self._decel_at is None or self._decel_at[0] != thrust_ratio:
            self._decel_at = (thrust_ratio, braking_decel(self.table.vehicle, thrust_ratio))
        return self._decel_at[1]

    def _stop_distance(self, v: float, thrust_ratio: float) -> float:
        """The stopping distance from a measured speed v: one evaluation per value, as `_braking_decel`."""
        if self._stop_at is None or self._stop_at[:2] != (v, thrust_ratio):
            veh = self.table.vehicle
            a = self._braking_decel(min(thrust_ratio, veh.thrust_ratio_range[1]))
            t_dead = stop_dead_time(veh) + self.t_cmd
            d = measured_stopping_distance(v, a, veh.braking.jerk_max_m_s3, t_dead) if a > 0 else math.inf
            self._stop_at = (v, thrust_ratio, d)
        return self._stop_at[2]

    def e_tr_pred_flown(self, v: float, tilt: float, thrust_ratio: float) -> float:
        """E_tr_pred (Figure 12) of the controller contract at speed v, at the tilt of the operating point
        being flown (a Ω with no speed — D_od lost, say — has no tilt of its own), one lookup per value."""
        tilt = self._tilt_in_force if self._tilt_in_force is not None else tilt
        # fallen back to the stop contract (offboard): it cruises on offboard setpoints and stops with the brake's
        # stop (`fallback_omega`), so its tracking is bounded by the larger of the two surfaces
        surfaces = (self.e_surface, "brake") if self.fallen_back else (self.e_surface,)
        if self._e_pred_at is None or self._e_pred_at[:4] != (v, tilt, thrust_ratio, surfaces):
            preds = [self.table.e_tr_pred(v, tilt, thrust_ratio, s) for s in surfaces]
            self._e_pred_at = (v, tilt, thrust_ratio, surfaces,
                               max(preds) if all(math.isfinite(p) for p in preds) else math.nan)
        return self._e_pred_at[4]

    def omega(self, i: Inputs) -> Omega:
        """Ω of the speed policy flown at this cycle's inputs (the contract's, `contract_omega`, by default)."""
        return self.policy.omega(i, self)

    def contract_omega(self, i: Inputs) -> Omega:
        """Ω of the contract at this cycle's inputs: one lookup per value, as `e_tr_pred_flown` (the lookup is a
        pure function of the table and these inputs, so a cycle whose inputs equal the last one's reuses its Ω)."""
        return self._contract_omega(i, self.recovery_dt, self.a0_max)

    def hold_omega(self, i: Inputs) -> Omega:
        """Ω of the contract at this cycle's inputs with the autopilot's Hold as the stop (`recovery_dt` None),
        whether or not the recovery brake is available: the limit its refusal falls back to."""
        return self._contract_omega(i, None, self.a0_max)

    def any_approach_omega(self, i: Inputs) -> Omega:
        """Ω of the contract at this cycle's inputs for any approach (without the approach ramp's bound): the speed
        the ramp lets the autopilot reach at its own acceleration."""
        return self._contract_omega(i, self.recovery_dt, None)

    @property
    def a0_max(self) -> float | None:
        """The approach's acceleration bound the stop contract takes now: the approach ramp's while in force."""
        return self.ramp.a0_max if self.ramp is not None and self.ramp.in_force else None

    def _contract_omega(self, i: Inputs, recovery_dt: float | None, a0_max: float | None) -> Omega:
        om = self._late_omega(i, recovery_dt, a0_max)
        if self.configured != "stop":
            return om  # offboard (under either contract): the daemon flies the setpoints itself
        v = self.overshoot.sent(om.v_max)  # the autopilot's overshoot budgeted: flown ≤ V_max
        return om if v == om.v_max else replace(om, v_max=v, gamma=v - om.v_safe)

    def _late_omega(self, i: Inputs, recovery_dt: float | None, a0_max: float | None) -> Omega:
        if i.late_s <= 0.0:
            return self._omega(i.dod.d_od, i, recovery_dt, a0_max)
        # the daemon's own lateness is reaction time the table's fold did not budget (DESIGN.md §2):
        # V ≤ V_safe(d_od − V·late_s − V·t_react), with V·late_s taken at the speed flown (measured or commanded,
        # the larger) — and again at Ω's own speed when that is higher: a shorter D_od never gives a higher V_max,
        # so that answer is safe at its own speed
        v_ref = self._v_ref(i)
        om = self._omega(i.dod.d_od - v_ref * i.late_s, i, recovery_dt, a0_max)
        if om.v_max > v_ref:
            om = self._omega(i.dod.d_od - om.v_max * i.late_s, i, recovery_dt, a0_max)
        return om

    def _v_ref(self, i: Inputs) -> float:
        """[m/s] the speed flown or commanded, the larger."""
        return max(i.ground_speed if math.isfinite(i.ground_speed) else 0.0, self.limit.value or 0.0)

    def _counted(self, i: Inputs) -> Inputs:
        """The inputs with the obstacles in view the avoid contract, in force since the last cycle, counts (`Apart`: a
        run the range noise splits off a column in one frame is one obstacle while the stop contract could still stop
        short of both); under the stop contract every one the beams tell apart counts (it holds on to the sighting)."""
        if self.configured != "avoid":
            return i
        n = self._apart.count(i, self._v_ref(i), lambda d: fallback_omega(self.table, d, i, self.t_cmd,
                                                                         self.loop_dt).v_max,
                              i.dod.silence_s + self.loop_dt)
        self._split = None if self.fallen_back else self._apart.split  # said by `_judge_guarantees`
        return i if n == i.obstacles or self.fallen_back else replace(i, obstacles=n)

    def _omega(self, d_od: float, i: Inputs, recovery_dt: float | None, a0_max: float | None) -> Omega:
        key = (d_od, i.r_obst, i.e_tr_measured, i.thrust_ratio, recovery_dt, a0_max, i.dod.silence_s, self.e_surface,
               self.contract, self.swerves)
        om = self._omega_at.get(key)
        if om is None:
            if len(self._omega_at) >= 6:  # this cycle's few lookups (with and without the brake, the ramp, fallen back)
                self._omega_at.clear()
            if self.fallen_back:
                om = fallback_omega(self.table, d_od, i, self.t_cmd, self.loop_dt)
                om = self._omega_at[key] = swerve_omega(self.table, om, i) if self.swerves else om
            else:
                om = self.table.omega(*key[:4], contract=self.contract, recovery_dt=recovery_dt, a0_max=a0_max,
                                      t_cmd=self.t_cmd, t_silent=i.dod.silence_s, e_brake=self.e_surface == "brake")
                om = self._omega_at[key] = self._in_view_speed(om, d_od, i) if self.fallback is not None else om
        return om

    def _in_view_speed(self, om: Omega, d_od: float, i: Inputs) -> Omega:
        """The avoid contract's Ω flown no faster than keeps its pass in view (contract_in_force rule (ii)) round the
        keep-out disc the planner goes round — R_obst + E_tr + r_body with E_tr = E_tr_pred at the speed flown
        (Figure 13's virtual obstacle), not only the measured error: where E_tr_pred(V_max) is larger than the rule
        allows at this D_od, V_max is lowered to the speed whose E_tr_pred it allows (E_tr_pred grows with speed).
        Where not even MIN_SPEED_CMD's does, Ω is kept and the rule puts the stop contract in force."""
        e_max = self.fallback.e_tr_in_view(d_od, i.r_obst, self.table.vehicle.r_body_m)

        def fits(v: float) -> bool:
            return self.table.e_tr_pred(v, om.tilt, i.thrust_ratio, self.e_surface) <= e_max

        if om.v_max < MIN_SPEED_CMD or fits(om.v_max) or not fits(MIN_SPEED_CMD):
            return om
        lo, hi = MIN_SPEED_CMD, om.v_max
        while hi - lo > VIEW_SPEED_TOL_M_S:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if fits(mid) else (lo, mid)
        e_tr = max(i.e_tr_measured, self.table.e_tr_pred(lo, om.tilt, i.thrust_ratio, self.e_surface))
        return replace(om, v_max=lo, e_tr=e_tr, gamma=lo - om.v_safe,
                       reason=f"{om.reason} (lowered: the pass round E_tr_pred {e_tr:.2f} m in view at D_od {d_od:.1f} m)")

    # ------------------------------------------------------------------ the cycle
    def e_tr_virtual(self, i: Inputs, d: _Draft) -> float:
        """E_tr of the virtual obstacle (Figure 13): the measured error, or the controller contract at the
        speed actually commanded if larger — while a higher V_max waits out its dwell, the vehicle still
        flies the lower limit, and E_tr_pred does not decrease with speed. (0 under a policy that does not
        inflate the keep-out discs: a negative control.)"""
        if not self.policy.inflate_e_tr:
            return 0.0
        if self.table.e_pred is not None and d.v_cmd:
            e = max(i.e_tr_measured, self.e_tr_pred_flown(_speed_flown(d.v_cmd, i), d.omega.tilt, i.thrust_ratio))
            if math.isfinite(e):
                return e
            # no answer in the grid (tilt or thrust outside it): the largest error the contract knows —
            # a keep-out disc is never unbounded (the planner could not plan round it, not even a stop)
            return max(i.e_tr_measured, float(np.max(self.table.e_pred.values)))
        return max(i.e_tr_measured, d.omega.e_tr) if math.isfinite(d.omega.e_tr) else i.e_tr_measured

    def step(self, i: Inputs) -> Decision:
        """One cycle's decision, with the keep-out discs guidance plans round (the obstacles grown by the
        virtual obstacle's E_tr and the vehicle's radius)."""
        i = self._counted(i)
        d = self._decide(i)
        e_tr_virtual = self.e_tr_virtual(i, d)
        # under the stop contract guidance plans round what is no wider than R_obst where the swerve stays in view,
        # else round nothing: it cruises the route, and stops
        if not self.fallen_back:
            discs = i.discs
            self._seen_again(i.hits, discs)  # (what the frames saw before a fallback counts as seen before it)
        elif self.swerves:
            seen = self._seen_again(i.hits, swerve_discs(i, self._hold_reach(i)))
            half_width = self.table.vehicle.r_body_m + e_tr_virtual
            discs = seen + self._out_of_view.keep(i, seen, swerve_discs(i, 0.0), half_width)
        else:
            discs = ()
        if not self.swerves:
            self._out_of_view = OutOfView()
        walls = wall_discs(i, discs) if self.swerves else None
        self._planned_round = (tuple(discs), walls) if self.swerves else ()
        r_body = self.table.vehicle.r_body_m
        return Decision(d.state, d.omega, d.v_cmd, d.send_speed, d.hold, tuple(d.events), tuple(d.statustext),
                        e_tr_virtual, tuple(inflated(list(discs), e_tr_virtual, r_body)), tuple(d.hold_causes),
                        None if walls is None else tuple(inflated(list(walls), e_tr_virtual, r_body)))

    def _seen_again(self, hits: tuple, discs) -> tuple:
        """Of the swerve's discs, those an earlier frame of the sensors saw too (`new_obstacles`): a stereo camera's
        range noise draws a pole out of a wall now and then, never twice at one place; one frame's disc is planned
        round from the next frame, its hit points kept out of meanwhile (`wall_discs`) and judged by the Hold."""
        before = self._swerve_frames.see(hits, discs)
        return tuple(d for d in discs if not new_obstacles([d], before))

    def _decide(self, i: Inputs) -> _Draft:
        """The cycle's decision: the guarantees judged (every mode), then the failsafes in order of what can still
        be done, the holds, and the limit in force."""
        ramp = self._judge_ramp(i) if self.ramp is not None else None
        in_force = self._contract_in_force(i)
        om = self.omega(i)
        d = _Draft(self.state, om, self.limit.value)
        if in_force is not None and in_force.changed:
            self._said_in_force(d, in_force)
        if ramp is not None:
            self._ramp_events(d, i, *ramp)
        self._authority(d, i)
        self._judge_guarantees(d, i, om)
        if not i.link_ok:
            self._set_state(d, State.FAILSAFE, "autopilot heartbeat lost" if self._linked else "no autopilot heartbeat yet")
            return d
        if self.state == State.FAILSAFE:
            self._last_sent = None
            self._set_state(d, State.STANDBY, "link restored" if self._linked else "link up")
        self._linked = True
        if not (i.engaged and i.armed and i.in_air) or not self.mode.commands:
            self.limit.reset()
            self._overshoot_watch.reset()
            if not i.in_air:
                self.overshoot = self.overshoot0  # measured per flight
            self._over_since = None
            self._recent_limits.clear()
            self._set_state(d, State.STANDBY, f"{self.mode.name} mode" if not self.mode.commands else
                            ("not engaged" if not i.engaged else "not flying"))
            d.v_cmd = None
            return self._shadow(d, i) if not self.mode.commands else d
        flown = self._judge_limit(i, self._over_limit(i) and i.limit_applies)
        self._judge_overshoot(d, i)
        ahead = self.ahead_m(i, om)  # once a cycle: the Hold's cause, its release and the dead end read it
        causes = self._causes(i, om, flown, ahead)
        self._violation(d, "limit_flown", flown is not None, lambda: dict(
                        subsystem=Subsystem.DELIVERY, guarantee=LIMIT_FLOWN, assumed=flown[0], observed=flown[1],
                        action="hold"))
        # a cause stood down from re-arms when it clears; an obstacle's only when nothing is left where its Hold looks
        causes_now = {c for c, on in causes.items() if on}
        self._suppressed = {c for c in self._suppressed if c in causes_now or
                            (c == Cause.OBSTACLE and math.isfinite(ahead))}
        fresh = [c for c, on in causes.items() if on and c not in self._suppressed]
        v_limit = self.limit.update(i.t, min(om.v_max * self.cap, self.v_covered))
        self._recent_limits.append((i.t, v_limit))
        while i.t - self._recent_limits[0][0] > self._limit_dead_time:
            self._recent_limits.popleft()
        d.v_cmd = v_limit
        if fresh:
            self._hold(d, fresh)
            # under the stop contract an obstacle on the way offboard flies (no plan round it) ends the route
            if Cause.OBSTACLE in fresh and self.fallen_back and self.fallback.dead_end():
                d.events.append(("dead_end", {"reason": DEAD_END, "obstacle_m": ahead}))
                d.statustext.append((2, f"CG: {DEAD_END}"))
            return d
        if self.state == State.HOLDING and (i.mode in STOP_MODES and i.mode_by_daemon or self.latched and i.mode == "offboard"):
            return d  # stay stopped until someone else decides (authority; latched: Hold asked, not yet seen)
        self._set_state(d, State.ACTIVE, "limit in force")
        if i.limit_applies:
            self._no_limit_mode_warned = None
            self._send_limit(d, i, v_limit)
        elif self._no_limit_mode_warned != i.mode:
            self._no_limit_mode_warned = i.mode
            d.events.append(("limit_not_applicable", {"mode": i.mode, "v_max": v_limit}))
            d.statustext.append((4, f"CG: speed limit not applied in {i.mode}"))
        return d

    def _authority(self, d: _Draft, i: Inputs) -> None:
        """Who changed the mode (the mode authority judged it): someone else left our Hold — stand down. The limit
        is sent again after any mode change, after take-off and at every new mission item."""
        if i.mode_changed:
            if self.state == State.HOLDING and i.taken_over:
                self.latched = False
                self._suppressed |= set(self._held_for)
                self._set_state(d, State.ACTIVE, f"{i.mode} set by someone else: standing down")
            self._last_sent = None
        if i.in_air and not self._last_in_air or i.mission_seq != self._last_seq:
            self._last_sent = None
        self._last_seq = i.mission_seq
        self._last_in_air = i.in_air

    @property
    def fallen_back(self) -> bool:
        """Offboard flies the stop contract this cycle (the avoid contract's assumptions are not there)."""
        return self.contract != self.configured

    @property
    def swerves(self) -> bool:
        """Fallen back for the world with the pass in view: offboard still swerves round what is no wider than R_obst
        (companion/onboard/contract_in_force.py)."""
        return self.fallen_back and self.fallback.now.swerve

    def _contract_in_force(self, i: Inputs) -> InForce | None:
        """The contract in force this cycle (`self.contract`), judged by the fallback on the avoid contract's Ω at
        these inputs (its E_tr: the keep-out disc the pass goes round); None without a fallback."""
        if self.fallback is None:
            return None
        self.contract = self.configured
        now = self.fallback.judge(i, self.contract_omega(i), self.table.vehicle.r_body_m)
        self.contract = now.contract
        return now

    @staticmethod
    def _said_in_force(d: _Draft, now: InForce) -> None:
        d.events.append(("contract_in_force", {"contract": now.contract, "reason": now.reason}))
        d.statustext.append((4 if now.contract == "stop" else 5, f"CG: {now.contract} contract in force: {now.reason}"))

    def _judge_guarantees(self, d: _Draft, i: Inputs, om: Omega) -> None:
        """Every subsystem's guarantee, logged in every mode (shadow included): actuators, environment, navigation
        (D_od), the daemon's own timeliness, the controller (E_tr ≤ E_tr_pred) and command delivery."""
        veh = self.table.vehicle
        lo = veh.thrust_ratio_range[0]
        self._violation(d, Subsystem.ACTUATORS, i.thrust_ratio < lo, lambda: dict(
                        subsystem=Subsystem.ACTUATORS, guarantee=f"thrust_ratio >= {lo}", assumed=lo,
                        observed=i.thrust_ratio, action="no safe speed: hold"))
        # R_obst is the avoid contract's assumption (the swerve round one column of it); the stop contract stops
        # short of whatever is within D_od, whatever its width: under it a wall or a wide box breaks nothing
        # a breach said lasts while the fallback holds on to it (seen, or still within reach: out of view for a moment
        # is not gone), so a wall that comes and goes in the sensors' view is one violation
        wide = self.configured == "avoid" and (i.obstacle_width > i.r_obst + WIDE_TOL_M or
                                              self._lasting(Subsystem.ENVIRONMENT, WIDE))
        self._violation(d, Subsystem.ENVIRONMENT, wide, lambda: dict(
                        subsystem=Subsystem.ENVIRONMENT, guarantee="no obstacle wider than R_obst", assumed=i.r_obst,
                        observed=i.obstacle_width, action="falling back to the stop contract" if self.fallback else
                        "planning round the observed width"))
        # the avoid contract's swerve goes round one obstacle at a time (DESIGN.md §1): several in view at once (a
        # stand of poles) may put one in the path of the swerve round another
        several = self.configured == "avoid" and (i.obstacles > 1 or self._lasting("one_at_a_time", SEVERAL))
        self._violation(d, "one_at_a_time", several, lambda: dict(
                        subsystem=Subsystem.ENVIRONMENT, guarantee=ONE_AT_A_TIME, assumed=1, observed=i.obstacles,
                        action="falling back to the stop contract" if self.fallback else "planning round all of them"))
        if self._split is not None:  # not a breach seen: runs one frame told apart, waiting for the next (`Apart`)
            d.events.append(("one_frame_split", self._split._asdict()))
        if i.dod.swept != self._dod_swept:  # D_od's basis: said when the swept coverage starts and ends
            self._dod_swept = i.dod.swept
            basis = "swept" if i.dod.swept else ("field of view" if i.dod.covered_by else "none")
            d.events.append(("dod_coverage", {"basis": basis, "d_od": i.dod.d_od, "reason": i.dod.reason}))
        silent = i.dod.silent[0] if i.dod.silent else None
        self._violation(d, "sensor_silent", silent is not None, lambda: dict(
                        subsystem=Subsystem.NAVIGATION, guarantee=SENSOR_SILENCE, sensor=silent.sensor,
                        assumed=silent.budget_s, observed=silent.silent_s,
                        action=f"sensors[{silent.sensor}] taken for dead, D_od without it: {i.dod.d_od:.2f} m "
                               f"({i.dod.reason})"))
        late = i.dod.late
        self._violation(d, Subsystem.NAVIGATION, i.dod.lowered, lambda: dict(
                        subsystem=Subsystem.NAVIGATION, guarantee="every obstacle within D_od is detected",
                        assumed=late.assumed_d_od if late else i.dod.stated_m,
                        observed=late.range_m if late else i.dod.d_od,
                        action=f"D_od lowered to {i.dod.d_od:.2f} m" + ("" if late else f": {i.dod.reason}")))
        self._judge_timeliness(d, i)
        if om.v_max >= MIN_SPEED_CMD:
            self._tilt_in_force = om.tilt
        if self.table.e_pred is not None and d.v_cmd and self._tilt_in_force is not None:
            # the measured error is the worst of a window, so it is judged against the prediction at the fastest
            # speed flown in that window and the path span before it (a shorter D_od a moment later does not make
            # the error a violation), and never below the floor the measurement reads at least (a vehicle at rest
            # cannot break it)
            self._e_pred_window.add(i.t, self.e_tr_pred_flown(_speed_flown(d.v_cmd, i), om.tilt, i.thrust_ratio))
            e_pred = max(self._e_pred_window.max, self.e_tr_floor)
            self._violation(d, Subsystem.CONTROLLER, i.e_tr_measured > e_pred + 0.05, lambda: dict(
                            subsystem=Subsystem.CONTROLLER, guarantee="contour error <= E_tr_pred(speed flown)",
                            assumed=e_pred, observed=i.e_tr_measured, action="E_tr raised to the measured value"))
        late_cmd = i.delivery_late  # a mode command past its budget (the mode authority's judgement)
        self._violation(d, Subsystem.DELIVERY, late_cmd is not None, lambda: dict(
                        subsystem=Subsystem.DELIVERY, guarantee=late_cmd.guarantee, assumed=late_cmd.assumed,
                        observed=late_cmd.observed, action=late_cmd.action),
                        text=(2, f"CG: delivery violation: {late_cmd.action}") if late_cmd is not None else None)

    def _judge_timeliness(self, d: _Draft, i: Inputs) -> None:
        """The daemon's own guarantee: one decision per loop period, give or take the jitter allowance t_react
        budgets (docs/daemon.md, Timeliness). Lateness inside the allowance is said; a cycle later than the reaction
        time being flown budgets breaks it, and its lateness then counts as reaction time for the next 10 s."""
        if i.late_within_s > 0.0:
            d.events.append(("cycle_jitter", {"late_s": i.late_within_s, "allowance_s": self.late_allowance_s}))
        allowance = self.late_allowance_s
        self._violation(d, Subsystem.GUIDANCE, i.late_unbudgeted_s > 0.0, lambda: dict(
                        subsystem=Subsystem.GUIDANCE,
                        guarantee=f"decides every cycle ({self.loop_dt * 1e3:.0f} ms + {allowance * 1e3:.0f} ms jitter "
                                  "allowance, inside t_react)",
                        assumed=self.loop_dt + max(allowance, self._late_counted),
                        observed=self.loop_dt + i.late_unbudgeted_s,
                        action="lateness counted as reaction time: a lower speed" +
                               (", hold" if i.late_s > self.late_hold_s else "")))
        if abs(i.late_s - self._late_counted) > 0.005 or (i.late_s == 0.0) != (self._late_counted == 0.0):
            self._late_counted = i.late_s
            d.events.append(("reaction_time", {"late_s": i.late_s, "t_react_s": self.table.vehicle.t_react_s + i.late_s}))

    def _hold(self, d: _Draft, fresh: list[Cause]) -> None:
        """Hold, once (the mode authority delivers it); a cause that arrives while already holding is logged too:
        no cause goes unsaid."""
        if self.state != State.HOLDING:
            d.hold = True
            self._held_for = list(fresh)
            said = [(c, "hold") for c in fresh]
        else:
            said = [(c, ALREADY_HOLDING) for c in fresh if c not in self._held_for]
            self._held_for += [c for c, _ in said]
        for c, action in said:
            d.events.append(("failsafe" if c in FAILSAFE_CAUSES else "hold_trigger", {"cause": c, "action": action}))
        d.hold_causes = list(fresh)
        self._set_state(d, State.HOLDING, fresh[0])

    def _send_limit(self, d: _Draft, i: Inputs, v_limit: float) -> None:
        """The limit sent (DO_CHANGE_SPEED) when it changed, after mode changes and take-off, every 5 s, and every
        cycle until the autopilot answers it (delivery: t_cmd). A governor sends no more than the mission's own
        speed — its speed item's at this item where the daemon knows the mission's items (calibration.legs), which
        is what the autopilot flies there (PX4 Navigator, ArduPilot Auto), else the cruise parameter."""
        v_own = i.v_mission if i.v_mission > 0 else i.v_cruise  # (NaN: not known)
        capped = self.mode.governs and 0 < v_own < v_limit
        v_send = v_own if capped else v_limit
        last, target, tol = self._last_sent, v_send, max(0.05, 0.02 * v_send)
        tol_up = tol_down = tol
        if self.ramp is not None:  # the approach ramp: on it up by half the ramp at a time; down at once
            v_send = self.ramp.command(target, i.ground_speed, self.any_approach_omega(i).v_max * self.cap)
            tol_up, tol_down = (0.5 * self.ramp.gap if self.ramp.free < v_send < target else tol), RAMP_SLACK_M_S
        changed = last is None or v_send - last > tol_up or last - v_send > tol_down
        waited = i.t - self._speed_t0  # the speed command on its way: past its delivery budget, said
        self._violation(d, "speed_delivery", not self._speed_answered and waited > self.t_cmd, lambda: dict(
                        subsystem=Subsystem.DELIVERY, guarantee=GUARANTEE_ANSWERED, assumed=self.t_cmd,
                        observed=waited, action="re-sending the speed limit"))
        if not (changed or i.t - self._last_sent_t > 5.0 or not self._speed_answered):
            return
        d.send_speed = max(v_send, MIN_SPEED_CMD)
        if self._speed_answered:
            self._speed_t0 = i.t
        # said when the target changes (the limit, or the autopilot's own speed); the ramp's steps are not
        if last is None or abs(target - self._target_sent) > tol:
            d.events.append(("limit_change", {"v_max": v_limit, "reason": d.omega.reason} |
                             ({"overshoot_budget_m_s": self.overshoot.allowance(v_limit)} if self.configured == "stop"
                              else {}) |
                             ({"sent": target, "cruise": i.v_cruise} if capped else {}) |
                             ({"mission_speed": i.v_mission} if capped and i.v_mission > 0 else {})))
        self._last_sent, self._last_sent_t, self._target_sent = v_send, i.t, target
        self._speed_answered = not self.mode.governs  # (offboard flies setpoints: nothing is sent)

    def _judge_ramp(self, i: Inputs) -> tuple[bool, bool]:
        """The approach ramp's check, before this cycle's Ω (which takes its bound while in force): its commands
        reach the autopilot while the limit is in force in a mode that applies it (the last cycle's state)."""
        ramping = (self.state == State.ACTIVE and i.link_ok and i.engaged and i.armed and i.in_air
                   and i.limit_applies and self._last_sent is not None)
        v_top = self.overshoot.top(self._last_sent) if self._last_sent is not None else math.inf
        return self.ramp.judge(i.t, ramping, i.accel_along, i.ground_speed, v_top, i.in_air)

    def _ramp_events(self, d: _Draft, i: Inputs, changed: bool, over: bool) -> None:
        ramp = self.ramp
        if changed:
            d.events.append(("approach_ramp", {"in_force": ramp.in_force, "a0_max": ramp.a0_max, "accel": i.accel_along}
                             | ({"why": "the autopilot flew faster or accelerated harder than the ramp allows: off "
                                        "until landed"} if ramp.broken else {})))
        on = over and (changed or "approach_ramp" in self._violations)  # from the break while the excess lasts
        what, unit, allowed, measured = ramp.excess or ("acceleration", "m/s²", ramp.a0_max, i.accel_along)
        self._violation(d, "approach_ramp", on, lambda: dict(
                        subsystem=Subsystem.AUTOPILOT, guarantee=RAMP_FOLLOWED, assumed=allowed, observed=measured,
                        action=f"{what} {measured:.2f} {unit} above the ramp's {allowed:.2f}: the stop contract for "
                               "any approach for the rest of the flight, a lower limit"))

    def _judge_limit(self, i: Inputs, over: bool) -> tuple[float, float] | None:
        """The speed limit flown (DESIGN.md §1, delivery): (allowed, flown) when the vehicle flies faster than a
        compliant autopilot could after the limit was sent (`slowdown_speed` from when it was first seen above
        it), None when it does not."""
        if not over:
            self._over_since = None
            return None
        # the slow-down starts when the vehicle is first seen above the limit, and again when the limit drops
        # below the one it was still about flying (a compliant autopilot starts a new slow-down); never while it
        # was well above the old limit (one that ignores the limits would never be caught)
        since = self._over_since
        if since is None or self.limit.value < since[2] - 0.05 and \
                i.ground_speed <= self.overshoot.top(since[2]) + SLOWDOWN_NEAR_M_S:
            # from the speed and acceleration flown then, never above the highest limit it may still be acting
            # on (those of the last dead time: a compliant autopilot's smoothing does not overshoot its target) —
            # or, while the limits have been in force for less than a dead time (just engaged), the speed its
            # acceleration toward its own earlier target, ramped out at its jerk, still carries it to
            a0 = i.accel_along if math.isfinite(i.accel_along) else 0.0
            recent = [v for _, v in self._recent_limits]
            new = not recent or i.t - self._recent_limits[0][0] < self._limit_dead_time - self.loop_dt
            reach = ramped_out(i.ground_speed, a0, self.table.vehicle.braking.jerk_max_m_s3) if new else 0.0
            cap = max([i.ground_speed, reach] + recent)
            self._over_since = (i.t, i.ground_speed, self.limit.value, a0, cap)
        t0, v0, _, a0, cap = self._over_since
        a = max(self._braking_decel(min(i.thrust_ratio, 1.0)), 0.1)
        allowed = min(cap, slowdown_speed(v0, self.limit.value, a, self.table.vehicle.braking.jerk_max_m_s3,
                                          self._limit_dead_time, i.t - t0, a0))
        # the autopilot's overshoot around its slow-down is that of the highest limit it may still be acting on
        return (allowed, i.ground_speed) if i.ground_speed > allowed + self.overshoot.allowance(cap) else None

    def _over_limit(self, i: Inputs) -> bool:
        """The vehicle flies above the limit in force by more than the autopilot's overshoot budget."""
        return (self.limit.value is not None and _finite_inputs(i)
                and i.ground_speed > self.overshoot.top(self.limit.value))

    def _judge_overshoot(self, d: _Draft, i: Inputs) -> None:
        """The autopilot's guarantee SPEED_OVERSHOOT, judged against the limit in force once the vehicle met it:
        broken, the excess flown becomes the budget for the rest of the flight (a lower limit from now on). Under the
        stop contract only: offboard flies its own setpoints."""
        limit = self.limit.value if i.limit_applies and self.configured == "stop" else None
        reach = ramped_out(i.ground_speed, i.accel_along, self.table.vehicle.braking.jerk_max_m_s3)
        over = self._overshoot_watch.judge(self.overshoot, limit, i.ground_speed, reach)
        if over is not None:
            self.overshoot = self.overshoot.raised(limit, over[1])
        self._violation(d, "speed_overshoot", over is not None, lambda: dict(
                        subsystem=Subsystem.AUTOPILOT, guarantee=SPEED_OVERSHOOT, assumed=over[0], observed=over[1],
                        action=f"overshoot budget raised to {self.overshoot.allowance(limit):.2f} m/s: a lower limit"))

    def _causes(self, i: Inputs, om: Omega, not_flown: tuple[float, float] | None, ahead: float) -> dict[Cause, bool]:
        """Every reason to stop now (each edge-triggered after an override); `not_flown`: the limit not flown
        (`_judge_limit`); `ahead`: the nearest obstacle the Hold judges (`ahead_m`)."""
        finite = _finite_inputs(i)
        obstacle = finite and ahead - self._hold_margin(i) <= self._stop_distance(i.ground_speed, i.thrust_ratio) * 1.1
        causes = {
            Cause.NON_FINITE: not finite,
            Cause.STALE: not i.telemetry_ok,
            Cause.BAD_NAV: not i.nav_ok,
            Cause.NO_SAFE_SPEED: om.v_max < MIN_SPEED_CMD,
            Cause.LATE: i.late_s > self.late_hold_s,
            Cause.OBSTACLE: obstacle,
            Cause.NOT_IN_FORCE: not_flown is not None,
        }
        if self.contract == "avoid" or not self.policy.stop_hold:
            del causes[Cause.OBSTACLE]  # offboard: the daemon flies round it (or brakes) itself; a law: its own speed
        return causes

    def _hold_margin(self, i: Inputs) -> float:
        """[m] what the Hold adds to the stopping distance: the tracking error, the vehicle's radius and the way flown
        in a cycle and the data's lateness."""
        return i.e_tr_measured + self.table.vehicle.r_body_m + i.ground_speed * (self.loop_dt + i.late_s)

    def _hold_reach(self, i: Inputs) -> float:
        """[m] how far along the path the Hold stops for an obstacle now (`_causes`; NaN where an input is not known)."""
        return self._hold_margin(i) + self._stop_distance(i.ground_speed, i.thrust_ratio) * 1.1

    def ahead_m(self, i: Inputs, om: Omega) -> float:
        """[m] the nearest obstacle the stop contract stops short of (companion/onboard/ahead.py): in the swept
        corridor r_body + E_tr about the direction of travel, whatever its shape (walls beside the route are not in
        it); near rest, the nearest in view; where offboard swerves under the stop contract, about the path the plan
        in force flies. E_tr: the larger of the measured and the one Ω budgets."""
        half_width = self.table.vehicle.r_body_m + max(i.e_tr_measured, om.e_tr)
        if not self.swerves:
            return stop_obstacle_m(i.hits, i.beta, i.ground_speed, half_width)
        # what guidance is given for the first time it plans round this cycle: the next judges that plan
        hits = unplanned(i, self._planned_round, self._hold_reach(i))
        if i.path:
            return path_obstacle_m(hits, i.pose, i.path, half_width)
        return stop_obstacle_m(hits, i.beta, i.ground_speed, half_width)

    def _shadow(self, d: _Draft, i: Inputs) -> _Draft:
        """Shadow mode: what the governor would do, logged, nothing commanded."""
        if i.armed and i.in_air:
            on = self._causes(i, d.omega, self._judge_limit(i, False), self.ahead_m(i, d.omega))
            causes = tuple(c for c, held in on.items() if held)
        else:
            causes = ()
        if causes != self._would:
            d.events.append(("would_hold", {"causes": list(causes)}))
            self._would = causes
        return d


def _speed_flown(v_cmd: float, i: Inputs) -> float:
    """[m/s] the speed the controller contract's E_tr_pred is taken at: the limit commanded, or the ground speed where
    the vehicle still flies faster (slowing to a limit that just fell: its tracking is that of the speed it flies)."""
    return max(v_cmd, i.ground_speed) if math.isfinite(i.ground_speed) else v_cmd


def _finite_inputs(i: Inputs) -> bool:
    """Every input the decision computes with is a number (NaN: unknown, stale)."""
    isfinite = math.isfinite
    return (isfinite(i.ground_speed) and isfinite(i.e_tr_measured) and isfinite(i.thrust_ratio)
            and isfinite(i.r_obst) and isfinite(i.dod.d_od))


OBSTACLE, LATE = Cause.OBSTACLE, Cause.LATE  # (the names other modules and tests know them by)
ALREADY_HOLDING = "already holding"  # the action of a cause that arrives while the daemon already holds
