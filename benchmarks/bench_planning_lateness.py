"""The loop's lateness while the avoidance planner works beside it: a 50 Hz loop (as the daemon's) that keeps one
planning job running (a real `AvoidancePlanner` job round a column ahead, replanned as soon as the last is done) on a
worker thread (`ThreadedPlanning`) or in a worker process (`ProcessPlanning`), and times its own cycles as the daemon
judges them (companion/onboard/estimators.py `Timeliness`: lateness beyond one period). One JSON object.

`BENCH_BUSY=N` (default 2) busy processes (`while True: pass`) run beside it for the whole run, stopped afterwards;
`BENCH_PLANNING_S` (default 20) seconds per runner, each runner measured twice, alternating. On a thread, the
planner's own Python work holds the interpreter lock; when the host deschedules it there, the loop waits.
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.onboard.guidance import ProcessPlanning, ThreadedPlanning  # noqa: E402
from contracts.online_planner import AvoidancePlanner, Disc  # noqa: E402

SECONDS = float(os.environ.get("BENCH_PLANNING_S", "20"))
PERIOD_S = 0.02
A_MAX = 9.81 * math.tan(math.radians(25.0))


def busy() -> None:
    while True:
        pass


def loop(runner, seconds: float) -> dict:
    """The loop with `runner` planning beside it; its cycles' lateness [ms] and how many plans were made."""
    planner = AvoidancePlanner()
    starts, plans, k = [], 0, 0
    t_end = time.monotonic() + seconds
    nxt = time.monotonic()
    while time.monotonic() < t_end:
        starts.append(time.monotonic())
        if runner.poll() is not None:
            plans += 1
        if not runner.busy:
            k += 1
            y = 0.3 * math.sin(k)  # a slightly different column each time: no two jobs alike
            runner.submit(planner, k, 0.0, None, np.array([0.0, 0.0]), np.array([4.0, 0.0]), np.array([1.0, 0.0]),
                          [Disc(7.3, y, 1.3)], v_max=4.0, a_max=A_MAX, budget_s=runner.budget_s)
        nxt += PERIOD_S
        delay = nxt - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            nxt = time.monotonic()
    late = np.maximum(np.diff(starts) - PERIOD_S, 0.0) * 1e3
    return {"cycles": int(late.size), "plans": plans, "p50": float(np.percentile(late, 50)),
            "p99": float(np.percentile(late, 99)), "p99_9": float(np.percentile(late, 99.9)), "max": float(late.max()),
            "beyond_20ms": int(np.sum(late > 20.0))}


def main() -> None:
    busies = [mp.Process(target=busy, daemon=True) for _ in range(int(os.environ.get("BENCH_BUSY", "2")))]
    for b in busies:
        b.start()
    runners = {"thread": ThreadedPlanning(), "process": ProcessPlanning()}
    time.sleep(2.0)  # the planning process started and its solver loaded
    load = os.getloadavg()[0]
    out: dict = {name: [] for name in runners}
    try:
        for _ in range(2):
            for name, runner in runners.items():
                out[name].append(loop(runner, SECONDS))
                while runner.busy:
                    time.sleep(0.01)
                runner.poll()
    finally:
        for runner in runners.values():
            runner.close()
        for b in busies:
            b.terminate()
            b.join(5)
    print(json.dumps({"benchmark": "planning_lateness", "busy_processes": len(busies), "seconds_per_run": SECONDS,
                      "loop_hz": 1 / PERIOD_S, "load_average_1min": round(load, 2), "cpu_count": os.cpu_count(),
                      "cycle_lateness_ms": out}))


if __name__ == "__main__":
    main()
