"""The review's pictures (`contract-guard review --out`): `review.png`, the time series, and `plan.png`, the plan
view. The only module of the review that imports matplotlib (never on the daemon's path).

Both mark what matters in a bad flight, each mark an artist with a `gid` (`mark:hold`, `mark:failsafe`, …)
so a test reads them back: the daemon's holds (the governor's own and calibration holds) and a shadow
flight's would-be holds, failsafes (events and the failsafe state), stand-downs, link-down spans,
collisions and contract violations.

Plan view: the track in the local frame (east right, north up), coloured by ground speed against the limit
in force (`v_cmd`, else `v_max`; for a log without obstacle data, against the assumed sensor's limit, else
plain speed), the obstacle hits the daemon saw (`obstacle_m` along the direction of travel), the obstacle and
its keep-out disc (R_obst, R_obst + E_tr) at each obstacle's closest approach, the commanded route (a
mission's waypoints, where the log has them) and where holds, violations and the closest approach happened;
where the review knows the flight's scenario, the true world beneath it all: walls, polygons and boxes
(`plan:wall`) and columns, a cluster's included (`plan:column`).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch
from matplotlib.patches import Polygon as PolygonPatch

SUBSYSTEM_COLOURS = {"navigation": "tab:blue", "controller": "tab:orange", "environment": "tab:green",
                     "actuators": "tab:red", "guidance": "tab:purple", "autopilot": "tab:brown"}
# mark kind → (colour, alpha, legend label); spans are shaded, points are vertical lines
SPAN_STYLE = {
    "hold": ("tab:red", 0.25, "hold (daemon)"),
    "would_hold": ("salmon", 0.3, "would hold (shadow)"),
    "calibration_hold": ("gold", 0.35, "calibration hold"),
    "failsafe_state": ("red", 0.12, "failsafe state (link lost)"),
    "link_down": ("dimgrey", 0.3, "link down"),
}
POINT_STYLE = {
    "failsafe": ("red", "-", "failsafe"),
    "stand_down": ("black", ":", "stand-down (pilot took over)"),
    "collision": ("black", "-", "collision"),
}
TITLE_PT = 11.0
MIN_HALF_SPAN_M = 5.0  # the plan view shows at least 10 m × 10 m
HEADING_SPEED = 0.5  # m/s: below this the velocity's direction is noise; the last one above it stands


def _num(x):
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def _closed(spans):
    return [s for s in spans or [] if _num(s.get("start_t")) is not None and _num(s.get("end_t")) is not None]


def spans_of(rep: dict) -> dict[str, list[dict]]:
    """Every span to shade, by kind (`SPAN_STYLE`)."""
    m = rep.get("marks") or {}
    return {"hold": _closed(m.get("holds")), "would_hold": _closed(rep.get("would_hold")),
            "calibration_hold": _closed(m.get("calibration_holds")),
            "failsafe_state": _closed(m.get("failsafe_states")), "link_down": _closed(m.get("link_down"))}


def points_of(rep: dict) -> dict[str, list[float]]:
    """Every instant to mark, by kind (`POINT_STYLE`)."""
    m = rep.get("marks") or {}

    def ts(items, key="t"):
        return [t for t in (_num(i.get(key)) for i in items or []) if t is not None]

    return {"failsafe": ts(rep.get("failsafes")) + ts(m.get("failsafe_states"), "start_t"),
            "stand_down": ts(m.get("stand_downs")), "collision": ts(m.get("collisions"))}


def fitted_title(fig: Figure, text: str, size: float = TITLE_PT) -> str:
    """`text` wrapped to the figure's width (an average glyph is ~0.55 em wide; a margin of 5 %)."""
    width_pt = fig.get_figwidth() * 72 * 0.9
    return textwrap.fill(text, max(20, int(width_pt / (0.55 * size))), break_on_hyphens=False)


def _figure(size) -> Figure:
    """A figure on the Agg canvas (no pyplot, no GUI, no global state)."""
    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig


