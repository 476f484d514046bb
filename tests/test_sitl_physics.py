"""Plant and sensor against closed forms (issue 3, "Physics against closed forms")."""

import math

import numpy as np
import pytest

from contracts.vehicle import G, load_vehicle
from sitl_harness.control import M_OFF, M_POS, S_THR, S_WCMD, SP_ACC, SP_HTE, SP_MODE, SP_POS, SP_YAW
from sitl_harness.kernel import VehicleModel
from sitl_harness.physics import E_N, E_TR, X_N, X_Q, X_R, deriv, euler_from_quat, initial_state, plant_params, quat_from_euler
from sitl_harness.sensors import RangeSensor, RangeSensorConfig
from sitl_harness.world import Box, Column, CollisionMonitor, World


@pytest.fixture(scope="module")
def mambo():
    return load_vehicle("mambo")


def still(vehicle, **upd):
    """The vehicle without drag (closed forms assume none)."""
    return vehicle.model_copy(update={"drag_coeff_n_s2_m2": 0.0, **upd})


def xdot(vehicle, x, wcmd=None, thrust_ratio=1.0):
    prm = plant_params(vehicle, G)
    env = np.zeros(E_N)
    env[E_TR] = thrust_ratio
    out = np.zeros(X_N)
    deriv(x, np.array(wcmd if wcmd is not None else x[X_R:X_R + 4], float), prm, env, np.zeros(4), out)
    return out


def test_plant_hover_rotor_speed_balances_weight(mambo):
    """All rotors at ω with 4·k·ω² = m·g: zero acceleration (to round-off)."""
    x = initial_state(pos=(0, 0, -5))
    x[X_R:X_R + 4] = math.sqrt(mambo.mass_kg * G / (4 * mambo.rotor.k_thrust))
    a = xdot(mambo, x)
    assert abs(a[5]) < 1e-9 and abs(a[3]) < 1e-12 and abs(a[12]) < 1e-9


@pytest.mark.parametrize("thrust_ratio", [1.0, 0.8, 0.6])
def test_closed_loop_hover_throttle_is_weight_over_max_thrust(mambo, thrust_ratio):
    """Hovering, the collective (VFR_HUD throttle, of T_nom) settles at m·g / (thrust_ratio · T_nom)."""
    m = VehicleModel(still(mambo), yaw=0.3)
    m.thrust_ratio = thrust_ratio
    m.x[2] = -3.0
    m.x[X_R:X_R + 4] = mambo.rotor.omega_max_rad_s * 0.7
    m.sp[SP_MODE] = M_POS
    m.sp[SP_POS:SP_POS + 3] = (0, 0, -3)
    m.sp[SP_YAW] = 0.3
    m.sp[SP_HTE] = 1.0
    m.step(15000)
    expected = mambo.mass_kg * G / (thrust_ratio * mambo.t_nom_n)
    assert m.s[S_THR] == pytest.approx(expected, rel=0.005)
    assert m.hover_thrust == pytest.approx(expected, rel=0.02)  # hover-thrust estimate adapted
    assert np.linalg.norm(m.pos - (0, 0, -3)) < 0.05


def test_plant_level_tilt_gives_g_tan_theta(mambo):
    """Exactly: tilt θ with vertical thrust component = weight → horizontal acceleration g·tanθ."""
    for theta in (0.1, 0.35, 0.6):
        x = initial_state(pos=(0, 0, -5))
        x[X_Q:X_Q + 4] = quat_from_euler(0.0, -theta, 0.0)  # nose down: accelerate +x
        t = mambo.mass_kg * G / math.cos(theta)
        x[X_R:X_R + 4] = math.sqrt(t / (4 * mambo.rotor.k_thrust))
        a = xdot(mambo, x)
        assert a[3] == pytest.approx(G * math.tan(theta), rel=1e-9)
        assert abs(a[5]) < 1e-9


