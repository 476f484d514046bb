"""The offboard route from the autopilot's mission: the download client against scripted messages, the
conversion to a level route, and lock-step flights where a ground station uploads the mission."""

import math
from pathlib import Path

import numpy as np
import pytest

from companion.onboard.config import config_from_dict, load_config
from companion.onboard.link import mavlink as mav
from companion.onboard.mission import (
    Home,
    HomeNeeded,
    Item,
    MissionDownload,
    MissionRefused,
    MissionSource,
    route_from_items,
)
from contracts.errors import ContractError
from contracts.geodesy import ne_from_geo
from tests.lockstep import Rig

AP, DAEMON = (1, 1), (1, 191)
LAT0, LON0, ALT0 = 47.397742, 8.545594, 488.0  # the SITL's default home


# ------------------------------------------------------------------------------------------ scripted messages
def count(n, to=DAEMON, mission_type=0):
    return mav.MAVLink_mission_count_message(*to, n, mission_type)


def item_int(seq, x=0.0, y=0.0, z=2.0, frame=mav.MAV_FRAME_LOCAL_NED, command=16, to=DAEMON, mission_type=0):
    """MISSION_ITEM_INT as an autopilot sends it: local metres × 1e4, lat/lon × 1e7."""
    k = 1e4 if frame == mav.MAV_FRAME_LOCAL_NED else 1e7
    return mav.MAVLink_mission_item_int_message(*to, seq, frame, command, 0, 1, 0, 0, 0, math.nan,
                                                int(round(x * k)), int(round(y * k)), z, mission_type)


def sent(msgs):
    return [(m.get_type(), getattr(m, "seq", None)) for m in msgs]


def started(t=0.0, **kw):
    d = MissionDownload(*AP, *DAEMON, **kw)
    assert sent(d.start(t)) == [("MISSION_REQUEST_LIST", None)]
    return d


# ------------------------------------------------------------------------------------------ the client
def test_download_happy_path_requests_each_item_and_acks():
    d = started()
    assert sent(d.take(0.01, count(3))) == [("MISSION_REQUEST_INT", 0)]
    assert sent(d.take(0.02, item_int(0, 1.0, 2.0, -3.0))) == [("MISSION_REQUEST_INT", 1)]
    assert sent(d.take(0.03, item_int(1, 4.5, -1.25, -3.0))) == [("MISSION_REQUEST_INT", 2)]
    out = d.take(0.04, item_int(2, 10.0, 0.0, -3.0))
    assert sent(out) == [("MISSION_ACK", None)] and out[0].type == mav.MAV_MISSION_ACCEPTED
    assert out[0].target_system == 1 and out[0].target_component == 1 and out[0].mission_type == 0
    assert d.state == "done"
    assert [(i.seq, i.x, i.y, i.z) for i in d.items] == [(0, 1.0, 2.0, -3.0), (1, 4.5, -1.25, -3.0), (2, 10.0, 0.0, -3.0)]
    assert d.stats == {"resent": 0, "duplicates": 0, "out_of_order": 0, "malformed": 0}


def test_lost_item_is_requested_again_after_the_item_timeout():
    d = started()
    d.take(0.0, count(2))
    d.take(0.01, item_int(0))
    assert d.poll(0.25) == []  # 250 ms per item (mavlink.io: Timeouts and Retries)
    assert sent(d.poll(0.27)) == [("MISSION_REQUEST_INT", 1)]
    assert sent(d.poll(0.30)) == []  # the timer restarted with the resend
    assert sent(d.take(0.31, item_int(1))) == [("MISSION_ACK", None)]
    assert d.state == "done" and d.stats["resent"] == 1


def test_lost_mission_count_is_requested_again_after_the_default_timeout():
    d = started()
    assert d.poll(1.4) == []
    assert sent(d.poll(1.6)) == [("MISSION_REQUEST_LIST", None)]
    d.take(1.7, count(1))
    d.take(1.8, item_int(0))
    assert d.state == "done"


