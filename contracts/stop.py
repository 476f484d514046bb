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

import numpy as np

from .flat import horizontal_accel_limit
from .vehicle import Vehicle


def braking_distance(v, a, j):
    """Distance of a jerk-limited stop from speed v with decel ≤ a and jerk ≤ j (zero decel at both ends).

    The speed profile is point-symmetric about its midpoint, so the distance is v·T/2 with
    T = v/a + a/j when a is reached (v ≥ a²/j), else T = 2√(v/j).
    """
    v = np.asarray(v, dtype=float)
    reach = v >= a * a / j
    t_full = np.where(reach, v / a + a / j, 2.0 * np.sqrt(np.maximum(v, 0.0) / j))
    return 0.5 * v * t_full


def stopping_distance(v, a, j, t_r):
    """Dead time at speed v, then the jerk-limited stop."""
    return np.asarray(v, dtype=float) * t_r + braking_distance(v, a, j)


def _largest_root_cubic(b, k):
    """Positive root of s³ + b·s² − k = 0 (b ≥ 0, k > 0: exactly one positive root)."""
    p = -b * b / 3.0
    q = 2.0 * b**3 / 27.0 - k
    disc = q * q / 4.0 + p**3 / 27.0
    sq = np.sqrt(np.maximum(disc, 0.0))
    u_cardano = np.cbrt(-q / 2.0 + sq) + np.cbrt(-q / 2.0 - sq)
    p_neg = np.where(p < 0.0, p, -1.0)  # the trigonometric branch only exists for p < 0
    r = np.sqrt(-p_neg / 3.0)
    arg = np.clip(3.0 * q / (2.0 * p_neg) / r, -1.0, 1.0)
    u_trig = 2.0 * r * np.cos(np.arccos(arg) / 3.0)
    u = np.where(disc >= 0.0, u_cardano, u_trig)
    return u - b / 3.0


def stop_speed(d_avail, a, j, t_r):
    """Largest v with stopping_distance(v) ≤ d_avail, in closed form (0 where d_avail ≤ 0)."""
    d = np.maximum(np.asarray(d_avail, dtype=float), 0.0)
    v_knee = a * a / j
    d_knee = v_knee * t_r + a**3 / j**2  # stopping distance at v = a²/j (both branches agree)
    beta = t_r + a / (2.0 * j)
    v_hi = a * (-beta + np.sqrt(beta * beta + 2.0 * d / a))  # v²/2a + β v = d
    sj = np.sqrt(j)
    s = _largest_root_cubic(t_r * sj, d * sj)  # s = √v: s³/√j + t_r s² = d
    v_lo = np.maximum(s, 0.0) ** 2
    # Round-off must never make the answer optimistic: shave a relative 1e-9.
    return np.where(d >= d_knee, v_hi, v_lo) * (1.0 - 1e-9)


def braking_decel(vehicle: Vehicle, thrust_ratio: float, tilt: float | None = None) -> float:
    """The autopilot's braking deceleration, degraded by thrust: min(MPC_ACC_HOR-like limit,
    g·tan(tilt), √((T_max/m)² − g²)) with T_max the thrust left at `thrust_ratio`."""
    tilt = vehicle.tilt_max if tilt is None else min(tilt, vehicle.tilt_max)
    a_phys = horizontal_accel_limit(tilt, vehicle.t_max(thrust_ratio), vehicle.mass_kg)
    return min(vehicle.braking.accel_max_m_s2, a_phys)


def stop_dead_time(vehicle: Vehicle) -> float:
    """Reaction time plus the switch to Hold/Brake."""
    return vehicle.t_react_s + vehicle.braking.hold_switch_s


def v_stop(vehicle: Vehicle, d_od, r_obst, e_tr, thrust_ratio: float, tilt: float | None = None):
    """Stop-contract speed limit [m/s]; 0 where no speed is safe.

    `r_obst` only sets the disc's centre: for a head-on stop only its near edge matters.
    """
    del r_obst  # the near edge d_od − e_tr − r_body does not depend on it
    a = braking_decel(vehicle, thrust_ratio, tilt)
    if a <= 0.0:
        return np.zeros_like(np.asarray(d_od, dtype=float))
    d_avail = np.asarray(d_od, dtype=float) - np.asarray(e_tr, dtype=float) - vehicle.r_body_m
    return stop_speed(d_avail, a, vehicle.braking.jerk_max_m_s3, stop_dead_time(vehicle))
