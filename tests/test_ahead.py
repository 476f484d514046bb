"""The nearest obstacle the stop contract stops short of (companion/onboard/ahead.py): the swept corridor
r_body + E_tr about the direction of travel, whatever is in it, and near rest anything close in view; the direction
of travel of a vehicle creeping out of view — pure, and flown lock-step (the real daemon, the real SITL, MAVLink over UDP) down a corridor whose walls stand beside the route.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.ground import false_alarms as fa
from companion.ground.flights import Rig, fly_mission
from companion.ground.worlds import column, turning_corridor
from companion.onboard import ahead
from companion.onboard.ahead import CREEP_SPEED_M_S, TRAVEL_SPEED_M_S, Creep, stop_obstacle_m, swept_obstacle_m
from companion.onboard.supervisor import Supervisor
from tests.swerve_rules import (
    grown_judged_at_once,
    guessed_at_speed_now,
    others_passed_through,
    out_of_view_forgotten,
    outline_unread,
    pass_left_beside_its_obstacle,
    seen_once,
    stops_bounded_by_v_max,
    threats_on_the_leg_line,
)

ROOT = Path(__file__).resolve().parents[1]
BIN = math.radians(5.0)
OBSTACLE = "obstacle inside the stop distance"
RAY_TOL_M = 0.01  # a bin's least range over its 20 rays may miss the surface's nearest point between two rays


def test_near_rest_the_nearest_hit_in_any_direction_counts():
    h = BIN / 2
    beside = (math.radians(70.0), 1.2, h, True)  # 1.1 m off the line of travel
    far = (0.0, 6.0, h, True)
    assert stop_obstacle_m([beside, far], 0.0, 3.0, 0.6) == 6.0  # at speed: only what is in the swept corridor
    for v in (0.0, TRAVEL_SPEED_M_S, math.nan):  # at rest, at the threshold, speed unknown
        assert stop_obstacle_m([beside, far], 0.0, v, 0.6) == 1.2
    assert stop_obstacle_m([], 0.0, 0.0, 0.6) == math.inf


def _column_bins(cx: float, cy: float, radius: float, n_bins: int = 24, rays_per_bin: int = 20):
    """A 5° sector sensor's bins (body bearing, least range in the bin) over ±60° looking at one column, by casting
    rays from the origin; the bins that see it."""
    out = []
    for k in range(n_bins):
        lo = -n_bins / 2 * BIN + k * BIN
        best = math.inf
        for a in np.linspace(lo, lo + BIN, rays_per_bin):
            dx, dy = math.cos(a), math.sin(a)
            along = dx * cx + dy * cy
            miss2 = cx * cx + cy * cy - along * along
            if along > 0 and miss2 <= radius * radius:
                best = min(best, along - math.sqrt(radius * radius - miss2))
        if math.isfinite(best):
            out.append((lo + BIN / 2, best, BIN / 2, True))
    return out


@pytest.mark.parametrize("radius", [0.1, 0.3, 1.0])
def test_a_column_whose_surface_enters_the_swept_corridor_is_held_for(radius):
    """Every column of radius up to R_obst (1 m) whose surface enters the band r_body + E_tr about the line of
    travel, seen by 5° bins, is in the swept corridor no farther than the nearest point of its surface inside the
    band; one whose surface stays outside the band by more than a bin's width at the bins' ranges is not."""
    w = 0.5
    for x in np.arange(2.0, 10.01, 0.5):
        for off in np.arange(-w - radius - 1.5, w + radius + 1.5, 0.05):
            hits = _column_bins(x, off, radius)
            if not hits:
                continue
            gap = abs(off) - radius  # the surface's distance from the line of travel
            surface = [(x + radius * math.cos(t), off + radius * math.sin(t)) for t in np.linspace(0, 2 * math.pi, 721)]
            got = swept_obstacle_m(hits, 0.0, w)
            if gap <= w:  # no farther than the nearest point of its surface inside the band
                near = min(math.hypot(px, py) for px, py in surface if abs(py) <= w + 1e-9)
                assert got <= near + RAY_TOL_M, (x, off)
            elif gap > w + max(r for _, r, _, _ in hits) * math.sin(BIN) + 1e-6:
                assert got == math.inf, (x, off)


# ------------------------------------------------------------------ lock-step: down a corridor, walls beside
CRUISE_M_S = 4.0  # fast enough that the walls 2.5 m beside are within the stop distance's reach


def _corridor_flight(columns=()) -> Rig:
    """The governor (the Mambo, PX4, the 60° sector sensor read as bins) flying its mission at 4 m/s down a straight
    corridor 5 m wide — its walls 2.5 m either side of the route — whose turn lies beyond the route's end and the
    sensor's 10 m, with `columns` on the route."""
    sc = fa.scenario_of("governor", "sector", "plain", 1)
    sc["world"] = {"corridors": [turning_corridor(70.0, 15.0, 5.0)], "columns": list(columns)}
    sc["route"].update(cruise_speed_m_s=CRUISE_M_S, waypoints=[[0.0, 0.0], [45.0, 0.0]])
    rig = Rig(sc, "px4", config=fa.config_of("governor", sc["route"]["waypoints"]))
    fly_mission(rig, 25.0, until=lambda r: bool(r.log.named("hold_trigger")) and r.sim.time_s > 3.0 +
                r.log.named("hold_trigger")[0]["t"])
    return rig


