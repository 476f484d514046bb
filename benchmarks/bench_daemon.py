"""The daemon's loop over real UDP: CPU use at 50 Hz, loop jitter, and sensor-message-to-command latency.

One JSON object on stdout. The daemon runs in this process exactly as `contract-guard run` runs it
(`Daemon.run`, real pymavlink UDP socket); a scripted autopilot in a child process streams the usual
telemetry and, every second, a DISTANCE_SENSOR reading of an obstacle inside the stop distance, and
times the daemon's Hold command from the moment that datagram left. Goals: CPU < 5 % of one
core, latency p95 < 25 ms.

`BENCH_FLOOD=junk|telemetry` adds a third process flooding the daemon's port at `BENCH_FLOOD_HZ`
(default 100 000 datagrams/s) from another socket: two bytes `fd ff` (junk), or well-formed ATTITUDE
claiming the autopilot's ids (telemetry). Goal under a flood: loop period p99 < 25 ms and no failsafe.
`cycle_work_ms` is one cycle's own work (poll and step) in wall time, apart from how late the OS wakes
the loop, and `cycle_cpu_ms` the same in CPU time (what a busy machine's preemption cannot inflate);
`load_average_1min` says how busy the machine was. The daemon runs at the service unit's `Nice=` and
`CPUSchedulingPolicy=fifo` priority (as installed; `BENCH_NICE=0`, `BENCH_FIFO=0` for the defaults); `nice` and
`sched_fifo` say which it got.

`cycle_lateness_ms` is each cycle's lateness as the daemon judges its own timeliness (companion/onboard/estimators.py
`Timeliness`: how much later than one loop period after the previous cycle it started), with the share of cycles
beyond each candidate jitter allowance (`timeouts.cycle_jitter_s`), from 2 s after start (the daemon does not judge
its start-up). `BENCH_BUSY=N` starts N busy processes
(`while True: pass`) beside the daemon for the run, stopped afterwards: a loaded host.
"""

from __future__ import annotations

import gc
import json
import multiprocessing as mp
import os
import socket
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pymavlink import mavutil  # noqa: E402

DURATION_S = float(os.environ.get("BENCH_DAEMON_S", "30"))
UNIT = Path(__file__).resolve().parents[1] / "systemd" / "contract-guard.service"


def unit_setting(name: str, default: str) -> str:
    """One of the service unit's settings (how the daemon runs when installed), `default` when it sets none."""
    for line in UNIT.read_text().splitlines():
        if line.startswith(f"{name}="):
            return line.split("=", 1)[1].strip()
    return default


NICE = int(os.environ.get("BENCH_NICE", unit_setting("Nice", "0")))  # as installed; needs root or CAP_SYS_NICE
# the unit's SCHED_FIFO priority (CPUSchedulingPolicy=fifo), 0 for none; BENCH_FIFO=0 measures without it
FIFO = int(os.environ.get("BENCH_FIFO", unit_setting("CPUSchedulingPriority", "0")
                          if unit_setting("CPUSchedulingPolicy", "other") == "fifo" else "0"))
PX4_MISSION, PX4_HOLD = (4 << 16) | (4 << 24), (4 << 16) | (3 << 24)
PARAMS = {"MPC_TILTMAX_AIR": (45.0, 9), "MPC_ACC_HOR": (3.0, 9), "MPC_JERK_AUTO": (4.0, 9), "COM_OBL_RC_ACT": (5.0, 9)}


