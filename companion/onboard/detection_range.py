"""The navigation guarantee `D_od` from evidence, not from the sensor's word (the paper's C_N(t) assessed in
flight). Pure: injected time, no I/O; fed with the samples the daemon already decodes (`Scan`, position,
heading).

A range sensor in fog, haze or dust does not lower the range it states: it stops seeing. What it cannot hide
is the physics of the medium (contracts/lidar.py: Koschmieder's extinction α, the lidar equation's
ρ·e^(−2αR)/R² against the receiver's threshold, the medium's own returns). The estimator reads four kinds
of evidence and turns each into an upper bound on the range at which the reference target (reflectivity
`reference_reflectivity`: the darkest obstacle the contract is to see) is still detected:

1. backscatter rate — the fraction of reports (bins × frames, or a single beam's frames) with a short return
   (< `near_m`) that is the medium's: no tracked target accounts for it (a surface near the sensor was first
   seen farther away and followed in), it does not stay put for `confirm_frames` frames in a row, and it is not
   one of a run of adjacent bins at ranges a surface gives (`surface_bins`: a wall swept into view by a turn). Each
   report is the nearest of the shots its sensor's frame gathers, shared by its reports (`shots_of`: the
   configured `shots_per_frame`, else one shot per report — a bin one shot, a single beam's frame one shot,
   the conservative reading for a beam that gathers several). A sensor's own spurious returns (a propeller in
   view, rain at the lens: `spurious_rate` of its reports in clear air, configured) come at the same ranges: a
   window's count they would reach with a probability above `OWN_RETURNS_P` (Poisson) is no evidence, and
   beyond it their expected number is taken off. The fraction over the last `window_s`, one
   standard error up (when unsure, the thicker fog), becomes a per-shot rate p by q = 1 − (1 − p)^shots and
   is inverted to α by p = 1 − e^(−α·L_bs) (`backscatter_length_m`, the sensor's, measured on one fog
   flight) — the law the SITL draws per bin and frame. A haze is not a fog: the medium lowers D_od only on evidence that it can —
   the last window's rate itself, or the rate over the longer `rate_window_s` one standard error up, giving at
   least α₀, the extinction at which the reference target's range is the claim (`extinction_for_range`);
   below it no range is shortened, and the few returns of a haze that happen to fall in one second, one
   standard error up, would read as fog. With that evidence, α is the last window's, one standard error up, as
   above. This is evidence for D_od only: the obstacle logic takes every return, these included (`add_scan`);
2. signal-quality trend — a single beam's quality is the strength of the return it reports; while one
   tracked target is approached, ln(margin) + 2 ln R falls linearly with R at slope −2α in a medium and is
   flat in clear air, whatever the target's reflectivity (it cancels). The margin is read from the quality
   with the driver's normalisation (`quality_full_margin`: quality 100 at that margin, 0 at threshold);
3. first detections — a static target (placed in the local frame from position and heading) first seen
   inside the stated range by more than its range noise allows (`NOISE_SIGMAS` σ of the configured noise),
   away from the field of view's edges, where one of the sensor's frames of the last
   `look_back_s` saw through its place — all of its bin's arc at its range — (the bins looking at it from where
   that frame was taken reported free, or a return beyond it, and that frame's stated range reached it), was not
   detectable farther: D_od ≤ that
   distance. A place no recent frame saw through is no evidence: a target behind a nearer one (occluded), outside
   the field of view then (a turn, a wall's end, a doorway's side), in a bin that reported nothing, beyond the
   claim of the frame (a fog lifting: the stated range just grew), or in the sensor's first frame. Such a sight
   counts once `first_confirm_frames` following frames see it again at its place (late_detection.py): a draw of
   a stereo camera's range noise 4 σ short of a wall near its claim is gone in the next frame, a surface stays;
4. disagreement — a point one sensor sees that another, looking the same way and claiming a longer range,
   does not see at the same time: that one's range is at most its distance.

(1) and (2) give α̂ (the larger, held for `recover_s`), and D_medium = the reference target's detection
range through α̂ (R·e^(α̂R) = R0, R0 = stated·√(ρ_ref/ρ_rated)); (3) and (4) are held for `recover_s`.
`D_od = min(stated, cap, D_medium, first detections, disagreements)`: never above the stated range or the
config's cap.

Timing (the defaults): a fog is taken into account within `window_s` (1 s) of its onset once its
backscatter gives `min_spurious` (3) short returns in a window and the window's rate reaches α₀ (a 10 m
sensor's reference range shortens only from α = 0.08/m: 6 returns in a second of a 12-bin sensor at 20 Hz);
a late first detection
`first_confirm_frames` frames after its first sight. The estimate recovers `window_s + recover_s` (4 s) after the
evidence clears. What it cannot see: a
medium that thickens faster than that (from clear to dense between two windows) is seen one window late, and
between two targets nothing but backscatter and quality tell of the medium (docs/detection-range.md).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from contracts.geometry import wrap
from contracts.lidar import (
    BACKSCATTER_LENGTH_M,
    QUALITY_FULL_MARGIN,
    RATED_REFLECTIVITY,
    REFERENCE_REFLECTIVITY,
    detection_range,
    extinction_for_range,
    extinction_from_backscatter,
    per_shot_from_reports,
)
from contracts.window import WindowMax

from .config import SensorConfig
from .late_detection import Candidate, Confirmations, Frame, LateDetection, seen_from
from .samples import Scan
from .sight import looked_past, neighbouring

NOISE_SIGMAS = 3.0  # a first sighting this many σ of range noise short of the stated range is still on time


def surface_bins(hits, increment: float | None, near_m: float, run: int, step_m: float) -> set[int]:
    """The indices of `hits` (bearing, range), nearer than near_m, that lie in a run of `run` or more adjacent bins
    (bearings one `increment` apart) whose ranges each differ from the next by at most step_m: a surface. The
    medium's returns come in a bin each, at ranges spread over a metre (contracts/lidar.py OVERLAP_M): of the SITL's
    draws (12 bins), three in a row within 0.2 m are 0.05 % of its short returns at α₀ of a 10 m sensor (0.08/m),
    0.3 % at 0.3/m, 2 % at 1/m (a 3 m visibility) — evidence a dense fog can spare."""
    if not increment:
        return set()
    near = sorted((b, r, k) for k, (b, r) in enumerate(hits) if r < near_m)
    out, cur = set(), []
    for b, r, k in near:
        if cur and neighbouring(b - cur[-1][0], increment / 2, increment / 2) and abs(r - cur[-1][1]) <= step_m:
            cur.append((b, r, k))
        else:
            out |= {c[2] for c in cur} if len(cur) >= run else set()
            cur = [(b, r, k)]
    return out | ({c[2] for c in cur} if len(cur) >= run else set())


@dataclass(frozen=True)
class RangeNoise:
    """The sensors' range noise as configured (`detection.range_noise_*`): 1 σ(r) = m + rel·r + quad·r² (a stereo
    camera's grows with the square of the depth)."""

    m: float = 0.03
    rel: float = 0.01
    quad: float = 0.0

    @classmethod
    def of(cls, detection) -> "RangeNoise":
        return cls(detection.range_noise_m, detection.range_noise_rel, detection.range_noise_quad_per_m)

    def short_m(self, r: float) -> float:
        """[m] how far short of range r a target reads by noise alone: NOISE_SIGMAS σ(r)."""
        return NOISE_SIGMAS * (self.m + self.rel * r + self.quad * r * r)

    def spread_m(self, r: float) -> float:
        """[m] how far apart two readings of one surface at range r fall by noise alone: NOISE_SIGMAS σ of their
        difference (√2 σ(r))."""
        return math.sqrt(2.0) * self.short_m(r)


