import math
from dataclasses import replace

import pytest

from companion.onboard.estimators import DodEstimate
from companion.onboard.authority import GUARANTEE_ANSWERED
from companion.onboard.overshoot import DEFAULT as OVERSHOOT
from companion.onboard.supervisor import Inputs, OneSidedLimit, Supervisor
from contracts.table import load_for_vehicle

TABLE = load_for_vehicle("mambo")


def dod(d=8.0, obstacle=math.inf, reason="sensor 0 reports range", lowered=False):
    return DodEstimate(d, (0,), obstacle, None, reason, lowered=lowered)


BIN_HALF = math.radians(2.5)  # a 5° bin's half-width


def seen(r, bearing=0.0, d=8.0):
    """What the sensors give the supervisor for one 5° bin's hit `r` m away at body `bearing` (the direction of
    travel is 0): the hit itself and D_od's estimate with it in its band (its `obstacle_m`)."""
    return {"dod": dod(d, obstacle=r), "hits": ((bearing, r, BIN_HALF, True),)}


BASE = Inputs(t=0.0, link_ok=True, telemetry_ok=True, nav_ok=True, armed=True, in_air=True, mode="mission",
              limit_applies=True, mode_by_daemon=False, ground_speed=2.0, dod=dod(), e_tr_measured=0.2, thrust_ratio=1.0,
              r_obst=1.0, engaged=True)


def sup(mode="governor", dwell=2.0):
    return Supervisor(TABLE, mode, contract="avoid" if mode == "offboard" else "stop", dwell_s=dwell,
                      loop_dt=0.02)


def run(s, inputs, t0, t1, dt=0.02, **changes):
    out = []
    t = t0
    while t < t1 - 1e-9:
        out.append(s.step(replace(inputs, t=t, **changes)))
        t += dt
    return out


def test_one_sided_limit_drops_at_once_and_rises_after_the_dwell():
    lim = OneSidedLimit(2.0)
    assert lim.update(0.0, 5.0) == 5.0
    assert lim.update(0.1, 3.0) == 3.0  # at once
    assert lim.update(1.0, 6.0) == 3.0
    assert lim.update(2.05, 6.0) == 3.0  # the 3.0 at t=0.1 is still inside the window
    assert lim.update(3.05, 6.0) == 6.0  # 6 has held for the whole dwell
    assert lim.update(3.1, 4.0) == 4.0


def test_standby_commands_nothing():
    s = sup()
    for changes in ({"engaged": False}, {"in_air": False}, {"armed": False}):
        d = s.step(replace(BASE, **changes))
        assert d.state == "standby" and d.send_speed is None and not d.hold


def test_governor_sends_the_stop_contract_speed_and_follows_dod():
    s = sup()
    d = s.step(BASE)
    # Ω with the E_tr_pred fixed point, sent with room below it for the autopilot's overshoot
    v_max = TABLE.omega(8.0, 1.0, 0.2, 1.0, contract="stop").v_max
    want = OVERSHOOT.sent(v_max)
    assert want <= TABLE.v_stop(8.0, 1.0, 0.2, 1.0) and OVERSHOOT.top(want) == pytest.approx(v_max)
    assert d.state == "active" and d.send_speed == pytest.approx(want) and d.v_cmd == pytest.approx(want)
    assert ("limit_change", {"v_max": pytest.approx(want), "reason": "ok",
                             "overshoot_budget_m_s": pytest.approx(v_max - want)}) in d.events
    # fog: D_od drops, the limit drops in the same cycle
    d2 = s.step(replace(BASE, t=0.02, dod=dod(4.0)))
    low = OVERSHOOT.sent(TABLE.omega(4.0, 1.0, 0.2, 1.0, contract="stop").v_max)
    assert d2.send_speed == pytest.approx(low) and low < want
    # fog clears: the limit rises only after the dwell
    ds = run(s, BASE, 0.04, 2.0)
    assert all(x.v_cmd == pytest.approx(low) for x in ds)
    ds = run(s, BASE, 2.0, 2.2)
    assert ds[-1].v_cmd == pytest.approx(want)


