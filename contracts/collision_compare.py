"""Analytical vs numerical contract, the paper's Figures 4, 6 and 7 (offline; the numerical curve uses
the CasADi planner through `contracts.sweep`, imported lazily).

- numerical: V_max(D_od) for a circular column of radius r_obst = 1 m by the avoid sweep's verified
  bisection (`sweep.solve_cell`: time-optimal planner eq. 14–19, stop branch in closed form, keep-out
  exact between samples, speed norm ≤ V, coast terminal set), point vehicle (r_k = r_obst: no body
  radius, no E_tr, no reaction time — the analytical construction has none of them either);
- analytical: the collision-set curves (`contracts.collision_sets`) of the inscribed (side √2·r_obst)
  and circumscribed (side 2·r_obst) squares, met face-on.

Placement of the squares along the flight line (`placement`):
- "face" (D_od as the contract measures it, to the obstacle's surface): each obstacle's own near surface is
  D_od ahead — the squares' near faces and the circle's nearest point all at D_od. The inscribed square is
  then *not* inside the circle (its front corners stick out ahead of the circle's arc), so nothing forces the
  circle's curve below the inscribed square's.
- "concentric" (the paper's Figure 5 nesting, inscribed ⊂ circle ⊂ circumscribed): all three share
  the centre D_od + r_obst; the inscribed square's face is r_obst·(1 − 1/√2) farther than D_od.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from . import csvfile
from .collision_sets import TS_DEFAULT, HeadOnLines, analytical_square_curve, input_vertices  # noqa: F401
from .vehicle import Vehicle, load_vehicle

CSV_COLUMNS = ("d_od_m", "v_numerical_circle", "v_analytical_inscribed", "v_analytical_circumscribed")
PLACEMENTS = ("face", "concentric")


def square_sides(r_obst: float = 1.0) -> dict:
    """Sides of the inscribed and circumscribed squares of a circle of radius r_obst (Figure 5)."""
    return {"inscribed": math.sqrt(2.0) * r_obst, "circumscribed": 2.0 * r_obst}


def face_offset(side: float, r_obst: float, placement: str) -> float:
    """D_ob of the square's face minus D_od of the circle's surface for a placement."""
    if placement == "face":
        return 0.0
    if placement == "concentric":
        return r_obst - 0.5 * side
    raise ValueError(f"unknown placement {placement!r} (one of {PLACEMENTS})")


def analytical_lines(vehicle: Vehicle, tilt: float, tilt_model: str = "box", ts: float = TS_DEFAULT,
                     r_obst: float = 1.0, thrust_ratio: float = 1.0) -> dict[str, HeadOnLines]:
    """Eq. (28) lines of the inscribed and circumscribed squares at tilt `tilt` [rad]."""
    w = input_vertices(tilt, tilt_model, vehicle.t_max(thrust_ratio), vehicle.mass_kg)
    return {name: analytical_square_curve(side, w, ts) for name, side in square_sides(r_obst).items()}


def analytical_curves(lines: dict[str, HeadOnLines], d_od, r_obst: float = 1.0, placement: str = "face") -> dict:
    """V_max(D_od) of each square for a placement (arrays like d_od)."""
    sides = square_sides(r_obst)
    return {name: lines[name].v_max(np.asarray(d_od, float) + face_offset(sides[name], r_obst, placement))
            for name in lines}


def numerical_circle_curve(vehicle: Vehicle, tilt: float, d_od, tilt_model: str = "box", r_obst: float = 1.0,
                           thrust_ratio: float = 1.0, n: int = 40, cpu_time: float = 2.0,
                           rel_tol: float = 1e-3) -> np.ndarray:
    """Numerical V_max(D_od) for the circular column (lower ends of verified bisection brackets)."""
    from .planner import Limits
    from .sweep import solve_cell

    lim = Limits.from_vehicle(vehicle, tilt, thrust_ratio, tilt_model=tilt_model)
    out, warm = [], None
    for d in np.atleast_1d(np.asarray(d_od, float)):
        if d <= 0.0:
            out.append(0.0)
            continue
        c = d + r_obst
        res = solve_cell(lim, r_obst / c, n=n, cpu_time=cpu_time, rel_tol=rel_tol, c=c, warm=warm)
        warm = (res.w, res.ts, res.lo) if res.branch == "pass" else None
        out.append(res.lo)
    return np.asarray(out)


def numerical_square_speed(vehicle: Vehicle, tilt: float, side: float, d_od: float, tilt_model: str = "box",
                           thrust_ratio: float = 1.0, n: int = 40, cpu_time: float = 3.0, keep_out: float = 0.0) -> float:
    """Diagnostic: the planner's largest verified speed past a face-on square column (near face at
    d_od), max-speed form, terminal set "past the rear face, Ẋ ≥ 0"; the stop branch √(2·a_x·d_od) is
    not included. `keep_out` [m]: the polygon's margin r (0: the bare square, as in the analytical
    construction)."""
    from dataclasses import replace

    from .avoid_limit import policy_guess
    from .planner import Limits, PlanProblem, Polygon, plan

    lim = Limits.from_vehicle(vehicle, tilt, thrust_ratio, tilt_model=tilt_model)
    a = lim.accel_bound()
    h = 0.5 * side
    poly = Polygon(((d_od, -h), (d_od + side, -h), (d_od + side, h), (d_od, h)), r=keep_out)
    inf = math.inf
    c = d_od + h
    v_seed = 0.8 * math.sqrt(a * c * c / h)
    pr = PlanProblem(limits=replace(lim, v_max=v_seed), q0=(0.0, v_seed, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                     obstacles=(poly,), terminal="box", qf_lb=(d_od + side, 0.0) + (-inf,) * 6, qf_ub=(inf,) * 8,
                     n=n, free_speed=True, v_bounds=(0.0, 50.0))
    best = 0.0
    for beta in (1.35, 0.8, 0.6):
        r = plan(pr, policy_guess(beta, v_seed, a, c, h * math.sqrt(2.0), n), cpu_time=cpu_time, verify_tol=1e-3)
        if r.ok:
            best = max(best, float(r.problem.q0[1]))
    return best


def compare(vehicle, tilt_deg: float, out_dir, tilt_model: str = "box", *, d_od_max: float = 10.0,
            d_od_step: float = 0.5, ts: float = TS_DEFAULT, r_obst: float = 1.0, thrust_ratio: float = 1.0,
            placement: str = "face", numerical=None) -> dict:
    """Figures 6/7 (numerical circle vs analytical squares), Figure 4 (lines and unsafe region) and
    the CSV (`CSV_COLUMNS`, one row per D_od in 0…d_od_max by d_od_step) in `out_dir`.

    `numerical`: precomputed circle speeds at those D_od (skips the planner). Returns a summary dict
    (paths, the rows, timings)."""
    veh = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
    if placement not in PLACEMENTS:
        raise ValueError(f"unknown placement {placement!r} (one of {PLACEMENTS})")
    tilt = math.radians(tilt_deg)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    d_od = np.round(np.arange(0.0, d_od_max + 0.5 * d_od_step, d_od_step), 10)
    t0 = time.perf_counter()
    lines = analytical_lines(veh, tilt, tilt_model, ts, r_obst, thrust_ratio)
    t_analytical = time.perf_counter() - t0
    t0 = time.perf_counter()
    v_num = (np.asarray(numerical, float) if numerical is not None
             else numerical_circle_curve(veh, tilt, d_od, tilt_model, r_obst, thrust_ratio))
    t_numerical = time.perf_counter() - t0
    ana = analytical_curves(lines, d_od, r_obst, placement)
    rows = [dict(zip(CSV_COLUMNS, (float(d), float(vn), float(vi), float(vc))))
            for d, vn, vi, vc in zip(d_od, v_num, ana["inscribed"], ana["circumscribed"])]
    stem = f"compare_{veh.name}_{tilt_deg:g}deg_{tilt_model}"
    csv_path = out / f"{stem}.csv"
    with csv_path.open("w", newline="") as fh:
        wr = csvfile.DictWriter(fh, fieldnames=CSV_COLUMNS)
        wr.writeheader()
        for r in rows:
            wr.writerow({k: f"{v:.6g}" for k, v in r.items()})
    title = f"{veh.name}, φ_max = θ_max = {tilt_deg:g}°" if tilt_model == "box" else f"{veh.name}, tilt {tilt_deg:g}° (cone)"
    png_cmp = plot_comparison(out / f"{stem}.png", d_od, v_num, lines, r_obst, placement, title, ts)
    png_lines = plot_lines(out / f"lines_{veh.name}_{tilt_deg:g}deg_{tilt_model}.png", lines, d_od_max, title)
    summary = {"vehicle": veh.name, "tilt_deg": tilt_deg, "tilt_model": tilt_model, "ts_s": ts,
               "placement": placement, "r_obst_m": r_obst, "thrust_ratio": thrust_ratio,
               "sets": {k: len(v.c11) for k, v in lines.items()},
               "time_analytical_s": round(t_analytical, 4), "time_numerical_s": round(t_numerical, 2),
               "files": [str(csv_path), str(png_cmp), str(png_lines)], "rows": rows}
    (out / f"{stem}.json").write_text(json.dumps(summary, indent=1))
    return summary


# ============================================================================ figures


def plot_comparison(path, d_od, v_num, lines, r_obst, placement, title, ts):
    """Figures 6/7: V_max vs D_od, numerical circle against both squares (both placements shown)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dense = np.linspace(0.0, float(d_od[-1]), 801)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(d_od, v_num, "ko-", ms=3, label="numerical, circle r = %g m" % r_obst)
    colours = {"inscribed": "tab:blue", "circumscribed": "tab:red"}
    for pl, style in (("face", "-"), ("concentric", "--")):
        cur = analytical_curves(lines, dense, r_obst, pl)
        for name, v in cur.items():
            lab = f"analytical, {name} square ({'near face at D_od' if pl == 'face' else 'concentric'})"
            ax.plot(dense, v, style, color=colours[name], lw=1.6 if pl == placement else 0.9, label=lab)
    ax.set_xlabel("D_od [m]")
    ax.set_ylabel("V_max [m/s]")
    ax.set_title(f"{title}: safe below each curve (t_s = {ts:g} s)")
    ax.grid(alpha=0.3)
    ax.set_xlim(0, float(d_od[-1]))
    ax.set_ylim(0, None)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return Path(path)