def test_item_that_never_arrives_fails_after_the_retries_and_cancels():
    d = started()
    d.take(0.0, count(3))
    d.take(0.0, item_int(0))
    t, out = 0.0, []
    for _ in range(6):
        t += 0.3
        out = d.poll(t)
        if d.state == "failed":
            break
        assert sent(out) == [("MISSION_REQUEST_INT", 1)]
    assert d.state == "failed" and d.stats["resent"] == 5
    assert sent(out) == [("MISSION_ACK", None)] and out[0].type == mav.MAV_MISSION_OPERATION_CANCELLED
    assert "mission item 1 of 3" in d.reason and "6 requests" in d.reason
    assert d.take(t, item_int(1)) == [] and d.state == "failed"  # a late answer changes nothing


def test_no_mission_count_fails_without_cancelling():
    d = started()
    out = []
    for k in range(1, 8):
        out = d.poll(1.6 * k)
    assert d.state == "failed" and "MISSION_COUNT" in d.reason and out == []


def test_malformed_items_are_counted_and_dropped():
    d = started()
    d.take(0.0, count(2))
    assert d.take(0.01, item_int(5)) == []  # seq beyond the count
    assert d.take(0.02, item_int(0, frame=99)) == []  # no such MAV_FRAME
    assert d.stats["malformed"] == 2 and d.items == []
    d.take(0.03, item_int(0))
    d.take(0.04, item_int(1))
    assert d.state == "done" and len(d.items) == 2


def test_duplicates_ignored_and_out_of_order_item_dropped_and_requested_again():
    d = started()
    d.take(0.0, count(3))
    d.take(0.01, item_int(0, 1.0))
    assert d.take(0.02, item_int(0, 1.0)) == [] and d.stats["duplicates"] == 1
    assert d.take(0.02, count(3)) == [] and d.stats["duplicates"] == 2  # late MISSION_COUNT too
    assert sent(d.take(0.03, item_int(2, 3.0))) == [("MISSION_REQUEST_INT", 1)]
    assert d.stats["out_of_order"] == 1 and len(d.items) == 1
    d.take(0.04, item_int(1, 2.0))
    d.take(0.05, item_int(2, 3.0))
    assert d.state == "done" and [i.x for i in d.items] == [1.0, 2.0, 3.0]


def test_messages_for_others_and_other_mission_types_are_ignored():
    d = started()
    assert d.take(0.0, count(2, to=(255, 190))) == []  # the autopilot talking to a ground station
    assert d.take(0.0, count(2, mission_type=mav.MAV_MISSION_TYPE_FENCE)) == []
    assert d.state == "count"
    d.take(0.0, count(1))
    assert d.take(0.0, item_int(0, to=(255, 190))) == [] and d.items == []


def test_error_ack_from_the_autopilot_ends_the_download():
    d = started()
    d.take(0.0, count(2))
    assert d.take(0.01, mav.MAVLink_mission_ack_message(*DAEMON, mav.MAV_MISSION_DENIED, 0)) == []
    assert d.state == "failed" and "MAV_MISSION_DENIED" in d.reason


def test_empty_mission_downloads_and_is_refused():
    d = started()
    out = d.take(0.0, count(0))
    assert d.state == "done" and sent(out) == [("MISSION_ACK", None)]
    with pytest.raises(MissionRefused, match="no mission"):
        route_from_items(d.items, skip_home=False, home=None)


def test_mission_item_float_message_is_taken_as_sent():
    d = started()
    d.take(0.0, count(1))
    d.take(0.0, mav.MAVLink_mission_item_message(*DAEMON, 0, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, 16, 0, 1,
                                                 0, 0, 0, 0, LAT0, LON0, 2.0))
    assert d.state == "done" and d.items[0].x == pytest.approx(LAT0) and d.items[0].y == pytest.approx(LON0)


# ------------------------------------------------------------------------------------------ conversion
def wp(seq, x, y, z, frame=mav.MAV_FRAME_LOCAL_NED, command=16):
    return Item(seq, frame, command, (0.0, 0.0, 0.0, math.nan), x, y, z)


HOME = Home(LAT0, LON0, ALT0)


