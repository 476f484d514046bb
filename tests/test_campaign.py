"""Campaigns (`companion/ground/campaign.py`): the spec, deterministic sampling, the baselines' laws against their
sources' algebra, re-flying one flight, resuming, the report — and a small campaign of lock-step flights
(0 collisions in assumption; the ×1.3 control and no guard collide in a stated share)."""

import json
import math

import pytest

from companion.ground import campaign as cg
from companion.ground.campaign_report import clopper_pearson, summarize, write_report
from companion.cli import main

SMALL = {"name": "t", "seed": 3, "scenarios": 1, "vehicles": ["mambo"], "personalities": ["px4"],
         "arms": ["governor", "no_guard", "px4_cp"], "duration_s": 25,
         "scenario": {"sensor_range_m": 6.0, "r_obst_true_m": 0.5, "lateral_offset_m": 0.0, "x_obst_m": 25.0,
                      "wind_factor": 0.5, "gust_factor": 0.5}}


# ----------------------------------------------------------------------------- spec and sampling

@pytest.mark.parametrize("bad, says", [
    ({"arms": ["governor", "warp"]}, "arms: unknown arm 'warp'"),
    ({"scenario": {"x_obst_m": [30, 20]}}, "scenario.x_obst_m: range low 30.0 above high 20.0"),
    ({"colour": 1}, "colour: unknown key"),
    ({"faults": [{"kind": "meteor", "p": 0.1}]}, "faults.0.kind"),
    ({"scenarios": 0}, "scenarios"),
])
def test_a_bad_spec_is_one_line_naming_the_field(bad, says):
    with pytest.raises(cg.CampaignError) as e:
        cg.spec_from_dict({**SMALL, **bad})
    assert says in str(e.value) and "\n" not in str(e.value)


