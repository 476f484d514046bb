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

from bisect import bisect_left
from math import sqrt

import numpy as np

from .jit import HAVE_NUMBA, njit
from .vehicle import G

NONE = -1  # index meaning "outside the grid on the side with no answer"
MARGIN = 1.0 - 1e-9  # the reaction-time answer is scaled by this: round-off never optimistic
# `ReactLookup.step_fixed_point` runs the compiled kernel `_fixed_point_kernel` where numba is installed (the
# `fast` extra), else its numpy path; the two give the same bits (tests/test_lookup_kernel.py). False: numpy.
USE_KERNEL = HAVE_NUMBA


def kernel_name() -> str:
    """Which Ω path runs here, for the start banner and the benchmark."""
    return "compiled (numba)" if USE_KERNEL else "numpy (no numba, or no executable memory for its JIT)"


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

    Computed: V*_j is admissible exactly where Vquad_j ≤ Vlim_j (both say ρ_j (c0 − V t_r) ≥ r_k at
    the crossing), i.e. for j ≥ j*, and there V*_j ≥ Vquad_j; so V = max(Vlim_{j*−1}, max_{j ≥ j*} V*_j),
    with j* the first admissible disc — one pass over the n cells per keep-out radius.
    """

    def __init__(self, rho, f, t_r, g=G, v_grid=None):
        self.rho = np.asarray(rho, dtype=float)
        f = np.atleast_2d(np.asarray(f, dtype=float))
        self.k, self.n = f.shape
        self.t_r = np.asarray(t_r, dtype=float).reshape(self.k, 1)
        if np.any(self.t_r <= 0):
            raise ValueError("reaction time must be positive")  # the folded tilt time makes it so
        gf2 = g * f * f
        self._rho_prev = np.concatenate([[np.inf], self.rho])  # ρ_{j−1}, shifted by one
        self._h = gf2 / (1.0 - self.rho)  # enclosing-disc family, per cell
        self._ht = self._h * self.t_r
        self._ht2 = self._ht * self._ht
        self._h4 = 4.0 * self._h
        self._u = self.rho / (1.0 - self.rho)
        # max over cells ≥ j of h (0 past the grid), flat per row: decides "V_safe ≥ w" (`step_fixed_point`)
        hsuf = np.zeros((self.k, self.n + 1))
        hsuf[:, :-1] = np.maximum.accumulate(self._h[:, ::-1], axis=1)[:, ::-1]
        self._hsuf = hsuf.ravel()
        self._hsuf2 = hsuf  # (k, n + 1), the kernel's view
        self._ones = np.ones(self.k)
        self._hsuf_start = (np.arange(self.k) * (self.n + 1))[:, None]
        # the same, as Python floats for one column at a time (`at`, `_reaches`)
        self._rho_l, self._u_l, self._hsuf_l = self.rho.tolist(), self._u.tolist(), hsuf.tolist()
        self._h_l, self._t_col, self._t_l = self._h.tolist(), self.t_r[:, 0].copy(), self.t_r[:, 0].tolist()
        if v_grid is not None:  # the E_tr fixed point's speeds and w = v/MARGIN
            self._v = np.asarray(v_grid, dtype=float)
            w = self._v / MARGIN
            self._w2 = np.where(w > 0, w * w, -np.inf)  # v ≤ 0 is always reached
            self._wt = self.t_r * w  # (k, m)

    def warm(self) -> None:
        """Compile the fixed point's kernel (or load numba's cache, ≈ 1 s) now: the daemon calls it at start,
        not in its first cycle; a tool that only reads the table never pays it."""
        if USE_KERNEL and hasattr(self, "_v"):
            self.step_fixed_point(1.0, np.full((self.k, len(self._v)), 0.5))

    def __call__(self, c0: float, r_k, rows=slice(None), lam=None) -> np.ndarray:
        """Speeds for finite keep-out radii `r_k` (k, m) ≥ 0, over columns `rows` (a slice or indices);
        `lam` (k,) scales each row's h (the thrust law), None: 1."""
        c0 = max(float(c0), 0.0)
        t_r = self.t_r[rows]
        r_k = np.minimum(r_k, c0 + 0.5)  # past c0 nothing is admissible; keeps r_k/ρ finite
        gap = np.maximum(c0 - r_k, 0.0)[..., None]
        ht, ht2, h4 = self._ht[rows][:, None, :], self._ht2[rows][:, None, :], self._h4[rows][:, None, :]
        if lam is not None:
            s = np.asarray(lam, dtype=float)[:, None, None]
            ht, h4 = ht * s, h4 * s
            ht2 = ht * ht
        v_star = 0.5 * (np.sqrt(ht2 + h4 * gap) - ht)  # (k, m, n)
        ok = (gap - v_star * t_r[..., None]) * self._u >= r_k[..., None]  # u*_j ≥ r_k: j ≥ j*
        ve = np.max(np.where(ok, v_star, 0.0), axis=-1)
        j = self.n - ok.sum(axis=-1)  # j*
        vl = np.where(j > 0, (c0 - r_k / self._rho_prev[j]) / t_r, 0.0)
        return np.maximum(np.maximum(vl, ve), 0.0) * MARGIN

    def at(self, c0: float, r_k: float, row: int, lam: float = 1.0) -> float:
        """`self(c0, [[r_k]], [row])` in scalars (`react_speed`), the row's h scaled by `lam`."""
        return react_speed(c0, r_k, self._t_l[row], lam, self._rho_l, self._u_l, self._h_l[row], self._hsuf_l[row])

    def best(self, c0: float, r: float, n_rows: int, floor: float = 0.0, lam=None) -> float:
        """max(floor, max over rows 0 … n_rows−1 of `at(c0, r, row, lam[row])`) without solving every row:
        the O(1) test of `step_fixed_point` ("the unscaled speed reaches w") over all rows at once keeps only
        the rows that can beat the best so far, solved in scalars from the top (usually the best) down.
        `lam` (n_rows,) scales each row's h (the thrust law), None: 1."""
        c0 = max(float(c0), 0.0)
        w = floor / MARGIN * (1.0 - 1e-12)
        c_w = c0 - self._t_col[:n_rows] * w
        h = self._hsuf[np.searchsorted(self.rho, r / np.maximum(c_w, 1e-12)) + self._hsuf_start[:n_rows, 0]]
        gain = h * (c_w - r) if lam is None else h * lam * (c_w - r)
        cand = np.flatnonzero(gain > 0.0 if w <= 0.0 else (c_w > r) & (gain >= w * w)).tolist()
        best = floor
        for row in reversed(cand):
            s = 1.0 if lam is None else float(lam[row])
            if best > floor and not self._reaches(c0, r, best / MARGIN * (1.0 - 1e-12), row, s):
                continue
            best = max(best, self.at(c0, r, row, s))
        return best

    def _reaches(self, c0: float, r: float, w: float, row: int, lam: float = 1.0) -> bool:
        """Unscaled speed ≥ w at keep-out radius r (see `step_fixed_point`), the row's h scaled by `lam`."""
        return reaches(c0, r, w, self._t_l[row], lam, self._rho_l, self._hsuf_l[row])

    def step_fixed_point(self, c0: float, r_k, lam=None) -> tuple[int, int, float, float]:
        """The E_tr fixed point (DESIGN.md §1) on the speed grid `v` given to the constructor: the largest
        V with V ≤ self(c0, r_k(V)), r_k(V) the keep-out radius with the error of V's (worst) grid cell,
        and the first row (tilt) reaching it. `r_k` (k, m): finite, non-decreasing along m, rows 0 … k−1;
        each row's answer is max_j min(v_j, lim_j), lim = self(c0, r_k), its first argmax j.
        Returns (row, j, V, lim at (row, j)). `lam` (k,) scales each row's h (the thrust law), None: 1.

        Whether lim reaches v (⟺ the unscaled speed ≥ w = v/MARGIN) costs O(1): cell j admits the
        V ≤ min(Vlim_j, V*_j), and Vlim_j ≥ w ⟺ ρ_j ≥ r_k/(c0 − w t_r), V*_j ≥ w ⟺ h_j (s − w t_r) ≥ w²,
        so w is reached iff max{h_j : ρ_j ≥ r_k/(c0 − w t_r)} · (s − w t_r) ≥ w². Reached speeds are a
        prefix of each row; with `top` the longest, the answer is v_{top−1} unless lim_top (< v_top) beats
        it in a row of that length, so lim is computed only there (and at the answer's cell).
        """
        c0 = max(float(c0), 0.0)
        k, m = r_k.shape
        if USE_KERNEL:  # the same answer compiled; it leaves "no row reaches v_0" (row −1) to the numpy path
            ans = _fixed_point_kernel(c0, r_k, self._wt[:k], self._w2, self._v, self.rho, self._u, self._h[:k],
                                      self._hsuf2[:k], self._t_col[:k], self._ones[:k] if lam is None else lam[:k])
            if ans[0] >= 0:
                return ans
        c_w = c0 - self._wt[:k]  # c0 − w·t_r; ≤ 0 reaches nothing (ρ past the grid, h = 0)
        h = self._hsuf[np.searchsorted(self.rho, r_k / np.maximum(c_w, 1e-12)) + self._hsuf_start[:k]]
        if lam is not None:
            h = h * lam[:k, None]
        n_reached = (h * (c_w - r_k) >= self._w2).sum(axis=1)
        top = int(n_reached.max())
        s = [1.0] * k if lam is None else lam[:k].tolist()
        if top == 0:  # no row reaches v_0: the best lim at v_0's error
            lim = self(c0, r_k[:, :1], slice(0, k), None if lam is None else lam[:k])[:, 0]
            b = int(np.argmax(lim))
            return b, 0, float(lim[b]), float(lim[b])
        rows = np.flatnonzero(n_reached == top).tolist()
        if top < m:  # the first row with the largest lim_top, if above v_{top−1}
            best, row = float(self._v[top - 1]), -1
            w = best / MARGIN * (1.0 - 1e-12)  # rows with lim_top ≥ v_{top−1} (and a hair below: round-off)
            for i in reversed(rows):  # higher tilts first (usually the best); a tie goes to the lower row
                r = float(r_k[i, top])
                if not self._reaches(c0, r, w, i, s[i]):
                    continue  # lim_top < best for sure
                lim = self.at(c0, r, i, s[i])
                if lim > best or (lim == best and row >= 0):
                    best, row, w = lim, i, lim / MARGIN * (1.0 - 1e-12)
            if row >= 0:
                return row, top, best, best
        row = rows[0]
        return row, top - 1, float(self._v[top - 1]), self.at(c0, float(r_k[row, top - 1]), row, s[row])


