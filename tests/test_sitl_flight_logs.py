"""The SITL writes the autopilot's own flight log (issue 14): a ULog for the PX4 personality, a DataFlash
`.bin` for ArduPilot. Read back with the well-kept libraries (pyulog, pymavlink's DFReader), never a
hand-written reader, and checked against the simulator's truth in the real formats' units and frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink import DFReader
from pyulog import ULog

from sitl_harness import Sim
from sitl_harness.__main__ import build_parser
from sitl_harness.flightlog import Px4Log

SCENARIO = {"vehicle": "x500", "start": {"alt_m": 5.0, "yaw_deg": 30.0}, "world": {"columns": [{"x_m": 5.196, "y_m": 3.0, "radius_m": 0.5}]}}


def _fly(personality, tmp_path, seconds=4.0):
    from sitl_harness.scenario import scenario_from_dict

    sim = Sim(scenario_from_dict(SCENARIO), personality, log_dir=tmp_path)
    sim.step(seconds)
    truth = sim.truth()
    return sim.close_log(), truth, sim


def test_px4_ulog_reads_back_with_pyulog(tmp_path):
    path, truth, _ = _fly("px4", tmp_path)
    assert path.name == "flight-001.ulg" and path.parent == tmp_path
    u = ULog(str(path))
    top = {d.name: d.data for d in u.data_list}
    lp = top["vehicle_local_position"]
    rate = (len(lp["timestamp"]) - 1) / ((lp["timestamp"][-1] - lp["timestamp"][0]) / 1e6)
    assert rate == pytest.approx(10, rel=0.05)
    # metres NED, the last sample within one 100 ms step of the truth
    assert lp["z"][-1] == pytest.approx(truth["pos"][2], abs=0.1) and lp["z"][-1] < -4
    assert lp["xy_valid"].all()
    att = top["vehicle_attitude"]
    w, x, y, z = (att[f"q[{i}]"][-1] for i in range(4))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))  # Hamilton, w first, FRD→NED
    assert yaw == pytest.approx(truth["yaw"], abs=0.02) and yaw == pytest.approx(math.radians(30), abs=0.05)
    thr = top["vehicle_thrust_setpoint"]["xyz[2]"]
    assert np.all(thr < 0) and -thr[-1] == pytest.approx(truth["hover_thrust"], abs=0.1)  # FRD: up is negative
    assert top["vehicle_status"]["arming_state"][-1] == 2 and top["vehicle_status"]["nav_state"][-1] == 4  # ARMED, LOITER
    assert top["estimator_status"]["solution_status_flags"][-1] & 0x0B == 0x0B
    assert top["estimator_selector_status"]["primary_instance"][-1] == 0
    od = top["obstacle_distance"]
    assert od["frame"][-1] == 12 and od["increment"][-1] == pytest.approx(5.0)  # MAV_FRAME_BODY_FRD, degrees
    centre = int(np.argmin([abs(od["angle_offset"][-1] + od["increment"][-1] * k) for k in range(72)]))
    assert od[f"distances[{centre}]"][-1] == pytest.approx((6.0 - 0.5) * 100, abs=40)  # centimetres
    ds = top["distance_sensor"]
    assert ds["current_distance"][-1] == pytest.approx(5.5, abs=0.4) and ds["orientation"][-1] == 0
    assert u.initial_parameters["MPC_TILTMAX_AIR"] == pytest.approx(35.0)
    assert u.initial_parameters["MAV_TYPE"] == 2
    assert u.msg_info_dict["sys_name"] == "PX4" and u.msg_info_dict["ver_sw_release"] == 0x010F0000


def test_ardupilot_dataflash_reads_back_with_dfreader(tmp_path):
    path, truth, _ = _fly("ardupilot", tmp_path)
    assert path.suffix == ".bin"
    df = DFReader.DFReader_binary(str(path), zero_time_base=False)
    last, counts, parms = {}, {}, {}
    while (m := df.recv_msg()) is not None:
        k = m.get_type()
        last[k], counts[k] = m, counts.get(k, 0) + 1
        if k == "PARM":
            parms[m.Name] = m.Value
    assert counts["XKF1"] == pytest.approx(40, abs=2)  # 10 Hz
    assert last["XKF1"].PD == pytest.approx(truth["pos"][2], abs=0.1)
    assert last["ATT"].Yaw == pytest.approx(30.0, abs=3) and last["ATT"].Yaw == pytest.approx(
        math.degrees(truth["yaw"]) % 360, abs=0.5)  # degrees
    assert last["CTUN"].ThO == pytest.approx(truth["hover_thrust"], abs=0.1)
    assert last["RFND"].Dist == pytest.approx(5.5, abs=0.4) and last["RFND"].Stat == 4  # metres, Good
    assert last["PRX"].D0 == pytest.approx(5.5, abs=0.4) and last["PRX"].D180 == 0.0  # metres; behind: no data
    assert last["MODE"].Mode == 4  # GUIDED (an airborne start)
    assert parms["ANGLE_MAX"] == pytest.approx(3500)  # centidegrees
    assert df.formats[df.name_to_id["GUIP"]].units[2] == "cm"


def test_sitl_cli_takes_log_dir():
    args = build_parser().parse_args(["--log-dir", "/tmp/x"])
    assert args.log_dir == "/tmp/x"


def test_the_readers_take_the_sitl_logs_in_si_units(tmp_path):
    """companion.ground.flightlogs.ulog / companion.ground.flightlogs.dataflash on the SITL's own logs: the same position, heading, thrust and
    range as the truth, whatever the format's units (cm, degrees, FRD thrust, PRX sectors)."""
    from companion.ground.flightlogs.dataflash import read_dataflash
    from companion.ground.flightlogs.ulog import read_ulog

    for personality, read in (("px4", read_ulog), ("ardupilot", read_dataflash)):
        path, truth, _ = _fly(personality, tmp_path / personality)
        feed = read(path)
        last = {op: args for _, op, args in feed.ops}
        assert last["pos"][2] == pytest.approx(truth["pos"][2], abs=0.1), personality
        assert last["att"][2] == pytest.approx(truth["yaw"], abs=0.02), personality
        assert last["thr"][0] == pytest.approx(truth["hover_thrust"], abs=0.1), personality
        assert feed.info["lacking"] == {} or personality == "ardupilot", feed.info["lacking"]
        bearings, ranges, _, inc, north = last["bins"]
        ahead = ranges[np.argmin(np.abs(bearings))]
        assert ahead == pytest.approx(5.5, abs=0.4) and not north, personality
        if personality == "ardupilot":  # PRX: 45° sectors, and no data behind the 60° field of view
            assert inc == pytest.approx(math.radians(45)) and len(bearings) == 3
            assert feed.info["sources"]["bins"] == "PRX"
        else:
            assert inc == pytest.approx(math.radians(5.0)) and feed.info["sources"]["bins"] == "obstacle_distance"


