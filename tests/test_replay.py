"""`contract-guard review FLIGHT.tlog`: a lock-step SITL flight recorded into a .tlog, replayed through the
table, checked against the live daemon's own event log of the same flight."""

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from companion.onboard.eventlog import EventLog, read_events
from companion.onboard.link import mavlink
from contracts.table import load_for_vehicle
from companion.ground.commands import review_log
from companion.onboard.logschema import REPLAY_LOG_FILE as REPLAY_LOG
from companion.ground.flightlogs.tlog import scan_tlog
from companion.ground.review import review
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly
from tests.test_offboard_lockstep import engage_and_fly, offboard_config, offboard_scenario

ROOT = Path(__file__).resolve().parents[1]
T0 = 1_790_000_000.0  # UNIX time of the simulator's t = 0 (the tlog's stamps)


def record(directory: Path, scenario, personality, config=None, outgoing=False, seconds=16.0, flight=fly,
           log_dir=None, keep: dict | None = None, rig_kwargs: dict | None = None):
    """Fly in lock-step with the daemon writing its event log and raw.tlog (stamped in sim time); with
    `outgoing`, the daemon's own packets go into the tlog too (a router or MAVProxy logging both ways);
    with `log_dir`, the SITL writes the autopilot's own flight log there too (`Rig.close_log`); `keep`
    gets the rig as "rig" (for its truth); `rig_kwargs`: more `Rig` arguments (e.g. a negative control's
    policy). Returns the config file the flight used."""
    box = {}

    def wall():
        return T0 + box["rig"].sim.time_s

    log = EventLog(directory, tlog=True, clock=wall, commit="none")
    rig = box["rig"] = Rig(scenario, personality, config={**(config or {}), "log": {"tlog": True}}, log=log,
                           log_dir=log_dir, **(rig_kwargs or {}))
    rig.daemon.wall = wall
    if keep is not None:
        keep["rig"] = rig
    if outgoing:
        send = rig.conn.write

        def both(buf):
            log.raw(int(wall() * 1e6), buf)
            send(buf)

        rig.conn.write = both
    flight(rig, seconds)
    log.close()
    rig.close_log()
    cfg = directory / "flight.yaml"
    cfg.write_text(yaml.safe_dump(rig.cfg.model_dump(mode="json", exclude_none=True)))
    return cfg


@pytest.fixture(scope="module")
def fog(tmp_path_factory):
    """PX4, governor, fog hides the column's first detection: a navigation violation. Daemon-written tlog."""
    d = tmp_path_factory.mktemp("fog")
    sc = column_scenario(1, x_col=40.0, faults=[{"at_s": 5.0, "fog": {"visibility_m": 3.0, "report": "hidden"}}])
    return d, record(d, sc, "px4", seconds=20.0)


@pytest.fixture(scope="module")
def thrust(tmp_path_factory):
    """ArduPilot, governor, thrust falls to half: an actuator violation. The tlog holds both directions."""
    d = tmp_path_factory.mktemp("thrust")
    sc = column_scenario(1, x_col=300.0, faults=[{"at_s": 10.0, "thrust_ratio": 0.5}])
    return d, record(d, sc, "ardupilot", config={"thrust": {"tau_s": 0.5}}, outgoing=True)


def states(path):
    return [r for r in read_events(path) if r["kind"] == "state"]


def disagreements(live, replayed, key, tol, offset, window=0.1):
    """Live sample times with no replayed sample within ±window s whose `key` is within `tol`."""
    bad = []
    for s in live:
        near = [r[key] for r in replayed if abs(r["t"] + offset - s["t"]) <= window + 1e-9]
        if not any(v is not None and s[key] is not None and abs(v - s[key]) <= tol for v in near):
            bad.append(s["t"])
    return bad


def offset_of(rep):
    """Live (sim) time of the replay's t = 0: the first packet's stamp."""
    return rep["replay"]["t0_unix"] - T0


def violations(rep, offset=0.0, skip=("controller",)):
    return [(v["subsystem"], v["start_t"] + offset, v["observed"])
            for v in rep["violations"] if v["subsystem"] not in skip]


