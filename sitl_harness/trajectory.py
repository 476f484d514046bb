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


def _track(a: np.ndarray, v: np.ndarray, vd: np.ndarray, acc_max: float, jerk: float, dt: float) -> np.ndarray:
    """Jerk-limited velocity tracking: the error is taken against the velocity the reference will
    reach once its present acceleration is ramped out (v + a·|a|/(2j)), so it never overshoots."""
    na = float(np.linalg.norm(a))
    e = vd - (v + a * na / (2.0 * jerk))
    n = float(np.linalg.norm(e))
    target = np.zeros_like(e) if n < 1e-9 else e / n * min(acc_max, math.sqrt(2.0 * jerk * n))
    da = target - a
    m = float(np.linalg.norm(da))
    step = jerk * dt
    return target if m <= step else a + da * (step / m)


class AutoTrajectory:
    """Reference state for the auto modes; `goto` a target or `brake` to a stop and hold."""

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
        """Advance toward `target` (NED, any component may be None/NaN = brake on that axis) at
        most at the given speeds; `target=None` brakes to a stop on all axes."""
        tgt = np.full(3, np.nan) if target is None else np.array(target, dtype=float)
        # horizontal desired velocity
        vd = np.zeros(3)
        pp = self._predicted_position()
        if np.all(np.isfinite(tgt[:2])):
            e = tgt[:2] - self.p[:2]
            d = float(np.linalg.norm(e))
            if d > 1e-6:
                dp = float(np.dot(tgt[:2] - pp[:2], e / d))  # remaining after ramping out a
                vd[:2] = e / d * min(speed_xy, stop_speed(dp, self.acc_hor, self.jerk))
        if np.isfinite(tgt[2]):
            e = tgt[2] - self.p[2]
            lim = speed_down if e > 0 else speed_up
            dp = (tgt[2] - pp[2]) * math.copysign(1.0, e)
            vd[2] = math.copysign(min(lim, stop_speed(dp, self.acc_z, self.jerk)), e)
        self.a[:2] = _track(self.a[:2], self.v[:2], vd[:2], self.acc_hor, self.jerk, dt)
        self.a[2:] = _track(self.a[2:], self.v[2:], vd[2:], self.acc_z, self.jerk, dt)
        self.p += self.v * dt + 0.5 * self.a * dt * dt
        self.v += self.a * dt
        # settle exactly on a reached target (removes the √ law's last-centimetre creep)
        for sl in (slice(0, 2), slice(2, 3)):
            if np.all(np.isfinite(tgt[sl])):
                if (np.linalg.norm(tgt[sl] - self.p[sl]) < 2e-3 and np.linalg.norm(self.v[sl]) < 0.02
                        and np.linalg.norm(self.a[sl]) <= self.jerk * dt):
                    self.p[sl] = tgt[sl]
                    self.v[sl] = 0.0
                    self.a[sl] = 0.0
            elif np.linalg.norm(self.v[sl]) < 0.01 and np.linalg.norm(self.a[sl]) <= self.jerk * dt:
                self.v[sl] = 0.0
                self.a[sl] = 0.0

    def _predicted_position(self) -> np.ndarray:
        """Where the reference is once its acceleration has been ramped to zero at the jerk limit."""
        p = self.p.copy()
        for sl in (slice(0, 2), slice(2, 3)):
            na = float(np.linalg.norm(self.a[sl]))
            t = na / self.jerk
            # ∫ v + a·τ − ĵ·τ²/2 dτ over [0, t], ĵ = j along −a
            p[sl] += self.v[sl] * t + self.a[sl] * (t * t / 2.0 - t * t / 6.0)
        return p

    @property
    def speed_xy(self) -> float:
        return float(np.hypot(self.v[0], self.v[1]))
