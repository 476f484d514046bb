"""The online avoidance planner: a convexified version of the paper's planner (eq. 14–19) on the
discretised flat dynamics (eq. 12–13), solved with OSQP (DESIGN.md §5, offboard mode). Pure maths, on
the ground floor (§3): the daemon's guidance plans with it, and the controller-contract sweep
(`sitl_harness.etr_sweep`, Figure 12) flies its plans.

Horizontal plane, constant altitude, in the route frame (x along the route). Decision variables are
the ZOH states q_k = (x, ẋ, y, ẏ), k = 0…N, and accelerations w_k, k = 0…N−1. Convexification:
- speed and total tilt (acceleration) as inscribed polygons: inner approximations, so every plan the
  QP returns satisfies the exact limits at the samples;
- the keep-out discs as half-planes, one per segment and disc, tangent to the disc inflated by the
  largest gap between a constant-acceleration arc and its chord (a·t_s²/8), imposed on both ends of
  the segment — a half-plane is convex, so the whole arc stays out of the disc — refined by a few
  sequential-convex iterations that re-linearise around the last solution.
Two plans are tried: **pass** (track the cruise speed, end beyond the obstacle moving along the
route) on either side, then **stop** (end at rest short of it); each is accepted only after an exact
check (dense re-simulation against the true discs, speed and acceleration norms). Braking at full
deceleration is the fallback that is always available. A plan may start inside a disc's E_tr
allowance (`admitted`: the vehicle may enter the virtual obstacle, Figures 13–16) but not go deeper;
`budget_s` stops further attempts once a replan has taken that long.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from contracts.flat import cone_polygon

# OSQP and scipy.sparse take ≈0.6 s to import, and only the planner needs them (not `Disc`, `offboard_cap`,
# `best_stop`, which the supervisor and a log review's shadow daemon use): imported by `load_solver`, from
# `AvoidancePlanner()` — and by a daemon starting in offboard mode, so its first plan does not stall the loop
osqp = sp = None


def load_solver() -> None:
    """Import the QP solver (OSQP) and scipy.sparse into this module, once."""
    global osqp, sp
    if osqp is None:
        import osqp as _osqp
        import scipy.sparse as _sp

        osqp, sp = _osqp, _sp

N_POLY = 16
# The factor on the avoid contract's speed at which this planner is shown to find a verified avoiding
# trajectory on 100 % of a seeded sample of table cells (tests/test_online_planner.py,
# benchmarks/bench_planner.py): the offboard contract flies at OFFBOARD_CAP × V_safe. Measured: 200/200 seeded
# cells per vehicle at 0.92–0.98 on two samples (seeds 0, 7), 199/200 at 0.99; 0.97 keeps one step below the
# largest value that held (the slower when unsure). The E_tr sweep flies its online plans at this cap.
OFFBOARD_CAP = 0.97
UNRECORDED_CAP = 0.92  # the cap a table whose E_tr_pred records none was flown at (built before the record)
REPLAN_S = 0.5  # [s] the offboard guidance refreshes an active plan this often (the E_tr sweep models it)
SUB_STEPS = 20  # dense re-simulation per interval for the exact check
MARGIN_M = 0.01  # kept from the discs in the QP, so solver tolerance never fails the exact check
SLACK_COST = 1e2  # per metre of keep-out violation in the first SCP iteration (×10 per iteration)
GUESS_CRUISE = 0.9  # a pass's first linearisation flies this fraction of the cruise speed (`_cold_guess`)
STOP_CREEP_M_S = 0.1  # a stop planned from slower than this may reach it (`_speed_caps`)
QP_TIGHTEN = 1e-3  # the QP's speed and acceleration polygons are shrunk by this fraction, so a solution within
# OSQP's tolerance still satisfies the exact limits (most failures near V_safe were a converged-to-ε
# brake-and-swerve sitting just outside the tilt limit)


@dataclass(frozen=True)
class Disc:
    """A keep-out disc (already R_obst + E_tr + r_body) in world coordinates. `r_min` is the part
    that may never be entered (R_obst + r_body); the rest, E_tr, is the controller's allowance."""

    x: float
    y: float
    r: float
    r_min: float | None = None  # None: no allowance, the whole disc is never entered


def pass_sides(local: list[Disc], v0, a_max: float) -> tuple[float, float]:
    """The two sides to pass on (+1: the route frame's +y), the nearer first: the side whose clear
    offset (beyond every disc's edge) is closer to where the sideways speed already carries the vehicle
    (its braking drift v_y·|v_y|/(2·a_max)). Trying a fixed side first passed a column 2.4 m to the left
    on its far side, a 6.5 m swerve, then reversed mid-pass past E_tr_pred (campaign flight 53)."""
    if not local:
        return (1.0, -1.0)
    drift = float(v0[1]) * abs(float(v0[1])) / (2.0 * max(a_max, 1e-3))
    up = max(d.y + d.r for d in local)  # the offset clear of every disc on the +y side
    down = min(d.y - d.r for d in local)
    return (1.0, -1.0) if abs(up - drift) <= abs(down - drift) else (-1.0, 1.0)


def _line_side(d: Disc) -> float:
    """The side of the route line a disc beside it is passed on: the line's (+1: the route frame's +y)."""
    return -1.0 if d.y > 0.0 else 1.0


def _across(d: Disc) -> bool:
    """Whether the route line (the frame's x axis) goes through the disc."""
    return abs(d.y) < d.r


