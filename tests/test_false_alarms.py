"""False alarms in clear air: what a perfect observer (the SITL's truth) calls unfounded, and the daemon-side rules
that kept a clear-air flight from being called unsafe (companion/ground/false_alarms.py)."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.ground.false_alarms import fly as fly_clear
from companion.onboard.config import SensorConfig, config_from_dict
from companion.onboard.detection_range import DetectionRange
from companion.onboard.mavlink_in import MavlinkIn, bins_scan
from companion.onboard.samples import Implausible, Scan
from sitl_harness.sensors import bin_rays
from sitl_harness.world import Column, World
from tests.swerve_rules import (
    far_side_passed,
    grown_judged_at_once,
    guessed_at_speed_now,
    horizon_over_speed_now,
    out_of_view_forgotten,
    outline_unread,
    seen_once,
    threats_past_the_route_end,
)

SENSOR = mav.MAVLink(None, srcSystem=1, srcComponent=158)


def _decode(distances, inc_f):
    cfg = config_from_dict({"mode": "shadow", "sensors": [{"kind": "obstacle_distance", "h_fov_deg": 87}]})
    inp = MavlinkIn(cfg, None, lambda: 0.0, None)
    msg = mav.MAVLink_obstacle_distance_message(0, 0, list(distances), 0, 30, 1000, inc_f, -87.0 / 2 + inc_f / 2, 12)
    return inp.samples(0.0, "OBSTACLE_DISTANCE", msg)


def test_a_camera_of_87_degrees_in_17_bins_is_read_and_only_bins_in_use_are_judged():
    """A RealSense-class camera's 87° in 17 bins of 5.12°: 72 × 5.12° is past a circle, but the 55 bins after the
    17th are UINT16_MAX, "not used" (MAVLink common.xml OBSTACLE_DISTANCE); the 17 it uses span 87°."""
    inc = 87.0 / 17
    d = [1001] * 17 + [65535] * 55
    d[8] = 420  # straight ahead
    out = _decode(d, inc)
    assert not [s for s in out if isinstance(s, Implausible)]
    (scan,) = [s for s in out if isinstance(s, Scan)]
    assert scan.quality != 1 and len(scan.known) == 17
    assert [r for _, r in scan.hits] == [4.2] and abs(scan.hits[0][0]) < 1e-9


def test_bins_in_use_past_a_circle_are_still_refused():
    """Negative control: the same increment with bins in use up to the 72nd (368°, overlapping the first)."""
    inc = 87.0 / 17
    d = [1001] * 72
    out = _decode(d, inc)
    assert [s for s in out if isinstance(s, Implausible)]
    assert [s.quality for s in out if isinstance(s, Scan)] == [1]


# ------------------------------------------------------------------ a hovering camera that drops its centre bin
def _hover_with_a_dropped_centre_bin(monkeypatch=None, start_m=None):
    """A 17-bin camera (5°) hovering, its position drifting 1 mm back a frame; every bin free for 1 s, then one
    frame without the centre bin (UINT16_MAX: unknown). D_od along the heading then."""
    from companion.onboard import estimators
    from companion.onboard.config import ContractConfig

    if start_m is not None:
        monkeypatch.setattr(estimators, "SWEPT_START_M", start_m)
    cam = SensorConfig(kind="obstacle_distance", h_fov_deg=85.0, max_range_m=10.0)
    e = estimators.DodEstimator([cam], ContractConfig(), stale_s=0.5, cover=False)
    inc = math.radians(5.0)
    bearings = (np.arange(17) - 8) * inc
    t = 0.0
    for k in range(31):
        t = k / 30.0
        e.add_position(t, -0.001 * k, 0.0)
        e.add_heading(t, 0.0)
        keep = np.ones(17, bool) if k < 30 else np.arange(17) != 8
        e.add_scan(bins_scan(t, 0, bearings[keep], np.full(keep.sum(), np.inf), 10.0, inc, 10.0))
        est = e.estimate(t, 0.0)
    return est


def test_a_hovering_camera_that_drops_its_centre_bin_keeps_what_it_just_saw_free():
    """A dropped bin is unknown, not free: D_od along it is what the last frames saw free (the swept coverage,
    less its position margin), not zero — zero is a "no safe speed" stop on one bin of one frame in clear air."""
    est = _hover_with_a_dropped_centre_bin()
    assert est.swept and 9.5 < est.d_od < 10.0


def test_negative_control_a_chain_that_must_start_at_the_centre_leaves_a_drifting_hover_nothing(monkeypatch):
    est = _hover_with_a_dropped_centre_bin(monkeypatch, start_m=0.0)
    assert est.d_od == 0.0


def test_the_swept_chain_starts_only_within_start_m_and_joins_no_gap_beyond_it():
    from contracts.coverage import covered_distance

    wedge = np.array([(0.03, 0.0, -0.3, 0.3, 5.0)])  # seen from 3 cm ahead
    assert covered_distance((0.0, 0.0), 0.0, wedge) == 0.0
    assert abs(covered_distance((0.0, 0.0), 0.0, wedge, start_m=0.05) - 5.03) < 1e-9
    assert covered_distance((0.0, 0.0), 0.0, np.array([(0.08, 0.0, -0.3, 0.3, 5.0)]), start_m=0.05) == 0.0
    two = np.array([(0.03, 0.0, -0.3, 0.3, 2.0), (2.06, 0.0, -0.3, 0.3, 3.0)])  # a 3 cm break at 2.03 m
    assert abs(covered_distance((0.0, 0.0), 0.0, two, start_m=0.05) - 2.03) < 1e-9


# ------------------------------------------------------------------ first detections that are no evidence

INC = math.radians(5.0)
CAMERA = SensorConfig(kind="obstacle_distance", h_fov_deg=85.0, max_range_m=10.0)
OFFSETS = (np.arange(17) - 8) * INC  # a RealSense-class camera's 17 bins of 5°


def frame(world, x, y, yaw, stated=10.0, dropped=()):
    """One frame of the camera's bins from (x, y, yaw): the nearest surface of each bin's rays (`bin_rays`), as the
    SITL's model builds it, without noise; `dropped`: bins that report nothing (UINT16_MAX)."""
    rays = bin_rays(OFFSETS, INC)
    r = world.ray_cast(x, y, 2.0, yaw + rays.ravel(), stated).reshape(rays.shape).min(axis=0)
    keep = np.array([k not in dropped for k in range(17)])
    return OFFSETS[keep], r[keep]


