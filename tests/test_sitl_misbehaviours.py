"""An autopilot that answers a command but does not act on it as asked, set by a scenario fault: speed commands
ignored, a requested mode entered late, OFFBOARD / GUIDED refused (with the answer, or silently)."""

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav
from sitl_client import PX4_OFFBOARD, lockstep_client

from sitl_harness import Sim
from sitl_harness.scenario import ScenarioError, scenario_from_dict

# a mode each personality is not in when it starts hovering (PX4 starts in Hold, ArduPilot in GUIDED): PX4 Land,
# ArduPilot BRAKE; and the personality's Hold
OTHER = {"px4": (4, 6), "ardupilot": (17, 0)}
HOLD = {"px4": (4, 3), "ardupilot": (17, 0)}


def hovering(pers, *faults):
    sim = Sim(scenario_from_dict({"start": {"alt_m": 2.0}, "faults": [{"at_s": 0.1, **f} for f in faults]}), pers)
    return sim, lockstep_client(sim)


def shown_after(c, req) -> tuple[int | None, float | None]:
    """Ask for mode `req`: the answer, and how long after the request the heartbeat first shows another mode."""
    before, t0, res = c.custom_mode, c.now(), None
    c.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *req, 0, 0, 0, 0)
    while c.now() < t0 + 1.0:
        for m in c.pump(0.01):
            if m.get_type() == "COMMAND_ACK" and res is None:
                res = m.result
            if m.get_type() == "HEARTBEAT" and m.custom_mode != before:
                return res, c.now() - t0
    return res, None


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_a_mode_request_is_accepted_at_once_and_entered_its_delay_later(pers):
    _, c = hovering(pers)
    res, prompt = shown_after(c, OTHER[pers])
    assert res == mav.MAV_RESULT_ACCEPTED and prompt == pytest.approx(0.01)  # the tick it arrived in
    _, c = hovering(pers, {"mode_delay": {"delay_s": 0.3}})
    res, late = shown_after(c, OTHER[pers])
    assert res == mav.MAV_RESULT_ACCEPTED and late == pytest.approx(prompt + 0.3)


def test_a_delay_of_hold_only_leaves_other_modes_prompt():
    sim, c = hovering("px4", {"mode_delay": {"delay_s": 0.5, "only": "hold"}})
    assert shown_after(c, OTHER["px4"])[1] == pytest.approx(0.01)  # Land: at once
    assert shown_after(c, HOLD["px4"])[1] == pytest.approx(0.51)
    assert sim.autopilot.mode == "hold"


def test_a_newer_request_replaces_one_not_yet_entered():
    sim, c = hovering("px4", {"mode_delay": {"delay_s": 0.5}})
    c.set_mode(*OTHER["px4"])  # Land, entered 0.5 s from now …
    c.set_mode(*HOLD["px4"])  # … unless Hold is asked for first: the vehicle stays in Hold
    c.pump(1.0)
    assert sim.autopilot.mode == "hold" and sim.autopilot.pending_mode is None


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
@pytest.mark.parametrize("how", ["denied", "silently"])
def test_offboard_refused_by_answer_or_silently(pers, how):
    sim, c = hovering(pers, {"offboard_refused": how})
    if pers == "ardupilot":  # it starts hovering in GUIDED: leave it first
        c.set_mode(*HOLD[pers])
    stream(c, 0.5)  # PX4 accepts OFFBOARD only with a setpoint stream
    res = c.set_mode(*((6, 0) if pers == "px4" else (4, 0)))
    assert res == (mav.MAV_RESULT_DENIED if how == "denied" else mav.MAV_RESULT_ACCEPTED)
    stream(c, 1.5)
    assert sim.autopilot.mode == "hold" and c.custom_mode != (PX4_OFFBOARD if pers == "px4" else 4)


@pytest.mark.parametrize("pers", ["px4", "ardupilot"])
def test_without_the_refusal_offboard_is_entered(pers):
    """The control of the test above: the same requests, no fault, OFFBOARD / GUIDED shown."""
    sim, c = hovering(pers)
    if pers == "ardupilot":
        c.set_mode(*HOLD[pers])
    stream(c, 0.5)
    assert c.set_mode(*((6, 0) if pers == "px4" else (4, 0))) == mav.MAV_RESULT_ACCEPTED
    stream(c, 1.5)
    assert sim.autopilot.mode == "offboard" and c.custom_mode == (PX4_OFFBOARD if pers == "px4" else 4)


def stream(c, seconds: float) -> None:
    """Hover setpoints at 20 Hz for `seconds`."""
    for _ in range(round(seconds / 0.05)):
        c.position_target(0x09C7, vel=(0.0, 0.0, 0.0))
        c.pump(0.05)


@pytest.mark.parametrize("ignored", [False, True])
def test_speed_commands_ignored_are_accepted_and_not_applied(ignored):
    sim, c = hovering("px4", *([{"speed_commands_ignored": True}] if ignored else []))
    c.pump(0.2)
    assert c.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 2.5, -1) == mav.MAV_RESULT_ACCEPTED
    assert sim.autopilot.cruise == (sim.autopilot.settings.cruise_default if ignored else 2.5)


def test_a_bad_misbehaviour_is_one_line():
    with pytest.raises(ScenarioError, match="offboard_refused"):
        scenario_from_dict({"faults": [{"at_s": 1, "offboard_refused": "sometimes"}]})
    with pytest.raises(ScenarioError, match="delay_s"):
        scenario_from_dict({"faults": [{"at_s": 1, "mode_delay": {"delay_s": -1}}]})
