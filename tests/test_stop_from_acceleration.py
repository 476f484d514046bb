"""Issue 19 item 1: the stop contract from a state with acceleration, and the SITL personalities' Hold/Brake
agreeing with it and with the autopilots' source.

PX4's Hold (FlightTaskAuto::activate) restarts its jerk-limited PositionSmoothing from the last trajectory
setpoint's position, velocity and acceleration; ArduPilot's Brake (AC_PosControl::init_xy_controller) from
the current position, velocity and the acceleration of the current lean angles. Both then stop along the
time-optimal jerk-limited profile from that acceleration, whose distance is `braking_distance_from`."""

import math

import numpy as np
import pytest

from contracts.stop import (approach_stop_speed, approach_stopping_distance, braking_distance, braking_distance_from,
                            ramp_accel, stopping_distance, stopping_distance_from)
from sitl_harness.scenario import Scenario
from sitl_harness.sim import Sim
from sitl_harness.trajectory import AutoTrajectory


def simulate_stop_from(v0, a0, a_max, j_max, dt=1e-5):
    """Independent fine time-step simulation of the time-optimal stop from (v0, a0) (a = dv/dt, a0 > 0 speeding
    up): the acceleration falls at j_max to at most −a_max, and rises back at j_max to reach 0 as v reaches 0."""
    x, v, a = 0.0, v0, a0
    while v > 0.0 or a > 0.0:
        if a < 0.0 and v <= a * a / (2.0 * j_max):  # a ramp back to 0 from here removes the speed left
            a = min(a + j_max * dt, 0.0)
            if a == 0.0:
                break
        else:
            a = max(a - j_max * dt, -a_max)
        v_new = v + a * dt
        x += 0.5 * (v + max(v_new, 0.0)) * dt
        v = v_new
    return x


@pytest.mark.parametrize("v0", [0.5, 2.0, 5.0])
@pytest.mark.parametrize("a0", [0.0, 1.0, 3.0, 6.0])
def test_closed_form_from_an_acceleration_matches_a_fine_simulation(v0, a0):
    a, j = 3.0, 4.0
    assert braking_distance_from(v0, a0, a, j) == pytest.approx(simulate_stop_from(v0, a0, a, j), rel=2e-3, abs=2e-4)


def test_zero_or_braking_acceleration_is_the_plain_stop_and_acceleration_lengthens_it():
    a, j, t_r = 3.0, 4.0, 0.25
    assert stopping_distance_from(4.0, 0.0, a, j, t_r) == pytest.approx(stopping_distance(4.0, a, j, t_r))
    assert braking_distance_from(4.0, -2.0, a, j) == pytest.approx(braking_distance(4.0, a, j))
    assert simulate_stop_from(4.0, -2.0, a, j) < braking_distance(4.0, a, j)  # taking it as 0 is conservative
    d = [stopping_distance_from(4.0, a0, a, j, t_r) for a0 in (0.0, 1.0, 2.0, 4.0)]
    assert all(x < y for x, y in zip(d, d[1:]))


@pytest.mark.parametrize("v0,a0", [(3.0, 0.0), (3.0, 2.0), (4.0, 5.0), (1.0, 3.0)])
def test_the_sitl_auto_modes_reference_stops_as_the_closed_form(v0, a0):
    """The SITL's Hold reference (sitl_harness/trajectory.py), reset to (v0, a0), brakes to rest in the stop
    contract's distance from (v0, a0)."""
    tj = AutoTrajectory(3.0, 4.0)
    tj.reset((0, 0, -2), (v0, 0, 0), (a0, 0, 0))
    for _ in range(2000):
        tj.step(0.005, None, 10.0, 3.0, 1.5)
    assert tj.speed_xy == 0.0
    # the SITL's tracking law (√(2·j·|e|) toward the target speed) is near time-optimal: up to 8 % longer
    assert braking_distance_from(v0, a0, 3.0, 4.0) - 0.02 <= tj.p[0] <= 1.08 * braking_distance_from(v0, a0, 3.0, 4.0)
    assert tj.p[0] > braking_distance(v0, 3.0, 4.0) - 0.02


