"""`contract-guard calibrate plan`: a mission that exercises the contract's envelope in open space.

Per speed of a ladder up to the top of the controller contract's speed axis (every speed of the table's
`E_tr_pred` v_max grid from 1 m/s), in a lawn-mower pattern of parallel lanes along north:
1. `DO_CHANGE_SPEED v`, a straight leg (accelerate at the vehicle's braking/acceleration limit, then
   cruise `CRUISE_S`) to waypoint A — a **hold leg**: the daemon in governor mode (or the operator)
   commands Hold/Brake `hold_before_m` before A, while at speed v; after `REST_S` at rest the mission
   is resumed (these are the legs "the daemon commands itself", marked in the files);
2. on to waypoint B (collinear, re-accelerating to v), where `DO_CHANGE_SPEED v/2` gives a speed step
   down at full speed, then waypoint C and `LOITER_TIME` — the autopilot's own stop from v/2;
3. a **zig-zag** at v (with `zigzag`): legs of `ZIGZAG_LEG_S · v + ZIGZAG_LEG_M` metres at ±30° from the lane
   (60° turns), then at ±60° (120° turns), joined by a 30° turn — the turns' braking, re-acceleration and
   overshoot reach the tilts of the contract's tilt axis that the autopilot's acceleration limit allows at
   that speed, with `ZIGZAG_LEGS` legs each (enough 1 s windows per (speed, tilt) cell to cover it, pooled over
   a PX4 and an ArduPilot flight); no 90° turn, so a 90° zig-zag stays a held-out manoeuvre;
4. a sideways leg of `2·turn radius` to the next leg's start: two 90° turns.
Every waypoint is at the plan's altitude, relative to home. The files: `calibration.plan` (QGroundControl)
and `calibration.waypoints` (MAVProxy / Mission Planner), the same items, and `calibration-legs.json`
(the marked legs; also inside both files). Pure geometry apart from `write_plan_files`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from contracts.geodesy import geo_from_ne
from contracts.missionfile import (
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    Item,
    MissionPlan,
    write_plan,
    write_waypoints,
)
from contracts.stop import stopping_distance

MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_NAV_LOITER_TIME = 19
CRUISE_S = 10.0  # steady cruise per speed before the Hold [s]: ≥ 10 one-second contour windows
REST_S = 2.0  # at rest in Hold before the mission resumes [s]
LOITER_S = 2.0
ZIGZAG_LEG_S = 8.0  # a zig-zag leg: this many seconds at v …
ZIGZAG_LEG_M = 4.0  # … plus this many metres (room to accelerate and turn)
ZIGZAG_LEGS = 4  # legs per turn angle
ZIGZAG_DEG = (30.0, 60.0)  # legs at ± these angles from the lane: turns of 60° and 120°
HOME = (47.397742, 8.545594, 488.0)  # PX4 SITL's default home (the SITL's too)


def speed_ladder(v_top: float, v_grid=None, every: int = 1) -> list[float]:
    """The plan's speeds: the grid's speeds from 1 m/s up to `v_top`, every `every`-th one (and the top)."""
    grid = [float(v) for v in (v_grid if v_grid is not None else range(1, int(v_top) + 1)) if 1.0 <= v <= v_top]
    out = grid[::every]
    if grid and out[-1] != grid[-1]:
        out.append(grid[-1])
    return out


def zigzag_points(start, sign: float, v: float) -> list[tuple[float, float]]:
    """The zig-zag's waypoints (north, east) from `start`, heading `sign` along north (see the module). Pure."""
    n, e = start
    leg = ZIGZAG_LEG_S * v + ZIGZAG_LEG_M
    out = []
    for k, deg in enumerate(ZIGZAG_DEG):
        for i in range(ZIGZAG_LEGS):
            # ±deg alternately; the second set starts on the side the first ended on (a 30° turn, no 90°)
            side = (1 if i % 2 == 0 else -1) * (1 if k % 2 == 0 else -1)
            a = math.radians(deg)
            n += sign * leg * math.cos(a)
            e += side * leg * math.sin(a)
            out.append((n, e))
    return out