def fly_frames(world, poses, stated=None, dropped=None, est=None):
    """Feed frames at 30 Hz from `poses` [(x, y, yaw)]; the bounds D_od took from first detections."""
    est = est or DetectionRange([CAMERA])
    out = []
    for k, (x, y, yaw) in enumerate(poses):
        t = k / 30.0
        s = stated(t) if stated else 10.0
        est.add_position(t, x, y)
        est.add_heading(t, yaw)
        b, r = frame(world, x, y, yaw, s, dropped(k) if dropped else ())
        est.add_scan(bins_scan(t, 0, b, r, s, INC, 10.0))
        e = est.estimate(t, s)
        if e.evidence["bound_m"] < math.inf:
            out.append((round(t, 3), e.d_od, e.reason))
    return out


def test_a_column_that_comes_into_view_in_a_turn_is_no_evidence():
    """Yawing at 90°/s toward a column 5 m off at 70°: it enters at the field of view's edge while the two outer
    bins report nothing, and is first seen two bins in: no frame looked at it before (a side entry)."""
    world = World([Column(5 * math.cos(math.radians(70)), 5 * math.sin(math.radians(70)), 0.3)])
    poses = [(0.0, 0.0, math.radians(3.0 * k)) for k in range(20)]
    def outer_dropped(k):  # (in the sun, say)
        return (15, 16) if k < 12 else ()

    assert fly_frames(world, poses, dropped=outer_dropped) == []


