"""The autopilot's speed overshoot above the speed limit sent (DO_CHANGE_SPEED), per vehicle × personality.

The SITL alone (no daemon): the limit is sent, the vehicle flies its mission along +x. Five ways of meeting a
limit — `takeoff` (armed on the ground, the mission's climb to 2 m then straight on up to the limit: the governor's
first approach), `late` (the same take-off toward the autopilot's own cruise speed, the limit arriving 0.2–0.4 s
after the vehicle starts to move along: PX4 resets its cruising speed at the end of a take-off, until the daemon's
next command arrives; judged from when the vehicle first flies at or below it), `approach` (from a settled hover up
to the limit), `step_up` (cruising at half the limit, the limit raised) and `step_down` (cruising at the
autopilot's own speed, the limit lowered; judged from when the vehicle first flies at or below it) — at limits
1–6 m/s, in still air and in the vehicle file's design wind from ahead, the right, behind and the left (seeds).
Per cell: the largest ground speed above the limit (overshoot, m/s), as a fraction of the limit, and how long the
ground speed stayed above limit + 0.05 m/s. Where it comes from: the mission's reference never exceeds the limit
(sitl_harness/trajectory.py: jerk-limited, no overshoot of its target speed), but the position loop lags the
reference while it accelerates (MPC_XY_P · lag adds to the velocity feed-forward), so the vehicle catches up above
the limit once the reference levels off; wind adds its gusts. Prints one JSON object.

    PYTHONPATH=. python benchmarks/bench_speed_overshoot.py [--vehicles x500 mambo] [--seeds 2]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from companion.onboard.overshoot import overshoot_of
from sitl_harness.mavlink_endpoint import mav
from sitl_harness.scenario import Scenario
from sitl_harness.sim import Sim

LIMITS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
OVER_M_S = 0.05  # the time above the limit is counted above limit + this
CRUISE = 8.0


KINDS = ("takeoff", "late", "approach", "step_up", "step_down")
WIND_FROM = (0.0, 90.0, 180.0, 270.0)  # [deg] the route flies north (+x): ahead, right, behind, left
LATE_S = (0.2, 0.4)  # the `late` limit arrives this long after the vehicle starts to move


def _scenario(vehicle: str, seed: int, wind: float | None, kind: str) -> Scenario:
    """`wind`: where the vehicle file's design wind comes from [deg] (None: still air)."""
    alt = 2.0 if kind in ("takeoff", "late") else 5.0
    return Scenario.model_validate({
        "name": "overshoot", "vehicle": vehicle, "seed": seed,
        "start": {"alt_m": 0.0 if kind in ("takeoff", "late") else alt},
        "route": {"altitude_m": alt, "cruise_speed_m_s": CRUISE, "waypoints": [[0, 0], [600, 0]]},
        "wind": {"from_deg": wind} if wind is not None else {"mean_m_s": 0.0, "gust_m_s": 0.0}})


def _speed(sim: Sim, v: float) -> None:
    sim.autopilot.handle_command(mav.MAV_CMD_DO_CHANGE_SPEED, (1.0, v, -1.0, 0.0, 0.0, 0.0, 0.0))


def fly(vehicle: str, personality: str, kind: str, limit: float, seed: int, wind: float | None,
        late_s: float = 0.3) -> dict:
    """One flight: the overshoot above the limit once met (`overshoot_of`: as the daemon judges it) [m/s], and
    how long the ground speed was above limit + OVER_M_S then [s]."""
    sim = Sim(_scenario(vehicle, seed, wind, kind), personality)
    sim.step(1.0 if kind in ("takeoff", "late") else 2.0)  # on the ground; or the hover settles
    ap = sim.autopilot
    if kind in ("takeoff", "late"):
        ap.arm(True)
        sim.step(0.5)
    ap.set_mode("mission")
    first = {"takeoff": limit, "late": CRUISE, "approach": limit, "step_up": 0.5 * limit, "step_down": CRUISE}[kind]
    _speed(sim, first)
    t, gs, lim = [], [], []

    def run(seconds: float, v: float | None, until=None) -> None:  # (v None: before the limit judged)
        for _ in range(int(round(seconds / sim.tick_dt))):
            if until is not None and until():
                return
            sim.tick()
            t.append(sim.time_s)
            gs.append(float(np.hypot(*sim.model.vel[:2])))
            lim.append(v)

    if kind == "late":  # climbed, and moving along: then the limit, late
        run(30.0, None, lambda: np.hypot(*sim.model.vel[:2]) >= 0.05 and sim.model.pos[2] <= -1.8)
        run(late_s, None)
    elif kind in ("step_up", "step_down"):
        run(12.0, None)  # cruising at the first speed
    if kind != "approach" and kind != "takeoff":
        _speed(sim, limit)
    run(20.0 if kind in ("takeoff", "late") else 15.0, limit)
    r = overshoot_of(t, gs, lim, ap.settings.jerk)
    k0 = len(t) - int(round((20.0 if kind in ("takeoff", "late") else 15.0) / sim.tick_dt))
    above = sum(sim.tick_dt for v in gs[k0:] if v > limit + OVER_M_S)
    return {"overshoot_m_s": round(r["overshoot_m_s"], 4) if r["overshoot_m_s"] is not None else None,
            "above_s": round(above, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", nargs="+", default=["x500", "mambo"])
    ap.add_argument("--personalities", nargs="+", default=["px4", "ardupilot"])
    ap.add_argument("--seeds", type=int, default=2)
    a = ap.parse_args()
    out: dict = {"limits_m_s": list(LIMITS), "over_m_s": OVER_M_S, "cells": {}}
    for veh in a.vehicles:
        for pers in a.personalities:
            rows = []
            for kind in KINDS:
                for limit in LIMITS:
                    for wind, seeds in ((None, [0]), *((w, list(range(1, a.seeds + 1))) for w in WIND_FROM)):
                        for seed in seeds:
                            for late_s in (LATE_S if kind == "late" else (None,)):
                                r = fly(veh, pers, kind, limit, seed, wind, late_s or 0.0)
                                rows.append({"kind": kind, "limit": limit, "wind": wind, "seed": seed}
                                            | ({"late_s": late_s} if late_s else {}) | r)
            still = [r for r in rows if r["wind"] is None]
            windy = [r for r in rows if r["wind"] is not None]
            cell = {
                "still_max_m_s": max(r["overshoot_m_s"] for r in still),
                "still_max_fraction": max(r["overshoot_m_s"] / r["limit"] for r in still),
                "wind_max_m_s": max(r["overshoot_m_s"] for r in windy),
                "wind_max_fraction": max(r["overshoot_m_s"] / r["limit"] for r in windy),
                "max_above_s": max(r["above_s"] for r in rows),
                "by_kind_m_s": {k: max(r["overshoot_m_s"] for r in rows if r["kind"] == k)
                                for k in KINDS},
                "by_limit_m_s": {str(v): max(r["overshoot_m_s"] for r in rows if r["limit"] == v) for v in LIMITS},
                "flights": rows,
            }
            out["cells"][f"{veh}/{pers}"] = cell
    print(json.dumps(out))


if __name__ == "__main__":
    main()