def haversine_m(lat1, lon1, lat2, lon2, r=6378137.0):
    p1, p2 = math.radians(lat1), math.radians(lat2)
    a = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(math.radians(lon2 - lon1) / 2) ** 2
    return 2 * r * math.asin(math.sqrt(a))


def test_local_ned_items_become_the_route():
    path = route_from_items([wp(0, 0, 0, -3), wp(1, 10, 0, -3), wp(2, 10, 5, -3.2)], skip_home=False, home=None)
    assert path.waypoints == [(0, 0), (10, 0), (10, 5)]
    assert path.altitude_m == pytest.approx(3.0667, abs=1e-3)


def test_tangent_plane_matches_great_circle_distance_and_bearing():
    lat, lon = LAT0 + 0.0003, LON0 - 0.0004  # about 33 m north, 30 m west
    n, e = ne_from_geo(lat, lon, LAT0, LON0)
    assert math.hypot(n, e) == pytest.approx(haversine_m(LAT0, LON0, lat, lon), abs=2e-3)
    assert n == pytest.approx(math.radians(0.0003) * 6378137.0, rel=1e-9) and e < 0


def test_global_relative_alt_items_are_placed_about_home():
    home = Home(LAT0, LON0, ALT0, x=1.0, y=-2.0, z=-0.5)  # home is not the local origin
    lat1 = LAT0 + math.degrees(20.0 / 6378137.0)
    items = [wp(0, LAT0, LON0, 3.0, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT),
             wp(1, lat1, LON0, 3.0, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT)]
    path = route_from_items(items, skip_home=False, home=home)
    assert path.waypoints[0] == pytest.approx((1.0, -2.0))
    assert path.waypoints[1] == pytest.approx((21.0, -2.0), abs=1e-6)
    assert path.altitude_m == pytest.approx(3.5)  # 3 m above home, home 0.5 m above the origin


def test_global_amsl_items_are_relative_to_home_altitude():
    items = [wp(0, LAT0, LON0, ALT0 + 4, mav.MAV_FRAME_GLOBAL_INT),
             wp(1, LAT0 + 1e-4, LON0, ALT0 + 4, mav.MAV_FRAME_GLOBAL)]
    assert route_from_items(items, skip_home=False, home=HOME).altitude_m == pytest.approx(4.0)


def test_global_items_without_home_wait_for_it():
    items = [wp(0, LAT0, LON0, 2, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT),
             wp(1, LAT0 + 1e-4, LON0, 2, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)]
    with pytest.raises(HomeNeeded):
        route_from_items(items, skip_home=False, home=None)


def test_ardupilot_home_item_is_skipped():
    g = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items = [wp(0, LAT0 - 0.001, LON0, 0.0, mav.MAV_FRAME_GLOBAL),  # ArduPilot: home, on the ground
             wp(1, LAT0, LON0, 2, g), wp(2, LAT0 + 1e-4, LON0, 2, g)]
    path = route_from_items(items, skip_home=True, home=HOME)
    assert len(path.waypoints) == 2 and path.altitude_m == pytest.approx(2.0)
    with pytest.raises(MissionRefused, match="level"):  # read as a waypoint, home is 488 m below the route
        route_from_items(items, skip_home=False, home=HOME)


def test_non_level_mission_is_refused_with_one_line():
    items = [wp(0, 0, 0, -2), wp(1, 10, 0, -2), wp(2, 20, 0, -2.6)]
    with pytest.raises(MissionRefused) as err:
        route_from_items(items, skip_home=False, home=None)
    assert "level" in str(err.value) and "\n" not in str(err.value) and "0.5 m" in str(err.value)
    assert route_from_items(items, skip_home=False, home=None, level_tol_m=0.7).altitude_m == pytest.approx(2.2)
    items[2] = wp(2, 20, 0, -2.4)
    assert route_from_items(items, skip_home=False, home=None).altitude_m == pytest.approx(2.1333, abs=1e-3)


