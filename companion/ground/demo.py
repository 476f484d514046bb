"""`contract-guard demo`: the SITL and the daemon as separate processes on loopback UDP, the paper's
in-flight scenario (Figure 17 by default), a summary, the event log and a plot.

The demo is the ground station: it waits for the daemon, arms and takes off the SITL vehicle, lets
the daemon fly the route in offboard mode, and performs the scenario's timed ground-station actions
(`gcs`, e.g. Figure 18's CG_R_OBST 1 → 0.6 m) at vehicle time, through the SITL's MAVLink routing.
It reads the scenario's world only to report clearances; the daemon sees the world only through
MAVLink. Exit status 0 only if the flight was safe.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path

import yaml

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from companion.onboard.logschema import LOG_FILE  # noqa: E402
from contracts.errors import ContractError  # noqa: E402


FIFO_PRIORITY = 50  # the service unit's CPUSchedulingPriority (systemd/contract-guard.service)


def _scheduling() -> tuple[object, str]:
    """How the SITL and the daemon run: SCHED_FIFO at the service unit's priority, their own children (the planning
    worker) back at the default (SCHED_RESET_ON_FORK), where this user may — the daemon as it runs on an aircraft,
    the SITL as the autopilot that has a processor of its own; else the default, and why. Returns (the child's
    set-up, or None; what the console says)."""
    fifo, reset = getattr(os, "SCHED_FIFO", None), getattr(os, "SCHED_RESET_ON_FORK", 0)
    if fifo is None:
        return None, "default (this system has no SCHED_FIFO)"
    try:  # asked of this process and given back at once: the answer the children would get
        os.sched_setscheduler(0, fifo | reset, os.sched_param(FIFO_PRIORITY))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError as e:
        return None, (f"default priority: SCHED_FIFO is not permitted for this user ({e.strerror}); on a loaded "
                      "computer cycles may come late (said in the review)")
    return (lambda: os.sched_setscheduler(0, fifo | reset, os.sched_param(FIFO_PRIORITY))), \
        f"SITL and daemon at SCHED_FIFO {FIFO_PRIORITY}, as the service unit runs the daemon"


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Tail:
    """The last `keep` lines of a child's output, read on a thread as they come: a child that writes more than a
    pipe holds (64 KiB) is never blocked by a demo that would read only at the end."""

    def __init__(self, stream, keep: int = 20):
        self.lines: deque[str] = deque(maxlen=keep)
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            if line.strip():
                self.lines.append(line.rstrip())

    def last(self, timeout_s: float = 5.0) -> str | None:
        """The last line, once the child has closed its end (or `timeout_s` has passed)."""
        self._thread.join(timeout_s)
        return self.lines[-1] if self.lines else None


def _events(log_dir: Path) -> list[dict]:
    from companion.onboard.eventlog import read_events

    try:
        return list(read_events(log_dir))
    except Exception:
        return []


class GroundStation:
    """The demo's ground station on its own MAVLink socket: HEARTBEAT at 1 Hz, the vehicle's clock
    (the autopilot's time_boot_ms), and the scenario's timed parameter sets, each re-sent every second
    until the target component echoes the value (PARAM_VALUE), at most `tries` times."""

    def __init__(self, conn, actions, sysid: int = 1, tries: int = 5):
        self.conn, self.sysid, self.tries = conn, sysid, tries
        self.todo = sorted(actions, key=lambda a: a.at_s)
        self.t_vehicle: float | None = None
        self.records: list[dict] = []
        self._t_hb = -math.inf

    def connect(self, timeout_s: float) -> None:
        deadline = time.time() + timeout_s
        while self.t_vehicle is None:
            if time.time() > deadline:
                raise ContractError("the SITL did not answer the ground station")
            self.poll(0.5)

    def poll(self, dt: float) -> None:
        """Read for `dt` s of wall time; send what is due."""
        end = time.time() + dt
        while True:
            self._send_due()
            left = end - time.time()
            if left <= 0:
                return
            m = self.conn.recv_match(blocking=True, timeout=min(left, 0.1))
            if m is not None:
                self._take(m)

    def settled(self) -> bool:
        """Every action already due has been acknowledged or given up."""
        due = bool(self.todo) and self.t_vehicle is not None and self.todo[0].at_s <= self.t_vehicle
        return not due and all(r["t_acked"] is not None or r["tries"] >= self.tries
                               and time.time() - r["_wall"] >= 1.0 for r in self.records)

    def _take(self, m) -> None:
        src = (m.get_srcSystem(), m.get_srcComponent())
        if src == (self.sysid, 1) and getattr(m, "time_boot_ms", None):
            self.t_vehicle = m.time_boot_ms / 1000.0
        elif m.get_type() == "PARAM_VALUE" and src[0] == self.sysid:
            for r in self.records:
                if r["t_acked"] is None and (r["component_id"], r["name"]) == (src[1], m.param_id):
                    r["echoed"] = m.param_value
                    if math.isclose(m.param_value, r["value"], rel_tol=1e-6, abs_tol=1e-6):
                        r["t_acked"] = self.t_vehicle

    def _send_due(self) -> None:
        now = time.time()
        if now - self._t_hb >= 1.0:  # a live client of the SITL (and a ground station the daemon may see)
            self.conn.mav.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
            self._t_hb = now
        while self.todo and self.t_vehicle is not None and self.todo[0].at_s <= self.t_vehicle:
            a = self.todo.pop(0)
            p = a.param_set
            self.records.append({"at_s": a.at_s, "component": p.component, "component_id": p.component_id,
                                 "name": p.name, "value": p.value, "t_sent": self.t_vehicle, "t_acked": None,
                                 "echoed": None, "tries": 0, "_wall": -math.inf})
        for r in self.records:
            if r["t_acked"] is None and r["tries"] < self.tries and now - r["_wall"] >= 1.0:
                self.conn.mav.param_set_send(self.sysid, r["component_id"], r["name"].encode(), r["value"],
                                             9)  # MAV_PARAM_TYPE_REAL32
                r["tries"] += 1
                r["_wall"] = now

    def report(self) -> list[dict]:
        return [{k: v for k, v in r.items() if not k.startswith("_")} for r in self.records] + \
            [{"at_s": a.at_s, "component": a.param_set.component, "name": a.param_set.name,
              "value": a.param_set.value, "t_sent": None, "t_acked": None} for a in self.todo]


def daemon_config(sc, port: int, speedup: float, personality: str, log_dir: Path) -> dict:
    """The daemon's config for the demo's flight of `sc` (written beside its log, read by `contract-guard run`). The
    log directory is absolute: a relative path in a config is the config file's directory's, not the demo's."""
    return {
        "vehicle": sc.vehicle, "mode": "offboard", "engage": True,
        # the scenario's ground station on this machine sets CG_* unsigned (weaker; the banner says so)
        "link": {"connect": f"udpout:127.0.0.1:{port}", "autopilot": personality, "clock_rate": speedup,
                 "unsigned_params": True},
        "sensors": [{"kind": "obstacle_distance", "h_fov_deg": sc.sensor.fov_deg, "max_range_m": sc.sensor.max_range_m}],
        "contract": {"r_obst_m": max((c.radius_m for c in sc.world.columns), default=1.0)},
        "route": {"waypoints": [list(w) for w in sc.route.waypoints], "altitude_m": sc.route.altitude_m},
        "log": {"dir": str(Path(log_dir).resolve())},
    }


def run_demo(sc, scenario_path: Path, out: Path = Path("demo-out"), speedup: float = 1.0,
             duration_s: float = 85.0, personality: str = "px4") -> dict:
    """Fly scenario `sc` (loaded from `scenario_path` by the CLI, which wires the harness in)."""
    from companion.onboard.autopilots import adapter_for

    from .review import review

    out = Path(out)
    log_dir = out / "log"
    ap_log_dir = out / "autopilot-log"  # the SITL's own flight log (.ulg / .bin), as the autopilot's SD card
    out.mkdir(parents=True, exist_ok=True)
    for d in (log_dir, ap_log_dir):
        for old in d.glob("*") if d.exists() else []:
            old.unlink()
    port = _free_port()
    cfg = daemon_config(sc, port, speedup, personality, log_dir)
    cfg_path = out / "daemon.yaml"
    cfg_path.write_text(yaml.safe_dump(cfg))
    py = sys.executable
    rt, scheduling = _scheduling()
    # the demo ends the flight `duration_s` of vehicle time after the take-off (not after the SITL's start: on a
    # busy host the daemon's start-up alone took 20 s of the SITL's 2× time, and the flight was cut 22 m short of
    # the route's end); the SITL's own --duration is a backstop covering the minute the daemon may take to start
    sitl = subprocess.Popen([py, "-m", "sitl_harness", "--scenario", str(scenario_path),
                             "--personality", personality, "--listen", f"udp:127.0.0.1:{port}",
                             "--speedup", str(speedup), "--duration", str(duration_s + 60.0 * (1.0 + speedup)), "--json",
                             "--log-dir", str(ap_log_dir)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=rt)
    daemon = gcs = gs = None
    try:
        if "listening" not in (sitl.stderr.readline() or ""):
            raise ContractError("the SITL did not start")
        sitl_out = _Tail(sitl.stdout)  # its summary, the last line; its stderr drained beside it
        _Tail(sitl.stderr)
        daemon = subprocess.Popen([py, "-m", "companion.cli", "run", "--config", str(cfg_path)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=rt)
        daemon_err = _Tail(daemon.stderr)
        deadline = time.time() + 60
        while not any(e.get("event") == "startup_check" for e in _events(log_dir)):
            if daemon.poll() is not None:
                said = daemon_err.last()
                raise ContractError("the daemon stopped before it connected to the SITL"
                                    + (f": {said.strip()}" if said else ""))
            if time.time() > deadline:
                raise ContractError(f"the daemon did not connect to the SITL within a minute (no start-up check in "
                                    f"{log_dir})")
            time.sleep(0.2)
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        gs = GroundStation(gcs, sc.gcs)
        gs.connect(30)
        while not gs.settled():  # actions due before take-off (e.g. the daemon's starting R_obst)
            gs.poll(0.2)
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm
        gs.poll(0.5)
        for k, (cmd, params) in enumerate(adapter_for(personality).takeoff_commands(sc.route.altitude_m)):
            if k:
                gs.poll(0.3)
            gcs.mav.command_long_send(1, 1, cmd, 0, *params)
        t_end, deadline = (gs.t_vehicle or 0.0) + duration_s, time.time() + duration_s / speedup + 120
        while sitl.poll() is None and time.time() < deadline and (gs.t_vehicle or 0.0) < t_end:
            gs.poll(0.2)
        # the end of the flight: the daemon first (offboard hands over to Hold, the log says "stop"), then
        # the SITL, which prints its summary on SIGTERM; the other order logged "autopilot link down" at
        # the end of every demo, a finding of the SITL stopping, not of the flight
        _stop(daemon, signal.SIGINT, 15)
        daemon = None
        if sitl.poll() is None:
            sitl.send_signal(signal.SIGTERM)
        sitl.wait(timeout=30)
        summary_line = sitl_out.last() or ""
    finally:
        if gcs is not None:
            gcs.close()
        if daemon is not None:
            _stop(daemon, signal.SIGINT, 15)
        if sitl.poll() is None:
            sitl.kill()
    sitl_summary = json.loads(summary_line.strip().splitlines()[-1]) if summary_line.strip() else {}
    rep = review([log_dir], out_dir=out / "review", world=sc.world.outline())
    return summarise_flight(sc, _events(log_dir), sitl_summary, rep, out, gs.report(), scheduling)


def _stop(proc, sig, timeout_s: float) -> None:
    proc.send_signal(sig)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


def summarise_flight(sc, records: list[dict], sitl_summary: dict, rep: dict, out: Path,
                     gcs_actions: list[dict] = (), scheduling: str | None = None) -> dict:
    """Collisions, minimum clearance to the true columns, violations, speeds and the V_max steps."""
    from contracts.vehicle import load_vehicle

    r_body = load_vehicle(sc.vehicle).r_body_m
    states = [r for r in records if r.get("kind") == "state" and r.get("x") is not None]
    flying = [s for s in states if s.get("mode") == "offboard"]
    clear = math.inf
    for s in states:
        for c in sc.world.columns:
            clear = min(clear, math.hypot(s["x"] - c.x_m, s["y"] - c.y_m) - c.radius_m - r_body)
    speeds = [s["ground_speed"] for s in flying if s.get("ground_speed") is not None]
    steps = []  # the daemon's own limit changes in offboard flight, with the state they took effect in
    for e in records:
        if e.get("event") != "limit_change" or e.get("t") is None:
            continue
        s = next((s for s in states if s["t"] >= e["t"]), None)
        if s is not None and s.get("mode") == "offboard":
            steps.append({"t": round(e["t"], 1), "v_max": round(e["v_max"], 2), "d_od": round(s["d_od"], 2),
                          "thrust_ratio": round(s["thrust_ratio"], 2), "e_tr": round(s["e_tr"], 2),
                          "r_obst": round(s["r_obst"], 2)})
    gcs_actions = [dict(a) for a in gcs_actions]
    for a in gcs_actions:  # when the daemon took it, on its log's clock
        a["t_log"] = next((round(e["t"], 1) for e in records if e.get("event") == "param_set"
                           and e.get("param") == a["name"] and e.get("t") is not None
                           and math.isclose(e.get("new", math.nan), a["value"], rel_tol=1e-6)), None)
    collisions = int(sitl_summary.get("collisions", 0))
    result = {
        "scenario": sc.name, "collisions": collisions, "min_clearance_m": round(clear, 3),
        # failsafes where they happened: failsafe events and entries into the failsafe state (the link lost)
        "violations": rep.get("violation_count", 0), "failsafes": rep.get("failsafe_count", 0),
        "mean_speed_m_s": round(sum(speeds) / len(speeds), 2) if speeds else 0.0,
        "max_speed_m_s": round(max(speeds), 2) if speeds else 0.0,
        "v_max_steps": steps, "route_progress_m": round(max((s["x"] for s in states), default=0.0), 1),
        "route_length_m": round(max((w[0] for w in sc.route.waypoints), default=math.nan), 1),
        "flight_end": rep.get("flight_end"),
        "gcs_actions": gcs_actions, "forwarded": int(sitl_summary.get("forwarded", 0)),
        # how far the SITL's ticks started behind their schedule (wall-clock ms): a SITL that cannot keep its
        # speed-up flies its vehicle slower than the daemon's clock runs
        "sitl_behind_ms": {k: round(float(sitl_summary[f"jitter_ms_{k}"]), 1) for k in ("p99", "max")
                           if sitl_summary.get(f"jitter_ms_{k}") is not None},
        "setpoints": _stream_figures(records), "scheduling": scheduling,
        "planning": next(({k: r.get(k) for k in ("answers", "first_s", "median_s", "max_s")} for r in records
                          if r.get("event") == "planning"), None),
        "event_log": str(out / "log" / LOG_FILE), "autopilot_log": sitl_summary.get("flight_log"), "plot": (rep.get("outputs") or {}).get("png"),
        "plot_note": (rep.get("outputs") or {}).get("png_skipped"),
        "safe": collisions == 0 and clear > 0,
        # one verdict: the flight's truth (no collision, clearance kept) and the review of its event log
        "review_ok": bool(rep.get("ok")), "review_findings": list(rep.get("findings") or []),
        "review": str(out / "review" / "review.json"),
    }
    result["verdict"] = ("SAFE" if result["safe"] and result["review_ok"] else
                         "NOT SAFE" if not result["safe"] else "REVIEW NEEDED")
    (out / "summary.json").write_text(json.dumps(result, indent=2))
    return result


def _stream_figures(records: list[dict]) -> dict:
    """The offboard setpoint stream as the daemon counted it (its `stop` record): count, longest gap."""
    c = next((r["counters"] for r in reversed(records) if r.get("event") == "stop" and "counters" in r), {})
    return {"sent": c.get("setpoints_sent"), "gap_max_s": c.get("setpoint_gap_max_s")}


def format_summary(r: dict) -> str:
    lines = [f"contract-guard demo — scenario {r['scenario']}",
             f"  collisions: {r['collisions']}   minimum clearance: {r['min_clearance_m']:.2f} m   "
             f"violations: {r['violations']}   failsafes: {r['failsafes']}",
             f"  speed: mean {r['mean_speed_m_s']:.2f} m/s, max {r['max_speed_m_s']:.2f} m/s; "
             f"route flown to x = {r['route_progress_m']:.0f} m of {r.get('route_length_m', math.nan):.0f} m"]
    if r.get("flight_end"):
        lines.append(f"  flight ended: {r['flight_end']['why']}")
    behind = r.get("sitl_behind_ms") or {}
    if behind:
        lines.append(f"  SITL ticks behind their schedule: p99 {behind.get('p99', math.nan):.0f} ms, max "
                     f"{behind.get('max', math.nan):.0f} ms (wall clock)")
    if r.get("scheduling"):
        lines.append(f"  scheduling: {r['scheduling']}")
    sp = r.get("setpoints") or {}
    if sp.get("sent"):
        lines.append(f"  setpoints: {sp['sent']} sent, longest gap {1e3 * sp['gap_max_s']:.0f} ms (vehicle time)")
    pl = r.get("planning") or {}
    if pl.get("answers"):
        lines.append(f"  planning: {pl['answers']} plans waited for; the first {pl['first_s']:.2f} s after it was "
                     f"asked, median {pl['median_s']:.2f} s, slowest {pl['max_s']:.2f} s (vehicle time)")
    lines += ["  V_max steps (event-log time):"]
    lines += [f"    t {s['t']:6.1f} s  V_max {s['v_max']:5.2f} m/s  (D_od {s['d_od']:.1f} m, thrust "
              f"{s['thrust_ratio']:.2f}, E_tr {s['e_tr']:.2f} m, R_obst {s['r_obst']:.2f} m)"
              for s in r["v_max_steps"]]
    for a in r.get("gcs_actions", []):
        done = ("acknowledged" if a["t_acked"] is not None
                else "NOT ACKNOWLEDGED" if a["t_sent"] is not None else "not sent")
        if a.get("t_log") is not None:
            done += f", in the event log at t {a['t_log']:.1f} s"
        lines.append(f"  ground station: vehicle time {a['at_s']:.1f} s: {a['name']} = {a['value']:g} "
                     f"({a['component']}) {done}")
    lines.append(f"  event log: {r['event_log']}")
    if r.get("autopilot_log"):
        lines.append(f"  autopilot log: {r['autopilot_log']}")
    lines += [f"  plot: {r['plot']}"] if r.get("plot") else []
    if r.get("plot_note"):
        lines.append(f"  {r['plot_note']}")
    lines += [f"  review: {'contract kept' if r['review_ok'] else 'findings'} ({r['review']})"]
    lines += [f"    - {f}" for f in r["review_findings"]]
    lines.append(f"  {r['verdict']}" + ("" if r["verdict"] == "SAFE" else
                                        " (no collision, but the review has findings)" if r["safe"] else ""))
    return "\n".join(lines)