def test_replayed_daemon_tlog_agrees_with_the_live_review(fog, tmp_path):
    d, cfg = fog
    live = review(d)
    rep, _ = review_log(d / "raw.tlog", tmp_path, config=cfg)
    off = offset_of(rep)
    assert 0.0 <= off <= 0.05  # the first poll of the flight

    lv, rv = violations(live), violations(rep, off)
    # the fog, read from its evidence, lowers D_od below the claim (once or in spells as the evidence comes and goes)
    assert lv and {v[0] for v in lv} == {"navigation"}, "the flight must break the navigation guarantee"
    assert [v[0] for v in rv] == [v[0] for v in lv]
    for (_, t_live, obs_live), (_, t_rep, obs_rep) in zip(lv, rv):
        # observed: the evidence's estimate, whose 1 s window ends a poll apart in the replay: within 5 cm
        assert t_rep == pytest.approx(t_live, abs=0.005) and obs_rep == pytest.approx(obs_live, abs=0.05)

    live_s, rep_s = states(d), states(tmp_path / REPLAY_LOG)
    assert len(rep_s) == pytest.approx(len(live_s), abs=5)
    speeds = load_for_vehicle("mambo").e_pred.axes[0]
    v_at = {s["t"]: s["v_max"] for s in live_s}
    # live samples beside a replayed one whose beam was untrusted (claim 0, below): V_max, and E_tr_pred with it, may
    # differ there
    untrusted = [r["t"] + off for r in rep_s if r["d_od_stated"] == 0.0]
    untrusted_in_replay = {s["t"] for s in live_s if any(abs(t - s["t"]) <= 0.1 + 1e-9 for t in untrusted)}
    for key, tol in (("d_od", 0.01), ("v_max", 0.02), ("e_tr", 0.02), ("thrust_ratio", 0.01)):
        bad = disagreements(live_s, rep_s, key, tol, off)
        if key == "e_tr":
            bad = [t for t in bad if t not in untrusted_in_replay]
            # E_tr_pred is a step function of V_max: where Ω's fixed point sits on one of its grid speeds (3.0 m/s
            # here, with the E_tr_pred rebuilt for issue 19 item 9), a hair's difference in the estimates flips E_tr
            # between the two cells' values (0.60 / 0.70 m) and V_max by 1 mm, both consistent answers: such
            # samples only, and few of them
            assert all(v_at[t] is not None and min(abs(speeds - v_at[t])) < 0.005 for t in bad), bad
            assert len(bad) <= 0.05 * len(live_s), bad
        elif key in ("d_od", "v_max"):  # (V_max follows D_od)
            # D_od from evidence: the medium's backscatter counted over a 1 s window of frames that the replay
            # steps at log time, a poll apart from the live daemon's: samples lowered by the evidence may differ,
            # and so may those where the beam was untrusted (claim 0: its nearest return the medium's, too weak
            # for its min_quality, in one frame and not the next), in either log; those at a trusted claim may not
            lowered = {s["t"] for s in live_s if s["d_od"] < s["d_od_stated"] - 1e-9 or s["d_od_stated"] == 0.0}
            lowered |= untrusted_in_replay
            assert [t for t in bad if t not in lowered] == [], key
            assert len(bad) <= 0.25 * len(live_s), (len(bad), len(live_s))
        else:
            assert bad == [], key
    assert {s["contract"] for s in rep_s} == {"stop"} and all(s["v_cmd"] is None for s in rep_s)  # shadow

    rp = rep["replay"]
    assert rp["packets"] > 4000 and rp["corrupt_packets"] == 0 and not rp["truncated_tail"]
    assert rp["autopilot"] == {"system": 1, "component": 1, "kind": "px4", "from": "config"}
    assert rp["missing_streams"] == {} and rp["slow_streams"] == [] and rp["in_flight"] is None
    assert rep["files"] == [str(d / "raw.tlog")] and (tmp_path / "review.png").exists()
    json.dumps(rep, allow_nan=False)


def test_negative_control_another_e_tr_floor_gives_another_v_max(fog, tmp_path):
    """The series comparison above can fail: replayed with an E_tr floor of 1 m instead of the flight's 0.3 m."""
    d, cfg = fog
    other = yaml.safe_load(cfg.read_text())
    other["contract"]["e_tr_floor_m"] = 1.0
    (tmp_path / "other.yaml").write_text(yaml.safe_dump(other))
    rep, _ = review_log(d / "raw.tlog", tmp_path / "out", config=tmp_path / "other.yaml")
    live_s, rep_s = states(d), states(tmp_path / "out" / REPLAY_LOG)
    # (judged where the flight had a speed to fly: in the fog both floors leave less than the autopilot's overshoot
    # budget, and both send nothing)
    flying = [s for s in live_s if s["v_max"]]
    assert len(disagreements(flying, rep_s, "v_max", 0.02, offset_of(rep))) > len(flying) // 2


