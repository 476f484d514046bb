"""`table plot`: the avoid table's curves and surfaces (the paper's Figures 6–7 and 9–10), PNG + CSV.

Reads a table through the verified reader only (no CasADi). Every speed is the table's conservative
answer `ContractTable.v_safe` (with the vehicle's body radius and folded reaction time); the curves
also show the bare reduced form √(g·c)·F(R_obst/c) at t_react = 0 without body radius and e_tr, the
setting closest to the paper's numerical curves.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import csvfile
from .table import verify
from .vehicle import G


def _bare(table, d_od, r_obst, tilt, thrust_ratio):
    c = d_od + r_obst
    return math.sqrt(G * c) * table.f_lookup(r_obst / c, tilt, thrust_ratio) if c > 0 else 0.0


def avoid_curves(table, tilts_deg=(5.0, 13.0), r_obst=1.0, e_tr=0.0, thrust_ratio=None, d_od=None) -> dict:
    """V_max vs D_od (Figures 6–7): per tilt, the contract speed and the bare reduced form."""
    tr = table.vehicle.thrust_ratio_range[1] if thrust_ratio is None else thrust_ratio
    d = np.linspace(0.25, 15.0, 60) if d_od is None else np.asarray(d_od, float)
    out = {"d_od": d}
    for td in tilts_deg:
        t = math.radians(td)
        out[f"v_safe_tilt{td:g}"] = np.array([table.v_safe(x, r_obst, e_tr, t, tr) for x in d])
        out[f"v_bare_tilt{td:g}"] = np.array([_bare(table, x, r_obst, t, tr) for x in d])
    return out


def plot_table(table_path, out_dir) -> list[Path]:
    """Write fig6_7_vmax_vs_dod.{png,csv}, fig9_vmax_dod_tilt.{png,csv}, fig10_vmax_robst_dod.{png,csv}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = verify(table_path)
    if table.avoid is None:
        from .errors import ContractError

        raise ContractError(f"table {table_path}: no avoid contract to plot")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = f"{table.vehicle.name}, {table.tilt_model} model"
    tr = table.vehicle.thrust_ratio_range[1]
    tilt_lo, tilt_hi = table.avoid.axes[1][0], min(table.avoid.axes[1][-1], table.vehicle.tilt_max)
    written = []

    # Figures 6–7: V_max vs D_od at R_obst = 1 m, tilt 5° and 13°
    cur = avoid_curves(table, (5.0, 13.0), r_obst=1.0, thrust_ratio=tr)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for td, col in ((5.0, "C0"), (13.0, "C3")):
        ax.plot(cur["d_od"], cur[f"v_bare_tilt{td:g}"], color=col, ls="--",
                label=f"tilt {td:g}°: √(g·c)·F, t_react = 0, no body radius")
        ax.plot(cur["d_od"], cur[f"v_safe_tilt{td:g}"], color=col,
                label=f"tilt {td:g}°: contract (t_react, r_body)")
    ax.set_xlabel("D_od [m]")
    ax.set_ylabel("V_max [m/s]")
    ax.set_title(f"V_max vs D_od, R_obst = 1 m, e_tr = 0, thrust ratio {tr:g} ({name})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    written += _save(fig, out / "fig6_7_vmax_vs_dod", cur)
    plt.close(fig)

    # Figure 9: V_max over (D_od, tilt) at R_obst = 1 m
    d = np.linspace(0.5, 15.0, 40)
    tilts = np.linspace(max(tilt_lo, math.radians(3.0)), tilt_hi, 30)
    V = np.array([[table.v_safe(x, 1.0, 0.0, t, tr) for x in d] for t in tilts])
    written += _surface(plt, d, np.degrees(tilts), V, "D_od [m]", "tilt [deg]",
                        f"V_max(D_od, tilt), R_obst = 1 m ({name})", out / "fig9_vmax_dod_tilt", ("d_od", "tilt_deg"))

    # Figure 10: V_max over (R_obst, D_od) at tilt 7°
    r = np.linspace(0.1, 2.0, 30)
    t7 = math.radians(7.0)
    V10 = np.array([[table.v_safe(x, ro, 0.0, t7, tr) for x in d] for ro in r])
    written += _surface(plt, d, r, V10, "D_od [m]", "R_obst [m]", f"V_max(R_obst, D_od), tilt 7° ({name})",
                        out / "fig10_vmax_robst_dod", ("d_od", "r_obst"))
    return written


def _save(fig, stem: Path, cols: dict) -> list[Path]:
    png, csv_path = stem.with_suffix(".png"), stem.with_suffix(".csv")
    fig.savefig(png, dpi=120)
    keys = list(cols)
    with open(csv_path, "w", newline="") as fh:
        w = csvfile.writer(fh)
        w.writerow(keys)
        for row in zip(*(cols[k] for k in keys)):
            w.writerow([f"{x:.6g}" for x in row])
    return [png, csv_path]


def _surface(plt, x, y, V, xl, yl, title, stem: Path, names) -> list[Path]:
    fig = plt.figure(figsize=(7, 5))
    ax = fig.add_subplot(111, projection="3d")
    X, Y = np.meshgrid(x, y)
    ax.plot_surface(X, Y, V, cmap="viridis", linewidth=0, antialiased=True)
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.set_zlabel("V_max [m/s]")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    cols = {names[0]: X.ravel(), names[1]: Y.ravel(), "v_max": V.ravel()}
    out = _save(fig, stem, cols)
    plt.close(fig)
    return out
