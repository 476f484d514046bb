"""One authority over the vehicle (companion/onboard/authority.py, companion/onboard/outbox.py): the one record of what the daemon
commanded, the one stand-down rule, the arbitration by priority — and, flown in lock-step against the SITL in both
personalities, a guard that stops when it stops: a shutdown in flight commands Hold, a failed re-check in flight
commands Hold, and a refused engage is said in all four places a person looks."""

import io
import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from companion.onboard.authority import (GUARANTEE_ANSWERED, HOLD, Delivery, ModeAuthority, ModeRequest,  # noqa: E402
                                 Requester)
from companion.onboard.console import ConsoleLog  # noqa: E402
from companion.ground.flights import Recorder  # noqa: E402
from companion.onboard.mavlink_out import text_chunks  # noqa: E402
from tests.lockstep import Rig, engage_and_fly, fly_mission  # noqa: E402
from tests.test_daemon_lockstep import column_scenario  # noqa: E402
from tests.test_offboard_lockstep import offboard_config, offboard_scenario  # noqa: E402

AUTOPILOT = mav.MAVLink(None, srcSystem=1, srcComponent=1)


# ----------------------------------------------------------------------------- the authority, pure

def test_the_daemons_own_mode_is_told_apart_from_someone_elses():
    a = ModeAuthority("hold")
    assert a.observe(0.0, "mission", True).event is None  # the first mode seen is no change
    cmd = a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])
    assert (cmd.mode, cmd.what) == ("hold", "hold")
    v = a.observe(0.5, "hold", True)  # the autopilot took our Hold
    assert v.by_daemon and not v.taken_over and v.event == ("mode_change", {"from": "mission", "to": "hold",
                                                                            "by": "daemon"})
    v = a.observe(1.0, "mission", True)  # the pilot resumes: someone else's, once
    assert v.taken_over and not v.by_daemon and v.event[1]["by"] == "other"
    assert not a.observe(1.5, "mission", True).taken_over  # no change, no new stand-down
    v = a.observe(2.0, "position", False)  # with the link down the mode is unknown, not changed
    assert v.event is None and not v.taken_over


def test_a_command_is_re_sent_every_cycle_until_the_autopilot_answers_it():
    a = ModeAuthority("hold", t_cmd_s=0.1, t_mode_s=1.2)
    a.observe(0.0, "mission", True)
    sends = [a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])]
    for k in range(1, 4):  # lost on the link: nothing answers, so every cycle sends it again
        v = a.observe(0.02 * k, "mission", True)
        assert v.late is None and v.settled is None
        sends.append(a.arbitrate(0.02 * k, [ModeRequest(HOLD, Requester.FAILSAFE)]))  # asked again: the same one
    assert all(c is not None and c.mode == "hold" for c in sends)
    a.answer(0)  # MAV_RESULT_ACCEPTED: delivered, so no more sends while the mode is awaited
    assert a.observe(0.08, "mission", True).settled is None and a.arbitrate(0.08, []) is None
    v = a.observe(0.10, "hold", True)
    assert v.by_daemon and v.settled.outcome == Delivery.SHOWN and v.late is None
    assert v.events[0][1]["sends"] == 4 and v.events[0][1]["outcome"] == "shown"


def test_a_command_unanswered_past_t_cmd_breaks_the_delivery_guarantee():
    a = ModeAuthority("hold", t_cmd_s=0.1, t_mode_s=1.2)
    a.observe(0.0, "mission", True)
    a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])
    assert a.observe(0.1, "mission", True).late is None  # within its budget
    late = a.observe(0.12, "mission", True).late
    assert late.guarantee == GUARANTEE_ANSWERED and late.assumed == 0.1 and late.observed > 0.1
    assert a.arbitrate(0.12, []) is None  # past its budget: re-sent every RESEND_LATE_S, not every cycle
    assert a.arbitrate(0.2, []).send == 2 and a.arbitrate(0.22, []) is None and a.arbitrate(0.4, []).send == 3
    assert a.observe(0.42, "hold", True).late is None  # shown: on time again


