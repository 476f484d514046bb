"""The online avoidance planner: consistency with the avoid contract and replanning time (one JSON object).

1. Consistency: on a seeded sample of avoid-table cells, start at k × V_safe (with the table's
   reaction time) with the obstacle revealed at D_od head-on; success = a verified avoiding plan.
   Reported for k = 0.92, 0.95, 0.97, 1.0 and OFFBOARD_CAP over BENCH_PLANNER_CELLS (default 200)
   cells per vehicle; the notes of the failed cells are counted by cause.
2. Replanning: closed loop at 50 Hz with perfect tracking — every cycle the vehicle moves along the
   plan and the guidance replans as it would in flight (warm-started from the last plan); time per
   replan p50/p95 and how often the exact check rejected a QP plan. Goal: p95 < 20 ms.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.onboard.guidance import OffboardGuidance, Route  # noqa: E402
from contracts.flat import horizontal_accel_limit  # noqa: E402
from contracts.online_planner import OFFBOARD_CAP, AvoidancePlanner, Disc  # noqa: E402
from contracts.table import load_for_vehicle  # noqa: E402
from contracts.vehicle import load_vehicle  # noqa: E402


def cells(vehicle, n, seed):
    veh = load_vehicle(vehicle)
    t = load_for_vehicle(veh)
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        d_od, r_obst = rng.uniform(1, 15), rng.uniform(0.1, 2)
        tilt, tr = math.radians(rng.uniform(3, 25)), rng.uniform(*veh.thrust_ratio_range)
        v = t.v_safe(d_od, r_obst, 0.0, tilt, tr)
        if v > 0.1:
            out.append((veh, d_od, r_obst, tilt, tr, v))
    return out


def consistency(vehicle, k, n=200, seed=0):
    pl = AvoidancePlanner()
    ok, times, causes = 0, [], {}
    for veh, d_od, r_obst, tilt, tr, v in cells(vehicle, n, seed):
        a = horizontal_accel_limit(tilt, veh.t_max(tr), veh.mass_kg)
        v *= k
        t0 = time.perf_counter()
        plan = pl.plan([v * veh.reaction_time(tilt), 0], [v, 0], [1, 0], [Disc(d_od + r_obst, 0, r_obst + veh.r_body_m)],
                       v_max=v, a_max=a)
        times.append(time.perf_counter() - t0)
        ok += plan.ok
        if not plan.ok:
            why = "; ".join(plan.notes)[:160] or plan.kind
            causes[why] = causes.get(why, 0) + 1
    return {"k": k, "cells": n, "success": ok, "rate": ok / n, "cold_plan_ms_p50": 1e3 * float(np.median(times)),
            "cold_plan_ms_p95": 1e3 * float(np.percentile(times, 95)), "failures": causes}


def replanning(vehicle="mambo", n=20, seed=1):
    times, rejected, replans = [], 0, 0
    for veh, d_od, r_obst, tilt, tr, v in cells(vehicle, n, seed):
        a = horizontal_accel_limit(tilt, veh.t_max(tr), veh.mass_kg)
        v *= OFFBOARD_CAP
        g = OffboardGuidance(Route([[0, 0], [d_od + 10 * r_obst + 30, 0]], 2.0))
        p, vel = np.array([v * veh.reaction_time(tilt), 0.0]), np.array([v, 0.0])
        g.start(p, vel)
        disc = [Disc(d_od + r_obst, 0.0, r_obst + veh.r_body_m)]
        t = 0.0
        for _ in range(150):  # 3 s at 50 Hz, the vehicle following its setpoints exactly
            sp = g.step(t, 0.02, p, vel, v, a, disc)
            p, vel = sp.p.copy(), sp.v.copy()
            t += 0.02
        times += g.plan_times
        rejected += g.rejected
        replans += g.replans
    return {"replans": replans, "replan_ms_p50": 1e3 * float(np.median(times)),
            "replan_ms_p95": 1e3 * float(np.percentile(times, 95)), "qp_plans_rejected_by_exact_check": rejected}


def main():
    n = int(os.environ.get("BENCH_PLANNER_CELLS", "200"))
    ks = sorted({0.92, 0.95, 0.97, 1.0, OFFBOARD_CAP})
    out = {"benchmark": "planner", "offboard_cap": OFFBOARD_CAP, "loadavg_1min": [os.getloadavg()[0]]}
    for vehicle in ("mambo", "x500"):
        out[vehicle] = {f"consistency_at_{k:g}": consistency(vehicle, k, n) for k in ks}
    out["replanning_mambo"] = replanning()
    out["goal"] = {"replan_ms_p95": 20, "rate_at_0.97": 1.0}
    out["loadavg_1min"].append(os.getloadavg()[0])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
