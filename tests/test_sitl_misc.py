"""House rules and small pieces: import direction, wind statistics, scenario faults, attitude offboard."""

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_client import PX4_HOLD, PX4_OFFBOARD, lockstep_client
from sitl_harness import Sim
from sitl_harness.physics import euler_from_quat, quat_from_euler
from sitl_harness.scenario import scenario_from_dict
from sitl_harness.wind import Wind

PKG = Path(__file__).resolve().parents[1] / "sitl_harness"


def test_sitl_harness_never_imports_companion():
    for f in PKG.glob("*.py"):
        tree = ast.parse(f.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            assert not any(n == "companion" or n.startswith("companion.") for n in names), f.name


def test_dryden_wind_statistics_and_seed():
    w = Wind(mean_m_s=2.0, from_deg=90.0, gust_m_s=0.8, length_m=20.0, seed=4)
    xs = np.array([w.step(0.01) for _ in range(60000)])
    assert xs[:, 1].mean() == pytest.approx(-2.0, abs=0.25)  # from the east: blows toward −y
    assert xs[:, 0].std() == pytest.approx(0.8, rel=0.2)
    assert xs[:, 2].std() == pytest.approx(0.4, rel=0.2)
    # correlation time L/V = 10 s: lag-1 s autocorrelation ≈ e^(−0.1)
    u = xs[:, 0] - xs[:, 0].mean()
    r = np.dot(u[:-100], u[100:]) / np.dot(u, u)
    assert r == pytest.approx(math.exp(-0.1), abs=0.1)
    w2 = Wind(mean_m_s=2.0, from_deg=90.0, gust_m_s=0.8, seed=4)
    assert np.allclose([w2.step(0.01) for _ in range(100)], xs[:100])


def test_discrete_gust_is_one_minus_cosine():
    w = Wind(seed=1)
    w.add_gust(1.0, 2.0, 3.0, from_deg=0.0)
    vals = [w.step(0.01)[0] for _ in range(400)]
    assert min(vals) == pytest.approx(-3.0, abs=1e-3) and vals[50] == 0.0 and vals[-1] == 0.0


def test_scenario_thrust_drop_is_felt_and_adapted():
    sim = Sim(scenario_from_dict({"wind": {"mean_m_s": 0, "gust_m_s": 0},
                                  "faults": [{"at_s": 12.0, "thrust_ratio": 0.7}]}), "px4")
    c = lockstep_client(sim)
    c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    c.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 6, 488.0 + 3.0)
    c.pump(11.0 - sim.time_s)
    thr_before = c.last["VFR_HUD"].throttle
    c.pump(8.0)
    assert sim.model.thrust_ratio == 0.7
    assert thr_before == pytest.approx(47, abs=2)
    assert c.last["VFR_HUD"].throttle == pytest.approx(47 / 0.7, abs=2)  # the daemon's thrust_ratio signal
    assert c.pos[2] == pytest.approx(-3.0, abs=0.1)


def test_px4_offboard_attitude_target():
    sim = Sim(scenario_from_dict({"wind": {"mean_m_s": 0, "gust_m_s": 0}}), "px4")
    c = lockstep_client(sim)
    c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    c.command(mav.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 6, 488.0 + 5.0)
    assert c.wait(lambda c: c.custom_mode == PX4_HOLD and abs(c.pos[2] + 5) < 0.2, 20.0)
    q = quat_from_euler(0.1, 0.0, 0.0)
    hover = sim.model.hover_thrust
    for _ in range(40):
        c.mav.set_attitude_target_send(0, 1, 1, 0b00000111, list(q), 0, 0, 0, hover / math.cos(0.1))
        c.pump(0.05)
        if c.custom_mode != PX4_OFFBOARD:
            c.set_mode(6)
    r, p, _ = euler_from_quat(sim.model.quat)
    assert c.custom_mode == PX4_OFFBOARD
    assert r == pytest.approx(0.1, abs=0.01) and abs(p) < 0.01
    assert c.last["LOCAL_POSITION_NED"].vy > 0.5  # rolled right: accelerates east


