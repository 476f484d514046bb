import math
import threading
import time

import numpy as np
import pytest

from companion.avoid_planner import AvoidancePlanner, Disc
from companion.guidance import OffboardGuidance, Route, ThreadedPlanning, obstacle_discs


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
    discs, widest = obstacle_discs(hits, (0.0, 0.0), 0.0, r_obst=1.0, inflate=0.3)
    assert len(discs) == 1
    d = discs[0]
    # the estimate holds the true obstacle: every point of the column is inside the keep-out disc
    ang = np.linspace(0, 2 * np.pi, 200)
    pts = c + r * np.column_stack([np.cos(ang), np.sin(ang)])
    assert np.all(np.hypot(pts[:, 0] - d.x, pts[:, 1] - d.y) <= d.r - 0.3 + 0.05)  # within 5 cm
    assert abs(d.y) < 0.3 and 5.5 < d.x < 6.8
    assert widest <= 1.0 + 1e-6  # no environment violation for an obstacle of exactly R_obst


def test_a_single_beam_keeps_every_position_consistent_with_the_hit():
    # a 30° beam reports 5 m: the obstacle may be anywhere across the beam at that range
    discs, _ = obstacle_discs([(0.0, 5.0, math.radians(15), False)], (0.0, 0.0), 0.0, r_obst=0.5, inflate=0.2)
    assert len(discs) > 2
    for off in np.linspace(-15, 15, 61):  # any hit point across the field of view …
        hp = 5.0 * np.array([math.cos(math.radians(off)), math.sin(math.radians(off))])
        # … and every obstacle of radius R_obst touching it (all within 2·R_obst of it) is kept out
        assert min(math.hypot(hp[0] - d.x, hp[1] - d.y) + 2 * 0.5 - (d.r - 0.2) for d in discs) <= 1e-9


def test_route_projection_and_cruise_reference():
    route = Route([[0, 0], [10, 0], [10, 10]], 2.0)
    assert route.length == pytest.approx(20.0)
    assert route.project([5.0, 1.0]) == pytest.approx(5.0)
    p, u = route.point(15.0)
    assert np.allclose(p, [10, 5]) and np.allclose(u, [0, 1])
    g = OffboardGuidance(route)
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
        self.gate.wait(5.0)
        if self.fail:
            raise RuntimeError("solver blew up")
        return super().plan(*a, **kw)


def _threat_step(g, t):
    return g.step(t, 0.02, [t * 5.0, 0.0], [5.0, 0.0], 5.0, 4.0, [Disc(12.0, 0.1, 1.6, 1.2)])


def test_threaded_planning_brakes_until_the_plan_arrives_then_follows_it_from_its_request_time():
    planner = _GatedPlanner()
    g = OffboardGuidance(Route([[0, 0], [60, 0]], 2.0), planner=planner, planning=ThreadedPlanning())
    g.start([0.0, 0.0], [5.0, 0.0])
    first = _threat_step(g, 0.0)
    assert first.mode == "planning" and first.v @ [1, 0] <= 5.0 and first.a @ [1, 0] < 0  # braking meanwhile
    assert _threat_step(g, 0.02).mode == "planning"  # the loop goes on while the worker is busy
    planner.gate.set()
    t, sp = 0.04, None
    for _ in range(200):
        sp = _threat_step(g, t)
        if sp.mode != "planning":
            break
        time.sleep(0.005)
        t += 0.02
    assert sp.mode == "avoid" and g.plan.ok and g.plan_t == 0.0  # the plan starts at the state asked for
    assert g.replans == 1


def test_a_planner_error_is_noted_and_the_vehicle_keeps_braking():
    planner = _GatedPlanner(fail=True)
    planner.gate.set()
    g = OffboardGuidance(Route([[0, 0], [60, 0]], 2.0), planner=planner, planning=ThreadedPlanning())
    g.start([0.0, 0.0], [5.0, 0.0])
    t = 0.0
    for _ in range(50):
        sp = _threat_step(g, t)
        time.sleep(0.005)
        t += 0.02
    assert sp.mode == "planning" and any("planner error" in n for n in g.last_notes)
