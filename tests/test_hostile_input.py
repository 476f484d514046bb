"""Hostile and degenerate input (issue 17): nothing on the link may raise the commanded speed, blind the
daemon or stop its loop; whatever is implausible is counted, logged and answered with the safe action.
Lock-step flights with real MAVLink bytes from a second encoder on the vehicle's link."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.onboard.console import event_line
from companion.onboard.config import ContractConfig, SensorConfig, config_from_dict
from companion.onboard.estimators import DodEstimator
from companion.onboard.mavlink_in import MavlinkIn, range_scan
from companion.onboard.states import CYCLE_COMPLETES
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly

AUTOPILOT = mav.MAVLink(None, srcSystem=1, srcComponent=1)
PERIPHERAL = mav.MAVLink(None, srcSystem=1, srcComponent=158)  # MAV_COMP_ID_PERIPHERAL: a sensor on the vehicle
RATED_M = 6.0  # the scenario's sensor range, and its rating in the daemon config


def cruising(seconds=8.0, **config):
    rig = Rig(column_scenario(1, x_col=400.0), "px4", config=config or None)
    fly(rig, seconds)
    assert rig.daemon.last.state == "active" and rig.log.states[-1]["v_cmd"]
    return rig


def inject(rig, make, seconds, rate_hz=20.0, enc=PERIPHERAL):
    """Send `make(rig)` to the daemon at `rate_hz` for `seconds` of flight."""
    for _ in range(int(seconds * rate_hz)):
        rig.to_daemon(make(rig), enc)
        rig.run(1.0 / rate_hz)


def after(rig, t0):
    return [s for s in rig.log.states if s["t"] >= t0]


# ------------------------------------------------------------------ item 1: one message stops the loop
def bins(inc_f=5.0, offset=-30.0, dist=None, min_cm=20, max_cm=600, frame=12):
    d = list(dist) if dist is not None else [max_cm + 1] * 13 + [65535] * 59
    return PERIPHERAL.obstacle_distance_encode(0, 0, d, 0, min_cm, max_cm, inc_f, offset, frame)


@pytest.mark.parametrize("inc_f", [math.inf, -math.inf, math.nan])
def test_a_non_finite_bin_increment_is_dropped_and_the_loop_goes_on(inc_f):
    rig = cruising(sensors=[{"kind": "distance_sensor", "h_fov_deg": 30},
                            {"kind": "obstacle_distance", "h_fov_deg": 60, "component_id": 158}])
    t0 = rig.sim.time_s
    rig.to_daemon(bins(inc_f=inc_f), PERIPHERAL)
    rig.run(3.0)  # lock-step: a cycle that raised would end this test
    states = after(rig, t0)
    assert states[-1]["t"] > t0 + 2.8 and max(np.diff([t0] + [s["t"] for s in states])) < 0.2  # samples all along
    assert not rig.log.named("loop_error")
    ev = [e for e in rig.log.named("implausible_input") if e["message"] == "OBSTACLE_DISTANCE"]
    assert ev and rig.daemon.counters.implausible >= 1


def test_an_exception_inside_the_cycle_ends_in_hold_and_is_logged(monkeypatch):
    rig = cruising()
    t0 = rig.sim.time_s

    def broken(i):
        raise ZeroDivisionError("a bug")

    with monkeypatch.context() as m:
        m.setattr(rig.daemon.cycle.sup, "step", broken)
        rig.run(2.5)
    rig.run(0.2)
    # the daemon's own guarantee broken from the first failed cycle to the next that completed
    (start,) = [e for e in rig.log.named("violation_start") if e["subsystem"] == "guidance"]
    (end,) = [e for e in rig.log.named("violation_end") if e["subsystem"] == "guidance"]
    assert start["guarantee"] == end["guarantee"] == CYCLE_COMPLETES and start["t"] - t0 < 0.05
    assert end["observed"] == rig.daemon.counters.loop_errors and end["t"] == pytest.approx(t0 + 2.5, abs=0.05)
    assert event_line("violation_start", start)[1].startswith("VIOLATION guidance: every cycle decides")
    assert event_line("violation_end", end)[1] == (f"violation over: guidance (cycles complete again after "
                                                   f"{rig.daemon.counters.loop_errors} that failed)")
    errs = [e for e in rig.log.named("loop_error") if e["t"] >= t0]
    assert errs and errs[0]["action"] == "hold" and "ZeroDivisionError" in errs[0]["error"]
    holds = [e for e in rig.log.named("command") if e["cmd"] == "hold" and e["t"] >= t0]
    assert holds and holds[0]["t"] - t0 < 0.1
    assert len(holds) == 1  # asked every failed cycle, sent once: the autopilot answered it (no re-send needed)
    assert [e for e in rig.log.named("command_ack") if e["t"] >= holds[0]["t"]]
    beats = [m for m in rig.daemon_messages() if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 191]
    assert beats[-1].system_status == mav.MAV_STATE_CRITICAL


# ------------------------------------------------------------------ item 4: a sensor's word for its range
def lying_range(rig):
    """A second forward sensor (id 5) claiming 655.35 m and nothing in range."""
    return PERIPHERAL.distance_sensor_encode(0, 10, 65535, 65535, 0, 5, 0, 255, 0.5, 0.0, [0.0] * 4, 100)


def test_a_sensor_claiming_655_m_does_not_raise_dod_or_the_speed():
    rig = cruising(sensors=[{"kind": "distance_sensor", "id": 0, "h_fov_deg": 30},
                            {"kind": "distance_sensor", "id": 5, "h_fov_deg": 30, "component_id": 158}])
    t0 = rig.sim.time_s
    v_before = rig.log.states[-1]["v_cmd"]
    inject(rig, lying_range, 4.0)
    states = after(rig, t0)
    assert max(s["d_od"] for s in states) <= RATED_M + 1e-9
    assert max(s["v_cmd"] or 0.0 for s in states) <= v_before + 1e-9
    sent = [m.param2 for m in rig.daemon_messages() if m.get_type() == "COMMAND_LONG"
            and m.command == mav.MAV_CMD_DO_CHANGE_SPEED]
    assert max(sent) <= v_before + 1e-6


def test_min_above_max_is_a_navigation_fault_and_the_daemon_holds():
    rig = cruising()
    t0 = rig.sim.time_s
    inject(rig, lambda r: AUTOPILOT.distance_sensor_encode(0, 1000, 500, 300, 0, 0, 0, 100), 1.0, enc=AUTOPILOT)
    assert [e for e in rig.log.named("implausible_input") if e["t"] >= t0]
    assert [e for e in rig.log.named("failsafe") + rig.log.named("hold_trigger") if e["t"] >= t0]


def test_a_reading_below_the_minimum_is_not_free_space():
    cfg = SensorConfig(h_fov_deg=30.0, max_range_m=10.0)
    e = DodEstimator([cfg], ContractConfig(), 0.5)
    e.add_scan(range_scan(0.0, 0, 0.0, 0.05, 0.2, 10.0, 100, cfg.max_range_m))  # below min_distance
    assert e.estimate(0.0, 0.0).d_od == 0.0
    e.add_scan(range_scan(0.05, 0, 0.0, 10.0, 0.2, 10.0, 100, cfg.max_range_m))  # nothing within range
    assert e.estimate(0.05, 0.0).d_od == 10.0


def _bins_dod(distances, rated=8.0):
    """D_od along the heading from one OBSTACLE_DISTANCE through MAVLink-in and the estimator."""
    cfg = config_from_dict({"mode": "shadow", "sensors": [{"kind": "obstacle_distance", "h_fov_deg": 60,
                                                          "max_range_m": rated}]})
    inp = MavlinkIn(cfg, None, lambda: 0.0, None)
    e = DodEstimator(list(cfg.sensors), cfg.contract, 0.5)
    msg = mav.MAVLink_obstacle_distance_message(0, 0, list(distances), 0, 20, 1000, 5.0, -30.0, 12)
    for s in inp.samples(0.0, "OBSTACLE_DISTANCE", msg):
        e.add_scan(s) if hasattr(s, "hits") else None
    return e.estimate(0.0, 0.0).d_od


def test_bins_that_know_nothing_are_not_free_space():
    assert _bins_dod([65535] * 72) == 0.0  # every bin unknown
    gap = [1001] * 13 + [65535] * 59
    gap[6] = 65535  # the bin straight ahead knows nothing
    assert _bins_dod(gap) == 0.0
    assert _bins_dod([1001] * 13 + [65535] * 59) == 8.0  # all clear: capped at the rating (claims 10 m)


# ------------------------------------------------------------------ item 7: parameters from anyone
def param_set(rig, name, value, src=255):
    enc = mav.MAVLink(None, srcSystem=src, srcComponent=190)
    rig.to_daemon(enc.param_set_encode(1, 191, name.encode(), value, 9), enc)
    rig.run(0.1)


@pytest.mark.parametrize("name,value,src", [("CG_R_OBST", 0.0, 255), ("CG_R_OBST", 1e30, 255),
                                            ("CG_ENGAGE", 1e30, 255), ("CG_ENGAGE", 0.0, 42),
                                            ("CG_R_OBST", 0.6, 42), ("CG_MODE", 2.0, 255)])
def test_a_parameter_set_out_of_range_or_from_a_stranger_is_refused(name, value, src):
    rig = cruising()
    before = dict(rig.daemon.params)
    v_before = rig.log.states[-1]["v_cmd"]
    param_set(rig, name, value, src)
    rig.run(3.0)
    assert rig.daemon.params == before
    refused = rig.log.named("param_refused")
    assert refused and refused[-1]["param"] == name and refused[-1]["source"] == src
    assert max(s["v_cmd"] or 0.0 for s in rig.log.states[-30:]) <= v_before + 1e-9
    echoed = [m.param_value for m in rig.daemon_messages() if m.get_type() == "PARAM_VALUE" and m.param_id == name]
    assert echoed and echoed[-1] == pytest.approx(before[name])  # the acknowledgement carries the value kept


def test_a_configured_ground_station_may_still_set_r_obst_in_range():
    rig = cruising()
    param_set(rig, "CG_R_OBST", 0.6)
    assert rig.daemon.params["CG_R_OBST"] == pytest.approx(0.6)
    assert rig.log.named("param_set")[-1]["new"] == pytest.approx(0.6)


# ------------------------------------------------------------------ item 8: implausible state
def test_a_velocity_of_a_million_metres_a_second_is_a_navigation_fault():
    rig = cruising()
    t0 = rig.sim.time_s
    inject(rig, lambda r: AUTOPILOT.local_position_ned_encode(int(r.sim.time_s * 1000), r.truth["pos"][0],
                                                              r.truth["pos"][1], -2.0, 1e6, 0.0, 0.0),
           0.5, enc=AUTOPILOT)
    fs = [e for e in rig.log.named("failsafe") if e["t"] >= t0]
    assert fs and fs[0]["cause"] == "bad navigation estimate" and fs[0]["t"] - t0 < 0.3
    assert max(s["ground_speed"] for s in after(rig, t0) if s["ground_speed"] == s["ground_speed"]) < 20.0
    assert [e for e in rig.log.named("implausible_input") if e["message"] == "LOCAL_POSITION_NED"]


def test_implausible_messages_are_counted_once_each_and_logged_at_most_once_a_second():
    rig = cruising()
    n0 = rig.daemon.counters.implausible
    inject(rig, lambda r: AUTOPILOT.attitude_encode(0, math.nan, 0.0, 0.0, 0, 0, 0), 2.0, rate_hz=50, enc=AUTOPILOT)
    assert rig.daemon.counters.implausible - n0 == 100
    ev = [e for e in rig.log.named("implausible_input") if e["message"] == "ATTITUDE"]
    assert 2 <= len(ev) <= 3 and sum(e["count"] for e in ev) <= 100
    assert np.isfinite(rig.daemon.tel.roll)


# ------------------------------------------------------------------ item 10: misleading records
def test_a_link_loss_is_not_a_mode_change_by_someone_else():
    rig = cruising()
    t0 = rig.sim.time_s
    saved = rig._pump
    rig._pump = lambda: rig.link.client_recv()  # nothing reaches the daemon for a while
    rig.run(3.0)
    rig._pump = saved
    rig.run(3.0)
    links = [e["status"] for e in rig.log.named("link") if e["t"] >= t0]
    assert links == ["down", "up"]
    assert not [e for e in rig.log.named("mode_change") if e["t"] >= t0 and (e["by"] == "other" or e["to"] == "other")]
    assert not [e for e in rig.log.named("state_change") if e["t"] >= t0 and "someone else" in e["reason"]]


def test_frames_of_an_unknown_message_id_are_not_counted_as_good_messages():
    """pymavlink hands over a well-framed message of an id it does not know as UNKNOWN_<id>."""
    rig = cruising()
    c = rig.daemon.counters
    n0, u0 = c.messages, c.unknown_messages
    rig.daemon.feed(mav.MAVLink_unknown(60000, b"\x00" * 9))
    assert (c.messages, c.unknown_messages) == (n0, u0 + 1)


def test_an_autopilot_restart_runs_the_start_up_checks_again():
    rig = cruising()
    t0 = rig.sim.time_s
    checks = len(rig.log.named("startup_check"))
    rig.to_daemon(AUTOPILOT.system_time_encode(0, 150), AUTOPILOT)  # boot clock back to 0.15 s
    rig.run(6.0)
    assert [e for e in rig.log.named("autopilot_restart") if e["t"] >= t0]
    again = [m for m in rig.daemon_messages() if m.get_type() == "PARAM_REQUEST_READ"]
    assert len(again) >= 2 * len(rig.daemon.checks.wanted())  # asked at link-up and again after the restart
    assert rig.daemon.startup_ok is True and len(rig.log.named("startup_check")) == checks + 1


def test_the_start_up_verdict_is_logged_when_it_changes_only():
    rig = cruising()
    n = len(rig.log.named("startup_check"))
    for _ in range(5):  # a ground station reading the whole list: the autopilot sends every parameter again
        rig.gcs.send(rig.gcs.param_request_list_encode(1, 1))
        rig.run(0.5)
    assert len(rig.log.named("startup_check")) == n == 1


def test_sighup_takes_the_shutdown_path(tmp_path):
    """SIGHUP (a closed terminal, a reload) ends the daemon like SIGTERM: shutdown, the `stop` record."""
    import signal
    import socket
    import subprocess
    import sys
    import time

    import yaml

    from companion.onboard.eventlog import read_events

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(yaml.safe_dump({"vehicle": "mambo", "mode": "shadow", "link": {"connect": f"udpin:127.0.0.1:{port}"},
                                   "sensors": [{"h_fov_deg": 30}], "log": {"dir": str(tmp_path / "log")}}))
    p = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 60
        while not (tmp_path / "log").exists() or not any(r.get("event") == "start" for r in read_events(tmp_path / "log")):
            assert time.time() < deadline and p.poll() is None, p.stderr.read() if p.poll() is not None else "no start"
            time.sleep(0.2)
        p.send_signal(signal.SIGHUP)
        assert p.wait(30) == 0
    finally:
        if p.poll() is None:
            p.kill()
    assert [r for r in read_events(tmp_path / "log") if r.get("event") == "stop"]


# ------------------------------------------------------------------ item 5: signing
KEY = bytes(range(32))


def signed_rig(clock_file, engage=False):
    from companion.onboard.link import SigningClock, setup_signing

    rig = Rig(column_scenario(1, x_col=300.0), "px4", config={"engage": engage}, sim_kwargs={"signing_key": KEY})
    clock = SigningClock(clock_file)
    setup_signing(rig.conn, KEY, clock)
    rig.daemon.signing_clock = clock
    return rig


def signer(key=KEY, ts=None, src=(255, 190), link_id=0):
    m = mav.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    m.signing.secret_key, m.signing.sign_outgoing, m.signing.link_id = key, True, link_id
    from companion.onboard.link import SIGNING_EPOCH
    import time as _time

    m.signing.timestamp = ts if ts is not None else int((_time.time() - SIGNING_EPOCH) * 1e5)
    return m


def test_forged_signatures_change_nothing(tmp_path):
    """256 wrongly signed HEARTBEATs claiming the autopilot's ids and timestamp 2⁴⁸−1: the real, signed
    stream goes on being accepted (pymavlink alone stores the timestamp before checking the HMAC)."""
    rig = signed_rig(tmp_path / "signing.json")
    fly(rig, 4.0)
    forger = signer(key=bytes(32), ts=2 ** 48 - 1, src=(1, 1))
    for _ in range(256):
        rig.to_daemon(forger.heartbeat_encode(2, 12, 0, 0, 4), forger)
    rig.run(0.2)
    before = rig.daemon.counters.messages
    rig.run(3.0)
    assert rig.daemon.counters.messages - before > 300  # the vehicle's telemetry is still taken
    assert rig.daemon.counters.rejected_signature >= 256
    assert not rig.log.named("failsafe") and rig.daemon.last.state != "failsafe"
    assert all(ts < 2 ** 48 - 1 for ts in rig.conn.mav.signing.stream_timestamps.values())


def test_the_signed_stream_table_is_bounded(tmp_path):
    from companion.onboard.link import MAX_STREAMS

    rig = signed_rig(tmp_path / "signing.json")
    fly(rig, 2.0)
    for link_id in range(200):  # 200 correctly signed streams (a key holder, or a replay of many)
        s = signer(link_id=link_id)
        rig.to_daemon(s.heartbeat_encode(6, 8, 0, 0, 4), s)
    wrong = signer(key=bytes(32))
    for k in range(2000):  # and wrong-key packets, which must leave no trace at all
        wrong.signing.link_id = k % 256
        rig.to_daemon(wrong.heartbeat_encode(6, 8, 0, 0, 4), wrong)
    rig.run(0.5)
    assert len(rig.conn.mav.signing.stream_timestamps) <= MAX_STREAMS


def test_a_captured_engage_replayed_after_a_restart_does_not_engage(tmp_path):
    clock_file = tmp_path / "signing.json"
    rig = signed_rig(clock_file)
    fly(rig, 3.0)
    gcs = signer()
    captured = gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9).pack(gcs)  # what an eavesdropper records
    rig._daemon_in.append(captured)
    rig.run(0.3)
    assert rig.daemon.params["CG_ENGAGE"] == 1.0  # taken once, in the first run
    # kill -9 and restart: a new daemon process with the persisted signing state, and the replay
    again = signed_rig(clock_file)
    fly(again, 3.0)
    rejected = again.daemon.counters.rejected_signature
    again._daemon_in.append(captured)
    again.run(0.5)
    assert again.daemon.params["CG_ENGAGE"] == 0.0
    assert again.daemon.counters.rejected_signature == rejected + 1
    assert not again.log.named("param_set")


# ------------------------------------------------------------------ item 6: time from anyone
def fake_autopilot_flight(tmp_path, boot_ms, seconds=6.0, extra=None):
    """The daemon as a process against a scripted autopilot on loopback UDP; `boot_ms(t_host)` is the
    autopilot's time_boot_ms. Returns (the daemon's event log, its HEARTBEAT arrival times)."""
    import signal
    import socket
    import subprocess
    import sys
    import time

    import yaml

    from companion.onboard.eventlog import read_events

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.02)
    port = sock.getsockname()[1]
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(yaml.safe_dump({"vehicle": "mambo", "mode": "shadow",
                                   "link": {"connect": f"udpout:127.0.0.1:{port}"},
                                   "sensors": [{"h_fov_deg": 30, "max_range_m": 6}],
                                   "log": {"dir": str(tmp_path / "log")}}))
    d = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg), "--quiet"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    ap = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    beats, peer, t_first, t_start = [], None, None, time.monotonic()
    try:
        while True:
            now = time.monotonic()
            if t_first is None and now - t_start > 90:
                break  # the daemon never spoke
            if t_first is not None and now - t_first > seconds:
                break
            try:
                data, peer = sock.recvfrom(4096)
                t_first = t_first or time.monotonic()
                for m in ap.parse_buffer(data) or []:
                    if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 191:
                        beats.append(time.monotonic())
            except socket.timeout:
                pass
            if peer is None:
                continue
            tb = int(boot_ms(time.monotonic() - t_first)) & 0xFFFFFFFF
            for msg in (ap.heartbeat_encode(2, 12, 1 | 128, 4 << 16 | 4 << 24, 4),
                        ap.system_time_encode(0, tb), ap.attitude_encode(tb, 0, 0, 0, 0, 0, 0),
                        ap.local_position_ned_encode(tb, 0, 0, -2, 0, 0, 0)):
                sock.sendto(msg.pack(ap), peer)
            for data in extra(tb) if extra else ():
                sock.sendto(data, peer)
    finally:
        d.send_signal(signal.SIGTERM)
        d.wait(30)
        sock.close()
    return read_events(tmp_path / "log"), beats


@pytest.mark.parametrize("name,boot_ms", [("slow x0.01", lambda th: 5000 + 10 * th),
                                          ("jump 1e6 s", lambda th: 5000 + 1000 * th + (1e9 if th > 2 else 0))])
def test_an_autopilot_clock_at_the_wrong_rate_or_jumping_is_a_fault_not_our_time(name, boot_ms, tmp_path):
    log, beats = fake_autopilot_flight(tmp_path, boot_ms)
    faults = [r for r in log if r.get("event") == "implausible_input" and r.get("message") == "time_boot_ms"]
    assert faults, f"{name}: the autopilot's clock fault was not logged"
    gaps = [b - a for a, b in zip(beats, beats[1:])]
    assert len(beats) >= 4 and max(gaps) < 1.6 and min(gaps) > 0.6  # our heartbeat: 1 Hz of host time


def sitl_clock(rate: float, stall_s: float, catch_up: float, seconds: float = 30.0, every_s: float = 2.0):
    """(host s, time_boot_ms) of a SITL paced to the host's clock at `rate` (as sitl_harness/serve.py paces its
    ticks): every `every_s` the host starves it for `stall_s` (its clock creeps at 0.45× its rate), then it
    catches up at `catch_up`× its rate until back on its schedule. Messages every 20 ms of host time."""
    out, tv, th = [], 0.0, 0.0
    starved_until = -1.0
    while th < seconds:
        th += 0.02
        if th % every_s < 0.02:
            starved_until = th + stall_s
        behind = rate * th - tv
        step = rate * 0.02 * (0.45 if th < starved_until else catch_up)
        tv += step if th < starved_until else min(step, behind)
        out.append((th, int(tv * 1000)))
    return out


@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_a_sitl_that_runs_behind_and_catches_up_is_not_a_clock_fault(rate):
    """A SITL on a loaded host starts its ticks late and catches up (its own tick jitter): its clock read over one
    second ran at 0.45× its rate ("runs at 0.952× the host's, expected 2×"), which was a navigation fault — a
    would-Hold in a shadow flight — though its clock keeps its rate."""
    from companion.onboard.mavlink_in import VehicleClock

    host = [0.0]
    clock = VehicleClock(lambda: host[0], rate=rate)
    faults = []
    for th, tb in sitl_clock(rate, stall_s=0.8, catch_up=3.0):
        host[0] = th
        clock.observe(tb)
        faults.append(clock.fault)
    assert not any(faults), next(f for f in faults if f)


@pytest.mark.parametrize("rate,ratio,within_s", [(1.0, 0.5, 3.0), (2.0, 0.476, 3.0), (1.0, 2.0, 1.5),
                                                 (1.0, 0.7, 6.0), (2.0, 0.01, 1.5)])
def test_a_clock_at_the_wrong_rate_is_a_fault_whatever_the_tick_jitter_allowance(rate, ratio, within_s):
    """The control: a steady wrong rate (a wrong link.clock_rate, a SITL starved for good) drifts out of the tick
    jitter's allowance and is a fault within a few seconds, and stays one."""
    from companion.onboard.mavlink_in import VehicleClock

    host = [0.0]
    clock = VehicleClock(lambda: host[0], rate=rate)
    seen = []
    for k in range(1, 1500):
        host[0] = 0.02 * k
        clock.observe(int(5000 + 1000 * rate * ratio * host[0]))
        seen.append((host[0], clock.fault))
    first = next(t for t, f in seen if f)
    assert first <= within_s and all(f for t, f in seen if t > first + 0.1)


