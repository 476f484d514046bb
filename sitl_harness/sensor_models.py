"""Body-fixed obstacle sensors with a real sensor's faults: a stereo depth camera (OBSTACLE_DISTANCE) and a
single-beam lidar (DISTANCE_SENSOR). Pure maths; `make_sensor` picks the scenario's `sensor.model`.

Both are fixed to the airframe (tilted by `mount_pitch_deg`): they turn with the vehicle's heading and pitch
with it. Each bin (the lidar has one) is built from horizontal rays across it (sensors.py `bin_rays`) against the
world, as the levelled sector sensor's are, plus **the ground**: the lowest ray each reading is
built from looks `v_fov_deg / 2` below the sensor's axis; once the vehicle pitches down far enough that this
ray meets the ground (altitude −z, flat) within range, the ground is a surface of reflectivity
`ground_reflectivity` at the ray's slant range. For a bin at azimuth φ off the axis and a nose-down pitch θ,
that ray's downward component is cos(v/2)·cos φ·sin θ + sin(v/2)·cos θ. Roll is not modelled.

On top of what is there (in order, every draw from seeded streams, so one seed gives one flight):
- the fog of the sector sensor (contracts/lidar.py: the lidar equation with the sensor's rated reflectivity,
  the honest/hidden stated range, backscatter when hidden) — for the camera a stand-in for the loss of contrast
  that limits stereo matching in a medium;
- range noise of σ(d) = max(noise_sd_m, noise_rel·d, noise_quad_per_m·d²) [1 σ, Gaussian], where d is what
  the sensor reports: the range along the ray, or for `reports: z_depth` (a depth camera) the depth along the
  optical axis, d·cos(azimuth), of the nearest pixel in the bin (a stereo camera's error grows with depth);
- dropped bins (no valid depth; a beam frame without a return) at `dropout_rate` per bin and frame;
- spurious close returns (a propeller in view, rain, dust) at `spurious_rate` per bin and frame, uniform in
  [min_range_m, spurious_max_m], reported when nearer than what the bin saw;
- quantisation to the message's centimetres.

Encodings (MAVLink common.xml; PX4's ObstacleDistance.msg says the same): nothing within range is
`max_distance + 1` ("no obstacle is present"). A dropped bin, and a return nearer than `min_range_m`, is
**UINT16_MAX** in OBSTACLE_DISTANCE ("unknown"); with `dropped_as: free` it is `max_distance + 1` instead, what
the ArduPilot wiki's `d4xx_to_mavlink.py` (vision_to_mavros) writes for every invalid depth ("the invalid distance
value (below MIN/above MAX) will be replaced with MAX+1"): a camera pipeline that calls a hole free. DISTANCE_SENSOR
has no "unknown" value: the single beam sends no message for a dropped frame, as PX4's TFmini driver publishes
nothing for a frame it rejects (`SingleBeam`), or `max_distance + 1` with `dropped_as: free`; a return below the
minimum is `current_distance` 0 (below `min_distance`: no valid reading).
"""

from __future__ import annotations

import math

import numpy as np

from contracts.lidar import OVERLAP_M, QUALITY_FULL_MARGIN, backscatter_probability, margin

from .sensors import N_BINS, UINT16_MAX, RangeReading, RangeSensor, RangeSensorConfig

# Intel RealSense D435 (Intel RealSense Product Family D400 Series Datasheet, doc. 337029): depth FOV 87° × 58°
# (H × V), min-Z ≈ 0.28 m at 848×480, range to ~10 m (scene dependent), depth up to 90 fps (30 fps used here),
# depth RMS error ≤ 2 % at 2 m, growing with the square of the distance (stereo: RMS = d²·subpixel/(focal·baseline),
# Intel's "Tuning depth cameras for best performance"): σ(d) = 0.02·2 m·(d/2 m)² = 0.01·d² [m]. The bins are
# built from a horizontal line of the image a few pixel rows thick (d4xx_to_mavlink.py's obstacle line: 10 rows
# of 480 over 58°, 1.2°), reported as depth along the optical axis (z), as that script does; 17 bins of 5° over
# the middle 85° of its 87°. `dropout_rate` and `spurious_rate` are not datasheet figures: modest stress values (the D435's
# fill rate is ≥ 99 % on textured scenes; a bin is the minimum over its rows and columns).
DEPTH_CAMERA = {"fov_deg": 87.0, "increment_deg": 5.0, "min_range_m": 0.3, "max_range_m": 10.0, "rate_hz": 30.0,
                "noise_sd_m": 0.0, "noise_rel": 0.0, "noise_quad_per_m": 0.01, "v_fov_deg": 1.2,
                "dropout_rate": 0.02, "spurious_rate": 0.002, "spurious_max_m": 1.0, "reports": "z_depth"}
