"""Time of one analytical V_max(D_od) curve (collision sets eq. 21–26 + lines eq. 28), one JSON object.

    PYTHONPATH=. python benchmarks/bench_collision_sets.py [--repeat 5] [--ts 0.02]

One curve = the sets of one square (propagation with an HiGHS LP per step until the first empty set),
its head-on lines, and V_max at 1001 points of D_od ∈ [0, 10] m. Goal: < 1 s.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contracts.collision_sets import TS_DEFAULT, analytical_square_curve, input_vertices  # noqa: E402


def one_curve(side: float, tilt: float, ts: float) -> tuple[float, int]:
    t0 = time.perf_counter()
    lines = analytical_square_curve(side, input_vertices(tilt, "box"), ts)
    lines.v_max(np.linspace(0.0, 10.0, 1001))
    return time.perf_counter() - t0, len(lines.c11)


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--ts", type=float, default=TS_DEFAULT)
    a = p.parse_args(argv)
    out = {"benchmark": "collision_sets_curve", "ts_s": a.ts, "d_od_points": 1001, "d_od_max_m": 10.0,
           "goal_s": 1.0, "cases": []}
    for tilt_deg in (5.0, 13.0):
        for name, side in (("inscribed", math.sqrt(2.0)), ("circumscribed", 2.0)):
            times, n_sets = [], 0
            for _ in range(a.repeat):
                dt, n_sets = one_curve(side, math.radians(tilt_deg), a.ts)
                times.append(dt)
            out["cases"].append({"tilt_deg": tilt_deg, "square": name, "sets": n_sets, "lps": n_sets + 1,
                                 "median_s": round(float(np.median(times)), 4), "max_s": round(max(times), 4)})
    out["worst_median_s"] = max(c["median_s"] for c in out["cases"])
    out["meets_goal"] = out["worst_median_s"] < out["goal_s"]
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
