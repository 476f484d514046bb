"""The review never calls a flight "kept" where the vehicle entered its keep-out disc, hit something as far as the
log tells, or a command did not take effect on time (companion/ground/review_checks.py). Small governor flights
written through the real EventLog, each beside a clean twin that stays kept; then the column flight in
lock-step with the daemon's first mode command lost on the link."""

from dataclasses import replace

import numpy as np
import pytest

from companion.ground import review_checks
from companion.ground.commands import review_log
from companion.onboard.eventlog import EventLog
from companion.onboard.guidance import OffboardGuidance
from companion.onboard.states import CYCLE_COMPLETES, REFERENCE_ON
from companion.ground.review import format_report, review, run_facts, summarise
from companion.ground.review_html import verdict
from tests import golden
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly
from tests.test_delivery_lockstep import ResendAfterOneSecond
from tests.test_offboard_lockstep import engage_and_fly, offboard_config, offboard_scenario

DT = 0.1
X_COL, R_COL = 20.0, 0.5  # a column ahead on the route (its surface at 19.5 m)
E_TR, R_BODY = 0.3, 0.10  # the Mambo's radius (the shipped vehicle the start record names)
KEEP_OUT = R_BODY + 0.1  # the body and the near miss's 0.1 m (the E_tr band is the path's: within the contract)


def sample(t, x, gs, mode="mission", **over):
    ob = X_COL - R_COL - x
    s = dict(state="active", mode=mode, contract="stop", engaged=True, x=x, y=0.0, z=-2.0, vx=gs, vy=0.0, vz=0.0,
             ground_speed=gs, d_od=6.0, e_tr=E_TR, e_tr_measured=0.2, r_obst=0.5, thrust_ratio=1.0, v_max=3.2,
             tilt_deg=20.0, v_safe=3.4, gamma=-0.2, gamma_flown=gs - 3.4, v_cmd=3.2,
             obstacle_m=ob if ob < 6.0 else float("inf"))
    s.update(over)
    return t, s


def write(directory, samples, events=(), start=None):
    """An event log: a governor's start record (the shipped Mambo), then `samples` [(t, fields)] and `events`
    [(t, name, fields)] in time order (an event before a sample of the same time)."""
    log = EventLog(directory)
    log.event(None, "start", **(start or {"mode": "governor", "vehicle": "mambo"}))
    recs = [(t, 0, name, f) for t, name, f in events] + [(t, 1, None, f) for t, f in samples]
    for t, _, name, f in sorted(recs, key=lambda r: r[:2]):
        log.event(t, name, **f) if name else log.state(t, **f)
    log.close()
    return directory


def stopping(directory, stop_at_m, events=(), v=3.0, a=3.0, t_end=12.0):
    """A cruise at v along +x towards the column, Hold commanded as it brakes at a m/s² to stop `stop_at_m` from
    the column's surface, the mode shown 0.1 s later; the review of its log."""
    brake_d = v * v / (2 * a)
    x_brake = X_COL - R_COL - stop_at_m - brake_d
    t_hold = round(x_brake / v, 1)
    samples = []
    for i in range(int(t_end / DT) + 1):
        t = i * DT
        tb = min(max(t - x_brake / v, 0.0), v / a)
        x, gs = min(v * t, x_brake) + v * tb - a * tb * tb / 2, v - a * tb
        samples.append(sample(t, x, gs, mode="hold" if t >= t_hold + 0.1 - 1e-9 else "mission"))
    return review(write(directory, samples, [hold_cmd(t_hold), mode_change(t_hold + 0.1), *events]))


def hold_cmd(t):
    return (t, "command", {"cmd": "hold", "params": [129.0, 4.0, 3.0, None, None, None, None]})


def mode_change(t, to="hold", frm="mission"):
    return (t, "mode_change", {"from": frm, "to": to, "by": "daemon"})


def said(rep) -> str:
    return " | ".join(rep["findings"])


# ----------------------------------------------------------------------------- keep-out and collisions

