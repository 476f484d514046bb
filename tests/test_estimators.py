import math

import numpy as np
import pytest

from companion.onboard.config import ContractConfig, SensorConfig, ThrustConfig
from companion.onboard.estimators import (SENSOR_LAG_S, SWEPT_MARGIN_M, DodEstimator, EtrEstimator, NavHealth,
                                         SilenceBudget, ThrustEstimator)
from companion.onboard.detection_range import RangeNoise
from companion.onboard.mavlink_in import bins_scan, range_scan
from contracts.vehicle import G


def add_range(e, i, t, current_m, min_m, max_m, quality):
    """A DISTANCE_SENSOR sample of configured sensor i, as MAVLink-in normalises it."""
    e.add_scan(range_scan(t, i, math.radians(e.sensors[i].cfg.orientation_deg), current_m, min_m, max_m, quality))


def add_bins(e, i, t, bearings, ranges_m, max_m, increment):
    """An OBSTACLE_DISTANCE sample of configured sensor i, as MAVLink-in normalises it."""
    e.add_scan(bins_scan(t, i, bearings, ranges_m, max_m, increment))

FWD = SensorConfig(h_fov_deg=30.0)
RIGHT = SensorConfig(h_fov_deg=30.0, orientation_deg=90.0, id=2)
CC = ContractConfig()


def dod(*sensors):
    return DodEstimator(list(sensors) or [FWD], CC, stale_s=0.5)


def test_dod_is_the_reported_range_along_a_covered_direction():
    e = dod()
    add_range(e, 0, 0.0, current_m=10.0, min_m=0.1, max_m=10.0, quality=100)
    assert e.estimate(0.1, beta=0.0).d_od == 10.0
    assert e.estimate(0.1, beta=math.radians(14)).d_od == 10.0
    assert e.estimate(0.1, beta=math.radians(20)).d_od == 0.0  # outside the 30° field of view
    assert e.estimate(0.1, beta=0.0).obstacle_m == math.inf  # current ≥ max: nothing seen


def test_dod_stale_untrusted_and_honest_fog():
    e = dod()
    add_range(e, 0, 0.0, 10.0, 0.1, 10.0, 100)
    assert e.estimate(0.6, 0.0).d_od == 0.0  # stale ⇒ 0
    add_range(e, 0, 1.0, 10.0, 0.1, 10.0, 1)  # quality 1 = invalid
    assert e.estimate(1.0, 0.0).d_od == 0.0
    add_range(e, 0, 1.1, 3.0, 0.1, 3.0, 80)  # honest fog: the sensor reports a shorter range
    assert e.estimate(1.1, 0.0).d_od == 3.0
    add_range(e, 0, 1.2, 10.0, 0.1, 10.0, 0)  # 0 = quality unknown: accepted
    assert e.estimate(1.2, 0.0).d_od == 10.0


def test_a_weak_reading_is_no_reading_its_return_an_obstacle_and_its_sensor_covers_within_its_budget():
    """A single beam at 20 Hz whose frames now and then carry a weak return (a fog's, quality 10, below min_quality
    50): such a frame says nothing of free space — D_od stays what the last trusted frame gave, within the sensor's
    silence budget — but its return is an obstacle. Weak frames alone for longer than the budget: D_od 0."""
    e = dod()
    for k in range(20):
        add_range(e, 0, 0.05 * k, 10.0, 0.1, 10.0, 100)
    add_range(e, 0, 1.0, 1.2, 0.1, 10.0, 10)
    est = e.estimate(1.0, 0.0)
    assert est.d_od == 10.0 and est.obstacle_m == 1.2
    add_range(e, 0, 1.05, 10.0, 0.1, 10.0, 100)
    assert e.estimate(1.05, 0.0).obstacle_m == math.inf
    for k in range(1, 20):
        add_range(e, 0, 1.05 + 0.05 * k, 1.2, 0.1, 10.0, 10)
    budget = e.sensors[0].budget
    assert budget < 0.95 and e.estimate(1.05 + 0.95, 0.0).d_od == 0.0


