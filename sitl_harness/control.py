"""PX4-like multicopter cascade (the paper's Figure 8 with PX4's structure), pure maths.

position P → velocity PID (+ velocity feed-forward) → acceleration (+ feed-forward) → thrust vector
(total-tilt limit, PX4's thrust priority) → attitude (quaternion P, thrust axis first, reduced yaw)
→ body-rate PID → mixer (roll/pitch over collective over yaw) → rotor-speed commands.

Written after PX4's `PositionControl`, `AttitudeControl` and `RateControl` (mc_pos_control,
mc_att_control, mc_rate_control; see shared/reference/vehicle-and-controller-facts.md); own code.
Gains are scale-free (accelerations per error), so one set flies the 63 g Mambo and a 2 kg X500:
torque = I · angular-acceleration, collective thrust normalised by the *nominal* maximum thrust
`t_nom_n` (the controller does not know `thrust_ratio`; the hover-thrust estimate adapts to it).

Setpoints `sp` follow PX4's trajectory_setpoint: any of position / velocity / acceleration per axis,
NaN = not controlled on that axis. Velocity and acceleration are feed-forward when a position is
given; an axis with neither position nor velocity but an acceleration is acceleration-controlled;
an axis with nothing is velocity-controlled to zero.
"""

from __future__ import annotations

import math

import numpy as np

from contracts.jit import njit
from .physics import P_D, P_G, P_IXX, P_IYY, P_IZZ, P_KQ, P_KT, P_SPIN, P_WMAX, RX, RY, X_Q, X_V, X_W

# controller parameters
(C_POS_P, C_ZPOS_P, C_VEL_P, C_VEL_I, C_VEL_D, C_ZVEL_P, C_ZVEL_I, C_ATT_P, C_YAW_P, C_RATE_P,
 C_RATE_I, C_RATE_D, C_THR_MAX, C_THR_MIN, C_THR_XY_MARG, C_TILT_MAX, C_TILT_RATE_MAX,
 C_YAW_RATE_MAX, C_VEL_XY_MAX, C_VEL_UP_MAX, C_VEL_DN_MAX, C_HTE_TAU, C_T_NOM, C_YAW_MOM_MAX,
 C_DT, C_IDLE) = range(26)
C_N = 26
# setpoint layout
SP_POS, SP_VEL, SP_ACC, SP_YAW, SP_YAWRATE, SP_MODE, SP_THRUST, SP_Q, SP_HTE = 0, 3, 6, 9, 10, 11, 12, 13, 17
SP_N = 18
# modes
M_OFF, M_IDLE, M_POS, M_ATT = 0, 1, 2, 3
# controller state layout
(S_VINT, S_RINT, S_HOVER, S_VPREV, S_ACCF, S_WCMD, S_THR, S_THRV, S_QSP, S_RSP, S_YAWHOLD, S_CNT,
 S_WPREV, S_SAT, S_VSP, S_ACCSP) = (0, 3, 6, 7, 10, 13, 17, 18, 21, 25, 28, 29, 30, 33, 34, 37)
S_N = 40

ACC_FILTER_HZ = 15.0  # low-pass of the velocity derivative (D term, hover-thrust estimator)


def empty_setpoint() -> np.ndarray:
    sp = np.full(SP_N, np.nan)
    sp[SP_MODE] = M_OFF
    sp[SP_THRUST] = 0.0
    sp[SP_Q : SP_Q + 4] = (1.0, 0.0, 0.0, 0.0)
    sp[SP_HTE] = 0.0
    return sp


# ----------------------------------------------------------------------------- quaternion helpers


@njit
def qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@njit
def dcm_z(q0, q1, q2, q3):
    """Body z axis expressed in NED (third column of R(q))."""
    return (2.0 * (q1 * q3 + q0 * q2), 2.0 * (q2 * q3 - q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2))


