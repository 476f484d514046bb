"""An independent estimate of the avoid contract's physical limit, and the closed-form stop branch.

Pure numpy (no CasADi, no I/O). Head-on geometry of DESIGN.md §2 in level flight with the cone model:
the horizontal acceleration is bounded by a disc |a_h| ≤ a (a = min(g·tan tilt, √((T_max/m)² − g²))),
the speed by V (= V_max, the initial speed), the keep-out disc has radius r_k at distance c.

Open-loop "full brake + full lateral" policy family (one parameter β ∈ [0, π/2]):
  1. full acceleration a in the fixed direction (−cos β, sin β) (brake and swerve at once) while the
     speed is below V (until t₁ = 2V·cos β / a);
  2. then, on the speed limit, turn at full lateral acceleration a (speed V, turn rate a/V);
  3. coast as soon as the straight continuation misses the disc (or the vehicle has stopped).
Each member is simulated finely in closed form; V_est = sup{V : some β avoids the disc}. β = 0 is the
pure stop, β = π/2 the pure constant-speed turn. By the scaling law only ρ = r_k/c matters:
V_est = √(a·c)·G_est(ρ).
"""

from __future__ import annotations

import math

import numpy as np


def stop_speed_kinematic(a, c, r_k, lead=0.0):
    """Stop branch in closed form: the largest V with V·lead + V²/(2a) ≤ c − r_k (full deceleration a
    after coasting `lead` seconds); with lead = 0 (the table's t_react = 0), V = √(2·a·(c − r_k))."""
    a = np.asarray(a, float)
    d = np.maximum(np.asarray(c, float) - np.asarray(r_k, float), 0.0)
    lead = np.asarray(lead, float)
    return np.where(a > 0, a * (-lead + np.sqrt(lead * lead + 2.0 * d / np.where(a > 0, a, 1.0))), 0.0)


def policy_states(beta, v, a, t):
    """Positions and velocities (…, len(t), 2) of policy β (array) at times t (origin start, +x)."""
    beta = np.asarray(beta, float)[..., None]
    t = np.asarray(t, float)
    cb, sb = np.cos(beta), np.sin(beta)
    t1 = 2.0 * v * cb / a
    tt = np.minimum(t, t1)
    px = v * tt - 0.5 * a * cb * tt**2
    py = 0.5 * a * sb * tt**2
    vx = v - a * cb * tt
    vy = a * sb * tt
    # phase 2: constant-speed turn (counter-clockwise) from the velocity angle at t1
    th1 = np.pi - 2.0 * beta
    om = a / v
    dt2 = np.maximum(t - t1, 0.0)
    th = th1 + om * dt2
    r = v / om
    px = px + r * (np.sin(th) - np.sin(th1))
    py = py - r * (np.cos(th) - np.cos(th1))
    turning = dt2 > 0.0
    vx = np.where(turning, v * np.cos(th), vx)
    vy = np.where(turning, v * np.sin(th), vy)
    return np.stack([px, py], -1), np.stack([vx, vy], -1)


