"""The medium's return near the sensor (contracts/lidar.py): the lidar equation for a volume target against the same
receiver threshold as a hard target, an exponential intensity per shot, and its inversion (for the estimator on board).

The law is p = e^(−1/M̄) per shot, M̄ = (π (α/S) (cτ/2) O(r*) / ρ_rated) · (R_max/r*)² · e^(−2αr*). These tests show
that p vanishes below a threshold-like extinction and stays near 1 in dense fog, that the estimator's inversion gives
α back, and (negative control) how the length law in force, p = 1 − e^(−α·0.3 m), differs from it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from contracts.lidar import (
    FOG_LIDAR_RATIO_SR,
    HAZE_LIDAR_RATIO_SR,
    NearField,
    backscatter_floor,
    backscatter_probability,
    densest_readable,
    extinction_for_range,
    extinction_from_met_visibility,
    extinction_from_volume_backscatter,
    margin,
    medium_margin,
    medium_peak,
    volume_backscatter_probability,
)

R_MAX = 8.0
NEAR = NearField(0.75, 0.2, 1.0)


def old_law(alpha: float, length_m: float = 0.3) -> float:
    """The length law the SITL draws now (`backscatter_probability`): any α returns, linearly."""
    return backscatter_probability(alpha, length_m)


def test_the_volume_target_is_normalised_like_a_hard_one():
    """At full overlap the medium is a Lambertian target of reflectivity π·β·cτ/2: the same `margin`."""
    flat = NearField(0.75, 0.5, 0.5)  # overlap full from 0.5 m: r* = 0.5 m
    a = 0.05
    rho_eq = math.pi * (a / FOG_LIDAR_RATIO_SR) * 0.75
    assert medium_peak(a, flat) == 0.5
    assert medium_margin(a, R_MAX, flat) == pytest.approx(float(margin(0.5, rho_eq, a, R_MAX)))
    assert medium_margin(a, R_MAX, flat, lidar_ratio_sr=2 * FOG_LIDAR_RATIO_SR) == \
        pytest.approx(medium_margin(a, R_MAX, flat) / 2)  # β = α / S
    assert medium_margin(a, R_MAX, flat, rho_rated=0.9) == pytest.approx(medium_margin(a, R_MAX, flat) / 9)


def test_the_peak_is_where_the_margin_is_largest():
    for a in (1e-4, 0.02, 0.2, 1.0):
        r = medium_peak(a, NEAR)
        grid = np.linspace(0.2, 3.0, 2801)
        m = [NEAR.overlap(x) * math.exp(-2 * a * x) / x ** 2 for x in grid]
        assert r == pytest.approx(grid[int(np.argmax(m))], abs=2e-3)
    assert medium_peak(0.0, NEAR) == pytest.approx(0.4)  # 2 r0 in thin media


def test_p_vanishes_below_a_threshold_and_dense_fog_still_returns():
    """A soft threshold: p is negligible where M̄ ≪ 1 (10⁻⁹ at M̄ = 0.05) and near 1 in dense fog; it grows with α
    up to the densest medium the law tells apart."""
    weak = NearField(0.15, 0.3, 3.0)  # a short pulse and a late overlap: a sensor that hardly sees the medium
    a_lo = 0.002
    assert medium_margin(a_lo, R_MAX, weak, lidar_ratio_sr=HAZE_LIDAR_RATIO_SR) < 0.05
    assert volume_backscatter_probability(a_lo, R_MAX, weak, lidar_ratio_sr=HAZE_LIDAR_RATIO_SR) < 1e-8
    assert old_law(a_lo) > 5e-4  # negative control: the old law returns at any α (6 · 10⁻⁴ per shot here)
    dense = extinction_for_range(0.4 * R_MAX, 0.5, R_MAX)  # the default target seen to 0.4 of the range
    assert volume_backscatter_probability(dense, R_MAX, weak, lidar_ratio_sr=HAZE_LIDAR_RATIO_SR) > 0.05  # 0.083: 20 a s
    assert volume_backscatter_probability(dense, R_MAX, NEAR) > 0.95
    ps = [volume_backscatter_probability(a, R_MAX, NEAR) for a in np.linspace(0.0, densest_readable(R_MAX, NEAR), 50)]
    assert ps[0] == 0.0 and all(np.diff(ps) > 0)


def test_the_inversion_inverts_the_law():
    for near, s in ((NEAR, FOG_LIDAR_RATIO_SR), (NEAR, HAZE_LIDAR_RATIO_SR), (NearField(0.15, 0.3, 3.0), 70.0)):
        for a in (0.003, 0.0196, 0.1, 0.5):
            p = volume_backscatter_probability(a, R_MAX, near, lidar_ratio_sr=s)
            if 1e-300 < p < 1.0 - 1e-9:
                assert extinction_from_volume_backscatter(p, R_MAX, near, lidar_ratio_sr=s) == pytest.approx(a, rel=1e-6)
    top = densest_readable(R_MAX, NEAR)
    assert extinction_from_volume_backscatter(1.0, R_MAX, NEAR) == pytest.approx(top)  # every shot: the densest readable
    assert extinction_from_volume_backscatter(0.0, R_MAX, NEAR) == 0.0
    # the floor: the α whose rate is 3 returns in 240 shots
    floor = backscatter_floor(3 / 240, R_MAX, NEAR)
    assert volume_backscatter_probability(floor, R_MAX, NEAR) == pytest.approx(3 / 240, rel=1e-6)


def test_negative_control_the_old_law_does_not_invert_the_new_one():
    """Read through the old law, a 200 m haze's rate of the volume law reads as a medium of another α entirely."""
    a = extinction_from_met_visibility(200.0)
    p = volume_backscatter_probability(a, R_MAX, NEAR)
    old = -math.log(1.0 - p) / 0.3
    assert extinction_from_volume_backscatter(p, R_MAX, NEAR) == pytest.approx(a, rel=1e-6)
    assert old > 10 * a


@pytest.mark.parametrize("r_max", [5.0, 8.0])
@pytest.mark.parametrize("near", [NEAR, NearField(0.15, 0.2, 1.0), NearField(0.75, 0.2, 3.0), NearField(0.75, 0.1, 0.5)])
def test_a_fog_at_0_8_of_the_range_is_seen_where_a_200_m_medium_is_barely_seen(r_max, near):
    """M̄ is linear in the pulse, 1/S and 1/ρ_rated, so the ratio of two media's margins depends on the overlap and
    the range only: scaled so that a 200 m medium returns on one shot in 10⁴, a fog that lets the reference target be
    seen to 0.8 of the stated range returns on more than a quarter of the shots."""
    haze = extinction_from_met_visibility(200.0)
    fog = extinction_for_range(0.8 * r_max, 0.5, r_max)
    ratio = medium_margin(fog, r_max, near) / medium_margin(haze, r_max, near)
    m_haze = -1.0 / math.log(1e-4)
    assert fog / haze > 8.0 and ratio > 7.0
    assert math.exp(-1.0 / (ratio * m_haze)) > 0.25
