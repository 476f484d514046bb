"""The online OSQP avoidance planner: exact safety of what it returns, and consistency with the avoid
contract it has to fly (DESIGN.md §5, offboard)."""

import math

import numpy as np
import pytest

from contracts.flat import horizontal_accel_limit
from contracts.online_planner import (
    OFFBOARD_CAP,
    UNRECORDED_CAP,
    AvoidancePlanner,
    Disc,
    admitted,
    dense_path,
    exact_check,
    offboard_cap,
    pass_sides,
)
from contracts.table import load_for_vehicle
from contracts.vehicle import G, load_vehicle

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
    t = load_for_vehicle(veh)
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


def test_a_plan_may_start_inside_the_e_tr_allowance_but_never_goes_deeper():
    """Paper, Figures 14–16: the vehicle may enter the virtual obstacle (R_obst + E_tr) and must still
    clear the real one. Starting 0.4 m inside a disc's E_tr allowance, the plan is accepted and keeps
    at least its starting distance (less the stated gap); with no allowance the same start only brakes."""
    c = np.array([5.0, -1.2])
    disc = Disc(c[0], c[1], 1.6 + 0.9, 1.6)  # keep-out 2.5 m, of which 0.9 m is E_tr
    p0 = c + np.array([-0.3, 2.1])  # 2.12 m from the centre, moving past it: inside the allowance
    plan = AvoidancePlanner().plan(p0, [4.0, 0.0], [1, 0], [disc], v_max=4.0, a_max=A9)
    assert plan.ok and plan.kind in ("pass", "stop")
    ts = plan.t[1] - plan.t[0]
    pts = dense_path(plan.p, plan.v, plan.a, ts)
    closest = float(np.min(np.hypot(*(pts - c).T)))
    assert closest >= math.hypot(0.3, 2.1) - (A9 * ts * ts / 8 + 0.02) - 1e-6
    assert closest > disc.r_min
    whole = AvoidancePlanner().plan(p0, [4.0, 0.0], [1, 0], [Disc(c[0], c[1], 2.5)], v_max=4.0, a_max=A9)
    assert not whole.ok or whole.kind == "brake"


def test_admitted_shrinks_only_the_allowance():
    d = Disc(0.0, 0.0, 2.0, 1.5)
    assert admitted([d], (3.0, 0.0), 0.1)[0] == [d]  # outside: as it is
    (inside,), notes = admitted([d], (1.8, 0.0), 0.1)
    assert inside.r == pytest.approx(1.7) and inside.r_min == 1.5 and notes
    assert admitted([d], (1.55, 0.0), 0.1)[0] == [d]  # within gap of the core: kept whole
    assert admitted([Disc(0.0, 0.0, 2.0)], (1.8, 0.0), 0.1)[0] == [Disc(0.0, 0.0, 2.0)]  # no allowance


def test_the_time_budget_skips_further_attempts():
    planner = AvoidancePlanner()
    discs = [Disc(3.0, 0.0, 2.0)]  # too close to pass or stop: every attempt fails
    slow = planner.plan([0, 0], [5.0, 0], [1, 0], discs, v_max=5.0, a_max=A9)
    quick = planner.plan([0, 0], [5.0, 0], [1, 0], discs, v_max=5.0, a_max=A9, budget_s=0.0)
    assert slow.qp_solves > quick.qp_solves and any("budget" in n for n in quick.notes)
    assert quick.kind == "brake"