def between_sides(local: list[Disc], one_side: bool = False) -> np.ndarray | None:
    """Per disc, the side to pass it on (+1: the route frame's +y) to go through the gap between the discs either
    side of the route line (each passed on the route line's side), or None where there is no such gap: discs on one
    side only (unless `one_side`: then those are passed on the route line's side too), one across the line, or the
    two sides' discs overlapping across it."""
    left = [d.y - d.r for d in local if d.y > 0.0]
    right = [d.y + d.r for d in local if d.y < 0.0]
    if not (left or right) or not one_side and not (left and right) or len(left) + len(right) < len(local) \
            or min(left, default=math.inf) <= max(right, default=-math.inf):
        return None
    return np.array([_line_side(d) for d in local])


def side_attempts(local: list[Disc], v0, a_max: float, along: bool | None) -> list:
    """The sides of the pass attempts (`pass_sides`' order), each one side for every disc or one per disc. Among walls
    (`along`) a pass goes round what lies across the route line on either side, but round what lies beside the line on
    the line's side (a wall's hit points are discs: going round one on its far side is going through the wall between
    the points seen, or behind it where the sensor saw none); with nothing across the line, no such attempt."""
    if not along:
        return list(pass_sides(local, v0, a_max))
    across = [d for d in local if _across(d)]
    return [np.array([side if _across(d) else _line_side(d) for d in local])
            for side in pass_sides(across, v0, a_max)] if across else []


def round_far_side(p, local: list[Disc], sides) -> bool:
    """Whether the path `p` (route frame) goes round a disc beside the route line on the side `sides` does not give it
    (within the disc's span along the route): the SCP may drift there from the side it was started on."""
    for d, side in zip(local, sides):
        if not _across(d):
            near = np.abs(p[:, 0] - d.x) <= d.r
            if np.any((p[near, 1] - d.y) * side < 0.0):
                return True
    return False


def pass_horizon(far: float, speed0: float, v_cruise: float, a_max: float) -> float:
    """[s] A pass's horizon: the time to get twice as far as the farthest keep-out's edge (`far` ahead) at the cruise
    speed, and to reach that speed from the speed now (at least 1.5 s)."""
    return max(1.5, 2.0 * far / max(v_cruise, 0.3) + max(v_cruise - speed0, 0.0) / max(a_max, 1e-3))


def _side_name(side) -> str:
    """A pass attempt's side in the planner's notes: +, -, between (one side per disc) or none."""
    if np.ndim(side):
        return " between"
    return "+" if side > 0 else "-" if side < 0 else ""


def admitted(discs: list[Disc], p0, gap: float) -> tuple[list[Disc], list[str]]:
    """The discs a plan starting at `p0` must keep out of (paper, Figures 13–16: the vehicle may enter
    the virtual obstacle by up to E_tr and must still avoid the real one). A disc that already holds
    `p0` in its E_tr allowance shrinks to leave `gap` between it and p0 — a plan may then go no deeper
    than the vehicle already is; one whose never-entered core is that close is kept whole (nothing
    starting there is acceptable: the planner brakes)."""
    out, notes = [], []
    for d in discs:
        dist = float(np.hypot(p0[0] - d.x, p0[1] - d.y))
        if dist - gap < d.r and d.r_min is not None and dist - gap > d.r_min:
            out.append(Disc(d.x, d.y, dist - gap, d.r_min))
            notes.append(f"inside the E_tr allowance of a disc: keep-out {d.r:.2f} → {dist - gap:.2f} m")
        else:
            out.append(d)
    return out, notes


@dataclass
class Plan:
    kind: str  # "pass", "stop", "brake" ("await": the guidance's braking while the first plan is computed)
    t: np.ndarray  # (N+1,) times from now
    p: np.ndarray  # (N+1, 2) world positions
    v: np.ndarray  # (N+1, 2)
    a: np.ndarray  # (N, 2) piecewise-constant accelerations
    ok: bool  # passed the exact check
    min_clearance: float  # smallest distance to a disc's edge along the dense path [m]
    solve_s: float = 0.0
    qp_solves: int = 0
    rejected: int = 0  # QP solutions the exact check refused
    notes: list[str] = field(default_factory=list)

    def sample(self, tau: float):
        """Position, velocity, acceleration `tau` seconds into the plan (held at the end)."""
        ts = self.t[1] - self.t[0]
        k = min(max(int(tau / ts), 0), len(self.a) - 1)
        if tau >= self.t[-1]:
            return self.p[-1].copy(), self.v[-1].copy(), np.zeros(2)
        dt = tau - self.t[k]
        a = self.a[k]
        return self.p[k] + self.v[k] * dt + 0.5 * a * dt * dt, self.v[k] + a * dt, a.copy()


def offboard_cap(flown: float | None) -> float:
    """The factor on V_safe that offboard flies: OFFBOARD_CAP, but never more than the cap at which the
    controller contract's sweep flew this planner's plans (`ContractTable.etr_offboard_cap`); a contract
    that records none (no E_tr_pred slot, or a table from before the record) gets UNRECORDED_CAP."""
    return min(OFFBOARD_CAP, UNRECORDED_CAP if flown is None else flown)


def keeps_plan(current: Plan | None, age: float, new: Plan) -> bool:
    """Whether a failed new plan is dropped for `current`, a verified pass/stop plan `age` seconds in
    and not yet ended: flying it beats braking (the next replan tries again). One rule for the
    guidance and the E_tr sweep."""
    return (not new.ok and current is not None and current.ok and current.kind in ("pass", "stop")
            and age < current.t[-1])


def dense_path(p, v, a, ts, sub=SUB_STEPS):
    """Positions along the piecewise-constant-acceleration path, `sub` points per interval."""
    tau = (np.arange(sub) / sub * ts)[None, :, None]
    pts = p[:-1, None, :] + v[:-1, None, :] * tau + 0.5 * a[:, None, :] * tau**2
    return np.concatenate([pts.reshape(-1, 2), p[-1:]], axis=0)


