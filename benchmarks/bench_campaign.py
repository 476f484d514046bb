"""Campaign throughput as one JSON object: lock-step flights per second per worker, in-process, on a local
process pool and on a Dask `LocalCluster`, and the overhead of each against in-process.

    PYTHONPATH=. python benchmarks/bench_campaign.py [--spec examples/campaign-evidence.yaml] [--flights 40]
                                                     [--workers 1]

The same flights (the spec's first `--flights`) are flown three times into fresh directories; the rows
must be identical (they are compared, `identical`). `flights_per_core_hour` is in-process flights per CPU
hour of this process; `cost_100k_flights_core_hours` projects a 100 000-flight campaign. Wall-clock figures
depend on what else the machine runs; never asserted in tests.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.ground import campaign as cg  # noqa: E402


def _timed(fn):
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spec", default="examples/campaign-evidence.yaml")
    ap.add_argument("--flights", type=int, default=40)
    ap.add_argument("--workers", type=int, default=1, help="pool and Dask workers")
    a = ap.parse_args()
    spec = cg.load_spec(a.spec)
    cg.fly(spec, 0)  # JIT-compile the SITL kernel and warm the caches before timing
    res = {"spec": a.spec, "flights": a.flights, "workers": a.workers, "cpus": os.cpu_count(),
           "python": platform.python_version()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        wall, cpu = _timed(lambda: cg.run(spec, tmp / "inproc", workers=1, progress=False, limit=a.flights))
        res.update(inproc_wall_s=wall, inproc_cpu_s=cpu, flights_per_s_per_worker=a.flights / wall,
                   flights_per_core_hour=3600.0 * a.flights / cpu, cost_100k_flights_core_hours=1e5 * cpu / a.flights / 3600)
        if a.workers > 1:
            wall, _ = _timed(lambda: cg.run(spec, tmp / "pool", workers=a.workers, progress=False, limit=a.flights))
        else:  # a one-worker pool is in-process in contracts/runner.py: measure a real 2-process pool's cost per worker
            wall, _ = _timed(lambda: cg.run(spec, tmp / "pool", workers=2, progress=False, limit=a.flights))
        pool_workers = max(a.workers, 2)
        res.update(pool_workers=pool_workers, pool_wall_s=wall,
                   pool_flights_per_s_per_worker=a.flights / wall / pool_workers)
        from distributed import LocalCluster

        t0 = time.perf_counter()
        with LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
            start = time.perf_counter() - t0
            wall, _ = _timed(lambda: cg.run(spec, tmp / "dask", scheduler=cl.scheduler_address, progress=False,
                                            limit=a.flights))
        res.update(dask_cluster_start_s=start, dask_wall_s=wall,
                   dask_flights_per_s_per_worker=a.flights / wall / a.workers,
                   dask_overhead_per_flight_s=(wall * a.workers - res["inproc_wall_s"]) / a.flights)
        res["pool_overhead_per_flight_s"] = (res["pool_wall_s"] * pool_workers - res["inproc_wall_s"]) / a.flights
        lines = [sorted((tmp / d / "results.jsonl").read_text().splitlines()) for d in ("inproc", "pool", "dask")]
        res["identical"] = lines[0] == lines[1] == lines[2]
    print(json.dumps(res, sort_keys=True))


if __name__ == "__main__":
    main()
