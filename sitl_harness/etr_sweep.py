"""The controller contract, E_tr_pred(v_max, tilt, thrust_ratio) — the paper's Figure 12 — from SITL flights.

Paper: "UAV simulation model" (Figure 8: cascaded PID with x_r, y_r, z_r, ψ_r references and attitude
feed-forward), "Contract: Controller subsystem" (Figure 11: contour error = shortest distance from
the vehicle to the commanded path; Figure 12: its worst value against V_max and T_max at fixed
φ_max = θ_max). DESIGN.md §3: this sweep flies the SITL, so it lives on the harness side and writes
its result through the table writer of `contracts.table`; §4.5, §4.6.

Per cell (v_max, tilt, thrust_ratio) a named set of manoeuvres is flown on the SITL cascade
(`kernel.VehicleModel`, PX4-like position → velocity → acceleration → attitude → rate loops) with
position + velocity + acceleration feed-forward (the acceleration is the flat model's attitude
feed-forward, eq. (8)), thrust limited to the cell's `thrust_ratio`, the vehicle file's design wind
(mean + Dryden turbulence, a direction drawn per seed) — the flight loop, the reference types and the
seeded wind are `sitl_harness.maneuvers`'s; this module keeps the cells, the grid and the build —
several seeds:

- ``avoid@ρ``: the avoid table's limiting trajectory (`contracts.trajectories.limiting_trajectory`) at a
  spread of geometries ρ = r_k/c, scaled (c chosen) so that it starts at the cell's speed; after its
  last interval the reference coasts ballistically (the planner's terminal set);
- ``online@ρ``: what the daemon itself flies in offboard mode — the online OSQP planner's plan
  (`contracts.online_planner.AvoidancePlanner.plan`) from the entry state around the head-on keep-out
  disc at the same ρ, scaled (c chosen) so that the cell's speed is the offboard contract's speed
  there, v = OFFBOARD_CAP × V_safe(c, ρ): the tightest geometry the offboard contract admits at that
  speed. The cell's v_max and a_h(tilt, thrust_ratio) are the planner's limits, as on board. While the
  disc is still ahead it is replanned `ONLINE_REPLANS` time(s), every `REPLAN_S`, from the measured
  state, warm-started, adopted as the guidance adopts it (`contracts.online_planner.keeps_plan`); after the plan's last interval the reference
  coasts (pass) or holds (stop). Geometries where the planner finds no verified plan are skipped and
  counted (the daemon brakes there: that is `step_down`);
- ``failsafe@ρ``: the same plan interrupted halfway (`FAILSAFE_FRAC`), mid-swerve, by
  the braking stop the daemon streams itself on an offboard fail-safe (`best_stop` from the measured
  state at a_h, straight or swerving, then rest);
- ``drop@ρ`` (a thrust drop): the first plan made at the acceleration of the top of
  the vehicle's thrust range (`a_h(tilt, thrust_max)`), flown with the cell's thrust; the replans (the
  thrust estimate has caught up by then) use the cell's a_h. Only for cells below the top;
- ``cruise``: straight and level at v_max;
- ``step_down`` / ``step_up``: speed steps v → 0 and v/2 → v at the cell's full horizontal
  acceleration a_h(tilt, thrust_ratio) (`contracts.flat.horizontal_accel_limit`).

Every flight first cruises `SETTLE_S` at its entry velocity (integrators and drag trim settle; not
measured), then the manoeuvre and `COAST_S` after it are measured. The cell's value is the worst
horizontal contour error (`contracts.contour.contour_errors`, the same measure as the on-board
estimator) over all its flights, times (1 + `MARGIN_REL`) plus `MARGIN_ABS`; a flight that loses
the path (NaN, ground) is +inf. The surface is repaired monotone upward (non-decreasing in v_max and
tilt, non-increasing in thrust_ratio; `contracts.lookup.repair_monotone`) and written as the table's
`e_tr_pred` slot next to its untouched avoid slot.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.errors import ContractError
from contracts.flat import horizontal_accel_limit
from contracts.gridspec import as_grid, axis, load_mapping, vehicle_spans
from contracts.lookup import repair_monotone
from contracts.online_planner import OFFBOARD_CAP, REPLAN_S, AvoidancePlanner, Disc
from contracts.runner import Checkpoint, run_tasks
from contracts.stop import braking_decel, recovery_brake_stop, stop_jerk
from contracts.table import SLOTS, Slot, verify, write_table
from contracts.trajectories import limiting_trajectory, pass_branches
from contracts.vehicle import Vehicle, load_vehicle

from .maneuvers import (COAST_S, DT_NAV, SETTLE_S, WINDOW_S, Z_REF, BrakeReference, OnlineReference, Reference,
                        cruise_reference, smooth_step_reference, speed_step_reference, worst_contour_error,
                        zoh_reference)

MARGIN_REL = 0.25  # stated margin: E_tr_pred = worst·(1 + MARGIN_REL) + MARGIN_ABS
MARGIN_ABS = 0.02  # [m]

BUILD_RHOS = (0.03, 0.1, 0.2, 0.35, 0.5, 0.7)  # avoid geometries flown to build the surface
HELD_OUT_RHOS = (0.05, 0.15, 0.27, 0.42, 0.6, 0.85)  # … and only to validate it
BUILD_SEEDS = (0, 1)
HELD_OUT_SEEDS = (101, 102)
MANEUVERS = ("cruise", "step_down", "step_up", "avoid", "online", "failsafe", "drop")
# what a governed vehicle flies: the autopilot's own mission, straight, its speed steps and its Hold,
# each through its velocity smoothing (MPC_ACC_HOR / MPC_JERK_AUTO: the vehicle file's braking settings)
GOVERNOR_MANEUVERS = ("cruise", "smooth_up", "hold")
# ... and with the daemon's recovery brake: its own stop as well (`maneuvers.BrakeReference`)
BRAKE_MANEUVERS = (*GOVERNOR_MANEUVERS, "brake")
ONLINE_REPLANS = 1  # replans modelled per online flight, from the measured state, warm-started
FAILSAFE_FRAC = 0.5  # ``failsafe@ρ``: the fail-safe stop starts at this fraction of the first plan


# ============================================================================ the cell's references


def avoid_reference(table_path, rho_index: int, tilt_index: int, thrust_index: int, v: float) -> Reference:
    """The avoid table's limiting trajectory of one cell, scaled to start at speed `v` (V ∝ √c at a
    fixed acceleration scale, DESIGN.md §2's reduced form)."""
    unit = limiting_trajectory(table_path, rho_index, tilt_index, thrust_index, 1.0)
    c = (v / unit["v"]) ** 2 if unit["v"] > 0 else 1.0
    tr = limiting_trajectory(table_path, rho_index, tilt_index, thrust_index, c)
    return zoh_reference(f"avoid@rho={tr['r_k'] / c:.3g}", tr["q0"], tr["w"], tr["ts"])