def rollout(p0, v0, w, ts, a_max):
    """The states the accelerations `w` (clipped to |w| ≤ a_max) really give from (p0, v0), eq. (12–13)
    exactly: the QP meets its dynamics only to its tolerance, and the exact check must judge the flown
    path. Returns positions, velocities (N+1, 2) and the accelerations (N, 2)."""
    w = np.array(w, dtype=float)
    norm = np.hypot(w[:, 0], w[:, 1])
    over = norm > a_max
    w[over] *= (a_max / norm[over])[:, None]
    n = len(w)
    v = np.empty((n + 1, 2))
    v[0] = v0
    v[1:] = v0 + np.cumsum(w, axis=0) * ts
    p = np.empty((n + 1, 2))
    p[0] = p0
    p[1:] = p0 + np.cumsum(v[:-1] * ts + 0.5 * w * ts * ts, axis=0)
    return p, v, w


def disc_clearance(pts, discs) -> np.ndarray:
    """Each point's distance to the nearest disc's edge (negative inside one; inf with no disc)."""
    pts = np.asarray(pts, float).reshape(-1, 2)
    return np.min([np.hypot(pts[:, 0] - d.x, pts[:, 1] - d.y) - d.r for d in discs], axis=0) if discs else \
        np.full(len(pts), math.inf)


def exact_check(p, v, a, ts, discs, v_max, a_max, tol=1e-6):
    """The true constraints, densely: (ok, min clearance, why not)."""
    clear = float(np.min(disc_clearance(dense_path(p, v, a, ts), discs)))
    speeds = np.hypot(v[:, 0], v[:, 1])  # |v| is convex along an arc: the ends bound it
    accs = np.hypot(a[:, 0], a[:, 1])
    if clear < -tol:
        return False, clear, f"enters a keep-out disc by {-clear:.3f} m"
    if np.any(speeds[1:] > np.asarray(v_max) * (1 + tol)):  # v_max: a bound, or one per sample k ≥ 1
        return False, clear, "speed above V_max"
    if np.max(accs) > a_max * (1 + tol):
        return False, clear, "acceleration above the tilt limit"
    return True, clear, ""


def braking_plan(p0, v0, a_max, n=40) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Full deceleration against the velocity until rest, then hold."""
    s = float(np.hypot(*v0))
    t_stop = s / a_max if a_max > 0 else 0.0
    ts = max(t_stop, 0.5) / n
    a = np.zeros((n, 2))
    p, v = np.zeros((n + 1, 2)), np.zeros((n + 1, 2))
    p[0], v[0] = p0, v0
    u = np.asarray(v0) / s if s > 0 else np.zeros(2)
    for k in range(n):
        rem = float(np.hypot(*v[k]))
        a[k] = -u * min(a_max, rem / ts)
        v[k + 1] = v[k] + a[k] * ts
        p[k + 1] = p[k] + v[k] * ts + 0.5 * a[k] * ts * ts
    return p, v, a, ts


STOP_SWERVE_DEG = (0.0, 10.0, -10.0, 20.0, -20.0, 30.0, -30.0, 45.0, -45.0)  # best_stop's candidate directions


def best_stop(p0, v0, a_max, discs=(), n=40, max_path_m: float = math.inf, a0=None, jerk: float = math.inf
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The best stop the geometry allows: deceleration |a| = a_max tilted by θ from straight against the
    velocity — sideways at a_max·sin θ while the speed along the motion is taken out, then the sideways
    speed braked. With a finite `jerk` the acceleration starts at `a0` (the vehicle's, measured) and turns
    and grows at most at `jerk` (a stop the vehicle can track: no step of the tilt), and ramps back to 0 at
    rest (|a| ≤ √(2·j·speed) per axis). θ = 0 is straight braking; |θ| ≤ 45° never flies faster than the start
    (the speed is convex in time and ends at s·tan θ ≤ s; a swerve that does, from a0, is not a candidate). In STOP_SWERVE_DEG's order (straight first), the
    first θ whose dense path keeps out of every disc wins; else the one with the largest clearance (a
    straight stop that only clears the never-entered core lost to a swerve off it). A
    swerving stop whose path is longer than `max_path_m` is not a candidate (the stop contract's distance).
    Returns positions, velocities, accelerations, the sampling time and the clearance to the full discs [m]."""
    p0, v0 = np.asarray(p0, float), np.asarray(v0, float)
    a0 = np.zeros(2) if a0 is None or not np.all(np.isfinite(a0)) else np.asarray(a0, float)
    s = float(np.hypot(*v0))
    discs = [d for d in discs if all(math.isfinite(x) for x in (d.x, d.y, d.r))]
    best = None
    for deg in (STOP_SWERVE_DEG if discs and s > 0.05 and a_max > 0 else (0.0,)):
        cand = _tilted_stop(p0, v0, s, a_max, math.radians(deg), n, a0, jerk)
        pts = dense_path(*cand[:4])
        if deg != 0.0 and (float(np.sum(np.hypot(*np.diff(pts, axis=0).T))) > max_path_m
                           or float(np.max(np.hypot(*cand[1].T))) > s * (1.0 + 1e-6)):
            continue  # too long for the stop contract, or faster than the start
        clear = float(np.min(disc_clearance(pts, discs)))
        out = (*cand, clear)
        if clear >= 0.0:
            return out
        if best is None or clear > best[-1]:
            best = out
    return best


