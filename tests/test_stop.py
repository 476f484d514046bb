import math

import numpy as np
import pytest

from contracts.stop import (approach_stop_speed, approach_stopping_distance, braking_decel, braking_distance, stop_speed,
                            stopping_distance, v_stop)
from contracts.vehicle import G, load_vehicle


def simulate_stop(v0, a_max, j_max, t_r, dt=1e-5):
    """Independent fine time-step simulation: dead time, then time-optimal jerk-limited braking
    (decel rises at j_max to at most a_max, and falls at j_max so that it reaches 0 as v reaches 0)."""
    x, v, a = v0 * t_r, v0, 0.0
    while v > 0.0:
        # start releasing when the speed left equals what a ramp-down from a would remove
        if v <= a * a / (2.0 * j_max):
            a = max(a - j_max * dt, 0.0)
            if a == 0.0:
                break
        else:
            a = min(a + j_max * dt, a_max)
        v_new = max(v - a * dt, 0.0)
        x += 0.5 * (v + v_new) * dt
        v = v_new
    return x + v * v / (2 * max(a, 1e-9)) * 0  # residual speed is O(dt)


@pytest.mark.parametrize("v0", [0.3, 1.0, 2.2, 4.0, 7.5])
@pytest.mark.parametrize("t_r", [0.0, 0.25])
def test_closed_form_matches_fine_simulation(v0, t_r):
    a, j = 3.0, 4.0
    sim = simulate_stop(v0, a, j, t_r)
    assert stopping_distance(v0, a, j, t_r) == pytest.approx(sim, rel=2e-3, abs=2e-4)


@pytest.mark.parametrize("d", [0.02, 0.3, 1.1, 2.0, 6.0, 40.0])
@pytest.mark.parametrize("t_r", [0.0, 0.1, 0.4])
def test_stop_speed_inverts_the_distance_and_is_never_optimistic(d, t_r):
    a, j = 3.0, 4.0
    v = float(stop_speed(d, a, j, t_r))
    assert simulate_stop(v, a, j, t_r) <= d * (1 + 2e-3)
    assert float(stopping_distance(v, a, j, t_r)) <= d
    assert float(stopping_distance(v * 1.001, a, j, t_r)) > d  # and tight


def test_no_room_means_no_speed():
    assert float(stop_speed(0.0, 3.0, 4.0, 0.1)) == 0.0
    assert float(stop_speed(-1.0, 3.0, 4.0, 0.1)) == 0.0
    v = load_vehicle("mambo")
    assert float(v_stop(v, d_od=0.05, r_obst=1.0, e_tr=0.0, thrust_ratio=1.0)) == 0.0


def test_v_stop_uses_the_keep_out_disc_near_edge():
    v = load_vehicle("x500")
    got = float(v_stop(v, d_od=8.0, r_obst=0.5, e_tr=0.3, thrust_ratio=1.0))
    a = braking_decel(v, 1.0)
    t_r = v.t_react_s + v.braking.hold_switch_s
    want = float(approach_stop_speed(8.0 - 0.3 - v.r_body_m, a, v.braking.jerk_max_m_s3, t_r))
    assert got == pytest.approx(want)
    assert got < float(stop_speed(8.0 - 0.3 - v.r_body_m, a, v.braking.jerk_max_m_s3, t_r))  # from cruise: faster
    # monotone: more range helps, more tracking error hurts
    assert float(v_stop(v, 9.0, 0.5, 0.3, 1.0)) > got > float(v_stop(v, 8.0, 0.5, 0.6, 1.0))


def test_thrust_loss_lowers_the_deceleration_where_thrust_binds():
    m = load_vehicle("mambo")
    v = m.model_copy(update={"tilt_max_deg": 45.0, "braking": m.braking.model_copy(update={"accel_max_m_s2": 20.0, "jerk_max_m_s3": 60.0})})
    a_full, a_low = braking_decel(v, 1.0), braking_decel(v, 0.6)
    # at 0.6 the usable thrust allows √((T/m)² − g²) < g·tan(45°); at 1.0 the tilt binds
    t_low = v.t_max(0.6)
    assert a_low == pytest.approx(np.sqrt((t_low / v.mass_kg) ** 2 - G**2))
    assert a_low < a_full == pytest.approx(G * np.tan(np.radians(45)))
    assert float(v_stop(v, 6.0, 1.0, 0.2, 0.6)) < float(v_stop(v, 6.0, 1.0, 0.2, 1.0))


def test_braking_distance_branches_meet_at_the_knee():
    a, j = 3.0, 4.0
    vk = a * a / j
    assert float(braking_distance(vk * (1 - 1e-9), a, j)) == pytest.approx(float(braking_distance(vk, a, j)))


@pytest.mark.parametrize("d", [0.02, 0.3, 1.1, 2.0, 6.0, 40.0])
@pytest.mark.parametrize("t_r", [0.0, 0.25])
def test_approach_stop_speed_inverts_its_distance_on_both_branches(d, t_r):
    a, j = 3.0, 4.0
    v = approach_stop_speed(d, a, j, t_r)
    assert approach_stopping_distance(v, a, j, t_r) == pytest.approx(d, rel=1e-6)
    assert approach_stopping_distance(v, a, j, t_r) <= d
    assert approach_stopping_distance(v, a, j, t_r) >= stopping_distance(v, a, j, t_r)


def test_approach_stop_speed_is_the_largest_safe_speed_on_both_branches():
    """The closed form (the worst Hold at a0 = a) and the bisection below it: each answer is within the bound and
    1e-6 below it is not, over random vehicles and distances, tiny and degenerate ones included."""
    rng = np.random.default_rng(18)
    for _ in range(4000):
        a = float(rng.choice([rng.uniform(0.05, 15.0), 10 ** rng.uniform(-3, 2)]))
        j = float(rng.choice([rng.uniform(0.5, 60.0), 4.0, 10 ** rng.uniform(-2, 3)]))
        t_r = float(rng.choice([0.0, rng.uniform(0.0, 1.0), 10 ** rng.uniform(-6, 1)]))
        d = float(10 ** rng.uniform(-6, 2))
        v = approach_stop_speed(d, a, j, t_r)
        assert 0.0 < v and approach_stopping_distance(v, a, j, t_r) <= d, (d, a, j, t_r)
        assert approach_stopping_distance(v * (1 + 1e-6), a, j, t_r) > d, (d, a, j, t_r)
    for d in (0.0, -1.0, math.nan, -math.inf, 5e-324, 1e-310):
        for t_r in (0.0, 0.25, 1e3, math.inf):
            v = approach_stop_speed(d, 3.0, 4.0, t_r)
            assert v == 0.0 or (v > 0.0 and approach_stopping_distance(v, 3.0, 4.0, t_r) <= d), (d, t_r)
    assert approach_stop_speed(math.inf, 3.0, 4.0, 0.25) == math.inf