def test_a_column_that_comes_out_from_behind_another_is_no_evidence():
    """Flying +x past a near pole, a far one 4 m behind it comes out from behind it: the bins that now see the far
    one saw the near one a frame before (occluded, not missed)."""
    world = World([Column(6.0, 0.9, 0.25), Column(9.5, 1.9, 0.25)])
    poses = [(1.5 * k / 30.0, 0.0, 0.0) for k in range(90)]
    assert fly_frames(world, poses) == []


def test_the_first_frame_is_no_evidence():
    """The camera's first frame in a corridor: every wall it sees is inside its range, none of it late."""
    world = World([Column(4.0, 0.0, 0.3)])
    assert fly_frames(world, [(0.0, 0.0, 0.0)] * 5) == []


def test_a_column_missed_where_the_camera_looked_is_still_evidence():
    """The rule keeps its teeth: a dark column the camera looks straight at, reported free by the bin on it until
    it is 4 m away (as in fog that hides), is first seen late: D_od bounded by its distance."""
    world = World([Column(9.0, 0.0, 0.3)])
    blind = World([])
    est = DetectionRange([CAMERA])
    poses = [(1.5 * k / 30.0, 0.0, 0.0) for k in range(110)]
    out = []
    for k, (x, y, yaw) in enumerate(poses):
        t = k / 30.0
        est.add_position(t, x, y)
        est.add_heading(t, yaw)
        b, r = frame(world if 9.0 - 0.3 - x < 4.0 else blind, x, y, yaw)
        est.add_scan(bins_scan(t, 0, b, r, 10.0, INC, 10.0))
        e = est.estimate(t, 10.0)
        if e.evidence["bound_m"] < math.inf:
            out.append(e.d_od)
    assert out and max(out) < 4.1  # its first return: 4.06 m in the bin beside the centre


def _fog_lift(monkeypatch=None):
    """Honest fog: the camera states 3 m; at t = 1 s it lifts and the claim grows to 10 m with a column 4.4 m
    ahead (the demo's case)."""
    world = World([Column(4.4 + 0.3, 0.0, 0.3)])
    return fly_frames(world, [(0.0, 0.0, 0.0)] * 60, stated=lambda t: 3.0 if t < 1.0 else 10.0)


def test_a_column_first_seen_because_the_fog_lifted_is_no_evidence():
    assert _fog_lift() == []


def test_negative_control_without_the_claim_rules_the_fog_lift_is_a_late_detection(monkeypatch):
    """The same frames with the stated-range rules taken out (a frame's claim not asked whether it reached the
    column; the claim of the frame now, not the smaller of it and the last frame's): "first seen at 4.4 m"."""
    from companion.onboard import detection_range as dr

    monkeypatch.setattr(dr._View, "saw_through", lambda v, places, tol: True)
    first = dr.DetectionRange._first_detections
    monkeypatch.setattr(dr.DetectionRange, "_first_detections",
                        lambda self, t, i, scan, placed, stated: first(self, t, i, scan, placed, scan.max_m))
    out = _fog_lift()
    assert out and "first seen at 4.4" in out[0][2]


def test_every_stretch_starting_within_start_m_begins_the_chain():
    """A hovering vehicle's wedges: a sliver of one ending 1.2 mm out and the next starting at 1.5 mm, both
    within the vehicle: the chain runs on through the long one."""
    from contracts.coverage import covered_distance

    sliver = (0.001, 0.0, -0.001, 0.001, 0.0002)  # [1.0, 1.2] mm along the ray
    long = (0.0015, 0.0, -0.3, 0.3, 5.0)
    d = covered_distance((0.0, 0.0), 0.0, np.array([sliver, long]), start_m=0.05)
    assert abs(d - 5.0015) < 1e-9


