"""Analytical construction of the contract from collision sets, eq. (20)–(28).

Pure numpy/scipy (no CasADi, no I/O). Horizontal flat dynamics only (level flight, DESIGN.md §2):
q = [X, Ẋ, Y, Ẏ], w = [Ẍ, Ÿ], discretised by ZOH with sample time t_s (`flat.zoh(ts, 2)`, eq. 12–13).

Obstacle: a polytope C_0 = {q | C_0 q ≤ D_0} with position rows only (velocity free) — a vertical
column of convex cross-section, e.g. a square of any side, centre and orientation (`square_obstacle`).
Input set: W^C = conv(w_1 … w_m) (`box_vertices`: the paper's roll/pitch limits; `cone_vertices`:
the inscribed polygon of the total-tilt disc).

Recursion, eq. (21)/(23): C_k = {q | ∀w ∈ W^C: F̂q + Ĝw ∈ C_{k−1}}, C_0 = obstacle. By linearity and
convexity it is enough to ask it at the vertices, eq. (24), which gives the closed propagation
eq. (25): C_k = C_{k−1}F̂, D_kj = D_{k−1} − C_{k−1}Ĝw_j, and because the m constraints of one row
are parallel hyperplanes their intersection is the row-wise minimum, eq. (26): D_k,min. Propagation
stops at the first k whose {q | C_k q ≤ D_k,min} is empty (decided by an LP, HiGHS); all later sets
are empty too. The union of C_0 … C_r is eq. (22)/(27).

What the recursion collects (read this before trusting the curves). C_k holds the states that are
inside the obstacle *at step k under every admissible input sequence* — the same step k for all of
them. Eq. (20) asks less: every sequence must hit the obstacle at *some* step, which may differ from
sequence to sequence. So ∪C_k ⊆ 𝒞 of eq. (20): the recursion misses states whose collision is
inevitable but not synchronous (e.g. braking hits a wide, thin wall later than not braking, and the
spread of positions reached at step k no longer fits inside the wall's depth, so C_k is already
empty). A smaller unsafe set means a *higher* V_max(D_od) curve: the analytical curve is optimistic
(never conservative) with respect to eq. (20)'s true collision set. For a square column met head-on
with equal roll and pitch limits the loss is nil (the recursion ends exactly when a full-lateral
swerve clears the half side, which is also when the true set ends); it grows for thin or elongated
obstacles and for unequal limits (see COLLISION_SETS.md). A second, smaller optimism comes from
sampling: collisions are only asked at t = k·t_s, so the minimum over the lines is taken over the
grid T = k·t_s instead of every T; it vanishes as t_s → 0 (`continuous_head_on_v_max`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import HalfspaceIntersection

from .flat import cone_polygon, thrust_limited_accel, zoh
from .vehicle import G

TS_DEFAULT = 0.02  # [s] the guidance loop period (50 Hz, DESIGN.md §5); see COLLISION_SETS.md
K_MAX_DEFAULT = 10_000  # safety cap on the number of backward steps (a degenerate W^C never empties)
N_AXES = 2  # horizontal chains only: q = [X, Ẋ, Y, Ẏ]


# ============================================================================ obstacle and input set


def polygon_obstacle(normals, offsets):
    """C_0, D_0 of a vertical column with cross-section {p | n_i·p ≤ b_i}: position rows, velocity free."""
    n = np.asarray(normals, dtype=float).reshape(-1, 2)
    c0 = np.zeros((len(n), 2 * N_AXES))
    c0[:, 0::2] = n  # columns X and Y; Ẋ, Ẏ stay zero
    return c0, np.asarray(offsets, dtype=float).reshape(-1).copy()


def square_obstacle(side: float, centre=(0.0, 0.0), angle: float = 0.0):
    """C_0, D_0 of a square column of side `side` [m] centred at `centre`, rotated by `angle` [rad].

    Rows in the order +x', +y', −x', −y' of the square's own axes (x' = rotated x)."""
    if not side > 0:
        raise ValueError(f"side must be positive, got {side}")
    ca, sa = math.cos(angle), math.sin(angle)
    axes = np.array([[ca, sa], [-sa, ca], [-ca, -sa], [sa, -ca]])
    return polygon_obstacle(axes, axes @ np.asarray(centre, float) + 0.5 * side)


def polygon_vertices(a, b) -> np.ndarray:
    """Vertices (counter-clockwise) of the bounded 2-D polygon {x | A x ≤ b} with 0 in its interior."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if np.any(b <= 0):
        raise ValueError("the origin must be interior to the polygon")
    v = HalfspaceIntersection(np.column_stack([a, -b]), np.zeros(2)).intersections
    v = v[np.argsort(np.arctan2(v[:, 1], v[:, 0]))]
    keep = np.ones(len(v), bool)  # drop duplicate vertices (degenerate facets)
    keep[1:] = np.linalg.norm(np.diff(v, axis=0), axis=1) > 1e-12
    if len(v) > 1 and np.linalg.norm(v[0] - v[-1]) <= 1e-12:
        keep[-1] = False
    return v[keep]