def _accelerating_then_hold(personality: str, a_cmd=2.0, v_hold=3.0):
    """SITL vehicle airborne in offboard, flying a streamed setpoint accelerating at `a_cmd` along x; Hold is
    asked (as over MAVLink) once the setpoint's speed passes `v_hold`. Returns (sim, last setpoint, state at the
    switch, the distance the vehicle then travels to rest)."""
    sim = Sim(Scenario.model_validate({"start": {"alt_m": 2.0}, "wind": {"mean_m_s": 0, "gust_m_s": 0}}),
              personality)
    ap, m = sim.autopilot, sim.model
    p0 = m.pos.copy()
    t, v = 0.0, 0.0
    x = 0.0
    while True:  # 1 s streaming the hover setpoint (PX4 enters OFFBOARD only then), 1 s in it, then accelerating
        if 1.0 <= t < 1.02:
            assert ap.request_custom_mode(ap.pers.default_custom("offboard")) == 0
        a = a_cmd if t > 2.0 else 0.0
        sp = (np.array([p0[0] + x, p0[1], p0[2]]), np.array([v, 0.0, 0.0]), np.array([a, 0.0, 0.0]))
        ap.handle_position_target(1, 0, sp[0], sp[1], sp[2], 0.0, math.nan)
        sim.step(0.02)
        if v >= v_hold:
            break
        x += v * 0.02 + 0.5 * a * 0.0004
        v += a * 0.02
        t += 0.02
    state = (m.pos.copy(), m.vel.copy(), ap.model.s.copy())
    assert ap.request_custom_mode(ap.pers.default_custom("hold")) == 0
    start = (ap.traj.p.copy(), ap.traj.v.copy(), ap.traj.a.copy())
    path, last = 0.0, m.pos.copy()
    for _ in range(600):
        sim.step(0.02)
        path += float(np.hypot(*(m.pos - last)[:2]))
        last = m.pos.copy()
    return sim, sp, state, start, path


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_hold_from_an_accelerating_state_starts_where_the_source_says_and_stops_within_the_contract(personality):
    sim, sp, (pos, vel, _), (p_s, v_s, a_s), path = _accelerating_then_hold(personality)
    if personality == "px4":  # FlightTaskAuto::activate: the last trajectory setpoint
        assert np.allclose(p_s, sp[0]) and np.allclose(v_s, sp[1]) and np.allclose(a_s, sp[2])
    else:  # AC_PosControl::init_xy_controller: the current position, velocity, lean-angle acceleration
        assert np.allclose(p_s, pos) and np.allclose(v_s, vel)
        assert a_s[0] > 1.0  # it was accelerating: the Brake starts from there
    assert float(np.hypot(*sim.model.vel[:2])) < 0.05  # at rest
    s = sim.autopilot.settings
    v0, a0 = float(v_s[0]), float(a_s[0])
    # the reference's stop from the state it starts from, plus the vehicle's lag (its E_tr floor, 0.3 m)
    assert path <= 1.08 * braking_distance_from(v0, a0, s.acc_hor, s.jerk) + 0.3 + abs(float(p_s[0] - pos[0]))
    assert path > braking_distance(v0, s.acc_hor, s.jerk)  # longer than a stop from zero acceleration


