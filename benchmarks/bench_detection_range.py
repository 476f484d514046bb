"""The detection-range estimator (companion/onboard/detection_range.py) against the SITL's sensor model in hidden fog:
per visibility, how soon the estimate is within 1.15 × the default target's true detection range, how close it
then stays, how soon it recovers; how a fog thickening over a ramp of T seconds is followed (the residual
assumption: the worst over-estimate and how long the estimate stays above the truth); each reading of the SITL's
sensor in fog (its 12 bins; its DISTANCE_SENSOR counted as 12 shots a frame, or as one) against the truth; and
haze of 200 m meteorological visibility for sensors stating 5–15 m (the cycles it lowers D_od in, and how far).
Prints one JSON object.

    python benchmarks/bench_detection_range.py [--seeds N]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.onboard.config import SensorConfig  # noqa: E402
from companion.onboard.detection_range import DetectionRange  # noqa: E402
from contracts.lidar import extinction_from_met_visibility, visibility_for_extinction  # noqa: E402
from sitl_harness.sensors import RangeSensorConfig  # noqa: E402
from tests.test_detection_range import BINS, R_MAX, fly, route_world  # noqa: E402

FACTOR = 1.15


def step(visibility: float, seed: int) -> dict:
    t_on, t_off = 6.0, 26.0
    trace = fly(route_world(200.0, seed=seed), 36.0, [(t_on, visibility), (t_off, None)], DetectionRange([BINS]),
                seed=seed)
    fog = [(t, d) for t, d, _, _ in trace if t_on <= t < t_off]
    above = [t for t, d in fog if d > FACTOR * visibility]
    onset = (max(above) - t_on + 0.05) if above else 0.0
    settled = [d / visibility for t, d in fog if t >= t_on + onset]
    clear = [t for t, d, stated, _ in trace if t >= t_off and d < stated]
    return {"visibility_m": visibility, "seed": seed, "onset_s": round(onset, 2),
            "max_ratio_after_onset": round(max(settled), 3), "median_ratio": round(float(np.median(settled)), 3),
            "recovery_s": round((max(clear) - t_off + 0.05) if clear else 0.0, 2)}


def ramp(ramp_s: float, seed: int, visibility: float = 3.0) -> dict:
    """Fog from clear to `visibility` over `ramp_s` (α linear in time); the estimate against the truth then."""
    from contracts.lidar import detection_range, extinction_for_range

    a_end = extinction_for_range(visibility, 0.5, R_MAX)
    t0, n = 6.0, max(1, int(ramp_s * 20))
    events = []
    for k in range(n + 1):
        a = a_end * k / n
        v = R_MAX * 10 if a == 0 else detection_range(a, 0.5, R_MAX)  # the visibility of that α (≥ R_max: none)
        events.append((t0 + ramp_s * k / n, None if a == 0 else v))
    trace = fly(route_world(200.0, seed=seed), t0 + ramp_s + 6.0, events, DetectionRange([BINS]), seed=seed)
    over = [(t, d / truth) for t, d, _, truth in trace if t >= t0 and d > truth + 1e-9]
    return {"ramp_s": ramp_s, "seed": seed, "worst_ratio": round(max((r for _, r in over), default=1.0), 3),
            "time_above_truth_s": round(len(over) / 20.0, 2)}


READINGS = {"bins": ("obstacle_distance", None), "beam_12_shots": ("distance_sensor", 12),
            "beam_one_shot": ("distance_sensor", None)}


def _reading(name: str, range_m: float) -> tuple[SensorConfig, bool]:
    kind, shots = READINGS[name]
    return SensorConfig(kind=kind, h_fov_deg=60.0, max_range_m=range_m, shots_per_frame=shots), kind != "obstacle_distance"


def reading(name: str, visibility: float, seed: int) -> dict:
    """Hidden fog from the start, 40 s at 3 m/s: the estimate / the true range after the first 2 s."""
    cfg, beam = _reading(name, R_MAX)
    trace = fly(route_world(200.0, seed=seed), 40.0, [(0.0, visibility)], DetectionRange([cfg]), beam=beam, seed=seed)
    r = [d / visibility for t, d, _, _ in trace if t >= 2.0]
    return {"reading": name, "visibility_m": visibility, "seed": seed, "median_ratio": round(float(np.median(r)), 3),
            "max_ratio": round(max(r), 3)}


def haze(name: str, range_m: float, seed: int, met_m: float = 200.0) -> dict:
    """Hidden haze of `met_m` meteorological visibility from the start, 60 s at 3 m/s: how often and how far D_od falls
    below the stated range after the first 2 s."""
    cfg, beam = _reading(name, range_m)
    vis = visibility_for_extinction(extinction_from_met_visibility(met_m), 0.5, range_m)
    trace = fly(route_world(200.0, seed=seed), 60.0, [(0.0, vis)], DetectionRange([cfg]), beam=beam, seed=seed,
                sensor_cfg=RangeSensorConfig(max_range_m=range_m))
    r = np.array([d / stated for t, d, stated, _ in trace if t >= 2.0])
    return {"reading": name, "range_m": range_m, "seed": seed, "cycles_lowered": round(float(np.mean(r < 1 - 1e-9)), 3),
            "lowest_ratio": round(float(r.min()), 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    a = ap.parse_args()
    seeds = range(1, a.seeds + 1)
    steps = [step(v, s) for v in (2.0, 3.0, 5.0, 8.0, 9.5) for s in seeds]
    ramps = [ramp(r, s) for r in (0.0, 1.0, 3.0, 10.0) for s in seeds]
    readings = [reading(n, v, s) for n in READINGS for v in (8.0, 6.0, 4.0) for s in seeds]
    hazes = [haze(n, r, s) for n in READINGS for r in (5.0, 8.0, 10.0, 15.0) for s in seeds]
    print(json.dumps({"bench": "detection_range", "sensor": "12 bins of 5 deg, 20 Hz, 10 m stated, 3 m/s",
                      "factor": FACTOR, "steps": steps, "ramps": ramps, "readings": readings, "haze_200m": hazes}))


if __name__ == "__main__":
    main()
