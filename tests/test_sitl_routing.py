"""The SITL routes MAVLink between its UDP clients like an autopilot: routes learnt from sources,
broadcasts to the others, addressed messages only where the target was seen, nothing back."""

import math
import time

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_client import lockstep_client
from sitl_harness import Sim
from sitl_harness.serve import Router
from sitl_process import sitl_process

GCS, CC = (255, 190), (1, 191)  # ground station; companion computer (MAV_COMP_ID_ONBOARD_COMPUTER)


def msg(src, encode, *args):
    """A decoded message from `src` = (sysid, compid), as the vehicle's parser yields it."""
    enc = mav.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    return mav.MAVLink(None).parse_buffer(getattr(enc, encode + "_encode")(*args).pack(enc))[0]


def hb(src):
    return msg(src, "heartbeat", mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)


def test_router_rules():
    r = Router(1, 1)
    clients = ["a", "b", "c"]
    r.learn("a", hb(GCS))
    r.learn("b", hb(CC))
    r.learn("c", hb((1, 1)))  # never a route to the vehicle itself
    r.learn("c", hb((5, 0)))  # nor to component 0
    assert r.routes == {GCS: "a", CC: "b"}
    assert r.destinations("b", hb(CC), clients) == ["a", "c"]  # broadcast: everyone else
    to_cc = msg(GCS, "param_set", 1, 191, b"CG_R_OBST", 0.6, 9)
    assert r.destinations("a", to_cc, clients) == ["b"]
    assert r.destinations("b", to_cc, clients) == []  # never back to the sender
    assert r.destinations("a", to_cc, ["a", "c"]) == []  # b no longer live
    assert r.destinations("a", msg(GCS, "param_set", 1, 1, b"MPC_XY_CRUISE", 2.0, 9), clients) == []
    assert r.destinations("a", msg(GCS, "param_request_list", 1, 0), clients) == ["b"]  # system 1's components
    assert r.destinations("a", msg(GCS, "param_request_list", 7, 1), clients) == []  # unknown
    assert r.destinations("a", msg(GCS, "param_request_list", 0, 0), clients) == ["b", "c"]


def test_vehicle_ignores_a_message_for_another_component():
    sim = Sim("empty", "px4")
    c = lockstep_client(sim)
    c.mav.param_set_send(1, 191, b"CG_R_OBST", 0.6, 9)
    c.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, 9)
    c.pump(0.5)
    assert c.texts == ["Unknown parameter NO_SUCH_PARAM"]
    assert not [m for m in c.log if m.get_type() == "PARAM_VALUE"]
    assert sim.endpoint.stats["rx_not_for_us"] == 1


def recv(conn, kind, src, timeout=5.0, cond=lambda m: True, seen=None):
    deadline = time.time() + timeout
    while time.time() < deadline:
        m = conn.recv_match(blocking=True, timeout=0.2)
        if m is not None and seen is not None:
            seen.append(m.get_type())
        if m is not None and m.get_type() == kind and (m.get_srcSystem(), m.get_srcComponent()) == src and cond(m):
            return m
    return None


def test_two_udp_clients_see_each_other_through_the_sitl():
    with sitl_process("empty", "px4", 2.0) as port:
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=GCS[0], source_component=GCS[1])
        cc = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=CC[0], source_component=CC[1])
        try:
            cc.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            assert recv(gcs, "HEARTBEAT", (1, 1)) and recv(cc, "HEARTBEAT", (1, 1))  # both are clients now
            cc.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            assert recv(gcs, "HEARTBEAT", CC), "the companion's HEARTBEAT reaches the ground station"
            gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            assert recv(cc, "HEARTBEAT", GCS)
            gcs.mav.command_long_send(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
            assert recv(gcs, "COMMAND_ACK", (1, 1)), "the vehicle answered the command"
            gcs.mav.param_set_send(1, 191, b"CG_R_OBST", 0.6, 9)
            seen = []
            m = recv(cc, "PARAM_SET", GCS, seen=seen)
            assert m and m.param_id == "CG_R_OBST" and math.isclose(m.param_value, 0.6, rel_tol=1e-6)
            assert "COMMAND_LONG" not in seen, "a command for the vehicle is not forwarded"
            cc.mav.param_value_send(b"CG_R_OBST", 0.6, 9, 3, 2)
            assert recv(gcs, "PARAM_VALUE", CC, cond=lambda m: m.param_id == "CG_R_OBST")
        finally:
            gcs.close()
            cc.close()
