"""Fuzz (issue 17): well-formed messages of every type the daemon decodes, with hostile field values, into
a governed lock-step flight. After every batch: the loop ran, the commanded speed never exceeded what the
configured sensors' rated range allows, and every implausible vehicle state was counted. (≥ 1 M inputs:
benchmarks/bench_fuzz.py.)"""

import numpy as np
import pytest

from tests.fuzz_messages import DECODED, packed
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly

RATED_M = 6.0


def speed_cap(daemon) -> float:
    """The fastest the stop contract allows with the sensor at its rated range and nothing else degraded."""
    cfg, table = daemon.cfg, daemon.table
    return table.omega(RATED_M, cfg.contract.r_obst_range_m[0], cfg.contract.e_tr_floor_m,
                       table.vehicle.thrust_ratio_range[1], contract="stop").v_max


@pytest.mark.parametrize("seed", [1, 2])
def test_hostile_messages_never_raise_the_speed_blind_or_stop_the_loop(seed):
    rig = Rig(column_scenario(1, x_col=400.0), "px4")
    fly(rig, 6.0)
    cap = speed_cap(rig.daemon)
    rng, encoders, expected_bad = np.random.default_rng(seed), {}, 0
    names = list(DECODED)
    for batch in range(30):
        for k in range(20):
            data, name, bad = packed(rng, encoders, names[(batch * 20 + k) % len(names)])
            rig._daemon_in.append(data)
            expected_bad += bad
        n_states = len(rig.log.states)
        rig.run(0.2)
        assert len(rig.log.states) > n_states, f"batch {batch}: the loop stopped logging"
        assert rig.daemon.last is not None
    assert not rig.log.named("loop_error")
    sent = [m.param2 for m in rig.daemon_messages() if m.get_type() == "COMMAND_LONG" and m.command == 178]
    assert sent and max(sent) <= cap + 1e-6
    assert max(s["v_cmd"] or 0.0 for s in rig.log.states) <= cap + 1e-9
    assert rig.daemon.counters.implausible >= expected_bad > 0