def box_vertices(phi_max: float, theta_max: float, a_thrust: float = math.inf, n_thrust: int = 32, g: float = G):
    """Vertices of W^C for the paper's box model at ψ = 0 in level flight: |Ẍ| ≤ g·tanθ_max,
    |Ÿ| ≤ g·tanφ_max (eq. 8 with Z̈ = 0; the exact roll limit |Ÿ| ≤ tanφ_max·√(g² + Ẍ²) is slightly
    larger and not convex, so the rectangle is an inner approximation). If a corner exceeds the thrust
    limit |a_h| ≤ a_thrust, the rectangle is clipped by the inscribed n_thrust-gon of that disc."""
    ax, ay = g * math.tan(theta_max), g * math.tan(phi_max)
    rect = np.array([[ax, ay], [-ax, ay], [-ax, -ay], [ax, -ay]])
    if math.hypot(ax, ay) <= a_thrust:
        return rect
    a_t, b_t = cone_polygon(a_thrust, n_thrust)
    a = np.vstack([[[1, 0], [-1, 0], [0, 1], [0, -1]], a_t])
    b = np.concatenate([[ax, ax, ay, ay], b_t])
    return polygon_vertices(a, b)


def cone_vertices(a_max: float, n: int = 16) -> np.ndarray:
    """Vertices of the regular n-gon inscribed in |a_h| ≤ a_max (the cone model's W^C), the polygon
    of `flat.cone_polygon`; one vertex points along −x (full braking head-on)."""
    return polygon_vertices(*cone_polygon(a_max, n))


def input_vertices(tilt: float, tilt_model: str = "box", t_max: float = math.inf, mass: float = 1.0,
                   n_cone: int = 16, g: float = G) -> np.ndarray:
    """W^C at tilt limit `tilt` [rad] in level flight: `box` (φ_max = θ_max = tilt) or `cone`."""
    a_thrust = thrust_limited_accel(t_max, mass, g) if math.isfinite(t_max) else math.inf
    if tilt_model == "box":
        return box_vertices(tilt, tilt, a_thrust, g=g)
    if tilt_model == "cone":
        return cone_vertices(min(g * math.tan(tilt), a_thrust), n_cone)
    raise ValueError(f"unknown tilt model {tilt_model!r}")


# ============================================================================ eq. (23)–(26)


def vertex_offsets(c_prev, d_prev, g_hat, w) -> np.ndarray:
    """Eq. (25): D_kj = D_{k−1} − C_{k−1}Ĝw_j for every vertex j → (m, p) (row j: vertex w_j)."""
    return np.asarray(d_prev)[None, :] - (np.asarray(w) @ (np.asarray(c_prev) @ g_hat).T)


def condense(d_kj) -> np.ndarray:
    """Eq. (26): D_k,min, the row-wise minimum over the m parallel hyperplanes of each row."""
    return np.min(d_kj, axis=0)