def _tilted_stop(p0, v0, s, a_max, th, n, a0=(0.0, 0.0), jerk=math.inf):
    """One candidate of `best_stop`: n intervals of constant acceleration, ending at rest."""
    if math.isfinite(jerk) and jerk > 0 and a_max > 0 and s > 0:
        return _smooth_stop(p0, v0, s, a_max, th, n, np.asarray(a0, float), jerk)
    if a_max <= 0:
        t_stop = 0.0
    else:  # the swerving stops get 10 % more time, so the sampled law surely ends at rest
        t_stop = s / a_max if th == 0 else (s / a_max / math.cos(th) + s * abs(math.tan(th)) / a_max) * 1.1
    ts = max(t_stop, 0.5) / n
    u = v0 / s if s > 0 else np.zeros(2)
    nn = np.array([-u[1], u[0]]) * math.copysign(1.0, th)
    a = np.zeros((n, 2))
    p, v = np.zeros((n + 1, 2)), np.zeros((n + 1, 2))
    p[0], v[0] = p0, v0
    for k in range(n):
        va, vl = float(v[k] @ u), float(v[k] @ nn)
        if va > 1e-9:
            a[k] = -u * min(a_max * math.cos(th), va / ts) + nn * a_max * abs(math.sin(th))
        else:
            a[k] = -u * (va / ts) - nn * math.copysign(min(a_max, abs(vl) / ts), vl)
        v[k + 1] = v[k] + a[k] * ts
        p[k + 1] = p[k] + v[k] * ts + 0.5 * a[k] * ts * ts
    return p, v, a, ts


SMOOTH_DT = 0.01  # [s] step of the jerk-limited stop's law, before it is sampled on n intervals
REST_M_S = 1e-4  # [m/s] the jerk-limited stop is at rest below this speed on each axis
SMOOTH_T_MAX = 30.0  # [s] longest such stop simulated (a 45° swerve from 8 m/s at 1 m/s² takes ~20 s)


def _smooth_stop(p0, v0, s, a_max, th, n, a0, jerk):
    """`_tilted_stop` with the acceleration turned at most at `jerk` per axis (along the start velocity û,
    and across it), starting from `a0`: along û the speed is taken out at ≤ a_max·cos θ while the sideways
    acceleration ramps to a_max·sin θ (θ ≠ 0) or takes out any sideways speed (θ = 0); then the sideways
    speed is braked. Each speed w is brought to rest with its acceleration (the jerk-limited S-curve's
    |b| ≤ √(2·j·|w|)); |a| ≤ max(a_max, |a0|), never growing above a_max. An a0 along the motion is ramped
    out first (+a0²/(2j) of speed, as the vehicle flies it). The law is stepped at SMOOTH_DT and sampled on
    n equal intervals (each the mean acceleration over it, so |a| and the speed stay within the law's)."""
    u = v0 / s
    nn = np.array([-u[1], u[0]]) * math.copysign(1.0, th if th != 0 else 1.0)
    j = jerk / math.sqrt(2.0)  # per axis: |jerk| ≤ `jerk`
    dt, jd = SMOOTH_DT, jerk / math.sqrt(2.0) * SMOOTH_DT
    w = [s, 0.0]  # along û, across
    b = [float(a0 @ u), float(a0 @ nn)]
    cap = max(a_max, math.hypot(*b))
    ts_, ws = [0.0], [tuple(w)]
    swerve = th != 0.0
    t = 0.0

    def toward_rest(wi, lim):
        """This axis's acceleration toward rest: the jerk-limited S-curve's √(2·j·|w|) (zero acceleration at
        zero speed), within `lim`, and linear near rest (|w|/(2·dt)) so the stepped law settles."""
        return -math.copysign(min(lim, math.sqrt(2.0 * j * abs(wi)), abs(wi) / (2.0 * dt)), wi)

    while t < SMOOTH_T_MAX:
        if swerve and w[0] <= REST_M_S:
            swerve = False  # the speed along the motion is out: brake the sideways speed
        if swerve:
            want = (toward_rest(w[0], a_max * math.cos(th)), a_max * abs(math.sin(th)))
        else:
            want = (toward_rest(w[0], a_max), toward_rest(w[1], a_max))
        nb = [bi + min(max(wi - bi, -jd), jd) for bi, wi in zip(b, want)]
        norm = math.hypot(*nb)
        cap = max(a_max, min(cap, norm))
        if norm > cap:
            nb = [x * cap / norm for x in nb]
        w = [wi + 0.5 * (bi + ni) * dt for wi, bi, ni in zip(w, b, nb)]
        b = nb
        t += dt
        ts_.append(t)
        ws.append(tuple(w))
        if not swerve and max(abs(x) for x in w) <= REST_M_S and max(abs(x) for x in b) <= jd:
            break  # at rest
    ts_, ws = np.array(ts_), np.array(ws)
    tk = np.linspace(0.0, ts_[-1], n + 1)
    wk = np.stack([np.interp(tk, ts_, ws[:, 0]), np.interp(tk, ts_, ws[:, 1])], axis=1)
    wk[-1] = 0.0  # at rest
    frame = np.stack([u, nn])  # rows: û, n̂
    v = wk @ frame
    ts = float(tk[1])
    a = np.diff(v, axis=0) / ts
    p = np.zeros((n + 1, 2))
    p[0] = p0
    for k in range(n):
        p[k + 1] = p[k] + v[k] * ts + 0.5 * a[k] * ts * ts
    return p, v, a, ts


# A stop that ended inside a keep-out disc backs off along the path flown before Hold (ArduPilot's AC_Avoid backs
# away from what is closer than its margin too, at AVOID_BACKUP_SPD, 0.75 m/s by default)
BACK_OFF_M_S = 0.5  # [m/s] the back-off's speed (blind: the sensors face the way the vehicle flew)
BACK_OFF_ACC = 0.5  # [m/s²] its acceleration
BACK_OFF_MAX_M = 3.0  # [m] never further back than this along the path flown
BACK_OFF_STEP_M = 0.05  # [m] the path flown is searched at this spacing
BACK_OFF_MARGIN_M = 0.05  # [m] the back-off ends this far outside every keep-out disc


