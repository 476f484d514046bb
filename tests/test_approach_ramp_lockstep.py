"""Governor mode's approach ramp (`governor.approach_ramp_m_s`) against the SITL in lock-step: the speed command never
more than the ramp above the speed flown, the stop contract then judged on the Hold-start acceleration the ramp
allows (contracts/stop.py `ramp_accel`) — a higher limit, checked against the measured acceleration and speed."""

from __future__ import annotations

import math

import pytest

from companion.onboard.console import event_line
from companion.onboard.overshoot import DEFAULT as OVERSHOOT
from companion.ground.review import format_report
from companion.onboard.states import RAMP_FOLLOWED
from companion.onboard.supervisor import (RAMP_A_TOL, RAMP_REARM_S, RAMP_SLACK_M_S, RAMP_WINDOW_S, SPEED_OVERSHOOT,
                                          ApproachRamp)
from contracts.stop import ramp_accel
from tests import test_daemon_lockstep as gov
from tests.lockstep import Rig
from tests.test_recovery_brake_lockstep import review_of

RAMP = 0.3
WIND = {"mean_m_s": 1.0, "from_deg": 90, "gust_m_s": 0.5}


def flight(personality: str, x_col: float, seconds: float, faults=(), ramp: float | None = RAMP) -> Rig:
    rig = Rig(gov.column_scenario(1, x_col=x_col, wind=WIND, faults=list(faults)), personality,
              config={"governor": {"approach_ramp_m_s": ramp}})
    gov.fly(rig, seconds)
    return rig


def limits(rig: Rig) -> tuple[float, float]:
    """The stop contract's limit at the flight's sensor range without and with the ramp's bound (its E_tr floor,
    full thrust: the open-air cruise before the column is seen), as sent: with room for the autopilot's overshoot."""
    t, e = rig.daemon.table, rig.daemon.cfg.contract.e_tr_floor_m
    a0 = ramp_accel(rig.daemon.table.vehicle.braking.jerk_max_m_s3, RAMP + RAMP_SLACK_M_S) + RAMP_A_TOL
    t_cmd = rig.daemon.cfg.delivery.t_cmd_s
    t_silent = rig.daemon.cycle.sensing.dod.sensors[0].budget  # the sensor's silence budget (3 of its periods)
    budget = rig.daemon.cfg.speed_overshoot.budget()
    return (budget.sent(t.omega(gov.D_SENSOR, 1.0, e, 1.0, contract="stop", t_cmd=t_cmd, t_silent=t_silent).v_max),
            budget.sent(t.omega(gov.D_SENSOR, 1.0, e, 1.0, contract="stop", a0_max=a0, t_cmd=t_cmd,
                                t_silent=t_silent).v_max))


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_the_ramp_raises_the_limit_and_the_governor_still_stops_short(personality):
    rig = flight(personality, 28.0, 25.0)
    assert not rig.truth["collisions"], rig.truth["collisions"]
    plain, shaped = limits(rig)
    assert shaped > 1.025 * plain  # what the ramp buys here (2.8 %, the sensor's silence in the dead time)
    (on,) = rig.log.named("approach_ramp")[:1]
    assert on["in_force"] and on["t"] >= rig.log.named("limit_change")[0]["t"] + RAMP_REARM_S - 0.05
    v_cmd = max(s["v_cmd"] or 0.0 for s in rig.log.states)
    assert v_cmd == pytest.approx(shaped, rel=0.02)  # flown at the ramp's limit, not above it
    fast = max(s["ground_speed"] for s in rig.log.states if s["t"] < rig.log.named("hold_trigger")[0]["t"])
    assert fast > plain  # the vehicle really flew faster than the any-approach contract allows
    assert rig.log.named("hold_trigger")[0]["cause"] == "obstacle inside the stop distance"
    assert not [v for v in rig.log.named("violation_start") if v["subsystem"] == "autopilot"]
    # every speed command: the any-approach limit, above it at most the ramp above the speed measured when it was
    # decided (the state samples within 0.1 s of it: they are not logged every cycle)
    sent = [(e["t"], e["params"][1]) for e in rig.log.named("command") if e["cmd"] == "change_speed"]
    assert any(v > plain + 0.05 for _, v in sent)
    for t, v in sent:
        speed = max(s["ground_speed"] for s in rig.log.states if abs(s["t"] - t) <= 0.1)
        assert v <= plain + 1e-6 or v <= speed + RAMP + 1e-6, (t, v, speed)


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_column_seen_during_the_ramped_speed_up_is_stopped_short_of(personality):
    rig = flight(personality, 6.0, 15.0)
    assert not rig.truth["collisions"], rig.truth["collisions"]
    assert rig.log.named("hold_trigger")[0]["cause"] == "obstacle inside the stop distance"