def propagate(c_prev, d_prev, f_hat, g_hat, w):
    """One step of the closed propagation, eq. (25)–(26): (C_k, D_k,min) from (C_{k−1}, D_{k−1})."""
    return np.asarray(c_prev) @ f_hat, condense(vertex_offsets(c_prev, d_prev, g_hat, w))


def is_empty(c, d) -> bool:
    """Whether {q | C q ≤ D} is empty: a feasibility LP (HiGHS)."""
    c = np.asarray(c, float)
    res = linprog(np.zeros(c.shape[1]), A_ub=c, b_ub=np.asarray(d, float), bounds=[(None, None)] * c.shape[1],
                  method="highs")
    if res.status == 2:
        return True
    if res.status == 0:
        return False
    raise RuntimeError(f"LP for the emptiness of C_k failed: {res.message}")


@dataclass(frozen=True)
class CollisionSets:
    """C_0 … C_r of eq. (27) (all non-empty); C_{r+1} = C_first_empty is the first empty set."""

    ts: float
    c: tuple  # C_k matrices (p, 4)
    d: tuple  # D_k,min vectors (p,)
    w: np.ndarray  # vertices of W^C (m, 2)

    @property
    def r(self) -> int:
        return len(self.c) - 1

    @property
    def first_empty(self) -> int:
        return len(self.c)

    def contains(self, q) -> np.ndarray:
        """Membership of states q (…, 4) in the union eq. (22)/(27)."""
        q = np.asarray(q, float)
        out = np.zeros(q.shape[:-1], bool)
        for c, d in zip(self.c, self.d):
            out |= np.all(q @ c.T <= d, axis=-1)
        return out

    def member_of(self, k: int, q) -> np.ndarray:
        """Membership of states q (…, 4) in C_k."""
        return np.all(np.asarray(q, float) @ self.c[k].T <= self.d[k], axis=-1)


def collision_sets(ts: float, c0, d0, w, k_max: int = K_MAX_DEFAULT) -> CollisionSets:
    """Eq. (21)–(26): propagate C_0 backwards with the vertices `w` (m, 2) of W^C until the first
    empty set (LP); returns the non-empty sets C_0 … C_r."""
    if not ts > 0:
        raise ValueError(f"t_s must be positive, got {ts}")
    f_hat, g_hat = zoh(ts, N_AXES)
    c, d = np.asarray(c0, float), np.asarray(d0, float)
    if is_empty(c, d):
        raise ValueError("the obstacle C_0 is empty")
    cs, ds = [c], [d]
    for _ in range(k_max):
        c, d = propagate(c, d, f_hat, g_hat, w)
        if is_empty(c, d):
            return CollisionSets(ts=ts, c=tuple(cs), d=tuple(ds), w=np.asarray(w, float))
        cs.append(c)
        ds.append(d)
    raise RuntimeError(f"collision sets still non-empty after {k_max} steps (is W^C degenerate?)")


# ============================================================================ eq. (27)–(28), Figure 4


