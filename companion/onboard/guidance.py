"""Offboard guidance: the daemon as the paper's guidance subsystem (Figure 1). No I/O; planning runs
inline (lock-step), in a worker process of its own (`ProcessPlanning`, in flight) or on a worker thread
(`ThreadedPlanning`).

- `Route`: the path to fly at constant altitude (NED): the waypoints with an arc at each corner, with
  along-track progress and the cruise speed profile (arcs, stops, the end).
- `obstacle_discs`: the keep-out discs from sensor hits — several beams of one obstacle give its
  position and width; a single beam keeps the conservative set of positions consistent with the hit.
- `OffboardGuidance`: each cycle a setpoint (position, velocity, acceleration feed-forward, yaw):
  cruise along the route at up to the contract's V_max (yaw on the motion, turning before speeding
  up); when an obstacle is on the path, fly the online avoidance plan (`contracts.online_planner`) around
  its keep-out disc; replan when an obstacle appears, when Ω changes, when the vehicle drifts from the
  plan, or as the plan ages; brake when nothing else is safe.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from contracts.contour import distance_to_polyline
from contracts.geometry import wrap
from contracts.online_planner import REPLAN_S, AvoidancePlanner, Disc, Plan, best_stop, keeps_plan, load_solver

from .ahead import CREEP_SPEED_M_S, TRAVEL_SPEED_M_S
from .sight import neighbouring

RANGE_TOL_M = 0.1  # [m] a bin's range is good to this (3 σ of the range noise the sensors are flown with)
# [m] a swerve's plan keeps this much farther from a run's sectors than the hold on its path (r_body + E_tr): a plan on
# the band's edge was held for the next cycle's range noise
SWERVE_MARGIN_M = 0.2
PATH_AHEAD_M = 40.0  # [m] the path ahead (`path_ahead`) reaches this far along the route: past any stopping distance
PATH_STEP_M = 0.5  # [m] … in steps of this (a corner's arc)
REPLAN_MIN_S = 0.1  # a new Ω, drift from the plan or braking asks for a replan at most this often
DRIFT_M = 0.5  # drift from the plan that asks for a replan
ENTER_TOL_M = 0.02  # [m] a plan that goes this far into a keep-out disc is planned again at once while swerving
PLAN_BUDGET_S = 0.15  # [s] a threaded replan starts no further attempt after this (its plan goes stale)
WORKER_START_S = 60.0  # [s] the planning process's start-up waited for before the loop runs, at most
PLAN_LEAD_S = (0.3, 1.0)  # [s] the lead a plan asked for while braking starts at: at least, at most (its answer's
# latency as the guidance measured it, in its own time: the SITL's 2× clock doubles a wall-clock solve)


A_LAT = 0.5  # fraction of a_max an arc's centripetal acceleration may use (the rest is for tracking)
A_BRAKE = 0.8  # fraction of a_max the reference slows at, for arcs, stops and the route end
A_SIDE = 0.5  # fraction of a_max a rejoin's sideways speed changes at
YAW_RATE_ARC = 1.5  # [rad/s] arcs are flown no faster than turns the heading at this rate (v ≤ ω·R)
REVERSAL_DEG = 150.0  # a corner turning more than this gets no arc: the reference stops at the vertex
YAW_SPEED = 0.5  # [m/s] above this commanded speed the yaw follows the velocity, else the route
YAW_MEAS_BELOW = 2.0  # [m/s] the measured velocity weighs in the yaw below this commanded speed (1 at rest)
SIDE_DEG = 25.0  # [°] a rejoin's sideways speed keeps the reference this close to the route's direction…
SIDE_SLOW = 0.7  # [m/s] …or below this, with the heading on the reference's direction (else TURN_FIRST_SPEED)
REJOIN_OPEN_M = 0.5  # [m] a rejoin this far beside the route slows for the next stop at A_REJOIN_STOP·a_max
ON_ROUTE_M = 0.1  # [m] this close beside the route the vehicle is on it (the route's end is reached)
A_REJOIN_STOP = 0.2
HEADING_TOL = math.radians(20.0)  # the reference speeds up only with the heading this close to the yaw
# below walking pace, a rejoin's reference off the heading by more than HEADING_TOL is flown no faster than this until
# the heading has turned to it: the daemon's own creep out of the field of view (companion/onboard/ahead.py `Creep`)
TURN_FIRST_SPEED = 0.5 * CREEP_SPEED_M_S
# the vehicle flown above V_max gives the excess back: the cruise reference's budget shrinks by GIVE_BACK × the
# excess, a pass's clock slows by the excess over its speed (at most PASS_SLOW_MAX); 0 and 0: the reference alone
GIVE_BACK = 1.0
PASS_SLOW_MAX = 0.5
PASS_OVER_VMAX_M_S = 0.1  # [m/s] a pass's reference above V_max by more than this is slowed to it (`_follow`)
LEG_TURN_DEG = 5.0  # [deg] the route's direction this far from a pass's: the pass has reached the route's turn


@dataclass
class Route:
    """Waypoints (x, y) [m, local NED] flown at `altitude_m` above the origin (z = −altitude).

    The path is the polyline with each interior vertex replaced by a circular arc tangent to both legs,
    passing `corner_cut_m` from the vertex (one value, or one per waypoint, ends unused), shrunk so an
    arc takes at most half of each adjacent leg. A corner turning more than REVERSAL_DEG, or with a cut
    of 0, stays sharp and the reference stops there. `s` is along-track distance on this path."""

    waypoints: np.ndarray
    altitude_m: float
    corner_cut_m: float | Sequence[float] = 1.0

    def __post_init__(self):
        self.waypoints = np.asarray(self.waypoints, dtype=float).reshape(-1, 2)
        cuts = np.broadcast_to(np.asarray(self.corner_cut_m, float), (len(self.waypoints),))
        keep = np.concatenate([[True], np.hypot(*np.diff(self.waypoints, axis=0).T) > 1e-6])
        w, cuts = self.waypoints[keep], cuts[keep]  # repeated points dropped
        if len(w) == 1:
            w, cuts = np.vstack([w, w]), np.append(cuts, cuts)  # one place: a route of length 0
        seg = np.diff(w, axis=0)
        ln = np.hypot(seg[:, 0], seg[:, 1])
        u = seg / np.maximum(ln, 1e-12)[:, None]
        tan_len, radius, turn = np.zeros(len(w)), np.zeros(len(w)), np.zeros(len(w))
        stop = np.zeros(len(w), bool)
        for i in range(1, len(w) - 1):
            d = math.atan2(u[i - 1, 0] * u[i, 1] - u[i - 1, 1] * u[i, 0], float(u[i - 1] @ u[i]))
            if abs(d) < 1e-6:
                continue  # straight on
            turn[i] = d  # signed: + turns towards n = (−u_y, u_x)
            if abs(d) > math.radians(REVERSAL_DEG) or not cuts[i] > 0:
                stop[i] = True
                continue
            h = abs(d) / 2
            r = cuts[i] / (1 / math.cos(h) - 1)  # the arc passes R/cos(δ/2) − R from the vertex
            tan_len[i] = min(r * math.tan(h), ln[i - 1] / 2, ln[i] / 2)
            radius[i] = tan_len[i] / math.tan(h)
        # elements in along-track order, one row each:
        # s0, length, x0, y0, ux, uy (lines: start point, direction) | cx, cy, R, θ0, sweep (arcs; R = 0 on lines)
        rows, stops, s = [], [], 0.0
        for i in range(len(w) - 1):
            a = w[i] + u[i] * tan_len[i]
            n_line = ln[i] - tan_len[i] - tan_len[i + 1]
            rows.append([s, n_line, *a, *u[i], 0, 0, 0, 0, 0])
            s += n_line
            j = i + 1
            if radius[j] > 0:
                b = w[j] - u[i] * tan_len[j]
                c = b + math.copysign(radius[j], turn[j]) * np.array([-u[i, 1], u[i, 0]])
                th0 = math.atan2(b[1] - c[1], b[0] - c[0])
                rows.append([s, radius[j] * abs(turn[j]), *b, *u[i], *c, radius[j], th0, turn[j]])
                s += rows[-1][1]
            elif stop[j]:
                stops.append(s)
        self._el = np.array(rows, float)
        self._is_arc = self._el[:, 8] > 0
        self._length = s
        # speed constraints: (from s0, until s1, radius): arcs, stops at sharp corners, rest at the end
        arcs = self._el[self._is_arc]
        self._con = np.vstack([np.column_stack([arcs[:, 0], arcs[:, 0] + arcs[:, 1], arcs[:, 8]]),
                               np.array([[x, x, 0.0] for x in stops]).reshape(-1, 3),
                               [[s, math.inf, 0.0]]])
        self._stops = np.array(stops + [s])

    @property
    def length(self) -> float:
        return float(self._length)

    @property
    def arcs(self) -> np.ndarray:
        """One row per arc: along-track start, length, start point (2), start direction (2), centre (2),
        radius, start angle, signed sweep [rad]."""
        return self._el[self._is_arc]

    def project(self, p, lo: float = -math.inf, hi: float = math.inf) -> float:
        """Along-track distance of the route point nearest to p (among the parts between lo and hi: a
        route that comes back near itself, e.g. a closed loop, is not confused with its other pass)."""
        p = np.asarray(p, float)
        e = self._el
        rel = p - e[:, 2:4]
        t = np.clip(np.einsum("ij,ij->i", rel, e[:, 4:6]), 0.0, e[:, 1])  # lines
        d = np.hypot(*(rel - e[:, 4:6] * t[:, None]).T)
        arc = self._is_arc
        if arc.any():
            a = e[arc]
            sgn, sweep, r = np.sign(a[:, 10]), np.abs(a[:, 10]), a[:, 8]
            q = p - a[:, 6:8]
            ang = np.mod(sgn * (np.arctan2(q[:, 1], q[:, 0]) - a[:, 9]), 2 * np.pi)
            ang = np.where((ang > sweep) & (ang - sweep > 2 * np.pi - ang), 0.0, np.minimum(ang, sweep))
            th = a[:, 9] + sgn * ang
            foot = a[:, 6:8] + r[:, None] * np.column_stack([np.cos(th), np.sin(th)])
            d[arc] = np.hypot(*(p - foot).T)
            t[arc] = r * ang
        d[(e[:, 0] + e[:, 1] < lo) | (e[:, 0] > hi)] = math.inf
        k = int(np.argmin(d))
        return float(min(max(e[k, 0] + t[k], lo), hi))

    def _at(self, s: float):
        s = min(max(s, 0.0), self._length)
        k = max(int(np.searchsorted(self._el[:, 0], s, side="right")) - 1, 0)
        return self._el[k], s - self._el[k, 0]

    def point(self, s: float):
        """(position, unit direction) at along-track s (clamped to the route; at a vertex, the leg ahead)."""
        e, ds = self._at(s)
        if e[8] <= 0:
            return e[2:4] + e[4:6] * ds, e[4:6].copy()
        sgn = math.copysign(1.0, e[10])
        th = e[9] + sgn * ds / e[8]
        return e[6:8] + e[8] * np.array([math.cos(th), math.sin(th)]), sgn * np.array([-math.sin(th), math.cos(th)])

    def curvature(self, s: float) -> float:
        """Signed curvature at s: du/ds = κ·n with n = (−u_y, u_x); 0 on lines."""
        e, _ = self._at(s)
        return math.copysign(1.0 / e[8], e[10]) if e[8] > 0 else 0.0

    def straight_left(self, s: float) -> float:
        """How far the straight leg at s goes on from s, to where the route turns (an arc, a sharp corner) or ends; inf
        on an arc."""
        e, ds = self._at(s)
        return float(e[1] - ds) if e[8] <= 0 else math.inf

    def end_ahead(self, s: float):
        """The route's end point where the leg at s runs straight on to it (the last leg), else None."""
        straight = self.straight_left(s)
        return self.point(self.length)[0] if math.isfinite(straight) and s + straight >= self.length - 1e-9 else None

    def next_stop(self, s: float) -> float:
        """Along-track position of the first stop (sharp corner or the route end) after s."""
        return float(self._stops[np.searchsorted(self._stops, s, side="right")]) if s < self._length else self._length

    def speed_limit(self, s, v_max: float, a_max: float):
        """The cruise reference's highest speed at s (scalar or array): V_max; on an arc
        min(sqrt(A_LAT·a_max·R), YAW_RATE_ARC·R); before each arc, stop and the route end, the speed
        from which slowing at A_BRAKE·a_max reaches that arc's speed, or rest, where it starts."""
        s = np.asarray(s, float)[..., None]
        s0, s1, r = self._con.T
        v_k = np.minimum(np.sqrt(A_LAT * a_max * r), YAW_RATE_ARC * r)
        lim = np.where(s < s0, np.sqrt(v_k * v_k + 2 * A_BRAKE * a_max * np.maximum(s0 - s, 0.0)), v_k)
        lim = np.where(s < s1, lim, math.inf).min(axis=-1)
        out = np.minimum(lim, v_max)
        return float(out) if out.ndim == 0 else out


