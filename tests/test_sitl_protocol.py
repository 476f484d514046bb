"""MAVLink behaviour of both personalities, in lock-step (real MAVLink bytes, simulated clock)."""

import math
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_client import (PX4_HOLD, PX4_LAND, PX4_MISSION, PX4_OFFBOARD, PX4_TAKEOFF, Client, LockstepTransport,
                         geo_item, lockstep_client)
from sitl_harness import Sim
from sitl_harness.scenario import Scenario, ScenarioError, load_scenario, scenario_from_dict

HOME_ALT = 488.0
ACC, DEN, FAIL, UNSUP, TEMP = (mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_DENIED, mav.MAV_RESULT_FAILED,
                               mav.MAV_RESULT_UNSUPPORTED, mav.MAV_RESULT_TEMPORARILY_REJECTED)
CALM = {"wind": {"mean_m_s": 0.0, "gust_m_s": 0.0}}
VEL_MASK_PX4 = 0x09C7
POS_MASK_PX4 = 0x09F8
AP_VEL = 0x0DC7
AP_POS = 0x0DF8


def sim_of(personality="px4", **sc):
    return Sim(scenario_from_dict({**CALM, **sc}), personality)


def px4_airborne(alt=3.0, **sc):
    sim = sim_of("px4", **sc)
    c = lockstep_client(sim)
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 6, HOME_ALT + alt) == ACC
    wait_takeoff(c)
    return sim, c


def wait_takeoff(c):
    assert c.wait(lambda c: c.custom_mode == PX4_TAKEOFF, 1.0)
    assert c.wait(lambda c: c.custom_mode == PX4_HOLD, 15.0)


def ap_airborne(alt=3.0, **sc):
    sim = sim_of("ardupilot", **sc)
    c = lockstep_client(sim)
    assert c.set_mode(4) == ACC  # GUIDED
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt) == ACC
    assert c.wait(lambda c: abs(c.pos[2] + alt) < 0.15, 15.0)
    c.pump(1.0)
    return sim, c


# ----------------------------------------------------------------------------- identity


@pytest.mark.parametrize("pers,autopilot,custom", [("px4", mav.MAV_AUTOPILOT_PX4, PX4_HOLD),
                                                   ("ardupilot", mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0)])
def test_heartbeat_identity_and_telemetry_set(pers, autopilot, custom):
    c = lockstep_client(sim_of(pers))
    c.pump(2.0)
    hb = c.last["HEARTBEAT"]
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert hb.type == mav.MAV_TYPE_QUADROTOR and hb.autopilot == autopilot
    assert hb.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and hb.custom_mode == custom
    kinds = {m.get_type() for m in c.log}
    need = {"HEARTBEAT", "SYS_STATUS", "EXTENDED_SYS_STATE", "ATTITUDE", "LOCAL_POSITION_NED",
            "GLOBAL_POSITION_INT", "HOME_POSITION", "VFR_HUD", "POSITION_TARGET_LOCAL_NED", "DISTANCE_SENSOR",
            "OBSTACLE_DISTANCE", "BATTERY_STATUS", "SYSTEM_TIME", "TIMESYNC", "MISSION_CURRENT"}
    need.add("ESTIMATOR_STATUS" if pers == "px4" else "EKF_STATUS_REPORT")
    assert need <= kinds
    ss = c.last["SYS_STATUS"]
    for bit in (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO, mav.MAV_SYS_STATUS_SENSOR_GPS, mav.MAV_SYS_STATUS_PREARM_CHECK):
        assert ss.onboard_control_sensors_health & bit
    n_att = sum(m.get_type() == "ATTITUDE" for m in c.log)
    assert 110 <= n_att <= 130  # 50 Hz over 2.5 s
    ds = c.last["DISTANCE_SENSOR"]
    assert ds.orientation == 0 and ds.horizontal_fov > 0 and ds.signal_quality == 100
    od = c.last["OBSTACLE_DISTANCE"]
    assert od.frame == mav.MAV_FRAME_BODY_FRD and len(od.distances) == 72 and od.distances[-1] == 65535
    assert od.distances[0] == od.max_distance + 1  # nothing seen in an empty field