def test_another_components_boot_clock_is_not_the_autopilots(tmp_path):
    peripheral = mav.MAVLink(None, srcSystem=1, srcComponent=158)

    def sensor(tb):
        m = peripheral.distance_sensor_encode((tb * 6 + 777_000) & 0xFFFFFFFF, 10, 600, 601, 0, 0, 0, 255)
        return [m.pack(peripheral)]

    log, beats = fake_autopilot_flight(tmp_path, lambda th: 5000 + 1000 * th, extra=sensor)
    assert not [r for r in log if r.get("event") == "implausible_input" and r.get("message") == "time_boot_ms"]
    assert len(beats) >= 4 and max(b - a for a, b in zip(beats, beats[1:])) < 1.6


# ------------------------------------------------------------------ item 9: a failing log is said
def test_a_log_that_cannot_write_is_said_to_the_ground_station(tmp_path):
    from companion.onboard.eventlog import EventLog

    (tmp_path / "file").write_text("not a directory")
    log = EventLog(tmp_path / "file" / "logs")  # cannot be created: a read-only or broken log directory
    rig = Rig(column_scenario(1, x_col=300.0), "px4", log=log)
    fly(rig, 3.0)
    assert any(t.startswith("CG: event log failing") for t in rig.daemon_texts())
    assert rig.daemon.last.state in ("active", "standby")  # and the daemon flies on


