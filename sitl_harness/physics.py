"""Rigid-body quadrotor plant: 6-DOF, quaternion attitude, ω² rotors, motor lag, drag, ground.

Pure maths on flat float64 arrays (numba-compiled when available), no I/O. Frames as MAVLink:
world NED (z down), body FRD. Quaternion q = (w, x, y, z) rotates body → NED.

State `x` (17): p[0:3] (m), v[3:6] (m/s), q[6:10], ω[10:13] body rates (rad/s), Ω[13:17] rotor
speeds (rad/s). Parameters `prm` (see `P_*`), environment `env` (thrust_ratio and wind, `E_*`).

Model (the paper's "UAV simulation model", Figure 8's plant):
- rotor i: thrust f_i = thrust_ratio · k_thrust · Ω_i², drag torque spin_i · k_torque · Ω_i² about
  +z_body (spin +1 = CCW seen from above, whose reaction torque yaws the body clockwise = +yaw);
- motor: Ω̇_i = (clip(Ω_cmd,i, 0, Ω_max) − Ω_i) / τ_m  (first-order lag, speed saturation);
- X layout, rotor i at body (d·RX[i], d·RY[i]) with d = arm/√2: 0 front-right, 1 back-right,
  2 back-left, 3 front-left;
- m·v̇ = m·g·e_z + R(q)·(0, 0, −Σf_i) − c·|v − w|·(v − w)  (w: wind velocity, quadratic drag);
- I·ω̇ = τ − ω × I·ω;  q̇ = ½ q ⊗ (0, ω);
- ground at z = 0: a vehicle touching it and not climbing rests there (level, at rest).
Integrated by classic RK4 at a fixed step (≥ 500 Hz, 1 kHz by default).
"""

from __future__ import annotations

import math

import numpy as np

from contracts.jit import njit

# state layout
X_P, X_V, X_Q, X_W, X_R, X_N = 0, 3, 6, 10, 13, 17
# parameter layout
P_MASS, P_IXX, P_IYY, P_IZZ, P_KT, P_KQ, P_D, P_TAU, P_WMAX, P_DRAG, P_G = range(11)
P_SPIN = 11  # 11..14
P_N = 15
# environment layout
E_TR, E_WIND, E_N = 0, 1, 4

RX = (1.0, -1.0, -1.0, 1.0)  # rotor x signs (forward)
RY = (1.0, 1.0, -1.0, -1.0)  # rotor y signs (right)


def plant_params(vehicle, g: float) -> np.ndarray:
    """Pack a `contracts.vehicle.Vehicle` into the plant parameter array."""
    r = vehicle.rotor
    prm = np.zeros(P_N)
    prm[P_MASS] = vehicle.mass_kg
    prm[P_IXX], prm[P_IYY], prm[P_IZZ] = vehicle.inertia_kg_m2
    prm[P_KT] = r.k_thrust
    prm[P_KQ] = r.k_torque
    prm[P_D] = r.arm_m / math.sqrt(2.0)
    prm[P_TAU] = r.motor_tau_s
    prm[P_WMAX] = r.omega_max_rad_s
    prm[P_DRAG] = vehicle.drag_coeff_n_s2_m2
    prm[P_G] = g
    prm[P_SPIN : P_SPIN + 4] = r.spin
    return prm


@njit
def rotor_forces(x, prm, env, out4):
    """Per-rotor thrust f_i [N] into `out4`; returns (T, τx, τy, τz) in body FRD."""
    kt = env[E_TR] * prm[P_KT]
    d = prm[P_D]
    t = 0.0
    tx = 0.0
    ty = 0.0
    tz = 0.0
    for i in range(4):
        om = x[X_R + i]
        if om < 0.0:
            om = 0.0
        w2 = om * om
        f = kt * w2
        out4[i] = f
        t += f
        # r × (0, 0, −f) with r = (d·RX, d·RY, 0) = (−d·RY·f, d·RX·f, 0)
        tx -= d * RY[i] * f
        ty += d * RX[i] * f
        tz += prm[P_SPIN + i] * prm[P_KQ] * w2
    return t, tx, ty, tz


