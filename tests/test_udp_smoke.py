"""Smoke tests over real loopback UDP: the SITL and the daemon as separate processes."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = {
    "name": "smoke", "vehicle": "mambo", "seed": 3,
    "world": {"columns": [{"x_m": 60.0, "y_m": 0.0, "radius_m": 0.5}]},
    "sensor": {"fov_deg": 30, "max_range_m": 6.0},
    "route": {"altitude_m": 2.0, "cruise_speed_m_s": 6.0, "waypoints": [[0, 0], [80, 0]]},
}


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cg(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "companion.cli", *map(str, args)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def read_log(d: Path):
    lines = (d / "events.jsonl").read_text().splitlines()
    good = []
    for i, ln in enumerate(lines):
        try:
            good.append(json.loads(ln))
        except json.JSONDecodeError:
            assert i == len(lines) - 1, f"line {i} of {len(lines)} does not parse"
    return good


@pytest.fixture
def world(tmp_path):
    sc = tmp_path / "smoke.yaml"
    sc.write_text(yaml.safe_dump(SCENARIO))
    port = free_port()
    sitl = cg("sitl", "--scenario", sc, "--listen", f"udp:127.0.0.1:{port}", "--speedup", "2")
    assert "listening" in sitl.stderr.readline()  # bound and ready

    def config(mode="governor", connect=None, engage=True, **link):
        p = tmp_path / "cg.yaml"
        p.write_text(yaml.safe_dump({
            "vehicle": "mambo", "mode": mode, "engage": engage,
            "link": {"connect": connect or f"udpout:127.0.0.1:{port}", "autopilot": "px4", "clock_rate": 2.0, **link},
            "sensors": [{"h_fov_deg": 30, "max_range_m": 6.0}], "log": {"dir": str(tmp_path / "log")},
        }))
        return p

    yield port, config, tmp_path / "log"
    sitl.send_signal(signal.SIGINT)
    try:
        sitl.wait(10)
    except subprocess.TimeoutExpired:
        sitl.kill()


def gcs_fly(port):
    m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    deadline = time.time() + 30
    while time.time() < deadline:  # say hello until the vehicle answers (it may still be starting)
        m.mav.heartbeat_send(6, 8, 0, 0, 0)
        if m.wait_heartbeat(timeout=0.5):
            break
    else:
        pytest.fail("the SITL never answered")
    m.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    time.sleep(0.5)
    m.mav.command_long_send(1, 1, 300, 0, 0, 0, 0, 0, 0, 0, 0)  # MISSION_START
    return m


def wait_for_event(logdir, name, timeout=30.0):
    """Until the daemon has logged `name` (it must see the vehicle on the ground before take-off:
    a daemon that first sees it flying never engages by itself)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        if (logdir / "events.jsonl").exists() and any(r.get("event") == name for r in read_log(logdir)):
            return
        time.sleep(0.2)
    seen = [(r.get("event"), r.get("to") or r.get("cause") or r.get("cmd")) for r in read_log(logdir) if r.get("event")
            and r.get("event") not in ("reaction_time", "violation_end")] if (logdir / "events.jsonl").exists() else []
    pytest.fail(f"the daemon never logged {name}; its last events: {seen[-20:]}")


def test_daemon_governs_the_sitl_over_udp_and_stops_cleanly(world):
    port, config, logdir = world
    d = cg("run", "--config", config())
    try:
        wait_for_event(logdir, "startup_check")
        gcs = gcs_fly(port)
        deadline = time.time() + 60
        acked = False
        while time.time() < deadline and not acked:
            gcs.recv_match(blocking=True, timeout=1)
            acked = any(e.get("event") == "command_ack" and e.get("command") == 178 and e.get("result") == 0
                        for e in read_log(logdir)) if (logdir / "events.jsonl").exists() else False
        assert acked, "the speed limit was sent and acknowledged over UDP"
        time.sleep(2.0)
    finally:
        d.send_signal(signal.SIGTERM)
        out, err = d.communicate(timeout=10)
    assert d.returncode == 0, err
    recs = read_log(logdir)
    names = [r.get("event") for r in recs]
    assert "start" in names and names[-1] == "stop"
    assert any(r.get("event") == "startup_check" and r["ok"] for r in recs)
    assert sum(1 for r in recs if r["kind"] == "state") > 20
    # the console, as a service's journal or a terminal shows it: one line per thing worth knowing
    said = [ln.removeprefix("contract-guard: ") for ln in out.splitlines()]
    for start in ("vehicle mambo, table", "governor mode (stop contract)", "sensors: [0] distance_sensor",
                  "waiting for the autopilot", "autopilot link up", "start-up checks: ok", "speed limit",
                  "stopping (SIGTERM)", "stopped after"):
        assert any(ln.startswith(start) for ln in said), (start, out)


def test_ground_station_sets_a_daemon_parameter_through_the_sitl(world):
    """The demo's ground station → the SITL's routing → the daemon's PARAM_SET, echoed back (unsigned: the
    config accepts it, weaker, as a SITL on this machine may)."""
    from companion.ground.demo import GroundStation
    from sitl_harness.scenario import GcsAction

    port, config, logdir = world
    d = cg("run", "--config", config(mode="shadow", unsigned_params=True))
    try:
        wait_for_event(logdir, "startup_check")
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        gs = GroundStation(gcs, [GcsAction(at_s=0, param_set={"name": "CG_R_OBST", "value": 0.6})])
        gs.connect(30)
        deadline = time.time() + 20
        while not gs.settled() and time.time() < deadline:
            gs.poll(0.2)
        gcs.close()
    finally:
        d.send_signal(signal.SIGTERM)
        d.communicate(timeout=10)
    [r] = gs.report()
    assert r["t_acked"] is not None and r["echoed"] == pytest.approx(0.6)
    assert any(e.get("event") == "param_set" and e["param"] == "CG_R_OBST" and e["new"] == pytest.approx(0.6)
               for e in read_log(logdir))


