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
- Backscatter from the medium: the fog's own return close to the sensor (where the receiver's field of
  view starts to overlap the beam) exceeds the threshold on a fraction of the shots that grows with α; we
  take p = 1 − e^(−α · L_bs) per shot (bin and frame), L_bs the sensor's backscatter length (a property of
  its optics and threshold, to be measured on one fog flight). A report that is the nearest of b shots (a
  DISTANCE_SENSOR giving the nearest return over a field of b beams) carries the medium's return when any of
  them does: q = 1 − (1 − p)^b, so p = 1 − (1 − q)^(1/b) from the fraction q of such reports.
"""

from __future__ import annotations

import math

import numpy as np

KOSCHMIEDER = -math.log(0.02)  # 3.912: α · V_met at the 2 % contrast threshold
RATED_REFLECTIVITY = 0.1  # the target the stated range is rated at (datasheets: ~10 %, a dark target)
REFERENCE_REFLECTIVITY = 0.5  # the default world obstacle (a grey surface); the fog's visibility is its range
BACKSCATTER_LENGTH_M = 0.3  # L_bs: p = 1 − e^(−α L_bs) per shot
OVERLAP_M = 1.0  # where the medium's return peaks: spurious returns at 0.5–1.5 × this
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
