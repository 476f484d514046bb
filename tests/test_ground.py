"""A body-fixed sensor's ground: where its lowest ray meets flat ground caps what it claims
(companion/onboard/ground.py), checked against the SITL's own ground model, in the decoded scan and in flight."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.onboard.config import config_from_dict
from companion.onboard.detection_range import RangeNoise
from companion.onboard.ground import ground_claim_m, ground_range_m
from companion.onboard.mavlink_in import MavlinkIn
from sitl_harness.sensor_models import DEPTH_CAMERA, DepthCamera
from sitl_harness.sensors import RangeSensorConfig

SENDER = mav.MAVLink(None, srcSystem=1, srcComponent=1)


@pytest.mark.parametrize("pitch_deg,alt", [(-15.0, 2.0), (-25.0, 1.5), (-5.0, 3.0), (10.0, 2.0)])
def test_the_ground_is_where_the_sitl_s_camera_sees_it(pitch_deg, alt):
    """The lowest ray of each of the camera's bins meets the ground where the SITL's model puts it (its own
    formula, `BodySensor.ground_ranges`), with no attitude error: the bin's nearest ray, over its centre and
    edges."""
    cam = DepthCamera(RangeSensorConfig(**{k: v for k, v in DEPTH_CAMERA.items() if k != "reports"}))
    pitch = math.radians(pitch_deg)
    for off in cam.offsets:
        edges = np.array([off - cam.inc / 2, off, off + cam.inc / 2])
        sitl = float(np.min(cam.ground_ranges(edges, alt, pitch)))
        ours = ground_range_m(alt, [off], cam.inc / 2, math.radians(1.2), 0.0, (0.0, 0.0), pitch, 0.0)
        if math.isinf(sitl):  # beyond the camera's range, the SITL says nothing of it
            assert ours > cam.cfg.max_range_m - 1e-9
        else:
            assert ours == pytest.approx(sitl, rel=1e-9)


def test_the_attitude_error_and_the_roll_bring_the_ground_nearer_never_farther():
    base = ground_range_m(2.0, [0.3], 0.04, math.radians(1.2), 0.0, (0.0, 0.0), math.radians(-12), 0.0)
    worse = ground_range_m(2.0, [0.3], 0.04, math.radians(1.2), 0.0, (0.0, 0.0), math.radians(-12),
                           math.radians(1.0))
    rolled = ground_range_m(2.0, [0.3], 0.04, math.radians(1.2), 0.0, (-0.1, 0.1), math.radians(-12), 0.0)
    assert worse < base and rolled < base
    assert ground_range_m(2.0, [0.0], 0.04, math.radians(1.2), math.radians(20), (0.0, 0.0), math.radians(-12),
                          0.0) == math.inf  # mounted pitched up by more than the vehicle pitches: never in view
    assert ground_range_m(math.nan, [0.0], 0.04, 0.02, 0.0, (0.0, 0.0), 0.0, 0.0) == 0.0  # altitude not known


def test_the_claim_stops_three_sigma_short_of_the_ground_within_it():
    noise = RangeNoise(0.0, 0.0, 0.01)
    assert ground_claim_m(10.0, 6.0, noise) == pytest.approx(6.0 - 3 * 0.36)
    assert ground_claim_m(10.0, 10.5, noise) == 10.0  # beyond the claim: not reported at all
    assert ground_claim_m(10.0, 0.5, noise) == pytest.approx(0.5 - 3 * 0.0025)
    assert ground_claim_m(math.inf, math.inf, noise) == math.inf  # no rating and no ground in view: not capped


def _camera_scan(pitch_deg: float, ranges_m, v_fov_deg=1.2):
    """A level-mounted camera's OBSTACLE_DISTANCE (17 bins of 5°, depth along its axis) decoded with the vehicle
    at 2 m, pitched `pitch_deg`."""
    sensor = {"kind": "obstacle_distance", "h_fov_deg": 85, "max_range_m": 10.0, "depth": "axis_depth",
              "v_fov_deg": v_fov_deg}
    cfg = config_from_dict({"mode": "shadow", "sensors": [sensor],
                            "detection": {"range_noise_quad_per_m": 0.01}})
    inp = MavlinkIn(cfg, None, lambda: 0.0, None)
    inp.tel.update(0.0, SENDER.local_position_ned_encode(0, 0.0, 0.0, -2.0, 1.0, 0.0, 0.0))
    inp.tel.update(0.0, SENDER.attitude_encode(0, 0.0, math.radians(pitch_deg), 0.0, 0.0, 0.0, 0.0))
    off = np.radians(np.arange(-40, 41, 5))
    cm = [int(round(r * math.cos(a) * 100)) if math.isfinite(r) else 1001 for r, a in zip(ranges_m, off)]
    msg = SENDER.obstacle_distance_encode(0, 0, cm + [65535] * (72 - 17), 5, 30, 1000, 5.0, -40.0, 12)
    return inp.samples(0.0, "OBSTACLE_DISTANCE", msg)[0]


def test_a_camera_pitched_down_claims_only_short_of_the_ground_and_the_ground_is_no_hit():
    """Nose-down 15° at 2 m the camera's line meets the ground about 6 m ahead: the claim stops short of it, the
    ground's returns are no obstacle; a pole nearer than the ground still is. Control: the same camera not known
    to pitch with the airframe (no `v_fov_deg`): every ground return is an obstacle 10 m is claimed over."""
    ground = [2.0 / math.sin(math.radians(15.6)) / math.cos(math.radians(abs(a))) for a in range(-40, 41, 5)]
    ranges = list(ground)
    ranges[8] = 3.0  # a pole straight ahead
    scan = _camera_scan(-15.0, ranges)
    assert scan.max_m < min(ground) - 1.0
    assert [round(r, 1) for _, r in scan.hits] == [3.0]
    level = _camera_scan(-15.0, ranges, v_fov_deg=None)
    assert level.max_m == 10.0 and len(level.hits) == 17  # negative control