def online_reference(table_path, rho_index: int, tilt_index: int, thrust_index: int, v: float,
                     a_max: float, kind: str = "online", a_plan: float | None = None) -> OnlineReference | None:
    """``online@ρ`` of one cell: the head-on disc at ρ = r_k/c with c such that v = OFFBOARD_CAP × V_safe(c, ρ)
    (V_safe ∝ √c, DESIGN.md §2), planned at V_max = v and `a_max` (the first plan at `a_plan` if given:
    ``drop``); None without a verified pass/stop plan. ``failsafe``: interrupted by the fail-safe stop (the
    cell's set derives it from its ``online@ρ`` instead of planning the same plan again: `cell_references`).
    The whole disc is E_tr allowance (r_min = 0): a replan from inside it is always admitted."""
    unit = limiting_trajectory(table_path, rho_index, tilt_index, thrust_index, 1.0)
    c = (v / (OFFBOARD_CAP * unit["v"])) ** 2
    disc = Disc(c, 0.0, unit["r_k"] * c, 0.0)
    plan = AvoidancePlanner().plan((0.0, 0.0), (v, 0.0), (1.0, 0.0), [disc], v_max=v,
                                   a_max=a_max if a_plan is None else a_plan)
    if not plan.ok or plan.kind not in ("pass", "stop"):
        return None
    return OnlineReference(f"{kind}@rho={unit['r_k']:.3g}", plan, disc, v, a_max, ONLINE_REPLANS,
                           FAILSAFE_FRAC if kind == "failsafe" else None)


