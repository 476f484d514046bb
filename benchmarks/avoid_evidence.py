"""Evidence for the avoid contract, printed as one JSON object.

    PYTHONPATH=. python benchmarks/avoid_evidence.py [--cells 50] [--rebuild-box]

- tightness: F_table / F_estimate at seeded random cells of each shipped table, the estimate being the
  best "full brake + full lateral" open-loop policy simulated finely (`contracts.avoid_limit`);
- the paper's three demonstration scenarios (Figures 14–16) answered by the shipped cone table, by a
  small box-model table (`contracts/data/mambo_box_paper.npz`, built here if missing), and by fresh
  planner solves in the paper's own setting (box model, no reaction time, no body radius).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contracts.avoid_limit import policy_limit_f  # noqa: E402
from contracts.flat import horizontal_accel_limit  # noqa: E402
from contracts.planner import Limits  # noqa: E402
from contracts.sweep import build_avoid_table, solve_cell  # noqa: E402
from contracts.table import load_for_vehicle, verify  # noqa: E402
from contracts.vehicle import DATA_DIR, G, load_vehicle  # noqa: E402

SCENARIOS = [  # thrust_ratio, d_od, r_obst, e_tr, tilt_deg, the paper's V_max
    (0.6, 6.0, 1.0, 0.85, 7.03, 4.09),
    (0.8, 6.0, 0.3, 0.75, 9.0, 5.29),
    (1.0, 3.0, 0.6, 0.24, 9.0, 2.93),
]
BOX_GRID = {"rho": {"min": 0.03, "max": 0.95, "n": 60, "spacing": "geometric"},
            "tilt_deg": [5.0, 7.03, 9.0, 13.0], "thrust_ratio": [0.6, 0.8, 1.0]}
BOX_TABLE = DATA_DIR / "mambo_box_paper.npz"


def tightness(name, n_cells, seed=4):
    veh = load_vehicle(name)
    t = load_for_vehicle(veh)
    rho, tilt, tr = t.avoid.axes
    rng = np.random.default_rng(seed)
    r = []
    for _ in range(n_cells):
        i, j, k = rng.integers(len(rho)), rng.integers(len(tilt)), rng.integers(len(tr))
        a_g = horizontal_accel_limit(tilt[j], veh.t_max(tr[k]), veh.mass_kg) / G
        r.append(float(t.avoid.values[i, j, k] / policy_limit_f(rho[i], a_g)))
    r = np.array(r)
    return {"vehicle": name, "cells": n_cells, "seed": seed, "min": round(r.min(), 5),
            "p5": round(float(np.percentile(r, 5)), 5), "median": round(float(np.median(r)), 5),
            "max": round(r.max(), 5), "above_1.001": int(np.sum(r > 1.001))}


def scenarios(rebuild_box=False):
    veh = load_vehicle("mambo")
    if rebuild_box or not BOX_TABLE.exists():
        build_avoid_table(veh, BOX_TABLE, grid=BOX_GRID, workers=2, tilt_model="box", progress=False,
                          partial_grid=True)  # the paper's tilts, for its figures
    cone = load_for_vehicle(veh)
    box = verify(BOX_TABLE, veh)
    rows = []
    for tr, d, ro, e, td, paper in SCENARIOS:
        tilt = math.radians(td)
        row = {"thrust_ratio": tr, "d_od": d, "r_obst": ro, "e_tr": e, "tilt_deg": td, "paper_v_max": paper,
               "cone_table": round(cone.v_safe(d, ro, e, tilt, tr), 3),
               "box_table": round(box.v_safe(d, ro, e, tilt, tr), 3)}
        c, rk = d + ro, ro + e  # the paper's own setting: no reaction time, no body radius
        for model in ("box", "cone"):
            lim = Limits.from_vehicle(veh, tilt, tr, tilt_model=model)
            res = solve_cell(lim, rk / c, c=c, cpu_time=2.0)
            row[f"{model}_planner_no_react_no_body"] = round(res.lo, 3)
        res = solve_cell(Limits.from_vehicle(veh, tilt, tr, tilt_model="box"), (rk + veh.r_body_m) / c, c=c,
                         cpu_time=2.0, lead_time=veh.reaction_time(tilt))
        row["box_planner_exact_point"] = round(res.lo, 3)
        rows.append(row)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=50)
    ap.add_argument("--rebuild-box", action="store_true")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    out = {"tightness": [tightness(n, args.cells) for n in ("mambo", "x500")], "paper_scenarios": scenarios(args.rebuild_box)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