@lru_cache(maxsize=256)
def _arc(lo: float, hi: float, n: int) -> tuple[float, ...]:
    """`np.linspace(lo, hi, n)` as floats, once per arc (a single beam's field of view: the same every cycle)."""
    return tuple(np.linspace(lo, hi, n).tolist())


@dataclass(frozen=True, slots=True)
class Place:
    """One obstacle the beams tell apart: the discs of its place — its runs' discs (before `widest` drops any), or the
    arc of a single beam's discs — and, for runs of bins, the body bearings of its outermost bins and a bin's
    half-width (None for a single beam)."""

    discs: tuple[Disc, ...]
    bins: tuple[float, float, float] | None = None  # (lowest, highest, ±half-width) [rad]


@dataclass(frozen=True, slots=True)
class Seen:
    """What the beams of one cycle show (`seen_obstacles`)."""

    discs: list[Disc]  # the keep-out discs
    width: float  # the widest obstacle half-width measured (0 if none measurable)
    obstacles: tuple[Place, ...]  # each obstacle the beams tell apart


def obstacle_discs(hits, p, yaw, r_obst: float, inflate: float = 0.0, widest: float = math.inf,
                   measured_beyond: float = math.inf, ends=None) -> tuple[list[Disc], float, int]:
    """`seen_obstacles`' discs, widest half-width and how many obstacles the beams tell apart."""
    seen = seen_obstacles(hits, p, yaw, r_obst, inflate, widest, measured_beyond, ends)
    return seen.discs, seen.width, len(seen.obstacles)


