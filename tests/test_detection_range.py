"""The detection-range estimator (companion/onboard/detection_range.py) against the SITL's range-sensor model
(sitl_harness/sensors.py): a kinematic flight past columns, each frame the sensor's reading decoded into a
`Scan` by MAVLink-in's own helpers (OBSTACLE_DISTANCE bins, or DISTANCE_SENSOR's single beam), no daemon.

Every property is asserted by one helper, and a stand-in that trusts the sensor's claim is run through the
same helpers and must fail them (the negative control)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from companion.onboard.autopilots import adapter_for
from companion.onboard.config import Config, SensorConfig, config_from_dict
from companion.onboard.cycle import Cycle
from companion.onboard.detection_range import (DetectionRange, DetectionRangeEstimate, DetectionRangeParams, RangeNoise,
                                               evidence_line, per_shot_rate, surface_bins)
from companion.onboard.guidance import InlinePlanning
from companion.onboard.mavlink_in import UINT16_MAX, bins_scan, range_scan
from companion.onboard.samples import Heading, Position, Scan
from contracts.errors import ContractError
from contracts.lidar import (backscatter_probability, detection_range, extinction_for_range,
                             extinction_from_met_visibility, per_shot_from_reports, visibility_for_extinction)
from contracts.table import load_for_vehicle
from sitl_harness.sensor_models import DepthCamera
from sitl_harness.sensors import RangeSensor, RangeSensorConfig
from sitl_harness.world import Column, World

R_MAX = 10.0
RATE_HZ = 20.0
SPEED = 3.0
T_ON_S = 1.5  # the estimator's stated onset bound (window 1 s) plus a frame and margin
T_RECOVER_S = 4.5  # window 1 s + hold 3 s, plus margin
FACTOR = 1.15  # after the onset, the estimate is at most this times the true detection range...
FLOOR = 0.5  # ... and, over the fog, its median at least this times it (useful, not just zero)

BINS = SensorConfig(kind="obstacle_distance", h_fov_deg=60.0, max_range_m=R_MAX)
BEAM = SensorConfig(kind="distance_sensor", h_fov_deg=60.0, max_range_m=R_MAX)
# the SITL's DISTANCE_SENSOR as it is: the nearest return of its 12 bins (60° in 5° bins), each one shot a frame
BEAMS = SensorConfig(kind="distance_sensor", h_fov_deg=60.0, max_range_m=R_MAX, shots_per_frame=12)
HAZE_MET_M = 200.0  # a haze's meteorological visibility: α = 3.912 / 200 m shortens no range of 10 m


class TrustTheClaim:
    """The negative control: D_od is whatever the sensor states."""

    def __init__(self, *_a, **_k):
        pass

    def add_position(self, *a):
        pass

    def add_heading(self, *a):
        pass

    def add_scan(self, scan):
        pass

    def estimate(self, t, stated_m):
        return DetectionRangeEstimate(stated_m, stated_m, 1.0, 0.0, "the claim")


def scan_of(reading, t: float, sensor: int, beam: bool, rated_m: float = R_MAX):
    """A sensor frame decoded as MAVLink-in decodes OBSTACLE_DISTANCE (bins) or DISTANCE_SENSOR (one beam)."""
    max_m = reading.max_cm / 100
    if beam:
        return range_scan(t, sensor, 0.0, reading.current_cm / 100, reading.min_cm / 100, max_m,
                          reading.signal_quality, rated_m)
    d = np.asarray(reading.distances_cm, dtype=float)
    used = d != UINT16_MAX
    ang = np.radians(reading.angle_offset_deg + reading.increment_deg * np.arange(len(d)))
    rng = np.where(d > reading.max_cm, np.inf, d / 100.0)
    return bins_scan(t, sensor, ang[used], rng[used], max_m, math.radians(reading.increment_deg), rated_m)


def route_world(length_m: float, seed: int, spacing: float = 12.0, rho=(0.5,)) -> World:
    """Columns along the +x route every `spacing` m, centres 0.9–3.5 m either side of it (none hit), of the
    given reflectivities in turn."""
    rng = np.random.default_rng(seed)
    cols = []
    for k, x in enumerate(np.arange(15.0, length_m, spacing)):
        side = 1 if rng.random() < 0.5 else -1
        cols.append(Column(float(x), side * float(rng.uniform(0.9, 3.5)), float(rng.uniform(0.2, 0.5)),
                           reflectivity=rho[k % len(rho)]))
    return World(cols)


def nearby(world: World, x: float, r_max: float = R_MAX) -> World:
    """The columns within reach of the sensor from x (the ray cast's cost is per column)."""
    return World([c for c in world.columns if -5.0 < c.x - x < r_max + 5.0])


def fly(world: World, seconds: float, fog: list[tuple[float, float | None]], estimator, *, beam=False,
        seed: int = 1, sensor_cfg: RangeSensorConfig | None = None, speed: float = SPEED, model=RangeSensor):
    """Fly +x at `speed` through `world` with fog events [(t, visibility or None: clear)] (hidden fog); returns
    per frame (t, d_od, stated, true detection range of the default target). `model`: the SITL's sensor class."""
    s = model(sensor_cfg or RangeSensorConfig(max_range_m=R_MAX), seed=seed)
    s.honest = False
    events = sorted(fog, key=lambda e: e[0])
    out = []
    for k in range(int(seconds * RATE_HZ)):
        t = k / RATE_HZ
        while events and events[0][0] <= t + 1e-9:
            v = events.pop(0)[1]
            s.visibility_m = math.inf if v is None else v
        pos = np.array([speed * t, 0.0, -2.0])
        estimator.add_position(t, pos[0], pos[1])
        estimator.add_heading(t, 0.0)
        r = s.read(nearby(world, pos[0], s.cfg.max_range_m), pos, 0.0)
        estimator.add_scan(scan_of(r, t, 0, beam, s.cfg.max_range_m))
        est = estimator.estimate(t, r.max_cm / 100)
        out.append((t, est.d_od, est.stated_m, min(s.visibility_m, s.cfg.max_range_m)))
    return out


# ------------------------------------------------------------------ the properties (used by every test)
def never_above_the_claim(trace):
    assert all(d <= stated + 1e-9 for _, d, stated, _ in trace)


def no_false_lowering(trace):
    low = [t for t, d, stated, _ in trace if d < stated - 1e-9]
    assert not low, f"{len(low)} of {len(trace)} cycles lowered in clear air, first at {low[0]:.2f} s"


def follows_the_fog(trace, t_on: float, t_off: float, truth: float):
    """From t_on + T_ON_S until the fog clears: at most FACTOR × the true range; its median at least FLOOR ×."""
    during = [d for t, d, _, _ in trace if t_on + T_ON_S <= t < t_off]
    assert during
    assert max(during) <= FACTOR * truth, f"estimate {max(during):.2f} m > {FACTOR} × true {truth:.2f} m"
    assert np.median(during) >= FLOOR * truth, f"median {np.median(during):.2f} m below {FLOOR} × {truth:.2f} m"


def costs_nothing(trace):
    """A medium that cannot shorten the range: the median estimate is the stated range, the mean at least 0.98 of
    it, and lowered in at most 10 % of the cycles (a rare second of haze returns as many as a fog's may still lower
    it for the hold's 3 s)."""
    ratio = np.array([d / stated for _, d, stated, _ in trace])
    assert np.median(ratio) == pytest.approx(1.0), f"median {np.median(ratio):.2f} of the stated range"
    assert ratio.mean() >= 0.98, f"mean {ratio.mean():.3f} of the stated range"
    assert np.mean(ratio < 1.0 - 1e-9) <= 0.1, f"lowered in {np.mean(ratio < 1.0 - 1e-9):.0%} of the cycles"


def recovers(trace, t_off: float):
    after = [(t, d, stated) for t, d, stated, _ in trace if t >= t_off + T_RECOVER_S]
    assert after and all(d == pytest.approx(stated) for _, d, stated in after)


# ------------------------------------------------------------------ clear air
def test_clear_air_never_lowers_over_a_long_flight():
    """10 minutes at 3 m/s (1.8 km) past 148 columns (0.9–3.5 m off the route, reflectivity 0.1, 0.5, 0.9 in
    turn): not one cycle of 12 000 lowers D_od below the stated range."""
    world = route_world(1800.0, seed=3, rho=(0.1, 0.5, 0.9))
    trace = fly(world, 600.0, [], DetectionRange([BINS]))
    no_false_lowering(trace)
    never_above_the_claim(trace)


# ------------------------------------------------------------------ evidence per shot
def test_a_report_of_the_nearest_of_many_shots_is_inverted_per_shot():
    """The SITL draws the medium's return per bin and frame (p = 1 − e^(−α·L_bs)); a DISTANCE_SENSOR reports the
    nearest of its bins, so a frame carries one with q = 1 − (1 − p)^12. Inverted per shot, 20 000 frames give p
    back; taken as one shot each (the per-frame reading) they over-state it about tenfold."""
    rng = np.random.default_rng(4)
    for alpha in (extinction_from_met_visibility(HAZE_MET_M), extinction_for_range(8.0, 0.5, R_MAX),
                  extinction_for_range(4.0, 0.5, R_MAX)):
        p = backscatter_probability(alpha)
        frames = (rng.random((20000, 12)) < p).any(axis=1)
        q = frames.mean()
        assert per_shot_from_reports(q, 12) == pytest.approx(p, rel=0.1)
        assert per_shot_from_reports(q, 1) == q > 5.0 * p  # the per-frame reading
    assert per_shot_from_reports(0.3, 1) == 0.3


def test_reports_of_different_shots_pool_between_their_own_rates():
    """Two sensors in one window, bins (one shot each) and a single beam (12 shots a frame): the pooled per-shot
    rate lies between the two sensors' own, and one sensor alone is its closed form."""
    bins, beam = {1.0: [240, 6]}, {12.0: [20, 4]}
    a, b = per_shot_rate(bins), per_shot_rate(beam)
    assert min(a, b) < per_shot_rate({**bins, **beam}) < max(a, b)
    assert per_shot_rate(beam, up=False) == pytest.approx(1 - (1 - 4 / 20) ** (1 / 12))
    assert per_shot_rate(bins, up=False) == 6 / 240


def test_the_banner_says_what_each_frame_is_counted_as():
    line = evidence_line([BEAM, BINS, BEAMS])
    assert "[0] one shot per frame (assumed; shots_per_frame not set" in line
    assert "[1] one shot per bin (assumed" in line and "[2] 12 shots per frame (configured)" in line


def test_shots_per_frame_below_one_is_refused_naming_the_key():
    with pytest.raises(ContractError, match="shots_per_frame"):
        config_from_dict({"vehicle": "mambo", "mode": "governor",
                          "sensors": [{"kind": "distance_sensor", "h_fov_deg": 60, "max_range_m": 8,
                                       "shots_per_frame": 0}]})


@pytest.mark.parametrize("sensor", ["beams", "bins"])
def test_haze_costs_nothing(sensor):
    """Hidden haze of 200 m meteorological visibility (α 0.0196/m: the default target seen to 16 m, past the
    10 m range) for a minute at 3 m/s on two seeds: D_od stays at the stated range — the SITL's DISTANCE_SENSOR
    counted as its 12 shots a frame, or its 12 bins."""
    haze = visibility_for_extinction(extinction_from_met_visibility(HAZE_MET_M), 0.5, R_MAX)
    assert haze > R_MAX
    for seed in (1, 3):
        est = DetectionRange([BEAMS if sensor == "beams" else BINS])
        trace = fly(route_world(200.0, seed), 60.0, [(0.0, haze)], est, beam=sensor == "beams", seed=seed)
        costs_nothing([x for x in trace if x[0] >= 2.0])


@pytest.mark.parametrize("control", ["one_shot_per_frame", "one_second_rate"])
def test_negative_control_haze_read_as_fog(control):
    """The same haze through the old readings fails `costs_nothing`: a single beam's frame taken as one shot (its
    rate over-stated about tenfold: D_od cut to a fifth), or the last second's rate one standard error up taken
    whatever it says (`rate_window_s` the last second: a haze's chance few returns in one second read as fog)."""
    haze = visibility_for_extinction(extinction_from_met_visibility(HAZE_MET_M), 0.5, R_MAX)
    seed = 3
    if control == "one_shot_per_frame":
        est, beam = DetectionRange([BEAM]), True
    else:
        est, beam = DetectionRange([BINS], params=DetectionRangeParams(rate_window_s=1.0)), False
    trace = fly(route_world(200.0, seed), 60.0, [(0.0, haze)], est, beam=beam, seed=seed)
    with pytest.raises(AssertionError):
        costs_nothing([x for x in trace if x[0] >= 2.0])


@pytest.mark.parametrize("visibility", [8.0, 4.0])
def test_single_beam_counted_per_shot_follows_the_fog(visibility):
    """Hidden fog of visibility 0.8 and 0.4 of the stated range, the SITL's DISTANCE_SENSOR counted as its 12 shots
    a frame: never above FACTOR × the true range once the fog has been seen, never above the claim, its median at
    least FLOOR × the truth (`follows_the_fog`); the frame taken as one shot fails that (a median near 0.15 ×)."""
    world = route_world(200.0, seed=5)
    t_on, t_off = 6.0, 26.0
    trace = fly(world, 36.0, [(t_on, visibility), (t_off, None)], DetectionRange([BEAMS]), beam=True)
    never_above_the_claim(trace)
    follows_the_fog(trace, t_on, t_off, visibility)
    recovers(trace, t_off)
    old = fly(world, 36.0, [(t_on, visibility), (t_off, None)], DetectionRange([BEAM]), beam=True)
    with pytest.raises(AssertionError, match="median"):
        follows_the_fog(old, t_on, t_off, visibility)


# a sensor with spurious returns of its own at 0.3–1.0 m, where the fog's backscatter comes (0.5–1.5 m): 12 bins of
# 5° at 20 Hz, 0.4 % of them, about one a second; level at 2 m, so the ground stays out of its view
OWN_RATE = 0.004
OWN_CLUTTER = RangeSensorConfig(max_range_m=R_MAX, fov_deg=60.0, increment_deg=5.0, min_range_m=0.3,
                                spurious_rate=OWN_RATE, spurious_max_m=1.0)


def test_a_sensors_own_spurious_returns_are_not_a_fog():
    """10 minutes of clear air with the sensor's own spurious returns, their rate configured (`spurious_rate`): not
    one cycle lowers D_od. Unconfigured, the same returns read as fog (a few in one second): the control."""
    world = route_world(1800.0, seed=3, rho=(0.1, 0.5, 0.9))
    told = fly(world, 600.0, [], DetectionRange([BINS.model_copy(update={"spurious_rate": OWN_RATE})]), sensor_cfg=OWN_CLUTTER,
               model=DepthCamera)
    no_false_lowering(told)
    untold = fly(world, 600.0, [], DetectionRange([BINS]), sensor_cfg=OWN_CLUTTER, model=DepthCamera)
    with pytest.raises(AssertionError, match="lowered in clear air"):
        no_false_lowering(untold)


@pytest.mark.parametrize("visibility", [3.0, 6.0])
def test_a_fog_is_seen_over_the_sensors_own_spurious_returns(visibility):
    """Hidden fog over the same sensor's own returns, their rate configured: followed as without them."""
    world = route_world(200.0, seed=5)
    t_on, t_off = 6.0, 26.0
    trace = fly(world, 36.0, [(t_on, visibility), (t_off, None)],
                DetectionRange([BINS.model_copy(update={"spurious_rate": OWN_RATE})]), sensor_cfg=OWN_CLUTTER, model=DepthCamera)
    never_above_the_claim(trace)
    follows_the_fog(trace, t_on, t_off, visibility)
    recovers(trace, t_off)


# ------------------------------------------------------------------ hidden fog
@pytest.mark.parametrize("visibility", [3.0, 5.0, 8.0])
def test_hidden_fog_lowers_within_the_bound_and_recovers(visibility):
    world = route_world(200.0, seed=5)
    t_on, t_off = 6.0, 26.0
    trace = fly(world, 36.0, [(t_on, visibility), (t_off, None)], DetectionRange([BINS]))
    truth = detection_range(extinction_for_range(visibility, 0.5, R_MAX), 0.5, R_MAX)
    assert truth == pytest.approx(visibility)  # the scenario's visibility is the default target's range
    never_above_the_claim(trace)
    no_false_lowering([x for x in trace if x[0] < t_on])
    follows_the_fog(trace, t_on, t_off, truth)
    recovers(trace, t_off)


@pytest.mark.parametrize("check", ["lowers", "clear_air", "recovers"])
def test_negative_control_the_claim_fails_the_same_checks(check):
    """The stand-in that trusts the claim fails the fog checks (the claim never falls); the checks that
    it passes (clear air, recovery) are those a do-nothing estimator is expected to pass."""
    world = route_world(200.0, seed=5)
    trace = fly(world, 36.0, [(6.0, 5.0), (26.0, None)], TrustTheClaim())
    if check == "lowers":
        with pytest.raises(AssertionError):
            follows_the_fog(trace, 6.0, 26.0, 5.0)
    elif check == "clear_air":
        no_false_lowering(trace)  # trivially: it never lowers, which is why it cannot see fog
    else:
        recovers(trace, 26.0)


def test_an_estimator_that_never_recovers_fails_the_recovery_check():
    world = route_world(200.0, seed=5)
    est = DetectionRange([BINS])
    trace = fly(world, 36.0, [(6.0, 5.0), (26.0, None)], est)
    stuck = [(t, min(d, 5.0) if t >= 6.0 else d, stated, v) for t, d, stated, v in trace]
    with pytest.raises(AssertionError):
        recovers(stuck, 26.0)


@pytest.mark.parametrize("rho", [0.5, 0.9])
def test_single_beam_sees_the_fog_from_its_quality_trend(rho):
    """DISTANCE_SENSOR only (one range, one quality per frame): the quality of a column as it is approached
    through hidden fog gives α whatever the column's reflectivity (it cancels), and with the beam's medium
    returns the estimate falls to within FACTOR of the reference target's range before the column is reached."""
    world = World([Column(20.0, 0.6, 0.4, reflectivity=rho)])
    est = DetectionRange([BEAM])
    trace = fly(world, 11.0, [(0.0, 5.0)], est, beam=True, speed=1.5)
    truth = 5.0
    never_above_the_claim(trace)
    assert est.estimate(11.0, R_MAX).evidence["alpha_trend"] == pytest.approx(extinction_for_range(5.0, 0.5, R_MAX),
                                                                               rel=0.25)
    late = [d for t, d, _, _ in trace if t >= 10.5]  # the column is ~3.8 m away
    assert late and max(late) <= FACTOR * truth
    neg = fly(world, 11.0, [(0.0, 5.0)], TrustTheClaim(), beam=True, speed=1.5)
    assert max(d for t, d, _, _ in neg if t >= 10.5) > FACTOR * truth


def test_the_medium_returns_are_counted_and_a_close_surface_is_told_from_them():
    """`add_scan` names the returns it counts as the medium's (backscatter evidence): a short return that no
    tracked target accounts for and that does not stay put; a surface close by is told from them once seen in
    `confirm_frames` frames in a row. It takes nothing out of the scan (the tests below)."""
    est = DetectionRange([BINS, BEAM])
    bearings = np.radians(np.arange(-27.5, 30.0, 5.0))
    rng = np.random.default_rng(0)
    wall = (1.2 * math.cos(bearings[6]), 1.2 * math.sin(bearings[6]))
    counted = 0
    for k in range(40):  # hovering at the origin; the fog's returns at random ranges, a post 1.2 m ahead in bin 6
        t = k / RATE_HZ
        est.add_position(t, 0.0, 0.0)
        est.add_heading(t, 0.0)
        ranges = np.where(rng.random(12) < 0.3, rng.uniform(0.5, 1.5, 12), np.inf)
        ranges[6] = 1.2 + 0.01 * rng.standard_normal()
        scan = bins_scan(t, 0, bearings, ranges, R_MAX, math.radians(5), R_MAX)
        medium = est.add_scan(scan)
        counted += len(medium)
        if k >= 3:  # the post from its 4th frame on; a fog return right beside it is taken for it
            post = [j for j, (b, _) in enumerate(scan.hits) if b == bearings[6]]
            assert post and post[0] not in medium
            run = surface_bins(scan.hits, math.radians(5), 2.0, 3, 0.2)  # fog returns in a row with it: a surface
            for j, (b, r) in enumerate(scan.hits):
                if j not in medium and j not in run:
                    assert math.hypot(r * math.cos(b) - wall[0], r * math.sin(b) - wall[1]) < 0.45
    assert counted > 60  # most of the fog's ~140 returns
    assert est.add_scan(range_scan(2.0, 1, 0.0, 0.6, 0.1, R_MAX, 5, R_MAX)) == (0,)  # 0.6 m from the post
    assert est.estimate(2.0, R_MAX).alpha > 0.0  # and they are the medium's evidence


@pytest.mark.parametrize("run", [3, 99])
def test_a_wall_swept_into_view_by_a_turn_is_no_evidence_of_a_medium(run):
    """Clear air, the vehicle turning at 240°/s beside a wall 1.7 m off: each frame sees a new piece of it in three
    adjacent bins, never in the same place twice (no `confirm_frames` can tell it from the medium's returns). A run
    of adjacent bins at a surface's ranges is a surface: no α, D_od the stated range. Control (`surface_run` 99): the
    wall's pieces read as a fog."""
    est = DetectionRange([BINS], params=DetectionRangeParams(surface_run=run))
    bearings = np.radians(np.arange(-27.5, 30.0, 5.0))
    for k in range(12):
        t = k / RATE_HZ
        est.add_position(t, 0.1 * k, 0.0)
        est.add_heading(t, math.radians(12.0 * k))
        ranges = np.full(12, np.inf)
        if k < 6:
            ranges[[9, 10, 11]] = (1.75, 1.71, 1.72)  # coming into view at the field's edge, swept on by the turn
        medium = est.add_scan(bins_scan(t, 0, bearings, ranges, R_MAX, math.radians(5), R_MAX))
        assert (medium == ()) == (run == 3 or k >= 6)
    e = est.estimate(11 / RATE_HZ, R_MAX)
    assert (e.alpha == 0.0 and e.d_od == R_MAX) if run == 3 else (e.alpha > 0.0 and e.d_od < R_MAX)


def governor_cycle(sensors=(BINS, BEAM)):
    """The daemon's cycle (governor mode, PX4), fed its samples directly: no link, no vehicle."""
    cfg = Config(vehicle="mambo", mode="governor", sensors=[s.model_dump() for s in sensors])
    return Cycle(cfg, load_for_vehicle(cfg.vehicle, cfg.table), adapter_for("px4"), "stop", InlinePlanning)


def hide_the_medium(cycle) -> None:
    """A negative control only: the returns `add_scan` counts as the medium's withheld from the obstacle logic
    (a surface first seen close by reaches it once `confirm_frames` frames confirm it), and a single beam's
    quality then unknown. Runs of adjacent bins are not read as surfaces here (`surface_run`): a dense fog's own
    runs are withheld too, as the medium's."""
    truth = cycle.sensing.truth
    truth.p = replace(truth.p, surface_run=10 ** 6)

    def scan(s):
        medium = cycle.sensing.truth.add_scan(s)
        if medium:
            s = replace(s, hits=tuple(h for k, h in enumerate(s.hits) if k not in medium),
                        quality=0 if s.known is None else s.quality)
        cycle.sensing.dod.add_scan(s)
    cycle.sensing._takers[Scan] = scan


def approach(cycle, frames: int, seen):
    """Fly +x at 2 m/s for `frames` sensor frames (20 Hz), each frame's scans from `seen(t, x)`; the obstacle
    logic's hits (body bearing, range) after each frame."""
    out = []
    for k in range(frames):
        t = k / RATE_HZ
        x = 2.0 * t
        cycle.take(Position(t, x, 0.0))
        cycle.take(Heading(t, 0.0, 2.0))
        for s in seen(t, x):
            cycle.take(s)
        out.append([(b, r) for b, r, *_ in cycle.sensing.dod.fresh_hits(t)])
    return out


def a_post_from(x_post: float, x_from: float):
    """Frames of both sensors: clear, until the vehicle is past `x_from`; then a post at `x_post` straight ahead."""
    bearings = np.radians(np.arange(-27.5, 30.0, 5.0))

    def seen(t, x):
        r = x_post - x if x >= x_from else np.inf
        ranges = np.where(np.abs(bearings - bearings[6]) < 1e-9, r, np.inf)
        return [bins_scan(t, 0, bearings, ranges, R_MAX, math.radians(5), R_MAX),
                range_scan(t, 1, 0.0, r if math.isfinite(r) else R_MAX + 0.01, 0.1, R_MAX, 100, R_MAX)]
    return seen


def reached_on_its_first_frame(hits_per_frame, first: int, r_first: float):
    """The frames before `first` see nothing; on frame `first` both sensors' hit at `r_first` is in the obstacle
    logic, and on every frame after."""
    assert all(not h for h in hits_per_frame[:first])
    assert [r for _, r in hits_per_frame[first]] == pytest.approx([r_first, r_first])
    assert all(len(h) == 2 for h in hits_per_frame[first:])


def test_a_close_return_reaches_the_obstacle_logic_on_its_first_frame():
    """A post first seen 1.8 m ahead at 2 m/s (inside `near_m`, on no tracked target: on its first frame the
    estimator counts it as the medium's) is in the obstacle logic from that frame on, from the sector sensor and
    the single beam alike; the beam's quality is the one it sent."""
    cycle = governor_cycle()
    hits = approach(cycle, 20, a_post_from(2.3, 0.5 - 1e-9))  # seen from frame 5 (x = 0.5 m) on
    reached_on_its_first_frame(hits, 5, 1.8)
    assert cycle.sensing.dod.sensors[1].trusted  # quality 100, as sent


def test_negative_control_withholding_the_medium_returns_hides_the_close_post():
    """The same frames with the returns counted as the medium's withheld from the obstacle logic
    (`hide_the_medium`): the post reaches it 3 frames late, and the check above fails."""
    cycle = governor_cycle()
    hide_the_medium(cycle)
    hits = approach(cycle, 20, a_post_from(2.3, 0.5 - 1e-9))
    with pytest.raises(AssertionError):
        reached_on_its_first_frame(hits, 5, 1.8)
    assert all(not h for h in hits[:8]) and len(hits[8]) == 2  # seen on frame 5, in the obstacle logic from 8


def test_a_dark_column_first_seen_late_in_clear_air_lowers_d_od():
    """A column of reflectivity 0.05 (half the rated 0.1) is seen only from R_max·√0.5 ≈ 7.1 m even in clear
    air: its first detection bounds D_od there (a sensor's stated range is for its rated target)."""
    world = World([Column(30.0, 0.3, 0.4, reflectivity=0.05)])
    trace = fly(world, 9.0, [], DetectionRange([BINS]))
    seen_at = R_MAX * math.sqrt(0.5)
    never_above_the_claim(trace)
    lowered = [d for t, d, stated, _ in trace if d < stated]
    assert lowered and max(lowered) <= seen_at + 0.3
    with pytest.raises(AssertionError):
        no_false_lowering(trace)  # the check itself sees a lowering


def test_disagreement_between_two_sensors():
    """Two forward sensors claim 10 m; the second's window is dirty (its link budget rated at a target of
    reflectivity 1.0: it sees the default target only to √0.5·10 ≈ 7.1 m). While the first sees a column
    between 7.1 and 10 m that the second does not, D_od is bounded by the column's distance."""
    world = World([Column(30.0, 0.3, 0.4)])
    est = DetectionRange([BINS, BINS])
    good = RangeSensor(RangeSensorConfig(max_range_m=R_MAX), seed=1)
    dirty = RangeSensor(RangeSensorConfig(max_range_m=R_MAX, rated_reflectivity=1.0), seed=2)
    lowered = []
    for k in range(int(8.0 * RATE_HZ)):
        t = k / RATE_HZ
        pos = np.array([SPEED * t, 0.0, -2.0])
        est.add_position(t, pos[0], pos[1])
        est.add_heading(t, 0.0)
        for i, s in enumerate((good, dirty)):
            est.add_scan(scan_of(s.read(world, pos, 0.0), t, i, False))
        e = est.estimate(t, R_MAX)
        assert e.d_od <= R_MAX
        if e.d_od < R_MAX:
            lowered.append((t, e.d_od, e.reason))
    assert lowered and any("does not" in why for _, _, why in lowered)
    assert all(d <= 10.0 for _, d, _ in lowered)


def test_bad_input_never_raises_d_od():
    est = DetectionRange([BINS], cap_m=8.0)
    est.add_position(0.0, math.nan, 0.0)
    est.add_heading(0.0, math.inf)
    est.add_scan(bins_scan(0.0, 0, np.radians([0.0, 5.0]), np.array([0.5, np.inf]), 10.0, math.radians(5), 10.0))
    assert est.estimate(0.1, 10.0).d_od <= 8.0
    assert est.estimate(0.2, math.nan).d_od == 0.0
    assert est.estimate(0.3, -1.0).d_od == 0.0


def _lowest_d_od(noise: RangeNoise, frames: int, seen) -> float:
    """Fly +x at SPEED with 12 bins of 5° at 20 Hz, frame k at t seeing `seen(k, t)` = (its bin, range) and nothing
    else: the lowest D_od the estimator told the range noise `noise` gives."""
    est = DetectionRange([BINS], params=DetectionRangeParams(range_noise=noise))
    bearings = np.radians(np.arange(-27.5, 30.0, 5.0))
    lowest = math.inf
    for k in range(frames):
        t = k / RATE_HZ
        est.add_position(t, SPEED * t, 0.0)
        est.add_heading(t, 0.0)
        b, r = seen(k, t)
        ranges = np.where(np.arange(len(bearings)) == b, r, np.inf)
        est.add_scan(bins_scan(t, 0, bearings, ranges, R_MAX, math.radians(5), R_MAX))
        lowest = min(lowest, est.estimate(t, R_MAX).d_od)
    return lowest


def _tracked_then_short(noise: RangeNoise, short_m: float) -> float:
    """A column tracked just right of ahead from 9.5 m in to 7.5 m (3 m/s), then three frames reading it `short_m`
    short in the next bin (it straddles the two), which had seen free."""
    return _lowest_d_od(noise, 16, lambda k, t: (7, 9.5 - SPEED * t - short_m) if k >= 13 else (6, 9.5 - SPEED * t))


def test_a_tracked_column_read_short_by_the_noise_is_that_column_not_a_first_sighting():
    """A stereo camera's noise (σ = 0.01 per metre × r²: 0.3 m at 5.5 m): frames read the tracked column 2 m short,
    within the tracking's 1 m, the bin's width and three σ. It is the column, not a target first seen at 5.5 m.
    Control: an estimator told of a lidar's noise (3 cm + 1 %) takes it for a first sighting and lowers D_od."""
    assert _tracked_then_short(RangeNoise(0.0, 0.0, 0.01), 2.0) == R_MAX
    assert _tracked_then_short(RangeNoise(), 2.0) < 6.0  # negative control


def test_a_first_sighting_is_judged_against_the_noise_at_the_stated_range():
    """A stereo camera (σ = 0.01 per metre × r²: 1 m at its stated 10 m) first sees a column at 7.2 m, where its
    frames had seen free: a target at the stated range reads that short by noise alone (2.8 σ), no evidence of a
    shorter range. Control: judged against the noise at 7.2 m (σ 0.52 m) it is a first sighting that lowers D_od."""
    class AtTheSighting(RangeNoise):  # the control's: no allowance beyond the noise at the sighting's 7.2 m
        def short_m(self, r: float) -> float:
            return super().short_m(min(r, 7.2))

    def lowest(at_stated: bool) -> float:
        noise = (RangeNoise if at_stated else AtTheSighting)(0.0, 0.0, 0.01)
        return _lowest_d_od(noise, 13, lambda k, t: (6, 7.2 - SPEED * (t - 0.5) if k >= 10 else np.inf))

    assert lowest(True) == R_MAX
    assert lowest(False) < R_MAX  # negative control


def _column_then_short(short_frames: int) -> float:
    """A stereo camera (σ = 0.01 per metre × r²) following a column dead ahead from 9.9 m in, then `short_frames`
    frames reading it at 5 m in its own bin, which had seen past there."""
    return _lowest_d_od(RangeNoise(0.0, 0.0, 0.01), 12,
                        lambda k, t: (6, 5.0 if 4 <= k < 4 + short_frames else 9.9 - SPEED * t))


def test_one_frame_of_range_noise_far_short_of_a_column_is_not_a_first_sighting():
    """A camera's reading 5 σ short of a column near its claim (4.3 m short at 9.3 m) comes at a place its frames had
    looked past, inside the claim by more than the noise at the claim allows: a first sighting by every rule of the
    first frame. The next frame reads the column again and nothing at 5 m: no surface stayed, D_od is not lowered.
    Control: the same reading in three frames in a row is a target first seen at 5 m."""
    assert _column_then_short(1) == R_MAX
    assert _column_then_short(3) == pytest.approx(5.0)  # negative control