def test_time_sources_follow_the_simulated_clock():
    sim = sim_of()
    c = lockstep_client(sim)
    c.pump(3.0)
    st = c.last["SYSTEM_TIME"]
    assert abs(st.time_boot_ms / 1000 - sim.time_s) <= 1.0
    c.mav.timesync_send(0, 123456789)
    m = c.wait_msg("TIMESYNC", 1.0, lambda m: m.ts1 == 123456789)
    assert m is not None and abs(m.tc1 * 1e-9 - sim.time_s) <= 0.03
    lp = c.wait_msg("LOCAL_POSITION_NED", 0.2)
    assert abs(lp.time_boot_ms / 1000 - sim.time_s) < 0.02


def test_message_interval_and_request_message():
    c = lockstep_client(sim_of())
    assert c.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 200000) == ACC
    c.log.clear()
    c.pump(2.0)
    n = sum(m.get_type() == "LOCAL_POSITION_NED" for m in c.log)
    assert 9 <= n <= 11
    assert c.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, -1) == ACC
    c.log.clear()
    c.pump(1.0)
    assert not any(m.get_type() == "LOCAL_POSITION_NED" for m in c.log)
    assert c.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == ACC
    c.pump(0.1)
    av = c.last["AUTOPILOT_VERSION"]
    assert av.capabilities & mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert av.capabilities & mav.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert c.command(31999) == UNSUP


# ----------------------------------------------------------------------------- take-off semantics


def test_px4_takeoff_altitude_is_amsl():
    sim, c = px4_airborne(alt=3.0)
    c.pump(2.0)
    assert c.pos[2] == pytest.approx(-3.0, abs=0.15)
    assert c.last["EXTENDED_SYS_STATE"].landed_state == mav.MAV_LANDED_STATE_IN_AIR


def test_px4_takeoff_relative_number_is_read_as_amsl_and_raised_to_minimum():
    """MAVProxy-style `takeoff 3` (param7 = 3) means 3 m AMSL to PX4: below home, so PX4 climbs to
    MIS_TAKEOFF_ALT (2.5 m) and says so."""
    sim = sim_of("px4")
    c = lockstep_client(sim)
    c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0) == ACC
    wait_takeoff(c)
    assert c.pos[2] == pytest.approx(-2.5, abs=0.15)
    assert any("minimum takeoff altitude" in t for t in c.texts)


def test_px4_takeoff_nan_uses_mis_takeoff_alt_and_denied_when_disarmed():
    sim = sim_of("px4")
    c = lockstep_client(sim)
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == DEN
    c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert c.param_set("MIS_TAKEOFF_ALT", 1.5, mav.MAV_PARAM_TYPE_REAL32).param_value == pytest.approx(1.5)
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == ACC
    wait_takeoff(c)
    assert c.pos[2] == pytest.approx(-1.5, abs=0.15)


def test_ardupilot_takeoff_relative_and_only_in_guided():
    sim = sim_of("ardupilot")
    c = lockstep_client(sim)
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0) == FAIL  # STABILIZE
    assert c.set_mode(4) == ACC
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0) == ACC
    assert c.wait(lambda c: abs(c.pos[2] + 3.0) < 0.1, 15.0)
    c.pump(2.0)
    assert c.custom_mode == 4 and c.pos[2] == pytest.approx(-3.0, abs=0.15)


# ----------------------------------------------------------------------------- offboard / guided


def test_px4_offboard_needs_a_stream_then_tracks_and_fails_safe():
    sim, c = px4_airborne()
    assert c.set_mode(6) == TEMP  # no setpoint stream yet
    assert c.param_set("COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", 4))[0], mav.MAV_PARAM_TYPE_INT32)
    for _ in range(20):  # 1 s at 20 Hz: velocity 1 m/s north
        c.position_target(VEL_MASK_PX4, vel=(1.0, 0.0, 0.0))
        c.pump(0.05)
    assert c.set_mode(6) == ACC
    for _ in range(60):
        t_sent = sim.time_s  # delivered at the start of the next tick
        c.position_target(VEL_MASK_PX4, vel=(1.0, 0.0, 0.0))
        c.pump(0.05)
    assert c.custom_mode == PX4_OFFBOARD
    assert c.last["LOCAL_POSITION_NED"].vx == pytest.approx(1.0, abs=0.1)
    assert c.wait(lambda c: any("offboard lost" in t for t in c.texts), 3.0, dt=0.01)
    assert 1.0 <= sim.time_s - t_sent <= 1.03  # COM_OF_LOSS_T default 1.0 s
    assert c.wait(lambda c: c.custom_mode == PX4_LAND, 1.1)  # COM_OBL_RC_ACT = 4
    assert c.wait(lambda c: not c.armed, 20.0)  # lands and disarms


