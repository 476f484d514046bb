"""What governor mode's approach ramp (`governor.approach_ramp_m_s`) buys: V_max of the stop contract with the
Hold-start acceleration the ramp allows against the contract for any approach. Prints JSON.

    PYTHONPATH=. python benchmarks/bench_approach_shaping.py [--ramp 0.2 0.3 0.5] [--fly]

The bound: an autopilot that approaches its commanded speed jerk-limited and never overshoots it holds
v + a²/(2j) ≤ v_cmd; the governor keeps v_cmd ≤ v + ramp (+ its slack), so the acceleration stays ≤ `ramp_accel`,
and the daemon's check allows RAMP_A_TOL beside it (companion/onboard/supervisor.py `ApproachRamp.a0_max`): the joint
bound is taken with that cap (contracts/stop.py `approach_stop_speed(a0_max=...)`). Deterministic, shipped tables'
vehicles, 320 points each (D_od 3–12 m, E_tr 0.1–0.8 m, thrust 0.7–1.0). `--fly`: the lock-step SITL column flights
(Mambo, PX4 and ArduPilot, a column first seen at 6 m; at 28 m from steady cruise, at 6 m during the speed-up) with
and without a 0.3 m/s ramp: the limit flown, the time from the mission's start to 95 % of it (the cost), clearance.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.onboard.supervisor import RAMP_A_TOL, RAMP_SLACK_M_S  # noqa: E402
from contracts import stop as S  # noqa: E402
from contracts.vehicle import load_vehicle  # noqa: E402


def bound(ramps: list[float]) -> dict:
    out = {}
    for name in ("mambo", "x500"):
        veh = load_vehicle(name)
        j, t_r = veh.braking.jerk_max_m_s3, S.stop_dead_time(veh)
        rows = {}
        for ramp in ramps:
            cap, gains = S.ramp_accel(j, ramp + RAMP_SLACK_M_S) + RAMP_A_TOL, []
            for d_od in np.linspace(3.0, 12.0, 10):
                for e_tr in np.linspace(0.1, 0.8, 8):
                    for tr in np.linspace(0.7, 1.0, 4):
                        a, d = S.braking_decel(veh, tr), d_od - e_tr - veh.r_body_m
                        base = S.approach_stop_speed(d, a, j, t_r) if a > 0 else 0.0
                        if base > 0.0:
                            gains.append(S.approach_stop_speed(d, a, j, t_r, cap) / base)
            rows[str(ramp)] = {"a0_max_m_s2": round(cap, 3), "points": len(gains),
                               "gain_median": round(float(np.median(gains)), 4),
                               "gain_min": round(min(gains), 4), "gain_max": round(max(gains), 4)}
        out[name] = {"jerk_m_s3": j, "t_r_s": t_r, "accel_max_m_s2": veh.braking.accel_max_m_s2, "by_ramp_m_s": rows}
    return out


def flights() -> dict:
    from tests.test_approach_ramp_lockstep import flight

    out = {}
    for personality in ("px4", "ardupilot"):
        for x_col, seconds in ((28.0, 25.0), (6.0, 15.0)):
            for ramp in (None, 0.3):
                rig = flight(personality, x_col, seconds, ramp=ramp)
                st, ev = rig.log.states, rig.log.events
                v_cmd = max(s["v_cmd"] or 0.0 for s in st)
                t0 = next(e["t"] for e in ev if e["event"] == "limit_change")
                t95 = next((s["t"] for s in st if s["ground_speed"] >= 0.95 * v_cmd), None)
                out[f"{personality} column {x_col:g} m ramp {ramp}"] = {
                    "v_cmd_max_m_s": round(v_cmd, 3), "collisions": len(rig.truth["collisions"]),
                    "min_clearance_m": round(rig.truth["min_clearance_m"], 3),
                    "to_95pct_s": None if t95 is None else round(t95 - t0, 2)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ramp", type=float, nargs="+", default=[0.2, 0.3, 0.5])
    ap.add_argument("--fly", action="store_true", help="also the lock-step SITL flights")
    args = ap.parse_args()
    out = {"bound": bound(args.ramp)}
    if args.fly:
        out["flights"] = flights()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