def seen_obstacles(hits, p, yaw, r_obst: float, inflate: float = 0.0, widest: float = math.inf,
                   measured_beyond: float = math.inf, ends=None) -> Seen:
    """Keep-out discs (radius R_obst + inflate) from hits (body bearing, range, ± uncertainty, from bins).

    Beams from a bin sensor that see one obstacle (adjacent bins) give its chord: the disc of radius
    R_obst through the chord's ends, on the far side (or wider, if the chord is wider than 2·R_obst —
    reported as the observed width). A single beam only says that the surface is at that range
    somewhere in its field of view: every disc of radius R_obst touching such a point lies within
    2·R_obst of it, so discs of that radius are placed along the arc of possible hit points. `ends`: for each hit,
    how far past it the bins beside it saw on its lower and higher bearing's side (`DodEstimator.hit_ends`): a run
    whose outline the bins beside it did not close — a bin that reported nothing, a nearer hit that hides its side —
    is of unknown width and gets no disc; beyond `measured_beyond` neither does one they saw less than a run's break
    (2·R_obst + 0.5 m) past, until it is nearer (a wall far ahead where the claim cuts it off, or a grazing wall's
    range noise splits, looks like a pole; a plan round it went through the wall beside). `measured_beyond`: a
    run seen farther than this gets the chord's own disc where that is the smaller — centred half the chord behind
    its middle (the silhouette of a column is as wide as the column), holding every bin's sector at its range, and
    SWERVE_MARGIN_M more — for a swerve whose guarantee is the stop contract's hold on the path flown, which counts
    those sectors, not the disc (R_obst's disc beside a pole closed a 5–7 m corridor's passage either side).
    The obstacles the beams tell apart: one per run of adjacent bins (runs whose discs overlap are one), one per single
    beam's hit. `widest`: a run whose measured half-width,
    or depth, is above it gets no disc (its width and count are still returned).
    """
    if not hits:  # nothing seen (most cycles): no disc
        return Seen([], 0.0, ())
    p = np.asarray(p, float)
    discs: list[Disc] = []
    seen = 0.0  # the widest half-width measured
    narrow: list[bool] = []  # each run's disc is kept (no wider than `widest`)
    if ends is None or len(ends) != len(hits):
        ends = [(math.inf, math.inf)] * len(hits)
    brk = 2 * r_obst + 0.5  # a range step that parts two runs
    bins = sorted((b, r, h, e) for (b, r, h, is_bins), e in zip(hits, ends) if is_bins)
    singles = [(b, r, h) for b, r, h, is_bins in hits if not is_bins]
    clusters: list[list] = []
    faces: list[tuple[np.ndarray, float]] = []  # each run's hit points and how far off a point may be
    for b, r, h, e in bins:
        if clusters and neighbouring(abs(b - clusters[-1][-1][0]), h, h) and abs(r - clusters[-1][-1][1]) < brk:
            clusters[-1].append((b, r, h, e))
        else:
            clusters.append([(b, r, h, e)])
    past = [min(cl[0][3][0], cl[-1][3][1]) for cl in clusters]  # how far past the run its outline was seen
    clusters = [[(b, r, h) for b, r, h, _ in cl] for cl in clusters]
    for cl in clusters:
        pts = np.array([p + r * np.array([math.cos(yaw + b), math.sin(yaw + b)]) for b, r, _ in cl])
        r_near = min(r for _, r, _ in cl)
        # a bin reports the nearest return in its sector at the sector's centre bearing: every hit point
        # may be off by up to half a bin sideways (and a little in range)
        pad = r_near * math.tan(cl[0][2]) + 0.05
        w2 = float(np.hypot(*(pts[-1] - pts[0]))) / 2  # half the chord the beams saw
        mid = 0.5 * (pts[0] + pts[-1])
        u = (mid - p) / max(float(np.hypot(*(mid - p))), 1e-9)
        if len(cl) > 1:
            seen = max(seen, w2 - pad)
        faces.append((pts, pad))
        radius = max(r_obst, w2)  # R_obst (or the chord, if wider), the front face what was seen
        centre = mid + math.sqrt(max(radius * radius - w2 * w2, 0.0)) * u
        disc = Disc(*map(float, centre), _holding(centre, radius, pts) + pad)
        if r_near > measured_beyond:  # half the chord behind its middle, holding every bin's sector, and a margin
            centre = mid + w2 * u
            sectors = np.array([p + r * np.array([math.cos(yaw + b + e), math.sin(yaw + b + e)])
                                for b, r, h in cl for e in (-h, 0.0, h)])
            own = Disc(*map(float, centre), _holding(centre, w2 + pad, sectors) + SWERVE_MARGIN_M)
            disc = own if own.r < disc.r else disc  # (far off, a few bins span more than R_obst's disc)
        discs.append(Disc(disc.x, disc.y, disc.r + inflate))
        # a face no wider than `widest` is no deeper either (what is seen of a disc lies within its radius of the
        # nearest point seen; a bin's range is its sector's nearest return, good to the range noise): a run deeper
        # than that is a wall seen along its length
        depth = max(r for _, r, _ in cl) - r_near - RANGE_TOL_M
        k = len(narrow)
        closed = past[k] > 0.0 and (r_near <= measured_beyond or past[k] >= brk)  # (`ends`)
        narrow.append((len(cl) == 1 or max(w2 - pad, depth) <= widest) and closed)
    px, py = float(p[0]), float(p[1])
    arcs = []
    for b, r, h in singles:
        n = max(2, int(math.ceil(2 * h * r / max(r_obst, 0.05))) + 1)
        reach = 2 * r * math.sin(h / (2 * (n - 1)))  # farthest any arc point is from its nearest sample
        # every hit point of the arc is within `reach` of a sample, every obstacle within 2·R_obst of it
        arcs.append(tuple(Disc(px + r * math.cos(yaw + a), py + r * math.sin(yaw + a), 2 * r_obst + reach + inflate)
                          for a in _arc(b - h, b + h, n)))  # each hit point p + r·(cos, sin)(yaw + a), in floats
        discs.extend(arcs[-1])
    groups = _apart(discs[:len(clusters)])
    for g in groups:
        if len(g) > 1:  # one obstacle seen as several runs: as wide as all their hits
            pts = np.vstack([faces[k][0] for k in g])
            spread = max(float(np.max(np.hypot(*(pts - q).T))) for q in pts)
            seen = max(seen, spread / 2 - max(faces[k][1] for k in g))
    places = tuple(Place(tuple(discs[k] for k in g), (min(clusters[k][0][0] for k in g),
                                                     max(clusters[k][-1][0] for k in g), clusters[g[0]][0][2]))
                   for g in groups) + tuple(Place(arc) for arc in arcs)
    if not all(narrow):
        discs = [d for k, d in enumerate(discs) if k >= len(narrow) or narrow[k]]
    return Seen(discs, seen, places)


def _holding(centre, radius: float, pts) -> float:
    """The radius, grown from `radius` if need be, of the disc about `centre` that holds every point of `pts`."""
    return radius + max(0.0, float(np.max(np.hypot(*(np.asarray(pts) - centre).T))) - radius)


def _apart(discs: list[Disc]) -> int:
    """How many obstacles the bins' discs tell apart: discs that overlap are one obstacle (a column whose middle
    bins returned nothing gives two runs of bins, and two discs that overlap)."""
    root = list(range(len(discs)))

    def find(k: int) -> int:
        while root[k] != k:
            k = root[k]
        return k
    for a in range(len(discs)):
        for b in range(a + 1, len(discs)):
            if math.hypot(discs[a].x - discs[b].x, discs[a].y - discs[b].y) < discs[a].r + discs[b].r:
                root[find(b)] = find(a)
    groups: dict[int, list[int]] = {}
    for k in range(len(discs)):
        groups.setdefault(find(k), []).append(k)
    return list(groups.values())