def test_px4_offboard_nan_axes_and_position_mask():
    sim, c = px4_airborne()
    x0 = c.pos[0]
    for _ in range(40):  # position target with x NaN: x is not controlled, y/z are
        c.position_target(POS_MASK_PX4, pos=(math.nan, 2.0, -3.0))
        c.pump(0.05)
    c.set_mode(6)
    for _ in range(100):
        c.position_target(POS_MASK_PX4, pos=(math.nan, 2.0, -3.0))
        c.pump(0.05)
    assert c.custom_mode == PX4_OFFBOARD
    assert c.pos[1] == pytest.approx(2.0, abs=0.1)
    assert abs(c.pos[0] - x0) < 0.3
    assert sim.endpoint.stats["rx_handler_errors"] == 0


def test_px4_change_speed_acked_but_not_applied_in_offboard():
    sim, c = px4_airborne()
    for _ in range(30):
        c.position_target(VEL_MASK_PX4, vel=(3.0, 0.0, 0.0))
        c.pump(0.05)
    c.set_mode(6)
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == ACC
    for _ in range(80):
        c.position_target(VEL_MASK_PX4, vel=(3.0, 0.0, 0.0))
        c.pump(0.05)
    assert c.speed_xy == pytest.approx(3.0, abs=0.15)  # offboard bypasses the Navigator's speed


def test_ardupilot_guided_velocity_times_out_position_does_not():
    sim, c = ap_airborne()
    for _ in range(40):
        t_sent = sim.time_s
        c.position_target(AP_VEL, vel=(1.5, 0.0, 0.0))
        c.pump(0.05)
    assert c.speed_xy == pytest.approx(1.5, abs=0.15)
    c.pump(2.5)
    assert c.speed_xy > 1.0  # GUID_TIMEOUT 3 s not reached
    assert c.wait(lambda c: any("timed out" in t for t in c.texts), 1.0, dt=0.01)
    assert 3.0 <= sim.time_s - t_sent <= 3.03
    c.pump(3.0)
    assert c.speed_xy < 0.1
    # a position target is flown (at WPNAV speed) and held with no refresh at all
    here = c.pos
    c.position_target(AP_POS, pos=(here[0] + 4.0, here[1], -3.0))
    c.pump(10.0)
    assert math.dist(c.pos, (here[0] + 4.0, here[1], -3.0)) < 0.15
    # partial masks are not supported by ArduPilot: ignored and counted
    before = sim.endpoint.stats["rx_refused_targets"]
    c.position_target(0x0DFC, pos=(0.0, 0.0, 0.0))
    c.pump(0.1)
    assert sim.endpoint.stats["rx_refused_targets"] == before + 1


# ----------------------------------------------------------------------------- DO_CHANGE_SPEED in missions


def route_mission(c, length=40.0, alt=2.0, ap=False):
    home = c.wait_msg("HOME_POSITION", 3.0)
    items = [geo_item(home, 0, 0, 0)] if ap else []  # ArduPilot: item 0 is home
    items += [geo_item(home, 0.0, 0.0, alt), geo_item(home, length, 0.0, alt)]
    assert c.upload_mission(items) == mav.MAV_MISSION_ACCEPTED
    return items


def test_px4_mission_speed_change_in_flight_and_reset():
    sim, c = px4_airborne(alt=2.0, params={"MPC_XY_CRUISE": 2.0})
    route_mission(c)
    assert c.set_mode(4, 4) == ACC
    c.pump(6.0)
    assert c.custom_mode == PX4_MISSION and c.speed_xy == pytest.approx(2.0, abs=0.15)
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == ACC
    c.pump(3.0)
    assert c.speed_xy == pytest.approx(1.0, abs=0.1)
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, -2, -1) == ACC  # ≤ 0: back to MPC_XY_CRUISE
    c.pump(3.0)
    assert c.speed_xy == pytest.approx(2.0, abs=0.15)
    # in Hold the command is still acknowledged (and kept for the auto modes)
    assert c.set_mode(4, 3) == ACC
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 0.5, -1) == ACC
    c.pump(4.0)
    assert c.speed_xy < 0.1
    assert c.set_mode(4, 4) == ACC
    c.pump(4.0)
    assert c.speed_xy == pytest.approx(0.5, abs=0.08)
    assert c.wait(lambda c: c.custom_mode == PX4_HOLD, 90.0)  # mission done → Hold (Loiter)
    assert c.pos[0] == pytest.approx(40.0, abs=2.1)  # within NAV_ACC_RAD