def plan_legs(vehicle, speeds: list[float], altitude_m: float = 5.0, turn_radius_m: float = 4.0,
              zigzag: bool = True) -> dict:
    """The plan in local metres: {"points": [(north, east)], "items": [(kind, …)], "legs": [...]}. Pure."""
    a = vehicle.braking.accel_max_m_s2
    j = vehicle.braking.jerk_max_m_s3
    items, legs = [], []
    east, sign = 0.0, 1.0
    north = 0.0
    for i, v in enumerate(speeds):
        d_acc = v * v / a + v * a / j  # accelerate (and the jerk-limited ramp), with room to spare
        d_stop = stopping_distance(v, a, j, vehicle.braking.hold_switch_s)
        hold_before = d_stop + 2.0
        a_north = north + sign * (d_acc + CRUISE_S * v + hold_before)
        b_north = a_north + sign * (d_acc + 3.0 * v)
        c_north = b_north + sign * (v * v / (4 * a) + 2.0 * v + 2.0)
        items.append(("speed", v))
        items.append(("wp", (a_north, east)))
        legs.append({"kind": "hold", "speed_m_s": v, "item": len(items) - 1, "hold_before_m": round(hold_before, 2),
                     "rest_s": REST_S, "commanded_by": "daemon (governor mode, config calibration.legs) or the operator"})
        items.append(("wp", (b_north, east)))
        items.append(("speed", max(v / 2, 0.5)))
        legs.append({"kind": "step_down", "speed_m_s": v, "to_m_s": max(v / 2, 0.5), "item": len(items) - 1,
                     "commanded_by": "mission"})
        items.append(("wp", (c_north, east)))
        items.append(("loiter", LOITER_S, (c_north, east)))
        legs.append({"kind": "autopilot_stop", "speed_m_s": max(v / 2, 0.5), "item": len(items) - 2,
                     "commanded_by": "autopilot (waypoint with loiter)"})
        if zigzag:
            items.append(("speed", v))
            first = len(items)
            for pt in zigzag_points((c_north, east), sign, v):
                items.append(("wp", pt))
            legs.append({"kind": "zigzag", "speed_m_s": v, "item": first, "items": len(items) - first,
                         "turns_deg": [2 * d for d in ZIGZAG_DEG], "commanded_by": "mission"})
            c_north, east = items[-1][1]
            if i == len(speeds) - 1:  # the plan ends at rest at its last waypoint (no stop at the mission's end)
                items.append(("loiter", LOITER_S, (c_north, east)))
        if i < len(speeds) - 1:
            east += 2 * turn_radius_m
            items.append(("speed", min(v, 2.0)))
            items.append(("wp", (c_north, east)))
            legs.append({"kind": "turn", "speed_m_s": min(v, 2.0), "item": len(items) - 1, "radius_m": turn_radius_m,
                         "commanded_by": "mission"})
        north, sign = c_north, -sign
    return {"items": items, "legs": legs, "altitude_m": altitude_m, "speeds_m_s": speeds}


def mission_plan(vehicle, speeds: list[float], altitude_m: float = 5.0, home=HOME, zigzag: bool = True) -> MissionPlan:
    """The legs as MAVLink mission items (global frame, altitude relative to home)."""
    lay = plan_legs(vehicle, speeds, altitude_m, zigzag=zigzag)
    lat0, lon0, _ = home
    out = []
    for it in lay["items"]:
        if it[0] == "speed":  # DO_CHANGE_SPEED: param1 speed type (1 ground speed), param2 speed, param3 −1
            out.append(Item(MAV_CMD_DO_CHANGE_SPEED, MAV_FRAME_GLOBAL_RELATIVE_ALT, (1.0, it[1], -1.0, 0.0), 0.0, 0.0, 0.0))
            continue
        n, e = it[1] if it[0] == "wp" else it[2]
        lat, lon = geo_from_ne(n, e, lat0, lon0)
        if it[0] == "wp":
            out.append(Item(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, (0.0, 0.0, 0.0, math.nan), lat, lon, altitude_m))
        else:
            out.append(Item(MAV_CMD_NAV_LOITER_TIME, MAV_FRAME_GLOBAL_RELATIVE_ALT, (it[1], 0.0, 0.0, math.nan), lat, lon, altitude_m))
    legs = [{**leg, "mission_seq_plan": leg["item"], "mission_seq_waypoints": leg["item"] + 1} for leg in lay["legs"]]
    for leg in legs:  # where the daemon commands a hold leg: its waypoint (the daemon places it from HOME_POSITION)
        if leg["kind"] == "hold":
            wp = out[leg["item"]]
            leg.update(lat_deg=wp.x, lon_deg=wp.y, alt_m=wp.z)
    extra = {"kind": "calibration plan", "vehicle": vehicle.name, "speeds_m_s": speeds, "altitude_m": altitude_m,
             "legs": legs,
             # the mission's own speed items: a governor flying the plan never sends more than the speed in force
             "mission_speeds": [{"mission_seq_plan": k, "mission_seq_waypoints": k + 1, "speed_m_s": it.params[1]}
                                for k, it in enumerate(out) if it.command == MAV_CMD_DO_CHANGE_SPEED],
             "note": "mission_seq_plan: index in the .plan's items (PX4's sequence); mission_seq_waypoints: the "
                     ".waypoints sequence (item 0 is home; ArduPilot's); a hold leg's lat_deg/lon_deg/alt_m: its "
                     "waypoint (altitude relative to home)"}
    return MissionPlan(tuple(home), out, extra, cruise_speed_m_s=speeds[0] if speeds else 1.0)


def write_plan_files(vehicle, out_dir: Path, speeds: list[float], altitude_m: float = 5.0, zigzag: bool = True) -> dict:
    out_dir.mkdir(parents=True, exist_ok=True)
    mp = mission_plan(vehicle, speeds, altitude_m, zigzag=zigzag)
    write_plan(out_dir / "calibration.plan", mp)
    write_waypoints(out_dir / "calibration.waypoints", mp)
    (out_dir / "calibration-legs.json").write_text(json.dumps(mp.extra, indent=1) + "\n")
    holds = [leg for leg in mp.extra["legs"] if leg["kind"] == "hold"]
    return {"plan": str(out_dir / "calibration.plan"), "waypoints": str(out_dir / "calibration.waypoints"),
            "legs_file": str(out_dir / "calibration-legs.json"), "items": len(mp.items), "speeds_m_s": speeds,
            "hold_legs": len(holds), "legs": len(mp.extra["legs"]), "altitude_m": altitude_m}
