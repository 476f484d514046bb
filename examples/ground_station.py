#!/usr/bin/env python3
"""A scripted ground station for the SITL recipe (docs/sitl.md) and the vehicle walk-through
(docs/vehicle-file.md): what you would do in MAVProxy or QGroundControl, over UDP with pymavlink.

    python examples/ground_station.py --connect udpout:127.0.0.1:14540 --takeoff-m 2.5 --seconds 40

It says hello (HEARTBEAT) until the autopilot (1:1) answers, waits for the daemon (1:191), then: arm,
take off, Mission (PX4) / Auto (ArduPilot), `CG_ENGAGE 1` on the daemon's component, and prints what it
hears for `--seconds`: the daemon's STATUSTEXTs, mode changes and the speed the vehicle flies. One line
per thing; exit status 0 when every step was acknowledged, 1 otherwise. Needs only pymavlink.

With `--signing-key FILE` (the key `contract-guard keys` made: 32 bytes, or 64 hex characters) it signs what
it sends and takes only messages signed with that key (MAVLink 2 signing, docs/signing.md); a message whose
signature does not verify is said once per sender ("signature mismatch ...: wrong key?").
"""

from __future__ import annotations

import argparse
import math
import os
import struct
import sys
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

mav = mavutil.mavlink
MODES = {"px4": {"mission": (4, 4)}, "ardupilot": {"mission": (3, 0)}}  # PX4 main/sub, Copter AUTO = 3


def say(text: str) -> None:
    print(f"gcs: {text}", flush=True)


SIGNING_EPOCH = 1420070400  # 2015-01-01: MAVLink 2 signing timestamps count 10 µs from here


def read_key(path: str) -> bytes:
    """A signing key file: 32 raw bytes or 64 hex characters (what `contract-guard keys` writes)."""
    try:
        raw = open(path, "rb").read(256).strip()
    except OSError as err:
        raise SystemExit(f"gcs: signing key {path}: {err.strerror or err}") from None
    if len(raw) == 64:
        try:
            raw = bytes.fromhex(raw.decode())
        except ValueError:
            raw = b""
    if len(raw) != 32:
        raise SystemExit(f"gcs: signing key {path}: not 32 bytes or 64 hex characters")
    return raw


