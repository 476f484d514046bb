"""The flight reviewer: a scripted flight written through the real EventLog, then checked against what the
script did (not against what the reviewer prints)."""

import csv
import json
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.onboard.eventlog import EventLog
from companion.onboard.logschema import REPLAY_LOG_FILE
from companion.ground.review import SCHEMA, Origin, format_report, review, summarise
from contracts.errors import ContractError

DT = 0.05  # 20 Hz samples


def sample(i, **over):
    t = i * DT
    s = dict(state="cruise", mode="AUTO.MISSION", contract="stop", engaged=True, x=t, y=0.0, z=-10.0,
             vx=2.0, vy=0.0, vz=0.0, ground_speed=2.0, d_od=6.0, e_tr=0.3, e_tr_measured=0.2, r_obst=0.5,
             thrust_ratio=1.0, v_max=3.0, tilt_deg=20.0, v_safe=3.2, gamma=-0.2, v_cmd=3.0)
    s.update(over)
    return t, s


def put(log, i, **over):
    t, s = sample(i, **over)
    log.state(t, **s)


def fly(directory, wall0=1_790_000_000.0):
    """A scripted two-run flight. Run 1, samples i = 0…599 (t 0…29.95 s):
    - i 100…139 (t 5.00…6.95): Γ = +0.4 (2.0 s), navigation violation 5.0 → 7.0 s, failsafe at 5.0 cleared 8.0
    - i 200…219 (t 10.00…10.95): ground speed 3.9 vs v_cmd 3.0 (excess 0.9, 1.0 s over)
    - i 300: d_od 1.5 (minimum), thrust_ratio 0.6 (minimum); i 310: e_tr 1.1 (maximum)
    - t 12.0: link down, t 14.5: link up; t 15.0: mode change by other
    - actuators violation starts at t 25.0 and is still open when run 1 is killed (last sample t 29.95)
    Run 2 (new boot), samples i = 700…799 (t 35.00…39.95), shadow mode (v_cmd null), clean stop.
    """
    wall = {"t": wall0}
    clock = lambda: wall["t"]  # noqa: E731
    log = EventLog(directory, clock=clock)
    log.event(0.0, "start")
    log.event(0.0, "startup_check", ok=True, reason="all checks passed")
    for i in range(600):
        t = i * DT
        wall["t"] = wall0 + t
        over = {}
        if 100 <= i < 140:
            over.update(gamma=0.4, v_safe=2.6)
        if 200 <= i < 220:
            over.update(ground_speed=3.9)
        if i == 300:
            over.update(d_od=1.5, thrust_ratio=0.6)
        if i == 310:
            over.update(e_tr=1.1)
        if i == 100:
            log.event(t, "violation_start", subsystem="navigation", guarantee="obstacles within D_od are detected",
                      assumed=6.0, observed=2.5, action="hold")
            log.event(t, "failsafe", cause="late_detection", action="hold")
        if i == 140:
            log.event(t, "violation_end", subsystem="navigation", guarantee="obstacles within D_od are detected",
                      assumed=6.0, observed=6.0, action="resume")
        if i == 160:
            log.event(t, "failsafe_clear", cause="late_detection")
        if i == 240:
            log.event(t, "link", status="down")
        if i == 290:
            log.event(t, "link", status="up")
        if i == 300:
            log.event(t, "mode_change", **{"from": "AUTO.MISSION", "to": "POSCTL", "by": "other"})
            log.event(t, "limit_change", v_max=2.0, reason="thrust")
            log.event(t, "command", name="MAV_CMD_DO_CHANGE_SPEED", params=[1, 2.0, -1], result="ACCEPTED")
            log.event(t, "command", name="MAV_CMD_DO_CHANGE_SPEED", params=[1, 2.0, -1], result="DENIED")
        if i == 500:
            log.event(t, "violation_start", subsystem="actuators", guarantee="thrust_ratio ≥ 0.8",
                      assumed=0.8, observed=0.55, action="limit lowered")
        put(log, i, **over)
    log.flush()  # then "kill -9": no close, no stop event
    log2 = EventLog(directory, clock=clock)
    log2.event(35.0, "start")
    for i in range(700, 800):
        wall["t"] = wall0 + i * DT
        put(log2, i, v_cmd=None, ground_speed=3.1)  # shadow: 0.1 over v_max (within tolerance)
    log2.event(39.95, "stop")
    log2.close()


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("flight")
    fly(d)
    return d