@pytest.mark.parametrize("weak", [True, False], ids=["weak_readings", "silent"])
def test_a_sensor_reading_only_weak_returns_keeps_what_it_saw_free_a_silent_one_nothing(weak):
    """Flying +x at 2 m/s with a single beam at 20 Hz: 1 s of trusted frames seeing nothing within its 10 m, then only
    weak ones (a fog's return at 1.2 m, quality 10, below min_quality 50). Past the silence budget D_od is what the
    trusted frames saw free, less the travel since (the obstacles are static), and said so — not 0 — until the
    swept coverage's 2 s have passed. The weak return is still an obstacle. Control: the sensor silent instead
    (no frames at all): dead past its budget (three periods, as the daemon's default), D_od 0."""
    e = DodEstimator([FWD], CC, stale_s=0.5, silence=SilenceBudget(3.0, 0.1, 0.5))
    t = 0.0
    for k in range(20):
        t = 0.05 * k
        e.add_position(t, 2.0 * t, 0.0)
        e.add_heading(t, 0.0)
        add_range(e, 0, t, 10.0, 0.1, 10.0, 100)
    last = t
    d = {}
    for k in range(1, 50):
        t = last + 0.05 * k
        e.add_position(t, 2.0 * t, 0.0)
        e.add_heading(t, 0.0)
        if weak:
            add_range(e, 0, t, 1.2, 0.1, 10.0, 10)
        d[k] = e.estimate(t, 0.0)
    assert e.sensors[0].budget < 0.5
    if not weak:
        assert d[10].d_od == 0.0 and d[10].silent
        return
    def free(since_s):  # the 10 m seen free, less the travel since it was taken (up to SENSOR_LAG_S before it)
        return 10.0 - 2.0 * (since_s + SENSOR_LAG_S) - SWEPT_MARGIN_M

    assert d[10].d_od == pytest.approx(free(0.5), abs=0.02)  # 0.5 s after the last trusted frame
    assert "min_quality" in d[10].reason and not d[10].swept and d[10].obstacle_m == 1.2
    assert d[30].d_od == pytest.approx(free(1.5), abs=0.02)
    assert d[45].d_od == 0.0  # nothing trusted in the last 2 s


def test_dod_follows_the_direction_of_travel_across_sensors():
    e = dod(FWD, RIGHT)
    add_range(e, 0, 0.0, 10.0, 0.1, 10.0, 100)
    add_range(e, 1, 0.0, 4.0, 0.1, 4.0, 100)
    assert e.estimate(0.0, 0.0).d_od == 10.0
    assert e.estimate(0.0, math.radians(90)).d_od == 4.0  # flying sideways to the right
    assert e.estimate(0.0, math.radians(-90)).d_od == 0.0  # to the left nothing looks


def test_late_first_detection_lowers_dod_and_is_reported():
    e = dod()
    t = 0.0
    for _ in range(10):
        add_range(e, 0, t, 10.0, 0.1, 10.0, 100)
        e.add_heading(t, 0.0)
        assert e.estimate(t, 0.0).late is None
        t += 0.05
    add_range(e, 0, t, 3.0, 0.1, 10.0, 100)  # hidden fog: first seen at 3 m although 10 m were promised
    est = e.estimate(t, 0.0)
    assert est.obstacle_m == 3.0  # an obstacle from its first frame
    assert est.late is None and est.d_od == 10.0  # the shorter range not yet: seen once
    for k, r in enumerate((2.95, 2.9)):  # seen again in each of the two frames that follow
        t += 0.05
        add_range(e, 0, t, r, 0.1, 10.0, 100)
        est = e.estimate(t, 0.0)
        assert (est.late is None) == (k == 0)
    assert est.late.range_m == 3.0 and est.late.assumed_d_od == 10.0  # where and when it was first seen
    assert est.late.t == pytest.approx(t - 0.1)
    assert est.d_od == 3.0 and est.obstacle_m == 2.9
    # the same obstacle getting closer is not a new late detection
    add_range(e, 0, t + 0.05, 2.8, 0.1, 10.0, 100)
    assert e.estimate(t + 0.05, 0.0).late is None
    # after the hold time the sensor's own range is believed again
    add_range(e, 0, t + 11.0, 10.0, 0.1, 10.0, 100)
    assert e.estimate(t + 11.0, 0.0).d_od == 10.0


def test_a_detection_at_the_range_edge_or_after_a_turn_is_not_late():
    e = dod()
    add_range(e, 0, 0.0, 10.0, 0.1, 10.0, 100)
    e.estimate(0.0, 0.0)
    add_range(e, 0, 0.05, 9.9, 0.1, 10.0, 100)  # at the edge of the range: on time
    assert e.estimate(0.05, 0.0).late is None
    e2 = dod()
    add_range(e2, 0, 0.0, 10.0, 0.1, 10.0, 100)
    e2.estimate(0.0, 0.0)
    e2.add_heading(0.0, 0.0)
    e2.add_heading(0.5, math.radians(40))  # turned more than half the field of view
    add_range(e2, 0, 0.5, 3.0, 0.1, 10.0, 100)
    assert e2.estimate(0.5, 0.0).late is None