def test_an_autopilot_that_stops_following_the_ramp_is_caught_and_the_limit_falls_back():
    """At 13 s (the ramp's limit flown) the autopilot starts to ignore DO_CHANGE_SPEED (accepted, not applied: back to its own 8 m/s). The
    ramp in force is broken — by the speed above the command before the acceleration shows it —, the limit falls
    to the any-approach contract's at once and stays there, the autopilot's violation is said on the console and
    in the review's verdict; the speed limit not in force then holds the vehicle (the net that stays)."""
    rig = flight("px4", 80.0, 22.0, faults=[{"at_s": 13.0, "speed_commands_ignored": True}])
    assert not rig.truth["collisions"]
    plain, shaped = limits(rig)
    # the ramp's guarantee broken, and then the speed overshoot's (the speed flown above the limit it had met)
    (v, over) = [e for e in rig.log.named("violation_start") if e["subsystem"] == "autopilot"]
    assert over["guarantee"] == SPEED_OVERSHOOT and over["t"] >= v["t"]
    assert v["guarantee"] == RAMP_FOLLOWED and 13.0 < v["t"] < 14.0 and v["observed"] > v["assumed"]
    off = [e for e in rig.log.named("approach_ramp") if not e["in_force"]][0]
    assert off["t"] == v["t"] and "faster or accelerated harder" in off["why"]
    after = [s["v_cmd"] for s in rig.log.states if s["t"] >= v["t"] and s["v_cmd"]]
    before = [s["v_cmd"] for s in rig.log.states if 12.0 < s["t"] < v["t"] and s["v_cmd"]]
    assert max(before) == pytest.approx(shaped, rel=0.02) and max(after) <= plain + 1e-9
    assert not [e for e in rig.log.named("approach_ramp") if e["in_force"] and e["t"] > v["t"]]  # not again
    hold = rig.log.named("hold_trigger")[0]
    assert hold["cause"] == "speed limit not in force" and hold["t"] > v["t"]
    prio, line = event_line("violation_start", v)
    assert "VIOLATION autopilot" in line and "the stop contract for any approach" in line
    text = format_report(review_of(rig))
    verdict = next(ln for ln in text.splitlines() if "verdict:" in ln)
    assert "accelerated harder than the approach ramp allows" in verdict and "recovery brake" not in verdict


TOP_2_2, TOP_3 = OVERSHOOT.top(2.2), OVERSHOOT.top(3.0)  # the most the default overshoot budget allows at 2.2, 3 m/s


def _follow(ramp: ApproachRamp, t0: float, seconds: float) -> float:
    """The ramp followed (on it: 2 m/s above its free 0 m/s, commanded 2.2 m/s, accelerating 1 m/s²) for
    `seconds`."""
    t = t0
    while t < t0 + seconds:
        ramp.judge(t, True, 1.0, 2.0, TOP_2_2, True)
        t += 0.05
    return t


def test_the_ramp_is_in_force_only_when_followed_and_once_broken_not_again_this_flight():
    ramp = ApproachRamp(0.3, 4.0)
    assert ramp.judge(0.0, True, 0.5, math.nan, TOP_2_2, True) == (False, False) and math.isinf(ramp.a0_max)  # no jerk
    ramp.autopilot_jerk(2.0)  # a smaller jerk reported: the vehicle file's (the start-up checks refuse it anyway)
    assert ramp.a0_max == pytest.approx(math.sqrt(2 * 4.0 * 0.35) + RAMP_A_TOL)
    ramp.autopilot_jerk(8.0)
    assert ramp.a0_max == pytest.approx(math.sqrt(2 * 8.0 * 0.35) + RAMP_A_TOL)
    ramp.autopilot_jerk(4.0)
    t = _follow(ramp, 1.0, RAMP_WINDOW_S + RAMP_REARM_S - 0.1)
    assert not ramp.in_force  # on the ramp for the window, then followed RAMP_REARM_S …
    t = _follow(ramp, t, 0.2)
    assert ramp.in_force  # … and no sooner
    assert ramp.judge(t, False, 1.0, 2.0, TOP_2_2, True) == (True, False) and not ramp.broken  # not ramping: no blame
    t = _follow(ramp, t + 0.05, RAMP_WINDOW_S + RAMP_REARM_S + 0.1)
    assert ramp.in_force
    assert ramp.command(5.0, 2.0, 1.0) == pytest.approx(2.3) and ramp.command(2.1, 2.0, 1.0) == 2.1
    assert ramp.command(5.0, 0.5, 3.0) == 3.0  # up to the any-approach limit the autopilot speeds up as it likes …
    assert ramp.judge(t, True, 2.5, 0.5, TOP_3, True) == (False, False)  # … however hard
    assert ramp.judge(t + 4.0, True, -1.0, 3.3, TOP_3, True) == (False, False)  # slowing to a command just lowered
    assert ramp.judge(t + 5.0, True, 1.0, 3.3, TOP_3, True) == (True, True) and ramp.broken  # faster, speeding up
    assert ramp.excess[0] == "speed" and ramp.excess[2] == pytest.approx(TOP_3)
    ramp.command(5.0, 2.0, 0.0)
    for k in range(200):  # followed again: not in force this flight
        assert ramp.judge(t + 6.0 + 0.05 * k, True, 1.0, 2.0, TOP_2_2, True)[0] is False
    ramp.judge(t + 20.0, False, 0.0, 0.0, math.inf, False)  # landed
    _follow(ramp, t + 30.0, RAMP_WINDOW_S + RAMP_REARM_S + 0.1)
    assert ramp.in_force


def test_a_limit_lowered_while_the_ramp_is_in_force_is_no_autopilot_violation():
    """Honest fog at 14 s (the ramp in force, its limit flown) lowers the limit at once; the vehicle slowing down
    to it is above the new command for a while, which is not the autopilot overshooting it."""
    rig = flight("px4", 80.0, 22.0, faults=[{"at_s": 14.0, "fog": {"visibility_m": 3.0, "report": "honest"}}])
    assert not rig.truth["collisions"]
    on = [e["t"] for e in rig.log.named("approach_ramp") if e["in_force"]]
    assert on and on[0] < 14.0
    fast = [s["v_cmd"] for s in rig.log.states if 13.0 < s["t"] < 14.0 and s["v_cmd"]]
    slow = [s["v_cmd"] for s in rig.log.states if 15.0 < s["t"] < 16.0 and s["v_cmd"]]
    assert min(slow) < max(fast) - 0.5  # the limit really fell
    assert not [e for e in rig.log.named("violation_start") if e["subsystem"] == "autopilot"]
