"""Offboard among walls (one JSON object on stdout): lock-step flights of the real daemon against the real SITL over
real MAVLink bytes (companion/ground/flights.py) through the clear-air worlds of companion/ground/false_alarms.py
that break the avoid contract's one-column assumption (a facade flown through its doorway; a corridor with a turn).

A flight ends at the route's end, or 3 s after the daemon's first stop (the pilot takes over), as in
benchmarks/false_alarms.py. Per world: flights, wall touches (flights with a collision), route completion, mean
ground speed while engaged in the air, and the share of that time flown under the stop contract.

    python benchmarks/offboard_walls.py [--worlds doorway corridor] [--seeds 1 20] [--model sector]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from itertools import pairwise
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.ground.false_alarms import CRUISE_M_S, config_of, scenario_of
from companion.ground.flights import Rig, engage_and_fly

STOPS = ("failsafe", "hold_trigger", "no_avoiding_plan")
AFTER_STOP_S = 3.0


def fly(world: str, seed: int, model: str) -> dict:
    sc = scenario_of("offboard", model, world, seed)
    route = sc["route"]["waypoints"]
    length = sum(math.dist(a, b) for a, b in pairwise(route))
    rig = Rig(sc, "px4", config=config_of("offboard", route, model))
    end, stopped = route[-1], []

    def watch(r) -> bool:
        p = r.truth["pos"]
        if not stopped and any(e["event"] in STOPS for e in r.log.events[-8:]):
            stopped.append(r.sim.time_s)
        return (math.hypot(p[0] - end[0], p[1] - end[1]) < 1.0 and r.sim.time_s > 5.0) or \
            (bool(stopped) and r.sim.time_s >= stopped[0] + AFTER_STOP_S)

    engage_and_fly(rig, length / CRUISE_M_S + 15.0, until=watch)
    p = rig.truth["pos"]
    flown = [s for s in rig.log.states if s.get("engaged") and s.get("z") is not None and s["z"] < -0.5
             and s["ground_speed"] == s["ground_speed"]]
    return {"world": world, "seed": seed, "collisions": len(rig.truth["collisions"]),
            "arrived": math.hypot(p[0] - end[0], p[1] - end[1]) < 1.0,
            "mean_speed": sum(s["ground_speed"] for s in flown) / len(flown) if flown else 0.0,
            "stop_share": sum(s.get("contract") == "stop" for s in flown) / len(flown) if flown else 0.0,
            "min_clearance_m": rig.truth.get("min_clearance_m"), "stopped_s": stopped[0] if stopped else None}


def summarise(rows: list[dict]) -> dict:
    n = len(rows)
    return {"flights": n, "touches": sum(r["collisions"] > 0 for r in rows),
            "route_completion": round(sum(r["arrived"] for r in rows) / n, 3) if n else None,
            "mean_speed_m_s": round(sum(r["mean_speed"] for r in rows) / n, 3) if n else None,
            "stop_contract_share": round(sum(r["stop_share"] for r in rows) / n, 3) if n else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", nargs="+", default=["doorway", "corridor"], choices=["doorway", "corridor"])
    ap.add_argument("--seeds", nargs=2, type=int, default=[1, 20], metavar=("FIRST", "LAST"))
    ap.add_argument("--model", default="sector", choices=["sector", "depth_camera", "single_beam"])
    a = ap.parse_args()
    if a.seeds[0] < 1 or a.seeds[1] < a.seeds[0]:
        ap.exit(2, "offboard_walls.py: --seeds FIRST LAST with 1 ≤ FIRST ≤ LAST\n")
    t0, rows = time.time(), []
    for w in a.worlds:
        for seed in range(a.seeds[0], a.seeds[1] + 1):
            rows.append(fly(w, seed, a.model))
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    print(json.dumps({"benchmark": "offboard_walls", "model": a.model, "seeds": a.seeds, "wall_s": round(time.time() - t0, 1),
                      "all": summarise(rows), "per_world": {w: summarise([r for r in rows if r["world"] == w])
                                                            for w in a.worlds},
                      "touched": [(r["world"], r["seed"]) for r in rows if r["collisions"]]}))


if __name__ == "__main__":
    main()
