"""The daemon's own timeliness in lock-step (guidance's guarantee, companion/onboard/estimators.py `Timeliness`): a daemon
that misses cycles — a loaded companion computer — says so, flies slower for it, and hands a cycle later than
`timeouts.cycle_late_s` to the autopilot's Hold. Real MAVLink bytes, the real SITL; the stall is the daemon not
being stepped while the SITL flies on (what a descheduled process looks like to the vehicle)."""

import pytest

from tests.lockstep import Rig, engage_and_fly
from tests.test_offboard_lockstep import offboard_config, offboard_scenario


def rig_for(personality, **timeouts):
    cfg = offboard_config()
    cfg["timeouts"] = timeouts
    return Rig(offboard_scenario(1, wind={"mean_m_s": 1.0, "from_deg": 90, "gust_m_s": 0.5}, personality=personality),
               personality, config=cfg)


def stall(rig, seconds):
    rig.daemon_on = False
    rig.run(seconds)
    rig.daemon_on = True


def guidance_violations(rig):
    return [e for e in rig.log.named("violation_start") if e["subsystem"] == "guidance"]


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_late_cycle_is_a_guidance_violation_and_lowers_the_speed(personality):
    rig = rig_for(personality)
    engage_and_fly(rig, 2.5)  # cruising, the column not yet in view
    v_before = rig.log.states[-1]["v_cmd"]
    stall(rig, 0.12)  # six cycles missed: 120 ms late
    rig.run(0.1)
    (v,) = guidance_violations(rig)
    # assumed: one cycle and the default jitter allowance (timeouts.cycle_jitter_s)
    assert v["observed"] == pytest.approx(0.02 + 0.12, abs=1e-6) and v["assumed"] == pytest.approx(0.02 + 0.02)
    after = rig.log.states[-1]
    assert after["v_cmd"] < v_before - 0.05  # the lateness is reaction time: a lower limit at once
    assert not rig.log.named("failsafe")  # under the hard limit: slower, not stopped
    rig.run(16.0)
    assert not rig.truth["collisions"]
    assert rig.log.named("violation_end")  # the next cycle on time: the longer reaction time is budgeted
    assert rig.log.named("reaction_time")[-1]["late_s"] == 0.0  # 10 s on time: back to the vehicle file's
    assert [e["to"] for e in rig.log.named("offboard")][-1] == "done"


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_cycle_later_than_the_hard_limit_hands_over_to_the_autopilots_hold(personality):
    rig = rig_for(personality)
    engage_and_fly(rig, 2.5)
    stall(rig, 0.3)
    rig.run(3.0)
    assert {"cause": "companion computer late", "action": "hold"} in \
        [{k: e[k] for k in ("cause", "action")} for e in rig.log.named("failsafe")]
    assert rig.log.states[-1]["mode"] == "hold"  # the autopilot holds (at once: no braking stop streamed)
    assert not rig.truth["collisions"]
    # the control: the same stall with the hard limit raised flies on (slower)
    ctl = rig_for(personality, cycle_late_s=1.0)
    engage_and_fly(ctl, 2.5)
    stall(ctl, 0.3)
    ctl.run(3.0)
    assert not ctl.log.named("failsafe") and ctl.log.states[-1]["mode"] == "offboard"
    assert guidance_violations(ctl)


def test_the_console_says_when_the_daemon_runs_late_and_when_it_is_on_time_again():
    from companion.onboard.console import event_line

    late = event_line("reaction_time", {"late_s": 0.12, "t_react_s": 0.22})
    assert late[1] == ("the daemon's cycles run late: reaction time 0.22 s (+120 ms) for the next 10 s, "
                       "a lower speed")
    assert event_line("reaction_time", {"late_s": 0.0, "t_react_s": 0.1})[1] == \
        "cycles on time again: reaction time back to 0.10 s"
    assert event_line("violation_end", {"subsystem": "guidance", "guarantee": "g"}) is None  # one late cycle
    assert event_line("violation_end", {"subsystem": "navigation", "guarantee": "g"})[1] == "violation over: navigation"


def test_the_loop_timing_tells_the_hosts_lateness_from_the_daemons_own_work():
    """`loop_timing` (the real-time loop's end): the largest wake-up lateness and work, the cycles over 10/20/40 ms
    in all, and the five worst cycles by that sum, each split into wake-up, poll, step and commit."""
    from companion.onboard.realtime import LoopTiming

    lt = LoopTiming()
    cycles = [(0.02 * k, 0.0002, 0.001, 0.002) for k in range(100)]
    cycles[30] = (0.6, 0.030, 0.001, 0.002)  # woken 30 ms late: the host's
    cycles[60] = (1.2, 0.0002, 0.004, 0.017)  # 21 ms of its own work: the daemon's
    cycles[61] = (1.22, 0.0002, 0.001, 0.004, 0.008)  # 8 ms of it the commit of its events
    for c in cycles:
        lt.add(*c)
    s = lt.summary()
    assert s["cycles"] == 100 and s["wake_late_ms_max"] == 30.0 and s["work_ms_max"] == 21.0
    assert s["cycles_over_ms"] == {"10": 3, "20": 2, "40": 0}
    assert [w["t"] for w in s["worst"][:3]] == [0.6, 1.2, 1.22] and len(s["worst"]) == LoopTiming.WORST
    assert s["worst"][1] == {"t": 1.2, "wake_late_ms": 0.2, "poll_ms": 4.0, "step_ms": 17.0, "commit_ms": 0.0}
    assert s["worst"][2]["commit_ms"] == 8.0