def new_obstacles(discs, known) -> list[Disc]:
    """The discs of obstacles not among `known`: whose centre lies within no known disc (a disc that moved as its
    obstacle was seen better is the same obstacle)."""
    return [d for d in discs if not any(math.hypot(d.x - k.x, d.y - k.y) <= max(d.r, k.r) for k in known)]


def inflated(discs: list[Disc], e_tr: float, r_body: float) -> list[Disc]:
    """The same discs grown by E_tr + r_body (the virtual obstacle of Figure 13); the vehicle may use
    the E_tr part (`Disc.r_min` keeps the rest)."""
    return [Disc(d.x, d.y, d.r + e_tr + r_body, d.r + r_body) for d in discs]


def slow_aim(heading: float | None, want) -> tuple[float | None, bool]:
    """The yaw for a slow reference velocity `want` of a rejoin (above TURN_FIRST_SPEED, at most walking pace;
    None otherwise: `OffboardGuidance._yaw` decides, which looks along the route for so slow a reference) — along
    it — and whether the reference is to creep until the heading has turned to it (more than HEADING_TOL off the
    measured heading). Below walking pace the cycle takes D_od along the heading until the vehicle has crept out
    of view farther than E_tr (companion/onboard/ahead.py `Creep`): the daemon does not fly that creep itself."""
    speed = float(np.hypot(*want))
    if not TURN_FIRST_SPEED < speed <= TRAVEL_SPEED_M_S:
        return None, False
    aim = math.atan2(want[1], want[0])
    return aim, heading is not None and abs(wrap(heading - aim)) > HEADING_TOL


@dataclass
class Setpoint:
    p: np.ndarray  # (x, y) NED [m]
    v: np.ndarray
    a: np.ndarray
    z: float
    yaw: float
    mode: str  # "cruise", "avoid", "brake", "planning" (braking for the first plan), "hold", "done"


def reference_jump(prev: Setpoint, dt: float, sp: Setpoint, p) -> float:
    """How much farther from the vehicle (at p) the reference `sp` is than the previous one, `prev`, flown on for dt
    at its velocity and acceleration would be [m]: 0 for a reference that flies on from where it was, or jumps towards
    the vehicle (a stop planned from the measured state, the cruise rejoining where the vehicle is)."""
    on = np.asarray(prev.p, float) + np.asarray(prev.v, float) * dt + 0.5 * np.asarray(prev.a, float) * dt * dt
    return max(math.dist(sp.p, p) - math.dist(on, p), 0.0)


def plan_job(planner, epoch, t_req, omega, *args, **kw):
    """One planning job, whoever runs it: (epoch, t_req, Ω, the plan — or the exception, which means brake)."""
    try:
        return epoch, t_req, omega, planner.plan(*args, **kw)
    except Exception as e:  # noqa: BLE001 — any planner failure means: brake
        return epoch, t_req, omega, e


class InlinePlanning:
    """Plans at once in the caller's thread (lock-step tests: deterministic in vehicle time, so no
    wall-clock budget either)."""

    busy = False
    deferred = False  # the answer is there when `submit` returns
    budget_s = None  # no wall-clock budget for the planner

    def __init__(self):
        self._out = None

    def submit(self, planner, *args, **kw) -> None:
        self._out = plan_job(planner, *args, **kw)

    def poll(self):
        out, self._out = self._out, None
        return out

    def close(self) -> None:
        pass


class ThreadedPlanning:
    """One planning job at a time on a worker thread, so the setpoint stream keeps its rate while OSQP
    solves. The planner's own Python work (the QP's assembly, the exact check) holds the interpreter lock,
    though: on a busy host the loop waits for it (`ProcessPlanning` does not)."""

    deferred = True  # the answer comes later than asked (`poll` once it is done)
    budget_s = PLAN_BUDGET_S  # the planner's wall-clock budget per job

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cg-planner")
        self._job: Future | None = None
        self._meta: tuple = ()

    @property
    def busy(self) -> bool:
        return self._job is not None and not self._job.done()

    def submit(self, planner, *args, **kw) -> None:
        self._meta = args[:3]
        self._job = self._pool.submit(plan_job, planner, *args, **kw)

    def close(self) -> None:
        """No more jobs: the worker ends (a job in progress is dropped)."""
        self._pool.shutdown(wait=False, cancel_futures=True)

    def poll(self):
        if self._job is None or not self._job.done():
            return None
        job, self._job = self._job, None
        try:
            return job.result()  # the job itself turns a planner failure into its answer
        except Exception as e:  # noqa: BLE001 — the runner failed (a worker process died): brake
            return (*self._meta, e)


_WORKER_PLANNERS: dict = {}  # in a planning process: its planners, by their parameters


def _worker_ready() -> None:
    """The planning process's start: the solver loaded, and this module with it — the jobs' entry point, else
    imported at the first job (0.16 s here unloaded, 0.3–0.4 s beside two busy processes: the first obstacle's
    plan came that much later)."""
    load_solver()


def _plan_in_worker(key, *args, **kw):
    """`plan_job` in the planning process, with its own planner of these parameters (kept: its solvers warm)."""
    planner = _WORKER_PLANNERS.get(key)
    if planner is None:
        planner = _WORKER_PLANNERS[key] = AvoidancePlanner(*key)
    return plan_job(planner, *args, **kw)


class ProcessPlanning(ThreadedPlanning):
    """One planning job at a time in a worker process of its own (started at once, its solver loaded), so no
    planning work shares the loop's interpreter lock. On a thread, the planner's Python work held that lock
    while the host descheduled it, and the loop's cycles came late exactly while it avoided an obstacle (two
    busy processes beside a 50 Hz loop and a planning thread: 72-177 of ~1000 cycles more than 20 ms late,
    none or 4 without the thread). The worker plans with an `AvoidancePlanner` of the same parameters; a worker
    that dies is a failed plan (brake), and the next job starts a new one."""

    def __init__(self):
        import multiprocessing

        self._ctx = multiprocessing.get_context("spawn")  # never fork a process that has threads
        self._pool = self._start()
        self._job = None
        self._meta = ()
        # the worker's start-up (its own interpreter, numpy, scipy, OSQP: seconds of CPU on a busy 2-core host) is
        # waited for here, before the loop runs: started beside a running loop it made the loop's first judged
        # cycles 50-110 ms late (guidance violations at every demo's take-off with two busy processes beside it)
        try:
            self._warm.result(timeout=WORKER_START_S)
        except Exception:  # noqa: BLE001 — not ready or broken: the first job finds out (a failed plan: brake)
            pass

    def _start(self) -> ProcessPoolExecutor:
        pool = ProcessPoolExecutor(max_workers=1, mp_context=self._ctx, initializer=_worker_ready)
        self._warm = pool.submit(_worker_ready)  # start the worker now, not at the first obstacle
        return pool

    def submit(self, planner, *args, **kw) -> None:
        self._meta = args[:3]
        key = (planner.n, planner.scp_iters, (planner.w_v, planner.w_y, planner.w_vy, planner.w_a))
        try:
            self._job = self._pool.submit(_plan_in_worker, key, *args, **kw)
        except RuntimeError:  # the worker died (BrokenProcessPool): a new one
            self._pool = self._start()
            self._job = self._pool.submit(_plan_in_worker, key, *args, **kw)


