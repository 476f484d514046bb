import numpy as np
import pytest
from scipy.linalg import expm

from contracts.flat import (
    accel_from_inputs,
    cone_polygon,
    horizontal_accel_limit,
    in_input_set,
    inputs_from_flat,
    integrator_chains,
    thrust_limited_accel,
    total_tilt,
    zoh,
)
from contracts.vehicle import G

rng = np.random.default_rng(7)


def test_eq8_then_eq7_round_trips_on_random_flat_states():
    n = 2000
    ax, ay = rng.uniform(-8, 8, (2, n))
    az = rng.uniform(-5, 5, n)
    psi = rng.uniform(-np.pi, np.pi, n)
    t, phi, theta, _ = inputs_from_flat(ax, ay, az, psi, mass=0.063)
    bx, by, bz = accel_from_inputs(t, phi, theta, psi, 0.063)
    np.testing.assert_allclose([bx, by, bz], [ax, ay, az], atol=1e-9)


def test_eq7_then_eq8_recovers_the_inputs():
    n = 2000
    t = rng.uniform(0.2, 2.0, n)
    phi, theta = rng.uniform(-0.6, 0.6, (2, n))
    psi = rng.uniform(-np.pi, np.pi, n)
    ax, ay, az = accel_from_inputs(t, phi, theta, psi, 0.1)
    t2, phi2, theta2, _ = inputs_from_flat(ax, ay, az, psi, mass=0.1)
    np.testing.assert_allclose([t2, phi2, theta2], [t, phi, theta], atol=1e-9)


def test_yaw_input_eq8():
    *_, u_psi = inputs_from_flat(0.0, 0.0, 0.0, 0.0, psi_ddot=2.0, k_psi=1e4)
    assert u_psi == pytest.approx(2e-4)


@pytest.mark.parametrize("ts", [0.01, 0.1, 0.37, 1.5])
def test_zoh_closed_form_equals_matrix_exponential(ts):
    f, g = integrator_chains(4)
    n, m = f.shape[0], g.shape[1]
    # Van Loan: expm([[F, G], [0, 0]] ts) = [[F̂, Ĝ], [0, I]]
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = f, g
    e = expm(big * ts)
    fh, gh = zoh(ts, 4)
    np.testing.assert_allclose(fh, e[:n, :n], atol=1e-12)
    np.testing.assert_allclose(gh, e[:n, n:], atol=1e-12)
    np.testing.assert_allclose(fh, expm(f * ts), atol=1e-12)


def test_zoh_propagation_matches_constant_acceleration_kinematics():
    fh, gh = zoh(0.2, 2)
    q = np.array([1.0, 2.0, -1.0, 0.5])
    w = np.array([0.3, -1.0])
    for _ in range(10):
        q = fh @ q + gh @ w
    t = 2.0
    np.testing.assert_allclose(q, [1 + 2 * t + 0.15 * t * t, 2 + 0.3 * t, -1 + 0.5 * t - 0.5 * t * t, 0.5 - t])


def test_cone_limit_is_tilt_or_thrust_bound():
    assert horizontal_accel_limit(np.radians(10), 100.0, 1.0) == pytest.approx(G * np.tan(np.radians(10)))
    # little thrust: the thrust bound binds
    t_max = 1.1 * G
    assert horizontal_accel_limit(np.radians(40), t_max, 1.0) == pytest.approx(np.sqrt(0.21) * G)
    assert thrust_limited_accel(0.5 * G, 1.0) == 0.0


def test_input_sets_cone_and_box():
    tilt = np.radians(10)
    a = G * np.tan(tilt)
    # cone: a diagonal acceleration of norm a is at the limit; box allows more on the diagonal
    d = a / np.sqrt(2)
    assert in_input_set(d, d, 0.0, 0.0, tilt, 10.0, 0.1, "cone", tol=1e-9)
    assert not in_input_set(1.01 * d, 1.01 * d, 0.0, 0.0, tilt, 10.0, 0.1, "cone")
    assert in_input_set(1.01 * d, 1.01 * d, 0.0, 0.0, tilt, 10.0, 0.1, "box")
    # box: pure pitch at the limit is allowed, a little more is not
    assert in_input_set(a, 0.0, 0.0, 0.0, tilt, 10.0, 0.1, "box", tol=1e-9)
    assert not in_input_set(1.01 * a, 0.0, 0.0, 0.0, tilt, 10.0, 0.1, "box")
    # thrust
    assert not in_input_set(0.0, 0.0, -5.0, 0.0, tilt, 1.0 * 0.1 * G, 0.1, "cone")
    assert total_tilt(a, 0.0) == pytest.approx(tilt)


def test_cone_polygon_is_an_inner_approximation():
    a_max = 3.0
    A, b = cone_polygon(a_max, 12)
    # vertices of the polygon: intersections of neighbouring edges
    for i in range(12):
        M = np.array([A[i], A[(i + 1) % 12]])
        v = np.linalg.solve(M, [b[i], b[(i + 1) % 12]])
        assert np.linalg.norm(v) <= a_max + 1e-12
        assert np.all(A @ v <= b + 1e-12)
