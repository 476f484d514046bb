"""The online OSQP avoidance planner: exact safety of what it returns, and consistency with the avoid
contract it has to fly (DESIGN.md §5, offboard)."""

import math

import numpy as np
import pytest

from companion.avoid_planner import OFFBOARD_CAP, AvoidancePlanner, Disc, exact_check
from contracts.flat import horizontal_accel_limit
from contracts.table import verify
from contracts.vehicle import DATA_DIR, G, load_vehicle

A9 = G * math.tan(math.radians(9))


@pytest.fixture(scope="module")
def planner():
    return AvoidancePlanner(n=40)


def test_passes_a_head_on_disc_within_every_limit(planner):
    plan = planner.plan([0, 0], [4.0, 0], [1, 0], [Disc(7.3, 0.0, 1.3)], v_max=4.0, a_max=A9)
    assert plan.ok and plan.kind == "pass" and plan.min_clearance >= 0
    ts = plan.t[1] - plan.t[0]
    assert exact_check(plan.p, plan.v, plan.a, ts, [Disc(7.3, 0.0, 1.3)], 4.0, A9)[0]
    assert np.max(np.hypot(*plan.a.T)) <= A9 * (1 + 1e-6)
    assert abs(plan.p[-1, 1]) > 0 and plan.p[-1, 0] > 7.3 + 1.3  # beyond it, beside the route


def test_route_frame_rotation_and_offsets(planner):
    u = np.array([math.cos(1.0), math.sin(1.0)])
    p0 = np.array([10.0, -3.0])
    c = p0 + 7.3 * u
    plan = planner.plan(p0, 4.0 * u, u, [Disc(c[0], c[1], 1.3)], v_max=4.0, a_max=A9)
    assert plan.ok and np.allclose(plan.p[0], p0) and np.allclose(plan.v[0], 4.0 * u)
    assert np.min(np.hypot(plan.p[:, 0] - c[0], plan.p[:, 1] - c[1])) >= 1.3


def test_exact_check_rejects_a_path_through_a_disc():
    n, ts = 10, 0.1
    p = np.column_stack([np.linspace(0, 4, n + 1), np.zeros(n + 1)])
    v = np.tile([4.0, 0.0], (n + 1, 1))
    a = np.zeros((n, 2))
    ok, clear, why = exact_check(p, v, a, ts, [Disc(2.2, 0.1, 0.18)], 4.0, 1.0)
    # the samples clear the disc (2.0 and 2.4 are outside), the path between them does not
    assert not ok and clear < 0 and "keep-out" in why


def test_too_close_to_pass_or_stop_falls_back_to_braking(planner):
    plan = planner.plan([0, 0], [5.0, 0], [1, 0], [Disc(2.0, 0.0, 1.5)], v_max=5.0, a_max=A9)
    assert plan.kind == "brake" and not plan.ok


def test_replanning_from_the_last_plan(planner):
    disc = [Disc(7.3, 0.0, 1.3)]
    first = planner.plan([0, 0], [4.0, 0], [1, 0], disc, v_max=4.0, a_max=A9)
    p, v, _ = first.sample(0.3)
    again = planner.plan(p, v, [1, 0], disc, v_max=4.0, a_max=A9, warm=first, elapsed=0.3)
    assert again.ok and again.kind == first.kind
    assert np.sign(again.p[-1, 1]) == np.sign(first.p[-1, 1])  # the same side: no dithering
    assert again.qp_solves <= first.qp_solves + 1


@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
def test_the_planner_achieves_the_capped_avoid_contract_on_a_seeded_sample(planner, vehicle):
    """Start at OFFBOARD_CAP × V_safe (the table's, with its reaction time) with the obstacle revealed at
    D_od head-on; the planner must return a verified avoiding trajectory every time."""
    veh = load_vehicle(vehicle)
    t = verify(DATA_DIR / f"{vehicle}.npz", veh)
    rng = np.random.default_rng(2026)
    tried = failed = 0
    while tried < 25:
        d_od, r_obst = rng.uniform(1, 15), rng.uniform(0.1, 2)
        tilt, tr = math.radians(rng.uniform(3, 25)), rng.uniform(*veh.thrust_ratio_range)
        v = OFFBOARD_CAP * t.v_safe(d_od, r_obst, 0.0, tilt, tr)
        if v < 0.1:
            continue
        tried += 1
        a = horizontal_accel_limit(tilt, veh.t_max(tr), veh.mass_kg)
        x0 = v * veh.reaction_time(tilt)  # covered before the manoeuvre starts
        r_k = r_obst + veh.r_body_m
        plan = planner.plan([x0, 0], [v, 0], [1, 0], [Disc(d_od + r_obst, 0, r_k)], v_max=v, a_max=a)
        failed += not plan.ok
    assert failed == 0
