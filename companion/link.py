"""The MAVLink link: pymavlink over UDP, TCP or serial, or an in-memory byte link (lock-step tests),
MAVLink 2, optional signing with a persisted timestamp. I/O only; no decisions here.

The daemon is a MAVLink component of its own (MAV_COMP_ID_ONBOARD_COMPUTER, same system id as the
vehicle). Malformed packets are counted (`bad_packets`) and dropped by pymavlink's robust parser.
"""

from __future__ import annotations

import errno
import os
import socket
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from contracts.errors import ContractError  # noqa: E402
from contracts.yamlfile import read_bounded  # noqa: E402

mavlink = mavutil.mavlink
SIGNING_EPOCH = 1420070400  # 2015-01-01, MAVLink 2 signing timestamps count 10 µs from here


class MemoryMavfile(mavutil.mavfile):
    """A pymavlink connection over an in-memory byte link (e.g. the SITL's lock-step link):
    `read()` returns the bytes waiting for us, `write(buf)` hands bytes to the other side."""

    def __init__(self, read, write, source_system=1, source_component=191):
        self._read, self._write = read, write
        self._pending = b""
        mavutil.mavfile.__init__(self, None, "memory", source_system=source_system, source_component=source_component)
        self.robust_parsing = True

    def recv(self, n=None):
        if not self._pending:
            self._pending = self._read() or b""
        data, self._pending = self._pending, b""
        return data

    def write(self, buf):
        self._write(bytes(buf))

    def close(self):
        pass


def _refuse_a_taken_port(url: str) -> None:
    """pymavlink binds udpin with SO_REUSEADDR, so a second daemon on the same port would bind too and
    share (or steal) the autopilot's datagrams: refuse when the port is taken."""
    host, _, port = url.removeprefix("udpin:").rpartition(":")
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((host or "0.0.0.0", int(port)))
    except OSError as err:
        if err.errno == errno.EADDRINUSE:
            raise ContractError(f"cannot open link {url}: the port is taken (another contract-guard, "
                                "or a ground station, listens there)") from None
    except ValueError:
        pass  # a malformed URL: pymavlink says so


def open_connection(url: str, baud: int, system: int, component: int):
    """A pymavlink connection for a config URL (udpin:, udpout:, tcp:, serial device path)."""
    if url.startswith("udpin:"):
        _refuse_a_taken_port(url)
    try:
        conn = mavutil.mavlink_connection(url, baud=baud, source_system=system, source_component=component,
                                          autoreconnect=True, dialect="ardupilotmega")
    except Exception as err:  # pymavlink raises many kinds for a bad URL or a missing device
        raise ContractError(f"cannot open link {url}: {err}") from None
    conn.robust_parsing = True
    return conn


def load_signing_key(path: Path) -> bytes:
    """32-byte key, raw or 64 hex characters; the file must not be readable by others."""
    try:
        st = path.stat()
    except OSError as err:
        raise ContractError(f"signing key {path}: cannot read ({err.strerror or err})") from None
    raw = read_bounded(path, "signing key", limit=256).strip()
    if st.st_mode & 0o077:
        raise ContractError(f"signing key {path}: readable by group or others (chmod 600)")
    if len(raw) == 64:
        try:
            raw = bytes.fromhex(raw.decode())
        except ValueError:
            raise ContractError(f"signing key {path}: not 32 bytes or 64 hex characters") from None
    if len(raw) != 32:
        raise ContractError(f"signing key {path}: not 32 bytes or 64 hex characters")
    return raw


class SigningClock:
    """The signing timestamp, persisted so that a board without a real-time clock never goes back in time
    (a receiver rejects timestamps ≤ the last one it saw)."""

    def __init__(self, path: Path | None, wall=time.time):
        self.path, self.wall = path, wall

    def initial(self) -> int:
        now = int((self.wall() - SIGNING_EPOCH) * 1e5)
        saved = 0
        if self.path is not None:
            try:
                saved = int(self.path.read_text().strip() or 0)
            except (OSError, ValueError):
                saved = 0
        return max(now, saved + 1)

    def save(self, timestamp: int) -> None:
        if self.path is None:
            return
        try:
            tmp = self.path.with_suffix(".tmp")
            tmp.write_text(str(int(timestamp)))
            os.replace(tmp, self.path)
        except OSError:
            pass  # never stops the loop; the next save may succeed


def setup_signing(conn, key: bytes, clock: SigningClock) -> None:
    """Sign everything we send; accept only correctly signed packets (unsigned RADIO_STATUS excepted)."""
    conn.setup_signing(key, sign_outgoing=True, initial_timestamp=clock.initial(),
                       allow_unsigned_callback=lambda mav, msgid: msgid == mavlink.MAVLINK_MSG_ID_RADIO_STATUS)
