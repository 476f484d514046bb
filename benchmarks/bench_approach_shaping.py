"""What approach shaping would buy the governor (a study for it, not a feature): V_max of the stop contract when the
governor never commands more than ΔV above the speed flown, against today's (any approach state). Prints JSON.

    PYTHONPATH=. python benchmarks/bench_approach_shaping.py [--dv 0.2 0.5 1.0]

An autopilot that approaches its commanded speed jerk-limited and never overshoots it holds v + a²/(2j) ≤ v_cmd;
with v_cmd ≤ v + ΔV its acceleration stays ≤ √(2jΔV), so the joint bound's worst Hold-start acceleration
(`contracts.stop.worst_hold_accel`) is capped there (`hold_start_gain` is concave in it: the clipped stationary
point is the worst). Deterministic: the bound only, nothing flown; the cost — a slower speed-up — is not counted.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from contracts import stop as S
from contracts.vehicle import load_vehicle


def shaped_distance(v: float, a: float, j: float, t_r: float, a0_max: float) -> float:
    """`approach_stopping_distance` with the Hold-start acceleration at most a0_max."""
    v = max(v, 0.0)
    return v * t_r + S.braking_distance(v, a, j) + S.hold_start_gain(v, min(S.worst_hold_accel(v, a, j, t_r), a0_max),
                                                                    j, t_r)


def shaped_speed(d_avail: float, a: float, j: float, t_r: float, a0_max: float) -> float:
    """Largest v with shaped_distance ≤ d_avail (bisection below the plain `stop_speed`)."""
    lo, hi = 0.0, S.stop_speed(d_avail, a, j, t_r)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if shaped_distance(mid, a, j, t_r, a0_max) <= d_avail else (lo, mid)
    return lo


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dv", type=float, nargs="+", default=[0.2, 0.5, 1.0])
    args = ap.parse_args()
    out = {}
    for name in ("mambo", "x500"):
        veh = load_vehicle(name)
        j, t_r = veh.braking.jerk_max_m_s3, S.stop_dead_time(veh)
        rows = {}
        for dv in args.dv:
            cap, gains = math.sqrt(2.0 * j * dv), []
            for d_od in np.linspace(3.0, 12.0, 10):
                for e_tr in np.linspace(0.1, 0.8, 8):
                    for tr in np.linspace(0.7, 1.0, 4):
                        a, d = S.braking_decel(veh, tr), d_od - e_tr - veh.r_body_m
                        base = S.approach_stop_speed(d, a, j, t_r) if a > 0 else 0.0
                        if base > 0.0:
                            gains.append(shaped_speed(d, a, j, t_r, cap) / base)
            rows[str(dv)] = {"a0_max_m_s2": round(cap, 3), "points": len(gains),
                             "gain_median": round(float(np.median(gains)), 4),
                             "gain_min": round(min(gains), 4), "gain_max": round(max(gains), 4)}
        out[name] = {"jerk_m_s3": j, "t_r_s": t_r, "by_dv_m_s": rows}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