OWN_RETURNS_P = 1e-6  # a window's short returns the sensors' own would reach this seldom are evidence of a medium
FULL_WINDOW_SHOTS_PER_S = 160.0  # shots per second behind a confidence of 1 (a 12-bin sensor at 20 Hz gives 240)


@dataclass(frozen=True)
class DetectionRangeParams:
    window_s: float = 1.0  # evidence window (backscatter rate, quality trend)
    rate_window_s: float = 4.0  # the backscatter rate's longer window, that tells a haze (the module docstring's (1))
    recover_s: float = 3.0  # a bound below the stated range is held this long after its evidence clears
    near_m: float = 2.0  # returns nearer than this are checked for the medium's (backscatter)
    confirm_m: float = 0.08  # a short return within this (+ its bin's width) of one in each of the last frames...
    confirm_frames: int = 4  # ... of this many in a row: a surface
    surface_run: int = 3  # short returns in this many adjacent bins or more, each within surface_step_m of the next...
    surface_step_m: float = 0.2  # ...: a surface (the medium's come one per bin, at ranges of their own)
    min_reports: int = 20  # reports in the window before the backscatter rate counts (a single beam at 20 Hz: 1 s)
    min_spurious: int = 3  # spurious short returns in the window before the rate counts
    backscatter_length_m: float = BACKSCATTER_LENGTH_M  # the sensor's L_bs (contracts/lidar.py)
    rated_reflectivity: float = RATED_REFLECTIVITY  # the target its stated range is rated at
    reference_reflectivity: float = REFERENCE_REFLECTIVITY  # the darkest obstacle D_od is for
    quality_full_margin: float = QUALITY_FULL_MARGIN  # margin over threshold at which signal quality is 100
    trend_samples: int = 5  # quality samples of one target before its trend counts
    trend_span_m: float = 1.0  # ... spanning at least this much range
    track_m: float = 1.0  # a hit within this (+ the bin's width at its range) of a tracked point: the same target
    first_tolerance_m: float = 0.3  # first seen this much inside the stated range (+ one frame's travel ...
    range_noise: RangeNoise = RangeNoise()  # ... + NOISE_SIGMAS of the range noise σ(r)): late
    look_back_s: float = 0.5  # ... and a frame this recent saw through its place
    first_confirm_frames: int = 2  # ... once this many following frames see it again (a noise draw is gone in the next)
    fresh_s: float = 0.5  # a sensor silent longer adds nothing (staleness is the other estimator's)

    @classmethod
    def of(cls, detection, confirm_frames: int = 2) -> "DetectionRangeParams":
        """The parameters a config's `detection:` section sets (companion/onboard/config.py DetectionConfig), and the
        contract's `late_detection_confirm_frames`."""
        return cls(reference_reflectivity=detection.reference_reflectivity,
                   rated_reflectivity=detection.rated_reflectivity,
                   backscatter_length_m=detection.backscatter_length_m, range_noise=RangeNoise.of(detection),
                   first_confirm_frames=confirm_frames)