def test_the_cli_refuses_a_bad_spec_in_one_line(tmp_path, capsys):
    p = tmp_path / "spec.yaml"
    p.write_text("scenarios: 2\narms: [nope]\n")
    assert main(["campaign", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown arm 'nope'" in err


def test_sampling_is_a_function_of_seed_and_index():
    spec = cg.load_spec("examples/campaign-compare.yaml")
    a, b = cg.sample_scenario(spec, 7), cg.sample_scenario(spec, 7)
    assert a == b and a != cg.sample_scenario(spec, 8)
    other = cg.spec_from_dict({**spec.model_dump(mode="json"), "seed": spec.seed + 1})
    assert cg.sample_scenario(other, 7) != a
    # every arm flies the same scenario
    arms = len(spec.arms)
    assert all(cg.flight_of(spec, 7 * arms + j)[0] == a for j in range(arms))
    assert [cg.flight_of(spec, 7 * arms + j)[1] for j in range(arms)] == spec.arms
    # the stated envelope is respected, and in-assumption means what it says
    ss = [cg.sample_scenario(spec, k) for k in range(200)]
    assert all(0.3 <= s["r_obst_true_m"] <= 1.3 and 20 <= s["x_obst_m"] <= 35 for s in ss)
    assert all(not s["in_assumption"] for s in ss if s["r_obst_true_m"] > s["r_obst_m"] or s["wind_factor"] > 1
               or any(f["kind"] == "fog_hidden" for f in s["faults"]))
    assert 0 < sum(s["in_assumption"] for s in ss) < 200
    with pytest.raises(cg.CampaignError):
        cg.flight_of(spec, spec.flights)


# ----------------------------------------------------------------------------- the laws, against their sources

# (the laws' algebra and maps against their sources: tests/test_baselines.py)


def test_the_px4_law_governs_a_real_flight_and_stops_short():
    """Flown as a governor through the daemon: it slows as the column nears, holds, and does not touch it."""
    spec = cg.spec_from_dict(SMALL)
    row, rig = cg.fly(spec, 2, keep_rig=True)
    assert row["arm"] == "px4_cp" and not row["collided"]
    assert rig.log.named("failsafe") + rig.log.named("hold_trigger")  # and ends held short of it
    sent = [e["v_max"] for e in rig.log.named("limit_change")]
    assert len(sent) > 3 and min(sent) < 0.5 * max(sent)  # the limit fell with the distance
    assert rig.daemon.cycle.sup.policy.name == "px4_cp"
    row, rig = cg.fly(spec, 0, keep_rig=True)  # the governor itself: no law (the on-board default)
    assert row["arm"] == "governor" and rig.daemon.cycle.sup.policy.name == "contract"


# ----------------------------------------------------------------------------- rows, re-flying, resuming

def test_a_campaign_resumes_and_a_flight_refies_to_its_row(tmp_path, capsys):
    spec = cg.spec_from_dict(SMALL)
    out = tmp_path / "c"
    cg.run(spec, out, progress=False, limit=2)
    assert [r["index"] for r in cg.read_rows(out)] == [0, 1]
    with open(out / "results.jsonl", "a") as f:
        f.write('{"index": 2, "arm": "px4')  # torn by an interruption
    rows = cg.run(spec, out, progress=False)
    assert [r["index"] for r in rows] == [0, 1, 2]
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines() if x.endswith("}")]
    assert sorted(r["index"] for r in lines if "collided" in r) == [0, 1, 2]
    r0 = rows[0]
    for key in ("collided", "contact_speed_m_s", "min_clearance_m", "mean_speed_m_s", "max_speed_m_s",
                "route_completed", "time_to_destination_s", "violations", "fault_outcomes", "failsafes", "holds",
                "sensor_range_m", "r_obst_true_m", "lateral_offset_m", "wind_factor", "faults", "in_assumption"):
        assert key in r0
    assert rows[1]["arm"] == "no_guard" and rows[1]["collided"]  # head-on at cruise speed
    # one command re-flies one flight, to the same row
    spec_file = tmp_path / "spec.yaml"
    spec_file.write_text(json.dumps(SMALL))
    assert main(["campaign", str(spec_file), "--fly", "0", "--json", "--out", str(tmp_path / "one")]) == 0
    again = json.loads(capsys.readouterr().out)
    assert cg.row_json({k: v for k, v in again.items() if k != "log"}) == cg.row_json(r0)
    assert (tmp_path / "one" / "flight-0.jsonl").exists()
    # another spec in the same directory is refused; the same with more scenarios extends it
    with pytest.raises(cg.CampaignError, match="another campaign"):
        cg.run(cg.spec_from_dict({**SMALL, "seed": 4}), out, progress=False)
    more = cg.run(cg.spec_from_dict({**SMALL, "scenarios": 2}), out, progress=False, limit=1)
    assert [r["index"] for r in more] == [0, 1, 2, 3] and more[:3] == rows


@pytest.mark.parametrize("flags", [["--no-progress"], []])
def test_an_interrupted_campaign_says_what_it_kept_in_one_line(tmp_path, capsys, monkeypatch, flags):
    """Ctrl-C (or SIGTERM, which the CLI turns into it) during a flight: exit 130, one line naming the flights
    kept and how to continue; every row written before it stays (the next run resumes from them). Off a terminal
    (a log file, a pipe) there is no progress bar either way: that one line is all of stderr."""
    def ninth_interrupted(args):
        if args[1] == 8:
            raise KeyboardInterrupt
        return [json.dumps({"index": args[1], "arm": "stub"})]  # no flight

    monkeypatch.setattr(cg, "_task", ninth_interrupted)
    spec_file = tmp_path / "spec.yaml"
    spec_file.write_text(json.dumps({**SMALL, "scenarios": 6}))  # 18 flights
    out = tmp_path / "c"
    assert main(["campaign", str(spec_file), "--out", str(out), *flags]) == 130
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert [r["index"] for r in cg.read_rows(out)] == list(range(8)) and len(err) == 1, err
    assert err[0] == (f"contract-guard: interrupted after 8 of 18 flights, kept in {out / 'results.jsonl'}: run the "
                      "same command to continue")


def test_clopper_pearson_exact():
    assert clopper_pearson(0, 1000)[1] == pytest.approx(1 - 0.025 ** (1 / 1000))
    lo, hi = clopper_pearson(5, 10)
    assert lo == pytest.approx(0.187086, abs=1e-6) and hi == pytest.approx(0.812914, abs=1e-6)
    assert clopper_pearson(10, 10) == (pytest.approx(0.025 ** (1 / 10)), 1.0)


# ----------------------------------------------------------------------------- a small campaign in the default suite

SMALL_CAMPAIGN = {
    "name": "suite", "seed": 5, "scenarios": 6, "vehicles": ["mambo", "x500"], "personalities": ["px4", "ardupilot"],
    "arms": ["governor", "offboard", "no_guard", "governor_x1.7", "offboard_x1.3"], "duration_s": 30,
    "scenario": {"sensor_range_m": [5, 8], "r_obst_true_m": [0.5, 1.0], "lateral_offset_m": [-0.5, 0.5],
                 "x_obst_m": [25, 32], "wind_factor": [0, 1], "gust_factor": [0, 1]},
    "faults": [{"kind": "fog_honest", "p": 0.3, "at_s": [4, 10], "visibility_m": [3, 5]},
               {"kind": "thrust_loss", "p": 0.3, "at_s": [4, 10], "thrust_ratio": [0.75, 0.95]}]}


@pytest.mark.slow  # campaign-grade (30 flights): make test-all
def test_a_small_campaign_is_safe_in_assumption_and_its_controls_collide(tmp_path):
    """30 lock-step flights: head-on columns (offset ≤ 0.5 m), design wind, honest fog and thrust losses.
    Stated shares (measured at this commit): no guard collides in 6/6, the governor at 1.7 × the contract's
    speed in 6/6 (the stop contract holds from the approach to its limit since issue 19 item 1, so from these
    steady-cruise detections it has slack: 1.3 × collides in 0/6, 1.5 × in 3/6), offboard at 1.3 × comes closer in
    every flight (it no longer collides: see below); ours in 0 (their 95 % Clopper–Pearson upper bound at
    6 flights is 0.46: this test shows the controls can fail, the large campaign gives the rate)."""
    spec = cg.spec_from_dict(SMALL_CAMPAIGN)
    rows = cg.run(spec, tmp_path, progress=False)
    assert len(rows) == 30 and all(r["in_assumption"] for r in rows)
    s = write_report(rows, tmp_path)
    per = s["per_arm"]
    assert per["governor"]["all"]["collisions"] == 0 and per["offboard"]["all"]["collisions"] == 0
    # 5/6 complete the route; flight 11 (mambo, PX4, no fault) measures a contour error above E_tr_pred during
    # its pass (a controller violation), raises E_tr to it, finds no safe speed and holds, safely
    assert per["offboard"]["all"]["route_completion"] >= 5 / 6
    assert per["no_guard"]["all"]["collisions"] == 6
    assert per["governor_x1.7"]["all"]["collisions"] == 6
    # offboard × 1.3 is held at the controller contract's grid top (8 m/s, issue 19 item 6; × 1.5 and × 1.7 fly the
    # same) and, since E_tr_pred covers the fail-safe stop mid-swerve (issue 19 item 9), its online plans still clear
    # these head-on columns (0/6 at this commit; at least 3/6 before): it must come closer in every flight (0.19-0.95 m against
    # 1.05-1.68 m). The offboard control that must touch is test_offboard_lockstep's
    # test_negative_control_well_above_the_contract_touches.
    by = {(r["scenario"], r["arm"]): r for r in rows}
    for k in {r["scenario"] for r in rows}:
        assert by[(k, "offboard_x1.3")]["min_clearance_m"] < by[(k, "offboard")]["min_clearance_m"] - 0.2, k
    assert per["offboard"]["all"]["cp95_high"] == pytest.approx(1 - 0.025 ** (1 / 6))
    for f in ("report.html", "report.json", "clearance.png", "speed.png"):
        assert (tmp_path / f).stat().st_size > 0
    faults = [c for c in s["fault_matrix"] if c["mode"] in ("governor", "offboard")]
    assert faults and all(c["subsystem"] != "not detected" for c in faults)  # every fault detected, attributed
    assert s["worst"][0]["refly"].startswith("contract-guard campaign ")
    assert summarize(rows) == summarize(list(reversed(rows)))  # order-free


# ----------------------------------------------------------------------------- a pool and a Dask cluster agree

def _lines(out):
    return sorted((out / "results.jsonl").read_text().splitlines(), key=lambda x: json.loads(x)["index"])


@pytest.mark.slow  # campaign-grade: make test-all
def test_a_process_pool_and_a_dask_cluster_give_the_same_rows_bit_for_bit(tmp_path):
    from distributed import LocalCluster

    spec = cg.spec_from_dict({**SMALL, "scenarios": 2, "arms": ["governor", "px4_cp"],
                              "vehicles": ["mambo", "x500"], "personalities": ["px4", "ardupilot"]})
    cg.run(spec, tmp_path / "pool", workers=2, progress=False)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        cg.run(spec, tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False)
    pool, dask = _lines(tmp_path / "pool"), _lines(tmp_path / "dask")
    assert len(pool) == 4 and pool == dask
    assert pool[0] == cg.row_json(cg.fly(spec, 0))  # and the same as flying it here


def test_an_arrived_flight_flies_on_for_its_faults_detection_window():
    """Issue 16's fault matrix: flights ended at the arrival counted faults 0.1–2 s old as missed (a thrust
    estimate needs ≈ 2.5 s). An arrived flight now ends no earlier than FAULT_WINDOW_S after its last fault."""
    class _M:
        pos, vel = [40.0, 0.0, -2.0], [0.0, 0.0, 0.0]

    class _S:
        model, time_s = _M(), 0.0

    class _R:
        sim = _S()

    rig = _R()
    trace = cg._Trace((40.0, 0.0), 10.0 + cg.FAULT_WINDOW_S)
    trace.t0 = 0.0
    ends = []
    for k in range(1, 1000):
        rig.sim.time_s = k * 0.02
        if trace(rig):
            ends.append(rig.sim.time_s)
            break
    assert trace.t_arrive is not None and trace.t_arrive < 1.0
    assert ends and ends[0] >= 10.0 + cg.FAULT_WINDOW_S - 1e-9
    assert cg._Trace((40.0, 0.0))(rig)  # without a fault it ends at the arrival, as before


def test_a_fault_inside_a_link_loss_is_not_counted_as_missed():
    from companion.ground.campaign import masked_by_link_loss

    loss = {"kind": "link_loss", "at_s": 6.4, "duration_s": 3.1}
    inside = {"kind": "bad_nav", "at_s": 8.0, "duration_s": 1.1}  # evidence flight 941
    after = {"kind": "bad_nav", "at_s": 9.0, "duration_s": 1.1}  # outlasts the loss by 0.6 s: observable after it
    barely = {"kind": "bad_nav", "at_s": 9.36, "duration_s": 0.3}  # 0.12 s after the loss (flight 2440's)
    assert masked_by_link_loss(barely, [loss, barely])
    fog = {"kind": "fog_honest", "at_s": 7.0}  # lasts: observable once the link is back
    assert masked_by_link_loss(inside, [loss, inside])
    assert not masked_by_link_loss(after, [loss, after]) and not masked_by_link_loss(fog, [loss, fog])
    assert not masked_by_link_loss(loss, [loss]) and not masked_by_link_loss(inside, [inside])


# ----------------------------------------------------------------------------- narrow beams

NARROW = {"name": "narrow", "seed": 5, "scenarios": 2, "vehicles": ["mambo"], "personalities": ["px4"],
          "arms": ["governor", "offboard"], "duration_s": 25,
          "stresses": [{"name": "beam_3deg", "scenario": {"sensor_fov_deg": 3.0}},
                       {"name": "beam_60deg", "scenario": {"sensor_fov_deg": 60.0}}],
          "scenario": {"sensor_range_m": 12.0, "r_obst_true_m": 0.5, "lateral_offset_m": 0.3, "x_obst_m": 30.0,
                       "wind_factor": 0.5, "gust_factor": 0.5, "cruise_m_s": 4.0}}


@pytest.mark.parametrize("arm", ["governor", "offboard"])
def test_a_beam_too_narrow_for_the_corridor_is_refused_and_a_wide_one_flies_clear(arm):
    """A 3° beam rated 12 m covers ±0.31 m at its range, less than the Mambo's r_body + E_tr: the start-up checks
    refuse it (said, and the row is outside the contract); the same column 0.3 m off the track with a 60° sensor is
    flown by without touching it. The field of view reaches the SITL's sensor and the daemon's config alike."""
    spec = cg.spec_from_dict(NARROW)
    i = spec.arms.index(arm)
    narrow, wide = cg.fly(spec, i), cg.fly(spec, len(spec.arms) + i)
    assert (narrow["stress"], wide["stress"]) == ("beam_3deg", "beam_60deg")
    assert narrow["sensor_fov_deg"] == 3.0 and cg.daemon_config(narrow, arm)["sensors"][0]["h_fov_deg"] == 3.0
    assert cg.scenario_dict(narrow, arm)["sensor"]["fov_deg"] == 3.0
    assert narrow["refused"] and "covers" in narrow["refused"] and not narrow["in_contract"]
    assert "refused at start-up" in narrow["outside_contract"]
    assert wide["refused"] is None and not wide["collided"] and wide["in_contract"], wide["outside_contract"]


def test_a_spec_without_the_field_of_view_samples_as_before():
    """The field of view is the fifth draw of the optional stream: the first four keep their values."""
    base = {**SMALL, "scenario": {**SMALL["scenario"], "wind_from_deg": [0, 360]}}
    a = cg.sample_scenario(cg.spec_from_dict(base), 0)
    b = cg.sample_scenario(cg.spec_from_dict({**base, "scenario": {**base["scenario"], "sensor_fov_deg": [3, 60]}}), 0)
    assert "sensor_fov_deg" not in a and 3 <= b.pop("sensor_fov_deg") <= 60 and a == b
