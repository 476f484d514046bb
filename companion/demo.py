"""`contract-guard demo`: the SITL and the daemon as separate processes on loopback UDP, the paper's
in-flight scenario (Figure 17 by default), a summary, the event log and a plot.

The demo is the ground station: it waits for the daemon, arms and takes off the SITL vehicle, and lets
the daemon fly the route in offboard mode. It reads the scenario's world only to report clearances;
the daemon sees the world only through MAVLink. Exit status 0 only if the flight was safe.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import yaml

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from contracts.errors import ContractError  # noqa: E402


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _events(log_dir: Path) -> list[dict]:
    from .eventlog import read_events

    try:
        return list(read_events(log_dir))
    except Exception:
        return []


def run_demo(scenario: str = "fig17", out: Path = Path("demo-out"), speedup: float = 2.0,
             duration_s: float = 75.0, personality: str = "px4") -> dict:
    from sitl_harness.scenario import load_scenario, resolve_scenario_path

    from .review import review

    sc = load_scenario(scenario)
    out = Path(out)
    log_dir = out / "log"
    out.mkdir(parents=True, exist_ok=True)
    for old in log_dir.glob("*") if log_dir.exists() else []:
        old.unlink()
    port = _free_port()
    cfg = {
        "vehicle": sc.vehicle, "mode": "offboard", "engage": True,
        "link": {"connect": f"udpout:127.0.0.1:{port}", "autopilot": personality},
        "sensors": [{"kind": "obstacle_distance", "h_fov_deg": sc.sensor.fov_deg}],
        "contract": {"r_obst_m": max((c.radius_m for c in sc.world.columns), default=1.0)},
        "route": {"waypoints": [list(w) for w in sc.route.waypoints], "altitude_m": sc.route.altitude_m},
        "log": {"dir": str(log_dir)},
    }
    cfg_path = out / "daemon.yaml"
    cfg_path.write_text(yaml.safe_dump(cfg))
    py = sys.executable
    sitl = subprocess.Popen([py, "-m", "sitl_harness", "--scenario", str(resolve_scenario_path(scenario)),
                             "--personality", personality, "--listen", f"udp:127.0.0.1:{port}",
                             "--speedup", str(speedup), "--duration", str(duration_s), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    daemon = None
    try:
        if "listening" not in (sitl.stderr.readline() or ""):
            raise ContractError("the SITL did not start")
        daemon = subprocess.Popen([py, "-m", "companion.cli", "run", "--config", str(cfg_path)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 60
        while not any(e.get("event") == "startup_check" for e in _events(log_dir)):
            if time.time() > deadline or daemon.poll() is not None:
                raise ContractError("the daemon did not connect to the SITL")
            time.sleep(0.2)
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        while not gcs.wait_heartbeat(timeout=0.5):
            gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm
        time.sleep(0.5)
        # take off: PX4 AUTO.TAKEOFF (to MIS_TAKEOFF_ALT), ArduPilot GUIDED + NAV_TAKEOFF (relative altitude)
        if personality == "px4":
            gcs.mav.command_long_send(1, 1, 176, 0, 1 | 128, 4, 2, 0, 0, 0, 0)
        else:
            gcs.mav.command_long_send(1, 1, 176, 0, 1 | 128, 4, 0, 0, 0, 0, 0)
            time.sleep(0.3)
            gcs.mav.command_long_send(1, 1, 22, 0, 0, 0, 0, 0, 0, 0, sc.route.altitude_m)
        summary_line, _ = sitl.communicate(timeout=duration_s / speedup + 120)
    finally:
        if daemon is not None:
            daemon.send_signal(signal.SIGINT)  # offboard hands over to Hold and the log is closed
            try:
                daemon.wait(15)
            except subprocess.TimeoutExpired:
                daemon.kill()
        if sitl.poll() is None:
            sitl.kill()
    sitl_summary = json.loads(summary_line.strip().splitlines()[-1]) if summary_line.strip() else {}
    rep = review([log_dir], out_dir=out / "review")
    return summarise_flight(sc, _events(log_dir), sitl_summary, rep, out)


def summarise_flight(sc, records: list[dict], sitl_summary: dict, rep: dict, out: Path) -> dict:
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
    steps, last = [], None
    for s in flying:
        v = s.get("v_cmd")
        if v is not None and (last is None or abs(v - last) > 0.3):
            steps.append({"t": round(s["t"], 1), "v_max": round(v, 2), "d_od": round(s["d_od"], 2),
                          "thrust_ratio": round(s["thrust_ratio"], 2), "e_tr": round(s["e_tr"], 2)})
            last = v
    collisions = int(sitl_summary.get("collisions", 0))
    result = {
        "scenario": sc.name, "collisions": collisions, "min_clearance_m": round(clear, 3),
        "violations": rep.get("violation_count", 0), "failsafes": len(rep.get("failsafes", [])),
        "mean_speed_m_s": round(sum(speeds) / len(speeds), 2) if speeds else 0.0,
        "max_speed_m_s": round(max(speeds), 2) if speeds else 0.0,
        "v_max_steps": steps, "route_progress_m": round(max((s["x"] for s in states), default=0.0), 1),
        "event_log": str(out / "log" / "events.jsonl"), "plot": str(out / "review" / "review.png"),
        "safe": collisions == 0 and clear > 0,
    }
    (out / "summary.json").write_text(json.dumps(result, indent=2))
    return result


def format_summary(r: dict) -> str:
    lines = [f"contract-guard demo — scenario {r['scenario']}",
             f"  collisions: {r['collisions']}   minimum clearance: {r['min_clearance_m']:.2f} m   "
             f"violations: {r['violations']}   failsafes: {r['failsafes']}",
             f"  speed: mean {r['mean_speed_m_s']:.2f} m/s, max {r['max_speed_m_s']:.2f} m/s; "
             f"route flown to x = {r['route_progress_m']:.0f} m",
             "  V_max steps:"]
    lines += [f"    t {s['t']:6.1f} s  V_max {s['v_max']:5.2f} m/s  (D_od {s['d_od']:.1f} m, thrust "
              f"{s['thrust_ratio']:.2f}, E_tr {s['e_tr']:.2f} m)" for s in r["v_max_steps"]]
    lines += [f"  event log: {r['event_log']}", f"  plot: {r['plot']}",
              "  SAFE" if r["safe"] else "  NOT SAFE"]
    return "\n".join(lines)