# ------------------------------------------------------------------ items 2, 3: the UDP link
def listening_daemon_flight(tmp_path, attack, seconds=6.0, key=None, run="log", stop=None):
    """The daemon as a process listening on loopback UDP (udpin), a scripted autopilot sending to it at
    50 Hz (signed with `key`, which the daemon then requires), and `attack(daemon_addr)` called every
    autopilot cycle; stopped with `stop` (default SIGTERM). Returns the daemon's event log (`run`: its
    folder's name under tmp_path)."""
    import signal
    import socket
    import subprocess
    import sys
    import time

    import yaml

    from companion.onboard.eventlog import read_events

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = tmp_path / "cg.yaml"
    link = {"connect": f"udpin:127.0.0.1:{port}"}
    if key is not None:
        (tmp_path / "key").write_bytes(key)
        (tmp_path / "key").chmod(0o600)
        link.update(signing_key_file=str(tmp_path / "key"), signing_timestamp_file=str(tmp_path / "signing.json"))
    cfg.write_text(yaml.safe_dump({"vehicle": "mambo", "mode": "shadow", "link": link,
                                   "sensors": [{"h_fov_deg": 30, "max_range_m": 6}],
                                   "log": {"dir": str(tmp_path / run)}}))
    d = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg), "--quiet"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(0.02)
    ap = signer(key, src=(1, 1)) if key is not None else mav.MAVLink(None, srcSystem=1, srcComponent=1)
    target, t_first, t_start = ("127.0.0.1", port), None, time.monotonic()
    try:
        while time.monotonic() - t_start < 90 and (t_first is None or time.monotonic() - t_first < seconds):
            tb = int((time.monotonic() - t_start) * 1000)
            for msg in (ap.heartbeat_encode(2, 12, 1 | 128, 4 << 16 | 4 << 24, 4), ap.attitude_encode(tb, 0, 0, 0, 0, 0, 0),
                        ap.local_position_ned_encode(tb, 1.0, 2.0, -2, 0, 0, 0)):
                sock.sendto(msg.pack(ap), target)
            try:
                sock.recvfrom(4096)
                t_first = t_first or time.monotonic()
            except (socket.timeout, ConnectionRefusedError):
                pass
            if t_first is not None:
                attack(target)
    finally:
        d.send_signal(stop or signal.SIGTERM)
        d.wait(30)
        sock.close()
    assert t_first is not None, "the daemon never answered"
    return read_events(tmp_path / run)


