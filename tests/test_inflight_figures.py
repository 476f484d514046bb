"""In-flight enforcement, the paper's Figures 17 and 18, in lock-step (offboard, Mambo)."""

import pytest

from contracts.online_planner import OFFBOARD_CAP, offboard_cap
from sitl_harness.scenario import load_scenario
from companion.ground.flights import fly_offboard_scenario


def _golden():
    from tests import golden  # (golden imports this module for its flights)

    return golden


def fly_scenario(name):
    """One of the paper's flights (its golden log: tests/golden.py, compared by the tests below)."""
    return fly_offboard_scenario(load_scenario(name))


def acked(rig, name, value):
    """The daemon echoed the parameter with this value (PARAM_VALUE)."""
    return any(m.get_type() == "PARAM_VALUE" and m.param_id == name and abs(m.param_value - value) < 1e-6
               for m in rig.daemon_messages())


def level(rig, t0, t1):
    v = [s["v_cmd"] for s in rig.log.states if t0 <= s["t"] <= t1 and s["v_cmd"] and s["mode"] == "offboard"]
    return min(v) if v else None


def test_figure_17_fog_clears_then_thrust_drops():
    """Up when the fog clears. After the thrust drop the paper's V_max goes down (≈5.5 → ≈5 m/s) because
    its E_tr grows with less thrust; in this SITL much less: at the Mambo's tilt ceiling (25°) thrust 0.8
    still holds altitude with margin (it binds above ≈50°), so V_safe does not change, and only the
    online plans at the top speeds are tracked a little worse with less thrust headroom (E_tr_pred at
    7 m/s: 1.108 → 1.145 m), so Ω drops by ≈0.02 m/s. The conservative lookup already answers at the
    0.8 grid point once the estimate dips below 1.0, so the flown levels before and after the drop
    agree — the contract's answer at the seen thrust, checked here, not a miss."""
    rig = fly_scenario("fig17")
    assert not rig.truth["collisions"]
    assert _golden().difference("figure_17", rig) is None  # and logs what it logged when recorded
    fog, clear, thrust = level(rig, 6, 24), level(rig, 30, 44), level(rig, 50, 60)
    assert fog and clear and clear > fog + 1.0  # up when the fog clears
    assert thrust is not None and thrust <= clear + 1e-9  # never up when thrust drops
    late = [s for s in rig.log.states if 55 <= s["t"] <= 60 and s["mode"] == "offboard"]
    assert late and all(abs(s["thrust_ratio"] - 0.8) < 0.05 for s in late)  # the drop is seen
    s = late[-1]
    table = rig.daemon.table
    t_silent = rig.daemon.cycle.sensing.dod.sensors[0].budget  # the sensor's silence budget, in the contract
    at = [table.omega(s["d_od"], s["r_obst"], 0.3, tr, contract="avoid", t_silent=t_silent) for tr in (0.8, 1.0)]
    assert at[0].v_max <= at[1].v_max  # never faster with less thrust
    cap = rig.daemon.cycle.sup.cap  # in force: OFFBOARD_CAP, or the cap the table's E_tr_pred was flown at if less
    assert cap == offboard_cap(table.etr_offboard_cap) <= OFFBOARD_CAP
    assert thrust == pytest.approx(cap * at[0].v_max)  # flown: the capped contract at the seen thrust


def test_figure_18_fog_clears_then_the_expected_obstacle_shrinks():
    rig = fly_scenario("fig18")
    assert not rig.truth["collisions"] and acked(rig, "CG_R_OBST", 0.6)
    assert _golden().difference("figure_18", rig) is None  # and logs what it logged when recorded
    fog, clear, small = level(rig, 6, 24), level(rig, 30, 44), level(rig, 50, 60)
    assert fog and clear and small and fog < clear < small  # up, then up again