@njit
def quat_between(ax, ay, az, bx, by, bz):
    """Shortest rotation taking unit vector a to unit vector b."""
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    d = ax * bx + ay * by + az * bz
    if cx * cx + cy * cy + cz * cz < 1e-12 and d < 0.0:
        # opposite: rotate π about any axis orthogonal to a
        if abs(ax) < abs(ay):
            if abs(ax) < abs(az):
                ox, oy, oz = 0.0, az, -ay
            else:
                ox, oy, oz = ay, -ax, 0.0
        elif abs(ay) < abs(az):
            ox, oy, oz = -az, 0.0, ax
        else:
            ox, oy, oz = ay, -ax, 0.0
        n = math.sqrt(ox * ox + oy * oy + oz * oz)
        return 0.0, ox / n, oy / n, oz / n
    w = d + 1.0
    n = math.sqrt(w * w + cx * cx + cy * cy + cz * cz)
    return w / n, cx / n, cy / n, cz / n


@njit
def quat_from_dcm(r00, r01, r02, r10, r11, r12, r20, r21, r22):
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        return 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    if r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        return (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    if r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        return (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
    return (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s


@njit
def attitude_from_thrust(tx, ty, tz, yaw):
    """PX4 bodyzToAttitude: body z opposite the thrust vector (tx, ty, tz) NED, heading `yaw`.
    For a thrust vector from accelerations this is the attitude of the paper's eq. (8) (checked
    against `contracts.flat.inputs_from_flat` in the tests)."""
    n = math.sqrt(tx * tx + ty * ty + tz * tz)
    if n < 1e-9:
        zx, zy, zz = 0.0, 0.0, 1.0
    else:
        zx, zy, zz = -tx / n, -ty / n, -tz / n
    yx, yy = -math.sin(yaw), math.cos(yaw)  # y axis of the intermediate (yaw-only) frame
    # body x = y_C × body_z
    bx = yy * zz
    by = -yx * zz
    bz = yx * zy - yy * zx
    if zz < 0.0:
        bx, by, bz = -bx, -by, -bz
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if nb < 1e-9:
        bx, by, bz = 0.0, 0.0, 1.0
    else:
        bx, by, bz = bx / nb, by / nb, bz / nb
    # body y = body_z × body_x
    cx = zy * bz - zz * by
    cy = zz * bx - zx * bz
    cz = zx * by - zy * bx
    return quat_from_dcm(bx, cx, zx, by, cy, zy, bz, cz, zz)


@njit
def limit_tilt(bx, by, bz, tilt_max):
    """Rotate unit vector b toward +z until its angle to +z is at most `tilt_max` (PX4 limitTilt)."""
    h = math.sqrt(bx * bx + by * by)
    ang = math.atan2(h, bz)
    if ang <= tilt_max or h < 1e-12:
        return bx, by, bz
    s = math.sin(tilt_max) / h
    return bx * s, by * s, math.cos(tilt_max)


# ----------------------------------------------------------------------------- the cascade


@njit
def _velocity_limit_xy(px, py, fx, fy, vmax):
    """Horizontal velocity setpoint: position term first, feed-forward fills up to `vmax`."""
    pn = math.sqrt(px * px + py * py)
    if pn >= vmax:
        return px * vmax / pn, py * vmax / pn
    sx = px + fx
    sy = py + fy
    if sx * sx + sy * sy <= vmax * vmax:
        return sx, sy
    ff2 = fx * fx + fy * fy
    pf = px * fx + py * fy
    disc = pf * pf - ff2 * (pn * pn - vmax * vmax)
    s = (-pf + math.sqrt(max(disc, 0.0))) / ff2
    s = min(max(s, 0.0), 1.0)
    return px + s * fx, py + s * fy


@njit
def position_control(x, prm, cp, sp, s):
    """Position → velocity → acceleration → normalised thrust vector (NED) into s[S_THRV]."""
    g = prm[P_G]
    dt = cp[C_DT]
    hover = s[S_HOVER]
    thr_max = cp[C_THR_MAX]
    thr_min = cp[C_THR_MIN]
    vsp = np.zeros(3)
    acc = np.zeros(3)
    active = np.zeros(3)
    ptm = np.zeros(3)
    ffv = np.zeros(3)
    for i in range(3):
        has_p = not math.isnan(sp[SP_POS + i])
        has_v = not math.isnan(sp[SP_VEL + i])
        kp = cp[C_POS_P] if i < 2 else cp[C_ZPOS_P]
        if has_p:
            ptm[i] = kp * (sp[SP_POS + i] - x[i])
        if has_v:
            ffv[i] = sp[SP_VEL + i]
        if has_p or has_v or math.isnan(sp[SP_ACC + i]):
            active[i] = 1.0
    vsp[0], vsp[1] = _velocity_limit_xy(ptm[0], ptm[1], ffv[0], ffv[1], cp[C_VEL_XY_MAX])
    vsp[2] = min(max(ptm[2] + ffv[2], -cp[C_VEL_UP_MAX]), cp[C_VEL_DN_MAX])
    verr = np.zeros(3)
    for i in range(3):
        a_ff = sp[SP_ACC + i]
        if math.isnan(a_ff):
            a_ff = 0.0
        if active[i] > 0.0:
            verr[i] = vsp[i] - x[X_V + i]
            if i < 2:
                acc[i] = cp[C_VEL_P] * verr[i] + s[S_VINT + i] - cp[C_VEL_D] * s[S_ACCF + i] + a_ff
            else:
                acc[i] = cp[C_ZVEL_P] * verr[i] + s[S_VINT + i] + a_ff
        else:
            vsp[i] = x[X_V + i]
            acc[i] = a_ff
    # acceleration → thrust (decoupled: attitude from horizontal acceleration against g)
    bx, by, bz = -acc[0], -acc[1], g
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    bx, by, bz = limit_tilt(bx / nb, by / nb, bz / nb, cp[C_TILT_MAX])
    thr_ned_z = acc[2] * (hover / g) - hover
    coll = min(thr_ned_z / bz, -thr_min)
    tx, ty, tz = bx * coll, by * coll, bz * coll
    # vertical anti-windup
    if (tz >= -thr_min and verr[2] >= 0.0) or (tz <= -thr_max and verr[2] <= 0.0):
        verr[2] = 0.0
    # PX4 thrust priority: vertical first, keep min(|T_xy|, margin) for horizontal
    txy = math.sqrt(tx * tx + ty * ty)
    alloc = min(txy, cp[C_THR_XY_MARG])
    tz = max(tz, -math.sqrt(max(thr_max * thr_max - alloc * alloc, 0.0)))
    txy_max = math.sqrt(max(thr_max * thr_max - tz * tz, 0.0))
    if txy > txy_max:
        tx *= txy_max / txy
        ty *= txy_max / txy
    # tracking anti-windup on the horizontal integrator
    pax = tx * g / hover
    pay = ty * g / hover
    if acc[0] * acc[0] + acc[1] * acc[1] > pax * pax + pay * pay:
        arw = 2.0 / cp[C_VEL_P]
        verr[0] -= arw * (acc[0] - pax)
        verr[1] -= arw * (acc[1] - pay)
    for i in range(3):
        if active[i] > 0.0:
            ki = cp[C_VEL_I] if i < 2 else cp[C_ZVEL_I]
            v = s[S_VINT + i] + ki * verr[i] * dt
            s[S_VINT + i] = min(max(v, -g), g)
        s[S_VSP + i] = vsp[i]
        s[S_ACCSP + i] = acc[i]
    s[S_THRV] = tx
    s[S_THRV + 1] = ty
    s[S_THRV + 2] = tz
    # hover-thrust estimate (PX4 MPC_USE_HTE): thrust that would give zero vertical acceleration
    if sp[SP_HTE] > 0.0:
        den = g - s[S_ACCF + 2]
        if den > 0.3 * g and -tz > thr_min:
            meas = -tz * g / den
            h = hover + (meas - hover) * dt / cp[C_HTE_TAU]
            s[S_HOVER] = min(max(h, 0.05), 0.95)


@njit
def attitude_rate_mixer(x, prm, cp, s, q0, q1, q2, q3, yawrate_ff, collective, wcmd):
    """Attitude P (thrust axis first) → rate PID → torques → mixer with saturation → Ω commands."""
    dt = cp[C_DT]
    a0, a1, a2, a3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    ezx, ezy, ezz = dcm_z(a0, a1, a2, a3)
    edx, edy, edz = dcm_z(q0, q1, q2, q3)
    r0, r1, r2, r3 = quat_between(ezx, ezy, ezz, edx, edy, edz)
    if abs(r1) > 1.0 - 1e-5 or abs(r2) > 1.0 - 1e-5:
        r0, r1, r2, r3 = q0, q1, q2, q3
    else:
        r0, r1, r2, r3 = qmul(r0, r1, r2, r3, a0, a1, a2, a3)
    m0, m1, m2, m3 = qmul(r0, -r1, -r2, -r3, q0, q1, q2, q3)
    if m0 < 0.0:
        m0, m1, m2, m3 = -m0, -m1, -m2, -m3
    m0 = min(max(m0, -1.0), 1.0)
    m3 = min(max(m3, -1.0), 1.0)
    yaw_w = min(max(cp[C_YAW_P] / cp[C_ATT_P], 0.0), 1.0)
    d0, d1, d2, d3 = qmul(r0, r1, r2, r3, math.cos(yaw_w * math.acos(m0)), 0.0, 0.0,
                          math.sin(yaw_w * math.asin(m3)))
    e0, e1, e2, e3 = qmul(a0, -a1, -a2, -a3, d0, d1, d2, d3)
    if e0 < 0.0:
        e1, e2, e3 = -e1, -e2, -e3
    kp = cp[C_ATT_P]
    rsp = np.empty(3)
    rsp[0] = 2.0 * e1 * kp
    rsp[1] = 2.0 * e2 * kp
    rsp[2] = 2.0 * e3 * kp
    if not math.isnan(yawrate_ff):
        # world yaw rate expressed in body axes: R^T e_z = dcm_z(q^-1)
        zx, zy, zz = dcm_z(a0, -a1, -a2, -a3)
        rsp[0] += zx * yawrate_ff
        rsp[1] += zy * yawrate_ff
        rsp[2] += zz * yawrate_ff
    for i in range(3):
        lim = cp[C_TILT_RATE_MAX] if i < 2 else cp[C_YAW_RATE_MAX]
        rsp[i] = min(max(rsp[i], -lim), lim)
        s[S_RSP + i] = rsp[i]
    s[S_QSP], s[S_QSP + 1], s[S_QSP + 2], s[S_QSP + 3] = q0, q1, q2, q3
    # rate PID → torques (torque = I · angular acceleration)
    inertia = (prm[P_IXX], prm[P_IYY], prm[P_IZZ])
    tau = np.empty(3)
    for i in range(3):
        w = x[X_W + i]
        e = rsp[i] - w
        wdot = (w - s[S_WPREV + i]) / dt
        s[S_WPREV + i] = w
        ang = cp[C_RATE_P] * e + s[S_RINT + i] - cp[C_RATE_D] * wdot
        tau[i] = inertia[i] * ang
        if s[S_SAT] < 0.5:
            ri = s[S_RINT + i] + cp[C_RATE_I] * e * dt
            lim = 0.3 * cp[C_RATE_P] * (cp[C_TILT_RATE_MAX] if i < 2 else cp[C_YAW_RATE_MAX])
            s[S_RINT + i] = min(max(ri, -lim), lim)
    ymax = cp[C_YAW_MOM_MAX]
    tau[2] = min(max(tau[2], -ymax), ymax)
    mix(prm, cp, s, collective * cp[C_T_NOM], tau[0], tau[1], tau[2], wcmd)


@njit
def mix(prm, cp, s, t_total, tx, ty, tz, wcmd):
    """Thrust/torque allocation for the X layout; saturation keeps roll/pitch, then collective,
    then yaw. Writes rotor-speed commands Ω_i = √(f_i / k_thrust)."""
    d = prm[P_D]
    kt = prm[P_KT]
    c = prm[P_KQ] / kt  # yaw torque per newton of rotor thrust
    fmax = cp[C_T_NOM] / 4.0
    base = t_total / 4.0
    rp = np.empty(4)
    yw = np.empty(4)
    rmin = 1e30
    rmax = -1e30
    for i in range(4):
        rp[i] = (-tx * RY[i] + ty * RX[i]) / (4.0 * d)
        yw[i] = tz * prm[P_SPIN + i] / (4.0 * c)
        rmin = min(rmin, rp[i])
        rmax = max(rmax, rp[i])
    sat = 0.0
    if rmax - rmin > fmax:
        k = fmax / (rmax - rmin)
        for i in range(4):
            rp[i] *= k
        rmin *= k
        rmax *= k
        sat = 1.0
    lo = -rmin
    hi = fmax - rmax
    if base < lo:
        base = lo
        sat = 1.0
    elif base > hi:
        base = hi
        sat = 1.0
    sy = 1.0
    for i in range(4):
        f = base + rp[i]
        if yw[i] > 1e-15:
            sy = min(sy, (fmax - f) / yw[i])
        elif yw[i] < -1e-15:
            sy = min(sy, f / -yw[i])
    if sy < 1.0:
        sat = 1.0
    sy = max(sy, 0.0)
    for i in range(4):
        f = min(max(base + rp[i] + sy * yw[i], 0.0), fmax)
        wcmd[i] = math.sqrt(f / kt)
    s[S_SAT] = sat


@njit
def control_step(x, prm, cp, sp, s):
    """One controller cycle (period cp[C_DT]): rotor-speed commands into s[S_WCMD:S_WCMD+4]."""
    dt = cp[C_DT]
    alpha = dt / (dt + 1.0 / (2.0 * math.pi * ACC_FILTER_HZ))
    for i in range(3):
        raw = (x[X_V + i] - s[S_VPREV + i]) / dt
        s[S_ACCF + i] += alpha * (raw - s[S_ACCF + i])
        s[S_VPREV + i] = x[X_V + i]
    mode = int(sp[SP_MODE])
    wcmd = np.zeros(4)
    if mode == M_OFF or mode == M_IDLE:
        for i in range(3):
            s[S_VINT + i] = 0.0
            s[S_RINT + i] = 0.0
            s[S_THRV + i] = 0.0
        a0, a1, a2, a3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
        s[S_YAWHOLD] = math.atan2(2.0 * (a0 * a3 + a1 * a2), 1.0 - 2.0 * (a2 * a2 + a3 * a3))
        idle = 0.0
        if mode == M_IDLE:
            idle = prm[P_WMAX] * math.sqrt(cp[C_IDLE])
        for i in range(4):
            s[S_WCMD + i] = idle
        s[S_THR] = cp[C_IDLE] if mode == M_IDLE else 0.0
        return
    yawrate = sp[SP_YAWRATE]
    if not math.isnan(sp[SP_YAW]):
        s[S_YAWHOLD] = sp[SP_YAW]
    elif not math.isnan(yawrate):
        s[S_YAWHOLD] += yawrate * dt
    if mode == M_POS:
        position_control(x, prm, cp, sp, s)
        tx, ty, tz = s[S_THRV], s[S_THRV + 1], s[S_THRV + 2]
        q0, q1, q2, q3 = attitude_from_thrust(tx, ty, tz, s[S_YAWHOLD])
        coll = math.sqrt(tx * tx + ty * ty + tz * tz)
    else:  # M_ATT: attitude quaternion and normalised collective thrust
        q0, q1, q2, q3 = sp[SP_Q], sp[SP_Q + 1], sp[SP_Q + 2], sp[SP_Q + 3]
        coll = min(max(sp[SP_THRUST], 0.0), 1.0)
        zx, zy, zz = dcm_z(q0, q1, q2, q3)
        s[S_THRV], s[S_THRV + 1], s[S_THRV + 2] = -zx * coll, -zy * coll, -zz * coll
    s[S_THR] = coll
    attitude_rate_mixer(x, prm, cp, s, q0, q1, q2, q3, yawrate, coll, wcmd)
    for i in range(4):
        s[S_WCMD + i] = wcmd[i]
