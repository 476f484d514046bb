import math
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from contracts.geometry import wrap
from companion.onboard.contract_in_force import WIDE_TOL_M
from companion.onboard.ahead import TRAVEL_SPEED_M_S
from companion.onboard.guidance import (A_LAT, HEADING_TOL, ON_ROUTE_M, SIDE_SLOW, TURN_FIRST_SPEED, YAW_RATE_ARC, YAW_SPEED,
                                        OffboardGuidance, Route, Setpoint, ThreadedPlanning, obstacle_discs,
                                        reference_jump)
from contracts.online_planner import AvoidancePlanner, Disc, Plan, dense_path


def test_bins_give_the_obstacle_position_and_width():
    # a column of radius 1 centred 6 m ahead: bins every 5° that hit its near surface
    c, r = np.array([6.0, 0.0]), 1.0
    hits = []
    for b in np.radians(np.arange(-30, 31, 5.0)):
        u = np.array([math.cos(b), math.sin(b)])
        # ray-circle intersection
        bb = u @ c
        disc = bb * bb - (c @ c - r * r)
        if disc >= 0:
            hits.append((b, bb - math.sqrt(disc), math.radians(2.5), True))
    discs, widest, _ = obstacle_discs(hits, (0.0, 0.0), 0.0, r_obst=1.0, inflate=0.3)
    assert len(discs) == 1
    d = discs[0]
    # the estimate holds the true obstacle: every point of the column is inside the keep-out disc
    ang = np.linspace(0, 2 * np.pi, 200)
    pts = c + r * np.column_stack([np.cos(ang), np.sin(ang)])
    assert np.all(np.hypot(pts[:, 0] - d.x, pts[:, 1] - d.y) <= d.r - 0.3 + 0.05)  # within 5 cm
    assert abs(d.y) < 0.3 and 5.5 < d.x < 6.8
    assert widest <= 1.0 + 1e-6  # no environment violation for an obstacle of exactly R_obst


def _bins_seeing(circles, bin_deg=5.0, half_fov_deg=30.0):
    """A bin sensor's hits (body bearing, range, ± half a bin, bins) from the vehicle at the origin heading +x: each
    bin the nearest return over its sector (rays across it), reported at the sector's centre bearing."""
    h = math.radians(bin_deg / 2)
    hits = []
    for b in np.radians(np.arange(-half_fov_deg, half_fov_deg + 1e-9, bin_deg)):
        ranges = []
        for a in np.linspace(b - h, b + h, 21):
            u = np.array([math.cos(a), math.sin(a)])
            for c, r in circles:
                c = np.asarray(c, float)
                near = u @ c
                disc = near * near - (c @ c - r * r)
                if disc >= 0:
                    ranges.append(near - math.sqrt(disc))
        if ranges:
            hits.append((float(b), min(ranges), h, True))
    return hits


def test_two_poles_a_free_bin_apart_are_one_obstacle_wider_than_r_obst():
    # poles of 0.4 m, 2.2 m apart at 6 m: one free 5° bin between them, and the runs' discs (R_obst 1 m) overlap —
    # one obstacle, which no disc of radius R_obst holds (both fit only in one of 1.5 m)
    hits = _bins_seeing([((6.0, -1.1), 0.4), ((6.0, 1.1), 0.4)])
    assert [round(math.degrees(b)) for b, *_ in hits] == [-15, -10, -5, 5, 10, 15]
    _, widest, apart = obstacle_discs(hits, (0.0, 0.0), 0.0, r_obst=1.0)
    assert apart == 1 and widest > 1.0 + WIDE_TOL_M


def test_a_column_whose_middle_bins_returned_nothing_is_one_obstacle_as_wide_as_its_face():
    # the control: a column of R_obst whose middle bin the fog blanked gives two runs, one obstacle, within R_obst
    hits = [hit for hit in _bins_seeing([((6.0, 0.0), 1.0)]) if abs(hit[0]) > 1e-6]
    assert len(hits) == 4
    _, widest, apart = obstacle_discs(hits, (0.0, 0.0), 0.0, r_obst=1.0)
    assert apart == 1 and widest <= 1.0 + WIDE_TOL_M


def test_a_single_beam_keeps_every_position_consistent_with_the_hit():
    # a 30° beam reports 5 m: the obstacle may be anywhere across the beam at that range
    discs, _, _ = obstacle_discs([(0.0, 5.0, math.radians(15), False)], (0.0, 0.0), 0.0, r_obst=0.5, inflate=0.2)
    assert len(discs) > 2
    for off in np.linspace(-15, 15, 61):  # any hit point across the field of view …
        hp = 5.0 * np.array([math.cos(math.radians(off)), math.sin(math.radians(off))])
        # … and every obstacle of radius R_obst touching it (all within 2·R_obst of it) is kept out
        assert min(math.hypot(hp[0] - d.x, hp[1] - d.y) + 2 * 0.5 - (d.r - 0.2) for d in discs) <= 1e-9