def test_ardupilot_change_speed_only_in_auto_and_guided():
    sim, c = ap_airborne(alt=2.0, params={"WPNAV_SPEED": 200.0})
    assert c.set_mode(5) == ACC  # LOITER
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == FAIL
    route_mission(c, ap=True)
    assert c.set_mode(3) == ACC  # AUTO
    c.pump(6.0)
    assert c.custom_mode == 3 and c.speed_xy == pytest.approx(2.0, abs=0.15)
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 0.0, -1) == DEN
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, -1.0, -1) == DEN
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 1.0, -1) == ACC
    c.pump(3.0)
    assert c.speed_xy == pytest.approx(1.0, abs=0.1)
    assert c.set_mode(4) == ACC  # GUIDED: allowed, and it resets to WPNAV_SPEED on entry
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 0.7, -1) == ACC
    here = c.pos
    c.position_target(AP_POS, pos=(here[0] + 6.0, here[1], -2.0))
    c.pump(4.0)
    assert c.speed_xy == pytest.approx(0.7, abs=0.08)


# ----------------------------------------------------------------------------- parameters


def test_px4_parameters_bytewise():
    sim = sim_of("px4")
    c = lockstep_client(sim)
    pv = c.param("MPC_TILTMAX_AIR")
    assert pv.param_value == pytest.approx(25.0) and pv.param_type == mav.MAV_PARAM_TYPE_REAL32
    pv = c.param("COM_OBL_RC_ACT")
    assert pv.param_type == mav.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", pv.param_value))[0] == 0
    assert c.param("COM_OF_LOSS_T").param_value == pytest.approx(1.0)
    assert c.param("MPC_ACC_HOR").param_value == pytest.approx(3.0)
    assert c.param("MPC_JERK_AUTO").param_value == pytest.approx(4.0)
    assert c.param("MPC_THR_HOVER").param_value == pytest.approx(0.473, abs=0.01)
    pv = c.param_set("MPC_TILTMAX_AIR", 35.0, mav.MAV_PARAM_TYPE_REAL32)
    assert pv.param_value == pytest.approx(35.0)
    assert sim.model.cp[15] == pytest.approx(math.radians(35.0))
    c.mav.param_request_list_send(1, 1)
    c.pump(0.2)
    names = {m.param_id for m in c.log if m.get_type() == "PARAM_VALUE"}
    assert {"MPC_TILTMAX_AIR", "MPC_ACC_HOR", "MPC_JERK_AUTO", "COM_OBL_RC_ACT", "COM_OF_LOSS_T",
            "MPC_THR_HOVER"} <= names


def test_px4_hover_thrust_param_follows_the_estimate_after_thrust_loss():
    sim, c = px4_airborne(faults=[{"at_s": 8.0, "thrust_ratio": 0.7}])
    c.pump(max(0.0, 20.0 - sim.time_s))
    hov = c.param("MPC_THR_HOVER").param_value
    assert hov == pytest.approx(0.473 / 0.7, rel=0.03)
    assert c.last["VFR_HUD"].throttle == pytest.approx(100 * 0.473 / 0.7, abs=2)


def test_ardupilot_parameters_c_cast():
    c = lockstep_client(sim_of("ardupilot"))
    pv = c.param("ANGLE_MAX")
    assert pv.param_type == mav.MAV_PARAM_TYPE_INT16 and pv.param_value == 2500.0
    assert c.param("WPNAV_ACCEL").param_value == pytest.approx(300.0)
    assert c.param("GUID_TIMEOUT").param_value == pytest.approx(3.0)
    assert c.param("MOT_THST_HOVER").param_value == pytest.approx(0.473, abs=0.01)
    assert c.param_set("ANGLE_MAX", 3000.0, mav.MAV_PARAM_TYPE_INT16).param_value == 3000.0


# ----------------------------------------------------------------------------- robustness


