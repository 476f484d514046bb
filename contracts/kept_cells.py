"""Extending a built avoid table on a finer ρ axis (`table build --extend BASE`): the base's verified class
cells are kept and only the new ρ points are solved (DESIGN.md §4.3).

What is kept is exactly what the base's sweep verified: per shape class and ρ its bracket (V, V_hi), ZOH
inputs, sample time and branch, read from `<base>.trajectories.npz` (tied to the base by its arrays' hash).
The extension is refused unless every input of those results is the same: the vehicle, the tilt model, the
tilt and thrust axes (hence the shape classes and their scales), the solver settings, and every base ρ point
is a point of the new axis. Each kept cell is then re-verified against its cell's own limits by the same
dense re-simulation as a solved one, so a kept cell is never taken on trust.

The base's controller contracts (`e_tr_pred`, `e_tr_pred_stop`) are carried over with a provenance note:
they do not depend on the ρ axis except through the limiting trajectories and V_safe of the ρ cells their
sweep flew, and those cells are kept unchanged.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .errors import ContractError
from .table import ContractTable, slot_sha256, verify
from .trajectories import trajectories_path

SETTINGS = ("n_intervals", "cpu_time_s", "rel_tol", "starts")  # the solver settings a kept cell depends on
RHO_MATCH_REL = 1e-12  # a base ρ point and a new one are the same point within this relative difference


@dataclass(frozen=True)
class KeptCells:
    """The verified class cells of a base table, placed on a new ρ axis."""

    base: Path
    table: ContractTable
    index: np.ndarray  # per new ρ index: the base ρ index it keeps, or -1 (to solve)
    v: np.ndarray  # (classes, base ρ): lower end of the verified bracket at c_ref
    v_hi: np.ndarray  # upper end (first unverified speed; inf: none found)
    w: np.ndarray  # (classes, base ρ, n, 2) ZOH inputs
    ts: np.ndarray  # (classes, base ρ) sample time
    branch: np.ndarray  # (classes, base ρ) 1 pass, 0 stop

    @property
    def count(self) -> int:
        return int(np.sum(self.index >= 0)) * self.v.shape[0]

    def solve_mask(self) -> np.ndarray:
        """True at the new ρ indices no base cell covers."""
        return self.index < 0

    def warm(self, ci: int, i: int):
        """The warm start (w, t_s, V) a run of new cells starting at ρ index i + 1 takes from the kept cell i
        below it, when that one passes (a stop cell's trajectory seeds no pass)."""
        b = int(self.index[i]) if 0 <= i < len(self.index) else -1
        if b < 0 or self.branch[ci, b] != 1:
            return None
        w4 = np.zeros((self.w.shape[2], 4))
        w4[:, :2] = self.w[ci, b]
        return (w4, float(self.ts[ci, b]), float(self.v[ci, b]))

    def fill(self, V, HI, W, TS, BR) -> None:
        """Write the kept cells into the build's class arrays (the caller's, in place)."""
        for i, b in enumerate(self.index):
            if b >= 0:
                V[:, i], HI[:, i], W[:, i], TS[:, i], BR[:, i] = (self.v[:, b], self.v_hi[:, b], self.w[:, b],
                                                                  self.ts[:, b], self.branch[:, b])

    def info(self, f_new: np.ndarray) -> dict:
        """The provenance the extended avoid slot records: the base, what was kept and solved, and how many kept
        cells the monotonicity repair lowered (an extension may only lower a kept value, never raise it)."""
        keep = self.index >= 0
        f_base = self.table.avoid.values[self.index[keep]]
        base_avoid = self.table.meta["contracts"]["avoid"]
        return {"base_avoid_sha256": slot_sha256("avoid", self.table.avoid),
                "base_grid": base_avoid.get("grid"), "base_solves": base_avoid.get("solves"),
                "kept_class_cells": self.count, "solved_class_cells": int(np.sum(~keep)) * self.v.shape[0],
                "kept_cells_lowered": int(np.sum(f_new[keep] < f_base)),
                "kept_cells_raised": int(np.sum(f_new[keep] > f_base))}

    def controller_slots(self) -> dict:
        """The base's E_tr_pred slots, each with a note on the avoid cells its sweep flew and why they still hold."""
        out = {}
        rho_base = self.table.avoid.axes[0]
        for name, slot in (("e_tr_pred", self.table.e_pred), ("e_tr_pred_stop", self.table.e_pred_stop)):
            if slot is None:
                out[name] = None
                continue
            info = dict(slot.info)
            if name == "e_tr_pred":
                flown = sorted({float(rho_base[int(np.argmin(np.abs(rho_base - r)))])
                                for r in (info.get("grid") or {}).get("avoid_rhos", [])})
                info["avoid_cells_flown"] = {
                    "rho": flown, "avoid_sha256_flown": slot_sha256("avoid", self.table.avoid),
                    "holds_on_extension": "the avoid table's ρ axis was extended with the cells of the table this "
                                          "sweep flew kept unchanged: the limiting trajectories and V_safe of the "
                                          "flown ρ cells are the same, and the new ρ points lie between flown "
                                          "geometries as the unflown base points do"}
            else:
                info["avoid_cells_flown"] = {"rho": [], "holds_on_extension": "flown without the avoid table"}
            out[name] = replace(slot, info=info)
        return out


def _base_grid(table: ContractTable) -> dict:
    g = table.meta["contracts"]["avoid"].get("grid") or {}
    return {k: g.get(k) for k in SETTINGS}


def grid_for_extension(base, vehicle, grid, make_grid):
    """The grid of an extension without a grid file: the base's tilt and thrust axes and solver settings, with the
    default build's ρ axis (`make_grid(vehicle)`); a given grid is returned as is (`kept_cells` checks it)."""
    if grid is not None:
        return grid
    table = verify(base, vehicle)
    if table.avoid is None:
        raise ContractError(f"--extend {base}: the table has no avoid contract to extend")
    g = make_grid(vehicle)
    s = _base_grid(table)
    return replace(g, tilt=np.array(table.avoid.axes[1]), thrust_ratio=np.array(table.avoid.axes[2]),
                   n_intervals=int(s["n_intervals"]), cpu_time_s=float(s["cpu_time_s"]), rel_tol=float(s["rel_tol"]),
                   starts=int(s["starts"]))


def kept_cells(base, vehicle, grid, tilt_model: str, class_of_cell: np.ndarray, scale_of_cell: np.ndarray) -> KeptCells:
    """The base table's verified class cells placed on `grid`'s ρ axis, or one `ContractError` line naming why
    they cannot be kept (another vehicle, tilt model, tilt or thrust axis, solver setting, a base ρ point not on
    the new axis, or a trajectories file that is not the base's)."""
    base = Path(base)
    table = verify(base, vehicle)  # schema, hash, monotonicity and the vehicle
    what = f"--extend {base}"
    if table.avoid is None:
        raise ContractError(f"{what}: the table has no avoid contract to extend")
    if table.tilt_model != tilt_model:
        raise ContractError(f"{what}: built with tilt model {table.tilt_model}, not {tilt_model}")
    rho_b, tilt_b, tr_b = table.avoid.axes
    if not (np.array_equal(tilt_b, grid.tilt) and np.array_equal(tr_b, grid.thrust_ratio)):
        raise ContractError(f"{what}: its tilt and thrust axes differ from the grid's (an extension adds ρ points "
                            "only; leave out --grid to take the base's axes)")
    mine = {"n_intervals": grid.n_intervals, "cpu_time_s": grid.cpu_time_s, "rel_tol": grid.rel_tol,
            "starts": grid.starts}
    for k, v in _base_grid(table).items():
        if v is None or float(v) != float(mine[k]):
            raise ContractError(f"{what}: solver setting {k} is {v} there and {mine[k]} in the grid")
    pos = np.searchsorted(grid.rho, rho_b)
    index = np.full(len(grid.rho), -1, dtype=np.int64)
    for b, (r, p) in enumerate(zip(rho_b, pos)):
        near = [q for q in (p - 1, p) if 0 <= q < len(grid.rho) and abs(grid.rho[q] - r) <= RHO_MATCH_REL * r]
        if not near:
            raise ContractError(f"{what}: its ρ point {r:.6g} is not on the new axis (an extension keeps every base "
                                "point)")
        index[near[0]] = b
    tp = trajectories_path(base)
    try:
        with np.load(tp, allow_pickle=False) as z:
            traj = {k: z[k] for k in z.files}
        meta = json.loads(traj["metadata_json"].tobytes().decode())
    except (OSError, ValueError, KeyError) as err:
        raise ContractError(f"{what}: its limiting trajectories {tp.name} are missing or unreadable "
                            f"({type(err).__name__})") from None
    if meta.get("arrays_sha256") != slot_sha256("avoid", table.avoid) or not np.array_equal(traj["rho"], rho_b):
        raise ContractError(f"{what}: {tp.name} is not the trajectories file of this table's avoid slot (its hash "
                            "differs)")
    if not (np.array_equal(traj["class_of_cell"], class_of_cell)
            and np.allclose(traj["scale_of_cell"], scale_of_cell, rtol=1e-12, atol=0.0)):
        raise ContractError(f"{what}: its shape classes differ from this build's")
    return KeptCells(base, table, index, traj["v"], traj["v_hi"], traj["w"], traj["ts"], traj["branch"])