def test_the_report_matches_the_scripted_flight(flight):
    rep = review(flight)
    assert rep["schema"] == SCHEMA and rep["ok"] is False
    assert rep["state_samples"] == 700
    assert rep["span"]["t_first"] == 0.0 and rep["span"]["t_last"] == pytest.approx(39.95)
    assert rep["span"]["utc_first"] == "2026-09-21T14:13:20+00:00"
    assert [b["clean_stop"] for b in rep["boots"]] == [False, True]
    assert rep["gamma_positive_s"] == pytest.approx(2.0)
    assert rep["sampled_s"] == pytest.approx(599 * DT + 99 * DT)  # the 5 s between runs is not sampled time
    assert rep["sample_gaps"] == 0  # a restart is not a gap inside a run

    assert rep["violation_count"] == 2
    nav, act = rep["violations"]
    assert (nav["subsystem"], nav["start_t"], nav["end_t"], nav["ended_by"]) == ("navigation", 5.0, 7.0, "violation_end")
    assert nav["duration_s"] == pytest.approx(2.0)
    assert (nav["assumed"], nav["observed"], nav["observed_end"], nav["action"]) == (6.0, 2.5, 6.0, "hold")
    assert (act["subsystem"], act["start_t"], act["ended_by"]) == ("actuators", 25.0, "restart")
    assert act["end_t"] == pytest.approx(29.95) and act["duration_s"] == pytest.approx(4.95)
    assert rep["violations_by_subsystem"]["navigation"]["count"] == 1

    worst = rep["over_limit"]["worst"]
    assert worst["excess_m_s"] == pytest.approx(0.9) and worst["limit_source"] == "v_cmd" and worst["t"] == 10.0
    assert rep["over_limit"]["time_over_limit_s"] == pytest.approx(1.0)
    assert rep["ranges"]["d_od"]["min"] == 1.5 and rep["ranges"]["thrust_ratio"]["min"] == 0.6
    assert rep["ranges"]["e_tr"]["max"] == 1.1 and rep["ranges"]["v_max"] == {"min": 3.0, "max": 3.0, "missing": 0}
    assert rep["ranges"]["v_cmd"]["missing"] == 100

    (fs,) = rep["failsafes"]
    assert (fs["cause"], fs["action"], fs["t"], fs["cleared_t"]) == ("late_detection", "hold", 5.0, 8.0)
    assert rep["mode_changes"] == [{"t": 15.0, "from": "AUTO.MISSION", "to": "POSCTL", "by": "other"}]
    assert rep["link"]["down_s"] == pytest.approx(2.5)
    assert rep["limit_changes"] == 1 and rep["commands"]["count"] == 2
    assert [c["result"] for c in rep["commands"]["failed"]] == ["DENIED"]
    assert rep["startup_checks"] == [{"t": 0.0, "ok": True, "reason": "all checks passed"}]
    text = " | ".join(rep["findings"])
    for needle in ("2 contract violation(s)", "Γ > 0 for 2.00 s", "by up to 0.90 m/s", "1 failsafe",
                   "link down for 2.5 s", "restarted 1× without a clean stop", "1 command(s) not accepted"):
        assert needle in text
    json.dumps(rep, allow_nan=False)
    out = format_report(rep)
    assert "navigation" in out and "REVIEW NEEDED" in out


def test_a_clean_flight_has_no_findings(tmp_path):
    log = EventLog(tmp_path)
    log.event(0.0, "start")
    for i in range(200):
        put(log, i)
    log.event(10.0, "stop")
    log.close()
    rep = review(tmp_path / "events.jsonl")
    assert rep["ok"] is True and rep["findings"] == [] and rep["violations"] == []
    assert rep["over_limit"]["worst"]["excess_m_s"] == pytest.approx(-1.0)  # a margin, not an excess
    assert "contract kept" in format_report(rep)


def test_the_returns_withheld_within_a_sensors_clutter_are_said_with_the_flights_count(tmp_path):
    """The daemon counts, frame by frame, the returns it withheld within a sensor's clutter; the review gives the
    flight's count (the last, cumulative), and says nothing of it where none was withheld."""
    for name, counts in (("some", [0] * 50 + [1] * 50 + [3] * 100), ("none", [0] * 200)):
        log = EventLog(tmp_path / name)
        for i, n in enumerate(counts):
            put(log, i, withheld=n)
        log.close()
        text = format_report(review(tmp_path / name / "events.jsonl"))
        said = [line for line in text.splitlines() if "withheld until confirmed" in line]
        assert said == (["  returns within a sensor's clutter withheld until confirmed: 3 (frame by frame; one "
                         "confirmed where the sensor had looked past is a navigation violation below)"]
                        if name == "some" else [])


