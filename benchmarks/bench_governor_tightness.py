"""How tight the governor's V_max is: the table's stop-contract answer against the same braking model's
limit found by flying approach histories, on a grid of 960 points per vehicle (D_od 3–12 m, R_obst 0.5–2 m,
E_tr 0.1–0.8 m, thrust 0.7–1.0). One JSON object on stdout.

    PYTHONPATH=. python benchmarks/bench_governor_tightness.py [--vehicles mambo,x500]

The limit at a point is the largest limit speed v from which every Hold on every history stops short of the
keep-out disc's near edge d_od − E_tr − r_body (DESIGN.md §2): histories flown at piecewise-constant jerk under v
(speed steps up from a lower cruise, with or without an acceleration plateau at a; dips — slowing and recovering),
a Hold commanded every 5 ms of them, the dead time flown on the history, then the stop from the state reached
(`braking_distance_from`, checked against a time-stepped stop in tests/test_stop_from_acceleration.py). The
histories and Hold times are sampled, so the limit can only come out high (the ratio low).

Ratios: `v_max` (Ω of the stop contract: e_tr = max(E_tr, E_tr_pred(V_max))) and `v_stop` (the stop contract at
the grid's E_tr, no E_tr_pred) over the limit. Goal: v_max ≥ 0.95 of the limit at every point, never above 1.
To compare with the code before a change, run this file with PYTHONPATH pointing at an export of the old tree.

`--governor-etr`: also `v_max_governor_etr`, Ω with E_tr_pred replaced at the vehicle's tilt limit (the tilt the
stop contract brakes at) by the governor's surface (`sitl_harness.etr_sweep.governor_surface`:
cruise, speed steps and the autopilot's Hold, the build's seeds and margin) flown here on the shipped speed and
thrust axes — what a table carrying that surface answers (the shipped tables carry it: their `e_tr_pred_stop` slot,
which the plain run uses).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.environ.get("PYTHONPATH", "").split(os.pathsep)[0] or str(Path(__file__).resolve().parents[1]))

from contracts.stop import braking_decel, braking_distance_from, stop_dead_time  # noqa: E402
from contracts.table import ContractTable, Slot, load_for_vehicle  # noqa: E402

D_OD = np.linspace(3.0, 12.0, 10)
R_OBST = (0.5, 1.0, 1.5, 2.0)
E_TR = np.linspace(0.1, 0.8, 6)
THRUST = (0.7, 0.8, 0.9, 1.0)
DT, HOLD_EVERY = 1e-3, 5


def fly(segments, v_top):
    """Speed and position along a history of (jerk, seconds) segments, integrated exactly and shifted so that its
    fastest speed is v_top (the segments are whole steps: the history never exceeds the limit)."""
    jerk = np.concatenate([np.full(int(round(s / DT)), jk) for jk, s in segments])
    acc = np.concatenate([[0.0], np.cumsum(jerk * DT)])
    v = np.concatenate([[0.0], np.cumsum(acc[:-1] * DT + jerk * DT**2 / 2)])
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * DT + acc[:-1] * DT**2 / 2 + jerk * DT**3 / 6)])
    shift = v_top - v.max()
    return x + shift * DT * np.arange(len(x)), v + shift, acc


def histories(v, a, j, t_r, n=24):
    """Approach histories under the limit v (speed never above it, |acceleration| ≤ a, |jerk| ≤ j)."""
    top = min(a, np.sqrt(j * v))  # a speed step of α²/j from cruise, or a dip to v − α²/(2j) and back
    for alpha in np.linspace(0.0, top, n)[1:]:
        yield fly([(0.0, t_r), (j, alpha / j), (-j, alpha / j), (0.0, t_r)], v)
        yield fly([(0.0, t_r), (-j, alpha / j), (j, 2 * alpha / j), (-j, alpha / j), (0.0, t_r)], v)
    if v > a * a / j:  # steps larger than a²/j: an acceleration plateau at a
        for plateau in np.linspace(0.0, (v - a * a / j) / a, 5)[1:]:
            yield fly([(0.0, t_r), (j, a / j), (0.0, plateau), (-j, a / j), (0.0, t_r)], v)


def worst_stop(v, a, j, t_r):
    """The longest dead time plus stop over the histories' Holds."""
    m, worst = int(round(t_r / DT)), v * t_r + braking_distance_from(v, 0.0, a, j)  # cruise at v
    for x, vel, acc in histories(v, a, j, t_r):
        for k in range(0, len(x) - m, HOLD_EVERY):
            worst = max(worst, x[k + m] - x[k] + braking_distance_from(vel[k + m], acc[k + m], a, j))
    return worst


