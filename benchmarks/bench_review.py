"""Review time per flight-hour and peak memory for each raw-log format (issue 14; goal: a 20-minute log in
under 10 s and under 1 GiB). Prints one JSON object.

    python benchmarks/bench_review.py [--minutes 20]

The DataFlash log is written by the harness's writer (a straight flight at the DataFlash rates of
`tests/test_flight_logs.py`, 50 Hz EKF/attitude/controller, rangefinder); the ULog is the largest real
PX4 log in ../shared/logs/px4 when present. Each review runs in a fresh process (peak RSS is its own)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "logs" / "px4"
CHILD = """
import json, resource, sys, time
from companion.cli import review_log
t = time.perf_counter()
rep, origin = review_log(sys.argv[1], vehicle="x500")
dt = time.perf_counter() - t
print(json.dumps({"s": dt, "span_s": rep["span"]["duration_s"], "samples": rep["state_samples"],
                  "rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(path: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, cwd=ROOT, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    r["s_per_flight_hour"] = r["s"] / (r["span_s"] / 3600) if r["span_s"] else None
    r["bytes"] = path.stat().st_size
    return r


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=20.0)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "tests"))
    from test_flight_logs import write_bin

    res = {"bench": "review", "minutes": args.minutes}
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        path = write_bin(Path(tmp) / "long.bin", speed=3.0, dur=args.minutes * 60)
        res["write_bin_s"] = time.perf_counter() - t
        res["dataflash"] = run(path)
    ulogs = sorted(SHARED.glob("*.ulg"), key=lambda p: p.stat().st_size) if SHARED.is_dir() else []
    res["ulog"] = run(ulogs[-1]) | {"file": ulogs[-1].name} if ulogs else None
    res["goal"] = "20-minute log < 10 s and < 1 GiB"
    print(json.dumps(res))


if __name__ == "__main__":
    main()
