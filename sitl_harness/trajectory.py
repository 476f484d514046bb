"""Reference generator of the auto modes (Hold, mission, take-off, land, RTL, guided waypoints).

Acceleration- and jerk-limited like PX4's auto trajectories (MPC_ACC_HOR, MPC_JERK_AUTO) or
ArduPilot's WPNAV_ACCEL / WPNAV_JERK. Pure maths: a reference state (p, v, a) in NED stepped at the
autopilot's navigation rate; the cascade tracks p with v and a as feed-forward.

Velocity tracking law (per horizontal plane and vertical axis): the acceleration target is
a* = ê · min(a_max, √(2·j·|e|)) for velocity error e (the largest acceleration from which a
jerk-limited ramp still ends exactly at the target speed), and the reference acceleration moves
toward a* by at most j·Δt per step. Braking from speed v with a = 0 therefore takes the familiar
jerk-limited distance v²/(2a) + v·a/(2j).

Approaching a target at distance d the speed is capped by the stop law
v ≤ −a²/j + √(a⁴/j² + 2·a·d), the positive root of d = v²/(2a) + v·a/j (twice the jerk term of
the braking distance, so the reference stops at the target without overshoot).
"""

from __future__ import annotations

import math

import numpy as np


def stop_speed(dist: float, acc: float, jerk: float) -> float:
    """Largest speed that still stops within `dist` under the limits (see module docstring)."""
    k = acc * acc / jerk
    return -k + math.sqrt(k * k + 2.0 * acc * max(dist, 0.0))


def _track2(ax: float, ay: float, vx: float, vy: float, dx: float, dy: float, acc_max: float, jerk: float,
            dt: float) -> tuple[float, float]:
    """Jerk-limited velocity tracking in a plane (1-D: pass y = 0). The error is taken against the
    velocity the reference reaches once its acceleration is ramped out (v + a·|a|/(2j)), so it
    never overshoots the target speed."""
    na = math.hypot(ax, ay)
    ex = dx - (vx + ax * na / (2.0 * jerk))
    ey = dy - (vy + ay * na / (2.0 * jerk))
    n = math.hypot(ex, ey)
    if n < 1e-9:
        tx = ty = 0.0
    else:
        k = min(acc_max, math.sqrt(2.0 * jerk * n)) / n
        tx, ty = ex * k, ey * k
    ddx, ddy = tx - ax, ty - ay
    m = math.hypot(ddx, ddy)
    step = jerk * dt
    if m <= step:
        return tx, ty
    return ax + ddx * step / m, ay + ddy * step / m


def _ramp_out(p: float, v: float, a: float, jerk: float) -> float:
    """Position reached while an acceleration `a` is ramped to zero at the jerk limit (1-D part)."""
    t = abs(a) / jerk
    return p + v * t + a * t * t / 3.0


class AutoTrajectory:
    """Reference state for the auto modes; `step` toward a target or brake to a stop and hold."""

    def __init__(self, acc_hor: float, jerk: float, acc_z: float = 3.0):
        self.acc_hor = acc_hor
        self.jerk = jerk
        self.acc_z = acc_z
        self.p = np.zeros(3)
        self.v = np.zeros(3)
        self.a = np.zeros(3)

    def reset(self, p, v, a=(0.0, 0.0, 0.0)) -> None:
        self.p = np.array(p, dtype=float)
        self.v = np.array(v, dtype=float)
        self.a = np.array(a, dtype=float)

    def step(self, dt: float, target, speed_xy: float, speed_up: float, speed_down: float) -> None:
        """Advance toward `target` (NED; a NaN/None component = brake on that axis) at most at the
        given speeds; `target=None` brakes to a stop on all axes."""
        j = self.jerk
        px, py, pz = (float(c) for c in self.p)
        vx, vy, vz = (float(c) for c in self.v)
        ax, ay, az = (float(c) for c in self.a)
        if target is None:
            tx = ty = tz = math.nan
        else:
            tx, ty, tz = (math.nan if c is None else float(c) for c in target)
        has_xy = math.isfinite(tx) and math.isfinite(ty)
        has_z = math.isfinite(tz)
        # desired velocity from the stop law on the distance left after ramping out the acceleration
        dvx = dvy = dvz = 0.0
        if has_xy:
            ex, ey = tx - px, ty - py
            d = math.hypot(ex, ey)
            if d > 1e-6:
                ux, uy = ex / d, ey / d
                na = math.hypot(ax, ay)
                t = na / j
                qx = px + vx * t + ax * t * t / 3.0
                qy = py + vy * t + ay * t * t / 3.0
                dp = (tx - qx) * ux + (ty - qy) * uy
                sp = min(speed_xy, stop_speed(dp, self.acc_hor, j))
                dvx, dvy = ux * sp, uy * sp
        if has_z:
            e = tz - pz
            sgn = 1.0 if e > 0 else -1.0
            dp = (tz - _ramp_out(pz, vz, az, j)) * sgn
            dvz = sgn * min(speed_down if e > 0 else speed_up, stop_speed(dp, self.acc_z, j))
        ax, ay = _track2(ax, ay, vx, vy, dvx, dvy, self.acc_hor, j, dt)
        az, _ = _track2(az, 0.0, vz, 0.0, dvz, 0.0, self.acc_z, j, dt)
        h = 0.5 * dt * dt
        px += vx * dt + ax * h
        py += vy * dt + ay * h
        pz += vz * dt + az * h
        vx += ax * dt
        vy += ay * dt
        vz += az * dt
        # settle exactly on a reached target (removes the √ law's last-centimetre creep), or at rest
        lim = j * dt
        if has_xy:
            if math.hypot(tx - px, ty - py) < 2e-3 and math.hypot(vx, vy) < 0.02 and math.hypot(ax, ay) <= lim:
                px, py, vx, vy, ax, ay = tx, ty, 0.0, 0.0, 0.0, 0.0
        elif math.hypot(vx, vy) < 0.01 and math.hypot(ax, ay) <= lim:
            vx = vy = ax = ay = 0.0
        if has_z:
            if abs(tz - pz) < 2e-3 and abs(vz) < 0.02 and abs(az) <= lim:
                pz, vz, az = tz, 0.0, 0.0
        elif abs(vz) < 0.01 and abs(az) <= lim:
            vz = az = 0.0
        self.p[:] = (px, py, pz)
        self.v[:] = (vx, vy, vz)
        self.a[:] = (ax, ay, az)

    @property
    def speed_xy(self) -> float:
        return float(math.hypot(self.v[0], self.v[1]))