def _band(monkeypatch):
    """The negative control: the Hold judged against D_od's band (2·R_obst + E_tr + r_body), as before."""
    monkeypatch.setattr(Supervisor, "ahead_m", lambda self, i, om: i.dod.obstacle_m)


def test_the_governor_flies_a_corridor_past_its_walls_without_a_hold():
    rig = _corridor_flight()
    assert not rig.truth["collisions"]
    assert [e for e in rig.log.named("hold_trigger") if e["cause"] == OBSTACLE] == []
    end = rig.sim.truth()["pos"]
    assert math.hypot(end[0] - 45.0, end[1]) < 1.5  # the route flown to its end
    assert max(s["ground_speed"] or 0.0 for s in rig.log.states) > 3.0  # at speed, between the walls


def test_negative_control_judged_against_the_band_the_corridor_walls_hold_the_governor(monkeypatch):
    _band(monkeypatch)
    rig = _corridor_flight()
    holds = [e for e in rig.log.named("hold_trigger") if e["cause"] == OBSTACLE]
    assert holds
    assert rig.sim.truth()["pos"][0] < 40.0  # stopped short of the route's end


def test_a_column_on_the_route_between_the_walls_is_held_for_without_contact():
    rig = _corridor_flight([column(25.0, 0.0, 0.3, "column")])
    assert not rig.truth["collisions"]
    holds = [e for e in rig.log.named("hold_trigger") if e["cause"] == OBSTACLE]
    assert holds
    assert rig.sim.truth()["pos"][0] < 25.0 - 0.3


FOV = math.radians(30.0)


def _in_view(beta: float) -> bool:
    return abs(beta) <= FOV


def test_creep_direction_of_travel():
    """Above walking pace the velocity's bearing; below it the heading's, until the vehicle has crept farther than
    the allowance along bearings no sensor looks along; a creep back into view, a stop, or no telemetry start it
    over."""
    c, dt, side = Creep(), 0.02, math.radians(-90.0)
    assert c.bearing(0.0, 0.0, 0.1, 0.0, _in_view, 0.3) == 0.0  # a hover's drift
    assert c.bearing(0.02, 2.0, 0.0, 0.5, _in_view, 0.3) == pytest.approx(-0.5)  # at speed: the velocity's
    v = 0.6  # sideways (−y, body −90°), below TRAVEL_SPEED_M_S
    got = [c.bearing(0.04 + k * dt, 0.0, -v, 0.0, _in_view, 0.3) for k in range(60)]
    first = next(k for k, b in enumerate(got) if b != 0.0)
    assert got[first] == pytest.approx(side) and all(b == pytest.approx(side) for b in got[first:])
    assert first * dt * v == pytest.approx(0.3, abs=v * dt)  # after the allowance, not before
    assert c.bearing(1.5, v, 0.0, 0.0, _in_view, 0.3) == 0.0  # back in view: the heading, and the creep starts over
    assert c.bearing(1.52, 0.0, -v, 0.0, _in_view, 0.3) == 0.0
    c.bearing(2.5, 0.0, -v, 0.0, _in_view, 0.3)
    assert c.out_m > 0.3 and c.bearing(2.52, 0.0, -CREEP_SPEED_M_S, 0.0, _in_view, 0.3) == 0.0 and c.out_m == 0.0
    assert c.bearing(2.54, math.nan, math.nan, 0.0, _in_view, 0.3) == 0.0
    # along a bearing in view, below walking pace: the heading's however long
    assert all(c.bearing(3.0 + k * dt, 0.6, 0.1, 0.0, _in_view, 0.3) == 0.0 for k in range(200))


