"""Issue 19 items 4, 5, 2, 3: the campaign's flights flown again in lock-step with the issue's parameters
(tests/issue19.py says how they are placed)."""

import pytest

from tests.issue19 import fly

# item 4: Mambo, D_od 4.263, R_obst 0.826, r_true 0.677, offset +0.80, thrust 0.772, wind 0.24 gust 0.22 from 271°,
# latency 3 ms, seed 1319567691; the column at 33 m (the issue does not say where; there the fault shows)
ITEM4 = dict(vehicle="mambo", d_od=4.263, r_obst=0.826, r_true=0.677, offset=0.80, thrust=0.772, wind=0.24,
             gust=0.22, wind_from=271, latency=0.003, seed=1319567691, x_col=33.0)


def navigation_violations(rig):
    return [e for e in rig.log.named("violation_start") if e.get("subsystem") == "navigation"]


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_a_column_tracked_since_its_detection_is_no_late_detection_in_the_pass(personality):
    """On 648351d (ArduPilot): during the pass the yaw swings back ~12° a sample and the column, out of view
    since the swerve began, lights up bins −28°…−18° at once at 0.98–1.17 m: taken for a late first
    detection, D_od lowered to 1.17 m for 10 s. Now hits are placed in the local frame and a hit within
    2·R_obst of one seen before is the obstacle already tracked."""
    r = fly(personality=personality, seconds=14.0, **ITEM4)
    assert not r["collided"], r["clearance_m"]
    assert not navigation_violations(r["rig"]), navigation_violations(r["rig"])
    assert all(s["d_od"] == 0.0 or s["d_od"] > 4.2 for s in r["rig"].log.states if s["d_od"] == s["d_od"])  # never lowered


def actuator_violations(rig):
    return [e for e in rig.log.named("violation_start") if e.get("subsystem") == "actuators"]


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
@pytest.mark.parametrize("vehicle,thrust", [("x500", 0.70), ("mambo", 0.61)])
def test_no_thrust_verdict_before_airborne_and_settled(vehicle, thrust, personality):
    """Item 5: governor, true thrust at (X500) or just above (Mambo) the bottom of the vehicle's range. On
    648351d (X500/PX4, seeds 1–3) the hover throttle of the take-off read 0.678 at 2.02 s, on the ground: an
    actuator violation, "no safe speed", Hold on the ground. The estimate is valid only airborne 2 s after the
    last sample on the ground and settled vertically; until then it is the vehicle's lowest thrust ratio."""
    r = fly(mode="governor", vehicle=vehicle, personality=personality, d_od=6.0, r_obst=1.0, r_true=0.6, offset=0.3,
            thrust=thrust, wind=0.3, gust=0.2, wind_from=90, latency=0.01, seed=1, seconds=10.0)
    rig = r["rig"]
    assert not actuator_violations(rig) and not rig.log.named("failsafe"), rig.log.named("failsafe")
    lo = rig.daemon.table.vehicle.thrust_ratio_range[0]
    assert all(s["thrust_ratio"] >= lo for s in rig.log.states)
    last = rig.log.states[-1]
    assert last["z"] < -1.0  # flying the mission by then
    assert abs(last["thrust_ratio"] - max(thrust, lo)) < 0.03  # and the estimate has come to the truth