def test_an_unbounded_keep_out_disc_is_the_best_stop_not_an_exception():
    """Issue 19 item 6: a disc inflated to infinity (E_tr_pred with no answer) made OSQP refuse the
    problem and the planner raise. Now: no exception, a braking plan — the best stop the finite part of
    the geometry (the disc's never-entered core) allows, which swerves off the core it would brake into."""
    from contracts.online_planner import AvoidancePlanner, Disc, best_stop, braking_plan

    planner = AvoidancePlanner()
    core = Disc(5.2, 0.3, 1.2)
    plan = planner.plan([0.0, 0.0], [6.0, 0.0], [1.0, 0.0], [Disc(core.x, core.y, math.inf, core.r)], 6.0, 4.0)
    assert plan.kind == "brake" and not plan.ok and np.all(np.isfinite(plan.p))
    assert any("not finite" in n for n in plan.notes)
    # straight braking from 6 m/s at 4 m/s² needs 4.5 m: into the core from 4.04 m; the best stop clears it
    p, v, a, ts = braking_plan(np.zeros(2), np.array([6.0, 0.0]), 4.0, 30)
    straight = float(np.min(np.hypot(p[:, 0] - core.x, p[:, 1] - core.y))) - core.r
    assert straight < 0
    assert plan.min_clearance > 0
    assert np.max(np.hypot(*plan.v.T)) <= 6.0 + 1e-9  # never faster than it was
    assert np.max(np.hypot(*plan.a.T)) <= 4.0 + 1e-9
    assert np.hypot(*plan.v[-1]) < 1e-6  # and at rest
    # with nothing in the way the best stop is the straight one
    p0, v0, a0, ts0, _ = best_stop(np.zeros(2), np.array([6.0, 0.0]), 4.0, [], 30)
    assert np.allclose(p0, p) and ts0 == ts


@pytest.mark.parametrize("y", [2.2, -2.2])
def test_a_disc_to_one_side_is_passed_on_its_near_side(planner, y):
    """Campaign flight 53 (issue 16): a keep-out disc reaching 0.6 m over the route from +y was passed on +y
    (its far side, a 6.5 m swerve) because +y was always tried first. The nearer side comes first now."""
    disc = Disc(7.0, y, 2.8)
    plan = planner.plan([0, 0], [5.8, 0], [1, 0], [disc], v_max=5.8, a_max=G * math.tan(math.radians(35)))
    assert plan.ok and plan.kind == "pass"
    assert np.sign(plan.p[:, 1]).sum() * np.sign(y) < 0  # beside the route, away from the disc
    assert np.max(np.abs(plan.p[:, 1])) < 2.0


def test_the_side_follows_the_sideways_speed():
    """Already moving sideways fast (a pass under way): the side it carries the vehicle to comes first, so a
    replan does not reverse the manoeuvre."""
    disc = [Disc(7.0, 0.3, 2.0)]
    assert pass_sides(disc, [5.0, 0.0], 5.0) == (-1.0, 1.0)
    assert pass_sides(disc, [5.0, 4.0], 5.0) == (1.0, -1.0)


@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
def test_offboard_never_flies_a_larger_cap_than_its_controller_contract_was_flown_at(vehicle, monkeypatch):
    """Issue 18: the E_tr sweep flies the planner's plans at OFFBOARD_CAP × V_safe and records that cap in
    the table; the offboard supervisor flies min(OFFBOARD_CAP, the recorded cap), so raising the cap takes
    effect only with tables whose E_tr_pred was flown at it. Control: a table recording 0.5 flies 0.5."""
    from companion.onboard.supervisor import Supervisor

    t = load_for_vehicle(vehicle)
    flown = t.etr_offboard_cap
    assert flown is not None and 0 < flown <= 1
    sup = Supervisor(t, "offboard", contract="avoid", dwell_s=2.0, loop_dt=0.02)
    assert sup.cap == min(OFFBOARD_CAP, flown) == offboard_cap(flown)
    assert offboard_cap(None) == UNRECORDED_CAP < OFFBOARD_CAP  # nothing recorded: the old, slower cap
    assert Supervisor(t, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02).cap == 1.0
    info = dict(t.e_pred.info, grid={**t.e_pred.info["grid"], "online": {**t.e_pred.info["grid"]["online"],
                                                                           "offboard_cap": 0.5}})
    monkeypatch.setattr(t, "e_pred", type(t.e_pred)(t.e_pred.axes, t.e_pred.values, info))
    assert t.etr_offboard_cap == 0.5
    assert Supervisor(t, "offboard", contract="avoid", dwell_s=2.0, loop_dt=0.02).cap == 0.5


