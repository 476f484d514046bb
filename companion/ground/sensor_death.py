"""The stress "sensor dies" flown at its worst moment: the campaign's own scenario (its world, wind, drawn braking,
sensor and daemon config), the obstacle sensor silent for good from just before the sample that would first have
seen the column. The moment is found by flying the same deterministic lock-step flight up to it. The negative
control (`unbudgeted`) is the time-out as it was: every sensor silent `OLD_TIMEOUT_S` before it counts as dead, and
the contracts taking none of that silence as dead time."""

from __future__ import annotations

import math

from .campaign import CampaignSpec, _with_braking, arm_mode, daemon_config, sample_scenario, scenario_dict
from .flights import Rig, engage_and_fly, fly_mission

OLD_TIMEOUT_S = 0.5  # [s] PX4 collision prevention's RANGE_STREAM_TIMEOUT_US, the daemon's time-out for every sensor


def column_due(rig: Rig, columns, radius_m: float) -> bool:
    """The nearest column's surface comes inside the sensor's range before its next sample (the last one saw it
    beyond)."""
    sim = rig.sim
    x, y = float(sim.model.pos[0]), float(sim.model.pos[1])
    speed = math.hypot(float(sim.model.vel[0]), float(sim.model.vel[1]))
    surface = min(math.hypot(cx - x, cy - y) for cx, cy in columns) - radius_m
    return surface - sim.scenario.sensor.max_range_m <= speed / sim.scenario.sensor.rate_hz


def _rig(spec: CampaignSpec, s: dict, arm: str, unbudgeted: bool) -> Rig:
    from .baselines import SilenceUnbudgeted

    config = daemon_config(s, arm, spec.nav_margin)
    if unbudgeted:
        config["timeouts"] = {"obstacle_min_s": OLD_TIMEOUT_S}
    return Rig(scenario_dict(s, arm), s["personality"], config=config, table_wrapper=_with_braking(s),
               policy=SilenceUnbudgeted() if unbudgeted else None)


def _fly(rig: Rig, arm: str, seconds: float, until=None) -> None:
    (engage_and_fly if arm_mode(arm) == "offboard" else fly_mission)(rig, seconds, until)


def fly_sensor_dies(spec: CampaignSpec, k: int, arm: str, unbudgeted: bool = False) -> tuple[Rig, float | None]:
    """Scenario `k` of `spec` for `arm` (governor, governor_brake, offboard), its faults replaced by the sensor dying
    for good at the worst moment; the rig after `spec.duration_s` and the moment (None: the column never came
    within the sensor's range: flown without the fault)."""
    s = {**sample_scenario(spec, k), "faults": []}
    probe = _rig(spec, s, arm, unbudgeted)
    _fly(probe, arm, spec.duration_s, lambda r: column_due(r, s["columns"], s["r_obst_true_m"]))
    t_kill = probe.sim.time_s if column_due(probe, s["columns"], s["r_obst_true_m"]) else None
    if t_kill is not None:
        s["faults"] = [{"kind": "sensor_dropout", "at_s": t_kill, "duration_s": 600.0}]
    rig = _rig(spec, s, arm, unbudgeted)
    _fly(rig, arm, spec.duration_s)
    return rig, t_kill


def sensor_dies_scenarios(spec: CampaignSpec) -> list[int]:
    """The scenarios of `spec` whose stress is a sensor that dies (a `sensor_dropout` fault lasting the flight)."""
    return [k for k in range(spec.scenarios)
            if any(f["kind"] == "sensor_dropout" and f["duration_s"] >= spec.duration_s
                   for f in sample_scenario(spec, k)["faults"])]
