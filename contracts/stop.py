"""The stop contract: the largest speed from which the autopilot's own braking stops short of the
keep-out disc (governor mode: the autopilot flies, the daemon can only make it stop).

The autopilot brakes along a jerk-limited S-curve (decel ramps up at jerk j to at most a, then back
down to zero as the vehicle stops), after a dead time t_r = reaction + switch to Hold. This is the
law PX4's collision prevention uses (stop distance from MPC_ACC_HOR and MPC_JERK_*), made aware of
`e_tr`, `r_obst`, `r_body`, a degraded `d_od` and the thrust left (`thrust_ratio`).

Head-on geometry (DESIGN.md §2): keep-out disc of radius r_k = r_obst + e_tr + r_body centred at
c = d_od + r_obst, so its near edge on the path is d_od − e_tr − r_body ahead.
"""

from __future__ import annotations

import math

from .flat import horizontal_accel_limit
from .vehicle import G, Vehicle

STOP_BUDGET = 0.75  # part of the stop contract's braking distance a swerving fail-safe stop may use


def braking_distance(v: float, a: float, j: float) -> float:
    """Distance of a jerk-limited stop from speed v with decel ≤ a and jerk ≤ j (zero decel at both ends).

    The speed profile is point-symmetric about its midpoint, so the distance is v·T/2 with
    T = v/a + a/j when a is reached (v ≥ a²/j), else T = 2√(v/j).
    """
    v = max(v, 0.0)
    t_full = v / a + a / j if v >= a * a / j else 2.0 * math.sqrt(v / j)
    return 0.5 * v * t_full


def stopping_distance(v: float, a: float, j: float, t_r: float) -> float:
    """Dead time at speed v, then the jerk-limited stop."""
    return v * t_r + braking_distance(v, a, j)


def braking_distance_from(v: float, a0: float, a: float, j: float) -> float:
    """Distance of the time-optimal jerk-limited stop from speed v with acceleration a0 along the velocity
    (a0 > 0: speeding up), decel ≤ a, jerk ≤ j — how PX4's Hold (FlightTaskAuto::activate restarts its
    PositionSmoothing from the last setpoint's acceleration) and ArduPilot's Brake (AC_PosControl::
    init_xy_controller: the acceleration of the current lean angles) stop.

    The jerk −j first ramps a0 out over t0 = a0/j (distance v·t0 + a0·t0²/2 − j·t0³/6 = v·a0/j + a0³/(3j²),
    speed v + a0²/(2j)), then the stop from zero acceleration follows (`braking_distance`). An a0 < 0 (braking
    already) is taken as 0: never longer than that stop.
    """
    v, a0 = max(v, 0.0), max(a0, 0.0)
    return v * a0 / j + a0**3 / (3.0 * j * j) + braking_distance(v + a0 * a0 / (2.0 * j), a, j)


def stopping_distance_from(v: float, a0: float, a: float, j: float, t_r: float) -> float:
    """Dead time t_r still flying the last command (speed v, acceleration a0 ≥ 0 along it), then the
    jerk-limited stop from there (`braking_distance_from`); a0 = 0 is `stopping_distance`."""
    v, a0 = max(v, 0.0), max(a0, 0.0)
    return v * t_r + 0.5 * a0 * t_r * t_r + braking_distance_from(v + a0 * t_r, a0, a, j)


def _positive_root_cubic(b: float, k: float) -> float:
    """The positive root of s³ + b·s² − k = 0 (b ≥ 0, k > 0: exactly one), Cardano or trigonometric."""
    p = -b * b / 3.0
    q = 2.0 * b**3 / 27.0 - k
    disc = q * q / 4.0 + p**3 / 27.0
    if disc >= 0.0:
        sq = math.sqrt(disc)
        u = math.cbrt(-q / 2.0 + sq) + math.cbrt(-q / 2.0 - sq)
    else:  # three real roots (p < 0): the largest
        r = math.sqrt(-p / 3.0)
        u = 2.0 * r * math.cos(math.acos(max(-1.0, min(1.0, 3.0 * q / (2.0 * p) / r))) / 3.0)
    return u - b / 3.0