def test_a_stop_short_of_the_keep_out_disc_is_kept(tmp_path):
    rep = stopping(tmp_path, 1.0)
    assert rep["ok"], rep["findings"]
    assert rep["keep_out"]["vehicles"][0]["r_body_m"] == R_BODY  # looked up: the shipped vehicle the log names
    assert verdict(rep) == "contract kept (no findings)"


def test_a_near_miss_inside_the_keep_out_disc_is_a_finding(tmp_path):
    assert stopping(tmp_path / "band", 0.3)["ok"]  # 0.3 m from the surface: inside E_tr + r_body, the path's margin
    rep = stopping(tmp_path, 0.15)  # 0.15 m from the surface: within 0.1 m of the body, short of it
    assert not rep["ok"]
    (e,) = rep["keep_out"]["entries"]
    assert e["closest_m"] == pytest.approx(0.15, abs=0.02) and e["margin_m"] == pytest.approx(KEEP_OUT)
    assert e["explained_by"] == [] and not rep["keep_out"]["collisions"]
    f = said(rep)
    assert "entered its keep-out disc 1×" in f and "unexplained" in f and "shown 0.10 s later" in f
    assert verdict(rep) == "REVIEW NEEDED: the vehicle entered its keep-out disc"
    assert "keep-out" in format_report(rep)


def test_a_keep_out_entry_names_the_violation_open_then(tmp_path):
    rep = stopping(tmp_path, 0.15, [(2.0, "violation_start", {
        "subsystem": "navigation", "guarantee": "obstacles within D_od are detected", "assumed": 6.0,
        "observed": 2.0, "action": "hold"})])
    assert "with navigation's guarantee broken then" in said(rep)
    assert rep["keep_out"]["entries"][0]["explained_by"] == ["navigation"]


def test_a_return_inside_the_body_is_a_collision(tmp_path):
    hover = [sample(i * DT, 19.42, 0.0, obstacle_m=0.08) for i in range(50)]  # 0.08 m: inside r_body 0.10 m
    rep = review(write(tmp_path, hover))
    assert not rep["ok"] and "collision as far as the log tells (1×)" in said(rep)
    (c,) = rep["keep_out"]["collisions"]  # one, however long it stays there
    assert c["t"] == 0.0 and "a return at 0.08 m, at or inside the vehicle's radius 0.10 m" in c["how"]
    assert verdict(rep) == "REVIEW NEEDED: a collision, as far as the log tells"


def test_a_return_too_near_to_stop_short_of_is_a_collision(tmp_path):
    """0.3 m from the surface closing at 3 m/s: braking at 2 g needs 0.23 m, the body has 0.2 m. The same log
    ending 0.6 m short (0.5 m for the body: enough at 2 g) shows none, and a nearer obstacle taking over as the
    nearest (0.5 m, outside E_tr + r_body) is no approach at all."""
    samples = [sample(i * DT, 3.0 * i * DT, 3.0) for i in range(64)]  # the last at 18.9 m: 0.6 m short
    samples.append(sample(6.4, 19.2, 3.0))
    rep = review(write(tmp_path / "a", samples))
    assert not rep["ok"] and "collision as far as the log tells (1×)" in said(rep)
    (c,) = rep["keep_out"]["collisions"]
    assert c["t"] == pytest.approx(6.4) and "a return 0.30 m away closing at 3.00 m/s" in c["how"]
    rep = review(write(tmp_path / "b", samples[:-1]))
    assert not rep["keep_out"]["collisions"]
    jump = [sample(i * DT, 0.0, 3.0, obstacle_m=3.0 if i < 20 else 0.5) for i in range(40)]
    assert review(write(tmp_path / "c", jump))["ok"]


def test_a_stop_faster_than_any_brake_against_a_return_is_a_collision(tmp_path):
    """At 3 m/s to a standstill in one 0.1 s sample, 0.35 m from the surface (a return far enough for 2 g to stop
    the body short of it): it hit the column, and the sensor, below its minimum range, then says nothing."""
    samples = [sample(i * DT, 3.0 * i * DT, 3.0) for i in range(63)]  # the last at 18.6 m: 0.9 m short
    samples += [sample(6.3, 18.85, 3.0), sample(6.4, 19.15, 3.0)]  # 0.65 m, 0.35 m
    samples += [sample(6.5 + i * DT, 19.2, 0.0, obstacle_m=None) for i in range(20)]
    rep = review(write(tmp_path, samples))
    assert not rep["ok"] and "collision as far as the log tells" in said(rep)
    (c,) = rep["keep_out"]["collisions"]
    assert c["t"] == pytest.approx(6.5) and "stopped from 3.00 to 0.00 m/s in 0.10 s with a return 0.35 m" in c["how"]


