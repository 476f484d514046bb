"""Seeded wind: mean wind + Dryden-type turbulence + discrete (1 − cos) gusts. Pure maths.

Turbulence per axis is the first-order (Dryden longitudinal-form) shaping filter
H(s) = σ·√(2τ) / (1 + τ s), τ = L / V, discretised exactly as a Gauss–Markov process:
u_{k+1} = a·u_k + σ·√(1 − a²)·n_k, a = e^{−Δt/τ}, n_k ~ N(0, 1). Stationary standard deviation σ.
The vertical axis uses half the horizontal intensity (near-ground turbulence is mostly horizontal).
"""

from __future__ import annotations

import math

import numpy as np


class Wind:
    """Wind velocity in NED [m/s] (the velocity *of the air*), advanced with `step(dt)`."""

    def __init__(self, mean_m_s: float = 0.0, from_deg: float = 0.0, gust_m_s: float = 0.0,
                 length_m: float = 20.0, seed: int = 0):
        self.rng = np.random.default_rng(seed)
        self.set_mean(mean_m_s, from_deg)
        self.sigma = float(gust_m_s)
        self.length = float(length_m)
        self.turb = np.zeros(3)
        if self.sigma > 0:  # start from the stationary distribution
            self.turb = self.rng.standard_normal(3) * self.sigma * np.array([1.0, 1.0, 0.5])
        self.gusts: list[tuple[float, float, np.ndarray]] = []  # (t_start, duration, peak vector)
        self.t = 0.0
        self._noise = np.zeros((0, 3))
        self._tx = tuple(float(c) for c in self.turb)
        self._k = 0

    def set_mean(self, mean_m_s: float, from_deg: float) -> None:
        """Mean wind of `mean_m_s` blowing *from* compass direction `from_deg`."""
        a = math.radians(from_deg)
        self.mean = np.array([-mean_m_s * math.cos(a), -mean_m_s * math.sin(a), 0.0])

    def add_gust(self, t_start: float, duration_s: float, peak_m_s: float, from_deg: float) -> None:
        a = math.radians(from_deg)
        self.gusts.append((t_start, duration_s, np.array([-math.cos(a), -math.sin(a), 0.0]) * peak_m_s))

    def step(self, dt: float) -> np.ndarray:
        self.t += dt
        if self.sigma > 0:
            v = max(float(np.linalg.norm(self.mean)), 1.0)
            a = math.exp(-dt * v / self.length)
            k = self.sigma * math.sqrt(1.0 - a * a)
            if self._k >= len(self._noise):  # draw normals in blocks (same sequence, fewer calls)
                self._noise = self.rng.standard_normal((1024, 3)) * np.array([1.0, 1.0, 0.5])
                self._k = 0
            nz = self._noise[self._k]
            self._k += 1
            t = self.turb
            self._tx = (a * self._tx[0] + k * float(nz[0]), a * self._tx[1] + k * float(nz[1]),
                        a * self._tx[2] + k * float(nz[2]))
            t[0], t[1], t[2] = self._tx
        return self.value()

    def value(self) -> np.ndarray:
        if not self.gusts:
            return np.array((self.mean[0] + self._tx[0], self.mean[1] + self._tx[1], self.mean[2] + self._tx[2]))
        w = self.mean + self.turb
        for t0, dur, peak in self.gusts:
            if t0 <= self.t <= t0 + dur:
                w = w + peak * 0.5 * (1.0 - math.cos(2.0 * math.pi * (self.t - t0) / dur))
        return w