# ============================================================================ one cell


def cell_references(table_path, vehicle: Vehicle, v: float, tilt: float, thrust_ratio: float,
                    avoid_index: tuple[int, int], rhos=BUILD_RHOS,
                    skipped: list | None = None, governor: bool | str = False) -> list:
    """The named manoeuvre set of one cell (module docstring); the names of ``online@ρ`` geometries
    without a verified plan are appended to `skipped`. `governor`: `GOVERNOR_MANEUVERS` only — no swerve, and
    the autopilot's own speed steps v/2 → v (``smooth_up``) and Hold v → 0 (``hold``), jerk-limited at
    `braking_decel` and its jerk, as its velocity smoothing flies them; "brake": `BRAKE_MANEUVERS`, those and the
    recovery brake's own stop from v at the cell's tilt and thrust (``brake``: `contracts.stop.recovery_brake_stop`,
    from the measured state, as the daemon flies it)."""
    a_h = horizontal_accel_limit(tilt, vehicle.t_max(thrust_ratio), vehicle.mass_kg)
    a_top = horizontal_accel_limit(tilt, vehicle.t_max(vehicle.thrust_ratio_range[1]), vehicle.mass_kg)
    if governor:
        a, j = braking_decel(vehicle, thrust_ratio, tilt), vehicle.braking.jerk_max_m_s3
        refs = [cruise_reference(v), smooth_step_reference("smooth_up", 0.5 * v, v, a, j),
                smooth_step_reference("hold", v, 0.0, a, j)]
        if governor == "brake":
            refs.append(BrakeReference("brake", v, *recovery_brake_stop(vehicle, thrust_ratio, tilt)))
        return refs
    refs = [cruise_reference(v), speed_step_reference("step_down", v, 0.0, a_h),
            speed_step_reference("step_up", 0.5 * v, v, a_h)]
    if table_path is not None:
        grid_rho, passes = pass_branches(table_path, *avoid_index)
        for rho in rhos:
            i = int(np.argmin(np.abs(grid_rho - rho)))
            if passes[i]:  # a stop-branch cell brakes straight at a_h: that is `step_down` already
                refs.append(avoid_reference(table_path, i, avoid_index[0], avoid_index[1], v))
            online = online_reference(table_path, i, avoid_index[0], avoid_index[1], v, a_h)
            if online is not None:
                refs.append(online)
                refs.append(dataclasses.replace(  # the same plan, cut by the daemon's stop (offboard.py, cycle.py)
                    online, name=online.name.replace("online@", "failsafe@", 1), failsafe_frac=FAILSAFE_FRAC,
                    stop_decel=braking_decel(vehicle, thrust_ratio), brake_jerk=vehicle.braking.jerk_max_m_s3,
                    stop_jerk=stop_jerk(vehicle)))
            elif skipped is not None:
                skipped.append(f"online@rho={grid_rho[i]:.3g}")
            if a_top > a_h * (1 + 1e-9):
                drop = online_reference(table_path, i, avoid_index[0], avoid_index[1], v, a_h, "drop", a_top)
                if drop is not None:
                    refs.append(drop)
    return refs