@pytest.mark.parametrize("command,name", [(mav.MAV_CMD_NAV_LOITER_TURNS, "NAV_LOITER_TURNS"),
                                          (mav.MAV_CMD_NAV_LOITER_TIME, "NAV_LOITER_TIME"),
                                          (mav.MAV_CMD_DO_JUMP, "DO_JUMP")])
def test_unsupported_command_in_the_middle_is_refused(command, name):
    items = [wp(0, 0, 0, -2), wp(1, 5, 0, -2, command=command), wp(2, 10, 0, -2)]
    with pytest.raises(MissionRefused, match=f"^mission item 1: {name} \\({command}\\) not supported"):
        route_from_items(items, skip_home=False, home=None)


def test_land_in_the_middle_is_refused_at_the_end_ignored():
    land = wp(2, 10, 0, 0, command=mav.MAV_CMD_NAV_LAND)
    with pytest.raises(MissionRefused, match="NAV_LAND .* before the last waypoint"):
        route_from_items([wp(0, 0, 0, -2), wp(1, 5, 0, -2), land, wp(3, 10, 5, -2)], skip_home=False, home=None)
    path = route_from_items([wp(0, 0, 0, -2), wp(1, 5, 0, -2), land], skip_home=False, home=None)
    assert path.waypoints == [(0, 0), (5, 0)] and any("NAV_LAND" in n for n in path.notes)
    held = Item(1, mav.MAV_FRAME_LOCAL_NED, 16, (3.0, 0.0, 0.0, 0.0), 5, 0, -2)  # param1: hold time [s]
    assert "hold time 3 s ignored" in route_from_items([wp(0, 0, 0, -2), held], skip_home=False, home=None).notes[0]


def test_takeoff_first_and_do_items_are_ignored_with_notes():
    items = [wp(0, 0, 0, -2, command=mav.MAV_CMD_NAV_TAKEOFF), wp(1, 0, 0, -2),
             wp(2, 0, 0, 0, mav.MAV_FRAME_MISSION, mav.MAV_CMD_DO_CHANGE_SPEED), wp(3, 10, 0, -2),
             wp(4, 0, 0, 0, command=mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)]
    path = route_from_items(items, skip_home=False, home=None)
    assert path.waypoints == [(0, 0), (10, 0)]
    assert [n.split(":")[0] for n in path.notes] == ["mission item 0", "mission item 2", "mission item 4"]
    with pytest.raises(MissionRefused, match="NAV_TAKEOFF"):  # a take-off after a waypoint is not a route
        route_from_items(items[1:2] + items[:1] + items[3:4], skip_home=False, home=None)


@pytest.mark.parametrize("items,match", [
    ([], "no mission"),
    ([wp(0, 0, 0, -2)], "1 NAV_WAYPOINT"),
    ([wp(0, 3, 3, -2), wp(1, 3, 3, -2)], "one place"),
    ([wp(0, 0, 0, -2), wp(1, 5, 0, -2, frame=mav.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT)], "TERRAIN"),
    ([wp(0, 0, 0, -2), wp(1, 0.0, 0.0, 2, frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)], "latitude"),
    ([wp(0, 0, 0, -2), wp(1, 5, math.nan, -2)], "not a number"),
    ([wp(0, 0, 0, 1), wp(1, 5, 0, 1)], "not above"),
    ([wp(0, LAT0, LON0, 2, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT),
      wp(1, LAT0 + 1, LON0, 2, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)], "km from home"),
])
def test_missions_that_are_not_a_route_are_refused(items, match):
    with pytest.raises(MissionRefused, match=match):
        route_from_items(items, skip_home=False, home=HOME)