def _series(samples, columns, key):
    col, cb, ct = columns.index(key), columns.index("boot"), columns.index("t")
    xs, ys, last = [], [], None
    for row in samples:
        t = _num(row[ct])
        if t is None:
            continue
        if last is not None and row[cb] != last:
            xs.append(math.nan)
            ys.append(math.nan)
        last = row[cb]
        v = _num(row[col])
        xs.append(t)
        ys.append(math.nan if v is None else v)
    return xs, ys


def _title(fig: Figure, text: str) -> None:
    fig.suptitle(fitted_title(fig, text), fontsize=TITLE_PT)


def _layout(fig: Figure, legend_rows: int) -> None:
    """Room for the (wrapped) title above and the legend below."""
    lines = (fig._suptitle.get_text().count("\n") + 1) if fig._suptitle else 0
    h_in = fig.get_figheight()
    top = 1 - (lines * TITLE_PT * 1.35 + 8) / 72 / h_in
    bottom = (legend_rows * 16 + 6) / 72 / h_in if legend_rows else 0
    fig.tight_layout(rect=(0, bottom, 1, top))


def _legend(fig: Figure, handles: list, ncol_max: int = 5) -> int:
    if not handles:
        return 0
    ncol = min(len(handles), ncol_max)
    fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize="small", frameon=False)
    return math.ceil(len(handles) / ncol)


def time_figure(rep: dict, samples: list[tuple], columns: tuple, title: str) -> Figure:
    """Panels sharing the time axis, every mark on every panel."""
    panels = [
        ("speed [m/s]", [("ground_speed", "ground speed"), ("v_max", "V_max"), ("v_cmd", "commanded"), ("v_safe", "V_safe")]),
        ("Γ [m/s]", [("gamma", "Γ = V_max − V_safe"), ("gamma_flown", "ground speed − V_safe")]),
        ("d_od [m]", [("d_od", "D_od (used: the evidence's)"), ("d_od_stated", "D_od as the sensors state it")]),
        ("e_tr [m]", [("e_tr", "E_tr (used)"), ("e_tr_measured", "E_tr measured")]),
        ("thrust ratio", [("thrust_ratio", "T_max / T_nom")]),
        ("r_obst [m]", [("r_obst", "R_obst")]),
    ]
    blind = not rep.get("obstacle_data", True)
    need = rep.get("detection_need") or {}
    # a log without obstacle data: every metre is "above V_safe"; those spans are not shaded (not judged)
    outside = [] if blind else _closed((rep.get("outside_contract") or {}).get("flown_above_v_safe"))
    spans, points = spans_of(rep), points_of(rep)
    fig = _figure((11, 2.0 * len(panels) + 1.6))
    axes = fig.subplots(len(panels), 1, sharex=True)
    for ax, (label, keys) in zip(axes, panels):
        for key, name in keys:
            xs, ys = _series(samples, columns, key)
            if any(not math.isnan(y) for y in ys):
                ax.plot(xs, ys, label=name, lw=1.0, ls="--" if key in ("v_cmd", "v_safe", "d_od_stated") else "-")
        first = keys[0][0]  # the panel's main series
        if first == "ground_speed" and (need.get("sensor") or {}).get("limit_min") is not None:
            ax.axhline(need["sensor"]["limit_min"], color="tab:green", ls="--", lw=1, label="assumed sensor's limit")
        if first == "d_od" and need.get("stretches"):
            st = [s for s in need["stretches"] if s.get("d_od_m") is not None]
            ax.hlines([s["d_od_m"] for s in st], [s["start_t"] for s in st], [s["end_t"] for s in st],
                      color="tab:red", lw=2, label="D_od needed (per stretch)", gid="need:d_od")
            if need.get("sensor"):
                ax.axhline(need["sensor"]["range_m"], color="tab:green", ls="--", lw=1, label="assumed sensor")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if len(keys) > 1 or (first == "d_od" and need):
            ax.legend(loc="upper right", fontsize="small")
        for v in rep["violations"]:
            if _num(v["start_t"]) is not None and _num(v["end_t"]) is not None:
                ax.axvspan(v["start_t"], v["end_t"], alpha=0.2, lw=0, gid="mark:violation",
                           color=SUBSYSTEM_COLOURS.get(str(v["subsystem"]), "grey"))
        for sp in outside:
            ax.axvspan(sp["start_t"], sp["end_t"], alpha=0.15, lw=0, color="black", hatch="//", fill=False,
                       gid="mark:above_v_safe")
        for kind, items in spans.items():
            colour, alpha, _ = SPAN_STYLE[kind]
            for sp in items:
                ax.axvspan(sp["start_t"], max(sp["end_t"], sp["start_t"] + 1e-3), color=colour, alpha=alpha, lw=0,
                           gid=f"mark:{kind}")
        for kind, ts in points.items():
            colour, ls, _ = POINT_STYLE[kind]
            for t in ts:
                ax.axvline(t, color=colour, ls=ls, lw=2.0 if kind == "collision" else 0.9, gid=f"mark:{kind}")
    axes[1].axhline(0.0, color="black", lw=0.8)
    handles = [Patch(color=SUBSYSTEM_COLOURS.get(s, "grey"), alpha=0.3, label=f"violation: {s}")
               for s in sorted({str(v["subsystem"]) for v in rep["violations"]})]
    handles += [Patch(color=SPAN_STYLE[k][0], alpha=SPAN_STYLE[k][1] + 0.1, label=SPAN_STYLE[k][2])
                for k, items in spans.items() if items]
    handles += [Line2D([], [], color=POINT_STYLE[k][0], ls=POINT_STYLE[k][1], label=POINT_STYLE[k][2])
                for k, ts in points.items() if ts]
    if outside:
        handles.append(Patch(fill=False, hatch="//", alpha=0.5, label="flown above V_safe"))
    axes[-1].set_xlabel("t [s] (daemon clock, at the vehicle's rate)")
    _title(fig, title)
    _layout(fig, _legend(fig, handles))
    return fig