@dataclass(frozen=True)
class HeadOnLines:
    """Eq. (28) per set C_k in the head-on frame: D_ob·c11 + V·c12 ≤ d (arrays (r+1, n_face)).

    Head-on frame: the vehicle flies +x along y = y_v at speed V, D_ob ahead of the obstacle's near
    face (the first point of the line y = y_v inside the obstacle). Only the rows of the faces that
    face the vehicle (outward normal with n_x < 0) are kept — the paper's "one inequality with our face
    of interest" — plus the faces parallel to the flight line (n_x = 0), which in the slice are constant
    (0 ≤ d: the flight line is inside C_k's lateral extent, else C_k cannot be met head-on). The rear
    faces are dropped: their rows only say that a state so fast that it is already *past* the obstacle
    at step k is not in C_k (tunnelling between samples), which is no safety. A C_k is unsafe where all
    kept rows hold (for a square met face-on: one line plus the lateral rows).
    """

    ts: float
    c11: np.ndarray
    c12: np.ndarray
    d: np.ndarray

    @property
    def k(self) -> np.ndarray:
        return np.arange(len(self.c11))

    def v_lines(self, d_ob) -> np.ndarray:
        """Speed on each C_k's boundary at D_ob (…, r+1): unsafe_k = {V ≥ v_k(D_ob)}; C_0 gives +∞
        for D_ob > 0 (never unsafe ahead of the face) and 0 at D_ob ≤ 0."""
        x = np.asarray(d_ob, float)[..., None, None]
        c11, c12, d = self.c11, self.c12, self.d
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.where(c12 < 0, (c11 * x - d) / -c12,
                         np.where(c11 * x <= d + 1e-12, 0.0, np.inf))
        return np.max(np.maximum(v, 0.0), axis=-1)

    def unsafe(self, d_ob, v) -> np.ndarray:
        """The union of the unsafe half-planes (Figure 4) at (D_ob, V)."""
        x = np.asarray(d_ob, float)[..., None, None]
        vv = np.asarray(v, float)[..., None, None]
        return np.any(np.all(self.c11 * x + self.c12 * vv <= self.d, axis=-1), axis=-1)

    def v_max(self, d_ob) -> np.ndarray:
        """The safe V_max(D_ob) curve: below the lowest line of the union of unsafe half-planes."""
        return np.min(self.v_lines(d_ob), axis=-1)


def head_on_lines(sets: CollisionSets, c0, d0, y_v: float = 0.0) -> HeadOnLines:
    """Eq. (28): substitute the head-on state q = (x_near − D_ob, V, y_v, 0) into each C_k's facing rows."""
    c0, d0 = np.asarray(c0, float), np.asarray(d0, float)
    nx, ny = c0[:, 0], c0[:, 2]
    face = nx < -1e-12
    if not np.any(face):
        raise ValueError("no face of the obstacle faces a vehicle flying +x")
    other = ~face & (nx <= 1e-12)  # faces parallel to the flight line must admit y = y_v
    if np.any(ny[other] * y_v > d0[other] + 1e-12):
        raise ValueError(f"the flight line y = {y_v} misses the obstacle")
    x_near = float(np.max((d0[face] - ny[face] * y_v) / nx[face]))
    rows = np.flatnonzero(face | other)  # parallel rows: constant in the slice (0 ≤ d or C_k misses it)
    c = np.stack([ck[rows] for ck in sets.c])  # (r+1, n_face, 4)
    d = np.stack([dk[rows] for dk in sets.d])
    return HeadOnLines(ts=sets.ts, c11=-c[..., 0], c12=c[..., 1], d=d - c[..., 0] * x_near - c[..., 2] * y_v)


def analytical_square_curve(side: float, w, ts: float = TS_DEFAULT, angle: float = 0.0) -> HeadOnLines:
    """Head-on lines of a square column of side `side` (met face-on at angle 0) under inputs `w`."""
    c0, d0 = square_obstacle(side, (0.5 * side, 0.0), angle)
    return head_on_lines(collision_sets(ts, c0, d0, w), c0, d0)


def continuous_head_on_v_max(d_ob, side: float, a_x: float, a_y: float) -> np.ndarray:
    """The t_s → 0 limit of the face-on square's curve with box inputs (hand-derived): the lines are
    D_ob − T·V ≤ −a_x·T²/2 for T ∈ (0, T_r], T_r = √(side / max(a_x, a_y)) the last time at which C_k
    is non-empty; the lowest line is min_T (D/T + a_x·T/2) = √(2·a_x·D) if √(2D/a_x) ≤ T_r, else
    D/T_r + a_x·T_r/2."""
    d = np.maximum(np.asarray(d_ob, float), 0.0)
    t_r = math.sqrt(side / max(a_x, a_y))
    t_star = np.sqrt(2.0 * d / a_x)
    return np.where(t_star <= t_r, np.sqrt(2.0 * a_x * d), d / t_r + 0.5 * a_x * t_r)