# ------------------------------------------------------------------------------------------ the daemon's view
def test_source_waits_for_home_then_holds_the_route():
    src = MissionSource(False, *AP, *DAEMON, home_timeout_s=5.0)
    acts = src.request(0.0, "test")
    kinds = [m.get_type() for m in acts.send]
    assert kinds == ["MISSION_REQUEST_LIST", "COMMAND_LONG"] and acts.send[1].param1 == 242  # HOME_POSITION
    src.take(0.0, count(2))
    g = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    src.take(0.0, item_int(0, LAT0, LON0, 2.0, frame=g))
    src.take(0.0, item_int(1, LAT0 + 1e-4, LON0, 2.0, frame=g))
    assert src.status == "waiting_home" and src.route is None
    src.take(0.5, mav.MAVLink_home_position_message(int(LAT0 * 1e7), int(LON0 * 1e7), int(ALT0 * 1000), 0, 0, 0,
                                                    [1, 0, 0, 0], 0, 0, 0))
    assert src.status == "ready" and src.route.length == pytest.approx(11.132, abs=0.01)


def test_a_waypoints_acceptance_radius_sets_its_corner_cut():
    """NAV_WAYPOINT param2 (acceptance radius) > 0: the corner there passes that close; else route.corner_cut_m."""
    src = MissionSource(False, *AP, *DAEMON, corner_cut_m=0.5)
    src.request(0.0, "test")
    src.take(0.0, count(4))
    for seq, (x, y, accept) in enumerate([(0, 0, 0.0), (30, 0, 2.0), (30, 30, 0.0), (0, 30, 0.0)]):
        src.take(0.0, mav.MAVLink_mission_item_int_message(*DAEMON, seq, mav.MAV_FRAME_LOCAL_NED, 16, 0, 1, 0.0,
                                                           accept, 0, math.nan, x * 10000, y * 10000, -2.0, 0))
    assert src.status == "ready" and src.path.accept_m == [None, 2.0, None, None]
    radii = src.route.arcs[:, 8]
    assert radii == pytest.approx([2.0 / (math.sqrt(2) - 1), 0.5 / (math.sqrt(2) - 1)])  # cut = R/cos 45° − R


def test_source_refuses_without_home_and_on_a_failed_download():
    src = MissionSource(False, *AP, *DAEMON, home_timeout_s=2.0)
    src.request(0.0, "test")
    src.take(0.0, count(2))
    src.take(0.0, item_int(0, LAT0, LON0, 2.0, frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT))
    src.take(0.0, item_int(1, LAT0 + 1e-4, LON0, 2.0, frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT))
    assert src.status == "waiting_home"
    acts = src.poll(2.5)
    assert src.status == "refused" and "HOME_POSITION" in src.reason
    assert acts.events[0][0] == "mission" and acts.events[0][1]["status"] == "refused"
    src.request(3.0, "again")
    for k in range(8):
        src.poll(3.0 + 1.6 * (k + 1))
    assert src.status == "refused" and "download failed" in src.reason and src.route is None


def test_route_config_source_and_keys():
    assert config_from_dict({"route": {"source": "mission"}}).route.waypoints is None
    assert config_from_dict({"route": {"source": "mission"}}).route.corner_cut_m == 1.0
    assert config_from_dict({"route": {"source": "mission", "corner_cut_m": 0}}).route.corner_cut_m == 0.0
    with pytest.raises(ContractError, match="corner_cut_m"):
        config_from_dict({"route": {"source": "mission", "corner_cut_m": -1}})
    with pytest.raises(ContractError, match="route.waypoints: List should have at least 2 items"):
        config_from_dict({"route": {"waypoints": [[0, 0]]}})
    with pytest.raises(ContractError, match="route: waypoints are required with source: config"):
        config_from_dict({"route": {"altitude_m": 2}})
    with pytest.raises(ContractError, match="come from the mission"):
        config_from_dict({"route": {"source": "mission", "waypoints": [[0, 0], [1, 0]]}})


# ------------------------------------------------------------------------------------------ lock-step flights
def scenario(personality):
    return {"name": "mission_route", "vehicle": "mambo", "seed": 1, "start": {"alt_m": 2.0},
            "params": {"COM_OBL_RC_ACT": 5} if personality == "px4" else {},
            "world": {"columns": []},
            "sensor": {"fov_deg": 60, "increment_deg": 5, "max_range_m": 6.0, "rate_hz": 20}}