def _first_seen(first_m: float, range_noise: RangeNoise):
    """A target first seen `first_m` by a sensor stating 10 m, then in the two frames that follow, 5 cm nearer each:
    the late detection declared, or None."""
    e = DodEstimator([FWD], CC, stale_s=0.5, range_noise=range_noise)
    add_range(e, 0, 0.0, 10.0, 0.1, 10.0, 100)
    e.estimate(0.0, 0.0)
    late = None
    for k in range(3):
        add_range(e, 0, 0.05 * (k + 1), first_m - 0.05 * k, 0.1, 10.0, 100)
        late = late or e.estimate(0.05 * (k + 1), 0.0).late
    return late


def test_a_first_sighting_within_the_range_noise_of_dod_is_on_time():
    """Three σ of the configured range noise (σ(10 m) = 0.03 + 0.01 × 10 = 0.13 m) beyond the 0.3 m tolerance: a
    target first seen 0.5 m inside the stated 10 m is on time, one first seen 0.8 m inside it is late. Control:
    without the noise allowance the first is late too."""
    noise = RangeNoise(0.03, 0.01)
    assert _first_seen(9.5, noise) is None
    late = _first_seen(9.2, noise)
    assert late is not None and late.range_m == 9.2 and late.assumed_d_od == 10.0
    assert _first_seen(9.5, RangeNoise(0.0, 0.0)) is not None  # the control must fail


def test_bins_side_entry_is_not_a_violation_but_interior_is():
    cfg = SensorConfig(kind="obstacle_distance", h_fov_deg=60.0)
    e = DodEstimator([cfg], CC, stale_s=0.5)
    bearings = np.radians(np.arange(-30, 31, 5.0))
    inc = math.radians(5)
    far = np.full(len(bearings), np.inf)
    add_bins(e, 0, 0.0, bearings, far, 10.0, inc)
    assert e.estimate(0.0, 0.0).d_od == 10.0
    edge = far.copy()
    edge[0] = 4.0  # appears in the outermost bin: came in from the side
    add_bins(e, 0, 0.05, bearings, edge, 10.0, inc)
    assert e.estimate(0.05, 0.0).late is None
    mid = edge.copy()
    mid[6] = 4.0  # appears dead ahead, well inside the promised 10 m, and stays
    for t in (0.1, 0.15, 0.2):
        add_bins(e, 0, t, bearings, mid, 10.0, inc)
        est = e.estimate(t, 0.0)
    assert est.late is not None and abs(est.late.bearing) < 1e-9 and est.d_od == 4.0


def test_etr_is_the_worst_contour_error_with_a_floor():
    e = EtrEstimator(ContractConfig(e_tr_floor_m=0.05, e_tr_window_s=1.0))
    for k in range(50):
        e.command(0.02 * k, 0.1 * k, 0.0)
    assert e.value == 0.05
    e.measure(0.5, 2.5, 0.3)
    assert e.value == pytest.approx(0.3)
    e.measure(0.6, 3.0, 0.01)
    assert e.value == pytest.approx(0.3)
    e.measure(1.7, 4.0, 0.01)
    assert e.value == 0.05


def test_thrust_ratio_from_hover_throttle_with_tilt_and_climb_corrections():
    est = ThrustEstimator(ThrustConfig(tau_s=0.5), hover_nominal=0.47, fallback=0.6)
    assert est.value(0.0)[0] == 0.6  # nothing known: the vehicle's lowest
    t = 0.0
    # level hover at throttle 0.47/0.8: a motor lost 20 % of its thrust
    for _ in range(200):
        est.add(t, 0.47 / 0.8, 0.0, 0.0, 0.0, True)
        t += 0.02
    assert est.value(t)[0] == pytest.approx(0.8, rel=1e-3)
    # 20° bank at the same vertical thrust needs throttle/cos(20°): still 0.8
    for _ in range(200):
        est.add(t, 0.47 / 0.8 / math.cos(math.radians(20)), math.radians(20), 0.0, 0.0, True)
        t += 0.02
    assert est.value(t)[0] == pytest.approx(0.8, rel=1e-3)
    # on the ground nothing is learnt
    est2 = ThrustEstimator(ThrustConfig(), 0.47, 0.6)
    est2.add(0.0, 0.2, 0, 0, 0, False)
    assert est2.value(0.0)[0] == 0.6
    # climbing at 1 m/s² needs (g+1)/g more throttle: corrected
    est3 = ThrustEstimator(ThrustConfig(tau_s=0.2), 0.47, 0.6)
    vz, t = 0.0, 0.0
    for _ in range(300):
        est3.add(t, 0.47 * (G + 1.0) / G, 0.0, 0.0, vz, True)
        vz -= 1.0 * 0.02
        t += 0.02
    assert est3.value(t)[0] == pytest.approx(1.0, rel=1e-2)