def test_the_planner_reaches_the_avoid_contract_where_it_used_to_fail(planner):
    """Issue 18: the Mambo cells of benchmarks/bench_planner.py's seeded sample (seed 0) where the old
    planner failed at 0.95 and 0.97 × V_safe (before the exact roll-out, the tightened polygons and the
    vertex turn): its QP solution sat a hair outside the inscribed 16-gon's tilt limit (`acceleration
    above the tilt limit`), or the 16-gon cost the brake-and-swerve up to 1.9 % of its acceleration.
    They verify now (on the old planner all three failed)."""
    veh = load_vehicle("mambo")
    t = load_for_vehicle(veh)
    rng = np.random.default_rng(0)
    cells = []
    while len(cells) < 200:  # the benchmark's draw, in its order
        d_od, r_obst = rng.uniform(1, 15), rng.uniform(0.1, 2)
        tilt, tr = math.radians(rng.uniform(3, 25)), rng.uniform(*veh.thrust_ratio_range)
        v = t.v_safe(d_od, r_obst, 0.0, tilt, tr)
        if v > 0.1:
            cells.append((d_od, r_obst, tilt, tr, v))
    for i, k in ((3, 0.95), (168, 0.97), (194, 0.97)):
        d_od, r_obst, tilt, tr, v = cells[i]
        v *= k
        a = horizontal_accel_limit(tilt, veh.t_max(tr), veh.mass_kg)
        plan = AvoidancePlanner().plan([v * veh.reaction_time(tilt), 0], [v, 0], [1, 0],
                                       [Disc(d_od + r_obst, 0, r_obst + veh.r_body_m)], v_max=v, a_max=a)
        assert plan.ok and plan.kind == "pass", (i, k, plan.notes)


# Issue 19 item 1: the daemon's fail-safe stop mid-swerve (Mambo, seed 8 of tests/test_failsafe_stop_lockstep.py:
# the measured state, the disc last seen, the Mambo's full-tilt deceleration, the path budget of that flight)
MID_P, MID_V = np.array([25.5698, -0.1755]), np.array([5.1533, -1.0077])
MID_DISC = Disc(30.0452, -0.1135, 2.2284, 1.3523)
MID_A, MID_BUDGET, MID_A0 = G * math.tan(math.radians(25.0)), 4.92, np.array([-0.872, -4.395])


def test_a_straight_stop_into_the_etr_margin_loses_to_a_swerve_with_more_clearance():
    """On 260d4bd the straight stop won because it cleared the disc's never-entered core, although it ended
    0.58 m inside the E_tr margin and a swerve off the disc within the budget kept ~0.45 m more: the vehicle's
    ~0.7 m overrun then hit the column. The stop with the most clearance wins when none clears the disc."""
    from contracts.online_planner import best_stop, braking_plan, dense_path

    p, v, a, ts = braking_plan(MID_P, MID_V, MID_A, 40)
    pts = dense_path(p, v, a, ts)
    straight = float(np.min(np.hypot(pts[:, 0] - MID_DISC.x, pts[:, 1] - MID_DISC.y))) - MID_DISC.r
    assert straight < -0.5
    bp, bv, ba, bts, clear = best_stop(MID_P, MID_V, MID_A, [MID_DISC], 40, max_path_m=MID_BUDGET)
    assert clear > straight + 0.3
    path = dense_path(bp, bv, ba, bts)
    assert float(np.sum(np.hypot(*np.diff(path, axis=0).T))) <= MID_BUDGET  # within the stop contract's budget
    assert np.max(np.hypot(*bv.T)) <= np.hypot(*MID_V) * (1 + 1e-6)  # never faster than it was
    assert np.hypot(*bv[-1]) < 1e-9


