"""The clutter campaign (`scenario.world_families`): old specs sample as before, the cluttered world families put
something on the route (the clear-air ones do not), a cluttered world reaches the SITL and the daemon in every arm
(real lock-step flights), a wall touched is counted against every shape, and the report's per-family table."""

import hashlib
import math
from itertools import pairwise

import numpy as np
import pytest

from companion.ground import campaign as cg
from companion.ground.campaign_report import format_summary, summarize, world_family_markdown, write_report
from companion.ground.worlds import CLEAR, CLUTTERED, clear_world, cluttered_world
from sitl_harness.scenario import scenario_from_dict
from sitl_harness.sim import Sim

# sha256 of the first 40 scenarios' JSON of shipped specs, as sampled before cluttered worlds existed
SAMPLED = {"examples/campaign-evidence.yaml": "247c0b30f0e77d85", "examples/campaign-compare.yaml": "ef1626bda13568bb",
           "examples/campaign-narrow-beams.yaml": "87c5d943721e88a3", "examples/campaign-brake.yaml": "f2d536d4915ef3eb"}

BASE = {"name": "clutter-t", "seed": 4, "scenarios": 1, "vehicles": ["mambo"], "personalities": ["px4"],
        "arms": ["governor", "offboard", "px4_cp", "ac_avoid", "no_guard"], "duration_s": 8,
        "scenario": {"sensor_range_m": 9.0, "wind_factor": 0.0, "gust_factor": 0.0, "cruise_m_s": 3.0,
                     "world_families": ["corridor"]}}


@pytest.mark.parametrize("path", sorted(SAMPLED))
def test_a_shipped_spec_samples_as_before(path):
    spec = cg.load_spec(path)
    h = hashlib.sha256()
    for k in range(40):
        h.update(cg.row_json(cg.sample_scenario(spec, k)).encode())
    assert h.hexdigest()[:16] == SAMPLED[path]


def test_world_families_draw_after_the_optional_dimensions_and_leave_the_rest_as_drawn():
    """The family, the world's seed and the sensor model are the sixth to eighth draws of the optional stream: the
    braking and the wind's direction drawn before them, and everything of the main stream, keep their values."""
    dims = {"sensor_range_m": 9.0, "accel_hor_m_s2": [1, 5], "wind_from_deg": [0, 360]}
    plain = cg.sample_scenario(cg.spec_from_dict({**BASE, "scenario": dims}), 3)
    spec = cg.spec_from_dict({**BASE, "scenario": {**dims, "world_families": list(CLUTTERED),
                                                   "sensor_models": ["sector", "depth_camera"]}})
    clut = cg.sample_scenario(spec, 3)
    assert "world_family" not in plain and "sensor_model" not in plain
    assert clut["world_family"] in CLUTTERED and clut["sensor_model"] in ("sector", "depth_camera")
    assert clut["route"] == cluttered_world(clut["world_family"], clut["world_seed"]).route
    for k in cg.COLUMN_KEYS:
        assert k in plain and k not in clut
    for k, v in plain.items():
        if k not in (*cg.COLUMN_KEYS, "route_end_m", "in_assumption", "stresses"):
            assert clut[k] == v, k
    families = {cg.sample_scenario(spec, k)["world_family"] for k in range(40)}
    assert families == set(CLUTTERED)
    with pytest.raises(cg.CampaignError, match="not with world_families"):
        cg.spec_from_dict({**BASE, "scenario": {**BASE["scenario"], "reveal_in_speedup": 0.5}})


def _hits_on_route(world: dict, route, offsets=(0.0,), alt: float = 2.0) -> float:
    """The nearest true surface along the route's legs, each leg moved by each of `offsets` across itself, as the
    SITL builds the world (inf: none)."""
    w = Sim(scenario_from_dict({"world": world}), "px4").world
    best = math.inf
    for (x0, y0), (x1, y1) in pairwise(route):
        leg, a = math.hypot(x1 - x0, y1 - y0), math.atan2(y1 - y0, x1 - x0)
        for off in offsets:
            px, py = x0 - off * math.sin(a), y0 + off * math.cos(a)
            best = min(best, float(w.ray_cast(px, py, alt, np.array([a]), leg)[0]))
    return best