def test_obstacle_inside_the_stop_distance_holds_and_authority_is_respected():
    s = sup()
    s.step(BASE)
    d = s.step(replace(BASE, t=0.02, ground_speed=3.0, **seen(2.0)))
    assert d.hold and d.state == "holding"
    assert any(n == "hold_trigger" and f["cause"] == "obstacle inside the stop distance" for n, f in d.events)
    # not taken within 1 s: asked once only (the mode authority re-sends it: companion/onboard/authority.py)
    d = s.step(replace(BASE, t=1.1, ground_speed=3.0, **seen(2.0)))
    assert not d.hold and d.state == "holding"
    # while in the daemon's Hold nothing more is commanded
    d = s.step(replace(BASE, t=1.14, mode="hold", mode_by_daemon=True, ground_speed=0.5, **seen(2.0)))
    assert not d.hold and d.state == "holding"
    # the pilot resumes the mission: the daemon stands down from that cause
    # (the mode authority judged the change someone else's: companion/onboard/authority.py, tests/test_authority.py)
    d = s.step(replace(BASE, t=1.16, mode="mission", mode_changed=True, taken_over=True, ground_speed=0.5,
                       **seen(2.0)))
    assert d.state == "active" and not d.hold
    assert ("state_change", {"from": "holding", "to": "active", "reason": "mission set by someone else: standing down"}
            ) in d.events
    d = s.step(replace(BASE, t=1.18, ground_speed=2.5, **seen(1.5)))
    assert not d.hold  # same cause, not cleared: no fight
    s.step(replace(BASE, t=1.20, **seen(math.inf)))  # clears
    d = s.step(replace(BASE, t=1.22, ground_speed=3.0, **seen(2.0)))
    assert d.hold  # a new obstacle: hold again


def test_a_wall_beside_the_route_is_not_an_obstacle_ahead():
    """A surface D_od's band holds (`obstacle_m` 2 m) but 60° off the direction of travel — 1.7 m beside the
    line, outside the swept corridor r_body + E_tr — gives no Hold; the same return on the line does."""
    beside = seen(2.0, bearing=math.radians(60))
    assert not any(d.hold for d in run(sup(), BASE, 0.0, 0.2, ground_speed=3.0, **beside))
    assert any(d.hold for d in run(sup(), BASE, 0.0, 0.2, ground_speed=3.0, **seen(2.0)))


def test_a_stood_down_obstacle_re_arms_once_the_corridor_is_clear_though_a_wall_beside_stays_in_view():
    """After the pilot stands the daemon down from an obstacle Hold, the cause re-arms when nothing is left in the
    swept corridor — a wall beside the route, still in D_od's band, does not keep it stood down — so the next
    thing on the path holds again."""
    s = sup()
    s.step(replace(BASE, t=0.0, ground_speed=3.0, **seen(2.0)))
    d = s.step(replace(BASE, t=0.02, mode="mission", mode_changed=True, taken_over=True, ground_speed=3.0, **seen(2.0)))
    assert d.state == "active"
    wall = seen(1.5, bearing=math.radians(70))
    assert not s.step(replace(BASE, t=0.04, ground_speed=3.0, **wall)).hold
    d = s.step(replace(BASE, t=0.06, ground_speed=3.0, **seen(2.0)))
    assert d.hold and any(n == "hold_trigger" for n, _ in d.events)
    # control: with the return still on the path the cause stays stood down (no fight with the pilot)
    s = sup()
    s.step(replace(BASE, t=0.0, ground_speed=3.0, **seen(2.0)))
    s.step(replace(BASE, t=0.02, mode="mission", mode_changed=True, taken_over=True, ground_speed=3.0, **seen(2.0)))
    s.step(replace(BASE, t=0.04, ground_speed=3.0, **seen(2.5)))
    assert not s.step(replace(BASE, t=0.06, ground_speed=3.0, **seen(2.0))).hold


def test_near_rest_anything_close_in_view_holds():
    """At or below 1 m/s the direction of travel is not known: a return close by in any direction holds (and the
    same return at speed, 70° off the line, does not)."""
    close = seen(1.0, bearing=math.radians(70))
    assert any(d.hold for d in run(sup(), BASE, 0.0, 0.1, ground_speed=0.8, **close))
    assert not any(d.hold for d in run(sup(), BASE, 0.0, 0.1, ground_speed=2.0, **close))


def test_far_obstacle_does_not_hold():
    s = sup()
    d = s.step(replace(BASE, ground_speed=2.0, **seen(7.5)))
    assert not d.hold