def test_nav_health_flags_and_staleness():
    n = NavHealth(stale_s=1.0)
    assert not n.healthy(0.0)
    n.update(0.0, "ESTIMATOR_STATUS", 1 | 2 | 4 | 8 | 16 | 32)
    assert n.healthy(0.5) and not n.healthy(1.5)
    n.update(2.0, "ESTIMATOR_STATUS", 1 | 2 | 8 | 1024)  # GPS glitch
    assert not n.healthy(2.0)
    n.update(3.0, "EKF_STATUS_REPORT", 1 | 2 | 8 | 16)
    assert n.healthy(3.0)
    n.update(4.0, "EKF_STATUS_REPORT", 1 | 2 | 8 | 32768)  # ArduPilot's GPS glitch bit
    assert not n.healthy(4.0)


def test_samples_delivered_in_a_burst_still_get_one_interval_of_travel():
    """A link that delivers two 20 Hz frames at once (as over UDP to a busy daemon) must not turn an
    on-time detection into a late one: the frames were taken 50 ms apart."""
    e = dod()
    e.set_speed(6.0)
    t = 0.0
    for _ in range(20):
        add_range(e, 0, t, 10.0, 0.1, 10.0, 100)
        e.add_heading(t, 0.0)
        e.estimate(t, 0.0)
        t += 0.05
    add_range(e, 0, t, 10.0, 0.1, 10.0, 100)
    add_range(e, 0, t + 0.001, 9.45, 0.1, 10.0, 100)  # burst: 6 m/s · 50 ms + 0.3 m tolerance covers 0.55 m
    assert e.estimate(t + 0.001, 0.0).late is None
    add_range(e, 0, t + 0.05, 10.0, 0.1, 10.0, 100)
    add_range(e, 0, t + 0.051, 8.9, 0.1, 10.0, 100)  # 1.1 m inside: late even so (once the next frames confirm it)
    add_range(e, 0, t + 0.1, 8.6, 0.1, 10.0, 100)
    add_range(e, 0, t + 0.15, 8.3, 0.1, 10.0, 100)
    assert e.estimate(t + 0.15, 0.0).late is not None


def test_an_obstacle_already_tracked_is_not_a_new_late_detection():
    """Issue 19 item 4: a column seen on time, lost from the field of view during a pass, then swept back
    into middle bins by a fast yaw is the same obstacle; another obstacle appearing where a frame from there had
    looked past is still late."""
    cfg = SensorConfig(kind="obstacle_distance", h_fov_deg=60.0)
    bearings = np.radians(np.arange(-30, 31, 5.0))
    inc = math.radians(5)
    far = np.full(len(bearings), np.inf)

    def flight(dx):
        e = DodEstimator([cfg], ContractConfig(r_obst_m=0.8), stale_s=0.5)
        e.add_position(0.0, 0.0, 0.0)
        e.add_heading(0.0, 0.0)
        seen = far.copy()
        seen[0] = 3.9  # on time, in the outermost bin: column surface at (3.38, -1.95)
        add_bins(e, 0, 0.0, bearings, seen, 4.0, inc)
        assert e.estimate(0.0, 0.0).late is None
        add_bins(e, 0, 0.05, bearings, far, 4.0, inc)  # out of view
        e.estimate(0.05, 0.0)
        # moved on, yaw swung fast to -30°, one frame there seeing nothing; then three middle bins light up at
        # once, 1.5 m ahead (a first sight is late only where a frame had looked past its place)
        yaw = math.radians(-30)
        for t in (0.3, 0.35, 0.4, 0.45):  # there for a while: its position a lag before is this one too
            e.add_position(t, 3.38 - 1.5 * math.cos(yaw) + dx, -1.95 - 1.5 * math.sin(yaw))
            e.add_heading(t, yaw)
        add_bins(e, 0, 0.45, bearings, far, 4.0, inc)
        e.estimate(0.45, 0.0)
        e.add_position(0.5, 3.38 - 1.5 * math.cos(yaw) + dx, -1.95 - 1.5 * math.sin(yaw))
        e.add_heading(0.5, yaw)
        back = far.copy()
        back[5:8] = 1.5
        late = None
        for t in (0.5, 0.55, 0.6):  # hovering there: seen in three frames
            add_bins(e, 0, t, bearings, back, 4.0, inc)
            late = late or e.estimate(t, 0.0).late
        return e.estimate(0.6, 0.0), late

    assert flight(0.0)[1] is None  # the tracked column (within 2·R_obst of its points): not late
    est, late = flight(8.5)  # 8.5 m on: no tracked obstacle there, a late detection as before
    assert late is not None and est.d_od == 1.5


