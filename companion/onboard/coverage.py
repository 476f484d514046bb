"""Beam coverage of the swept corridor: the detection range `D_od` the configured beams can guarantee.

The navigation guarantee is that an obstacle in the vehicle's way is detected at least `D_od` ahead. Which
obstacles are in the way is set by the swept corridor: along the direction of travel, a band of half-width

    w = r_body + E_tr

about the line of travel through the vehicle (the body's radius, and the tracking error by which the flown
path may stray from that line towards an obstacle). A column of radius r_obst can be touched when its nearest
point is inside that band; that point is also the column's point nearest the line of travel, so the beams see
a threatening column as soon as they reach the band's edge: r_obst widens what is hit, not what must be seen,
and `w` does not include it.

At range r from the sensor the band spans the bearings β ± a(r), a(r) = asin(min(w / r, 1)), β the direction of
travel in the body frame (wide near the vehicle, narrowing with range). The corridor is *covered at r* when
those bearings lie inside the union of the beams whose range reaches r (each beam: its axis ± half its field of
view, out to its range). A beam of half-angle θ pointed along β covers the corridor from w / sin θ out to its
range R; a beam too narrow for the corridor at its own range (R·sin θ < w: a 3° lidar rated 12 m covers
±0.31 m at 12 m) covers it nowhere.

An obstacle approaching from ahead is first seen where its lateral offset first falls inside a beam; it stays
in view while the corridor stays covered on the way in. The D_od the beams guarantee is therefore the far end
of the covered range interval that reaches down nearest the vehicle (the lowest one): further out, a longer
but narrower beam sees an obstacle on the corridor's edge, loses it, and the next beam sees it again only at
its own range — it was, for stopping, first seen there. Nearer than that interval's near end the corridor is
not covered whatever the sensors: an obstacle is first seen before it (the stop has begun, or was not needed)
and the near end is stated (`Cover.lo`).

Pure maths on (axis, field of view, range) triples; angles in degrees at the interface, radians inside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Iterable

TWO_PI = 2 * math.pi
EPS = 1e-9


@dataclass(frozen=True)
class Beam:
    """A sensor as mounted: axis (body yaw, clockwise from forward), full horizontal field of view, range."""

    orientation_deg: float
    h_fov_deg: float
    range_m: float


@dataclass(frozen=True)
class Cover:
    """The lowest range interval [lo, hi] over which the beams cover the corridor of half-width `half_width_m`
    (`covered` False: none; then lo = inf, hi = 0)."""

    lo: float
    hi: float
    half_width_m: float

    @property
    def covered(self) -> bool:
        return self.hi > 0.0 and self.lo <= self.hi


def _wrap(a: float) -> float:
    return (a + math.pi) % TWO_PI - math.pi


def _arcs(beams: Iterable[tuple[float, float]], beta: float) -> list[tuple[float, float]]:
    """The beams' bearing intervals relative to the direction of travel, each also shifted by ±2π (so that a
    wrap-around needs no special case), sorted by start."""
    out = []
    for axis, half in beams:
        if half >= math.pi - EPS:
            return [(-4 * math.pi, 4 * math.pi)]
        c = _wrap(axis - beta)
        out.extend((c - half + k * TWO_PI, c + half + k * TWO_PI) for k in (-1, 0, 1))
    return sorted(out)


def _inside(arcs: list[tuple[float, float]], a: float) -> bool:
    """Whether the bearings [−a, a] lie inside the union of `arcs` (sorted by start)."""
    reach = -a
    for lo, hi in arcs:
        if hi <= reach:
            continue
        if lo > reach + EPS:  # a gap no later arc (starting later still) can close
            return False
        reach = hi
        if reach >= a - EPS:
            return True
    return False


def _covered_at(r: float, beams: tuple, half_width: float, beta: float) -> bool:
    live = [(ax, half) for ax, half, rng in beams if rng >= r - EPS]
    if not live:
        return False
    a = math.asin(min(half_width / r, 1.0)) if r > 0 else math.pi / 2
    return _inside(_arcs(live, beta), a)


@lru_cache(maxsize=4096)
def _cover(beams: tuple, half_width: float, beta: float) -> Cover:
    if not beams or half_width < 0 or not math.isfinite(half_width):
        return Cover(math.inf, 0.0, half_width)
    # coverage changes only at a beam's range, or where the band's edge a(r) crosses a beam's edge
    cuts = {rng for _, _, rng in beams}
    for ax, half, _ in beams:
        for edge in (ax - half, ax + half):
            s = abs(math.sin(_wrap(edge - beta)))
            if s > EPS and abs(_wrap(edge - beta)) < math.pi / 2 and half_width > 0:
                cuts.add(half_width / s)
    top = max(rng for _, _, rng in beams)
    pts = sorted(c for c in cuts if 0 < c <= top + EPS)
    pieces, prev = [], 0.0  # (probe, lower end, upper end): each open stretch between cuts, then the cut
    for c in pts:
        pieces += [((prev + c) / 2, prev, c), (c, c, c)]
        prev = c
    lo = hi = None
    for r, below, above in pieces:
        if _covered_at(r, beams, half_width, beta):
            lo = below if lo is None else lo
            hi = above
        elif lo is not None:
            break
    return Cover(math.inf, 0.0, half_width) if lo is None else Cover(lo, hi, half_width)


BETA_STEP = 1e-3  # [rad] the direction of travel is rounded to this (the cache's key) ...
WIDTH_STEP = 0.01  # [m] ... and the half-width rounded up to this, after widening it by what that rounding moves


def corridor_cover(beams: Iterable[Beam], half_width_m: float, beta: float = 0.0, grid: bool = False) -> Cover:
    """The lowest range interval over which `beams` together cover the swept corridor of half-width
    `half_width_m` (= r_body + E_tr) along body bearing `beta` [rad] (module docstring). Cached; with `grid`
    (the daemon's every cycle, where E_tr and the direction of travel vary continuously) on a grid that errs on
    the safe side: `beta` rounded to BETA_STEP moves the corridor's edge at range r by at most r·BETA_STEP/2, so
    the half-width is widened by that at the longest range, then rounded up to WIDTH_STEP (the cover of a wider
    corridor is never longer)."""
    key = tuple(sorted((round(math.radians(b.orientation_deg), 9), round(math.radians(b.h_fov_deg) / 2, 9),
                        math.floor(float(b.range_m) * 1e6) / 1e6)  # (a range never rounded up)
                       for b in beams if 0 < b.range_m < math.inf and b.h_fov_deg > 0))
    if not key or not math.isfinite(half_width_m) or not math.isfinite(beta):
        return Cover(math.inf, 0.0, half_width_m)
    if not grid:
        return _cover(key, round(float(half_width_m), 9), round(float(beta), 9))
    wide = half_width_m + max(r for _, _, r in key) * BETA_STEP / 2
    w = math.ceil(round(wide / WIDTH_STEP, 6)) * WIDTH_STEP
    return _cover(key, round(w, 6), round(round(beta / BETA_STEP) * BETA_STEP, 9))


def covered_d_od(beams: Iterable[Beam], half_width_m: float, beta: float = 0.0, grid: bool = False) -> float:
    """`D_od` the beams guarantee for the corridor: the far end of the lowest covered interval (0: covered
    nowhere)."""
    c = corridor_cover(beams, half_width_m, beta, grid)
    return c.hi if c.covered else 0.0


def half_width(r_body_m: float, e_tr_m: float) -> float:
    """The swept corridor's half-width the beams must cover: w = r_body + E_tr."""
    return r_body_m + e_tr_m


def beams_of(sensors) -> list[Beam]:
    """The configured sensors as beams at their rated range (a sensor without one counts as covering
    nothing: its claims are not taken)."""
    return [Beam(s.orientation_deg, s.h_fov_deg, s.max_range_m) for s in sensors if s.max_range_m]


def banner_line(sensors, r_body_m: float, e_tr_m: float) -> str:
    """The start banner's line: where the configured sensors cover the corridor along the heading, at the least
    E_tr assumed (a larger E_tr in flight widens it: D_od is then the cover of that wider corridor)."""
    w = half_width(r_body_m, e_tr_m)
    what = f"the swept corridor ±{w:.2f} m (r_body {r_body_m:g} m + E_tr {e_tr_m:g} m)"
    beams = beams_of(sensors)
    if not beams:
        return f"sensor coverage: no rated sensor: {what} is not known to be covered"
    c = corridor_cover(beams, w)
    if not c.covered:
        return f"sensor coverage: {what} is covered at NO range: D_od is 0, no speed is safe"
    top = max(b.range_m for b in beams)
    cap = "" if c.hi >= top else f" (not the {top:g} m of the longest sensor: beyond {c.hi:g} m the beams are too narrow)"
    return (f"sensor coverage: {what} is covered by the beams from {c.lo:.2f} m out to {c.hi:g} m: D_od at most "
            f"{c.hi:g} m{cap}")


def refusal(sensors, r_body_m: float, e_tr_m: float) -> str | None:
    """Why a set-up cannot cover the corridor anywhere (one line naming each sensor, its width and the
    corridor), or None. Along the heading (β = 0), at the least E_tr the daemon assumes."""
    w = half_width(r_body_m, e_tr_m)
    beams = beams_of(sensors)
    if not beams or corridor_cover(beams, w).covered:
        return None
    each = "; ".join(f"sensors[{k}] {s.h_fov_deg:g}° wide, rated {s.max_range_m:g} m, covers "
                     f"±{s.max_range_m * math.sin(math.radians(min(s.h_fov_deg, 180) / 2)):.2f} m at its range"
                     for k, s in enumerate(sensors) if s.max_range_m)
    return (f"the sensors cannot cover the swept corridor ±{w:.2f} m (r_body {r_body_m:g} m + E_tr {e_tr_m:g} m) at "
            f"any range: {each}; an obstacle at the corridor's edge would never be seen (a wider sensor, or more)")
