"""Whether one frame of a sensor looked past a place: the question both the evidence of a late first detection
(detection_range.py) and the clutter rule (estimators.py) ask of the frames before a new return — in a world of
static obstacles, a surface at a place an earlier frame looked past was not there, so what is seen there now is
either no surface or a broken guarantee; and which of a frame's bins are neighbours, one run of an obstacle or a
surface (guidance.py, detection_range.py). Pure maths on one frame: where it was taken from, its bins and hits,
its claim."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from contracts.geometry import wrap


def neighbouring(gap: float, h_a: float, h_b: float) -> bool:
    """Two bins whose centres are `gap` [rad] apart, of half-widths h_a and h_b, are neighbours (one run may hold
    both): at most a bin and a quarter apart."""
    return gap <= 1.25 * (h_a + h_b) + 1e-9


def looked_past(apex: tuple[float, float], yaw: float, bins: Sequence[float] | None, increment: float,
                hits: Iterable[tuple[float, float]], claim: float, places: Iterable[tuple[float, float]], tol: float,
                turn: float = 0.0, interior: bool = False, beam: tuple[float, float] | None = None,
                slack: float = 0.0, apex_m: float = 0.0) -> bool:
    """Whether a frame taken at `apex` (local x, y) heading `yaw` looked past every one of `places` (local x, y):
    each within its `claim` with `tol` to spare, every direction within `turn` [rad] of it inside a bin that
    reported (`bins`: their body bearings, `increment` wide, widened by `slack` for the heading's noise and by the
    bearing `apex_m` of uncertainty in where the frame was taken subtends at the place; an inner one if `interior`;
    None: a single beam, `beam` = (axis, half width)), and none of its `hits` (body bearing, range) there nearer
    than `tol` beyond it."""
    hits = list(hits)
    inner = None if bins is None else (list(bins[1:-1]) if interior else list(bins))
    for x, y in places:
        dx, dy = x - apex[0], y - apex[1]
        d = math.hypot(dx, dy)
        if d + tol > claim:
            return False
        phi = wrap(math.atan2(dy, dx) - yaw)
        wide = slack + math.atan2(apex_m, d)
        if inner is None:  # a single beam: inside its field of view, its one range beyond the place
            if abs(wrap(phi - beam[0])) + turn > beam[1] + wide or any(h <= d + tol for _, h in hits):
                return False
            continue
        if any(abs(wrap(b - phi)) <= turn + increment / 2 and h <= d + tol for b, h in hits):
            return False
        m = 1 + math.ceil(4 * turn / increment)  # directions half a bin apart across phi ± turn
        if not all(any(abs(wrap(phi + turn * (2 * j / m - 1) - b)) <= increment / 2 + wide + 1e-9 for b in inner)
                   for j in range(m + 1)):
            return False
    return True
