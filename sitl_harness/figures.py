"""`contract-guard figures`: Figure 12 (the E_tr surface) and Figures 14–16 (demonstration flights), PNG + CSV.

Offline (matplotlib, the planner). The flights are `demo_flights.demo_set`; this module only draws and
writes files.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from contracts import csvfile
from contracts.errors import ContractError

from .demo_flights import PAPER, SCENARIOS, demo_set

FIG12_TILT_DEG = 5.0  # the paper's Figure 12 is drawn at φ_max = θ_max = 5°


def _mpl():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure12(table, out: Path, tilt_deg: float = FIG12_TILT_DEG) -> list[Path]:
    """E_tr_pred against V_max and thrust_ratio at one tilt (the conservative lookup's grid tilt at or
    above `tilt_deg`), as a surface PNG; the whole slot as CSV."""
    if table.e_pred is None:
        raise ContractError(f"table {table.path}: no e_tr_pred slot (build it: contract-guard table etr)")
    plt = _mpl()
    v, tilts, trs = table.e_pred.axes
    e = table.e_pred.values
    j = int(np.searchsorted(tilts, math.radians(tilt_deg) - 1e-12))
    j = min(j, len(tilts) - 1)
    csv_path = out / "fig12_etr_surface.csv"
    with csv_path.open("w", newline="") as f:
        wr = csvfile.writer(f)
        wr.writerow(["v_max_m_s", "tilt_deg", "thrust_ratio", "e_tr_pred_m"])
        for i, vv in enumerate(v):
            for jj, tt in enumerate(tilts):
                for k, rr in enumerate(trs):
                    wr.writerow([f"{vv:.4g}", f"{math.degrees(tt):.4g}", f"{rr:.4g}", f"{e[i, jj, k]:.6g}"])
    fig = plt.figure(figsize=(7.5, 5.5))
    ax = fig.add_subplot(111, projection="3d")
    vv, rr = np.meshgrid(v, trs, indexing="ij")
    ez = np.where(np.isfinite(e[:, j, :]), e[:, j, :], np.nan)
    ax.plot_surface(vv, rr, ez, cmap="viridis", edgecolor="k", linewidth=0.2)
    ax.set_xlabel("V_max [m/s]")
    ax.set_ylabel("T_max / T_nom")
    ax.set_zlabel("E_tr [m]")
    ax.set_title(f"Figure 12: E_tr_pred(V_max, T_max), tilt {math.degrees(tilts[j]):.0f}° "
                 f"(margin {table.e_pred.info.get('margin', {}).get('relative', '?')} rel.)")
    png = out / "fig12_etr_surface.png"
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return [png, csv_path]


def plan_view(flights, out: Path, stem: str) -> list[Path]:
    """One scenario at one tilt mode: real obstacle, virtual envelope R_obst + E_tr, the planned and
    the flown path of the contract flight (seed 0) and, faint, the negative controls' flown paths."""
    plt = _mpl()
    main = next(f for f in flights if f.variant == "contract")
    cx, cy, r = main.obstacle
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.add_patch(plt.Circle((cx, cy), r + main.e_tr, color="orange", alpha=0.25, label=f"virtual obstacle R_obst+E_tr"))
    ax.add_patch(plt.Circle((cx, cy), r, color="k", alpha=0.7, label="real obstacle R_obst"))
    ax.add_patch(plt.Circle((cx, cy), r + main.r_body, fill=False, ls="--", lw=0.8, color="k",
                            label="R_obst + body radius (touch)"))
    ax.plot(main.planned[:, 0], main.planned[:, 1], "b--", lw=1.5, label="planned path")
    ax.plot(main.flown[:, 0], main.flown[:, 1], "g-", lw=1.5, label=f"flown (min clearance {main.min_clearance:.2f} m)")
    styles = {"no_inflation": "r:", "speed_x1.15": "m:"}
    for f in flights:
        if f.variant in styles and f.seed == main.seed:
            ax.plot(f.flown[:, 0], f.flown[:, 1], styles[f.variant], lw=1.0,
                    label=f"control {f.variant} (clearance {f.min_clearance:.2f} m)")
    x0 = cx - main.d_od - r
    ax.axvline(x0, color="0.6", lw=0.8)
    ax.text(x0, cy - 0.4, " revealed at D_od", fontsize=8, color="0.4")
    ax.set_xlim(x0 - 2.0, cx + 3.0 * max(r, 1.0) + 4.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x north [m]")
    ax.set_ylabel("y east [m]")
    p = PAPER.get(main.name, {})
    ax.set_title(f"Fig. {p.get('figure', '?')}: T_max={main.thrust_ratio:.1f} T_nom, D_od={main.d_od:g} m, "
                 f"R_obst={main.r_obst:g} m\ntilt {main.tilt_deg:.2f}°, V_max {main.v_max:.2f} m/s, "
                 f"E_tr {main.e_tr:.2f} m (paper: {p.get('tilt_deg')}°, {p.get('v_max')} m/s, {p.get('e_tr')} m)",
                 fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    png = out / f"{stem}.png"
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
    csv_path = out / f"{stem}.csv"
    with csv_path.open("w", newline="") as fh:
        wr = csvfile.writer(fh)
        wr.writerow(["variant", "seed", "kind", "x_m", "y_m"])
        for f in flights:
            for kind, arr in (("planned", f.planned), ("flown", f.flown)):
                for x, y in arr[:: 5 if kind == "flown" else 1]:
                    wr.writerow([f.variant, f.seed, kind, f"{x:.4f}", f"{y:.4f}"])
    return [png, csv_path]


def make_figures(table, out, seeds=(0, 1, 2), names=SCENARIOS) -> dict:
    """All figures into `out`; returns the flights' summary (also written as demo_flights.csv/json)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = figure12(table, out)
    flights = demo_set(table, seeds=seeds, names=names)
    for name in names:
        for mode in ("paper", "chosen"):
            sel = [f for f in flights if f.name == name and (f.tilt_cap_deg is not None) == (mode == "paper")]
            files += plan_view(sel, out, f"{name}_{mode}_tilt")
    rows = [f.summary() for f in flights]
    keys = list(rows[0])
    with (out / "demo_flights.csv").open("w", newline="") as fh:
        wr = csvfile.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        for r in rows:
            wr.writerow({k: (list(v) if isinstance(v, tuple) else v) for k, v in r.items()})
    (out / "demo_flights.json").write_text(json.dumps(rows, indent=1, default=float))
    files += [out / "demo_flights.csv", out / "demo_flights.json"]
    return {"files": [str(f) for f in files], "flights": rows}
