"""Estimators of the subsystems' guarantees, fed only with timestamped MAVLink-derived samples.

Pure classes, no I/O and no simulator truth (a test checks the import graph):
- `DodEstimator`: the navigation guarantee `D_od` along the direction of travel (DESIGN.md §1);
- `EtrEstimator`: the controller guarantee `E_tr`, the worst contour error over a window (Figure 11);
- `ThrustEstimator`: the actuators' `thrust_ratio` from hover throttle;
- `NavHealth`: the autopilot's estimator flags;
- `AccelEstimator`: the horizontal acceleration the autopilot flies, from its velocity.
Angles in radians; body yaw angles clockwise from forward (FRD), as MAVLink.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from contracts.contour import ContourWindow
from contracts.coverage import covered_distance, sample_sectors
from contracts.geometry import wrap
from contracts.vehicle import G
from contracts.window import WindowMax

from .config import ContractConfig, SensorConfig, ThrustConfig
from .coverage import Beam, corridor_cover, covered_d_od
from .detection_range import RangeNoise
from .late_detection import Candidate, Confirmations, Frame, LateDetection, seen_from
from .samples import Scan
from .sight import looked_past

# ============================================================================ D_od

LOOK_BACK_S = 1.0  # [s] a place a frame this recent looked past holds no static surface (late sights, the clutter)
HEADING_SLACK = math.radians(0.5)  # [rad] a direction this close to a bin that reported was looked at (heading noise)
COVERAGE_S = 2.0  # [s] space seen free this recently counts as covered (static obstacles; odometry drift small)
SWEPT_MARGIN_M = 0.1  # [m] off the swept distance: position noise
# [m] the swept chain may start this far ahead of the vehicle's centre: its position drifts by millimetres between
# two samples at a hover, behind the apexes it saw from; inside any vehicle's radius (the Mambo's 0.10 m)
SWEPT_START_M = 0.05
SENSOR_LAG_S = 0.1  # [s] a sample was taken up to this before it is placed (latency ≤ 0.05 s + one position interval)
PERIOD_SAMPLES = 16  # a sensor's period is the mean of its last this many intervals (their span over their count)


@dataclass
class _SensorState:
    cfg: SensorConfig
    t: float = -math.inf  # time of the last sample
    max_m: float = 0.0  # reported maximum range (lowered by honest degradation)
    trusted: bool = False  # the last sample's signal quality acceptable
    # the last trusted sample's time: a sample below `min_quality` is no reading (its hits are obstacles, its free space
    # nothing, its claim not taken), and the sensor counts as covering until its silence budget runs from this
    t_trusted: float = -math.inf
    hits: list[tuple[float, float]] = field(default_factory=list)  # (body bearing, range) seen now
    known: tuple[float, ...] | None = None  # body bearings of the bins that report (None: a single beam)
    increment: float = 0.0
    period: float = 0.0  # smoothed interval between samples (delivery jitter does not shorten it)
    gaps: deque = field(default_factory=lambda: deque(maxlen=PERIOD_SAMPLES))  # its last intervals [s]
    budget: float = math.inf  # [s] the silence after which it counts as dead (`SilenceBudget`); set at construction
    swept: deque = field(default_factory=deque)  # `_Seen` samples of the last COVERAGE_S
    # each source's last sample (t, hits, claimed range, trusted): a sensor matching several DISTANCE_SENSOR ids
    # sees what any of them saw within the time-out (a "free" reading never erases another source's obstacle)
    sources: dict = field(default_factory=dict)

    def merged(self, own: list) -> list:
        """What the sensor sees now: `own` (this sample's hits) when it has one source, else every fresh source's."""
        return own if len(self.sources) == 1 else [h for v in self.sources.values() for h in v[1]]

    def seen_past(self) -> list[tuple[float, float]]:
        """For each hit, how far past its range the bin beside it on each side (the lower bearing's, the higher's)
        saw [m]: to a hit there (negative: a nearer one, which hides the side), or to the claim where it saw
        nothing; -inf where a bin inside the field of view reported nothing; inf beyond the field of view's edge
        (what the bins cannot bound there is R_obst's by the contract, as the avoid contract plans round it). A
        single beam's hits: inf (its one return is placed along the arc it may lie on, not bounded by bins)."""
        if self.known is None:
            return [(math.inf, math.inf)] * len(self.hits)
        tol = self.increment / 2
        lo, hi = min(self.known, default=0.0), max(self.known, default=0.0)

        def past(b: float, r: float) -> float:
            if not any(abs(wrap(b - k)) <= tol for k in self.known):
                return -math.inf if lo - tol <= b <= hi + tol else math.inf
            return min((r2 for b2, r2 in self.hits if abs(wrap(b2 - b)) <= tol), default=self.max_m) - r

        return [(past(b - self.increment, r), past(b + self.increment, r)) for b, r in self.hits]


@dataclass(slots=True)
class _Seen:
    """What one trusted sample saw free, as it was taken: its hits (body bearing, range), the sensor's bins,
    increment and claimed range then, the last position (t, x, y) and the one `SENSOR_LAG_S` before it, the
    last two headings (t, yaw). Its wedges in the local frame (`sectors`) and the travel in the lag (`shift`)
    are made only when the swept coverage is asked for — the direction of travel outside every field of view,
    rare — and then once, not at every sample."""

    t: float
    pos: tuple[float, float, float]
    pos_lag: tuple[float, float, float]
    stale_s: float
    yaw_last: tuple[float, float]
    yaw_prev: tuple[float, float] | None
    known: tuple[float, ...] | None
    increment: float
    max_m: float
    seen: list
    shift: tuple[float, float] | None = None  # set by `sectors`
    _sectors: list | None = None

    def sectors(self, cfg: SensorConfig) -> list[tuple]:
        """The free wedges (contracts.coverage rows), each narrowed by the heading's turn in the lag; sets
        `shift`, where the vehicle was `SENSOR_LAG_S` before, from the position they are placed at."""
        if self._sectors is None:
            apex, yaw = self.pos[1:], self.yaw_last[1]
            if self.known is not None:  # bins: each free to its hit, or to the claimed range
                hit = {round(b, 9): r for b, r in self.seen}
                ranges = [hit.get(round(b, 9), math.inf) for b in self.known]
                sec = sample_sectors(apex, yaw, self.known, self.increment, ranges, self.max_m)
            else:  # a single beam: its whole field of view, free to the nearest hit
                n = 1 + int(cfg.h_fov_deg // 90)  # wedges narrower than π
                w = math.radians(cfg.h_fov_deg) / n
                first = math.radians(cfg.orientation_deg) - math.radians(cfg.h_fov_deg) / 2 + w / 2
                r = min((r for _, r in self.seen), default=math.inf)
                sec = sample_sectors(apex, yaw, [first + k * w for k in range(n)], w, [r] * n, self.max_m)
            prev, last = self.yaw_prev, self.yaw_last  # the yaw rate from the last two headings
            rate = 0.0 if prev is None or last[0] <= prev[0] else wrap(last[1] - prev[1]) / (last[0] - prev[0])
            turn = abs(rate) * SENSOR_LAG_S
            self._sectors = [(x, y, lo + turn, hi - turn, r) for x, y, lo, hi, r in sec if hi - lo > 2 * turn]
            (t0, x0, y0), (t1, x1, y1) = self.pos_lag, self.pos
            self.shift = (x0 - x1, y0 - y1) if t1 - t0 <= self.stale_s else (0.0, 0.0)
        return self._sectors


def _saw_free(seen: _Seen, pose: tuple[float, float, float], width: float, bearing: float, r: float, tol: float,
              rate: float, beam: tuple[float, float]) -> bool:
    """Whether frame `seen` looked past every place a return at body `bearing` and range `r`, seen from `pose` (x, y,
    yaw) now, may be (`sight.looked_past`): its bin's arc (`width` wide) widened by the turn in `SENSOR_LAG_S` at the
    yaw `rate` now, in places half that frame's bin apart; that frame's directions as uncertain as the turn in its
    own lag, its bins wider by `HEADING_SLACK`, the travel in both lags added to `tol`, and the travel in that
    frame's lag to where it was taken from (a place near the sensor at its field of view's edge moves across that
    edge as the vehicle drifts by millimetres). A single beam: `beam` = (axis, half width)."""
    (_, x0, y0), (t0, yaw0), prev = seen.pos, seen.yaw_last, seen.yaw_prev
    rate0 = 0.0 if prev is None or t0 <= prev[0] else abs(wrap(yaw0 - prev[1])) / (t0 - prev[0])
    spread = width / 2 + abs(rate) * SENSOR_LAG_S
    a0 = pose[2] + bearing
    mid = math.hypot(pose[0] + r * math.cos(a0) - x0, pose[1] + r * math.sin(a0) - y0)
    step = max(mid - r * spread, 0.05) * (seen.increment or 2 * beam[1]) / 2
    n = min(1 + math.ceil(2 * spread * r / step), 200)
    places = [(pose[0] + r * math.cos(a), pose[1] + r * math.sin(a))
              for a in (a0 + spread * (2 * k / n - 1) for k in range(n + 1))]
    travel = math.hypot(seen.pos[1] - seen.pos_lag[1], seen.pos[2] - seen.pos_lag[2])
    return looked_past((x0, y0), yaw0, seen.known, seen.increment, seen.seen, seen.max_m, places, tol + 2 * travel,
                       rate0 * SENSOR_LAG_S, beam=beam, slack=HEADING_SLACK, apex_m=travel)


@dataclass(frozen=True, slots=True)
class DodEstimate:
    d_od: float  # guaranteed detection range along the direction of travel [m]
    covered_by: tuple[int, ...]  # sensors covering that direction, fresh and trusted
    obstacle_m: float  # nearest obstacle hit near the path [m] (inf: none)
    late: LateDetection | None  # a late first detection in this update, if any
    reason: str  # why d_od is what it is
    # d_od is the swept coverage because the direction of travel is outside every field of view (not because the
    # sensor looking along it reads only weak returns now: the reason says that)
    swept: bool = False
    lowered: bool = False  # d_od is below the sensors' claim: a late first detection, or the evidence (a violation)
    stated_m: float = math.nan  # the D_od the sensors' claim gives (before any lowering)
    # [s] the longest silence budget of the sensors D_od rests on: the dead time the contracts take for it
    silence_s: float = 0.0
    silent: tuple[SilentSensor, ...] = ()  # the sensors heard before and silent longer than their budget now
    withheld: int = 0  # returns withheld within a sensor's clutter until confirmed, since the start (one per frame)


@dataclass(frozen=True)
class SilenceBudget:
    """How long a sensor may be silent before it counts as dead: `periods` of its own measured period, at least
    `min_s`, at most `max_s` (and `max_s` until PERIOD_SAMPLES intervals are measured). The period is the mean of its
    last PERIOD_SAMPLES intervals as received — their span over their count, which a burst of samples delivered
    together does not shorten and the daemon's loop, receiving a 20 Hz sensor 40 and 60 ms apart in turn, does not
    move. The contracts take that silence as dead time: the vehicle flies on the last reading for as long."""

    periods: float
    min_s: float
    max_s: float

    def of(self, gaps) -> float:
        """The budget [s] for a sensor whose last intervals are `gaps`."""
        if len(gaps) < PERIOD_SAMPLES:
            return self.max_s
        # to the millisecond above (the clock's rounding neither lowers it nor makes every sample a new value)
        budget = math.ceil(self.periods * math.fsum(gaps) / len(gaps) * 1e3 - 1e-6) / 1e3
        return min(max(budget, self.min_s), self.max_s)


@dataclass(frozen=True, slots=True)
class SilentSensor:
    """A sensor silent longer than its budget: the navigation guarantee it gave is gone."""

    sensor: int
    silent_s: float  # since its last sample
    budget_s: float  # what the contracts took


class DodEstimator:
    """`D_od` along the direction of travel from the sensors' configured mounting and field of view,
    their reported range limits and signal quality, each sensor's silence (one silent longer than its own budget,
    `SilenceBudget`, counts for nothing; none left ⇒ 0), coverage and late first detections (which lower the
    estimate for a hold time once the following frames confirm them, `late_detection`). A direction outside every
    field of view gets the distance along it that the fresh, trusted sensors saw free in the last `COVERAGE_S` (the
    swept coverage, `contracts.coverage`; never more than was seen; none ⇒ 0)."""

    def __init__(self, sensors: list[SensorConfig], contract: ContractConfig, stale_s: float,
                 silence: SilenceBudget | None = None, cover: bool = True,
                 range_noise: RangeNoise = RangeNoise(0.0, 0.0)):
        """`stale_s`: the time-out (`timeouts.obstacle_s`): a position or heading older than it places nothing, and
        a sensor's sources are merged within it; `silence`: each sensor's own budget (None: the time-out for all);
        `range_noise`: the configured range noise σ(r) (`detection.range_noise_*`): a first sighting less short of
        D_od than noise alone reads (`RangeNoise.short_m`) is on time, as the detection range from evidence judges it
        (companion/onboard/detection_range.py), not a late first detection;
        `cover`: D_od is capped by the beams' cover of the swept corridor (`estimate`); False under the avoid
        contract, where the daemon's own swerves put the direction of travel at a field of view's edge and the cap
        read them as blindness (Figure 17 with late plans stopped short of its route; its braking broke the
        controller contract)."""
        self.cover = cover
        self.silence = silence if silence is not None else SilenceBudget(1.0, stale_s, stale_s)
        self.sensors = [_SensorState(c, budget=self.silence.max_s) for c in sensors]
        self.contract = contract
        self.stale_s = stale_s
        self.range_noise = range_noise
        self._penalty: tuple[float, float] | None = None  # (until t, d_od cap)
        self._last_d_od = 0.0
        self._pending: list[LateDetection] = []
        self._withheld = 0  # returns withheld within a sensor's clutter, counted frame by frame (`DodEstimate`)
        # first sights inside D_od awaiting the following frames that confirm them (`late_detection`)
        self._confirm = Confirmations(contract.late_detection_confirm_frames, stale_s, range_noise.spread_m)
        self._yaw_hist: deque[tuple[float, float]] = deque()
        self._pos: tuple[float, float, float] | None = None  # (t, x, y) local NED, the last known
        self._tracked: deque[tuple[float, float, float]] = deque(maxlen=256)  # (t seen, x, y) of obstacle hits
        self._pos_hist: deque[tuple[float, float, float]] = deque()  # (t, x, y) over the last SENSOR_LAG_S
        self.r_obst = contract.r_obst_m  # the R_obst in force (`estimate` takes it every cycle)

    # ---- inputs
    def set_speed(self, speed: float) -> None:
        """Ground speed now: an obstacle can come up to one sample interval's travel inside the range
        before a sample sees it, which is on time (the reaction time budgets the sensor's latency)."""
        self._speed = speed if math.isfinite(speed) else 0.0

    _speed = 0.0

    def add_heading(self, t: float, yaw: float) -> None:
        self._yaw_hist.append((t, yaw))
        while len(self._yaw_hist) > 2 and self._yaw_hist[0][0] < t - 2.0:
            self._yaw_hist.popleft()

    def add_position(self, t: float, x: float, y: float) -> None:
        """The vehicle's horizontal position, to place hits and the swept coverage in the local frame
        (the obstacles tracked, the swept coverage); its velocity from the last two."""
        if math.isfinite(x) and math.isfinite(y):
            self._pos = (t, x, y)
            self._pos_hist.append(self._pos)
            while len(self._pos_hist) > 2 and self._pos_hist[1][0] <= t - SENSOR_LAG_S:
                self._pos_hist.popleft()

    def add_scan(self, scan: Scan) -> None:
        """One sensor's sample, whatever its message (DISTANCE_SENSOR, OBSTACLE_DISTANCE, …)."""
        s = self.sensors[scan.sensor]
        if scan.increment is not None:  # bins: which report, and their width
            s.known, s.increment = scan.known, scan.increment
        self._update(scan.sensor, scan.t, scan.max_m, scan.quality, list(scan.hits), scan.source)

    def _update(self, i, t, max_m, quality, seen, source=None) -> None:
        """One sample of sensor i from `source`. The sensor's state is its fresh sources' together: every hit
        any of them saw (the nearest wins), the smallest range claimed, trusted only if each of them is."""
        s = self.sensors[i]
        fresh = t - s.t <= self.stale_s
        before = s.hits if fresh else []
        gap = t - s.t if fresh else 0.0
        if gap > 0:
            s.period = gap if s.period == 0 else 0.9 * s.period + 0.1 * gap
            s.gaps.append(gap)
            s.budget = self.silence.of(s.gaps)
        # samples delivered in a burst were still taken one interval apart
        tolerance = self.contract.late_detection_tolerance_m + self._speed * max(gap, s.period if fresh else 0.0)
        trusted = s.cfg.trusts(quality)
        claim = max(max_m, 0.0)
        s.sources[source] = (t, seen, claim, trusted)
        s.t = t
        if len(s.sources) == 1:  # the one source is this sample's (the most of sensors): fresh, its values
            s.trusted = trusted
            if trusted:
                s.max_m = claim
        else:
            s.sources = {k: v for k, v in s.sources.items() if t - v[0] <= self.stale_s}
            s.max_m = min(v[2] for v in s.sources.values())
            s.trusted = all(v[3] for v in s.sources.values())
        if s.trusted:
            s.t_trusted = t
        view = s.merged(seen)
        placed = self._placed(i, t, seen)
        self._sweep(i, t, view)  # free only short of every fresh source's hits, withheld ones too
        followed = self._confirm.follow(Frame(t, i, source, seen, placed, s.known, s.increment, tolerance, trusted),
                                        lambda c: self._seen_from_here(t, c))
        track = [p for c in followed.confirmed for p in self._declare(t, c)]  # (`_declare` says the late ones)
        # a candidate this frame ended was no obstacle: a hit in its bin now is not "the same as before"
        before = [h for h in before if h[0] not in followed.ended]
        untracked = set(followed.used)  # a candidate's sightings are tracked only once it is confirmed
        # ... and within the sensor's clutter reach the obstacle logic only then (`late_detection`)
        withheld = {k for k in followed.waiting if seen[k][1] <= s.cfg.clutter_m}
        late_inside = self._last_d_od - tolerance - self.range_noise.short_m(self._last_d_od)
        for k, (bearing, r) in enumerate(seen):
            near = [r0 for b0, r0 in before if abs(wrap(bearing - b0)) <= s.increment * 1.5 + 1e-9]
            if k in followed.used or any(abs(r - r0) <= tolerance for r0 in near):
                continue  # a candidate seen again, or the same surface as before
            late = not near and r < late_inside and not self._side_entry(i, t, bearing) \
                and not self._tracked_already(t, placed[k], tolerance)
            # a first sight inside D_od is late only where a recent frame looked past its place (a static surface
            # there would have been seen; without a pose, as the field of view's edges allow); within the sensor's
            # own clutter such a return waits for confirmation too, and confirmed is a broken guarantee as a late one is
            looked = (late or r <= s.cfg.clutter_m) and self._seen_free_before(i, t, bearing, r, tolerance)
            late = late and (looked or not self._posed(t))
            clutter = r <= s.cfg.clutter_m and looked
            if late or clutter:
                untracked.add(k)
                c = self._confirm.offer(LateDetection(t, i, bearing, r, self._last_d_od), source, placed[k])
                if c is not None:
                    track += self._declare(t, c)
                elif clutter:
                    withheld.add(k)
        track += [p for k, p in enumerate(placed) if p is not None and k not in untracked]
        for p in track:
            self._tracked.append((t, *p[:2]))
        if withheld:
            self._withheld += len(withheld)
            kept = [h for k, h in enumerate(seen) if k not in withheld]
            s.sources[source] = (t, kept, claim, trusted)
            view = s.merged(kept)
        s.hits = view

    def _declare(self, t: float, c: Candidate) -> list:
        """A confirmed late first detection (or a surface where the sensor had looked past): reported, and D_od capped
        at the range it was first seen at for the late-detection hold time from now. Returns its sightings' points: a
        tracked obstacle from now on."""
        self._pending.append(c.first)
        r = c.first.range_m
        cap = r if self._penalty is None or self._penalty[0] < t else min(r, self._penalty[1])
        self._penalty = (t + self.contract.late_detection_hold_s, cap)
        return list(c.points)

    def _seen_from_here(self, t: float, c: Candidate) -> tuple[float, float]:
        """The body bearing and range at which a sample at `t` sees candidate `c`'s place: from the vehicle's pose now
        where it and the place are known, else where it was last seen."""
        return seen_from(c, (self._pos[1], self._pos[2], self._yaw_hist[-1][1]) if self._posed(t) else None)

    def _placed(self, i: int, t: float, seen) -> list[tuple[float, float, float] | None]:
        """Each hit in the local frame: (x, y, uncertainty ±) from the last position and heading (None when
        either is unknown or older than the sensor's staleness)."""
        s = self.sensors[i]
        if not self._posed(t):
            return [None] * len(seen)
        _, x, y = self._pos
        yaw = self._yaw_hist[-1][1]
        half = s.increment / 2 if s.known is not None else math.radians(s.cfg.h_fov_deg) / 2
        out = []
        for bearing, r in seen:
            a = yaw + bearing
            out.append((x + r * math.cos(a), y + r * math.sin(a), r * math.sin(min(half, math.pi / 2))))
        return out

    def _sweep(self, i: int, t: float, seen) -> None:
        """Keep what this sample saw free (a `_Seen`; its wedges are made when first needed) for `COVERAGE_S`:
        the swept coverage `estimate` falls back on when the direction of travel is outside every field of view.
        The sample is placed at the last position and heading, but was taken up to `SENSOR_LAG_S` before: each
        wedge is narrowed by the heading's turn in that time and keeps the travel in it as its apex's uncertainty
        (`covered_distance`'s shift). An untrusted sample, or one whose position or heading is unknown or stale,
        adds nothing."""
        s = self.sensors[i]
        while s.swept and s.swept[0].t < t - COVERAGE_S:
            s.swept.popleft()
        if not s.trusted or s.max_m <= 0 or not self._posed(t):
            return
        yh = self._yaw_hist
        s.swept.append(_Seen(t, self._pos, self._pos_hist[0], self.stale_s, yh[-1], yh[-2] if len(yh) > 1 else None,
                             s.known, s.increment, s.max_m, seen))

    def _swept(self, t: float, theta: float) -> float:
        """The distance along absolute direction `theta` from the vehicle through the space the sensors still heard
        (none silent longer than its budget) saw free in their trusted samples of the last `COVERAGE_S`
        (contracts.coverage), each wedge no farther than its sensor claims now and within the navigation margin, less
        `SWEPT_MARGIN_M` (position noise). A sensor whose readings are all weak now (below `min_quality`) still
        counts for what it saw free before: the obstacles are static."""
        if self._pos is None or t - self._pos[0] > self.stale_s:
            return 0.0
        rows, shifts = [], []
        trust = 1.0 - self.contract.nav_margin
        for s in self.sensors:
            if t - s.t > s.budget:  # silent: dead. Heard, however weak its readings: what it saw free stays free
                continue
            for seen in s.swept:
                if seen.t >= t - COVERAGE_S:
                    sec = seen.sectors(s.cfg)
                    rows.extend((*q[:4], min(q[4], s.max_m) * trust) for q in sec)
                    shifts.extend([seen.shift] * len(sec))
        if not rows:
            return 0.0
        d = covered_distance(self._pos[1:], theta, np.array(rows), np.array(shifts), start_m=SWEPT_START_M)
        return max(d - SWEPT_MARGIN_M, 0.0)

    def _tracked_already(self, t: float, p, tolerance: float) -> bool:
        """Whether a hit is on an obstacle already tracked: within 2·R_obst (two points of one
        obstacle no wider than R_obst) plus the bearing's uncertainty and the tolerance of a point seen within
        the late-detection hold time. A column that leaves the field of view during a pass, or that a fast yaw
        sweeps across several bins between two samples, is not a new late detection."""
        if p is None:
            return False
        horizon = t - self.contract.late_detection_hold_s
        while self._tracked and self._tracked[0][0] < horizon:
            self._tracked.popleft()
        reach = 2 * max(self.r_obst, 0.0) + p[2] + tolerance
        return any(math.hypot(p[0] - qx, p[1] - qy) <= reach for _, qx, qy in self._tracked)

    def _posed(self, t: float) -> bool:
        """Position and heading known and no older than the sensors' staleness."""
        return self._pos is not None and bool(self._yaw_hist) and t - self._pos[0] <= self.stale_s \
            and t - self._yaw_hist[-1][0] <= self.stale_s

    def _seen_free_before(self, i: int, t: float, bearing: float, r: float, tol: float) -> bool:
        """Whether one of the sensor's frames of the last `LOOK_BACK_S` before this one saw past every place a return
        at body `bearing` and range `r` now may be (`_saw_free`): a static surface there would have been seen. False
        where no such frame, pose or heading is known."""
        s = self.sensors[i]
        frames = [seen for seen in list(s.swept)[:-1] if t - seen.t <= LOOK_BACK_S]
        if not self._posed(t) or not frames:
            return False
        yh = self._yaw_hist
        rate = wrap(yh[-1][1] - yh[-2][1]) / (yh[-1][0] - yh[-2][0]) if len(yh) > 1 and yh[-1][0] > yh[-2][0] else 0.0
        pose = (*self._pos[1:], yh[-1][1])
        half = math.radians(s.cfg.h_fov_deg) / 2
        width = s.increment if s.known is not None else 2 * half
        beam = (math.radians(s.cfg.orientation_deg), half)
        return any(_saw_free(seen, pose, width, bearing, r, tol, rate, beam) for seen in frames)

    def _side_entry(self, i: int, t: float, bearing: float) -> bool:
        """Whether a new hit may have come in from the side of the field of view rather than out of range."""
        s = self.sensors[i]
        if s.known is not None:  # bins: an edge bin is a side entry
            lo, hi = s.known[0], s.known[-1]
            return min(abs(wrap(bearing - lo)), abs(wrap(bearing - hi))) <= s.increment * 1.01
        # single beam: only a turn of more than half the field of view in the last second can bring one in
        half = math.radians(s.cfg.h_fov_deg) / 2
        past = [y for (ty, y) in self._yaw_hist if ty >= t - 1.0]
        return len(past) > 1 and max(abs(wrap(y - past[-1])) for y in past) > half

    # ---- output
    def fresh_hits(self, t: float) -> list[tuple[float, float, float, bool]]:
        """Obstacle hits of the fresh sensors: (body bearing, range, bearing uncertainty ±, from bins)."""
        out = []
        for s in self._fresh(t):
            bins = s.known is not None
            half = s.increment / 2 if bins else math.radians(s.cfg.h_fov_deg) / 2
            out.extend((b, r, half, bins) for b, r in s.hits)
        return out

    def hit_ends(self, t: float) -> list[tuple[float, float]]:
        """For each of `fresh_hits(t)`, in its order: how far past it the bins beside it saw on its lower and its
        higher bearing's side (`_SensorState.seen_past`)."""
        return [e for s in self._fresh(t) for e in s.seen_past()]

    def _fresh(self, t: float) -> list[_SensorState]:
        return [s for s in self.sensors if t - s.t <= s.budget]

    @staticmethod
    def _covers(s: _SensorState, beta: float) -> bool:
        """Whether the sensor looks along body bearing `beta`: a bin that reports (a bin that knows nothing
        is not free space), or within a single beam's configured field of view."""
        if s.known is not None:
            return bool(s.known) and min(abs(wrap(beta - b)) for b in s.known) <= s.increment / 2 + 1e-9
        return abs(wrap(beta - math.radians(s.cfg.orientation_deg))) <= math.radians(s.cfg.h_fov_deg) / 2 + 1e-9

    def in_view(self, t: float, beta: float) -> bool:
        """Whether a fresh, trusted sensor looks along body bearing `beta` (`_covers`)."""
        return any(t - s.t_trusted <= s.budget and self._covers(s, beta) for s in self.sensors)

    def estimate(self, t: float, beta: float, corridor_m: float = math.inf, r_obst: float | None = None
                 ) -> DodEstimate:
        """`beta`: direction of travel in the body frame; `corridor_m`: half-width of the swept path for
        deciding which hits are on it (single-beam hits are always taken as on it); `r_obst`: the R_obst in force
        from now on (CG_R_OBST; None: unchanged). The swept corridor the beams must cover has half-width
        w = r_body + E_tr (`companion.onboard.coverage`): `corridor_m` less its 2·R_obst, as the cycle makes it
        2·R_obst + E_tr + r_body (no corridor given: the claim alone). D_od is at most the far end of
        the range interval over which the fresh, trusted beams together cover that corridor, 0 where they cover it
        nowhere; the swept coverage (the direction of travel outside every field of view) no more than the beams
        cover of that corridor along any of their axes."""
        if r_obst is not None:
            self.r_obst = r_obst
        covered, d, reason = [], 0.0, "no fresh, trusted sensor covers the direction of travel"
        obstacle = math.inf
        beams, heard, weak = [], [], []  # the fresh, trusted sensors' beams; every heard sensor's; weak ones
        silence, silent = 0.0, []
        for i, s in enumerate(self.sensors):
            if t - s.t > s.budget:
                if math.isfinite(s.t):
                    silent.append(SilentSensor(i, t - s.t, s.budget))
                continue
            silence = max(silence, s.budget)
            bins = s.known is not None
            for b, r in s.hits:
                if not bins or abs(r * math.sin(wrap(b - beta))) <= corridor_m:
                    obstacle = min(obstacle, r)
            beam = Beam(s.cfg.orientation_deg, s.cfg.h_fov_deg, s.max_m)
            heard.append(beam)
            if t - s.t_trusted > s.budget:
                if self._covers(s, beta):
                    weak.append(i)
                continue
            beams.append(beam)
            if not self._covers(s, beta):
                continue
            covered.append(i)
            if s.max_m > d:
                d, reason = s.max_m, f"sensor {i} reports range {s.max_m:.2f} m"
        w = max(corridor_m - 2 * self.r_obst, 0.0) if self.cover and math.isfinite(corridor_m) else None
        short = False  # the beams cover less of the corridor along the direction of travel than they claim
        if covered and w is not None:  # the beams' cover of the corridor (companion/onboard/coverage.py)
            cover = corridor_cover(beams, w, beta, grid=True)
            if cover.hi < d:
                short = True
                d, reason = cover.hi, (f"the fresh, trusted sensors cover the swept corridor ±{cover.half_width_m:.2f} m "
                                       f"from {cover.lo:.2f} m to {cover.hi:.2f} m" if cover.covered else
                                       f"the fresh, trusted sensors cover the swept corridor ±{cover.half_width_m:.2f} m "
                                       "nowhere")
        if self.contract.nav_margin > 0.0 and d > 0.0:  # the navigation margin: trust (1 − m) of the claim
            d, reason = d * (1.0 - self.contract.nav_margin), f"{reason}, {self.contract.nav_margin:g} not trusted"
        swept = 0.0
        if (not covered or short) and self._yaw_hist:  # what was seen free on the way
            swept = self._swept(t, self._yaw_hist[-1][1] + beta)
            if swept > 0.0 and w is not None:  # no more than the beams can cover of the corridor along any axis
                swept = min(swept, max((covered_d_od(heard, w, math.radians(b.orientation_deg), grid=True)
                                        for b in heard), default=0.0))
            if swept > d:
                where = ("at the fields of view's edge" if covered else
                         f"seen only in readings below min_quality (sensor {', '.join(map(str, weak))})" if weak else
                         "outside the field of view")
                d, reason = swept, (f"direction of travel {where}: {swept:.2f} m of it seen free in the last "
                                    f"{COVERAGE_S:g} s")
            else:
                swept = 0.0
        lowered, stated = False, d
        if self._penalty is not None:
            if t <= self._penalty[0]:
                if self._penalty[1] < d:
                    d, reason, lowered = self._penalty[1], "lowered after a late first detection", True
            else:
                self._penalty = None
        self._last_d_od = d
        late = self._pending[0] if self._pending else None
        self._pending.clear()
        return DodEstimate(d, tuple(covered), obstacle, late, reason, swept > 0.0 and not weak, lowered, stated,
                           silence, tuple(silent), self._withheld)


# ============================================================================ E_tr


class EtrEstimator:
    """Worst horizontal contour error over a window, never below the configured floor."""

    def __init__(self, contract: ContractConfig, floor_m: float | None = None):
        self.floor = contract.e_tr_floor_m if floor_m is None else floor_m
        self.window = ContourWindow(window_s=contract.e_tr_window_s, path_span_s=contract.e_tr_window_s)
        self.last: float | None = None

    def command(self, t: float, x: float, y: float) -> None:
        if math.isfinite(x) and math.isfinite(y):
            self.window.command(t, (x, y))

    def measure(self, t: float, x: float, y: float) -> None:
        if math.isfinite(x) and math.isfinite(y):
            self.last = self.window.measure(t, (x, y))

    @property
    def value(self) -> float:
        return max(self.floor, self.window.worst)

    def reset(self) -> None:
        self.window.reset()


# ============================================================================ thrust_ratio


SETTLE_S = 2.0  # [s] after the last sample on the ground, before the throttle is a hover throttle (spin-up, lift-off)
SETTLED_A_UP = 1.0  # [m/s²] and once the vertical acceleration has come within this (the correction's own error)


class ThrustEstimator:
    """thrust_ratio = nominal hover throttle / measured hover throttle, the latter from the collective
    throttle corrected for tilt and vertical acceleration: h = throttle·cosφ·cosθ·g/(g + a_up),
    low-passed. Until it is known, `fallback`: the start value (`companion.onboard.assumptions.start_thrust`: the lowest the
    vehicle may have, where the table answers).

    Valid only airborne and settled: on the ground and during spin-up the throttle holds
    the vehicle against nothing (PX4's spin-up read 0.678 for a true 0.700). A sample counts once the
    autopilot says the vehicle is in the air, its last sample on the ground is `SETTLE_S` or more before, and
    its vertical acceleration has come within `SETTLED_A_UP` (then every sample counts until the next landing:
    a thrust loss in flight makes it sink, and skipping those would keep the estimate high just when it must
    fall). A landed state not yet reported (MAV_LANDED_STATE_UNDEFINED: `in_air` None) is no ground sample, so a
    flight first seen flying keeps the estimate, and only the samples decide: a replay of the flight's .tlog
    decides at the same sample as the live daemon."""

    def __init__(self, cfg: ThrustConfig, hover_nominal: float, fallback: float, top: float = 1.0):
        self.cfg, self.h_nom, self.fallback, self.top = cfg, hover_nominal, fallback, top
        self._h: float | None = None
        self._t = None
        self._vz = None  # (t, vz down)
        self._a_up = 0.0
        self._t_ground: float | None = None  # the last sample on the ground (None: none seen)
        self._settled = False  # airborne and settled since the last sample on the ground

    def add(self, t: float, throttle: float, roll: float, pitch: float, vz_down: float, in_air: bool | None) -> None:
        """`in_air` None: the autopilot has not said (no EXTENDED_SYS_STATE yet) — neither ground nor air."""
        if self._vz is not None and t > self._vz[0]:
            a = -(vz_down - self._vz[1]) / (t - self._vz[0])
            k = min(1.0, (t - self._vz[0]) / 0.2)
            self._a_up += k * (a - self._a_up)
        self._vz = (t, vz_down)
        if in_air is None:
            return
        if not in_air:  # on the ground: what was estimated aloft is not known now
            self._t_ground, self._h, self._settled = t, None, False
            return
        # 1 ms short of SETTLE_S: on a regular sample grid the wait is an exact multiple of the period, and a
        # log's µs stamps must not move the decision by a sample (the replay decides at the live sample)
        self._settled = self._settled or ((self._t_ground is None or t - self._t_ground >= SETTLE_S - 1e-3)
                                          and abs(self._a_up) <= SETTLED_A_UP)
        tilt_cos = math.cos(roll) * math.cos(pitch)
        if not (self._settled and 0.05 < throttle <= 1.0 and tilt_cos > math.cos(math.radians(35))):
            return
        h = throttle * tilt_cos * G / max(G + self._a_up, 0.5 * G)
        if self._h is None:
            self._h = h
        else:
            self._h += min(1.0, (t - self._t) / self.cfg.tau_s) * (h - self._h)
        self._t = t

    def basis(self, t: float) -> str:
        """What `value` is now: "configured" (thrust.source), "hover" (the hover estimate, airborne and settled) or
        "start" (no estimate yet, or none for 2 s: the start value `fallback`)."""
        if self.cfg.source == "configured":
            return "configured"
        return "start" if self._h is None or t - self._t > 2.0 else "hover"

    def value(self, t: float) -> tuple[float, str]:
        basis = self.basis(t)
        if basis == "configured":
            return (self.cfg.value or self.fallback), "configured"
        if basis == "start":
            return self.fallback, "not airborne and settled: the start value"
        return min(self.top, self.h_nom / self._h), f"hover throttle {self._h:.3f} vs nominal {self.h_nom:.3f}"


# ============================================================================ navigation health

# ESTIMATOR_STATUS.flags (ESTIMATOR_STATUS_FLAGS, common.xml) and EKF_STATUS_REPORT.flags (ardupilotmega.xml)
_NEED = 1 | 2 | 8  # attitude, horizontal velocity, relative horizontal position
_BAD = {"ESTIMATOR_STATUS": 128 | 1024 | 2048, "EKF_STATUS_REPORT": 128 | 1024 | 32768}


class NavHealth:
    """Healthy when the autopilot's estimator reports attitude, horizontal velocity and relative
    position, and no constant-position mode, glitch or accelerometer error; stale ⇒ unhealthy."""

    def __init__(self, stale_s: float):
        self.stale_s = stale_s
        self._t = -math.inf
        self._ok = False
        self.reason = "no estimator status yet"

    def update(self, t: float, msg_type: str, flags: int) -> None:
        self._t = t
        self._ok = (flags & _NEED) == _NEED and not flags & _BAD.get(msg_type, 0)
        self.reason = "ok" if self._ok else f"{msg_type} flags 0x{flags:x}"

    _t_fault = -math.inf

    def fault(self, t: float, why: str) -> None:
        """The vehicle's state as reported cannot be true (e.g. 10⁶ m/s): unhealthy for `stale_s`."""
        self._t_fault, self.reason = t, f"implausible state: {why}"

    def healthy(self, t: float) -> bool:
        return self._ok and t - self._t <= self.stale_s and t - self._t_fault > self.stale_s


class AccelEstimator:
    """The horizontal acceleration flown, Δv/Δt of the reported velocity over at least a window (the newest sample
    against the newest one at least that much older), for windows up to `keep_s`: the recovery brake's starting
    state (0.1 s) and the approach ramp's check (0.3 s), from one set of samples."""

    def __init__(self, keep_s: float):
        self.keep_s = keep_s
        self._seen: deque = deque()  # (t, vx, vy), the oldest the newest at least keep_s before the newest

    def add(self, t: float, vx: float, vy: float) -> None:
        """Take a velocity sample (a repeated or non-finite time is ignored)."""
        seen = self._seen
        if not math.isfinite(t) or (seen and t <= seen[-1][0]):
            return
        seen.append((t, vx, vy))
        while len(seen) > 2 and t - seen[1][0] >= self.keep_s:
            seen.popleft()

    def over(self, window_s: float) -> np.ndarray | None:
        """The acceleration over at least `window_s` (≤ keep_s); None before window_s of samples."""
        seen = self._seen
        if not seen:
            return None
        t, vx, vy = seen[-1]
        k = len(seen) - 1
        while k > 0 and t - seen[k][0] < window_s:  # (the difference itself: no sample lost to round-off)
            k -= 1
        t0, vx0, vy0 = seen[k]
        dt = t - t0
        return np.array([vx - vx0, vy - vy0]) / dt if dt >= window_s else None


# ============================================================================ the daemon's own timeliness

LATE_WINDOW_S = 10.0  # [s] a late cycle counts this long: a loaded computer is likely to be late again
JUDGED_AFTER_S = 1.0  # [s] after the autopilot's first heartbeat before the cycles' timeliness is judged
LATE_NOTE_S = 0.005  # [s] lateness inside the allowance is said (an event) from this much on


class Timeliness:
    """Guidance's own guarantee: the daemon decides once every cycle, 1/loop_hz, give or take a stated jitter
    allowance — the "decision" part of the vehicle file's `t_react` (sensor latency + one cycle + the allowance +
    the autopilot's response; docs/daemon.md, Timeliness). A cycle that comes later than its period by no more than `allowance_s`
    is inside that budget: said (`within_s`, an event), not counted. One later than that is reaction time the
    contract did not budget: until `LATE_WINDOW_S` has passed, `late_s` is the worst such lateness (all of it, the
    allowance included: the safe side), which the supervisor adds to t_react (V ≤ V_safe(d_od − V·(t_react +
    late_s))). Measured in daemon time (the vehicle's clock rate), so a SITL sped up k times sees k times the
    host's lateness; in lock-step and replays the cycles are on time by construction.

    Not judged before the autopilot's first heartbeat and for `JUDGED_AFTER_S` after it (`tick(t, linked)`):
    start-up (imports, the table, the first checks and plans) is no flight, and nothing is commanded before the
    link is up. `unbudgeted_s`: this cycle's lateness where it exceeds what was counted before it (the contract
    was flying a smaller reaction time than happened: the guarantee broken), else 0; `within_s`: this cycle's
    lateness inside the allowance when it is at least `LATE_NOTE_S` and more than any said in the window, else 0."""

    def __init__(self, period_s: float, allowance_s: float, window_s: float = LATE_WINDOW_S):
        self.period, self.allowance, self.window = period_s, allowance_s, window_s
        self._t: float | None = None
        self._t_linked: float | None = None  # the first cycle with the autopilot's heartbeat fresh
        self._late = WindowMax(window_s)  # lateness beyond the allowance
        self._within = WindowMax(window_s)  # lateness inside it
        self.last_late_s = 0.0  # this cycle's own lateness beyond the allowance (0 when inside it)
        self.unbudgeted_s = 0.0
        self.within_s = 0.0

    def judged(self, t: float) -> bool:
        """Whether a cycle at t is judged: `JUDGED_AFTER_S` or more after the first with the link up."""
        return self._t_linked is not None and t - self._t_linked >= JUDGED_AFTER_S

    def tick(self, t: float, linked: bool = True) -> float:
        """One cycle at daemon time t (`linked`: the autopilot's heartbeat is fresh); returns the worst counted
        lateness of the window [s] (0: on time)."""
        if linked and self._t_linked is None:
            self._t_linked = t
        late = 0.0 if self._t is None or t < self._t or not self.judged(t) else t - self._t - self.period
        self._t = t
        self.last_late_s = late if late > self.allowance else 0.0
        inside = late if LATE_NOTE_S <= late <= self.allowance else 0.0
        self.within_s = inside if inside > self._within.value(t) else 0.0
        if self.within_s > 0.0:
            self._within.add(t, inside)
        self.unbudgeted_s = self.last_late_s if self.last_late_s > self._late.value(t) else 0.0
        if self.last_late_s > 0.0:
            self._late.add(t, late)
        return self._late.value(t)