MISSION_CONFIG = {"mode": "offboard", "engage": True, "sensors": [{"kind": "obstacle_distance", "h_fov_deg": 60}],
                  "route": {"source": "mission"}, "contract": {"r_obst_m": 1.0}}


def mission_items(rig, personality, points, alts, accept_m=0.0):
    """What a ground station plans: take-off, waypoints in MAV_FRAME_GLOBAL_RELATIVE_ALT_INT placed on
    the map (the SITL's own geodesy; acceptance radius `accept_m`), a speed change; ArduPilot's item 0 is home."""
    ap, g = rig.sim.autopilot, rig.gcs
    rows = []
    if personality == "ardupilot":
        rows.append((16, mav.MAV_FRAME_GLOBAL, ap.home_geo[0], ap.home_geo[1], ap.home_geo[2]))
    rows.append((22, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0.0, 0.0, alts[0]))
    for k, ((x, y), alt) in enumerate(zip(points, alts)):
        lat, lon, _ = ap.geo_from_local((x, y, -alt))
        rows.append((16, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, lat, lon, alt))
        if k == 0:
            rows.append((178, mav.MAV_FRAME_MISSION, 0.0, 0.0, 0.0))
    return [g.mission_item_int_encode(1, 1, seq, frame, cmd, 0, 1, 1.0 if cmd == 178 else 0.0,
                                      3.0 if cmd == 178 else accept_m if cmd == 16 else 0.0, 0, math.nan,
                                      int(round(lat * 1e7)), int(round(lon * 1e7)), z)
            for seq, (cmd, frame, lat, lon, z) in enumerate(rows)]


def upload(rig, items, seconds=5.0):
    """The ground station's side of the upload: MISSION_COUNT, then answer each MISSION_REQUEST_INT."""
    rig.gcs.send(rig.gcs.mission_count_encode(1, 1, len(items), 0))
    seen = len(rig.gcs_msgs)
    for _ in range(int(seconds / 0.02)):
        rig.run(0.02)
        for m in rig.gcs_msgs[seen:]:
            if getattr(m, "target_system", None) != 255:
                continue
            if m.get_type() == "MISSION_REQUEST_INT":
                rig.gcs.send(items[m.seq])
            elif m.get_type() == "MISSION_ACK":
                return m.type
        seen = len(rig.gcs_msgs)
    return None


def engage(rig, seconds, until_done=False):
    """CG_ENGAGE off and on: an engage request (in flight the daemon engages only when asked anew).
    With `until_done`, stop when the daemon has flown the route (its hand-over to Hold)."""
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 0.0, 9))
    rig.run(0.2)
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9))
    rig.run(0.1)
    rig.run(seconds, until=(lambda r: r.daemon.offboard.state == "done") if until_done else None)


POINTS = [(0.0, 0.0), (12.0, 0.0), (24.0, 4.0)]  # a gentle turn (sharp corners: test_offboard_lockstep.py)


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_daemon_flies_the_uploaded_mission_to_its_last_waypoint(personality):
    rig = Rig(scenario(personality), personality, config=MISSION_CONFIG)
    rig.run(0.5)
    assert upload(rig, mission_items(rig, personality, POINTS, [2.0] * 3)) == mav.MAV_MISSION_ACCEPTED
    t_uploaded = rig.sim.time_s
    engage(rig, 14.0, until_done=True)
    ready = [e for e in rig.log.named("mission") if e["status"] == "ready"]
    assert len(ready) == 1 and ready[0]["t"] > t_uploaded
    route = rig.daemon.offboard.guidance.route
    assert route.waypoints.ravel().tolist() == pytest.approx(np.ravel(POINTS), abs=0.02)  # 1e-7° ≈ 1 cm
    assert route.altitude_m == pytest.approx(2.0, abs=1e-3)
    assert len(ready[0]["notes"]) == 2  # the take-off and the speed change
    assert [e["to"] for e in rig.log.named("offboard")] == ["entering", "flying", "done"]
    truth = rig.truth
    assert not truth["collisions"]
    assert math.hypot(truth["pos"][0] - 24.0, truth["pos"][1] - 4.0) < 1.0  # within E_tr of the end
    assert abs(-truth["pos"][2] - 2.0) < 0.3
    assert max(s["ground_speed"] for s in rig.log.states if s["ground_speed"] == s["ground_speed"]) > 1.0


