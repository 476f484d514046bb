"""Mid-swerve fail-safes in offboard (issue 19 item 1), for tests and the figures in the report.

The head-on offboard flight of `test_offboard_lockstep`; once the daemon flies its avoidance pass, a
seeded delay later, the sensor is fogged honestly to 0.3 m (D_od 0.3 m: no safe speed, a fail-safe).
Measured: the speed, the acceleration along it and the limit in force at the fail-safe, the distance travelled
after it and the fastest speed after it, against the stop contract's distance from that state
(`stopping_distance_from`: PX4's Hold and ArduPilot's Brake start from the acceleration the vehicle has)."""

from __future__ import annotations

import math
import random

import numpy as np

from contracts.stop import braking_decel, stop_dead_time, stopping_distance_from
from tests.lockstep import Rig
from tests.test_offboard_lockstep import DESIGN_WIND, engage_and_fly, offboard_config, offboard_scenario


class _Inject:
    def __init__(self, delay_s: float):
        self.delay_s, self.t_pass, self.t_fs = delay_s, None, None
        self.rows: list[tuple[float, float, float, float, float, float]] = []  # (t, x, y, speed, vx, vy)

    def __call__(self, rig) -> bool:
        tr = rig.truth
        self.rows.append((tr["time_s"], float(tr["pos"][0]), float(tr["pos"][1]), float(np.hypot(*tr["vel"][:2])),
                          float(tr["vel"][0]), float(tr["vel"][1])))
        plan = rig.daemon.offboard.guidance.plan
        if self.t_pass is None and plan is not None and plan.kind == "pass":
            self.t_pass = tr["time_s"]
        if self.t_pass is not None and self.t_fs is None and tr["time_s"] >= self.t_pass + self.delay_s:
            self.t_fs = tr["time_s"]
            rig.sim.sensor.visibility_m, rig.sim.sensor.honest = 0.3, True  # honest fog: D_od 0.3 m
        return False


def fly(seed: int, personality: str = "px4", vehicle: str = "mambo") -> dict:
    rng = random.Random(seed)
    delay = rng.uniform(0.1, 0.9)
    wind = {**DESIGN_WIND, "from_deg": rng.uniform(0, 360)} if vehicle == "mambo" else None
    sc = offboard_scenario(seed, wind=wind, vehicle=vehicle, personality=personality)
    cfg = {**offboard_config(x_end=70.0), "vehicle": vehicle}
    rig = Rig(sc, personality, config=cfg)
    inj = _Inject(delay)
    engage_and_fly(rig, 22.0, inj)
    assert inj.t_fs is not None, "no pass was flown"
    veh = rig.daemon.table.vehicle
    before = [s for s in rig.log.states if s["t"] <= inj.t_fs and s["v_cmd"]]
    limit = before[-1]["v_cmd"]
    thrust = before[-1]["thrust_ratio"]
    k = next(i for i, r in enumerate(inj.rows) if r[0] >= inj.t_fs)
    at, pre = inj.rows[k], inj.rows[max(k - 2, 0)]
    # the acceleration along the velocity at the fail-safe (truth, over the two cycles before it)
    a_vec = np.subtract(at[4:6], pre[4:6]) / max(at[0] - pre[0], 1e-9)
    a_par = float(np.dot(a_vec, at[4:6]) / max(at[3], 1e-9))
    after = inj.rows[k:]
    travelled = sum(math.hypot(b[1] - a[1], b[2] - a[2]) for a, b in zip(after, after[1:]))
    a_brake = braking_decel(veh, min(max(thrust, veh.thrust_ratio_range[0]), veh.thrust_ratio_range[1]))
    bound = stopping_distance_from(at[3], a_par, a_brake, veh.braking.jerk_max_m_s3, stop_dead_time(veh))
    return {"seed": seed, "personality": personality, "vehicle": vehicle, "delay_s": delay, "v_fs": at[3], "a_fs": a_par,
            "a_fs_total": float(np.hypot(*a_vec)),
            "limit": limit, "v_after_max": max(r[3] for r in after), "travelled_m": travelled, "bound_m": bound,
            "v_end": after[-1][3], "collided": bool(rig.truth["collisions"]), "rig": rig}


if __name__ == "__main__":
    import sys

    for pers in ("px4", "ardupilot"):
        for veh in ("mambo", "x500"):
            for seed in range(1, int(sys.argv[1]) + 1 if len(sys.argv) > 1 else 4):
                r = fly(seed, pers, veh)
                print({k: (round(v, 2) if isinstance(v, float) else v) for k, v in r.items() if k != "rig"})