def test_route_projection_and_cruise_reference():
    route = Route([[0, 0], [10, 0], [10, 10]], 2.0, corner_cut_m=0.0)  # uncut: the polyline, a stop at the corner
    assert route.length == pytest.approx(20.0) and len(route.arcs) == 0
    assert route.project([5.0, 1.0]) == pytest.approx(5.0)
    p, u = route.point(15.0)
    assert np.allclose(p, [10, 5]) and np.allclose(u, [0, 1])
    assert np.allclose(route.point(10.0)[1], [0, 1])  # at a vertex: the leg ahead
    assert route.speed_limit(10.0 - 1e-6, 3.0, 2.0) < 0.01 and route.next_stop(0.0) == pytest.approx(10.0)
    one_place = Route([[1, 2], [1, 2]], 2.0)  # repeated points dropped: a route of length 0, done at once
    assert one_place.length == 0.0 and one_place.project([5, 5]) == 0.0 and one_place.speed_limit(0.0, 3.0, 2.0) == 0
    g = OffboardGuidance(Route([[0, 0], [10, 0], [10, 10]], 2.0))
    g.start([0.0, 0.0], [0.0, 0.0])
    t, sp = 0.0, None
    for _ in range(500):
        sp = g.step(t, 0.02, sp.p if sp is not None else [0, 0], sp.v if sp is not None else [0, 0], 3.0, 2.0, [])
        t += 0.02
        assert math.hypot(*sp.v) <= 3.0 + 1e-9 and math.hypot(*sp.a) <= 2.0 + 1e-9
    assert sp.z == -2.0 and g.s_ref > 10.0


class _GatedPlanner(AvoidancePlanner):
    """The real planner, held until the test opens the gate (so the worker's timing is the test's)."""

    def __init__(self, fail=False):
        super().__init__()
        self.gate, self.fail = threading.Event(), fail

    def plan(self, *a, **kw):
        self.gate.wait(10.0)
        if self.fail:
            raise RuntimeError("solver blew up")
        return super().plan(*a, **kw)


@pytest.fixture
def gated():
    """A guidance planning on a worker thread with a gated planner; the worker is shut down after."""
    made = []

    def make(fail=False):
        planner, planning = _GatedPlanner(fail), ThreadedPlanning()
        made.append((planner, planning))
        g = OffboardGuidance(Route([[0, 0], [60, 0]], 2.0), planner=planner, planning=planning)
        g.start([0.0, 0.0], [5.0, 0.0])
        return g, planner

    yield make
    for planner, planning in made:
        planner.gate.set()
        planning._pool.shutdown(wait=True)


def _threat_step(g, t):
    return g.step(t, 0.02, [t * 5.0, 0.0], [5.0, 0.0], 5.0, 4.0, [Disc(12.0, 0.1, 1.6, 1.2)])


def _until(cond, g, t0, seconds=20.0):
    """Step the guidance every 20 ms of its time until `cond(setpoint)` (wall-clock deadline)."""
    t, deadline = t0, time.monotonic() + seconds
    while time.monotonic() < deadline:
        sp = _threat_step(g, t)
        if cond(sp):
            return sp
        time.sleep(0.002)
        t += 0.02
    raise AssertionError("the worker did not answer in time")


def test_threaded_planning_brakes_until_the_plan_is_due_then_flies_it_from_where_the_braking_left_the_vehicle(gated):
    from companion.onboard.guidance import PLAN_LEAD_S

    g, planner = gated()
    first = _threat_step(g, 0.0)
    braking = g.plan
    assert first.mode == "planning" and first.a @ [1, 0] < 0  # braking meanwhile
    assert _threat_step(g, 0.02).mode == "planning"  # the loop goes on while the worker is busy
    planner.gate.set()
    while g.planning.busy:
        time.sleep(0.002)
    assert _threat_step(g, 0.04).mode == "planning"  # answered, but its start has not come: still braking
    sp = _until(lambda sp: sp.mode != "planning", g, 0.06)
    lead = PLAN_LEAD_S[0]
    assert sp.mode == "avoid" and g.plan.ok and g.plan_t == pytest.approx(lead)  # flown from its start
    p_due, v_due, _ = braking.sample(lead)
    assert np.allclose(g.plan.p[0], p_due) and np.allclose(g.plan.v[0], v_due)  # where the braking leaves it
    assert np.hypot(*v_due) < 5.0 - 0.5  # (slower than when it was asked: the braking's lost speed)
    assert g.replans == 1 and g.latencies and g.latencies[0] > 0.0


def test_a_planner_error_is_noted_and_the_vehicle_brakes(gated):
    g, planner = gated(fail=True)
    planner.gate.set()
    sp = _until(lambda sp: sp.mode == "brake", g, 0.0)  # the answer is braking, not more waiting
    assert any("planner error" in n for n in g.last_notes) and g.planner_failed


def test_a_plan_that_arrives_after_the_obstacle_is_gone_is_not_flown(gated):
    g, planner = gated()
    assert _threat_step(g, 0.0).mode == "planning"  # asked; the worker is held at the gate
    g.plan = None  # (the braking plan ended)
    sp = g.step(0.5, 0.02, [2.5, 0.0], [5.0, 0.0], 5.0, 4.0, [])  # nothing ahead any more …
    assert sp.mode == "cruise"
    planner.gate.set()  # … and only then does the old answer come
    while g.planning.busy:
        time.sleep(0.002)
    later = g.step(0.6, 0.02, [3.0, 0.0], [5.0, 0.0], 5.0, 4.0, [Disc(25.0, 0.1, 1.6, 1.2)])  # a new obstacle
    assert later.mode == "planning" and g.replans == 0  # planned afresh: the stale answer was dropped
    assert g.plan.kind == "await" and g.plan_t == 0.6