def test_thrust_ratio_is_only_measured_airborne_and_settled():
    """Issue 19 item 5: spin-up and lift-off throttle is no hover throttle; the fallback until 2 s after the last
    sample on the ground and settled, and again after a landing; an unreported landed state is no ground."""
    est = ThrustEstimator(ThrustConfig(tau_s=0.5), hover_nominal=0.47, fallback=0.7)
    t = 0.0
    for _ in range(50):  # on the ground, motors spinning up
        est.add(t, 0.6, 0.0, 0.0, 0.0, False)
        t += 0.02
    assert est.value(t)[0] == 0.7
    for _ in range(90):  # just airborne (1.8 s), throttle high: not yet valid
        est.add(t, 0.75, 0.0, 0.0, 0.0, True)
        t += 0.02
    assert est.value(t) == (0.7, "not airborne and settled: the start value") and est.basis(t) == "start"
    for _ in range(200):  # settled in hover at 0.47/0.9
        est.add(t, 0.47 / 0.9, 0.0, 0.0, 0.0, True)
        t += 0.02
    assert est.value(t)[0] == pytest.approx(0.9, rel=2e-3)
    est.add(t, 0.2, 0.0, 0.0, 0.0, False)  # landed
    assert est.value(t)[0] == 0.7


def test_a_flight_first_seen_flying_keeps_the_thrust_estimate():
    """No landed state reported yet (None), then in the air: no lift-off to wait out, the first samples count."""
    est = ThrustEstimator(ThrustConfig(tau_s=0.5), hover_nominal=0.47, fallback=0.7)
    t = 0.0
    for k in range(10):
        est.add(t, 0.47 / 0.9, 0.0, 0.0, 0.0, None if k < 3 else True)
        t += 0.02
    assert est.value(t)[0] == pytest.approx(0.9, rel=2e-3)


def test_the_navigation_margin_trusts_only_part_of_the_claimed_range():
    """Issue 19 item 8: contract.nav_margin m gives D_od = (1 − m) × the claim, and says so."""
    e = DodEstimator([FWD], ContractConfig(nav_margin=0.3), stale_s=0.5)
    add_range(e, 0, 0.0, current_m=10.0, min_m=0.1, max_m=10.0, quality=100)
    est = e.estimate(0.1, beta=0.0)
    assert est.d_od == pytest.approx(7.0) and "0.3 not trusted" in est.reason
    add_range(e, 0, 0.2, current_m=6.8, min_m=0.1, max_m=10.0, quality=100)  # first seen at 6.8 m: on time (tolerance)
    assert e.estimate(0.2, beta=0.0).late is None


def swept_flight(track_deg: float, *, hit_m: float | None = None, margin: float = 0.0, seconds: float = 2.0):
    """Issue 19 item 2: a vehicle flies +x at 2 m/s for `seconds`, ending at the origin, its 60° bin sensor
    (6 m) forward; then its track swings to `track_deg` (slowing with a sideways component) while its heading
    stays on +x. Returns the estimator and its D_od along the new track."""
    cfg = SensorConfig(kind="obstacle_distance", h_fov_deg=60.0)
    e = DodEstimator([cfg], ContractConfig(nav_margin=margin), stale_s=0.5)
    bearings = np.radians(np.arange(-27.5, 28, 5.0))
    ranges = np.full(len(bearings), np.inf)
    if hit_m is not None:
        ranges[-1] = hit_m  # the bin at +27.5°: something there
    e.set_speed(2.0)
    n = round(seconds / 0.05)
    for k in range(n + 1):
        t = 0.05 * k
        e.add_position(t, 2.0 * (t - seconds), 0.0)
        e.add_heading(t, 0.0)
        add_bins(e, 0, t, bearings, ranges, 6.0, math.radians(5))
    return e, e.estimate(seconds, math.radians(track_deg))