def _etr_column(task: dict) -> list[dict]:
    """Worker: all speeds of one (tilt, thrust_ratio) column; returns one record per cell."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    veh = task["vehicle"]
    out = []
    for v in task["v"]:
        skipped: list[str] = []
        refs = cell_references(task["table"], veh, v, task["tilt"], task["thrust_ratio"], task["avoid_index"],
                               task["rhos"], skipped, task.get("governor", False))
        per = {}
        for ref in refs:
            kind = ref.name.split("@")[0]
            for seed in task["seeds"]:
                e = worst_contour_error(veh, ref, task["thrust_ratio"], seed)
                per[kind] = max(per.get(kind, 0.0), e)
        out.append({"v": v, "worst": max(per.values()), "per_maneuver": per, "online_skipped": len(skipped)})
    return out


# ============================================================================ the build


@dataclass(frozen=True)
class EtrGrid:
    """Axes of the E_tr_pred slot; tilt and thrust_ratio must lie on the avoid table's grid (the
    avoid cell's limiting trajectories are flown)."""

    v: np.ndarray  # [m/s]
    tilt: np.ndarray  # [rad]
    thrust_ratio: np.ndarray
    rhos: tuple = BUILD_RHOS
    seeds: tuple = BUILD_SEEDS

    def describe(self) -> dict:
        return {"v_max": [float(x) for x in self.v], "tilt_deg": [round(math.degrees(x), 4) for x in self.tilt],
                "thrust_ratio": [float(x) for x in self.thrust_ratio], "avoid_rhos": list(self.rhos),
                "seeds": list(self.seeds),
                "online": {"rhos": list(self.rhos), "speed": "OFFBOARD_CAP x V_safe", "offboard_cap": OFFBOARD_CAP,
                           "replans": ONLINE_REPLANS, "replan_s": REPLAN_S, "failsafe_frac": FAILSAFE_FRAC,
                           "drop_from": "thrust_ratio_max"}}


def default_etr_grid(vehicle: Vehicle) -> EtrGrid:
    """The shipped grid, cut to what builds in about a quarter of an hour on two shared cores: v 1–8 m/s
    by 0.5 (above 8 m/s there is no bound: the contract answers at most 8 m/s), tilt 3, 5, 7, 9, 12,
    15, 20, 25° and every 5° above up to the vehicle's tilt limit (no tilt above the grid is usable),
    thrust_ratio at the bottom, middle and top of the vehicle's range (in between, the conservative
    lookup answers with the lower thrust)."""
    lo, hi = vehicle.thrust_ratio_range
    tilts = [t for t in (3.0, 5.0, 7.0, 9.0, 12.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0)
             if t <= vehicle.tilt_max_deg + 1e-9]
    return EtrGrid(v=np.round(np.arange(1.0, 8.0 + 1e-9, 0.5), 10), tilt=np.radians(tilts),
                   thrust_ratio=np.round(np.array([lo, 0.5 * (lo + hi), hi]), 10))


def etr_grid_from_dict(data: dict, vehicle: Vehicle) -> EtrGrid:
    """`table etr --grid FILE` format (YAML mapping); every key optional, defaults from `default_etr_grid`:

        v_max: {min: 1, max: 8, step: 0.5}     # [m/s], or a list
        tilt_deg: [5, 15, 30]                  # must lie on the avoid table's tilt axis
        thrust_ratio: [0.6, 1.0]               # must lie on the avoid table's thrust axis
        thrust_ratio: {n: 2}                   # min/max left out: the vehicle's range; n: 1 is the top end
        rhos: [0.1, 0.35]                      # avoid geometries flown (default BUILD_RHOS)
        seeds: [0, 1]                          # wind seeds per flight
    """
    known = {"v_max", "tilt_deg", "thrust_ratio", "rhos", "seeds"}
    bad = set(data) - known
    if bad:
        raise ContractError(f"E_tr grid: unknown key {min(bad)!r} (known: {', '.join(sorted(known))})")
    g = default_etr_grid(vehicle)
    v = axis(data["v_max"], "v_max") if "v_max" in data else g.v
    if v[0] <= 0:
        raise ContractError("E_tr grid: v_max must be positive")
    span = vehicle_spans(vehicle)
    tilt = axis(data["tilt_deg"], "tilt_deg", deg=True, span=span["tilt_deg"]) if "tilt_deg" in data else g.tilt
    tr = (axis(data["thrust_ratio"], "thrust_ratio", span=span["thrust_ratio"]) if "thrust_ratio" in data
          else g.thrust_ratio)
    rhos = tuple(float(r) for r in axis(data["rhos"], "rhos")) if "rhos" in data else g.rhos
    seeds = tuple(int(x) for x in data["seeds"]) if "seeds" in data else g.seeds
    if not seeds:
        raise ContractError("E_tr grid: seeds must name at least one seed")
    return EtrGrid(v=v, tilt=tilt, thrust_ratio=tr, rhos=rhos, seeds=seeds)