@dataclass(frozen=True, slots=True)
class DetectionRangeEstimate:
    d_od: float  # the detection range the evidence allows [m] (≤ stated, ≤ cap)
    stated_m: float  # the range the sensors claim (the input)
    confidence: float  # 0–1: the shots of the last window behind the figure over FULL_WINDOW_SHOTS_PER_S's
    alpha: float  # the medium's extinction α̂ [1/m] in force (0: none seen)
    reason: str  # which evidence sets d_od
    evidence: dict = field(default_factory=dict)  # each bound [m] (inf: none) and the counts behind them


@dataclass
class _Frame:
    t: float
    sensor: int
    reports: int  # the frame's reports (bins that report, or one for a single beam)
    per: float  # the shots behind each report (`shots_of`)
    near: list  # (x, y) of short returns (local frame, or body frame without a pose) on no tracked target
    own: float = 0.0  # the sensor's own spurious returns expected among them (reports × `spurious_rate`)


@dataclass(frozen=True)
class _View:
    """What one frame of bins looked at: from where (local frame), the bins that reported (body bearings), its hits
    (body bearing, range), the claim."""

    t: float
    x: float
    y: float
    yaw: float
    bearings: tuple
    hits: tuple
    increment: float
    stated: float

    def saw_through(self, places, tol: float) -> bool:
        """Whether this frame looked at every one of `places` (local x, y) from an inner bin, within its claim, and
        saw more than `tol` past it (`sight.looked_past`)."""
        return looked_past((self.x, self.y), self.yaw, self.bearings, self.increment, self.hits, self.stated,
                           places, tol, interior=True)


@dataclass
class _Track:
    x: float
    y: float
    t_first: float
    t_last: float
    reach: float = 0.0  # a return this close is on it (0: the parameters' track_m)
    samples: deque = field(default_factory=lambda: deque(maxlen=40))  # (range, margin) from quality


