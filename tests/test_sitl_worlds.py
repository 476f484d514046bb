"""The SITL's worlds beyond single columns (sitl_harness/world.py, world_build.py): walls with gaps and doorways,
polygons, seeded clusters and corridors — what the ray cast sees, what the collision truth counts, the scenario
keys and their one-line errors, and a corridor with a turn flown in lock-step over real MAVLink bytes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_client import Client, LockstepTransport
from sitl_harness import Sim
from sitl_harness.scenario import ScenarioError, load_scenario, scenario_from_dict
from sitl_harness.world import Column, CollisionMonitor, Polygon, World
from sitl_harness.world_build import built, cluster_columns, corridor_walls, open_spans, outline, wall_polygons

DOOR = {"points": [[10, -10], [10, 10]], "thickness_m": 0.3, "gaps": [{"at_m": 10, "width_m": 1.2}]}


def world_of(spec: dict) -> World:
    cols, polys = built(scenario_from_dict({"world": spec}).world)
    return World(cols, [], polys)


def cast(world: World, x: float, y: float, bearing_deg, max_range: float = 50.0):
    return world.ray_cast(x, y, 2.0, np.radians(np.atleast_1d(bearing_deg).astype(float)), max_range)


# ----------------------------------------------------------------------------- ray casting


def test_a_ray_through_the_doorway_passes_and_one_at_the_wall_stops():
    w = world_of({"walls": [DOOR]})
    through, at_wall, edge = cast(w, 0.0, 0.0, [0.0, 10.0, math.degrees(math.atan2(0.7, 9.85))])
    assert through == math.inf  # nothing behind the doorway
    assert at_wall == pytest.approx(9.85 / math.cos(math.radians(10.0)))  # the wall's near face
    assert edge == pytest.approx(math.hypot(9.85, 0.7))  # the doorway's jamb, 0.1 m beside the gap
    # the same wall without its gap stops the straight ray at its face: the gap is what lets it through
    assert cast(world_of({"walls": [{**DOOR, "gaps": []}]}), 0.0, 0.0, 0.0)[0] == pytest.approx(9.85)


def test_the_ray_cast_sees_the_nearest_of_every_kind_in_one_pass():
    w = World([Column(6.0, 0.0, 0.5, reflectivity=0.2)], [],
              wall_polygons([(4.0, -1.0), (4.0, 1.0)], 0.2, reflectivity=0.9))
    d, rho = w.ray_cast(0.0, 0.0, 2.0, np.radians([0.0, 20.0]), 50.0, reflectivity=True)
    assert d[0] == pytest.approx(3.9) and rho[0] == 0.9  # the wall, in front of the column
    assert d[1] == math.inf  # past the wall's end, beside the column
    beside = World([Column(6.0, 0.0, 0.5, reflectivity=0.2)])
    assert beside.ray_cast(0.0, 0.0, 2.0, np.radians([0.0]), 50.0)[0] == pytest.approx(5.5)


def test_a_ray_from_inside_a_polygon_is_zero_and_a_low_polygon_is_flown_over():
    tri = Polygon(((0.0, -2.0), (4.0, 0.0), (0.0, 2.0)), height=1.0)
    w = World([], [], [tri])
    assert list(w.ray_cast(1.0, 0.0, 0.5, np.radians([0.0, 180.0]), 20.0)) == [0.0, 0.0]
    assert w.ray_cast(-3.0, 0.0, 0.5, np.radians([0.0]), 20.0)[0] == pytest.approx(3.0)
    assert w.ray_cast(-3.0, 0.0, 2.0, np.radians([0.0]), 20.0)[0] == math.inf  # above its 1 m
    assert w.clearance(1.0, 0.0, 0.5)[0] < 0.0 and w.clearance(-3.0, 0.0, 0.5) == (pytest.approx(3.0), 0)
    assert w.clearance(1.0, 0.0, 2.0)[0] == math.inf


def test_the_vectorised_columns_answer_as_one_column_at_a_time():
    rng = np.random.default_rng(4)
    cols = [Column(float(x), float(y), float(r), reflectivity=float(p))
            for x, y, r, p in zip(rng.uniform(-10, 10, 40), rng.uniform(-10, 10, 40), rng.uniform(0.1, 0.8, 40),
                                  rng.uniform(0.1, 1.0, 40))]
    angles = np.linspace(-math.pi, math.pi, 361)
    d, rho = World(cols).ray_cast(0.3, -0.2, 2.0, angles, 12.0, reflectivity=True)
    best, best_rho = np.full(angles.shape, np.inf), np.zeros(angles.shape)
    for c in cols:
        di, ri = World([c]).ray_cast(0.3, -0.2, 2.0, angles, 12.0, reflectivity=True)
        nearer = di < best
        best, best_rho = np.where(nearer, di, best), np.where(nearer, ri, best_rho)
    assert np.array_equal(d, best) and np.array_equal(rho, best_rho)


# ----------------------------------------------------------------------------- building the shapes


def test_gaps_cut_the_wall_and_joints_are_closed():
    assert open_spans(20.0, [(10.0, 1.2)]) == [(0.0, pytest.approx(9.4)), (pytest.approx(10.6), 20.0)]
    assert open_spans(20.0, [(0.0, 2.0), (20.0, 2.0)]) == [(1.0, 19.0)]
    corner = World([], [], wall_polygons([(0.0, 0.0), (5.0, 0.0), (5.0, 5.0)], 0.4, reflectivity=0.5))
    assert corner.clearance(5.19, -0.19, 2.0)[0] < 0.0  # the outer corner square is solid: no notch
    assert cast(corner, 2.0, -3.0, 0.0)[0] == math.inf  # the wall is only where its points say


def test_a_corridor_is_two_walls_width_apart_and_closes_where_it_says():
    left, right, end = corridor_walls([(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)], 3.0, 3.0, 0.2, True)
    assert len(corridor_walls([(0.0, 0.0), (10.0, 0.0)], 3.0, 3.0, 0.2, False)) == 2  # open: no end wall
    assert len(corridor_walls([(0.0, 0.0), (10.0, 0.0)], 3.0, 0.0, 0.2, False)) == 3  # closing to 0: closed
    assert left[0] == pytest.approx((0.0, -1.6)) and right[0] == pytest.approx((0.0, 1.6))
    assert left[1] == pytest.approx((11.6, -1.6)) and right[1] == pytest.approx((8.4, 1.6))  # mitred corner
    assert end == [left[-1], right[-1]]
    w = world_of({"corridors": [{"points": [[0, 0], [10, 0], [10, 10]], "width_m": 3, "closed_end": True}]})
    assert cast(w, 5.0, 0.0, [90.0, -90.0]) == pytest.approx([1.5, 1.5])  # the inner faces either side
    assert cast(w, 10.0, 5.0, 90.0)[0] == pytest.approx(4.9)  # the dead end's face, after the turn
    funnel = world_of({"corridors": [{"points": [[0, 0], [20, 0]], "width_m": 4, "end_width_m": 0}]})
    assert cast(funnel, 2.0, 0.0, 90.0)[0] == pytest.approx(1.8, abs=0.01)  # narrowing: 4 m → 0 over 20 m
    assert all(cast(funnel, 0.0, 0.0, [-1.0, 0.0, 1.0]) <= 20.0 + 1e-6)  # closed: the walls meet ahead


def test_a_cluster_is_the_same_for_its_seed_and_keeps_its_gaps():
    a = cluster_columns(0.0, 0.0, 6.0, 15, 0.1, 0.4, 1.5, seed=3)
    assert a == cluster_columns(0.0, 0.0, 6.0, 15, 0.1, 0.4, 1.5, seed=3)
    assert a != cluster_columns(0.0, 0.0, 6.0, 15, 0.1, 0.4, 1.5, seed=4)
    assert all(math.hypot(x, y) <= 6.0 and 0.1 <= r <= 0.4 for x, y, r in a)
    assert min(math.hypot(p[0] - q[0], p[1] - q[1]) - p[2] - q[2] for i, p in enumerate(a) for q in a[i + 1:]) >= 1.5
    with pytest.raises(ValueError, match="only .* of 200 columns fit"):
        cluster_columns(0.0, 0.0, 3.0, 200, 0.1, 0.4, 1.5, seed=3)


def test_the_collision_truth_counts_walls():
    w = world_of({"walls": [DOOR]})
    mon = CollisionMonitor(w, 0.1)
    for x in np.arange(0.0, 12.0, 0.05):  # through the doorway: no contact
        mon.update(x, np.array([x, 0.0, -2.0]))
    assert mon.collisions == [] and mon.min_clearance == pytest.approx(0.5, abs=1e-6)
    mon = CollisionMonitor(w, 0.1)
    for x in np.arange(0.0, 12.0, 0.05):  # 3 m beside it: into the wall
        mon.update(x, np.array([x, 3.0, -2.0]))
    assert len(mon.collisions) == 1 and mon.collisions[0].obstacle_name == "wall0"
    assert mon.collisions[0].position[0] == pytest.approx(9.75, abs=0.05)


def test_the_plan_outline_is_plain_data():
    o = outline(scenario_from_dict({"world": {"walls": [DOOR], "columns": [{"x_m": 1, "y_m": 2, "radius_m": 0.5}],
                                              "boxes": [{"x_m": 0, "y_m": 0, "length_m": 2, "width_m": 1}]}}).world)
    assert o["columns"] == [[1.0, 2.0, 0.5, ""]] and len(o["polygons"]) == 3
    assert all(type(v) is float for poly in o["polygons"] for p in poly for v in p)


# ----------------------------------------------------------------------------- scenario keys


@pytest.mark.parametrize("world, where", [
    ({"walls": [{"points": [[0, 0]]}]}, "world.walls.0.points"),
    ({"walls": [{"points": [[0, 0], [1, 0]], "door": 1}]}, "world.walls.0.door"),
    ({"walls": [{"points": [[0, 0], [0, 0]]}]}, "two consecutive points are the same"),
    ({"walls": [{**DOOR, "gaps": [{"at_m": 30, "width_m": 1}]}]}, "beyond the wall's end"),
    ({"walls": [{**DOOR, "thickness_m": 0}]}, "world.walls.0.thickness_m"),
    ({"polygons": [{"points": [[0, 0], [1, 1], [2, 2]]}]}, "no area"),
    ({"clusters": [{"x_m": 0, "y_m": 0, "radius_m": 2, "count": 50}]}, "only"),
    ({"clusters": [{"x_m": 0, "y_m": 0, "radius_m": 2, "count": 2, "column_radius_m": [0.5, 0.1]}]}, "smallest"),
    ({"corridors": [{"points": [[0, 0], [5, 0]]}]}, "world.corridors.0.width_m"),
    ({"corridors": [{"points": [[0, 0], [5, 0]], "width_m": 2, "end_width_m": -1}]}, "end_width_m"),
])
def test_bad_world_keys_are_one_scenario_error_line(world, where):
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict({"world": world})
    assert where in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("name", ["wall_doorway", "column_cluster", "corridor_turn", "closing_corridor"])
def test_the_shipped_clutter_scenarios_load_and_stand_clear_of_their_start(name):
    sim = Sim(name)
    assert sim.world.obstacles and sim.world.clearance(0.0, 0.0, 2.0)[0] > 1.0


# ----------------------------------------------------------------------------- a corridor with a turn, in lock-step


def _depth_bins(m) -> tuple[np.ndarray, np.ndarray]:
    """Body bearings [rad] and ranges [m] of an OBSTACLE_DISTANCE's bins that report an obstacle."""
    d = np.asarray(m.distances, dtype=float)
    ang = np.radians(m.angle_offset + m.increment_f * np.arange(len(d)))
    ok = (d != 65535) & (d <= m.max_distance)
    return ang[ok], d[ok] / 100.0