@njit
def deriv(x, wcmd, prm, env, f4, out):
    """ẋ of the plant for rotor-speed commands `wcmd` (4,) into `out` (17,)."""
    t, tx, ty, tz = rotor_forces(x, prm, env, f4)
    qw = x[X_Q]
    qx = x[X_Q + 1]
    qy = x[X_Q + 2]
    qz = x[X_Q + 3]
    # third column of R(q): body z axis in NED
    r02 = 2.0 * (qx * qz + qw * qy)
    r12 = 2.0 * (qy * qz - qw * qx)
    r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
    m = prm[P_MASS]
    vx = x[X_V]
    vy = x[X_V + 1]
    vz = x[X_V + 2]
    rx = vx - env[E_WIND]
    ry = vy - env[E_WIND + 1]
    rz = vz - env[E_WIND + 2]
    c = prm[P_DRAG] * math.sqrt(rx * rx + ry * ry + rz * rz)
    out[0] = vx
    out[1] = vy
    out[2] = vz
    out[3] = (-r02 * t - c * rx) / m
    out[4] = (-r12 * t - c * ry) / m
    out[5] = (-r22 * t - c * rz) / m + prm[P_G]
    wx = x[X_W]
    wy = x[X_W + 1]
    wz = x[X_W + 2]
    out[6] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    out[7] = 0.5 * (qw * wx + qy * wz - qz * wy)
    out[8] = 0.5 * (qw * wy - qx * wz + qz * wx)
    out[9] = 0.5 * (qw * wz + qx * wy - qy * wx)
    ixx = prm[P_IXX]
    iyy = prm[P_IYY]
    izz = prm[P_IZZ]
    out[10] = (tx - (izz - iyy) * wy * wz) / ixx
    out[11] = (ty - (ixx - izz) * wz * wx) / iyy
    out[12] = (tz - (iyy - ixx) * wx * wy) / izz
    wmax = prm[P_WMAX]
    for i in range(4):
        cmd = wcmd[i]
        if cmd < 0.0 or cmd != cmd:
            cmd = 0.0
        elif cmd > wmax:
            cmd = wmax
        out[13 + i] = (cmd - x[X_R + i]) / prm[P_TAU]


@njit
def ground_contact(x):
    """Rest on the ground (z = 0, NED) when touching it and not climbing; returns True if resting."""
    if x[X_P + 2] >= 0.0 and x[X_V + 2] >= 0.0:
        x[X_P + 2] = 0.0
        for i in range(3):
            x[X_V + i] = 0.0
            x[X_W + i] = 0.0
        qw = x[X_Q]
        qx = x[X_Q + 1]
        qy = x[X_Q + 2]
        qz = x[X_Q + 3]
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        x[X_Q] = math.cos(0.5 * yaw)
        x[X_Q + 1] = 0.0
        x[X_Q + 2] = 0.0
        x[X_Q + 3] = math.sin(0.5 * yaw)
        return True
    return False


@njit
def rk4_step(x, wcmd, prm, env, dt, k1, k2, k3, k4, tmp, f4):
    """One classic RK4 step of length `dt` in place, quaternion renormalised, ground applied."""
    n = x.shape[0]
    deriv(x, wcmd, prm, env, f4, k1)
    for i in range(n):
        tmp[i] = x[i] + 0.5 * dt * k1[i]
    deriv(tmp, wcmd, prm, env, f4, k2)
    for i in range(n):
        tmp[i] = x[i] + 0.5 * dt * k2[i]
    deriv(tmp, wcmd, prm, env, f4, k3)
    for i in range(n):
        tmp[i] = x[i] + dt * k3[i]
    deriv(tmp, wcmd, prm, env, f4, k4)
    for i in range(n):
        x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    qn = math.sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9])
    for i in range(4):
        x[X_Q + i] /= qn
    return ground_contact(x)


def initial_state(yaw: float = 0.0, pos=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Level, at rest, rotors stopped."""
    x = np.zeros(X_N)
    x[X_P : X_P + 3] = pos
    x[X_Q] = math.cos(0.5 * yaw)
    x[X_Q + 3] = math.sin(0.5 * yaw)
    return x


def euler_from_quat(q) -> tuple[float, float, float]:
    """(roll φ, pitch θ, yaw ψ) [rad], ZYX convention, from q = (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array([
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ])