@dataclass
class OffboardGuidance:
    route: Route
    planner: AvoidancePlanner = field(default_factory=AvoidancePlanner)
    planning: InlinePlanning | ThreadedPlanning = field(default_factory=InlinePlanning)
    plan: Plan | None = None
    plan_t: float = 0.0
    plan_held: float = 0.0  # [s] the pass's clock held back while the vehicle flew above V_max (`_follow`)
    plan_omega: tuple[float, float] | None = None
    s_ref: float = 0.0  # along-track position of the cruise reference
    v_ref: float = 0.0  # speed of the cruise reference
    y_off: float = 0.0  # lateral offset of the cruise reference from the route (rejoining after a pass)
    vy_off: float = 0.0
    # the rest of its offset, which neither s_ref nor y_off can take: beyond the route's ends, outside a sharp corner
    off: np.ndarray = field(default_factory=lambda: np.zeros(2))
    v_off: np.ndarray = field(default_factory=lambda: np.zeros(2))
    replans: int = 0
    kept: int = 0  # replans that failed while a verified plan was still being flown
    plan_t_try: float = -1e9
    plan_times: list = field(default_factory=list)
    rejected: int = 0
    last_notes: list = field(default_factory=list)
    epoch: int = 0  # bumped whenever the obstacle situation ends: older planning jobs are not flown
    planner_failed: bool = False  # the last job raised: braking is not "awaiting" but the answer
    latencies: list = field(default_factory=list)  # how long each answer of the flight took, request to poll [s]
    lead_s: tuple[float, float] = PLAN_LEAD_S  # (0, 0): plans start at the state measured at the request
    _pending: tuple | None = None  # an answer that starts later than now (asked for while braking)
    _asked_t: float = 0.0
    _asked_discs: tuple = ()  # the discs the last plan asked for goes round
    _walls: tuple = ()  # this cycle's discs a plan keeps out of too (`step`)
    _in_way: tuple = ()  # this cycle's discs in the way (`step`)
    _swerving: bool = False  # offboard swerves under the stop contract (`step`'s walls given)
    _asked_walls: tuple = ()  # those the last plan asked for keeps out of
    _v_meas: np.ndarray = field(default_factory=lambda: np.zeros(2))  # the measured velocity this cycle
    _rate: float = 1.0  # how fast a pass's clock runs while the heading turns to it (`_follow`)

    def start(self, p, v) -> None:
        self.s_ref = self.route.project(p)
        self.v_ref = float(np.hypot(*v))
        self.plan = None
        self.epoch += 1
        self._rejoin_from(p, v)

    def path_ahead(self, t: float) -> tuple[tuple[float, float], ...]:
        """The points the setpoints ahead fly through from their reference at t on: the plan in force (a pass round
        the keep-out discs, then the route from where it ends; a stop, or the braking while a plan is computed, up to
        where it rests), else the route from the cruise reference — each up to PATH_AHEAD_M along the route, or its
        end (where the reference rests)."""
        plan, tau = self.plan, self._tau(t)
        if plan is None or tau >= plan.t[-1]:
            return self._route_from(self.s_ref)
        k = int(np.searchsorted(plan.t, tau, side="right"))
        pts = tuple((float(x), float(y)) for x, y in (plan.sample(tau)[0], *plan.p[k:]))
        if float(np.hypot(*plan.v[-1])) <= 0.1:
            return pts
        return pts + self._route_from(self.route.project(plan.p[-1]))

    def _route_from(self, s0: float) -> tuple[tuple[float, float], ...]:
        """Points of the route from along-track s0 on, every PATH_STEP_M, up to PATH_AHEAD_M or its end."""
        s1 = min(s0 + PATH_AHEAD_M, self.route.length)
        return tuple((float(q[0]), float(q[1])) for q in
                     (self.route.point(s)[0] for s in (*np.arange(s0, s1, PATH_STEP_M), s1)))

    def _rejoin_from(self, p, v) -> None:
        """Start the cruise reference where the vehicle is: beside the route if it is beside it, and before its start,
        past its end or outside a sharp corner (a pass that ends there) where it is too, not on the route's nearest
        point (a reference metres off the vehicle is flown to at the whole a_max, out of the sensors' view)."""
        s = self.route.project(p)
        base, u = self.route.point(s)
        n = np.array([-u[1], u[0]])
        d, v = np.asarray(p, float) - base, np.asarray(v, float)
        self.y_off, self.vy_off = float(d @ n), float(v @ n)
        along = float(d @ u)
        if abs(along) <= ON_ROUTE_M:  # on the route (at its start, as engaged there)
            along = 0.0
        beyond = s >= self.route.length - 1e-9 and along > 0.0  # past the end: its speed along is the offset's too
        self.off = u * along
        self.v_off = u * max(float(v @ u), 0.0) if beyond else np.zeros(2)
        self.v_ref = 0.0 if beyond else max(float(v @ u), 0.0)

    def step(self, t: float, dt: float, p, v, v_max: float, a_max: float, discs: list[Disc],
             yaw: float | None = None, walls: tuple[Disc, ...] | None = None) -> Setpoint:
        """One cycle: the setpoint for now (t), given the vehicle's state (`yaw`: its measured heading,
        if known) and Ω = (v_max, a_max). `walls`: keep-out discs a plan round `discs` must also keep out of,
        which are never a reason to plan (the hit points of what is wider than R_obst), given while offboard swerves
        under the stop contract (None: the avoid contract's plans). A plan goes round the discs in the way
        (`_threats`) and keeps out of every other disc and wall."""
        p, v = np.asarray(p, float), np.asarray(v, float)
        self._v_meas = v if np.all(np.isfinite(v)) else np.zeros(2)
        z = -self.route.altitude_m
        self._swerving = walls is not None
        # a disc the pass in force goes into is in the way too, wherever it is (more of a corner come into view beside
        # the route): planned round at once, not judged against the pass by the hold
        ahead = self._threats(p, v, discs) or (self._entered(t, p, discs) if self._swerving else [])
        self._walls = (*(walls or ()), *self._others(discs, ahead))
        self._in_way = tuple(ahead)
        if ahead:
            return self._avoid(t, dt, p, v, (v_max, a_max), ahead, z, yaw)
        self.epoch += 1  # a plan still being computed for an obstacle no longer ahead is not flown
        if self.plan is not None and self.plan.kind == "pass" and self._tau(t) < self.plan.t[-1] \
                and not self._past_the_profile(t, p, v_max, a_max) and not self._past_the_leg(t):
            return self._follow(t, dt, z, v_max, a_max, yaw)  # finish going round the obstacle before rejoining
        if self.plan is not None:  # done with it: rejoin the route smoothly from where the plan ends
            end_p, end_v, _ = self.plan.sample(self._tau(t))
            self.s_ref = self.route.project(end_p)
            self._rejoin_from(end_p, end_v * self._rate)
            self.plan, self._rate = None, 1.0
        return self._cruise(dt, p, v_max, a_max, z, yaw)

    # ---------------------------------------------------------------- cruising
    def _cruise(self, dt, p, v_max, a_max, z, heading=None) -> Setpoint:
        route = self.route
        s_here = route.project(p, self.s_ref - 3.0, self.s_ref + 3.0)
        if self.s_ref < s_here - 1.0 or self.s_ref > s_here + 2.0:
            self.s_ref = s_here  # rejoin where the vehicle is
        # lateral offset back to the route: critically damped, peak lateral acceleration ≤ a_max/2
        w = math.sqrt(0.5 * a_max / max(abs(self.y_off), 0.2))
        ay = -2.0 * w * self.vy_off - w * w * self.y_off
        # sideways no faster than keeps the reference's direction within SIDE_DEG of the route, or its whole
        # speed below SIDE_SLOW: slow and sideways (rejoining at a route's end) the track left the sensor's
        # view. A floor on the sideways speed alone (0.7 m/s) let the along-track
        # speed fall to 0 under it: the track swung 40° → 80° off the heading at 1.1 m/s, faster than the
        # yaw (≈ 45°/s flown) could follow, where the sensor had seen under a metre free: no safe speed.
        cap = max(self.v_ref * math.tan(math.radians(SIDE_DEG)), math.sqrt(max(SIDE_SLOW ** 2 - self.v_ref ** 2, 0.0)))
        vy = min(max(self.vy_off + ay * dt, -cap), cap)
        _, u = route.point(self.s_ref)
        n = np.array([-u[1], u[0]])
        # rejoining from beside the route below walking pace: the yaw on the way the reference goes; with the heading
        # off it, turn first, creeping
        w_off = self._w_off(a_max)
        want_off = self.v_off - (2.0 * w_off * self.v_off + w_off ** 2 * self.off) * dt
        rejoin = abs(self.y_off) > ON_ROUTE_M or float(np.hypot(*self.off)) > ON_ROUTE_M
        aim, turning = slow_aim(heading, u * self.v_ref + n * vy + want_off) if rejoin else (None, False)
        if turning:
            cap = max(self.v_ref * math.tan(math.radians(SIDE_DEG)),
                      math.sqrt(max(TURN_FIRST_SPEED ** 2 - self.v_ref ** 2, 0.0)))
        a_off = self._close_off(want_off, dt, a_max, min(TURN_FIRST_SPEED if turning else SIDE_SLOW, v_max))
        # a sideways speed above the cap (a pass handed over sideways) slows at A_SIDE·a_max, as the offset is flown
        # (clipped at once, the setpoint's acceleration would be the whole step in one cycle, tens of m/s²)
        step = A_SIDE * a_max * dt
        vy = float(np.clip(np.clip(vy, -cap, cap), self.vy_off - step, self.vy_off + step))
        ay = (vy - self.vy_off) / dt if dt > 0 else 0.0
        self.vy_off = vy
        self.y_off += self.vy_off * dt
        # along the path: the speed profile, and no speeding up until the heading is on the yaw wanted
        stretch = max(1.0 - route.curvature(self.s_ref) * self.y_off, 0.1)  # path speed at the offset / v_ref
        limit = min(route.speed_limit(self.s_ref, v_max, a_max),
                    route.speed_limit(self.s_ref + self.v_ref * dt, v_max, a_max))
        if abs(self.y_off) > REJOIN_OPEN_M:  # still beside the route: slow gently for the stop ahead, so the
            # vehicle does not overshoot it and come back outside the sensor's view
            limit = min(limit, math.sqrt(2 * A_REJOIN_STOP * a_max * max(route.next_stop(self.s_ref) - self.s_ref, 0.0)))
        # the vehicle flown above V_max (catching up with a reference ahead of it, overshooting a speed-up) gives the
        # excess back: the reference's budget shrinks by it, so the ground speed, not only the reference, stays ≤ V_max
        budget = max(v_max - GIVE_BACK * self._excess(math.hypot(self.v_ref * stretch, self.vy_off), v_max), 0.0)
        target = min(math.sqrt(max(budget * budget - self.vy_off * self.vy_off, 0.0)) / max(stretch, 1.0), limit)
        up = 0.5 * a_max * dt
        if heading is not None and abs(wrap(heading - self._yaw(u * self.v_ref * stretch + n * self.vy_off, u))) \
                > HEADING_TOL:
            up = 0.0  # turn first
        dv = max(min(target - self.v_ref, up), -a_max * dt)
        acc = dv / dt if dt > 0 else 0.0
        self.v_ref = max(self.v_ref + dv, 0.0)
        stop = route.next_stop(self.s_ref)
        self.s_ref += self.v_ref * dt
        if self.s_ref >= stop:  # a sharp corner or the end: arrive there at rest
            self.s_ref, self.v_ref, acc = stop, 0.0, 0.0
        pos, u = route.point(self.s_ref)
        n = np.array([-u[1], u[0]])
        k = route.curvature(self.s_ref)
        stretch = max(1.0 - k * self.y_off, 0.1)
        vel = u * self.v_ref * stretch + n * self.vy_off
        # exact acceleration of the offset point: tangential, Coriolis-like, centripetal (v²/R) and lateral
        a_vec = u * (stretch * acc - 2 * k * self.vy_off * self.v_ref) + n * (stretch * k * self.v_ref ** 2 + ay)
        vel, a_vec = vel + self.v_off, a_vec + a_off
        arrived = self.s_ref >= route.length - 1e-9 and abs(self.y_off) <= ON_ROUTE_M \
            and float(np.hypot(*self.off)) <= ON_ROUTE_M  # at rest, on the route
        if rejoin and not turning:  # (while turning: where the reference is to go, not its creep)
            aim, _ = slow_aim(None, vel)
        yaw = self._yaw(vel, u) if aim is None else aim
        return Setpoint(pos + n * self.y_off + self.off, vel, a_vec, z, yaw, "done" if arrived else "cruise")

    def _w_off(self, a_max: float) -> float:
        """The rate the offset the route cannot take closes at: critically damped as the lateral offset."""
        return math.sqrt(0.5 * a_max / max(float(np.hypot(*self.off)), 0.2))

    def _close_off(self, want, dt: float, a_max: float, cap: float) -> np.ndarray:
        """That offset flown back to the route at the velocity `want` (its damped law's), no faster than `cap`, the
        velocity changing at A_SIDE·a_max; its acceleration."""
        if not (self.off.any() or self.v_off.any()) or dt <= 0:
            return np.zeros(2)
        speed = float(np.hypot(*want))
        want = want * (cap / speed) if speed > cap else want
        dv = want - self.v_off
        step, size = A_SIDE * a_max * dt, float(np.hypot(*dv))
        dv = dv * (step / size) if size > step else dv
        self.v_off = self.v_off + dv
        self.off = self.off + self.v_off * dt
        if float(np.hypot(*self.off)) < 1e-3 and float(np.hypot(*self.v_off)) < 1e-2:
            self.off, self.v_off = np.zeros(2), np.zeros(2)
        return dv / dt

    def _yaw(self, vel, u) -> float:
        """The heading to fly: along the commanded velocity, plus — when that is slow — the measured one
        (weight 1 at rest, 0 from YAW_MEAS_BELOW), when the sum is above 2·YAW_SPEED, else along the route
        ahead. The sensor looks where the vehicle goes (the contract's D_od is along the measured velocity)
        and where it is told to go. The commanded velocity alone let a slow vehicle's track run 30° and more
        off the heading while it lagged a slow reference (overshooting a route's end after a pass, drifting
        back: D_od 0, no safe speed); the measured one at speed made the X500 lag its
        avoidance pass beyond E_tr_pred."""
        vel = np.asarray(vel, float)
        d = vel + max(0.0, 1.0 - float(np.hypot(*vel)) / YAW_MEAS_BELOW) * self._v_meas
        d = d if float(np.hypot(*d)) > 2 * YAW_SPEED else u
        return math.atan2(d[1], d[0])

    # ---------------------------------------------------------------- avoiding
    def _threats(self, p, v, discs) -> list[Disc]:
        """Discs the route ahead (or the current motion) would run into: within 0.5 m of the line from the vehicle
        along the leg it is on, as far as that leg goes straight; beyond the leg's turn, within 0.5 m of the route
        there widened by the vehicle's offset from the route now (the reference turns with the route: a disc beyond
        the turn on the leg's line, a piece of a corridor's far wall, is not in the way, and a swerve round it planned
        straight on would go through the side wall). On the route's last leg, within 0.5 m of the way from the vehicle
        to the route's end, where it rests (a corridor's corner beyond the end is not in the way: a pass round it,
        its cruise speed beyond the end 0, ran 50 m out through the wall)."""
        if not discs:
            return []
        route = self.route
        s = route.project(p)
        base, u = route.point(s)
        off = abs(float((p - base) @ np.array([-u[1], u[0]])))
        straight = route.straight_left(s)
        end = route.end_ahead(s)
        out = []
        for d in discs:
            c = np.array([d.x, d.y])
            rel = c - p
            along = float(rel @ u)
            if along <= -d.r:
                continue
            if end is not None:
                near = distance_to_polyline(c, np.array([p, end])) < d.r + 0.5
            elif along - d.r <= straight:
                near = abs(float(rel[0] * u[1] - rel[1] * u[0])) < d.r + 0.5
            else:
                q, _ = route.point(route.project(c, lo=s))
                near = float(np.hypot(*(c - q))) < d.r + 0.5 + off
            if near:
                out.append(d)
        return out

    @staticmethod
    def _others(discs, ahead) -> tuple[Disc, ...]:
        """The discs a plan round those in the way (`ahead`) keeps out of as well: every other one (a pole of a stand
        beside the route is no reason to swerve, but the swerve round its neighbour on the route must not go through
        it)."""
        return tuple(d for d in discs if d not in ahead)

    def _avoid(self, t, dt, p, v, limits, discs, z, heading=None) -> Setpoint:
        """Replan when an obstacle appears (no plan), every REPLAN_S, and — at most every REPLAN_MIN_S —
        when Ω changes, the vehicle drifts from the plan or it is braking. A plan starts at the state
        measured when it was asked for, so it is followed from its request time. While the first plan is
        computed the vehicle brakes, and a plan asked for while braking starts where that braking will have
        taken the vehicle when the answer is due (`_lead`), flown from then: a plan from the state before the
        braking, flown from its request, left the vehicle behind it by the braking's lost speed (a controller
        violation at the demo's first obstacle in fog on a loaded host)."""
        self._take(t, self.planning.poll())
        v_max, a_max = limits  # Ω's (V_max, a_max)
        omega = (round(v_max, 3), round(a_max, 3))
        since = t - max(self.plan_t, self.plan_t_try)
        urgent = False
        if self.plan is None:  # no plan yet: start braking now (the slower choice)
            bp, bv, ba, bts, _ = best_stop(np.array(p, float), np.array(v, float), a_max, [*discs, *self._walls],
                                           self.planner.n)
            kind = "brake" if self.planner_failed else "await"  # a planner that fails is not awaited
            self.plan = Plan(kind, np.arange(len(bp)) * bts, bp, bv, ba, False, -math.inf)
            self.plan_t, self.plan_held, self.plan_omega, since = t, 0.0, omega, math.inf
        else:
            drift = float(np.hypot(*(self.plan.sample(self._tau(t))[0] - p)))
            urgent = self.plan.kind in ("brake", "await") or omega != self.plan_omega or drift > DRIFT_M
        # swerving under the stop contract, something the plan was not asked to keep out of, or a keep-out the plan now
        # goes into (more of an obstacle come into view): at once (the hold judges the plan's path from the next cycle)
        unknown = self._swerving and bool(new_obstacles(discs, self._asked_discs) or
                                          new_obstacles(self._walls, self._asked_walls) or
                                          self._entered(t, p, [*discs, *self._walls]))
        if (since > REPLAN_S or urgent and since > REPLAN_MIN_S or unknown) and not self.planning.busy:
            t_req, p_req, v_req = t, np.array(p, float), np.array(v, float)
            if self.plan.kind in ("brake", "await") and self.planning.deferred:
                t_req = t + self._lead()
                p_req, v_req, _ = self.plan.sample(self._tau(t_req))
            u = self._plan_direction(p_req, discs)
            # (among walls a plan is not warm-started: the side it went round the points then seen may be the wall's)
            warm = self.plan if self.plan.kind in ("pass", "stop") and not self._walls else None
            self.plan_t_try, self._asked_t, self._asked_discs, self._asked_walls = t_req, t, tuple(discs), self._walls
            self.planning.submit(self.planner, self.epoch, t_req, omega, p_req, v_req, u,
                                 [*discs, *self._walls], v_max=v_max, a_max=a_max,
                                 v_cruise=self._pass_speed(discs, v_max, a_max),
                                 along=bool(self._walls) if self._swerving else None,
                                 warm=warm, elapsed=self._tau(t), budget_s=self.planning.budget_s)
            self._take(t, self.planning.poll())
        return self._follow(t, dt, z, v_max, a_max, heading)

    def _entered(self, t: float, p, keep_out) -> list[Disc]:
        """The keep-out discs the pass or stop in force goes, from now on, more than ENTER_TOL_M into (one grown or
        moved since it was planned); a disc the vehicle is in (its E_tr allowance, where a plan may start) does not
        count."""
        plan = self.plan
        if plan is None or plan.kind not in ("pass", "stop"):
            return []
        ahead = plan.p[plan.t > self._tau(t)]
        return [d for d in keep_out if math.hypot(p[0] - d.x, p[1] - d.y) >= d.r and
                float(np.min(np.hypot(ahead[:, 0] - d.x, ahead[:, 1] - d.y))) < d.r - ENTER_TOL_M] if len(ahead) else []

    def stopped_short(self, p) -> float | None:
        """While the plan in force stops the vehicle short of what is in the way (the planner's stop: no pass it could
        prove; or braking with no plan): the room left before the body touches the nearest of it [m]; else None."""
        if not self._in_way or self.plan is None or self.plan.kind == "pass":
            return None
        return min(math.hypot(p[0] - d.x, p[1] - d.y) - (d.r if d.r_min is None else d.r_min) for d in self._in_way)

    def _plan_direction(self, p, discs) -> np.ndarray:
        """The direction a pass from p round `discs` is planned along: the route's where the vehicle is, or on a
        turn's arc, where the nearest obstacle is (a pass is straight: one planned along the arc went straight on
        across the turn towards the wall beyond it)."""
        s = self.route.project(p)
        if self.route.curvature(s):
            s = max(s, min(self.route.project((d.x, d.y)) for d in discs))
        return self.route.point(s)[1]

    def _lead(self) -> float:
        """How far ahead a plan asked for while braking starts: the slowest of the last answers' latencies,
        within PLAN_LEAD_S (an answer later than its start is flown from its start: the vehicle then lags it
        by the braking since, as before)."""
        return min(max([self.lead_s[0], *self.latencies[-5:]]), self.lead_s[1])

    def _take(self, t: float, done) -> None:
        """An answer from the planning, or the one held until its start time has come."""
        if done is not None and done[0] == self.epoch and self.planning.deferred:
            self.latencies.append(t - self._asked_t)
        if done is not None and done[1] > t:
            self._pending = done  # asked for while braking: fly it from where the braking leaves the vehicle
            return
        if done is None and self._pending is not None and self._pending[1] <= t:
            done, self._pending = self._pending, None
        self._adopt(done)

    def _past_the_profile(self, t: float, p, v_max: float, a_max: float) -> bool:
        """Whether the pass being finished, its obstacle behind the vehicle along the route, flies faster than the
        route's speed profile at half its braking allows — then the vehicle rejoins now and slows for what is ahead
        (the route's end, a corner). Finishing a 3.5 s pass at 6 m/s 2 m before the end overshot it; a pass left
        beside a pole that had gone out of view, the rejoin cut back across its keep-out (0.02 m from contact)."""
        s_here = self.route.project(p)
        if any(self.route.project((d.x, d.y)) + d.r > s_here for d in self._asked_discs):
            return False
        pos, vel, _ = self.plan.sample(self._tau(t))
        return float(np.hypot(*vel)) > float(self.route.speed_limit(self.route.project(pos), v_max, 0.5 * a_max))

    def _past_the_leg(self, t: float) -> bool:
        """Whether the pass being finished (its obstacle behind) has reached where the route turns from the
        direction it was planned along (an arc, a sharp corner): a pass is straight along the route where it was
        asked for and ends about twice the obstacle's distance on; flown past the turn it leaves the route (a
        corridor's turn: straight on towards its end wall)."""
        route = self.route
        _, u0 = route.point(route.project(self.plan.p[0]))
        _, u = route.point(route.project(self.plan.sample(self._tau(t))[0]))
        return float(u0 @ u) < math.cos(math.radians(LEG_TURN_DEG))

    def _pass_speed(self, discs, v_max: float, a_max: float) -> float:
        """The speed a pass ends at: what the route's speed profile allows beyond the farthest disc, at half
        the braking the cruise reference uses (the rest is for rejoining the route sideways). A pass that
        ended at V_max 2 m before the route's end overshot it by 2–5 m and drifted back outside the
        sensor's view."""
        s_far = max(self.route.project((d.x, d.y)) + d.r for d in discs)
        return float(self.route.speed_limit(s_far, v_max, 0.5 * a_max))

    def _adopt(self, done) -> None:
        """Take a finished plan of the current obstacle situation; a failed one never replaces a
        verified plan still in progress."""
        if done is None or done[0] != self.epoch:
            return
        _, t_req, omega, new = done
        if self.plan is not None and t_req < self.plan_t:
            return  # older than the plan being flown
        if isinstance(new, BaseException):
            self.last_notes = [f"planner error: {new!r}"[:200]]
            self.planner_failed = True
            if self.plan is not None and self.plan.kind == "await":
                self.plan = Plan("brake", self.plan.t, self.plan.p, self.plan.v, self.plan.a, False, -math.inf)
            return
        self.planner_failed = False
        self.replans += 1
        self.plan_times.append(new.solve_s)
        self.rejected += new.rejected
        self.last_notes = new.notes
        if keeps_plan(self.plan, self._tau(t_req), new):  # keep flying the verified plan in progress
            self.kept += 1
        else:
            self.plan, self.plan_t, self.plan_held, self.plan_omega = new, t_req, 0.0, omega

    def _excess(self, ref_speed: float, v_max: float) -> float:
        """How much faster than V_max the vehicle flies because it outruns its reference (catching up with it, or
        overshooting a speed-up): the ground speed's excess over both. A V_max that just fell is not this: the
        reference slows (the cruise's braking, a replan) and the vehicle with it."""
        speed = float(np.hypot(*self._v_meas))
        return max(min(speed - v_max, speed - ref_speed), 0.0)

    def planning_summary(self) -> dict:
        """How the plans came (the `planning` event at the loop's end): answers, how late the first came — the
        first obstacle's, asked for at first sight — and the median and the slowest, request to poll in the
        guidance's own time [s] (None: no answer was waited for); plans flown, failed replans that kept the verified
        plan in force, plans the exact check rejected."""
        lat = self.latencies
        return {"answers": len(lat), "first_s": round(lat[0], 3) if lat else None,
                "median_s": round(float(np.median(lat)), 3) if lat else None,
                "max_s": round(max(lat), 3) if lat else None, "replans": self.replans, "kept": self.kept,
                "rejected": self.rejected}

    def _tau(self, t: float) -> float:
        """Where in the plan being flown the reference is at time t (its own clock)."""
        return t - self.plan_t - self.plan_held

    def _stop_turning_first(self, vel, acc, speed, turning, a_max, dt):
        """A stop's reference (the planner's; from rest it may lead back out of a keep-out disc, away from the heading)
        slowed on its path to TURN_FIRST_SPEED (at half a_max) while the measured heading is more than HEADING_TOL off
        its direction, the yaw on that direction (`_follow`), and back at the plan's own speed once the heading is on
        it: the sensor looks where the vehicle is to go before it goes. Backed away unturned, the direction of travel
        left the view: "no safe speed", a Hold with nothing in the way."""
        want = TURN_FIRST_SPEED / speed if turning else 1.0
        self._rate = float(np.clip(want, self._rate - 0.5 * a_max * dt / max(speed, 0.1), 1.0))
        self.plan_held += (1.0 - self._rate) * dt
        return vel * self._rate, acc * self._rate ** 2

    def _follow(self, t, dt, z, v_max, a_max, heading=None) -> Setpoint:
        """The plan's reference now. A pass's clock slows while the vehicle flies above V_max (catching up with a
        reference it lags, it overshoots the plan's speed): by the excess over the reference's speed, so the path
        (clear of every keep-out disc) is the same and its speed, the feed-forward's with it, is lower. Swerving
        under the stop contract, it slows too while the measured heading is more than HEADING_TOL off the pass's
        direction, to TURN_FIRST_SPEED (changing speed at half a_max), the yaw on that direction: the pass turns
        the velocity faster than the heading follows, and the direction of travel left the sensor's view (D_od 0,
        no safe speed, at a corridor's turn and beside a column). A pass faster than the V_max now in force slows on
        the same path to V_max, at half a_max too."""
        pos, vel, acc = self.plan.sample(self._tau(t))
        speed = float(np.hypot(*vel))
        aim = math.atan2(vel[1], vel[0]) if speed > TURN_FIRST_SPEED else None
        turning = self._swerving and heading is not None and aim is not None \
            and abs(wrap(heading - aim)) > HEADING_TOL
        if self.plan.kind == "stop" and dt > 0:
            vel, acc = self._stop_turning_first(vel, acc, speed, turning, a_max, dt)
        elif self.plan.kind != "pass":
            self._rate = 1.0
        elif dt > 0:
            slow = min(self._excess(speed, v_max) / max(speed, 0.1), PASS_SLOW_MAX)
            # a pass planned at a higher V_max than the one now in force (the stop contract come in mid-pass, no
            # replan found at the new one) is flown on along its path at V_max: slowed at half a_max, as for the turn
            # (the path is curved: braking along it at the whole a_max adds to the turn's acceleration)
            cap = v_max / speed if speed > v_max + PASS_OVER_VMAX_M_S else 1.0
            want = min(TURN_FIRST_SPEED / speed if turning else 1.0, cap)
            step = 0.5 * a_max * dt / max(speed, 0.1)
            self._rate = float(np.clip(want, self._rate - step, self._rate + step))
            slow = max(slow, 1.0 - self._rate)
            self.plan_held += slow * dt
            vel, acc = vel * (1.0 - slow), acc * (1.0 - slow) ** 2
        s_here = self.route.project(pos)
        _, u = self.route.point(s_here)
        yaw = aim if self._rate < 1.0 and aim is not None else self._yaw(vel, u)
        self.s_ref, self.v_ref = s_here, float(vel @ u)
        mode = {"pass": "avoid", "stop": "avoid", "brake": "brake", "await": "planning"}[self.plan.kind]
        return Setpoint(pos, vel, acc, z, yaw, mode)