def near(true_m: float) -> float:
    """What a depth camera's median over the centre bins may miss by: 3 σ of its noise (0.01·d²), the frame's
    age (up to 0.1 s at 1.5 m/s) and the z-depth of the bins beside the axis."""
    return 3 * 0.01 * true_m ** 2 + 0.3


def _fly_corridor(frozen_heading: bool = False):
    """The SITL's own mission (north 12 m, a right turn, east 8 m) in the corridor_turn world over real MAVLink
    bytes; per OBSTACLE_DISTANCE before and after the turn: (x, y, centre bins' ranges, bearings of the bins
    that see something). `frozen_heading`: the camera fed heading north throughout (a negative control)."""
    base = load_scenario("corridor_turn")
    sim = Sim(base.model_copy(update={"start": base.start.model_copy(update={"alt_m": 2.0})}), "px4")
    if frozen_heading:
        read = sim.sensor.read
        sim.sensor.read = lambda world, pos, yaw, pitch=0.0: read(world, pos, 0.0, pitch)
    c = Client(LockstepTransport(sim))
    c.pump(0.5)
    assert c.set_mode(4, 4) == mav.MAV_RESULT_ACCEPTED
    before, after = [], []
    end = c.now() + 40.0
    while c.now() < end:
        for m in c.pump(0.1):
            if m.get_type() != "OBSTACLE_DISTANCE":
                continue
            t = sim.truth()
            x, y, yaw = float(t["pos"][0]), float(t["pos"][1]), t["yaw"]
            ang, rng = _depth_bins(m)
            ahead = rng[np.abs(ang) < math.radians(8)]
            if 6.0 < x < 9.0 and abs(yaw) < math.radians(10):
                before.append((x, y, ahead, ang))
            if 2.5 < y < 5.0 and abs(yaw - math.pi / 2) < math.radians(10):
                after.append((x, y, ahead, ang))
    assert sim.collisions == [] and 11.0 < sim.truth()["pos"][0] < 13.0 and sim.truth()["pos"][1] > 7.0
    return c, before, after


