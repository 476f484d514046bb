"""The offboard guidance against the planning's latency: Figure 17's flight (fog, four columns, a thrust drop)
flown in lock-step with every plan answered L seconds of vehicle time after it was asked for (`DelayedPlanning`,
as a planning worker on a busy host; the demo's SITL runs at 2×, so 0.2 s of a loaded host's wall time is 0.4 s),
with the plan asked for while braking started where the braking will have left the vehicle when it is due
(`lead`), and without (`measured`: from the state measured at the request, as before). Prints JSON: per latency and
arm, collisions, contract violations, failsafes, the route flown and the worst contour error.

    PYTHONPATH=. python benchmarks/bench_plan_latency.py [--delays 0.2 0.4 0.6]
"""
import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.ground.flights import fly_offboard_scenario  # noqa: E402
from sitl_harness.scenario import load_scenario  # noqa: E402


def fly(delay: float, lead: bool) -> dict:
    def measured(rig):  # the control: plans from the state measured at the request
        rig.daemon.cycle.offboard.guidance.lead_s = (0.0, 0.0)

    rig = fly_offboard_scenario(load_scenario("fig17"), planning_delay_s=delay, setup=None if lead else measured)
    ev, states = rig.log.events, rig.log.states
    return {"delay_s": delay, "arm": "lead" if lead else "measured", "collisions": len(rig.truth["collisions"]),
            "violations": [{"t": round(e["t"], 1), "subsystem": e["subsystem"], "assumed": round(e["assumed"], 2),
                            "observed": round(e["observed"], 2)} for e in ev if e["event"] == "violation_start"],
            "failsafes": [{"t": round(e["t"], 1), "cause": e.get("cause"), "input": e.get("input")}
                          for e in ev if e["event"] == "failsafe"],
            "route_m": round(max((s["x"] for s in states if s.get("x") is not None), default=0.0), 1),
            "e_tr_max_m": round(max((s["e_tr_measured"] for s in states), default=0.0), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--delays", type=float, nargs="+", default=[0.2, 0.4, 0.6])
    args = ap.parse_args()
    rows = [fly(d, lead) for d in args.delays for lead in (True, False)]
    print(json.dumps({"scenario": "fig17 (lock-step, PX4 personality, 62 s)", "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
