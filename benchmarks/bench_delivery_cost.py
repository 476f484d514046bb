"""The speed the command-delivery budget costs the stop contract: V_max with `delivery.t_cmd_s` against V_max
without it (t_cmd 0), over D_od 3–12 m, E_tr 0.3–1 m and thrust 0.7–1, for the shipped vehicles' tables, the
autopilot's Hold and the recovery brake (closed form, deterministic); with `--flights N`, also the mean speed flown
in the link campaign's first N fault-free scenarios (examples/campaign-link.yaml, both modes), each flown with and
without the budget (lock-step, deterministic). Prints one JSON object.

    PYTHONPATH=. python benchmarks/bench_delivery_cost.py [--t-cmd 0.1] [--flights 40]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from companion.ground import campaign as cg
from contracts.table import load_for_vehicle

SPEC = Path(__file__).resolve().parents[1] / "examples" / "campaign-link.yaml"

D_OD = np.arange(3.0, 12.01, 0.5)
E_TR = (0.3, 0.5, 1.0)
THRUST = (0.7, 0.85, 1.0)
LOOP_DT = 0.02


def cost(vehicle: str, t_cmd: float, recovery_dt: float | None) -> dict:
    """Relative speed lost (1 − V_max(t_cmd)/V_max(0)) over the grid where V_max(0) > 0.5 m/s."""
    table = load_for_vehicle(vehicle)
    brake = recovery_dt is not None  # the brake flies the stops: its own controller contract
    losses = []
    for d in D_OD:
        for e in E_TR:
            for k in THRUST:
                base = table.omega(float(d), 1.0, e, k, contract="stop", recovery_dt=recovery_dt, e_brake=brake).v_max
                if base > 0.5:
                    with_budget = table.omega(float(d), 1.0, e, k, contract="stop", recovery_dt=recovery_dt,
                                              e_brake=brake,
                                              t_cmd=t_cmd).v_max
                    losses.append(1.0 - with_budget / base)
    at6 = [1.0 - table.omega(6.0, 1.0, 0.3, 1.0, contract="stop", recovery_dt=recovery_dt, e_brake=brake,
                             t_cmd=t_cmd).v_max /
           table.omega(6.0, 1.0, 0.3, 1.0, contract="stop", recovery_dt=recovery_dt, e_brake=brake).v_max]
    return {"cells": len(losses), "mean_pct": round(100 * float(np.mean(losses)), 2),
            "max_pct": round(100 * float(np.max(losses)), 2), "at_6m_pct": round(100 * at6[0], 2)}


def flown(t_cmd: float, n: int) -> dict:
    """Mean speed flown per mode, with the budget and without, paired over the link campaign's first `n` fault-free
    scenarios (its stress 0)."""
    spec = cg.load_spec(SPEC)
    arms, stresses = len(spec.arms), len(spec.stresses)
    base_config = cg.daemon_config
    out = {}
    for budget in (t_cmd, 0.0):
        cg.daemon_config = lambda s, arm, nav=0.0: {**base_config(s, arm, nav), "delivery": {"t_cmd_s": budget}}
        try:
            for k in range(n):
                for a in range(arms):
                    row = cg.fly(spec, k * stresses * arms + a)
                    out.setdefault(spec.arms[a], {}).setdefault(budget, []).append(row["mean_speed_m_s"])
        finally:
            cg.daemon_config = base_config
    return {arm: {"flights": n, "mean_speed_with": round(float(np.mean(v[t_cmd])), 3),
                  "mean_speed_without": round(float(np.mean(v[0.0])), 3),
                  "cost_pct": round(100 * (1 - float(np.mean(v[t_cmd])) / float(np.mean(v[0.0]))), 2)}
            for arm, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-cmd", type=float, default=0.1, help="the delivery budget [s] (default 0.1)")
    ap.add_argument("--flights", type=int, default=0, help="also fly this many fault-free scenarios per mode")
    args = ap.parse_args()
    out = {"t_cmd_s": args.t_cmd}
    for vehicle in ("mambo", "x500"):
        out[vehicle] = {"hold": cost(vehicle, args.t_cmd, None), "recovery_brake": cost(vehicle, args.t_cmd, LOOP_DT)}
    if args.flights:
        out["flown"] = flown(args.t_cmd, args.flights)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
