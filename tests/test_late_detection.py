"""A return first seen inside D_od is an obstacle at once, and a late detection (D_od lowered, a navigation
violation) only once the following frames see it again at a consistent place (companion/onboard/late_detection.py).

The SITL's own sensor models (sitl_harness/sensor_models.py: the TFmini-class single beam, the RealSense-class depth
camera, their spurious close returns and dropped frames and bins) feed the estimator through the normalisers the
MAVLink decoders use; each rule has its negative control (`late_detection_confirm_frames: 0`, every first sight
declared at once)."""

import math

import numpy as np
import pytest

from companion.onboard.config import ContractConfig, SensorConfig, config_from_dict, weakened
from companion.onboard.detection_range import RangeNoise
from companion.onboard.estimators import DodEstimator
from companion.onboard.mavlink_in import bins_scan, range_scan
from contracts.errors import ContractError
from sitl_harness.sensor_models import DEPTH_CAMERA, SINGLE_BEAM, DepthCamera, SingleBeam
from sitl_harness.sensors import UINT16_MAX, RangeSensorConfig
from sitl_harness.world import Column, World

ALT_M = 2.0
SPEED = 1.5  # [m/s] along +x
BEAM = SensorConfig(h_fov_deg=SINGLE_BEAM["fov_deg"], max_range_m=SINGLE_BEAM["max_range_m"])
CAMERA = SensorConfig(kind="obstacle_distance", h_fov_deg=85.0, max_range_m=DEPTH_CAMERA["max_range_m"])


def model(cls, defaults, seed=1, **over):
    """The SITL's sensor model `cls` with its defaults, `over` them."""
    keys = RangeSensorConfig.__dataclass_fields__
    return cls(RangeSensorConfig(**{k: v for k, v in {**defaults, **over}.items() if k in keys}), seed=seed)


def scan_of(sensor, reading, t: float):
    """The reading as the MAVLink decoders normalise it: DISTANCE_SENSOR (a single beam) or OBSTACLE_DISTANCE bins."""
    if isinstance(sensor, SingleBeam):
        return range_scan(t, 0, 0.0, reading.current_cm / 100, reading.min_cm / 100, reading.max_cm / 100,
                          reading.signal_quality)
    d = np.asarray(reading.distances_cm, dtype=float)
    used = d != UINT16_MAX
    ang = np.radians(reading.angle_offset_deg + reading.increment_deg * np.arange(len(d)))
    rng = np.where(d > reading.max_cm, np.inf, d / 100.0)
    return bins_scan(t, 0, ang[used], rng[used], reading.max_cm / 100, math.radians(reading.increment_deg))


def fly(sensor, cfg: SensorConfig, world: World, seconds: float, confirm: int, appear=None,
        noise: RangeNoise = RangeNoise(0.0, 0.0)):
    """Fly +x at SPEED past `world`, one frame per sensor period; `appear` (t, obstacle): added to the world then;
    `noise`: the range noise the estimator is told. Returns (declared late detections, the estimator's (t,
    obstacle_m, D_od lowered) per frame, frames received)."""
    e = DodEstimator([cfg], ContractConfig(late_detection_confirm_frames=confirm), stale_s=0.5, range_noise=noise)
    dt = 1.0 / sensor.cfg.rate_hz
    declared, nearest, frames = [], [], []
    for k in range(int(seconds / dt)):
        t = k * dt
        x = SPEED * t
        if appear is not None and t >= appear[0] and appear[1] not in world.obstacles:
            world.add(appear[1])
        e.add_position(t, x, 0.0)
        e.add_heading(t, 0.0)
        e.set_speed(SPEED)
        reading = sensor.read(world, np.array([x, 0.0, -ALT_M]), 0.0)
        if reading is not None:  # a single beam sends nothing for a dropped frame
            e.add_scan(scan_of(sensor, reading, t))
            frames.append(t)
        est = e.estimate(t, 0.0)
        nearest.append((t, est.obstacle_m, est.lowered))
        if est.late is not None:
            declared.append((t, est.late, est.d_od))
    return declared, nearest, frames


@pytest.mark.parametrize("cls,defaults,cfg,rate", [(SingleBeam, SINGLE_BEAM, BEAM, 0.02),
                                                   (DepthCamera, DEPTH_CAMERA, CAMERA, 0.01)],
                         ids=["single_beam", "depth_camera"])