def vehicle(port: int, out: mp.Queue) -> None:
    """A scripted PX4: telemetry at realistic rates, an obstacle every second, Hold on command."""
    m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    t0 = time.monotonic()
    mode, lat, obstacle_since, clear_at = PX4_MISSION, [], None, None
    nxt = {k: 0.0 for k in ("hb", "pos", "att", "ext", "est", "hud", "dist")}
    period = {"hb": 1.0, "pos": 0.02, "att": 0.02, "ext": 0.5, "est": 0.2, "hud": 0.1, "dist": 0.05}
    next_obstacle, speed = 3.0, 3.0
    while time.monotonic() - t0 < DURATION_S + 2:
        now = time.monotonic() - t0
        tb = int(now * 1000)
        msg = m.recv_match(blocking=False)
        while msg is not None:
            if msg.get_type() == "PARAM_REQUEST_READ" and msg.param_id in PARAMS:
                v, ty = PARAMS[msg.param_id]
                m.mav.param_value_send(msg.param_id.encode(), v, ty, len(PARAMS), list(PARAMS).index(msg.param_id))
            elif msg.get_type() == "COMMAND_LONG" and msg.command == 178 and msg.param2 > 0:
                speed = min(3.0, msg.param2)  # a compliant autopilot (instantly, for simplicity)
            elif msg.get_type() == "COMMAND_LONG" and msg.command == 176 and obstacle_since is not None:
                lat.append(time.monotonic() - obstacle_since)
                obstacle_since, mode, clear_at = None, PX4_HOLD, now + 0.3
                nxt["hb"] = 0.0
            msg = m.recv_match(blocking=False)
        if clear_at is not None and now >= clear_at:  # the pilot resumes, the obstacle is gone
            mode, clear_at, nxt["hb"] = PX4_MISSION, None, 0.0
            next_obstacle = now + 0.7
        for k in nxt:
            if now >= nxt[k]:
                nxt[k] = now + (period[k] if k != "ext" or now > 1.5 else 0.1)
                if k == "hb":
                    m.mav.heartbeat_send(2, 12, 1 | 128, mode, 4)
                elif k == "pos":
                    m.mav.local_position_ned_send(tb, speed * now, 0.0, -2.0, speed, 0.0, 0.0)
                elif k == "att":
                    m.mav.attitude_send(tb, 0.0, 0.0, 0.0, 0, 0, 0)
                elif k == "ext":
                    m.mav.extended_sys_state_send(0, 2 if now > 1.5 else 1)  # takes off after 1.5 s
                elif k == "est":
                    m.mav.estimator_status_send(tb * 1000, 1 | 2 | 4 | 8 | 16 | 32, 0, 0, 0, 0, 0, 0, 0, 0)
                elif k == "hud":
                    m.mav.vfr_hud_send(speed, speed, 0, 47, 2.0, 0.0)
                elif k == "dist":
                    seen = obstacle_since is None and mode == PX4_MISSION and now >= next_obstacle
                    cur = 200 if seen else 1000
                    m.mav.distance_sensor_send(tb, 10, 1000, cur, 0, 0, 0, 255, 0.5, 0.5, [0, 0, 0, 0], 100)
                    if seen:
                        obstacle_since = time.monotonic()
        time.sleep(0.002)
    out.put(lat)


def flood(port: int, kind: str, rate_hz: float, seconds: float) -> None:
    """Datagrams at `rate_hz` to the daemon from a socket that is not the autopilot's."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    spoof = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    data = b"\xfd\xff" if kind == "junk" else spoof.attitude_encode(0, 0.1, 0.1, 0.0, 0, 0, 0).pack(spoof)
    t0, sent = time.monotonic(), 0
    while (now := time.monotonic() - t0) < seconds:
        for _ in range(max(0, int(now * rate_hz) - sent)):
            try:
                s.sendto(data, ("127.0.0.1", port))
            except OSError:
                pass
            sent += 1
        time.sleep(0.001)


def busy() -> None:
    """A process that only burns CPU (`BENCH_BUSY`: a loaded host)."""
    while True:
        pass


ALLOWANCES_MS = (5, 10, 20, 30, 40, 50)  # candidate jitter allowances the lateness is counted against


JUDGED_FROM_S = 2.0  # the daemon judges its cycles from 1 s after the autopilot's first heartbeat (≈ 0.5 s here)


def lateness(starts: list[float], period_s: float) -> dict:
    """Each cycle's lateness [ms] as `Timeliness` judges it: its start later than one period after the last's,
    from `JUDGED_FROM_S` after the first cycle (start-up is not judged)."""
    import numpy as np

    t = np.asarray(starts)
    late = np.maximum(np.diff(t) - period_s, 0.0)[t[1:] - t[0] >= JUDGED_FROM_S] * 1e3
    return {"p50": float(np.percentile(late, 50)), "p99": float(np.percentile(late, 99)),
            "p99_9": float(np.percentile(late, 99.9)), "max": float(np.max(late)), "cycles": int(late.size),
            "beyond_allowance": {str(a): int(np.sum(late > a)) for a in ALLOWANCES_MS}}


def _full_gc_ms() -> float:
    """One full cyclic collection's wall time [ms]: the stall it puts in whichever cycle it falls."""
    t = time.perf_counter()
    gc.collect()
    return round((time.perf_counter() - t) * 1e3, 2)


