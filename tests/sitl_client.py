"""A small pymavlink ground-station client for the SITL tests (lock-step or UDP).

Not a mock: it encodes real MAVLink 2 bytes with pymavlink and parses the vehicle's bytes.
"""

from __future__ import annotations

import math
import os
import time

os.environ["MAVLINK20"] = "1"

from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from sitl_harness import LockstepLink  # noqa: E402

PX4_OFFBOARD = 6 << 16
PX4_HOLD = (4 << 16) | (3 << 24)
PX4_MISSION = (4 << 16) | (4 << 24)
PX4_LAND = (4 << 16) | (6 << 24)
PX4_TAKEOFF = (4 << 16) | (2 << 24)


class Client:
    """Ground station 245/190. `transport` has send(bytes), pump(dt) -> bytes, time()."""

    def __init__(self, transport, sysid: int = 245, compid: int = 190, signing_key: bytes | None = None):
        self.tr = transport
        self.mav = mav.MAVLink(self, srcSystem=sysid, srcComponent=compid)
        self.rx = mav.MAVLink(None)
        self.rx.robust_parsing = True
        if signing_key is not None:
            self.mav.signing.secret_key = signing_key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - 1_420_070_400) * 1e5)
        self.last: dict[str, object] = {}
        self.log: list = []
        self.texts: list[str] = []
        self.vehicle_ms = 0

    def write(self, b) -> None:  # encoder sink
        self.tr.send(bytes(b))

    def pump(self, dt: float) -> list:
        data = self.tr.pump(dt)
        msgs = [m for m in (self.rx.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]
        for m in msgs:
            self.last[m.get_type()] = m
            if hasattr(m, "time_boot_ms"):
                self.vehicle_ms = m.time_boot_ms
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)
        self.log.extend(msgs)
        return msgs

    def now(self) -> float:
        """Simulated time: the lock-step clock, or over UDP the vehicle's time_boot_ms."""
        t = self.tr.time()
        return self.vehicle_ms / 1000.0 if t is None else t

    def wait(self, pred, timeout: float, dt: float = 0.05) -> bool:
        end = self.now() + timeout
        while self.now() < end:
            self.pump(dt)
            if pred(self):
                return True
        return False

    def wait_msg(self, kind: str, timeout: float, cond=lambda m: True):
        end = self.now() + timeout
        while self.now() < end:
            for m in self.pump(0.02):
                if m.get_type() == kind and cond(m):
                    return m
        return None

    def command(self, cmd: int, *params: float, timeout: float = 2.0):
        """COMMAND_LONG and its COMMAND_ACK; over a lossy link (the transport's `command_tries` > 1: UDP on a
        loaded machine) re-sent with confirmation 1, 2, … when no answer comes in `timeout`, as the MAVLink
        command protocol does. The lock-step link loses nothing: one try."""
        p = list(params) + [0.0] * (7 - len(params))
        for confirmation in range(getattr(self.tr, "command_tries", 1)):
            self.mav.command_long_send(1, 1, cmd, confirmation, *p)
            ack = self.wait_msg("COMMAND_ACK", timeout, lambda m: m.command == cmd)
            if ack is not None:
                return ack.result
        return None

    # --- conveniences
    @property
    def pos(self):
        m = self.last["LOCAL_POSITION_NED"]
        return (m.x, m.y, m.z)

    @property
    def speed_xy(self) -> float:
        m = self.last["LOCAL_POSITION_NED"]
        return math.hypot(m.vx, m.vy)

    @property
    def custom_mode(self) -> int:
        return self.last["HEARTBEAT"].custom_mode

    @property
    def armed(self) -> bool:
        return bool(self.last["HEARTBEAT"].base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)

    def set_mode(self, main_or_custom: int, sub: float = 0.0):
        return self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main_or_custom, sub)

    def param(self, name: str, timeout: float = 1.0):
        self.mav.param_request_read_send(1, 1, name.encode(), -1)
        return self.wait_msg("PARAM_VALUE", timeout, lambda m: m.param_id == name)

    def param_set(self, name: str, wire_value: float, ptype: int, timeout: float = 1.0):
        self.mav.param_set_send(1, 1, name.encode(), wire_value, ptype)
        return self.wait_msg("PARAM_VALUE", timeout, lambda m: m.param_id == name)

    def position_target(self, mask: int, pos=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0), acc=(0.0, 0.0, 0.0),
                        yaw: float = 0.0, yaw_rate: float = 0.0, frame: int = mav.MAV_FRAME_LOCAL_NED) -> None:
        self.mav.set_position_target_local_ned_send(int(self.now() * 1000), 1, 1, frame, mask, *pos, *vel, *acc,
                                                    yaw, yaw_rate)

    def upload_mission(self, items: list[tuple], timeout: float = 5.0) -> int:
        """items: (frame, command, p1, p2, p3, p4, x_int, y_int, z). Returns MISSION_ACK type."""
        self.mav.mission_count_send(1, 1, len(items))
        end = self.now() + timeout
        while self.now() < end:
            for m in self.pump(0.02):
                if m.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
                    it = items[m.seq]
                    self.mav.mission_item_int_send(1, 1, m.seq, it[0], it[1], int(m.seq == 0), 1, *it[2:6],
                                                   it[6], it[7], it[8])
                elif m.get_type() == "MISSION_ACK":
                    return m.type
        return -1


class LockstepTransport:
    def __init__(self, sim):
        self.link = LockstepLink(sim)
        self.sim = sim

    def send(self, data: bytes) -> None:
        self.link.client_send(data)

    def pump(self, dt: float) -> bytes:
        self.link.step(dt)
        return self.link.client_recv()

    def time(self) -> float:
        return self.sim.time_s


class UdpTransport:
    command_tries = 3  # UDP may drop a datagram on a loaded machine

    """Real loopback UDP to a SITL process (`python -m sitl_harness --listen udp:HOST:PORT`)."""

    def __init__(self, port: int, speedup: float = 1.0, host: str = "127.0.0.1"):
        import socket

        self.addr = (host, port)
        self.speedup = speedup
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, 0))
        self.sock.settimeout(0.005)

    def send(self, data: bytes) -> None:
        self.sock.sendto(data, self.addr)

    def pump(self, dt: float) -> bytes:
        """Collect what arrives during `dt` simulated seconds (dt / speedup of wall time)."""
        import socket

        end = time.monotonic() + dt / self.speedup
        chunks = []
        while True:
            try:
                chunks.append(self.sock.recv(65535))
            except socket.timeout:
                pass
            if time.monotonic() >= end:
                return b"".join(chunks)

    def time(self):
        return None

    def close(self) -> None:
        self.sock.close()


def lockstep_client(sim, **kw) -> Client:
    c = Client(LockstepTransport(sim), **kw)
    c.pump(0.5)
    return c


def geo_item(home, x: float, y: float, alt_rel: float, command=mav.MAV_CMD_NAV_WAYPOINT, p1=0.0, p2=0.0):
    """A mission item `x` m north and `y` m east of the HOME_POSITION message `home` (flat earth)."""
    lat0, lon0 = home.latitude * 1e-7, home.longitude * 1e-7
    lat = lat0 + math.degrees(x / 6378137.0)
    lon = lon0 + math.degrees(y / (6378137.0 * math.cos(math.radians(lat0))))
    return (mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, p1, p2, 0.0, math.nan, int(round(lat * 1e7)),
            int(round(lon * 1e7)), alt_rel)
