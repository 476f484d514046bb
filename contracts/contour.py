"""Contour error (the paper's Figure 11): the shortest distance from the vehicle to the commanded path.

Exact per segment (foot-point search over the segments of a window of the path), for polylines and
sampled trajectories in any dimension. One implementation, shared by the controller-contract builder
(offline, whole flights) and the on-board `E_tr` estimator (`ContourWindow`).
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right

import numpy as np

from .jit import HAVE_NUMBA, njit
from .window import WindowMax


def distance_to_polyline(p, pts) -> float:
    """Shortest distance from point `p` (d,) to the polyline through `pts` (n, d), n ≥ 1."""
    pts = np.asarray(pts, dtype=float)
    p = np.asarray(p, dtype=float)
    if len(pts) == 1:
        return float(np.linalg.norm(p - pts[0]))
    if compiled_2d(p, pts):
        return _polyline_2d(float(p[0]), float(p[1]), pts)
    ab = pts[1:] - pts[:-1]
    return distance_to_segments(p, pts[:-1], ab, segment_norms(ab))


def segment_norms(ab: np.ndarray) -> np.ndarray:
    """|ab|² of each segment, 1 for a zero-length one (its foot-point fraction ap·ab / 1 is then 0)."""
    den = np.einsum("ij,ij->i", ab, ab)
    return np.where(den > 0, den, 1.0)


@njit
def _polyline_2d(px: float, py: float, pts: np.ndarray) -> float:
    """`distance_to_polyline` of the point (px, py) to `pts` (n, 2), n ≥ 2, compiled: `distance_to_segments`'
    operations in its order (the same bits; NaN as numpy's `min`)."""
    best = math.inf
    for k in range(pts.shape[0] - 1):
        abx, aby = pts[k + 1, 0] - pts[k, 0], pts[k + 1, 1] - pts[k, 1]
        den = abx * abx + aby * aby
        if not den > 0:
            den = 1.0
        apx, apy = px - pts[k, 0], py - pts[k, 1]
        s = (apx * abx + apy * aby) / den
        if s < 0.0:
            s = 0.0
        elif s > 1.0:
            s = 1.0
        fx, fy = apx - s * abx, apy - s * aby
        d = fx * fx + fy * fy
        if d != d:  # NaN: numpy's min is NaN too
            return math.nan
        if d < best:
            best = d
    return math.sqrt(best)


def compiled_2d(p: np.ndarray, pts: np.ndarray) -> bool:
    """Whether `_polyline_2d` measures `p` against `pts` (numba there, points in the plane)."""
    return HAVE_NUMBA and p.shape[0] == 2 and pts.shape[1] == 2


def distance_to_segments(p: np.ndarray, a: np.ndarray, ab: np.ndarray, den: np.ndarray) -> float:
    """Shortest distance from `p` (d,) to the segments from `a` (m, d) along `ab` (m, d), m ≥ 1, whose
    `segment_norms` are `den`: the foot point's fraction along each, clipped to the segment."""
    ap = p - a
    s = np.einsum("ij,ij->i", ap, ab)
    s /= den
    np.minimum(np.maximum(s, 0.0, out=s), 1.0, out=s)  # clipped to [0, 1] (ufuncs: no np.clip wrappers per call)
    ap -= s[:, None] * ab  # the foot point's offset
    return math.sqrt(np.einsum("ij,ij->i", ap, ap).min())


def contour_errors(positions, times, path_times, path_points, window_s: float) -> np.ndarray:
    """Contour error of each flown sample against the commanded path near its own time.

    Sample i at `times[i]` is measured against the path samples with times in
    [times[i] − window_s, times[i] + window_s] (plus the segment entering that window), so a path
    that crosses itself later does not hide an error now.
    """
    positions = np.asarray(positions, dtype=float)
    path_times = np.asarray(path_times, dtype=float)
    path_points = np.asarray(path_points, dtype=float)
    lo = np.searchsorted(path_times, np.asarray(times) - window_s, side="left")
    hi = np.searchsorted(path_times, np.asarray(times) + window_s, side="right")
    out = np.empty(len(positions))
    for i, p in enumerate(positions):
        a, b = max(lo[i] - 1, 0), max(hi[i], lo[i] + 1)
        out[i] = distance_to_polyline(p, path_points[a : min(b + 1, len(path_points))])
    return out


class ContourWindow:
    """On-board sliding window: the worst contour error over the last `window_s` seconds.

    Feed commanded path samples with `command(t, p)` (they may lie ahead of the current time) and
    measured positions with `measure(t, p)`; `worst` is the largest error in the window. The path is kept
    in a growing array (times non-decreasing; a sample earlier than the last starts a new plan), so a
    measurement slices it instead of re-stacking every sample (at 50 Hz, per cycle); each segment's
    direction and |ab|² are computed once, when first measured against (`_segments`), not every cycle (with
    numba, in the plane, `_polyline_2d` makes them on the fly, cheaper than one numpy call); the times are a
    list, searched with `bisect` (as `np.searchsorted`, without an array call per search).
    """

    def __init__(self, window_s: float = 2.0, path_span_s: float = 2.0):
        self.window_s = window_s
        self.path_span_s = path_span_s
        self._t: list[float] = []
        self._p = np.empty((0, 0))
        self._lo = self._hi = 0  # the live path is [_lo, _hi) of the arrays
        self._ab, self._den = np.empty((0, 0)), np.empty(0)  # segment k: from point k to k + 1
        self._seg = 0  # segments [_lo, _seg) are computed
        self._errors = WindowMax(window_s)
        if HAVE_NUMBA:  # compile (or load numba's cache) now, not in the first cycle that measures
            _polyline_2d(0.0, 0.0, np.zeros((2, 2)))

    def command(self, t: float, p) -> None:
        p = np.asarray(p, dtype=float)
        if self._hi > self._lo and t < self._t[self._hi - 1]:
            self._lo = self._hi = self._seg = 0  # a new plan replaces the old one from here on
        if self._hi == len(self._t) or self._p.shape[1] != p.shape[0]:
            self._make_room(p.shape[0])
        self._t[self._hi] = float(t)
        self._p[self._hi] = p
        self._hi += 1

    def _make_room(self, dim: int) -> None:
        """Copy the live part to the front of arrays twice its size (amortised O(1) per sample)."""
        n = self._hi - self._lo if self._p.shape[1] == dim else 0  # another dimension: a new path
        cap = max(64, 2 * n)
        t, q, ab, den = [0.0] * cap, np.empty((cap, dim)), np.empty((cap, dim)), np.empty(cap)
        seg = max(self._seg - self._lo, 0) if n else 0
        if n:
            t[:n], q[:n] = self._t[self._lo:self._hi], self._p[self._lo:self._hi]
            ab[:seg], den[:seg] = self._ab[self._lo:self._seg], self._den[self._lo:self._seg]
        self._t, self._p, self._ab, self._den, self._lo, self._hi, self._seg = t, q, ab, den, 0, n, seg

    def _segments(self, end: int) -> None:
        """Compute the segments up to `end` (exclusive; each needs its next point)."""
        k = max(self._seg, self._lo)
        if end > k:
            ab = self._ab[k:end]
            np.subtract(self._p[k + 1:end + 1], self._p[k:end], out=ab)
            self._den[k:end] = segment_norms(ab)
            self._seg = end

    def measure(self, t: float, p) -> float | None:
        """Contour error of position `p` at time `t` (None if no commanded path is known yet)."""
        lo, hi = self._lo, self._hi
        if hi == lo:
            return None
        # drop the leading samples while the next one is older than the span (one sample stays)
        lo = bisect_left(self._t, t - self.path_span_s, lo + 1, hi) - 1
        self._lo = lo
        n = bisect_right(self._t, t + self.path_span_s, lo, hi) - lo
        p = np.asarray(p, dtype=float)
        if n <= 1:
            e = float(np.linalg.norm(p - self._p[lo]))
        elif compiled_2d(p, self._p):  # the segments' directions are made on the fly
            e = _polyline_2d(float(p[0]), float(p[1]), self._p[lo:lo + n])
        else:
            end = lo + n - 1
            self._segments(end)
            e = distance_to_segments(p, self._p[lo:end], self._ab[lo:end], self._den[lo:end])
        self._errors.add(t, e)
        return e

    @property
    def worst(self) -> float:
        worst = self._errors.max
        return 0.0 if worst is None else worst

    def reset(self) -> None:
        self._lo = self._hi = self._seg = 0
        self._errors.clear()