def test_two_bytes_from_anyone_do_not_blind_the_daemon(tmp_path):
    """`fd ff` — a MAVLink 2 start and a huge length — 100 times a second from another socket: pymavlink's
    shared parse buffer waited for 255 bytes and swallowed the autopilot's next datagrams."""
    import socket

    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def attack(target):
        junk.sendto(b"\xfd\xff", target)
        junk.sendto(b"\xfd\xff", target)

    log = listening_daemon_flight(tmp_path, attack)
    junk.close()
    links = [r["status"] for r in log if r.get("event") == "link"]
    assert links == ["up"]  # never down
    states = [r for r in log if r.get("kind") == "state" and r.get("x") is not None]
    assert len(states) > 40 and all(r["x"] == 1.0 for r in states)
    assert not [r for r in log if r.get("event") == "would_hold" and "stale telemetry" in r.get("causes", [])]


def test_the_autopilot_is_taken_from_its_address_only_and_the_clients_are_bounded(tmp_path):
    """A second sender claiming the autopilot's ids (a spoofer) is dropped; 300 other senders do not all
    become clients that the daemon answers."""
    import socket

    from companion.onboard.link import MAX_CLIENTS

    spoof = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fake = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    crowd = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(300)]
    for s in crowd:
        s.setblocking(False)
    stranger = mav.MAVLink(None, srcSystem=200, srcComponent=190)
    sent = {"n": 0}

    def attack(target):
        spoof.sendto(fake.local_position_ned_encode(0, 1000.0, 1000.0, -2, 0, 0, 0).pack(fake), target)
        for s in crowd[sent["n"] % 300: sent["n"] % 300 + 10]:
            s.sendto(stranger.heartbeat_encode(6, 8, 0, 0, 4).pack(stranger), target)
        sent["n"] += 10

    log = listening_daemon_flight(tmp_path, attack)
    answered = 0
    for s in crowd:
        try:
            s.recvfrom(4096)
            answered += 1
        except (BlockingIOError, ConnectionRefusedError):
            pass
        s.close()
    spoof.close()
    states = [r for r in log if r.get("kind") == "state" and r.get("x") is not None]
    assert states and all(r["x"] == 1.0 for r in states)  # never the spoofer's 1000 m
    assert answered <= MAX_CLIENTS