def test_a_back_off_is_said_with_how_deep_and_how_far(tmp_path):
    """A braking stop at rest inside a keep-out that backed off before Hold: the review says when, how far inside and
    how far back (the speed above V_safe while it flies blind is the daemon's own, and the review's other lines judge
    it as any); a flight without one says nothing of it."""
    for name, back in (("backed", True), ("none", False)):
        log = EventLog(tmp_path / name)
        for i in range(100):
            put(log, i)
        if back:
            log.event(4.2, "back_off", inside_m=0.394, path_m=0.61)
        log.close()
        rep = review(tmp_path / name / "events.jsonl")
        said = [line for line in format_report(rep).splitlines() if "backed off" in line]
        if back:
            assert rep["back_offs"] == [{"t": 4.2, "inside_m": 0.394, "path_m": 0.61}]
            assert len(said) == 1 and "4.20 s" in said[0] and "0.394 m inside" in said[0] and "0.61 m back" in said[0]
        else:
            assert rep["back_offs"] == [] and said == []


def test_gaps_and_lost_records_are_findings():
    recs = [{"kind": "state", "t": t, "seq": s, "boot": "a", "gamma": None if s == 8 else -1.0,
             "ground_speed": 1.0, "v_max": 2.0} for s, t in zip([0, 1, 2, 8, 9, 10], [0.0, 0.1, 0.2, 0.3, 0.4, 3.0])]
    recs.insert(3, {"kind": "event", "t": 0.25, "seq": 3, "boot": "a", "event": "log_recovered",
                    "dropped_records": 4, "since_wall": 0.0, "error": "OSError: [Errno 28] No space left"})
    rep = summarise(recs)
    assert rep["sample_gaps"] == 1 and rep["sampled_s"] == pytest.approx(0.4)
    assert rep["gamma_unknown_s"] == pytest.approx(0.1)
    assert rep["boots"][0]["seq_missing"] == 4  # seq 4…7
    assert any("4 reported dropped" in f for f in rep["findings"])


def test_outputs_plot_csv_json(flight, tmp_path):
    out = tmp_path / "out"
    rep = review([flight], out_dir=out)
    png = (out / "review.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", png[16:24])
    assert w >= 800 and h >= 800
    with open(out / "samples.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 700 and float(rows[100]["gamma"]) == 0.4 and rows[-1]["v_cmd"] == ""
    assert json.loads((out / "review.json").read_text())["gamma_positive_s"] == pytest.approx(2.0)
    assert set(rep["outputs"]) == {"csv", "png", "plan", "json", "html"} and (out / "plan.png").exists()
    assert (out / "review.html").exists()


def one_line_error(fn, *args):
    with pytest.raises(ContractError) as ei:
        fn(*args)
    msg = str(ei.value)
    assert "\n" not in msg and msg
    return msg


def test_bad_input_is_one_contract_error(tmp_path):
    assert "no such file" in one_line_error(review, tmp_path / "missing.jsonl")
    (tmp_path / "empty").mkdir()
    assert "holds no event log" in one_line_error(review, tmp_path / "empty")
    (tmp_path / "f.tlog").write_bytes(b"\x00" * 20)
    assert ".tlog" in one_line_error(review, tmp_path / "f.tlog")
    (tmp_path / "bin.jsonl").write_bytes(bytes(range(256)) * 10)
    assert "not a contract-guard event log" in one_line_error(review, tmp_path / "bin.jsonl")
    (tmp_path / "other.jsonl").write_text('{"a": 1}\n[1, 2]\n"x"\n')
    assert "not a contract-guard event log" in one_line_error(review, tmp_path / "other.jsonl")
    (tmp_path / "zero.jsonl").write_text("")
    assert "not a contract-guard event log" in one_line_error(review, tmp_path / "zero.jsonl")
    (tmp_path / "blocker").write_text("a file where the output directory should go")
    assert "cannot write" in one_line_error(review, _tiny_log(tmp_path), tmp_path / "blocker" / "out")


def _tiny_log(tmp_path):
    d = tmp_path / "tiny"
    with EventLog(d) as log:
        put(log, 0)
    return d


def test_foreign_nan_tokens_and_torn_lines_do_not_break_the_report(tmp_path):
    p = tmp_path / "events.jsonl"
    p.write_text(
        '{"kind":"state","t":0.0,"seq":0,"boot":"b","gamma":NaN,"v_max":Infinity,"ground_speed":1e999}\n'
        '{"kind":"event","t":0.1,"seq":1,"boot":"b","event":"violation_start","subsystem":"navigation",'
        '"guarantee":"g","assumed":NaN,"observed":-Infinity,"action":"hold"}\n'
        '{"kind":"state","t":0.2,"seq":2,"boo'
    )
    rep = review(p)
    json.dumps(rep, allow_nan=False)
    assert rep["violations"][0]["assumed"] is None and rep["ranges"]["gamma"]["missing"] == 1
    assert [b["kind"] for b in rep["bad_lines"]] == ["tail"]
    assert not any("unparsable" in f for f in rep["findings"]), "a torn last line is expected after a crash"


json_scalar = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=5))
json_value = st.recursive(json_scalar, lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=3), c, max_size=3),
                          max_leaves=6)
