"""Flat quadrotor model of the paper, eq. (7)–(13), and the input sets of the two tilt models.

Flat output y = [X, Y, Z, ψ] (NED, ψ yaw). Synthetic input w = [Ẍ, Ÿ, Z̈, ψ̈]. Pure numpy, no I/O,
safe to import on board. Arrays broadcast: every function takes scalars or equal-shape arrays.
"""

from __future__ import annotations

import math

import numpy as np

from .vehicle import G

# ----------------------------------------------------------------------------- eq. (7), (8)


def accel_from_inputs(t, phi, theta, psi, mass, g=G):
    """Eq. (7): NED accelerations (Ẍ, Ÿ, Z̈) from thrust T, roll φ, pitch θ and yaw ψ."""
    s = t / mass
    cphi, sphi = np.cos(phi), np.sin(phi)
    cth, sth = np.cos(theta), np.sin(theta)
    cpsi, spsi = np.cos(psi), np.sin(psi)
    ax = -s * (cphi * sth * cpsi + sphi * spsi)
    ay = -s * (cphi * sth * spsi - sphi * cpsi)
    az = g - s * cphi * cth
    return ax, ay, az


def inputs_from_flat(ax, ay, az, psi, psi_ddot=0.0, mass=1.0, k_psi=1.0, g=G):
    """Eq. (8): inputs (T, φ, θ, u_ψ) from the flat output's second derivatives and ψ."""
    a_fwd = ax * np.cos(psi) + ay * np.sin(psi)  # along the heading
    a_lat = -ax * np.sin(psi) + ay * np.cos(psi)  # to the right of the heading
    gz = g - az
    phi = np.arctan(a_lat / np.sqrt(gz**2 + a_fwd**2))
    theta = -np.arctan(a_fwd / gz)
    t = mass * np.sqrt(ax**2 + ay**2 + gz**2)
    u_psi = psi_ddot / k_psi
    return t, phi, theta, u_psi


def attitude_from_flat(ax, ay, az, psi, g=G):
    """N_p's attitude part, eq. (9) with eq. (8): (φ, θ, ψ) along a flat trajectory."""
    _, phi, theta, _ = inputs_from_flat(ax, ay, az, psi, g=g)
    return phi, theta, psi


# ----------------------------------------------------------------------------- eq. (9)–(13)


def integrator_chains(n_axes: int = 4):
    """Eq. (10)–(11): q̇ = F q + G w for `n_axes` double integrators, q = [X, Ẋ, Y, Ẏ, …]."""
    j2 = np.array([[0.0, 1.0], [0.0, 0.0]])
    l2 = np.array([[0.0], [1.0]])
    eye = np.eye(n_axes)
    return np.kron(eye, j2), np.kron(eye, l2)


def zoh(ts: float, n_axes: int = 4):
    """Eq. (12)–(13) in closed form: F̂ = e^{F t_s}, Ĝ = ∫₀^{t_s} e^{Fτ} G dτ per integrator chain."""
    fh = np.array([[1.0, ts], [0.0, 1.0]])
    gh = np.array([[0.5 * ts * ts], [ts]])
    eye = np.eye(n_axes)
    return np.kron(eye, fh), np.kron(eye, gh)


# ----------------------------------------------------------------------------- input sets (eq. 14)


def total_tilt(ax, ay, az=0.0, g=G):
    """Angle between the thrust axis and the vertical for a commanded acceleration."""
    return np.arctan2(np.hypot(ax, ay), g - az)


def thrust_limited_accel(t_max: float, mass: float, g=G) -> float:
    """Largest horizontal acceleration that thrust `t_max` allows in level flight, √((T/m)² − g²)."""
    s = t_max / mass
    return math.sqrt(max(s * s - g * g, 0.0))  # float(np.sqrt(…)) to the bit (both round correctly), without numpy's call


def horizontal_accel_limit(tilt: float, t_max: float, mass: float, g=G) -> float:
    """Cone model in level flight: |a_h| ≤ min(g·tan(tilt), √((T_max/m)² − g²))."""
    return min(g * float(np.tan(tilt)), thrust_limited_accel(t_max, mass, g))


def in_input_set(ax, ay, az, psi, tilt, t_max, mass, model="cone", t_min=0.0, tol=0.0, g=G):
    """Whether w = (Ẍ, Ÿ, Z̈) at yaw ψ satisfies eq. (14)'s tilt and thrust limits.

    `cone`: total tilt ≤ `tilt` (PX4 MPC_TILTMAX_AIR, ArduPilot ANGLE_MAX).
    `box`: |φ| ≤ tilt and |θ| ≤ tilt separately (the paper's form, φ_max = θ_max = tilt).
    """
    t, phi, theta, _ = inputs_from_flat(ax, ay, az, psi, mass=mass, g=g)
    ok_t = (t >= t_min - tol) & (t <= t_max + tol)
    if model == "cone":
        ok_tilt = total_tilt(ax, ay, az, g) <= tilt + tol
    elif model == "box":
        ok_tilt = (np.abs(phi) <= tilt + tol) & (np.abs(theta) <= tilt + tol)
    else:
        raise ValueError(f"unknown tilt model {model!r}")
    return ok_t & ok_tilt & (g - az > 0)


def cone_polygon(a_max: float, n: int = 16):
    """Inner polygonal approximation of the disc |a_h| ≤ a_max: rows of A·a ≤ b (for QPs).

    The regular n-gon inscribed in the disc: every point it admits is in the disc.
    """
    ang = 2.0 * np.pi * (np.arange(n) + 0.5) / n
    a = np.column_stack([np.cos(ang), np.sin(ang)])
    b = np.full(n, a_max * np.cos(np.pi / n))
    return a, b
