"""Avoid-contract performance figures, printed as one JSON object.

    PYTHONPATH=. python benchmarks/bench_contracts.py            # everything (full builds: minutes)
    PYTHONPATH=. python benchmarks/bench_contracts.py --quick    # no full builds

- solve time (CPU s per IPOPT solve incl. dense verification) median/p95, verified (feasible) vs not
  (infeasible or capped at the CPU limit), over the cells of a ρ sweep;
- NLP cells per second of a 16-cell sweep with 1 and with 2 workers (wall clock);
- build wall time of each shipped vehicle's default table with 2 workers (written to a temp dir).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contracts.planner import Limits  # noqa: E402
from contracts.sweep import build_avoid_table, solve_cell  # noqa: E402
from contracts.vehicle import load_vehicle  # noqa: E402


def _stats(x):
    x = np.asarray(x, float)
    if x.size == 0:
        return {"n": 0}
    return {"n": int(x.size), "median_s": round(float(np.median(x)), 4), "p95_s": round(float(np.percentile(x, 95)), 4)}


def solve_times(n_rho=16):
    veh = load_vehicle("mambo")
    lim = Limits.from_vehicle(veh, math.radians(13.0), 1.0)
    feas, infeas = [], []
    warm = None
    for rho in np.geomspace(0.01, 0.95, n_rho):
        r = solve_cell(lim, float(rho), warm=warm)
        warm = (r.w, r.ts, r.lo) if r.branch == "pass" else None
        for _, ok, cpu, _ in r.solves:
            (feas if ok else infeas).append(cpu)
    return {"feasible": _stats(feas), "infeasible": _stats(infeas)}


def cells_per_second(workers, n_rho=16):
    grid = {"rho": {"min": 0.01, "max": 0.95, "n": n_rho, "spacing": "geometric"}, "tilt_deg": [10],
            "thrust_ratio": [1.0]}
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        s = build_avoid_table("mambo", Path(d) / "b.npz", grid=grid, workers=workers, progress=False,
                              partial_grid=True)  # a timing grid, not a table to fly
        wall = time.perf_counter() - t0
    return {"workers": workers, "nlp_cells": s["class_cells"], "wall_s": round(wall, 2),
            "cells_per_s": round(s["class_cells"] / wall, 3)}


def full_build(name, workers=2):
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        s = build_avoid_table(name, Path(d) / f"{name}.npz", workers=workers, progress=False)
        wall = time.perf_counter() - t0
    return {"vehicle": name, "workers": workers, "wall_s": round(wall, 1), "table_cells": s["cells"],
            "nlp_cells": s["class_cells"], "solves": s["solves"], "grid": s["grid"],
            "monotone_repairs": s["monotone_repairs"]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip the full per-vehicle builds")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    out = {"benchmark": "contracts/avoid", "cpu_count": os.cpu_count(),
           "solve_time": solve_times(),
           "throughput": [cells_per_second(1), cells_per_second(2)]}
    if not args.quick:
        out["build"] = [full_build("mambo"), full_build("x500")]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