def garbage_burst(rng, good: bytes) -> list[bytes]:
    out = [rng.bytes(int(n)) for n in rng.integers(1, 300, 20)]  # random noise
    out += [good[: int(k)] for k in rng.integers(1, len(good) - 1, 20)]  # truncated
    for _ in range(20):  # bad CRC / flipped payload bytes
        b = bytearray(good)
        b[int(rng.integers(6, len(b)))] ^= 0xFF
        out.append(bytes(b))
    out.append(good[:5] + b"\xfd" * 40)  # bad length
    out.append(b"\xfd" + bytes([255]) + b"\x00" * 300)  # oversized length claim
    return out


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_malformed_burst_leaves_vehicle_flying(pers):
    sim, c = (px4_airborne if pers == "px4" else ap_airborne)()
    pos0 = np.array(c.pos)
    rng = np.random.default_rng(5)
    enc = mav.MAVLink(None, 245, 190)
    good = enc.command_long_encode(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0).pack(enc)
    for _ in range(5):
        for pkt in garbage_burst(rng, good):
            c.tr.send(pkt)
        c.pump(0.2)
    # a NaN where an integer is needed: handled without a crash
    c.mav.command_long_send(1, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, math.nan, math.nan, 0, 0, 0, 0, 0)
    c.pump(1.0)
    st = sim.endpoint.stats
    assert st["rx_bad"] >= 100 and st["rx_truncated_bytes"] > 0
    assert c.armed and np.linalg.norm(np.array(c.pos) - pos0) < 0.3
    assert c.command(mav.MAV_CMD_NAV_LAND) == ACC  # still answers commands
    assert c.wait(lambda c: not c.armed, 20.0)


def test_signing_rejects_unsigned_and_wrong_key():
    key = bytes(range(32))
    sim = Sim(scenario_from_dict(CALM), "px4", signing_key=key)
    tr = LockstepTransport(sim)
    unsigned = Client(tr)
    unsigned.pump(0.5)
    assert "HEARTBEAT" in unsigned.last  # a receiver without a key accepts signed packets
    assert unsigned.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=1.0) is None
    wrong = Client(tr, signing_key=bytes(32))
    assert wrong.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=1.0) is None
    good = Client(tr, signing_key=key)
    assert good.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC
    assert sim.endpoint.stats["rx_bad"] >= 2


def test_deterministic_per_seed():
    def run(seed):
        sim = Sim(scenario_from_dict({"seed": seed, "wind": {"mean_m_s": 1.0, "gust_m_s": 0.5},
                                      "world": {"columns": [{"x_m": 4, "y_m": 0, "radius_m": 0.5}]}}), "px4")
        tr = LockstepTransport(sim)
        c = Client(tr)
        c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        c.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 6, HOME_ALT + 2)
        tr.link.step(5.0)
        return tr.link.client_recv()
    a, b, other = run(3), run(3), run(4)
    assert a == b and a != other


# ----------------------------------------------------------------------------- world over MAVLink


def test_collision_is_recorded_and_announced():
    sim, c = px4_airborne(alt=2.0, world={"columns": [{"x_m": 6.0, "y_m": 0.0, "radius_m": 0.5, "name": "pole"}]})
    for _ in range(20):
        c.position_target(VEL_MASK_PX4, vel=(2.0, 0.0, 0.0))
        c.pump(0.05)
    c.set_mode(6)
    for _ in range(100):
        c.position_target(VEL_MASK_PX4, vel=(2.0, 0.0, 0.0))
        c.pump(0.05)
    assert len(sim.collisions) == 1
    hit = sim.collisions[0]
    assert hit.obstacle_name == "pole" and 5.3 < hit.position[0] < 5.45 and hit.clearance_m < 0.1
    assert any(t.startswith("COLLISION pole") for t in c.texts)