def test_spurious_close_returns_in_clear_air_are_never_late_detections_nor_within_the_clutter_obstacles(
        cls, defaults, cfg, rate):
    """Clear air, spurious close returns at 40× (the beam) and 5× (the camera) their defaults: none is declared a
    late detection and D_od is never lowered. With the sensor's clutter configured (`clutter_m`, the reach of its
    spurious returns) none reaches the obstacle logic: each came where the frames before saw free and is withheld
    until the following frames confirm it, which they never do. Without it each is an obstacle the frame it is seen
    (the hold and brake react to it); without the confirmation (negative control) the first is declared at once and
    holds D_od down for the hold time."""
    def run(confirm, clutter=0.0):
        sensor = model(cls, defaults, spurious_rate=rate, dropout_rate=0.0)
        return fly(sensor, cfg.model_copy(update={"clutter_m": clutter}), World(), 60.0, confirm)

    def close(frames):
        return sum(1 for _, m, _ in frames if m <= defaults["spurious_max_m"] + 0.05)

    declared, frames, _ = run(2, clutter=defaults["spurious_max_m"])
    assert close(frames) == 0 and declared == [] and not any(low for _, _, low in frames)
    declared, frames, _ = run(2)
    assert close(frames) > 100  # the returns were there, and without the clutter reached the obstacle logic
    assert declared == [] and not any(low for _, _, low in frames)
    old, frames, _ = run(0)
    assert len(old) >= 1 and old[0][1].range_m <= defaults["spurious_max_m"] + 0.05  # negative control
    lowered_s = sum(low for _, _, low in frames) / defaults["rate_hz"]
    assert lowered_s >= ContractConfig().late_detection_hold_s - 0.1  # at least one whole hold time


def test_a_real_obstacle_first_seen_inside_dod_is_declared_two_frames_later_where_it_was_first_seen():
    """A column that appears 4 m ahead (well inside the beam's 12 m) with the beam's dropped frames (10 %) and
    spurious returns on: an obstacle from its first frame, declared on the second frame received after it, at the
    range and time it was first seen; D_od lowered to that range. The same with the rule off: declared at once."""
    for seed in range(1, 9):
        def run(confirm, spurious, seed=seed):
            sensor = model(SingleBeam, SINGLE_BEAM, spurious_rate=spurious, dropout_rate=0.1, seed=seed)
            appear = (3.0, Column(SPEED * 3.0 + 4.0 + 0.3, 0.0, 0.3))
            return fly(sensor, BEAM, World(), 4.0, confirm, appear)

        declared, nearest, frames = run(2, 0.002)
        first = next(t for t, m, _ in nearest if t >= 3.0 and 3.0 < m < 4.5)  # the column's first frame
        assert len(declared) == 1, (seed, declared)
        t_decl, late, d_od = declared[0]
        assert late.t == pytest.approx(first) and late.range_m == pytest.approx(4.0, abs=0.3)
        assert frames.index(t_decl) - frames.index(first) == 2  # two frames received after the first
        assert d_od == late.range_m
        old, nearest, _ = run(0, 0.0)
        first = next(t for t, m, _ in nearest if t >= 3.0 and 3.0 < m < 4.5)
        assert len(old) == 1 and old[0][0] == pytest.approx(first)  # negative control: declared in its first frame


def test_a_real_obstacle_seen_by_bins_is_declared_although_bins_drop_out():
    """The depth camera with 20 % of bins dropped each frame: a dropped bin neither confirms nor ends a candidate
    (it looked at nothing), so a column appearing 4 m ahead is still declared, within a few frames."""
    for seed in range(1, 9):
        sensor = model(DepthCamera, DEPTH_CAMERA, spurious_rate=0.002, dropout_rate=0.2, seed=seed)
        appear = (3.0, Column(SPEED * 3.0 + 4.0 + 0.3, 0.0, 0.3))
        declared, _, _ = fly(sensor, CAMERA, World(), 4.0, 2, appear)
        period = 1.0 / DEPTH_CAMERA["rate_hz"]
        assert declared, seed
        t_decl, late, _ = declared[0]
        assert 3.0 - 1e-9 <= late.t <= 3.0 + 2 * period and late.range_m == pytest.approx(4.0, abs=0.3)
        assert t_decl - late.t <= 6 * period + 1e-9, (seed, t_decl, late)


