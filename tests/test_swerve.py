"""Offboard under the stop contract because of the world (something wider than R_obst, several obstacles) still swerves
round what is no wider than R_obst, at a speed the stop contract allows, and stops where anything lies on the path it
will fly (companion/onboard/contract_in_force.py). The pieces directly, then lock-step flights of the real daemon
against the real SITL over real MAVLink bytes (examples/campaign-clutter.yaml's worlds), each with its negative
control: the swerve disabled, today's straight flight that ends in a dead end."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.swerve_rules import (
    far_side_passed,
    guessed_at_speed_now,
    horizon_over_speed_now,
    out_of_view_as_union,
    out_of_view_forgotten,
    outline_unread,
    pass_at_its_own_speed,
    pass_left_beside_its_obstacle,
    seen_once,
    stops_bounded_by_v_max,
    stops_flown_unturned,
    threats_on_the_leg_line,
)

from companion.onboard.ahead import swept_obstacle_m
from companion.onboard.contract_in_force import (
    E_SWERVE_M,
    SWERVE_MIN_M_S,
    ContractInForce,
    path_obstacle_m,
    swerve_discs,
    swerve_omega,
    uncovered,
    wall_discs,
)
from companion.onboard.guidance import obstacle_discs
from contracts import online_planner
from contracts.online_planner import AvoidancePlanner, Disc, between_sides, dense_path, exact_check
from contracts.table import load_for_vehicle

TABLE = load_for_vehicle("mambo")
H = math.radians(2.5)  # a 5° bin's half-width
SPEC = Path(__file__).resolve().parents[1] / "examples" / "campaign-clutter.yaml"


def _wall_hits(x_wall: float, ys, pose=(0.0, 0.0, 0.0)):
    """The bins' hits (body bearing, range, ±, from bins) of the points (x_wall, y) seen from `pose`."""
    x, y, yaw = pose
    return [(math.atan2(yy - y, x_wall - x) - yaw, math.hypot(x_wall - x, yy - y), H, True) for yy in ys]


# ----------------------------------------------------------------------------- the path's nearest hit

def test_the_path_measure_is_the_swept_corridor_laid_along_the_path():
    """Along a straight path it finds what the swept corridor finds, never farther (the distance along the path to
    where the band is entered, not the range); a pole the path swerves round is not on it, a wall the path runs into
    is, at the distance along the path; a single beam's hit is on the path at its range; a path that ends at rest
    before a wall does not reach it; something touching the vehicle is at 0."""
    pose = (0.0, 0.0, 0.0)
    straight = ((20.0, 0.0),)
    pole = (math.radians(1.0), 8.0, H, True)
    assert swept_obstacle_m([pole], 0.0, 0.5) == 8.0
    assert 7.4 < path_obstacle_m([pole], pose, straight, 0.5) <= 8.0
    beside = (math.radians(25.0), 5.0, H, True)  # 2.1 m off the line of travel
    assert path_obstacle_m([beside], pose, straight, 0.5) == math.inf == swept_obstacle_m([beside], 0.0, 0.5)
    # a swerve 3 m to the left round the pole, then back
    swerve = ((4.0, 1.5), (8.0, 3.0), (12.0, 1.5), (16.0, 0.0), (30.0, 0.0))
    assert path_obstacle_m([pole], pose, swerve, 0.5) == math.inf
    wall = _wall_hits(8.5, [2.0, 2.6, 3.2, 3.8])  # what the swerve would run into
    d = path_obstacle_m(wall, pose, swerve, 0.5)
    assert 6.0 < d < 9.0
    assert path_obstacle_m([(math.radians(40.0), 5.0, H, False)], pose, swerve, 0.5) == 5.0  # a single beam
    short = ((4.0, 0.0),)  # a stop that rests 4 m on
    assert path_obstacle_m([pole], pose, short, 0.5) == math.inf
    assert path_obstacle_m([(math.pi, 0.3, H, True)], pose, straight, 0.5) == 0.0  # touching, behind
    # in another frame: the same world turned and moved gives the same answer
    yaw, at = 0.7, np.array([3.0, -2.0])
    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    moved = tuple(tuple(at + rot @ np.array(q)) for q in swerve)
    assert path_obstacle_m(wall, (*at, yaw), moved, 0.5) == pytest.approx(d, abs=1e-9)


def test_the_nearest_on_the_path_is_found_whatever_order_the_hits_come_in():
    """A hit straight ahead at 1.5 m enters the path's band (0.6 m) 0.9 m on; one 1.0 m away at 34° (0.56 m off the
    line) enters it 0.61 m on: the nearest on the path, in either order — a hit farther than the nearest so far may
    still be reached sooner along the path, by up to the band's half-width."""
    pose, straight = (0.0, 0.0, 0.0), ((20.0, 0.0),)
    ahead = (0.0, 1.5, 1e-4, True)
    th = math.radians(34.0)
    beside = (th, 1.0, 1e-4, True)
    enter = math.cos(th) - math.sqrt(0.6**2 - math.sin(th) ** 2)
    assert path_obstacle_m([ahead], pose, straight, 0.6) == pytest.approx(0.9, abs=1e-3)
    assert path_obstacle_m([ahead, beside], pose, straight, 0.6) == pytest.approx(enter, abs=1e-3)
    assert path_obstacle_m([beside, ahead], pose, straight, 0.6) == pytest.approx(enter, abs=1e-3)


def test_a_hit_in_a_disc_the_plan_goes_round_is_covered_and_a_wall_beside_it_is_not():
    discs = [Disc(9.0, 0.0, 1.3)]
    pole = (0.0, 8.0, H, True)
    wall = (math.radians(20.0), 8.0, H, True)
    assert uncovered([pole, wall], (0.0, 0.0, 0.0), discs) == (wall,)


# ----------------------------------------------------------------------------- what guidance is given