def test_sensor_on_the_wire_with_fog_and_dropout():
    faults = [{"at_s": 2.0, "fog": {"visibility_m": 3.0, "report": "honest"}},
              {"at_s": 4.0, "fog": {"visibility_m": 3.0, "report": "hidden"}},
              {"at_s": 6.0, "fog": "clear"},
              {"at_s": 7.0, "sensor_dropout_s": 1.0}]
    sim = sim_of("px4", world={"columns": [{"x_m": 5.5, "y_m": 0.0, "radius_m": 0.5}]},
                 sensor={"max_range_m": 8.0, "noise_sd_m": 0.0, "noise_rel": 0.0}, faults=faults)
    c = lockstep_client(sim)
    c.pump(1.0)
    ds = c.last["DISTANCE_SENSOR"]
    assert ds.current_distance == 500 and ds.max_distance == 800 and ds.signal_quality == 100
    c.pump(2.0)  # t ≈ 3.5: honest fog
    ds, od = c.last["DISTANCE_SENSOR"], c.last["OBSTACLE_DISTANCE"]
    assert ds.max_distance == 300 and ds.current_distance == 301 and ds.signal_quality == round(100 * 3 / 8)
    assert od.max_distance == 300 and 301 in od.distances
    c.pump(2.0)  # t ≈ 5.5: hidden fog
    ds = c.last["DISTANCE_SENSOR"]
    # its full range stated; the column at 5 m unseen: nothing (801) or the fog's own return near the sensor
    assert ds.max_distance == 800 and (ds.current_distance == 801 or ds.current_distance <= 150)
    c.pump(1.0)  # clear
    assert c.last["DISTANCE_SENSOR"].current_distance == 500
    c.pump(1.2)  # t ≈ 7.7: drop-out
    c.log.clear()
    c.pump(0.25)
    assert not any(m.get_type() in ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE") for m in c.log)
    assert not c.last["SYS_STATUS"].onboard_control_sensors_health & mav.MAV_SYS_STATUS_SENSOR_PROXIMITY
    c.pump(1.0)
    assert any(m.get_type() == "DISTANCE_SENSOR" for m in c.log)


def test_link_dropout_silences_both_directions():
    sim = sim_of("px4", faults=[{"at_s": 1.0, "link_dropout_s": 2.0}])
    c = lockstep_client(sim)
    c.pump(0.6)
    c.log.clear()
    c.pump(1.5)  # t ≈ 1.1–2.6
    assert c.log == []
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=0.3) is None
    c.pump(0.5)
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACC


# ----------------------------------------------------------------------------- missions over the protocol


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_mission_upload_download_roundtrip(pers):
    c = lockstep_client(sim_of(pers))
    home = c.wait_msg("HOME_POSITION", 3.0)
    items = [geo_item(home, 0, 0, 0), geo_item(home, 5.0, 1.0, 2.0), geo_item(home, 10.0, -1.0, 3.0)]
    assert c.upload_mission(items) == mav.MAV_MISSION_ACCEPTED
    c.mav.mission_request_list_send(1, 1)
    cnt = c.wait_msg("MISSION_COUNT", 1.0)
    assert cnt.count == 3
    c.mav.mission_request_int_send(1, 1, 2)
    it = c.wait_msg("MISSION_ITEM_INT", 1.0)
    assert (it.x, it.y, it.z) == (items[2][6], items[2][7], pytest.approx(3.0))


def test_land_and_auto_disarm_px4():
    sim, c = px4_airborne()
    assert c.command(mav.MAV_CMD_NAV_LAND) == ACC
    assert c.wait(lambda c: c.last["EXTENDED_SYS_STATE"].landed_state == mav.MAV_LANDED_STATE_LANDING, 2.0)
    assert c.wait(lambda c: not c.armed, 20.0)
    assert c.pos[2] == pytest.approx(0.0, abs=0.02)


# ----------------------------------------------------------------------------- scenarios


def test_shipped_scenarios_load_and_run():
    for name in ("empty", "column_ahead", "inflight_degradation"):
        sc = load_scenario(name)
        sim = Sim(sc, "ardupilot")
        sim.step(1.0)


@pytest.mark.parametrize("data,needle", [
    ({"bogus": 1}, "bogus: unknown key"),
    ({"world": {"columns": [{"x_m": 1, "y_m": 0, "radius_m": -1}]}}, "world.columns.0.radius_m"),
    ({"world": {"columns": [{"x_m": 1, "y_m": 0, "radius_m": 1, "appears_within_m": 0}]}},
     "world.columns.0.appears_within_m"),
    ({"faults": [{"at_s": 1, "thrust_ratio": 0.5, "link_dropout_s": 1}]}, "exactly one"),
    ({"faults": [{"at_s": 1, "fog": {"visibility_m": 2, "report": "maybe"}}]}, "faults.0.fog"),
])
def test_scenario_errors_are_one_line(data, needle):
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(data)
    msg = str(err.value)
    assert needle in msg and "\n" not in msg


def test_unknown_parameter_in_scenario_is_one_line():
    with pytest.raises(ScenarioError, match="params.NOPE"):
        Sim(Scenario(params={"NOPE": 1.0}), "px4")


