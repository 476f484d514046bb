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


def hold_start_gain(v: float, a0: float, j: float, t_r: float) -> float:
    """How much longer than `stopping_distance(v)` the stop is when the autopilot's approach to the limit v reaches
    the end of the dead time (the Hold's start) at acceleration a0 ≥ 0, jointly over dead time and approach state.

    The approach never overshoots v, so the Hold starts at speed ≤ v − a0²/(2j), whence the stop is
    `braking_distance_from` = braking_distance(v) + v·a0/j − a0³/(6j²). Over the dead time before it the speed
    was at most U(s) (s back from the Hold's start: the speed rising back in time at jerk j from −a0, turning at
    jerk −j so that it never exceeds v: U + U′²/(2j) ≤ v), so it flew v·t_r less ∫₀^t_r (v − U) — the deficit
    v − U = a0²/(2j) + a0·s − j·s²/2 to s = 2a0/j, (3a0 − j·s)²/(2j) to 3a0/j, 0 after. Bounding the dead time
    by v and the state by the worst a0 separately (the old `approach_stopping_distance`) forgot this deficit."""
    ramp = v * a0 / j - a0**3 / (6.0 * j * j)
    jt = j * t_r
    if 2.0 * a0 >= jt:  # the whole dead time on the rising arc
        short = a0 * a0 * t_r / (2.0 * j) + a0 * t_r * t_r / 2.0 - jt * t_r * t_r / 6.0
    elif 3.0 * a0 >= jt:
        short = (11.0 * a0**3 - (3.0 * a0 - jt) ** 3) / (6.0 * j * j)
    else:
        short = 11.0 * a0**3 / (6.0 * j * j)
    return ramp - short


def ramp_accel(j: float, gap: float) -> float:
    """The largest acceleration of an approach that never overshoots its target and turns its acceleration out at
    jerk ≤ j, when the target is at most `gap` above the speed: a²/(2j) ≤ gap (the governor's approach ramp)."""
    return math.sqrt(2.0 * j * max(gap, 0.0))


def worst_hold_accel(v: float, a: float, j: float, t_r: float, a0_max: float = math.inf) -> float:
    """The a0 ∈ [0, min(a, √(2jv), a0_max)] maximising `hold_start_gain` (concave in a0 and C¹, so its stationary
    point clipped): √(2jv) − j·t_r where the dead time lies on the rising arc (v ≥ 9j·t_r²/8), √(jv/6) where it
    covers the whole dip (v ≤ 2j·t_r²/3), the smaller root of 15a0² − 18j·t_r·a0 + 3j²t_r² + 2jv between.
    `a0_max`: the approach's acceleration is known to stay below it (the governor's ramp, `ramp_accel`)."""
    jt = j * t_r
    if v >= 9.0 * jt * t_r / 8.0:
        a0 = math.sqrt(2.0 * j * v) - jt
    elif v >= 2.0 * jt * t_r / 3.0:
        a0 = (9.0 * jt - math.sqrt(max(36.0 * jt * jt - 30.0 * v * j, 0.0))) / 15.0
    else:
        a0 = math.sqrt(j * v / 6.0)
    return min(max(a0, 0.0), a, math.sqrt(2.0 * j * v), a0_max)


def approach_stopping_distance(v: float, a: float, j: float, t_r: float, a0_max: float = math.inf) -> float:
    """The longest stop when Hold comes at any moment of the autopilot's jerk-limited approach to speed v
    (speed ≤ v throughout, acceleration ≤ min(a, a0_max), jerk ≤ j — its velocity smoothing), one bound over the
    dead time and the approach state jointly (DESIGN.md §1 stop contract): the dead time flown on the approach,
    then the stop from the state it reached (`hold_start_gain` at `worst_hold_accel`)."""
    v = max(v, 0.0)
    return v * t_r + braking_distance(v, a, j) + hold_start_gain(v, worst_hold_accel(v, a, j, t_r, a0_max), j, t_r)


