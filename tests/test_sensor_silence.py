"""Each obstacle sensor's silence budget (companion/onboard/estimators.py SilenceBudget): a few of its own measured
periods, floored and capped, before it counts as dead; and the contracts taking it as dead time
(contracts/table.py `ContractTable.omega(..., t_silent=)`)."""

from __future__ import annotations

import math

import pytest

from companion.onboard.config import ContractConfig, SensorConfig, config_from_dict
from companion.onboard.estimators import PERIOD_SAMPLES, DodEstimator, SilenceBudget
from companion.onboard.samples import Scan
from companion.onboard.sensing import silence_budget
from contracts.table import load_for_vehicle

BUDGET = SilenceBudget(3.0, 0.1, 0.5)


def estimator(budget: SilenceBudget | None = BUDGET) -> DodEstimator:
    return DodEstimator([SensorConfig(h_fov_deg=30, max_range_m=8.0)], ContractConfig(), 0.5, budget)


def feed(est: DodEstimator, times) -> None:
    for t in times:
        est.add_scan(Scan(t, 0, (), 8.0, 0, None, None, None))


def test_the_budget_is_periods_of_the_mean_interval_floored_and_capped():
    n = PERIOD_SAMPLES
    assert BUDGET.of([0.05] * (n - 1)) == 0.5  # too few intervals measured: the time-out
    assert BUDGET.of([0.05] * n) == pytest.approx(0.15)  # 20 Hz: 3 periods
    assert BUDGET.of([0.01] * n) == 0.1  # 100 Hz: the floor
    assert BUDGET.of([0.25] * n) == 0.5  # 4 Hz: the cap
    # received by a 50 Hz loop 40 and 60 ms apart in turn, or in bursts: the same period
    assert BUDGET.of([0.04, 0.06] * (n // 2)) == pytest.approx(0.15)
    assert BUDGET.of([0.0, 0.0, 0.0, 0.2] * (n // 4)) == pytest.approx(0.15)
    # a late sample lengthens it (a slower limit, never a sensor taken for dead sooner)
    assert BUDGET.of([0.05] * (n - 1) + [0.3]) > 0.15


def test_a_sensor_silent_past_its_budget_counts_as_dead_and_is_named():
    est = estimator()
    feed(est, [k * 0.05 for k in range(20)])  # 20 Hz, the last sample at 0.95 s
    alive = est.estimate(0.95 + 0.1499, 0.0)
    assert alive.d_od == 8.0 and alive.silence_s == pytest.approx(0.15) and not alive.silent
    dead = est.estimate(0.95 + 0.16, 0.0)
    assert dead.d_od == 0.0 and dead.silence_s == 0.0
    [s] = dead.silent
    assert s.sensor == 0 and s.silent_s == pytest.approx(0.16) and s.budget_s == pytest.approx(0.15)
    feed(est, [1.2])  # it speaks again: alive, its late interval lengthening the budget a little
    back = est.estimate(1.2, 0.0)
    assert back.d_od == 8.0 and not back.silent and 0.15 < back.silence_s < 0.2


def test_negative_control_the_old_time_out_believes_a_silent_sensor_for_half_a_second():
    est = estimator(None)  # every sensor the time-out, as before
    feed(est, [k * 0.05 for k in range(20)])
    assert est.estimate(0.95 + 0.45, 0.0).d_od == 8.0


def test_a_sensor_never_heard_is_not_silent():
    assert not estimator().estimate(5.0, 0.0).silent


def test_the_config_states_the_budget_with_safe_defaults():
    cfg = config_from_dict({})
    assert silence_budget(cfg) == SilenceBudget(3.0, 0.1, 0.5)
    assert silence_budget(config_from_dict({"timeouts": {"obstacle_s": 0.05}})) == SilenceBudget(3.0, 0.05, 0.05)
    for bad in ({"obstacle_periods": 1.0}, {"obstacle_min_s": 0.0}, {"obstacle_periods": math.inf}):
        with pytest.raises(Exception, match=next(iter(bad))):
            config_from_dict({"timeouts": bad})


@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
def test_the_stop_contract_takes_the_silence_as_dead_time(vehicle):
    table = load_for_vehicle(vehicle)
    for d in (3.0, 6.0, 10.0):
        a = table.omega(d, 1.0, 0.3, 1.0, contract="stop", t_cmd=0.1, t_silent=0.15).v_max
        assert a == table.omega(d, 1.0, 0.3, 1.0, contract="stop", t_cmd=0.25).v_max
        assert a < table.omega(d, 1.0, 0.3, 1.0, contract="stop", t_cmd=0.1).v_max


@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
def test_the_avoid_contract_takes_the_silence_as_reaction_time(vehicle):
    """V ≤ V_safe(d_od − V·t_silent): the answer is safe at its own speed, and lower than without the budget."""
    table = load_for_vehicle(vehicle)
    for d in (3.0, 6.0):
        v0 = table.omega(d, 1.0, 0.3, 1.0).v_max
        v = table.omega(d, 1.0, 0.3, 1.0, t_silent=0.15).v_max
        assert 0 < v < v0
        assert v <= table.omega(d - v * 0.15, 1.0, 0.3, 1.0).v_max  # safe at its own speed
        # no lower than one step from above, and within the tolerance of the largest speed safe at its own range
        assert v >= table.omega(d - v0 * 0.15, 1.0, 0.3, 1.0).v_max
        w = v + 2e-3
        assert w > table.omega(d - w * 0.15, 1.0, 0.3, 1.0).v_max
    assert table.omega(0.1, 1.0, 0.3, 1.0, t_silent=0.5).v_max == 0.0


def test_the_start_record_states_the_silence_budget(tmp_path, monkeypatch):
    """`contract-guard run` on a real UDP link: the start record carries the budget's terms as configured."""
    from companion import cli
    from companion.onboard.daemon import Daemon
    from companion.onboard.eventlog import read_events

    monkeypatch.setattr(Daemon, "run", lambda self, *a, **k: None)  # started, then stopped at once
    cfg = tmp_path / "c.yaml"
    cfg.write_text("vehicle: mambo\nlink: {connect: 'udpin:127.0.0.1:0'}\ntimeouts: {obstacle_periods: 4}\n"
                   f"log: {{dir: {tmp_path / 'log'}}}\n")
    assert cli.main(["run", "--config", str(cfg), "--quiet"]) == 0
    [start] = [e for e in read_events(tmp_path / "log") if e.get("event") == "start"]
    assert start["sensor_silence"] == {"periods": 4.0, "min_s": 0.1, "max_s": 0.5}
