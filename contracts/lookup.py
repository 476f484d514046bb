"""Conservative table lookup and the contract's fixed points (DESIGN.md §2). Pure numpy, no I/O.

Rules, for every table axis:
- between grid points answer with the grid corner that is worst in every axis (never interpolate up);
- a "helps" axis (more is better): above the top clamp to the top; below the bottom there is no answer
  (no safe speed / an infinite error);
- a "hurts" axis: below the bottom clamp to the bottom; above the top there is no answer.

Reduced avoid contract: V_safe = √(g·c)·F(ρ; tilt, thrust_ratio), ρ = r_k/c, c = d_od + r_obst,
r_k = r_obst + e_tr + r_body. F does not increase with ρ ("hurts").
"""

from __future__ import annotations

import numpy as np

from .vehicle import G

NONE = -1  # index meaning "outside the grid on the side with no answer"


def helps_index(grid: np.ndarray, x: float) -> int:
    """Worst corner on a 'helps' axis: the largest grid point ≤ x (top if above; NONE below)."""
    return int(np.searchsorted(grid, x, side="right")) - 1  # -1 == NONE when x < grid[0]


def hurts_index(grid: np.ndarray, x: float) -> int:
    """Worst corner on a 'hurts' axis: the smallest grid point ≥ x (bottom if below; NONE above)."""
    i = int(np.searchsorted(grid, x, side="left"))
    return i if i < len(grid) else NONE


