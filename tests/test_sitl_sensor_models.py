"""The body-fixed sensor models of the SITL (sitl_harness/sensor_models.py): a RealSense-class depth camera and a
TFmini-class single-beam lidar. Their statistics against their datasheet figures (noise growing with range,
dropped bins, spurious close returns, ground returns once pitched down), their MAVLink encodings and messages,
the fog on top, and the `sensor:` keys."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl_client import Client, LockstepTransport
from sitl_harness import Sim
from sitl_harness.scenario import ScenarioError, scenario_from_dict
from sitl_harness.sensor_models import DepthCamera, SingleBeam, make_sensor
from sitl_harness.sensors import UINT16_MAX, RangeSensor
from sitl_harness.world import World
from sitl_harness.world_build import wall_polygons

POS = np.array([0.0, 0.0, -2.0])
EMPTY = World()


def sensor(seed: int = 1, **keys):
    return make_sensor(scenario_from_dict({"sensor": keys}).sensor, seed)


def wall_at(d: float, reflectivity: float = 0.5) -> World:
    """A wall across the view whose near face is `d` m ahead (north)."""
    return World([], [], wall_polygons([(d + 0.1, -40.0), (d + 0.1, 40.0)], 0.2, reflectivity=reflectivity))


def frames(s, world, n: int, pitch: float = 0.0):
    return [s.read(world, POS, 0.0, pitch) for _ in range(n)]


def bins(readings, s) -> np.ndarray:
    return np.array([r.distances_cm[: s.n_used] for r in readings])


# ----------------------------------------------------------------------------- the depth camera


def test_the_depth_camera_defaults_are_the_datasheets():
    s = sensor(model="depth_camera")
    assert isinstance(s, DepthCamera) and s.n_used == 17 and s.cfg.fov_deg == 87.0
    assert (s.cfg.min_range_m, s.cfg.max_range_m, s.cfg.rate_hz) == (0.3, 10.0, 30.0)
    assert s.sigma(np.array([2.0]))[0] == pytest.approx(0.02 * 2.0)  # RMS 2 % at 2 m
    over = sensor(model="depth_camera", fov_deg=60)  # a key given wins over the model's default
    assert over.cfg.fov_deg == 60.0 and over.cfg.max_range_m == 10.0


def test_depth_noise_grows_with_the_square_of_the_range():
    s = sensor(model="depth_camera", dropout_rate=0.0, spurious_rate=0.0)
    sd = {}
    for d in (2.0, 4.0, 7.0):
        b = bins(frames(s, wall_at(d), 300), s) / 100.0
        assert np.abs(b.mean() - d) < 0.05 * d  # unbiased, in z-depth: every bin reads the wall's distance
        sd[d] = float(b.std())
    for d, got in sd.items():
        assert got == pytest.approx(0.01 * d * d, rel=0.15), sd
    assert sd[2.0] < sd[4.0] < sd[7.0]


def test_z_depth_against_range_along_the_bin():
    z = sensor(model="depth_camera", noise_quad_per_m=0.0, dropout_rate=0.0, spurious_rate=0.0)
    r = sensor(model="depth_camera", noise_quad_per_m=0.0, dropout_rate=0.0, spurious_rate=0.0, reports="range")
    bz, br = (np.array(x.read(wall_at(4.0), POS, 0.0).distances_cm[: x.n_used]) for x in (z, r))
    assert set(bz) == {400}  # a wall square to the axis is one depth
    inner_edge = math.cos(z.offsets[0] + 0.5 * z.inc)  # the outer bin's nearest ray: its inner edge
    assert br[0] == round(400 / inner_edge) and br[8] == 400  # along the outer bin's rays it is farther


@pytest.mark.parametrize("dropped_as, value", [("unknown", UINT16_MAX), ("free", 1001)])
def test_dropped_bins_at_their_rate_and_what_they_say(dropped_as, value):
    s = sensor(model="depth_camera", dropout_rate=0.05, spurious_rate=0.0, dropped_as=dropped_as)
    b = bins(frames(s, wall_at(3.0), 400), s)
    n = b.size
    dropped = int((b == value).sum())
    assert abs(dropped - 0.05 * n) < 4 * math.sqrt(0.05 * 0.95 * n), (dropped, n)
    assert ((b == value) | (np.abs(b - 300) < 50)).all()  # everything else is the wall
    assert sensor(model="depth_camera", dropout_rate=0.0, spurious_rate=0.0).read(
        wall_at(3.0), POS, 0.0).distances_cm[:17].count(value) == 0  # the negative control: none without


def test_spurious_close_returns_at_their_rate():
    s = sensor(model="depth_camera", dropout_rate=0.0, spurious_rate=0.05, spurious_max_m=1.0)
    b = bins(frames(s, EMPTY, 400), s)
    close = int((b <= 100).sum())
    assert abs(close - 0.05 * b.size) < 4 * math.sqrt(0.05 * 0.95 * b.size), close
    assert b[b <= 100].min() >= 30 and ((b <= 100) | (b == 1001)).all()  # in [min, spurious_max] or free
    quiet = sensor(model="depth_camera", dropout_rate=0.0, spurious_rate=0.0)
    assert (bins(frames(quiet, EMPTY, 50), quiet) == 1001).all()  # clear air, level, nothing there: free


def test_ground_returns_once_pitched_down_far_enough():
    s = sensor(model="depth_camera", dropout_rate=0.0, spurious_rate=0.0, noise_quad_per_m=0.0)
    assert (bins(frames(s, EMPTY, 5, pitch=math.radians(-8.0)), s) == 1001).all()  # the ground beyond 10 m
    b = bins(frames(s, EMPTY, 5, pitch=math.radians(-15.0)), s)
    down = math.cos(math.radians(0.6)) * math.sin(math.radians(15.0)) + math.sin(math.radians(0.6)) * math.cos(
        math.radians(15.0))
    assert b[0, 8] == round(100 * 2.0 / down)  # the centre bin: the ground's slant range (7.4 m)
    assert (b < 1001).sum() >= 5 * 5  # several bins see it
    mounted = sensor(model="depth_camera", dropout_rate=0.0, spurious_rate=0.0, mount_pitch_deg=-15.0)
    assert mounted.read(EMPTY, POS, 0.0, 0.0).distances_cm[8] < 1001  # a camera mounted nose-down: in level flight
    levelled = sensor()  # the sector sensor is levelled: pitch does not tilt it
    assert isinstance(levelled, RangeSensor) and not isinstance(levelled, DepthCamera)
    assert set(levelled.read(EMPTY, POS, 0.0, math.radians(-30.0)).distances_cm[: levelled.n_used]) == {1001}


# ----------------------------------------------------------------------------- the single-beam lidar


def test_the_single_beam_lidar_is_the_tfmini_plus():
    s = sensor(model="single_beam")
    assert isinstance(s, SingleBeam) and s.n_used == 1
    assert (s.cfg.min_range_m, s.cfg.max_range_m, s.cfg.rate_hz, s.cfg.fov_deg) == (0.1, 12.0, 100.0, 3.6)
    quiet = sensor(model="single_beam", noise_sd_m=0.0, noise_rel=0.0, dropout_rate=0.0, spurious_rate=0.0)
    # rated 12 m at 90 % reflectivity; the 1/R² law puts a 10 % target at 4 m, as the datasheet says
    seen = [d for d in np.arange(1.0, 12.0, 0.05) if quiet.read(wall_at(d, 0.1), POS, 0.0).current_cm <= 1200]
    assert max(seen) == pytest.approx(4.0, abs=0.06)
    assert quiet.read(wall_at(11.5, 0.9), POS, 0.0).current_cm == 1150


def test_single_beam_noise_is_5_cm_then_1_percent():
    s = sensor(model="single_beam", dropout_rate=0.0, spurious_rate=0.0)
    near = np.array([r.current_cm for r in frames(s, wall_at(3.0, 0.9), 400)]) / 100
    far = np.array([r.current_cm for r in frames(s, wall_at(10.0, 0.9), 400)]) / 100
    assert near.std() == pytest.approx(0.05, rel=0.15) and far.std() == pytest.approx(0.10, rel=0.15)


def test_single_beam_dropouts_are_frames_not_sent_and_spurious_returns_are_close():
    s = sensor(model="single_beam", dropout_rate=0.05, spurious_rate=0.0)
    rs = frames(s, wall_at(3.0, 0.9), 2000)
    assert abs(rs.count(None) - 100) < 4 * math.sqrt(2000 * 0.05 * 0.95)  # PX4's TFmini driver: nothing published
    assert all(abs(r.current_cm - 300) < 30 and r.signal_quality == 0 for r in rs if r is not None)  # quality unknown
    free = sensor(model="single_beam", dropout_rate=0.05, spurious_rate=0.0, dropped_as="free")
    said_free = [r for r in frames(free, wall_at(3.0, 0.9), 2000) if r.current_cm == r.max_cm + 1]
    assert abs(len(said_free) - 100) < 4 * math.sqrt(2000 * 0.05 * 0.95)  # a wall 3 m ahead called free space
    sp = sensor(model="single_beam", dropout_rate=0.0, spurious_rate=0.05)
    close = [r.current_cm for r in frames(sp, EMPTY, 2000) if r.current_cm <= 100]
    assert abs(len(close) - 100) < 4 * math.sqrt(2000 * 0.05 * 0.95) and min(close) >= 10


def test_single_beam_sees_the_ground_when_pitched_and_reports_too_near_as_no_reading():
    s = sensor(model="single_beam", dropout_rate=0.0, spurious_rate=0.0, noise_sd_m=0.0, noise_rel=0.0)
    assert s.read(EMPTY, POS, 0.0, math.radians(-5.0)).current_cm == 1201
    r = s.read(EMPTY, POS, 0.0, math.radians(-18.0))
    down = math.cos(math.radians(1.8)) * math.sin(math.radians(18.0)) + math.sin(math.radians(1.8)) * math.cos(
        math.radians(18.0))
    assert r.current_cm == round(100 * 2.0 / down)  # the ground (5.9 m), within what ρ 0.3 returns from
    assert s.read(wall_at(0.05, 0.9), POS, 0.0).current_cm == 0  # below min_distance: no valid reading


def test_each_model_sends_its_own_message_over_mavlink():
    for model, want, other in (("single_beam", "DISTANCE_SENSOR", "OBSTACLE_DISTANCE"),
                               ("depth_camera", "OBSTACLE_DISTANCE", "DISTANCE_SENSOR")):
        c = Client(LockstepTransport(Sim(scenario_from_dict({"sensor": {"model": model}, "start": {"alt_m": 2}}))))
        got = [m.get_type() for m in c.pump(1.0)]
        rate = 100 if model == "single_beam" else 30
        assert abs(got.count(want) - rate) <= 2 and other not in got, (model, got.count(want))
    c = Client(LockstepTransport(Sim(scenario_from_dict({"start": {"alt_m": 2}}))))
    got = [m.get_type() for m in c.pump(1.0)]
    assert got.count("DISTANCE_SENSOR") == got.count("OBSTACLE_DISTANCE")  # the sector sensor: both
    assert abs(got.count("DISTANCE_SENSOR") - 20) <= 1


# ----------------------------------------------------------------------------- fog on top


@pytest.mark.parametrize("model", ["depth_camera", "single_beam"])
def test_fog_works_on_top_of_each_model(model):
    s = sensor(model=model, dropout_rate=0.0, spurious_rate=0.0)
    world = wall_at(5.0, 0.5 if model == "depth_camera" else 0.9)
    assert s.read(world, POS, 0.0).current_cm < 600  # clear air: the wall
    s.visibility_m, s.honest = 3.0, True
    r = s.read(world, POS, 0.0)
    assert r.max_cm == 300 and r.current_cm == 301 and r.signal_quality < 50  # honest: the stated range falls
    s.honest = False
    hidden = frames(s, world, 300)
    assert hidden[0].max_cm == s.cfg.max_range_m * 100  # hidden: the nominal range stays
    assert any(r.current_cm <= 150 for r in hidden)  # and the medium's own returns come first, now and then


# ----------------------------------------------------------------------------- keys


@pytest.mark.parametrize("sensor_keys, where", [
    ({"model": "lidar"}, "sensor.model"),
    ({"dropout_rate": 0.1}, "dropout_rate: only for model depth_camera or single_beam"),
    ({"model": "depth_camera", "dropout_rate": 2}, "sensor.dropout_rate"),
    ({"model": "depth_camera", "dropped_as": "zero"}, "sensor.dropped_as"),
    ({"model": "single_beam", "rated_reflectivity": 0}, "sensor.rated_reflectivity"),
    ({"model": "single_beam", "beams": 2}, "sensor.beams"),
])
def test_bad_sensor_keys_are_one_scenario_error_line(sensor_keys, where):
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict({"sensor": sensor_keys})
    assert where in str(err.value) and "\n" not in str(err.value)


def test_a_dumped_scenario_loads_again():
    for model in ("sector", "depth_camera", "single_beam"):
        sc = scenario_from_dict({"sensor": {"model": model}})
        assert scenario_from_dict(sc.model_dump()) == sc


def test_the_lockstep_rigs_daemon_takes_the_sitls_sensor_as_it_is():
    from tests.lockstep import Rig

    for model, want in (("sector", ("distance_sensor", 60.0, 10.0)), ("single_beam", ("distance_sensor", 3.6, 12.0)),
                        ("depth_camera", ("obstacle_distance", 85.0, 10.0))):
        (s,) = Rig({"sensor": {"model": model}}, "px4").cfg.sensors
        assert (s.kind, s.h_fov_deg, s.max_range_m) == want, model