def test_mission_item_reached_and_mission_current():
    sim = Sim(scenario_from_dict({"wind": {"mean_m_s": 0, "gust_m_s": 0},
                                  "route": {"altitude_m": 2, "cruise_speed_m_s": 2, "waypoints": [[0, 0], [6, 0]]},
                                  "params": {"NAV_ACC_RAD": 0.3}}), "px4")
    c = lockstep_client(sim)
    c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert c.command(mav.MAV_CMD_MISSION_START, 0, 1) == mav.MAV_RESULT_ACCEPTED  # from the ground
    assert c.wait(lambda c: c.custom_mode == PX4_HOLD and sim.autopilot.mission_seq == 2, 30.0)
    reached = [m.seq for m in c.log if m.get_type() == "MISSION_ITEM_REACHED"]
    assert reached == [0, 1]
    assert c.pos[0] == pytest.approx(6.0, abs=0.3)
    assert c.last["MISSION_CURRENT"].total == 2


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_inflight_degradation_scenario_timeline_over_mavlink(pers):
    """The shipped in-flight scenario, flown as its preloaded mission: every fault of the timeline is
    visible to a MAVLink client when it should be, and the columns on the route are hit (the
    autopilot alone does not avoid them) and recorded with time and position."""
    sim = Sim("inflight_degradation", pers)
    c = lockstep_client(sim)
    if pers == "ardupilot":
        c.set_mode(4)
        c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 2.0)
        c.pump(4.0)
        assert c.set_mode(3) == mav.MAV_RESULT_ACCEPTED
    else:
        c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert c.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    samples = {}
    gaps = []
    last_rx = sim.time_s
    while sim.time_s < 55.0:
        msgs = c.pump(0.05)
        if msgs:
            if sim.time_s - last_rx > 0.5:
                gaps.append((round(last_rx, 2), round(sim.time_s, 2)))
            last_rx = sim.time_s
        for t_probe in (9.0, 14.0, 20.0, 35.0, 42.5):
            if t_probe <= sim.time_s < t_probe + 0.05:
                samples[t_probe] = (c.last["DISTANCE_SENSOR"], c.last["VFR_HUD"], c.last["SYS_STATUS"])
    ds9, hud9, _ = samples[9.0]
    ds14, hud14, _ = samples[14.0]
    assert ds9.max_distance == 800 and ds9.signal_quality == 100
    assert hud14.throttle == pytest.approx(hud9.throttle / 0.7, abs=4)  # thrust_ratio 0.7 from 10 s
    ds20 = samples[20.0][0]
    assert ds20.max_distance == 400 and ds20.signal_quality == 50  # honest fog
    ds35 = samples[35.0][0]
    assert ds35.max_distance == 800  # hidden fog: still states its full range
    ss = samples[42.5][2]
    assert not ss.onboard_control_sensors_health & mav.MAV_SYS_STATUS_SENSOR_PROXIMITY  # drop-out
    assert any(44.9 <= a <= 45.1 and 46.9 <= b <= 47.2 for a, b in gaps), gaps  # link drop-out 45–47 s
    names = [h.obstacle_name for h in sim.collisions]
    assert "c1" in names and "c2" in names
    hit = sim.collisions[0]
    assert hit.obstacle_name == "c1" and 14.0 < hit.position[0] < 14.8 and hit.time_s > 5.0
    assert any(t.startswith("COLLISION c1") for t in c.texts)


@pytest.mark.parametrize("pers,mode", [("px4", PX4_HOLD), ("ardupilot", 4)])
def test_scenario_can_start_hovering(pers, mode):
    sim = Sim(scenario_from_dict({"start": {"x_m": 1.0, "y_m": 2.0, "alt_m": 2.5, "yaw_deg": 90}}), pers)
    c = lockstep_client(sim)
    c.pump(3.0)
    assert c.armed and c.custom_mode == mode
    assert c.last["EXTENDED_SYS_STATE"].landed_state == mav.MAV_LANDED_STATE_IN_AIR
    assert math.dist(c.pos, (1.0, 2.0, -2.5)) < 0.1
    assert c.last["ATTITUDE"].yaw == pytest.approx(math.pi / 2, abs=0.02)


