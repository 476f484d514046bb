"""The autopilot's speed overshoot above the limit sent: budgeted below the stop contract's V_max, judged with the
same allowance in flight, raised where the autopilot flies more (companion/onboard/overshoot.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from companion.onboard.config import config_from_dict, weakened
from companion.onboard.overshoot import DEFAULT, OvershootBudget, OvershootWatch, overshoot_of, ramped_out
from companion.onboard.states import Subsystem
from companion.onboard.supervisor import SPEED_OVERSHOOT, Supervisor
from tests.test_supervisor import BASE, TABLE, run


def test_the_limit_sent_leaves_exactly_the_budget_below_v_max():
    b = OvershootBudget(0.15, 0.04)
    for v_max in (0.3, 1.0, 3.0, 7.5):
        v = b.sent(v_max)
        assert v < v_max and b.top(v) == pytest.approx(v_max)
    assert b.sent(0.05) == 0.0 and b.sent(0.0) == 0.0 and math.isinf(b.sent(math.inf))
    assert OvershootBudget(0.0, 0.0).sent(3.0) == 3.0  # no budget: the contract's V_max itself (the old behaviour)


def test_a_raised_budget_covers_the_excess_flown_and_is_never_lowered():
    b = OvershootBudget(0.15, 0.04)
    r = b.raised(2.0, 2.5)
    assert r.top(2.0) == pytest.approx(2.5) and r.fraction == b.fraction
    assert r.raised(2.0, 2.1) is r


def test_the_watch_judges_only_a_limit_the_vehicle_has_met():
    w, b = OvershootWatch(), OvershootBudget(0.1, 0.0)
    assert w.judge(b, 3.0, 5.0, 5.0) is None  # slowing down to a lower limit: the slow-down's judgement, not this
    assert w.judge(b, 3.0, 3.05, 3.05) is None  # met
    assert w.judge(b, 3.0, 3.3, 3.3) == (pytest.approx(3.1), 3.3)  # then above it by more than the budget
    assert w.judge(b, 2.0, 3.3, 3.3) is None  # a lower limit: not met yet
    assert w.judge(b, 4.0, 3.3, 3.3) is None and w.judge(b, 4.0, 4.2, 4.2) == (pytest.approx(4.1), 4.2)  # higher: met
    assert w.judge(b, None, 9.0, 9.0) is None and w.judge(b, 4.0, 4.2, 4.2) is None  # no limit: forgotten
    # a limit lowered while the vehicle speeds up: below it, but its acceleration ramped out still passes it — the
    # autopilot's jerk-limited slow-down, not an overshoot (until it has met the limit)
    w = OvershootWatch()
    assert w.judge(b, 1.0, 0.6, ramped_out(0.6, 2.5, 4.0)) is None and w.judge(b, 1.0, 1.4, 1.4) is None
    assert w.judge(b, 1.0, 0.9, 0.9) is None and w.judge(b, 1.0, 1.2, 1.2) == (pytest.approx(1.1), 1.2)
    assert math.isnan(ramped_out(1.0, math.nan, 4.0)) and ramped_out(1.0, -2.0, 4.0) == 1.0


def test_the_governor_sends_v_max_minus_the_budget_and_shadow_too_offboard_not():
    gov = Supervisor(TABLE, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02)
    bare = Supervisor(TABLE, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02,
                      overshoot=OvershootBudget(0.0, 0.0))
    d, d0 = gov.step(BASE), bare.step(BASE)
    assert d.send_speed == pytest.approx(DEFAULT.sent(d0.send_speed)) and d.omega.v_safe == d0.omega.v_safe
    assert d.omega.gamma == pytest.approx(d.omega.v_max - d.omega.v_safe)
    shadow = Supervisor(TABLE, "shadow", contract="stop", dwell_s=2.0, loop_dt=0.02)
    assert shadow.step(BASE).omega.v_max == pytest.approx(d.omega.v_max)
    off = Supervisor(TABLE, "offboard", contract="avoid", dwell_s=2.0, loop_dt=0.02)
    off0 = Supervisor(TABLE, "offboard", contract="avoid", dwell_s=2.0, loop_dt=0.02,
                      overshoot=OvershootBudget(0.0, 0.0))
    assert off.step(BASE).omega.v_max == off0.step(BASE).omega.v_max


def _violations(ds, name):
    return [f for d in ds for n, f in d.events if n == name and f.get("guarantee") == SPEED_OVERSHOOT]


def test_an_overshoot_beyond_the_budget_is_the_autopilots_violation_and_lowers_the_limit():
    s = Supervisor(TABLE, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02)
    level = replace(BASE, accel_along=0.0)  # (flying level: its acceleration ramped out adds nothing)
    v = s.step(replace(level, ground_speed=1.0)).v_cmd
    ok = run(s, level, 0.02, 1.0, ground_speed=DEFAULT.top(v) - 0.01)  # within the budget: nothing
    assert not _violations(ok, "violation_start") and ok[-1].v_cmd == pytest.approx(v)
    over = run(s, level, 1.0, 1.5, ground_speed=DEFAULT.top(v) + 0.2)
    start = _violations(over, "violation_start")
    assert len(start) == 1 and start[0]["subsystem"] == Subsystem.AUTOPILOT
    assert start[0]["assumed"] == pytest.approx(DEFAULT.top(v)) and "budget raised" in start[0]["action"]
    assert s.overshoot.top(v) == pytest.approx(DEFAULT.top(v) + 0.2)
    # the raised budget: a lower limit at once (which the vehicle then slows down to: `_judge_limit`'s to judge)
    assert _violations(over, "violation_end") and over[-1].v_cmd < v - 0.15
    run(s, level, 1.6, 1.7, in_air=False, ground_speed=0.0)
    assert s.overshoot == DEFAULT  # measured per flight


def test_negative_control_without_the_budget_the_same_overshoot_is_above_v_safe():
    """The flight the budget exists for: the autopilot overshoots its limit by what it guarantees. With the budget
    the speed flown stays at the contract's V_safe; without it (budget 0, the old rule) it is above."""
    for budget, above in ((DEFAULT, False), (OvershootBudget(0.0, 0.0), True)):
        s = Supervisor(TABLE, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02, overshoot=budget)
        d = s.step(BASE)
        flown = DEFAULT.top(d.send_speed)
        assert (flown > d.omega.v_safe + 1e-9) is above