def test_held_total_tilt_gives_g_tan_theta_within_2_percent(mambo):
    """Closed loop: acceleration-only x setpoint, altitude held; measured a_x vs g·tan(measured tilt)."""
    v = still(mambo, wind={"mean_m_s": 0.0, "gust_m_s": 0.0})
    m = VehicleModel(v)
    m.x[2] = -10.0
    m.x[X_R:X_R + 4] = math.sqrt(v.mass_kg * G / (4 * v.rotor.k_thrust))
    theta_cmd = math.radians(20.0)
    m.sp[SP_MODE] = M_POS
    m.sp[SP_POS:SP_POS + 3] = (math.nan, 0.0, -10.0)
    m.sp[SP_ACC] = G * math.tan(theta_cmd)
    m.sp[SP_YAW] = 0.0
    m.sp[SP_HTE] = 1.0
    m.step(1500)
    v0, tilts = m.vel[0], []
    for _ in range(100):
        m.step(10)
        r, p, _ = euler_from_quat(m.quat)
        tilts.append(math.acos(math.cos(r) * math.cos(p)))
    a_meas = (m.vel[0] - v0) / 1.0
    tilt = float(np.mean(tilts))
    assert a_meas == pytest.approx(G * math.tan(tilt), rel=0.02)
    assert a_meas == pytest.approx(G * math.tan(theta_cmd), rel=0.02)
    assert abs(m.pos[2] + 10.0) < 0.05


def test_free_fall(mambo):
    m = VehicleModel(still(mambo))
    m.x[2] = -100.0
    m.sp[SP_MODE] = M_OFF
    m.step(2000)  # 2 s
    assert m.pos[2] == pytest.approx(-100.0 + 0.5 * G * 4.0, abs=1e-6)
    assert m.vel[2] == pytest.approx(2.0 * G, abs=1e-9)


def test_ground_contact_holds_a_resting_vehicle(mambo):
    m = VehicleModel(still(mambo))
    m.sp[SP_MODE] = M_OFF
    m.step(500)
    assert m.resting and m.pos[2] == 0.0 and np.allclose(m.vel, 0.0)


def test_yaw_torque_sign(mambo):
    """Rotors with spin +1 (CCW from above) faster: the body yaws clockwise from above (+ψ in NED)."""
    x = initial_state(pos=(0, 0, -5))
    w0 = 1500.0
    w = np.array([w0 + 100, w0, w0 + 100, w0])  # rotors 0 and 2: spin +1
    x[X_R:X_R + 4] = w
    a = xdot(mambo, x)
    expected = mambo.rotor.k_torque * (2 * (w0 + 100) ** 2 - 2 * w0 ** 2) / mambo.inertia_kg_m2[2]
    assert a[12] == pytest.approx(expected, rel=1e-9) and a[12] > 0
    assert abs(a[10]) < 1e-6 and abs(a[11]) < 1e-6  # diagonal pairs: no roll/pitch torque
    # and integrated: ψ grows
    m = VehicleModel(still(mambo))
    m.x[:] = x
    m.sp[SP_MODE] = M_OFF
    # hold commands by giving the motors a long lag and no time to spin down noticeably
    m.step(50)
    assert euler_from_quat(m.quat)[2] > 0.0


def test_motor_lag_time_constant(mambo):
    """First-order lag: after τ the rotor has covered 1 − e⁻¹ of a command step."""
    v = still(mambo)
    tau = v.rotor.motor_tau_s
    x = initial_state(pos=(0, 0, -50))
    x[X_R:X_R + 4] = 1000.0
    m = VehicleModel(v)
    m.x[:] = x
    cmd = 2000.0
    from sitl_harness.physics import rk4_step
    prm, env = m.prm, m.env
    n = round(tau / m.dt)
    sc = np.zeros((6, X_N))
    for _ in range(n):
        rk4_step(m.x, np.full(4, cmd), prm, env, m.dt, sc[0], sc[1], sc[2], sc[3], sc[4], sc[5])
    frac = (m.x[X_R] - 1000.0) / (cmd - 1000.0)
    assert frac == pytest.approx(1 - math.exp(-n * m.dt / tau), rel=1e-6)
    assert frac == pytest.approx(1 - math.exp(-1), rel=0.01)