def test_guided_targets_are_the_commanded_path_without_pscn(tmp_path):
    """A DataFlash log with GUIDED targets (GUIP, cm, NEU) but no PSCN/PSCE: GUIP is the commanded path."""
    from companion.ground.flightlogs.dataflash import read_dataflash
    from sitl_harness.flightlog import DataFlashWriter

    path = tmp_path / "guip.bin"
    with DataFlashWriter(path) as w:
        w.write("UNIT", 1, ord("m"), "m")
        w.write("MULT", 1, ord("B"), 0.01)
        w.write("FMTU", 1, w.type_of("GUIP"), "s-mmm-nnnooo", "F-BBB-BBBBBB")
        for k in range(1, 50):
            t = k * 100_000
            w.write("XKF1", t, 0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.1 * k, 0.0, -2.0)
            w.write("GUIP", t, 1, 10.0 * k + 50.0, 250.0, 200.0, 0, 100.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    feed = read_dataflash(path)
    targets = [a for _, op, a in feed.ops if op == "target"]
    assert targets[-1] == pytest.approx((4.9 + 0.5, 2.5)) and feed.info["sources"]["target"] == "GUIP (GUIDED target)"


def test_fixed_wing_phases_are_cut_out():
    from companion.ground.flightlogs.loginput import exclude

    ops = [(t, "pos", (t,)) for t in range(0, 100, 10)]
    out, cuts = exclude(ops, [(30, 60)])
    assert [o[0] for o in out] == [0, 10, 20, 30, 40, 50, 60] and [o[2][0] for o in out][3] == 60
    assert cuts == [{"t": 30e-6, "cut_s": 30e-6}]


def test_the_primary_estimator_is_the_one_judged(tmp_path):
    """estimator_selector_status names instance 1 primary: its estimator_status (a bad solution) is the one read."""
    from companion.ground.flightlogs.ulog import read_ulog
    from sitl_harness.ulog_writer import ULogWriter

    path = tmp_path / "two_ekf.ulg"
    w = ULogWriter(path)
    w.define("vehicle_local_position", Px4Log.TOPICS["vehicle_local_position"])
    w.define("estimator_status", "uint64_t timestamp;uint16_t solution_status_flags")
    w.define("estimator_selector_status", "uint64_t timestamp;uint8_t primary_instance")
    lp, e0, e1, sel = w.add("vehicle_local_position"), w.add("estimator_status", 0), w.add("estimator_status", 1), \
        w.add("estimator_selector_status")
    for k in range(1, 30):
        t = k * 100_000
        w.data(lp, {"timestamp": t, "x": 0.1 * k, "z": -2.0, "xy_valid": True, "v_xy_valid": True})
        w.data(e0, {"timestamp": t, "solution_status_flags": 0x33F})
        w.data(e1, {"timestamp": t, "solution_status_flags": 0x21})
        w.data(sel, {"timestamp": t, "primary_instance": 0 if k < 5 else 1})
    w.close()
    feed = read_ulog(path)
    navs = [a[1] for _, op, a in feed.ops if op == "nav"]
    assert set(navs) == {0x21}
    assert "primary estimator changed 1×" in feed.info["estimator_notes"][0]


def test_a_vtols_fixed_wing_phase_is_excluded_and_said_once(tmp_path):
    """A VTOL ULog: hover-speed multirotor flight, a 20 s fixed-wing phase at 18 m/s, multirotor again. The
    fixed-wing phase is cut out of the review (said once), so its speed is not a multirotor finding."""
    from companion.ground.commands import review_log
    from sitl_harness.ulog_writer import ULogWriter

    path = tmp_path / "vtol.ulg"
    w = ULogWriter(path)
    for name in ("vehicle_local_position", "vehicle_status", "distance_sensor", "vehicle_land_detected"):
        w.define(name, Px4Log.TOPICS[name])
    w.param("MAV_TYPE", 22, True)  # MAV_TYPE_VTOL_QUADROTOR (quadplane)
    lp, st, ds, ld = (w.add(n) for n in ("vehicle_local_position", "vehicle_status", "distance_sensor",
                                         "vehicle_land_detected"))
    w.data(ld, {"timestamp": 1, "landed": False})
    x = 0.0
    for k in range(1, 601):  # 60 s at 10 Hz
        t = k * 100_000
        fw = 200 <= k < 400
        v = 18.0 if fw else 0.5
        x += v * 0.1
        w.data(lp, {"timestamp": t, "x": x, "z": -20.0, "vx": v, "xy_valid": True, "v_xy_valid": True})
        w.data(ds, {"timestamp": t, "min_distance": 0.2, "max_distance": 40.0, "current_distance": 41.0,
                    "signal_quality": 100, "orientation": 0})
        if k % 5 == 0:
            w.data(st, {"timestamp": t, "nav_state": 3, "arming_state": 2, "vehicle_type": 2 if fw else 1,
                        "is_vtol": True})
    w.close()
    rep, _ = review_log(path, tmp_path / "out", vehicle="x500")
    said = [f for f in rep["findings"] if "fixed-wing" in f]
    assert len(said) == 1 and "excluded" in said[0] and "1 phase(s)" in said[0], rep["findings"]
    assert rep["outside_contract"]["flown_above_v_safe_s"] == 0 and not rep["over_limit"]["worst_beyond_allowed"]
    assert rep["span"]["duration_s"] == pytest.approx(40.0, abs=1.0)  # 60 s less the 20 s cut out


def test_the_dataflash_log_knows_its_utc_from_gps(tmp_path):
    """GPS week and ms (less the leap seconds) give the log's wall-clock time, as the ULog's time_utc_usec."""
    from companion.ground.flightlogs.dataflash import read_dataflash
    from sitl_harness.scenario import scenario_from_dict

    sim = Sim(scenario_from_dict(SCENARIO), "ardupilot", log_dir=tmp_path, unix_epoch_s=1_767_225_600.0)
    sim.step(2.0)
    feed = read_dataflash(sim.close_log())
    assert feed.wall0 == pytest.approx(1_767_225_600.0, abs=0.02)
    df = DFReader.DFReader_binary(str(next(tmp_path.glob("*.bin"))), zero_time_base=False)
    gps = df.recv_match(type="GPS")
    assert gps.Lat == pytest.approx(sim.scenario.home.lat_deg, abs=1e-4) and gps.Status == 3  # degrees (1e-7 int)