def load_etr_grid(path, vehicle: Vehicle) -> EtrGrid:
    return etr_grid_from_dict(load_mapping(path, "E_tr grid file"), vehicle)


def _avoid_index(table, tilt: float, thrust_ratio: float) -> tuple[int, int]:
    _, tilts, trs = table.avoid.axes
    j = np.flatnonzero(np.isclose(tilts, tilt, atol=1e-9))
    k = np.flatnonzero(np.isclose(trs, thrust_ratio, atol=1e-9))
    if not len(j) or not len(k):
        raise ContractError(f"E_tr grid point (tilt {math.degrees(tilt):.3g}°, thrust_ratio {thrust_ratio:.3g}) "
                            "is not on the avoid table's grid")
    return int(j[0]), int(k[0])


def measure_surface(table_path, vehicle: Vehicle, grid: EtrGrid, workers: int = 2, scheduler: str | None = None,
                    progress: bool = True, checkpoint=None, governor: bool | str = False
                    ) -> tuple[np.ndarray, dict, np.ndarray]:
    """Worst contour error per cell (no margin, no repair) → (values (n_v, n_tilt, n_tr), per-manoeuvre
    worst, number of ``online@ρ`` geometries skipped for want of a verified plan). `checkpoint`: a
    `contracts.runner.Checkpoint` keeping the finished columns. `governor`: `GOVERNOR_MANEUVERS` only (no
    avoid table needed)."""
    table = verify(table_path, vehicle) if table_path is not None and not governor else None
    tasks = []
    for j, tilt in enumerate(grid.tilt):
        for k, tr in enumerate(grid.thrust_ratio):
            idx = _avoid_index(table, float(tilt), float(tr)) if table is not None else (0, 0)
            tasks.append({"vehicle": vehicle, "table": str(table_path) if table_path is not None else None,
                          "v": [float(x) for x in grid.v], "tilt": float(tilt), "thrust_ratio": float(tr),
                          "avoid_index": idx, "rhos": tuple(grid.rhos), "seeds": tuple(grid.seeds), "jk": (j, k),
                          "governor": governor})
    results = run_tasks(tasks, workers, scheduler, progress, len(tasks) * len(grid.v), fn=_etr_column,
                        desc="E_tr cells", checkpoint=checkpoint)
    worst = np.zeros((len(grid.v), len(grid.tilt), len(grid.thrust_ratio)))
    per = {m: np.zeros_like(worst) for m in (BRAKE_MANEUVERS if governor == "brake" else
                                             GOVERNOR_MANEUVERS if governor else MANEUVERS)}
    skipped = np.zeros(worst.shape, dtype=int)
    for task, res in zip(tasks, results):
        j, k = task["jk"]
        for i, r in enumerate(res):
            worst[i, j, k] = r["worst"]
            skipped[i, j, k] = r["online_skipped"]
            for m, e in r["per_maneuver"].items():
                per[m][i, j, k] = e
    return worst, per, skipped


def with_margin(worst: np.ndarray) -> tuple[np.ndarray, int]:
    """E_tr_pred from the worst contour errors: the stated margin (NaN/inf: no bound), repaired monotone upward."""
    e = np.where(np.isfinite(worst), worst * (1.0 + MARGIN_REL) + MARGIN_ABS, np.inf)
    return repair_monotone(e, SLOTS["e_tr_pred"][2], "up")


def governor_surface(vehicle: Vehicle, grid: EtrGrid, workers: int = 2, scheduler: str | None = None,
                     progress: bool = True, brake: bool = False) -> tuple[np.ndarray, dict, int]:
    """The governor's E_tr_pred: the controller contract (Figure 12) flown on what a governed
    vehicle flies — cruise, speed steps and the autopilot's braking stop, no swerve — with the build's margin and
    upward repair → (values (n_v, n_tilt, n_tr), per-manoeuvre worst, repairs). Its rows need no avoid table.
    `brake`: the governor with its recovery brake (`BRAKE_MANEUVERS`: the brake's own stop too)."""
    worst, per, _ = measure_surface(None, vehicle, grid, workers, scheduler, progress,
                                    governor="brake" if brake else True)
    e, repairs = with_margin(worst)
    return e, per, repairs