# ------------------------------------------------------------------ clear-air flights judged by the SITL's truth


def unfounded(row):
    return [e for e in row["events"] if not e["founded"]]


@pytest.mark.parametrize("mode,world", [("governor", "cluster"), ("offboard", "columns")])
def test_a_clear_air_cluttered_flight_has_no_unfounded_hold_or_violation(mode, world):
    """The sector sensor's bins (as the demo reads them), a stand of poles flown beside (governor: the SITL's
    mission) or a route past columns (offboard: the daemon flies): to the route's end with nothing a perfect
    observer would call unfounded."""
    row = fly_clear(mode, "sector", world, 1)
    assert row["arrived"] and row["collisions"] == 0 and row["flown_s"] > 8.0
    assert row["guarded"] and row["refused"] is None  # the daemon guarded the flight, not only watched it
    assert unfounded(row) == []


# the camera pitched up by more than the Mambo pitches, so that the ground stays out of its view
PITCHED_UP = {"spurious_rate": 0.005, "mount_pitch_deg": 15.0}


def _confirm_frames(monkeypatch, frames):
    """The flights' daemon config with `contract.late_detection_confirm_frames` set."""
    from companion.ground import false_alarms as fa

    config_of = fa.config_of

    def with_frames(mode, route, model="sector"):
        cfg = config_of(mode, route, model)
        return {**cfg, "contract": {**cfg["contract"], "late_detection_confirm_frames": frames}}

    monkeypatch.setattr(fa, "config_of", with_frames)


def test_spurious_returns_where_the_camera_saw_free_are_withheld_no_hold_no_late_detection():
    """The governor with a depth camera whose spurious close returns come at 0.5 % a bin and frame (2.5 times its
    default, about 2.5 a second): each comes where the frames before saw free, is withheld until the frames that
    follow confirm it and never is — no hold, no late detection, the route flown to its end."""
    row = fly_clear("governor", "depth_camera", "cluster", 1, sensor=PITCHED_UP)
    assert row["arrived"] and row["events"] == []


def test_negative_control_without_confirmation_a_spurious_return_is_a_hold_and_a_late_detection(monkeypatch):
    """The same flight with every first sight an obstacle and declared at once: a spurious return is taken for an
    obstacle first seen inside the stated range and stops the flight (a Hold, or no safe speed below D_od lowered
    to it); the observer calls both unfounded."""
    _confirm_frames(monkeypatch, 0)
    row = fly_clear("governor", "depth_camera", "cluster", 1, sensor=PITCHED_UP)
    bad = {e["kind"] for e in unfounded(row) if e["cause"] == "spurious close return"}
    assert "violation (navigation)" in bad and bad & {"hold (obstacle)", "no safe speed"}


def test_a_spurious_return_in_a_corners_turn_where_the_camera_looked_a_second_before_is_withheld():
    """The governor through a corridor's corner with the depth camera (its default spurious returns): yawing at
    180 °/s there, a spurious return at 0.95 m, 25° off the axis (15.2 s in), where none of the last 0.2 s of frames
    can vouch for the place (their bins widened by that turn in their lag) but one of the last second's looked past
    it — it is withheld, and the route flown to its end."""
    row = fly_clear("governor", "depth_camera", "corridor", 7)
    assert row["arrived"] and unfounded(row) == []


def test_negative_control_a_look_back_of_a_fifth_of_a_second_holds_for_that_return(monkeypatch):
    from companion.onboard import estimators

    monkeypatch.setattr(estimators, "LOOK_BACK_S", 0.2)
    row = fly_clear("governor", "depth_camera", "corridor", 7)
    assert [(e["kind"], e["cause"]) for e in unfounded(row)] == [("hold (obstacle)", "spurious close return")]