def _inputs(hits, pose=(0.0, 0.0, 0.0), r_obst=1.0):
    return SimpleNamespace(hits=tuple(hits), hit_ends=(), pose=pose, r_obst=r_obst)


def test_the_swerve_plans_round_a_pole_not_round_a_facade_whose_hit_points_it_keeps_out_of():
    """A pole (one run within R_obst) gets its disc; a facade across the route (a run 6 m wide) gets none — its
    chord's disc would block its own doorway — but each of its hits is a small disc the plan keeps out of (its lateral
    uncertainty); a corridor's wall seen along its length (a run deeper than R_obst, however narrow its chord) is a
    wall too."""
    bearings = np.radians(np.arange(-27.5, 27.6, 5.0))  # twelve 5° bins, each its sector's nearest return
    hits = [(b, 8.0 if abs(b) < math.radians(3.0) else 12.0 / math.cos(b), H, True) for b in bearings]
    facade = [h for h in hits if h[1] > 9.0]  # both sides of the pole: two runs 5 m wide
    discs = swerve_discs(_inputs(hits), math.inf)
    assert len(discs) == 1 and discs[0].x > 8.0 and abs(discs[0].y) < 0.1
    walls = wall_discs(_inputs(hits), discs)
    assert len(walls) == len(facade) and all(abs(w.x - 12.0) < 1e-9 and w.r < 0.7 for w in walls)
    # the same facade in the avoid contract's discs: a disc wider than R_obst each side
    all_discs, width, _ = obstacle_discs(hits, (0.0, 0.0), 0.0, 1.0)
    assert len(all_discs) == 3 and width > 1.5
    # a corridor wall 2.8 m to the left, seen by three bins along its length: chord within R_obst, depth not
    along = [(b, 2.8 / math.sin(b), H, True) for b in np.radians([20.0, 25.0, 30.0])]
    chord = math.hypot(*(np.array([math.cos(along[0][0]), math.sin(along[0][0])]) * along[0][1]
                         - np.array([math.cos(along[-1][0]), math.sin(along[-1][0])]) * along[-1][1]))
    assert along[0][1] - along[-1][1] > 2.0 and chord / 2 < 2.0
    assert swerve_discs(_inputs(along), 0.0) == ()
    assert len(obstacle_discs(along, (0.0, 0.0), 0.0, 1.0)[0]) == 1  # (the avoid contract's discs: unchanged)


@pytest.mark.parametrize("cx, cy, radius", [(2.0, 0.3, 0.1), (4.0, -0.8, 0.4), (6.0, 0.5, 0.25), (9.0, 0.0, 0.15)])
def test_the_swerve_plans_round_the_pole_it_sees_beyond_the_hold_s_reach(cx, cy, radius):
    """Under the stop contract the hold on the path flown is the guarantee, not the disc: beyond the hold's reach a
    pole's disc is centred half the chord of bins that saw it behind the chord, holding every bin's sector and
    SWERVE_MARGIN_M more — every point of the pole inside, and within R_obst's disc, which beside a pole in a 5–7 m
    corridor closed the passage either side (far off, where a few bins span more than R_obst, R_obst's). Within the
    hold's reach, R_obst's."""
    from tests.test_ahead import _column_bins

    hits = _column_bins(cx, cy, radius)
    (disc,) = swerve_discs(_inputs(hits), 1.0)
    pole = [(cx + radius * math.cos(a), cy + radius * math.sin(a)) for a in np.linspace(0.0, 2 * math.pi, 360)]
    assert max(math.hypot(x - disc.x, y - disc.y) for x, y in pole) <= disc.r
    (avoid,), _, _ = obstacle_discs(hits, (0.0, 0.0), 0.0, 1.0)  # the avoid contract's: R_obst
    assert avoid.r >= 1.0 and disc.r <= avoid.r
    if math.hypot(cx, cy) < 7.0:
        assert abs(disc.y) + disc.r < abs(avoid.y) + avoid.r - 0.3  # less far to the side
    assert swerve_discs(_inputs(hits), 12.0) == (avoid,)


def test_the_planner_goes_through_the_gap_between_two_discs_either_side_of_the_route():
    """Two door edges either side of the route line: the pass goes between them (each disc passed on the route's
    side), checked exactly; without the gap (the discs overlap across the line) no such attempt is made."""
    left, right = Disc(12.0, 2.4, 1.4, 1.0), Disc(12.0, -2.4, 1.4, 1.0)
    sides = between_sides([left, right])
    assert list(sides) == [-1.0, 1.0]
    assert between_sides([Disc(12.0, 1.0, 1.4), Disc(12.0, -1.0, 1.4)]) is None  # overlapping across the line
    assert between_sides([Disc(12.0, 2.4, 1.4)]) is None  # one side only: the one-sided passes …
    assert list(between_sides([Disc(12.0, 2.4, 1.4)], one_side=True)) == [-1.0]  # … or beside it, among walls

    def across(along):
        plan = AvoidancePlanner().plan((0.0, 0.0), (3.0, 0.0), (1.0, 0.0), [left, right], v_max=3.0, a_max=4.0,
                                       along=along)
        assert plan.kind == "pass" and plan.ok
        assert exact_check(plan.p, plan.v, plan.a, plan.t[1] - plan.t[0], [left, right], 3.0, 4.0)[0]
        return abs(plan.p[np.argmin(np.abs(plan.p[:, 0] - 12.0)), 1])

    assert across(False) < 1.0  # through the doorway
    assert across(None) > 3.0  # control: the avoid contract's planner passes all discs on one side: round the outside