def test_a_direction_of_travel_outside_the_view_gets_what_was_seen_free_on_the_way():
    _, inside = swept_flight(20.0)
    assert inside.d_od == 6.0 and inside.reason.startswith("sensor 0")  # inside the view: as before
    _, est = swept_flight(40.0)
    assert 1.0 < est.d_od < 6.0 and est.reason.startswith("direction of travel outside the field of view")
    # never more than seen: every point of the ray up to D_od lies in a wedge a sample saw free
    th = math.radians(40.0)
    for s in np.linspace(0.0, est.d_od, 50):
        q = (s * math.cos(th), s * math.sin(th))
        assert s == 0 or any(math.hypot(q[0] - x, q[1]) <= 6.0 and abs(math.atan2(q[1], q[0] - x)) <= math.radians(30)
                             for x in np.linspace(-4.0, 0.0, 41))
    # the navigation margin shortens it like any claimed range
    _, est_m = swept_flight(40.0, margin=0.3)
    assert est_m.d_od < est.d_od


@pytest.mark.parametrize("seconds, obstacle", [(2.0, (0.5, 2.8)), (0.2, (0.3, 0.8))])
def test_negative_control_an_obstacle_the_sensor_never_saw_is_beyond_dod(seconds, obstacle):
    """An obstacle outside every wedge flown past (never in the ±30° view from the line flown) is farther along
    the direction of travel towards it than D_od: the claim stays true. After a short run (0.4 m) one 0.85 m
    away leaves D_od under a metre: the contract has no safe speed, the vehicle stops."""
    ox, oy = obstacle
    for x in np.linspace(-2.0 * seconds, 0.0, 50):
        assert math.atan2(oy, ox - x) > math.radians(30)  # never in view
    dist = math.hypot(ox, oy)
    _, est = swept_flight(math.degrees(math.atan2(oy, ox)), seconds=seconds)
    assert est.d_od < dist
    if seconds < 1:
        assert est.d_od < 0.85


def test_negative_control_behind_a_hit_or_with_the_sensor_stale_is_not_covered():
    _, clear = swept_flight(40.0)
    _, blocked = swept_flight(40.0, hit_m=1.2)  # the +27.5° bin saw something 1.2 m off at every sample
    assert blocked.d_od < clear.d_od
    e, _ = swept_flight(40.0)
    assert e.estimate(2.6, math.radians(40.0)).d_od == 0.0  # the sensor stale: nothing, as before


def test_timeliness_counts_a_late_cycle_for_its_window_and_ignores_jitter():
    from companion.onboard.estimators import Timeliness

    tm = Timeliness(0.02, allowance_s=0.01, window_s=10.0)
    t = 0.0
    assert tm.tick(t) == 0.0  # the first cycle has nothing to be late against
    for _ in range(50):
        t += 0.02
        assert tm.tick(t) == 0.0
    t += 0.028  # 8 ms late: jitter inside the budget
    assert tm.tick(t) == 0.0 and tm.last_late_s == 0.0
    t += 0.02 + 0.15  # 150 ms late
    assert tm.tick(t) == pytest.approx(0.15) and tm.last_late_s == pytest.approx(0.15)
    assert tm.unbudgeted_s == pytest.approx(0.15)  # more than was counted: the guarantee broke
    t += 0.02 + 0.05  # a smaller lateness does not hide the worse one
    assert tm.tick(t) == pytest.approx(0.15)
    assert tm.unbudgeted_s == 0.0  # inside the reaction time already counted
    t_late = t
    while t < t_late + 9.9:
        t += 0.02
        assert tm.tick(t) == pytest.approx(0.05 if t - (t_late - 0.07) > 10.0 else 0.15)
    while t < t_late + 10.1:
        t += 0.02
        tm.tick(t)
    assert tm.tick(t + 0.02) == 0.0  # both have left the window
    assert tm.tick(1.0) == 0.0  # a clock that goes back (a restart) is not lateness