# ------------------------------------------------------------------ the rule, frame by frame

def beam(confirm=2):
    return DodEstimator([BEAM], ContractConfig(late_detection_confirm_frames=confirm), stale_s=0.5)


def frame(e, t, r, x=None, quality=0):
    e.add_position(t, SPEED * t if x is None else x, 0.0)
    e.add_heading(t, 0.0)
    e.add_scan(range_scan(t, 0, 0.0, r, 0.1, 12.0, quality))
    return e.estimate(t, 0.0)


def clear_run(e, n=10, dt=0.01):
    for k in range(n):
        frame(e, k * dt, 12.01)
    return n * dt


def test_a_column_first_seen_late_by_the_camera_is_declared_although_its_readings_spread_with_the_noise():
    """The depth camera's σ grows with the square of the depth (0.36 m at 6 m): two frames' readings of a column
    appearing 6 m ahead fall up to ~1.5 m apart, beyond the late-detection tolerance (0.3 m + a frame's travel). Told
    the camera's noise, the confirmation matches them within what the noise spreads, and every seed is declared.
    Negative control: not told, a following reading outside the tolerance ends the candidate, and some real late
    columns are never declared."""
    def declared(noise):
        n = 0
        for seed in range(1, 13):
            sensor = model(DepthCamera, DEPTH_CAMERA, spurious_rate=0.0, dropout_rate=0.0, seed=seed)
            appear = (3.0, Column(SPEED * 3.0 + 6.0 + 0.3, 0.0, 0.3))
            n += bool(fly(sensor, CAMERA, World(), 4.0, 2, appear, noise)[0])
        return n

    assert declared(RangeNoise(0.0, 0.0, DEPTH_CAMERA["noise_quad_per_m"])) == 12
    assert declared(RangeNoise(0.0, 0.0)) < 12  # negative control


@pytest.mark.parametrize("quality,declared", [(10, False), (100, True)], ids=["weak", "strong_control"])
def test_weak_returns_in_a_row_at_one_place_are_no_surface(quality, declared):
    """A fog's own returns come near the sensor and weak (quality 2–10, below min_quality 50): three in a row at one
    place (each a frame's travel nearer) where the frames before saw 12 m free are neither declared nor, within the
    beam's 1.5 m clutter, an obstacle — a weak frame is no reading, it neither confirms a candidate nor ends one.
    Control: the same returns strong are a surface, declared on the third frame."""
    e = DodEstimator([BEAM.model_copy(update={"clutter_m": 1.5})], ContractConfig(), stale_s=0.5)
    t = clear_run(e)
    ests = [frame(e, t + 0.01 * k, 0.9 - SPEED * 0.01 * k, quality=quality) for k in range(3)]
    assert (ests[2].late is not None) == declared
    assert ests[2].lowered == declared and (ests[2].obstacle_m < 1.0) == declared


@pytest.mark.parametrize("between,declared", [(10, True), (100, False)], ids=["weak", "strong_control"])
def test_a_weak_frame_between_does_not_end_a_real_late_surface(between, declared):
    """A column first seen 4 m ahead (strong), then one frame whose nearest return is the fog's, weak, at 0.8 m, then
    the column again in two frames: declared where it was first seen — the weak frame hid it, it did not look past
    it. Control: the frame between strong (a trusted reading of something nearer) ends the candidate."""
    e = beam()
    t = clear_run(e)
    frame(e, t, 4.0)
    frame(e, t + 0.01, 0.8, quality=between)
    ests = [frame(e, t + 0.01 * k, 4.0 - SPEED * 0.01 * k) for k in (2, 3)]
    late = next((est.late for est in ests if est.late is not None), None)
    assert (late is not None) == declared
    if declared:
        assert late.range_m == 4.0 and late.t == t