# Benewake TFmini Plus (TFmini Plus datasheet / product manual): 0.1–12 m at 90 % reflectivity (0.1–4 m at 10 %:
# the 1/R² law, R ∝ √ρ), accuracy ±5 cm to 6 m and ±1 % from 6 to 12 m (taken as 1 σ: conservative), 1 cm
# resolution, 100 Hz default frame rate, FOV 3.6° (one bin of 3.6°). σ = max(5 cm, 1 %·d): 1 % from 5 m, a little
# above the datasheet between 5 and 6 m.
SINGLE_BEAM = {"fov_deg": 3.6, "increment_deg": 3.6, "min_range_m": 0.1, "max_range_m": 12.0, "rate_hz": 100.0,
               "noise_sd_m": 0.05, "noise_rel": 0.01, "noise_quad_per_m": 0.0, "v_fov_deg": 3.6,
               "rated_reflectivity": 0.9, "dropout_rate": 0.005, "spurious_rate": 0.0005, "spurious_max_m": 1.0,
               "reports": "range"}
MODEL_DEFAULTS = {"depth_camera": DEPTH_CAMERA, "single_beam": SINGLE_BEAM}


class BodySensor(RangeSensor):
    """The common frame of the body-fixed models (module docstring); `MESSAGES` says which messages carry it."""

    MESSAGES = ("OBSTACLE_DISTANCE",)
    SENSOR_TYPE = "INFRARED"

    def __init__(self, cfg: RangeSensorConfig, seed: int = 0):
        super().__init__(cfg, seed)
        # bins of exactly `increment_deg`, as many as fit the field of view (87° → 17 × 5° = 85°): OBSTACLE_DISTANCE's
        # 72 bins then span 360° at most, which a reader checks of the whole array, unused bins included
        n = max(1, min(N_BINS, math.floor(cfg.fov_deg / cfg.increment_deg + 1e-9)))
        self.n_used = n
        self.inc = math.radians(cfg.increment_deg)
        self.offsets = (np.arange(n) - (n - 1) / 2.0) * self.inc
        self.rng_faults = np.random.default_rng(seed + 15485863)  # dropouts and spurious returns

    def ground_ranges(self, rays: np.ndarray, alt: float, pitch: float) -> np.ndarray:
        """Slant range to flat ground along the lowest ray at each azimuth `rays` (rad off the axis), inf where
        that ray does not meet the ground within the nominal range. `pitch`: the vehicle's, nose up positive."""
        down_pitch = -(pitch + math.radians(self.cfg.mount_pitch_deg))
        h = 0.5 * math.radians(self.cfg.v_fov_deg)
        down = math.cos(h) * np.cos(rays) * math.sin(down_pitch) + math.sin(h) * math.cos(down_pitch)
        with np.errstate(divide="ignore"):
            r = np.where(down > 0.0, alt / down, np.inf)
        return np.where((r <= self.cfg.max_range_m) & (alt > 0.0), r, np.inf)

    def surfaces(self, world, pos, yaw: float, pitch: float) -> tuple[np.ndarray, np.ndarray]:
        """(rays × bins) range and reflectivity of the first surface, world or ground."""
        d3, rho3 = self._rays(world, pos, yaw)
        g3 = self.ground_ranges(self.rays(), float(-pos[2]), pitch)
        ground = g3 < d3
        return np.where(ground, g3, d3), np.where(ground, self.cfg.ground_reflectivity, rho3)

    def sigma(self, d: np.ndarray) -> np.ndarray:
        c = self.cfg
        return np.maximum(np.maximum(c.noise_sd_m, c.noise_rel * d), c.noise_quad_per_m * d * d)

    def read(self, world, pos, yaw: float, pitch: float = 0.0) -> RangeReading | None:
        """One frame (None: the sensor sends nothing this time)."""
        cfg = self.cfg
        n = self.n_used
        d3, rho3 = self.surfaces(world, pos, yaw, pitch)
        alpha = self.extinction()
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            m3 = np.where(np.isfinite(d3), margin(d3, rho3, alpha, cfg.max_range_m, cfg.rated_reflectivity), 0.0)
        det3 = m3 >= 1.0
        rep3 = d3 * np.cos(self.rays()) if cfg.reports == "z_depth" else d3  # what a pixel reports
        k = np.where(det3, rep3, np.inf).argmin(axis=0)
        d_det = rep3[k, np.arange(n)]
        d_det = np.where(det3[k, np.arange(n)], d_det, np.inf)  # the nearest detected return per bin
        m_det = m3[k, np.arange(n)]
        eff = self.effective_range()
        seen = np.isfinite(d_det) & (d_det <= (eff if self.honest else cfg.max_range_m))
        base = np.where(seen, d_det, 0.0)
        noisy = base + self.rng.standard_normal(n) * self.sigma(base)
        if alpha > 0.0 and not self.honest:  # the medium's own returns near the sensor (sensors.py)
            u = self.rng_medium.random((3, n))
            bs = u[0] < backscatter_probability(alpha, cfg.backscatter_length_m)
            r_bs = np.maximum(cfg.min_range_m, OVERLAP_M * (0.5 + u[1]))
            first = bs & (~seen | (r_bs < noisy))
            noisy = np.where(first, r_bs, noisy)
            m_det = np.where(first, 1.0 + 0.1 * (QUALITY_FULL_MARGIN - 1.0) * u[2], m_det)
            seen = seen | first
        f = self.rng_faults.random((3, n))
        spurious = f[1] < cfg.spurious_rate
        r_sp = cfg.min_range_m + (cfg.spurious_max_m - cfg.min_range_m) * f[2]
        first = spurious & (~seen | (r_sp < noisy))
        noisy = np.where(first, r_sp, noisy)
        m_det = np.where(first, 1.0 + 0.1 * (QUALITY_FULL_MARGIN - 1.0) * f[2], m_det)
        seen = seen | first
        dropped = f[0] < cfg.dropout_rate
        return self.encode(np.round(noisy * 100.0), seen, dropped, m_det, eff)

    def _max_cm(self, eff: float) -> int:
        return int(round((eff if self.honest else self.cfg.max_range_m) * 100))

    def _quality(self, eff: float, margin_of_return: float | None) -> int:
        """The sector sensor's rule: a return's own strength (hidden, or clear air), else the stated fraction."""
        if margin_of_return is not None and (not self.honest or self.extinction() == 0.0):
            m = min(margin_of_return, QUALITY_FULL_MARGIN)
            return int(max(2, round(100.0 * (m - 1.0) / (QUALITY_FULL_MARGIN - 1.0))))
        return int(max(2, min(100, round(100.0 * eff / self.cfg.max_range_m)))) if self.honest else 100

    def encode(self, cm: np.ndarray, seen: np.ndarray, dropped: np.ndarray, m_det: np.ndarray,
               eff: float) -> RangeReading:
        """OBSTACLE_DISTANCE bins (module docstring)."""
        max_cm = self._max_cm(eff)
        min_cm = int(round(self.cfg.min_range_m * 100))
        free = max_cm + 1
        hole = free if self.cfg.dropped_as == "free" else UINT16_MAX
        bins = [UINT16_MAX] * N_BINS
        for i in range(self.n_used):
            if dropped[i]:
                bins[i] = hole
            elif not seen[i] or cm[i] > max_cm:
                bins[i] = free
            elif cm[i] < min_cm:
                bins[i] = hole  # too near to measure: no valid depth
            else:
                bins[i] = int(cm[i])
        valid = [b for b in bins[: self.n_used] if b <= max_cm]
        current = min(valid) if valid else free
        m = float(m_det[bins.index(current)]) if valid else None
        return RangeReading(bins, math.degrees(self.inc), math.degrees(self.offsets[0]), min_cm, max_cm, current,
                            self._quality(eff, m), self.n_used * self.inc)