def test_px4_refuses_invalid_targets_like_px4():
    """Nothing valid, FORCE_SET accelerations and unsupported frames are refused (and are no
    proof of life for OFFBOARD)."""
    sim, c = px4_airborne()
    stats = sim.endpoint.stats
    for mask in (0x0DFF, 0x0E3F):  # all ignored (yaw only); acceleration as force
        for _ in range(10):
            c.position_target(mask, acc=(1.0, 0.0, 0.0))
            c.pump(0.05)
    for _ in range(10):
        c.position_target(VEL_MASK_PX4, vel=(1.0, 0, 0), frame=mav.MAV_FRAME_LOCAL_OFFSET_NED)
        c.pump(0.05)
    assert stats["rx_refused_targets"] == 30
    assert c.set_mode(6) == TEMP
    assert any("invalid" in t for t in c.texts) and any("force not supported" in t for t in c.texts)
    # BODY_NED velocity is rotated by the attitude: heading east, body-forward is east
    for _ in range(20):
        c.position_target(POS_MASK_PX4 & ~0x400, pos=(0.0, 0.0, -3.0), yaw=math.pi / 2)
        c.pump(0.05)
    assert c.set_mode(6) == ACC
    for _ in range(40):
        c.position_target(POS_MASK_PX4 & ~0x400, pos=(0.0, 0.0, -3.0), yaw=math.pi / 2)
        c.pump(0.05)
    for _ in range(60):
        c.position_target(0x0DC7, vel=(1.0, 0.0, 0.0), frame=mav.MAV_FRAME_BODY_NED)
        c.pump(0.05)
    lp = c.last["LOCAL_POSITION_NED"]
    assert lp.vy == pytest.approx(1.0, abs=0.1) and abs(lp.vx) < 0.15


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_hold_brakes_with_the_vehicle_files_limits(pers):
    """Mission at 3 m/s, then Hold (PX4 AUTO.LOITER / ArduPilot BRAKE): the vehicle stops within the
    jerk-limited distance v²/(2a) + v·a/(2j) of the braking limits (MPC_ACC_HOR / WPNAV_ACCEL,
    MPC_JERK_AUTO / WPNAV_JERK), plus a small tracking margin."""
    if pers == "px4":
        sim, c = px4_airborne(alt=2.0, params={"MPC_XY_CRUISE": 3.0})
    else:
        sim, c = ap_airborne(alt=2.0, params={"WPNAV_SPEED": 300.0})
    route_mission(c, length=60.0, ap=pers == "ardupilot")
    assert c.set_mode(*((4, 4) if pers == "px4" else (3,))) == ACC
    assert c.wait(lambda c: c.speed_xy > 2.95, 15.0)
    c.pump(1.0)
    v0, x0 = c.speed_xy, c.pos[0]
    assert c.set_mode(*((4, 3) if pers == "px4" else (17,))) == ACC
    c.pump(4.0)
    a, j = sim.vehicle.braking.accel_max_m_s2, sim.vehicle.braking.jerk_max_m_s3
    expected = v0 ** 2 / (2 * a) + v0 * a / (2 * j)
    dist = c.pos[0] - x0
    assert c.speed_xy < 0.05
    assert expected * 0.9 <= dist <= expected * 1.1 + 0.1


def test_px4_every_mode_request_is_safe():
    """Every PX4 main/sub mode, armed on the ground and in the air: answered, never a crash."""
    for airborne in (False, True):
        if airborne:
            sim, c = px4_airborne()
        else:
            sim = sim_of("px4")
            c = lockstep_client(sim)
            c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        for main in range(0, 10):
            for sub in range(0, 10):
                r = c.set_mode(main, sub)
                assert r in (ACC, DEN, UNSUP, TEMP)
                c.pump(0.05)
        assert sim.endpoint.stats["rx_handler_errors"] == 0
        c.pump(2.0)