def main() -> None:
    from companion.onboard.config import config_from_dict
    from companion.onboard.daemon import Daemon
    from companion.onboard.eventlog import EventLog
    from companion.onboard.link import open_connection
    from contracts.table import load_for_vehicle
    from contracts.vehicle import load_vehicle

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = config_from_dict({"vehicle": "mambo", "mode": "governor", "engage": True,
                            "link": {"connect": f"udpin:127.0.0.1:{port}", "autopilot": "px4"},
                            "sensors": [{"h_fov_deg": 30, "max_range_m": 6.0}], "log": {"dir": tempfile.mkdtemp()}})
    v = load_vehicle("mambo")
    table = load_for_vehicle(v)
    conn = open_connection(cfg.link.connect, 0, 1, 191)
    q: mp.Queue = mp.Queue()
    child = mp.Process(target=vehicle, args=(port, q), daemon=True)
    child.start()
    kind, rate = os.environ.get("BENCH_FLOOD", ""), float(os.environ.get("BENCH_FLOOD_HZ", "100000"))
    flooder = mp.Process(target=flood, args=(port, kind, rate, DURATION_S), daemon=True) if kind else None
    log = EventLog(cfg.log.dir)
    daemon = Daemon(cfg, table, conn, log)
    starts: list[float] = []
    work: list[float] = []  # one cycle's own work (poll + step) in wall time, preemption included
    work_cpu: list[float] = []  # the same in this thread's CPU time: what the daemon itself costs
    poll, step, polled = daemon.poll, daemon.step, [0.0, 0.0]

    def timed_poll():
        polled[:] = time.monotonic(), time.thread_time()
        return poll()

    def timed_step():
        starts.append(time.monotonic())
        try:
            return step()
        finally:
            work.append(time.monotonic() - polled[0])
            work_cpu.append(time.thread_time() - polled[1])

    daemon.poll, daemon.step = timed_poll, timed_step
    t0, c0 = time.monotonic(), time.process_time()
    if flooder is not None:
        flooder.start()
    busies = [mp.Process(target=busy, daemon=True) for _ in range(int(os.environ.get("BENCH_BUSY", "0")))]
    for b in busies:
        b.start()
    nice = 0
    if NICE:  # the daemon's own priority, as the systemd unit sets it (Nice=); the children keep theirs
        try:
            os.setpriority(os.PRIO_PROCESS, 0, NICE)
            nice = NICE
        except OSError:
            print(f"bench_daemon: cannot set nice {NICE} (not root): measured at 0", file=sys.stderr)
    fifo = 0
    if FIFO:  # the unit's real-time scheduling; children started from here on get the default (reset on fork)
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(FIFO))
            fifo = FIFO
        except OSError as e:
            print(f"bench_daemon: cannot set SCHED_FIFO {FIFO} ({e.strerror}): measured without", file=sys.stderr)
    load = os.getloadavg()[0]
    gc_ms = {"objects_at_start": len(gc.get_objects()), "before_freeze": _full_gc_ms()}
    daemon.run(lambda: time.monotonic() - t0 > DURATION_S)  # (it freezes start-up's objects: `freeze_startup`)
    gc_ms["in_the_loop"] = _full_gc_ms()  # what a full collection costs once the loop has run
    wall, cpu = time.monotonic() - t0, time.process_time() - c0
    for b in busies:
        b.terminate()
        b.join(5)
    log.close()
    lat = sorted(q.get(timeout=10))
    child.join(5)
    import numpy as np

    gaps = np.diff(starts) * 1e3
    print(json.dumps({
        "benchmark": "daemon", "duration_s": round(wall, 2), "loop_hz": cfg.loop_hz,
        "cpu_percent_of_one_core": round(100 * cpu / wall, 2), "full_gc_ms": gc_ms,
        "loop_period_ms": {"mean": float(np.mean(gaps)), "p99": float(np.percentile(gaps, 99)),
                           "max": float(np.max(gaps)), "jitter_sd": float(np.std(gaps))},
        "cycle_lateness_ms": lateness(starts, 1.0 / cfg.loop_hz), "busy_processes": len(busies),
        "cycle_work_ms": {"p50": float(np.percentile(work, 50) * 1e3), "p99": float(np.percentile(work, 99) * 1e3),
                          "max": float(np.max(work) * 1e3)},
        "cycle_cpu_ms": {"p50": float(np.percentile(work_cpu, 50) * 1e3),
                         "p99": float(np.percentile(work_cpu, 99) * 1e3), "max": float(np.max(work_cpu) * 1e3)},
        "sensor_to_hold_latency_ms": {"n": len(lat), "p50": float(np.percentile(lat, 50) * 1e3),
                                      "p95": float(np.percentile(lat, 95) * 1e3), "max": float(max(lat) * 1e3)}
        if lat else {"n": 0},
        "messages": daemon.counters.messages, "bad_packets": daemon.counters.bad_packets,
        "flood": {"kind": kind or None, "rate_hz": rate if kind else 0, "link": dict(conn.stats),
                  "poll_budget_hits": daemon.counters.poll_budget_hits,
                  "failsafes": [e for e in failsafes(cfg.log.dir)]},
        "load_average_1min": round(load, 2), "nice": nice, "sched_fifo": fifo,
        "goal": {"cpu_percent": 5, "latency_p95_ms": 25, "flood_loop_p99_ms": 25, "flood_failsafes": 0},
    }))


def failsafes(log_dir) -> list[str]:
    from companion.onboard.eventlog import read_events

    return [f"{r.get('cause')} at {r.get('t'):.1f} s" for r in read_events(log_dir) if r.get("event") == "failsafe"]


if __name__ == "__main__":
    main()
