"""The eq. (14)–(19) planner itself: ZOH, scaling law, stop branch, between-sample keep-out, features."""

import math

import numpy as np
import pytest

pytest.importorskip("casadi")

from contracts.avoid_limit import policy_guess, stop_speed_kinematic  # noqa: E402
from contracts.flat import accel_from_inputs, zoh  # noqa: E402
from contracts.planner import (  # noqa: E402
    Limits,
    PlanProblem,
    Polygon,
    check_trajectory,
    circle_min_distance,
    head_on_problem,
    plan,
    propagate,
)
from contracts.sweep import brake_accel, solve_cell  # noqa: E402
from contracts.vehicle import G, load_vehicle  # noqa: E402

CONE45 = Limits(mass=1.0, t_max=10.0 * G, tilt=math.radians(45.0))


def max_speed(lim, c, r_k, n=40):
    a = lim.accel_bound()
    v0 = 0.5 * math.sqrt(a * c * c / r_k)
    best = 0.0
    for beta in (1.35, 0.6):
        w, ts = policy_guess(beta, v0, a, c, r_k, n)
        r = plan(head_on_problem(lim, v0, c, r_k, n=n, free_speed=True), (w, ts), verify_tol=0.0)
        if r.ok:
            best = max(best, r.problem.q0[1])
    return best


def test_propagate_is_the_zoh_of_eq_12_13():
    rng = np.random.default_rng(1)
    q0, w, ts = rng.normal(size=8), rng.normal(size=(5, 4)), 0.37
    fh, gh = zoh(ts)
    q = q0.copy()
    for k in range(5):
        q = fh @ q + gh @ w[k]
    assert np.allclose(propagate(q0, w, ts)[-1], q, atol=1e-12)


def test_scaling_law_lengths_times_lambda_speed_times_sqrt_lambda():
    v1 = max_speed(CONE45, 2.0, 0.5)
    v4 = max_speed(CONE45, 8.0, 2.0)  # λ = 4
    assert v1 > 0
    assert v4 / v1 == pytest.approx(2.0, rel=1e-3)


def test_invariance_in_c_and_r_k_reduced_form():
    # same ρ = r_k/c at two scales and two tilts: V/√(a·c) is one number G(ρ)
    lim13 = Limits(mass=1.0, t_max=10.0 * G, tilt=math.radians(13.0))
    g1 = max_speed(CONE45, 3.0, 0.9) / math.sqrt(CONE45.accel_bound() * 3.0)
    g2 = max_speed(lim13, 7.0, 2.1) / math.sqrt(lim13.accel_bound() * 7.0)
    assert g1 == pytest.approx(g2, rel=1e-3)


def test_v_safe_at_least_the_stop_speed_and_well_above_it_for_a_small_far_obstacle():
    veh = load_vehicle("mambo")
    lim = Limits.from_vehicle(veh, math.radians(10.0), 0.8)
    a_b = brake_accel(lim)
    # big obstacle close: the stop branch is (nearly) the limit, never below it
    big = solve_cell(lim, 0.8, starts=1, c=4.0)
    assert big.lo >= float(stop_speed_kinematic(a_b, 4.0, 3.2)) * (1 - 1e-8)
    # small obstacle far away: swerving beats stopping by far
    small = solve_cell(lim, 0.02, starts=1, c=10.0)
    v_stop = float(stop_speed_kinematic(a_b, 10.0, 0.2))
    assert small.branch == "pass"
    assert small.lo > 2.0 * v_stop


def test_solution_re_simulates_clean_and_keeps_out_between_samples():
    r = plan(head_on_problem(CONE45, 5.0, 5.0, 1.0, n=30), verify_tol=0.0)
    assert r.ok, r.check
    assert r.check["sub_steps"] >= 20
    # independent fine Euler-free check: exact parabola sampled 1000× per interval
    q = r.q
    tau = np.linspace(0.0, r.ts, 1000)
    for k in range(len(r.w)):
        px = q[k, 0] + q[k, 1] * tau + 0.5 * r.w[k, 0] * tau**2
        py = q[k, 2] + q[k, 3] * tau + 0.5 * r.w[k, 1] * tau**2
        assert np.min(np.hypot(px - 5.0, py)) >= 1.0 - 1e-9


def test_checker_catches_a_path_that_cuts_the_disc_between_samples():
    # coasting straight through a small disc whose centre lies between two nodes
    pr = head_on_problem(CONE45, 10.0, 5.0, 0.2, n=2)
    w = np.zeros((2, 4))
    ts = 0.45  # nodes at x = 0, 4.5, 9.0: all outside the disc
    nodes = propagate(pr.q0, w, ts)
    assert np.all(np.hypot(nodes[:, 0] - 5.0, nodes[:, 2]) > 0.2)
    assert circle_min_distance(nodes, w, ts, 5.0, 0.0).min() == pytest.approx(0.0, abs=1e-12)
    assert not check_trajectory(pr, w, ts)["ok"]


def test_infeasible_speed_is_not_accepted():
    r = plan(head_on_problem(CONE45, 40.0, 3.0, 1.5, n=30), cpu_time=1.0)
    assert not r.ok


def test_paper_boundary_conditions_polygon_altitude_rates_yaw_and_references():
    """Full 3-D problem: q(N) = q_f box, w(1) = w_0, w(N) = w_f, a square column, altitude band,
    box tilt model, roll/pitch-rate and yaw-moment limits; references map back through eq. (7)."""
    veh = load_vehicle("mambo")
    lim = Limits.from_vehicle(veh, math.radians(15.0), 1.0, tilt_model="box", rates=True, v_max=3.0,
                              z_min=-2.0, z_max=-0.5, t_min=0.1)
    q0 = (0.0, 2.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0)
    qf = (8.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.5, 0.0)
    square = Polygon(((3.5, -0.5), (4.5, -0.5), (4.5, 0.5), (3.5, 0.5)), r=0.2)
    pr = PlanProblem(limits=lim, q0=q0, obstacles=(square,), w0=(0, 0, 0, 0), wf=(0, 0, 0, 0), terminal="box",
                     qf_lb=qf, qf_ub=qf, n=40, planar=False)
    w = np.zeros((40, 4))
    w[5:15, 1] = 1.0
    w[15:25, 1] = -1.0
    r = plan(pr, (w, 0.12), cpu_time=20.0)
    assert r.ok, (r.status, r.check)
    assert np.allclose(r.q[-1], qf, atol=1e-6)
    ref = r.references(sub=4)
    assert {"x_r", "y_r", "z_r", "phi_r", "theta_r", "psi_r"} <= set(ref)
    ax, ay, az = accel_from_inputs(ref["thrust"], ref["phi_r"], ref["theta_r"], ref["psi_r"], veh.mass_kg)
    assert np.allclose(ax, ref["ax"], atol=1e-9) and np.allclose(ay, ref["ay"], atol=1e-9)
    assert np.all(np.abs(ref["phi_r"]) <= lim.tilt * (1 + 1e-9))
    assert np.all((ref["z_r"] >= -2.0 - 1e-3) & (ref["z_r"] <= -0.5 + 1e-3))
