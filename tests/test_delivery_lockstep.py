"""Command delivery as a contracted subsystem, flown in lock-step against the SITL (real MAVLink bytes): the mode
authority re-sends a Hold every cycle until the autopilot answers or shows it, the stop contract budgets that time
(`delivery.t_cmd_s`), a speed limit that is not flown is caught by the autopilot's own slow-down, and a Hold
refused takes Land. Each case has a negative control that collides: the test can fail."""

from __future__ import annotations

import functools

import pytest

from companion.ground.baselines import SilenceUnbudgeted
from companion.onboard import supervisor as supervisor_module
from companion.onboard.authority import GUARANTEE_ANSWERED, GUARANTEE_SHOWN, Delivery, ModeAuthority
from companion.onboard.console import event_line
from companion.onboard.cycle import Cycle
from companion.onboard.supervisor import LIMIT_FLOWN
from sitl_harness.autopilot import DENIED
from tests import test_daemon_lockstep as gov
from tests.lockstep import Rig

CELLS = [(v, p) for v in ("mambo", "x500") for p in ("px4", "ardupilot")]


class ResendAfterOneSecond(ModeAuthority):
    """The negative control: a mode command on its way re-sent only a second after the last (before the mode
    authority owned delivery, the supervisor re-sent an unanswered Hold after 1 s)."""

    def arbitrate(self, t, requests):
        p = self.pending
        if p is not None and p.state == Delivery.SENDING and p.sends and t - p.t_sent < 1.0 and \
                all(r.mode == p.asked for r in requests):
            return None
        return super().arbitrate(t, requests)


def column_flight(vehicle: str, personality: str, lost: int = 0, config: dict | None = None, faults=(),
                  authority=None) -> tuple[Rig, list[float]]:
    """The column flight of tests/test_daemon_lockstep.py (cruise 8 m/s, sensor 6 m, column at 28 m), its first
    `lost` Holds lost on the link."""
    rig = Rig(gov.column_scenario(1, vehicle=vehicle, faults=list(faults)), personality, config=config,
              outbound={"drop_holds": lost} if lost else None)
    if authority is not None:
        cyc = rig.daemon.cycle
        cyc.authority = authority(cyc.authority.hold_mode, cyc.authority.t_cmd_s, cyc.authority.t_mode_s,
                                  cyc.authority.hold_fallbacks)
    gov.fly(rig, 25.0)
    return rig, [t for t, name in rig.outbound.dropped] if lost else []


@functools.cache
def lost_holds(vehicle: str, personality: str, lost: int) -> tuple[Rig, list[float]]:
    return column_flight(vehicle, personality, lost)


@pytest.mark.parametrize("lost", [1, 2, 3])
@pytest.mark.parametrize("vehicle,personality", CELLS)
def test_holds_lost_on_the_link_are_re_sent_and_the_vehicle_stops_short(vehicle, personality, lost):
    rig, dropped = lost_holds(vehicle, personality, lost)
    assert len(dropped) == lost  # the faults happened
    assert not rig.truth["collisions"], rig.truth["collisions"]
    holds = [e for e in rig.log.named("command") if e["cmd"] == "hold"]
    assert holds[0]["t"] == dropped[0]  # the first Hold was the one lost
    # re-sent every cycle: the one that arrived went out `lost` cycles after the first
    delivery = [e for e in rig.log.named("delivery") if e["cmd"] == "hold"][0]
    assert delivery["outcome"] == "shown" and delivery["sends"] == lost + 1
    assert delivery["waited_s"] <= rig.daemon.cfg.delivery.t_cmd_s + 0.02 + 1e-9
    # inside the budget: no delivery violation
    assert not [e for e in rig.log.named("violation_start") if e["subsystem"] == "delivery"]