@pytest.mark.parametrize(
    "changes, cause",
    [
        ({"telemetry_ok": False}, "stale telemetry"),
        ({"nav_ok": False}, "bad navigation estimate"),
        ({"ground_speed": math.nan}, "non-finite telemetry"),
        ({"dod": dod(0.0, reason="no fresh, trusted sensor covers the direction of travel")}, "no safe speed"),
        ({"thrust_ratio": 0.4}, "no safe speed"),
    ],
)
def test_failsafes_hold(changes, cause):
    s = sup()
    s.step(BASE)
    d = s.step(replace(BASE, t=0.02, **changes))
    assert d.hold and d.state == "holding"
    assert any(n == "failsafe" and f["cause"] == cause for n, f in d.events)


def test_link_loss_is_a_failsafe_without_commands_and_restores():
    s = sup()
    s.step(BASE)
    d = s.step(replace(BASE, t=0.02, link_ok=False))
    assert d.state == "failsafe" and not d.hold and d.send_speed is None
    d = s.step(replace(BASE, t=0.04))
    assert d.state == "active" and d.send_speed is not None  # limit re-sent after the link comes back


def test_before_the_first_heartbeat_the_log_says_not_yet_seen_not_lost():
    """Started before the autopilot, the daemon said "autopilot heartbeat lost", then "link restored", of a link
    it never had; a reviewer reads that as a link loss."""
    def reasons(d):
        return [f["reason"] for n, f in d.events if n == "state_change"]
    s = sup()
    assert reasons(s.step(replace(BASE, link_ok=False))) == ["no autopilot heartbeat yet"]
    assert reasons(s.step(replace(BASE, t=0.02))) == ["link up", "limit in force"]
    s.step(replace(BASE, t=0.04, link_ok=False))
    assert s.state == "failsafe"
    assert "link restored" in reasons(s.step(replace(BASE, t=0.06)))


def test_mode_without_speed_limit_is_reported_once():
    s = sup()
    ds = run(s, BASE, 0.0, 0.1, mode="position", limit_applies=False)
    events = [n for d in ds for n, _ in d.events]
    assert events.count("limit_not_applicable") == 1
    assert all(d.send_speed is None for d in ds)


def test_speed_limit_not_in_force_holds_after_the_settle_time():
    s = sup()
    v = TABLE.v_stop(8.0, 1.0, 0.2, 1.0)
    ds = run(s, BASE, 0.0, 1.0, ground_speed=v + 1.0)
    assert not any(d.hold for d in ds)  # a compliant autopilot would still be slowing
    ds = run(s, BASE, 1.0, 4.0, ground_speed=v + 1.0)
    assert any(d.hold for d in ds)


def test_shadow_mode_commands_nothing_but_logs_what_it_would_do():
    s = sup("shadow")
    d = s.step(replace(BASE, **seen(1.0), ground_speed=3.0))
    assert not d.hold and d.send_speed is None and d.state == "standby"
    assert any(n == "would_hold" and "obstacle inside the stop distance" in f["causes"] for n, f in d.events)
    assert d.omega.v_max > 0  # Ω is still computed


def test_violations_start_and_end():
    s = sup()
    d = s.step(replace(BASE, thrust_ratio=0.5))
    assert any(n == "violation_start" and f["subsystem"] == "actuators" for n, f in d.events)
    d = s.step(replace(BASE, t=0.02, dod=dod(3.0, reason="lowered after a late first detection", lowered=True)))
    assert any(n == "violation_start" and f["subsystem"] == "navigation" for n, f in d.events)
    assert any(n == "violation_end" and f["subsystem"] == "actuators" for n, f in d.events)