def _corridor_pass(right_wall_y: float):
    """A pass among walls round a pole on the route line (its keep-out 1.8 m), the corridor's walls' hit points seen
    either side (keep-outs of 1 m) every 0.5 m: the plan, and whether any point of it is beyond a wall's line."""
    pole = Disc(8.0, 0.4, 1.8, 1.3)
    walls = [Disc(x, y, 1.0, 0.4) for x in np.arange(3.0, 14.0, 0.5) for y in (3.0, right_wall_y)]
    plan = AvoidancePlanner().plan((0.0, 0.0), (1.9, 0.0), (1.0, 0.0), [pole, *walls], v_max=1.9, a_max=4.0,
                                   along=True)
    pts = dense_path(plan.p, plan.v, plan.a, plan.t[1] - plan.t[0])
    return plan, bool(np.any(pts[:, 1] > 3.0) or np.any(pts[:, 1] < right_wall_y))


def test_among_walls_a_pass_keeps_to_the_near_side_of_every_wall_point(monkeypatch):
    """A wall's hit points are discs to the planner: a pass round one on its far side goes through the wall between
    the points seen, or behind it where none was seen (the Hold then stops it as the wall comes into view). Among walls
    a pass goes round what lies across the route line on either side and round what lies beside it on the line's side:
    in a corridor too narrow beside the pole, no pass (the stop); in one wide enough, the pass inside it. Control: every
    disc passed on one side, a pass round the outside of a wall."""
    plan, behind = _corridor_pass(-2.6)
    assert not behind and plan.kind == "stop"
    plan, behind = _corridor_pass(-4.5)
    assert plan.kind == "pass" and plan.ok and not behind
    far_side_passed(monkeypatch)
    plan, behind = _corridor_pass(-2.6)
    assert plan.kind == "pass" and plan.ok and behind  # negative control


# examples/campaign-clutter.yaml flight 52 (the X500 swerving in a 5.9 m corridor): the column ahead and the walls' hit
# points either side, seen from (9.59, -0.16), its Ω then (V_max 1.45 m/s, a_max 6.87 m/s²)
CORRIDOR_52 = [Disc(14.21, 0.43, 1.82, 1.36), Disc(14.50, -2.73, 1.13, 0.67), Disc(15.67, -2.69, 1.17, 0.72),
               Disc(17.32, -2.61, 1.24, 0.78), Disc(18.33, 2.58, 1.28, 0.83), Disc(16.37, 2.64, 1.21, 0.75),
               Disc(15.05, 2.68, 1.15, 0.70)]


def _plan_52(speed: float):
    return AvoidancePlanner().plan((9.59, -0.16), (speed, 0.0), (1.0, 0.0), CORRIDOR_52, v_max=1.45, a_max=6.87,
                                   v_cruise=1.45, along=True)


def test_a_pass_never_ends_round_a_wall_point_on_its_far_side(monkeypatch):
    """The SCP starts each wall point on the route line's side but may drift round it: a pass that ends on the far side
    of a point beside the line is rejected. Control: unchecked, and linearised first about a path at the speed now
    (near rest: where the vehicle is), the pass runs 2 m behind the right wall's points."""
    plan = _plan_52(0.05)
    assert plan.p[:, 1].min() > -2.6
    guessed_at_speed_now(monkeypatch)
    assert _plan_52(0.05).p[:, 1].min() > -2.6
    monkeypatch.setattr(online_planner, "round_far_side", lambda p, local, sides: False)
    plan = _plan_52(0.05)
    assert plan.kind == "pass" and plan.p[:, 1].min() < -4.0  # negative control


@pytest.mark.parametrize("speed", [0.6, 1.0])
def test_a_pass_from_below_the_cruise_speed_is_planned_over_the_time_it_takes(speed, monkeypatch):
    """Slowed below the cruise speed in the corridor, a pass between the column and the right wall, forward, inside the
    corridor: its horizon is the way at the cruise speed and the time to reach it. Control: a horizon of twice the way
    over the speed now (tens of seconds) leaves no pass (the stop), and from 0.32 m/s, unchecked and linearised first
    about the path at the speed now, one 60 s long that runs 19 m out of the corridor."""
    plan = _plan_52(speed)
    assert plan.kind == "pass" and plan.ok
    assert plan.p[:, 0].min() >= 9.59 - 1e-6 and -2.6 < plan.p[:, 1].min() and plan.p[:, 1].max() < 2.5
    horizon_over_speed_now(monkeypatch)
    assert _plan_52(speed).kind == "stop"  # negative control
    guessed_at_speed_now(monkeypatch)
    monkeypatch.setattr(online_planner, "round_far_side", lambda p, local, sides: False)
    plan = _plan_52(0.32)
    assert plan.t[-1] > 30.0 and plan.p[:, 1].min() < -10.0


# examples/campaign-clutter.yaml flight 117 (the X500 in a 5.4 m corridor, a 0.34 m column 0.35 m right of the route):
# the column's disc and the walls' hit points seen from (6.75, 0.04) at rest, its Ω then (V_max 1.45 m/s, a_max 6.87)
CORRIDOR_117 = [Disc(11.28, -0.36, 1.47, 1.01), Disc(11.59, -2.48, 1.12, 0.67), Disc(12.76, -2.45, 1.17, 0.71),
                Disc(14.38, -2.37, 1.23, 0.78), Disc(14.03, 2.34, 1.22, 0.76), Disc(12.6, 2.47, 1.16, 0.71),
                Disc(11.43, 2.48, 1.12, 0.66)]


def test_a_pass_from_rest_threads_the_room_between_a_column_and_a_wall(monkeypatch):
    """At rest before the column, 0.2 m of room left between its keep-out and the left wall's points: the pass goes
    forward through it, inside the corridor. Its first linearisation is a path along the route at the cruise speed,
    so each half-plane faces the side of its disc where the path passes it. Control: linearised first about the
    path at the speed now — every point where the vehicle rests, every half-plane facing a disc's front — the SCP's
    passes go through the walls and the exact check leaves only the stop (the vehicle hovered there)."""
    def plan():
        return AvoidancePlanner().plan((6.75, 0.04), (0.034, 0.006), (1.0, 0.0), CORRIDOR_117, v_max=1.45,
                                       a_max=6.87, v_cruise=1.45, along=True)

    p = plan()
    assert p.kind == "pass" and p.ok
    assert p.p[:, 0].min() >= 6.75 - 1e-6 and p.p[-1, 0] > 14.0 and -1.3 < p.p[:, 1].min() and p.p[:, 1].max() < 1.4
    guessed_at_speed_now(monkeypatch)
    assert plan().kind == "stop"  # negative control


