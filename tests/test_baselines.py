"""The autopilots' own laws (`companion/ground/baselines.py`) against numbers worked out by hand from their sources:
PX4 `CollisionPrevention.cpp` / `TrajMath.hpp`, ArduPilot `AC_Avoid.cpp` / `AP_Proximity_MAV.cpp` /
`AP_Proximity_Boundary_3D.cpp` / `AP_Math/control.cpp`. Each law builds its own obstacle map from the
sensor samples (`Scan`), never from the daemon's D_od estimate."""

import math
from types import SimpleNamespace

import pytest

from companion.ground import baselines as bl
from companion.onboard.samples import AutopilotParam, Heading, Scan, Throttle


def inputs(t, v):
    """The fields of `Inputs` a law reads: the clock and the ground speed."""
    return SimpleNamespace(t=t, ground_speed=v)


def beam(t, r, max_m=8.0, sensor=0):
    """A forward DISTANCE_SENSOR as MAVLink-in makes it (`range_scan`): a hit, or nothing within max_m."""
    return Scan(t, sensor, ((0.0, r),) if r is not None else (), max_m, 100)


# ----------------------------------------------------------------------------- PX4

def test_trajmath_algebra():
    """TrajMath.hpp: b = 4a²/J, c = −2a·s; v = (−b + sqrt(b² − 4c))/2. J = 4, a = 3, s = 3.5:
    b = 9, c = −21, v = (−9 + sqrt(81 + 84))/2 = (−9 + 12.8452)/2 = 1.92261."""
    assert bl.px4_max_speed_from_distance(4.0, 3.0, 3.5) == pytest.approx(1.92261, abs=1e-5)
    assert bl.px4_max_speed_from_distance(4.0, 3.0, 0.0) == 0.0
    assert bl.px4_max_speed_from_distance(4.0, 3.0, 0.0, 1.5) == 1.5  # never below the final speed


def test_px4_bins_of_a_60_degree_beam():
    """_addDistanceSensorData: floor((0 − 30)/10) = −3 → −2 (a negative bound +1), floor((0 + 30)/10) = 3:
    bins −2..3 = 34, 35, 0, 1, 2, 3. A 90° sensor of 20°: floor(80/10) = 8 .. floor(100/10) = 10."""
    assert bl.px4_sensor_bins(0.0, 60.0) == [34, 35, 0, 1, 2, 3]
    assert bl.px4_sensor_bins(90.0, 20.0) == [8, 9, 10]


def test_px4_law_per_bin_with_the_data_age_and_the_auto_jerk():
    """A 6 m reading at t = 0 (range 8 m), flying 3 m/s, asked at t = 0.1 s; CP_DIST 1, CP_DELAY 0.4,
    MPC_ACC_HOR 3, MPC_JERK_AUTO 4. Bin 0: v∥ = 3, delay = 3·0.4 + 3·0.1 (age, in range) = 1.5,
    s = 6 − max(0.1, 1) − 1.5 = 3.5 → 1.92261 (above). Bin 1 (10°): v∥ = 2.95442, delay = 1.47721, s = 3.52279:
    b = 9, c = −21.1367, v = (−9 + sqrt(165.1367))/2 = 1.92526, over cos 10° = 1.95497 — looser.
    Limit 1.92261."""
    law = bl.Px4CollisionPrevention(cp_dist_m=1.0, acc_hor=3.0, jerk=4.0)
    law.take(beam(0.0, 6.0))
    assert law.dist_cm[34:] + law.dist_cm[:4] == [600] * 6 and law.dist_cm[4] == bl.UINT16_MAX
    assert law.omega(inputs(0.1, 3.0)).v_max == pytest.approx(1.92261, abs=1e-4)
    # the data-age term: asked at t = 0.3 s, delay = 3·0.7 = 2.1, s = 2.9: c = −17.4,
    # v = (−9 + sqrt(150.6))/2 = (−9 + 12.27192)/2 = 1.63596
    assert law.omega(inputs(0.3, 3.0)).v_max == pytest.approx(1.63596, abs=1e-4)
    # MPC_JERK_MAX 8 (the firmware's own Position mode) at t = 0.1: b = 4.5, c = −21,
    # v = (−4.5 + sqrt(20.25 + 84))/2 = (−4.5 + 10.21029)/2 = 2.85515 — faster than the auto-mode jerk allows
    law.jerk = 8.0
    assert law.omega(inputs(0.1, 3.0)).v_max == pytest.approx(2.85515, abs=1e-4)