def back_off(track, discs, ts: float = 0.05) -> Plan | None:
    """The way out of a keep-out disc for a vehicle at rest inside one: a straight line, at BACK_OFF_M_S and
    BACK_OFF_ACC, to the newest point of `track` (the positions flown, oldest first, the last where it rests; its
    body swept them clear of static obstacles) that lies BACK_OFF_MARGIN_M outside every disc, within
    BACK_OFF_MAX_M back along the track, and along which the line never goes deeper into a disc than the vehicle
    is now. The hold that follows then starts from a reference with the controller's whole allowance E_tr round it
    (the virtual obstacle of Figure 13), not from where the allowance was already used. None: at rest outside every
    disc, or no such point."""
    discs = [d for d in discs if all(math.isfinite(x) for x in (d.x, d.y, d.r))]
    pts = np.asarray(track, float)[::-1]
    if not discs or len(pts) == 0:
        return None

    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    s_q = np.arange(0.0, min(s[-1], BACK_OFF_MAX_M) + 1e-9, BACK_OFF_STEP_M)
    q = np.stack([np.interp(s_q, s, pts[:, 0]), np.interp(s_q, s, pts[:, 1])], axis=1)
    clear = disc_clearance(q, discs)
    if clear[0] >= 0.0:
        return None
    u = np.linspace(0.0, 1.0, SUB_STEPS)[:, None]
    for k in np.flatnonzero(clear >= BACK_OFF_MARGIN_M):
        if float(np.min(disc_clearance(q[0] + u * (q[k] - q[0]), discs))) >= clear[0]:
            break
    else:
        return None
    length = float(np.hypot(*(q[k] - q[0])))
    v_top = min(BACK_OFF_M_S, math.sqrt(BACK_OFF_ACC * length))  # a trapezoid, or a triangle when short
    t_end = length / v_top + v_top / BACK_OFF_ACC
    t = np.arange(0.0, t_end + ts, ts)
    speed = np.minimum.reduce([BACK_OFF_ACC * t, np.full_like(t, v_top), BACK_OFF_ACC * np.maximum(t_end - t, 0.0)])
    along = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * ts)])
    along = np.minimum(along * length / along[-1], length)
    e = (q[k] - q[0]) / length
    p, v = q[0] + along[:, None] * e, speed[:, None] * e
    return Plan("back_off", t, p, v, np.diff(v, axis=0) / ts, True, float(clear[0]))  # (its clearance: the start's)


