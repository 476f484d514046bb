"""Forward range sensor: ray casting over a horizontal field of view, noise, and an obscurant (fog). Pure maths.

The sensor is mounted level looking along the vehicle's heading (a gimbal-levelled or horizontally
scanning sensor; the vehicle's roll/pitch do not tilt its rays). Its field of view is split into
bins of `increment_deg`; each bin reports the nearest surface *detected* by rays across it, its edges included,
at most `RAY_SPACING_DEG` apart (`bin_rays`), with Gaussian noise.

Fog is a medium of extinction α (contracts/lidar.py: Koschmieder, the lidar equation). A ray's return
from a surface of reflectivity ρ at range R is detected while its margin over the receiver's threshold,
(ρ/ρ_rated)·(R_max/R)²·e^(−2αR), is ≥ 1: the range at which a target is still seen falls with α, sooner
for dark targets. The scenario's fog is given as `visibility_m`, which keeps its old meaning: **the range
to which the default target (reflectivity `REFERENCE_REFLECTIVITY`, 0.5) is still seen**. The model
takes α = ln(R0/V)/V from it (R0 = R_max·√(ρ_ref/ρ_rated) ≈ 2.24·R_max, the default target's clear-air
link range), the α at which that target's margin is 1 exactly at V; the medium's meteorological
visibility is then 3.912/α. For R_max = 10 m: visibility_m 3 → α 0.67/m (V_met 5.8 m), 5 → 0.30/m
(13 m), 8 → 0.13/m (30 m); a dark column (ρ 0.1) is then seen to 2.2, 3.5 and 5.2 m, a bright wall (ρ
0.9) to 3.3, 5.6 and 9.2 m. No fog (α = 0): every target of ρ ≥ ρ_rated is seen to R_max, as before.

Reported **honestly**, the sensor knows its medium: `max_distance` drops to the default target's range
and `signal_quality` falls in proportion (as before), and it rejects the medium's own returns.
**Hidden**, it still advertises its nominal `max_distance` (that is the point) and fills its fields as a
lidar driver does:
- signal quality from the strength of the return it reports (the nearest), normalised the way PX4's
  LidarLite driver does (drivers/distance_sensor/ll40ls/LidarLiteI2C.cpp: 100·(peak − low)/(high − low)):
  100 at a margin of `QUALITY_FULL_MARGIN` or more, falling to 2 at the threshold (a detection is never
  "invalid": MAVLink's 1; PX4's mavlink DISTANCE_SENSOR stream maps uORB −1 unknown → 0, 0 invalid → 1,
  src/modules/mavlink/streams/DISTANCE_SENSOR.hpp); 100 when nothing is returned (as before);
- backscatter: on a fraction 1 − e^(−α·L_bs) of the shots (per bin and frame, seeded) the medium's own
  return near the sensor (0.5–1.5 × `OVERLAP_M`) comes first, a short spurious range with a weak return;
  the bin reports the nearest return, as PX4's LightWare SF45 driver keeps the nearest reading of a bin
  (drivers/distance_sensor/lightware_sf45_serial: `_current_bin_dist = min(...)`) and ArduPilot's asks
  the SF45/B for its first, unfiltered return (AP_Proximity_LightWareSF45B.h).

Encodings follow MAVLink common.xml (DISTANCE_SENSOR, OBSTACLE_DISTANCE): centimetres, an
OBSTACLE_DISTANCE bin holds `max_distance + 1` for "nothing seen" and UINT16_MAX when unused;
DISTANCE_SENSOR `current_distance` uses the same `max_distance + 1` when nothing is in range (as the SF45
driver does: "As per ObstacleDistance.msg definition"). In clear air the readings are those of the model
before fog had a physics (no extra random draws: the noise stream is the same).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from contracts.lidar import (BACKSCATTER_LENGTH_M, OVERLAP_M, QUALITY_FULL_MARGIN, RATED_REFLECTIVITY,
                             REFERENCE_REFLECTIVITY, backscatter_probability, extinction_for_range, margin)

UINT16_MAX = 65535
N_BINS = 72  # OBSTACLE_DISTANCE.distances length
# A bin reports the nearest return over its whole sector, as a depth camera's bin (the least depth of its pixels:
# 848 px over 87° on a RealSense D435, ~0.1° each, Intel D400 datasheet 337029) or a scanning lidar's sector (a
# LightWare SF45/B samples every 0.2°–1°, its manual) does: rays this far apart at most, so that nothing the worlds
# hold (a pole of 0.1 m radius subtends 0.95° at 12 m) falls between two rays of a bin.
RAY_SPACING_DEG = 0.5


def bin_rays(offsets: np.ndarray, inc: float) -> np.ndarray:
    """(rays × bins) azimuths [rad] of the rays each bin is built from: evenly across the bin, its two edges
    included, at most `RAY_SPACING_DEG` apart (three at least: its edges and centre)."""
    k = max(3, math.ceil(math.degrees(inc) / RAY_SPACING_DEG - 1e-9) + 1)
    return offsets[None, :] + np.linspace(-0.5, 0.5, k)[:, None] * inc


@dataclass
class RangeSensorConfig:
    fov_deg: float = 60.0
    increment_deg: float = 5.0
    min_range_m: float = 0.1
    max_range_m: float = 10.0  # nominal (stated) range, rated at a target of `rated_reflectivity`
    noise_sd_m: float = 0.02  # constant part of the noise (1 σ)
    noise_rel: float = 0.01  # part proportional to the distance (1 σ per metre)
    rate_hz: float = 20.0
    rated_reflectivity: float = RATED_REFLECTIVITY
    backscatter_length_m: float = BACKSCATTER_LENGTH_M  # L_bs (contracts/lidar.py)
    # the body-fixed models only (sensor_models.py; the scenario's `sensor` block documents each)
    v_fov_deg: float = 1.2
    mount_pitch_deg: float = 0.0
    noise_quad_per_m: float = 0.0
    dropout_rate: float = 0.0
    dropped_as: str = "unknown"
    spurious_rate: float = 0.0
    spurious_max_m: float = 1.0
    ground_reflectivity: float = 0.3
    reports: str = "range"


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
    MESSAGES = ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE")  # what carries its frames (mavlink_endpoint.py)
    SENSOR_TYPE = "LASER"  # MAV_DISTANCE_SENSOR_*

    def __init__(self, cfg: RangeSensorConfig, seed: int = 0):
        self.cfg = cfg
        self.rng = np.random.default_rng(seed + 7919)
        self.rng_medium = np.random.default_rng(seed + 104729)  # backscatter only: the noise stream stays as it was
        self.visibility_m = math.inf  # fog: the default target's detection range (module docstring)
        self.honest = True
        self.dropout = False  # when True the sensor sends nothing
        n = max(1, min(N_BINS, round(cfg.fov_deg / cfg.increment_deg)))
        self.n_used = n
        self.inc = math.radians(cfg.fov_deg) / n
        self.offsets = (np.arange(n) - (n - 1) / 2.0) * self.inc  # bin centres, clockwise (+yaw)

    def effective_range(self) -> float:
        """The default target's detection range now (what an honest sensor states)."""
        return min(self.cfg.max_range_m, self.visibility_m)

    def extinction(self) -> float:
        """α [1/m] of the medium now, from `visibility_m` (module docstring); 0 in clear air."""
        return extinction_for_range(self.visibility_m, REFERENCE_REFLECTIVITY, self.cfg.max_range_m,
                                    self.cfg.rated_reflectivity) if math.isfinite(self.visibility_m) else 0.0

    def rays(self) -> np.ndarray:
        """(rays × bins) azimuths off the axis of the rays each bin is built from (`bin_rays`)."""
        return bin_rays(self.offsets, self.inc)

    def _rays(self, world, pos, yaw: float) -> tuple[np.ndarray, np.ndarray]:
        """Per ray (rays × bins, `rays`): distance to the first surface within the nominal range (inf if none) and
        its reflectivity."""
        rays = self.rays()
        d, rho = world.ray_cast(float(pos[0]), float(pos[1]), float(-pos[2]), yaw + rays.ravel(), self.cfg.max_range_m,
                                reflectivity=True)
        return d.reshape(rays.shape), rho.reshape(rays.shape)

    def true_ranges(self, world, pos, yaw: float) -> np.ndarray:
        """Noise-free nearest surface per bin (inf if none within the nominal range), seen or not."""
        return self._rays(world, pos, yaw)[0].min(axis=0)

    def read(self, world, pos, yaw: float, pitch: float = 0.0) -> RangeReading:
        """One frame; levelled, so the vehicle's `pitch` does not tilt it."""
        cfg = self.cfg
        d3, rho3 = self._rays(world, pos, yaw)
        d = d3.min(axis=0)
        finite = np.isfinite(d)
        alpha = self.extinction()
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            m3 = np.where(np.isfinite(d3), margin(d3, rho3, alpha, cfg.max_range_m, cfg.rated_reflectivity), 0.0)
        det3 = m3 >= 1.0  # the lidar equation's threshold (contracts/lidar.py)
        d_det = np.where(det3, d3, np.inf).min(axis=0)  # nearest detected surface per bin
        k = np.where(det3, d3, np.inf).argmin(axis=0)
        m_det = m3[k, np.arange(self.n_used)]
        dd = np.where(np.isfinite(d_det), d_det, d)
        noisy = dd.copy()
        noisy[finite] += self.rng.standard_normal(int(finite.sum())) * (cfg.noise_sd_m + cfg.noise_rel * dd[finite])
        eff = self.effective_range()
        if self.honest:
            max_m = eff
            quality = int(max(2, min(100, round(100.0 * eff / cfg.max_range_m))))
        else:
            max_m = cfg.max_range_m
            quality = 100  # nothing returned (below: the strength of the return reported)
        max_cm = int(round(max_m * 100))
        min_cm = int(round(cfg.min_range_m * 100))
        seen = np.isfinite(d_det) & (d_det <= eff if self.honest else True)
        if alpha > 0.0 and not self.honest:  # the medium's own returns near the sensor (the honest one rejects them)
            u = self.rng_medium.random((3, self.n_used))
            bs = u[0] < backscatter_probability(alpha, cfg.backscatter_length_m)
            r_bs = np.maximum(cfg.min_range_m, OVERLAP_M * (0.5 + u[1]))
            first = bs & (~seen | (r_bs < noisy))
            noisy = np.where(first, r_bs, noisy)
            m_det = np.where(first, 1.0 + 0.1 * (QUALITY_FULL_MARGIN - 1.0) * u[2], m_det)  # weak: near threshold
            seen = seen | first
        bins = [UINT16_MAX] * N_BINS
        for i in range(self.n_used):
            if seen[i]:
                bins[i] = int(min(max(round(noisy[i] * 100), min_cm), max_cm))
            else:
                bins[i] = max_cm + 1
        current = min(bins[: self.n_used])
        if (not self.honest or alpha == 0.0) and current <= max_cm:  # hidden or clear: the return's own quality
            m = min(float(m_det[bins.index(current)]), QUALITY_FULL_MARGIN)  # inf at 0 m: touching
            quality = int(max(2, round(100.0 * (m - 1.0) / (QUALITY_FULL_MARGIN - 1.0))))
        return RangeReading(bins, math.degrees(self.inc), math.degrees(self.offsets[0]), min_cm,
                            max_cm, current, quality, math.radians(cfg.fov_deg))
