"""The avoid table's limiting trajectories, `<table>.trajectories.npz` beside the table (DESIGN.md §4.3:
"keep the limiting trajectories: the controller contract flies them"): the file's path, its writer,
and its readers. Per shape class and ρ the verified ZOH inputs w, sample time t_s, speed V and branch
at centre distance c_ref; a cell scales its class by the reduced form's law (DESIGN.md §2). No solver.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np


def write_trajectories(table_path, rho, tilt, thrust_ratio, class_of_cell, scale_of_cell, v, v_hi, w, ts, branch,
                       c_ref: float, tilt_model: str, arrays_sha256: str) -> Path:
    """Write the limiting trajectories of the table at `table_path` (`arrays_sha256`, its avoid slot's own hash
    `table.slot_sha256`, ties them to it whatever slots the table carries beside)."""
    out = Path(table_path)
    traj_path = trajectories_path(out)
    np.savez_compressed(traj_path, rho=rho, tilt=tilt, thrust_ratio=thrust_ratio, class_of_cell=class_of_cell,
                        scale_of_cell=scale_of_cell, v=v, v_hi=v_hi, w=w, ts=ts, branch=branch, c_ref=np.array(c_ref),
                        metadata_json=np.frombuffer(json.dumps({
                            "table": out.name, "tilt_model": tilt_model, "arrays_sha256": arrays_sha256,
                            "how_to_scale": "cell (i,j,k) at centre distance c: class ci=class_of_cell[j,k], "
                                            "lam=scale_of_cell[j,k], kappa=c/c_ref; ZOH inputs w[ci,i]*lam, "
                                            "t_s=ts[ci,i]*sqrt(kappa/lam), V=v[ci,i]*sqrt(kappa*lam); "
                                            "positions scale by kappa; start at origin flying +x, "
                                            "keep-out disc radius rho*c at (c, 0)"}).encode(), dtype=np.uint8))
    return traj_path


def trajectories_path(table_path) -> Path:
    p = Path(table_path)
    return p.with_name(p.stem + ".trajectories.npz")


def limiting_trajectory(table_path, rho_index: int, tilt_index: int, thrust_index: int, c: float) -> dict:
    """The limiting trajectory of one cell at centre distance `c` [m] (physical units): q0, w, t_s,
    V and the obstacle, ready for `planner.check_trajectory` or the controller contract."""
    with np.load(trajectories_path(table_path), allow_pickle=False) as z:
        ci = int(z["class_of_cell"][tilt_index, thrust_index])
        lam = float(z["scale_of_cell"][tilt_index, thrust_index])
        kappa = c / float(z["c_ref"])
        w = np.zeros((z["w"].shape[2], 4))
        w[:, :2] = z["w"][ci, rho_index] * lam
        ts = float(z["ts"][ci, rho_index]) * math.sqrt(kappa / lam)
        v = float(z["v"][ci, rho_index]) * math.sqrt(kappa * lam)
        rho = float(z["rho"][rho_index])
    return {"q0": (0.0, v, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), "w": w, "ts": ts, "v": v, "c": c, "r_k": rho * c}


def pass_branches(table_path, tilt_index: int, thrust_index: int) -> tuple[np.ndarray, np.ndarray]:
    """The ρ grid and, per ρ, whether the cell's limiting trajectory passes the obstacle (else it stops)."""
    with np.load(trajectories_path(table_path), allow_pickle=False) as z:
        cls = int(z["class_of_cell"][tilt_index, thrust_index])
        return z["rho"], z["branch"][cls] == 1
