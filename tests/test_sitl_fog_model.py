"""The SITL range sensor in fog (sitl_harness/sensors.py, contracts/lidar.py): what a target of each
reflectivity is still seen at, the medium's backscatter, the driver-style signal quality, the stated range,
and the scenario keys. Clear air is unchanged: the golden clear-air flights (tests/test_golden_logs.py) log
byte for byte what they logged before fog had a physics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from contracts.lidar import (KOSCHMIEDER, backscatter_probability, detection_range, extinction_for_range,
                             extinction_from_backscatter, extinction_from_met_visibility, margin)
from sitl_harness.scenario import ScenarioError, scenario_from_dict
from sitl_harness.sensors import RangeSensor, RangeSensorConfig
from sitl_harness.world import Column, World

R_MAX = 10.0
POS = np.array([0.0, 0.0, -2.0])


def quiet(seed: int = 1) -> RangeSensor:
    return RangeSensor(RangeSensorConfig(max_range_m=R_MAX, noise_sd_m=0.0, noise_rel=0.0), seed=seed)


def seen_from(rho: float, visibility: float | None, honest: bool = False) -> float:
    """The farthest range [m] at which a column of reflectivity rho straight ahead is reported (0: never)."""
    s = quiet()
    s.visibility_m, s.honest = (math.inf if visibility is None else visibility), honest
    for x in np.arange(R_MAX + 0.5, 0.4, -0.05):
        r = s.read(World([Column(float(x) + 0.4, 0.0, 0.4, reflectivity=rho)]), POS, 0.0)
        centre = r.distances_cm[s.n_used // 2 - 1: s.n_used // 2 + 1]
        if any(d <= r.max_cm and abs(d / 100 - x) < 0.02 for d in centre):
            return float(x)
    return 0.0


def test_the_laws():
    assert extinction_from_met_visibility(100.0) == pytest.approx(3.912 / 100.0, rel=1e-3)
    assert KOSCHMIEDER == pytest.approx(3.912, abs=1e-3)
    a = extinction_for_range(4.0, 0.5, R_MAX)
    assert margin(4.0, 0.5, a, R_MAX) == pytest.approx(1.0)  # the default target exactly at threshold there
    assert detection_range(a, 0.5, R_MAX) == pytest.approx(4.0)
    assert detection_range(0.0, 0.5, R_MAX) == R_MAX and detection_range(0.0, 0.05, R_MAX) < R_MAX
    ranges = [detection_range(x, 0.5, R_MAX) for x in (0.05, 0.1, 0.3, 1.0)]
    assert ranges == sorted(ranges, reverse=True)  # falls with α
    assert extinction_from_backscatter(backscatter_probability(0.4)) == pytest.approx(0.4)


@pytest.mark.parametrize("visibility", [3.0, 6.0])
def test_what_is_seen_falls_with_the_fog_and_with_the_reflectivity(visibility):
    dark, grey, bright = (seen_from(rho, visibility) for rho in (0.1, 0.5, 0.9))
    a = extinction_for_range(visibility, 0.5, R_MAX)
    assert grey == pytest.approx(visibility, abs=0.06)  # `visibility_m` keeps its meaning for the default target
    assert dark == pytest.approx(detection_range(a, 0.1, R_MAX), abs=0.06)
    assert bright == pytest.approx(detection_range(a, 0.9, R_MAX), abs=0.06)
    assert dark < grey < bright


def test_clear_air_sees_every_rated_target_to_the_full_range():
    assert seen_from(0.1, None) >= R_MAX - 0.06 and seen_from(0.5, None) >= R_MAX - 0.06
    assert seen_from(0.05, None) == pytest.approx(R_MAX * math.sqrt(0.5), abs=0.06)  # below the rated reflectivity


def test_hidden_fog_keeps_the_stated_range_and_the_honest_sensor_lowers_it():
    world = World([Column(20.0, 0.0, 0.4)])
    s = quiet()
    s.visibility_m, s.honest = 4.0, False
    assert s.read(world, POS, 0.0).max_cm == 1000
    s.honest = True
    r = s.read(world, POS, 0.0)
    assert r.max_cm == 400 and r.signal_quality == 40


def shots(visibility, honest=False, seed=1, frames=400):
    s = quiet(seed)
    s.visibility_m, s.honest = visibility, honest
    out = [s.read(World(), POS, 0.0) for _ in range(frames)]
    short = sum(d <= 150 for r in out for d in r.distances_cm[: s.n_used])
    return short / (frames * s.n_used), out


def test_backscatter_grows_with_the_fog_is_seeded_and_absent_in_clear_air_and_honest_fog():
    rates = [shots(v)[0] for v in (8.0, 5.0, 3.0)]
    assert rates == sorted(rates) and rates[0] > 0
    for v, rate in zip((8.0, 5.0, 3.0), rates):  # the model's rate, within sampling error
        p = backscatter_probability(extinction_for_range(v, 0.5, R_MAX))
        assert rate == pytest.approx(p, abs=4 * math.sqrt(p / 4800) + 1e-3)
    assert shots(math.inf)[0] == 0.0 and shots(3.0, honest=True)[0] == 0.0
    a, b, c = (shots(3.0, seed=k)[1] for k in (1, 1, 2))
    assert [r.distances_cm for r in a] == [r.distances_cm for r in b] != [r.distances_cm for r in c]
    short = [d for r in a for d in r.distances_cm[:12] if d <= 150]
    assert min(short) >= 50 and max(short) <= 150  # near the sensor, where the beam enters the receiver's view


def test_signal_quality_is_the_strength_of_the_return_reported():
    s = quiet()
    near, far = World([Column(3.4, 0.0, 0.4)]), World([Column(6.4, 0.0, 0.4)])
    assert s.read(near, POS, 0.0).signal_quality == 100 and s.read(far, POS, 0.0).signal_quality == 100  # clear air
    s.visibility_m, s.honest = 7.0, False
    s.rng_medium = np.random.default_rng(0)
    q_near = [s.read(near, POS, 0.0) for _ in range(50)]
    q_far = [s.read(far, POS, 0.0) for _ in range(50)]
    # frames whose nearest return is the column (not the fog's own): strong near, weak near the threshold far
    near_q = [r.signal_quality for r in q_near if r.current_cm == 300]
    far_q = [r.signal_quality for r in q_far if r.current_cm == 600]
    assert near_q and far_q and min(near_q) > max(far_q)
    assert max(far_q) < 100 and min(far_q) >= 2
    s.visibility_m = math.inf
    assert s.read(World(), POS, 0.0).signal_quality == 100  # nothing returned


def test_scenario_reflectivity_key():
    sc = scenario_from_dict({"world": {"columns": [{"x_m": 5, "y_m": 0, "radius_m": 0.5, "reflectivity": 0.1}],
                                       "boxes": [{"x_m": 9, "y_m": 0, "length_m": 1, "width_m": 4}]}})
    assert sc.world.columns[0].reflectivity == 0.1 and sc.world.boxes[0].reflectivity == 0.5
    for bad in (0, 1.5, -0.1):
        with pytest.raises(ScenarioError, match="reflectivity"):
            scenario_from_dict({"world": {"columns": [{"x_m": 5, "y_m": 0, "radius_m": 0.5, "reflectivity": bad}]}})