def test_the_config_names_the_budget_and_a_smaller_one_is_weaker():
    cfg = config_from_dict({})
    assert cfg.speed_overshoot.budget() == DEFAULT
    weak = weakened(config_from_dict({"speed_overshoot": {"base_m_s": 0.0}}))
    assert any("speed_overshoot.base_m_s" in w for w in weak)


def test_the_banner_and_the_console_say_the_limit_leaves_room_for_the_overshoot():
    from companion.onboard.console import banner, event_line

    sensors = [{"kind": "distance_sensor", "h_fov_deg": 30, "max_range_m": 8.0}]
    for mode, said in (("governor", True), ("shadow", True), ("offboard", False)):
        cfg = config_from_dict({"vehicle": "mambo", "mode": mode, "sensors": sensors,
                                **({"route": {"waypoints": [[0, 0], [10, 0]]}} if mode == "offboard" else {})})
        lines = [ln for ln in banner(cfg, TABLE, "x") if "overshoot budget" in ln]
        assert bool(lines) is said and (not said or "V_max − δ_v" in lines[0] and "0.15 m/s + 0.04" in lines[0])
    _, line = event_line("limit_change", {"v_max": 2.84, "reason": "ok", "overshoot_budget_m_s": 0.26})
    assert "V_max − 0.26 m/s, the autopilot's overshoot budget" in line


def test_the_overshoot_a_log_shows_is_counted_after_the_limit_is_met():
    t = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.4]
    speed = [5.0, 3.5, 2.9, 2.9, 3.2, 3.1, 1.0, 1.3]
    limit = [3.0, 3.0, 3.0, 3.0, 3.0, 3.0, 1.2, 1.2]
    r = overshoot_of(t, speed, limit, jerk=4.0)
    assert r["overshoot_m_s"] == pytest.approx(0.2) and r["at_limit_m_s"] == 3.0 and r["samples"] == 6
    assert overshoot_of([0], [2.0], [None], jerk=4.0)["overshoot_m_s"] is None


# ---------------------------------------------------------------- lock-step: the real daemon against the real SITL
def _approach(policy=None, personality="px4"):
    """The X500 cruising toward a column far beyond its sensor's 8 m (light wind): the governor's approach to its
    limit, the column never within reach of a stop in these 25 s."""
    from companion.ground.flights import fly_mission
    from tests.lockstep import Rig
    from tests.test_daemon_lockstep import column_scenario

    sc = column_scenario(1, x_col=90.0, vehicle="x500", wind={"mean_m_s": 1.0, "from_deg": 90, "gust_m_s": 0.5})
    sc["sensor"]["max_range_m"] = 8.0
    rig = Rig(sc, personality, policy=policy)
    fly_mission(rig, 25.0)
    return rig


def _gamma_flown(rig):
    st = [s for s in rig.log.states if s.get("engaged") and s.get("gamma_flown") is not None]
    assert st and not rig.truth["collisions"] and not rig.log.named("hold_trigger")
    assert max(s["ground_speed"] for s in st) > 3.0  # it really flew up to its limit
    return max(s["gamma_flown"] for s in st)


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_lockstep_the_budget_keeps_the_flown_speed_within_v_safe(personality):
    rig = _approach(personality=personality)
    assert _gamma_flown(rig) <= 0.05
    (first, *_) = rig.log.named("limit_change")
    assert first["overshoot_budget_m_s"] == pytest.approx(DEFAULT.allowance(first["v_max"]))
    assert not rig.log.named("violation_start")


def test_lockstep_negative_control_without_the_budget_the_autopilot_overshoots_v_safe():
    from companion.ground.baselines import OvershootUnbudgeted

    assert _gamma_flown(_approach(OvershootUnbudgeted())) > 0.2