def test_a_level_camera_pitching_with_the_mambo_sees_the_ground_and_says_nothing_of_it():
    """The depth camera mounted level (its default), its spurious returns on: the Mambo pitches nose-down to
    accelerate, and the camera's line meets the ground inside its 10 m; the claim stops short of it, so the ground
    is neither an obstacle nor a target first seen late. The route flown to its end with nothing unfounded."""
    row = fly_clear("governor", "depth_camera", "plain", 2)
    assert row["arrived"] and unfounded(row) == []


@pytest.mark.parametrize("runs_seen", [True, False])
def test_negative_control_a_camera_not_known_to_pitch_reads_the_ground_as_a_fog_unless_it_reads_surfaces(
        monkeypatch, runs_seen):
    """Not told its vertical field of view, the camera's claim does not stop short of the ground: the ground's close
    returns are read, and the medium's evidence takes them for a fog's backscatter — unless it tells a surface by its
    run of adjacent bins (`detection_range.surface_bins`), which the ground's returns are."""
    from companion.ground.flights import Rig
    from companion.onboard import detection_range

    entry = Rig._scenario_sensor
    monkeypatch.setattr(Rig, "_scenario_sensor", lambda self, sc: {**entry(self, sc), "v_fov_deg": None})
    if not runs_seen:
        monkeypatch.setattr(detection_range, "surface_bins", lambda *args: set())
    row = fly_clear("governor", "depth_camera", "plain", 2)
    assert any(e["cause"] == "ground in view" for e in unfounded(row)) is not runs_seen


def test_offboard_with_a_single_beam_has_no_late_detection_from_a_spurious_return():
    """Offboard with the TFmini-class beam in clear air (its default spurious returns): a return at 0.29 m five
    seconds in is no late detection (it is not seen again), so nothing is judged. The beam cannot cover the swept
    corridor (3.6° at 12 m covers ±0.38 m of the ±0.40 m): the daemon refuses to engage, says why, and the vehicle
    hovers where it took off; that refusal, not an alarm, is why no single-beam route is completed."""
    row = fly_clear("offboard", "single_beam", "plain", 1)
    assert row["events"] == []
    assert not row["guarded"] and "cannot cover the swept corridor" in row["refused"] and not row["arrived"]


def test_negative_control_without_confirmation_the_single_beams_spurious_return_is_a_violation(monkeypatch):
    _confirm_frames(monkeypatch, 0)
    row = fly_clear("offboard", "single_beam", "plain", 1)
    assert [(e["kind"], e["founded"], e["cause"]) for e in row["events"]] == [
        ("violation (navigation)", False, "spurious close return")]


def _fog_lift_flight(monkeypatch=None):
    """Governor, the sector sensor's bins in honest fog (3 m) until the column ahead is 4.4 m away, then clear: the
    stated range grows from 3 to 10 m with the column inside it."""
    from companion.ground import false_alarms as fa

    sc = fa.scenario_of("governor", "sector", "plain", 1)
    sc["world"] = {"columns": [{"x_m": 8.0, "y_m": 0.0, "radius_m": 0.3, "name": "column"}]}
    sc["route"]["waypoints"] = [[0.0, 0.0], [5.0, 0.0]]
    lift_at = {}

    def clear_when_close(rig):
        x = rig.sim.truth()["pos"][0]
        if not lift_at and 8.0 - 0.3 - x <= 4.4:
            lift_at["t"] = rig.sim.time_s
            rig.sim.sensor.visibility_m = math.inf
        return False

    sc["faults"] = [{"at_s": 0.0, "fog": {"visibility_m": 3.0, "report": "honest"}}]
    from companion.ground.flights import Rig, fly_mission

    rig = Rig(sc, "px4", config=fa.config_of("governor", sc["route"]["waypoints"]))
    fly_mission(rig, 20.0, until=clear_when_close)
    assert lift_at, "the fog never lifted"
    return [e for e in rig.log.named("violation_start") if e["subsystem"] == "navigation" and e["t"] >= lift_at["t"]]