SQUARE = [(0.0, 0.0), (15.0, 0.0), (15.0, 15.0), (0.0, 15.0)]  # two 90° corners, as a ground station plans them


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_mission_with_right_angle_corners_is_flown_to_the_end(personality):
    """Sharp corners from a ground station, each with a 1.5 m acceptance radius: arcs passing 1.5 m from
    the waypoints, flown without a failsafe or a contract violation to a clean "route complete"."""
    rig = Rig(scenario(personality), personality, config=MISSION_CONFIG)
    rig.run(0.5)
    assert upload(rig, mission_items(rig, personality, SQUARE, [2.0] * 4, accept_m=1.5)) == mav.MAV_MISSION_ACCEPTED
    engage(rig, 25.0, until_done=True)
    route = rig.daemon.offboard.guidance.route
    assert route.arcs[:, 8] == pytest.approx([1.5 / (math.sqrt(2) - 1)] * 2, rel=0.01)
    assert [(e["to"], e["reason"]) for e in rig.log.named("offboard")][-1] == ("done", "route complete")
    for name in ("failsafe", "hold_trigger", "violation_start"):
        assert rig.log.named(name) == [], name
    pos = rig.truth["pos"]
    assert math.hypot(pos[0] - 0.0, pos[1] - 15.0) < 1.0


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_non_level_mission_refuses_to_engage_and_says_why(personality):
    rig = Rig(scenario(personality), personality, config=MISSION_CONFIG)
    rig.run(0.5)
    assert upload(rig, mission_items(rig, personality, POINTS, [2.0, 2.0, 4.0])) == mav.MAV_MISSION_ACCEPTED
    t_uploaded = rig.sim.time_s
    engage(rig, 4.0)
    refused = [e for e in rig.log.named("mission") if e["status"] == "refused" and e["t"] > t_uploaded]
    assert len(refused) == 1 and "level flight" in refused[0]["reason"]
    assert any(t.startswith("CG: refusing to engage") and "level flight" in t for t in rig.daemon_texts())
    assert rig.log.named("offboard") == []  # never entered offboard
    kinds = {m.get_type() for m in rig.daemon_messages()}
    assert "SET_POSITION_TARGET_LOCAL_NED" not in kinds
    assert not any(m.get_type() == "COMMAND_LONG" and m.command == mav.MAV_CMD_DO_SET_MODE
                   for m in rig.daemon_messages())
    assert math.hypot(*rig.truth["pos"][:2]) < 0.5  # still hovering where it was


def test_edited_mission_is_downloaded_again_on_the_next_engage_request():
    rig = Rig(scenario("px4"), "px4", config=MISSION_CONFIG)
    rig.run(0.5)
    upload(rig, mission_items(rig, "px4", POINTS, [2.0] * 3))
    engage(rig, 14.0, until_done=True)
    assert rig.daemon.offboard.state == "done"
    second = [(24.0, 4.0), (30.0, 14.0)]
    assert upload(rig, mission_items(rig, "px4", second, [2.5, 2.5])) == mav.MAV_MISSION_ACCEPTED
    engage(rig, 12.0, until_done=True)
    route = rig.daemon.offboard.guidance.route
    assert route.waypoints.ravel().tolist() == pytest.approx(np.ravel(second), abs=0.02)
    assert route.altitude_m == pytest.approx(2.5, abs=1e-3)
    assert [e["to"] for e in rig.log.named("offboard")] == ["entering", "flying", "done"] * 2
    pos = rig.truth["pos"]
    assert math.hypot(pos[0] - 30.0, pos[1] - 14.0) < 1.0 and abs(-pos[2] - 2.5) < 0.3


def test_example_config_loads():
    cfg = load_config(Path(__file__).resolve().parents[1] / "examples" / "offboard-mission.yaml")
    assert cfg.mode == "offboard" and cfg.route.source == "mission"
