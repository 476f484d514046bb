"""The avoid table at points nobody chose: the shipped table's `v_safe` at random off-grid points of a wide
envelope (E_tr up to 1.5 m, small columns), against three independent references, and where the lookup
loses speed. One JSON object on stdout.

    PYTHONPATH=. python benchmarks/bench_offgrid.py [--points 10] [--seed 28] [--vehicles mambo,x500]
                                                    [--cache FILE.jsonl] [--rate-limited 10]

References at each point (c = D_od + R_obst, r_k = R_obst + E_tr + r_body):
- `fresh`: a fresh planner bisection with the contract's own model — the reaction time folded as a coast of
  V·(t_react + tilt/rate) (`contracts.sweep.fresh_v_safe`, as `bench_tightness.py`; reused from `--cache`);
- `rate_limited`: the planner with the autopilot's roll/pitch-rate limits, starting level, after a coast of
  V·t_react only (`contracts.sweep.rate_limit_check`): the physical limit of a vehicle that must tilt first
  (its own best speed, or the table's where it verifies a trajectory at the table's speed — a local solver's
  best is a lower bound of the limit; `rate_limited_ok_at_table` says whether the table's speed was flown);
- `instant_tilt`: the contract's planner after a coast of V·t_react only, as if the vehicle were already
  tilted — above what a rate-limited vehicle can fly (a reference that ignores the attitude rate).

And the lookup's own loss in r_k/c: `rho_interp`, the same table column interpolated linearly in log ρ
between its grid points (optimistic: only a measure of what the worst corner in ρ costs), where tilt and
thrust are grid points. Ratio goal: table / rate_limited ≥ 0.95, never above 1.01.

`etr_fixed_point`: what Ω's E_tr fixed point on E_tr_pred's speed grid costs — Ω's V_max against the
fixed point V = v_safe(max(E_tr measured, E_tr_pred(V))) with E_tr_pred interpolated linearly in speed
(optimistic), at Ω's own tilt, over 200 random points (no planner: seconds).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_tightness import fresh_bracket  # noqa: E402

from contracts.sweep import _cell_limits, rate_limit_check, solve_cell  # noqa: E402
from contracts.table import load_for_vehicle  # noqa: E402
from contracts.vehicle import G, load_vehicle  # noqa: E402

NAMED = {"mambo": [(9.1, 0.25, 1.34, 17.0, 0.7)]}  # the worst of the four points the evidence named


def points(veh, n, seed):
    """Random off-grid points: D_od 2–12 m, R_obst 0.1–2 m, E_tr 0–1.5 m, tilt 3°–min(25°, limit), thrust."""
    rng = np.random.default_rng(seed)
    lo, hi = veh.thrust_ratio_range
    for _ in range(n):
        yield (float(rng.uniform(2.0, 12.0)), float(rng.uniform(0.1, 2.0)), float(rng.uniform(0.0, 1.5)),
               float(rng.uniform(3.0, min(25.0, veh.tilt_max_deg))), float(rng.uniform(lo, hi)))


def rho_interp(t, veh, d_od, r_obst, e_tr, tilt, tr):
    """V = √(g·c')·F(r_k/c'), c' = c − V·t_r, with F interpolated in log ρ (grid tilt and thrust only)."""
    rho, tilts, trs = t.avoid.axes
    j = np.flatnonzero(np.isclose(tilts, tilt))
    k = np.flatnonzero(np.isclose(trs, tr))
    if not (len(j) and len(k)):
        return None
    col, t_r = t.avoid.values[:, j[0], k[0]], veh.reaction_time(tilt)
    c0, r_k = d_od + r_obst, r_obst + e_tr + veh.r_body_m
    lo, hi = 0.0, math.sqrt(G * c0) * float(col[0])
    for _ in range(60):  # V − √(g c') F(ρ(V)) is increasing in V
        v = 0.5 * (lo + hi)
        c1 = c0 - v * t_r
        ok = c1 > 0 and r_k / c1 <= rho[-1] and v <= math.sqrt(G * c1) * np.interp(
            math.log(max(r_k / c1, rho[0])), np.log(rho), col)
        lo, hi = (v, hi) if ok else (lo, v)
    return lo