def _segment_distance(p0, p1, o):
    """Distance from point o to the segments p0→p1 (…, 2)."""
    d = p1 - p0
    dd = np.einsum("...i,...i->...", d, d)
    s = np.clip(np.einsum("...i,...i->...", o - p0, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(p0 + s[..., None] * d - o, axis=-1)


def _policy_safe(v, a, c, r_k, betas, block=2000):
    """Which policies β avoid the disc: simulated on a time grid fine enough that the path bulges at
    most 1e-4·r_k from its chords, exact point-to-chord distances, processed block by block until
    every policy has either hit the disc or reached a clear coast."""
    dt = math.sqrt(8e-4 * r_k / a)
    dt = min(dt, r_k / (20.0 * v) if v > 0 else dt, c / (50.0 * v) if v > 0 else dt)
    t_end = 2.0 * v / a + math.pi * v / a + 2.0 * c / max(v, 1e-9)
    o = np.array([c, 0.0])
    betas = np.asarray(betas, float)
    alive = np.ones(len(betas), bool)
    safe = np.zeros(len(betas), bool)
    t0 = 0.0
    while alive.any() and t0 <= t_end:
        t = t0 + dt * np.arange(block + 1)
        idx = np.flatnonzero(alive)
        p, vel = policy_states(betas[idx], v, a, t)
        d = p - o
        vv = np.einsum("...i,...i->...", vel, vel)
        s = np.maximum(0.0, -np.einsum("...i,...i->...", d, vel) / np.where(vv > 0, vv, 1.0))
        clear = np.linalg.norm(d + s[..., None] * vel, axis=-1) >= r_k
        seg = _segment_distance(p[:, :-1], p[:, 1:], o)
        hit_seg = seg < r_k
        first_clear = np.where(clear.any(-1), np.argmax(clear, axis=-1), block + 1)
        first_hit = np.where(hit_seg.any(-1), np.argmax(hit_seg, axis=-1), block + 1)
        hit = first_hit < first_clear
        done_clear = (first_clear <= block) & ~hit
        safe[idx[done_clear]] = True
        alive[idx[hit | done_clear]] = False
        t0 = t[-1]
    return safe


def policy_limit_speed(a, c, r_k, *, n_beta=91, rel_tol=2e-4) -> tuple[float, float]:
    """V_est = sup V such that some policy β avoids the disc; returns (V_est, best β).

    Bisection on V between the stop speed (β = 0 is in the family) and a generous upper bound.
    """
    v_lo = float(stop_speed_kinematic(a, c, r_k))
    betas = np.linspace(0.0, 0.5 * math.pi, n_beta)
    v_hi = max(2.0 * v_lo, math.sqrt(a * c) * 4.0 / math.sqrt(max(r_k / c, 1e-6)))
    best = 0.0
    while v_hi - v_lo > rel_tol * v_hi:
        v = 0.5 * (v_lo + v_hi)
        ok = _policy_safe(v, a, c, r_k, betas)
        if np.any(ok):
            v_lo, best = v, float(betas[np.argmax(ok)])
        else:
            v_hi = v
    return v_lo, best


def policy_limit_f(rho, a_over_g=1.0, **kw) -> float:
    """The estimate in reduced form: F_est(ρ) = V_est/√(g·c) for the cone model with a = a_over_g·g."""
    v, _ = policy_limit_speed(1.0, 1.0, float(rho), **kw)
    return v * math.sqrt(a_over_g)


def policy_guess(beta, v, a, c, r_k, n):
    """ZOH inputs (n, 4) and t_s sampling policy β up to the coast point: a start for the planner."""
    t_end = 2.0 * v / a + math.pi * v / a + 2.0 * c / v
    t = np.linspace(0.0, t_end, 4000)
    p, vel = policy_states(np.array([beta]), v, a, t)
    p, vel = p[0], vel[0]
    d = p - np.array([c, 0.0])
    vv = np.einsum("ij,ij->i", vel, vel)
    s = np.where(vv > 0, np.maximum(0.0, -np.einsum("ij,ij->i", d, vel) / np.where(vv > 0, vv, 1.0)), 0.0)
    clear = np.linalg.norm(d + s[:, None] * vel, axis=-1) >= r_k
    t_c = t[np.argmax(clear)] if clear.any() else t_end
    t_c = max(t_c, 1e-3 * t_end)
    ts = t_c / n
    tk = (np.arange(n) + 0.5) * ts
    _, v1 = policy_states(np.array([beta]), v, a, tk)
    _, v0 = policy_states(np.array([beta]), v, a, tk - 0.5 * ts)
    _, v2 = policy_states(np.array([beta]), v, a, tk + 0.5 * ts)
    acc = (v2[0] - v0[0]) / ts
    acc *= np.minimum(1.0, a / np.maximum(np.linalg.norm(acc, axis=1), 1e-12))[:, None]
    w = np.zeros((n, 4))
    w[:, :2] = acc
    return w, ts
