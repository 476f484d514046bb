"""Lookup and Ω-selection time per call (one JSON object on stdout).

Goal: Ω and v_safe median ≤ 20 µs, p99 ≤ 200 µs at low load (the first goal was 50 µs / 1 ms).
`v_safe` at tilt 0.2 rad (between grid tilts) and `v_safe_any_tilt` at random tilts 3°–tilt_max (the law's row
between grid points). Uses the shipped table if it carries the avoid contract,
otherwise a synthetic avoid + E_tr_pred table of the shipped tables' size on the same vehicle.
Records the 1-minute load average before and after: on a shared machine the figures move with it; the
`cpu_` figures (the thread's CPU time per call) move less. Ω avoid runs the compiled kernel where numba can
JIT (`omega_kernel`); `omega_avoid_numpy_path` is the same queries on the numpy path (a process without a JIT,
such as the service unit with MemoryDenyWriteExecute=yes).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import contracts.lookup as lookup  # noqa: E402
from contracts.lookup import repair_monotone  # noqa: E402
from contracts.table import SLOTS, Slot, load_for_vehicle, verify, write_table  # noqa: E402
from contracts.vehicle import load_vehicle  # noqa: E402


def synthetic(vehicle, path):
    rng = np.random.default_rng(0)
    rho = np.linspace(0.02, 0.95, 40)
    tilt = np.radians(np.arange(3.0, 25.01, 2.0))
    tr = np.linspace(*vehicle.thrust_ratio_range, 5)
    f, _ = repair_monotone(rng.uniform(0, 1.5, (40, len(tilt), 5)), SLOTS["avoid"][2], "down")
    vg = np.linspace(0.5, 12.0, 16)
    e, _ = repair_monotone(rng.uniform(0, 1.0, (16, len(tilt), 5)), SLOTS["e_tr_pred"][2], "up")
    write_table(path, vehicle, avoid=Slot((rho, tilt, tr), f), e_tr_pred=Slot((vg, tilt, tr), e))
    return verify(path, vehicle)


def timed(fn, queries):
    """Wall time per call, then (a second pass) the thread's CPU time per call: on a loaded machine the
    wall figures include waits for a core, the CPU figures do not."""
    res = {}
    for key, clock in (("", time.perf_counter_ns), ("cpu_", time.thread_time_ns)):
        out = []
        for q in queries:
            t0 = clock()
            fn(*q)
            out.append((clock() - t0) / 1e3)
        a = np.array(out)
        res.update({f"{key}median_us": float(np.median(a)), f"{key}p99_us": float(np.percentile(a, 99))})
    return {**res, "calls": len(queries)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="mambo")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()[0]
    vehicle = load_vehicle(args.vehicle)
    t = load_for_vehicle(vehicle)
    source = "shipped"
    if t.avoid is None or t.e_pred is None:
        t = synthetic(vehicle, Path(tempfile.mkdtemp()) / "synthetic.npz")
        source = "synthetic (shipped table lacks avoid or e_tr_pred)"
    rng = np.random.default_rng(1)
    n = 20000
    qs = np.column_stack([rng.uniform(0, 16, n), rng.uniform(0.1, 2, n), rng.uniform(0, 1.5, n),
                          rng.uniform(*vehicle.thrust_ratio_range, n)]).tolist()
    tilts = np.radians(rng.uniform(3.0, vehicle.tilt_max_deg, n)).tolist()
    qt = [q + [x] for q, x in zip(qs, tilts)]
    for q in qs[:200]:  # warm-up
        t.omega(*q)
    res = {
        "benchmark": "lookup",
        "table": source,
        "vehicle": vehicle.name,
        "v_safe": timed(lambda d, r, e, k: t.v_safe(d, r, e, 0.2, k), qs),
        "v_safe_any_tilt": timed(lambda d, r, e, k, x: t.v_safe(d, r, e, x, k), qt),
        "omega_avoid": timed(lambda d, r, e, k: t.omega(d, r, e, k, "avoid"), qs),
        "omega_stop": timed(lambda d, r, e, k: t.omega(d, r, e, k, "stop"), qs),
        "omega_kernel": lookup.kernel_name(),
        "goal": {"median_us": 20, "p99_us": 200},
        "loadavg_1min": [load_before, os.getloadavg()[0]],
    }
    if lookup.USE_KERNEL:  # the same queries on the numpy path: what a process without a JIT (the service unit) runs
        lookup.USE_KERNEL = False
        res["omega_avoid_numpy_path"] = timed(lambda d, r, e, k: t.omega(d, r, e, k, "avoid"), qs)
        lookup.USE_KERNEL = True
        res["loadavg_1min"][1] = os.getloadavg()[0]
    print(json.dumps(res))


if __name__ == "__main__":
    main()
