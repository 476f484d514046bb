"""The campaign's strict classifier (companion/ground/campaign.py `strict`): a flight is within the contract only
where every subsystem's guarantee held as stated — in assumption, no violation logged, and ground speed never above
V_safe beyond the review's tolerance (Γ_flown). Both counts in the report, and the bounds labelled as computed."""

import copy

import pytest

from companion.ground import campaign as cg
from companion.ground.campaign_report import clopper_pearson, format_summary, one_sided_upper, summarize
from companion.ground.review import review
from companion.ground.review_checks import SPEED_TOLERANCE_M_S
from companion.onboard.eventlog import EventLog

SPEC_10K = "examples/campaign-evidence-10k.yaml"


def write_event_log(rig, directory) -> None:
    """The rig's records (events and state samples, by time) as the daemon's event log."""
    log = EventLog(directory, commit="none")
    recs = [(e["t"] if e["t"] is not None else -1.0, 0, e) for e in rig.log.events]
    recs += [(s["t"], 1, s) for s in rig.log.states]
    for _, kind, rec in sorted(recs, key=lambda x: (x[0], x[1])):
        rec = dict(rec)
        t = rec.pop("t")
        if kind == 0:
            log.event(t, rec.pop("event"), **rec)
        else:
            log.state(t, **rec)
    log.close()


def test_honest_fog_faster_than_the_vehicle_slows_is_outside_the_contract_and_a_review_finding(tmp_path):
    """Flight 42104 of the 10⁴ campaign (offboard, X500 on ArduPilot): honest fog cuts D_od from 8.5 to 3.2 m at
    6.63 s at 7.8 m/s. The lenient classifier (the sampled conditions) counts it in assumption — the negative
    control; the flight itself shows ground speed above V_safe by up to about 4 m/s for about 1 s."""
    spec = cg.load_spec(SPEC_10K)
    row, rig = cg.fly(spec, 42104, keep_rig=True)
    assert [f["kind"] for f in row["faults"]] == ["fog_honest"]
    assert row["in_assumption"] and cg.classify(row)[0]  # lenient: in
    assert row["gamma_flown_max"] > 3.0 and row["gamma_flown_over_s"] > 0.5
    # (the pass at D_od 3.2 m would leave the field of view: offboard falls back to the stop contract, whose lower
    # limit also makes the brake from 7.8 m/s a controller violation — a consequence of the same speed)
    assert not row["in_contract"] and "ground speed above V_safe" in row["outside_contract"]
    write_event_log(rig, tmp_path / "log")
    found = [f for f in review(tmp_path / "log")["findings"] if f.startswith("flown outside the contract")]
    assert found and f"{row['gamma_flown_max']:.2f} m/s" in found[0]


def _row(i, arm="governor", in_assumption=True, collided=False, violations=(), gamma=None, fog=False):
    r = {"index": i, "arm": arm, "mode": arm, "scenario": i, "in_assumption": in_assumption, "collided": collided,
         "min_clearance_m": 1.0, "mean_speed_m_s": 2.0, "time_to_destination_s": None, "route_completed": False,
         "contact_speed_m_s": None, "faults": [{"kind": "fog_honest"}] if fog else [], "stresses": [],
         "violations": [{"subsystem": s, "t": 1.0} for s in violations], "fault_outcomes": [],
         "vehicle": "x500", "personality": "px4", "gamma_flown_max": gamma}
    return r


def test_the_report_keeps_both_counts_and_says_why_a_flight_is_outside_the_contract():
    rows = [_row(0), _row(1, gamma=SPEED_TOLERANCE_M_S + 0.5, fog=True), _row(2, violations=("controller",)),
            _row(3, gamma=SPEED_TOLERANCE_M_S - 0.05), _row(4, in_assumption=False, collided=True)]
    s = summarize(rows)
    st = s["per_arm"]["governor"]
    assert st["in_assumption"]["flights"] == 4 and st["in_contract"]["flights"] == 2
    ia = st["in_assumption"]
    assert ia["in_assumption_outside_contract"] == 2 and ia["strict_judged_in_full"]
    assert ia["outside_contract_why"] == {"controller violation": 1, "ground speed above V_safe": 1}
    text = format_summary(s)
    assert "in assumption but outside the contract: 2" in text and "one-sided" in text and "two-sided" in text
    # a row flown before Γ_flown was kept: judged by its violations alone, and the report says so
    old = copy.deepcopy(rows)
    for r in old:
        del r["gamma_flown_max"]
    so = summarize(old)["per_arm"]["governor"]["in_assumption"]
    assert so["in_assumption_outside_contract"] == 1 and not so["strict_judged_in_full"]
    assert "judged by their violations only" in format_summary(summarize(old))


def test_the_bounds_on_a_zero_count_are_labelled_as_computed():
    """0 in 10 584: the one-sided 95 % bound 1 − 0.05^(1/n) = 0.0283 %; the two-sided interval's upper end
    1 − 0.025^(1/n) = 0.0348 % (what `--report-only` printed as "95 % CP upper")."""
    n = 10584
    assert one_sided_upper(0, n) == pytest.approx(1 - 0.05 ** (1 / n)) == pytest.approx(2.83e-4, abs=1e-6)
    assert clopper_pearson(0, n)[1] == pytest.approx(3.485e-4, abs=1e-6)
    assert one_sided_upper(5, 10) == pytest.approx(clopper_pearson(5, 10, confidence=0.90)[1])
    st = summarize([_row(i) for i in range(50)])["per_arm"]["governor"]["all"]
    assert st["upper95_one_sided"] < st["cp95_high"]