def _limit(rep: dict, row, col) -> float | None:
    """The limit the track is coloured against: commanded, else V_max; a log without obstacle data: the
    assumed sensor's lowest limit (else none: plain speed)."""
    if not rep.get("obstacle_data", True):
        s = (rep.get("detection_need") or {}).get("sensor")
        return s["limit_min"] if s and s.get("limit_min") else None
    return _num(row[col["v_cmd"]]) if _num(row[col["v_cmd"]]) is not None else _num(row[col["v_max"]])


def _speed(row, col) -> float:
    """Ground speed; where the log has none (stale telemetry), the velocity's horizontal norm; else NaN."""
    v = _num(row[col["ground_speed"]])
    if v is None and _num(row[col["vx"]]) is not None and _num(row[col["vy"]]) is not None:
        v = math.hypot(row[col["vx"]], row[col["vy"]])
    return np.nan if v is None else v


def plan_figure(rep: dict, samples: list[tuple], columns: tuple, title: str) -> Figure:
    """The track from above, with what the daemon saw and where things happened."""
    col = {k: columns.index(k) for k in ("t", "x", "y", "vx", "vy", "ground_speed", "v_cmd", "v_max", "obstacle_m",
                                          "r_obst", "e_tr")}
    rows = [r for r in samples if _num(r[col["x"]]) is not None and _num(r[col["y"]]) is not None
            and _num(r[col["t"]]) is not None]
    fig = _figure((9, 9))
    ax = fig.add_subplot(1, 1, 1)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east [m] (local frame)")
    ax.set_ylabel("north [m]")
    ax.grid(alpha=0.3)
    handles = []
    if not rows:
        ax.text(0.5, 0.5, "no position in this log", ha="center", va="center", transform=ax.transAxes)
        _title(fig, title)
        _layout(fig, 0)
        return fig
    t = np.array([float(r[col["t"]]) for r in rows])
    n = np.array([float(r[col["x"]]) for r in rows])
    e = np.array([float(r[col["y"]]) for r in rows])
    gs = np.array([_speed(r, col) for r in rows])
    lim = np.array([_limit(rep, r, col) or np.nan for r in rows])
    # the track, coloured by speed against the limit (or by speed where no limit is known)
    seg = np.stack([np.column_stack([e[:-1], n[:-1]]), np.column_stack([e[1:], n[1:]])], axis=1)
    jump = np.hypot(np.diff(e), np.diff(n)) > 50.0  # a restart or a position reset: no line across it
    against = np.isfinite(lim).any()
    value = gs[:-1] / np.where(lim[:-1] > 0, lim[:-1], np.nan) if against else gs[:-1]
    lc = LineCollection(seg[~jump], array=value[~jump], cmap="RdYlGn_r" if against else "viridis", lw=2.2,
                        gid="plan:track")
    if against:
        lc.set_clim(0.0, 1.5)
    ax.add_collection(lc)
    blind = not rep.get("obstacle_data", True)
    fig.colorbar(lc, ax=ax, shrink=0.7, label=("ground speed / the assumed sensor's limit" if blind else
                                               "ground speed / limit in force (1 = at the limit)") if against
                 else "ground speed [m/s]" + (" (no obstacle data: no limit)" if blind else ""))
    ax.plot(e[0], n[0], "o", color="black", ms=6, gid="plan:start")
    ax.plot(e[-1], n[-1], "s", color="black", ms=6, gid="plan:end")
    handles += [Line2D([], [], marker="o", color="black", ls="", label="start"),
                Line2D([], [], marker="s", color="black", ls="", label="end")]
    route = rep.get("route")
    if route:
        rn, re_ = zip(*route)
        ax.plot(re_, rn, "--", color="tab:blue", lw=1.2, marker="+", ms=9, gid="plan:route")
        handles.append(Line2D([], [], color="tab:blue", ls="--", marker="+", label="commanded route"))
    _world(ax, rep.get("world"), handles)
    _obstacles(ax, rows, col, handles)

    def at(tt):
        i = int(np.nanargmin(np.abs(t - tt)))
        return e[i], n[i]

    marks = [("hold", [s["start_t"] for k in ("hold", "calibration_hold") for s in spans_of(rep)[k]],
              dict(marker="s", color="tab:red", ms=9, mfc="none", mew=2), "hold"),
             ("would_hold", [s["start_t"] for s in spans_of(rep)["would_hold"]],
              dict(marker="s", color="salmon", ms=8, mfc="none", mew=2), "would hold (shadow)"),
             ("violation", [v["start_t"] for v in rep["violations"] if _num(v["start_t"]) is not None],
              dict(marker="^", color="tab:orange", ms=8, mfc="none", mew=1.5), "violation starts"),
             ("failsafe", points_of(rep)["failsafe"], dict(marker="X", color="red", ms=9), "failsafe"),
             ("link_down", [s["start_t"] for s in spans_of(rep)["link_down"]],
              dict(marker="o", color="dimgrey", ms=7, mfc="none"), "link down"),
             ("stand_down", points_of(rep)["stand_down"], dict(marker="v", color="black", ms=8), "stand-down"),
             ("collision", points_of(rep)["collision"], dict(marker="X", color="black", ms=14), "collision")]
    where = {c["t"]: (c["y"], c["x"]) for c in (rep.get("marks") or {}).get("collisions") or []
             if _num(c.get("x")) is not None and _num(c.get("y")) is not None and _num(c.get("t")) is not None}
    for kind, ts, style, label in marks:
        ts = [x for x in ts if x is not None]
        if ts:
            pe, pn = zip(*(where[x] if kind == "collision" and x in where else at(x) for x in ts))
            ax.plot(pe, pn, ls="", gid=f"mark:{kind}", **style)
            handles.append(Line2D([], [], ls="", label=label, **style))
    # at least 10 m × 10 m: a hover stays a point, not centimetres blown up to the page
    mid_e, mid_n, h = (e.min() + e.max()) / 2, (n.min() + n.max()) / 2, MIN_HALF_SPAN_M
    ax.update_datalim([(mid_e - h, mid_n - h), (mid_e + h, mid_n + h)])
    ax.autoscale_view()
    _title(fig, title)
    _layout(fig, _legend(fig, handles, 4))
    return fig