# ----------------------------------------------------------------------------- corners


def fly_reference(route, v_max=5.5, a_max=4.4, seconds=60.0, heading=None, p0=None, dt=0.02):
    """The cruise reference with a vehicle that tracks it exactly (its heading the setpoint's yaw, unless
    `heading(k, sp)` says otherwise); rows (s_ref, v_ref, setpoint) until done."""
    g = OffboardGuidance(route)
    p = np.asarray(route.waypoints[0] if p0 is None else p0, float)
    v = np.zeros(2)
    g.start(p, v)
    rows, yaw = [], math.atan2(*route.point(0.0)[1][::-1])
    for k in range(int(seconds / dt)):
        sp = g.step(k * dt, dt, p, v, v_max, a_max, [], yaw=yaw if heading is None else heading(k, rows))
        rows.append((g.s_ref, g.v_ref, sp))
        p, v, yaw = sp.p, sp.v, sp.yaw
        if sp.mode == "done":
            break
    return rows


def test_fillet_is_tangent_to_both_legs_and_passes_the_stated_cut_from_the_vertex():
    route = Route([[0, 0], [10, 0], [10, 10]], 2.0, corner_cut_m=1.0)
    (arc,) = route.arcs
    r = 1.0 / (math.sqrt(2) - 1)  # cut = R/cos(45°) − R
    t_len = r  # R·tan(45°)
    assert arc[8] == pytest.approx(r) and arc[0] == pytest.approx(10 - t_len)
    assert route.length == pytest.approx(20 - 2 * t_len + r * math.pi / 2)
    # tangency: the arc starts on the first leg along it and ends on the second along it
    p, u = route.point(arc[0])
    assert np.allclose(p, [10 - t_len, 0]) and np.allclose(u, [1, 0])
    p, u = route.point(arc[0] + arc[1])
    assert np.allclose(p, [10, t_len]) and np.allclose(u, [0, 1])
    assert route.curvature(arc[0] + 1.0) == pytest.approx(1 / r) and route.curvature(2.0) == 0.0
    s = np.linspace(0, route.length, 4001)
    pts = np.array([route.point(x)[0] for x in s])
    dirs = np.array([route.point(x)[1] for x in s])
    steps = np.hypot(*np.diff(pts, axis=0).T)
    assert np.allclose(steps, np.diff(s), atol=1e-6)  # continuous, parametrised by length
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", dirs[1:], dirs[:-1]), -1, 1))
    assert turn.max() <= np.diff(s)[0] / r + 1e-6  # the direction turns smoothly, never jumps
    assert np.allclose(np.diff(pts, axis=0) / steps[:, None], (dirs[1:] + dirs[:-1]) / 2, atol=1e-3)
    assert np.hypot(*(pts - [10, 0]).T).min() == pytest.approx(1.0, abs=1e-4)  # the cut
    assert np.allclose([route.project(q) for q in pts[::40]], s[::40], atol=1e-9)
    assert route.project([10.0, 0.0]) == pytest.approx(arc[0] + arc[1] / 2)  # the vertex: the arc's middle


def test_fillets_never_overlap_a_short_leg_shrinks_them():
    route = Route([[0, 0], [10, 0], [10, 2], [20, 2]], 2.0, corner_cut_m=1.0)
    a1, a2 = route.arcs
    tan_len = [a[8] * math.tan(abs(a[10]) / 2) for a in (a1, a2)]
    assert tan_len == pytest.approx([1.0, 1.0])  # half of the 2 m leg (the cut alone asks for 2.41 m)
    assert a1[0] + a1[1] <= a2[0] + 1e-9
    assert route.length == pytest.approx(22 - 4 * 1.0 + 2 * 1.0 * math.pi / 2)
    pts = np.array([route.point(x)[0] for x in np.linspace(0, route.length, 2001)])
    assert np.hypot(*(pts - [10, 0]).T).min() == pytest.approx(math.sqrt(2) - 1, abs=1e-3)  # cut only 0.41 m
    # per-waypoint cuts: the second corner uncut, a stop
    route = Route([[0, 0], [10, 0], [10, 10], [20, 10]], 2.0, corner_cut_m=[0, 0.5, 0.0, 0])
    assert len(route.arcs) == 1 and route.next_stop(0.0) == pytest.approx(route.length - 10)


def test_a_near_reversal_is_a_stop_at_the_vertex():
    def turning(deg):
        a = math.radians(deg)
        return Route([[0, 0], [10, 0], [10 + 10 * math.cos(a), 10 * math.sin(a)]], 2.0)

    assert len(turning(140).arcs) == 1 and len(turning(160).arcs) == 0  # REVERSAL_DEG = 150
    route = Route([[0, 0], [10, 0], [0, 1]], 2.0)  # turns 174°
    assert len(route.arcs) == 0 and route.length == pytest.approx(10 + math.hypot(10, 1))
    assert route.next_stop(0.0) == pytest.approx(10.0)
    rows = fly_reference(route)
    assert rows[-1][2].mode == "done" and np.allclose(rows[-1][2].p, [0, 1], atol=0.05)
    at_vertex = [v for s, v, _ in rows if s == pytest.approx(10.0)]
    assert at_vertex and max(at_vertex) == 0.0  # it stopped there, and went on
    assert max(v for s, v, _ in rows if 9.0 < s < 10.0) < math.sqrt(2 * 0.8 * 4.4 * 1.0) + 0.05