def test_kill9_and_restart_keep_the_log(world):
    port, config, logdir = world
    cfg = config()
    d = cg("run", "--config", cfg)
    wait_for_event(logdir, "startup_check")
    gcs_fly(port)
    time.sleep(4.0)
    d.kill()
    d.wait(5)
    first = read_log(logdir)
    assert len(first) > 10
    d2 = cg("run", "--config", cfg)
    deadline = time.time() + 60  # its start-up (imports, the table) takes seconds on a loaded host
    while time.time() < deadline and d2.poll() is None and len({r["boot"] for r in read_log(logdir)}) < 2:
        time.sleep(0.2)
    time.sleep(2.0)  # the restarted daemon at work a while
    d2.send_signal(signal.SIGTERM)
    d2.wait(10)
    after = read_log(logdir)
    assert after[: len(first)] == first  # the old lines are intact
    boots = {r["boot"] for r in after}
    assert len(boots) == 2
    # after a restart in flight the daemon does not engage by itself
    second = [r for r in after if r["boot"] != first[0]["boot"]]
    assert not any(r.get("event") == "command" and r.get("cmd") in ("change_speed", "hold") for r in second)


def test_100k_malformed_datagrams_at_the_daemon_port(world, tmp_path):
    port, config, logdir = world
    dport = free_port()
    d = cg("run", "--config", config(mode="shadow", connect=f"udpin:127.0.0.1:{dport}"))
    time.sleep(1.5)
    rng = __import__("random").Random(7)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for i in range(100_000):
        n = rng.randrange(1, 300)
        junk = bytes(rng.randrange(256) for _ in range(min(n, 12))) * (n // 12 + 1)
        if i % 3 == 0:
            junk = b"\xfd" + junk  # looks like the start of a MAVLink 2 frame
        s.sendto(junk[:n], ("127.0.0.1", dport))
        if i % 2000 == 0:
            time.sleep(0.01)
    time.sleep(1.0)
    assert d.poll() is None, "the daemon is still running"
    d.send_signal(signal.SIGTERM)
    d.wait(10)
    recs = read_log(logdir)
    stop = [r for r in recs if r.get("event") == "stop"][-1]
    assert stop["counters"]["bad_packets"] > 0  # (the kernel drops most of a burst this size: not all reach us)
    assert sum(1 for r in recs if r["kind"] == "state") > 10  # the loop kept running


def test_sigterm_in_flight_holds_the_vehicle_short_of_the_column(tmp_path):
    """Stop means stop, with real processes over UDP: `contract-guard sitl` and `contract-guard run` (governor,
    engaged); SIGTERM to the daemon mid-mission, with the column still beyond its sensor. The daemon commands Hold,
    sees the autopilot take it, says so, and exits 0; the vehicle then stays short of the column (the SITL's own
    collision count), where without the Hold the mission flew into it."""
    sc = tmp_path / "smoke.yaml"
    sc.write_text(yaml.safe_dump(SCENARIO))
    port = free_port()
    sitl = cg("sitl", "--scenario", sc, "--listen", f"udp:127.0.0.1:{port}", "--speedup", "2", "--json")
    assert "listening" in sitl.stderr.readline()
    logdir = tmp_path / "log"
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(yaml.safe_dump({
        "vehicle": "mambo", "mode": "governor", "engage": True,
        "link": {"connect": f"udpout:127.0.0.1:{port}", "autopilot": "px4", "clock_rate": 2.0},
        "sensors": [{"h_fov_deg": 30, "max_range_m": 6.0}], "log": {"dir": str(logdir)}}))
    d = cg("run", "--config", cfg)
    try:
        wait_for_event(logdir, "startup_check")
        gcs_fly(port)
        wait_for_event(logdir, "limit_change", 60.0)
        time.sleep(3.0)  # 6 s of flight at twice real time: cruising, the column 60 m out
        d.send_signal(signal.SIGTERM)
        out, err = d.communicate(timeout=15)
        assert d.returncode == 0, err
        time.sleep(8.0)  # 16 s more of flight: long enough to have reached the column
    finally:
        if d.poll() is None:
            d.kill()
        sitl.send_signal(signal.SIGINT)
        sout, _ = sitl.communicate(timeout=15)
    recs = read_log(logdir)
    [sd] = [r for r in recs if r.get("event") == "shutdown"]
    assert sd["hold"] and sd["confirmed"], sd
    assert any(r.get("event") == "command" and r.get("cmd") == "hold" for r in recs)
    said = [ln.removeprefix("contract-guard: ") for ln in out.splitlines()]
    assert any(ln.startswith("stopping (SIGTERM)") for ln in said), out
    assert any(ln.startswith("stopping in flight: Hold commanded, the autopilot shows it") for ln in said), out
    assert any("1 holds" in ln for ln in said if ln.startswith("stopped after")), out
    summary = json.loads(sout.strip().splitlines()[-1])
    assert summary["collisions"] == 0, summary