def measured_stopping_distance(v: float, a: float, j: float, t_r: float) -> float:
    """A stop bound for a *measured* speed v (the supervisor's obstacle trigger), not a limit kept throughout: the
    dead time at v and the worst Hold-start acceleration a_up = min(a, √(2jv)) at v taken separately (the stop
    contract's form before its joint bound, `approach_stopping_distance`). A vehicle measured at v may still be
    speeding up, which the joint bound's history (speed ≤ v throughout) does not cover, so the trigger keeps this,
    the slower answer."""
    v = max(v, 0.0)
    a_up = min(a, math.sqrt(2.0 * j * v))
    return v * t_r + braking_distance_from(v - a_up * a_up / (2.0 * j), a_up, a, j)


def approach_stop_speed(d_avail: float, a: float, j: float, t_r: float, a0_max: float = math.inf) -> float:
    """Largest v with approach_stopping_distance(v) ≤ d_avail (0 where d_avail ≤ 0): Γ = V_max − V_safe ≤ 0 of the
    paper's eq. (6) for the stop contract. Where the worst Hold starts at a0 = a with the dead time on the rising
    arc and the stop reaches a (v ≥ (a + j·t_r)²/(2j), v ≥ a²/j, 2a ≥ j·t_r) the distance is
    v²/(2a) + (t_r + 3a/(2j))·v − a³/(6j²) − a²t_r/(2j) − a·t_r²/2 + j·t_r³/6: `stop_speed` with dead time
    t_r + a/j. Elsewhere (and under an `a0_max` below a: the governor's ramp) a bracketed root search below the
    plain `stop_speed` (the approach only shortens it)."""
    if not d_avail > 0.0:
        return 0.0
    jt = j * t_r
    if a0_max >= a:
        v = stop_speed(d_avail + a**3 / (6.0 * j * j) + a * a * t_r / (2.0 * j) + a * t_r * t_r / 2.0
                       - jt * t_r * t_r / 6.0, a, j, t_r + a / j)
        if 2.0 * a >= jt and v >= max((a + jt) ** 2 / (2.0 * j), a * a / j):
            return v
    hi = stop_speed(d_avail, a, j, t_r)
    if not hi > 0.0 or hi == math.inf:
        return hi if hi == math.inf else 0.0
    f_lo, f_hi = -d_avail, approach_stopping_distance(hi, a, j, t_r, a0_max) - d_avail
    if f_hi <= 0.0:  # no gain from the approach (hi keeps stop_speed's round-off margin)
        return hi
    lo, side = 0.0, 0
    for _ in range(200):  # Illinois regula falsi: lo always within d_avail
        if hi - lo <= 1e-12 * hi:
            break
        mid = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        if not lo < mid < hi:
            mid = 0.5 * (lo + hi)
        f = approach_stopping_distance(mid, a, j, t_r, a0_max) - d_avail
        if f <= 0.0:
            lo, f_lo = mid, f
            f_hi, side = (0.5 * f_hi if side == -1 else f_hi), -1
        else:
            hi, f_hi = mid, f
            f_lo, side = (0.5 * f_lo if side == 1 else f_lo), 1
    return lo * (1.0 - 1e-9)


def airframe_decel(vehicle: Vehicle, thrust_ratio: float, tilt: float | None = None) -> float:
    """The airframe's own braking deceleration: min(g·tan(tilt), √((T_max/m)² − g²)) with T_max the thrust left
    at `thrust_ratio` (eq. (14)'s cone, level flight), the tilt at most the vehicle's limit."""
    tilt = vehicle.tilt_max if tilt is None else min(tilt, vehicle.tilt_max)
    return horizontal_accel_limit(tilt, vehicle.t_max(thrust_ratio), vehicle.mass_kg)


def braking_decel(vehicle: Vehicle, thrust_ratio: float, tilt: float | None = None) -> float:
    """The autopilot's braking deceleration, degraded by thrust: min(MPC_ACC_HOR-like limit, `airframe_decel`)."""
    return min(vehicle.braking.accel_max_m_s2, airframe_decel(vehicle, thrust_ratio, tilt))


def stop_jerk(vehicle: Vehicle) -> float:
    """The jerk of the daemon's own fail-safe stop [m/s³]: g times the attitude-rate limit, the fastest the
    horizontal acceleration g·tan(tilt) can turn near level (d/dt g·tan θ ≥ g·θ̇). A stop whose acceleration
    steps (as the full-tilt stop did) is one the vehicle cannot track."""
    return G * vehicle.tilt_rate_max