def stop_speed(d_avail: float, a: float, j: float, t_r: float) -> float:
    """Largest v with stopping_distance(v) ≤ d_avail, in closed form (0 where d_avail ≤ 0)."""
    if not d_avail > 0.0:
        return 0.0
    d_knee = a * a / j * t_r + a**3 / j**2  # stopping distance at v = a²/j (both branches agree)
    if d_avail >= d_knee:  # reaches a: v²/2a + β v = d
        beta = t_r + a / (2.0 * j)
        v = a * (-beta + math.sqrt(beta * beta + 2.0 * d_avail / a))
    else:  # s = √v: s³/√j + t_r s² = d
        sj = math.sqrt(j)
        v = max(_positive_root_cubic(t_r * sj, d_avail * sj), 0.0) ** 2
    return v * (1.0 - 1e-9)  # round-off must never make the answer optimistic


def approach_stopping_distance(v: float, a: float, j: float, t_r: float) -> float:
    """The longest stop from any state of the autopilot's jerk-limited approach to speed v (acceleration ≤ a
    along the velocity, speed + a0²/(2j) ≤ v, as its velocity smoothing keeps it) when Hold comes: the dead
    time at ≤ v, then `braking_distance_from`. Ramping a0 out costs v·a0/j − a0³/(6j²) beyond the stop from
    v, largest at a0 = min(a, √(2jv)): the stop contract holds from a state with acceleration."""
    v = max(v, 0.0)
    a_up = min(a, math.sqrt(2.0 * j * v))
    return v * t_r + v * a_up / j - a_up**3 / (6.0 * j * j) + braking_distance(v, a, j)


KAPPA = 1.0 + 2.0 * math.sqrt(2.0) / 3.0  # below the knee: approach_stopping_distance = t_r·v + KAPPA·v^{3/2}/√j
EVAL_TOL = 5e-15  # bound on the relative round-off of approach_stopping_distance (≈ 15 roundings, 3× spared)
ZONE = 6e-14  # relative half-width about the closed-form root inside which the bisection's steps are evaluated


def _approach_root(d_avail: float, j: float, t_r: float) -> float:
    """The v with t_r·v + KAPPA·v^{3/2}/√j = d_avail (the approach stopping distance where a_up = √(2jv) < a:
    v·a_up/j − a_up³/(6j²) + v·√(v/j) = KAPPA·v^{3/2}/√j): with s = √v, s³ + (t_r√j/KAPPA)·s² − d√j/KAPPA = 0,
    Cardano (`_positive_root_cubic`), then Newton steps (Cardano cancels where t_r is large and d small)."""
    sj = math.sqrt(j)
    b, k = t_r * sj / KAPPA, d_avail * sj / KAPPA
    s_up = min(math.sqrt(k / b) if b > 0.0 else math.inf, math.cbrt(k))  # b·s² ≤ k and s³ ≤ k
    s = _positive_root_cubic(b, k)
    if not 0.0 < s <= s_up:  # q² or the cubes under- or overflowed
        s = s_up
    if not 0.0 < s < math.inf:
        return math.nan  # degenerate (k underflowed, t_r infinite …): the caller bisects as before
    for _ in range(40):  # the cubic is convex for s > 0: from above, Newton falls monotonically
        step = ((s + b) * s * s - k) / (s * (3.0 * s + 2.0 * b))
        s -= step
        if not abs(step) > 1e-16 * s:
            break
    return s * s