class AvoidancePlanner:
    """OSQP avoidance planner with a fixed horizon of `n` intervals; solvers are cached per shape."""

    def __init__(self, n: int = 30, scp_iters: int = 4, weights=(1.0, 0.05, 0.2, 0.02)):
        load_solver()
        self.n = n
        self.scp_iters = scp_iters
        self.w_v, self.w_y, self.w_vy, self.w_a = weights
        self._solvers: dict = {}
        self._patterns: dict = {}
        self.poly_a, self.poly_b = cone_polygon(1.0, N_POLY)  # unit polygon, scaled per call
        self.poly_ang = np.arctan2(self.poly_a[:, 1], self.poly_a[:, 0])  # its face normals' angles

    # ---------------------------------------------------------------- QP assembly
    def _index(self):
        n = self.n
        nq = 4 * (n + 1)
        return n, nq, nq + 2 * n

    def _pattern(self, n_discs):
        """The constraint matrix's fixed sparsity pattern (COO, no duplicates) and its CSC order.

        Rows: q_0 = q0 (4) · dynamics q_{k+1} − F̂ q_k − Ĝ w_k = 0 (4N) · acceleration polygon (16N) ·
        speed polygon for k ≥ 1 (16N) · two half-plane rows per disc and segment · terminal x_N, ẋ_N, ẏ_N.
        """
        n, nq, nz = self._index()
        nz += n * n_discs  # one slack per disc and segment (soft keep-out while the SCP converges)
        rows, cols, tags = [], [], []  # tag: how the value is computed

        def add(r, c, tag):
            rows.append(r)
            cols.append(c)
            tags.append(tag)

        for i in range(4):
            add(i, i, ("one",))
        for k in range(n):
            r0 = 4 + 4 * k
            for i in range(4):
                add(r0 + i, 4 * (k + 1) + i, ("one",))
            for ax in range(2):  # per axis block: rows (pos, vel) × cols (pos, vel) and the input
                rp, rv = r0 + 2 * ax, r0 + 2 * ax + 1
                cp, cv = 4 * k + 2 * ax, 4 * k + 2 * ax + 1
                add(rp, cp, ("minus_one",))
                add(rp, cv, ("minus_ts",))
                add(rv, cv, ("minus_one",))
                add(rp, nq + 2 * k + ax, ("minus_half_ts2",))
                add(rv, nq + 2 * k + ax, ("minus_ts",))
        r = 4 + 4 * n
        for k in range(n):
            for j in range(N_POLY):
                add(r + N_POLY * k + j, nq + 2 * k, ("poly", j, 0, k))
                add(r + N_POLY * k + j, nq + 2 * k + 1, ("poly", j, 1, k))
        r += N_POLY * n
        for k in range(1, n + 1):
            for j in range(N_POLY):
                add(r + N_POLY * (k - 1) + j, 4 * k + 1, ("poly", j, 0, n + k - 1))
                add(r + N_POLY * (k - 1) + j, 4 * k + 3, ("poly", j, 1, n + k - 1))
        r += N_POLY * n
        r_hp = r
        for dd in range(n_discs):
            for k in range(n):
                for e, kk in enumerate((k, k + 1)):
                    row = r + 2 * (dd * n + k) + e
                    add(row, 4 * kk, ("hp", row - r_hp, 0))
                    add(row, 4 * kk + 2, ("hp", row - r_hp, 1))
                    add(row, nq + 2 * n + dd * n + k, ("one",))
        r += 2 * n * n_discs
        for i in range(n * n_discs):  # slacks ≥ 0
            add(r + i, nq + 2 * n + i, ("one",))
        r += n * n_discs
        for i, c in enumerate((4 * n, 4 * n + 1, 4 * n + 3)):
            add(r + i, c, ("one",))
        m = r + 3
        rows, cols = np.array(rows), np.array(cols)
        order = np.lexsort((rows, cols))  # CSC order: by column, then row
        csc = sp.csc_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, nz))
        assert csc.nnz == len(rows)
        tags = [tags[i] for i in order]
        kind = np.array([{"one": 0, "minus_one": 1, "minus_ts": 2, "minus_half_ts2": 3, "poly": 4, "hp": 5}[t[0]]
                         for t in tags])
        poly_j = np.array([t[1] if t[0] == "poly" else 0 for t in tags])
        hp_i = np.array([t[1] if t[0] == "hp" else 0 for t in tags])
        comp = np.array([t[2] if t[0] in ("poly", "hp") else 0 for t in tags])
        poly_k = np.array([t[3] if t[0] == "poly" else 0 for t in tags])
        return {"csc": csc, "kind": kind, "poly_j": poly_j, "poly_k": poly_k, "hp_i": hp_i, "comp": comp,
                "r_hp": r_hp, "m": m, "nz": nz}

    def _values(self, pat, ts, normals, turn=None):
        """CSC data for sampling time `ts`, half-plane `normals` (rows of unit vectors) and the polygons'
        rotations `turn` (2N angles [rad]: the N acceleration polygons, then the N speed polygons)."""
        kind = pat["kind"]
        val = np.empty(len(kind))
        val[kind == 0] = 1.0
        val[kind == 1] = -1.0
        val[kind == 2] = -ts
        val[kind == 3] = -0.5 * ts * ts
        pk = kind == 4
        ang = self.poly_ang[pat["poly_j"][pk]] + (0.0 if turn is None else turn[pat["poly_k"][pk]])
        val[pk] = np.where(pat["comp"][pk] == 0, np.cos(ang), np.sin(ang))
        hk = kind == 5
        if np.any(hk):
            nv = normals[pat["hp_i"][hk], pat["comp"][hk]]
            val[hk] = np.where(np.abs(nv) < 1e-12, 1e-12, nv)  # keep the slot: the pattern is fixed
        return val

    def _cost(self, kind, v_cruise, n_discs):
        n, nq, nz0 = self._index()
        nz = nz0 + n * n_discs
        diag = np.zeros(nz)
        q = np.zeros(nz)
        for k in range(1, n + 1):
            if kind == "pass":
                diag[4 * k + 1] = self.w_v
                q[4 * k + 1] = -self.w_v * v_cruise
            diag[4 * k + 2] = self.w_y
            diag[4 * k + 3] = self.w_vy
        diag[nq:nz0] = self.w_a
        if kind == "stop":
            diag[[4 * k + 1 for k in range(1, n + 1)]] += 0.01  # prefer slowing early
        diag[nz0:] = 1e-3
        q[nz0:] = SLACK_COST
        return sp.diags(diag, format="csc"), q

    def _solver(self, kind, n_discs, pat, q, lo, hi, val, fresh):
        """One OSQP workspace per (plan kind, number of discs): set up afresh for a cold start (its
        scaling fits that problem), updated in place while replanning the same situation."""
        key = (kind, n_discs)
        if fresh or key not in self._solvers:
            p_mat, _ = self._cost(kind, 0.0, n_discs)
            a_mat = pat["csc"].copy()
            a_mat.data = val
            s = osqp.OSQP()
            s.setup(p_mat, q, a_mat, lo, hi, verbose=False, eps_abs=1e-4, eps_rel=1e-4, max_iter=400,
                    polishing=True, warm_starting=True, adaptive_rho=True)
            self._solvers[key] = s
        else:
            self._solvers[key].update(q=q, l=lo, u=hi, Ax=val)
        return self._solvers[key]

    # ---------------------------------------------------------------- one plan
    def plan(self, p0, v0, route_dir, discs: list[Disc], v_max: float, a_max: float, v_cruise: float | None = None,
             horizon_s: float | None = None, warm: Plan | None = None, elapsed: float = 0.0,
             budget_s: float | None = None, along: bool | None = None) -> Plan:
        """Plan from (p0, v0) along `route_dir` around `discs` within V_max and the tilt's a_max.

        `warm`: the previous plan, `elapsed` seconds old — its remainder is the first linearisation of
        the same kind of plan (replanning), tried before the cold starts. `budget_s`: no further QP
        attempt starts once this much time is spent (the first always runs; braking is always ready).
        `along` (None: not tried): first try passing every disc on the route line's side — through the gap between
        what lies either side of it, and (True) beside what lies on one side of it only (among walls, whose hit
        points are discs: a pass round their far side goes through the wall between the points seen); among walls
        the other passes too go round what lies beside the line on its side (`side_attempts`).
        """
        t0 = time.perf_counter()
        bad = [d for d in discs if not all(math.isfinite(x) for x in (d.x, d.y, d.r))]
        if bad:  # no QP with an unbounded keep-out: stop as well as the finite part of the geometry allows
            core = [Disc(d.x, d.y, d.r_min) for d in bad if d.r_min is not None and
                    all(math.isfinite(x) for x in (d.x, d.y, d.r_min))]
            discs = [d for d in discs if d not in bad] + core
            return self._stop_plan(p0, v0, discs, v_max, a_max, t0, 0, 0,
                                   [f"{len(bad)} keep-out disc(s) not finite: no plan, the best stop"], False)
        u = np.asarray(route_dir, float)
        u = u / np.linalg.norm(u)
        rot = np.array([[u[0], u[1]], [-u[1], u[0]]])  # world → route frame
        p0 = np.asarray(p0, float)
        pr0, vr0 = np.zeros(2), rot @ np.asarray(v0, float)
        local = [Disc(*(rot @ (np.array([d.x, d.y]) - p0)), d.r, d.r_min) for d in discs]
        v_cruise = v_max if v_cruise is None else min(v_cruise, v_max)
        speed0 = float(np.hypot(*vr0))
        # horizons: passing needs the time to get beyond the obstacle at the cruise speed (`pass_horizon`), stopping the
        # time to brake; an explicit horizon overrides both
        far = max((d.x + d.r for d in local), default=0.0)
        h = {"pass": pass_horizon(far, speed0, v_cruise, a_max),
             "stop": max(1.5, 1.5 * speed0 / max(a_max, 1e-3))}
        if horizon_s is not None:
            h = {"pass": horizon_s, "stop": horizon_s}
        total = 0
        rejected = 0
        notes = []
        attempts = [("pass", side, None) for side in side_attempts(local, vr0, a_max, along)] + [("stop", 0.0, None)]
        between = between_sides(local, one_side=along) if along is not None else None
        if between is not None:  # a gap between what lies either side of the route line: through it first
            attempts.insert(0, ("pass", between, None))
        if warm is not None and warm.kind in ("pass", "stop"):
            h[warm.kind] = max(h[warm.kind], warm.t[-1] - elapsed)
            tw = h[warm.kind] / self.n
            guess = np.array([warm.sample(elapsed + k * tw)[0] for k in range(self.n + 1)])
            attempts.insert(0, (warm.kind, 0.0, (guess - p0) @ rot.T))
        for i, (kind, side, guess) in enumerate(attempts):
            if i and budget_s is not None and time.perf_counter() - t0 > budget_s:
                notes.append(f"time budget {budget_s * 1e3:.0f} ms spent: {len(attempts) - i} attempt(s) skipped")
                break
            if kind == "pass" and not local:
                side = 0.0
            ts = h[kind] / self.n
            keep_out, why_in = admitted(local, pr0, a_max * ts * ts / 8.0 + 2 * MARGIN_M)
            notes += [n for n in why_in if n not in notes]
            res = self._scp(kind, side, pr0, vr0, keep_out, v_max, a_max, v_cruise, ts, guess)
            total += res[-1]
            if res[0] is None:
                notes.append(f"{kind}{_side_name(side)}: {res[1]}")
                continue
            p, v, a, why, ok, clear = res[:6]
            if ok and np.ndim(side) and round_far_side(p, local, side):
                ok, why = False, "round a disc beside the route line on its far side"
            if ok:
                return self._world(kind, p, v, a, ts, rot, p0, True, clear, t0, total, rejected, notes)
            rejected += 1
            notes.append(f"{kind}: rejected by the exact check ({why})")
            if kind == "pass" and not local:
                break
        return self._stop_plan(p0, v0, discs, v_max, a_max, t0, total, rejected, notes)

    def _stop_plan(self, p0, v0, discs, v_max, a_max, t0, solves, rejected, notes, may_be_ok=True) -> Plan:
        """The fallback that is always available: the best stop (`best_stop`), checked exactly."""
        p0 = np.asarray(p0, float)
        keep = admitted(list(discs), p0, MARGIN_M)[0]
        p, v, a, tsb, _ = best_stop(p0, v0, a_max, keep, self.n)
        ok, clear, why = exact_check(p, v, a, tsb, keep, max(v_max, float(np.hypot(*v0))), a_max)
        if not ok:
            notes.append(f"brake: {why}")
        return Plan("brake", np.arange(len(p)) * tsb, p, v, a, ok and may_be_ok, clear, time.perf_counter() - t0,
                    solves, rejected, notes)

    def _world(self, kind, p, v, a, ts, rot, p0, ok, clear, t0, solves, rejected, notes) -> Plan:
        back = rot.T
        return Plan(kind, np.arange(len(p)) * ts, p @ back.T + p0, v @ back.T, a @ back.T, ok, clear,
                    time.perf_counter() - t0, solves, rejected, notes)

    def _speed_caps(self, kind, v0, v_max, a_max, ts):
        """Speed bound at k = 1…N: V_max, or — flying faster after the limit dropped — the current
        speed less what braking at 70 % of a_max removes by then. A stop never flies faster than it starts (from
        rest: STOP_CREEP_M_S): an iterate OSQP had not converged on, safe by the exact check, backed a vehicle at
        rest 1 m away from a column at 1.1 m/s, out of its sensor's view."""
        k = np.arange(1, self.n + 1)
        speed0 = float(np.hypot(*v0))
        caps = np.maximum(v_max, speed0 - 0.7 * a_max * ts * k)
        return np.minimum(caps, max(speed0, STOP_CREEP_M_S)) if kind == "stop" else caps

    def _scp(self, kind, side, p0, v0, discs, v_max, a_max, v_cruise, ts, guess=None):
        n, nq, nz = self._index()
        key = len(discs)
        if key not in self._patterns:
            self._patterns[key] = self._pattern(key)
        pat = self._patterns[key]
        _, q = self._cost(kind, v_cruise, len(discs))
        inflate = a_max * ts * ts / 8.0 + MARGIN_M
        m, r_hp = pat["m"], pat["r_hp"]
        lo, hi = np.zeros(m), np.zeros(m)
        lo[0:4] = hi[0:4] = [p0[0], v0[0], p0[1], v0[1]]
        r = 4 + 4 * n
        lo[r : r + 2 * N_POLY * n] = -np.inf
        hi[r : r + N_POLY * n] = np.tile(self.poly_b * (a_max * (1.0 - QP_TIGHTEN)), n)
        caps = self._speed_caps(kind, v0, v_max, a_max, ts)
        hi[r + N_POLY * n : r + 2 * N_POLY * n] = np.outer(caps * (1.0 - QP_TIGHTEN), self.poly_b).ravel()
        r = r_hp + 2 * n * len(discs)
        hi[r_hp:r] = np.inf
        lo[r : r + n * len(discs)], hi[r : r + n * len(discs)] = 0.0, np.inf
        r += n * len(discs)
        if kind == "pass":
            beyond = max((d.x + d.r + inflate for d in discs), default=-np.inf)
            lo[r : r + 3], hi[r : r + 3] = [beyond, 0.0, 0.0], [np.inf, np.inf, 0.0]
        else:
            lo[r : r + 3], hi[r : r + 3] = [-np.inf, 0.0, 0.0], [np.inf, 0.0, 0.0]
        # first linearisation: the straight path at the current velocity; each segment's half-plane
        # faces the point beside the disc on `side` at the segment's abscissa (pass: the normals turn
        # smoothly from −x through the side to +x, so neighbouring half-planes always intersect), or
        # the disc's front (stop)
        warm = guess is not None
        if not warm:
            guess = _cold_guess(kind, p0, v0, v_cruise, a_max, ts, n)
        centres = np.array([[d.x, d.y] for d in discs]).reshape(-1, 2)
        radii = np.array([d.r for d in discs])
        lift = np.reshape(side * (radii + inflate), (-1, 1)) if kind == "pass" else np.zeros((len(discs), 1))
        solves, sol = 0, None
        p = v = a = None
        gv = np.vstack([v0, np.diff(guess, axis=0) / ts])  # the guess's velocities, then its accelerations
        turn = _vertex_turns(np.diff(gv, axis=0) / ts, gv[1:])
        why, clear = "no iteration", -math.inf
        for it in range(self.scp_iters):
            normals = np.zeros((2 * n * len(discs), 2))
            if discs:
                mid = 0.5 * (guess[:-1] + guess[1:])  # (n, 2)
                nrm = mid[None, :, :] - centres[:, None, :]  # (discs, n, 2)
                if it == 0 and not warm:
                    nrm[..., 1] = lift  # the virtual point beside the disc
                    if kind == "stop":
                        nrm[..., 0] = -1.0
                ln = np.hypot(nrm[..., 0], nrm[..., 1])[..., None]
                nrm = np.where(ln > 1e-9, nrm / np.maximum(ln, 1e-12), np.array([-1.0, 0.0]))
                bound = np.einsum("dkc,dc->dk", nrm, centres) + radii[:, None] + inflate
                normals = np.repeat(nrm.reshape(-1, 2), 2, axis=0)
                lo[r_hp : r_hp + 2 * n * len(discs)] = np.repeat(bound.reshape(-1), 2)
            # soft keep-out with a penalty that grows each iteration (exact check = the only judge)
            q[nq + 2 * n :] = SLACK_COST * (10.0 ** it)
            solver = self._solver(kind, len(discs), pat, q, lo, hi, self._values(pat, ts, normals, turn),
                                  fresh=(it == 0 and not warm))
            if sol is None:  # start from the guess, never from another problem's solution
                x_init = np.zeros(pat["nz"])
                vel = np.vstack([v0, np.diff(guess, axis=0) / ts])
                x_init[:nq] = np.column_stack([guess[:, 0], vel[:, 0], guess[:, 1], vel[:, 1]]).ravel()
                solver.warm_start(x=x_init, y=np.zeros(pat["m"]))
            else:
                solver.warm_start(x=sol)
            out = solver.solve(raise_error=False)
            solves += 1
            if out.x is None or not np.all(np.isfinite(out.x)) or "infeasible" in out.info.status:
                return None, f"QP {out.info.status}", solves
            # an unconverged iterate is still a candidate: the exact check below is the only judge
            sol = out.x
            p, v, a = rollout(p0, v0, sol[nq : nq + 2 * n].reshape(n, 2), ts, a_max)
            ok, clear, why = exact_check(p, v, a, ts, discs, caps, a_max)
            if ok:
                return p, v, a, why, ok, clear, solves
            guess = p
            turn = _vertex_turns(a, v[1:])
        return p, v, a, why, False, clear, solves


