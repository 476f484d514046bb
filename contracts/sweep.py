"""The avoid-contract sweep: F(ρ; tilt, thrust_ratio) of V_safe = √(g·c)·F(r_k/c) (DESIGN.md §2, §4.3).

Offline only (imports the CasADi planner). Per cell the largest *verified* safe speed at t_react = 0:
- stop branch in closed form, V = √(2·a_b·(c − r_k)) (a_b the full braking deceleration);
- pass branch by the planner (`contracts.planner`) in its max-speed form (V a decision variable,
  several starts, warm-started from the neighbouring ρ cell), every answer re-simulated densely;
- then bisection upward from the verified speed: V·(1 + rel_tol) is tried at fixed speed; the cell
  stores the lower end of the bracket [verified, first unverified], never a guess.

Shape classes. Only the input set's shape matters, not its size, beyond ρ (scaling law):
- `cone` in level flight: the input set is the disc |a_h| ≤ a_h(tilt, thrust_ratio) =
  min(g·tan tilt, √((T_max/m)² − g²)) (`flat.horizontal_accel_limit`), so every cell scales one
  normalised curve, F = √(a_h/g)·G(ρ): the sweep solves G once per ρ and then re-verifies each
  distinct (ρ, a_h) by re-simulating the scaled trajectory against that cell's own limits.
  Thrust binds only where √((T_max/m)² − g²) < g·tan tilt; elsewhere the thrust axis is flat.
- `box` (φ_max = θ_max = tilt, yaw held): the set's shape changes with tilt and, where thrust binds
  (T_max/m < g/cos² tilt), with thrust; cells whose thrust does not bind share the top thrust's class.

Monotonicity is repaired only downward (`lookup.repair_monotone`), counted, and the build fails above
1 % of the cells. Each cell's limiting trajectory goes to `<table>.trajectories.npz` (`contracts.trajectories`);
the tasks run on `contracts.runner`.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .avoid_limit import policy_guess, stop_speed_kinematic
from .errors import ContractError
from .flat import horizontal_accel_limit, thrust_limited_accel
from .gridspec import as_grid, load_mapping, vehicle_spans
from .gridspec import axis as _axis
from .kept_cells import grid_for_extension, kept_cells
from .lookup import repair_monotone
from .planner import Limits, check_trajectory, head_on_problem, plan
from .runner import ONE_THREAD, Checkpoint, run_tasks
from .table import MAX_REPAIR_FRACTION, THRUST_AXIS_TOL, Slot, slot_sha256, verify, write_table
from .trajectories import trajectories_path, write_trajectories
from .vehicle import G, Vehicle, load_vehicle

C_REF = 1.0  # [m] the cell problems are solved at c = 1 m (any c gives the same F)


# ============================================================================ grid


@dataclass(frozen=True)
class Grid:
    """Axes of the avoid table and the solver settings of its sweep."""

    rho: np.ndarray
    tilt: np.ndarray  # [rad]
    thrust_ratio: np.ndarray
    n_intervals: int = 40
    cpu_time_s: float = 1.0  # IPOPT max_cpu_time per solve
    rel_tol: float = 1e-3  # bisection bracket width (relative)
    starts: int = 3  # cold starts per cell (plus the warm start from the neighbour)
    chunk: int = 8  # ρ cells per task (warm starts run along a chunk)

    def describe(self) -> dict:
        return {"rho": [float(self.rho[0]), float(self.rho[-1]), len(self.rho)],
                "tilt_deg": [round(math.degrees(self.tilt[0]), 4), round(math.degrees(self.tilt[-1]), 4), len(self.tilt)],
                "thrust_ratio": [float(self.thrust_ratio[0]), float(self.thrust_ratio[-1]), len(self.thrust_ratio)],
                "n_intervals": self.n_intervals, "cpu_time_s": self.cpu_time_s, "rel_tol": self.rel_tol,
                "starts": self.starts}


def default_grid(vehicle: Vehicle) -> Grid:
    """The default build grid: ρ geometric 0.01–0.97 (239), tilt 3°…tilt_max by 0.25°, thrust by 0.05.

    The tilt axis is cheap in the cone model (cells scale one curve), and fine steps matter at small
    tilts, where the conservative lookup would otherwise lose up to √(tan 3°/tan 4°) ≈ 13 % per step.
    ρ: where a pass is possible F ∝ ρ^(-1/2) (d ln F / d ln ρ = −0.500 in the shipped tables), so the worst
    corner in ρ loses up to half the axis' log step in speed: 1.9 % at 120 points (ratio 1.0392), 1.0 % at
    239 (ratio 1.0194). The 239 points are the shipped tables' 120 and their geometric midpoints, so a
    rebuild keeps every shipped cell."""
    lo, hi = vehicle.thrust_ratio_range
    return Grid(rho=np.geomspace(0.01, 0.97, 239),
                tilt=np.radians(_with_end(np.arange(3.0, vehicle.tilt_max_deg + 0.125, 0.25), vehicle.tilt_max_deg)),
                thrust_ratio=_with_end(np.arange(lo, hi + 0.025, 0.05), hi))


def _with_end(axis: np.ndarray, end: float) -> np.ndarray:
    """A stepped axis ending exactly at `end` (the vehicle's limit), whatever the step."""
    axis = np.round(axis[axis < end - 1e-9], 10)
    return np.append(axis, round(end, 10))


def grid_coverage(grid: Grid, vehicle: Vehicle) -> list[str]:
    """Where the grid's axes fall short of the vehicle: a thrust ratio below the lowest on the axis has no safe
    speed at all (the lookup answers NONE below a 'helps' axis); above the top, or a tilt above the top tilt,
    the table answers for the axis end (safe, slower)."""
    lo, hi = vehicle.thrust_ratio_range
    tr, top = grid.thrust_ratio, math.degrees(grid.tilt[-1])
    gaps = []
    if tr[0] > lo + THRUST_AXIS_TOL:
        gaps.append(f"thrust_ratio axis starts at {tr[0]:g} above the vehicle's {lo:g}: from {lo:g} to {tr[0]:g} "
                    "(a fresh or degraded thrust estimate) the daemon finds no safe speed")
    if tr[-1] < hi - 1e-9:
        gaps.append(f"thrust_ratio axis ends at {tr[-1]:g} below the vehicle's {hi:g}")
    if top < vehicle.tilt_max_deg - 1e-6:
        gaps.append(f"tilt axis ends at {top:g}° below the vehicle's tilt limit {vehicle.tilt_max_deg:g}°")
    return gaps


def grid_from_dict(data: dict, vehicle: Vehicle) -> Grid:
    """`--grid FILE` format (YAML mapping); every key optional, defaults from `default_grid`:

        rho: {min: 0.01, max: 0.97, n: 239, spacing: geometric}   # or a list
        tilt_deg: {min: 3, max: 25, step: 1}                      # or a list
        thrust_ratio: {min: 0.6, max: 1.0, step: 0.05}            # or a list
        thrust_ratio: {n: 2}     # min/max left out: the vehicle's (`vehicle_spans`); n: 1 is the top end
        n_intervals: 40      # planner intervals N
        cpu_time_s: 1.0      # IPOPT max_cpu_time per solve
        rel_tol: 0.001       # bisection bracket width
        starts: 3            # cold starts per cell
    """
    if not isinstance(data, dict):
        raise ContractError("grid: expected a mapping")
    known = {"rho", "tilt_deg", "thrust_ratio", "n_intervals", "cpu_time_s", "rel_tol", "starts", "chunk"}
    bad = set(data) - known
    if bad:
        raise ContractError(f"grid: unknown key {sorted(bad)[0]!r}")
    g, span = default_grid(vehicle), vehicle_spans(vehicle)
    rho = _axis(data["rho"], "rho") if "rho" in data else g.rho
    if rho[0] <= 0 or rho[-1] >= 1:
        raise ContractError("grid: rho must lie in (0, 1)")
    tilt = _axis(data["tilt_deg"], "tilt_deg", deg=True, span=span["tilt_deg"]) if "tilt_deg" in data else g.tilt
    tr = (_axis(data["thrust_ratio"], "thrust_ratio", span=span["thrust_ratio"]) if "thrust_ratio" in data
          else g.thrust_ratio)
    kw = {k: type(getattr(g, k))(data[k]) for k in ("n_intervals", "cpu_time_s", "rel_tol", "starts", "chunk") if k in data}
    return Grid(rho=rho, tilt=tilt, thrust_ratio=tr, **kw)


def load_grid(path: str | Path, vehicle: Vehicle) -> Grid:
    return grid_from_dict(load_mapping(path), vehicle)


# ============================================================================ one cell


def brake_accel(lim: Limits) -> float:
    """Full straight-line deceleration of the input set (level flight, heading +x)."""
    tilt = lim.tilt if lim.tilt_model == "cone" else lim.theta_lim
    return min(lim.g * math.tan(tilt), thrust_limited_accel(lim.t_max, lim.mass, lim.g))


def _stop_speed(a_b: float, c: float, r_k: float, lead: float = 0.0) -> float:
    return float(stop_speed_kinematic(a_b, c, r_k, lead))


def stop_trajectory(a_b: float, v: float, n: int) -> tuple[np.ndarray, float]:
    w = np.zeros((n, 4))
    w[:, 0] = -a_b
    return w, max(v / a_b, 1e-9) * (1.0 + 1e-9) / n  # ends just past the stop: never creeping forward


@dataclass
class CellResult:
    rho: float
    lo: float  # verified speed at c = C_REF [m/s] (lower end of the bracket)
    hi: float  # first speed not verified (upper end), inf if never tried
    branch: str  # "stop" or "pass"
    w: np.ndarray  # (N, 4) limiting trajectory's ZOH inputs
    ts: float
    solves: list = field(default_factory=list)  # (kind, verified, cpu_s, status)


def solve_cell(lim: Limits, rho: float, n: int = 40, cpu_time: float = 1.0, rel_tol: float = 1e-3, starts: int = 3,
               warm: tuple | None = None, c: float = C_REF, lead_time: float = 0.0) -> CellResult:
    """Largest verified safe speed for the head-on cell (c, r_k = ρ·c) under `lim` (t_react folded
    out; `lead_time` > 0 coasts V·lead_time first). `warm` = (w, t_s, V) of a neighbouring cell."""
    r_k = rho * c
    a_b = brake_accel(lim)
    a = lim.accel_bound()
    v_stop = _stop_speed(a_b, c, r_k, lead_time) * (1.0 - 1e-9)
    solves = []
    best = None
    v_cap = 50.0 * math.sqrt(max(a, 1e-9) * c) + 10.0 * v_stop
    v_seed = max(v_stop * 1.2, 0.5 * math.sqrt(a * c / max(rho, 1e-3)), 1e-3)
    seeds = []
    if warm is not None:
        seeds.append((warm[0], warm[1], warm[2]))
    for beta in (1.35, 0.6, 0.0)[: max(starts, 0)]:
        w, ts = policy_guess(beta, v_seed, a, c, r_k, n)
        seeds.append((w, ts, v_seed))
    for w, ts, v0 in seeds:
        pr = head_on_problem(lim, v0, c, r_k, n=n, free_speed=True, v_bounds=(0.0, v_cap), lead_time=lead_time)
        r = plan(pr, (w, ts), cpu_time=cpu_time, verify_tol=0.0)
        solves.append(("max_speed", r.ok, r.cpu_s, r.status))
        if r.ok and (best is None or r.problem.q0[1] > best.problem.q0[1]):
            best = r
    if best is not None and best.problem.q0[1] > v_stop:
        lo, w_lo, ts_lo, branch = best.problem.q0[1], best.w, best.ts, "pass"
    else:
        lo, branch = v_stop, "stop"
        w_lo, ts_lo = stop_trajectory(a_b, v_stop, n)
    # bisection upward from the verified speed: the bracket's upper end must fail verification
    hi, step = math.inf, rel_tol
    for _ in range(6):
        v_try = lo * (1.0 + step)
        pr = head_on_problem(lim, v_try, c, r_k, n=n)
        if lead_time:
            q0 = list(pr.q0)
            q0[0] = v_try * lead_time
            pr = replace(pr, q0=tuple(q0))
        r = plan(pr, (w_lo * (1.0 + step) ** 2, ts_lo), cpu_time=cpu_time, verify_tol=0.0)
        solves.append(("bracket", r.ok, r.cpu_s, r.status))
        if not r.ok:
            hi = v_try
            break
        lo, w_lo, ts_lo, branch = v_try, r.w, r.ts, "pass"
        step *= 2.0
    return CellResult(rho=rho, lo=lo, hi=hi, branch=branch, w=w_lo, ts=ts_lo, solves=solves)


def _solve_chunk(task: dict) -> list[CellResult]:
    """Worker: one run of neighbouring ρ cells of one shape class, warm-starting along the run (its first cell from
    the task's `warm`, if any)."""
    for k, v in ONE_THREAD.items():
        os.environ.setdefault(k, v)
    out, warm = [], task.get("warm")
    for rho in task["rhos"]:
        res = solve_cell(task["limits"], rho, n=task["n"], cpu_time=task["cpu_time"], rel_tol=task["rel_tol"],
                         starts=task["starts"], warm=warm)
        out.append(res)
        warm = (res.w, res.ts, res.lo) if res.branch == "pass" else None
    return out


# ============================================================================ shape classes


def _cell_limits(vehicle: Vehicle, tilt: float, thrust_ratio: float, tilt_model: str) -> Limits:
    return Limits.from_vehicle(vehicle, tilt, thrust_ratio, tilt_model=tilt_model)


def _classes(vehicle: Vehicle, grid: Grid, tilt_model: str):
    """Shape classes: (limits to solve, per-cell class index, per-cell acceleration scale λ)."""
    nt, nr = len(grid.tilt), len(grid.thrust_ratio)
    cls_of = np.zeros((nt, nr), dtype=np.int64)
    scale = np.ones((nt, nr))
    if tilt_model == "cone":
        ref = Limits(mass=1.0, t_max=10.0 * G, tilt=math.radians(45.0), tilt_model="cone")
        for j, t in enumerate(grid.tilt):
            for k, tr in enumerate(grid.thrust_ratio):
                a_h = horizontal_accel_limit(t, vehicle.t_max(tr), vehicle.mass_kg)
                scale[j, k] = a_h / ref.accel_bound()
        return [ref], cls_of, scale
    classes, keys = [], {}
    for j, t in enumerate(grid.tilt):
        for k, tr in enumerate(grid.thrust_ratio):
            binds = vehicle.t_max(tr) / vehicle.mass_kg < G / math.cos(t) ** 2
            kk = k if binds else nr - 1
            key = (j, kk)
            if key not in keys:
                keys[key] = len(classes)
                classes.append(_cell_limits(vehicle, t, float(grid.thrust_ratio[kk]), "box"))
            cls_of[j, k] = keys[key]
    return classes, cls_of, scale


def _scaled(w, ts, v, lam):
    """Scaling law at fixed c: accelerations × λ, time / √λ, speed × √λ."""
    return w * lam, ts / math.sqrt(lam), v * math.sqrt(lam)


def _tasks(classes, grid: Grid, kept=None) -> list[dict]:
    """The sweep's tasks: per shape class, runs of up to `grid.chunk` neighbouring ρ cells; with `kept`
    (`contracts.kept_cells.KeptCells`) only the cells it lacks, each run warm-started from the kept cell below it."""
    todo = np.ones(len(grid.rho), dtype=bool) if kept is None else kept.solve_mask()
    tasks = []
    for ci, lim in enumerate(classes):
        s = 0
        while s < len(grid.rho):
            if not todo[s]:
                s += 1
                continue
            e = s
            while e < len(grid.rho) and todo[e] and e - s < grid.chunk:
                e += 1
            tasks.append({"class": ci, "limits": lim, "rhos": [float(r) for r in grid.rho[s:e]],
                          "n": grid.n_intervals, "cpu_time": grid.cpu_time_s, "rel_tol": grid.rel_tol,
                          "starts": grid.starts, "first": s, "warm": kept.warm(ci, s - 1) if kept is not None else None})
            s = e
    return tasks


# ============================================================================ the build


def build_avoid_table(vehicle, out, grid=None, workers: int = 2, scheduler: str | None = None,
                      tilt_model: str = "cone", progress: bool = True, resume: bool = False,
                      checkpoint: bool = True, partial_grid: bool = False, extend=None) -> dict:
    """Build, verify and write the avoid table (plus `<out>.trajectories.npz`); returns a summary.

    `vehicle`: a `Vehicle`, a shipped name or a YAML path. `grid`: a `Grid`, a dict (`grid_from_dict`),
    a YAML path, or None (`default_grid`). `workers`: local process pool size (1: in-process);
    `scheduler`: a Dask distributed scheduler address (overrides `workers`).
    Raises `ContractError` if the grid does not cover the vehicle's thrust range and tilt limit
    (`grid_coverage`; `partial_grid`: the summary's `coverage_gaps` lists them instead), or if more than 1 % of the
    cells need a monotonicity repair. With `checkpoint`,
    finished tasks are kept in `<out>.partial/` until the table is written; `resume` continues from it
    (`contracts.runner.Checkpoint`), and an existing checkpoint without `resume` is refused.
    `extend`: a built table whose verified cells are kept (`contracts.kept_cells`): only the ρ points its axis
    lacks are solved, and its E_tr_pred slots are carried over; without `grid` the grid is its own with the
    default build's ρ axis.
    """
    t_start = time.perf_counter()
    veh = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
    veh.require(("inertia_kg_m2", "yaw_moment_max_nm"), "the avoid table (build with --stop-only without them)")
    if extend is not None:
        grid = grid_for_extension(extend, veh, grid, default_grid)
    grid = as_grid(grid, veh, default_grid, grid_from_dict)
    gaps = grid_coverage(grid, veh)
    if gaps and not partial_grid:
        raise ContractError(f"grid does not cover vehicle {veh.name}: {'; '.join(gaps)} (widen the grid, or "
                            "--partial-grid to build it anyway)")
    if tilt_model not in ("cone", "box"):
        raise ContractError(f"unknown tilt model {tilt_model!r} (cone or box)")
    out = Path(out)
    classes, cls_of, scale = _classes(veh, grid, tilt_model)
    kept = kept_cells(extend, veh, grid, tilt_model, cls_of, scale) if extend is not None else None
    tasks = _tasks(classes, grid, kept)
    ckpt = None
    if checkpoint:
        key = {"build": "avoid", "vehicle": veh.fingerprint(), "tilt_model": tilt_model, "grid": grid.describe(),
               "axes": [grid.rho.tolist(), grid.tilt.tolist(), grid.thrust_ratio.tolist()], "chunk": grid.chunk,
               "tasks": len(tasks)}
        if kept is not None:
            key["extends"] = kept.table.meta.get("arrays_sha256")
        ckpt = Checkpoint(out, key, resume, "contract-guard table build")
    results = run_tasks(tasks, workers, scheduler, progress, sum(len(t["rhos"]) for t in tasks), fn=_solve_chunk,
                        desc="avoid cells", checkpoint=ckpt)
    n_rho, n = len(grid.rho), grid.n_intervals
    V = np.zeros((len(classes), n_rho))
    HI = np.full((len(classes), n_rho), np.inf)
    W = np.zeros((len(classes), n_rho, n, 2))
    TS = np.zeros((len(classes), n_rho))
    BR = np.zeros((len(classes), n_rho), dtype=np.int8)
    if kept is not None:
        kept.fill(V, HI, W, TS, BR)
    solves = []
    for t, res in zip(tasks, results):
        for off, r in enumerate(res):
            i = t["first"] + off
            V[t["class"], i], HI[t["class"], i] = r.lo, r.hi
            W[t["class"], i], TS[t["class"], i] = r.w[:, :2], r.ts
            BR[t["class"], i] = 1 if r.branch == "pass" else 0
            solves += r.solves
    # per cell: F from the scaled class trajectory, re-verified against the cell's own limits
    F = np.zeros((n_rho, len(grid.tilt), len(grid.thrust_ratio)))
    fails = 0
    checked: dict[tuple, np.ndarray] = {}
    for j, tilt in enumerate(grid.tilt):
        for k, tr in enumerate(grid.thrust_ratio):
            ci, lam = int(cls_of[j, k]), float(scale[j, k])
            lim = _cell_limits(veh, float(tilt), float(tr), tilt_model)
            key = (ci, round(lam, 12), lim.t_max, lim.tilt)
            if tilt_model == "cone":
                key = (ci, round(lam, 12))
            if key not in checked:
                col = np.zeros(n_rho)
                for i, rho in enumerate(grid.rho):
                    w4 = np.zeros((n, 4))
                    w4[:, :2] = W[ci, i]
                    w_c, ts_c, v_c = _scaled(w4, TS[ci, i], V[ci, i], lam)
                    pr = head_on_problem(lim, v_c, C_REF, float(rho) * C_REF, n=n)
                    ok = check_trajectory(pr, w_c, ts_c, tol=0.0)["ok"]
                    if ok:
                        col[i] = v_c / math.sqrt(G * C_REF)
                    else:  # never optimistic: fall back to the closed-form stop of this cell
                        fails += 1
                        col[i] = _stop_speed(brake_accel(lim), C_REF, float(rho) * C_REF) / math.sqrt(G * C_REF)
                checked[key] = col * (1.0 - 1e-9)
            F[:, j, k] = checked[key]
    F_rep, repairs = repair_monotone(F, (-1, +1, +1), "down")
    frac = repairs / F.size
    if frac > MAX_REPAIR_FRACTION:
        if ckpt is not None:  # a finished build that fails: nothing to resume
            ckpt.remove()
        raise ContractError(f"avoid table: {repairs} of {F.size} cells ({100 * frac:.2f} %) needed a "
                            f"monotonicity repair (limit {100 * MAX_REPAIR_FRACTION:.0f} %)")
    cpu = np.array([s[2] for s in solves])
    ok = np.array([bool(s[1]) for s in solves])
    wall = time.perf_counter() - t_start
    info = {
        "method": "numerical construction (paper: 'Numerical construction of contract'), reduced form "
                  "V_safe = sqrt(g*c)*F(r_k/c; tilt, thrust_ratio) at t_react = 0; stop branch closed form, "
                  "pass branch by the eq. (14)-(19) planner in max-speed form, then upward bisection; "
                  "stored: lower end of the verified bracket",
        "tilt_model": tilt_model,
        "shape_classes": len(classes),
        "scaling": "cone: F = sqrt(a_h/g)*G(rho), each (rho, a_h) re-verified by re-simulation" if tilt_model == "cone"
        else "box: one class per tilt and binding thrust ratio",
        "grid": grid.describe(),
        "planner": {"n_intervals": n, "keep_out": "separating line per ZOH interval on its Bezier hull",
                    "verification": "dense re-simulation, 20 sub-steps/interval, exact per-interval minimum distance, "
                                    "zero length tolerance", "shrink": 1e-6, "ipopt_max_cpu_time_s": grid.cpu_time_s},
        "solves": int(len(solves)), "solves_verified": int(ok.sum()),
        "verify_fallbacks": int(fails), "monotone_repairs": int(repairs),
        "bracket_rel_width_max": float(np.nanmax(np.where(np.isfinite(HI), HI / np.maximum(V, 1e-12) - 1.0, np.nan)))
        if np.any(np.isfinite(HI)) else None,
        "build_wall_s": round(wall, 2), "workers": (scheduler or workers),
        "trajectories": trajectories_path(out).name,
    }
    carried, method = {}, {"avoid": "contracts.sweep.build_avoid_table"}
    if kept is not None:  # the solves above are this build's; the kept cells' are the base's
        info["extends"] = kept.info(F_rep)
        carried = kept.controller_slots()
        method = dict(kept.table.meta.get("method") or {}) | method
    avoid = Slot((grid.rho, grid.tilt, grid.thrust_ratio), F_rep, info)
    meta = write_table(out, veh, tilt_model=tilt_model, avoid=avoid, method=method, **carried)
    traj_path = write_trajectories(out, grid.rho, grid.tilt, grid.thrust_ratio, cls_of, scale, V, HI, W, TS, BR, C_REF,
                                   tilt_model, slot_sha256("avoid", avoid))
    verify(out, veh)
    if ckpt is not None:
        ckpt.remove()
    wall = time.perf_counter() - t_start
    feas = cpu[ok] if ok.any() else np.zeros(1)
    infeas = cpu[~ok] if (~ok).any() else np.zeros(1)
    return {"path": str(out), "trajectories": str(traj_path), "vehicle": veh.name, "tilt_model": tilt_model,
            "cells": int(F.size), "shape_classes": len(classes), "class_cells": int(len(classes) * n_rho),
            "solves": int(len(solves)), "solve_cpu_s": {"feasible": feas.tolist(), "infeasible": infeas.tolist()},
            "monotone_repairs": int(repairs), "verify_fallbacks": int(fails), "wall_s": wall,
            "resumed_cells": ckpt.resumed_items if ckpt is not None else 0, "grid": grid.describe(),
            "coverage_gaps": gaps, "extends": info.get("extends")}


# ============================================================================ fresh answers (tests, note)


def fresh_v_safe(vehicle: Vehicle, d_od: float, r_obst: float, e_tr: float, tilt: float, thrust_ratio: float,
                 tilt_model: str = "cone", n: int = 40, cpu_time: float = 2.0, rel_tol: float = 1e-3,
                 reaction: bool = True) -> CellResult:
    """A fresh bisection with the planner at one off-grid point, with the folded reaction time as a
    coast of V·t_react(tilt) before the manoeuvre (what the table's lookup approximates from below)."""
    c = d_od + r_obst
    r_k = r_obst + e_tr + vehicle.r_body_m
    lim = _cell_limits(vehicle, tilt, thrust_ratio, tilt_model)
    lead = vehicle.reaction_time(tilt) if reaction else 0.0
    return solve_cell(lim, r_k / c, n=n, cpu_time=cpu_time, rel_tol=rel_tol, starts=3, c=c, lead_time=lead)


def rate_limit_check(vehicle: Vehicle, v: float, d_od: float, r_obst: float, e_tr: float, tilt: float,
                     thrust_ratio: float, tilt_model: str = "cone", n: int = 40, cpu_time: float = 5.0) -> dict:
    """Is the folded reaction time conservative at this point?

    `v` is the table's answer (reaction folded as t_react + tilt/rate). The full eq. (14) planner with
    roll/pitch-rate limits, w(1) = w_0 = 0 (level cruise) and only the pure latency t_react (a coast of
    V·t_react) first finds (a) its own largest verified speed, then (b) a verified trajectory at `v`
    itself, warm-started from (a). Returns {"v_table", "v_rate_limited_max", "ok", "result"}.
    """
    c = d_od + r_obst
    r_k = r_obst + e_tr + vehicle.r_body_m
    lim = Limits.from_vehicle(vehicle, tilt, thrust_ratio, tilt_model=tilt_model, rates=True)
    a = lim.accel_bound()
    lead = vehicle.t_react_s
    best = None
    for beta in (1.35, 0.8, 0.3, 0.0):
        pr = head_on_problem(lim, v, c, r_k, n=n, w0=(0.0, 0.0, 0.0, 0.0), free_speed=True, lead_time=lead)
        w, ts = policy_guess(beta, v, a, c - v * lead, r_k, n)
        w[0] = 0.0
        r = plan(pr, (w, ts), cpu_time=cpu_time, verify_tol=0.0)
        if r.ok and (best is None or r.problem.q0[1] > best.problem.q0[1]):
            best = r
    v_max = best.problem.q0[1] if best is not None else 0.0
    at_v = None
    if best is not None and v_max >= v:
        pr = head_on_problem(lim, v, c - v * lead, r_k, n=n, w0=(0.0, 0.0, 0.0, 0.0))
        at_v = plan(pr, (best.w * (v / v_max) ** 2, best.ts), cpu_time=cpu_time, verify_tol=0.0)
        if not at_v.ok:  # the (a) trajectory re-timed is not exact at a lower speed: try cold starts
            for beta in (1.35, 0.8, 0.3, 0.0):
                w, ts = policy_guess(beta, v, a, c - v * lead, r_k, n)
                w[0] = 0.0
                at_v = plan(pr, (w, ts), cpu_time=cpu_time, verify_tol=0.0)
                if at_v.ok:
                    break
    return {"v_table": v, "v_rate_limited_max": v_max, "ok": bool(at_v is not None and at_v.ok), "result": at_v}