# ----------------------------------------------------------------------------- when it swerves, and how fast

def _judged(width=0.0, obstacles=0, d_od=9.0, fov=60.0):
    rule = ContractInForce(math.radians(fov) / 2, dwell_s=1.0)
    i = SimpleNamespace(t=0.0, ground_speed=3.0, obstacle_width=width, r_obst=1.0, e_tr_measured=0.3,
                        thrust_ratio=1.0, obstacles=obstacles, dod=SimpleNamespace(d_od=d_od, silence_s=0.0),
                        discs=(), pose=(0.0, 0.0, 0.0), beta=0.0, hits=())
    return rule.judge(i, SimpleNamespace(v_max=5.0, e_tr=0.3), 0.1)


def test_it_swerves_where_the_world_broke_the_avoid_contract_not_where_the_view_did():
    wide = _judged(width=3.0)
    several = _judged(obstacles=3)
    assert wide.contract == several.contract == "stop" and wide.swerve and several.swerve
    narrow_view = _judged(fov=9.0)  # the pass would leave a 9° view: no swerve
    assert narrow_view.contract == "stop" and not narrow_view.swerve
    both = _judged(width=3.0, fov=9.0)  # a wall in a 9° view: the world's breach said, still no swerve
    assert both.contract == "stop" and "wider than R_obst" in both.reason and not both.swerve
    assert _judged().contract == "avoid" and not _judged().swerve


@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
def test_the_swerve_flies_no_faster_than_the_stop_contract_at_the_tracking_error_it_plans_with(vehicle):
    """The stop contract's Ω lowered (never raised) to the speed whose E_tr_pred (offboard's and the brake's surfaces)
    is E_SWERVE_M; never below SWERVE_MIN_M_S; unchanged where the stop contract's own speed is slower."""
    from companion.onboard.contract_in_force import fallback_omega

    table = load_for_vehicle(vehicle)
    i = SimpleNamespace(r_obst=1.0, thrust_ratio=1.0, e_tr_measured=0.3, dod=SimpleNamespace(silence_s=0.0))
    om = fallback_omega(table, 9.0, i, 0.1, 0.02)
    sw = swerve_omega(table, om, i)
    assert SWERVE_MIN_M_S <= sw.v_max < om.v_max and sw.tilt == om.tilt and sw.v_safe == om.v_safe
    e = max(table.e_tr_pred(sw.v_max, om.tilt, 1.0, s) for s in ("avoid", "brake"))
    assert e <= E_SWERVE_M + 1e-9 and sw.e_tr == pytest.approx(max(0.3, e))
    faster = max(table.e_tr_pred(sw.v_max + 0.1, om.tilt, 1.0, s) for s in ("avoid", "brake"))
    assert faster > E_SWERVE_M - 0.05  # the highest such speed, within the bisection's step
    slow = fallback_omega(table, 1.5, i, 0.1, 0.02)
    assert swerve_omega(table, slow, i) == slow


# ----------------------------------------------------------------------------- lock-step flights

def _no_swerve(monkeypatch):
    """The negative control: the stop contract flown as before the swerve (straight, no discs, the straight line's
    hold)."""
    from companion.onboard.supervisor import Supervisor

    monkeypatch.setattr(Supervisor, "swerves", property(lambda self: False))


def _clutter(scenario: int, seed: int | None = None):
    """examples/campaign-clutter.yaml's offboard flight of this scenario (the spec's arms: governor, offboard, …), with
    another seed if given."""
    from companion.ground.campaign import flight_of, fly, load_spec

    spec = load_spec(SPEC)
    spec = spec.model_copy(update={"scenarios": max(spec.scenarios, scenario + 1),  # a scenario is (seed, k) alone
                                   "seed": spec.seed if seed is None else seed})
    i = scenario * len(spec.arms) + spec.arms.index("offboard")
    s, arm = flight_of(spec, i)
    assert arm == "offboard"
    return s, *fly(spec, i, keep_rig=True)


def _swerved(rig) -> bool:
    """Guidance flew a plan round a disc (an avoid setpoint) under the stop contract."""
    return any(s["contract"] == "stop" for s in rig.log.states) and rig.daemon.cycle.offboard.guidance.replans > 0


def test_a_pole_on_the_route_beside_a_stand_of_poles_is_passed_without_contact(monkeypatch):
    """Scenario 20 (the Mambo on PX4, a stand of nine poles beside the route and a pole on it): the avoid contract's
    one obstacle at a time broken, the stop contract in force, said; the swerve round the pole on the route at the swerve's speed; no contact;
    the route completed. Control: the straight flight of the stop contract ends at the pole, a dead end."""
    s, row, rig = _clutter(20)
    assert s["world_family"] == "cluster"
    assert not row["collided"] and row["min_clearance_m"] > 0.3 and row["route_completed"]
    # the stand and the pole: several obstacles, or one run of bins wider than R_obst across two poles
    assert any("obstacles in view" in e["reason"] or "wider than R_obst" in e["reason"]
               for e in rig.log.named("contract_in_force"))
    assert _swerved(rig) and not rig.log.named("dead_end")
    assert any("swerving" in e.get("reason", "") for e in rig.log.named("limit_change"))

    _no_swerve(monkeypatch)
    _, old, old_rig = _clutter(20)
    assert not old["collided"] and not old["route_completed"]  # the control must fail: today's dead end
    assert old_rig.log.named("dead_end")


