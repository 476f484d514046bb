"""The MAVLink link: pymavlink over UDP, TCP or serial, or an in-memory byte link (lock-step tests),
MAVLink 2, optional signing with a persisted timestamp. I/O only; no decisions here.

The daemon is a MAVLink component of its own (MAV_COMP_ID_ONBOARD_COMPUTER, same system id as the
vehicle). Malformed packets are counted (`bad_packets`) and dropped by pymavlink's robust parser.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import socket
import struct
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


SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)  # Linux: the kernel's drop count on each datagram
RCVBUF_BYTES = 8 << 20  # room for ~100 ms of a 100 000 datagram/s flood between two polls
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)  # as root: past net.core.rmem_max
MAX_CLIENTS = 8  # udpin: other senders (ground stations, routers) heard from and answered
CLIENT_TIMEOUT_S = 10.0  # a client silent this long is forgotten
MAX_DATAGRAMS_PER_READ = 256
READ_BUDGET_S = 0.005  # one recv_msg reads datagrams for at most this long looking for a message
PORT_DATAGRAMS_PER_POLL = 256  # udpin, autopilot pinned: the shared port's datagrams read per poll at most
REPORT_EVERY_S = 10.0  # a refused address is reported at its first datagram, then at most this often
MAX_REPORTED = 64  # refused addresses remembered at most (the first heard of them is forgotten first)
REPORTS_PER_WINDOW = 16  # reports per REPORT_EVERY_S at most, whatever the number of addresses (then counted only)
SEAT_SETTLE_S = 2.0  # a seat without a configured address goes to a claimant heard alone for this long
CONTEST_S = CLIENT_TIMEOUT_S  # an address that claimed a seat this recently still claims it
MAV_MODE_FLAG_SAFETY_ARMED = 128


class UdpLink(mavutil.mavfile):
    """MAVLink over UDP with the parsing a safety daemon needs (pymavlink's `mavudp` keeps one parse buffer
    for every sender, so a partial frame from anyone swallows the next real datagram):

    - each datagram is parsed on its own (the parser's state is reset before it): never joined to another's;
      a datagram that cannot hold a MAVLink frame is dropped unread (`not_mavlink`);
    - `udpout:HOST:PORT` connects the socket, so the kernel delivers only that peer's datagrams and the
      local side is bound to the interface that reaches it;
    - `udpin:HOST:PORT` binds (a second daemon on the port is refused) and gives each *seat* — the autopilot
      (`autopilot` = (system, component) of its HEARTBEAT) and each sensor with ids of its own (`pins`:
      (system, component) → configured address or None) — to one address only. A configured address holds its
      seat for good. Without one, arrival order alone never decides: an address claims the seat (the autopilot
      by its HEARTBEAT, a sensor by any message) and takes it only once it has been the only claimant for
      SEAT_SETTLE_S; until then its messages are dropped unread (`unseated`, not reported: an ordinary start).
      Once held, a seat moves only when its holder has been silent for CLIENT_TIMEOUT_S, and never while the
      seats are held (`hold_seats`: engaged, or the autopilot reports itself armed); the move is reported.
      Every other address claiming a held seat is refused (`foreign_autopilot`, `foreign_source`: dropped) and
      reported (`refusals`, at its first datagram and then at most every REPORT_EVERY_S). Two addresses claiming
      one seat within CONTEST_S of each other make it *contested* (`contested()`: the daemon refuses to engage
      while any seat is), reported when it starts and when it ends. The autopilot's seat, once held, gets a
      second socket connected to its address, so no flood on the port can crowd its datagrams out. Other
      senders of well-formed MAVLink are clients (answered too), at most MAX_CLIENTS, forgotten after
      CLIENT_TIMEOUT_S of silence; new senders beyond that are dropped unread (`refused_sources`). An address is
      no authentication (a forged UDP source address passes): only signing is (docs/link-trust.md). With
      signing on, a signed frame whose signature does not verify under our key is reported at once
      (`bad_signature`: a wrong key, most likely);
    - reading drains the sockets in batches (`recv_msg` returns one message at a time; the daemon bounds
      what it takes per cycle); once the autopilot has its own socket, the shared port (ground stations,
      and whatever a flood sends) is read for at most PORT_DATAGRAMS_PER_POLL datagrams between two
      empty reads (one poll), so a flood on the port costs a bounded, small part of each cycle; the rest
      waits or is dropped by the kernel, which is counted (SO_RXQ_OVFL, `kernel_drops`).
    """

    def __init__(self, url: str, source_system: int, source_component: int, autopilot: tuple[int, int],
                 pins: dict[tuple[int, int], tuple | None] | None = None):
        mode, _, address = url.partition(":")
        host, _, port = address.rpartition(":")
        try:
            self.local = (socket.gethostbyname(host or "0.0.0.0"), int(port))
        except (ValueError, OSError) as err:
            raise ContractError(f"cannot open link {url}: {err}") from None
        self.listening, self.autopilot_ids = mode == "udpin", tuple(autopilot)
        try:
            if self.listening:
                _refuse_a_taken_port(self.local)
                self.sock = _udp_socket(bind=self.local)
            else:
                self.sock = _udp_socket(connect=self.local)
        except OSError as err:
            raise ContractError(f"cannot open link {url}: {err.strerror or err}") from None
        self.ap_sock: socket.socket | None = None  # udpin: connected to the autopilot once it holds its seat
        pins = dict(pins or {})
        pins.setdefault(self.autopilot_ids, None)
        # udpin: (system, component) → the address holding its seat (None: not taken yet)
        self.pinned: dict[tuple[int, int], tuple | None] = dict(pins) if self.listening else {}
        self.fixed = {ids for ids, a in pins.items() if a is not None} if self.listening else set()
        self._seen: dict[tuple[int, int], float] = {}  # seat → when last heard from its holder
        # seat → {address: when last heard} of the other addresses claiming it (candidates or rivals)
        self._claims: dict[tuple[int, int], dict[tuple, float]] = {}
        self._alone: dict[tuple[int, int], tuple[tuple, float]] = {}  # free seat → (sole claimant, since when)
        self._contests_said: dict[tuple[int, int], tuple] = {}  # contested seat → its claimants as last reported
        self.engaged = False  # set by `hold_seats`
        self.armed = False  # the autopilot's last HEARTBEAT from its seat says armed
        self.refusals: list[dict] = []  # what the daemon should say (`take_refusals`)
        self._reported: dict[tuple, list] = {}  # (ids, address, what) → [refused since reported, when reported]
        self._window = [-math.inf, 0]  # [start, reports in it]: at most REPORTS_PER_WINDOW per REPORT_EVERY_S
        self.clients: dict[tuple, float] = {}
        self.stats = {"datagrams": 0, "not_mavlink": 0, "refused_sources": 0, "foreign_autopilot": 0,
                      "foreign_source": 0, "autopilot_moves": 0, "truncated_datagrams": 0, "kernel_drops": 0,
                      "send_errors": 0, "unseated": 0, "bad_signature": 0}
        self._drops: dict[int, int] = {}
        self._queue: list = []
        self._q = 0
        self._port_read = 0  # shared-port datagrams read in this poll (see PORT_DATAGRAMS_PER_POLL)
        mavutil.mavfile.__init__(self, self.sock.fileno(), url, source_system=source_system,
                                 source_component=source_component)
        self.robust_parsing = True
        self.mav.robust_parsing = True
        if self.listening and self.pinned[self.autopilot_ids] is not None:
            self._pin(self.autopilot_ids, self.pinned[self.autopilot_ids], time.monotonic())

    @property
    def autopilot_addr(self) -> tuple | None:
        """The address the autopilot is taken from (udpout: the peer; udpin: its seat's holder, or None)."""
        return self.pinned.get(self.autopilot_ids) if self.listening else self.local

    # ---- seats: who sends from where
    def hold_seats(self, engaged: bool) -> None:
        """The daemon is engaged (or not): while it is, or while the autopilot reports itself armed, no seat
        moves, whatever falls silent."""
        self.engaged = bool(engaged)

    @property
    def seats_held(self) -> str | None:
        """Why no seat may move now (None: they may)."""
        return "engaged" if self.engaged else "armed" if self.armed else None

    def contested(self, now: float | None = None) -> list[dict]:
        """The seats two or more addresses claim (each heard within CONTEST_S): `ids`, `autopilot` (the seat is
        the autopilot's), `seat` (the holder's address, or None: no one holds it) and `claimants` (every
        claiming address, the holder first). The daemon refuses to engage while this is not empty."""
        now = time.monotonic() if now is None else now
        out = []
        for ids, claims in self._claims.items():
            holder = self.pinned.get(ids)
            active = [a for a, last in claims.items() if now - last <= CONTEST_S and a != holder]
            if holder is not None and now - self._seen.get(ids, -math.inf) <= CONTEST_S:
                active.insert(0, holder)
            if len(active) >= 2:
                out.append({"ids": ids, "autopilot": ids == self.autopilot_ids, "seat": _fmt_addr(holder),
                            "claimants": [_fmt_addr(a) for a in active]})
        return out

    def _pin(self, ids: tuple[int, int], addr: tuple, now: float) -> None:
        """Give `ids`'s seat to `addr` from now on; the autopilot on a socket of its own."""
        before = self.pinned.get(ids)
        self.pinned[ids], self._seen[ids] = addr, now
        self._claims.get(ids, {}).pop(addr, None)
        self._alone.pop(ids, None)
        if before is not None and before != addr:
            if ids == self.autopilot_ids:
                self.stats["autopilot_moves"] += 1
            self._report(ids, addr, before, "moved", now)
        if ids != self.autopilot_ids:
            return
        self.armed = False  # until its own HEARTBEAT says so
        if self.ap_sock is not None:
            self.ap_sock.close()
            self.ap_sock = None
        self.clients.pop(addr, None)
        try:
            self.ap_sock = _udp_socket(bind=self.local, connect=addr, reuse=True)
        except OSError:
            self.ap_sock = None  # the shared socket still serves (without the flood protection)

    def _claim(self, ids: tuple[int, int], addr: tuple, now: float) -> None:
        """`addr` claims the seat of `ids` now (at most MAX_REPORTED claimants kept: the longest silent goes)."""
        claims = self._claims.setdefault(ids, {})
        claims[addr] = now
        if len(claims) > MAX_REPORTED:
            del claims[min(claims, key=claims.get)]

    def _refuse(self, ids: tuple[int, int], addr: tuple, now: float) -> None:
        """A held seat's ids from another address: dropped, a rival claim recorded, reported."""
        self.stats["foreign_autopilot" if ids == self.autopilot_ids else "foreign_source"] += 1
        self._claim(ids, addr, now)
        self._report(ids, addr, self.pinned.get(ids), "refused", now)

    def _report(self, ids, addr, pinned, what: str, now: float) -> None:
        """A refusal (or a move) for the daemon to say: the first of each address, then at most every
        REPORT_EVERY_S with the number refused since (`count`); at most MAX_REPORTED addresses remembered and
        REPORTS_PER_WINDOW reports per REPORT_EVERY_S, so that no spoofer can flood the log through it."""
        key = (ids, addr, what)
        rec = self._reported.get(key)
        if rec is None:
            if len(self._reported) >= MAX_REPORTED:
                del self._reported[next(iter(self._reported))]  # the first heard of them: O(1) under a flood
            rec = self._reported[key] = [0, -math.inf]
        rec[0] += 1
        if now - self._window[0] >= REPORT_EVERY_S:
            self._window = [now, 0]
        if now - rec[1] >= REPORT_EVERY_S and self._window[1] < REPORTS_PER_WINDOW:
            self._window[1] += 1
            self.refusals.append({"what": what, "autopilot": ids == self.autopilot_ids, "ids": ids,
                                  "address": _fmt_addr(addr), "pinned": _fmt_addr(pinned),
                                  "count": rec[0], "held": self.seats_held})
            rec[0], rec[1] = 0, now

    def take_refusals(self) -> list[dict]:
        """The refusals, moves and contests to report since the last call (see `_report`): a contest when it
        starts or its claimants change (`contested`, `pinned`: the seat's holder, `address`: every claimant) and
        when it ends (`uncontested`)."""
        now = time.monotonic()
        contests = {c["ids"]: c for c in self.contested(now)}
        for ids, c in contests.items():
            if self._contests_said.get(ids) != tuple(c["claimants"]):
                self._contests_said[ids] = tuple(c["claimants"])
                self.refusals.append({"what": "contested", "autopilot": c["autopilot"], "ids": ids,
                                      "address": ", ".join(c["claimants"]), "pinned": c["seat"],
                                      "count": len(c["claimants"]), "held": self.seats_held})
        for ids in [i for i in self._contests_said if i not in contests]:
            del self._contests_said[ids]
            self.refusals.append({"what": "uncontested", "autopilot": ids == self.autopilot_ids, "ids": ids,
                                  "address": None, "pinned": _fmt_addr(self.pinned.get(ids)), "count": 0,
                                  "held": self.seats_held})
        out, self.refusals = self.refusals, []
        return out

    def _may_move(self, ids: tuple[int, int], now: float) -> bool:
        """Whether a held seat may go to another address: not configured, its holder silent for
        CLIENT_TIMEOUT_S, and the seats not held (engaged or armed)."""
        return ids not in self.fixed and self.seats_held is None \
            and now - self._seen.get(ids, -math.inf) > CLIENT_TIMEOUT_S

    def _accept_from(self, msg, addr: tuple, now: float) -> bool:
        """Whether a message claiming a seat's ids may be taken from `addr` (no seat for its ids: yes)."""
        ids = (msg.get_srcSystem(), msg.get_srcComponent())
        if ids not in self.pinned:
            return True
        holder = self.pinned[ids]
        if addr == holder:
            return True
        # the autopilot claims its seat by its HEARTBEAT (what makes it the autopilot), a sensor by any message
        claims = ids != self.autopilot_ids or msg.get_type() == "HEARTBEAT"
        if holder is not None and not self._may_move(ids, now):
            self._refuse(ids, addr, now)
            return False
        if not claims:
            self.stats["unseated"] += 1  # e.g. the autopilot's telemetry before its HEARTBEAT took the seat
            return False
        self._claim(ids, addr, now)
        active = [a for a, last in self._claims[ids].items() if now - last <= CONTEST_S and a != holder]
        if active != [addr]:
            self._alone.pop(ids, None)  # more than one claimant: no one takes the seat
            self.stats["unseated"] += 1
            return False
        alone = self._alone.get(ids)
        if alone is None or alone[0] != addr:
            alone = self._alone[ids] = (addr, now)
        if now - alone[1] >= SEAT_SETTLE_S:
            self._pin(ids, addr, now)
            return True
        self.stats["unseated"] += 1
        return False

    def _claimed_ids(self, data: bytes) -> tuple[int, int] | None:
        """The first frame's (system, component), read from its header without parsing."""
        at = 5 if data[0] == 0xFD else 3
        return (data[at], data[at + 1]) if len(data) > at + 1 else None

    def _signature_mismatch(self, data: bytes, addr: tuple, now: float) -> None:
        """A datagram whose first frame is signed, and whose signature does not verify under our key (not a
        replay: that one verifies and is old): reported at once, then at most every REPORT_EVERY_S."""
        key = getattr(self.mav.signing, "secret_key", None)
        if key is None or data[0] != 0xFD or len(data) < 10 or not data[2] & 0x01:
            return
        n = 10 + data[1] + 2 + 13
        if len(data) < n or hashlib.sha256(key + bytes(data[:n - 6])).digest()[:6] == bytes(data[n - 6:n]):
            return
        self.stats["bad_signature"] += 1
        ids = self._claimed_ids(data)
        self._report(ids, addr, self.pinned.get(ids), "bad_signature", now)

    def _admit(self, addr: tuple, now: float) -> bool:
        if addr in self.clients:
            return True
        for a, seen in list(self.clients.items()):
            if now - seen > CLIENT_TIMEOUT_S:
                del self.clients[a]
        if len(self.clients) >= MAX_CLIENTS:
            self.stats["refused_sources"] += 1
            return False
        return True

    # ---- reading
    def _parse(self, data: bytes) -> list:
        mav = self.mav
        mav.buf, mav.buf_index, mav.expected_length, mav.have_prefix_error = bytearray(), 0, 8, False
        try:
            msgs = mav.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 — pymavlink raises for some damage even when robust
            msgs = [mavutil.mavlink.MAVLink_bad_data(bytearray(data[:64]), "unparsable datagram")]
        if mav.buf_len():
            self.stats["truncated_datagrams"] += 1  # a frame cut at the datagram's end: dropped, not carried over
        return msgs

    def _recv(self, sock: socket.socket):
        data, anc, _, addr = sock.recvmsg(65535, socket.CMSG_SPACE(4))
        for level, kind, payload in anc:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(payload) >= 4:
                self._drops[sock.fileno()] = struct.unpack("I", payload[:4])[0]
                self.stats["kernel_drops"] = sum(self._drops.values())
        return data, addr

    def _read_batch(self, sock: socket.socket, limit: int = MAX_DATAGRAMS_PER_READ) -> int:
        """Read up to `limit` datagrams from `sock` into the queue; returns how many. Cheap checks first,
        so that a flood costs little."""
        now = time.monotonic()
        for n in range(limit):
            try:
                data, addr = self._recv(sock)
            except (BlockingIOError, InterruptedError):
                return n
            except OSError:  # e.g. ECONNREFUSED after sending to a closed port: nothing to read
                return n
            self.stats["datagrams"] += 1
            if len(data) < 8 or data[0] not in (0xFD, 0xFE):
                self.stats["not_mavlink"] += 1  # MAVLink over UDP: every datagram starts with a frame
                continue
            signing = self.mav.signing.secret_key is not None
            if self.listening:
                ids = self._claimed_ids(data)
                pinned = self.pinned.get(ids, addr)
                if not signing and pinned is not None and pinned != addr and not self._may_move(ids, now):
                    self._refuse(ids, addr, now)  # cheap: a flood claiming the autopilot's ids is not parsed
                    continue  # (signed: a claim counts only once its signature verifies)
                if addr != self.autopilot_addr and not self._admit(addr, now):
                    continue
            valid = False
            for m in self._parse(data):
                if m.get_type() != "BAD_DATA":
                    if self.listening and not self._accept_from(m, addr, now):
                        continue
                    valid = True
                    ids = (m.get_srcSystem(), m.get_srcComponent())
                    if self.listening and ids in self.pinned:
                        self._seen[ids] = now
                        if ids == self.autopilot_ids and m.get_type() == "HEARTBEAT":
                            self.armed = bool(m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
                elif signing and "signature" in str(getattr(m, "reason", "")).lower():
                    self._signature_mismatch(data, addr, now)
                self.post_message(m)
                self._queue.append(m)
            if valid and self.listening and addr != self.autopilot_addr:
                self.clients[addr] = now  # a sender is a client once it has said something well-formed
        return limit

    def _read_port(self) -> int:
        """The shared port's next batch; with the autopilot on its own socket, within this poll's quota."""
        if self.ap_sock is None:
            return self._read_batch(self.sock)
        limit = min(MAX_DATAGRAMS_PER_READ, PORT_DATAGRAMS_PER_POLL - self._port_read)
        got = self._read_batch(self.sock, limit) if limit > 0 else 0
        self._port_read += got
        return got

    def recv_msg(self):
        """The next message: the autopilot's socket first, then the port's, reading until a message comes,
        the sockets are empty (or the port's quota is spent), or READ_BUDGET_S has passed. None ends a
        poll and renews the port's quota."""
        if self._q >= len(self._queue):
            self._queue, self._q = [], 0
            t_end = time.monotonic() + READ_BUDGET_S
            while not self._queue and time.monotonic() < t_end:
                got = self._read_batch(self.ap_sock) if self.ap_sock is not None else 0
                if not self._queue:
                    got += self._read_port()
                if not got:
                    break
            if not self._queue:
                self._port_read = 0
                return None
        m = self._queue[self._q]
        self._q += 1
        return m

    def recv(self, n=None):  # pymavlink's byte interface is not used: recv_msg parses per datagram
        return b""

    # ---- writing
    def write(self, buf) -> None:
        try:
            if not self.listening:
                self.sock.send(buf)
                return
            if self.ap_sock is not None:
                self.ap_sock.send(buf)
            now = time.monotonic()
            for addr in [a for a, seen in self.clients.items() if now - seen <= CLIENT_TIMEOUT_S]:
                self.sock.sendto(buf, addr)
        except OSError:
            self.stats["send_errors"] += 1  # the peer is not there (yet): the link checks will say so

    def close(self) -> None:
        for s in (self.sock, self.ap_sock):
            if s is not None:
                s.close()


def _fmt_addr(addr: tuple | None) -> str | None:
    return None if addr is None else f"{addr[0]}:{addr[1]}"


def _udp_socket(bind: tuple | None = None, connect: tuple | None = None, reuse: bool = False) -> socket.socket:
    """A non-blocking UDP socket with a large receive buffer and the kernel's drop count on each datagram."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        if reuse or bind is not None:  # the listening socket too, so the autopilot's socket may share the port
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RCVBUF_BYTES)
        except OSError:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
        try:
            s.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        except OSError:
            pass
        if bind is not None:
            s.bind(bind)
        if connect is not None:
            s.connect(connect)
        s.setblocking(False)
    except OSError:
        s.close()
        raise
    return s


def _refuse_a_taken_port(local: tuple) -> None:
    """Our sockets share the port only among themselves: a bind without SO_REUSEADDR fails if anyone
    holds it (another contract-guard, or a ground station)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(local)
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                raise OSError(err.errno, "the port is taken (another contract-guard, or a ground station, "
                                         "listens there)") from None
            raise


def open_connection(url: str, baud: int, system: int, component: int, autopilot: tuple[int, int] = (1, 1),
                    pins: dict | None = None):
    """A MAVLink connection for a config URL: `UdpLink` for udpin:/udpout:, pymavlink for tcp: and serial
    (`autopilot`: its system and component ids, which a UDP link accepts from one address only; `pins`: the
    sources taken from one address only, `LinkConfig.pins`)."""
    if url.startswith(("udpin:", "udpout:")):
        return UdpLink(url, system, component, autopilot, pins)
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


MAX_STREAMS = 64  # signed streams (link id, system, component) remembered; the oldest is forgotten first
NEW_STREAM_SLACK = 6000 * 1000  # a new stream may be this far (60 s, in 10 µs) behind our timestamp


class SigningClock:
    """The signing state, persisted so that a board without a real-time clock never goes back in time
    (a receiver rejects timestamps ≤ the last one it saw) and a packet captured before a restart is
    still old after it: our timestamp and every signed stream's last timestamp, as JSON (a file holding
    one number, as older versions wrote, is read as our timestamp)."""

    def __init__(self, path: Path | None, wall=time.time):
        self.path, self.wall = path, wall

    def _read(self) -> dict:
        if self.path is None:
            return {}
        try:
            data = json.loads(read_bounded(self.path, "signing timestamp file", limit=64 * 1024) or b"0")
        except (ContractError, ValueError):
            return {}
        return {"timestamp": data} if isinstance(data, int) else data if isinstance(data, dict) else {}

    def initial(self) -> int:
        now = int((self.wall() - SIGNING_EPOCH) * 1e5)
        saved = self._read().get("timestamp", 0)
        return max(now, int(saved) + 1 if isinstance(saved, int) else now)

    def streams(self) -> dict[tuple[int, int, int], int]:
        out = {}
        for k, ts in (self._read().get("streams") or {}).items():
            try:
                out[tuple(int(x) for x in k.split(":"))] = int(ts)
            except (ValueError, TypeError):
                continue
        return dict(sorted(out.items(), key=lambda kv: kv[1])[-MAX_STREAMS:])

    def save(self, signing) -> None:
        """Persist a pymavlink `MAVLinkSigning` (its timestamp and stream timestamps)."""
        if self.path is None:
            return
        data = {"timestamp": int(signing.timestamp),
                "streams": {":".join(map(str, k)): int(v) for k, v in signing.stream_timestamps.items()}}
        try:
            tmp = self.path.with_suffix(".tmp")
            tmp.write_text(json.dumps(data))
            os.replace(tmp, self.path)
        except OSError:
            pass  # never stops the loop; the next save may succeed


def verified_signature_check(mav, key: bytes):
    """A `check_signature` for a pymavlink MAVLink object that checks the HMAC *before* anything changes
    (pymavlink records a stream's timestamp first, so forged packets could make every real one "old"),
    keeps at most MAX_STREAMS streams, and refuses a new stream more than a minute behind our clock."""
    sig = mav.signing

    def check(msgbuf: bytearray, src_sys: int, src_comp: int) -> bool:
        if hashlib.sha256(key + bytes(msgbuf[:-6])).digest()[:6] != bytes(msgbuf[-6:]):
            return False
        tlow, thigh = struct.unpack("<IH", bytes(msgbuf[-12:-6]))
        ts, stream = tlow + (thigh << 32), (msgbuf[-13], src_sys, src_comp)
        last = sig.stream_timestamps.get(stream)
        if last is not None and ts <= last or last is None and ts + NEW_STREAM_SLACK < sig.timestamp:
            return False  # replayed, or a new stream from the past
        if last is None and len(sig.stream_timestamps) >= MAX_STREAMS:
            del sig.stream_timestamps[min(sig.stream_timestamps, key=sig.stream_timestamps.get)]
        sig.stream_timestamps[stream] = ts
        sig.timestamp = max(sig.timestamp, ts)
        return True

    return check


def setup_signing(conn, key: bytes, clock: SigningClock) -> None:
    """Sign everything we send; accept only correctly signed packets (unsigned RADIO_STATUS excepted),
    checked by `verified_signature_check`, with the streams remembered from before a restart."""
    conn.setup_signing(key, sign_outgoing=True, initial_timestamp=clock.initial(),
                       allow_unsigned_callback=lambda mav, msgid: msgid == mavlink.MAVLINK_MSG_ID_RADIO_STATUS)
    conn.mav.signing.stream_timestamps.update(clock.streams())
    conn.mav.check_signature = verified_signature_check(conn.mav, key)
