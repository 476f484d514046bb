"""Swept sensor coverage: how far along a ray the sensors have seen free space.

The navigation guarantee `D_od` says that every obstacle within D_od along the direction of travel is
detected. Inside a sensor's field of view that is its claimed range. When the direction of travel leaves
the field of view (a vehicle slowing with a sideways component: the velocity's direction turns at
|a⊥|/v, faster than any yaw rate as v → 0), the direction is not covered *now*, but the sensor saw part
of it free while the vehicle moved. For the paper's static obstacles a region seen free stays free, so
the covered distance along the ray is the length of the ray's first stretch inside the union of the
sectors seen free recently.

A sector is a wedge of a sensor sample: apex (where the sensor was), bearings [θ_lo, θ_hi] (absolute,
counter-clockwise from x, width under π), radius (the claimed range, or the range of the hit that
bounds it). Pure maths, no I/O; NED x, y in metres, angles in radians.
"""

from __future__ import annotations

import math

import numpy as np

EPS = 1e-9


def ray_intervals(p, theta: float, sectors: np.ndarray) -> np.ndarray:
    """The stretch [s0, s1] (s ≥ 0) of the ray p + s·(cos θ, sin θ) inside each sector.

    `sectors`: rows (apex x, apex y, θ_lo, θ_hi, radius), θ_hi − θ_lo in (0, π). A wedge of width under π
    is the intersection of two half-planes and a disc: each is an interval of s (linear, quadratic), and
    their intersection is one interval (convex). Returns (n, 2); an empty stretch has s1 < s0."""
    sec = np.asarray(sectors, float).reshape(-1, 5)
    ux, uy = math.cos(theta), math.sin(theta)
    wx, wy = p[0] - sec[:, 0], p[1] - sec[:, 1]  # the ray's start seen from the apex
    lo = np.zeros(len(sec))
    hi = np.full(len(sec), math.inf)
    # the disc |w + s·u| ≤ R: s² + 2 b s + c ≤ 0
    b = wx * ux + wy * uy
    c = wx * wx + wy * wy - sec[:, 4] ** 2
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    lo = np.maximum(lo, -b - root)
    hi = np.where(disc >= 0, np.minimum(hi, -b + root), -1.0)
    # the wedge's edges: cross(e_lo, w + s·u) ≥ 0 and cross(w + s·u, e_hi) ≥ 0, each f0 + s·k ≥ 0
    for th, sign in ((sec[:, 2], 1.0), (sec[:, 3], -1.0)):
        ex, ey = np.cos(th), np.sin(th)
        f0 = sign * (ex * wy - ey * wx)
        k = sign * (ex * uy - ey * ux)
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = -f0 / k
        lo = np.where(k > EPS, np.maximum(lo, bound), lo)
        hi = np.where(k < -EPS, np.minimum(hi, bound), hi)
        hi = np.where((np.abs(k) <= EPS) & (f0 < -EPS), -1.0, hi)  # parallel to the edge, outside it
    return np.column_stack([lo, hi])


def covered_distance(p, theta: float, sectors: np.ndarray, shifts=None, gap_m: float = 0.0,
                     start_m: float = 0.0) -> float:
    """How far the ray from p along θ runs through seen-free space without a break: the end of the chain
    of the sectors' stretches that starts at p (0 when p's own neighbourhood along θ was never seen).
    `start_m`: the chain may start this far along the ray — a stretch of the ray inside the vehicle itself, where
    an obstacle would already be a collision (a hovering vehicle a millimetre behind the apexes of the wedges it
    just saw is otherwise outside every one of them).

    `shifts` (n, 2): where each sector's apex is known only to the segment from its apex to apex + shift (a
    sample taken up to a latency before the position it is placed at). A wedge is a translate of a convex
    cone cut by a disc, both convex in the apex, so what every apex on the segment saw is what both ends saw:
    the stretch is the intersection of the two ends' stretches. Stretches closer than `gap_m` are joined (the
    default joins only touching ones)."""
    sec = np.asarray(sectors, float).reshape(-1, 5)
    iv = ray_intervals(p, theta, sec)
    if shifts is not None:
        moved = sec.copy()
        moved[:, :2] += np.asarray(shifts, float).reshape(-1, 2)
        other = ray_intervals(p, theta, moved)
        iv = np.column_stack([np.maximum(iv[:, 0], other[:, 0]), np.minimum(iv[:, 1], other[:, 1])])
    iv = iv[iv[:, 1] > iv[:, 0] + EPS]
    if len(iv) == 0:
        return 0.0
    iv = iv[np.argsort(iv[:, 0])]
    reach = 0.0
    for s0, s1 in iv:
        if s0 > max(reach + gap_m, start_m) + EPS:  # any stretch starting within start_m begins the chain
            break  # a stretch not seen: beyond it nothing counts
        reach = max(reach, float(s1))
    return reach


def sample_sectors(apex, yaw: float, bearings, increment: float, ranges, max_m: float) -> list[tuple]:
    """The free wedges of one bin sample: the bins that report, at body `bearings` (sorted, each
    `increment` wide), seen from `apex` with the vehicle's heading `yaw`. A bin with a hit at r is free
    only to r (what lies behind it was not seen); adjacent free bins of equal radius are one wedge.
    `ranges`: the hit range per bin (inf: none, free to `max_m`)."""
    out: list[list] = []
    half = increment / 2
    for b, r in zip(bearings, ranges):
        radius = min(float(r), max_m)
        if radius <= 0:
            continue
        lo, hi = yaw + b - half, yaw + b + half
        last = out[-1] if out else None
        if last is not None and abs(last[3] - lo) <= 1e-6 and last[4] == radius and hi - last[2] < math.pi - 1e-6:
            last[3] = hi
        else:
            out.append([float(apex[0]), float(apex[1]), lo, hi, radius])
    return [tuple(s) for s in out]