def test_a_refused_hold_takes_land_and_a_refused_land_is_given_up():
    a = ModeAuthority("brake", hold_fallbacks=("land",))
    a.observe(0.0, "mission", True)
    a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])
    a.answer(4)  # MAV_RESULT_FAILED
    v = a.observe(0.02, "mission", True)
    assert v.settled is None and v.events[0][1]["outcome"] == "fallback" and v.events[0][1]["next"] == "land"
    cmd = a.arbitrate(0.02, [])
    assert (cmd.mode, cmd.what, cmd.by) == ("land", "land", Requester.FAILSAFE)
    a.answer(2)  # MAV_RESULT_DENIED
    v = a.observe(0.04, "mission", True)
    assert v.settled.outcome == Delivery.REFUSED and v.settled.what == HOLD and "answered 2" in v.settled.why
    assert v.late is not None and a.arbitrate(0.04, []) is None  # given up, and said until someone decides
    assert a.observe(0.5, "position", True).late is None  # the pilot took over


def test_a_mode_not_shown_in_t_mode_is_not_the_daemons_when_it_comes_later():
    a = ModeAuthority("hold", t_mode_s=1.2, hold_fallbacks=())
    a.observe(0.0, "mission", True)
    a.arbitrate(0.0, [ModeRequest(HOLD, Requester.SHUTDOWN)])
    a.answer(0)
    assert a.observe(1.2, "mission", True).settled is None
    v = a.observe(1.22, "mission", True)
    assert v.settled.outcome == Delivery.NOT_SHOWN and "not shown within 1.2 s" in v.settled.why
    assert a.observe(4.0, "hold", True).taken_over  # Hold long after: not ours any more


def test_a_mode_shown_is_not_sent_again_and_a_lower_priority_may_follow_it():
    a = ModeAuthority("hold")
    a.observe(0.0, "mission", True)
    a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])
    a.observe(0.02, "hold", True)
    assert a.arbitrate(0.02, [ModeRequest(HOLD, Requester.FAILSAFE)]) is None  # shown: asked again, not sent
    assert a.arbitrate(0.04, [ModeRequest("offboard", Requester.OFFBOARD_ENTRY)]).mode == "offboard"


def test_a_mode_is_not_judged_while_the_link_is_down():
    a = ModeAuthority("hold", t_mode_s=1.2)
    a.observe(0.0, "mission", True)
    a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])
    assert a.observe(2.0, "other", False).settled is None  # the link is lost: the mode is unknown
    assert a.observe(2.02, "mission", True).settled is None  # back: 1.2 s from now to show it
    assert a.observe(3.24, "mission", True).settled.outcome == Delivery.NOT_SHOWN


def test_a_lower_priority_never_displaces_a_command_on_its_way_and_the_same_one_keeps_its_clock():
    a = ModeAuthority("hold", t_cmd_s=0.1)
    a.observe(0.0, "mission", True)
    a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])
    a.observe(0.02, "mission", True)
    assert a.arbitrate(0.02, [ModeRequest("offboard", Requester.OFFBOARD_ENTRY)]).mode == "hold"
    a.observe(0.04, "mission", True)
    assert a.arbitrate(0.04, [ModeRequest(HOLD, Requester.SHUTDOWN)]).by == Requester.FAILSAFE
    assert a.observe(0.12, "mission", True).late is not None  # 0.12 s since the first send, not since the last ask


def test_someone_elses_mode_change_ends_a_delivery_never_fought():
    a = ModeAuthority("hold")
    a.observe(0.0, "mission", True)
    a.arbitrate(0.0, [ModeRequest(HOLD, Requester.FAILSAFE)])
    v = a.observe(0.02, "position", True)
    assert v.taken_over and v.late is None
    assert a.arbitrate(0.04, []) is None