def test_router_tlog_with_the_daemons_own_packets(thrust, tmp_path):
    """Both directions in the tlog: the autopilot is found by its HEARTBEAT, our daemon's packets do not
    confuse the replay, and its NAMED_VALUE_FLOATs are compared with the replayed values."""
    d, cfg = thrust
    live = review(d)
    rep, _ = review_log(d / "raw.tlog", config=cfg)
    off = offset_of(rep)
    lv, rv = violations(live), violations(rep, off)
    assert [v[0] for v in lv] == ["actuators"]
    assert [v[0] for v in rv] == ["actuators"] and rv[0][1] == pytest.approx(lv[0][1], abs=0.005)
    fl = rep["replay"]["in_flight"]
    assert fl["components"] == [[1, 191]] and fl["compared_part"] == "engaged" and fl["compared"]["v_max"] >= 15
    assert fl["max_abs_diff"]["v_max"] < 0.01 and fl["max_abs_diff"]["d_od"] < 0.01
    assert fl["commands"].get("change_speed", 0) >= 1
    assert any("actuators violation" in s["text"] for s in fl["statustext"])
    assert not any("in-flight" in f for f in rep["findings"])
    assert rep["replay"]["event_log"] is None  # no --out: the replayed log was temporary

    # without the flight's config (thrust estimate τ 2 s instead of 0.5 s) the replay misses the
    # violation, and the in-flight comparison says the replay is not the flight
    bare, _ = review_log(d / "raw.tlog", vehicle="mambo")
    assert bare["replay"]["autopilot"] == {"system": 1, "component": 1, "kind": "ardupilot", "from": "detected"}
    assert violations(bare) == []
    assert bare["replay"]["in_flight"]["max_abs_diff"]["v_max"] > 1.0
    assert any("replay differs from the in-flight daemon" in f for f in bare["findings"])


def test_an_offboard_flight_is_replayed_under_the_avoid_contract(tmp_path):
    d = tmp_path / "flight"
    cfg = record(d, offboard_scenario(1), "px4", config=offboard_config(), outgoing=True, seconds=22.0,
                 flight=engage_and_fly)
    rep, _ = review_log(d / "raw.tlog", tmp_path / "out", config=cfg)
    assert rep["replay"]["contract"] == "avoid"
    live_s, rep_s = states(d), states(tmp_path / "out" / REPLAY_LOG)
    assert {s["contract"] for s in live_s} == {s["contract"] for s in rep_s} == {"avoid"}
    assert any(s["mode"] == "offboard" for s in live_s)
    for key, tol in (("d_od", 0.01), ("v_max", 0.02)):
        assert disagreements(live_s, rep_s, key, tol, offset_of(rep)) == [], key
    fl = rep["replay"]["in_flight"]
    assert fl["compared_part"] == "engaged" and fl["compared"]["v_max"] >= 25 and fl["max_abs_diff"]["v_max"] < 0.01


def frames(data):
    s = scan_tlog(data)
    return [(s.offset[i], 8 + s.length[i]) for i in range(s.packets)]


def test_corrupt_and_truncated_tlog_is_replayed_with_the_damage_counted(fog, tmp_path):
    d, cfg = fog
    data = (d / "raw.tlog").read_bytes()
    fr = frames(data)
    broken = bytearray()
    flipped = {len(fr) // 5, len(fr) // 3, len(fr) // 2}  # a payload bit flipped: the CRC fails
    garbage_after = 2 * len(fr) // 3
    for k, (o, n) in enumerate(fr[:-1]):
        chunk = bytearray(data[o:o + n])
        if k in flipped:
            chunk[8 + 10] ^= 0x40
        broken += chunk
        if k == garbage_after:
            broken += b"\x00" * 37
    o, n = fr[-1]
    broken += data[o:o + n - 5]  # the last packet torn
    (tmp_path / "broken.tlog").write_bytes(bytes(broken))

    rep, _ = review_log(tmp_path / "broken.tlog", config=cfg)
    rp = rep["replay"]
    assert rp["corrupt_packets"] == 4 and rp["truncated_tail"] is True
    assert rp["packets"] == len(fr) - 3 - 1
    assert rp["skipped_bytes"] == sum(fr[k][1] for k in flipped) + 37 + fr[-1][1] - 5
    assert violations(rep) and {v[0] for v in violations(rep)} == {"navigation"}  # the flight is still there
    assert any("tlog damaged: 4 corrupt stretch(es) skipped and last packet torn" in f for f in rep["findings"])


def test_a_ground_station_style_tlog_says_what_it_lacks(fog, tmp_path):
    """A ground station's tlog: no range sensor or estimator messages, position at 2 Hz."""
    d, cfg = fog
    data = (d / "raw.tlog").read_bytes()
    parser = mavlink.MAVLink(None)
    kept, n_pos = bytearray(), 0
    for o, n in frames(data):
        kind = parser.decode(bytearray(data[o + 8:o + n])).get_type()
        if kind in ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE", "ESTIMATOR_STATUS"):
            continue
        if kind == "LOCAL_POSITION_NED":
            n_pos += 1
            if n_pos % 25:
                continue
        kept += data[o:o + n]
    (tmp_path / "gcs.tlog").write_bytes(bytes(kept))
    rep, _ = review_log(tmp_path / "gcs.tlog", vehicle="mambo")
    rp = rep["replay"]
    assert set(rp["missing_streams"]) == {"navigation health", "obstacle data (DISTANCE_SENSOR: D_od is 0 throughout)"}
    assert [s["stream"] for s in rp["slow_streams"]] == ["LOCAL_POSITION_NED"]
    assert rp["slow_streams"][0]["rate_hz"] == pytest.approx(2.0, abs=0.1)
    text = " | ".join(rep["findings"])
    assert "tlog lacks navigation health (ESTIMATOR_STATUS or EKF_STATUS_REPORT)" in text
    assert "LOCAL_POSITION_NED at 2.0 Hz in the tlog, too slow" in text
    assert rep["ranges"]["d_od"]["max"] == 0.0  # what the finding warns of


def test_log_time_is_monotone_and_clock_jumps_are_closed_up():
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = mav.heartbeat_encode(2, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 4)
    year = 365 * 86400 * 1_000_000
    base = int(T0 * 1e6)
    stamps = [0, 100_000, 50_000, 200_000, year, year + 100_000, year - 7_200_000_000, year - 7_199_900_000]
    unknown = bytes([0xFD, 1, 0, 0, 0, 1, 1, 0xAB, 0xCD, 0xEF, 7, 0, 0])  # a valid frame, message id unknown
    data = b"".join(struct.pack(">Q", base + s) + hb.pack(mav) for s in stamps[:4])
    data += struct.pack(">Q", base + 150_000) + unknown
    data += b"".join(struct.pack(">Q", base + s) + hb.pack(mav) for s in stamps[4:])
    s = scan_tlog(data)
    assert s.packets == 8 and s.unknown == 1 and s.corrupt == 0
    assert list(s.t_us) == [0, 100_000, 100_000, 200_000, 200_000, 300_000, 300_000, 400_000]
    assert [j["t"] for j in s.time_jumps] == [0.2, 0.3]
    assert list(s.raw_us) == [base + x for x in stamps]


# ----------------------------------------------------------------------------- the command line


def cg(*args):
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT)