def test_hovering_beside_a_wall_outside_the_margin_is_kept(tmp_path):
    """A return 0.3 m away for 20 s, outside r_body + 0.1 m: no finding; 0.15 m: a finding."""
    hover = [sample(i * DT, 0.0, 0.05, obstacle_m=0.3) for i in range(200)]
    assert review(write(tmp_path / "a", hover))["ok"]
    close = [sample(i * DT, 0.0, 0.05, obstacle_m=0.15) for i in range(200)]
    rep = review(write(tmp_path / "b", close))
    assert not rep["ok"] and rep["keep_out"]["entry_count"] == 1
    assert rep["keep_out"]["entries"][0]["duration_s"] == pytest.approx(19.9)


# ----------------------------------------------------------------------------- mode commands

def hold_flight(directory, shown_after_s, t_hold=5.0, start=None, ack=None):
    """Cruising at 1 m/s far from anything; Hold commanded at t_hold, shown `shown_after_s` later (None: never)."""
    t_mode = None if shown_after_s is None else t_hold + shown_after_s
    samples = [sample(i * DT, i * DT, 1.0, mode="hold" if t_mode is not None and i * DT >= t_mode - 1e-9
                      else "mission", obstacle_m=float("inf")) for i in range(121)]
    events = [hold_cmd(t_hold)] + ([mode_change(t_mode)] if t_mode is not None else [])
    events += [] if ack is None else [(t_hold + 0.02, "command_ack", {"command": 176, "result": ack})]
    return review(write(directory, samples, events, start))


def test_a_hold_shown_at_once_is_kept(tmp_path):
    rep = hold_flight(tmp_path, 0.1, ack=0)
    assert rep["ok"], rep["findings"]
    assert rep["delivery"]["mode_delay_max_s"] == pytest.approx(0.1)


def test_a_hold_never_shown_is_a_finding(tmp_path):
    rep = hold_flight(tmp_path, None)
    assert not rep["ok"]
    assert "1 mode command(s) not taken within their 1.20 s: hold at t = 5.00 s not shown" in said(rep)
    (m,) = rep["delivery"]["modes_not_taken"]
    assert m["outcome"] == "not shown" and m["mode_seen"] == "mission"
    assert verdict(rep) == "REVIEW NEEDED: a command was refused or not taken in time"


def test_a_hold_shown_two_seconds_late_is_a_finding(tmp_path):
    rep = hold_flight(tmp_path, 2.0)
    assert not rep["ok"] and "hold at t = 5.00 s shown 2.00 s later" in said(rep)
    (m,) = rep["delivery"]["modes_not_taken"]
    assert m["outcome"] == "shown late" and m["delay_s"] == pytest.approx(2.0)


def test_the_logs_own_mode_budget_is_used(tmp_path):
    """`start.delivery.t_mode_s` replaces the review's default budget (1.5 s)."""
    assert hold_flight(tmp_path / "a", 1.0)["ok"]
    rep = hold_flight(tmp_path / "b", 1.0, start={"mode": "governor", "vehicle": "mambo",
                                                  "delivery": {"t_mode_s": 0.5}})
    assert not rep["ok"] and "not taken within their 0.50 s" in said(rep)


def test_a_mode_command_refused_by_the_autopilot_is_a_finding(tmp_path):
    rep = hold_flight(tmp_path, None, ack=4)  # MAV_RESULT_FAILED
    f = said(rep)
    assert "not accepted by the autopilot, the first at t = 5.02 s: DO_SET_MODE: FAILED (4)" in f
    assert "hold at t = 5.00 s not shown" in f
    assert verdict(rep) == "REVIEW NEEDED: a command was refused or not taken in time"


