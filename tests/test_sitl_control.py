"""The PX4-like cascade: step responses, limits, thrust priority, auto-mode braking, circle tracking."""

import math

import numpy as np
import pytest

from contracts.vehicle import G, load_vehicle
from sitl_harness.control import S_THR, SP_ACC, SP_POS
from sitl_harness.maneuvers import fly_circle, hovering, step_response
from sitl_harness.physics import euler_from_quat
from sitl_harness.trajectory import AutoTrajectory, stop_speed


@pytest.fixture(scope="module", params=["mambo", "x500"])
def vehicle(request):
    return load_vehicle(request.param).model_copy(update={"drag_coeff_n_s2_m2": 0.0})


# Stated step-response bounds of the SITL cascade with the shipped (PX4-default) gains. The
# horizontal overshoot comes from the velocity integrator (MPC_XY_VEL_I_ACC 0.4) as in PX4.
BOUNDS = {("pos", 0, 1.0): (0.15, 2.0), ("pos", 1, 1.0): (0.15, 2.0), ("pos", 2, -1.0): (0.02, 2.0),
          ("vel", 0, 2.0): (0.12, 1.2)}


@pytest.mark.parametrize("kind,axis,size", list(BOUNDS))
def test_step_response_within_stated_overshoot(vehicle, kind, axis, size):
    r = step_response(vehicle, axis, size, kind=kind)
    max_os, max_rise = BOUNDS[(kind, axis, size)]
    assert r["overshoot"] <= max_os
    assert r["rise_90_s"] <= max_rise
    assert abs(r["final_error"]) < 0.04 * abs(size)


def test_total_tilt_limit_holds(vehicle):
    """A huge horizontal acceleration request never tilts the thrust axis past the limit."""
    m = hovering(vehicle)
    m.sp[SP_POS:SP_POS + 2] = math.nan
    m.sp[SP_ACC] = 30.0
    m.sp[SP_ACC + 1] = 30.0
    worst = 0.0
    for _ in range(200):
        m.step(5)
        r, p, _ = euler_from_quat(m.quat)
        worst = max(worst, math.acos(math.cos(r) * math.cos(p)))
    assert worst <= vehicle.tilt_max * 1.03
    assert worst >= vehicle.tilt_max * 0.9


def test_thrust_priority_keeps_altitude_and_gives_horizontal_the_rest():
    """Thrust short (Mambo at thrust_ratio 0.6, tilt limit raised to 60°): altitude holds and the
    horizontal acceleration is what √(T_max² − T_z²) leaves (PX4 vertical-first priority)."""
    v = load_vehicle("mambo").model_copy(update={"drag_coeff_n_s2_m2": 0.0})
    tr = 0.6
    m = hovering(v, tr, tilt_max=math.radians(60))
    m.sp[SP_POS:SP_POS + 2] = math.nan
    m.sp[SP_ACC] = 20.0
    m.step(1500)
    v0 = m.vel[0]
    m.step(1000)
    a = m.vel[0] - v0
    u_max = v.collective_max_fraction
    hover = v.mass_kg * G / (tr * v.t_nom_n)
    expected = math.sqrt(u_max ** 2 - hover ** 2) / hover * G
    assert a == pytest.approx(expected, rel=0.03)
    assert abs(m.pos[2] + 5.0) < 0.1
    assert m.s[S_THR] == pytest.approx(u_max, rel=0.01)


def test_auto_brake_follows_accel_and_jerk_limits():
    """Hold-mode braking reference from 3 m/s: |a| ≤ accel_max, |jerk| ≤ jerk_max, stop distance
    = v²/(2a) + v·a/(2j) within 10 %."""
    tj = AutoTrajectory(3.0, 4.0)
    v0 = 3.0
    tj.reset((0, 0, -2), (v0, 0, 0))
    acc = []
    for _ in range(600):
        tj.step(0.01, None, 5.0, 3.0, 1.5)
        acc.append(tj.a[0])
    acc = np.array(acc)
    assert np.all(np.abs(acc) <= 3.0 + 1e-9)
    jumps = np.abs(np.diff(acc))
    assert np.sum(jumps > 4.0 * 0.01 + 1e-9) <= 1  # the final settle may drop a remainder < j·Δt
    assert np.all(jumps <= 2 * 4.0 * 0.01 + 1e-9)
    assert tj.speed_xy == 0.0
    assert tj.p[0] == pytest.approx(v0 ** 2 / 6.0 + v0 * 3.0 / 8.0, rel=0.1)