def test_a_column_inside_a_corridor_is_passed_without_contact(monkeypatch):
    """Scenario 61 (the Mambo on ArduPilot, a corridor with a turn, a column inside): its walls wider than R_obst
    keep the stop contract in force; the swerve round the column between the walls; no contact; the route
    completed. Control: today's straight flight ends in a dead end."""
    s, row, rig = _clutter(61)
    assert s["world_family"] == "corridor"
    assert not row["collided"] and row["route_completed"] and _swerved(rig)

    _no_swerve(monkeypatch)
    _, old, old_rig = _clutter(61)
    assert not old["collided"] and not old["route_completed"] and old_rig.log.named("dead_end")


def test_a_pass_planned_at_the_avoid_contract_s_speed_slows_when_the_stop_contract_comes_in(monkeypatch):
    """Seed 48's scenario 88 (the Mambo on PX4, a doorway): a pass through the doorway planned at the avoid contract's
    7.4 m/s; a cycle later both of the door's edges are in view and the stop contract comes in with V_max 1.94 m/s; no
    pass at that speed is found from 7.3 m/s, so the pass in force is kept — flown on along its path, slowed to
    V_max at half a_max: the speed limit flown within its slow-down, above V_safe for under half a second,
    the route completed. Control: the pass flown at its own speed — 7 m/s for 1.7 s under a limit of 1.94 m/s, the
    delivery judge's Hold, the route not completed."""
    s, row, rig = _clutter(88, seed=48)
    assert s["world_family"] == "doorway" and not row["collided"]
    assert any(e["contract"] == "stop" for e in rig.log.named("contract_in_force"))
    assert not [v for v in row["violations"] if v["subsystem"] == "delivery"]
    assert row["route_completed"] and row["gamma_flown_over_s"] < 0.6

    pass_at_its_own_speed(monkeypatch)
    _, old, _ = _clutter(88, seed=48)
    assert [v for v in old["violations"] if v["subsystem"] == "delivery"] and not old["route_completed"]
    assert old["gamma_flown_over_s"] > 1.0


@pytest.mark.parametrize("scenario", [96, 42])  # the Mambo on PX4, the X500 on ArduPilot
def test_a_column_inside_a_corridor_is_passed_round_what_was_seen_of_it(scenario, monkeypatch):
    """A corridor with a turn and a column inside: the swerve plans round the column as seen (beyond the hold's
    reach), passes it without contact and completes the route. Control: R_obst's disc at every range (and, as the
    swerve was then, round every run of bins from its first frame), which with the walls' keep-out closes the
    passage either side of the column, with a pass's horizon and its sides among walls as they were then too — the
    route is not completed (a dead end, or no safe speed from a pass that swung the direction of travel out of
    view); and nothing planned round once out of view, as then."""
    from companion.onboard.supervisor import Supervisor

    s, row, rig = _clutter(scenario)
    assert s["world_family"] == "corridor" and s["world"]["columns"]
    assert not row["collided"] and row["route_completed"] and _swerved(rig) and row["min_clearance_m"] > 0.3

    monkeypatch.setattr(Supervisor, "_hold_reach", lambda self, i: math.inf)
    outline_unread(monkeypatch)
    seen_once(monkeypatch)
    far_side_passed(monkeypatch)
    horizon_over_speed_now(monkeypatch)
    out_of_view_forgotten(monkeypatch)
    _, old, _ = _clutter(scenario)
    assert not old["collided"] and not old["route_completed"]  # the control must fail


@pytest.mark.parametrize("scenario", [42])
def test_a_pass_before_a_corridor_s_turn_leaves_it_for_the_turn(scenario, monkeypatch):
    """The pass round the column is straight along the corridor's first leg and ends about twice the column's
    distance on, past the turn: left where the route turns, the cruise takes the turn and the route is completed.
    Control: the pass flown to its end goes on towards the wall beyond the turn — a dead end."""
    from companion.onboard.guidance import OffboardGuidance

    _, row, _ = _clutter(scenario)
    assert not row["collided"] and row["route_completed"]
    monkeypatch.setattr(OffboardGuidance, "_past_the_leg", lambda self, t: False)
    _, old, old_rig = _clutter(scenario)
    assert not old["collided"] and not old["route_completed"]  # the control must fail
    assert old_rig.log.named("dead_end")


def test_a_wall_piece_beyond_a_corridor_s_turn_is_no_reason_to_swerve(monkeypatch):
    """Scenario 9 (the 450–500 mm quad on PX4, a 6.8 m corridor turning left, a column inside): past the column the
    vehicle rejoins from 1.4 m right of the route; the bin at the field of view's edge sees a piece of the right
    wall's far end beyond the turn, a run the swerve takes for a pole. Beyond the turn it is not in the way (the
    route turns away from it): no swerve round it, the route is completed. Control: judged against the leg's line
    however far on, a wall's points passed on their far side too and a pass's horizon as it was then, the swerve round
    it is planned straight on past the turn, through the side wall — a dead end."""
    s, row, _ = _clutter(9)
    assert s["world_family"] == "corridor"
    assert not row["collided"] and row["route_completed"]
    threats_on_the_leg_line(monkeypatch)
    far_side_passed(monkeypatch)
    horizon_over_speed_now(monkeypatch)
    _, old, old_rig = _clutter(9)
    assert not old["collided"] and not old["route_completed"]  # the control must fail
    assert old_rig.log.named("dead_end")