def test_actuator_delay_shifts_the_rotor_commands_by_its_steps(mambo):
    """The command FIFO: with a delay of N physics steps the rotors see the controller's commands exactly N
    steps late (the same rotor history, shifted); with no delay the direct path; a bad delay is refused."""
    def rotor_history(delay_s, n=400):
        m = VehicleModel(still(mambo), actuator_delay_s=delay_s)
        m.x[2] = -5.0
        m.x[X_R:X_R + 4] = 1000.0
        m.fifo[:] = 1000.0
        m.sp[SP_MODE] = M_POS
        m.sp[SP_POS:SP_POS + 3] = (0.0, 0.0, -6.0)  # a climb step: the commands change at once
        m.sp[SP_YAW] = 0.0
        cmds, rot = [], []
        for _ in range(n):
            m.step(1)
            cmds.append(m.s[S_WCMD:S_WCMD + 4].copy())
            rot.append(m.x[X_R])
        return m, np.array(cmds), np.array(rot)

    m0, c0, r0 = rotor_history(0.0)
    m6, c6, r6 = rotor_history(0.06)
    assert m0.delay_steps == 0 and m6.delay_steps == 60
    # the first 60 steps the motors still get the queued 1000 rad/s: the rotors do not move
    assert np.allclose(r6[:60], 1000.0) and not np.allclose(r0[:60], 1000.0)
    # the delayed aircraft's first step of change is the undelayed one's first, 60 steps on
    k0 = int(np.argmax(np.abs(r0 - 1000.0) > 1e-6))
    k6 = int(np.argmax(np.abs(r6 - 1000.0) > 1e-6))
    assert k6 - k0 == 60
    # the very commands that reach the motors: step k's command arrives at step k + 60
    assert np.array_equal(c6[0], c0[0])
    with pytest.raises(ValueError, match="actuator_delay_s"):
        VehicleModel(mambo, actuator_delay_s=float("nan"))
    # a scenario's `actuator_delay_s` reaches the model; the Sim keyword overrides it; an airborne start
    # queues the hover command (no drop while the FIFO fills)
    from sitl_harness.scenario import scenario_from_dict
    from sitl_harness.sim import Sim

    sim = Sim(scenario_from_dict({"vehicle": "mambo", "actuator_delay_s": 0.02, "start": {"alt_m": 3.0}}))
    assert sim.model.delay_steps == 20 and np.all(sim.model.fifo == sim.model.x[X_R])
    sim.step(1.0)
    assert abs(sim.model.pos[2] + 3.0) < 0.05
    assert Sim(scenario_from_dict({"vehicle": "mambo"}), actuator_delay_s=0.005).model.delay_steps == 5


def test_speed_saturation(mambo):
    x = initial_state(pos=(0, 0, -50))
    x[X_R:X_R + 4] = mambo.rotor.omega_max_rad_s
    a = xdot(mambo, x, wcmd=[1e5] * 4)  # commands beyond Ω_max are clipped
    assert np.allclose(a[13:17], 0.0)