def test_goto_target_stops_on_it_without_overshoot():
    tj = AutoTrajectory(3.0, 4.0)
    tj.reset((0, 0, -2), (0, 0, 0))
    xs = []
    for _ in range(2000):
        tj.step(0.01, (20.0, 0.0, -2.0), 5.0, 3.0, 1.5)
        xs.append(tj.p[0])
    assert max(xs) <= 20.0 + 1e-6 and xs[-1] == 20.0
    assert stop_speed(0.0, 3.0, 4.0) == 0.0


def test_hover_thrust_estimate_recovers_altitude_after_thrust_drop():
    v = load_vehicle("mambo").model_copy(update={"drag_coeff_n_s2_m2": 0.0})
    m = hovering(v, 1.0)
    m.step(1000)
    m.thrust_ratio = 0.6
    zs = []
    for _ in range(1000):
        m.step(10)
        zs.append(m.pos[2])
    assert max(zs) - (-5.0) < 0.8  # sag bounded (a sudden 40 % thrust loss sags ≈ 0.6 m)
    assert abs(zs[-1] + 5.0) < 0.05  # recovered
    assert m.hover_thrust == pytest.approx(v.mass_kg * G / (0.6 * v.t_nom_n), rel=0.03)


def test_circle_tracking_error_grows_as_thrust_drops():
    """Mambo, R = 2 m at 7 m/s² lateral (3.74 m/s), tilt limit 45°: thrust_ratio 0.6 is the binding
    limit there (√(T²−W²)/m = 5.9 m/s² < 7), 0.7 is not (9.1 m/s²). The contour error grows
    as thrust drops and jumps where thrust binds."""
    v = load_vehicle("mambo")
    res = [fly_circle(v, tr, 2.0, 7.0, math.radians(45.0), laps=1.5) for tr in (1.0, 0.9, 0.8, 0.7, 0.6)]
    e = [r.contour_max_m for r in res]
    print("circle R=2 m a=7 m/s^2 contour max [m] at thrust_ratio 1.0..0.6:", [round(x, 3) for x in e])
    assert all(b >= a - 0.005 for a, b in zip(e, e[1:]))
    assert e[-1] > 2.0 * e[0]
    assert e[0] < 0.25


def test_cascade_attitude_matches_the_flat_map_eq8():
    """The thrust-vector → attitude step of the cascade agrees with the paper's eq. (8)."""
    from contracts.flat import inputs_from_flat
    from sitl_harness.control import attitude_from_thrust

    for ax, ay, psi in ((3.0, 0.0, 0.0), (0.0, -2.0, 0.7), (2.5, 1.5, -2.0), (-4.0, 3.0, 3.0)):
        bz = np.array([-ax, -ay, G])
        bz /= np.linalg.norm(bz)
        q = attitude_from_thrust(*(-bz), psi)
        roll, pitch, yaw = euler_from_quat(q)
        _, phi, theta, _ = inputs_from_flat(ax, ay, 0.0, psi)
        assert roll == pytest.approx(phi, abs=1e-9) and pitch == pytest.approx(theta, abs=1e-9)
        assert yaw == pytest.approx(psi, abs=1e-9)


def test_track_reference_with_contour_error_matches_circle_closed_form():
    """The sampled-reference flyer plus contracts.contour gives the circle's closed-form figure."""
    from contracts.contour import contour_errors
    from sitl_harness.maneuvers import track_reference

    v = load_vehicle("mambo")
    r, acc = 2.0, 4.0
    spd = math.sqrt(acc * r)
    w = spd / r
    t = np.arange(0.0, 3 * 2 * math.pi / w, 0.01)
    p = np.stack([r * np.cos(w * t), r * np.sin(w * t), np.full_like(t, -5.0)], axis=1)
    vel = np.stack([-spd * np.sin(w * t), spd * np.cos(w * t), 0 * t], axis=1)
    a = np.stack([-acc * np.cos(w * t), -acc * np.sin(w * t), 0 * t], axis=1)
    flown = track_reference(v, t, p, vel, a, tilt_max=math.radians(45))
    lap = t >= 2 * math.pi / w
    e = contour_errors(flown[lap], t[lap], t, p, window_s=0.5)
    ref = fly_circle(v, 1.0, r, acc, math.radians(45), laps=2.0)
    assert e.max() == pytest.approx(ref.contour_max_m, rel=0.1)