def test_a_wall_across_the_route_is_still_a_dead_end_stopped_short_and_said():
    """Scenario 16 (the Mambo on ArduPilot, a wall across the route: no route exists): the stop contract's braking
    stop short of the wall, then Hold, said as a dead end (event and STATUSTEXT over MAVLink)."""
    s, row, rig = _clutter(16)
    assert s["world_family"] == "dead_end" and not row["route_exists"]
    assert not row["collided"] and row["stopped_short"] and not row["route_completed"]
    (dead,) = rig.log.named("dead_end")
    assert dead["reason"] == "no path the contract can prove: stopped"
    assert any("no path the contract can prove" in t for t in rig.daemon_texts())


def test_a_dead_end_hands_over_to_hold_from_a_setpoint_at_rest():
    """PX4's Hold restarts from the last setpoint's velocity and acceleration (FlightTaskAuto::activate). At a dead end
    the planner's stop may have begun to lead the vehicle back out of a keep-out disc (its setpoint accelerating away
    while the vehicle still rests): the daemon first streams a setpoint at rest where the vehicle is for SETTLE_S, and
    only then says the dead end and asks for Hold. Handed over from the moving setpoint, the vehicle flew on backwards
    under Hold at up to 5.9 m/s, out of its sensor's view."""
    from types import SimpleNamespace

    from companion.onboard import offboard
    from companion.onboard.guidance import Setpoint
    from companion.onboard.states import OffboardState, SetpointKind

    away = Setpoint(np.array([4.9, 0.0]), np.array([-0.2, 0.0]), np.array([-3.0, 0.0]), -2.0, 0.0, SetpointKind.AVOID)
    guidance = SimpleNamespace(step=lambda *a, **k: away, stopped_short=lambda p: 0.6, last_notes=[])
    ctl = offboard.OffboardController(guidance, state=OffboardState.FLYING)
    dt, out = 0.02, []
    for k in range(int((offboard.DEAD_END_S + 2 * offboard.SETTLE_S) / dt) + 2):
        ask = offboard.Ask(t=k * dt, mode="offboard", p=(5.0, 0.0), v=(0.05, 0.0), z=-2.0, yaw=0.0, by_daemon=True,
                           engaged=True, flying=True, v_max=2.0, a_max=3.0)
        out.append((ask.t, ctl.step(ask)))
    (t_hold,) = [t for t, a in out if a.hold]
    said = [t for t, a in out if any(name == "dead_end" for name, _ in a.events)]
    assert said == [t_hold] and ctl.state == OffboardState.HELD
    still = [a.setpoint for t, a in out if t_hold - offboard.SETTLE_S <= t <= t_hold]
    assert still and all(np.allclose(sp.v, 0.0) and np.allclose(sp.a, 0.0) and np.allclose(sp.p, (5.0, 0.0))
                         for sp in still)
    assert t_hold >= offboard.DEAD_END_S + offboard.SETTLE_S - dt


def test_a_stop_short_of_a_column_with_no_pass_is_a_dead_end_said_and_held(monkeypatch):
    """Scenario 156 (the 450–500 mm quad on ArduPilot, a 5.1 m corridor, a 0.4 m column 0.26 m left of the route: 1.8 m
    and 2.3 m between it and the walls): the column's keep-out and the walls' points, each grown by r_body + E_tr and
    the bins' width, leave the planner no pass, so the vehicle rests on its stop; after 3 s at rest that is said as a
    dead end (event, STATUSTEXT over MAVLink), Hold asked and latched as such; no contact. Control: without the rule the
    vehicle hovers on the stop and says nothing."""
    from companion.onboard import offboard

    s, row, rig = _clutter(156)
    assert s["world_family"] == "corridor" and row["route_exists"]
    assert not row["collided"] and row["stopped_short"] and not row["route_completed"]
    (dead,) = rig.log.named("dead_end")
    assert dead["reason"] == "no path the contract can prove: stopped" and dead["obstacle_m"] > 0.5
    held = [e for e in rig.log.named("offboard") if e["to"] == "held"]
    assert held and held[0]["t"] == dead["t"] and "dead end" in held[0]["reason"]
    assert any(e["to"] == "holding" and "dead end" in e["reason"] for e in rig.log.named("state_change"))
    assert any("no path the contract can prove" in t for t in rig.daemon_texts())
    rested = [st for st in rig.log.states if dead["t"] - offboard.DEAD_END_S <= st["t"] <= dead["t"]]
    assert rested and max(st["ground_speed"] for st in rested) < 0.3

    monkeypatch.setattr(offboard, "DEAD_END_S", math.inf)
    _, old, old_rig = _clutter(156)
    assert not old["collided"] and not old["route_completed"]  # the control must fail: a silent hover
    assert not old["stopped_short"] and not old_rig.log.named("dead_end")


def test_a_stop_at_rest_before_a_column_stays_at_rest(monkeypatch):
    """Seed 46, scenario 332 (the 450–500 mm quad on PX4, a corridor, a column on the route): the vehicle comes to rest
    before the column on the planner's stop, and each replan of that stop is a stop from rest — never faster than it
    starts — until a pass is found: no Hold a perfect observer calls unfounded, no contact, the route completed.
    Control: a stop bounded by V_max only, and flown without turning first — an iterate OSQP had not converged on, safe
    by the exact check, backs the vehicle away at over 1 m/s, the direction of travel behind the sensor's view: "no safe
    speed", a Hold with nothing behind it (nothing planned round once out of view, as then). Flown as then: what was
    seen of a disc out of view held as the union of its sights (with its widest single sight, the flight goes on
    past the column and ends on "no safe speed" later, its direction of travel out of view, the route not completed)."""
    out_of_view_as_union(monkeypatch)
    s, row, rig = _clutter(332, seed=46)
    assert s["world_family"] == "corridor" and s["vehicle"] == "x500"
    assert not row["collided"] and not row["unfounded_alarms"] and not rig.log.named("hold_trigger")
    assert row["route_completed"]

    stops_bounded_by_v_max(monkeypatch)
    stops_flown_unturned(monkeypatch)
    out_of_view_forgotten(monkeypatch)
    _, old, old_rig = _clutter(332, seed=46)
    assert not old["collided"]
    assert old["unfounded_alarms"] and old_rig.log.named("hold_trigger")  # the control must fail


