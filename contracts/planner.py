"""Time-optimal planner of the paper, eq. (14)–(19), in CasADi/IPOPT (offline only: imports CasADi).

Flat model eq. (9)–(13): four double-integrator chains q = [X, Ẋ, Y, Ẏ, Z, Ż, ψ, ψ̇], synthetic input
w = [Ẍ, Ÿ, Z̈, ψ̈] held constant over each of the N intervals (ZOH, eq. 12–13), sample time t_s free
(cost J = t_f = N·t_s, eq. 16). Path constraints eq. (14) through the flat maps eq. (8): speed norm,
altitude band, tilt (`cone`: total tilt; `box`: |φ| ≤ φ_max, |θ| ≤ θ_max), thrust min/max, roll and
pitch rates (finite differences of consecutive ZOH attitudes, |Δφ| ≤ φ̇_max·t_s, starting from the
attitude of w(1) = w_0), yaw moment u_ψ = ψ̈/K. Boundary conditions eq. (18): q(1) = q_0, w(1) = w_0,
and either a terminal box on q(N) (the paper's q(N) = q_f when lower = upper), w(N) = w_f, or the
contract's terminal set "the ballistic continuation is safe" (`terminal="coast"`).

Keep-out between samples (DESIGN.md §2): over one ZOH interval the position is a quadratic Bézier
curve with control points P0 = p_k, P1 = p_k + v_k·t_s/2, P2 = p_{k+1}, so it lies in their convex
hull. Per interval and obstacle a separating line n_k puts all three control points at distance ≥ r
from the obstacle, eq. (19) q ∉ O (circle: |n| ≤ 1, n·(P − o) ≥ r; convex polygon with vertices V_j:
|n| = 1, n·P ≥ β + r, n·V_j ≤ β), which keeps the whole continuous path out, not only the samples.
The coast terminal set uses the same device for the ray p_N + s·v_N, s ≥ 0: n·(p_N − o) ≥ r,
n·v_N ≥ 0.

A solution is accepted only after `check_trajectory` re-simulates it from q_0 with ≥ 20 sub-steps per
interval and confirms every constraint (keep-out by the exact minimum over each interval of the
distance to a circle's centre, or of the signed distance to a polygon, not only at the sub-steps).
The NLP tightens its limits by a relative 1e-6 so that IPOPT's tolerances never leave a verified
trajectory outside the true limits.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from .flat import inputs_from_flat, thrust_limited_accel, total_tilt
from .vehicle import G, Vehicle

SHRINK = 1e-6  # relative tightening of every limit inside the NLP
STOPPED = 1e-6  # [m/s] a final speed below this is a stop (the vehicle holds position)


# ============================================================================ problem description


@dataclass(frozen=True)
class Limits:
    """The path-constraint set Ξ1 of eq. (14) (SI units, radians)."""

    mass: float
    t_max: float  # [N]
    tilt: float  # cone: total tilt limit; box: default for φ_max = θ_max
    tilt_model: str = "cone"
    phi_max: float | None = None  # box model only (defaults to tilt)
    theta_max: float | None = None
    t_min: float = 0.0
    v_max: float = math.inf  # horizontal speed norm
    z_min: float = -math.inf  # altitude band on Z (NED, down positive)
    z_max: float = math.inf
    rate_max: float | None = None  # |φ̇|, |θ̇| [rad/s]; None: not constrained
    u_psi_max: float = math.inf  # |u_ψ| [N·m]
    k_psi: float = 1.0  # K of eq. (7)
    g: float = G

    @classmethod
    def from_vehicle(cls, vehicle: Vehicle, tilt: float, thrust_ratio: float, v_max: float = math.inf,
                     tilt_model: str | None = None, rates: bool = False, **kw) -> "Limits":
        vehicle.require(("inertia_kg_m2", "yaw_moment_max_nm"), "the avoid contract (build with --stop-only without them)")
        return cls(mass=vehicle.mass_kg, t_max=vehicle.t_max(thrust_ratio), tilt=tilt,
                   tilt_model=tilt_model or vehicle.tilt_model, v_max=v_max,
                   rate_max=vehicle.tilt_rate_max if rates else None,
                   u_psi_max=vehicle.yaw_moment_max_nm, k_psi=vehicle.k_psi, **kw)

    @property
    def phi_lim(self) -> float:
        return self.tilt if self.phi_max is None else self.phi_max

    @property
    def theta_lim(self) -> float:
        return self.tilt if self.theta_max is None else self.theta_max

    def accel_bound(self) -> float:
        """An upper bound on |a_h| over the input set in level flight (used for scaling only)."""
        a_t = thrust_limited_accel(self.t_max, self.mass, self.g)
        if self.tilt_model == "cone":
            return min(a_t, self.g * math.tan(self.tilt))
        tp, tt = math.tan(self.phi_lim), math.tan(self.theta_lim)
        return min(a_t, self.g * math.hypot(tt, tp * math.sqrt(1 + tt * tt)))


@dataclass(frozen=True)
class Circle:
    """Vertical circular column (keep-out disc) centred at (cx, cy) with radius r."""

    cx: float
    cy: float
    r: float


@dataclass(frozen=True)
class Polygon:
    """Convex vertical prism with horizontal cross-section conv(vertices) (ordered), kept `r` away."""

    vertices: tuple[tuple[float, float], ...]
    r: float = 0.0

    def halfplanes(self):
        """Unit outward normals A and offsets b with A·p ≤ b inside (counter-clockwise or not)."""
        v = np.asarray(self.vertices, dtype=float)
        ctr = v.mean(axis=0)
        e = np.roll(v, -1, axis=0) - v
        n = np.column_stack([e[:, 1], -e[:, 0]])
        n /= np.linalg.norm(n, axis=1)[:, None]
        b = np.einsum("ij,ij->i", n, v)
        flip = (n @ ctr - b) > 0
        n[flip] *= -1.0
        b[flip] *= -1.0
        return n, b


@dataclass(frozen=True)
class PlanProblem:
    """One instance of eq. (16)–(19).

    `planar`: level flight at the altitude and yaw of q_0 (Z, ψ fixed, Z̈ = ψ̈ = 0) — the contract's
    setting (DESIGN.md §2); otherwise all four chains are free.
    `terminal`: "coast" (the ballistic continuation from q(N) is safe against every circle; for the
    contract — polygons are kept out over the horizon only) or "box" (q(N) within [qf_lb, qf_ub],
    the paper's q(N) = q_f).
    """

    limits: Limits
    q0: tuple[float, ...]  # [X, Ẋ, Y, Ẏ, Z, Ż, ψ, ψ̇]
    obstacles: tuple = ()
    w0: tuple[float, ...] | None = None  # eq. (18) w(1) = w_0 (needed for rate limits)
    wf: tuple[float, ...] | None = None  # eq. (18) w(N) = w_f
    terminal: str = "coast"
    qf_lb: tuple[float, ...] | None = None
    qf_ub: tuple[float, ...] | None = None
    n: int = 40
    planar: bool = True
    t_f_max: float = 60.0
    free_speed: bool = False  # max-speed form: q0's Ẋ and V_max become one decision variable V
    v_bounds: tuple[float, float] = (0.0, 1e3)
    lead_time: float = 0.0  # max-speed form only: X(0) = V·lead_time (coast during the reaction time)


@dataclass
class PlanResult:
    ok: bool  # IPOPT returned a point AND the dense re-simulation confirmed every constraint
    status: str  # IPOPT return status
    t_f: float
    ts: float
    q: np.ndarray  # (N+1, 8) re-simulated node states
    w: np.ndarray  # (N, 4) ZOH synthetic inputs
    check: dict
    cpu_s: float
    iterations: int
    problem: PlanProblem
    raw: dict = field(default_factory=dict, repr=False)  # primal/dual vectors for warm starts

    def references(self, sub: int = 1) -> dict:
        """Controller references x_r, y_r, z_r, φ_r, θ_r, ψ_r (and T) along the plan, eq. (7)–(8).

        Positions at `sub` points per interval (plus the final node); attitude and thrust are the ZOH
        values of the interval each point starts (the last point repeats the last interval's).
        """
        lim = self.problem.limits
        t, q, wi = dense_states(self.problem.q0, self.w, self.ts, sub)
        t_cmd, phi, theta, _ = inputs_from_flat(wi[:, 0], wi[:, 1], wi[:, 2], q[:, 6], mass=lim.mass,
                                                k_psi=lim.k_psi, g=lim.g)
        return {"t": t, "x_r": q[:, 0], "y_r": q[:, 2], "z_r": q[:, 4], "phi_r": phi, "theta_r": theta,
                "psi_r": q[:, 6], "thrust": t_cmd, "vx": q[:, 1], "vy": q[:, 3], "vz": q[:, 5],
                "ax": wi[:, 0], "ay": wi[:, 1], "az": wi[:, 2]}


# ============================================================================ exact re-simulation


def propagate(q0, w, ts):
    """Eq. (12)–(13) in closed form: node states q(k) for the ZOH inputs w (N, 4) → (N+1, 8)."""
    q = np.empty((len(w) + 1, 8))
    q[0] = q0
    for k, wk in enumerate(w):
        pos, vel = q[k, 0::2], q[k, 1::2]
        q[k + 1, 0::2] = pos + vel * ts + 0.5 * wk * ts * ts
        q[k + 1, 1::2] = vel + wk * ts
    return q


def dense_states(q0, w, ts, sub):
    """Re-simulate from q0 with `sub` sub-steps per interval: times, states (N·sub+1, 8), and the
    input in force at each point (the last point repeats the last input)."""
    w = np.asarray(w, dtype=float)
    qn = propagate(np.asarray(q0, dtype=float), w, ts)
    tau = ts * np.arange(sub) / sub
    pos = qn[:-1, None, 0::2] + qn[:-1, None, 1::2] * tau[None, :, None] + 0.5 * w[:, None, :] * tau[None, :, None] ** 2
    vel = qn[:-1, None, 1::2] + w[:, None, :] * tau[None, :, None]
    q = np.empty((len(w) * sub + 1, 8))
    q[:-1, 0::2] = pos.reshape(-1, 4)
    q[:-1, 1::2] = vel.reshape(-1, 4)
    q[-1] = qn[-1]
    wi = np.vstack([np.repeat(w, sub, axis=0), w[-1:]])
    t = np.append((np.arange(len(w))[:, None] * ts + tau[None, :]).ravel(), len(w) * ts)
    return t, q, wi


def circle_min_distance(qn, w, ts, cx, cy):
    """Exact minimum over each interval of |p(τ) − o|, p a ZOH parabola: endpoints and the real
    roots in (0, t_s) of the cubic d/dτ |p − o|² = 0. Returns an (N,) array."""
    p0 = qn[:-1, [0, 2]] - np.array([cx, cy])
    v0 = qn[:-1, [1, 3]]
    a = 0.5 * np.asarray(w, dtype=float)[:, :2]
    out = np.empty(len(p0))
    for k in range(len(p0)):
        P, V, A = p0[k], v0[k], a[k]
        cand = [0.0, ts]
        coef = [2.0 * A @ A, 3.0 * V @ A, 2.0 * P @ A + V @ V, P @ V]
        while coef and abs(coef[0]) < 1e-300:
            coef = coef[1:]
        if len(coef) > 1:
            for r in np.roots(coef):
                if abs(r.imag) < 1e-9 * max(1.0, abs(r.real)) and 0.0 < r.real < ts:
                    cand.append(r.real)
        tt = np.array(cand)
        pts = P[None, :] + V[None, :] * tt[:, None] + A[None, :] * tt[:, None] ** 2
        out[k] = np.sqrt(np.min(np.einsum("ij,ij->i", pts, pts)))
    return out


def polygon_distance(points, poly: Polygon):
    """Signed distance from points (M, 2) to a convex polygon: Euclidean outside, −(depth to the
    nearest face) = max_j(a_j·p − b_j) ≤ 0 inside."""
    points = np.asarray(points, dtype=float)
    v = np.asarray(poly.vertices, dtype=float)
    a, b = poly.halfplanes()
    e0, e1 = v, np.roll(v, -1, axis=0)
    d = e1 - e0
    t = np.clip(np.einsum("mke,ke->mk", points[:, None, :] - e0[None], d) / np.einsum("ke,ke->k", d, d), 0.0, 1.0)
    foot = e0[None] + t[..., None] * d[None]
    dist = np.min(np.linalg.norm(points[:, None, :] - foot, axis=-1), axis=1)
    face = np.max(points @ a.T - b, axis=1)
    return np.where(face <= 0.0, face, dist)


def _quadratic_roots(c2, c1, c0):
    """Roots of c2·τ² + c1·τ + c0, elementwise, in the cancellation-free form (a degenerate quadratic
    gives its linear root, a complex pair its real part; non-finite where there is none)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sqrt(np.maximum(c1 * c1 - 4.0 * c2 * c0, 0.0))
        q = -0.5 * (c1 + np.where(c1 >= 0.0, s, -s))
        return q / c2, c0 / q


def polygon_min_distance(qn, w, ts, poly: Polygon):
    """Exact minimum over each ZOH interval of the signed distance (`polygon_distance`) from the
    parabola p(τ) = p_k + v_k·τ + ½w_k·τ² to the polygon. Returns an (N,) array.

    Candidates τ ∈ [0, t_s]: the ends; outside, stationary points of |p − V_j|² (cubic, as in
    `circle_min_distance`) and of a_j·p; inside, where sd = max_j(a_j·p − b_j), also the crossings
    a_i·p − b_i = a_j·p − b_j and the face crossings a_j·p = b_j. The distance is evaluated at each
    candidate, so a root off by δτ moves the answer by at most |v|·δτ."""
    qn, w = np.asarray(qn, float), np.asarray(w, float)
    P, V, A = qn[:-1, [0, 2]], qn[:-1, [1, 3]], 0.5 * w[:, :2]
    a, b = poly.halfplanes()
    verts = np.asarray(poly.vertices, float)
    i, j = np.triu_indices(len(b), 1)
    C = np.vstack([a, a[i] - a[j]])  # linear functionals c·p − e whose zeros are candidates
    e = np.concatenate([b, b[i] - b[j]])
    c2, c1, c0 = A @ C.T, V @ C.T, P @ C.T - e
    r1, r2 = _quadratic_roots(c2, c1, c0)
    with np.errstate(divide="ignore", invalid="ignore"):
        stat = -c1[:, : len(b)] / (2.0 * c2[:, : len(b)])  # d/dτ a_j·p = 0
    out = np.empty(len(P))
    for k in range(len(P)):
        cand = [np.array([0.0, ts]), r1[k], r2[k], stat[k]]
        for vx in verts:
            D = P[k] - vx
            coef = [2.0 * A[k] @ A[k], 3.0 * V[k] @ A[k], 2.0 * D @ A[k] + V[k] @ V[k], D @ V[k]]
            while coef and abs(coef[0]) < 1e-300:
                coef = coef[1:]
            if len(coef) > 1:
                cand.append(np.roots(coef).real)
        tau = np.concatenate(cand)
        tau = np.clip(tau[np.isfinite(tau)], 0.0, ts)[:, None]
        out[k] = np.min(polygon_distance(P[k] + V[k] * tau + A[k] * tau**2, poly))
    return out


def ray_clear_of_circle(p, v, c: Circle) -> float:
    """Minimum distance from the ray p + s·v (s ≥ 0) to the centre of `c`, minus its radius.
    A speed below STOPPED [m/s] counts as stopped (position hold), not as a creep along the ray."""
    d = np.asarray(p, float) - np.array([c.cx, c.cy])
    vv = float(np.dot(v, v))
    s = 0.0 if vv <= STOPPED**2 else max(0.0, -float(np.dot(d, v)) / vv)
    return float(np.linalg.norm(d + s * np.asarray(v, float))) - c.r


def check_trajectory(problem: PlanProblem, w, ts, sub: int = 20, tol: float = 1e-3) -> dict:
    """Dense re-simulation (≥ 20 sub-steps per interval) from q_0 and every constraint of eq. (14),
    the obstacles and the boundary conditions. Lengths are confirmed to `tol` [m]; angles, thrust and
    speed to a relative 1e-9. Returns the worst margin of each constraint (≥ 0 is satisfied) and `ok`.
    """
    sub = max(int(sub), 20)
    lim = problem.limits
    w = np.asarray(w, dtype=float)
    t, q, wi = dense_states(problem.q0, w, ts, sub)
    qn = propagate(np.asarray(problem.q0, float), w, ts)
    rel = 1e-9
    m: dict[str, float] = {}
    g = lim.g
    ax, ay, az, psi = wi[:, 0], wi[:, 1], wi[:, 2], q[:, 6]
    gz = g - az
    m["thrust_axis_up"] = float(np.min(gz))
    t_cmd, phi, theta, u_psi = inputs_from_flat(ax, ay, az, psi, wi[:, 3], mass=lim.mass, k_psi=lim.k_psi, g=g)
    if lim.tilt_model == "cone":
        m["tilt"] = float(np.min(lim.tilt * (1 + rel) - total_tilt(ax, ay, az, g)))
    else:
        m["roll"] = float(np.min(lim.phi_lim * (1 + rel) - np.abs(phi)))
        m["pitch"] = float(np.min(lim.theta_lim * (1 + rel) - np.abs(theta)))
    m["thrust_max"] = float(np.min(lim.t_max * (1 + rel) - t_cmd))
    m["thrust_min"] = float(np.min(t_cmd - lim.t_min * (1 - rel)))
    if math.isfinite(lim.u_psi_max):
        m["yaw_moment"] = float(np.min(lim.u_psi_max * (1 + rel) - np.abs(u_psi)))
    if math.isfinite(lim.v_max):
        m["speed"] = float(np.min(lim.v_max * (1 + rel) - np.hypot(q[:, 1], q[:, 3])))
    if math.isfinite(lim.z_min) or math.isfinite(lim.z_max):
        m["altitude"] = float(min(np.min(q[:, 4] - lim.z_min), np.min(lim.z_max - q[:, 4]))) + tol
    if lim.rate_max is not None:
        _, phi_k, th_k, _ = inputs_from_flat(w[:, 0], w[:, 1], w[:, 2], qn[:-1, 6], mass=lim.mass, g=g)
        if problem.w0 is not None:
            w0 = np.asarray(problem.w0, float)
            _, p0, t0, _ = inputs_from_flat(w0[0], w0[1], w0[2], problem.q0[6], mass=lim.mass, g=g)
            phi_k, th_k = np.append(p0, phi_k), np.append(t0, th_k)
        step = lim.rate_max * ts * (1 + rel)
        m["roll_rate"] = float(np.min(step - np.abs(np.diff(phi_k)))) if len(phi_k) > 1 else 0.0
        m["pitch_rate"] = float(np.min(step - np.abs(np.diff(th_k)))) if len(th_k) > 1 else 0.0
    if problem.w0 is not None:
        m["w0"] = -float(np.max(np.abs(w[0] - np.asarray(problem.w0))[: _n_free(problem)])) + 1e-9
    for i, ob in enumerate(problem.obstacles):
        if isinstance(ob, Circle):
            d = circle_min_distance(qn, w, ts, ob.cx, ob.cy)
            m[f"keep_out_{i}"] = float(np.min(d) - ob.r) + tol
            if problem.terminal == "coast":
                m[f"coast_{i}"] = ray_clear_of_circle(qn[-1, [0, 2]], qn[-1, [1, 3]], ob) + tol
        else:  # exact per-interval minimum of the signed distance (negative inside)
            d = polygon_min_distance(qn, w, ts, ob)
            m[f"keep_out_{i}"] = float(np.min(d) - ob.r) + tol
    if problem.terminal == "box":
        lo = np.asarray(problem.qf_lb, float)
        hi = np.asarray(problem.qf_ub, float)
        m["terminal"] = float(min(np.min(qn[-1] - lo), np.min(hi - qn[-1]))) + tol
    if problem.wf is not None:
        m["wf"] = -float(np.max(np.abs(w[-1] - np.asarray(problem.wf))[: _n_free(problem)])) + 1e-9
    ok = all(np.isfinite(v) and v >= 0.0 for v in m.values())
    return {"ok": bool(ok), "margins": m, "sub_steps": sub,
            "min_clearance": min((v - tol for k, v in m.items() if k.startswith("keep_out")), default=math.inf)}


def _n_free(problem: PlanProblem) -> int:
    return 2 if problem.planar else 4


# ============================================================================ NLP construction


class _Builder:
    """Collects decision variables and constraints of one NLP structure."""

    def __init__(self):
        self.x, self.lbx, self.ubx, self.g, self.lbg, self.ubg = [], [], [], [], [], []

    def var(self, name, n=1):
        v = ca.SX.sym(name, n)
        self.x.append(v)
        return v

    def con(self, expr, lb, ub):
        self.g.append(expr)
        n = expr.shape[0]
        self.lbg.append(np.broadcast_to(lb, (n,)).astype(float))
        self.ubg.append(np.broadcast_to(ub, (n,)).astype(float))


def _structure(problem: PlanProblem) -> tuple:
    lim = problem.limits
    obs = tuple(("c",) if isinstance(o, Circle) else ("p", len(o.vertices)) for o in problem.obstacles)
    return (problem.n, problem.planar, lim.tilt_model, lim.rate_max is not None, problem.w0 is not None,
            problem.terminal, obs, problem.free_speed)


_CACHE: dict[tuple, tuple] = {}


def _solver(struct: tuple, ipopt_opts: dict):
    key = (struct, tuple(sorted(ipopt_opts.items())))
    if key not in _CACHE:
        _CACHE[key] = _build(struct, ipopt_opts)
    return _CACHE[key]


def _build(struct, ipopt_opts):
    n, planar, tilt_model, rates, has_w0, terminal, obs, free_speed = struct
    nax = 2 if planar else 4
    b = _Builder()
    # parameters
    P = {k: ca.SX.sym(k) for k in ("g", "tan_a", "tan_b", "tmax2", "tmin2", "vmax2", "rate", "z0", "psi0", "lead", "zmin", "zmax")}
    w0p = ca.SX.sym("w0", 4)
    obs_p = []
    for o in obs:
        obs_p.append(ca.SX.sym("circ", 3) if o[0] == "c" else ca.SX.sym("poly", 2 * o[1] + 1))
    pvec = ca.vertcat(*P.values(), w0p, *obs_p)

    ts = b.var("ts")
    Q = [b.var(f"q{k}", 2 * nax) for k in range(n + 1)]
    W = [b.var(f"w{k}", nax) for k in range(n)]
    if free_speed:  # max-speed form: V = Ẋ(0) = V_max is a decision variable, cost −V
        vfree = ca.SX.sym("v")  # appended last to the variables
        b.con(Q[0][1] - vfree, 0.0, 0.0)
        b.con(Q[0][0] - P["lead"] * vfree, 0.0, 0.0)  # coasted V·t_lead before the manoeuvre
        vmax2 = vfree**2
    else:
        vmax2 = P["vmax2"]

    def full_w(wk):  # → (ax, ay, az, psi_ddot)
        return (wk[0], wk[1], 0, 0) if planar else (wk[0], wk[1], wk[2], wk[3])

    def psi_of(qk):
        return P["psi0"] if planar else qk[6]

    # eq. (12)-(13): ZOH double-integrator chains, closed form with symbolic t_s
    for k in range(n):
        pos, vel = Q[k][0::2], Q[k][1::2]
        b.con(Q[k + 1][0::2] - (pos + vel * ts + 0.5 * W[k] * ts**2), 0.0, 0.0)
        b.con(Q[k + 1][1::2] - (vel + W[k] * ts), 0.0, 0.0)

    g = P["g"]
    att = []
    for k in range(n):
        ax, ay, az, _ = full_w(W[k])
        gz = g - az
        h2 = ax**2 + ay**2
        psi = psi_of(Q[k])
        a_fwd = ax * ca.cos(psi) + ay * ca.sin(psi)
        a_lat = -ax * ca.sin(psi) + ay * ca.cos(psi)
        if not planar:
            b.con(gz, 1e-3, ca.inf)
        if tilt_model == "cone":
            b.con(h2 - P["tan_a"] ** 2 * gz**2, -ca.inf, 0.0)
        else:  # box: |θ| ≤ θ_max and |φ| ≤ φ_max through eq. (8), at 0, ½, 1 of the interval's yaw
            fracs = (0.0,) if planar else (0.0, 0.5, 1.0)
            for fr in fracs:
                tau = fr * ts
                ps = psi if planar else Q[k][6] + Q[k][7] * tau + 0.5 * W[k][3] * tau**2
                af = ax * ca.cos(ps) + ay * ca.sin(ps)
                al = -ax * ca.sin(ps) + ay * ca.cos(ps)
                b.con(af**2 - P["tan_b"] ** 2 * gz**2, -ca.inf, 0.0)
                b.con(al**2 - P["tan_a"] ** 2 * (gz**2 + af**2), -ca.inf, 0.0)
        b.con(h2 + gz**2 - P["tmax2"], -ca.inf, 0.0)
        b.con(h2 + gz**2 - P["tmin2"], 0.0, ca.inf)
        if rates:
            att.append((ca.atan(a_lat / ca.sqrt(gz**2 + a_fwd**2)), -ca.atan(a_fwd / gz)))
    if not planar:  # altitude band between samples: the Bézier middle control point of Z (nodes: bounds)
        for k in range(n):
            b.con(Q[k][4] + 0.5 * ts * Q[k][5] - P["zmin"], 0.0, ca.inf)
            b.con(P["zmax"] - Q[k][4] - 0.5 * ts * Q[k][5], 0.0, ca.inf)
    # speed norm at the nodes (|v|² is convex along a ZOH interval, so the nodes bound it)
    for k in range(1, n + 1):
        b.con(Q[k][1] ** 2 + Q[k][3] ** 2 - vmax2, -ca.inf, 0.0)  # V_max itself: a cruise at V_max is allowed
    if has_w0:  # eq. (18) w(1) = w_0
        b.con(W[0] - w0p[:nax], 0.0, 0.0)
    if rates:
        if has_w0:
            ax0, ay0, az0 = w0p[0], w0p[1], w0p[2] if not planar else 0
            gz0 = g - az0
            psi = psi_of(Q[0])
            f0 = ax0 * ca.cos(psi) + ay0 * ca.sin(psi)
            l0 = -ax0 * ca.sin(psi) + ay0 * ca.cos(psi)
            att.insert(0, (ca.atan(l0 / ca.sqrt(gz0**2 + f0**2)), -ca.atan(f0 / gz0)))
        for k in range(len(att) - 1):
            for j in range(2):
                b.con(att[k + 1][j] - att[k][j] - P["rate"] * ts, -ca.inf, 0.0)
                b.con(att[k + 1][j] - att[k][j] + P["rate"] * ts, 0.0, ca.inf)

    # keep-out between samples: separating line per interval for the Bézier control points
    for o, op in zip(obs, obs_p):
        if o[0] == "c":
            ctr, r = op[0:2], op[2]
        else:
            m = o[1]
            verts = ca.reshape(op[: 2 * m], 2, m)
            r = op[2 * m]
        for k in range(n):
            p0 = ca.vertcat(Q[k][0], Q[k][2])
            v0 = ca.vertcat(Q[k][1], Q[k][3])
            p2 = ca.vertcat(Q[k + 1][0], Q[k + 1][2])
            p1 = p0 + 0.5 * ts * v0
            nv = b.var(f"n{k}", 2)
            if o[0] == "c":
                b.con(ca.sumsqr(nv), -ca.inf, 1.0)
                for pc in (p0, p1, p2):
                    b.con(ca.dot(nv, pc - ctr) - r, 0.0, ca.inf)
            else:  # |n| = 1: with |n| ≤ 1 and r = 0, n = 0, β = 0 would satisfy eq. (19) trivially
                b.con(ca.sumsqr(nv), 1.0, 1.0)
                beta = b.var(f"beta{k}")
                for pc in (p0, p1, p2):
                    b.con(ca.dot(nv, pc) - beta - r, 0.0, ca.inf)
                b.con(ca.mtimes(nv.T, verts).T - beta, -ca.inf, 0.0)
        if terminal == "coast" and o[0] == "c":  # the ballistic continuation misses the disc
            nt = b.var("nT", 2)
            pn = ca.vertcat(Q[n][0], Q[n][2])
            vn = ca.vertcat(Q[n][1], Q[n][3])
            b.con(ca.sumsqr(nt), -ca.inf, 1.0)
            b.con(ca.dot(nt, pn - ctr) - r, 0.0, ca.inf)
            b.con(ca.dot(nt, vn), 0.0, ca.inf)

    if free_speed:
        b.x.append(vfree)
    x = ca.vertcat(*b.x)
    nlp = {"x": x, "p": pvec, "f": -vfree if free_speed else n * ts, "g": ca.vertcat(*b.g)}
    opts = {"ipopt": dict(ipopt_opts), "print_time": False}
    solver = ca.nlpsol("planner", "ipopt", nlp, opts)
    layout = {"nax": nax, "n": n, "nx": int(x.shape[0]), "np": int(pvec.shape[0])}
    return solver, np.concatenate(b.lbg), np.concatenate(b.ubg), layout, obs


DEFAULT_IPOPT = {
    "print_level": 0,
    "sb": "yes",
    "tol": 1e-8,
    "constr_viol_tol": 1e-9,
    "acceptable_tol": 1e-6,
    "acceptable_constr_viol_tol": 1e-9,
    "max_iter": 3000,
    "mu_strategy": "adaptive",
    "linear_solver": "mumps",
}


def _params(problem: PlanProblem) -> np.ndarray:
    lim = problem.limits
    s = 1.0 - SHRINK
    if lim.tilt_model == "cone":
        tan_a, tan_b = math.tan(lim.tilt) * s, 0.0
    else:
        tan_a, tan_b = math.tan(lim.phi_lim) * s, math.tan(lim.theta_lim) * s
    tmax2 = (lim.t_max / lim.mass * s) ** 2
    tmin2 = (lim.t_min / lim.mass / s) ** 2
    vmax2 = lim.v_max**2 if math.isfinite(lim.v_max) else 1e12
    rate = (lim.rate_max or 0.0) * s
    w0 = np.zeros(4) if problem.w0 is None else np.asarray(problem.w0, float)
    zb = [max(lim.z_min, -1e9), min(lim.z_max, 1e9)]
    vals = [lim.g, tan_a, tan_b, tmax2, tmin2, vmax2, rate, problem.q0[4], problem.q0[6], problem.lead_time, *zb, *w0]
    for o in problem.obstacles:
        if isinstance(o, Circle):
            vals += [o.cx, o.cy, o.r * (1 + SHRINK)]
        else:
            vals += list(np.asarray(o.vertices, float).T.ravel(order="F")) + [o.r * (1 + SHRINK)]
    return np.asarray(vals, dtype=float)


def _x_bounds(problem: PlanProblem, layout) -> tuple[np.ndarray, np.ndarray]:
    nax, n, nx = layout["nax"], layout["n"], layout["nx"]
    lim = problem.limits
    lbx, ubx = np.full(nx, -np.inf), np.full(nx, np.inf)
    lbx[0], ubx[0] = 1e-5, problem.t_f_max / n
    ns = 2 * nax
    q0 = np.asarray(problem.q0, float)[:ns]
    lbx[1 : 1 + ns] = ubx[1 : 1 + ns] = q0
    if not problem.planar:
        zi = 1 + np.arange(n + 1) * ns + 4
        lbx[zi] = np.maximum(lbx[zi], lim.z_min)
        ubx[zi] = np.minimum(ubx[zi], lim.z_max)
        wi = 1 + (n + 1) * ns + np.arange(n) * nax + 3
        psi_dd = lim.u_psi_max * lim.k_psi * (1 - SHRINK)
        lbx[wi], ubx[wi] = -psi_dd, psi_dd
        lbx[zi[0]] = ubx[zi[0]] = q0[4]
    if problem.free_speed:
        lbx[1], ubx[1] = -np.inf, np.inf
        lbx[2], ubx[2] = problem.v_bounds
        lbx[-1], ubx[-1] = problem.v_bounds
    if problem.terminal == "box":
        last = 1 + n * ns
        lbx[last : last + ns] = np.asarray(problem.qf_lb, float)[:ns]
        ubx[last : last + ns] = np.asarray(problem.qf_ub, float)[:ns]
    if problem.wf is not None:
        last = 1 + (n + 1) * ns + (n - 1) * nax
        lbx[last : last + nax] = ubx[last : last + nax] = np.asarray(problem.wf, float)[:nax]
    return lbx, ubx


def _obstacle_normals_guess(problem: PlanProblem, qn: np.ndarray, ts: float) -> list[float]:
    """Initial separating lines: from each obstacle's centre towards the interval's midpoint."""
    out = []
    mids = 0.5 * (qn[:-1, [0, 2]] + qn[1:, [0, 2]])
    for o in problem.obstacles:
        if isinstance(o, Circle):
            ctr = np.array([o.cx, o.cy])
        else:
            ctr = np.asarray(o.vertices, float).mean(axis=0)
        for mpt in mids:
            d = mpt - ctr
            if isinstance(o, Circle):
                out += list(d / max(np.linalg.norm(d), 1e-9))
            else:  # a unit normal (|n| = 1) and the supporting line β = max_j n·V_j
                u = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-9 else np.array([0.0, 1.0])
                out += list(u) + [float(np.max(np.asarray(o.vertices, float) @ u))]
        if problem.terminal == "coast" and isinstance(o, Circle):
            d = qn[-1, [0, 2]] - ctr
            out += list(d / max(np.linalg.norm(d), 1e-9))
    return out


def initial_guess(problem: PlanProblem, w: np.ndarray, ts: float) -> np.ndarray:
    """Primal start from ZOH inputs (N, 4) and a sample time: states by exact propagation."""
    nax = 2 if problem.planar else 4
    w = np.asarray(w, float)
    qn = propagate(np.asarray(problem.q0, float), w, ts)
    ns = 2 * nax
    if problem.free_speed:
        qn[:, 0] += problem.q0[1] * problem.lead_time - problem.q0[0]
    x = [ts] + list(qn[:, :ns].ravel()) + list(w[:, :nax].ravel())
    x += _obstacle_normals_guess(problem, qn, ts)
    if problem.free_speed:
        x.append(float(problem.q0[1]))
    return np.asarray(x, dtype=float)


def default_guess(problem: PlanProblem) -> tuple[np.ndarray, float]:
    """A gentle swerve to +y (half the level-flight acceleration bound) for the time to coast past
    the farthest obstacle (or 2 s): keeps the separating lines of the start well defined."""
    q0 = np.asarray(problem.q0, float)
    v = math.hypot(q0[1], q0[3])
    far = 0.0
    for o in problem.obstacles:
        c = (o.cx, o.cy) if isinstance(o, Circle) else np.asarray(o.vertices, float).mean(axis=0)
        far = max(far, math.hypot(c[0] - q0[0], c[1] - q0[2]) + 2 * getattr(o, "r", 0.0))
    t_f = far / v if v > 0 and far > 0 else 2.0
    w = np.zeros((problem.n, 4))
    w[:, 1] = 0.5 * problem.limits.accel_bound()
    return w, min(t_f, problem.t_f_max) / problem.n


def plan(problem: PlanProblem, guess: tuple[np.ndarray, float] | None = None, *, x0: np.ndarray | None = None,
         cpu_time: float = 5.0, verify_tol: float = 1e-3, sub: int = 20, ipopt: dict | None = None) -> PlanResult:
    """Solve eq. (16)–(19) and verify the answer by dense re-simulation (`check_trajectory`).

    `guess` = (w (N, 4), t_s) builds a primal start; `x0` (a previous `raw['x']` of the same structure)
    overrides it (warm start). `cpu_time` caps IPOPT (`max_cpu_time`). `ok` is True only if the
    re-simulated trajectory satisfies every constraint (lengths to `verify_tol`).
    """
    opts = dict(DEFAULT_IPOPT, max_cpu_time=float(cpu_time), **(ipopt or {}))
    solver, lbg, ubg, layout, _ = _solver(_structure(problem), opts)
    lbx, ubx = _x_bounds(problem, layout)
    if x0 is None:
        w_g, ts_g = guess if guess is not None else default_guess(problem)
        x0 = initial_guess(problem, w_g, ts_g)
    x0 = np.clip(np.asarray(x0, float), lbx, ubx)
    t0 = time.process_time()
    sol = solver(x0=x0, p=_params(problem), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    cpu = time.process_time() - t0
    st = solver.stats()
    x = np.asarray(sol["x"]).ravel()
    nax, n = layout["nax"], layout["n"]
    ts = float(x[0])
    ns = 2 * nax
    w = np.zeros((n, 4))
    w[:, :nax] = x[1 + (n + 1) * ns : 1 + (n + 1) * ns + n * nax].reshape(n, nax)
    if problem.free_speed:  # verify the answer as the fixed-speed problem it certifies
        v = float(x[-1])
        q0 = list(problem.q0)
        q0[0], q0[1] = v * problem.lead_time, v
        problem = replace(problem, q0=tuple(q0), limits=replace(problem.limits, v_max=v), free_speed=False,
                          lead_time=0.0)
    qn = propagate(np.asarray(problem.q0, float), w, ts)
    if np.all(np.isfinite(w)) and np.isfinite(ts) and ts > 0:
        check = check_trajectory(problem, w, ts, sub=sub, tol=verify_tol)
    else:
        check = {"ok": False, "margins": {}, "sub_steps": sub, "min_clearance": -math.inf}
    return PlanResult(ok=bool(check["ok"]), status=str(st.get("return_status")), t_f=n * ts, ts=ts, q=qn, w=w,
                      check=check, cpu_s=cpu, iterations=int(st.get("iter_count", 0)), problem=problem,
                      raw={"x": x, "lam_g": np.asarray(sol["lam_g"]).ravel(), "lam_x": np.asarray(sol["lam_x"]).ravel()})


def head_on_problem(limits: Limits, v: float, c: float, r_k: float, n: int = 40, **kw) -> PlanProblem:
    """The contract's head-on geometry (DESIGN.md §2): at the origin flying +x at `v` (= V_max), the
    keep-out disc of radius r_k centred at (c, 0); level flight; terminal set: coast is safe."""
    limits = replace(limits, v_max=v)
    return PlanProblem(limits=limits, q0=(0.0, v, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                       obstacles=(Circle(c, 0.0, r_k),), n=n, terminal="coast", **kw)