def detect_and_hold(speed: float) -> tuple[Sim, float]:
    """A minimal companion loop over MAVLink bytes: fly north at `speed` in OFFBOARD; at the first
    DISTANCE_SENSOR reading inside its max range, command Hold. Returns the sim and the stop margin
    (distance from the first detection to the stopping point)."""
    sim = Sim(scenario_from_dict({"start": {"alt_m": 2.0}, "wind": {"mean_m_s": 0, "gust_m_s": 0},
                                  "world": {"columns": [{"x_m": 40.0, "y_m": 0.0, "radius_m": 0.5, "name": "pole"}]},
                                  "sensor": {"max_range_m": 6.0, "noise_sd_m": 0.0, "noise_rel": 0.0},
                                  "params": {"MPC_XY_VEL_MAX": 12.0}}), "px4")
    c = lockstep_client(sim)
    for _ in range(10):
        c.position_target(0x09C7, vel=(speed, 0.0, 0.0))
        c.pump(0.05)
    assert c.set_mode(6) == mav.MAV_RESULT_ACCEPTED
    seen_at = None
    while sim.time_s < 40.0:
        c.position_target(0x09C7, vel=(speed, 0.0, 0.0))
        for m in c.pump(0.05):
            if m.get_type() == "DISTANCE_SENSOR" and m.current_distance <= m.max_distance:
                seen_at = c.pos[0]
                break
        if seen_at is not None:
            break
    assert seen_at is not None and c.speed_xy == pytest.approx(speed, abs=0.2)
    assert c.set_mode(4, 3) == mav.MAV_RESULT_ACCEPTED
    c.pump(6.0)
    return sim, c.pos[0] - seen_at


def test_detect_and_hold_loop_over_mavlink_positive_and_negative_control():
    """At 2 m/s Hold stops well short of the column seen 6 m ahead; at 6 m/s the jerk-limited
    braking distance v²/(2a) + v·a/(2j) = 8.25 m exceeds the 6 m range and the vehicle hits it —
    the harness can show both outcomes."""
    slow, d_slow = detect_and_hold(2.0)
    assert not slow.collisions and d_slow < 6.0 - 0.5 - 0.1
    assert d_slow == pytest.approx(4 / 6 + 2 * 3 / 8, abs=0.3)
    fast, _ = detect_and_hold(6.0)
    assert len(fast.collisions) == 1 and fast.collisions[0].obstacle_name == "pole"