def reaches(c0: float, r: float, w: float, t: float, lam: float, rho, hsuf) -> bool:
    """Whether `react_speed`'s unscaled speed (before MARGIN) at keep-out radius r is ≥ w, in O(1) (the test of
    `ReactLookup.step_fixed_point`): max{lam·h_j : ρ_j ≥ r/(c0 − w·t)}·(c0 − w·t − r) ≥ w²."""
    c_w = c0 - t * w
    return w <= 0 or c_w > r and lam * hsuf[bisect_left(rho, r / c_w)] * (c_w - r) >= w * w


def react_speed(c0: float, r_k: float, t: float, lam: float, rho, u, h, hsuf) -> float:
    """One column of `ReactLookup` in scalars: the reaction-time fixed point for the cells h_j = lam·h[j]
    (h_j = g·F_j²/(1 − ρ_j)), reaction time t, u_j = ρ_j/(1 − ρ_j), hsuf[j] = max(h[j:]) (0 at n).

    j* (the first admissible enclosing disc; the admissible ones are j ≥ j*) by bisection; the best V*_j
    over j ≥ j* is V* at the largest h_j there (V* rises with h), so the answer is
    max(Vlim_{j*−1}, V*(lam·hsuf[j*])) — O(log n), no array. Python lists (or tuples) in, a float out."""
    c0 = max(float(c0), 0.0)
    r = min(r_k, c0 + 0.5)
    gap = max(c0 - r, 0.0)
    lo, hi = 0, len(rho)
    while lo < hi:
        mid = (lo + hi) // 2
        hm = lam * h[mid]
        ht = hm * t
        if (gap - 0.5 * (sqrt(ht * ht + 4.0 * hm * gap) - ht) * t) * u[mid] >= r:
            hi = mid
        else:
            lo = mid + 1
    hm = lam * hsuf[lo]  # 0 past the grid
    ht = hm * t
    ve = 0.5 * (sqrt(ht * ht + 4.0 * hm * gap) - ht)
    vl = (c0 - r / rho[lo - 1]) / t if lo else 0.0
    return max(vl, ve, 0.0) * MARGIN