def test_controller_guarantee_is_checked_at_the_tilt_being_flown():
    """When D_od is lost mid-flight Ω has no speed and no meaningful tilt; the measured contour error
    is still judged against E_tr_pred at the operating point the vehicle was flying, not at the grid's
    smallest tilt (which raised a false controller violation at every route end)."""
    s = sup("offboard")
    flying = replace(BASE, mode="offboard", ground_speed=5.0, dod=dod(6.0), e_tr_measured=0.3)
    d = s.step(flying)
    om = d.omega
    assert om.v_max > 1.0
    e_flown = TABLE.e_tr_pred(d.v_cmd, om.tilt, 1.0)
    e_low = TABLE.e_tr_pred(d.v_cmd, float(TABLE.e_pred.axes[1][0]), 1.0)
    e_meas = 0.5 * (e_flown + e_low)
    assert e_low + 0.05 < e_meas < e_flown - 0.05  # the two readings disagree here
    lost = s.step(replace(flying, t=0.02, dod=dod(0.0), e_tr_measured=e_meas))
    assert lost.omega.v_max == 0.0
    assert not [e for e in lost.events if e[0] == "violation_start" and e[1]["subsystem"] == "controller"]
    s2 = sup("offboard")
    s2.step(flying)
    over = s2.step(replace(flying, t=0.02, dod=dod(0.0), e_tr_measured=e_flown + 0.2))
    assert [e for e in over.events if e[0] == "violation_start" and e[1]["subsystem"] == "controller"]


def _controller_started(d) -> bool:
    return any(e[0] == "violation_start" and e[1]["subsystem"] == "controller" for e in d.events)


def test_the_worst_error_of_a_window_is_judged_against_the_fastest_prediction_of_that_window():
    """E_tr measured is the worst of its window (2 s), each error measured against the path commanded over the span
    (2 s) before it: an error flown at a high V_max is judged against E_tr_pred at that speed while it is in those
    4 s, not against the lower one a shorter D_od sets a moment later (a false controller violation in the demo's fog);
    past them the lower prediction is the one."""
    s = sup("offboard")
    fast = replace(BASE, mode="offboard", ground_speed=5.0, dod=dod(7.0), e_tr_measured=0.3)
    d_fast = s.step(fast)
    e_fast = TABLE.e_tr_pred(d_fast.v_cmd, d_fast.omega.tilt, 1.0)
    slow = replace(fast, dod=dod(3.0), ground_speed=1.0)  # the vehicle slowed below the lower limit
    d_slow = s.step(replace(slow, t=0.02))
    e_slow = TABLE.e_tr_pred(d_slow.v_cmd, d_fast.omega.tilt, 1.0)
    assert d_slow.v_cmd < d_fast.v_cmd - 1.0 and e_slow + 0.1 < e_fast  # the prediction fell with the speed
    e_meas = e_fast - 0.02  # flown within the fast prediction
    assert not _controller_started(s.step(replace(slow, t=0.04, e_tr_measured=e_meas)))
    assert _controller_started(s.step(replace(slow, t=0.06, e_tr_measured=e_fast + 0.1)))  # above even the fast one
    s2 = sup("offboard")
    s2.step(fast)
    s2.step(replace(slow, t=0.02))
    assert not _controller_started(s2.step(replace(slow, t=3.5, e_tr_measured=e_meas)))  # within the path span
    assert _controller_started(s2.step(replace(slow, t=4.5, e_tr_measured=e_meas)))  # the fast speed left both


def test_an_error_flown_above_a_limit_that_just_fell_is_judged_at_the_speed_flown():
    """The limit falls under the vehicle (a shorter D_od): while it still flies faster, slowing, its tracking is that
    of the speed it flies — E_tr_pred at the ground speed, not at the lower limit. Control: the same error with the
    vehicle at the limit breaks the controller contract."""
    def first(ground_speed):
        s = sup("offboard")
        i = replace(BASE, mode="offboard", ground_speed=ground_speed, dod=dod(3.0), e_tr_measured=0.3)
        d = s.step(i)
        e_cmd = TABLE.e_tr_pred(d.v_cmd, d.omega.tilt, 1.0)
        e_flown = TABLE.e_tr_pred(5.0, d.omega.tilt, 1.0)
        assert d.v_cmd < 4.0 and e_cmd + 0.1 < e_flown
        return s.step(replace(i, t=0.02, e_tr_measured=0.5 * (e_cmd + e_flown) + 0.025))

    assert not _controller_started(first(5.0))
    assert _controller_started(first(1.0))  # the control must fail


def test_a_prediction_below_the_measurements_floor_is_judged_at_the_floor():
    """The measured E_tr never reads below its floor (0.3 m): a prediction under it (the governor's at a crawl) is
    judged at the floor, not broken by a vehicle at rest; above the floor the prediction is the bound again."""
    s = Supervisor(TABLE, "offboard", contract="avoid", dwell_s=2.0, loop_dt=0.02,
                   e_tr_floor_m=0.3)
    s.e_tr_pred_flown = lambda v, tilt, thrust: 0.16  # noqa: E731 (a prediction under the floor)
    crawl = replace(BASE, mode="offboard", ground_speed=0.3, dod=dod(7.0), e_tr_measured=0.3)
    assert not _controller_started(s.step(crawl))
    assert _controller_started(s.step(replace(crawl, t=0.02, e_tr_measured=0.4)))


