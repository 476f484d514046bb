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