@pytest.mark.parametrize("winner,losers", [
    (Requester.FAILSAFE, [Requester.OFFBOARD_STOP, Requester.SHUTDOWN, Requester.CALIBRATION, Requester.OFFBOARD_ENTRY]),
    (Requester.OFFBOARD_STOP, [Requester.SHUTDOWN, Requester.CALIBRATION, Requester.OFFBOARD_ENTRY]),
    (Requester.SHUTDOWN, [Requester.CALIBRATION, Requester.OFFBOARD_ENTRY]),
    (Requester.CALIBRATION, [Requester.OFFBOARD_ENTRY]),
])
def test_arbitration_by_priority(winner, losers):
    modes = {Requester.OFFBOARD_ENTRY: "offboard", Requester.CALIBRATION: "mission"}
    reqs = [ModeRequest(modes.get(r, HOLD), r) for r in losers] + [ModeRequest(modes.get(winner, HOLD), winner)]
    a = ModeAuthority("hold")
    assert a.arbitrate(1.0, reqs).by == winner
    assert a.arbitrate(1.02, []).by == winner  # on its way: re-sent
    a.answer(0)
    assert a.arbitrate(1.04, []) is None  # answered: nothing more to send


def test_statustext_chunks_end_at_words():
    text = ("CG: refusing to engage: COM_OBL_RC_ACT = 0: a companion-only aircraft needs Hold or Land as "
            "offboard-loss action")
    chunks = text_chunks(text)
    assert len(chunks) > 1 and all(len(c) == 50 for c in chunks[:-1]) and len(chunks[-1]) < 50
    words = text.split()
    for c in chunks:  # each chunk shown on its own holds whole words only
        assert all(w in words for w in c.decode().split()), c
    assert " ".join(b"".join(chunks).decode().split()) == text  # joined, the whole text
    assert text_chunks("short") == [b"short"]
    exact = "CG: refusing to engage: no configured sensor looks forward"  # a word ends at byte 50 exactly
    assert b"".join(text_chunks(exact)).decode().split() == exact.split()  # joined as they come: no glued words


# ----------------------------------------------------------------------------- stop means stop

def far_column(personality):
    """A governed mission towards a column 60 m out, beyond the sensor at the moment the daemon is stopped."""
    return Rig(column_scenario(1, x_col=60.0), personality)


def autopilot_mode(rig):
    hb = [m for m in rig.gcs_msgs if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1
          and m.get_srcComponent() == 1]
    return rig.daemon.adapter.mode_name(hb[-1].base_mode, hb[-1].custom_mode)


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_governor_stopped_in_flight_holds_and_the_vehicle_stops_short(personality):
    rig = far_column(personality)
    fly_mission(rig, 6.0)
    assert rig.daemon.last.state == "active" and rig.daemon.tel.ground_speed > 2.0
    rig.daemon.stop()  # SIGTERM, Ctrl-C, systemctl stop: the run loop's stop
    rig.run(2.0, until=lambda r: r.daemon.stopped)
    assert rig.daemon.stopped
    rig.daemon_on = False  # the daemon is gone
    rig.run(20.0)
    [sd] = rig.log.named("shutdown")
    assert sd["hold"] and sd["confirmed"] and sd["waited_s"] <= 1.0
    assert [e for e in rig.log.named("command") if e["cmd"] == "hold" and e["t"] >= sd["t"] - 1.0]
    assert "CG: stopping in flight: Hold" in rig.daemon_texts()
    assert autopilot_mode(rig) == rig.daemon.adapter.hold_mode()
    assert not rig.truth["collisions"], rig.truth["collisions"]


def test_negative_control_a_daemon_that_vanishes_without_hold_lets_the_mission_hit_the_column():
    rig = far_column("px4")
    fly_mission(rig, 6.0)
    rig.daemon_on = False
    rig.run(20.0)
    assert rig.truth["collisions"], "the same flight without the shutdown Hold must reach the column"