def test_a_fog_lifting_in_flight_is_no_evidence_of_a_shorter_detection_range():
    assert _fog_lift_flight() == []


def test_negative_control_without_the_claim_rules_a_fog_lifting_in_flight_is_a_violation(monkeypatch):
    from companion.onboard import detection_range as dr

    monkeypatch.setattr(dr._View, "saw_through", lambda v, places, tol: True)
    first = dr.DetectionRange._first_detections
    monkeypatch.setattr(dr.DetectionRange, "_first_detections",
                        lambda self, t, i, scan, placed, stated: first(self, t, i, scan, placed, scan.max_m))
    late = _fog_lift_flight()
    assert late and "first seen" in late[0]["action"]


# ------------------------------------------------------------------ a depth camera's depth is along its axis
def _wall_bins(depth):
    """A wall 5 m ahead across a 17-bin camera's view, sent as the camera sends it (each bin: the depth along the
    axis of its nearest pixel, 5 m in every bin), decoded with the sensor's `depth` setting."""
    cfg = config_from_dict({"mode": "shadow", "sensors": [{"kind": "obstacle_distance", "h_fov_deg": 85,
                                                          "max_range_m": 10.0, "depth": depth}]})
    inp = MavlinkIn(cfg, None, lambda: 0.0, None)
    msg = mav.MAVLink_obstacle_distance_message(0, 0, [500] * 17 + [65535] * 55, 0, 30, 1000, 5.0, -40.0, 12)
    (scan,) = [s for s in inp.samples(0.0, "OBSTACLE_DISTANCE", msg) if isinstance(s, Scan)]
    return dict(scan.hits)


def test_axis_depth_is_read_as_the_least_range_the_bin_allows_never_more_than_the_truth():
    hits = _wall_bins("axis_depth")
    for b, r in hits.items():
        edge = max(abs(b) - math.radians(2.5), 0.0)
        true_far, true_near = 5.0 / math.cos(abs(b) + math.radians(2.5)), 5.0 / math.cos(edge)
        assert r <= true_near + 1e-9 <= true_far + 1e-9  # the wall's nearest point in the bin is no nearer
        assert abs(r - true_near) < 1e-9
    assert abs(hits[0.0] - 5.0) < 1e-9
    # the outer bins (37.5–42.5° off): the wall's nearest point in them is 5 / cos 37.5° = 6.30 m away, not 5 m
    assert abs(hits[math.radians(40.0)] - 5.0 / math.cos(math.radians(37.5))) < 1e-9


def test_negative_control_axis_depth_read_as_range_puts_the_side_of_a_wall_nearer_than_it_is():
    """Read as range, every bin of the wall is 5 m away: its sides 1.2 m nearer than they are, inside a corridor
    they are not in (a hold with nothing there)."""
    hits = _wall_bins("range")
    assert all(abs(r - 5.0) < 1e-9 for r in hits.values())


def test_two_poles_seen_as_one_wide_run_break_the_environment_assumption_truly(monkeypatch):
    """examples/campaign-clutter.yaml flight 529 (offboard, the 450–500 mm quad on PX4, a stand of poles beside the
    route and one on it): a run of bins spans the pole on the route and a pole of the stand behind it — said as "no
    obstacle wider than R_obst". Neither pole is wide, but two are within the stated range: the avoid contract's
    assumption (one obstacle no wider than R_obst at a time) is truly broken, and the observer says so. Control: an
    observer that judges that guarantee by width alone calls it unfounded."""
    from pathlib import Path

    from companion.ground import false_alarms as fa
    from companion.ground.campaign import fly, load_spec

    spec = load_spec(Path(__file__).resolve().parents[1] / "examples" / "campaign-clutter.yaml")
    row, rig = fly(spec, 529, keep_rig=True)
    wide = [v["t"] for v in rig.log.named("violation_start") if v["guarantee"] == "no obstacle wider than R_obst"]
    assert wide
    assert not any(a["kind"] == "violation (environment)" for a in row["unfounded_alarms"])

    monkeypatch.setattr(fa.Observer, "several_in_view", lambda self, tr, reach: False)
    old = fly(spec, 529)
    assert any(a["kind"] == "violation (environment)" and a["t"] == pytest.approx(wide[0])
               for a in old["unfounded_alarms"])