def test_an_answer_in_progress_is_no_refusal(tmp_path):
    assert hold_flight(tmp_path, 0.3, ack=5)["ok"]  # MAV_RESULT_IN_PROGRESS, then the mode shown


def test_a_delivery_violation_logged_by_the_daemon_is_named_in_the_verdict(tmp_path):
    samples = [sample(i * DT, i * DT, 1.0, obstacle_m=float("inf")) for i in range(50)]
    events = [(2.0, "violation_start", {"subsystem": "delivery", "guarantee": "a requested mode is shown within t_cmd",
                                        "assumed": 1.0, "observed": 1.6, "action": "re-sent"}),
              (2.5, "violation_end", {"subsystem": "delivery", "guarantee": "a requested mode is shown within t_cmd"})]
    rep = review(write(tmp_path, samples, events))
    assert rep["violations_by_subsystem"]["delivery"]["count"] == 1
    assert "delivery ×1" in said(rep)
    assert verdict(rep) == "REVIEW NEEDED: a command was refused or not taken in time"


def test_a_cycle_of_the_daemon_that_ended_in_an_internal_error_is_named_in_the_verdict(tmp_path):
    """As the daemon logs 25 failed cycles in a row (tests/test_hostile_input.py): the loop errors it logged (the
    1st and the 10th), and guidance's violation from the first to the next cycle that completed."""
    samples = [sample(i * DT, i * DT, 1.0, obstacle_m=float("inf")) for i in range(50)]
    broke = {"subsystem": "guidance", "guarantee": CYCLE_COMPLETES}
    events = [(2.0, "violation_start", {**broke, "assumed": 0, "observed": 1, "action": "hold"}),
              (2.0, "loop_error", {"error": "ZeroDivisionError: a bug", "consecutive": 1, "action": "hold"}),
              (2.2, "loop_error", {"error": "ZeroDivisionError: a bug", "consecutive": 10, "action": "hold"}),
              (2.5, "violation_end", {**broke, "observed": 25})]
    rep = review(write(tmp_path, samples, events))
    assert not rep["ok"] and verdict(rep) == "REVIEW NEEDED: the daemon's own cycle failed"
    assert ("the daemon's cycle ended in an internal error (up to 10 in a row), first at t = 2.00 s: "
            "ZeroDivisionError: a bug; action: hold") in said(rep)
    assert "guidance ×1 (0.5 s)" in said(rep) and "ms apart" not in said(rep)  # a count, not a cycle's lateness


def test_a_setpoint_put_metres_off_the_vehicle_is_guidance_s_violation_said_and_reviewed(tmp_path, monkeypatch):
    """A fault of guidance's own, injected in the offboard flight (PX4, nothing in the way): from 8 s on every cruise
    setpoint is put 3 m to the side of where it should be — one jump, then on from there. The daemon says guidance's
    guarantee broken at that setpoint, by about 3 m, and kept again at the next; the review names it. Before the
    fault: nothing."""
    def shifted(self, *args, **kw):
        sp = cruise(self, *args, **kw)
        return replace(sp, p=sp.p + np.array([0.0, 3.0])) if on else sp

    cruise, on = OffboardGuidance._cruise, False
    monkeypatch.setattr(OffboardGuidance, "_cruise", shifted)
    log = EventLog(tmp_path / "log")
    rig = Rig(offboard_scenario(1, x_col=400.0), "px4", log=log, config=offboard_config(x_end=120.0))
    log.event(None, "start", mode=rig.cfg.mode, vehicle=rig.daemon.table.vehicle.name, table=str(rig.daemon.table.path))
    engage_and_fly(rig, 8.0)
    on, t0 = True, rig.sim.time_s
    rig.run(2.0)
    log.close()
    rep, _ = review_log(tmp_path / "log")
    (v,) = [v for v in rep["violations"] if v["subsystem"] == "guidance"]
    assert v["guarantee"] == REFERENCE_ON and 2.5 < v["observed"] < 3.5 and v["ended_by"] == "violation_end"
    assert 0.0 <= v["start_t"] - t0 < 0.1 and 0.0 < v["end_t"] - v["start_t"] < 0.1
    assert not rep["ok"] and "guidance ×1" in said(rep) and "ms apart" not in said(rep)


