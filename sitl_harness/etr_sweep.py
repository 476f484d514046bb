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
(mean + Dryden turbulence, a direction drawn per seed), several seeds:

- ``avoid@ρ``: the avoid table's limiting trajectory (`contracts.sweep.limiting_trajectory`) at a
  spread of geometries ρ = r_k/c, scaled (c chosen) so that it starts at the cell's speed; after its
  last interval the reference coasts ballistically (the planner's terminal set);
- ``online@ρ``: what the daemon itself flies in offboard mode — the online OSQP planner's plan
  (`contracts.online_planner.AvoidancePlanner.plan`) from the entry state around the head-on keep-out
  disc at the same ρ, scaled (c chosen) so that the cell's speed is the offboard contract's speed
  there, v = OFFBOARD_CAP × V_safe(c, ρ): the tightest geometry the offboard contract admits at that
  speed. The cell's v_max and a_h(tilt, thrust_ratio) are the planner's limits, as on board. While the
  disc is still ahead it is replanned `ONLINE_REPLANS` time(s), every `REPLAN_S`, from the measured
  state, warm-started, adopted as the guidance adopts it; after the plan's last interval the reference
  coasts (pass) or holds (stop). Geometries where the planner finds no verified plan are skipped and
  counted (the daemon brakes there: that is `step_down`);
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

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from contracts.contour import contour_errors
from contracts.errors import ContractError
from contracts.flat import horizontal_accel_limit
from contracts.lookup import repair_monotone
from contracts.online_planner import OFFBOARD_CAP, REPLAN_S, AvoidancePlanner, Disc, Plan, keeps_plan
from contracts.table import SLOTS, Slot, verify, write_table
from contracts.vehicle import Vehicle, load_vehicle

from .control import SP_ACC, SP_POS, SP_VEL, SP_YAW
from .maneuvers import hovering
from .wind import Wind

DT_NAV = 0.01  # [s] setpoint rate (100 Hz, the SITL's navigation tick)
SETTLE_S = 4.0  # [s] cruise before the manoeuvre (not measured)
COAST_S = 2.0  # [s] measured after the manoeuvre's last interval
WINDOW_S = 1.0  # [s] contour-error path window (±) around each sample's own time
MEASURE_EVERY = 4  # contour error at every 4th tick (25 Hz; the margin covers the sampling)
Z_REF = -2.0  # [m] NED altitude of the flights (level flight, DESIGN.md §2)
MARGIN_REL = 0.25  # stated margin: E_tr_pred = worst·(1 + MARGIN_REL) + MARGIN_ABS
MARGIN_ABS = 0.02  # [m]
DIVERGED_M = 50.0  # a contour error beyond this is a lost vehicle: the cell has no bound (+inf)

BUILD_RHOS = (0.03, 0.1, 0.2, 0.35, 0.5, 0.7)  # avoid geometries flown to build the surface
HELD_OUT_RHOS = (0.05, 0.15, 0.27, 0.42, 0.6, 0.85)  # … and only to validate it
BUILD_SEEDS = (0, 1)
HELD_OUT_SEEDS = (101, 102)
MANEUVERS = ("cruise", "step_down", "step_up", "avoid", "online")
ONLINE_REPLANS = 1  # replans modelled per online flight, from the measured state, warm-started


# ============================================================================ references (pure maths)


@dataclass(frozen=True)
class Reference:
    """A horizontal reference on the DT_NAV grid from the manoeuvre start (t = 0): positions,
    velocities, accelerations (n, 2). Before t = 0 it is the straight line through p[0] at v[0]."""

    name: str
    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray

    def at(self, t: float):
        """(p, v, a) at time t: the settle line before 0, the nearest sample, the ballistic coast after the end."""
        if t < 0.0:
            return self.p[0] + self.v[0] * t, self.v[0], np.zeros(2)
        if t > self.t[-1]:
            return self.p[-1] + self.v[-1] * (t - self.t[-1]), self.v[-1], np.zeros(2)
        i = int(round(t / DT_NAV))
        return self.p[i], self.v[i], self.a[i]

    def path(self, t0: float = -WINDOW_S):
        """Path samples from t0 (the settle line included) to the end: (times, points (m, 2))."""
        pre = np.arange(math.floor(t0 / DT_NAV), 0) * DT_NAV
        pts = np.vstack([self.p[0] + np.outer(pre, self.v[0]), self.p]) if len(pre) else self.p
        return np.concatenate([pre, self.t]), pts

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def flight(self) -> Reference:
        """The setpoint source of one flight: a fixed reference is its own (no state)."""
        return self

    def setpoint(self, t: float, pos, vel):
        return self.at(t)


def _grid(duration: float) -> np.ndarray:
    return np.arange(int(math.ceil(round(duration / DT_NAV, 6))) + 1) * DT_NAV


def zoh_reference(name: str, q0, w, ts: float, coast_s: float = COAST_S, p0=(0.0, 0.0)) -> Reference:
    """The flat model's ZOH trajectory, eq. (12)–(13) (nodes by `contracts.planner.propagate`), evaluated
    in closed form on the DT_NAV grid (x, y chains of q0 = [X, Ẋ, Y, Ẏ, …] and w (N, ≥2)), then the
    ballistic coast (a = 0). `p0` shifts the positions."""
    from contracts.planner import propagate  # offline side (CasADi) like the rest of the sweep

    w = np.asarray(w, dtype=float)[:, :2]
    n = len(w)
    q = np.zeros(8)
    q[:4] = (q0[0] + p0[0], q0[1], q0[2] + p0[1], q0[3])
    w4 = np.zeros((n, 4))
    w4[:, :2] = w
    qn = propagate(q, w4, ts)
    pn, vn = qn[:, [0, 2]], qn[:, [1, 3]]
    t = _grid(n * ts + coast_s)
    k = np.minimum((t / ts).astype(int), n)
    tau = (t - k * ts)[:, None]
    a = np.where((k < n)[:, None], w[np.minimum(k, n - 1)], 0.0)
    return Reference(name, t, pn[k] + vn[k] * tau + 0.5 * a * tau * tau, vn[k] + a * tau, a)


def cruise_reference(v: float, duration: float = 4.0) -> Reference:
    """Straight, level cruise along +x at `v`."""
    t = _grid(duration)
    z = np.zeros_like(t)
    return Reference("cruise", t, np.column_stack([v * t, z]), np.column_stack([v + z, z]), np.zeros((len(t), 2)))


def speed_step_reference(name: str, v_from: float, v_to: float, a_max: float, coast_s: float = COAST_S) -> Reference:
    """A speed step along +x from `v_from` to `v_to` at constant |acceleration| `a_max` (ZOH, as the
    planner's bang-bang inputs), then `coast_s` at `v_to`."""
    t_acc = abs(v_to - v_from) / a_max
    a = math.copysign(a_max, v_to - v_from)
    return zoh_reference(name, (0.0, v_from, 0.0, 0.0), np.array([[a, 0.0]]), t_acc, coast_s)


def avoid_reference(table_path, rho_index: int, tilt_index: int, thrust_index: int, v: float) -> Reference:
    """The avoid table's limiting trajectory of one cell, scaled to start at speed `v` (V ∝ √c at a
    fixed acceleration scale, DESIGN.md §2's reduced form)."""
    from contracts.sweep import limiting_trajectory

    unit = limiting_trajectory(table_path, rho_index, tilt_index, thrust_index, 1.0)
    c = (v / unit["v"]) ** 2 if unit["v"] > 0 else 1.0
    tr = limiting_trajectory(table_path, rho_index, tilt_index, thrust_index, c)
    return zoh_reference(f"avoid@rho={tr['r_k'] / c:.3g}", tr["q0"], tr["w"], tr["ts"])


@dataclass(frozen=True)
class OnlineReference:
    """``online@ρ`` (Figure 12 over what offboard mode flies): the online planner's first plan around
    `disc` from the entry state (origin, +x at the plan's v[0]) and its limits; each `flight()`
    replans it as the guidance would."""

    name: str
    plan: Plan
    disc: Disc
    v_max: float
    a_max: float
    replans: int = ONLINE_REPLANS

    @property
    def t_end(self) -> float:
        return float(self.plan.t[-1]) + COAST_S

    @property
    def p(self) -> np.ndarray:  # entry state, as `Reference.p[0]`, `Reference.v[0]`
        return self.plan.p[:1]

    @property
    def v(self) -> np.ndarray:
        return self.plan.v[:1]

    def flight(self) -> OnlineFlight:
        return OnlineFlight(self)


class OnlineFlight:
    """One flight of an `OnlineReference`: the setpoints sent (its commanded path for the contour
    error, Figure 11, as the on-board estimator sees it) and the replans — from the measured state,
    every REPLAN_S while the disc is still ahead, warm-started from the plan in progress, which a
    failed replan does not replace."""

    def __init__(self, ref: OnlineReference):
        self.ref = ref
        self.plan, self.plan_t = ref.plan, 0.0
        self.left = ref.replans
        self.planner = AvoidancePlanner()  # per flight: the replans do not depend on other flights
        self.adopted = self.kept = 0
        self._t: list[float] = []
        self._p: list[np.ndarray] = []

    def setpoint(self, t: float, pos, vel):
        ref, d = self.ref, self.ref.disc
        if t < 0.0:
            p, v, a = ref.plan.p[0] + ref.plan.v[0] * t, ref.plan.v[0], np.zeros(2)
        else:
            if self.left and t - self.plan_t >= REPLAN_S - 1e-9 and pos[0] < d.x + d.r:
                self.left -= 1
                new = self.planner.plan(pos[:2], vel[:2], (1.0, 0.0), [d], v_max=ref.v_max, a_max=ref.a_max,
                                        warm=self.plan, elapsed=t - self.plan_t)
                if keeps_plan(self.plan, t - self.plan_t, new):
                    self.kept += 1
                else:
                    self.plan, self.plan_t = new, t
                    self.adopted += 1
            tau = t - self.plan_t
            # after the last interval, as the guidance: a pass rejoins the route at its end velocity (the
            # coast); a stop is at rest (as `Plan.sample` holds)
            if tau >= self.plan.t[-1]:
                p, v, a = self.plan.p[-1] + self.plan.v[-1] * (tau - self.plan.t[-1]), self.plan.v[-1], np.zeros(2)
            else:
                p, v, a = self.plan.sample(tau)
        if t >= -WINDOW_S - 1e-9:
            self._t.append(t)
            self._p.append(np.asarray(p, dtype=float))
        return p, v, a

    def path(self):
        """The setpoints sent from −WINDOW_S on: (times, points (m, 2))."""
        return np.array(self._t), np.array(self._p)


def online_reference(table_path, rho_index: int, tilt_index: int, thrust_index: int, v: float,
                     a_max: float) -> OnlineReference | None:
    """``online@ρ`` of one cell: the head-on disc at ρ = r_k/c with c such that v = OFFBOARD_CAP × V_safe(c, ρ)
    (V_safe ∝ √c, DESIGN.md §2), planned at V_max = v and `a_max`; None without a verified pass/stop plan.
    The whole disc is E_tr allowance (r_min = 0): a replan from inside it is always admitted."""
    from contracts.sweep import limiting_trajectory

    unit = limiting_trajectory(table_path, rho_index, tilt_index, thrust_index, 1.0)
    c = (v / (OFFBOARD_CAP * unit["v"])) ** 2
    disc = Disc(c, 0.0, unit["r_k"] * c, 0.0)
    plan = AvoidancePlanner().plan((0.0, 0.0), (v, 0.0), (1.0, 0.0), [disc], v_max=v, a_max=a_max)
    if not plan.ok or plan.kind not in ("pass", "stop"):
        return None
    return OnlineReference(f"online@rho={unit['r_k']:.3g}", plan, disc, v, a_max)


# ============================================================================ flying (the SITL cascade)


def wind_for_seed(vehicle: Vehicle, seed: int) -> Wind:
    """The vehicle file's design wind (mean + turbulence), blowing from a direction drawn from `seed`."""
    from_deg = float(np.random.default_rng(seed + 7919).uniform(0.0, 360.0))
    return Wind(vehicle.wind.mean_m_s, from_deg, vehicle.wind.gust_m_s, seed=seed)


@dataclass
class Flight:
    t: np.ndarray  # sample times (manoeuvre start = 0)
    pos: np.ndarray  # (n, 3) true NED positions
    ok: bool  # never NaN, never on the ground


def fly(vehicle: Vehicle, setpoint: Callable, t_end: float, thrust_ratio: float, wind: Wind, start_p, start_v,
        settle_s: float = SETTLE_S, on_sample: Callable | None = None) -> Flight:
    """Fly `setpoint(t, pos, vel) -> (p, v, a)` (horizontal, NED; given the true position and
    velocity) on the SITL cascade from −settle_s to t_end at altitude Z_REF with heading north:
    position + velocity + acceleration feed-forward (PX4 offboard style), thrust limited to
    `thrust_ratio`, the given wind. `on_sample(t, pos)` sees every true position."""
    m = hovering(vehicle, thrust_ratio, (start_p[0], start_p[1], Z_REF), (start_v[0], start_v[1], 0.0))
    n_phys = max(1, round(DT_NAV / m.dt))
    ticks = int(round((t_end + settle_s) / DT_NAV))
    ts = np.empty(ticks)
    ps = np.empty((ticks, 3))
    ok = True
    m.sp[SP_YAW] = 0.0
    for k in range(ticks):
        t = -settle_s + k * DT_NAV
        p, v, a = setpoint(t, m.pos, m.vel)
        m.sp[SP_POS:SP_POS + 3] = (p[0], p[1], Z_REF)
        m.sp[SP_VEL:SP_VEL + 3] = (v[0], v[1], 0.0)
        m.sp[SP_ACC:SP_ACC + 3] = (a[0], a[1], 0.0)
        m.set_wind(wind.step(DT_NAV))
        m.step(n_phys)
        ts[k] = t + DT_NAV
        ps[k] = m.pos
        if on_sample is not None:
            on_sample(ts[k], ps[k])
        if not np.all(np.isfinite(m.pos)) or m.pos[2] > -0.05:
            ok = False
            ts, ps = ts[: k + 1], ps[: k + 1]
            break
    return Flight(ts, ps, ok)


def worst_contour_error(vehicle: Vehicle, ref: Reference | OnlineReference, thrust_ratio: float, seed: int) -> float:
    """Fly `ref` (after SETTLE_S on its entry line) and return the worst horizontal contour error
    from t = 0 to its end against the path commanded in that flight (Figure 11); +inf if the vehicle
    was lost."""
    run = ref.flight()
    fl = fly(vehicle, run.setpoint, ref.t_end, thrust_ratio, wind_for_seed(vehicle, seed),
             ref.p[0] - ref.v[0] * SETTLE_S, ref.v[0])
    if not fl.ok:
        return math.inf
    sel = np.flatnonzero(fl.t >= 0.0)[::MEASURE_EVERY]
    path_t, path_p = run.path()
    e = contour_errors(fl.pos[sel, :2], fl.t[sel], path_t, path_p, WINDOW_S)
    worst = float(np.max(e)) if e.size else 0.0
    return worst if worst < DIVERGED_M else math.inf


# ============================================================================ one cell


def cell_references(table_path, vehicle: Vehicle, v: float, tilt: float, thrust_ratio: float,
                    avoid_index: tuple[int, int], rhos=BUILD_RHOS,
                    skipped: list | None = None) -> list[Reference | OnlineReference]:
    """The named manoeuvre set of one cell (module docstring); the names of ``online@ρ`` geometries
    without a verified plan are appended to `skipped`."""
    a_h = horizontal_accel_limit(tilt, vehicle.t_max(thrust_ratio), vehicle.mass_kg)
    refs = [cruise_reference(v), speed_step_reference("step_down", v, 0.0, a_h),
            speed_step_reference("step_up", 0.5 * v, v, a_h)]
    if table_path is not None:
        with np.load(_traj_path(table_path), allow_pickle=False) as z:
            grid_rho = z["rho"]
            cls = int(z["class_of_cell"][avoid_index])
            passes = z["branch"][cls] == 1
        for rho in rhos:
            i = int(np.argmin(np.abs(grid_rho - rho)))
            if passes[i]:  # a stop-branch cell brakes straight at a_h: that is `step_down` already
                refs.append(avoid_reference(table_path, i, avoid_index[0], avoid_index[1], v))
            online = online_reference(table_path, i, avoid_index[0], avoid_index[1], v, a_h)
            if online is not None:
                refs.append(online)
            elif skipped is not None:
                skipped.append(f"online@rho={grid_rho[i]:.3g}")
    return refs


def _traj_path(table_path) -> Path:
    from contracts.sweep import trajectories_path

    return trajectories_path(table_path)


def _etr_column(task: dict) -> list[dict]:
    """Worker: all speeds of one (tilt, thrust_ratio) column; returns one record per cell."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    veh = task["vehicle"]
    out = []
    for v in task["v"]:
        skipped: list[str] = []
        refs = cell_references(task["table"], veh, v, task["tilt"], task["thrust_ratio"], task["avoid_index"],
                               task["rhos"], skipped)
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
                           "replans": ONLINE_REPLANS, "replan_s": REPLAN_S}}


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


def _avoid_index(table, tilt: float, thrust_ratio: float) -> tuple[int, int]:
    _, tilts, trs = table.avoid.axes
    j = np.flatnonzero(np.isclose(tilts, tilt, atol=1e-9))
    k = np.flatnonzero(np.isclose(trs, thrust_ratio, atol=1e-9))
    if not len(j) or not len(k):
        raise ContractError(f"E_tr grid point (tilt {math.degrees(tilt):.3g}°, thrust_ratio {thrust_ratio:.3g}) "
                            "is not on the avoid table's grid")
    return int(j[0]), int(k[0])


def measure_surface(table_path, vehicle: Vehicle, grid: EtrGrid, workers: int = 2, scheduler: str | None = None,
                    progress: bool = True) -> tuple[np.ndarray, dict, np.ndarray]:
    """Worst contour error per cell (no margin, no repair) → (values (n_v, n_tilt, n_tr), per-manoeuvre
    worst, number of ``online@ρ`` geometries skipped for want of a verified plan)."""
    from contracts.sweep import run_tasks

    table = verify(table_path, vehicle) if table_path is not None else None
    tasks = []
    for j, tilt in enumerate(grid.tilt):
        for k, tr in enumerate(grid.thrust_ratio):
            idx = _avoid_index(table, float(tilt), float(tr)) if table is not None else (0, 0)
            tasks.append({"vehicle": vehicle, "table": str(table_path) if table_path is not None else None,
                          "v": [float(x) for x in grid.v], "tilt": float(tilt), "thrust_ratio": float(tr),
                          "avoid_index": idx, "rhos": tuple(grid.rhos), "seeds": tuple(grid.seeds), "jk": (j, k)})
    results = run_tasks(tasks, workers, scheduler, progress, len(tasks) * len(grid.v), fn=_etr_column,
                        desc="E_tr cells")
    worst = np.zeros((len(grid.v), len(grid.tilt), len(grid.thrust_ratio)))
    per = {m: np.zeros_like(worst) for m in MANEUVERS}
    skipped = np.zeros(worst.shape, dtype=int)
    for task, res in zip(tasks, results):
        j, k = task["jk"]
        for i, r in enumerate(res):
            worst[i, j, k] = r["worst"]
            skipped[i, j, k] = r["online_skipped"]
            for m, e in r["per_maneuver"].items():
                per[m][i, j, k] = e
    return worst, per, skipped


def build_etr(table_path, vehicle=None, grid: EtrGrid | None = None, workers: int = 2, scheduler: str | None = None,
              progress: bool = True, out=None) -> dict:
    """Fly the sweep, add the margin, repair upward and write E_tr_pred into the table (in place, or
    to `out`), keeping its avoid slot exactly; returns a summary (build time included)."""
    t0 = time.perf_counter()
    veh = vehicle if isinstance(vehicle, Vehicle) else (load_vehicle(vehicle) if vehicle else None)
    table = verify(table_path, veh)
    veh = table.vehicle
    if table.avoid is None:
        raise ContractError(f"table {table_path}: no avoid contract (its limiting trajectories are flown)")
    grid = grid or default_etr_grid(veh)
    worst, per, skipped = measure_surface(table_path, veh, grid, workers, scheduler, progress)
    e = np.where(np.isfinite(worst), worst * (1.0 + MARGIN_REL) + MARGIN_ABS, np.inf)
    e_rep, repairs = repair_monotone(e, SLOTS["e_tr_pred"][2], "up")
    wall = time.perf_counter() - t0
    info = {
        "method": "controller contract (paper: 'Contract: Controller subsystem', Figures 8, 11, 12): worst "
                  "horizontal contour error of SITL flights on the PX4-like cascade with position, velocity and "
                  "acceleration (attitude) feed-forward, thrust limited to thrust_ratio, the vehicle's design wind; "
                  "manoeuvres: the avoid table's limiting trajectories at the listed rho, the online OSQP "
                  "planner's plans (replanned once from the measured state) at the same rho at "
                  "OFFBOARD_CAP x V_safe, cruise, speed steps v->0 and v/2->v at the cell's full horizontal "
                  "acceleration",
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
    dest = Path(out) if out is not None else Path(table_path)
    method = dict(table.meta.get("method") or {})
    method["e_tr_pred"] = "sitl_harness.etr_sweep.build_etr"
    write_table(dest, veh, tilt_model=table.tilt_model, avoid=table.avoid,
                e_tr_pred=Slot((grid.v, grid.tilt, grid.thrust_ratio), e_rep, info), method=method)
    verify(dest, veh)
    return {"path": str(dest), "vehicle": veh.name, "cells": int(e.size), "wall_s": round(time.perf_counter() - t0, 1),
            "monotone_repairs_up": int(repairs), "unbounded_cells": info["unbounded_cells"],
            "online_skipped": info["online_skipped"], "online_flown": info["online_flown"],
            "worst_maneuver_cells": info["worst_maneuver_cells"],
            "raw_worst_max_m": info["raw_worst_max_m"], "grid": grid.describe(),
            "per_maneuver_worst_m": {m: float(np.max(np.where(np.isfinite(a), a, 0.0))) for m, a in per.items()}}