def test_the_cluttered_families_stand_on_the_route_and_the_clear_ones_beside_it():
    for seed in range(8):
        for fam in CLEAR:
            world, route = clear_world(fam, seed)
            assert math.isinf(_hits_on_route(world, route)), (fam, seed)
        for fam in CLUTTERED:
            d = cluttered_world(fam, seed)
            assert d.route_exists == (fam != "dead_end")
            if fam == "columns":  # within ±1 m of the route: on it for the sensor, maybe not on its centre line
                ys = [c["y_m"] for c in d.world["columns"]]
                assert abs(ys[0]) <= 1.0 and len(ys) >= 2
                xs = [c["x_m"] for c in d.world["columns"]]
                assert min(np.diff(xs)) >= 11.0  # one at a time
            elif fam == "doorway":
                gap = d.world["walls"][0]["gaps"][0]
                assert 3.0 <= gap["width_m"] <= 6.0 and abs(gap["at_m"] - 20.0) <= 0.5
            else:  # a pole, a column or an end wall within 1 m of the route: inside the swept corridor (R_obst 1 m)
                assert _hits_on_route(d.world, d.route, np.linspace(-1, 1, 9)) < math.inf, (fam, seed)


def test_a_cluttered_world_reaches_the_sitl_and_the_daemon_in_every_arm():
    """One corridor with a turn and a column, flown 8 s by each arm on the real rig: the SITL holds the corridor's
    walls and the column, the governor arms' mission and offboard's route are the world's route (with its turn), the
    sector sensor is read as its bins, and the row says the world and what the observer judged."""
    spec = cg.spec_from_dict(BASE)
    s, _ = cg.flight_of(spec, 0)
    assert s["world_family"] == "corridor" and len(s["route"]) == 3 and s["in_assumption"]
    for i, arm in enumerate(spec.arms):
        row, rig = cg.fly(spec, i, keep_rig=True)
        names = {o.name for o in rig.sim.world.obstacles}
        assert {"corridor.left", "corridor.right", "column"} <= names, names
        assert rig.cfg.sensors[0].kind == "obstacle_distance"
        if arm == "offboard":
            assert [list(p) for p in rig.cfg.route.waypoints] == s["route"]
        else:
            assert [list(p) for p in rig.sim.scenario.route.waypoints] == s["route"]
        assert row["world_family"] == "corridor" and row["route_exists"] and row["airborne_s"] > 2.0, arm
        assert isinstance(row["unfounded_alarms"], list) and row["judged_alarms"] >= 0
        assert not row["collided"] and row["min_clearance_m"] > 0.5, arm  # 8 s: not yet at the column


DEAD_END = {**BASE, "arms": ["governor", "no_guard"], "duration_s": 60,
            "scenario": {**BASE["scenario"], "cruise_m_s": 4.0, "world_families": ["dead_end"]}}


def test_a_dead_end_is_stopped_short_and_a_wall_touched_is_counted():
    """In a closed corridor the governor stops short without contact and says so (its success where no route
    exists); the negative control, no guard, flies into the end wall: the row says it touched the wall (the SITL's
    collision truth against every shape, not the column formula) and the family's table counts it."""
    spec = cg.spec_from_dict(DEAD_END)
    gov, none = cg.fly(spec, 0), cg.fly(spec, 1)
    assert gov["world_family"] == none["world_family"] == "dead_end" and not gov["route_exists"]
    assert not gov["collided"] and gov["stopped_short"] and not gov["route_completed"], gov["failsafes"]
    assert none["collided"] and any(n.startswith("dead end") for n in none["collided_with"])
    assert none["min_clearance_m"] < 0.0 and not none["stopped_short"]
    table = summarize([gov, none])["per_world_family"]["dead_end"]
    assert table["no_guard"]["collisions_in_assumption"] == 1 and table["governor"]["collisions"] == 0
    assert (table["governor"]["stopped_short"], table["governor"]["dead_ends"]) == (1, 1)
    assert table["governor"]["with_route"] == 0 and table["governor"]["hours"] > 0