def test_one_frame_return_is_an_obstacle_then_gone_and_nothing_is_lowered():
    e = beam()
    t = clear_run(e)
    est = frame(e, t, 0.4)
    assert est.obstacle_m == pytest.approx(0.4) and est.late is None and not est.lowered
    for k in range(1, 5):
        est = frame(e, t + 0.01 * k, 12.01)
        assert est.late is None and not est.lowered and est.d_od == pytest.approx(12.0)


@pytest.mark.parametrize("r,withheld", [(0.4, True), (1.2, False)])
def test_a_one_frame_return_within_the_sensor_s_clutter_is_withheld(r, withheld):
    """The beam with its clutter at 1 m: a return at 0.4 m where the frames before saw 12 m free is withheld until
    the frames that follow confirm it (they do not: it never reaches the obstacle logic); one at 1.2 m, beyond the
    clutter, is an obstacle from its first frame."""
    e = DodEstimator([BEAM.model_copy(update={"clutter_m": 1.0})], ContractConfig(), stale_s=0.5)
    t = clear_run(e)
    est = frame(e, t, r)
    assert est.obstacle_m == (math.inf if withheld else pytest.approx(r)) and est.withheld == int(withheld)
    assert frame(e, t + 0.01, 12.01).late is None


def test_a_return_within_the_clutter_seen_again_in_two_frames_is_an_obstacle_from_the_second():
    e = DodEstimator([BEAM.model_copy(update={"clutter_m": 1.0})], ContractConfig(), stale_s=0.5)
    t = clear_run(e)
    seen = [frame(e, t + 0.01 * k, 0.8 - SPEED * 0.01 * k).obstacle_m for k in range(4)]
    assert seen[:2] == [math.inf, math.inf] and seen[2] == pytest.approx(0.8 - SPEED * 0.02)


def test_returns_in_consecutive_frames_at_inconsistent_places_are_not_confirmed():
    """Two spurious returns one after the other, 0.2 m and 0.9 m: not one surface (a static one would be within
    the tolerance plus a frame's travel of where it was); a third, consistent with the second, starts anew."""
    e = beam()
    t = clear_run(e)
    for k, r in enumerate((0.2, 0.9)):
        assert frame(e, t + 0.01 * k, r).late is None
    assert frame(e, t + 0.02, 12.01).late is None
    old = beam(0)
    t = clear_run(old)
    assert frame(old, t, 0.2).late is not None  # negative control


def test_a_candidate_ended_in_a_bin_does_not_hide_a_real_obstacle_appearing_there_next():
    """A spurious return in the frame just before a real obstacle appears in the same bin: the obstacle is not
    "the same as before" (that return was ended as no obstacle), it is a first sight of its own, declared."""
    cfg = SensorConfig(kind="obstacle_distance", h_fov_deg=60.0)
    e = DodEstimator([cfg], ContractConfig(), stale_s=0.5)
    bearings = np.radians(np.arange(-30, 31, 5.0))
    inc = math.radians(5)
    far = np.full(len(bearings), np.inf)

    def bins(t, r6):
        ranges = far.copy()
        ranges[6] = r6
        e.add_position(t, 0.0, 0.0)
        e.add_heading(t, 0.0)
        e.add_scan(bins_scan(t, 0, bearings, ranges, 10.0, inc))
        return e.estimate(t, 0.0)

    for k in range(5):
        bins(0.05 * k, np.inf)
    assert bins(0.25, 0.5).late is None  # spurious, 0.5 m
    lates = [bins(0.30 + 0.05 * k, 4.0).late for k in range(3)]  # a real surface at 4 m from the next frame on
    assert lates[:2] == [None, None] and lates[2] is not None and lates[2].range_m == 4.0