def test_a_fault_that_arrives_while_already_holding_is_logged_once_without_another_hold():
    """Issue 16: bad navigation while the daemon already held for another cause wrote no event (the
    campaign detected it in 63 % / 89 % of flights). It is logged now, once, with its own action."""
    s = sup()
    s.step(BASE)
    d = s.step(replace(BASE, t=0.02, thrust_ratio=0.4))
    assert d.hold and [f["cause"] for n, f in d.events if n == "failsafe"] == ["no safe speed"]
    d = s.step(replace(BASE, t=0.04, thrust_ratio=0.4, mode="hold", mode_by_daemon=True))
    assert not d.hold and d.state == "holding"
    d = s.step(replace(BASE, t=0.06, thrust_ratio=0.4, mode="hold", mode_by_daemon=True, nav_ok=False))
    fs = [f for n, f in d.events if n == "failsafe"]
    assert not d.hold and fs == [{"cause": "bad navigation estimate", "action": "already holding"}]
    d = s.step(replace(BASE, t=0.08, thrust_ratio=0.4, mode="hold", mode_by_daemon=True, nav_ok=False))
    assert not [n for n, _ in d.events if n == "failsafe"]  # once


def test_dod_from_the_swept_coverage_is_logged_when_it_starts_and_ends():
    """Issue 19 item 2: D_od taken from what was seen free (the direction of travel outside the view) is said."""
    s = sup("offboard")
    assert not [e for e in s.step(BASE).events if e[0] == "dod_coverage"]  # the field of view: nothing new
    swept = DodEstimate(2.5, (), math.inf, None, "direction of travel outside the field of view: 2.50 m …", True)
    d = s.step(replace(BASE, t=0.02, dod=swept))
    assert ("dod_coverage", {"basis": "swept", "d_od": 2.5, "reason": swept.reason}) in d.events
    assert d.omega.v_max > 0  # a speed, not "no safe speed"
    assert not [e for e in s.step(replace(BASE, t=0.04, dod=swept)).events if e[0] == "dod_coverage"]
    d = s.step(replace(BASE, t=0.06))
    assert [e[1]["basis"] for e in d.events if e[0] == "dod_coverage"] == ["field of view"]


# ------------------------------------------------ the daemon's own lateness (guidance's guarantee)

def test_lateness_counts_as_reaction_time_never_faster_and_safe_at_its_own_speed():
    """A late cycle is reaction time the table's fold did not budget: Ω must satisfy
    V ≤ V_safe(d_od − V·late, …) (the table's own t_react fold on top), whatever speed is being flown."""
    for contract, mode in (("stop", "governor"), ("avoid", "offboard")):
        for speed in (0.0, 2.0, 6.0):
            for late in (0.05, 0.2, 0.6):
                on_time = sup(mode).step(replace(BASE, ground_speed=speed, mode=mode))
                s = sup(mode)
                d = s.step(replace(BASE, ground_speed=speed, mode=mode, late_s=late, late_unbudgeted_s=late))
                v = d.omega.v_max
                assert v < on_time.omega.v_max  # a lower speed, always
                # safe at its own speed: the table at D_od shortened by v·late answers at least v
                assert v <= TABLE.omega(8.0 - v * late, 1.0, 0.2, 1.0, contract=contract).v_max + 1e-9
                starts = [f for n, f in d.events if n == "violation_start"]
                assert [f["subsystem"] for f in starts] == ["guidance"]
                assert starts[0]["observed"] == pytest.approx(0.02 + late) and starts[0]["assumed"] == 0.02
                assert ("reaction_time", {"late_s": late, "t_react_s": TABLE.vehicle.t_react_s + late}) in d.events