record = st.fixed_dictionaries(
    {"kind": st.sampled_from(["state", "event", "junk", None])},
    optional={
        "t": json_scalar, "seq": json_scalar, "boot": st.sampled_from(["a", "b", 1, None]), "wall": json_scalar,
        "event": st.sampled_from(["violation_start", "violation_end", "failsafe", "failsafe_clear", "link",
                                  "mode_change", "command", "stop", "startup_check", "log_recovered", "zzz"]),
        "subsystem": json_value, "guarantee": json_value, "status": json_value, "cause": json_value,
        "ok": json_value, "result": json_value, "dropped_records": json_value,
        **{k: json_value for k in ("gamma", "ground_speed", "v_max", "v_cmd", "d_od", "e_tr")},
    },
)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(record, json_value), max_size=25))
def test_summarise_never_raises_on_odd_records(recs):
    rep = summarise(recs)
    assert isinstance(rep["findings"], list)
    format_report(rep)


def test_a_flapping_guarantee_is_counted_in_full_but_listed_in_part():
    recs = []
    for i in range(1200):
        for name, t in (("violation_start", i * 1.0), ("violation_end", i * 1.0 + 0.5)):
            recs.append({"kind": "event", "t": t, "seq": len(recs), "boot": "a", "event": name,
                         "subsystem": "controller", "guarantee": "e_tr ≤ E_tr", "assumed": 0.3, "observed": 0.5})
    rep = summarise(recs)
    assert rep["violation_count"] == 1200 and len(rep["violations"]) == 1000
    assert rep["violations_by_subsystem"]["controller"]["total_s"] == pytest.approx(600.0)
    assert rep["findings"][0].startswith("1200 contract violation(s): controller ×1200 (600.0 s)")


class _Fake(Origin):
    key = "fake"

    def findings(self):
        return ["fake log: no obstacle sensor"]

    def lines(self):
        return ["  converted from a fake raw log"]


def fake_to_event_log(path, log_dir, *, config, vehicle, table):
    """A stand-in raw-log reader (the shape a .ulg or .bin reader takes): writes an event log, names its origin."""
    log = EventLog(log_dir, commit="none")
    for i in range(40):
        put(log, i)
    log.close()
    return _Fake([str(path)], {"source": str(path)})


def test_the_cli_dispatches_raw_logs_to_their_reader_then_reviews_the_event_log(tmp_path, monkeypatch):
    from companion.ground import commands
    from companion.ground.flightlogs import Reader

    monkeypatch.setitem(commands.READERS, ".fake", Reader("fake log", ".fake", read=None, replay=fake_to_event_log))
    (tmp_path / "flight.fake").write_bytes(b"")
    rep, origin = commands.review_log(tmp_path / "flight.fake", tmp_path / "out")
    assert rep["files"] == [str(tmp_path / "flight.fake")] and rep["fake"]["source"] == str(tmp_path / "flight.fake")
    assert rep["findings"] == ["fake log: no obstacle sensor"] and rep["ok"] is False
    assert rep["fake"]["event_log"] == str(tmp_path / "out" / REPLAY_LOG_FILE)
    assert "converted from a fake raw log" in format_report(rep, origin)
    with pytest.raises(ContractError, match="replayed on its own"):
        commands.review_log([tmp_path / "flight.fake", tmp_path])


def test_the_review_knows_nothing_of_raw_logs():
    import subprocess
    import sys

    code = "import sys, companion.ground.review; assert not [m for m in sys.modules if m.startswith('companion.ground.flightlogs.tlog')]"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_the_daemons_own_lateness_is_a_finding_that_says_how_late():
    recs = []
    for i, gap in enumerate((0.035, 0.14, 0.06)):
        for name, t in (("violation_start", i * 5.0), ("violation_end", i * 5.0 + 0.02)):
            recs.append({"kind": "event", "t": t, "seq": len(recs), "boot": "a", "event": name, "subsystem": "guidance",
                         "guarantee": "decides every cycle (20 ms, inside t_react)", "assumed": 0.02, "observed": gap})
    rep = summarise(recs)
    assert rep["violations_by_subsystem"]["guidance"]["worst_observed"] == pytest.approx(0.14)
    assert rep["findings"][0] == ("3 contract violation(s): guidance ×3 (0.1 s; cycles up to 140 ms apart: the "
                                  "companion computer was late)")