def stop_path_budget(v: float, stop_decel: float, jerk: float) -> float:
    """The longest path a swerving fail-safe stop from speed v may plan [m]: STOP_BUDGET of the stop contract's
    braking distance (`braking_distance`); the rest is for the vehicle's lag behind the stop and its return
    to the stop's end while the autopilot's velocity integrator (its learnt drag) bleeds off."""
    return STOP_BUDGET * braking_distance(v, stop_decel, jerk) if stop_decel > 0 else 0.0


def slowdown_speed(v0: float, v_lim: float, a: float, j: float, t_dead: float, tau: float, a0: float = 0.0) -> float:
    """The fastest speed an autopilot that obeys a lower speed limit `v_lim` may still fly `tau` after it was seen
    at speed `v0` accelerating at `a0` (≥ 0): through the dead time still accelerating, then its acceleration turned
    at jerk `j` down to the deceleration `a` (a jerk-limited slow-down, the stop contract's model of the autopilot's
    braking, contracts/stop.py `braking_distance_from`); never below `v_lim`."""
    a0 = max(a0, 0.0)
    if tau <= t_dead:
        return max(v0 + a0 * max(tau, 0.0), v_lim)
    s, s1 = tau - t_dead, (a0 + a) / j  # s1: the time to turn the acceleration from a0 to −a
    v = v0 + a0 * t_dead + (a0 * s - 0.5 * j * s * s if s <= s1 else a0 * s1 - 0.5 * j * s1 * s1 - a * (s - s1))
    return max(v, v_lim)


def stop_dead_time(vehicle: Vehicle) -> float:
    """Reaction time plus the switch to Hold/Brake."""
    return vehicle.t_react_s + vehicle.braking.hold_switch_s


def recovery_brake_stop(vehicle: Vehicle, thrust_ratio: float, tilt: float | None = None) -> tuple[float, float]:
    """(a, j) of the recovery brake's stop, as the daemon flies it and as its stop contract takes it: the airframe's
    braking (`airframe_decel`) at `stop_jerk`, never softer than the autopilot's own (`braking_decel` and its jerk).
    The vehicle's lag behind the stop it is given is not taken off the deceleration: it is tracking error, which the
    brake's controller contract measures by flying this same stop (the table's `e_tr_pred_brake`) and which the
    keep-out disc's E_tr then holds."""
    a = max(airframe_decel(vehicle, thrust_ratio, tilt), braking_decel(vehicle, thrust_ratio, tilt))
    return a, max(stop_jerk(vehicle), vehicle.braking.jerk_max_m_s3)


def recovery_brake(vehicle: Vehicle, thrust_ratio: float, loop_dt: float, tilt: float | None = None,
                   t_cmd: float = 0.0) -> tuple[float, float, float]:
    """(a, j, t_r) of the recovery brake's stop contract, for `approach_stop_speed` (DESIGN.md §1 stop contract): the
    stop it flies (`recovery_brake_stop`), and its dead time: reaction, one loop period (the first setpoint goes out a
    cycle before OFFBOARD / GUIDED is asked: PX4 refuses offboard without a stream) and the switch (`hold_switch_s`:
    command round trip and mode switch; `t_cmd`: the command-delivery budget). The joint bound's approach (speed ≤
    V_max, acceleration ≤ a, jerk ≤ j) covers the autopilot's own approach, whose acceleration and jerk are no
    larger."""
    return (*recovery_brake_stop(vehicle, thrust_ratio, tilt), stop_dead_time(vehicle) + loop_dt + t_cmd)


def v_stop(vehicle: Vehicle, d_od: float, r_obst: float, e_tr: float, thrust_ratio: float,
           tilt: float | None = None) -> float:
    """Stop-contract speed limit [m/s]; 0 where no speed is safe. It holds from any state of the autopilot's
    approach to it (a Hold while speeding up first ramps the acceleration out).

    `r_obst` only sets the disc's centre: for a head-on stop only its near edge matters.
    """
    del r_obst  # the near edge d_od − e_tr − r_body does not depend on it
    a = braking_decel(vehicle, thrust_ratio, tilt)
    if a <= 0.0:
        return 0.0
    return approach_stop_speed(d_od - e_tr - vehicle.r_body_m, a, vehicle.braking.jerk_max_m_s3, stop_dead_time(vehicle))