def test_a_signed_engage_replayed_over_udp_after_kill_9_does_not_engage(tmp_path):
    """Over loopback UDP with the daemon as a process: a signed ground station's CG_ENGAGE is taken; the
    daemon is killed (-9) and restarted; the captured datagram sent again is refused."""
    import signal
    import socket

    gcs_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs = signer(KEY)
    captured = {"data": None, "sent": 0}

    def engage_once(target):
        if captured["data"] is None:
            captured["data"] = gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9).pack(gcs)
        if captured["sent"] < 1:
            gcs_sock.sendto(captured["data"], target)
            captured["sent"] += 1

    first = listening_daemon_flight(tmp_path, engage_once, seconds=3.0, key=KEY, run="first", stop=signal.SIGKILL)
    assert [r for r in first if r.get("event") == "param_set" and r.get("param") == "CG_ENGAGE"]

    def replay(target):
        if captured["sent"] < 3:
            gcs_sock.sendto(captured["data"], target)
            captured["sent"] += 1

    second = listening_daemon_flight(tmp_path, replay, seconds=3.0, key=KEY, run="second")
    gcs_sock.close()
    assert captured["sent"] == 3
    assert not [r for r in second if r.get("event") == "param_set"]
    stop = [r for r in second if r.get("event") == "stop"]
    assert stop and stop[0]["counters"]["rejected_signature"] >= 2


