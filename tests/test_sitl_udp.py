"""Real loopback UDP against the SITL in its own process: a pymavlink client flies both
personalities (take-off, a mission whose speed is changed in flight, each autopilot's
DO_CHANGE_SPEED semantics, landing), and a burst of malformed datagrams leaves the vehicle flying."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_client import PX4_HOLD, PX4_MISSION, PX4_TAKEOFF, Client, UdpTransport, geo_item
from sitl_process import sitl_process

SPEEDUP = 4.0
ACC, DEN, FAIL = mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_DENIED, mav.MAV_RESULT_FAILED


def connect(port):
    tr = UdpTransport(port, SPEEDUP)
    c = Client(tr)
    for _ in range(40):  # say hello until the vehicle answers
        c.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        c.pump(0.25)
        if "HEARTBEAT" in c.last and "LOCAL_POSITION_NED" in c.last:
            return c
    raise AssertionError("no telemetry from the SITL")


def px4_take_off(c, alt):
    """Arm, AUTO.TAKEOFF to `alt` above home (NAV_TAKEOFF takes AMSL), and wait for the Hold after it."""
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    home = c.wait_msg("HOME_POSITION", 5.0)
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 6, home.altitude / 1000 + alt) == ACC
    assert c.wait(lambda c: c.custom_mode == PX4_TAKEOFF, 2.0)
    assert c.wait(lambda c: c.custom_mode == PX4_HOLD, 20.0)


def mission_items(c, length, alt, ap):
    home = c.wait_msg("HOME_POSITION", 5.0)
    items = [geo_item(home, 0, 0, 0)] if ap else []
    return items + [geo_item(home, 0.0, 0.0, alt), geo_item(home, length, 0.0, alt)]


def test_pymavlink_flies_px4_mission_with_speed_change():
    with sitl_process("empty", "px4", SPEEDUP) as port:
        c = connect(port)
        try:
            assert c.param_set("MPC_XY_CRUISE", 2.0, mav.MAV_PARAM_TYPE_REAL32).param_value == pytest.approx(2.0)
            px4_take_off(c, 3.0)
            c.pump(1.0)
            assert c.pos[2] == pytest.approx(-3.0, abs=0.2)
            assert c.upload_mission(mission_items(c, 40.0, 3.0, ap=False)) == mav.MAV_MISSION_ACCEPTED
            assert c.set_mode(4, 4) == ACC
            c.pump(6.0)
            assert c.custom_mode == PX4_MISSION and c.speed_xy == pytest.approx(2.0, abs=0.25)
            assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == ACC
            c.pump(3.0)
            assert c.speed_xy == pytest.approx(1.0, abs=0.15)
            assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, -2.0, -1) == ACC  # ≤ 0 → MPC_XY_CRUISE
            c.pump(3.0)
            assert c.speed_xy == pytest.approx(2.0, abs=0.25)
            assert c.set_mode(4, 3) == ACC  # Hold: still acknowledged
            assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.5, -1) == ACC
            assert c.command(mav.MAV_CMD_NAV_LAND) == ACC
            assert c.wait(lambda c: not c.armed, 30.0)
        finally:
            c.tr.close()


def test_pymavlink_flies_ardupilot_mission_with_speed_change():
    with sitl_process("empty", "ardupilot", SPEEDUP) as port:
        c = connect(port)
        try:
            assert c.param_set("WPNAV_SPEED", 200.0, mav.MAV_PARAM_TYPE_REAL32).param_value == pytest.approx(200.0)
            assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == FAIL  # STABILIZE
            assert c.set_mode(4) == ACC
            assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
            assert c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 2.0) == ACC  # relative
            assert c.wait(lambda c: abs(c.pos[2] + 2.0) < 0.15, 20.0)
            assert c.upload_mission(mission_items(c, 40.0, 2.0, ap=True)) == mav.MAV_MISSION_ACCEPTED
            assert c.set_mode(3) == ACC  # AUTO
            c.pump(6.0)
            assert c.custom_mode == 3 and c.speed_xy == pytest.approx(2.0, abs=0.25)
            assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == ACC
            c.pump(3.0)
            assert c.speed_xy == pytest.approx(1.0, abs=0.15)
            assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 0.0, -1) == DEN  # ≤ 0 denied, speed kept
            c.pump(2.0)
            assert c.speed_xy == pytest.approx(1.0, abs=0.15)
            assert c.set_mode(9) == ACC  # LAND
            assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == FAIL
            assert c.wait(lambda c: not c.armed, 30.0)
        finally:
            c.tr.close()


def test_malformed_udp_burst_leaves_vehicle_flying():
    with sitl_process("empty", "px4", SPEEDUP) as port:
        c = connect(port)
        try:
            px4_take_off(c, 2.0)
            c.pump(1.0)
            p0 = np.array(c.pos)
            rng = np.random.default_rng(11)
            enc = mav.MAVLink(None, 245, 190)
            good = enc.command_long_encode(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0).pack(enc)
            for i in range(600):
                kind = i % 3
                if kind == 0:
                    pkt = rng.bytes(int(rng.integers(1, 280)))
                elif kind == 1:
                    pkt = good[: int(rng.integers(1, len(good) - 1))]
                else:
                    b = bytearray(good)
                    b[int(rng.integers(6, len(b)))] ^= 0x5A
                    pkt = bytes(b)
                c.tr.send(pkt)
            c.pump(2.0)
            assert c.armed and np.linalg.norm(np.array(c.pos) - p0) < 0.3
            assert c.last["HEARTBEAT"].custom_mode == PX4_HOLD
            assert c.command(mav.MAV_CMD_NAV_LAND) == ACC
            assert c.wait(lambda c: not c.armed, 30.0)
        finally:
            c.tr.close()


def test_serve_udpout_pushes_to_a_listening_client_and_reports():
    """`serve(..., listen='udpout:HOST:PORT')` pushes telemetry to a client that only listens
    (MAVSDK `udpin://`), sped up 10×; the summary reports ticks and pacing jitter."""
    import socket
    import threading

    from sitl_harness.serve import serve

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    port = rx.getsockname()[1]
    out = {}
    th = threading.Thread(target=lambda: out.update(serve("empty", "ardupilot", f"udpout:127.0.0.1:{port}", 10.0,
                                                          duration_s=5.0)))
    th.start()
    parser = mav.MAVLink(None)
    seen = []
    try:
        while len(seen) < 200:
            seen += [m for m in parser.parse_buffer(rx.recv(65535)) or [] if m.get_type() != "BAD_DATA"]
    finally:
        th.join(30)
        rx.close()
    hb = next(m for m in seen if m.get_type() == "HEARTBEAT")
    assert hb.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert out["ticks"] == 500 and out["sim_time_s"] == pytest.approx(5.0)
    assert 0.2 < out["wall_time_s"] < 5.0 and "jitter_ms_p99" in out


def test_cli_errors_are_one_line():
    import subprocess
    import sys

    from sitl_process import ROOT

    r = subprocess.run([sys.executable, "-m", "sitl_harness", "--scenario", "no_such_scenario"], cwd=ROOT,
                       capture_output=True, text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no_such_scenario" in r.stderr
    assert "Traceback" not in r.stderr


def test_cli_end_summary_is_written_for_a_person_and_json_for_a_machine():
    """The SITL's end-of-run summary was printed as a Python dict; now lines a person reads, and `--json` one
    JSON object with the same figures."""
    import json
    import subprocess
    import sys

    from sitl_process import ROOT

    def run(*extra):
        return subprocess.run([sys.executable, "-m", "sitl_harness", "--scenario", "empty", "--duration", "1",
                               "--speedup", "10", "--listen", "udpout:127.0.0.1:9", *extra], cwd=ROOT,
                              capture_output=True, text=True, timeout=60, check=False,
                              env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    text, js = run(), run("--json")
    assert text.returncode == 0 and js.returncode == 0, (text.stderr, js.stderr)
    lines = text.stdout.splitlines()
    assert lines[0].startswith("SITL stopped: 1.0 s simulated") and "{" not in text.stdout
    assert "collisions: 0" in text.stdout and "malformed (dropped)" in text.stdout
    assert json.loads(js.stdout)["ticks"] == 100