def test_a_column_the_cameras_range_noise_splits_for_one_frame_is_one_obstacle(monkeypatch):
    """Offboard with the depth camera, a cluster (seed 1192): at 5.3 s the nearest column is 9.6 m off, in two bins; one
    reads 7.2 m (2.5 σ short), and the step to the other is more than a run's break: two runs, one obstacle. The
    next frame does not split it, and the stop contract could still stop short of the short reading a frame later:
    no fallback, no violation. Control: counted from the frame it is seen in, the split is an environment violation
    ("one obstacle in view at a time") the observer calls unfounded."""
    from companion.onboard.contract_in_force import Apart

    def split(row):
        return [e for e in unfounded(row) if e["kind"] == "violation (environment)"]

    assert split(fly_clear("offboard", "depth_camera", "cluster", 1192, seconds=6.5)) == []
    monkeypatch.setattr(Apart, "count", lambda self, i, *a: len(i.places))
    assert split(fly_clear("offboard", "depth_camera", "cluster", 1192, seconds=6.5))


DARK_COLUMN = {"columns": [{"x_m": 30.0, "y_m": 0.4, "radius_m": 0.3, "reflectivity": 0.02, "name": "dark column"}]}


def _evidence_first(monkeypatch) -> None:
    """The evidence's first detections bound D_od at their first sight (no following frame asked for), so that the
    evidence ("a target first seen at …") declares a late target before the late-detection rule does."""
    from companion.onboard import sensing
    from companion.onboard.detection_range import DetectionRangeParams

    class AtOnce(DetectionRangeParams):
        @classmethod
        def of(cls, detection, confirm_frames: int = 2):
            return DetectionRangeParams.of(detection, 0)

    monkeypatch.setattr(sensing, "DetectionRangeParams", AtOnce)


@pytest.mark.parametrize("evidence_first", [False, True])
def test_a_column_darker_than_the_rating_is_a_founded_first_detection_whichever_estimate_declares_it(
        evidence_first, monkeypatch):
    """Governor, the sector sensor, a column of reflectivity 0.02 on the route (a fifth of the rated 10 %): the lidar
    equation sees it at 4.5 m of a 10 m rating, and it is truly first seen late. Whichever estimate says so first —
    the evidence's first detection ("a target first seen at …") or the late-detection rule's confirmed one — the
    observer judges it by the truth (the surface's reflectivity and its true reach), not as a medium's lowering."""
    if evidence_first:
        _evidence_first(monkeypatch)
    row = fly_clear("governor", "sector", "plain", 1, world=DARK_COLUMN)
    nav = [e for e in row["events"] if e["kind"] == "violation (navigation)"]
    assert nav and nav[0]["founded"] and nav[0]["true_reach_m"] < nav[0]["assumed"], nav


def test_negative_control_judged_as_a_medium_the_evidences_first_detection_is_unfounded(monkeypatch):
    from companion.ground import false_alarms as fa

    _evidence_first(monkeypatch)
    monkeypatch.setattr(fa, "FIRST_SEEN", fa.re.compile(r"(?!)"))  # never matches: every ":" action is a medium's
    row = fly_clear("governor", "sector", "plain", 1, world=DARK_COLUMN)
    nav = [e for e in row["events"] if e["kind"] == "violation (navigation)"]
    assert nav and not nav[0]["founded"]