def test_speed_profile_slows_for_each_arc_and_comes_to_rest_at_the_end():
    d = 10 / math.sqrt(2)
    route = Route([[0, 0], [20, 0], [20, 20], [20 + 2 * d, 20 + 2 * d]], 2.0)  # a 90° and a 45° corner
    v_max, a_max, dt = 5.5, 4.4, 0.02
    rows = fly_reference(route, v_max, a_max, dt=dt)
    assert rows[-1][2].mode == "done" and rows[-1][1] == 0.0
    assert np.allclose(rows[-1][2].p, route.waypoints[-1], atol=0.05)
    s, v = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
    assert np.all(v <= route.speed_limit(s, v_max, a_max) + 1e-3)  # never above the profile
    assert v.max() == pytest.approx(v_max)  # and it is no slower than it says
    for sp in (r[2] for r in rows):
        assert math.hypot(*sp.v) <= v_max + 1e-9 and math.hypot(*sp.a) <= a_max + 1e-9
    for a in route.arcs:
        on = (s > a[0]) & (s < a[0] + a[1])
        v_arc = min(math.sqrt(A_LAT * a_max * a[8]), YAW_RATE_ARC * a[8])
        assert on.sum() > 10 and v[on].max() <= v_arc + 0.02 and v[on].min() >= 0.95 * v_arc
        for k in np.flatnonzero(on)[1:-1]:  # the feed-forward is the path's acceleration: v²/R towards the centre
            sp = rows[k][2]
            to_centre = a[6:8] - sp.p
            assert sp.a @ to_centre / np.hypot(*to_centre) == pytest.approx(v[k] ** 2 / a[8], rel=1e-6)
            fd = (rows[k + 1][2].v - rows[k - 1][2].v) / (2 * dt)
            assert np.hypot(*(fd - sp.a)) < 0.05 * a_max
    # braking into the first arc and to rest at the end uses A_BRAKE·a_max, not more
    assert np.diff(v).min() >= -1.01 * 0.8 * a_max * dt


def test_yaw_follows_the_commanded_and_measured_velocity_else_the_route_ahead():
    """The yaw: along a slow command itself (above TURN_FIRST_SPEED, at most walking pace); faster, along the
    commanded velocity plus the measured one while the command is slow; near rest along the route ahead."""
    route = Route([[0, 0], [30, 0], [30, 30]], 2.0)
    g = OffboardGuidance(route)
    g.start([0.0, 0.0], [0.0, 0.0])
    g.y_off, g.vy_off = 2.0, 0.0  # 2 m beside the route, as after an avoidance pass: the lateral rejoin
    p, v, sideways, slow, rest = np.array([0.0, 2.0]), np.zeros(2), 0, 0, 0
    for k in range(1500):
        sp = g.step(k * 0.02, 0.02, p, v, 5.0, 4.0, [], yaw=None)
        _, u = route.point(g.s_ref)
        speed = math.hypot(*sp.v)
        # commanded + measured when the command is slow (here measured = last cycle's command, tracked exactly)
        d = sp.v + max(0.0, 1.0 - speed / 2.0) * v
        if TURN_FIRST_SPEED < speed <= TRAVEL_SPEED_M_S:
            assert sp.yaw == pytest.approx(math.atan2(sp.v[1], sp.v[0]), abs=1e-3)
            slow += 1
        elif math.hypot(*d) > 2 * YAW_SPEED:
            assert sp.yaw == pytest.approx(math.atan2(d[1], d[0]))
            sideways += abs(wrap(sp.yaw - math.atan2(u[1], u[0]))) > math.radians(10)
        else:
            assert sp.yaw == pytest.approx(math.atan2(u[1], u[0]))
            rest += 1
        p, v = sp.p, sp.v
        if sp.mode == "done":
            break
    assert sideways > 10 and slow > 3 and rest > 0 and sp.mode == "done"
    assert sp.yaw == pytest.approx(math.pi / 2)  # at rest at the end: along the last leg


def _rejoin_at_the_end(turn: bool):
    """The route's end reached 3 m beside it, the heading along the route; the heading turns at 45°/s towards the
    yaw asked (`turn`; else the guidance is not told the heading), the vehicle flies the setpoint exactly. Rows of
    (heading, setpoint)."""
    route = Route([[0, 0], [10, 0]], 2.0)
    g = OffboardGuidance(route)
    g.start([10.0, 3.0], [0.0, 0.0])
    g.s_ref, g.v_ref, g.y_off, g.vy_off = route.length, 0.0, 3.0, 0.0
    p, v, heading, rows = np.array([10.0, 3.0]), np.zeros(2), 0.0, []
    for k in range(3000):
        sp = g.step(k * 0.02, 0.02, p, v, 5.0, 4.0, [], yaw=heading if turn else None)
        rows.append((heading, sp))
        heading += max(min(wrap(sp.yaw - heading), math.radians(45.0) * 0.02), -math.radians(45.0) * 0.02)
        p, v = sp.p, sp.v
        if sp.mode == "done":
            break
    return rows