def test_a_governor_stopped_on_the_ground_just_stops():
    rig = far_column("px4")
    rig.run(2.0)
    rig.daemon.stop()
    rig.run(0.5, until=lambda r: r.daemon.stopped)
    assert rig.daemon.stopped
    [sd] = rig.log.named("shutdown")
    assert not sd["hold"] and not [e for e in rig.log.named("command") if e["cmd"] == "hold"]


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_offboard_ctrl_c_hands_over_to_hold_and_the_summary_counts_it(personality):
    out = io.StringIO()
    log = ConsoleLog(Recorder(), out=out)
    rig = Rig(offboard_scenario(1, personality=personality), personality, config=offboard_config(), log=log)
    engage_and_fly(rig, 6.0)
    assert rig.daemon.offboard.state == "flying"
    rig.daemon.stop()
    rig.run(2.0, until=lambda r: r.daemon.stopped)
    [sd] = log.log.named("shutdown")
    assert sd["hold"] and sd["confirmed"]
    assert rig.daemon.offboard.state == "off" and not rig.daemon.offboard.streaming
    assert autopilot_mode(rig) == rig.daemon.adapter.hold_mode()
    summary = log.summary(rig.daemon.counters)
    assert "1 holds" in summary, summary
    assert "stopping in flight: Hold commanded, the autopilot shows it" in out.getvalue()


# ----------------------------------------------------------------------------- a failed re-check in flight

WEAK = {"px4": ("MPC_ACC_HOR", 2.0), "ardupilot": ("WPNAV_ACCEL", 200.0)}  # below the vehicle file's braking


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_failed_recheck_in_flight_holds(personality):
    rig = Rig(column_scenario(1, x_col=400.0), personality)
    fly_mission(rig, 6.0)
    assert rig.daemon.last.state == "active"
    name, value = WEAK[personality]
    t0 = rig.sim.time_s
    rig.to_daemon(AUTOPILOT.system_time_encode(0, 150), AUTOPILOT)  # the autopilot restarted ...
    rig.gcs.send(rig.gcs.param_set_encode(1, 1, name.encode(), value, mav.MAV_PARAM_TYPE_REAL32))  # ... weaker
    rig.run(8.0)
    assert [e for e in rig.log.named("autopilot_restart") if e["t"] >= t0]
    chk = [e for e in rig.log.named("startup_check") if e["t"] >= t0]
    assert chk and not chk[-1]["ok"] and name in chk[-1]["reason"]
    fs = [e for e in rig.log.named("failsafe") if e["cause"] == "start-up checks failed in flight"]
    assert len(fs) == 1 and fs[0]["t"] >= chk[-1]["t"]
    assert [e for e in rig.log.named("command") if e["cmd"] == "hold" and e["t"] >= fs[0]["t"]]
    assert autopilot_mode(rig) == rig.daemon.adapter.hold_mode()
    assert rig.daemon.tel.ground_speed < 0.5


# ----------------------------------------------------------------------------- a refused engage

def test_a_refused_engage_is_said_in_all_four_places_each_time():
    out = io.StringIO()
    log = ConsoleLog(Recorder(), out=out)
    sc = offboard_scenario(1)
    sc["params"] = {"COM_OBL_RC_ACT": 0}  # PX4: offboard loss → position (a companion-only aircraft needs Hold/Land)
    rig = Rig(sc, "px4", config={**offboard_config(), "engage": False}, log=log)
    rig.run(7.0)  # the start-up checks have answered
    assert rig.daemon.startup_ok is False
    for k in range(2):
        rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9))
        rig.run(0.5)
        assert rig.daemon.params["CG_ENGAGE"] == 0.0
        refused = log.log.named("engage_refused")  # the event log
        assert len(refused) == k + 1 and "COM_OBL_RC_ACT" in refused[-1]["reason"]
        texts = [x for x in rig.daemon_texts() if x.startswith("CG: engage REFUSED:")]  # STATUSTEXT
        assert len(texts) == k + 1 and "COM_OBL_RC_ACT" in texts[-1] and "companion-only aircraft" in texts[-1]
        echoed = [m for m in rig.daemon_messages() if m.get_type() == "PARAM_VALUE" and m.param_id == "CG_ENGAGE"]
        assert echoed and echoed[-1].param_value == 0.0  # the parameter echoed back: not engaged
        said = [ln for ln in out.getvalue().splitlines() if "engage REFUSED" in ln]  # the console
        assert len(said) == k + 1 and "COM_OBL_RC_ACT" in said[-1]
    assert not [e for e in log.log.named("param_set") if e["param"] == "CG_ENGAGE"]
    assert not [e for e in log.log.named("command") if e["cmd"] == "offboard"]
