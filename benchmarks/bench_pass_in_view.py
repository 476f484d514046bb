"""Whether offboard's passes keep the direction of travel in the sensor's view (one JSON object on stdout).

Figure 17's flight (companion/ground/flights.py `fly_offboard_scenario`: the Mambo at 2 m, a 60° sensor, fog that
shows 3 m for the first 25 s, five columns on a 270 m route) in lock-step, every plan answered `--delays` seconds
of vehicle time after it was asked for (a planning worker on a busy host). Each daemon cycle samples the SITL's
truth; per column, over the approach and the pass (8 m before its centre to 2 m past it, above 1 m/s):

- `track_heading_deg`: the largest angle between the direction of travel and the heading (the sensor's axis). The
  daemon's D_od is measured along the direction of travel: past the half field of view less the heading's lag the
  contract budgets (30° − 8°), the sensor would no longer look where the vehicle goes;
- `track_off_route_deg`: the largest angle of the track off the route (how far the pass turned);
- `speed_max_m_s`, and per flight the contract switches, violations and collisions.

    PYTHONPATH=. python benchmarks/bench_pass_in_view.py [--delays 0 0.3 0.6]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.ground.flights import fly_offboard_scenario
from companion.onboard.contract_in_force import LAG_BUDGET_DEG
from sitl_harness.scenario import load_scenario


def _angle(a: float) -> float:
    return abs(math.degrees((a + math.pi) % (2 * math.pi) - math.pi))


def fly(delay: float) -> dict:
    scenario = load_scenario("fig17")
    samples = []

    def sampled(rig):
        step = rig.daemon.step

        def step_and_sample():
            step()
            tr = rig.sim.truth()
            samples.append((tr["pos"][0], tr["pos"][1], tr["vel"][0], tr["vel"][1], tr["yaw"]))

        rig.daemon.step = step_and_sample

    rig = fly_offboard_scenario(scenario, seconds=72.0, planning_delay_s=delay or None, setup=sampled)
    columns = []
    for c in scenario.world.columns:
        near = [s for s in samples if c.x_m - 8.0 <= s[0] <= c.x_m + 2.0 and math.hypot(s[2], s[3]) > 1.0]
        if not near:
            columns.append({"column": c.name, "flown": False})
            continue
        track = [(math.atan2(vy, vx), yaw, math.hypot(vx, vy)) for _, _, vx, vy, yaw in near]
        columns.append({"column": c.name, "flown": True,
                        "track_heading_deg": round(max(_angle(a - yaw) for a, yaw, _ in track), 1),
                        "track_off_route_deg": round(max(_angle(a) for a, _, _ in track), 1),
                        "speed_max_m_s": round(max(v for _, _, v in track), 2)})
    events = [(round(e["t"], 1), e["event"], e.get("contract") or e.get("subsystem")) for e in rig.log.events
              if e["event"] in ("violation_start", "hold_trigger")
              or e["event"] == "contract_in_force" and e["contract"] == "stop"]
    return {"delay_s": delay, "columns": columns, "stop_contract_or_violations": events,
            "collisions": len(rig.truth["collisions"]),
            "route_m": round(max(s[0] for s in samples), 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--delays", type=float, nargs="+", default=[0.0, 0.3, 0.6])
    args = ap.parse_args()
    flights = [fly(d) for d in args.delays]
    sensor = load_scenario("fig17").sensor
    print(json.dumps({"half_fov_deg": sensor.fov_deg / 2, "lag_budget_deg": LAG_BUDGET_DEG, "flights": flights},
                     indent=1))


if __name__ == "__main__":
    main()