def test_a_corridor_with_a_turn_flown_in_lockstep_the_camera_turns_and_sees_the_walls():
    """Before the turn the camera, looking north, sees the corner's far wall ahead; after it, looking east, the
    dead end ahead and the side walls: the field of view turned with the heading."""
    c, before, after = _fly_corridor()
    assert c.last["OBSTACLE_DISTANCE"].sensor_type == mav.MAV_DISTANCE_SENSOR_INFRARED
    assert "DISTANCE_SENSOR" not in c.last  # a depth camera sends OBSTACLE_DISTANCE only
    assert len(before) >= 5 and len(after) >= 5
    # looking north: the far wall of the corner (inner face at x = 13.5) ahead
    seen = [(13.5 - x, float(np.median(a))) for x, y, a, _ in before if a.size]
    assert len(seen) >= 0.8 * len(before)
    assert all(abs(true - got) < near(true) for true, got in seen), seen
    # looking east: the dead end (inner face at y = 11.9) ahead, and both side walls in the outer bins
    seen = [(11.9 - y, float(np.median(a))) for x, y, a, _ in after if a.size]
    assert len(seen) >= 0.8 * len(after)
    assert all(abs(true - got) < near(true) for true, got in seen), seen
    sides = [(ang.min() < math.radians(-30), ang.max() > math.radians(30)) for *_, ang in after]
    assert sum(left and right for left, right in sides) >= 0.8 * len(after)


def test_negative_control_a_camera_that_does_not_turn_misses_the_dead_end():
    """The same flight with the camera held looking north: after the turn it sees the corridor's right-hand wall
    beside it, never the dead end ahead — what the test above would catch."""
    _, _, after = _fly_corridor(frozen_heading=True)
    seen = [(11.9 - y, float(np.median(a))) for x, y, a, _ in after if a.size]
    assert len(after) >= 5 and not any(abs(true - got) < near(true) for true, got in seen), seen