@pytest.mark.parametrize("vehicle,personality", CELLS)
def test_negative_control_one_lost_hold_re_sent_a_second_later_collides(vehicle, personality):
    """Today's behaviour before the mode authority owned delivery: the contract budgeting no loss, a lost Hold
    re-sent a second later. It hits the column."""
    rig, dropped = column_flight(vehicle, personality, 1, config={"delivery": {"t_cmd_s": 0.0}},
                                 authority=ResendAfterOneSecond)
    holds = [e["t"] for e in rig.log.named("command") if e["cmd"] == "hold"]
    assert dropped and holds[1] - holds[0] >= 1.0
    assert rig.truth["collisions"], "a Hold lost and re-sent a second later must reach the column"


def test_holds_lost_beyond_the_budget_are_the_delivery_subsystems_violation():
    """Six Holds lost in a row (0.12 s > t_cmd_s 0.1 s): outside the contract, and said as such, with the
    assumed budget and the time observed."""
    rig, dropped = column_flight("mambo", "px4", 6)
    assert len(dropped) == 6
    [v] = [e for e in rig.log.named("violation_start") if e["subsystem"] == "delivery"]
    assert v["guarantee"] == GUARANTEE_ANSWERED and v["assumed"] == 0.1 and v["observed"] > 0.1
    assert v["t"] - dropped[0] == pytest.approx(0.12, abs=0.011)
    assert any("delivery violation" in t for t in rig.daemon_texts())
    assert [e for e in rig.log.named("violation_end") if e["subsystem"] == "delivery"]  # the 7th arrived


@functools.cache
def ignored_limit(vehicle: str, personality: str, judged: bool = True) -> Rig:
    """DO_CHANGE_SPEED accepted and never applied from the start: the autopilot flies its own 8 m/s. `judged`:
    False, the speed flown is never judged against the limit (a negative control)."""
    with pytest.MonkeyPatch.context() as mp:
        if not judged:
            mp.setattr(supervisor_module.Supervisor, "_judge_limit", lambda self, i, over: None)
        rig, _ = column_flight(vehicle, personality, faults=[{"at_s": 0.0, "speed_commands_ignored": True}])
    return rig


@pytest.mark.parametrize("vehicle,personality", CELLS)
def test_a_limit_acknowledged_and_not_flown_is_caught_by_the_autopilots_own_slow_down(vehicle, personality):
    rig = ignored_limit(vehicle, personality)
    assert not rig.truth["collisions"], rig.truth["collisions"]
    [v] = [e for e in rig.log.named("violation_start") if e.get("guarantee") == LIMIT_FLOWN]
    assert v["subsystem"] == "delivery" and v["observed"] > v["assumed"]
    hold = rig.log.named("hold_trigger")[0]
    assert hold["cause"] == "speed limit not in force" and hold["t"] == v["t"]
    # caught while speeding up past the limit, well before the column's stop distance
    at = next(s for s in rig.log.states if s["t"] >= hold["t"])
    assert at["ground_speed"] < 1.3 * at["v_cmd"] + 0.5
    assert max(s["x"] for s in rig.log.states) < 28.0 - 0.5 - 2.0


def test_negative_control_a_limit_not_flown_and_not_caught_collides():
    """The same flight where the speed flown is never judged against the limit: the autopilot's own 8 m/s meets the
    column, whose stop distance at that speed is about twice the sensor's range."""
    rig = ignored_limit("mambo", "px4", judged=False)
    assert rig.truth["collisions"], "a limit not flown, held for too late, must reach the column"


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_hold_refused_takes_land_and_is_said(personality):
    """The autopilot refuses Hold (PX4 Hold, ArduPilot Brake): the mode authority asks for Land at once, and the
    Hold refused is the delivery subsystem's violation."""
    rig = Rig(gov.column_scenario(1), personality)
    ap, enter = rig.sim.autopilot, rig.sim.autopilot._enter
    ap._enter = lambda mode, custom: DENIED if mode == "hold" else enter(mode, custom)
    gov.fly(rig, 25.0)
    cmds = [e["cmd"] for e in rig.log.named("command") if e["cmd"] in ("hold", "land")]
    assert cmds[:2] == ["hold", "land"]
    fb = [e for e in rig.log.named("delivery") if e["outcome"] == "fallback"][0]
    assert fb["cmd"] == "hold" and fb["next"] == "land" and "answered" in fb["why"]
    prio, line = event_line("delivery", fb)  # the console says it
    assert "hold fallback after" in line and "asking for land instead" in line
    [v] = [e for e in rig.log.named("violation_start") if e["subsystem"] == "delivery"]
    assert v["guarantee"] == GUARANTEE_SHOWN and "land" in v["action"]
    assert any(e["to"] == "land" and e["by"] == "daemon" for e in rig.log.named("mode_change"))
    assert len([e for e in rig.log.named("command") if e["cmd"] == "hold"]) == 1  # landing is the daemon's stop
    assert not rig.truth["collisions"], rig.truth["collisions"]


