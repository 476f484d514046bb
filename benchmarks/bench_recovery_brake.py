"""The recovery brake's speed gain (governor.recovery_brake; docs/daemon.md, "The recovery brake"): the governor's
V_max from the shipped tables under the autopilot's Hold's stop contract and under the brake's own (contracts/stop.py
`recovery_brake`, 50 Hz loop), at a few D_od for both vehicles (R_obst 1 m, measured E_tr 0.3 m, thrust ratio 1.0
and 0.7, the default command-delivery budget); with `--fly`, the lock-step SITL two-stop flights of
tests/test_recovery_brake_lockstep.py (Mambo, sensor 6 m: the first stop shows the brake's switch, the second flies
from its limit), both personalities: the speed at the second stop command and the braking distance from it; with
`--sweep`, the brake on both vehicles and personalities at a second column 8 m (first seen while speeding up) to
28 m past where the vehicle rests after its first stop, in wind (a second column already in the sensor's view where the vehicle rests after its
first stop is the pilot's to mind: the daemon stood down from it when the mission was resumed): collisions and the
least clearance, and the controller violations (the brake's tracking error against its own E_tr_pred). Prints one
JSON object.

    PYTHONPATH=. python benchmarks/bench_recovery_brake.py [--fly] [--sweep]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.onboard.config import DeliveryConfig  # noqa: E402
from contracts.table import load_for_vehicle  # noqa: E402

D_OD = (3.0, 4.0, 6.0, 9.0, 12.0)
LOOP_DT = 0.02
T_CMD = DeliveryConfig().t_cmd_s


def limits(vehicle: str, thrust_ratio: float) -> list[dict]:
    table = load_for_vehicle(vehicle)
    out = []
    for d in D_OD:
        hold = table.omega(d, 1.0, 0.3, thrust_ratio, contract="stop", t_cmd=T_CMD).v_max
        brake = table.omega(d, 1.0, 0.3, thrust_ratio, contract="stop", recovery_dt=LOOP_DT, t_cmd=T_CMD,
                            e_brake=True).v_max
        out.append({"d_od_m": d, "v_max_hold": round(hold, 3), "v_max_brake": round(brake, 3),
                    "gain": round(brake / hold, 3) if hold > 0 else None})
    return out


def controller_violations(rig) -> int:
    """The flight's controller violations (E_tr above the E_tr_pred the supervisor judged it against)."""
    return sum(e["subsystem"] == "controller" for e in rig.log.named("violation_start"))


def flights() -> dict:
    from tests.test_recovery_brake_lockstep import flight, second_stop, v_max

    out = {}
    for personality in ("px4", "ardupilot"):
        for brake in (False, True):
            rig = flight(personality, brake, second=70.0)
            _, v, d = second_stop(rig)
            out[f"{personality}_{'brake' if brake else 'hold'}"] = {
                "v_max": round(v_max(rig), 3), "speed_at_stop_command": round(v, 3), "braking_distance_m": round(d, 3),
                "min_clearance_m": round(rig.truth["min_clearance_m"], 3), "collisions": len(rig.truth["collisions"]),
                "controller_violations": controller_violations(rig)}
    return out


def sweep() -> dict:
    from tests.test_recovery_brake_lockstep import BESIDE, two_stops

    wind, out = {"mean_m_s": 1.0, "from_deg": 90, "gust_m_s": 0.5}, []
    for vehicle in ("mambo", "x500"):
        for personality in ("px4", "ardupilot"):
            for x_col in (8.0, 10.0, 14.0, 20.0, 28.0):  # past where it rests (4 m before the first): beyond the sensor
                rig = two_stops(personality, True, BESIDE["x_m"] - 4.0 + x_col, vehicle=vehicle, wind=wind, seed=2)
                braked = sum(e["cmd"] == "offboard" for e in rig.log.named("command")) == 2
                out.append({"vehicle": vehicle, "autopilot": personality, "x_col_m": x_col, "braked": braked,
                            "v_max": round(max(s["v_max"] or 0.0 for s in rig.log.states), 3),
                            "min_clearance_m": round(rig.truth["min_clearance_m"], 3),
                            "collisions": len(rig.truth["collisions"]),
                            "controller_violations": controller_violations(rig)})
    return {"flights": out, "collisions": sum(f["collisions"] for f in out),
            "controller_violations": sum(f["controller_violations"] for f in out),
            "least_clearance_m": min(f["min_clearance_m"] for f in out), "all_braked": all(f["braked"] for f in out)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fly", action="store_true", help="also fly the lock-step SITL column flights (about a minute)")
    ap.add_argument("--sweep", action="store_true", help="also fly the brake at second columns 8 to 28 m on (20 flights)")
    args = ap.parse_args()
    res = {"settings": {"r_obst_m": 1.0, "e_tr_measured_m": 0.3, "loop_hz": 1.0 / LOOP_DT},
           "v_max": {v: {str(tr): limits(v, tr) for tr in (1.0, 0.7)} for v in ("mambo", "x500")}}
    if args.fly:
        res["flights"] = flights()
    if args.sweep:
        res["sweep"] = sweep()
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