def build_governor_etr(table_path, vehicle=None, grid: EtrGrid | None = None, workers: int = 2,
                       scheduler: str | None = None, progress: bool = True, out=None, brake: bool = False) -> dict:
    """Fly `governor_surface` on `grid` (default: the E_tr grid's) and write it as the table's `e_tr_pred_stop` slot
    (the stop contract's E_tr_pred), keeping its other slots exactly; returns a summary. `brake`: the surface with
    the recovery brake's own stop, written as the `e_tr_pred_brake` slot (the stop contract's E_tr_pred while the
    brake flies the stops)."""
    t0 = time.perf_counter()
    veh = vehicle if isinstance(vehicle, Vehicle) else (load_vehicle(vehicle) if vehicle else None)
    table = verify(table_path, veh)
    veh = table.vehicle
    grid = as_grid(grid, veh, default_etr_grid, etr_grid_from_dict, "E_tr grid file")
    e, per, repairs = governor_surface(veh, grid, workers, scheduler, progress, brake)
    info = {"method": "controller contract (Figure 12) flown on what a governed vehicle flies: "
                      + ", ".join(BRAKE_MANEUVERS if brake else GOVERNOR_MANEUVERS)
                      + " (speed steps and Hold jerk-limited at braking_decel and "
                      "the vehicle's braking jerk, as the autopilot's velocity smoothing flies them"
                      + ("; the recovery brake's straight stop from the measured state at the airframe's braking and "
                         "the attitude-rate jerk (contracts/stop.py recovery_brake_stop), as the daemon streams it"
                         if brake else "") + "); no swerve",
            "per_maneuver_worst_m": {m: float(np.max(np.where(np.isfinite(a), a, 0.0))) for m, a in per.items()},
            "margin": {"relative": MARGIN_REL, "absolute_m": MARGIN_ABS,
                       "rule": "E_tr_pred = worst * (1 + relative) + absolute"},
            "grid": grid.describe(), "monotone_repairs_up": int(repairs),
            "build_wall_s": round(time.perf_counter() - t0, 1)}
    name = "e_tr_pred_brake" if brake else "e_tr_pred_stop"
    method = dict(table.meta.get("method") or {}) | {name: "sitl_harness.etr_sweep.build_governor_etr"}
    dest = Path(out) if out is not None else Path(table_path)
    slots = {"e_tr_pred_stop": table.e_pred_stop, "e_tr_pred_brake": table.e_pred_brake}
    slots[name] = Slot((grid.v, grid.tilt, grid.thrust_ratio), e, info)
    write_table(dest, veh, tilt_model=table.tilt_model, avoid=table.avoid, e_tr_pred=table.e_pred, method=method,
                **slots)
    verify(dest, veh)
    return {"path": str(dest), "vehicle": veh.name, "cells": int(e.size), "monotone_repairs_up": int(repairs),
            "wall_s": round(time.perf_counter() - t0, 1)}