def plot_lines(path, lines, d_od_max, title):
    """Figure 4: every C_k's line D_ob·c11 + V·c12 = d, the union of unsafe half-planes and V_max."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dense = np.linspace(0.0, d_od_max, 801)
    fig, axes = plt.subplots(1, len(lines), figsize=(6 * len(lines), 4.5), squeeze=False)
    for ax, (name, hl) in zip(axes[0], lines.items()):
        vk = hl.v_lines(dense)  # (801, r+1)
        vmax = hl.v_max(dense)
        top = 1.6 * float(np.max(vmax))
        step = max(1, (vk.shape[1] - 1) // 25)
        for k in range(1, vk.shape[1], step):
            ax.plot(dense, vk[:, k], color="0.55", lw=0.6)
        ax.fill_between(dense, vmax, top, color="tab:red", alpha=0.18, label="unsafe: ∪ of half-planes")
        ax.plot(dense, vmax, "k", lw=2, label="V_max(D_ob)")
        ax.plot([], [], color="0.55", lw=0.6, label=f"lines of C_k, k = 1…{vk.shape[1] - 1} (1 in {step} drawn)")
        ax.set_ylim(0, top)
        ax.set_xlim(0, d_od_max)
        ax.set_xlabel("D_ob to the near face [m]")
        ax.set_ylabel("V [m/s]")
        ax.set_title(f"{name} square — {title}", fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return Path(path)
