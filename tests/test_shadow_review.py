"""Issue 13 items 3 and 4: a shadow flight that breaks the limit and hits a column is reported as such by
`review` (text, JSON and the plot's title): the holds the daemon would have commanded with their causes, the
time the flight was above the safe speed and above the limit it would have commanded; and a governed flight's
tracking overshoot within the supervisor's own rule is not a finding."""

import json

import pytest

from companion.onboard.eventlog import EventLog
from companion.ground.review import format_report, plot_title, review, summarise
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly


@pytest.fixture(scope="module")
def shadow_crash(tmp_path_factory):
    """The Mambo in shadow mode cruising at 8 m/s (the contract allows about 4) into a column."""
    d = tmp_path_factory.mktemp("shadow")
    log = EventLog(d / "log", commit="none")
    rig = Rig(column_scenario(1, x_col=28.0, cruise=8.0), "px4", config={"mode": "shadow"}, log=log)
    fly(rig, 12.0)
    log.close()
    assert rig.truth["collisions"]  # the flight did hit the column (truth from the simulator)
    return d, rig


def test_a_shadow_flight_into_a_column_is_not_reported_clean(shadow_crash):
    d, rig = shadow_crash
    rep = review(d / "log", out_dir=d / "review")
    assert rep["ok"] is False
    oc = rep["outside_contract"]
    assert oc["flown_above_v_safe_s"] > 3.0 and oc["worst_gamma_flown"]["gamma_flown"] > 3.0
    assert oc["flown_above_v_safe"] and oc["above_limit"]
    f = "\n".join(rep["findings"])
    assert "flown outside the contract" in f and "would have commanded" in f and "would have held" in f
    # every would-be hold names its causes; a would_hold record without causes is the end of one, not a hold
    assert rep["would_hold"] and all(w["causes"] for w in rep["would_hold"])
    assert "obstacle inside the stop distance" in rep["would_hold"][0]["causes"]
    text = format_report(rep)
    assert "REVIEW NEEDED" in text and "would have held (shadow mode): " in text and "obstacle inside" in text
    saved = json.loads((d / "review" / "review.json").read_text())
    assert saved["ok"] is False and saved["would_hold"] == rep["would_hold"]
    title = plot_title(rep)
    assert "above V_safe" in title and "would hold" in title and "REVIEW NEEDED" in title


def test_would_hold_without_causes_closes_the_hold():
    recs = [{"kind": "event", "t": 1.0, "boot": "b", "event": "would_hold", "causes": ["no safe speed"]},
            {"kind": "event", "t": 2.5, "boot": "b", "event": "would_hold", "causes": []},
            {"kind": "event", "t": 3.0, "boot": "b", "event": "would_hold", "causes": []}]
    rep = summarise(recs)
    assert rep["would_hold"] == [{"start_t": 1.0, "causes": ["no safe speed"], "end_t": 2.5, "duration_s": 1.5,
                                  "ended_by": "released", "boot": "b"}]


def state(t, gs, v_cmd, v_safe):
    return {"kind": "state", "t": t, "boot": "b", "ground_speed": gs, "v_cmd": v_cmd, "v_max": v_cmd,
            "v_safe": v_safe, "gamma": v_cmd - v_safe, "gamma_flown": gs - v_safe}


def test_a_tracking_overshoot_below_v_safe_is_not_a_finding_but_a_real_excess_is():
    """The demo's 0.24 m/s over a 6.12 m/s offboard limit (V_safe 6.65): inside the supervisor's own
    1.05 × limit rule and below V_safe; 0.6 m/s over is a finding, and so is anything above V_safe."""
    ok = summarise([state(0.1 * i, 6.36 if 10 <= i < 20 else 6.0, 6.12, 6.65) for i in range(40)])
    assert ok["ok"], ok["findings"]
    bad = summarise([state(0.1 * i, 6.72 if 10 <= i < 20 else 6.0, 6.12, 7.5) for i in range(40)])
    assert not bad["ok"] and any("above the limit" in f for f in bad["findings"])
    unsafe = summarise([state(0.1 * i, 6.36 if 10 <= i < 20 else 6.0, 6.12, 6.13) for i in range(40)])
    assert any("flown outside the contract" in f for f in unsafe["findings"])


def test_the_demo_has_one_verdict(tmp_path):
    """`demo`'s verdict is the flight's truth and its review together; the exit status follows it (cli)."""
    from companion.ground.demo import format_summary, summarise_flight
    from sitl_harness.scenario import load_scenario

    sc = load_scenario("fig17")
    recs = [{"kind": "state", "t": 1.0, "x": 0.0, "y": 0.0, "mode": "offboard", "ground_speed": 1.0}]
    kept = summarise_flight(sc, recs, {"collisions": 0}, {"ok": True, "findings": [], "outputs": {}}, tmp_path)
    assert kept["verdict"] == "SAFE" and format_summary(kept).endswith("SAFE")
    flagged = summarise_flight(sc, recs, {"collisions": 0}, {"ok": False, "findings": ["autopilot link down for 1.0 s"],
                                                            "outputs": {}}, tmp_path)
    text = format_summary(flagged)
    assert flagged["verdict"] == "REVIEW NEEDED" and "autopilot link down" in text and "SAFE\n" not in text + "\n"
    hit = summarise_flight(sc, recs, {"collisions": 1}, {"ok": True, "findings": [], "outputs": {}}, tmp_path)
    assert hit["verdict"] == "NOT SAFE"