def test_a_stop_leading_away_from_the_heading_turns_to_it_first(monkeypatch):
    """Seed 50, scenario 763 (the Mambo on PX4, a corridor): past the corridor's column, inside its keep-out disc, the
    planner's stop leads back out of it, 150° off the heading. Flown slowly on its path while the heading turns to it,
    the sensor looks where the vehicle goes: no alarm a perfect observer calls unfounded. Control: the stop flown as
    planned — backing away at 0.85 m/s out of the sensor's view, "no safe speed", then a Hold for the column 0.8 m off,
    nowhere along the way the vehicle was going (nothing planned round once out of view, as then)."""
    s, row, _ = _clutter(763, seed=50)
    assert s["world_family"] == "corridor" and s["vehicle"] == "mambo"
    assert not row["collided"] and not row["unfounded_alarms"]

    stops_flown_unturned(monkeypatch)
    out_of_view_forgotten(monkeypatch)
    _, old, _ = _clutter(763, seed=50)
    assert not old["collided"] and old["unfounded_alarms"]  # the control must fail


def test_a_pass_is_finished_beside_a_pole_gone_out_of_view(monkeypatch):
    """Seed 46, scenario 844 (the 450–500 mm quad on PX4 in a stand of poles, a 0.18 m pole on the route): swerving
    round the pole at the stop contract's 1.5 m/s, the pole leaves the sensor's view 2.5 m before the vehicle is beside
    it. The pass flies a little faster than the route's profile (V_max), but its pole is not yet behind: the pass is
    finished, no rejoin across its keep-out; the route completed. Control: the pass left for the rejoin wherever its pole
    is — back to the route past the pole, 0.02 m from contact (flown, as then, with passes at their planned speed
    whatever V_max: slowed to V_max, that pass no longer comes near the pole; and with nothing planned round once out
    of view: the swerve's memory of what it saw keeps that pass clear of the pole too)."""
    s, row, _ = _clutter(844, seed=46)
    assert s["world_family"] == "cluster" and s["vehicle"] == "x500"
    assert not row["collided"] and row["route_completed"] and row["min_clearance_m"] > 0.5

    pass_at_its_own_speed(monkeypatch)
    pass_left_beside_its_obstacle(monkeypatch)
    out_of_view_forgotten(monkeypatch)
    _, old, _ = _clutter(844, seed=46)
    assert old["min_clearance_m"] < 0.1  # the control must fail


def test_a_pole_gone_out_of_view_on_the_swerve_is_still_planned_round(monkeypatch):
    """Scenario 1459 (the 450–500 mm quad on ArduPilot in a stand of poles, a 0.16 m pole on the route): two poles in
    view at 6.8 m/s, the stop contract in force with its swerve, which turns right; the pole on the route leaves the
    60° sensor's view 3.3 m off while the way back to the route still passes it. Planned round again once the path
    ahead flies into it (`OutOfView`), it is passed with room. Control: planned round only while in view, the vehicle
    passes it blind, 0.035 m from contact."""
    s, row, _ = _clutter(1459)
    assert s["world_family"] == "cluster" and s["vehicle"] == "x500"
    assert not row["collided"] and row["route_completed"] and row["min_clearance_m"] > 1.0

    out_of_view_forgotten(monkeypatch)
    _, old, _ = _clutter(1459)
    assert old["min_clearance_m"] < 0.1  # the control must fail


def test_a_corridor_wall_a_fast_turn_sweeps_into_view_is_no_fog(monkeypatch):
    """Scenario 365 (the Mambo in a corridor, clear air): dithering between passes by the corridor's wall, the heading
    turning at 200°/s, the sensor sweeps the wall into view 1.7 m off — a new piece of it in three or four adjacent
    bins each frame, never twice in one place. Read as a run of adjacent bins, it is a surface: no navigation
    violation. Control (runs not read): 8 of 240 shots in a second taken for a fog's backscatter, D_od lowered to
    6.8 m, a violation the perfect observer finds unfounded."""
    from companion.onboard import detection_range

    s, row, _ = _clutter(365)
    assert s["world_family"] == "corridor" and s["vehicle"] == "mambo"
    assert row["unfounded_alarms"] == [] and not [v for v in row["violations"] if v["subsystem"] == "navigation"]

    monkeypatch.setattr(detection_range, "surface_bins", lambda *args: set())
    _, old, _ = _clutter(365)
    assert [a["kind"] for a in old["unfounded_alarms"]] == ["violation (navigation)"]


def test_the_dwell_after_the_view_broke_keeps_the_flight_straight():
    """The stop contract in force because the pass would leave the view, then the view holds again: during the dwell
    before the avoid contract returns it stays straight (the swerve is for a breach of the world only)."""
    rule = ContractInForce(math.radians(30.0), dwell_s=1.0)

    def at(t, d_od):
        i = SimpleNamespace(t=t, ground_speed=1.0, obstacle_width=0.0, r_obst=1.0, e_tr_measured=0.3,
                            thrust_ratio=1.0, obstacles=0, dod=SimpleNamespace(d_od=d_od, silence_s=0.0),
                            discs=(), pose=(0.0, 0.0, 0.0), beta=0.0, hits=())
        return rule.judge(i, SimpleNamespace(v_max=2.0, e_tr=0.3), 0.1)

    assert at(0.0, 1.0).contract == "stop" and not rule.now.swerve  # the view broken at D_od 1 m
    dwell = at(0.5, 9.0)
    assert dwell.contract == "stop" and not dwell.swerve
    assert at(2.0, 9.0).contract == "avoid"


@pytest.mark.parametrize("seed,controls", [(2, (outline_unread, threats_on_the_leg_line, far_side_passed)),
                                           (11, (seen_once, far_side_passed))])