def one_line_error(r):
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert r.stdout == "" and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("contract-guard: error: ")
    return lines[0]


def test_cli_replays_a_tlog(fog, tmp_path):
    d, cfg = fog
    out = tmp_path / "out"
    r = cg("review", d / "raw.tlog", "--config", cfg, "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["replay"]["event_log"] == str(out / REPLAY_LOG) and rep["violations_by_subsystem"]["navigation"]
    assert {p.name for p in out.iterdir()} == {REPLAY_LOG, "review.png", "plan.png", "review.html", "review.json",
                                              "samples.csv"}
    # the kept replay log reviews on its own, to the same violations
    again = review(out / REPLAY_LOG)
    assert violations(again) == violations(rep)
    r = cg("review", d / "raw.tlog", "--vehicle", "mambo", "--strict")
    assert r.returncode == 1 and "replayed" in r.stdout and "navigation" in r.stdout


def test_cli_error_lines(fog, tmp_path):
    d, cfg = fog
    (tmp_path / "empty.tlog").write_bytes(b"")
    assert "empty .tlog" in one_line_error(cg("review", tmp_path / "empty.tlog"))
    (tmp_path / "noise.tlog").write_bytes(bytes(range(256)) * 40)
    assert "no MAVLink packets in 10240 bytes" in one_line_error(cg("review", tmp_path / "noise.tlog"))

    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    gcs_only = b"".join(struct.pack(">Q", int(T0 * 1e6) + k * 1_000_000)
                        + mav.heartbeat_encode(6, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(mav) for k in range(5))
    (tmp_path / "gcs.tlog").write_bytes(gcs_only)
    line = one_line_error(cg("review", tmp_path / "gcs.tlog"))
    assert "no usable telemetry: no autopilot HEARTBEAT in 5 packets" in line and "255/190" in line

    other = yaml.safe_load(cfg.read_text())
    other["link"]["target_system"] = 7
    (tmp_path / "sys7.yaml").write_text(yaml.safe_dump(other))
    line = one_line_error(cg("review", d / "raw.tlog", "--config", tmp_path / "sys7.yaml"))
    assert "no usable telemetry: no HEARTBEAT or LOCAL_POSITION_NED from the autopilot 7/1" in line

    assert "replayed on its own" in one_line_error(cg("review", d / "raw.tlog", d))
    assert "apply only to a .tlog" in one_line_error(cg("review", d, "--vehicle", "mambo"))
    assert "no such file" in one_line_error(cg("review", tmp_path / "missing.tlog"))
    assert "vehicle" in one_line_error(cg("review", d / "raw.tlog", "--vehicle", "no-such-vehicle"))
