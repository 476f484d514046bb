"""Which manoeuvres the shipped controller contract does not cover: at a seeded sample of
E_tr_pred grid cells, fly every manoeuvre of the sweep (`sitl_harness.etr_sweep.cell_references`: cruise,
speed steps, the avoid table's limiting trajectories, the online planner's plans, and the new
``failsafe@ρ`` — the daemon's braking stop mid-swerve — and ``drop@ρ`` — a plan made at the top thrust's
acceleration flown at the cell's thrust) with the build's seeds, and compare each manoeuvre's worst
contour error, with the build's margin, against the shipped E_tr_pred of that cell. One JSON object.

    PYTHONPATH=. python benchmarks/bench_etr_maneuvers.py [--cells 6] [--seed 9]

`covered` is false where worst·(1 + MARGIN_REL) + MARGIN_ABS exceeds the shipped value: a manoeuvre
the daemon flies that the shipped controller contract does not bound.
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

from contracts.table import shipped_table, verify  # noqa: E402
from contracts.vehicle import load_vehicle  # noqa: E402
from sitl_harness import etr_sweep as es  # noqa: E402
from sitl_harness.maneuvers import worst_contour_error  # noqa: E402


def cells(name, n, seed):
    veh = load_vehicle(name)
    path = shipped_table(name)
    t = verify(path, veh)
    v, tilt, tr = t.e_pred.axes
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        i, j, k = int(rng.integers(len(v) // 2, len(v))), int(rng.integers(len(tilt))), int(rng.integers(len(tr)))
        out.append((veh, path, t, i, j, k))
    return out


def measure(name, n, seed):
    rows = []
    for veh, path, t, i, j, k in cells(name, n, seed):
        v, tilt, tr = (float(a[x]) for a, x in zip(t.e_pred.axes, (i, j, k)))
        shipped = float(t.e_pred.values[i, j, k])
        t0 = time.perf_counter()
        refs = es.cell_references(str(path), veh, v, tilt, tr, es._avoid_index(t, tilt, tr), es.BUILD_RHOS, [])
        per = {}
        for ref in refs:
            kind = ref.name.split("@")[0]
            for s in es.BUILD_SEEDS:
                per[kind] = max(per.get(kind, 0.0), worst_contour_error(veh, ref, tr, s))
        with_margin = {m: e * (1 + es.MARGIN_REL) + es.MARGIN_ABS for m, e in per.items()}
        rows.append({"v": v, "tilt_deg": round(math.degrees(tilt), 2), "thrust_ratio": tr, "shipped_e_tr_pred": shipped,
                     "worst_m": {m: round(e, 4) for m, e in per.items()},
                     "with_margin_m": {m: round(e, 4) for m, e in with_margin.items()},
                     "not_covered": sorted(m for m, e in with_margin.items() if e > shipped + 1e-9),
                     "wall_s": round(time.perf_counter() - t0, 1)})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=6)
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--vehicles", default="mambo,x500")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    load = os.getloadavg()[0]
    out = {"benchmark": "etr_maneuvers", "margin": {"relative": es.MARGIN_REL, "absolute_m": es.MARGIN_ABS},
           "offboard_cap_flown": es.OFFBOARD_CAP}
    for name in args.vehicles.split(","):
        rows = measure(name, args.cells, args.seed)
        out[name] = {"cells": rows, "not_covered_count": {m: sum(m in r["not_covered"] for r in rows)
                                                          for m in es.MANEUVERS}}
    out["loadavg_1min"] = [load, os.getloadavg()[0]]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