def test_a_slow_rejoin_turns_first_then_goes_sideways():
    """Sideways to the route at its end the daemon does not creep out of its sensor's view: the reference is no
    faster than TURN_FIRST_SPEED while the heading is more than HEADING_TOL off the way it goes, then SIDE_SLOW with
    the heading on it. Control: not told the heading, it goes sideways at SIDE_SLOW looking along the route."""
    rows = _rejoin_at_the_end(turn=True)
    assert rows[-1][1].mode == "done"
    off = [math.hypot(*sp.v) for h, sp in rows
           if math.hypot(*sp.v) > 1e-6 and abs(wrap(h - math.atan2(sp.v[1], sp.v[0]))) > HEADING_TOL + 0.02]
    assert off and max(off) <= TURN_FIRST_SPEED + 0.05  # (one cycle's change at half a_max)
    assert max(math.hypot(*sp.v) for _, sp in rows) == pytest.approx(SIDE_SLOW, abs=0.01)
    control = _rejoin_at_the_end(turn=False)
    heading_fixed = [math.hypot(*sp.v) for _, sp in control if abs(wrap(math.atan2(sp.v[1], sp.v[0]))) > HEADING_TOL]
    assert max(heading_fixed) == pytest.approx(SIDE_SLOW, abs=0.01)  # the control: sideways, fast, off the route


def test_a_pass_that_ends_past_the_route_s_end_is_flown_back_from_where_the_vehicle_is():
    """A pass round a pole by the destination that hands over 3 m past the route's end, 0.5 m beside it, still moving
    on at 1 m/s: the cruise reference starts where the vehicle is and flies it back to the end, slowing within
    a_max, no faster than a rejoin, and arrives. (Put on the route's nearest point, the end, the reference was 3 m
    from the vehicle, which the autopilot flew to at the whole a_max, out of the sensors' view.)"""
    route = Route([[0, 0], [10, 0]], 2.0)
    g = OffboardGuidance(route)
    g.start([13.0, 0.5], [1.0, 0.0])
    p, v, rows = np.array([13.0, 0.5]), np.array([1.0, 0.0]), []
    for k in range(3000):
        sp = g.step(k * 0.02, 0.02, p, v, 5.0, 4.0, [])
        rows.append(sp)
        p, v = sp.p, sp.v
        if sp.mode == "done":
            break
    assert math.dist(rows[0].p, (13.0, 0.5)) < 0.05 and rows[0].v == pytest.approx([1.0, 0.0], abs=0.05)
    assert max(float(np.hypot(*sp.a)) for sp in rows) <= 4.0 + 1e-9
    assert max(float(np.hypot(*sp.v)) for sp in rows[1:]) <= 1.0 + 1e-9
    assert max(sp.p[0] for sp in rows) < 13.5  # slowed from 1 m/s, then back
    assert rows[-1].mode == "done" and math.dist(rows[-1].p, (10.0, 0.0)) <= 2 * ON_ROUTE_M


def test_a_reference_jump_is_how_much_farther_from_the_vehicle_it_is_than_the_last_one_flown_on():
    last = Setpoint(np.array([0.0, 0.0]), np.array([2.0, 0.0]), np.array([0.0, 0.0]), -2.0, 0.0, "cruise")
    on = Setpoint(np.array([0.04, 0.0]), np.array([2.0, 0.0]), np.zeros(2), -2.0, 0.0, "cruise")
    assert reference_jump(last, 0.02, on, (-0.3, 0.0)) == pytest.approx(0.0)  # flown on: the vehicle 0.3 m behind
    away = replace(on, p=np.array([0.04, 3.0]))
    assert reference_jump(last, 0.02, away, (-0.3, 0.0)) == pytest.approx(math.hypot(0.34, 3.0) - 0.34)
    assert reference_jump(last, 0.02, replace(on, p=np.array([-0.3, 0.0])), (-0.3, 0.0)) == 0.0  # onto the vehicle


def test_the_reference_turns_first_then_speeds_up():
    route = Route([[0, 0], [-20, 0]], 2.0)  # behind the vehicle, which faces north (+x)
    g = OffboardGuidance(route)
    g.start([0.0, 0.0], [0.0, 0.0])
    for k, heading_deg in enumerate([0.0] * 50 + [150.0] * 10 + [165.0] * 10):
        sp = g.step(k * 0.02, 0.02, [0, 0], [0, 0], 5.0, 4.0, [], yaw=math.radians(heading_deg))
        assert sp.yaw == pytest.approx(math.pi)  # asks to turn round
        assert g.v_ref == (0.0 if k < 60 else pytest.approx(2.0 * 0.02 * (k - 59)))  # then speeds up at a_max/2
    # flying, a heading more than 20° off holds the speed (no speeding up), it does not brake
    v0 = g.v_ref
    g.step(2.0, 0.02, sp.p, sp.v, 5.0, 4.0, [], yaw=math.radians(150.0))
    assert g.v_ref == v0


def test_a_closed_route_is_flown_once_round():
    route = Route([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], 2.0)
    rows = fly_reference(route, p0=[0.0, 0.0])
    s = np.array([r[0] for r in rows])
    assert rows[-1][2].mode == "done" and s[-1] == pytest.approx(route.length)
    assert np.all(np.diff(s) >= 0)  # never jumps back to the start it passes again