@pytest.mark.parametrize("deg_disc", [None, "mid"])
def test_the_failsafe_stop_turns_from_the_vehicles_acceleration_at_the_jerk_limit(deg_disc):
    """A stop the vehicle can track: it starts from the acceleration the vehicle was given (mid-swerve, 4.5 m/s²
    sideways), turns it at most at the jerk limit (the full-tilt stop stepped it by 5.2 m/s² at once), stays
    within the deceleration, and ends at rest with zero acceleration."""
    from contracts.online_planner import best_stop

    jerk = G * math.radians(220.0)  # contracts.stop.stop_jerk for the Mambo
    discs = [MID_DISC] if deg_disc else []
    p, v, a, ts, _ = best_stop(MID_P, MID_V, MID_A, discs, 40, max_path_m=MID_BUDGET, a0=MID_A0, jerk=jerk)
    tol = 1.03  # the law is stepped at SMOOTH_DT and sampled on the plan's intervals
    assert np.hypot(*(a[0] - MID_A0)) <= jerk * ts * tol
    assert np.max(np.hypot(*np.diff(a, axis=0).T)) <= jerk * ts * tol
    assert np.max(np.hypot(*a.T)) <= max(MID_A, float(np.hypot(*MID_A0))) * (1 + 1e-9)
    assert np.hypot(*v[-1]) < 1e-9 and np.hypot(*a[-1]) <= jerk * ts * tol
    assert np.all(np.isfinite(p))
    # without a jerk limit the acceleration steps (the old stop)
    _, _, a_step, ts_step, _ = best_stop(MID_P, MID_V, MID_A, discs, 40, max_path_m=MID_BUDGET)
    assert np.hypot(*(a_step[0] - MID_A0)) > 3 * jerk * ts_step


def test_a_stop_at_rest_inside_a_keep_out_backs_off_along_the_path_flown():
    """At rest 0.3 m inside a keep-out disc, having come in on a 90° turn: the way out is a straight line to a point
    of the path flown outside the disc, at the back-off's speed and acceleration, never deeper in than at its start,
    ending at rest. Outside every disc, or with no such point, there is none."""
    from contracts.online_planner import (BACK_OFF_ACC, BACK_OFF_M_S, BACK_OFF_MARGIN_M, Disc, back_off,
                                          dense_path)

    disc = Disc(3.0, 0.0, 1.0)
    # flown along y = -2 to x = 2.3, then turned up along x = 2.3 to rest at (2.3, 0.0): 0.3 m inside the disc
    track = [(x, -2.0) for x in np.arange(0.0, 2.3, 0.05)] + [(2.3, y) for y in np.arange(-2.0, 0.001, 0.05)]
    plan = back_off(track, [disc])
    assert plan is not None and plan.min_clearance == pytest.approx(-0.3, abs=1e-6)
    pts = dense_path(plan.p, plan.v, plan.a, plan.t[1] - plan.t[0])
    clear = np.hypot(pts[:, 0] - disc.x, pts[:, 1] - disc.y) - disc.r
    assert clear[0] == pytest.approx(-0.3, abs=1e-3) and np.min(clear) >= -0.3 - 1e-3
    assert clear[-1] >= BACK_OFF_MARGIN_M - 1e-3 and clear[-1] < BACK_OFF_MARGIN_M + 0.1  # no further than needed
    assert np.max(np.hypot(*plan.v.T)) <= BACK_OFF_M_S + 1e-9
    assert np.max(np.hypot(*plan.a.T)) <= BACK_OFF_ACC * 1.05
    assert np.allclose(plan.v[[0, -1]], 0.0)
    assert back_off(track[:-25], [disc]) is None  # at rest outside (1.25 m back along the turn): stay
    assert back_off([(2.3, 0.0)], [disc]) is None  # no path flown to back along
