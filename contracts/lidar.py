"""A time-of-flight range sensor in an obscurant (fog, haze, dust): the few laws the SITL's sensor and the
on-board detection-range estimator share. Pure maths, SI units.

- Extinction: Koschmieder's law, the visibility V_met (the distance at which a black target's contrast
  falls to the 2 % threshold) and the extinction coefficient α are related by α = −ln(0.02) / V_met ≈
  3.912 / V_met [1/m] (H. Koschmieder, Beiträge zur Physik der freien Atmosphäre 12, 1924; the WMO's
  meteorological optical range takes 5 % instead, α = 2.996 / MOR: WMO-No. 8, vol. I, ch. 9).
- Return strength: the lidar equation for an extended diffuse (Lambertian) target filling the beam,
  P(R) ∝ ρ · e^(−2αR) / R² (two-way transmission of the medium; e.g. Weitkamp (ed.), Lidar, Springer 2005,
  ch. 1). A return is detected when P reaches the receiver's threshold. We normalise the threshold by the
  sensor's rating: a target of the *rated* reflectivity ρ_rated at the stated maximum range R_max in clear
  air is exactly at threshold (datasheets state the range at a dark, ~10 % target). So the detection
  margin P / P_th = (ρ / ρ_rated) · (R_max / R)² · e^(−2αR), and a target is seen while it is ≥ 1.
- Detection range of a target of reflectivity ρ: the R with margin 1, i.e. R · e^(αR) = R0(ρ) with the
  clear-air link range R0(ρ) = R_max · √(ρ / ρ_rated); closed form R = W(α R0) / α (Lambert W), never more
  than R_max (the sensor's range gate).
- Backscatter from the medium (the law in force in the SITL and on board: `backscatter_probability`): the
  medium's return close to the sensor exceeds the threshold on a fraction of the shots that grows with α;
  p = 1 − e^(−α · L_bs) per shot (bin and frame), L_bs the sensor's backscatter length.
- The medium's return from the lidar equation (`volume_backscatter_probability`; not yet drawn by the SITL nor
  inverted on board): a volume target. The medium near the sensor returns
  P_vol(r) ∝ β · (cτ/2) · O(r) · e^(−2αr) / r² (Weitkamp (ed.), Lidar, Springer 2005, ch. 1, eq. 1.7), with β the
  medium's backscatter coefficient, cτ/2 the pulse's range length and O(r) the receiver's overlap with the beam
  (a biaxial sensor's near field: 0 inside its blind zone, rising to 1 at full overlap). A Lambertian target returns
  P ∝ (ρ/π) · e^(−2αR) / R², so the medium at r is a target of reflectivity ρ_eq(r) = π · β · (cτ/2) · O(r), and its
  margin over the same threshold is (ρ_eq(r) / ρ_rated) · (R_max / r)² · e^(−2αr). β = α / S with S the medium's
  lidar ratio: fog and cloud droplets S ≈ 18 sr (Pinnick et al., "Backscatter and extinction in water clouds",
  J. Geophys. Res. 88 (1983) 6787: σ_e = 18.2 σ_b at 1.06 µm), continental aerosol and haze 40–70 sr (Ackermann,
  "The extinction-to-backscatter ratio of tropospheric aerosol: a numerical study", J. Atmos. Oceanic Technol. 15
  (1998) 1043). The margin peaks at r* (`medium_peak`: with a linear overlap ramp r* ≈ 2 × its start in thin
  media). A volume return is the sum of many droplets' fields with random phases: its intensity fluctuates from
  shot to shot as an exponential variable (fully developed speckle; Goodman, Speckle Phenomena in Optics, 2007,
  ch. 3), so a shot crosses the threshold with p = e^(−1/M̄), M̄ the mean margin at r* — a soft threshold: p is
  negligible while M̄ ≪ 1 (M̄ = 0.1: 5 · 10⁻⁵) and near 1 once M̄ ≫ 1. A report that is the nearest of b shots (a
  DISTANCE_SENSOR giving the nearest return over a field of b beams) carries the medium's return when any of them
  does: q = 1 − (1 − p)^b, so p = 1 − (1 − q)^(1/b) from the fraction q of such reports. The inversion
  (`extinction_from_volume_backscatter`) is the same law solved for α; a rate below what a window can count reads as
  "α below α_bs" (`backscatter_floor`), not as a number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KOSCHMIEDER = -math.log(0.02)  # 3.912: α · V_met at the 2 % contrast threshold
RATED_REFLECTIVITY = 0.1  # the target the stated range is rated at (datasheets: ~10 %, a dark target)
REFERENCE_REFLECTIVITY = 0.5  # the default world obstacle (a grey surface); the fog's visibility is its range
BACKSCATTER_LENGTH_M = 0.3  # L_bs: p = 1 − e^(−α L_bs) per shot
OVERLAP_M = 1.0  # where the medium's return peaks: spurious returns at 0.5–1.5 × this
FOG_LIDAR_RATIO_SR = 18.2  # S of fog and cloud droplets (Pinnick et al. 1983, module docstring)
HAZE_LIDAR_RATIO_SR = 70.0  # the top of continental aerosol's 40–70 sr (Ackermann 1998): the most extinction per backscatter
QUALITY_FULL_MARGIN = REFERENCE_REFLECTIVITY / RATED_REFLECTIVITY  # margin at which signal quality is 100


def extinction_from_met_visibility(v_met_m: float) -> float:
    """α [1/m] from the meteorological visibility (Koschmieder); 0 for an infinite visibility."""
    return KOSCHMIEDER / v_met_m if math.isfinite(v_met_m) and v_met_m > 0 else 0.0


def link_range(max_range_m: float, rho: float, rho_rated: float = RATED_REFLECTIVITY) -> float:
    """R0(ρ): the clear-air range at which a target of reflectivity ρ is at the threshold."""
    return max_range_m * math.sqrt(rho / rho_rated)


def margin(r_m, rho, alpha: float, max_range_m: float, rho_rated: float = RATED_REFLECTIVITY):
    """P / P_th of a return from range r (scalars or numpy arrays): ≥ 1 is detected."""
    return (rho / rho_rated) * (max_range_m / r_m) ** 2 * np.exp(-2.0 * alpha * r_m)


def detection_range(alpha: float, rho: float, max_range_m: float, rho_rated: float = RATED_REFLECTIVITY) -> float:
    """The range to which a target of reflectivity ρ is seen through extinction α: R · e^(αR) = R0(ρ),
    capped by the range gate R_max. Solved by Newton on ln R + αR = ln R0 (convex, monotone; no SciPy)."""
    r0 = link_range(max_range_m, rho, rho_rated)
    if alpha <= 0.0:
        return min(r0, max_range_m)
    return min(_through(alpha, r0), max_range_m)


def visibility_for_extinction(alpha: float, rho: float, max_range_m: float,
                              rho_rated: float = RATED_REFLECTIVITY) -> float:
    """The range to which a target of reflectivity ρ is seen through extinction α with no range gate (the SITL's
    `visibility_m` of a medium, which may exceed the sensor's range: haze): R · e^(αR) = R0(ρ); inf without
    extinction. The inverse of `extinction_for_range`."""
    return _through(alpha, link_range(max_range_m, rho, rho_rated)) if alpha > 0.0 else math.inf


def _through(alpha: float, r0: float) -> float:
    """The R with R · e^(αR) = r0 (α > 0): Newton on ln R + αR = ln r0."""
    ln_r0 = math.log(r0)
    r = min(r0, 1.0 / alpha)
    for _ in range(60):
        f = math.log(r) + alpha * r - ln_r0
        step = f / (1.0 / r + alpha)
        r = max(r - step, r * 1e-3)
        if abs(step) < 1e-12 * max(r, 1.0):
            break
    return r


def extinction_for_range(range_m: float, rho: float, max_range_m: float, rho_rated: float = RATED_REFLECTIVITY) -> float:
    """The α at which a target of reflectivity ρ is seen exactly to `range_m`: α = ln(R0 / R) / R (0 when
    R ≥ R0: no extinction is that weak). The inverse of `detection_range`."""
    r0 = link_range(max_range_m, rho, rho_rated)
    return math.log(r0 / range_m) / range_m if 0.0 < range_m < r0 else 0.0


def backscatter_probability(alpha: float, length_m: float = BACKSCATTER_LENGTH_M) -> float:
    """The chance that one shot (one bin of one frame) returns from the medium near the sensor."""
    return 1.0 - math.exp(-alpha * length_m) if alpha > 0.0 else 0.0


def per_shot_from_reports(q: float, shots: float) -> float:
    """The chance p that one shot returns from the medium, from the fraction q of reports that carry such a
    return when each report is the nearest of `shots` shots: q = 1 − (1 − p)^shots (one shot: p = q)."""
    if shots == 1 or q <= 0.0:
        return q
    return 1.0 - (1.0 - min(q, 1.0)) ** (1.0 / shots)


def extinction_from_backscatter(p: float, length_m: float = BACKSCATTER_LENGTH_M) -> float:
    """The inverse of `backscatter_probability`: α from a measured fraction of shots with a medium return."""
    return -math.log(1.0 - min(p, 0.999)) / length_m if p > 0.0 else 0.0


@dataclass(frozen=True)
class NearField:
    """What sets a sensor's return from the medium near it (module docstring): the pulse's range length cτ/2 and the
    receiver's overlap with the beam, 0 nearer than `overlap_start_m`, rising linearly to 1 at `overlap_full_m`
    (the usual first-order form of a biaxial sensor's overlap). The defaults, for a LightWare SF45/B-class scanning
    lidar: the overlap starts at its stated 0.2 m minimum range (SF45/B product manual); full overlap at 1 m, a
    biaxial geometry's estimate (lens baseline d ≈ 20 mm, receiver aperture radius ≈ 6 mm, the receiver's field a
    few mrad wider than the beam: r_full ≈ (d + a_t − a_r) / (θ_r − θ_t) ≈ 1 m), not a datasheet figure; cτ/2 =
    0.75 m, a 5 ns pulse of the 905 nm pulsed laser diodes such sensors use (not published by the maker: an
    assumption at the short end of pulsed diodes' 5–100 ns, the least backscatter). A TFmini Plus-class single
    beam: overlap from its stated 0.1 m minimum, full by 0.5 m, where a TFmini's readings become true (below it
    they read long: ArduPilot/ardupilot_wiki issue 1251; Benewake states a 0.3 m blind range)."""

    pulse_m: float = 0.75  # cτ/2 [m]
    overlap_start_m: float = 0.2  # O = 0 nearer (the blind zone)
    overlap_full_m: float = 1.0  # O = 1 from here

    def overlap(self, r: float) -> float:
        """O(r), the fraction of the beam the receiver sees at range r."""
        r0, r1 = self.overlap_start_m, self.overlap_full_m
        if r1 <= r0:
            return 1.0 if r >= r0 else 0.0
        return min(max((r - r0) / (r1 - r0), 0.0), 1.0)


NEAR_FIELD = NearField()


def medium_peak(alpha: float, near: NearField = NEAR_FIELD) -> float:
    """r*: the range at which the medium's margin O(r) · e^(−2αr) / r² peaks. On the ramp, d/dr ln = 0 gives
    2α r² + (1 − 2α r0) r − 2 r0 = 0 (2 r0 as α → 0); clipped to the ramp (beyond full overlap the margin falls)."""
    r0, r1 = near.overlap_start_m, near.overlap_full_m
    if r1 <= r0:
        return r0
    if alpha <= 0.0:
        r = 2.0 * r0
    else:
        b = 1.0 - 2.0 * alpha * r0
        r = (-b + math.sqrt(b * b + 16.0 * alpha * r0)) / (4.0 * alpha)
    return min(max(r, r0), r1)


def medium_margin(alpha: float, max_range_m: float, near: NearField = NEAR_FIELD,
                  rho_rated: float = RATED_REFLECTIVITY, lidar_ratio_sr: float = FOG_LIDAR_RATIO_SR) -> float:
    """M̄: the mean margin over the receiver's threshold of the medium's return at its peak r* (module docstring):
    ρ_eq = π (α/S) (cτ/2) O(r*), through the same normalisation as a target's (`margin`)."""
    if alpha <= 0.0:
        return 0.0
    r = medium_peak(alpha, near)
    rho_eq = math.pi * (alpha / lidar_ratio_sr) * near.pulse_m * near.overlap(r)
    return float(margin(r, rho_eq, alpha, max_range_m, rho_rated))


def volume_backscatter_probability(alpha: float, max_range_m: float, near: NearField = NEAR_FIELD,
                            rho_rated: float = RATED_REFLECTIVITY, lidar_ratio_sr: float = FOG_LIDAR_RATIO_SR) -> float:
    """The chance that one shot (one bin of one frame) returns from the medium near the sensor: p = e^(−1/M̄)."""
    m = medium_margin(alpha, max_range_m, near, rho_rated, lidar_ratio_sr)
    return math.exp(-1.0 / m) if m > 0.0 else 0.0


def densest_readable(max_range_m: float, near: NearField = NEAR_FIELD, rho_rated: float = RATED_REFLECTIVITY,
                     lidar_ratio_sr: float = FOG_LIDAR_RATIO_SR) -> float:
    """The α at which M̄ stops growing (2α r* = 1: a denser medium dims its own near return); the law tells media
    apart only below it. Bisection (α r*(α) grows with α)."""
    lo, hi = 0.0, 1.0 / (2.0 * max(near.overlap_start_m, 1e-3))
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if 2.0 * mid * medium_peak(mid, near) < 1.0:
            lo = mid
        else:
            hi = mid
    return lo


def extinction_from_volume_backscatter(p: float, max_range_m: float, near: NearField = NEAR_FIELD,
                                rho_rated: float = RATED_REFLECTIVITY,
                                lidar_ratio_sr: float = FOG_LIDAR_RATIO_SR) -> float:
    """The inverse of `volume_backscatter_probability`: α from a measured fraction p of shots with a medium return, on the
    branch where M̄ grows with α (`densest_readable`; a rate above that medium's reads as it: beyond it every shot
    returns from the medium anyway). 0 for p = 0. Bisection (M̄ grows with α there)."""
    if p <= 0.0:
        return 0.0
    target = -1.0 / math.log(min(p, 1.0 - 1e-12))
    top = densest_readable(max_range_m, near, rho_rated, lidar_ratio_sr)
    if medium_margin(top, max_range_m, near, rho_rated, lidar_ratio_sr) <= target:
        return top
    lo, hi = 0.0, top
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if medium_margin(mid, max_range_m, near, rho_rated, lidar_ratio_sr) < target:
            lo = mid
        else:
            hi = mid
    return hi


def backscatter_floor(rate: float, max_range_m: float, near: NearField = NEAR_FIELD,
                      rho_rated: float = RATED_REFLECTIVITY, lidar_ratio_sr: float = FOG_LIDAR_RATIO_SR) -> float:
    """α_bs: the extinction whose medium returns per shot reach `rate` (the least a window can count, e.g. its
    required returns over its shots). Below it the law's p is too small to read: backscatter says only "α below
    α_bs", and a medium between α_bs and the α that shortens the range is left to the other evidence."""
    return extinction_from_volume_backscatter(rate, max_range_m, near, rho_rated, lidar_ratio_sr)