def limit(d_avail, a, j, t_r, guess):
    """The largest v with worst_stop(v) ≤ d_avail (a bisection bracketed about `guess`, to 1e-4 relative)."""
    lo, hi = 0.9 * guess, 1.1 * guess
    while worst_stop(lo, a, j, t_r) > d_avail:
        lo, hi = 0.9 * lo, lo
    while worst_stop(hi, a, j, t_r) <= d_avail:
        lo, hi = hi, 1.1 * hi
    while hi - lo > 1e-4 * lo:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if worst_stop(mid, a, j, t_r) <= d_avail else (lo, mid)
    return lo


def _stats(x):
    return {"median": round(float(np.median(x)), 4), "min": round(float(np.min(x)), 4), "max": round(float(np.max(x)), 4)}


def governor_table(t):
    """The table's stop contract with the governor's E_tr_pred flown at the vehicle's tilt limit (other tilts kept)."""
    from sitl_harness.etr_sweep import BUILD_SEEDS, EtrGrid, governor_surface

    v, tilts, trs = t.e_pred.axes
    col = int(np.searchsorted(tilts, t.vehicle.tilt_max - 1e-9))
    e, _, _ = governor_surface(t.vehicle, EtrGrid(v=v, tilt=tilts[col:col + 1], thrust_ratio=trs, seeds=BUILD_SEEDS),
                               workers=1, progress=False)
    values = t.e_pred.values.copy()
    values[:, col, :] = e[:, 0, :]
    return ContractTable(t.meta, t.vehicle, None, Slot(t.e_pred.axes, values), t.path)


def tightness(name, governor_etr=False):
    t = load_for_vehicle(name)
    veh, t0 = t.vehicle, time.perf_counter()
    tg = governor_table(t) if governor_etr else None
    j, t_r, cache, rows = veh.braking.jerk_max_m_s3, stop_dead_time(veh), {}, []
    for d_od in D_OD:
        for e_tr in E_TR:
            for thrust in THRUST:
                a = braking_decel(veh, thrust)
                key = (round(float(d_od - e_tr), 9), a)
                v_stop = [t.v_stop(float(d_od), r, float(e_tr), thrust) for r in R_OBST]
                if key not in cache:
                    cache[key] = limit(float(d_od - e_tr) - veh.r_body_m, a, j, t_r, max(v_stop[0], 0.1))
                for r, vs in zip(R_OBST, v_stop):
                    om = t.omega(float(d_od), r, float(e_tr), thrust, "stop")
                    og = tg.omega(float(d_od), r, float(e_tr), thrust, "stop").v_max if tg is not None else np.nan
                    rows.append((om.v_max / cache[key], vs / cache[key], og / cache[key]))
    r = np.array(rows)
    out = {"vehicle": name, "points": len(rows), "v_max/limit": _stats(r[:, 0]), "v_stop/limit": _stats(r[:, 1]),
           "v_max_below_0.95": int(np.sum(r[:, 0] < 0.95)), "above_1": int(np.sum(r[:, :2] > 1.0))}
    if tg is not None:
        out |= {"v_max_governor_etr/limit": _stats(r[:, 2]), "v_max_governor_etr_below_0.95": int(np.sum(r[:, 2] < 0.95))}
    return out | {"wall_s": round(time.perf_counter() - t0, 1)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", default="mambo,x500")
    ap.add_argument("--governor-etr", action="store_true", help="also V_max with the governor's E_tr_pred (flown here)")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0]
    out = {"benchmark": "governor_tightness", "goal": {"min": 0.95, "max": 1.0},
           "vehicles": [tightness(v, args.governor_etr) for v in args.vehicles.split(",")], "loadavg_1min": [load, os.getloadavg()[0]]}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
