"""`calibrate`'s cost per flight-hour of logs (JSON): reads, windows and calibrates the given logs (or a
lock-step calibration flight it flies first), reporting CPU and wall time per hour of logged flight.

    PYTHONPATH=. python benchmarks/bench_calibrate.py [LOG ...]
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.ground.calibrate import calibrate
from contracts.table import load_for_vehicle
from contracts.vehicle import load_vehicle


def main() -> None:
    logs = [Path(p) for p in sys.argv[1:]]
    tmp = Path(tempfile.mkdtemp(prefix="bench-calibrate-"))
    veh = load_vehicle("x500")
    table = load_for_vehicle(veh)
    if not logs:
        from companion.ground.calibrate_plan import speed_ladder, write_plan_files
        from tests.calibration_flights import fly_calibration

        info = write_plan_files(veh, tmp / "plan", speed_ladder(8.0, table.e_pred.axes[0]))
        fly_calibration(Path(info["plan"]), tmp / "px4.tlog", max_s=7200.0)  # the whole plan (~30 min)
        logs = [tmp / "px4.tlog"]
    c0, w0 = time.process_time(), time.perf_counter()
    s = calibrate(logs, veh, table, tmp / "new.npz")
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    hours = sum(lg.get("span_s", 0.0) for lg in s["logs"]) / 3600.0
    print(json.dumps({"logs": [str(p) for p in logs], "flight_hours": hours, "cpu_s": cpu, "wall_s": wall,
                      "cpu_s_per_flight_hour": cpu / hours if hours else None,
                      "wall_s_per_flight_hour": wall / hours if hours else None, "samples": s["samples"]}))


if __name__ == "__main__":
    main()
