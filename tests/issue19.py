"""Issue 19's Monte Carlo flights, flown again in lock-step from the parameters the issue gives.

One column of true radius `r_true` whose centre is `offset` to the side of a straight route along +x, at
`x_col`; the sensor (OBSTACLE_DISTANCE, 60°, 5° bins) rated at `d_od`, so the column is revealed when the
vehicle is `d_od` from its surface; the daemon configured with `r_obst`; the thrust ratio set by a fault
at t = 0; wind mean/gust/direction; sensor latency; SITL seed. As the campaign flies them: offboard from a
hover at 2 m, the route ending `after_m` beyond the column; governor on an autopilot mission from the ground.
"""

from __future__ import annotations

import math

import numpy as np

from tests.lockstep import Rig
from tests.test_offboard_lockstep import engage_and_fly

ARRIVE_M = 1.0  # within this of the last waypoint: the route is complete (the campaign's)


class Trace:
    """Truth, and what the daemon judged, at every daemon cycle (for assertions only)."""

    def __init__(self):
        self.rows: list[dict] = []

    def __call__(self, rig) -> bool:
        tr = rig.truth
        g = rig.daemon.offboard.guidance if rig.daemon.offboard is not None else None
        plan = g.plan if g is not None else None
        self.rows.append({"t": tr["time_s"], "x": float(tr["pos"][0]), "y": float(tr["pos"][1]),
                          "v": float(np.hypot(*tr["vel"][:2])), "plan": plan.kind if plan is not None else None})
        return False


def scenario(*, vehicle, personality, d_od, r_true, offset, thrust, wind, gust, wind_from, latency, seed,
             x_col=30.0, mode="offboard", after_m=15.0, cruise=8.0):
    sc = {"name": "issue19", "vehicle": vehicle, "seed": seed,
          "world": {"columns": [{"x_m": x_col, "y_m": offset, "radius_m": r_true, "name": "column"}]},
          "sensor": {"fov_deg": 60, "increment_deg": 5, "max_range_m": d_od, "rate_hz": 20, "latency_s": latency},
          "wind": {"mean_m_s": wind, "from_deg": wind_from, "gust_m_s": gust},
          "faults": [{"at_s": 0.0, "thrust_ratio": thrust}]}
    if mode == "offboard":
        sc["start"] = {"alt_m": 2.0}
        sc["params"] = {"COM_OBL_RC_ACT": 5} if personality == "px4" else {}
    else:
        sc["route"] = {"altitude_m": 2.0, "cruise_speed_m_s": cruise, "waypoints": [[0, 0], [x_col + after_m, 0]]}
    return sc


def config(*, vehicle, r_obst, x_end, mode="offboard"):
    cfg = {"vehicle": vehicle, "mode": mode, "engage": True, "contract": {"r_obst_m": r_obst}}
    if mode == "offboard":
        cfg.update({"sensors": [{"kind": "obstacle_distance", "h_fov_deg": 60}],
                    "route": {"waypoints": [[0, 0], [x_end, 0]], "altitude_m": 2.0}})
    return cfg


def fly(*, mode="offboard", seconds=30.0, x_col=30.0, after_m=15.0, r_obst, **kw) -> dict:
    """Fly one case; the rig, the trace and the figures the assertions need."""
    sc = scenario(mode=mode, x_col=x_col, after_m=after_m, **kw)
    x_end = x_col + after_m
    rig = Rig(sc, kw["personality"], config=config(vehicle=kw["vehicle"], r_obst=r_obst, x_end=x_end, mode=mode))
    trace = Trace()
    if mode == "offboard":
        engage_and_fly(rig, seconds, trace)
    else:
        rig.run(1.0, trace)
        rig.arm()
        rig.run(0.5, trace)
        rig.start_mission()
        rig.run(seconds, trace)
    truth = rig.truth
    col = (x_col, kw["offset"])
    clearance = min(math.hypot(r["x"] - col[0], r["y"] - col[1]) for r in trace.rows) - kw["r_true"]
    return {"rig": rig, "trace": trace, "collided": bool(truth["collisions"]), "clearance_m": clearance,
            "end_dist_m": math.hypot(truth["pos"][0] - x_end, truth["pos"][1]),
            "completed": any(math.hypot(r["x"] - x_end, r["y"]) < ARRIVE_M for r in trace.rows),
            "late": rig.log.named("late_detection") if hasattr(rig.log, "named") else [],
            "holds": [e for e in rig.log.events if e["event"] in ("hold_trigger", "failsafe")]}