def test_a_flood_on_the_port_costs_each_poll_a_bounded_read_and_the_autopilot_is_read_in_full(monkeypatch):
    """Issue 17 item 3: with the autopilot on its own socket, one poll reads at most
    PORT_DATAGRAMS_PER_POLL datagrams of the shared port (a flood there once took the whole poll budget,
    37 % of a core at 100 000/s), yet every autopilot message waiting is read, and a ground station's
    message behind a burst still comes through within a few polls."""
    import socket

    import companion.onboard.link as lk
    from companion.onboard.link import PORT_DATAGRAMS_PER_POLL, open_connection

    monkeypatch.setattr(lk, "SEAT_SETTLE_S", 0.0)  # the autopilot's seat at its first HEARTBEAT (no one else claims)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    link = open_connection(f"udpin:127.0.0.1:{port}", 0, 1, 191)
    ap_sock, junk, gcs_sock = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3))
    ap, gcs = mav.MAVLink(None, srcSystem=1, srcComponent=1), mav.MAVLink(None, srcSystem=255, srcComponent=190)
    target = ("127.0.0.1", port)

    def poll() -> list:
        got, m = [], link.recv_msg()
        while m is not None:
            got.append(m)
            m = link.recv_msg()
        return got

    try:
        ap_sock.sendto(ap.heartbeat_encode(2, 12, 1 | 128, 0, 4).pack(ap), target)
        for _ in range(200):  # until the autopilot is pinned on its own socket
            if poll() or link.ap_sock is not None:
                break
        assert link.ap_sock is not None
        for _ in range(3000):
            junk.sendto(b"\xfd\xff", target)
        gcs_sock.sendto(gcs.param_request_list_encode(1, 191).pack(gcs), target)
        for i in range(10):
            ap_sock.sendto(ap.attitude_encode(i, 0, 0, 0, 0, 0, 0).pack(ap), target)
        before = link.stats["datagrams"]
        first = poll()
        assert [m.get_type() for m in first].count("ATTITUDE") == 10  # the autopilot's, all of them
        assert link.stats["datagrams"] - before <= 10 + min(PORT_DATAGRAMS_PER_POLL, 512)  # a small part
        seen_gcs = any(m.get_type() == "PARAM_REQUEST_LIST" for m in first)
        for _ in range(3000 // PORT_DATAGRAMS_PER_POLL + 2):
            seen_gcs = seen_gcs or any(m.get_type() == "PARAM_REQUEST_LIST" for m in poll())
        assert seen_gcs
    finally:
        for s in (ap_sock, junk, gcs_sock):
            s.close()
        link.close()


def test_a_sample_its_taker_complains_of_is_dropped_counted_and_said(monkeypatch):
    """A sample that raises where it is taken (a decoder's or an estimator's complaint — or a fault of a speed
    policy) is dropped and counted, never fatal, and said in the event log: a fault is never silent."""
    rig = cruising()
    c, t0 = rig.daemon.counters, rig.sim.time_s

    def complain(s):
        raise ValueError("not a number I take")

    monkeypatch.setattr(rig.daemon.cycle.sup.policy, "take", complain)
    bad0 = c.bad_packets
    rig.run(0.5)
    assert c.bad_packets > bad0 and rig.daemon.last is not None
    said = [e for e in rig.log.named("sample_dropped") if e["t"] >= t0]
    assert said and "ValueError: not a number I take" in said[0]["error"] and said[0]["count"] >= 1