@pytest.mark.parametrize("thrust_ratio", [1.0, 0.8, 0.6])
def test_max_climb_acceleration_under_degraded_thrust(mambo, thrust_ratio):
    """Open loop: all rotors at Ω_max → a_up = thrust_ratio·T_nom/m − g. Closed loop: the cascade's
    saturated climb reaches collective_max_fraction of it (MPC_THR_MAX), within 2 %."""
    x = initial_state(pos=(0, 0, -50))
    x[X_R:X_R + 4] = mambo.rotor.omega_max_rad_s
    a = xdot(mambo, x, thrust_ratio=thrust_ratio)
    t_rotors = 4 * mambo.rotor.k_thrust * mambo.rotor.omega_max_rad_s ** 2
    assert -a[5] == pytest.approx(thrust_ratio * t_rotors / mambo.mass_kg - G, rel=1e-9)
    m = VehicleModel(still(mambo))
    m.thrust_ratio = thrust_ratio
    m.x[2] = -5.0
    m.x[X_R:X_R + 4] = math.sqrt(mambo.mass_kg * G / (4 * thrust_ratio * mambo.rotor.k_thrust))
    m.sp[SP_MODE] = M_POS
    m.sp[SP_POS:SP_POS + 3] = (0.0, 0.0, math.nan)
    m.sp[SP_ACC + 2] = -50.0  # far more than available: thrust saturates
    m.sp[SP_YAW] = 0.0
    m.step(300)
    vz0 = m.vel[2]
    m.step(200)
    a_meas = -(m.vel[2] - vz0) / 0.2
    expected = mambo.collective_max_fraction * thrust_ratio * mambo.t_nom_n / mambo.mass_kg - G
    assert a_meas == pytest.approx(expected, rel=0.02)


# ----------------------------------------------------------------------------- world and sensor


def sensor(**kw):
    cfg = RangeSensorConfig(**{"fov_deg": 60, "increment_deg": 5, "max_range_m": 10, "noise_sd_m": 0.0, "noise_rel": 0.0, **kw})
    return RangeSensor(cfg, seed=3)


def test_ray_cast_columns_and_boxes():
    w = World([Column(10.0, 0.0, 1.0)], [Box(5.0, 3.0, 2.0, 2.0)])
    d = w.ray_cast(0, 0, 2, np.array([0.0, math.pi]), 50)
    assert d[0] == pytest.approx(9.0) and math.isinf(d[1])
    d = w.ray_cast(5.0, 0.0, 2, np.array([math.pi / 2]), 50)  # east toward the box face at y = 2
    assert d[0] == pytest.approx(2.0)
    rot = World([], [Box(5.0, 0.0, 2.0, 2.0, yaw=math.pi / 4)])
    assert rot.ray_cast(0, 0, 2, np.array([0.0]), 50)[0] == pytest.approx(5.0 - math.sqrt(2.0))
    tall = World([Column(10.0, 0.0, 1.0, height=1.5)])
    assert math.isinf(tall.ray_cast(0, 0, 2.0, np.array([0.0]), 50)[0])  # flying above it
    assert tall.ray_cast(0, 0, 1.0, np.array([0.0]), 50)[0] == pytest.approx(9.0)


def test_sensor_reports_column_and_box_ranges():
    s = sensor()
    r = s.read(World([Column(8.0, 0.0, 0.5)]), np.array([0, 0, -2.0]), 0.0)
    assert r.current_cm == 750 and r.max_cm == 1000 and r.signal_quality == 100
    assert r.distances_cm[s.n_used:] == [65535] * (72 - s.n_used)
    assert r.angle_offset_deg == pytest.approx(-27.5) and r.increment_deg == pytest.approx(5.0)
    # box seen obliquely: the nearest bin holds the true nearest surface point within the field of view
    r = s.read(World([], [Box(6.0, 0.0, 2.0, 4.0)]), np.array([0, 0, -2.0]), 0.0)
    assert r.current_cm == 500
    # nothing in view: every used bin says max + 1
    r = s.read(World([Column(0.0, 8.0, 0.5)]), np.array([0, 0, -2.0]), 0.0)
    assert set(r.distances_cm[: s.n_used]) == {1001} and r.current_cm == 1001
    # heading matters: facing east it is seen
    r = s.read(World([Column(0.0, 8.0, 0.5)]), np.array([0, 0, -2.0]), math.pi / 2)
    assert r.current_cm == 750