def test_ardupilot_every_mode_request_is_safe():
    sim, c = ap_airborne()
    for custom in list(range(0, 30)) + [255, 1 << 20]:
        assert c.set_mode(custom) in (ACC, DEN, UNSUP, FAIL)
        c.pump(0.05)
    assert sim.endpoint.stats["rx_handler_errors"] == 0


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_hostile_command_parameters_are_handled(pers):
    """NaN, ±inf and absurd values in every handled command: answered, no handler exception."""
    sim = sim_of(pers)
    c = lockstep_client(sim)
    rng = np.random.default_rng(2)
    cmds = [mav.MAV_CMD_COMPONENT_ARM_DISARM, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND,
            mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, mav.MAV_CMD_DO_SET_MODE, mav.MAV_CMD_DO_CHANGE_SPEED,
            mav.MAV_CMD_MISSION_START, mav.MAV_CMD_DO_SET_MISSION_CURRENT, mav.MAV_CMD_SET_MESSAGE_INTERVAL,
            mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_NAV_LOITER_UNLIM, mav.MAV_CMD_GET_HOME_POSITION]
    values = [math.nan, math.inf, -math.inf, 0.0, 1.0, -1.0, 1e9, -1e9, 21196.0, 4.0, 6.0, 3.0]
    for _ in range(400):
        cmd = int(rng.choice(cmds))
        params = [float(rng.choice(values)) if rng.random() < 0.7 else float(rng.normal() * 100) for _ in range(7)]
        c.mav.command_long_send(1, 1, cmd, 0, *params)
        c.pump(0.02)
    for name in ("MPC_TILTMAX_AIR", "ANGLE_MAX", "COM_OF_LOSS_T", "GUID_TIMEOUT"):
        for v in (math.nan, math.inf, -5.0):
            c.mav.param_set_send(1, 1, name.encode(), v, mav.MAV_PARAM_TYPE_REAL32)
            c.pump(0.02)
    c.pump(3.0)
    assert sim.endpoint.stats["rx_handler_errors"] == 0
    acks = [m for m in c.log if m.get_type() == "COMMAND_ACK"]
    assert len(acks) >= 380
    assert np.all(np.isfinite(sim.model.x))


def test_px4_do_reposition_goes_there_in_hold():
    sim, c = px4_airborne(alt=3.0)
    home = c.wait_msg("HOME_POSITION", 3.0)
    lat = home.latitude + int(round(math.degrees(5.0 / 6378137.0) * 1e7))
    c.mav.command_int_send(1, 1, mav.MAV_FRAME_GLOBAL_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0, 1.0, 1, 0, math.nan,
                           lat, home.longitude, HOME_ALT + 3.0)
    ack = c.wait_msg("COMMAND_ACK", 1.0, lambda m: m.command == mav.MAV_CMD_DO_REPOSITION)
    assert ack.result == ACC
    c.pump(3.0)
    assert c.custom_mode == PX4_HOLD and c.speed_xy == pytest.approx(1.0, abs=0.1)
    c.pump(6.0)
    assert math.dist(c.pos, (5.0, 0.0, -3.0)) < 0.15


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_rtl_returns_home_lands_and_disarms(pers):
    sim, c = (px4_airborne if pers == "px4" else ap_airborne)(alt=3.0)
    if pers == "px4":
        for _ in range(20):
            c.position_target(POS_MASK_PX4, pos=(8.0, -4.0, -3.0))
            c.pump(0.05)
        assert c.set_mode(6) == ACC
        for _ in range(300):
            c.position_target(POS_MASK_PX4, pos=(8.0, -4.0, -3.0))
            c.pump(0.05)
    else:
        c.position_target(AP_POS, pos=(8.0, -4.0, -3.0))
        c.pump(15.0)
    assert math.dist(c.pos, (8.0, -4.0, -3.0)) < 0.2
    assert c.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH) == ACC
    assert c.wait(lambda c: not c.armed, 40.0)
    assert math.hypot(c.pos[0], c.pos[1]) < 0.35 and c.pos[2] == pytest.approx(0.0, abs=0.02)


def test_signed_vehicle_output_is_accepted_by_a_keyed_receiver():
    key = bytes(range(32))
    sim = Sim(scenario_from_dict(CALM), "px4", signing_key=key)
    link = LockstepTransport(sim)
    rx = mav.MAVLink(None)
    rx.robust_parsing = True
    rx.signing.secret_key = key
    rx.signing.timestamp = int((__import__("time").time() - 1_420_070_400) * 1e5)
    msgs = rx.parse_buffer(link.pump(1.0)) or []
    assert any(m.get_type() == "HEARTBEAT" for m in msgs)
    assert not any(m.get_type() == "BAD_DATA" for m in msgs)
    assert rx.signing.goodsig_count > 50