def test_lateness_beyond_the_hard_limit_holds_at_once_and_only_unbudgeted_lateness_is_a_violation():
    s = Supervisor(TABLE, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02, late_hold_s=0.25,
                   t_cmd_s=0.1)  # (its speed commands unanswered here: within their delivery budget)
    s.step(BASE)
    d = s.step(replace(BASE, t=0.02, late_s=0.1, late_unbudgeted_s=0.1))
    assert not d.hold and d.state == "active"  # only slower
    assert [n for n, _ in d.events].count("violation_start") == 1
    d = s.step(replace(BASE, t=0.04, late_s=0.1))  # counted, on time: the guarantee holds at the longer t_react
    assert ("violation_end", {"subsystem": "guidance", "guarantee": "decides every cycle (20 ms + 0 ms jitter allowance, inside t_react)"}) \
        in d.events
    d = s.step(replace(BASE, t=0.06, late_s=0.3, late_unbudgeted_s=0.3))
    assert d.hold and d.state == "holding" and "companion computer late" in d.hold_causes
    assert ("failsafe", {"cause": "companion computer late", "action": "hold"}) in d.events
    (start,) = [f for n, f in d.events if n == "violation_start"]
    assert start["assumed"] == pytest.approx(0.12) and start["observed"] == pytest.approx(0.32)
    d = s.step(replace(BASE, t=0.08, late_s=0.0))  # 10 s later (Timeliness's window): on time again
    assert ("reaction_time", {"late_s": 0.0, "t_react_s": TABLE.vehicle.t_react_s}) in d.events


def test_lateness_inside_the_jitter_allowance_is_an_event_not_a_violation():
    """t_react budgets one loop period plus a stated jitter allowance: a cycle late within it is said, the guarantee
    holds; beyond it the violation names the allowance it assumed."""
    s = Supervisor(TABLE, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02,
                   late_allowance_s=0.03, t_cmd_s=0.1)
    s.step(BASE)
    d = s.step(replace(BASE, t=0.02, late_within_s=0.025))
    assert ("cycle_jitter", {"late_s": 0.025, "allowance_s": 0.03}) in d.events
    assert not [n for n, _ in d.events if n.startswith("violation")] and d.omega == s.step(BASE).omega
    d = s.step(replace(BASE, t=0.04, late_s=0.04, late_unbudgeted_s=0.04))
    (start,) = [f for n, f in d.events if n == "violation_start"]
    assert start["subsystem"] == "guidance" and "30 ms jitter allowance" in start["guarantee"]
    assert start["assumed"] == pytest.approx(0.05) and start["observed"] == pytest.approx(0.06)


def test_a_speed_command_is_sent_every_cycle_until_the_autopilot_answers_it():
    """DO_CHANGE_SPEED lost on the link is sent again the next cycle (delivery), not 5 s later."""
    s = Supervisor(TABLE, "governor", contract="stop", dwell_s=2.0, loop_dt=0.02, t_cmd_s=0.1)
    first = s.step(BASE)
    assert first.send_speed is not None
    again = s.step(replace(BASE, t=0.02))  # no answer: sent again
    assert again.send_speed == pytest.approx(first.send_speed)
    assert not [n for n, _ in s.step(replace(BASE, t=0.1)).events if n == "violation_start"]  # within its budget
    late = s.step(replace(BASE, t=0.12))  # unanswered past it: said
    assert [f["guarantee"] for n, f in late.events if n == "violation_start"] == [GUARANTEE_ANSWERED]
    s.speed_answered()
    d = s.step(replace(BASE, t=0.14))
    assert d.send_speed is None  # answered: not until it changes (or 5 s)
    assert any(n == "violation_end" and f["subsystem"] == "delivery" for n, f in d.events)
    assert s.step(replace(BASE, t=5.2)).send_speed is not None


def test_an_obstacle_wider_than_r_obst_breaks_the_avoid_contract_not_the_stop_contract():
    """R_obst is what the swerve is planned round: a wall seen wider is an environment violation under the avoid
    contract; the stop contract stops short of whatever is within D_od, so under it nothing is broken (a wall beside
    a governor's route is not a finding)."""
    wall = replace(BASE, obstacle_width=3.0)
    subsystems = lambda d: [f["subsystem"] for n, f in d.events if n == "violation_start"]  # noqa: E731
    assert "environment" not in subsystems(sup("governor").step(wall))
    assert "environment" not in subsystems(sup("shadow").step(wall))
    assert "environment" in subsystems(sup("offboard").step(replace(wall, mode="offboard")))