class ReactLookup:
    """V ≤ √(g·c(V))·F_cons(r_k/c(V)), c(V) = c0 − V·t_r: the reaction-time fixed point, solved
    exactly for the step function F_cons of the conservative lookup on the ρ grid.

    Built once per table column set: `rho` (n,) ascending, `f` (k, n) — k columns of F (one per
    tilt), non-increasing along n — and `t_r` (k,) the reaction time of each column.

    Grid cell j admits the V with ρ(V) ≤ ρ_j, i.e. V ≤ Vlim_j = (c0 − r_k/ρ_j)/t_r, and bounds them
    by Vquad_j, the root of V² + g F_j² t_r V − g F_j² c0 = 0 (independent of r_k). Vquad_j falls
    and Vlim_j rises with j, so the best cell sits where they cross: Vlim_j ≥ Vquad_j ⟺
    r_k ≤ R_j = ρ_j (c0 − t_r Vquad_j), R_j increasing. Then V = max(Vquad_{j*}, Vlim_{j*−1}).

    Enclosing discs: the disc of radius r_k + δ centred at c0 + δ contains the keep-out disc and has
    the same near point (gap s = c0 − r_k), so a speed safe for it is safe here. Along that family a
    cell's bounds cross (Vlim falls, Vquad rises with δ) at V*_j, the root of V² + h t_r V − h s = 0
    with h = g F_j²/(1 − ρ_j), reached at radius u*_j = (s − V*_j t_r) ρ_j/(1 − ρ_j); where u*_j ≥ r_k
    (δ ≥ 0) V*_j is admissible too. This keeps the answer non-increasing in r_obst, never less tight.
    """

    def __init__(self, rho, f, t_r, g=G):
        self.rho = np.asarray(rho, dtype=float)
        f = np.atleast_2d(np.asarray(f, dtype=float))
        self.k, self.n = f.shape
        self.t_r = np.asarray(t_r, dtype=float).reshape(self.k, 1)
        if np.any(self.t_r <= 0):
            raise ValueError("reaction time must be positive")  # the folded tilt time makes it so
        gf2 = g * f * f
        self._b = gf2 * self.t_r
        self._b2 = self._b * self._b
        self._4gf2 = 4.0 * gf2
        self._row = np.arange(self.k, dtype=float)[:, None]
        self._row_start = (np.arange(self.k) * self.n)[:, None]
        self._rho_prev = np.concatenate([[np.inf], self.rho])  # ρ_{j−1}, shifted by one
        self._h = gf2 / (1.0 - self.rho)  # enclosing-disc family, per cell
        self._ht = self._h * self.t_r
        self._ht2 = self._ht * self._ht
        self._u = self.rho / (1.0 - self.rho)

    def __call__(self, c0: float, r_k, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Speeds for keep-out radii `r_k` (k, m) ≥ 0, over columns lo … hi−1 (all by default)."""
        c0 = max(float(c0), 0.0)
        sl = slice(lo, hi)
        t_r = self.t_r[sl]
        v_quad = 0.5 * (np.sqrt(self._b2[sl] + self._4gf2[sl] * c0) - self._b[sl])  # (k, n)
        k = v_quad.shape[0]
        lift = self._row[:k] * (c0 + 1.0)  # one searchsorted for all rows: lift row i by i·(c0+1)
        big_r = self.rho * (c0 - t_r * v_quad) + lift  # increasing along rows and across them
        r_k = np.minimum(r_k, c0 + 0.5)  # R < c0 < c0 + 0.5: a clipped query still lands past the row
        j = np.searchsorted(big_r.ravel(), (r_k + lift).ravel()).reshape(r_k.shape) - self._row_start[:k]
        # the best cell: Vquad_{j*} (none when j* = n) or Vlim_{j*−1} (none when j* = 0)
        n = self.n
        vq = np.where(j < n, v_quad.ravel()[np.minimum(j, n - 1) + self._row_start[:k]], 0.0)
        vl = np.where(j > 0, (c0 - r_k / self._rho_prev[j]) / t_r, 0.0)
        # enclosing discs (k, m, n): V*_j where its disc is at least the keep-out disc
        gap = np.maximum(c0 - r_k, 0.0)[..., None]
        h, ht = self._h[sl][:, None, :], self._ht[sl][:, None, :]
        v_star = 0.5 * (np.sqrt(self._ht2[sl][:, None, :] + 4.0 * h * gap) - ht)
        ok = (gap - v_star * t_r[..., None]) * self._u >= r_k[..., None]
        ve = np.max(np.where(ok, v_star, 0.0), axis=-1)
        return np.maximum(np.maximum(np.maximum(vq, vl), ve), 0.0) * (1.0 - 1e-9)  # round-off never optimistic


def step_fixed_point(v_grid, limit_on_grid):
    """Largest V with V ≤ limit(E_cons(V)), E_cons the conservative (step) lookup on `v_grid`.

    `limit_on_grid[..., j]` is the speed limit using the error of grid speed v_j (already the worse
    of measured and predicted); it does not increase with j. Candidate j is min(v_j, limit_j); every
    candidate is feasible and the sup is among them. Speeds above the grid's top have no error bound.
    Returns (best speed, its index j) along the last axis.
    """
    cand = np.minimum(v_grid, limit_on_grid)
    j = cand.argmax(axis=-1)
    return cand.max(axis=-1), j


def crossing_fixed_point(v_grid, limit_of_j) -> tuple[float, int]:
    """`step_fixed_point` for one column by bisection, calling the scalar `limit_of_j(j)` O(log n) times:
    min(v_j, limit_j) rises then falls, and the sup sits where v_j first reaches limit_j."""
    lo, hi = 0, len(v_grid)  # find the first j with v_j ≥ limit_j
    cache = {}

    def lim(j):
        if j not in cache:
            cache[j] = limit_of_j(j)
        return cache[j]

    while lo < hi:
        mid = (lo + hi) // 2
        if v_grid[mid] >= lim(mid):
            hi = mid
        else:
            lo = mid + 1
    best, arg = 0.0, 0
    if lo < len(v_grid) and lim(lo) > best:
        best, arg = lim(lo), lo
    if lo > 0 and v_grid[lo - 1] > best:
        best, arg = float(v_grid[lo - 1]), lo - 1
    return float(best), arg


def repair_monotone(values: np.ndarray, directions: tuple[int, ...], safe: str) -> tuple[np.ndarray, int]:
    """Make `values` monotone by moving violations only in the `safe` direction ('down' or 'up').

    `directions[k]` = +1 if values must not decrease along axis k, −1 if they must not increase,
    0 if the axis is free. Each violation copies the worse neighbour's value; returns the repaired
    array and the number of cells changed.
    """
    out = np.array(values, dtype=float, copy=True)
    acc = np.minimum.accumulate if safe == "down" else np.maximum.accumulate
    for axis, d in enumerate(directions):
        if d == 0:
            continue
        # 'down' keeps a non-decreasing axis by a running min from the top; 'up' by a running max
        # from the bottom (and the reverse for a non-increasing axis).
        from_top = (d > 0) == (safe == "down")
        x = np.flip(out, axis) if from_top else out
        x = acc(x, axis=axis)
        out = np.flip(x, axis) if from_top else x
    changed = int(np.count_nonzero(out != np.asarray(values, dtype=float)))
    return out, changed


def is_monotone(values: np.ndarray, directions: tuple[int, ...]) -> bool:
    for axis, d in enumerate(directions):
        if d and values.shape[axis] > 1 and np.any(d * np.diff(values, axis=axis) < 0):
            return False
    return True
