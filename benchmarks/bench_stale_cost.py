"""The speed the obstacle sensors' silence budget costs the contracts: cruise V_max with the budget taken as dead time
(`ContractTable.omega(..., t_silent=)`) against V_max without it, at D_od 3, 6 and 10 m (and the mean over D_od 3–12 m,
E_tr 0.3–1 m, thrust 0.7–1), for the shipped vehicles' tables: the governor (the autopilot's Hold), the governor with
its recovery brake, and offboard (the avoid contract). Budgets: 3 periods of a 20 Hz sensor (0.15 s, the default at
that rate), of a 10 Hz sensor (0.3 s), and the 0.5 s time-out; every figure with the command-delivery budget
(`delivery.t_cmd_s`, 0.1 s) in both. Closed form, deterministic. With `--flown N`, also the stress campaign's first N
"sensor dies" scenarios (examples/campaign-stress.yaml) flown in lock-step with the sensor dying at the worst moment
(`companion/ground/sensor_death.py`), per arm: collisions with the budget and with the 0.5 s time-out unbudgeted.
Prints one JSON object.

    PYTHONPATH=. python benchmarks/bench_stale_cost.py [--flown 24]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from companion.onboard.config import DeliveryConfig
from contracts.table import load_for_vehicle

SPEC = Path(__file__).resolve().parents[1] / "examples" / "campaign-stress.yaml"
BUDGETS = {"3_periods_20hz": 0.15, "3_periods_10hz": 0.3, "timeout_0.5s": 0.5}
D_AT = (3.0, 6.0, 10.0)
D_OD = np.arange(3.0, 12.01, 0.5)
E_TR = (0.3, 0.5, 1.0)
THRUST = (0.7, 0.85, 1.0)
LOOP_DT = 0.02
T_CMD = DeliveryConfig().t_cmd_s
ARMS = {"governor": ("stop", None), "governor_brake": ("stop", LOOP_DT), "offboard": ("avoid", None)}


def v_max(table, d: float, e: float, k: float, arm: str, t_silent: float) -> float:
    contract, recovery_dt = ARMS[arm]
    return table.omega(d, 1.0, e, k, contract=contract, recovery_dt=recovery_dt, t_cmd=T_CMD,
                       t_silent=t_silent).v_max


def cost(vehicle: str, arm: str, t_silent: float) -> dict:
    """V_max without and with the budget at D_OD_AT (E_tr 0.3 m, full thrust), and the relative speed lost over the
    grid where V_max without it exceeds 0.5 m/s."""
    table = load_for_vehicle(vehicle)
    at = {}
    for d in D_AT:
        v0, v1 = v_max(table, d, 0.3, 1.0, arm, 0.0), v_max(table, d, 0.3, 1.0, arm, t_silent)
        at[f"{d:g}m"] = {"without": round(v0, 3), "with": round(v1, 3),
                         "cost_pct": round(100 * (1 - v1 / v0), 1) if v0 > 0 else None}
    losses = [1.0 - v_max(table, float(d), e, k, arm, t_silent) / v0
              for d in D_OD for e in E_TR for k in THRUST
              if (v0 := v_max(table, float(d), e, k, arm, 0.0)) > 0.5]
    return {"at": at, "cells": len(losses), "mean_pct": round(100 * float(np.mean(losses)), 1),
            "max_pct": round(100 * float(np.max(losses)), 1)}


def flown(n: int) -> dict:
    """Collisions per arm over the stress campaign's first `n` sensor-dies scenarios, the sensor dying at the worst
    moment: with the budget, and with the old time-out unbudgeted (the negative control)."""
    from companion.ground.campaign import load_spec
    from companion.ground.sensor_death import fly_sensor_dies, sensor_dies_scenarios

    spec = load_spec(SPEC)
    ks = sensor_dies_scenarios(spec)[:n]
    out = {}
    for arm in ARMS:
        row = {"flights": len(ks)}
        for label, unbudgeted in (("budgeted", False), ("unbudgeted_0.5s", True)):
            flights = [fly_sensor_dies(spec, k, arm, unbudgeted) for k in ks]
            rigs = [r for r, _ in flights]
            # the limit in force when the sensor died (the cruise limit: the column not yet seen)
            limits = [max((s["v_cmd"] or 0.0 for s in r.log.states if s["t"] <= t), default=0.0)
                      for r, t in flights if t is not None]
            row[label] = {"collisions": sum(bool(r.truth["collisions"]) for r in rigs),
                          "min_clearance_m": round(min(r.truth["min_clearance_m"] for r in rigs), 2),
                          "v_limit_at_death_mean": round(float(np.mean(limits)), 3)}
        row["v_limit_cost_pct"] = round(100 * (1 - row["budgeted"]["v_limit_at_death_mean"] /
                                               row["unbudgeted_0.5s"]["v_limit_at_death_mean"]), 1)
        out[arm] = row
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flown", type=int, default=0, help="also fly this many sensor-dies scenarios per arm")
    args = ap.parse_args()
    out = {"t_cmd_s": T_CMD, "budgets_s": BUDGETS}
    for vehicle in ("mambo", "x500"):
        out[vehicle] = {arm: {name: cost(vehicle, arm, t) for name, t in BUDGETS.items()} for arm in ARMS}
    if args.flown:
        out["flown"] = flown(args.flown)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
