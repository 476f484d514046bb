"""How tight the shipped avoid tables are: the table's answer `v_safe` against a fresh, densely
verified planner bisection (`contracts.sweep.fresh_v_safe`: the offline IPOPT planner with its exact
dense check, the reaction time as a coast) at random off-grid points. One JSON object on stdout.

    PYTHONPATH=. python benchmarks/bench_tightness.py [--points 50] [--seed 18] [--cache FILE.jsonl]

`--cache`: the fresh bisections (which do not depend on the table or its lookup) are appended to a
JSON-lines file as they finish and reused from it by a later run with the same vehicle, seed and point,
so the table's answer can be compared before and after a lookup change against the same references.

Ratio = table / fresh lower bound (≤ 1 is safe-side; goal ≥ 0.95, never above 1.001). A ratio above 1
would mean the table answers faster than any speed the planner verified there: it is listed with the
bracket's upper end (the first speed the planner could not verify), which is what safety is judged by.
Points are drawn where both answer a speed (the fresh bisection's upper end is finite). A point above 1.001
is bisected again with 80 intervals instead of 40 (the coarser planner can verify less than the table's
build did there): `ratio80`, and `above_1.001_after_80_interval_recheck`.
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

from contracts.sweep import fresh_v_safe  # noqa: E402
from contracts.table import load_for_vehicle  # noqa: E402
from contracts.vehicle import load_vehicle  # noqa: E402


def points(veh, n, seed):
    """Random off-grid points inside the table's grid: D_od, R_obst, E_tr, tilt and thrust uniform."""
    rng = np.random.default_rng(seed)
    lo, hi = veh.thrust_ratio_range
    for _ in range(n):
        yield (float(rng.uniform(1.0, 15.0)), float(rng.uniform(0.1, 2.0)), float(rng.uniform(0.0, 1.0)),
               math.radians(float(rng.uniform(3.0, min(25.0, veh.tilt_max_deg)))), float(rng.uniform(lo, hi)))


def _cached(cache, key):
    """The cached (lo, hi) of a fresh bisection, or None."""
    if cache is None or not cache.exists():
        return None
    for line in cache.read_text().splitlines():
        try:
            rec = json.loads(line)
        except ValueError:
            continue  # a line cut short by an interrupted run
        if rec.get("key") == key:
            return rec["lo"], (math.inf if rec["hi"] is None else rec["hi"])
    return None


def fresh_bracket(veh, point, tilt_model, cache, key, n=40):
    """(lo, hi) of the fresh planner bisection at `point` with `n` intervals, from `cache` when it has it."""
    hit = _cached(cache, key)
    if hit is not None:
        return hit
    fresh = fresh_v_safe(veh, *point, tilt_model=tilt_model, n=n)
    if cache is not None:
        with cache.open("a") as fh:
            fh.write(json.dumps({"key": key, "lo": fresh.lo,
                                 "hi": fresh.hi if math.isfinite(fresh.hi) else None}) + "\n")
    return fresh.lo, fresh.hi


def tightness(name, n, seed, cache=None):
    veh = load_vehicle(name)
    t = load_for_vehicle(veh)
    rows, t0 = [], time.perf_counter()
    for idx, (d_od, r_obst, e_tr, tilt, tr) in enumerate(points(veh, n, seed)):
        table = t.v_safe(d_od, r_obst, e_tr, tilt, tr)
        key = [name, seed, idx, [d_od, r_obst, e_tr, tilt, tr]]
        lo, hi = fresh_bracket(veh, (d_od, r_obst, e_tr, tilt, tr), t.tilt_model, cache, key)
        rows.append({"d_od": round(d_od, 3), "r_obst": round(r_obst, 3), "e_tr": round(e_tr, 3),
                     "tilt_deg": round(math.degrees(tilt), 2), "thrust_ratio": round(tr, 3),
                     "table": round(table, 4), "fresh_lo": round(lo, 4), "fresh_hi": hi,
                     "ratio": table / lo if lo > 0 else (1.0 if table == 0 else math.inf)})
        if rows[-1]["ratio"] > 1.001:  # above the 40-interval bracket: bisect again with a finer planner
            lo80, hi80 = fresh_bracket(veh, (d_od, r_obst, e_tr, tilt, tr), t.tilt_model, cache, key + [80], n=80)
            rows[-1].update({"fresh80_lo": round(lo80, 4), "fresh80_hi": hi80,
                             "ratio80": table / lo80 if lo80 > 0 else math.inf})
    r = np.array([x["ratio"] for x in rows])
    r80 = np.array([x.get("ratio80", x["ratio"]) for x in rows])
    worst = sorted(rows, key=lambda x: x["ratio"])
    return {"vehicle": name, "points": n, "seed": seed, "min": round(float(r.min()), 4),
            "median": round(float(np.median(r)), 4), "max": round(float(r.max()), 4),
            "below_0.95": int(np.sum(r < 0.95)), "above_1.001": int(np.sum(r > 1.001)),
            "above_1.001_after_80_interval_recheck": int(np.sum(r80 > 1.001)), "max_after_recheck": round(float(r80.max()), 4),
            "loosest": worst[:3], "highest": worst[-2:], "wall_s": round(time.perf_counter() - t0, 1)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=50)
    ap.add_argument("--seed", type=int, default=18)
    ap.add_argument("--vehicles", default="mambo,x500")
    ap.add_argument("--cache", type=Path, default=None, help="JSON-lines file of fresh bisections (reused)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    load = os.getloadavg()[0]
    out = {"benchmark": "tightness", "goal": {"min": 0.95, "max": 1.001},
           "vehicles": [tightness(v, args.points, args.seed, args.cache) for v in args.vehicles.split(",")],
           "loadavg_1min": [load, os.getloadavg()[0]]}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