def test_a_camera_s_corridor_is_flown_without_planning_round_pieces_of_its_walls(seed, controls, monkeypatch):
    """Clear air, a corridor 5–6 m wide turning 90°, the depth camera (its range noise 0.8 m at 9 m, 2 % of bins
    dropped): the far wall's pieces the claim cuts off, the side walls' runs that dropped bins split, and the
    column one frame's noise draws out of a wall are no poles to plan round — the route is completed without
    contact. Controls: every run a pole's disc whatever the bins beside it saw and a disc in the way wherever it is
    near the leg's line (seed 2: its far wall's piece lies beyond the turn, either rule alone keeps the swerve from
    it), or a disc planned round from the frame it is first seen in (seed 11), each with a wall's points passed on
    their far side too — a pass round a piece of wall runs into the side wall, a dead end."""
    from companion.ground.false_alarms import fly

    row = fly("offboard", "depth_camera", "corridor", seed)
    assert row["arrived"] and row["collisions"] == 0
    for control in controls:
        control(monkeypatch)
    old = fly("offboard", "depth_camera", "corridor", seed)
    assert not old["arrived"] and old["collisions"] == 0  # the control must fail


def test_a_failsafe_stop_at_rest_inside_a_keep_out_backs_off_before_hold(monkeypatch):
    """Seed 47, scenario 86 (the Mambo on ArduPilot, wind 0.49 of its design, a stand of poles beside the route and a
    0.29 m pole on it): a 90° turn at the pole's keep-out, the vehicle 0.33 m past its reference, the supervisor's Hold,
    and the fail-safe stop, planned from the state measured, comes to rest inside the pole's keep-out — where the
    controller's allowance E_tr is already used. It backs off along the path it flew before Hold: no contact, no
    delivery violation for the back-off's own speed. Control: handed over to Hold where it rests, ArduPilot's Loiter
    holds it downwind of its reference, into the pole. (That stop no longer comes in this flight: its pass, planned at
    the avoid contract's speed before the stop contract came in, is now slowed to V_max, and the stop that ends the
    flight rests 0.7 m clear; the back-off is tested on the flight as it was, its pass at its planned speed.)"""
    from companion.onboard import offboard

    s, row, rig = _clutter(86, seed=47)  # today: the pass slowed to V_max; the stop rests clear of every keep-out
    assert s["world_family"] == "cluster" and s["vehicle"] == "mambo" and s["personality"] == "ardupilot"
    assert not row["collided"] and row["min_clearance_m"] > 0.5 and not rig.log.named("back_off")

    pass_at_its_own_speed(monkeypatch)  # the stop as it came then: a pass flown at its planned speed
    s, row, rig = _clutter(86, seed=47)
    backs = rig.log.named("back_off")
    assert len(backs) == 1 and backs[0]["inside_m"] > 0.0
    assert not row["collided"] and row["min_clearance_m"] > 0.05
    assert not any(v["subsystem"] == "delivery" for v in row["violations"])
    assert rig.daemon.cycle.offboard.state.value == "held"

    monkeypatch.setattr(offboard, "back_off", lambda track, discs: None)
    _, old, _ = _clutter(86, seed=47)
    assert old["collided"]  # the control must fail


def test_a_failsafe_stop_is_one_hold_however_its_cause_comes_and_goes(monkeypatch):
    """Seed 47, scenario 940 (the Mambo on PX4 in a stand of poles, wind 0.8 of its design): the supervisor's Hold
    fires on a pole near the swerve's path and the daemon brakes. While it brakes the pole leaves the Hold's reach (the
    vehicle slows) and comes back: the same stop, said once — the Hold is latched from the braking on, not only once
    the vehicle rests — and the observer finds no alarm without cause. (Flown without the swerve's memory of what it saw
    out of view: with it the swerve keeps clear of that pole and no Hold fires.)"""
    out_of_view_forgotten(monkeypatch)
    s, row, rig = _clutter(940, seed=47)
    assert s["world_family"] == "cluster" and s["vehicle"] == "mambo"
    holds = rig.log.named("hold_trigger")
    assert len(holds) == 1 and holds[0]["action"] == "hold"
    states = [e["to"] for e in rig.log.named("state_change")]
    assert states[-1] == "holding" and "active" not in states[states.index("holding"):]
    assert not row["collided"] and not row["unfounded_alarms"]


def test_a_pole_first_seen_from_behind_another_is_no_evidence_of_a_shorter_range(monkeypatch):
    """Seed 46, scenario 542 (the Mambo on ArduPilot in a stand of poles): a 0.17 m pole first seen at 5.2 m, inside
    the stated 8.5 m. A frame 0.15 s before had seen past the centre of the bin it was first seen in — but the pole's
    side of that bin was behind a nearer pole in the frame before (a neighbouring bin, 2.7 m). A return may come from
    anywhere across its bin: only a frame that saw past all of it is evidence. No navigation violation, no alarm the
    observer calls unfounded. Control: the bin's centre alone judged — "a target first seen at 5.2 m" (on the flight
    as it was then, its passes at their planned speed whatever V_max)."""
    from companion.onboard import detection_range as dr

    s, row, rig = _clutter(542, seed=46)
    assert s["world_family"] == "cluster"
    nav = [e for e in rig.log.named("violation_start") if e["subsystem"] == "navigation"]
    assert not nav and not row["unfounded_alarms"] and not row["collided"]

    whole = dr._View.saw_through
    monkeypatch.setattr(dr._View, "saw_through", lambda v, places, tol: whole(v, places[1:2], tol))
    pass_at_its_own_speed(monkeypatch)  # the flight as it was flown then: a pass at its planned speed
    _, old, rig = _clutter(542, seed=46)
    assert any("first seen at 5.2" in e.get("action", "") for e in rig.log.named("violation_start"))  # the control