def test_sensor_fog_honest_and_hidden():
    world = World([Column(8.0, 0.0, 0.5), Column(3.5, 2.0, 0.3)])
    pos = np.array([0, 0, -2.0])
    s = sensor()
    s.visibility_m = 5.0
    s.honest = True
    r = s.read(world, pos, 0.0)
    assert r.max_cm == 500 and r.signal_quality == 50
    far = [d for d in r.distances_cm[: s.n_used] if d != 501]
    assert min(far) < 500  # the near column (≈3.7 m) is still seen
    assert 750 not in r.distances_cm  # the far column (7.5 m) is beyond the fog
    s.honest = False
    r = s.read(world, pos, 0.0)
    assert r.max_cm == 1000  # hidden: advertises its full range
    assert 2 <= r.signal_quality < 100  # but the return it reports is weak (the lidar equation through fog)
    assert 1001 in r.distances_cm and all(d < 500 or d == 1001 for d in r.distances_cm[: s.n_used])


def test_sensor_noise_is_seeded():
    world = World([Column(8.0, 0.0, 0.5)])
    a = RangeSensor(RangeSensorConfig(noise_sd_m=0.05, noise_rel=0.0), seed=1).read(world, np.zeros(3), 0.0).distances_cm
    b = RangeSensor(RangeSensorConfig(noise_sd_m=0.05, noise_rel=0.0), seed=1).read(world, np.zeros(3), 0.0).distances_cm
    c = RangeSensor(RangeSensorConfig(noise_sd_m=0.05, noise_rel=0.0), seed=2).read(world, np.zeros(3), 0.0).distances_cm
    assert a == b and a != c


def test_collision_monitor_swept_and_near_miss():
    w = World([Column(5.0, 0.0, 0.5, name="c")])
    mon = CollisionMonitor(w, r_body=0.1)
    # one big step straight through the column is still caught (swept check)
    mon.update(0.0, np.array([0.0, 0.0, -2.0]))
    hit = mon.update(0.1, np.array([10.0, 0.0, -2.0]))
    assert hit is not None and hit.obstacle_name == "c" and 4.3 < hit.position[0] < 4.5
    assert len(mon.collisions) == 1
    miss = CollisionMonitor(w, r_body=0.1)
    for x in np.linspace(0, 10, 200):
        miss.update(x, np.array([x, 0.65, -2.0]))  # clearance 0.15 − 0.1 = 0.05 m
    assert not miss.collisions and miss.min_clearance == pytest.approx(0.05, abs=1e-3)


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

coord = st.floats(-20, 20)


@settings(max_examples=150, deadline=None)
@given(cx=coord, cy=coord, length=st.floats(0.2, 6), width=st.floats(0.2, 6), yaw=st.floats(-3.2, 3.2),
       ox=coord, oy=coord, ang=st.floats(-3.2, 3.2), column=st.booleans())
def test_ray_cast_hits_the_surface_first(cx, cy, length, width, yaw, ox, oy, ang, column):
    """Property: the returned range lands on the surface (clearance 0) and no earlier point along
    the ray is inside; an infinite range means no sampled point of the ray is inside."""
    w = World([Column(cx, cy, 0.5 * width)]) if column else World([], [Box(cx, cy, length, width, yaw)])
    if w.clearance(ox, oy, 0.0)[0] <= 1e-6:
        return  # origin inside or on the surface
    d = float(w.ray_cast(ox, oy, 0.0, np.array([ang]), 100.0)[0])
    ux, uy = math.cos(ang), math.sin(ang)
    stop = d if math.isfinite(d) else 100.0
    for s in np.linspace(0.0, stop, 400)[:-1]:
        assert w.clearance(ox + s * ux, oy + s * uy, 0.0)[0] > -1e-9
    if math.isfinite(d):
        assert abs(w.clearance(ox + d * ux, oy + d * uy, 0.0)[0]) < 1e-6
