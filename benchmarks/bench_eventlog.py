"""Event-log cost per call and review throughput (one JSON object on stdout).

Goal: `EventLog.state()` well under 50 µs per call (it runs in the 50 Hz control loop; the 1 s
buffer flush is included in the figures, amortised as it happens). `event()` includes an fsync, so
its cost is the disk's: measure it on the companion computer's own storage (`--dir` on the SD card/eMMC).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.onboard.eventlog import EventLog  # noqa: E402
from companion.ground.review import review  # noqa: E402

SAMPLE = dict(state="cruise", mode="AUTO.MISSION", contract="stop", engaged=True, x=12.3456, y=-2.3456, z=-10.0,
              vx=3.21, vy=0.12, vz=-0.01, ground_speed=3.2122, d_od=6.0, e_tr=0.31, e_tr_measured=0.25, r_obst=0.5,
              thrust_ratio=0.87, v_max=4.09, tilt_deg=20.0, v_safe=4.1, gamma=-0.01, v_cmd=4.09)


def stats_us(samples_ns):
    a = np.asarray(samples_ns, dtype=float) / 1e3
    return {"mean_us": float(a.mean()), "median_us": float(np.median(a)), "p99_us": float(np.percentile(a, 99)),
            "max_us": float(a.max()), "calls": int(a.size)}


def bench(directory: Path, n_states: int, n_events: int) -> dict:
    out = {}
    log = EventLog(directory / "log")
    # state(): real wall clock and monotonic clock, so the once-a-second flush happens as in flight
    times = []
    for i in range(n_states):
        t0 = time.perf_counter_ns()
        log.state(i * 0.02, **SAMPLE)
        times.append(time.perf_counter_ns() - t0)
    out["state"] = stats_us(times)
    nan = dict(SAMPLE, d_od=math.nan, gamma=math.inf)
    times = []
    for i in range(n_states // 4):
        t0 = time.perf_counter_ns()
        log.state(i * 0.02, **nan)
        times.append(time.perf_counter_ns() - t0)
    out["state_with_nonfinite"] = stats_us(times)
    times = []
    for i in range(n_events):
        t0 = time.perf_counter_ns()
        log.event(i * 0.02, "limit_change", v_max=3.0, reason="bench")
        times.append(time.perf_counter_ns() - t0)
    out["event_fsync"] = stats_us(times)
    log.close()
    out["log_bytes_per_state"] = (directory / "log" / "events.jsonl").stat().st_size / (n_states * 1.25 + n_events)
    t0 = time.perf_counter()
    rep = review(directory / "log")
    dt = time.perf_counter() - t0
    out["review_records_per_s"] = rep["records"] / dt
    out["review_s_per_flight_hour_at_50hz"] = 3600 * 50 / out["review_records_per_s"]
    return out


def bench_full_disk(directory: Path, seconds: float = 20.0) -> dict:
    """A 50 Hz loop (simulated time) logging into a 64 KiB tmpfs: cost per call while the disk is full."""
    mnt = directory / "full"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        return {"skipped": f"cannot mount a tmpfs: {r.stderr.strip() or 'not root'}"}
    try:
        mono = [0.0]
        log = EventLog(mnt, monotonic=lambda: mono[0])
        st, ev, acked, n_ev = [], [], 0, 0
        for i in range(int(seconds * 50)):
            mono[0] += 0.02
            t0 = time.perf_counter_ns()
            log.state(i * 0.02, **SAMPLE)
            st.append(time.perf_counter_ns() - t0)
            if i % 50 == 0:
                t0 = time.perf_counter_ns()
                acked += log.event(i * 0.02, "limit_change", v_max=3.0, reason="bench")
                ev.append(time.perf_counter_ns() - t0)
                n_ev += 1
        out = {"simulated_s": seconds, "state_while_full": stats_us(st), "event_while_full": stats_us(ev),
               "events_acknowledged": acked, "events_attempted": n_ev, **log.stats()}
        log.close()
        return out
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dir", type=Path, help="where to write (default: a temporary directory)")
    p.add_argument("--states", type=int, default=50_000)
    p.add_argument("--events", type=int, default=200)
    a = p.parse_args()
    with tempfile.TemporaryDirectory(dir=a.dir) as d:
        out = bench(Path(d), a.states, a.events)
        out["full_disk"] = bench_full_disk(Path(d))
    out.update(benchmark="eventlog", python=platform.python_version(), machine=platform.machine())
    print(json.dumps(out))


if __name__ == "__main__":
    main()