class DepthCamera(BodySensor):
    """A stereo depth camera's obstacle line as OBSTACLE_DISTANCE (RealSense D435 class; DEPTH_CAMERA)."""


class SingleBeam(BodySensor):
    """A single-beam lidar as DISTANCE_SENSOR (TFmini Plus class; SINGLE_BEAM), sent as PX4's TFmini driver sends
    it (src/drivers/distance_sensor/tfmini: `_px4_rangefinder.update(timestamp, distance_m)`, no signal quality:
    MAVLink's 0, unknown; a frame its parser rejects is not published at all): a dropped frame is no message
    (`read` returns None), or with `dropped_as: free` `max_distance + 1`; quality 0, except an honest sensor in
    fog, which states its fallen range and quality as the sector sensor does."""

    MESSAGES = ("DISTANCE_SENSOR",)
    SENSOR_TYPE = "LASER"

    def encode(self, cm, seen, dropped, m_det, eff) -> RangeReading | None:
        max_cm = self._max_cm(eff)
        min_cm = int(round(self.cfg.min_range_m * 100))
        if dropped[0] and self.cfg.dropped_as != "free":
            return None
        if dropped[0] or not seen[0] or cm[0] > max_cm:
            current = max_cm + 1
        elif cm[0] < min_cm:
            current = 0
        else:
            current = int(cm[0])
        quality = self._quality(eff, None) if self.honest and self.extinction() > 0.0 else 0
        bins = [UINT16_MAX] * N_BINS
        bins[0] = current if current else UINT16_MAX
        return RangeReading(bins, math.degrees(self.inc), math.degrees(self.offsets[0]), min_cm, max_cm, current,
                            quality, self.n_used * self.inc)


MODELS = {"sector": RangeSensor, "depth_camera": DepthCamera, "single_beam": SingleBeam}


def make_sensor(spec, seed: int) -> RangeSensor:
    """The scenario's `sensor` block (`scenario.SensorSpec`) as a sensor."""
    keys = RangeSensorConfig.__dataclass_fields__
    cfg = RangeSensorConfig(**{k: getattr(spec, k) for k in keys if hasattr(spec, k)})
    return MODELS[spec.model](cfg, seed=seed)