class DetectionRange:
    """D_od from evidence. Feed `add_position`, `add_heading` and `add_scan` as samples arrive; ask
    `estimate(t, stated_m)` once per cycle with the range the sensors claim (the D_od the claim gives)."""

    def __init__(self, sensors: list[SensorConfig], cap_m: float | None = None,
                 params: DetectionRangeParams = DetectionRangeParams()):
        """`params`: `DetectionRangeParams.of(cfg.detection)` for a config's."""
        self.sensors, self.cap_m, self.p = sensors, cap_m, params
        self._pos: tuple[float, float, float] | None = None  # (t, x, y)
        self._speed = 0.0
        self._yaw: tuple[float, float] | None = None  # (t, yaw)
        self._frames: deque[_Frame] = deque()  # the frames of the last rate_window_s (`_window`)
        self._near_frames: deque[_Frame] = deque()  # those of them with short returns, in the same order
        self._tracks: list[_Track] = []
        self._alphas = WindowMax(params.recover_s)  # α̂ of the last recover_s
        self._bounds: deque[tuple[float, float, str]] = deque()  # (t, bound m, why): first detections, disagreements
        self._last_hits: dict[int, tuple[float, float, list]] = {}  # sensor → (t, its stated m, [(x, y, r)])
        self._stated: dict[int, float] = {}
        self._near_hist: dict[int, deque] = {}  # sensor → the short returns (x, y) of its last frames
        self._views: dict[int, deque] = {}  # sensor → its frames of bins of the last look_back_s (`_View`)
        # late first sights awaiting the following frames that see them again (companion/onboard/late_detection.py)
        self._late = Confirmations(params.first_confirm_frames, params.fresh_s, params.range_noise.spread_m)

    # ---------------------------------------------------------------- inputs
    def add_position(self, t: float, x: float, y: float) -> None:
        if math.isfinite(x) and math.isfinite(y):
            if self._pos is not None and t > self._pos[0]:
                self._speed = math.hypot(x - self._pos[1], y - self._pos[2]) / (t - self._pos[0])
            self._pos = (t, x, y)

    def add_heading(self, t: float, yaw: float) -> None:
        if math.isfinite(yaw):
            self._yaw = (t, yaw)

    def _posed(self, t: float) -> bool:
        """Position and heading known and fresh at `t`."""
        p = self.p
        return self._pos is not None and self._yaw is not None and t - self._pos[0] <= p.fresh_s \
            and t - self._yaw[0] <= p.fresh_s

    def _place(self, t: float, bearing: float, r: float) -> tuple[float, float]:
        """A hit in the local frame (the body frame when position or heading is unknown or stale)."""
        if not self._posed(t):
            return r * math.cos(bearing), r * math.sin(bearing)
        a = self._yaw[1] + bearing
        return self._pos[1] + r * math.cos(a), self._pos[2] + r * math.sin(a)

    def add_scan(self, scan: Scan) -> tuple[int, ...]:
        """One sensor's sample (companion/onboard/samples.py), as evidence. Returns the indices in `scan.hits` of the
        returns counted as the medium's: the short returns that no tracked target accounts for and that
        `confirm_frames` consecutive frames do not confirm at the same place.

        Nothing is taken out of the scan: the obstacle logic takes it whole. A close return is an obstacle until
        shown otherwise, and no rule can show it in its first frame: the medium's return is a new one in every
        shot, as a surface's is in the frame it first appears, so waiting for frames to tell them apart withholds
        that surface for those frames (3 at 20 Hz: 0.3 m at 2 m/s). The medium may lower D_od; it never hides a
        return. An invalid scan (quality 1) adds nothing."""
        p, i, t = self.p, scan.sensor, scan.t
        if scan.quality == 1 or scan.max_m <= 0.0:
            return ()
        stated = scan.max_m
        before = self._stated.get(i, stated)  # the claim of the sensor's last frame
        self._stated[i] = stated
        reports = len(scan.known) if scan.known is not None else 1
        placed = [(*self._place(t, b, r), b, r) for b, r in scan.hits]
        near, medium, now = [], [], []
        hist = self._near_hist.get(i)
        if hist is None:
            hist = self._near_hist[i] = deque(maxlen=max(p.confirm_frames - 1, 0))
        surface = surface_bins(scan.hits, scan.increment, p.near_m, p.surface_run, p.surface_step_m) \
            if scan.known is not None else set()
        for k, (x, y, _, r) in enumerate(placed):
            if r >= p.near_m:
                continue
            tr = self._nearest_track(x, y)
            reach = p.confirm_m + r * (scan.increment or 0.0)
            now.append((x, y))
            if tr is not None:  # a tracked target come close (not moved: the medium's returns near it must not drag it)
                tr.t_last = t
            elif len(hist) == hist.maxlen and all(any(math.hypot(x - a, y - b) <= reach for a, b in pts) for pts in hist):
                self._tracks.append(_Track(x, y, t, t, 2.0 * reach))  # a surface close by, seen frame after frame
            elif k not in surface:  # (a surface across adjacent bins: a wall a turn sweeps into view is new each frame)
                near.append((x, y))
                medium.append(k)
        hist.append(now)
        own = reports * getattr(self.sensors[i] if i < len(self.sensors) else None, "spurious_rate", 0.0)
        frame = _Frame(t, i, reports, self.shots_of(i, reports), near, own)
        self._frames.append(frame)
        if near:
            self._near_frames.append(frame)
        if scan.known is None and placed:  # a single beam: the target it follows in (and its quality, the return's)
            x, y, _, r = min(placed, key=lambda h: h[3])
            if r >= p.near_m:
                tr = self._track(t, x, y, r, scan.increment)
                if 2 <= scan.quality < 100:
                    tr.samples.append((r, 1.0 + scan.quality / 100.0 * (p.quality_full_margin - 1.0)))
        if scan.known is not None:
            self._follow_late(t, i, scan, placed)
            # a target is late only if the last frame's claim, too, reached it (a claim that just grew, as a fog
            # clears, does not make a target at its old edge late)
            self._first_detections(t, i, scan, placed, min(stated, before))
            self._remember_view(t, i, scan, stated)
        self._disagreements(t, i, scan, placed, stated)
        self._last_hits[i] = (t, stated, [(x, y, r) for k, (x, y, _, r) in enumerate(placed) if k not in medium])
        return tuple(medium)

    def shots_of(self, i: int, reports: int) -> float:
        """The shots behind each of a frame's `reports` from sensor i: its configured `shots_per_frame` shared by
        them (at least one each), else one."""
        cfg = self.sensors[i] if i < len(self.sensors) else None
        spf = getattr(cfg, "shots_per_frame", None)
        return max(1.0, spf / max(reports, 1)) if spf else 1.0

    def _nearest_track(self, x: float, y: float) -> _Track | None:
        near = [(math.hypot(x - tr.x, y - tr.y), k) for k, tr in enumerate(self._tracks)]
        near = [(d, k) for d, k in near if d <= (self._tracks[k].reach or self.p.track_m)]
        return self._tracks[min(near)[1]] if near else None

    def _track(self, t: float, x: float, y: float, r: float, increment: float | None) -> _Track:
        reach = self.p.track_m + (r * (increment or 0.0) if increment else 0.0)
        for tr in self._tracks:
            d = math.hypot(x - tr.x, y - tr.y)
            if d <= reach:  # the same static target: its points stay where they were seen (a wide one is not
                tr.t_last = t  # dragged to its last hit, away from its other side), and its extent is added
                if d > self.p.track_m / 2.0:
                    self._tracks.append(_Track(x, y, t, t))
                return tr
        tr = _Track(x, y, t, t)
        self._tracks.append(tr)
        return tr

    def _remember_view(self, t: float, i: int, scan: Scan, stated: float) -> None:
        """Keep what this frame of bins looked at (a frame without a fresh pose is kept by none)."""
        views = self._views.setdefault(i, deque())
        while views and views[0].t < t - self.p.look_back_s:
            views.popleft()
        if not self._posed(t) or not scan.known:
            return
        views.append(_View(t, self._pos[1], self._pos[2], self._yaw[1], tuple(scan.known), tuple(scan.hits),
                           scan.increment or 0.0, stated))

    def _seen_through(self, i: int, places, tol: float) -> bool:
        """Whether one of the sensor's recent frames saw through every one of `places` (`_View.saw_through`)."""
        return any(v.saw_through(places, tol) for v in self._views.get(i, ()))

    def _period(self, i: int) -> float:
        """Sensor i's frame interval: its last two frames' (1/20 s before it has two)."""
        same = [f.t for f in self._frames if f.sensor == i][-2:]
        return max(same[1] - same[0], 1e-3) if len(same) == 2 else 1.0 / 20.0

    def _first_detections(self, t: float, i: int, scan: Scan, placed: list, stated: float) -> None:
        """Static targets first seen inside the stated range, away from the edges of the field of view, where a
        recent frame saw through their place (module docstring, 3)."""
        p = self.p
        inc = scan.increment or 0.0
        lo, hi = (scan.known[0], scan.known[-1]) if scan.known else (0.0, 0.0)
        period = self._period(i)
        for x, y, b, r in placed:
            if r < p.near_m:
                continue  # the medium's returns are the backscatter evidence
            # a tracked target read short by its range noise is still that target
            reach = p.track_m + r * inc + p.range_noise.short_m(r)
            known = any(math.hypot(x - tr.x, y - tr.y) <= reach for tr in self._tracks)
            self._track(t, x, y, r, inc)
            edge = min(abs(wrap(b - lo)), abs(wrap(b - hi))) <= inc * 1.01
            # a target at the stated range reads up to NOISE_SIGMAS σ(stated) short of it by noise alone
            tol = p.first_tolerance_m + self._speed * period + p.range_noise.short_m(stated)
            # the return may come from anywhere across its bin: its place is the bin's arc at r, all of it seen through
            arc = [self._place(t, b + k * inc / 2, r) for k in (-1, 0, 1)]
            if not known and not edge and r < stated - tol and self._seen_through(i, arc, tol):
                c = self._late.offer(LateDetection(t, i, b, r, stated), None, (x, y) if self._posed(t) else None)
                if c is not None:
                    self._first_seen(t, c)

    def _follow_late(self, t: float, i: int, scan: Scan, placed: list) -> None:
        """The late first sights this frame sees again at their place (companion/onboard/late_detection.py: a range
        noise draw is gone in the next frame, a surface stays), those seen often enough bound D_od at the range of
        their first sight."""
        posed = self._posed(t)
        pose = (self._pos[1], self._pos[2], self._yaw[1]) if posed else None
        tol = self.p.first_tolerance_m + self._speed * self._period(i)
        trusted = self.sensors[i].trusts(scan.quality) if i < len(self.sensors) else True
        frame = Frame(t, i, None, list(scan.hits), [(x, y) if posed else None for x, y, _, _ in placed],
                      tuple(scan.known), scan.increment or 0.0, tol, trusted)
        for c in self._late.follow(frame, lambda c: seen_from(c, pose)).confirmed:
            self._first_seen(t, c)

    def _first_seen(self, t: float, c: Candidate) -> None:
        """A late first sight confirmed: D_od ≤ the range it was first seen at."""
        r = c.first.range_m
        self._bounds.append((t, r, f"a target first seen at {r:.2f} m"))

    def _disagreements(self, t: float, i: int, scan: Scan, placed: list, stated: float) -> None:
        """A point another sensor sees now, inside this one's stated range and field of view, unseen here."""
        p = self.p
        cfg = self.sensors[i] if i < len(self.sensors) else None
        if cfg is None or self._pos is None or self._yaw is None:
            return
        for j, (tj, _, hits) in self._last_hits.items():
            if j == i or t - tj > 0.1:
                continue
            for x, y, _ in hits:
                dx, dy = x - self._pos[1], y - self._pos[2]
                r = math.hypot(dx, dy)
                if r < p.near_m or r >= stated - p.first_tolerance_m:
                    continue
                bearing = wrap(math.atan2(dy, dx) - self._yaw[1])
                if scan.known is not None:
                    inside = any(abs(wrap(bearing - b)) <= (scan.increment or 0.0) / 2 for b in scan.known[1:-1])
                else:
                    inside = abs(wrap(bearing - math.radians(cfg.orientation_deg))) < math.radians(cfg.h_fov_deg) / 2
                if inside and not any(math.hypot(x - hx, y - hy) <= p.track_m for hx, hy, _, _ in placed):
                    self._bounds.append((t, r, f"sensor {j} sees a target at {r:.2f} m that sensor {i} does not"))

    # ---------------------------------------------------------------- evidence
    def _window(self, t: float) -> None:
        """Drop the frames older than the rate's window."""
        start = t - max(self.p.rate_window_s, self.p.window_s)
        while self._frames and self._frames[0].t < start:
            old = self._frames.popleft()
            if self._near_frames and self._near_frames[0] is old:
                self._near_frames.popleft()

    def _alpha_backscatter(self, t: float, harmless: float) -> tuple[float, int, int]:
        """α from the spurious short returns (the module docstring's (1)), the last window_s's spurious returns and
        reports. `harmless`: α₀, below which the medium cannot shorten D_od. A short return on a tracked target
        (one first seen farther away and followed in) is a surface, not the medium. Reports behind which stand
        different numbers of shots (`shots_of`) are pooled by `per_shot_rate`. A window needs `min_reports`
        reports and `min_spurious` such returns beyond the sensors' own (`_beyond_own`) to count."""
        raw = self._counts(t - self.p.window_s)
        last, whole = self._beyond_own(raw), self._beyond_own(self._counts(-math.inf))
        a_last = self._alpha(last, True)
        if a_last >= harmless and self._alpha(last, False) < harmless and self._alpha(whole, True) < harmless:
            a_last = 0.0  # neither the last window at its rate nor the longer one says the medium can shorten D_od
        return a_last, int(sum(c[1] for c in raw.values())), sum(c[0] for c in raw.values())

    def _counts(self, start: float) -> dict[float, list]:
        """[reports, spurious short returns, the sensors' own expected among them] by the shots behind each report,
        of the frames from `start` on."""
        out: dict[float, list] = {}
        for f in reversed(self._frames):
            if f.t < start:
                break
            c = out.setdefault(f.per, [0, 0, 0.0])
            c[0] += f.reports
            c[2] += f.own
        for f in reversed(self._near_frames):
            if f.t < start:
                break
            out[f.per][1] += sum(1 for x, y in f.near if not self._on_track(x, y))
        return out

    @staticmethod
    def _beyond_own(counts: dict[float, list]) -> dict[float, list]:
        """[reports, spurious returns beyond the sensors' own] by shots per report; none where the sensors' own
        spurious returns (`sensors[k].spurious_rate`, Poisson with the expected count) would reach the window's
        count with a probability above `OWN_RETURNS_P`: no evidence of a medium."""
        own = sum(c[2] for c in counts.values())
        if own > 0.0 and poisson_tail(sum(c[1] for c in counts.values()), own) > OWN_RETURNS_P:
            return {}
        return {per: [n, max(k - o, 0.0)] for per, (n, k, o) in counts.items()}

    def _alpha(self, counts: dict[float, list[int]], up: bool) -> float:
        return extinction_from_backscatter(per_shot_rate(counts, up), self.p.backscatter_length_m) \
            if self._enough(counts) else 0.0

    def _enough(self, counts: dict[float, list[int]]) -> bool:
        return sum(n for n, _ in counts.values()) >= self.p.min_reports and \
            sum(k for _, k in counts.values()) >= self.p.min_spurious

    def _on_track(self, x: float, y: float) -> bool:
        return self._nearest_track(x, y) is not None

    def _alpha_trend(self, t: float) -> float:
        """α from the quality of tracked targets as they were approached (the largest recent fit)."""
        p, best = self.p, 0.0
        if self._tracks:
            self._tracks = [tr for tr in self._tracks if tr.t_last >= t - p.recover_s - p.window_s]
        for tr in self._tracks:
            s = [(r, m) for r, m in tr.samples]
            if len(s) < p.trend_samples or tr.t_last < t - p.window_s:
                continue
            r = np.array([q[0] for q in s])
            if r.max() - r.min() < p.trend_span_m:
                continue
            y = np.log([q[1] for q in s]) + 2.0 * np.log(r)
            slope = float(np.polyfit(r, y, 1)[0])
            best = max(best, -slope / 2.0)
        return best

    # ---------------------------------------------------------------- output
    def estimate(self, t: float, stated_m: float) -> DetectionRangeEstimate:
        """D_od now, given the range the sensors claim (`stated_m`: the claim-based D_od, already capped by the
        sensors' ratings)."""
        p = self.p
        stated = max(stated_m, 0.0) if math.isfinite(stated_m) else 0.0
        top = stated if self.cap_m is None else min(stated, self.cap_m)
        self._window(t)
        r_max = max(self._stated.values(), default=stated)
        harmless = extinction_for_range(top, p.reference_reflectivity, r_max, p.rated_reflectivity) if top > 0 else 0.0
        a_bs, spurious, reports = self._alpha_backscatter(t, harmless)
        shots = sum(f.per * f.reports for f in self._frames if f.t >= t - p.window_s)
        a_tr = self._alpha_trend(t)
        self._alphas.add(t, max(a_bs, a_tr))
        alpha = self._alphas.max
        while self._bounds and self._bounds[0][0] < t - p.recover_s:
            self._bounds.popleft()
        d_medium = detection_range(alpha, p.reference_reflectivity, r_max, p.rated_reflectivity) if alpha > 0 else math.inf
        d_bound, why_bound = min(((b, w) for _, b, w in self._bounds), default=(math.inf, ""))
        d, reason = top, "the stated range" if self.cap_m is None or stated <= self.cap_m else "the configured cap"
        if d_medium < d:
            d, reason = d_medium, (f"the medium: extinction {alpha:.3f}/m (backscatter {spurious}/{reports} "
                                   f"{'shots' if shots == reports else f'reports of {shots / reports:.3g} shots'}"
                                   f"{f', quality trend {a_tr:.3f}/m' if a_tr > 0 else ''})")
        if d_bound < d:
            d, reason = d_bound, why_bound
        confidence = min(1.0, shots / (FULL_WINDOW_SHOTS_PER_S * p.window_s))
        return DetectionRangeEstimate(max(d, 0.0), stated, confidence, alpha, reason,
                                      {"medium_m": d_medium, "bound_m": d_bound, "alpha_backscatter": a_bs,
                                       "alpha_trend": a_tr, "spurious": spurious, "reports": reports,
                                       "shots": shots})