def test_a_late_detection_is_judged_at_its_first_sight():
    """The violation is said when the following frames confirm it; the observer looks at the truth when it was first
    seen (the frame before that is the one whose rays may have stepped over it)."""
    from companion.ground.false_alarms import Observer

    obs = Observer.__new__(Observer)
    obs.late = [(5.10, 5.00), (9.30, 9.20)]
    assert obs.first_seen(9.30) == 9.20 and obs.first_seen(5.10) == 5.00
    assert obs.first_seen(7.0) == 7.0  # no late detection declared then: the event's own time


def test_a_hold_on_the_path_the_swerve_flies_is_judged_on_that_path(monkeypatch):
    """examples/campaign-clutter.yaml flight 597 (offboard, a corridor with a turn and a column inside), its swerve
    planned round every run of bins from its first frame, more of the column past its disc judged at once, a wall's
    points passed on their far side too, a pass's horizon and first linearisation as they were, a disc beyond the
    route's end in the way, nothing planned round once out of view (as it was flown when this flight held; now it
    flies on without a Hold): under the stop contract offboard swerves, and its
    Hold judges the path the plan flies (contract_in_force.path_obstacle_m); the observer finds the true surface on
    that path. Control: an observer that judges the line of travel calls the Hold unfounded."""
    from pathlib import Path

    from companion.ground import false_alarms as fa
    from companion.ground.campaign import fly, load_spec

    outline_unread(monkeypatch)
    seen_once(monkeypatch)
    grown_judged_at_once(monkeypatch)
    far_side_passed(monkeypatch)
    horizon_over_speed_now(monkeypatch)
    guessed_at_speed_now(monkeypatch)
    threats_past_the_route_end(monkeypatch)
    out_of_view_forgotten(monkeypatch)

    spec = load_spec(Path(__file__).resolve().parents[1] / "examples" / "campaign-clutter.yaml")
    row, rig = fly(spec, 597, keep_rig=True)
    assert row["world_family"] == "corridor" and rig.log.named("hold_trigger")
    assert not any(a["kind"] == "hold (obstacle)" for a in row["unfounded_alarms"])

    monkeypatch.setattr(fa.Observer, "path_judged", lambda self, t: None)
    old = fly(spec, 597)
    assert any(a["kind"] == "hold (obstacle)" for a in old["unfounded_alarms"])


def test_the_benchmark_keeps_each_flight_as_it_lands_and_resumes_from_them(tmp_path):
    """A run stopped part-way keeps its flights: each is appended to `--rows` as it lands, a run on the same file
    flies only what is missing, and a last line cut short by a kill is flown again rather than read."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    rows = tmp_path / "rows.jsonl"

    def run(*args):
        out = subprocess.run([sys.executable, str(root / "benchmarks" / "false_alarms.py"), *args],
                             capture_output=True, text=True, cwd=root, timeout=600)
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout), out.stderr

    common = ["--hours", "0.001", "--modes", "governor", "--models", "sector", "--worlds", "plain", "columns",
              "--rows", str(rows)]
    first, _ = run(*common, "--max-flights", "1")
    lines = rows.read_text().splitlines()
    assert [(json.loads(x)["world"], json.loads(x)["seed"]) for x in lines] == [("plain", 1), ("columns", 1)]
    rows.write_text(lines[0] + "\n" + lines[1][: len(lines[1]) // 2])  # killed while writing the second flight
    again, _ = run(*common, "--max-flights", "1")
    kept = [json.loads(x) for x in rows.read_text().splitlines()[:1]] + \
           [json.loads(x) for x in rows.read_text().splitlines()[2:]]
    assert [(r["world"], r["seed"]) for r in kept] == [("plain", 1), ("columns", 1)]  # only the cut one flown again
    assert again["all"]["flights"] == first["all"]["flights"] == 2
    assert again["all"]["hours"] == first["all"]["hours"]
    alone, _ = run("--report-only", str(rows))
    assert alone["all"]["flights"] == 2 and alone["all"]["hours"] == first["all"]["hours"]
    assert [c["world"] for c in alone["cells"]] == ["plain", "columns"]
