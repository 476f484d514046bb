"""Polygon (polytopic) obstacles in the eq. (14)–(19) planner: keep-out with zero margin, signed
distance in the dense check, and an exact, memory-bounded check at verify_tol = 0."""

import math
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("casadi")

from contracts.planner import (  # noqa: E402
    Limits,
    PlanProblem,
    Polygon,
    check_trajectory,
    dense_states,
    plan,
    polygon_distance,
)
from contracts.vehicle import G  # noqa: E402

INF = math.inf
LIM = Limits(mass=1.0, t_max=2.0 * G, tilt=math.radians(30.0), v_max=3.0)
SQUARE = Polygon(((2.0, -0.5), (3.0, -0.5), (3.0, 0.5), (2.0, 0.5)), r=0.0)  # x ∈ [2, 3], y ∈ [-½, ½]


def _past_square(poly=SQUARE, n=20):
    """Level flight at 2 m/s along +x from the origin, q(N): X ≥ 5, Y = 0 (terminal box, eq. 18)."""
    return PlanProblem(limits=LIM, q0=(0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), obstacles=(poly,),
                       terminal="box", qf_lb=(5.0, -INF, 0.0, -INF) + (-INF,) * 4,
                       qf_ub=(INF, INF, 0.0, INF) + (INF,) * 4, n=n)


def _depth_inside(poly, q0, w, ts):
    """Independent check: max over dense samples of min_j (b_j − a_j·p) (> 0: inside the prism)."""
    _, q, _ = dense_states(q0, w, ts, 400)
    a, b = poly.halfplanes()
    return float(np.max(np.min(b - q[:, [0, 2]] @ a.T, axis=1)))


@pytest.mark.parametrize("start", ["straight", "default"])
def test_zero_margin_polygon_is_not_trivially_avoided(start):
    """Eq. (19) q ∉ C_0 with r = 0: the separating line must not degenerate to n = 0, β = 0."""
    pr = _past_square()
    guess = (np.zeros((pr.n, 4)), 5.0 / 2.0 / pr.n) if start == "straight" else None
    r = plan(pr, guess, cpu_time=5.0)
    assert _depth_inside(SQUARE, pr.q0, r.w, r.ts) < 0.0  # independent of check_trajectory
    assert r.ok, (r.status, r.check)
    assert r.check["min_clearance"] >= 0.0


def test_signed_polygon_distance_negative_inside():
    pts = np.array([[2.5, 0.0], [2.1, 0.2], [3.5, 0.0], [4.0, 1.5], [2.0, 0.0]])
    d = polygon_distance(pts, SQUARE)
    assert d == pytest.approx([-0.5, -0.1, 0.5, math.hypot(1.0, 1.0), 0.0], abs=1e-12)


def test_check_rejects_a_path_through_the_polygon():
    """Straight at 2 m/s through the square's middle: the dense check must see depth −½ m."""
    pr = _past_square()
    w = np.zeros((20, 4))
    ts = 0.125  # X(N) = 5 m
    for tol in (1e-3, 0.0):
        chk = check_trajectory(pr, w, ts, tol=tol)
        assert not chk["ok"]
        assert chk["margins"]["keep_out_0"] == pytest.approx(-0.5 + tol, abs=1e-9)
        assert chk["min_clearance"] == pytest.approx(-0.5, abs=1e-9)


@pytest.mark.parametrize("clear", [1e-9, -1e-9])
def test_verify_tol_zero_is_exact_and_bounded(clear):
    """verify_tol = 0: the keep-out minimum is exact per ZOH interval (no Lipschitz sampling term)
    and costs no more memory than the other checks, even at 10 m/s."""
    poly = Polygon(SQUARE.vertices, r=0.25)
    y = 0.5 + 0.25 + clear
    pr = PlanProblem(limits=replace(LIM, v_max=10.0), q0=(0.0, 10.0, y, 0.0, 0.0, 0.0, 0.0, 0.0), obstacles=(poly,), n=10)
    w = np.zeros((10, 4))
    tracemalloc.start()
    chk = check_trajectory(pr, w, 0.05, tol=0.0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 5e6
    assert chk["margins"]["keep_out_0"] == pytest.approx(clear, abs=1e-12)
    assert chk["ok"] is (clear > 0), chk["margins"]


@pytest.mark.parametrize("y0,enters", [(1.2, True), (1.25, False)])
def test_exact_minimum_on_a_curved_arc_near_a_corner(y0, enters):
    """A ZOH parabola past the corner (1, 1) of a unit square, between samples: the exact per-interval
    minimum is never above a fine sampling of the signed distance, and below it by at most the
    Lipschitz bound ½·|v|max·Δτ."""
    poly = Polygon(((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)), r=0.0)
    pr = PlanProblem(limits=Limits(mass=1.0, t_max=10 * G, tilt=1.4), q0=(0.3, 2.0, y0, 0.0, 0, 0, 0, 0),
                     obstacles=(poly,), n=1)
    w, ts, sub = np.array([[0.0, -3.6, 0.0, 0.0]]), 0.7, 200000
    _, q, _ = dense_states(pr.q0, w, ts, sub)
    fine = float(np.min(polygon_distance(q[:, [0, 2]], poly)))
    exact = check_trajectory(pr, w, ts, tol=0.0)["margins"]["keep_out_0"]
    assert (fine < 0) is enters
    assert exact <= fine + 1e-12
    assert fine - exact <= 0.5 * float(np.max(np.hypot(q[:, 1], q[:, 3]))) * ts / sub
