"""Forward range sensor: ray casting over a horizontal field of view, noise, fog. Pure maths.

The sensor is mounted level looking along the vehicle's heading (a gimbal-levelled or horizontally
scanning sensor; the vehicle's roll/pitch do not tilt its rays). Its field of view is split into
bins of `increment_deg`; each bin reports the nearest surface seen by three rays (its centre and
both edges), with Gaussian noise.

Fog (a visibility limit changeable in flight) stops the sensor seeing beyond `visibility_m`.
Reported **honestly**, the range fields say so: `max_distance` drops to the visibility and
`signal_quality` falls in proportion. **Hidden**, the sensor simply stops seeing: it still
advertises its nominal range with full quality (the dangerous case the contract must survive).

Encodings follow MAVLink common.xml (DISTANCE_SENSOR, OBSTACLE_DISTANCE): centimetres, an
OBSTACLE_DISTANCE bin holds `max_distance + 1` for "nothing seen" and UINT16_MAX when unused;
DISTANCE_SENSOR `current_distance` uses the same `max_distance + 1` when nothing is in range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

UINT16_MAX = 65535
N_BINS = 72  # OBSTACLE_DISTANCE.distances length


@dataclass
class RangeSensorConfig:
    fov_deg: float = 60.0
    increment_deg: float = 5.0
    min_range_m: float = 0.1
    max_range_m: float = 10.0  # nominal range
    noise_sd_m: float = 0.02  # constant part of the noise (1 σ)
    noise_rel: float = 0.01  # part proportional to the distance (1 σ per metre)
    rate_hz: float = 20.0


@dataclass
class RangeReading:
    """One sensor frame, already in MAVLink units (cm)."""

    distances_cm: list[int]  # N_BINS entries
    increment_deg: float
    angle_offset_deg: float  # centre of bin 0, clockwise from forward
    min_cm: int
    max_cm: int
    current_cm: int  # nearest over the field of view (DISTANCE_SENSOR)
    signal_quality: int  # 1..100 (MAVLink: 0 unknown, 1 invalid, 100 perfect)
    fov_rad: float


class RangeSensor:
    def __init__(self, cfg: RangeSensorConfig, seed: int = 0):
        self.cfg = cfg
        self.rng = np.random.default_rng(seed + 7919)
        self.visibility_m = math.inf  # fog
        self.honest = True
        self.dropout = False  # when True the sensor sends nothing
        n = max(1, min(N_BINS, round(cfg.fov_deg / cfg.increment_deg)))
        self.n_used = n
        self.inc = math.radians(cfg.fov_deg) / n
        self.offsets = (np.arange(n) - (n - 1) / 2.0) * self.inc  # bin centres, clockwise (+yaw)

    def effective_range(self) -> float:
        return min(self.cfg.max_range_m, self.visibility_m)

    def true_ranges(self, world, pos, yaw: float) -> np.ndarray:
        """Noise-free nearest surface per bin (inf if none within the nominal range)."""
        rays = np.concatenate([self.offsets - 0.5 * self.inc, self.offsets, self.offsets + 0.5 * self.inc])
        d = world.ray_cast(float(pos[0]), float(pos[1]), float(-pos[2]), yaw + rays, self.cfg.max_range_m)
        return d.reshape(3, self.n_used).min(axis=0)

    def read(self, world, pos, yaw: float) -> RangeReading:
        cfg = self.cfg
        d = self.true_ranges(world, pos, yaw)
        finite = np.isfinite(d)
        noisy = d.copy()
        noisy[finite] += self.rng.standard_normal(int(finite.sum())) * (cfg.noise_sd_m + cfg.noise_rel * d[finite])
        eff = self.effective_range()
        if self.honest:
            max_m = eff
            quality = int(max(2, min(100, round(100.0 * eff / cfg.max_range_m))))
        else:
            max_m = cfg.max_range_m
            quality = 100
        max_cm = int(round(max_m * 100))
        min_cm = int(round(cfg.min_range_m * 100))
        seen = finite & (d <= eff)
        bins = [UINT16_MAX] * N_BINS
        for i in range(self.n_used):
            if seen[i]:
                bins[i] = int(min(max(round(noisy[i] * 100), min_cm), max_cm))
            else:
                bins[i] = max_cm + 1
        current = min(bins[: self.n_used])
        return RangeReading(bins, math.degrees(self.inc), math.degrees(self.offsets[0]), min_cm,
                            max_cm, current, quality, math.radians(cfg.fov_deg))