def test_process_planning_plans_as_inline_in_a_worker_process_and_survives_its_death():
    """The daemon plans in a worker process (no planning work holds the loop's interpreter lock): the same plan
    as inline for the same job; a worker that dies is a failed plan (brake), and the next job gets a new one."""
    import math
    import os
    import signal
    import time

    from companion.onboard.guidance import InlinePlanning, ProcessPlanning
    from contracts.online_planner import AvoidancePlanner, Disc

    job = (7, 1.5, None, np.array([0.0, 0.0]), np.array([4.0, 0.0]), np.array([1.0, 0.0]), [Disc(7.3, 0.2, 1.3)])
    kw = {"v_max": 4.0, "a_max": 9.81 * math.tan(math.radians(25.0))}
    inline = InlinePlanning()
    inline.submit(AvoidancePlanner(), *job, **kw)
    want = inline.poll()

    def wait(runner):
        deadline = time.monotonic() + 60
        while (out := runner.poll()) is None:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        return out

    runner = ProcessPlanning()
    try:
        runner.submit(AvoidancePlanner(), *job, **kw)
        got = wait(runner)
        assert got[:3] == want[:3] and got[3].kind == want[3].kind and got[3].ok
        assert np.allclose(got[3].p, want[3].p)
        (pid,) = list(runner._pool._processes)
        assert pid != os.getpid()
        os.kill(pid, signal.SIGKILL)  # the worker dies
        time.sleep(0.5)
        runner.submit(AvoidancePlanner(), *job, **kw)
        dead = wait(runner)
        if isinstance(dead[3], BaseException):  # the job went to the dead worker: a failed plan, said as such
            assert dead[:3] == want[:3]
            runner.submit(AvoidancePlanner(), *job, **kw)
            dead = wait(runner)
        assert dead[3].ok  # a new worker plans again
    finally:
        runner.close()


def test_the_planning_worker_has_the_planning_code_loaded_before_its_first_job():
    """The worker's start-up (waited for before the loop runs) loads the code its jobs run, not only the solver:
    loaded at the first job, the first obstacle's plan came 0.3–0.4 s late on a busy host."""
    from companion.onboard.guidance import ProcessPlanning

    runner = ProcessPlanning()
    try:
        loaded = runner._pool.submit(eval, "sorted(set(__import__('sys').modules) & "
                                           "{'companion.onboard.guidance', 'osqp'})").result(timeout=60)
        assert loaded == ["companion.onboard.guidance", "osqp"]
    finally:
        runner.close()


def _straight_pass(p0, u, speed: float, length: float) -> Plan:
    """A pass plan straight from p0 along u at a constant speed (what the planner's pass is once beside its obstacle)."""
    n = 60
    t = np.linspace(0.0, length / speed, n + 1)
    u = np.asarray(u, float)
    p = np.asarray(p0, float) + np.outer(t * speed, u)
    return Plan("pass", t, p, np.tile(u * speed, (n + 1, 1)), np.zeros((n, 2)), True, 1.0)


def _fly_pass(g, plan, steps: int, heading=None, walls=None):
    """Fly the pass from now with the vehicle on its setpoints; the setpoints."""
    g.plan, g.plan_t, g.plan_held = plan, 0.0, 0.0
    p, v, out = plan.p[0], plan.v[0], []
    for k in range(steps):
        sp = g.step(k * 0.02, 0.02, p, v, 5.0, 4.0, [], yaw=heading, walls=walls)
        out.append(sp)
        p, v = sp.p, sp.v
    return out


def test_a_pass_is_left_where_the_route_turns():
    """A pass is straight along the route where it was asked for and ends about twice its obstacle's distance on: its
    obstacle behind, it is left where the route turns from its direction, and the cruise takes the turn. Control: a
    pass flown to its end goes straight on past a corridor's turn (towards the wall beyond it)."""
    route = Route([[0, 0], [20, 0], [20, 20]], 2.0)
    plan = _straight_pass([10.0, 0.5], [1.0, 0.0], 1.5, 16.0)  # to x = 26, 6 m past the turn
    g = OffboardGuidance(route)
    g.start([10.0, 0.5], [1.5, 0.0])
    out = _fly_pass(g, plan, 600)
    left = next(k for k, sp in enumerate(out) if sp.mode == "cruise")
    arc_start = route.arcs[0][2]
    assert out[left - 1].p[0] <= arc_start + 1.0  # left where the arc starts
    assert max(sp.p[0] for sp in out) < 20.5 and out[-1].p[1] > 5.0  # the turn taken, not overshot
    control = OffboardGuidance(route)
    control.start([10.0, 0.5], [1.5, 0.0])
    control._past_the_leg = lambda t: False
    assert max(sp.p[0] for sp in _fly_pass(control, plan, 600)) > 25.0  # the control must fail