def test_px4_out_of_range_bins_limit_at_the_range_without_the_age_term():
    """Nothing seen (the reading is max + 1 cm, clamped to max = 5 m): the bins hold 500 cm = the bin's
    range, so no age term. v = 2, t = 0.4: delay = 2·0.4 = 0.8, s = 5 − 1 − 0.8 = 3.2: c = −19.2,
    v = (−9 + sqrt(81 + 76.8))/2 = (−9 + 12.56185)/2 = 1.78092. No MPC_XY_P·s cap (0.95·3.2 = 3.04 would not bind
    here anyway; at s = 0.5: smooth (−9 + sqrt(93))/2 = 0.32183 vs 0.475 — the old cap never bound at J = 4)."""
    law = bl.Px4CollisionPrevention(cp_dist_m=1.0, acc_hor=3.0, jerk=4.0)
    law.take(beam(0.0, None, max_m=5.0))
    assert law.dist_cm[0] == 500 and law.range_cm[0] == 500
    assert law.omega(inputs(0.4, 2.0)).v_max == pytest.approx(1.78092, abs=1e-4)


def test_px4_no_data_allows_no_motion_and_bins_go_stale_after_half_a_second():
    law = bl.Px4CollisionPrevention()
    assert law.omega(inputs(0.0, 3.0)).v_max == 0.0  # nothing ever heard: "No obstacle data, not moving"
    law.take(beam(1.0, 6.0))
    assert law.omega(inputs(1.49, 0.0)).v_max > 0.0
    assert law.omega(inputs(1.51, 0.0)).v_max == 0.0  # RANGE_STREAM_TIMEOUT_US 500 ms: the bins are reset
    law.take(Scan(2.0, 0, (), 0.0, 1))  # below min range: discarded, the bins stay empty
    assert law.omega(inputs(2.05, 0.0)).v_max == 0.0
    law.take(Scan(3.0, 0, ((0.0, 6.0),), 8.0, 1))  # signal_quality 1 but a reading in range: PX4 does not read it
    assert law.dist_cm[0] == 600


def test_px4_direction_without_data_is_not_flown_and_the_pitch_shortens_a_reading():
    side = bl.Px4CollisionPrevention(sensors=(bl.SensorMount(90.0, 20.0),))
    side.take(Scan(0.0, 0, ((math.pi / 2, 3.0),), 8.0, 100))
    assert side.omega(inputs(0.1, 1.0)).v_max == 0.0  # bin 0 (the motion's) has no data, CP_GO_NO_DATA 0
    side.go_no_data = True
    # allowed: only bin 8 (80°) bounds forward motion: v∥ = cos 80° = 0.173648, delay = 0.173648·(0.4 + 0.1)
    # = 0.086824, s = 3 − 1 − 0.086824 = 1.913176; at MPC_JERK_MAX's default 8: b = 4·3²/8 = 4.5,
    # c = −11.47906, v = (−4.5 + sqrt(66.16624))/2 = 1.817131, over cos 80°: 10.4644 (bins 9, 10 at 90°, 100°
    # bound none)
    assert side.jerk == 8.0
    assert side.omega(inputs(0.1, 1.0)).v_max == pytest.approx(10.4644, abs=2e-3)
    law = bl.Px4CollisionPrevention()
    law.take(Throttle(0.0, 0.5, 0.0, math.radians(20.0), 0.0, True))
    law.take(beam(0.0, 6.0))
    assert law.dist_cm[0] == round(600 * math.cos(math.radians(20.0)))  # 563.8 → 564 cm


def test_px4_obstacle_distance_bins_and_reported_parameters():
    """OBSTACLE_DISTANCE, 5° bins at −30..+25° (offset −30): map bin 0 takes message bin ceil((0 + 30)/5) = 6
    (at 0°), map bin 1 ceil(40/5) = 8 (10°), map bin 35 ceil(20/5) = 4 (−10°)."""
    inc = math.radians(5.0)
    known = tuple(math.radians(-30.0 + 5.0 * j) for j in range(12))
    hits = ((known[6], 4.0), (known[8], 5.0))
    law = bl.Px4CollisionPrevention()
    law.take(Scan(0.0, 0, hits, 8.0, 0, known, inc))
    assert (law.dist_cm[0], law.dist_cm[1], law.dist_cm[35]) == (400, 500, 801)  # 801: nothing seen (max + 1)
    assert law.dist_cm[4] == bl.UINT16_MAX  # 40°: outside the message's bins
    law.take(AutopilotParam(0.0, "MPC_JERK_AUTO", 1.0))
    law.take(Heading(0.0, 0.0, 1.0))  # other samples are ignored
    assert law.jerk == 8.0  # the mission's jerk is not the law's: CollisionPrevention.cpp passes MPC_JERK_MAX
    law.take(AutopilotParam(0.0, "MPC_JERK_MAX", 6.0))
    law.take(AutopilotParam(0.0, "MPC_ACC_HOR", 2.5))
    assert (law.jerk, law.acc_hor) == (6.0, 2.5)
    auto = bl.Px4CollisionPrevention(jerk_param="MPC_JERK_AUTO")  # the separate mission-jerk arm
    auto.take(AutopilotParam(0.0, "MPC_JERK_AUTO", 1.0))
    assert auto.jerk == 1.0