def _holds_along_the_approach(v_lim, a, j, t_r, seconds, command, dt=0.005):
    """The autopilot speeding up along its jerk-limited law (the SITL's reference: PX4's and ArduPilot's velocity
    smoothing) toward `command(speed)` (asked every 50 ms); a Hold every 50 ms of it, after the dead time t_r flown
    on the approach. (the longest stop, the peak acceleration, the speed reached)."""
    tj = AutoTrajectory(a, j)
    tj.reset((0, 0, -2), (0, 0, 0))
    worst, a_peak, cmd = 0.0, 0.0, 0.0
    for k in range(int(seconds / dt)):
        if k % 10 == 0:
            cmd = command(tj.speed_xy)
        tj.step(dt, (1e4, 0, -2), cmd, 3.0, 1.5)
        a_peak = max(a_peak, float(tj.a[0]))
        if k % 10:
            continue
        probe = AutoTrajectory(a, j)
        probe.reset(tj.p, tj.v, tj.a)
        for _ in range(int(t_r / dt)):
            probe.step(dt, (1e4, 0, -2), cmd, 3.0, 1.5)
        for _ in range(2000):
            probe.step(dt, None, v_lim, 3.0, 1.5)
            if not probe.v[0] and not probe.a[0]:  # at rest (the reference settles exactly)
                break
        worst = max(worst, float(probe.p[0] - tj.p[0]))
    return worst, a_peak, tj.speed_xy


@pytest.mark.parametrize("v_lim", [1.0, 3.0, 6.0])
def test_every_state_of_the_approach_to_the_limit_stops_within_the_approach_distance(v_lim):
    """The autopilot speeding up to v_lim; a Hold at any moment of it stops within approach_stopping_distance(v_lim)
    (dead time 0.25 s flown on the approach, then the stop from that state)."""
    a, j, t_r = 3.0, 4.0, 0.25
    worst, _, _ = _holds_along_the_approach(v_lim, a, j, t_r, 6.0, lambda v: v_lim)
    # the SITL's law is up to 8 % longer than the time-optimal stop (see above)
    assert worst <= 1.08 * approach_stopping_distance(v_lim, a, j, t_r)
    assert worst > 1.02 * stopping_distance(v_lim, a, j, t_r)  # the plain stop contract does not hold here


@pytest.mark.parametrize("v_lim", [3.0, 6.0])
def test_a_ramped_approach_keeps_its_acceleration_and_stops_within_the_shaped_distance(v_lim):
    """The governor's approach ramp: every 50 ms the speed command is raised to at most `gap` above the speed flown.
    The acceleration stays ≤ ramp_accel(j, gap), and a Hold at any moment stops within the joint bound with the
    Hold-start acceleration capped there — shorter than the bound for any approach (what the ramp buys), longer
    than the plain stop."""
    a, j, t_r, gap = 3.0, 4.0, 0.25, 0.35
    cap = ramp_accel(j, gap)
    worst, a_peak, reached = _holds_along_the_approach(v_lim, a, j, t_r, 8.0, lambda v: min(v_lim, v + gap))
    assert reached == pytest.approx(v_lim, abs=0.01)  # it got there
    assert a_peak <= cap + 1e-6
    shaped = approach_stopping_distance(v_lim, a, j, t_r, a0_max=cap)
    assert worst <= 1.08 * shaped
    assert shaped < approach_stopping_distance(v_lim, a, j, t_r) - 0.1
    assert worst > stopping_distance(v_lim, a, j, t_r)


@pytest.mark.parametrize("d", [0.5, 2.0, 6.0, 15.0])
@pytest.mark.parametrize("a0_max", [0.5, 1.5, 2.9])
def test_the_capped_speed_is_the_largest_within_the_capped_distance(d, a0_max):
    a, j, t_r = 3.0, 4.0, 0.2
    v = approach_stop_speed(d, a, j, t_r, a0_max)
    assert approach_stopping_distance(v, a, j, t_r, a0_max) <= d
    assert approach_stopping_distance(v * 1.001 + 1e-6, a, j, t_r, a0_max) > d
    assert v >= approach_stop_speed(d, a, j, t_r)  # a cap never lowers the speed …
    assert approach_stop_speed(d, a, j, t_r, a0_max=a) == approach_stop_speed(d, a, j, t_r)  # … nor does one at a