def build_etr(table_path, vehicle=None, grid: EtrGrid | None = None, workers: int = 2, scheduler: str | None = None,
              progress: bool = True, out=None, resume: bool = False, checkpoint: bool = True) -> dict:
    """Fly the sweep, add the margin, repair upward and write E_tr_pred into the table (in place, or
    to `out`), keeping its avoid slot exactly; returns a summary (build time included). `grid`: an
    `EtrGrid`, a mapping (`etr_grid_from_dict`), a YAML path or None. With `checkpoint` the finished
    columns are kept in `<destination>.partial/` until the table is written; `resume` continues from it."""
    t0 = time.perf_counter()
    veh = vehicle if isinstance(vehicle, Vehicle) else (load_vehicle(vehicle) if vehicle else None)
    table = verify(table_path, veh)
    veh = table.vehicle
    if table.avoid is None:
        raise ContractError(f"table {table_path}: no avoid contract (its limiting trajectories are flown)")
    grid = as_grid(grid, veh, default_etr_grid, etr_grid_from_dict, "E_tr grid file")
    dest = Path(out) if out is not None else Path(table_path)
    ckpt = None
    if checkpoint:
        key = {"build": "e_tr_pred", "vehicle": veh.fingerprint(), "table_arrays": table.meta.get("arrays_sha256"),
               "grid": grid.describe(), "margin": [MARGIN_REL, MARGIN_ABS], "maneuvers": list(MANEUVERS)}
        ckpt = Checkpoint(dest, key, resume, "contract-guard table etr")
    worst, per, skipped = measure_surface(table_path, veh, grid, workers, scheduler, progress, ckpt)
    e_rep, repairs = with_margin(worst)
    wall = time.perf_counter() - t0
    info = {
        "method": "controller contract (paper: 'Contract: Controller subsystem', Figures 8, 11, 12): worst "
                  "horizontal contour error of SITL flights on the PX4-like cascade with position, velocity and "
                  "acceleration (attitude) feed-forward, thrust limited to thrust_ratio, the vehicle's design wind; "
                  "manoeuvres: the avoid table's limiting trajectories at the listed rho, the online OSQP "
                  "planner's plans (replanned once from the measured state) at the same rho at "
                  "OFFBOARD_CAP x V_safe, the same plans interrupted halfway by the daemon's fail-safe braking stop "
                  "(best_stop from the measured state), the first plan made at the top of the thrust range's "
                  "acceleration and flown at the cell's thrust (a thrust drop), cruise, speed steps v->0 and v/2->v "
                  "at the cell's full horizontal acceleration",
        "margin": {"relative": MARGIN_REL, "absolute_m": MARGIN_ABS,
                   "rule": "E_tr_pred = worst * (1 + relative) + absolute"},
        "grid": grid.describe(),
        "flight": {"dt_nav_s": DT_NAV, "settle_s": SETTLE_S, "coast_s": COAST_S, "contour_window_s": WINDOW_S,
                   "altitude_m": -Z_REF, "wind": {"mean_m_s": veh.wind.mean_m_s, "gust_m_s": veh.wind.gust_m_s,
                                                  "direction": "drawn per seed"}},
        "monotone_repairs_up": int(repairs), "unbounded_cells": int(np.sum(~np.isfinite(worst))),
        "online_skipped": int(skipped.sum()), "online_flown": int(len(grid.rhos) * worst.size - skipped.sum()),
        "worst_maneuver_cells": {m: int(np.sum((a >= worst) & (a > 0))) for m, a in per.items()},
        "raw_worst_max_m": float(np.max(np.where(np.isfinite(worst), worst, 0.0))),
        "build_wall_s": round(wall, 1), "workers": scheduler or workers,
    }
    method = dict(table.meta.get("method") or {})
    method["e_tr_pred"] = "sitl_harness.etr_sweep.build_etr"
    write_table(dest, veh, tilt_model=table.tilt_model, avoid=table.avoid,
                e_tr_pred=Slot((grid.v, grid.tilt, grid.thrust_ratio), e_rep, info), method=method,
                e_tr_pred_stop=table.e_pred_stop, e_tr_pred_brake=table.e_pred_brake)
    verify(dest, veh)
    if ckpt is not None:
        ckpt.remove()
    return {"path": str(dest), "vehicle": veh.name, "cells": int(e_rep.size), "wall_s": round(time.perf_counter() - t0, 1),
            "resumed_cells": ckpt.resumed_items if ckpt is not None else 0,
            "monotone_repairs_up": int(repairs), "unbounded_cells": info["unbounded_cells"],
            "online_skipped": info["online_skipped"], "online_flown": info["online_flown"],
            "worst_maneuver_cells": info["worst_maneuver_cells"],
            "raw_worst_max_m": info["raw_worst_max_m"], "grid": grid.describe(),
            "per_maneuver_worst_m": {m: float(np.max(np.where(np.isfinite(a), a, 0.0))) for m, a in per.items()}}