def _cold_guess(kind: str, p0, v0, v_cruise: float, a_max: float, ts: float, n: int) -> np.ndarray:
    """The first linearisation's path (route frame): straight on at the current velocity, and for a pass slower than
    GUESS_CRUISE of the cruise speed, speeding up along the route at half a_max to that. A pass guessed at the speed now
    went nowhere from rest: every segment at the start, every half-plane faced the discs' fronts, beside-line ones too,
    and the QP's slack took the path through a wall. (Guessed up to the cruise speed itself — V_max, on the QP's speed
    polygon — the QP's unconverged iterates ran 0.02–0.6 % above V_max.)"""
    tk = np.arange(n + 1) * ts
    guess = p0[None, :] + v0[None, :] * tk[:, None]
    u0, u1, a = float(v0[0]), GUESS_CRUISE * v_cruise, 0.5 * a_max
    if kind == "pass" and u0 < u1:
        tr = np.minimum(tk, (u1 - u0) / a)
        guess[:, 0] = p0[0] + u0 * tr + 0.5 * a * tr * tr + u1 * (tk - tr)
    return guess


def _vertex_turns(a, v):
    """Rotations of the N acceleration and N speed polygons that put a vertex on the last iterate's
    direction: the inscribed 16-gon is then exact where the limiting brake-and-swerve sits,
    instead of losing up to 1 − cos(π/16) = 1.9 % of the tilt's acceleration between vertices."""
    return np.concatenate([np.arctan2(a[:, 1], a[:, 0]), np.arctan2(v[:, 1], v[:, 0])])