def test_timeliness_says_lateness_inside_the_allowance_and_counts_only_beyond_it():
    """The jitter allowance is a stated part of t_react: a cycle late by up to it is said (`within_s`), not counted
    and no violation (`unbudgeted_s` 0); only beyond it does the lateness count as reaction time."""
    from companion.onboard.estimators import Timeliness

    tm = Timeliness(0.02, allowance_s=0.03)
    t = 0.0
    for _ in range(60):  # linked from the first cycle; judged from 1 s on
        t += 0.02
        tm.tick(t)
    t += 0.02 + 0.025  # 25 ms late: inside the 30 ms allowance
    assert tm.tick(t) == 0.0 and tm.unbudgeted_s == 0.0 and tm.within_s == pytest.approx(0.025)
    t += 0.02 + 0.012  # less than already said in the window: not said again
    assert tm.tick(t) == 0.0 and tm.within_s == 0.0
    t += 0.02 + 0.002  # below the note threshold: sleep jitter, nothing to say
    assert tm.tick(t) == 0.0 and tm.within_s == 0.0
    t += 0.02 + 0.04  # 40 ms late: beyond the allowance, counted whole (the safe side) and a broken guarantee
    assert tm.tick(t) == pytest.approx(0.04) and tm.unbudgeted_s == pytest.approx(0.04) and tm.within_s == 0.0


def test_timeliness_is_not_judged_before_the_first_heartbeat_nor_in_the_second_after_it():
    """Start-up is no flight: before the autopilot's first heartbeat, and for a second after it, a late cycle is
    neither counted nor a violation (nearly every start printed a guidance violation in its first second)."""
    from companion.onboard.estimators import JUDGED_AFTER_S, Timeliness

    tm = Timeliness(0.02, allowance_s=0.01)
    assert tm.tick(0.0, linked=False) == 0.0
    assert tm.tick(0.5, linked=False) == 0.0 and tm.unbudgeted_s == 0.0  # 480 ms late, no autopilot yet
    assert tm.tick(0.54, linked=True) == 0.0  # the first heartbeat
    assert tm.tick(0.54 + 0.02 + 0.3, linked=True) == 0.0 and tm.unbudgeted_s == 0.0  # its first second
    t = 0.86
    while t < 0.54 + JUDGED_AFTER_S:
        t += 0.02
        tm.tick(t)
    assert tm.tick(t + 0.02 + 0.3) == pytest.approx(0.3) and tm.unbudgeted_s == pytest.approx(0.3)  # judged now


def test_the_swept_wedges_are_made_only_when_the_swept_coverage_is_asked_for(monkeypatch):
    """Issue 14 (review speed): a scan keeps what it saw; its wedges are made when the direction of travel is
    outside every field of view — rare — and once, not at every scan."""
    import companion.onboard.estimators as est_mod

    made = []
    real = est_mod.sample_sectors
    monkeypatch.setattr(est_mod, "sample_sectors", lambda *a, **kw: made.append(1) or real(*a, **kw))
    _, inside = swept_flight(20.0)
    assert inside.d_od == 6.0 and made == []  # 41 scans, the direction in view: none made
    e, outside = swept_flight(40.0)
    assert 1.0 < outside.d_od < 6.0 and len(made) == 41  # each scan of the last COVERAGE_S, once
    again = e.estimate(2.0, math.radians(40.0))
    assert again.d_od == outside.d_od and len(made) == 41  # asked again: reused


# ------------------------------------------------------------------ one sensor, several sources
def add_from(e, source, t, current_m, max_m=6.0, quality=100):
    """A DISTANCE_SENSOR sample of sensor 0 from `source` ((system, component, id), as MAVLink-in tags it)."""
    s = range_scan(t, 0, 0.0, current_m, 0.2, max_m, quality)
    e.add_scan(type(s)(s.t, s.sensor, s.hits, s.max_m, s.quality, s.known, s.increment, source))


def test_a_free_reading_from_one_source_never_erases_another_sources_obstacle():
    """Sensor 0 matches any DISTANCE_SENSOR id: id 0 sees an obstacle at 3 m at 20 Hz, id 1 says "free to
    6 m" at 200 Hz. Within the time-out the nearest fresh reading wins; after it, the silent source is gone."""
    e = dod()
    a, b = (1, 1, 0), (1, 1, 1)
    t = 0.0
    for k in range(200):  # 1 s
        t = k * 0.005
        if k % 10 == 0:
            add_from(e, a, t, 3.0)
        add_from(e, b, t, 6.01)
        assert e.estimate(t, 0.0).obstacle_m == 3.0
    t_last_a = 0.95
    for k in range(1, 200):
        t = 1.0 + k * 0.005
        add_from(e, b, t, 6.01)
        seen = e.estimate(t, 0.0).obstacle_m
        assert seen == (3.0 if t - t_last_a <= 0.5 else math.inf), t  # the obstacle times out with its source