def _world(ax, world: dict | None, handles) -> None:
    """The scenario's true world (`review.world_outline`): over the daemon's obstacle estimates, beneath the track
    and the marks — what was really there."""
    if not world:
        return
    for pts in world.get("polygons") or []:
        ax.add_patch(PolygonPatch([(e, n) for n, e in pts], closed=True, color="saddlebrown", alpha=0.55, lw=0,
                                  zorder=1.5, gid="plan:wall"))
    for x, y, r, _ in world.get("columns") or []:
        ax.add_patch(Circle((y, x), r, color="saddlebrown", alpha=0.55, lw=0, zorder=1.5, gid="plan:column"))
    if world.get("polygons") or world.get("columns"):
        handles.append(Patch(color="saddlebrown", alpha=0.55, label="world (scenario)"))


def _obstacles(ax, rows, col, handles) -> None:
    """The hits (`obstacle_m` along the direction of travel, the last one flown above `HEADING_SPEED`; the event
    log has no heading), and per obstacle (hits within 2 m of each other)
    the obstacle (R_obst) and its keep-out disc (R_obst + E_tr) where the vehicle came closest."""
    hits, u = [], None
    for r in rows:
        ob, vx, vy = _num(r[col["obstacle_m"]]), _num(r[col["vx"]]), _num(r[col["vy"]])
        if vx is not None and vy is not None and math.hypot(vx, vy) >= HEADING_SPEED:
            u = (vy / math.hypot(vx, vy), vx / math.hypot(vx, vy))  # (east, north) unit vector of travel
        if ob is None or u is None:  # slower (braking, hovering): the last direction travelled
            continue
        pe, pn = float(r[col["y"]]), float(r[col["x"]])
        hits.append((ob, pe, pn, pe + ob * u[0], pn + ob * u[1], u, r))
    if not hits:
        return
    ax.plot([h[3] for h in hits], [h[4] for h in hits], ".", color="black", ms=2.5, alpha=0.6, gid="plan:hits")
    handles.append(Line2D([], [], marker=".", color="black", ls="", label="obstacle hits seen"))
    closest: dict[tuple, tuple] = {}
    for h in hits:
        cell = (round(h[3] / 2.0), round(h[4] / 2.0))
        if cell not in closest or h[0] < closest[cell][0]:
            closest[cell] = h
    shown = sorted(closest.values(), key=lambda h: h[0])[:20]
    for ob, pe, pn, he, hn, u, r in shown:
        r_obst = _num(r[col["r_obst"]]) or 0.0
        e_tr = _num(r[col["e_tr"]]) or 0.0
        ce, cn = he + r_obst * u[0], hn + r_obst * u[1]
        ax.add_patch(Circle((ce, cn), max(r_obst, 0.05), color="dimgrey", alpha=0.5, gid="plan:obstacle"))
        ax.add_patch(Circle((ce, cn), r_obst + e_tr, fill=False, ls="--", color="tab:red", gid="plan:keep_out"))
    ob, pe, pn, he, hn, _, r = shown[0]
    ax.plot([pe, he], [pn, hn], "-", color="tab:purple", lw=1)
    ax.plot(pe, pn, "*", color="tab:purple", ms=14, gid="mark:closest")
    ax.annotate(f"closest {ob:.2f} m at t {float(r[col['t']]):.1f} s", (pe, pn), textcoords="offset points",
                xytext=(8, 8), fontsize="small", color="tab:purple")
    handles += [Patch(color="dimgrey", alpha=0.5, label="obstacle (R_obst) at closest approach"),
                Patch(fill=False, ls="--", ec="tab:red", label="keep-out R_obst + E_tr"),
                Line2D([], [], marker="*", color="tab:purple", ls="", ms=12, label="closest approach")]


def save(fig: Figure, path: Path) -> None:
    fig.savefig(path, dpi=100)