def test_a_swerving_pass_waits_for_the_heading_to_turn_to_it():
    """Swerving under the stop contract, a pass whose direction is more than HEADING_TOL off the measured heading is
    slowed (its clock, at half a_max) to TURN_FIRST_SPEED and the yaw asked along it; the heading on it, it speeds up
    again on the same path. Control: the avoid contract's pass (not swerving) is flown at its speed."""
    route = Route([[0, 0], [30, 0]], 2.0)
    plan = _straight_pass([5.0, 0.0], [0.0, 1.0], 1.2, 6.0)  # sideways to the route, the heading along it
    g = OffboardGuidance(route)
    g.start([5.0, 0.0], [0.0, 1.2])
    out = _fly_pass(g, plan, 100, heading=0.0, walls=())
    speeds = [float(np.hypot(*sp.v)) for sp in out]
    assert speeds[-1] == pytest.approx(TURN_FIRST_SPEED, abs=0.01)
    assert max(abs(np.diff(speeds))) <= 0.5 * 4.0 * 0.02 + 1e-9  # slowing at half a_max
    assert all(sp.yaw == pytest.approx(math.pi / 2) for sp in out)
    assert all(abs(sp.p[0] - 5.0) < 1e-9 for sp in out)  # the same path
    more = _fly_pass(g, plan, 100, heading=math.pi / 2, walls=())  # (flown again from its start, heading on it)
    assert float(np.hypot(*more[-1].v)) == pytest.approx(1.2, abs=0.01)
    control = OffboardGuidance(route)
    control.start([5.0, 0.0], [0.0, 1.2])
    assert min(float(np.hypot(*sp.v)) for sp in _fly_pass(control, plan, 100, heading=0.0)) == pytest.approx(1.2)


def test_a_pass_handed_over_sideways_slows_sideways_at_half_a_max():
    """The cruise taking over from a pass that ends moving sideways faster than a rejoin flies: the sideways speed
    falls at half a_max, its acceleration in the setpoint with it (clipped at once it was the whole step in one
    cycle, 30 m/s², and a fail-safe brake started from that acceleration flew at 14 m/s)."""
    route = Route([[0, 0], [30, 0]], 2.0)
    g = OffboardGuidance(route)
    g.start([5.0, 1.0], [0.5, 2.0])
    p, v, acc, vy = np.array([5.0, 1.0]), np.array([0.5, 2.0]), [], [g.vy_off]
    for k in range(50):
        sp = g.step(k * 0.02, 0.02, p, v, 5.0, 4.0, [])
        acc.append(float(np.hypot(*sp.a)))
        vy.append(g.vy_off)
        p, v = sp.p, sp.v
    assert max(acc) <= 4.0  # within a_max (sideways half of it, the along-track speed-up the rest)
    assert max(abs(np.diff(vy))) <= 0.5 * 4.0 * 0.02 + 1e-9 and vy[-1] < 0.7


def _pole_run(ends):
    """Two bins of 5° seeing a pole 6 m ahead (beyond a hold's reach of 4 m), with `ends` (how far past each hit the
    bins beside it saw): the discs `obstacle_discs` gives under the stop contract's swerve rules."""
    h = math.radians(2.5)
    hits = [(-h, 6.0, h, True), (h, 6.05, h, True)]
    return obstacle_discs(hits, (0.0, 0.0), 0.0, 1.0, widest=1.0 + WIDE_TOL_M, measured_beyond=4.0, ends=ends)[0]


def test_a_run_whose_sides_the_bins_did_not_see_past_gets_no_swerve_disc():
    """A pole is planned round where the bins beside it saw well past it (a hit 4 m behind, nothing within a claim 4
    m beyond). A run whose side a bin that reported nothing, or a nearer hit, hides is of unknown width; one whose
    neighbours saw nothing only because the claim ends 1 m behind it (a wall far ahead cut off by the range: it looks
    like a pole) waits until it is within the hold's reach. Control: every run's disc without the bins' word."""
    assert len(_pole_run([(4.0, 0.0), (0.0, 4.0)])) == 1
    assert _pole_run([(-math.inf, 0.0), (0.0, 4.0)]) == []  # a dropped bin beside it
    assert _pole_run([(4.0, 0.0), (0.0, -1.5)]) == []  # a nearer hit beside it
    assert _pole_run([(1.0, 0.0), (0.0, 1.0)]) == []  # the claim ends 1 m behind it, beyond the reach
    h = math.radians(2.5)
    near = obstacle_discs([(-h, 3.0, h, True), (h, 3.05, h, True)], (0.0, 0.0), 0.0, 1.0, widest=1.0 + WIDE_TOL_M,
                          measured_beyond=4.0, ends=[(1.0, 0.0), (0.0, 1.0)])[0]
    assert len(near) == 1  # within the reach: planned round
    assert len(_pole_run(None)) == 1  # negative control


def test_a_disc_beyond_the_route_s_turn_is_in_the_way_only_near_the_route_after_it():
    """The vehicle 1.4 m right of a corridor's first leg, 6 m before the left turn (an arc from 16.7 m): a disc
    beyond the turn's outside corner, 1.7 m off the vehicle's line but 3.8 m from the route where it turns away, is
    not in the way; one on the route after the turn is, and so is one on the vehicle's line before the turn. Control:
    measured against the leg's line however far on, the corner's disc is in the way (a swerve planned straight on
    went through the side wall)."""
    g = OffboardGuidance(Route([[0, 0], [19.1, 0], [19.1, 20]], 2.0))
    p, v = np.array([13.2, -1.4]), np.array([1.4, 0.0])
    corner, after, before = Disc(19.5, -3.1, 1.4), Disc(19.3, 6.0, 1.0), Disc(15.0, -1.9, 1.0)
    assert g.route.straight_left(g.route.project(p)) == pytest.approx(16.7 - 13.2, abs=0.05)
    assert g._threats(p, v, [corner, after, before]) == [after, before]
    leg_line = OffboardGuidance(Route([[0, 0], [19.1, 0], [19.1, 20]], 2.0))
    leg_line.route.straight_left = lambda s: math.inf  # negative control: the leg's line however far on
    assert corner in leg_line._threats(p, v, [corner, after, before])