def test_the_firmware_jerk_is_faster_than_the_mission_jerk_where_it_is_drawn_low():
    """computeMaxSpeedFromDistance at 5 m, MPC_ACC_HOR 3: J 8 → 3.67 m/s, J 4 → 2.59, J 1 → 0.81."""
    for j, v in ((8.0, 3.67), (4.0, 2.59), (1.0, 0.81)):
        assert bl.px4_max_speed_from_distance(j, 3.0, 5.0) == pytest.approx(v, abs=0.01)


# ----------------------------------------------------------------------------- ArduPilot

def test_sqrt_controller():
    """AP_Math sqrt_controller: kP·e up to a/kP², then sqrt(2a(e − a/(2kP²)))."""
    assert bl.sqrt_controller(1.0, 1.0, 1.0) == pytest.approx(1.0)
    assert bl.sqrt_controller(5.0, 1.0, 1.0) == pytest.approx(math.sqrt(2 * (5.0 - 0.5)))
    assert bl.ac_avoid_speed(7.0, accel=3.0) == bl.ac_avoid_speed(7.0)  # AC_AVOID_ACCEL_CMSS_MAX
    assert bl.ac_avoid_speed(1.5) == 0.0


def test_ac_avoid_takes_its_own_parameters_and_ignores_the_others():
    law = bl.ArduPilotAcAvoid(cruise_m_s=8.0)
    law.take(AutopilotParam(0.0, "ANGLE_MAX", 3000.0))  # not its own: ignored (the law has no jerk)
    law.take(AutopilotParam(0.0, "MPC_JERK_MAX", 8.0))
    law.take(AutopilotParam(0.0, "AVOID_MARGIN", 1.5))
    assert law.margin_m == 1.5


def test_ac_avoid_boundary_of_one_forward_reading():
    """A forward reading of 6 m: face 0 valid; update_boundary puts edge points at ±22.5° and, the neighbours
    having no data, ±67.5° (the cup), all at 6 m. Obstacle 7 is the segment −22.5°..22.5°: its closest point
    is straight ahead at 6·cos 22.5° = 5.54328; obstacles 0 and 6 at ±45°, same distance. Straight ahead:
    e = 5.54328 − 2 = 3.54328, v = sqrt(2·1·(3.54328 − 0.5)) = 2.46710; at 45°: 2.46710 / cos 45° = 3.48901.
    Limit 2.46710 — and not capped by the 8 m range."""
    law = bl.ArduPilotAcAvoid(cruise_m_s=8.0)
    law.take(beam(0.0, 6.0))
    pts = sorted(law.obstacles(0.0), key=lambda p: p[1])
    assert len(pts) == 3
    assert pts[1] == pytest.approx((5.54328, 0.0), abs=1e-4)
    assert math.hypot(*pts[0]) == pytest.approx(5.54328, abs=1e-4) and pts[0][1] < 0
    assert law.omega(inputs(0.0, 3.0)).v_max == pytest.approx(2.46710, abs=1e-4)


def test_ac_avoid_filters_drops_beyond_max_and_fails_open():
    """The face's distance is low-pass filtered at 0.25 Hz: a 5 m reading 0.05 s after 6 m gives
    α = 0.05/(0.05 + 1/(2π·0.25)) = 0.072817, 6 − 0.072817 = 5.92718. A reading beyond max_distance resets the
    face (no obstacle: the cruise speed), and so does silence for 1 s (PROXIMITY_FACE_RESET_MS)."""
    law = bl.ArduPilotAcAvoid(cruise_m_s=8.0)
    law.take(beam(0.0, 6.0))
    law.take(beam(0.05, 5.0))
    assert law.filt[0] == pytest.approx(5.92718, abs=1e-5)
    law.take(beam(0.1, None, max_m=3.0))  # honest fog: nothing within 3 m — dropped, not an obstacle at 3 m
    assert law.omega(inputs(0.1, 3.0)).v_max == 8.0
    law.take(Scan(0.2, 0, ((0.0, 6.0),), 8.0, 1))  # signal_quality is not read either
    assert law.omega(inputs(1.1, 3.0)).v_max < 8.0  # 0.9 s without news: the face still stands
    assert law.omega(inputs(1.25, 3.0)).v_max == 8.0  # 1.05 s: reset, fail-open at the mission's speed
    assert not law.healthy(1.25)