# ----------------------------------------------------------------------------- speed limits

def speed_flight(directory, v_before, v_cmd, slow_m_s2, t_cmd=3.0):
    """Flying at v_before far from anything; a limit of v_cmd commanded at t_cmd; then slowing at slow_m_s2."""
    samples = []
    for i in range(101):
        t = i * DT
        gs = v_before if t < t_cmd else max(v_before - slow_m_s2 * (t - t_cmd), min(v_before, v_cmd))
        samples.append(sample(t, 0.0, gs, obstacle_m=float("inf"), v_cmd=v_before if t < t_cmd else v_cmd,
                              v_max=3.2))
    events = [(0.0, "command", {"cmd": "change_speed", "params": [1.0, v_before, -1.0, 0, 0, 0, 0]}),
              (t_cmd, "command", {"cmd": "change_speed", "params": [1.0, v_cmd, -1.0, 0, 0, 0, 0]})]
    return review(write(directory, samples, events))


def test_a_speed_limit_flown_is_kept(tmp_path):
    rep = speed_flight(tmp_path, 2.0, 3.0, 3.0)  # a higher limit: nothing to slow down for
    assert rep["ok"], rep["findings"]
    assert rep["delivery"]["speed_limits"] == 2


def test_a_lower_limit_flown_within_the_braking_time_is_no_delivery_finding(tmp_path):
    """3 → 1 m/s at the Mambo's 3 m/s² braking: flown within (3 − 1)/3 + 1 s. (Ground speed above the new limit
    while slowing is still the review's `above the limit` finding: the limit is not in force at once.)"""
    rep = speed_flight(tmp_path, 3.0, 1.0, 3.0)
    assert rep["delivery"]["limits_not_flown"] == [] and "not flown" not in said(rep)


def test_a_speed_limit_not_flown_is_a_finding(tmp_path):
    rep = speed_flight(tmp_path, 3.0, 1.0, 0.0)  # the autopilot flies on at 3 m/s
    assert "1 speed limit(s) not flown: 1.00 m/s commanded at t = 3.00 s, ground speed up to 3.00 m/s" in said(rep)
    (s,) = rep["delivery"]["limits_not_flown"]
    assert s["budget_s"] == pytest.approx(2.0 / 3.0 + 1.0) and s["worst_m_s"] == 3.0
    assert "command was refused or not taken in time" in verdict(rep)


# ----------------------------------------------------------------------------- the daemon in lock-step

def golden_records(name: str) -> list[dict]:
    """A recorded golden flight (tests/golden.py) as its event log's records, headed by a start record."""
    g = golden.load(name)
    recs = sorted([{"kind": "event", **e} for e in g["events"]] + [{"kind": "state", **s} for s in g["states"]],
                  key=lambda r: (r["t"], r["kind"] == "state"))
    for r in recs:  # the recording keeps non-finite floats as text; the event log writes null
        r.update({k: None for k, v in r.items() if v in ("inf", "-inf", "nan")})
    vehicle = "x500" if "x500" in name else "mambo"
    return [{"kind": "event", "t": None, "event": "start", "vehicle": vehicle,
             "mode": "shadow" if name.startswith("shadow") else "governor"}, *recs]


FOG_RETURNS_INSIDE = ()  # flights whose (medium's) returns come inside the keep-out: none at r_body + 0.1 m


@pytest.mark.parametrize("name", sorted(golden.FLIGHTS))
def test_the_golden_flights_get_no_new_finding_but_the_shadow_flight_into_the_column(name):
    """No keep-out, collision or delivery finding on the recorded flights (a Hold shown within 0.06 s, limits
    flown, the closest return 0.04 m outside E_tr + r_body in figure 17) — but the shadow flight flew through
    the column, and says so; and the offboard flight held in hidden fog has the medium's returns inside its
    keep-out disc (every return is an obstacle until shown otherwise), said with the navigation guarantee broken."""
    rep = summarise(golden_records(name), facts_of=run_facts)
    said_here = review_checks.findings(rep)
    if name in FOG_RETURNS_INSIDE:
        assert said_here and all("keep-out" in f and "navigation's guarantee broken" in f for f in said_here)
        return
    if name != "shadow_px4_column":
        assert said_here == [], said_here
        return
    (e,) = rep["keep_out"]["entries"]
    assert e["closest_m"] < 0.2 and "(shadow mode: the daemon commanded nothing)" in said_here[0]