def _clutter_spec(tmp_path):
    """examples/campaign-clutter.yaml at 2 000 scenarios and its two arms, as the clutter evidence flew it."""
    from companion.ground.campaign import load_spec

    text = (ROOT / "examples" / "campaign-clutter.yaml").read_text()
    text = text.replace("scenarios: 500", "scenarios: 2000").replace(
        "arms: [governor, offboard, px4_cp, ac_avoid]", "arms: [governor, offboard]")
    path = tmp_path / "clutter-2000.yaml"
    path.write_text(text)
    return load_spec(path)


def _old_guidance(monkeypatch):
    """Offboard guidance that slides back onto the route whatever the heading, its yaw along the route when slow —
    and as it flew swerves before: R_obst's disc round a pole at any range and round every run of bins whatever the
    bins beside it saw, from its first frame, a disc in the way wherever it is near the leg's line, the other discs not
    kept out of, more of an obstacle past its disc judged at once, a pass flown to its end past the route's turn,
    planned along the route where the vehicle is, linearised first about the path at the speed now, not waiting for
    the heading, a sideways speed clipped at once, a stop as fast as V_max allows, a pass left beside its obstacle,
    nothing planned round once out of view."""
    from companion.onboard import guidance
    from companion.onboard.guidance import OffboardGuidance
    from companion.onboard.supervisor import Supervisor

    outline_unread(monkeypatch)
    seen_once(monkeypatch)
    threats_on_the_leg_line(monkeypatch)
    others_passed_through(monkeypatch)
    grown_judged_at_once(monkeypatch)
    guessed_at_speed_now(monkeypatch)
    stops_bounded_by_v_max(monkeypatch)
    pass_left_beside_its_obstacle(monkeypatch)
    out_of_view_forgotten(monkeypatch)

    monkeypatch.setattr(guidance, "slow_aim", lambda heading, want: (None, False))
    monkeypatch.setattr(guidance, "A_SIDE", math.inf)
    monkeypatch.setattr(Supervisor, "_hold_reach", lambda self, i: math.inf)
    monkeypatch.setattr(OffboardGuidance, "_past_the_leg", lambda self, t: False)
    monkeypatch.setattr(OffboardGuidance, "_plan_direction", lambda self, p, discs: self.route.point(
        self.route.project(p))[1])
    follow = OffboardGuidance._follow
    monkeypatch.setattr(OffboardGuidance, "_follow", lambda self, t, dt, z, v_max, a_max, heading=None: follow(
        self, t, dt, z, v_max, a_max))


def test_offboard_creeping_sideways_out_of_view_judges_where_it_goes(tmp_path, monkeypatch):
    """The clutter campaign's flight 3431 (the Mambo on PX4, a turning corridor with a column inside): sliding back
    onto the route at walking pace after a swerve, the vehicle crept sideways while its heading, and its sensor,
    pointed along the corridor, into a column it never saw. D_od is judged along where the vehicle goes once a creep
    out of view passes E_tr (`Creep`): it stops clear, with or without today's guidance (which turns the heading to a
    slow rejoin before flying it, `slow_aim`, and no longer flies that creep: it plans round the column as seen and
    takes the corridor's turn), which alone keeps it off the column too. Control: both off — the column, never in
    view, is hit."""
    from companion.ground.campaign import flight_of, fly

    spec = _clutter_spec(tmp_path)
    s, arm = flight_of(spec, 3431)
    assert arm == "offboard" and s["world_family"] == "corridor" and s["vehicle"] == "mambo"
    row = fly(spec, 3431)
    assert not row["collided"] and row["min_clearance_m"] > 0.3
    with monkeypatch.context() as m:
        _old_guidance(m)
        row = fly(spec, 3431)
        assert not row["collided"] and row["min_clearance_m"] > 0.3
    monkeypatch.setattr(ahead, "CREEP_SPEED_M_S", math.inf)
    assert not fly(spec, 3431)["collided"]  # the guidance alone
    _old_guidance(monkeypatch)
    assert fly(spec, 3431)["collided"]  # the control must fail