@njit
def _bisect_left(a, x):
    """`bisect.bisect_left` on a sorted float array (numba has no bisect)."""
    lo, hi = 0, a.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


# `react_speed` compiled for arrays (the same source: no second copy of the maths), for the kernel
_react_speed_c = njit(react_speed)


@njit
def _fixed_point_kernel(c0, r_k, wt, w2, v, rho, u, h, hsuf, t_col, lam):
    """`ReactLookup.step_fixed_point` as loops, compiled by numba: per row the count of grid speeds reached
    (the O(1) test `reaches`), the longest, then the tie rule on the rows of that length. Arrays: `r_k`, `wt` (k, m),
    `w2` (m,), `v` (m,), `rho`, `u` (n,), `h` (k, n), `hsuf` (k, n + 1), `t_col`, `lam` (k,). Returns
    (row, j, V, lim), or row −1 where no row reaches v_0 (the caller's numpy path answers that)."""
    k, m = r_k.shape
    n_reached = np.zeros(k, np.int64)
    top = 0
    for i in range(k):
        cnt = 0
        for j in range(m):
            c_w = c0 - wt[i, j]
            if hsuf[i, _bisect_left(rho, r_k[i, j] / max(c_w, 1e-12))] * lam[i] * (c_w - r_k[i, j]) >= w2[j]:
                cnt += 1
        n_reached[i] = cnt
        top = max(top, cnt)
    if top == 0:
        return -1, 0, 0.0, 0.0
    if top < m:
        best, row = v[top - 1], -1
        w = best / MARGIN * (1.0 - 1e-12)
        for i in range(k - 1, -1, -1):
            if n_reached[i] != top:
                continue
            r = r_k[i, top]
            c_w = c0 - t_col[i] * w  # `reaches`
            if not (w <= 0 or c_w > r and lam[i] * hsuf[i, _bisect_left(rho, r / c_w)] * (c_w - r) >= w * w):
                continue
            lim = _react_speed_c(c0, r, t_col[i], lam[i], rho, u, h[i], hsuf[i])
            if lim > best or (lim == best and row >= 0):
                best, row, w = lim, i, lim / MARGIN * (1.0 - 1e-12)
        if row >= 0:
            return row, top, best, best
    row = 0
    while n_reached[row] != top:
        row += 1
    return row, top - 1, v[top - 1], _react_speed_c(c0, r_k[row, top - 1], t_col[row], lam[row], rho, u, h[row],
                                                    hsuf[row])