def test_a_column_appears_once_the_vehicle_comes_within_its_distance():
    """`appears_within_m`: absent (not sensed, not hit) until the vehicle's centre comes within that distance of
    its surface, then there for good, in the world the sensor and the collision monitor share."""
    sim = Sim(scenario_from_dict({"start": {"alt_m": 2.0}, "wind": {"mean_m_s": 0, "gust_m_s": 0},
                                  "world": {"columns": [{"x_m": 12.0, "y_m": 0.0, "radius_m": 0.5, "name": "door",
                                                         "appears_within_m": 1.8}]},
                                  "sensor": {"max_range_m": 6.0, "noise_sd_m": 0.0, "noise_rel": 0.0}}), "px4")
    c = lockstep_client(sim)
    for _ in range(10):
        c.position_target(0x09C7, vel=(2.0, 0.0, 0.0))
        c.pump(0.05)
    assert c.set_mode(6) == mav.MAV_RESULT_ACCEPTED
    ranges = []  # (vehicle x, nearest range reported) per frame
    while not sim.revealed or sim.time_s < sim.revealed[0][0] + 0.2:
        c.position_target(0x09C7, vel=(2.0, 0.0, 0.0))
        for m in c.pump(0.05):
            if m.get_type() == "DISTANCE_SENSOR":
                ranges.append((c.pos[0], m.current_distance / 100 if m.current_distance <= m.max_distance else None))
    (t, col), = sim.revealed
    assert col.name == "door" and sim.world.columns == [col]
    seen = [(xv, r) for xv, r in ranges if r is not None]
    assert seen and all(r is None for xv, r in ranges if xv < 11.5 - 1.8 - 0.05)  # not sensed from 6 m
    assert seen[0][0] >= 11.5 - 1.8 - 0.02 and seen[0][1] == pytest.approx(11.5 - seen[0][0], abs=0.1)
    assert not sim.collisions


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_nav_fault_shows_in_estimator_flags_and_blocks_arming(pers):
    sim = Sim(scenario_from_dict({"faults": [{"at_s": 1.0, "nav_fault_s": 3.0}]}), pers)
    c = lockstep_client(sim)
    c.pump(1.0)  # t = 1.5
    name = "ESTIMATOR_STATUS" if pers == "px4" else "EKF_STATUS_REPORT"
    flag = mav.ESTIMATOR_POS_HORIZ_ABS if pers == "px4" else mav.EKF_POS_HORIZ_ABS
    assert not c.last[name].flags & flag
    assert not c.last["SYS_STATUS"].onboard_control_sensors_health & mav.MAV_SYS_STATUS_SENSOR_GPS
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_DENIED
    c.pump(3.0)  # t = 4.5: over
    assert c.last[name].flags & flag
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED


@pytest.mark.slow
@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_campaign_column_ahead_seeds_with_design_wind(pers):
    """Campaign: the column_ahead mission under the vehicle file's design wind for several seeds.
    Every seed hits the column on the route (the autopilot alone does not avoid), at a time and
    place that is reproducible per seed and varies between seeds."""
    def fly(seed):
        sim = Sim("column_ahead", pers, seed=seed)
        ap = sim.autopilot
        if pers == "ardupilot":
            ap.request_custom_mode(4)
            ap.handle_command(mav.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0, 0, 0, 0, 0, 0))
            ap.handle_command(mav.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 2.0))
            sim.step(5.0)
        else:
            ap.handle_command(mav.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0, 0, 0, 0, 0, 0))
        assert ap.handle_command(mav.MAV_CMD_MISSION_START, (0, 0, 0, 0, 0, 0, 0)) == mav.MAV_RESULT_ACCEPTED
        sim.step(25.0)
        assert sim.collisions, f"seed {seed}: no collision recorded"
        return sim.collisions[0]

    hits = [fly(s) for s in range(1, 7)]
    again = fly(1)
    assert (again.time_s, again.position) == (hits[0].time_s, hits[0].position)
    assert len({h.position for h in hits}) == len(hits)
    for h in hits:
        assert h.obstacle_name == "column" and 11.0 < h.position[0] < 11.6


def test_sensor_latency_delays_each_frame_by_exactly_that_long():
    """A frame seen at t is sent at t + latency_s (the contract's reaction time budgets it)."""
    def frames(latency):
        sim = Sim(scenario_from_dict({"world": {"columns": [{"x_m": 5.0, "y_m": 0.3, "radius_m": 0.5}]},
                                      "sensor": {"latency_s": latency, "rate_hz": 20}}), seed=4)
        out, seq = [], 0
        for _ in range(100):
            sim.tick()
            if sim.sensor_seq != seq:
                seq = sim.sensor_seq
                out.append((round(sim.time_s, 6), tuple(sim.reading.distances_cm)))
        return out

    now, late = frames(0.0), frames(0.1)
    assert len(late) == len(now) - 2  # two frames still in flight at the end
    assert all(min(d) < 500 for _, d in now)  # the column is seen (4.5 m away)
    for (t0, d0), (t1, d1) in zip(now, late):
        assert d1 == d0 and t1 == pytest.approx(t0 + 0.1, abs=1e-6)