def column_flight(directory, drop: bool):
    """The governor's column flight (PX4, the column at 28 m) with the event log the daemon writes, headed by the
    start record `contract-guard run` writes; if `drop`, its first Hold lost on the link and — as before the mode
    authority re-sent commands every cycle and the stop contract budgeted their delivery — re-sent a second later
    (tests/test_delivery_lockstep.py's negative control): a flight that reaches the column."""
    log = EventLog(directory)
    rig = Rig(column_scenario(1), "px4", log=log, config={"delivery": {"t_cmd_s": 0.0}} if drop else None,
              outbound={"drop_holds": 1} if drop else None)
    if drop:
        a = rig.daemon.cycle.authority
        rig.daemon.cycle.authority = ResendAfterOneSecond(a.hold_mode, a.t_cmd_s, a.t_mode_s, a.hold_fallbacks)
    log.event(None, "start", mode=rig.cfg.mode, vehicle=rig.daemon.table.vehicle.name, table=str(rig.daemon.table.path))
    fly(rig, 25.0)
    log.close()
    return rig, [t for t, _ in rig.outbound.dropped] if drop else []


def test_a_lost_hold_that_ends_in_the_column_is_not_kept(tmp_path):
    """The Hold went out again 1 s later, the autopilot showed it at once, too late: the column is hit. The
    sensor's last return is inside the keep-out disc, and at or inside the body's radius or nearer than it could stop
    even at 2 g: a collision as far as the log tells."""
    rig, lost = column_flight(tmp_path / "log", drop=True)
    assert lost and rig.truth["collisions"]
    rep, _ = review_log(tmp_path / "log")
    assert not rep["ok"]
    # (the vehicle then rests against the column: its sensor's return wavers about the keep-out margin, one entry or
    # several, each after that same late Hold)
    e, *more = rep["keep_out"]["entries"]
    assert all(m["last_mode_command"] == e["last_mode_command"] for m in more)
    assert e["closest_m"] < R_BODY + 0.1 and e["margin_m"] == pytest.approx(KEEP_OUT)
    last = e["last_mode_command"]
    assert last["cmd"] == "hold" and last["t"] == pytest.approx(lost[0]) and last["delay_s"] > 0.9
    (c,) = rep["keep_out"]["collisions"]
    assert c["t"] == pytest.approx(rig.truth["collisions"][0].time_s, abs=0.15)
    f = said(rep)
    assert "collision as far as the log tells (1×)" in f
    assert "not even braking at 2 g" in f or "at or inside the vehicle's radius" in f
    assert "entered its keep-out disc" in f and "the last mode command before it: hold at t = " in f
    assert "contract kept" not in format_report(rep) and "collision" in verdict(rep)


def test_the_same_flight_with_its_hold_delivered_is_kept(tmp_path):
    rig, _ = column_flight(tmp_path / "log", drop=False)
    assert not rig.truth["collisions"]
    rep, _ = review_log(tmp_path / "log")
    assert rep["ok"], rep["findings"]
    assert rep["delivery"]["mode_commands"] == 1 and rep["delivery"]["mode_delay_max_s"] < 0.1


def test_the_same_hold_lost_and_re_sent_every_cycle_stops_short_and_is_kept(tmp_path):
    """With the mode authority's delivery (re-sent the next cycle) and its budget in the stop contract, the same lost
    Hold stops short: kept, the re-send in the log."""
    log = EventLog(tmp_path / "log")
    rig = Rig(column_scenario(1), "px4", log=log, outbound={"drop_holds": 1})
    log.event(None, "start", mode=rig.cfg.mode, vehicle=rig.daemon.table.vehicle.name, table=str(rig.daemon.table.path))
    fly(rig, 25.0)
    log.close()
    assert rig.outbound.dropped and not rig.truth["collisions"]
    rep, _ = review_log(tmp_path / "log")
    assert rep["ok"], rep["findings"]