@pytest.mark.parametrize("looked", [True, False])
def test_a_surface_confirmed_within_the_clutter_where_the_sensor_had_looked_past_is_declared(looked):
    """Bins of 5° over 60°, their clutter at 1.5 m, flying +x: a surface at 1.0 m in the edge bin (no late first
    detection: it may have come in from the side) where the frames before, from farther back, looked past it is
    withheld two frames, then declared — a surface where the sensor had looked past is a broken guarantee. Where
    no frame had looked (that half of the bins dropped before), it may have come in from the side: taken at once,
    not declared."""
    cfg = SensorConfig(kind="obstacle_distance", h_fov_deg=60.0, clutter_m=1.5)
    e = DodEstimator([cfg], ContractConfig(), stale_s=0.5)
    bearings = np.radians(np.arange(-27.5, 28, 5.0))
    inc = math.radians(5)
    for k in range(6):
        used = bearings if looked else bearings[6:]
        e.add_position(0.05 * k, SPEED * 0.05 * k, 0.0)
        e.add_heading(0.05 * k, 0.0)
        e.add_scan(bins_scan(0.05 * k, 0, used, np.full(len(used), np.inf), 10.0, inc))
        e.estimate(0.05 * k, 0.0)
    out = []
    for k in range(6, 9):
        ranges = np.full(len(bearings), np.inf)
        ranges[0] = 1.0 - SPEED * 0.05 * (k - 6) * math.cos(bearings[0])
        e.add_position(0.05 * k, SPEED * 0.05 * k, 0.0)
        e.add_heading(0.05 * k, 0.0)
        e.add_scan(bins_scan(0.05 * k, 0, bearings, ranges, 10.0, inc))
        out.append(e.estimate(0.05 * k, 0.0))
    if looked:
        assert [o.obstacle_m for o in out[:2]] == [math.inf, math.inf] and out[2].obstacle_m < 1.0
        assert out[2].late is not None and out[2].late.range_m == 1.0 and out[2].d_od == pytest.approx(1.0)
    else:
        assert all(o.obstacle_m <= 1.0 and o.late is None for o in out)


def test_a_confirmed_detection_holds_dod_down_for_the_hold_time_from_its_declaration():
    e = beam()
    t = clear_run(e)
    for k in range(3):
        est = frame(e, t + 0.01 * k, 5.0 - SPEED * 0.01 * k)
    assert est.late is not None and est.d_od == pytest.approx(5.0)
    t_decl = t + 0.02
    hold = ContractConfig().late_detection_hold_s
    assert frame(e, t_decl + hold - 0.05, 12.01).d_od == pytest.approx(5.0)
    assert frame(e, t_decl + hold + 0.05, 12.01).d_od == pytest.approx(12.0)


def test_the_confirmation_frames_are_bounded_and_more_than_the_default_is_named_weaker():
    with pytest.raises(ContractError, match="late_detection_confirm_frames"):
        config_from_dict({"contract": {"late_detection_confirm_frames": 6}})
    with pytest.raises(ContractError, match="late_detection_confirm_frames"):
        config_from_dict({"contract": {"late_detection_confirm_frames": -1}})
    lines = weakened(config_from_dict({"contract": {"late_detection_confirm_frames": 4}}))
    assert any("late_detection_confirm_frames 4 (default 2)" in line for line in lines), lines
    assert not any("late_detection_confirm" in line for line in
                   weakened(config_from_dict({"contract": {"late_detection_confirm_frames": 0}})))



def test_close_returns_in_bins_far_apart_are_not_one_place():
    """The camera's bins, flying at 1.5 m/s: spurious returns at −15° 0.54 m, −10° 0.60 m, +30° 0.47 m in three frames
    in a row (as the SITL's camera drew them once) are not one surface: 0.38 m apart in the local frame, within the
    tolerance, but 40° apart — a static surface stays in its bin or the one beside it. The same surface seen in
    its bin and coming nearer by the travel is."""
    bearings = np.radians(np.arange(-40, 41, 5.0))
    inc = math.radians(5)

    def run(seen):
        e = DodEstimator([CAMERA], ContractConfig(), stale_s=0.5)
        e.set_speed(SPEED)
        dt = 1 / 30
        late = None
        for k in range(10 + len(seen)):
            t = k * dt
            ranges = np.full(len(bearings), np.inf)
            if k >= 10:
                deg, r = seen[k - 10]
                ranges[int(round((deg + 40) / 5))] = r
            e.add_position(t, SPEED * t, 0.0)
            e.add_heading(t, 0.0)
            e.add_scan(bins_scan(t, 0, bearings, ranges, 10.0, inc))
            late = late or e.estimate(t, 0.0).late
        return late

    assert run([(-15, 0.54), (-10, 0.60), (30, 0.47)]) is None
    surface = run([(-15, 0.54), (-15, 0.49), (-15, 0.44)])
    assert surface is not None and surface.range_m == 0.54
