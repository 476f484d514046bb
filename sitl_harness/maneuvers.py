"""Reference manoeuvres flown directly on the cascade (no MAVLink): circles, steps.

Used by the controller tests, the benchmark and (later) the controller-contract sweep. Contour
error (the paper's Figure 11) on a circle of radius R centred at the origin is exact in closed
form: √((ρ − R)² + Δz²), ρ the horizontal distance from the centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from contracts.vehicle import G

from .control import C_TILT_MAX, M_POS, S_HOVER, SP_ACC, SP_HTE, SP_MODE, SP_POS, SP_VEL, SP_YAW
from .kernel import VehicleModel
from .physics import X_R


def hovering(vehicle, thrust_ratio: float = 1.0, pos=(0.0, 0.0, -5.0), vel=(0.0, 0.0, 0.0),
             tilt_max: float | None = None) -> VehicleModel:
    """A `VehicleModel` in the air at `pos` with rotors at hover speed and a converged hover estimate."""
    m = VehicleModel(vehicle)
    m.thrust_ratio = thrust_ratio
    m.x[0:3] = pos
    m.x[3:6] = vel
    m.x[X_R:X_R + 4] = math.sqrt(vehicle.mass_kg * G / (4 * thrust_ratio * vehicle.rotor.k_thrust))
    m.s[S_HOVER] = vehicle.mass_kg * G / (thrust_ratio * vehicle.t_nom_n)
    if tilt_max is not None:
        m.cp[C_TILT_MAX] = tilt_max
    m.sp[SP_MODE] = M_POS
    m.sp[SP_POS:SP_POS + 3] = pos
    m.sp[SP_YAW] = 0.0
    m.sp[SP_HTE] = 1.0
    m.resting = False
    return m


@dataclass
class CircleResult:
    thrust_ratio: float
    radius_m: float
    speed_m_s: float
    lateral_acc_m_s2: float
    contour_max_m: float
    contour_mean_m: float


def fly_circle(vehicle, thrust_ratio: float, radius: float, lateral_acc: float, tilt_max: float,
               laps: float = 2.0, wind=None, dt_nav: float = 0.01) -> CircleResult:
    """Track a horizontal circle (position + velocity + acceleration feed-forward, PX4 offboard
    style) at speed √(a·R); one lap to settle, then the contour error over `laps` laps."""
    spd = math.sqrt(lateral_acc * radius)
    w = spd / radius
    z = -5.0
    m = hovering(vehicle, thrust_ratio, (radius, 0.0, z), (0.0, spd, 0.0), tilt_max)
    if wind is not None:
        m.set_wind(wind)
    n_phys = max(1, round(dt_nav / m.dt))
    period = 2 * math.pi / w
    errs = []
    for k in range(int(round((1.0 + laps) * period / dt_nav))):
        t = k * dt_nav
        c, s = math.cos(w * t), math.sin(w * t)
        m.sp[SP_POS:SP_POS + 3] = (radius * c, radius * s, z)
        m.sp[SP_VEL:SP_VEL + 3] = (-spd * s, spd * c, 0.0)
        m.sp[SP_ACC:SP_ACC + 3] = (-lateral_acc * c, -lateral_acc * s, 0.0)
        m.step(n_phys)
        if t >= period:
            rho = math.hypot(m.pos[0], m.pos[1])
            errs.append(math.hypot(rho - radius, m.pos[2] - z))
    e = np.array(errs)
    return CircleResult(thrust_ratio, radius, spd, lateral_acc, float(e.max()), float(e.mean()))


def step_response(vehicle, axis: int, size: float, seconds: float = 8.0, kind: str = "pos") -> dict:
    """Position (`kind='pos'`) or velocity (`'vel'`) step on one NED axis from hover; overshoot as a
    fraction of the step and the 90 % rise time."""
    m = hovering(vehicle)
    m.step(1000)
    start = (m.pos if kind == "pos" else m.vel)[axis]
    if kind == "pos":
        m.sp[SP_POS + axis] = m.pos[axis] + size
    else:
        m.sp[SP_POS + axis] = math.nan
        m.sp[SP_VEL + axis] = size
    tr = []
    for _ in range(int(seconds / 0.01)):
        m.step(10)
        tr.append(((m.pos if kind == "pos" else m.vel)[axis] - start) * math.copysign(1.0, size))
    tr = np.array(tr)
    rise = int(np.argmax(tr >= 0.9 * abs(size))) * 0.01 if np.any(tr >= 0.9 * abs(size)) else math.inf
    return {"overshoot": float((tr.max() - abs(size)) / abs(size)), "rise_90_s": rise,
            "final_error": float(abs(size) - tr[-1])}


def track_reference(vehicle, t, p, v, a, thrust_ratio: float = 1.0, tilt_max: float | None = None,
                    yaw: float = 0.0, wind=None, dt_nav: float = 0.01) -> np.ndarray:
    """Fly a sampled reference (times `t` (n,), NED positions/velocities/accelerations (n, 3)) with
    position + velocity + acceleration feed-forward, starting on it; returns the flown positions at
    the reference times (n, 3). Pair with `contracts.contour.contour_errors` for E_tr."""
    t = np.asarray(t, float)
    p, v, a = (np.asarray(x, float) for x in (p, v, a))
    m = hovering(vehicle, thrust_ratio, tuple(p[0]), tuple(v[0]), tilt_max)
    m.sp[SP_YAW] = yaw
    if wind is not None:
        m.set_wind(wind)
    n_phys = max(1, round(dt_nav / m.dt))
    out = np.empty_like(p)
    out[0] = m.pos
    k = 1
    tk = t[0]
    while k < len(t):
        for arr, idx in ((p, SP_POS), (v, SP_VEL), (a, SP_ACC)):
            for i in range(3):
                m.sp[idx + i] = np.interp(tk, t, arr[:, i])
        m.step(n_phys)
        tk += n_phys * m.dt
        while k < len(t) and t[k] <= tk + 1e-9:
            out[k] = m.pos
            k += 1
    return out
