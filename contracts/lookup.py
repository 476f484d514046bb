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


def react_fixed_point(c0, r_k, rho, f, t_r, g=G, enclosing=False):
    """Largest V with V ≤ √(g·c(V))·F_cons(r_k/c(V)), c(V) = c0 − V·t_r, exactly for the step
    function F_cons of the conservative lookup on the ρ grid (`rho` ascending, `f` on it).

    Broadcasting: `rho`/`f` carry the grid on their last axis; `c0`, `r_k`, `t_r` broadcast against
    the rest. For grid cell j the admissible V satisfy ρ(V) ≤ ρ_j, i.e. V ≤ (c0 − r_k/ρ_j)/t_r, and
    V² + g F_j² t_r V − g F_j² c0 ≤ 0; the answer is the best cell. Returns 0 where no V > 0 is safe.

    `enclosing=True` also answers from the discs that enclose the keep-out disc with the same near
    point (radius r_k + δ at c0 + δ): safe for them is safe here, so the best of them is a valid and
    tighter answer, and it makes the answer non-increasing in r_obst (see below).
    """
    c0 = np.asarray(c0, dtype=float)[..., None]
    r_k = np.asarray(r_k, dtype=float)[..., None]
    t_r = np.asarray(t_r, dtype=float)[..., None]
    gf2 = g * np.asarray(f, dtype=float) ** 2
    b = gf2 * t_r
    v_quad = 0.5 * (-b + np.sqrt(b * b + 4.0 * gf2 * np.maximum(c0, 0.0)))
    slack = c0 - r_k / rho  # ≥ 0 iff the cell admits V = 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        v_lim = np.where(t_r > 0.0, slack / t_r, np.where(slack >= 0.0, np.inf, -np.inf))
    v = np.minimum(v_quad, v_lim)
    # Enclosing discs: a disc of radius r_k + δ centred at c0 + δ contains the keep-out disc (same near
    # point, gap s = c0 − r_k), so any speed safe for it is safe here. Along that family the cell's two
    # bounds cross (v_lim falls, v_quad rises with δ) at V*: V² + h·t_r·V − h·s = 0, h = g F²/(1 − ρ_j),
    # reached at radius u* = (s − V*·t_r)·ρ_j/(1 − ρ_j). Where u* ≥ r_k that crossing is the cell's best
    # answer; this keeps the lookup non-increasing in r_obst (and never less tight).
    if enclosing:
        s = np.maximum(c0 - r_k, 0.0)
        h = gf2 / (1.0 - rho)
        ht = h * t_r
        v_star = 0.5 * (-ht + np.sqrt(ht * ht + 4.0 * h * s))
        u_star = (s - v_star * t_r) * rho / (1.0 - rho)
        v = np.where(u_star >= r_k, np.maximum(v, v_star), v)
    best = np.max(v, axis=-1, initial=0.0)
    return np.maximum(best, 0.0) * (1.0 - 1e-9)  # round-off never optimistic


def step_fixed_point(v_grid, v_of_e_on_grid):
    """Largest V with V ≤ V_safe(E_cons(V)), E_cons the conservative (step) lookup on `v_grid`.

    `v_of_e_on_grid[..., j]` is the speed limit using the error of grid speed v_j (already the
    worse of measured and predicted). Candidate j is min(v_j, limit_j); every candidate is feasible
    and the sup is among them. Speeds above the grid's top have no error bound (no answer).
    """
    cand = np.minimum(v_grid, v_of_e_on_grid)
    j = np.argmax(cand, axis=-1)
    return np.take_along_axis(cand, j[..., None], axis=-1)[..., 0], j


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