def test_each_source_keeps_its_own_state_and_the_sensor_is_as_good_as_its_worst_fresh_source():
    e = dod()
    add_from(e, (1, 1, 0), 0.0, 6.01, max_m=6.0)
    add_from(e, (1, 1, 1), 0.01, 6.01, max_m=4.0)  # a second source claiming less: the smaller claim
    assert e.estimate(0.02, 0.0).d_od == 4.0
    add_from(e, (1, 1, 1), 0.02, 6.01, max_m=4.0, quality=1)  # invalid: no reading, the last trusted one stands ...
    assert e.estimate(0.03, 0.0).d_od == 4.0
    assert e.estimate(0.55, 0.0).d_od == 0.0  # ... for the silence budget (0.5 s) from it, no longer
    add_from(e, (1, 1, 0), 0.6, 6.01, max_m=6.0)  # the others are stale now: this source alone
    assert e.estimate(0.6, 0.0).d_od == 6.0


def test_one_source_behaves_as_before():
    """The same source (the autopilot's sensor) seeing an obstacle and then free space: it is gone at once."""
    e = dod()
    add_from(e, (1, 1, 0), 0.0, 3.0)
    assert e.estimate(0.0, 0.0).obstacle_m == 3.0
    add_from(e, (1, 1, 0), 0.05, 6.01)
    assert e.estimate(0.05, 0.0).obstacle_m == math.inf


def test_one_acceleration_estimator_answers_each_window_from_the_same_samples():
    """Δv/Δt against the newest sample at least the window older: 0.1 s and 0.3 s from one set of 50 Hz samples,
    each as an estimator of that window alone would say, at every sample once a window has passed (exact 20 ms
    steps whose sum rounds below the window included); None before; no time, no sample."""
    from companion.onboard.estimators import AccelEstimator

    both, short, long_ = AccelEstimator(0.3), AccelEstimator(0.1), AccelEstimator(0.3)
    both.add(-math.inf, 0.0, 0.0)  # telemetry not yet heard
    assert both.over(0.1) is None
    for k in range(60):  # 1 m/s² along x for 0.4 s, then 2 m/s² along y
        t = 0.02 * k
        v = (min(t, 0.4), 2.0 * max(t - 0.4, 0.0))
        for e in (both, short, long_):
            e.add(t, *v)
            e.add(t, 99.0, 99.0)  # a repeated time: ignored
        for w, alone in ((0.1, short), (0.3, long_)):
            a, b = both.over(w), alone.over(w)
            assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))
            assert (a is None) == (t < w - 1e-9), (t, w)
            if t >= 0.4 + w + 0.02:  # the window wholly in the second part
                assert a == pytest.approx([0.0, 2.0])


def test_a_reading_at_the_minimum_is_a_return_there_not_free_space():
    """A driver clamps a return nearer than its minimum to the minimum (the SITL's sector sensor does): that reading is
    an obstacle at most that far, never "nothing within range". Below the minimum the scan is unknown (invalid)."""
    at_min = range_scan(0.0, 0, 0.0, 0.2, 0.2, 6.0, 100)
    assert at_min.hits == ((0.0, 0.2),) and at_min.quality != 1
    below = range_scan(0.0, 0, 0.0, 0.1, 0.2, 6.0, 100)
    assert below.hits == () and below.quality == 1
    e = dod()
    e.add_scan(at_min)
    assert e.estimate(0.05, 0.0).obstacle_m == pytest.approx(0.2)  # the daemon sees it: no speed towards it


def test_how_far_past_each_hit_the_bins_beside_it_saw():
    """`hit_ends`: per hit, how far past it the bin on each side saw — to its hit (negative where nearer), to the
    claim where it saw nothing, -inf where the bin reported nothing (a dropped bin), inf beyond the field of view's
    edge."""
    cfg = SensorConfig(kind="obstacle_distance", h_fov_deg=65.0)
    e = DodEstimator([cfg], CC, stale_s=0.5)
    bearings = np.radians([-30, -25, -20, -15, -10, -5, 0, 5, 15, 20, 25, 30])  # 10° reported nothing
    ranges = np.full(len(bearings), np.inf)
    ranges[[6, 7, 9, 10, 11]] = [6.0, 6.1, 5.0, 3.0, 4.0]
    add_bins(e, 0, 0.0, bearings, ranges, 10.0, math.radians(5))
    ends = e.hit_ends(0.0)
    hits = [round(math.degrees(b)) for b, *_ in e.fresh_hits(0.0)]
    assert hits == [0, 5, 20, 25, 30]
    want = [(4.0, 0.1), (-0.1, -math.inf), (5.0, -2.0), (2.0, 1.0), (-1.0, math.inf)]
    assert ends == [pytest.approx(x) for x in want]
