"""The speed the command-delivery budget costs the stop contract: V_max with `delivery.t_cmd_s` against V_max
without it (t_cmd 0), over D_od 3–12 m, E_tr 0.3–1 m and thrust 0.7–1, for the shipped vehicles' tables, the
autopilot's Hold and the recovery brake. Deterministic (closed form); prints one JSON object.

    PYTHONPATH=. python benchmarks/bench_delivery_cost.py [--t-cmd 0.1]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from contracts.table import load_for_vehicle

D_OD = np.arange(3.0, 12.01, 0.5)
E_TR = (0.3, 0.5, 1.0)
THRUST = (0.7, 0.85, 1.0)
LOOP_DT = 0.02


def cost(vehicle: str, t_cmd: float, recovery_dt: float | None) -> dict:
    """Relative speed lost (1 − V_max(t_cmd)/V_max(0)) over the grid where V_max(0) > 0.5 m/s."""
    table = load_for_vehicle(vehicle)
    losses = []
    for d in D_OD:
        for e in E_TR:
            for k in THRUST:
                base = table.omega(float(d), 1.0, e, k, contract="stop", recovery_dt=recovery_dt).v_max
                if base > 0.5:
                    with_budget = table.omega(float(d), 1.0, e, k, contract="stop", recovery_dt=recovery_dt,
                                              t_cmd=t_cmd).v_max
                    losses.append(1.0 - with_budget / base)
    at6 = [1.0 - table.omega(6.0, 1.0, 0.3, 1.0, contract="stop", recovery_dt=recovery_dt, t_cmd=t_cmd).v_max /
           table.omega(6.0, 1.0, 0.3, 1.0, contract="stop", recovery_dt=recovery_dt).v_max]
    return {"cells": len(losses), "mean_pct": round(100 * float(np.mean(losses)), 2),
            "max_pct": round(100 * float(np.max(losses)), 2), "at_6m_pct": round(100 * at6[0], 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-cmd", type=float, default=0.1, help="the delivery budget [s] (default 0.1)")
    args = ap.parse_args()
    out = {"t_cmd_s": args.t_cmd}
    for vehicle in ("mambo", "x500"):
        out[vehicle] = {"hold": cost(vehicle, args.t_cmd, None), "recovery_brake": cost(vehicle, args.t_cmd, LOOP_DT)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
