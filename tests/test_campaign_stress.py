"""The stress comparison's sampler dimensions (companion/ground/campaign.py, examples/campaign-stress.yaml): drawn
autopilot braking reaches the SITL, the daemon's vehicle and the PX4 law; columns revealed during the speed-up;
the wind's direction; named stresses — and an existing spec's scenarios stay as they were."""

import math

import pytest

from companion.ground import campaign as cg
from companion.ground.campaign_report import stress_markdown, summarize

BASE = {"name": "t", "seed": 5, "scenarios": 4, "vehicles": ["mambo"], "personalities": ["px4"],
        "arms": ["px4_cp", "governor"], "duration_s": 20,
        "scenario": {"sensor_range_m": 6.0, "r_obst_true_m": 0.5, "lateral_offset_m": 0.0, "x_obst_m": 25.0,
                     "wind_factor": 0.3, "gust_factor": 0.3}}


def _with(**dims):
    return cg.spec_from_dict({**BASE, "scenario": {**BASE["scenario"], **dims}})


def test_the_new_dimensions_leave_the_other_draws_as_they_were():
    plain = cg.spec_from_dict(BASE)
    drawn = _with(accel_hor_m_s2=[1, 5], jerk_auto_m_s3=[1, 8], wind_from_deg=270)
    named = cg.spec_from_dict({**BASE, "stresses": [{"name": "a"}, {"name": "b"}]})
    for k in range(4):
        a, b, c = cg.sample_scenario(plain, k), cg.sample_scenario(drawn, k), cg.sample_scenario(named, k)
        assert "braking" not in a and "stress" not in a
        assert 1 <= b["braking"]["accel_max_m_s2"] <= 5 and 1 <= b["braking"]["jerk_max_m_s3"] <= 8
        assert b["wind_from_deg"] == 270.0
        assert {x: v for x, v in b.items() if x not in ("braking", "wind_from_deg")} == \
            {x: v for x, v in a.items() if x != "wind_from_deg"}
        assert c.pop("stress") == "ab"[k % 2] and c == a


def test_a_column_revealed_during_the_speed_up_is_first_seen_there():
    spec = _with(accel_hor_m_s2=2.0, jerk_auto_m_s3=1.0, reveal_in_speedup=0.5)
    s = cg.sample_scenario(spec, 0)
    d_up = 0.5 * 8.0 * (8.0 / 2.0 + 2.0 / 1.0)  # from rest to 8 m/s at 2 m/s², 1 m/s³: mean speed 4 m/s for 6 s
    assert cg.speedup_distance(8.0, 2.0, 1.0) == pytest.approx(d_up)
    assert s["x_obst_m"] == pytest.approx(6.0 + 0.5 + 0.5 * d_up) and s["columns"][0][0] == s["x_obst_m"]


def test_a_stress_is_checked_like_the_spec():
    with pytest.raises(cg.CampaignError, match="stresses.0.scenario: x_obst_m"):
        cg.spec_from_dict({**BASE, "stresses": [{"name": "x", "scenario": {"x_obst_m": [30, 20]}}]})


def test_drawn_braking_is_what_the_sitl_brakes_with_and_the_px4_law_and_the_daemon_use():
    spec = _with(accel_hor_m_s2=[1, 5], jerk_auto_m_s3=[1, 8])
    s = cg.sample_scenario(spec, 0)
    a, j = s["braking"]["accel_max_m_s2"], s["braking"]["jerk_max_m_s3"]
    ap = cg.scenario_dict({**s, "personality": "ardupilot"}, "governor")["params"]
    assert ap == {"WPNAV_ACCEL": 100.0 * a, "WPNAV_JERK": j}
    row, rig = cg.fly(spec, 0, keep_rig=True)  # scenario 0 flown by px4_cp
    assert row["arm"] == "px4_cp" and row["braking"] == s["braking"]
    assert (rig.sim.autopilot.traj.acc_hor, rig.sim.autopilot.traj.jerk) == (pytest.approx(a, rel=1e-6),
                                                                            pytest.approx(j, rel=1e-6))
    law = rig.daemon.cycle.sup.policy
    # the drawn MPC_ACC_HOR as reported; the firmware's jerk MPC_JERK_MAX (its default 8), not the mission's
    assert (law.acc_hor, law.jerk) == (pytest.approx(a, rel=1e-6), 8.0) and j < 8.0
    auto = cg._policy("px4_cp_auto_jerk", s, spec)(rig.daemon.cfg)  # the separate arm: the mission's jerk
    assert (auto.jerk, auto.jerk_param, auto.name) == (pytest.approx(j, rel=1e-6), "MPC_JERK_AUTO", "px4_cp_auto_jerk")
    assert rig.daemon.table.vehicle.braking.jerk_max_m_s3 == j  # the vehicle file the daemon checks and flies
    assert [e["ok"] for e in rig.log.events if e["event"] == "startup_check"][-1]
    assert row["sim_time_s"] > 5 and math.isfinite(row["mean_speed_m_s"])


