"""Issue 15 evidence: a "real aircraft" that differs from its vehicle file (the X500 with its position- and
velocity-loop gains × GAIN, wind WIND m/s against the file's 3 m/s) flies the calibration plan in the
lock-step SITL (both personalities, .tlog as a ground station writes it); `calibrate` builds its table;
held-out flights (a zig-zag mission at 3, 5, 7 m/s, other seeds) are scored window by window: measured
contour error / E_tr_pred(v, tilt, thrust_ratio) of the calibrated and of the stock table. Prints JSON.

    PYTHONPATH=. python benchmarks/calibrate_evidence.py [--gain 0.6] [--wind 5] [--seeds 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.calibrate import calibrate, read_log, trace_of
from companion.calibrate_plan import speed_ladder, write_plan_files
from contracts import calibrate as cal
from contracts.table import load_for_vehicle, verify
from contracts.vehicle import load_vehicle
from tests.calibration_flights import fly_calibration, heldout_plan, truth_vehicle


def scores(tlog: Path, tables: dict) -> dict:
    feed, cmds = read_log(tlog)
    tr = trace_of(tlog.name, feed, cmds)
    w = cal.windows(tr.t, tr.xy, np.hypot(tr.vel[:, 0], tr.vel[:, 1]), tr.tilt, tr.t_path, tr.xy_path, tr.airborne)
    ratio_tr = tr.hover.get("median")
    out = {"windows": len(w.e), "e_max_m": float(np.max(w.e)) if len(w.e) else None}
    for name, t in tables.items():
        k = min(1.0, t.vehicle.controller.thr_hover / ratio_tr) if ratio_tr else 0.7
        pred = np.array([t.e_tr_pred(v, ti, k) for v, ti in zip(w.v, w.tilt)])
        fin = np.isfinite(pred)
        r = w.e[fin] / pred[fin]
        out[name] = {"worst_ratio": float(np.max(r)) if len(r) else None,
                     "median_ratio": float(np.median(r)) if len(r) else None,
                     "windows_over_1": int(np.count_nonzero(r > 1.0)), "windows_no_bound": int(np.count_nonzero(~fin))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gain", type=float, default=0.6)
    ap.add_argument("--wind", type=float, default=5.0)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("/tmp/calibrate-evidence"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    veh = load_vehicle("x500")
    stock = load_for_vehicle(veh)
    truth = truth_vehicle("x500", a.gain)
    plan = write_plan_files(veh, a.out / "plan", speed_ladder(float(stock.e_pred.axes[0][-1]), stock.e_pred.axes[0]))
    t0 = time.process_time()
    logs, flights = [], []
    for pers, f in (("px4", plan["plan"]), ("ardupilot", plan["waypoints"])):
        tlog = a.out / f"calibration-{pers}.tlog"
        flights.append({"personality": pers, **fly_calibration(Path(f), tlog, truth=truth, personality=pers, seed=0,
                                                               wind_m_s=a.wind)})
        logs.append(tlog)
    fly_cpu = time.process_time() - t0
    t1 = time.process_time()
    summary = calibrate(logs, veh, stock, a.out / "calibrated.npz")
    cal_cpu = time.process_time() - t1
    new = verify(a.out / "calibrated.npz")
    held = heldout_plan(a.out / "heldout.plan")
    rows = []
    for pers in ("px4", "ardupilot"):
        for seed in range(1, a.seeds + 1):
            tlog = a.out / f"heldout-{pers}-{seed}.tlog"
            fly_calibration(held, tlog, truth=truth, personality=pers, seed=seed, wind_m_s=a.wind, max_s=300)
            rows.append({"personality": pers, "seed": seed, **scores(tlog, {"calibrated": new, "stock": stock})})
    res = {"gain": a.gain, "wind_m_s": a.wind, "calibration_flights": flights, "fly_cpu_s": fly_cpu,
           "calibrate_cpu_s": cal_cpu, "coverage": summary["coverage"],
           "ratio_measured_over_predicted": summary["ratio_measured_over_predicted"],
           "braking": summary["braking"]["calibrated"], "v_max": summary["v_max"], "findings": summary["findings"],
           "heldout": rows,
           "worst_ratio_calibrated": max(r["calibrated"]["worst_ratio"] for r in rows),
           "median_ratio_calibrated": float(np.median([r["calibrated"]["median_ratio"] for r in rows])),
           "worst_ratio_stock": max(r["stock"]["worst_ratio"] for r in rows)}
    (a.out / "evidence.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res))


if __name__ == "__main__":
    main()