@functools.cache
def late_switch(vehicle: str, personality: str, delay_s: float, today: bool = False) -> Rig:
    """The column flight with the recovery brake, the autopilot answering its OFFBOARD / GUIDED at once and
    showing it `delay_s` later (it flies its mission meanwhile). `today`: the negative control — the brake's own
    limit from the start, its switch awaited the mode authority's whole 1.2 s, the contract budgeting no delivery (nor
    the sensor's silence, which it did not budget then either)."""
    sc = gov.column_scenario(1, vehicle=vehicle,
                             faults=[{"at_s": 0.0, "mode_delay": {"delay_s": delay_s, "only": "offboard"}}])
    sc["params"] = {"COM_OBL_RC_ACT": 5} if personality == "px4" else {}
    config = {"governor": {"recovery_brake": True}} | ({"delivery": {"t_cmd_s": 0.0}} if today else {})
    rig = Rig(sc, personality, config=config, policy=SilenceUnbudgeted() if today else None)
    with pytest.MonkeyPatch.context() as mp:
        if today:
            rig.daemon.cycle.brake.shown()
            mp.setattr(rig.daemon.cycle.flying, "within_s", rig.cfg.delivery.t_mode_s)
        gov.fly(rig, 25.0)
    return rig


@pytest.mark.parametrize("delay_s", [0.3, 1.0])
@pytest.mark.parametrize("vehicle,personality", CELLS)
def test_a_brake_switch_shown_late_at_its_first_stop_holds_within_the_holds_limit(vehicle, personality, delay_s):
    """OFFBOARD / GUIDED not shown within the 0.22 s the brake's contract budgets for its switch (the switch, a
    cycle and the delivery budget): refused, Hold at once; the limit was still the autopilot's Hold's (the switch
    not yet shown in this flight), so the vehicle stops short and it is no violation; the brake is off after."""
    rig = late_switch(vehicle, personality, delay_s)
    assert not rig.truth["collisions"], rig.truth["collisions"]
    offb, hold = [e for e in rig.log.named("command") if e["cmd"] in ("offboard", "hold")][:2]
    assert (offb["cmd"], hold["cmd"]) == ("offboard", "hold") and 0.22 < hold["t"] - offb["t"] <= 0.26
    switch = [e for e in rig.log.named("delivery") if e["cmd"] == "offboard"][0]
    assert switch["outcome"] == "not shown" and "within 0.22 s" in switch["why"]
    off = rig.log.named("recovery_brake")[-1]
    assert not off["available"] and "not shown within 0.22 s" in off["reason"]
    assert not [e for e in rig.log.named("violation_start") if e["subsystem"] == "autopilot"]


@pytest.mark.parametrize("vehicle,personality", CELLS)
def test_negative_control_the_brakes_limit_before_its_switch_is_shown_collides(vehicle, personality):
    """Today's behaviour before the switch had to be shown first: the brake's own limit from the start, a switch
    shown 0.6 s late awaited, no delivery budget: the column is hit."""
    rig = late_switch(vehicle, personality, 0.6, today=True)
    assert rig.truth["collisions"], "the brake's limit flown before its switch was shown must reach the column"
