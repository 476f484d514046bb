"""The autopilot's speed overshoot above the speed limit sent (DO_CHANGE_SPEED), per vehicle × personality.

The SITL alone (no daemon): the vehicle hovers, the limit is sent, it flies its mission along +x. Three ways of
meeting a limit — `approach` (from hover up to the limit), `step_up` (cruising at half the limit, the limit raised)
and `step_down` (cruising at the autopilot's own speed, the limit lowered; judged from when the vehicle first flies
at or below it) — at limits 1–6 m/s, in still air and in the vehicle file's design wind (seeds). Per cell: the
largest ground speed above the limit (overshoot, m/s), as a fraction of the limit, and how long the ground speed
stayed above limit + 0.05 m/s. Where it comes from: the mission's reference never exceeds the limit
(sitl_harness/trajectory.py: jerk-limited, no overshoot of its target speed), but the position loop lags the
reference while it accelerates (MPC_XY_P · lag adds to the velocity feed-forward), so the vehicle catches up above
the limit once the reference levels off; wind adds its gusts. Prints one JSON object.

    PYTHONPATH=. python benchmarks/bench_speed_overshoot.py [--vehicles x500 mambo] [--seeds 3]
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from sitl_harness.mavlink_endpoint import mav
from sitl_harness.scenario import Scenario
from sitl_harness.sim import Sim

LIMITS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
OVER_M_S = 0.05  # the time above the limit is counted above limit + this
CRUISE = 8.0


def _scenario(vehicle: str, seed: int, wind: bool) -> Scenario:
    return Scenario.model_validate({
        "name": "overshoot", "vehicle": vehicle, "seed": seed, "start": {"alt_m": 5.0},
        "route": {"altitude_m": 5.0, "cruise_speed_m_s": CRUISE, "waypoints": [[0, 0], [600, 0]]},
        **({} if wind else {"wind": {"mean_m_s": 0.0, "gust_m_s": 0.0}})})


def _speed(sim: Sim, v: float) -> None:
    sim.autopilot.handle_command(mav.MAV_CMD_DO_CHANGE_SPEED, (1.0, v, -1.0, 0.0, 0.0, 0.0, 0.0))


def fly(vehicle: str, personality: str, kind: str, limit: float, seed: int, wind: bool) -> dict:
    """One flight: (overshoot [m/s], time above limit + OVER_M_S [s]) after the limit is met."""
    sim = Sim(_scenario(vehicle, seed, wind), personality)
    sim.step(2.0)  # hover settles
    ap = sim.autopilot
    ap.set_mode("mission")
    first = {"approach": limit, "step_up": 0.5 * limit, "step_down": CRUISE}[kind]
    _speed(sim, first)
    if kind != "approach":
        sim.step(12.0)  # cruising at the first speed
        _speed(sim, limit)
    worst, above_s, met = -math.inf, 0.0, kind != "step_down"
    for _ in range(int(15.0 / sim.tick_dt)):
        sim.tick()
        gs = float(np.hypot(*sim.model.vel[:2]))
        met = met or gs <= limit
        if met:
            worst = max(worst, gs - limit)
            above_s += sim.tick_dt if gs > limit + OVER_M_S else 0.0
    return {"overshoot_m_s": round(worst, 4), "above_s": round(above_s, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", nargs="+", default=["x500", "mambo"])
    ap.add_argument("--personalities", nargs="+", default=["px4", "ardupilot"])
    ap.add_argument("--seeds", type=int, default=3)
    a = ap.parse_args()
    out: dict = {"limits_m_s": list(LIMITS), "over_m_s": OVER_M_S, "cells": {}}
    for veh in a.vehicles:
        for pers in a.personalities:
            rows = []
            for kind in ("approach", "step_up", "step_down"):
                for limit in LIMITS:
                    for wind, seeds in ((False, [0]), (True, list(range(1, a.seeds + 1)))):
                        for seed in seeds:
                            r = fly(veh, pers, kind, limit, seed, wind)
                            rows.append({"kind": kind, "limit": limit, "wind": wind, "seed": seed} | r)
            still = [r for r in rows if not r["wind"]]
            windy = [r for r in rows if r["wind"]]
            cell = {
                "still_max_m_s": max(r["overshoot_m_s"] for r in still),
                "still_max_fraction": max(r["overshoot_m_s"] / r["limit"] for r in still),
                "wind_max_m_s": max(r["overshoot_m_s"] for r in windy),
                "wind_max_fraction": max(r["overshoot_m_s"] / r["limit"] for r in windy),
                "max_above_s": max(r["above_s"] for r in rows),
                "by_kind_m_s": {k: max(r["overshoot_m_s"] for r in rows if r["kind"] == k)
                                for k in ("approach", "step_up", "step_down")},
                "by_limit_m_s": {str(v): max(r["overshoot_m_s"] for r in rows if r["limit"] == v) for v in LIMITS},
                "flights": rows,
            }
            out["cells"][f"{veh}/{pers}"] = cell
    print(json.dumps(out))


if __name__ == "__main__":
    main()
