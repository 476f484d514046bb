"""Late first detections, confirmed before they are declared.

The navigation subsystem guarantees that every obstacle within `D_od` that reaches the swept corridor is detected
(DESIGN.md §1; the `D_od` of the paper's contract Γ, eq. (1), and of the stop distance). A return first seen
inside the assumed `D_od` says two things, and they need different evidence:

- *something is there*: the return is an obstacle from the frame it is first seen in. It goes to the obstacle logic
  at once (the stop contract's hold, the planner's keep-out disc, the recovery brake) whatever this module decides
  — except within its sensor's own clutter (below);
- *the sensor sees less far than it claims* (the navigation guarantee broken): `D_od` is lowered for the
  late-detection hold time and a navigation violation is said. One frame cannot show that. A real surface first
  seen late is static (the contract's assumption) and stays in the beam: it is seen again in every following
  frame that looks at its place, nearer by the travel between frames. A spurious close return (a propeller in view,
  rain, dust) is drawn anew in every frame at a random range: two or three in a row at one place are as unlikely
  as the product of their per-frame chances.

So a candidate is declared only once the sensor (the same source of it) has seen a return at a consistent place in
`frames` following frames (`ContractConfig.late_detection_confirm_frames`). A frame that looks at the candidate's
place and sees nothing consistent there ends it; a frame that does not look there (a bin that reported nothing, the
place outside the field of view) neither confirms nor ends it, until the sensor's time-out; nor does a frame below
its sensor's `min_quality`, which is no reading (a fog's weak return in front of a surface hides it in that frame, and
the medium's returns, weak and near, come anew in every frame: in fog a single beam's nearest return is the medium's in
about half its frames, and three of them in a row at one place would confirm each other as a surface). The rule
delays the *declaration* by `frames` frames (at 20 Hz and 2 frames, 0.1 s) and cannot hide a real late detection: a
static surface inside `D_od` and in the field of view is in each following frame, and the declaration keeps the range
and time of its first sight. With `frames` 0 every first sight is declared at once.

**Within a sensor's clutter** (`sensors[k].clutter_m`: the reach of its own spurious returns) a return that is a
late first detection, or that comes where one of the sensor's recent frames looked past (no static surface can be
there), is a candidate too — confirmed, a surface where the sensor had looked past is a broken guarantee, declared
as a late first detection is — and its returns are withheld from the obstacle logic until it is confirmed (`Followed.waiting`), never from what the sensor saw free,
which stops short of them. What is withheld is what the navigation guarantee excludes: a static obstacle within
`D_od` is first seen at `D_od`, or comes in from the side or from behind another, and reaches the obstacle logic in
the frame it is seen. One first seen inside the clutter where the sensor had just seen free is a broken guarantee,
declared, and held for `frames` frames after its first sight (at 30 Hz and 2 frames, 67 ms).

A "consistent place": where the candidate's last sight would be seen now, the vehicle's own motion and turn
accounted for (its place in the local frame, seen from the vehicle's pose now; its last bearing and range where a
pose is missing) — in the bin that covers that bearing or the one beside it (a single beam: its one beam), and
within the late-detection tolerance (which holds one frame's travel) of that range, or where two readings of one
surface fall further apart by the sensor's range noise alone (a stereo camera's σ is 0.36 m at 6 m), within that.
Close to the sensor a bin is narrow in metres: a distance in the local frame alone would let returns in bins far
apart at short range match.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from contracts.geometry import wrap


@dataclass(frozen=True)
class LateDetection:
    """A navigation guarantee broken: an obstacle first seen inside the assumed D_od, within the FOV."""

    t: float  # when it was first seen
    sensor: int
    bearing: float  # body frame, at its first sight
    range_m: float  # where it first appeared
    assumed_d_od: float  # what the estimate promised just before


@dataclass
class Candidate:
    """A return first seen inside D_od, not yet confirmed: its first sight, its last, and the points it was placed
    at (local frame (x, y, ±); None where no pose was known)."""

    first: LateDetection
    source: object
    bearing: float  # body frame, at its last sight
    range_m: float  # at its last sight
    t_last: float
    point: tuple[float, float, float] | None
    points: list = field(default_factory=list)
    seen_again: int = 0  # frames since the first that saw it again


@dataclass(frozen=True, slots=True)
class Frame:
    """One sample of one sensor, as the confirmation reads it: its hits (body bearing, range) and where each is
    placed (None: no pose), the bins it reported (None: a single beam) and their width, and the tolerance of a
    first sight (the late-detection tolerance plus one frame's travel), and whether its quality is trusted."""

    t: float
    sensor: int
    source: object
    hits: list
    placed: list
    known: tuple[float, ...] | None
    increment: float
    tolerance: float
    trusted: bool = True  # its signal quality at least its sensor's min_quality


@dataclass(frozen=True, slots=True)
class Followed:
    """What one frame did to the candidates: those it confirmed, the hits it used to follow candidates (indices into
    the frame's hits: not first sights of their own, not yet tracked obstacles), and the body bearings of candidates
    it ended (a hit in such a bin now is not "the same as before")."""

    confirmed: tuple[Candidate, ...]
    used: frozenset[int]
    ended: tuple[float, ...]
    waiting: frozenset[int] = frozenset()  # of `used`, the hits of candidates still waiting: withheld


def seen_from(c: Candidate, pose: tuple[float, float, float] | None) -> tuple[float, float]:
    """The body bearing and range at which a frame taken at `pose` (local x, y, heading; None: unknown) sees
    candidate `c`'s place: from that pose where it and the place are known, else where it was last seen."""
    if c.point is None or pose is None:
        return c.bearing, c.range_m
    dx, dy = c.point[0] - pose[0], c.point[1] - pose[1]
    return wrap(math.atan2(dy, dx) - pose[2]), math.hypot(dx, dy)


class Confirmations:
    """The candidates of every sensor awaiting confirmation (module docstring). Pure: frames in, declarations out."""

    def __init__(self, frames: int, stale_s: float, spread=lambda r: 0.0):
        """`frames`: the following frames that must see a candidate again (0: declared at once); `stale_s`: the
        sensors' time-out, the longest a candidate waits for a frame that looks at its place; `spread(r)`: how far
        apart two readings of one surface at range r fall by the sensor's noise alone [m] (`RangeNoise.spread_m`)."""
        self.frames = max(int(frames), 0)
        self.stale_s = stale_s
        self.spread = spread
        self._open: list[Candidate] = []

    @property
    def waiting(self) -> tuple[Candidate, ...]:
        return tuple(self._open)

    def offer(self, first: LateDetection, source, point) -> Candidate | None:
        """A first sight inside D_od, or a return where a recent frame looked past: the candidate, already confirmed
        when no following frame is asked for (None: it waits for `follow`)."""
        c = Candidate(first, source, first.bearing, first.range_m, first.t, point, [point] if point is not None else [])
        if self.frames == 0:
            return c
        self._open.append(c)
        return None

    def follow(self, f: Frame, where) -> Followed:
        """Match the frame's hits against the sensor's candidates of the same source. `where(candidate)`: the body
        bearing and range at which this frame would see the candidate's place."""
        confirmed, used, ended, keep, waiting = [], set(), [], [], set()
        for c in self._open:
            if c.first.sensor != f.sensor or c.source != f.source or not f.trusted:
                if f.t - c.t_last <= self.stale_s:
                    keep.append(c)
                continue
            bearing, rng = where(c)
            k = self._match(f, bearing, rng, max(f.tolerance, self.spread(rng)), used)
            if k is not None:
                used.add(k)
                c.seen_again += 1
                c.bearing, c.range_m, c.t_last, c.point = f.hits[k][0], f.hits[k][1], f.t, f.placed[k]
                if f.placed[k] is not None:
                    c.points.append(f.placed[k])
                if c.seen_again >= self.frames:
                    confirmed.append(c)
                else:
                    keep.append(c)
                    waiting.add(k)
            elif self._looks(f, bearing) or f.t - c.t_last > self.stale_s:
                ended.append(c.bearing)
            else:
                keep.append(c)
        self._open = keep
        return Followed(tuple(confirmed), frozenset(used), tuple(ended), frozenset(waiting))

    @staticmethod
    def _looks(f: Frame, bearing: float) -> bool:
        """Whether the frame looked along body `bearing`: a single beam always; bins when one that reported covers
        it."""
        return f.known is None or any(abs(wrap(bearing - b)) <= f.increment / 2 + 1e-9 for b in f.known)

    @staticmethod
    def _match(f: Frame, bearing: float, rng: float, tol: float, used: set) -> int | None:
        """The hit of `f` at a consistent place (module docstring) with a candidate expected at body `bearing` and
        range `rng`, within `tol` of it (the nearest in range of such), or None."""
        best, best_d = None, math.inf
        for k, (b, r) in enumerate(f.hits):
            d = abs(r - rng)
            same_bin = f.known is None or abs(wrap(b - bearing)) <= f.increment + 1e-9
            if k not in used and same_bin and d <= tol and d < best_d:
                best, best_d = k, d
        return best