def _row(scenario, arm, fam, v, collided=False, done=True, alarms=0, air=3600.0, exists=True):
    return {"index": 2 * scenario + (arm != "px4_cp"), "scenario": scenario, "arm": arm, "mode": "governor",
            "world_family": fam, "route_exists": exists, "in_assumption": True, "collided": collided,
            "route_completed": done, "stopped_short": not done and not collided, "mean_speed_m_s": v,
            "airborne_s": air, "unfounded_alarms": [{"t": 1.0, "kind": "hold (obstacle)"}] * alarms,
            "min_clearance_m": 1.0, "time_to_destination_s": 10.0, "contact_speed_m_s": None, "faults": [],
            "stresses": [], "vehicle": "mambo", "personality": "px4", "fault_outcomes": [], "violations": []}


def test_the_family_table_pairs_speeds_with_the_px4_law_and_counts_alarms_per_hour(tmp_path):
    rows = [_row(0, "px4_cp", "doorway", 1.0), _row(0, "offboard", "doorway", 3.0, alarms=1),
            _row(1, "px4_cp", "doorway", 2.0), _row(1, "offboard", "doorway", 3.0, done=False, air=1800.0),
            _row(2, "offboard", "dead_end", 1.0, done=False, exists=False)]
    s = summarize(rows)
    door = s["per_world_family"]["doorway"]["offboard"]
    assert door["speed_x_peer"] == pytest.approx(2.0)  # 3 / mean(1, 2) over the scenarios both flew
    assert (door["routes_completed"], door["with_route"]) == (1, 2)
    assert door["hours"] == pytest.approx(1.5) and door["unfounded_per_hour"] == pytest.approx(1 / 1.5)
    dead = s["per_world_family"]["dead_end"]["offboard"]
    assert (dead["stopped_short"], dead["dead_ends"], dead["speed_x_peer"]) == (1, 1, None)
    md = world_family_markdown(s)
    assert "| doorway | offboard | 2 | 0/2 |" in md and "| 1/2 | – | 3.00 | 2.00 | 0.7 (1.500) |" in md
    write_report(rows, tmp_path)
    page = (tmp_path / "report.html").read_text()
    assert "Per world family" in page and "<td>dead_end</td><td>offboard</td>" in page
    plain = [{k: v for k, v in r.items() if k != "world_family"} for r in rows]  # a campaign without worlds
    assert summarize(plain)["per_world_family"] == {} and "| world |" not in format_summary(summarize(plain))


def test_an_output_directory_begun_before_the_new_dimensions_is_the_same_campaign():
    """A campaign begun before `world_families` and `sensor_models` existed stored a spec without them: it resumes
    (they are unset); one that sets either is another campaign."""
    spec = cg.load_spec("examples/campaign-small.yaml")
    old = spec.model_dump(mode="json")
    for k in ("world_families", "sensor_models"):
        del old["scenario"][k]
    assert cg.same_campaign(old, spec)
    clutter = cg.spec_from_dict({**spec.model_dump(mode="json"),
                                 "scenario": {**old["scenario"], "world_families": ["doorway"]}})
    assert not cg.same_campaign(old, clutter)


def test_a_reflown_cluttered_flight_is_kept_for_its_review_with_its_world(tmp_path, capsys):
    """`campaign --fly N --out DIR` keeps the flight as an event log the review reads and the SITL scenario it flew;
    the review draws that world (the dead end's walls) beneath the track and sees the governor's stop."""
    import json

    from companion.cli import main

    spec_file = tmp_path / "clutter.yaml"
    spec_file.write_text(json.dumps(DEAD_END))
    out = tmp_path / "one"
    assert main(["campaign", str(spec_file), "--fly", "0", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"contract-guard review {out / 'flight-0'} --scenario {out / 'scenario-0.json'}" in said
    assert main(["review", str(out / "flight-0"), "--scenario", str(out / "scenario-0.json"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert len(rep["world"]["polygons"]) >= 3 and rep["state_samples"] > 100  # left, right and end walls
    assert rep["modes"] and not rep["keep_out"]["collisions"], rep["keep_out"]