def approach_stop_speed(d_avail: float, a: float, j: float, t_r: float) -> float:
    """Largest v with approach_stopping_distance(v) ≤ d_avail (0 where d_avail ≤ 0). Where the approach
    reaches a (v ≥ a²/(2j)) it is `stop_speed` with dead time t_r + a/j and d_avail + a³/(6j²).

    Below, the 60-step bisection on [0, a²/(2j)] it always was, to the bit, but its steps are decided by the
    closed-form root v_c (`_approach_root`) wherever they fall outside v_c·(1 ± ZONE): the distance is evaluated
    only inside, and at the zone's ends, which must bracket the root by 3·EVAL_TOL (else every step is evaluated,
    as before): the distance rises with v and is computed to within EVAL_TOL, so a step outside the zone would
    have been decided the same way. The bisection stops where its bracket no longer moves."""
    if not d_avail > 0.0:
        return 0.0
    v = stop_speed(d_avail + a**3 / (6.0 * j * j), a, j, t_r + a / j)
    top = a * a / (2.0 * j)
    if v >= top:
        return v
    v_c = _approach_root(d_avail, j, t_r) if j > 0.0 else math.nan
    x_lo, x_hi = v_c * (1.0 - ZONE), v_c * (1.0 + ZONE)
    if not (approach_stopping_distance(x_lo, a, j, t_r) * (1.0 + 3.0 * EVAL_TOL) <= d_avail
            < approach_stopping_distance(x_hi, a, j, t_r) * (1.0 - 3.0 * EVAL_TOL)):
        x_lo, x_hi = -math.inf, math.inf  # no certified bracket: evaluate every step
    lo, hi = 0.0, top
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if mid == lo or (mid == hi and hi != top):
            break  # the bracket no longer moves (lo and hi were decided already)
        if mid < x_lo or (mid <= x_hi and approach_stopping_distance(mid, a, j, t_r) <= d_avail):
            lo = mid
        else:
            hi = mid
    return lo * (1.0 - 1e-9)


def braking_decel(vehicle: Vehicle, thrust_ratio: float, tilt: float | None = None) -> float:
    """The autopilot's braking deceleration, degraded by thrust: min(MPC_ACC_HOR-like limit,
    g·tan(tilt), √((T_max/m)² − g²)) with T_max the thrust left at `thrust_ratio`."""
    tilt = vehicle.tilt_max if tilt is None else min(tilt, vehicle.tilt_max)
    a_phys = horizontal_accel_limit(tilt, vehicle.t_max(thrust_ratio), vehicle.mass_kg)
    return min(vehicle.braking.accel_max_m_s2, a_phys)


def stop_jerk(vehicle: Vehicle) -> float:
    """The jerk of the daemon's own fail-safe stop [m/s³]: g times the attitude-rate limit, the fastest the
    horizontal acceleration g·tan(tilt) can turn near level (d/dt g·tan θ ≥ g·θ̇). A stop whose acceleration
    steps (as the full-tilt stop did) is one the vehicle cannot track (issue 19 item 1)."""
    return G * vehicle.tilt_rate_max


def stop_path_budget(v: float, stop_decel: float, jerk: float) -> float:
    """The longest path a swerving fail-safe stop from speed v may plan [m]: STOP_BUDGET of the stop contract's
    braking distance (`braking_distance`); the rest is for the vehicle's lag behind the stop and its return
    to the stop's end while the autopilot's velocity integrator (its learnt drag) bleeds off."""
    return STOP_BUDGET * braking_distance(v, stop_decel, jerk) if stop_decel > 0 else 0.0


def stop_dead_time(vehicle: Vehicle) -> float:
    """Reaction time plus the switch to Hold/Brake."""
    return vehicle.t_react_s + vehicle.braking.hold_switch_s


def v_stop(vehicle: Vehicle, d_od: float, r_obst: float, e_tr: float, thrust_ratio: float,
           tilt: float | None = None) -> float:
    """Stop-contract speed limit [m/s]; 0 where no speed is safe. It holds from any state of the autopilot's
    approach to it (issue 19 item 1: a Hold while speeding up first ramps the acceleration out).

    `r_obst` only sets the disc's centre: for a head-on stop only its near edge matters.
    """
    del r_obst  # the near edge d_od − e_tr − r_body does not depend on it
    a = braking_decel(vehicle, thrust_ratio, tilt)
    if a <= 0.0:
        return 0.0
    return approach_stop_speed(d_od - e_tr - vehicle.r_body_m, a, vehicle.braking.jerk_max_m_s3, stop_dead_time(vehicle))