def test_a_pass_round_the_disc_in_the_way_keeps_out_of_the_disc_beside_the_route():
    """A pole on the route 10 m ahead and, 3.8 m beside it, a pole of a stand that is not in the way; the vehicle at
    7.8 m/s swerving at V_max 1.45 m/s. The pass round the pole in the way keeps out of the one beside it too. Control:
    planned round the pole in the way alone, the pass goes through the other (a stand of poles beside the route:
    the Hold stopped the flight at once, a dead end)."""
    g = OffboardGuidance(Route([[0, 0], [50, 0]], 2.0))
    on, beside = Disc(24.7, 0.0, 2.31, 1.4), Disc(22.7, 3.8, 2.41, 1.5)
    p, v = np.array([14.6, 0.04]), np.array([7.8, 0.0])
    assert g._threats(p, v, [on, beside]) == [on]
    g.step(0.0, 0.02, p, v, 1.45, 4.0, [on, beside], yaw=0.0, walls=())
    plan = g.plan
    assert plan.kind == "pass" and plan.ok

    def entered(plan, d):
        pts = dense_path(plan.p, plan.v, plan.a, plan.t[1] - plan.t[0])
        return float(np.min(np.hypot(pts[:, 0] - d.x, pts[:, 1] - d.y))) < d.r - 1e-3
    assert not entered(plan, on) and not entered(plan, beside)
    alone = AvoidancePlanner().plan(p, v, (1.0, 0.0), [on], v_max=1.45, a_max=4.0, along=False)
    assert alone.ok and entered(alone, beside)  # negative control


def _swerve_then(second, check: bool):
    """Swerving, a pass round a pole on the route; the next cycle only the disc `second(first plan)` is seen: the
    first plan, the plan then in force and how far that one keeps outside the disc [m] (`check` False: the pass in
    force is not checked against the discs)."""
    g = OffboardGuidance(Route([[0, 0], [40, 0]], 2.0))
    if not check:
        g._entered = lambda t, p, keep_out: []
    p, v = np.array([0.0, 0.0]), np.array([2.0, 0.0])
    g.step(0.0, 0.02, p, v, 2.0, 4.0, [Disc(10.0, 0.3, 1.5)], yaw=0.0, walls=())
    first = g.plan
    d = second(first)
    g.step(0.02, 0.02, p + 0.02 * v, v, 2.0, 4.0, [d], yaw=0.0, walls=())
    pts = dense_path(g.plan.p, g.plan.v, g.plan.a, g.plan.t[1] - g.plan.t[0])
    return first, g.plan, float(np.min(np.hypot(pts[:, 0] - d.x, pts[:, 1] - d.y))) - d.r


def _beside(first) -> Disc:
    """A disc beside the route, farther out than a reason to swerve, 0.3 m into the pass's widest point."""
    q = first.p[np.argmax(np.abs(first.p[:, 1]))]
    d = Disc(float(q[0]), float(q[1] + 0.5 * np.sign(q[1])), 0.8)
    assert abs(d.y) > d.r + 0.5
    return d


@pytest.mark.parametrize("second", [lambda first: Disc(10.0, 0.3, 1.9), _beside], ids=["grown", "beside"])
def test_a_swerve_is_planned_again_at_once_when_its_pass_goes_into_a_disc(second):
    """The pole's disc grown (a bin more of its outline come into view: the same obstacle, its centre where it was), or
    a disc beside the route where the pass goes (a corridor's corner come into view, nothing in the way any more): the
    pass goes into it, planned again in that cycle, round it (the Hold judges the new plan from the next cycle).
    Control: without that check the pass in force is kept until the next timed replan, into the disc."""
    first, plan, clear = _swerve_then(second, True)
    assert first.kind == "pass" and plan is not first and plan.kind == "pass" and plan.ok and clear >= 0.0
    first, plan, clear = _swerve_then(second, False)
    assert plan is first and clear < 0.0  # negative control


def test_a_corner_beyond_the_route_s_end_is_not_in_the_way(monkeypatch):
    """examples/campaign-clutter.yaml flight 472 (the X500 on a corridor's last leg, 0.8 m right of the route, 2.8 m
    before its end): a piece of the corridor's corner beyond the end, taken for a pole, lies 1.9 m beside the leg's line
    and 2.6 m from the way to the end, where the vehicle rests: not in the way. What lies on that way still is. Control:
    judged against the leg's line as on any other leg, the corner is in the way (the pass round it, its cruise speed
    beyond the route's end 0, ran 50 m out through the wall)."""
    from tests.swerve_rules import threats_past_the_route_end

    g = OffboardGuidance(Route([[0, 0], [20.35, 0], [20.35, -17.75]], 2.0))
    p, v = np.array([21.15, -14.92]), np.array([-0.05, -1.33])
    corner, on_the_way = Disc(23.07, -19.48, 1.93, 1.47), Disc(21.4, -16.8, 0.9, 0.45)
    assert g._threats(p, v, [corner]) == []
    assert g._threats(p, v, [corner, on_the_way]) == [on_the_way]
    threats_past_the_route_end(monkeypatch)
    assert g._threats(p, v, [corner]) == [corner]  # negative control