def one(veh, t, point, cache, key, rate_limited):
    d_od, r_obst, e_tr, tilt_deg, tr = point
    tilt = math.radians(tilt_deg)
    row = {"d_od": round(d_od, 3), "r_obst": round(r_obst, 3), "e_tr": round(e_tr, 3), "tilt_deg": round(tilt_deg, 2),
           "thrust_ratio": round(tr, 3), "rho": round((r_obst + e_tr + veh.r_body_m) / (d_od + r_obst), 4)}
    row["table"] = t.v_safe(d_od, r_obst, e_tr, tilt, tr)
    lo, _ = fresh_bracket(veh, (d_od, r_obst, e_tr, tilt, tr), t.tilt_model, cache, key)
    row["fresh"] = lo
    ri = rho_interp(t, veh, d_od, r_obst, e_tr, tilt, tr)
    if ri is not None:
        row["rho_interp"] = ri
    if rate_limited:  # its own best speed, or the table's where it verified a trajectory at that speed
        rl = rate_limit_check(veh, row["table"], d_od, r_obst, e_tr, tilt, tr)
        row["rate_limited_ok_at_table"] = rl["ok"]
        row["rate_limited"] = max(rl["v_rate_limited_max"], row["table"] if rl["ok"] else 0.0)
        lim = _cell_limits(veh, tilt, tr, t.tilt_model)
        c, r_k = d_od + r_obst, r_obst + e_tr + veh.r_body_m
        row["instant_tilt"] = solve_cell(lim, r_k / c, n=40, cpu_time=2.0, starts=3, c=c, lead_time=veh.t_react_s).lo
    if rate_limited and row["rate_limited"] < row["table"] * 0.999:
        # its first interval is held level (w(1) = w_0): a coast of a whole sample time, longer than the tilt
        # time the contract folds in slow manoeuvres — checked again with 3× the intervals
        rl = rate_limit_check(veh, row["table"], d_od, r_obst, e_tr, tilt, tr, n=120, cpu_time=20.0)
        row["rate_limited_40_intervals"] = row["rate_limited"]
        row["rate_limited_ok_at_table"] = rl["ok"]
        row["rate_limited"] = max(rl["v_rate_limited_max"], row["table"] if rl["ok"] else 0.0)
    for ref in ("fresh", "rate_limited", "instant_tilt", "rho_interp"):
        if row.get(ref):
            row[f"table/{ref}"] = round(row["table"] / row[ref], 4)
    return {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}


def summary(rows, ref):
    r = np.array([x[f"table/{ref}"] for x in rows if f"table/{ref}" in x])
    if not len(r):
        return None
    return {"n": int(len(r)), "min": round(float(r.min()), 4), "p5": round(float(np.percentile(r, 5)), 4),
            "median": round(float(np.median(r)), 4), "max": round(float(r.max()), 4),
            "below_0.95": int(np.sum(r < 0.95)), "above_1.01": int(np.sum(r > 1.01))}


def etr_fixed_point(t, veh, n=200, seed=5):
    """Ω's V_max / the fixed point with E_tr_pred interpolated in speed (see the module docstring)."""
    ev, et, er = t.e_pred.axes
    rng = np.random.default_rng(seed)
    r = []
    for _ in range(n):
        d, ro, em = rng.uniform(2.0, 12.0), rng.uniform(0.1, 2.0), rng.uniform(0.0, 0.3)
        tr = rng.uniform(*veh.thrust_ratio_range)
        om = t.omega(d, ro, em, tr, contract="avoid")
        if om.v_max <= 0:
            continue
        col = t.e_pred.values[:, min(np.searchsorted(et, om.tilt), len(et) - 1),
                              max(np.searchsorted(er, tr, side="right") - 1, 0)]
        gap = lambda v: v - t.v_safe(d, ro, max(em, float(np.interp(v, ev, col))), om.tilt, tr)  # noqa: E731
        lo, hi = 0.0, 1.5 * om.v_max
        if gap(hi) < 0:
            continue
        for _ in range(50):
            m = 0.5 * (lo + hi)
            lo, hi = (m, hi) if gap(m) < 0 else (lo, m)
        r.append(om.v_max / lo)
    r = np.array(r)
    return {"n": int(len(r)), "min": round(float(r.min()), 4), "median": round(float(np.median(r)), 4),
            "max": round(float(r.max()), 4), "speed_grid_m_s": [float(ev[0]), float(ev[-1]), int(len(ev))]}


def vehicle_run(name, n, seed, cache, n_rate):
    veh = load_vehicle(name)
    t = load_for_vehicle(veh)
    t0 = time.perf_counter()
    named = [one(veh, t, p, cache, ["offgrid-named", name, list(p)], n_rate > 0) for p in NAMED.get(name, [])]
    rows = []
    for idx, p in enumerate(points(veh, n, seed)):
        rows.append(one(veh, t, p, cache, ["offgrid", name, seed, idx, list(p)], idx < n_rate))
    return {"vehicle": name, "points": n, "seed": seed, "named": named,
            "table/fresh": summary(rows, "fresh"), "table/rate_limited": summary(rows, "rate_limited"),
            "table/instant_tilt": summary(rows, "instant_tilt"), "table/rho_interp": summary(rows, "rho_interp"),
            "etr_fixed_point": etr_fixed_point(t, veh), "rows": rows,
            "wall_s": round(time.perf_counter() - t0, 1)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10)
    ap.add_argument("--seed", type=int, default=28)
    ap.add_argument("--vehicles", default="mambo,x500")
    ap.add_argument("--rate-limited", type=int, default=10, help="points also checked with the rate-limited planner")
    ap.add_argument("--cache", type=Path, default=None, help="JSON-lines file of fresh bisections (reused)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    load = os.getloadavg()[0]
    out = {"benchmark": "offgrid", "goal": {"table/rate_limited": {"min": 0.95, "max": 1.01}},
           "vehicles": [vehicle_run(v, args.points, args.seed, args.cache, args.rate_limited)
                        for v in args.vehicles.split(",")],
           "loadavg_1min": [load, os.getloadavg()[0]], "cpus": os.cpu_count()}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