def law_cells(f: np.ndarray, a: np.ndarray, rel_tol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """The cone tables' scaling law F(ρ; tilt, thrust) = √(a_h/g)·G(ρ) (`contracts.sweep`: every cell scales
    one verified curve; a_h the horizontal acceleration limit), checked at every grid cell.

    `f` (n_ρ, n_tilt, n_thrust) the table, `a` (n_tilt, n_thrust) a_h at the grid points. For the cell
    [tilt_j, tilt_j+1] × [thrust_k, thrust_k+1] (clipped at the top of each axis) returns Ĝ = min over its
    corners c of F_c/√(a_c/g), and whether the corners agree within `rel_tol` at every ρ (the law holds
    there). Where it holds, √(a_h(p)/g)·Ĝ at a point p of the cell is no more than any corner's verified
    value scaled to p by the law, F_c·√(a_h(p)/a_c). Returns (Ĝ (n_ρ, n_tilt, n_thrust), holds (n_tilt, n_thrust))."""
    nt, nk = a.shape
    j1, k1 = np.minimum(np.arange(nt) + 1, nt - 1), np.minimum(np.arange(nk) + 1, nk - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        g_n = f / np.sqrt(a / G)[None]
    corners = np.stack([g_n, g_n[:, j1], g_n[:, :, k1], g_n[:, j1][:, :, k1]])
    g_hat, g_max = corners.min(axis=0), corners.max(axis=0)
    ok = np.isfinite(g_max) & (g_max - g_hat <= rel_tol * g_max)
    holds = ok.all(axis=0) & (a > 0) & (a[j1] > 0) & (a[:, k1] > 0)
    return np.where(np.isfinite(g_hat), g_hat, 0.0), holds


def crossing_fixed_point(v_grid, limit_of_j, decide=None) -> tuple[float, int, float]:
    """Largest V with V ≤ limit(E_cons(V)), E_cons the conservative (step) lookup on `v_grid`, for one
    column by bisection, calling the scalar `limit_of_j(j)` (the limit with the error of grid speed v_j,
    non-increasing in j) O(log n) times: min(v_j, limit_j) rises then falls, and the sup sits where
    v_j first reaches limit_j. Speeds above the grid's top have no error bound.

    `decide(j)`, if given, answers "v_j ≥ limit_j" where it is sure (True/False) and None where not; the
    limit is then computed only where it is not sure and at the answer. Returns (speed, j, limit_j)."""
    lo, hi = 0, len(v_grid)  # find the first j with v_j ≥ limit_j
    cache = {}

    def lim(j):
        if j not in cache:
            cache[j] = limit_of_j(j)
        return cache[j]

    while lo < hi:
        mid = (lo + hi) // 2
        sure = None if decide is None else decide(mid)
        if sure if sure is not None else v_grid[mid] >= lim(mid):
            hi = mid
        else:
            lo = mid + 1
    best, arg = 0.0, 0
    if lo < len(v_grid) and lim(lo) > best:
        best, arg = lim(lo), lo
    if lo > 0 and v_grid[lo - 1] > best:
        best, arg = float(v_grid[lo - 1]), lo - 1
    return float(best), arg, lim(arg)


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