class Station:
    def __init__(self, url: str, sysid: int = 255, tlog: str | None = None, key: bytes | None = None):
        self.m = mavutil.mavlink_connection(url, source_system=sysid, source_component=mav.MAV_COMP_ID_MISSIONPLANNER)
        if key is not None:  # sign everything sent; take only what is signed with the same key
            self.m.setup_signing(key, sign_outgoing=True,
                                 initial_timestamp=int((time.time() - SIGNING_EPOCH) * 1e5))
        self.mismatch: set[tuple[int, int]] = set()  # senders whose signature did not verify (said once each)
        # what it receives, stamped on arrival (8-byte big-endian µs, then the packet), as MAVProxy's and
        # QGC's telemetry logs are
        self.tlog = open(tlog, "wb") if tlog else None  # noqa: SIM115 (closed at the end of main)
        self.last: dict[str, object] = {}
        self.seen: set[tuple[int, int]] = set()
        self.t_hb = 0.0
        self.mode = None
        self.v_max_seen = 0.0

    def poll(self, dt: float, want=None):
        """Read for `dt` s (heartbeat at 1 Hz); the first message `want(m)` accepts, or None."""
        end = time.time() + dt
        while time.time() < end:
            if time.time() - self.t_hb > 1.0:
                self.m.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self.t_hb = time.time()
            msg = self.m.recv_match(blocking=True, timeout=0.05)
            if msg is not None and msg.get_type() == "BAD_DATA":
                self._bad(msg)
                continue
            if msg is None:
                continue
            self._take(msg)
            if want is not None and want(msg):
                return msg
        return None

    def _bad(self, msg) -> None:
        """A frame refused for its signature: said once per sender (its ids from the frame's header)."""
        data = bytes(msg.data)
        if "signature" not in str(getattr(msg, "reason", "")).lower() or len(data) < 7 or data[0] != 0xFD:
            return
        src = (data[5], data[6])
        if src not in self.mismatch:
            self.mismatch.add(src)
            say(f"signature mismatch from {src[0]}:{src[1]}: wrong key?" if data[2] & 1 else
                f"unsigned messages from {src[0]}:{src[1]} refused (signing is on here)")

    def _take(self, msg) -> None:
        if self.tlog is not None:
            self.tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + msg.get_msgbuf())
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        kind = msg.get_type()
        self.last[kind] = msg
        if kind == "HEARTBEAT":
            if src not in self.seen:
                self.seen.add(src)
                say(f"heard {src[0]}:{src[1]}")
            if src == (1, 1) and msg.custom_mode != self.mode:
                self.mode = msg.custom_mode
        elif kind == "STATUSTEXT":
            say(f"{src[0]}:{src[1]} says: {msg.text}")
        elif kind == "LOCAL_POSITION_NED":
            self.v_max_seen = max(self.v_max_seen, math.hypot(msg.vx, msg.vy))

    def command(self, cmd: int, *p: float, target=(1, 1), tries: int = 3):
        p = list(p) + [0.0] * (7 - len(p))
        for confirmation in range(tries):
            self.m.mav.command_long_send(target[0], target[1], cmd, confirmation, *p)
            ack = self.poll(2.0, lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd)
            if ack is not None:
                return ack.result
        return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="ground_station.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", default="udpout:127.0.0.1:14540", help="the SITL's (or router's) UDP port")
    ap.add_argument("--autopilot", choices=list(MODES), default="px4")
    ap.add_argument("--takeoff-m", type=float, default=2.5, help="take-off altitude above home [m] (PX4: at least its MIS_TAKEOFF_ALT 2.5 m)")
    ap.add_argument("--seconds", type=float, default=40.0, help="listen this long after engaging")
    ap.add_argument("--no-engage", action="store_true", help="leave CG_ENGAGE alone")
    ap.add_argument("--tlog", help="write what this ground station receives to a .tlog (as MAVProxy does)")
    ap.add_argument("--wait-s", type=float, default=60.0, help="give up when the vehicle or daemon stays silent")
    ap.add_argument("--signing-key", metavar="FILE", help="sign with this MAVLink 2 key (32 bytes or 64 hex "
                    "characters, as `contract-guard keys` writes it) and take only messages signed with it")
    a = ap.parse_args(argv)
    s = Station(a.connect, tlog=a.tlog, key=read_key(a.signing_key) if a.signing_key else None)
    say(f"connecting to {a.connect}{' (signed)' if a.signing_key else ''}")
    if s.poll(a.wait_s, lambda m: m.get_type() == "HEARTBEAT" and (m.get_srcSystem(), m.get_srcComponent()) == (1, 1)) is None:
        say("no autopilot heartbeat (is the SITL listening on that port?)")
        return 1
    if not a.no_engage and (1, 191) not in s.seen and s.poll(a.wait_s, lambda m: m.get_type() == "HEARTBEAT"
                                                             and m.get_srcComponent() == 191) is None:
        say("no daemon heartbeat from 1:191 (is contract-guard run connected to the same port?)")
        return 1
    ok = True
    r = s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    say(f"arm: {'accepted' if r == mav.MAV_RESULT_ACCEPTED else r}")
    ok &= r == mav.MAV_RESULT_ACCEPTED
    r = s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, a.takeoff_m)
    say(f"take-off to {a.takeoff_m:g} m: {'accepted' if r == mav.MAV_RESULT_ACCEPTED else r}")
    ok &= r == mav.MAV_RESULT_ACCEPTED
    up = s.poll(a.wait_s, lambda m: m.get_type() == "LOCAL_POSITION_NED" and -m.z > 0.8 * a.takeoff_m)
    say(f"at {-up.z:.1f} m" if up is not None else "never reached the take-off altitude")
    ok &= up is not None
    main_mode, sub = MODES[a.autopilot]["mission"]
    r = s.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main_mode, sub)
    say(f"mode mission: {'accepted' if r == mav.MAV_RESULT_ACCEPTED else r}")
    ok &= r == mav.MAV_RESULT_ACCEPTED
    if not a.no_engage:
        for _ in range(5):
            s.m.mav.param_set_send(1, 191, b"CG_ENGAGE", 1.0, mav.MAV_PARAM_TYPE_REAL32)
            echo = s.poll(1.0, lambda m: m.get_type() == "PARAM_VALUE" and m.get_srcComponent() == 191
                          and m.param_id == "CG_ENGAGE")
            if echo is not None:
                break
        say(f"param set CG_ENGAGE 1: {'echoed ' + format(echo.param_value, 'g') if echo is not None else 'no answer'}")
        ok &= echo is not None and echo.param_value == 1.0
    s.poll(a.seconds)
    say(f"done: fastest ground speed {s.v_max_seen:.2f} m/s{'' if ok else ' (a step failed)'}")
    if s.tlog is not None:
        s.tlog.close()
    s.m.close()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
