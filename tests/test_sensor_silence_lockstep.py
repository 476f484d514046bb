"""A sensor that dies at the worst moment, flown in lock-step against the SITL (real MAVLink bytes): the stress
campaign's own "sensor dies" scenarios (examples/campaign-stress.yaml: drawn braking, wind, sensor latency), the
sensor's last sample clear and the column due in its next (companion/ground/sensor_death.py). Each sensor's silence
budget (a few of its own measured periods: `timeouts.obstacle_periods`, `obstacle_min_s`, capped by `obstacle_s`) is
dead time of the stop and avoid contracts, so the vehicle stops short in governor mode, with the recovery brake and
in offboard mode, and the silence is said as a navigation violation. The negative control is the time-out as it was:
0.5 s of silence, which the contracts did not take: offboard hits the column, the governor flies blind for 0.5 s."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import pytest

from companion.ground.campaign import load_spec, sample_scenario
from companion.ground.sensor_death import OLD_TIMEOUT_S, fly_sensor_dies, sensor_dies_scenarios
from companion.onboard.supervisor import SENSOR_SILENCE

SPEC = load_spec(Path(__file__).resolve().parents[1] / "examples" / "campaign-stress.yaml")
ARMS = ("governor", "governor_brake", "offboard")
SCENARIOS = sensor_dies_scenarios(SPEC)[:3]  # Mambo on PX4, X500 on PX4, Mambo on ArduPilot


@functools.cache
def dies(k: int, arm: str, unbudgeted: bool = False):
    rig, t_kill = fly_sensor_dies(SPEC, k, arm, unbudgeted)
    assert t_kill is not None, "the column never came within the sensor's range"
    return rig, t_kill


def silence_violation(rig) -> dict:
    [v] = [e for e in rig.log.named("violation_start") if e.get("guarantee") == SENSOR_SILENCE]
    return v


def test_the_stress_campaigns_sensor_dies_scenarios_are_the_ones_flown():
    assert len(sensor_dies_scenarios(SPEC)) == 24
    assert {(s["vehicle"], s["personality"]) for s in (sample_scenario(SPEC, k) for k in SCENARIOS)} == \
        {("mambo", "px4"), ("x500", "px4"), ("mambo", "ardupilot")}


@pytest.mark.parametrize("k", SCENARIOS)
@pytest.mark.parametrize("arm", ARMS)
def test_a_sensor_dying_at_the_worst_moment_ends_short_of_the_column(arm, k):
    rig, t_kill = dies(k, arm)
    assert not rig.truth["collisions"], rig.truth["collisions"]
    assert rig.truth["min_clearance_m"] > 0.0
    # it never saw the column: the sensor died first
    assert not [s for s in rig.log.states if math.isfinite(s["obstacle_m"] if s["obstacle_m"] is not None
                                                           else math.inf)]
    # the budget is three of the sensor's own 50 ms periods, not the 0.5 s time-out
    budget = rig.daemon.cycle.sensing.dod.sensors[0].budget
    assert budget == pytest.approx(0.15, abs=0.011)
    # the silence is said as the navigation subsystem's violation, with its budget, within a cycle of its end
    v = silence_violation(rig)
    assert v["subsystem"] == "navigation" and v["sensor"] == 0 and v["assumed"] == pytest.approx(budget)
    assert budget < v["observed"] <= budget + 0.05 + 1e-9 and v["t"] - t_kill <= budget + 0.05 + 1e-9
    assert v["action"].startswith("sensors[0] taken for dead, D_od without it: 0.00 m")
    # D_od fell to 0 and the vehicle came to rest
    assert any(s["d_od"] == 0.0 for s in rig.log.states if s["t"] >= v["t"])
    vx, vy = rig.truth["vel"][:2]
    assert math.hypot(vx, vy) < 0.2


@pytest.mark.parametrize("arm", ARMS)
def test_the_budget_is_dead_time_of_the_contract(arm):
    """While the sensor is alive Ω takes its silence budget: the limit in force before the death is below the one
    the same flight flies with the contracts taking none of it (by 0.4 % for the governor here, where E_tr_pred's
    step at the speed grid sets the limit; benchmarks/bench_stale_cost.py gives the cost over D_od)."""
    k = SCENARIOS[0]
    (new, t_new), (old, t_old) = dies(k, arm), dies(k, arm, unbudgeted=True)
    assert cruise_limit(new, t_new) < cruise_limit(old, t_old)


def cruise_limit(rig, t_kill: float) -> float:
    """The highest limit commanded before the sensor died."""
    return max(s["v_cmd"] or 0.0 for s in rig.log.states if s["t"] < t_kill)


@pytest.mark.parametrize("k", SCENARIOS)
def test_negative_control_offboard_with_the_old_unbudgeted_time_out_hits_the_column(k):
    rig, t_kill = dies(k, "offboard", unbudgeted=True)
    v = silence_violation(rig)
    assert v["assumed"] == OLD_TIMEOUT_S and v["t"] - t_kill >= OLD_TIMEOUT_S - 0.05
    assert rig.truth["collisions"], "flying blind for 0.5 s unbudgeted must reach the column"


@pytest.mark.parametrize("arm", ("governor", "governor_brake"))
def test_negative_control_the_governor_with_the_old_time_out_flies_blind_for_half_a_second(arm):
    """The old time-out: the sensor is taken for dead 0.5 s after its last sample, at a limit that budgeted none of
    it (the distance flown blind is outside the stop contract)."""
    k = SCENARIOS[0]
    rig, t_kill = dies(k, arm, unbudgeted=True)
    v = silence_violation(rig)
    assert v["assumed"] == OLD_TIMEOUT_S and v["t"] - t_kill >= OLD_TIMEOUT_S - 0.05
    blind = [s for s in rig.log.states if t_kill <= s["t"] <= v["t"]]
    assert blind and all(s["d_od"] > 0 for s in blind)  # D_od still the dead sensor's claim