def evidence_line(sensors: list[SensorConfig]) -> str:
    """The start banner's line on what the backscatter rate is counted per: each sensor's shots per report, and
    whether configured (`shots_per_frame`) or assumed (one per report: the conservative reading)."""
    def one(k: int, s: SensorConfig) -> str:
        if s.shots_per_frame is not None:
            per = "frame" if s.kind == "distance_sensor" else "frame, shared by its bins"
            return f"[{k}] {s.shots_per_frame} shots per {per} (configured)"
        if s.kind == "obstacle_distance":
            return f"[{k}] one shot per bin (assumed; shots_per_frame not set)"
        return (f"[{k}] one shot per frame (assumed; shots_per_frame not set: a sensor reporting the nearest of "
                "several beams reads fog thicker than it is)")
    lines = "; ".join(one(k, s) for k, s in enumerate(sensors)) or "no sensors"
    return f"fog evidence (backscatter) counted per shot: {lines}"


def per_shot_rate(counts: dict[float, list[int]], up: bool = True) -> float:
    """The per-shot backscatter rate p from spurious reports: `counts` maps the shots behind each report (b) to
    [reports n_b, spurious k_b]. The fraction of spurious reports (`up`: one standard error up — when unsure, the
    thicker fog) is matched to its expectation under q_b = 1 − (1 − p)^b (contracts/lidar.py): with one b,
    q + √(q(1 − q)/n) = 1 − (1 − p)^b in closed form; with several, Σ n_b·q_b(p) = Σ k_b + √(Σ k_b(1 − k_b/n_b))
    solved by bisection (the expectation grows with p)."""
    if len(counts) == 1:
        (per, (n, k)), = counts.items()
        rate = k / n
        if up:
            rate += math.sqrt(rate * (1.0 - rate) / n)
        return per_shot_from_reports(rate, per)
    target = sum(k for _, k in counts.values()) + \
        (math.sqrt(sum(k * (1.0 - k / n) for n, k in counts.values())) if up else 0.0)
    if target >= sum(n for n, _ in counts.values()):
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(60):
        p = 0.5 * (lo + hi)
        if sum(n * (1.0 - (1.0 - p) ** per) for per, (n, _) in counts.items()) < target:
            lo = p
        else:
            hi = p
    return hi


def poisson_tail(k: float, mean: float) -> float:
    """P(N ≥ k) for N Poisson with `mean`."""
    if k <= 0:
        return 1.0
    term = cdf = math.exp(-mean)
    for j in range(1, math.ceil(k)):
        term *= mean / j
        cdf += term
    return max(0.0, 1.0 - cdf)