def test_the_report_has_a_row_per_stress_and_arm():
    rows = [{"index": i, "arm": arm, "scenario": i // 2, "stress": st, "collided": c, "min_clearance_m": 1.0,
             "mean_speed_m_s": 2.0, "time_to_destination_s": None, "route_completed": False, "in_assumption": True,
             "faults": [], "stresses": [], "fault_outcomes": [], "contact_speed_m_s": None, "vehicle": "mambo",
             "personality": "px4"}
            for i, (arm, st, c) in enumerate([("governor", "fog", False), ("px4_cp", "fog", True)])]
    md = stress_markdown(summarize(rows))
    assert "| fog | px4_cp | 1 | 1 | 1 | 1.00 | 2.00 | – | 0/1 |" in md and "| fog | governor | 1 | 1 | 0 | 0.97 |" in md


def test_the_governor_brake_arm_flies_the_governor_with_its_recovery_brake_armed():
    spec = cg.spec_from_dict({**BASE, "arms": ["governor", "governor_brake"]})
    s = cg.sample_scenario(spec, 0)
    assert cg.daemon_config(s, "governor_brake")["governor"] == {"recovery_brake": True}
    assert "governor" not in cg.daemon_config(s, "governor")
    # its start-up check needs PX4's offboard-loss action to be Hold (a companion-only aircraft)
    assert cg.scenario_dict(s, "governor_brake")["params"]["COM_OBL_RC_ACT"] == 5
    assert "COM_OBL_RC_ACT" not in cg.scenario_dict(s, "governor").get("params", {})
    row, rig = cg.fly(spec, 1, keep_rig=True)  # scenario 0 flown by governor_brake
    assert row["arm"] == "governor_brake" and rig.daemon.cycle.brake is not None
    said = rig.log.named("recovery_brake")
    assert said and said[-1]["available"], said
    with pytest.raises(cg.CampaignError, match="unknown arm 'offboard_brake'"):
        cg.spec_from_dict({**BASE, "arms": ["offboard_brake"]})


def test_every_shipped_campaign_spec_loads():
    from pathlib import Path

    specs = sorted((Path(__file__).resolve().parents[1] / "examples").glob("campaign-*.yaml"))
    assert len(specs) >= 6
    loaded = {p.name: cg.load_spec(p) for p in specs}  # a bad one raises CampaignError with its one line
    big = loaded["campaign-evidence-10k.yaml"]
    assert big.arms == ["governor", "governor_brake", "offboard"] and big.flights == 43500


RESUME = {**BASE, "scenarios": 1, "arms": ["px4_cp"], "duration_s": 30,
          "scenario": {**BASE["scenario"], "x_obst_m": 200.0, "wind_factor": 0.0, "gust_factor": 0.0, "cruise_m_s": 4},
          "faults": [{"kind": "sensor_dropout", "p": 1, "at_s": 8, "duration_s": 0.8}]}


class _Latched(cg.FirmwareResume):
    """The negative control: the law's Hold kept to the end of the flight (no resume)."""

    def __call__(self, rig) -> bool:
        return self.trace(rig)


@pytest.mark.parametrize("resumes", [True, False])
def test_the_px4_law_resumes_after_a_momentary_limit_below_what_a_governor_can_command(resumes, monkeypatch):
    """A 0.8 s sensor drop-out at 8 s: the law's map goes stale (no obstacle data: "not moving", limit 0), the
    daemon holds; the data back, the firmware would go on. Resumed (the mission mode again, from its current item),
    the flight goes on along its route; latched (the old baseline), it stands where it stopped."""
    if not resumes:
        monkeypatch.setattr(cg, "FirmwareResume", _Latched)
    row, rig = cg.fly(cg.spec_from_dict(RESUME), 0, keep_rig=True)
    assert "no safe speed" in row["failsafes"]
    t_hold = rig.log.named("failsafe")[0]["t"]
    x_hold = next(s["x"] for s in rig.log.states if s["t"] >= t_hold)
    x_end = rig.log.states[-1]["x"]
    if resumes:
        assert len(row["resumed_s"]) == 1 and t_hold < row["resumed_s"][0] < t_hold + 2.0
        assert x_end > x_hold + 30.0 and rig.log.states[-1]["state"] == "active"
    else:
        assert row["resumed_s"] == [] and x_end < x_hold + 3.0
