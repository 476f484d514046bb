"""A raw MAVLink `.tlog` turned into an event log: `replay_tlog(path, log_dir)` replays it through a Γ table.

The packets go, in log time, to a shadow-mode `Daemon` over an in-memory link (what it sends is
discarded), stepped at its loop rate with no sleeping; it writes its event log into `log_dir`, which
`companion.ground.review` reads like any other (`contract-guard review FLIGHT.tlog`: `companion.cli` wires the
two). The returned `Replay` (a `review.Origin`) becomes the report's `replay` section: what the tlog held,
lacked or spoiled, and its findings. Every packet in the tlog is fed — the autopilot's stream and
anything else (a ground station's, or our daemon's own outgoing packets when a router or MAVProxy
logged both directions); the daemon keeps what it would have kept in flight. The in-flight daemon's
`NAMED_VALUE_FLOAT` values, when present, are compared with the replay, aligned in time and over the part
of the flight in which it was engaged (`in_flight`); a real difference is one finding saying which value,
where, and what it points at.

Log time is the tlog's stamp relative to the first good packet; an earlier stamp by ≤ 1 s is taken
as reordering, a larger step back or a silence longer than `MAX_GAP_US` as a clock jump (closed up,
listed). Corrupt packets are counted and skipped (the reader resynchronises on the next packet with a
valid CRC); a torn last packet is reported.
"""

from __future__ import annotations

import bisect
import math
import operator
import re
import struct
from array import array
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from companion.onboard.autopilots import adapter_for, name_for_heartbeat
from companion.onboard.config import Config, SensorConfig, load_config
from companion.onboard.eventlog import EventLog, finite_copy, read_events
from companion.onboard.link import MemoryMavfile, mavlink
from companion.onboard.logschema import COMMANDS, LOG_FILE, NVF
from companion.onboard.mavlink_in import sensor_orientation
from contracts.errors import ContractError

from ..review import Origin, fmt_value
from .bounds import MAX_SAMPLES, gc_frozen, gc_paused
from .flightspan import Watch, facing, flight_end, gaps_finding, not_forward_lines
from .loginput import Feed, not_multirotor, order

MAGIC = re.compile(b"[\xfd\xfe]")
MAX_BACKSTEP_US = 1_000_000  # an earlier stamp by up to this is reordering (clamped); more is a clock jump
MAX_GAP_US = 300_000_000  # a longer silence is taken as a clock jump and closed up
MAX_STAMP_US = (1 << 63) - 1  # the largest stamp a time can be (int64 µs)
RESYNC_WINDOW_US = 86_400_000_000  # a packet found by resynchronising must lie within a day of the last good one
TICK_SLACK_US = 5  # stamps written as int(float seconds · 1e6) may fall a few µs past a loop tick
# a silence in a log is stepped through for the daemon's longest staleness time-out plus this (it goes stale
# and fails safe as it would have in flight), then skipped; never longer than SILENCE_MAX_S
SILENCE_MARGIN_S, SILENCE_MAX_S = 2.0, 30.0
NOT_AUTOPILOT = (mavlink.MAV_AUTOPILOT_INVALID,)
# without the flight's config: the sensors assumed, said in the report's notes
ASSUMED_SENSORS = (SensorConfig(kind="distance_sensor", h_fov_deg=30.0),)
ASSUMED_NOTE = ("no --config: sensors assumed to be one forward DISTANCE_SENSOR with a 30° field of view, "
                "its claimed range taken as rated (give the flight's config for its sensors and ratings)")
IN_FLIGHT = {name: f for name, (f, _, _) in NVF.items() if f}  # the daemon's NAMED_VALUE_FLOATs → state field
# its COMMAND_LONGs counted: the speed limit and the mode (a hold or an offboard entry, alike on the wire)
DAEMON_COMMANDS = {getattr(mavlink, COMMANDS["change_speed"]): "change_speed", getattr(mavlink, COMMANDS["hold"]): "set_mode"}
LISTED = 100


@dataclass
class Scan:
    """The good packets of a tlog (where they are, their log time) and what the reader saw."""

    size: int = 0
    offset: array = field(default_factory=lambda: array("q"))  # of the packet's 8-byte stamp
    length: array = field(default_factory=lambda: array("l"))  # MAVLink frame bytes after the stamp
    t_us: array = field(default_factory=lambda: array("q"))  # log time [µs] from the first good packet
    raw_us: array = field(default_factory=lambda: array("q"))  # the stamp as written (UNIX µs)
    common: array = field(default_factory=lambda: array("l"))  # the message id of a frame of the common kind
    # (`_plain_frame`: checked), else -1
    corrupt: int = 0  # stretches of bad bytes skipped (each counted once)
    skipped_bytes: int = 0
    truncated_tail: bool = False
    bad_stamps: int = 0  # stamps too large to be a time (taken as the previous one)
    capped: bool = False  # more than MAX_SAMPLES packets: the rest not read
    unknown: int = 0  # valid frames of messages this dialect does not know (skipped)
    counts: Counter = field(default_factory=Counter)  # (sys, comp, type) → packets
    spans: dict = field(default_factory=dict)  # (sys, comp, type) → [first, last] log time [µs]
    heartbeats: dict = field(default_factory=dict)  # (sys, comp) → (MAV_TYPE, MAV_AUTOPILOT)
    time_jumps: list = field(default_factory=list)
    in_flight: list = field(default_factory=list)  # (t_us, sys, comp, name, value): our daemon's values
    texts: list = field(default_factory=list)  # (t_us, sys, comp, text): "CG: …" status texts
    commands: list = field(default_factory=list)  # (t_us, sys, comp, name, param1, param2)

    @property
    def packets(self) -> int:
        return len(self.offset)

    def rate_hz(self, src: tuple[int, int] | int, kind: str) -> float:
        """Mean rate of one message type while it was being sent, from a source (sys, comp) or from any
        component of a system (int)."""
        keys = [key for key in self.counts
                if key[2] == kind and (key[:2] == src if isinstance(src, tuple) else key[0] == src)]
        if not keys:
            return 0.0
        n = sum(self.counts[key] for key in keys)
        span = (max(self.spans[key][1] for key in keys) - min(self.spans[key][0] for key in keys)) / 1e6
        return (n - 1) / span if span > 0 else 0.0


def _frame_len(data: bytes, pos: int) -> int | None:
    """Bytes of the MAVLink frame after the stamp at `pos`: None if none starts there, -1 if the file ends first."""
    if len(data) - pos < 11:
        return -1
    magic = data[pos + 8]
    if magic == 0xFE:
        return 8 + data[pos + 9]
    if magic == 0xFD and not data[pos + 10] & ~1:  # incompat_flags: only MAVLINK_IFLAG_SIGNED exists
        return 12 + data[pos + 9] + (13 if data[pos + 10] & 1 else 0)
    return None


def _decode(data: bytes, pos: int, parser):
    """(status, frame length, message) for the packet at `pos`; status "ok", "bad" or "short"."""
    plain = _plain_v2(data, pos + 8, parser)
    if plain is not None:
        return "ok", plain[0], plain[1]
    n = _frame_len(data, pos)
    if n is None:
        return "bad", None, None
    if n < 0 or pos + 8 + n > len(data):
        return "short", n, None
    try:
        return "ok", n, parser.decode(bytearray(data[pos + 8:pos + 8 + n]))
    except Exception:  # noqa: BLE001 — pymavlink raises MAVError, struct.error, …: a bad packet either way
        return "bad", n, None


_V2_HEADER = struct.Struct("<BBBBBBBHB")  # pymavlink's MAVLink 2 header (magic as a number)
_PLAIN: dict = {}  # message class → what `_plain_message` / `_message` decode it with (`_plain_for`)
mcrf4xx = getattr(mavlink, "mcrf4xx", None)  # pymavlink's CRC (fastcrc's), when it has it


class _Plain(NamedTuple):
    """`MAVLink.decode`'s per-message steps for one message class, made once (`_plain_for`)."""

    crc_extra: bytes  # CRC_EXTRA as one byte
    unpacker: struct.Struct
    size: int  # the unpacker's: a MAVLink 2 payload cut short by its trailing zeros is padded to it
    pick: Callable  # the unpacked tuple → the fields in the class's order (an array a list)
    strings: bool  # has char arrays (their trailing NULs stripped)
    light: type | None  # its `Light` class, for a kind in LIGHT
    arrays: bool


def _plain_for(cls) -> _Plain:
    """The `_Plain` of a message class, made at its first frame."""
    plain = _PLAIN.get(cls)
    if plain is not None:
        return plain
    lengths, orders = cls.lengths, cls.orders
    arrays = sum(lengths) != len(lengths)
    if not arrays:  # the fields are single items of the tuple
        pick = (lambda t, k=orders[0]: [t[k]]) if len(orders) == 1 else operator.itemgetter(*orders)
    else:  # arrays: each a list, a char array a string
        at = [sum(lengths[:k]) for k in range(len(lengths))]

        def pick(t):
            return [t[at[k]] if lengths[k] == 1 or isinstance(t[at[k]], bytes) else list(t[at[k]:at[k] + lengths[k]])
                    for k in orders]
    light = None
    if cls.msgname in LIGHT:  # its fields by name: where pymavlink's unpacked tuple has them (no arrays), else `pick`'s
        names = cls.fieldnames if arrays else cls.ordered_fieldnames
        light = type(f"Light_{cls.msgname}", (Light,), {"__slots__": (), "msgname": cls.msgname, "id": cls.id}
                     | {f: property(operator.itemgetter(k)) for k, f in enumerate(names)})
    plain = _PLAIN[cls] = _Plain(bytes((cls.crc_extra,)), cls.unpacker, cls.unpacker.size, pick,
                                 "s" in cls.unpacker.format, light, arrays)
    return plain


def _unpacked(data: bytes, at: int, end: int, plain: _Plain) -> tuple:
    """The payload of the frame [at, end) as `plain.unpacker` unpacks it (MAVLink 2's trailing zeros put back)."""
    mlen, size = data[at + 1], plain.size
    return plain.unpacker.unpack_from(data, at + 10) if mlen >= size else \
        plain.unpacker.unpack(data[at + 10:end - 2] + bytes(size - mlen))


def _plain_frame(data: bytes, at: int, parser, crc: bool = True):
    """(frame length, message class, its `_Plain`, the header's fields) of the frame starting at `at` in `data`
    when it is the common kind: MAVLink 2, unsigned, of a known message, whole, its CRC right; None for any other
    (pymavlink decodes those, and raises for the bad). The frame is checked, not decoded: the scan needs only
    this of most frames. `crc=False`: a frame the scan has checked (its CRC is not computed again)."""
    if mcrf4xx is None or len(data) - at < 12 or data[at] != 0xFD or data[at + 2] \
            or parser.signing.secret_key is not None:
        return None
    header = _V2_HEADER.unpack_from(data, at)
    mlen = header[1]
    end = at + 12 + mlen
    cls = mavlink.mavlink_map.get(header[7] | header[8] << 16)
    if cls is None or end > len(data) or mavlink.MAVLINK_IGNORE_CRC:
        return None
    plain = _plain_for(cls)
    if crc and mcrf4xx(plain.crc_extra, mcrf4xx(data[at + 1:end - 2], 0xFFFF)) != data[end - 2] | data[end - 1] << 8:
        return None  # pymavlink raises "invalid MAVLink CRC"
    return 12 + mlen, cls, plain, header


def _plain_message(data: bytes, at: int, n: int, cls, plain: _Plain, header: tuple):
    """`MAVLink.decode`'s message (the same object, field for field) of a frame `_plain_frame` checked:
    pymavlink's own steps without its per-call generality."""
    _, mlen, _, compat, seq, sys_id, comp, _, _ = header
    end = at + n
    buf = bytearray(data[at:end])
    fields = plain.pick(_unpacked(data, at, end, plain))
    if plain.strings:
        fields = [f.rstrip(b"\x00") if isinstance(f, bytes) else f for f in fields]
    m = cls(*fields)
    m._msgbuf, m._payload, m._crc = buf, buf[6:-2], data[end - 2] | data[end - 1] << 8
    h = m._header  # the header `cls.__init__` made (msgId set, incompat_flags 0): given the frame's other fields, as
    h.mlen, h.seq, h.srcSystem, h.srcComponent, h.compat_flags = mlen, seq, sys_id, comp, compat  # decode's new one
    return m


# The kinds the daemon reads only field by field (Telemetry.update, MavlinkIn.samples, the sensors' decoders), the
# most of a log: the replay hands them on as a `Light` tuple, not as pymavlink's message object (the decoding of a
# dense 20-minute .tlog's frames: 1.6 s → 0.9 s). No strings among them (`_message` does not strip them).
LIGHT = frozenset(("HEARTBEAT", "LOCAL_POSITION_NED", "ATTITUDE", "VFR_HUD", "EXTENDED_SYS_STATE",
                   "POSITION_TARGET_LOCAL_NED", "DISTANCE_SENSOR", "OBSTACLE_DISTANCE", "ESTIMATOR_STATUS",
                   "EKF_STATUS_REPORT"))


class Light(tuple):
    """A frame of a kind in `LIGHT` decoded as the daemon reads it: pymavlink's message's fields (by name; a
    property of each kind's subclass), `get_type`, `get_srcSystem`/`get_srcComponent` and `get_msgbuf`, and the
    class's `id` (the message id, unless a field is so named). The tuple: the fields, then the source's system and
    component, then the frame's bytes."""

    __slots__ = ()
    msgname = ""

    def get_type(self) -> str:
        return self.msgname

    def get_srcSystem(self) -> int:
        return self[-3]

    def get_srcComponent(self) -> int:
        return self[-2]

    def get_msgbuf(self) -> bytearray:
        return bytearray(self[-1])


def _message(data: bytes, at: int, n: int, msg_id: int, parser):
    """The message the daemon is fed of the `n`-byte frame at `at` that the scan kept: `msg_id` ≥ 0, a frame of the
    common kind (the scan checked it, `_plain_frame`), its kind in `LIGHT`: a `Light`, else `MAVLink.decode`'s
    message (made as `_plain_message` makes it when common). The frame's CRC is not computed again."""
    if msg_id < 0 or parser.signing.secret_key is not None:  # (signing: pymavlink judges every frame)
        return parser.decode(bytearray(data[at:at + n]))
    cls = mavlink.mavlink_map[msg_id]
    plain = _plain_for(cls)
    if plain.light is None:
        return _plain_message(data, at, n, cls, plain, _V2_HEADER.unpack_from(data, at))
    t = _unpacked(data, at, at + n, plain)
    if plain.arrays:  # the fields as `pick` makes them
        t = tuple(plain.pick(t))
    return tuple.__new__(plain.light, (*t, data[at + 5], data[at + 6], data[at:at + n]))


def _plain_v2(data: bytes, at: int, parser):
    """(frame length, `MAVLink.decode`'s message) of a frame of the common kind (`_plain_frame`), else None."""
    frame = _plain_frame(data, at, parser)
    return None if frame is None else (frame[0], _plain_message(data, at, *frame))


def _resync(data: bytes, start: int, parser, last_raw: int | None) -> int | None:
    """The next position holding a known message with a valid CRC (and a plausible stamp)."""
    known = mavlink.mavlink_map
    for m in MAGIC.finditer(data, start + 8):
        p = m.start() - 8
        if len(data) - p < 16:
            break
        msg_id = data[p + 13] if data[p + 8] == 0xFE else int.from_bytes(data[p + 15:p + 18], "little")
        if msg_id not in known:  # cheap: most false starts end here, before a CRC is computed
            continue
        if last_raw is not None and abs(struct.unpack_from(">Q", data, p)[0] - last_raw) > RESYNC_WINDOW_US:
            continue
        status, _, msg = _decode(data, p, parser)
        if status == "ok" and not msg.get_type().startswith("UNKNOWN"):
            return p
    return None


@dataclass
class _Clock:
    """The scan's log time so far: a stamp + `shift`; the last stamp and log time (`scan_tlog`)."""

    last_raw: int | None = None
    last_t: int = 0
    shift: int = 0


def scan_tlog(data: bytes, runs: bool = True) -> Scan:
    """Index the good packets of a tlog (pure; never raises on bad bytes). A frame of the common kind
    (`_plain_frame`) is checked, not decoded, unless it is one the scan keeps something of (`NOTED`): the replay
    decodes each packet as it feeds it, so no log's messages are all held at once. `runs`: stretches of common
    frames with nothing to say of them are indexed at once (`_clean_run`, the same index as frame by frame)."""
    parser = mavlink.MAVLink(None)
    s = Scan(size=len(data))
    size, stamp, plain_frame = len(data), _STAMP.unpack_from, _plain_frame
    offset, length, t_us, raw_us, common = s.offset, s.length, s.t_us, s.raw_us, s.common
    per: dict = {}  # msg id << 16 | sys << 8 | comp → [type, packets, first, last log time]
    clock = _Clock()
    u8 = np.frombuffer(data, np.uint8) if runs and mcrf4xx is not None and not mavlink.MAVLINK_IGNORE_CRC else None
    pos, by_frame = 0, 0  # by_frame: frames taken one by one before a run is tried again
    while pos < size:
        if len(offset) >= MAX_SAMPLES:
            s.capped = True
            break
        if u8 is not None and not by_frame:
            pos, done, whole = _clean_run(data, u8, pos, s, clock, per, parser)
            by_frame = 0 if whole else 1 if done >= RUN_MIN else BY_FRAME_AFTER_SHORT_RUN
            continue
        by_frame = max(by_frame - 1, 0)
        at = pos + 8
        frame = plain_frame(data, at, parser)  # the common frame (what `_decode` tries first)
        if frame is not None:
            n, cls = frame[0], frame[1]
            kind, mid = cls.msgname, cls.id
            key = mid << 16 | data[at + 5] << 8 | data[at + 6]
            msg = _plain_message(data, at, *frame) if kind in NOTED else None
        else:
            status, n, msg = _decode(data, pos, parser)
            if status != "ok":
                nxt = _resync(data, pos + 1, parser, clock.last_raw)
                if nxt is None:
                    s.skipped_bytes += size - pos
                    if status == "short":
                        s.truncated_tail = True
                    else:
                        s.corrupt += 1
                    break
                s.corrupt += 1
                s.skipped_bytes += nxt - pos
                pos = nxt
                continue
            kind, mid = msg.get_type(), -1
            h = msg._header  # (get_srcSystem, get_srcComponent)
            key = msg.get_msgId() << 16 | h.srcSystem << 8 | h.srcComponent
        raw = stamp(data, pos)[0]
        if raw > MAX_STAMP_US:  # a stamp past the year 2262: corrupt, taken as the last good one (a jump is said)
            s.bad_stamps += 1
            raw = clock.last_raw if clock.last_raw is not None else 0
        pos = at + n
        if kind.startswith("UNKNOWN"):
            s.unknown += 1
            continue
        if clock.last_raw is None:
            clock.shift = -raw
        else:
            step = raw + clock.shift - clock.last_t
            if step < -MAX_BACKSTEP_US or step > MAX_GAP_US:
                s.time_jumps.append({"t": clock.last_t / 1e6, "jump_s": step / 1e6})
                clock.shift = clock.last_t - raw
        t = max(raw + clock.shift, clock.last_t)
        clock.last_raw, clock.last_t = raw, t
        offset.append(at - 8)
        length.append(n)
        t_us.append(t)
        raw_us.append(raw)
        common.append(mid)
        seen = per.get(key)
        if seen is None:
            per[key] = [kind, 1, t, t]
        else:
            seen[1] += 1
            seen[3] = t
        if kind in NOTED:
            _note(s, t, msg, kind, (key >> 8 & 0xFF, key & 0xFF))
    for key, (kind, count, first, last) in per.items():
        src = (key >> 8 & 0xFF, key & 0xFF, kind)
        s.counts[src] = count
        s.spans[src] = [first, last]
    return s


RUN_CHUNK = 1 << 16  # frames one `_clean_run` takes at most (its memory bounded)
# a run shorter than this (odd frames close together) is followed by this many frames taken one by one: a
# damaged log costs at most a few times the frame-by-frame scan, never a run's fixed cost per frame
RUN_MIN, BY_FRAME_AFTER_SHORT_RUN = 256, 1024


def _clean_run(data: bytes, u8: np.ndarray, pos: int, s: Scan, clock: _Clock, per: dict, parser
               ) -> tuple[int, int, bool]:
    """The frame-by-frame scan's bookkeeping, at once (numpy), for the stretch of frames from `pos` that it would
    take as common (`_plain_frame`: MAVLink 2, unsigned, known, whole, CRC right) with a plausible stamp and no
    clock jump. Returns (the position after them, how many, whether the stretch ended only at RUN_CHUNK frames);
    a frame there that ended it is the frame-by-frame path's."""
    size, limit = len(data), min(RUN_CHUNK, MAX_SAMPLES - len(s.offset))
    walk, p = [], pos
    while len(walk) < limit and p + 20 <= size and data[p + 8] == 0xFD and not data[p + 10]:
        e = p + 20 + data[p + 9]
        if e > size:
            break
        walk.append(p)
        p = e
    if len(walk) < min(RUN_MIN, limit):  # a short stretch: frame by frame is cheaper than the run's fixed cost
        return pos, 0, False
    stamp_at = np.array(walk, np.int64)
    at = stamp_at + 8
    mlen = u8[at + 1].astype(np.int64)
    mid = u8[at + 7].astype(np.int64) | u8[at + 8].astype(np.int64) << 8 | u8[at + 9].astype(np.int64) << 16
    ids, id_of = np.unique(mid, return_inverse=True)
    classes = [mavlink.mavlink_map.get(int(i)) for i in ids]
    extra = np.array([-1 if c is None else c.crc_extra for c in classes], np.int64)[id_of]
    end = at + 12 + mlen
    ok = (extra >= 0) & (x25_frames(u8, at + 1, mlen + 9, extra) == (u8[end - 2] | u8[end - 1].astype(np.int64) << 8))
    raw = u8[stamp_at[:, None] + np.arange(8)].view(">u8").ravel()
    ok &= raw <= MAX_STAMP_US
    m = len(walk) if ok.all() else int(np.argmin(ok))
    raw = raw[:m].astype(np.int64)
    if m:  # log time, as frame by frame: t_k = max(stamp_k + shift, t_k-1); up to the first clock jump
        first = clock.last_raw is None
        shift = -int(raw[0]) if first else clock.shift
        t = np.maximum.accumulate(np.concatenate(([clock.last_t], raw + shift)))
        step = raw + shift - t[:-1]
        jump = (step < -MAX_BACKSTEP_US) | (step > MAX_GAP_US)
        jump[0] &= not first
        if jump.any():
            m = int(np.argmax(jump))
        t = t[1:m + 1]
    if not m:
        return pos, 0, False
    whole = m == len(walk) == limit
    stamp_at, at, n, mid, raw = stamp_at[:m], at[:m], 12 + mlen[:m], mid[:m], raw[:m]
    for arr, values in ((s.offset, stamp_at), (s.length, n), (s.t_us, t), (s.raw_us, raw), (s.common, mid)):
        arr.frombytes(values.astype(f"i{arr.itemsize}").tobytes())
    clock.last_raw, clock.last_t, clock.shift = int(raw[-1]), int(t[-1]), shift
    key = mid << 16 | u8[at + 5].astype(np.int64) << 8 | u8[at + 6]
    keys, first_k, which, count = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    last_k = np.zeros(len(keys), np.int64)
    np.maximum.at(last_k, which, np.arange(m))
    for j in np.argsort(first_k):  # in the order the frame-by-frame scan first met them
        k, c, t_last = int(keys[j]), int(count[j]), int(t[last_k[j]])
        seen = per.get(k)
        if seen is None:
            per[k] = [mavlink.mavlink_map[k >> 16].msgname, c, int(t[first_k[j]]), t_last]
        else:
            seen[1] += c
            seen[3] = t_last
    for k in np.nonzero(np.isin(mid, NOTED_IDS))[0]:
        a = int(at[k])
        msg = _plain_message(data, a, *_plain_frame(data, a, parser, crc=False))
        _note(s, int(t[k]), msg, msg.msgname, (data[a + 5], data[a + 6]))
    return int(stamp_at[-1] + 8 + n[-1]), m, whole


def _x25(crc: np.ndarray, byte: np.ndarray) -> np.ndarray:
    """One byte into CRC-16/MCRF4XX, MAVLink's X.25 checksum (pymavlink's `x25crc.accumulate`), element-wise."""
    tmp = (byte ^ crc) & 0xFF
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return (crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)


def x25_frames(u8: np.ndarray, start: np.ndarray, length: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """The MAVLink CRC of many frames at once: of the bytes [start, start + length) of `u8` each, then its
    CRC_EXTRA (`extra`), byte position by byte position, the longest frames first. Pure."""
    order = np.argsort(-length, kind="stable")
    start, length = start[order], length[order]
    crc = np.full(len(start), 0xFFFF, np.int64)
    longest = int(length[0]) if len(length) else 0
    active = np.searchsorted(-length, -np.arange(longest), side="left")  # frames longer than each position
    for k in range(longest):
        a = active[k]
        crc[:a] = _x25(crc[:a], u8[start[:a] + k])
    out = np.empty_like(crc)
    out[order] = _x25(crc, extra[order])
    return out


_STAMP = struct.Struct(">Q")
NOTED = frozenset(("HEARTBEAT", "NAMED_VALUE_FLOAT", "STATUSTEXT", "COMMAND_LONG"))  # what `_note` keeps of
NOTED_IDS = np.array(sorted(c.id for c in mavlink.mavlink_map.values() if c.msgname in NOTED), np.int64)


def _note(s: Scan, t: int, msg, kind: str, src: tuple[int, int]) -> None:
    """Keep what the reviewer may want of a few messages (`NOTED`)."""
    if kind == "HEARTBEAT":
        s.heartbeats[src] = (msg.type, msg.autopilot)
    elif kind == "NAMED_VALUE_FLOAT" and msg.name in IN_FLIGHT:
        s.in_flight.append((t, *src, msg.name, msg.value))
    elif kind == "STATUSTEXT" and msg.text.startswith("CG:"):
        s.texts.append((t, *src, msg.text))
    elif kind == "COMMAND_LONG" and msg.command in DAEMON_COMMANDS:
        s.commands.append((t, *src, DAEMON_COMMANDS[msg.command], msg.param1, msg.param2))


# ============================================================================ configuration


def _autopilots(scan: Scan) -> list[tuple[int, int]]:
    """Sources whose HEARTBEAT says autopilot, most LOCAL_POSITION_NED first."""
    found = [src for src, (_, ap) in scan.heartbeats.items() if ap not in NOT_AUTOPILOT]
    return sorted(found, key=lambda src: (-scan.counts[(*src, "LOCAL_POSITION_NED")], src))


def _describe_sources(scan: Scan) -> str:
    per: Counter = Counter()
    for (sy, cp, _), c in scan.counts.items():
        per[(sy, cp)] += c
    return ", ".join(f"{sy}/{cp} ({c})" for (sy, cp), c in per.most_common(6)) or "none"


def resolve(scan: Scan, path: Path, config: Path | None, vehicle: str | None, table: Path | None):
    """(config forced to shadow, table, contract, how the autopilot was chosen) for this tlog."""
    cfg = load_config(config) if config is not None else Config(sensors=list(ASSUMED_SENSORS))
    chosen = "config"
    if config is None:  # no flight config: take the autopilot the tlog shows
        aps = _autopilots(scan)
        if not aps:
            raise ContractError(f"{path}: no usable telemetry: no autopilot HEARTBEAT in {scan.packets} packets "
                                f"(sources sys/comp: {_describe_sources(scan)})")
        sy, cp = aps[0]
        kind = name_for_heartbeat(scan.heartbeats[(sy, cp)][1]) or "px4"
        cfg = cfg.model_copy(update={"link": cfg.link.model_copy(
            update={"target_system": sy, "target_component": cp, "autopilot": kind})})
        chosen = "detected"
    target = (cfg.link.target_system, cfg.link.target_component)
    lacking = [k for k in ("HEARTBEAT", "LOCAL_POSITION_NED") if not scan.counts[(*target, k)]]
    if lacking:
        raise ContractError(f"{path}: no usable telemetry: no {' or '.join(lacking)} from the autopilot "
                            f"{target[0]}/{target[1]} in {scan.packets} packets (sources sys/comp: "
                            f"{_describe_sources(scan)}; set link.target_system/target_component in --config)")
    if target in scan.heartbeats:  # the vehicle type its HEARTBEAT states (the last one seen)
        not_multirotor(scan.heartbeats[target][0], path, f"the autopilot {target[0]}/{target[1]}'s HEARTBEAT")
    return (*settle(cfg, config, vehicle, table), chosen)


def settle(cfg: Config, config: Path | None, vehicle: str | None, table: Path | None):
    """(config forced to shadow, table, contract) of a raw log's replay: the flight's mode decides the
    contract (offboard: avoid, else stop); `--vehicle` replaces the config's; a table alone brings its own."""
    from contracts.table import load_for_vehicle

    flown = cfg.daemon_mode
    cfg = cfg.model_copy(update={"mode": "shadow", "log": cfg.log.model_copy(update={"tlog": False})})
    if vehicle is not None:
        cfg = cfg.model_copy(update={"vehicle": vehicle, "table": None})
    alone = table is not None and vehicle is None and config is None  # a table alone: its own vehicle
    tab = load_for_vehicle(None if alone else cfg.vehicle, table or cfg.table)
    contract = flown.contract
    if contract == "avoid" and tab.avoid is None:
        raise ContractError(f"the flight flew {flown} (avoid contract); table {tab.path} carries the stop "
                            "contract only")
    return cfg, tab, contract


# ============================================================================ the replay


def _discard(msg, force_mavlink1: bool = False) -> None:
    """A replay's `MAVLink.send`: nothing leaves a replay, so nothing is packed either."""


def shadow_daemon(cfg: Config, table, log_dir: Path, contract: str, source: str, clock, wall):
    """(the shadow `Daemon` a log is replayed into, its event log in `log_dir`, started): its link reads nothing,
    and what it would send is discarded unpacked. `contract`: the one the flight flew under (shadow alone would say
    "stop"); `clock`, `wall`: the replay's log time and UNIX time [s]."""
    from companion.onboard.daemon import Daemon

    conn = MemoryMavfile(lambda: b"", lambda buf: None, source_system=cfg.link.target_system,
                         source_component=cfg.link.component_id)
    conn.mav.send = _discard
    log = EventLog(log_dir, clock=wall, commit="none", max_bytes=1 << 62)
    daemon = Daemon(cfg, table, conn, log, clock=clock, wall=wall, planning="inline", contract=contract)
    log.event(0.0, "start", mode="shadow", replay_of=source, vehicle=table.vehicle.name, table=str(table.path),
              contract=contract)
    return daemon, log


def replay(data: bytes, scan: Scan, cfg: Config, table, log_dir: Path, contract: str = "stop",
           source: str = "") -> dict:
    """Feed the scanned packets to a shadow `Daemon` in log time; its event log goes to `log_dir`."""
    now = {"t": 0.0, "wall": scan.raw_us[0] / 1e6}
    daemon, log = shadow_daemon(cfg, table, log_dir, contract, source, lambda: now["t"], lambda: now["wall"])
    off, length, t_us, raw_us, common = scan.offset, scan.length, scan.t_us, scan.raw_us, scan.common

    mav = daemon.conn.mav  # the daemon's own dialect (the scan's: mavutil's)
    watch, target = Watch(cfg.timeouts.heartbeat_s), (cfg.link.target_system, cfg.link.target_component)
    # (sys, comp, id, orientation) → samples, of DISTANCE_SENSORs off the horizontal or where no configured one looks
    off_path: Counter = Counter()
    looks = {sensor_orientation(s.orientation_deg) for s in cfg.sensors if s.kind == "distance_sensor"}
    checked = {c.name: None for c in adapter_for(cfg.link.autopilot).param_checks}  # → when the log first has it

    def take(i: int, t: float) -> None:
        now["t"], now["wall"] = t / 1e6, raw_us[i] / 1e6
        try:  # (the scan kept only frames with a valid CRC: a failure here is a dialect's complaint)
            msg = _message(data, off[i] + 8, length[i], common[i], mav)
        except Exception:  # noqa: BLE001 — as the parser would: a bad packet, counted
            daemon.counters.bad_packets += 1
            return
        kind = msg.get_type()
        if kind == "HEARTBEAT" and (msg.get_srcSystem(), msg.get_srcComponent()) == target:
            watch.stream(now["t"], t_us[i] / 1e6)
            watch.armed(now["t"], bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
        elif kind == "DISTANCE_SENSOR" and msg.orientation not in looks:
            off_path[(msg.get_srcSystem(), msg.get_srcComponent(), msg.id, msg.orientation)] += 1
        elif kind == "PARAM_VALUE" and checked.get(msg.param_id, 0) is None:
            checked[msg.param_id] = now["t"]
        daemon.feed(msg)

    def step(tick: float) -> None:
        now["wall"] += tick / 1e6 - now["t"]  # the stamp of the last packet, carried on to this tick
        now["t"] = tick / 1e6
        daemon.step()

    run = in_log_time(t_us[:scan.packets], cfg.loop_hz, take, step, stepped_silence(cfg))
    log.event(now["t"], "stop", counters=daemon.counters.__dict__)
    log.close()
    sensors = [{"what": f"DISTANCE_SENSOR id {i} from {sy}/{cp}", "facing": facing(o), "samples": n, "system": sy}
               for (sy, cp, i, o), n in sorted(off_path.items())]
    sensors += [{"what": f"RANGEFINDER from {sy}/{cp}", "samples": n,
                 "facing": "no orientation given (ArduPilot's primary rangefinder, usually the downward one)"}
                for (sy, cp, k), n in sorted(scan.counts.items()) if k == "RANGEFINDER"]
    return {**run, "messages": daemon.counters.messages, "bad_packets": daemon.counters.bad_packets,
            "flight": watch.result(now["t"]), "other_sensors": sensors, "checked_params": checked}


def stepped_silence(cfg: Config) -> float:
    """How long a silence in a log the replay steps through before skipping the rest [s]."""
    to = cfg.timeouts
    return min(SILENCE_MAX_S, max(to.heartbeat_s, to.telemetry_s, to.obstacle_s, to.nav_s) + SILENCE_MARGIN_S)


def cut_time(cuts: list, t_us: float) -> float:
    """A log time [µs] as the replay's, after the silences `in_log_time` cut out before it. Pure."""
    k = bisect.bisect_right([c[0] for c in cuts], t_us) - 1
    return t_us - cuts[k][1] if k >= 0 else t_us


def silences(info: dict) -> str:
    """The finding of the silences a replay skipped."""
    return (f"{info['gaps_skipped']} silence(s) in the log ({info['skipped_s']:.0f} s in all) cut out by the replay once "
            "the daemon had gone stale in each: no state samples there, and later times moved earlier by the cut")


def in_log_time(t_us, loop_hz: float, take, step, silence_s: float = math.inf) -> dict:
    """Step a replayed daemon every loop period: `take(i, t_us)` for every entry stamped by that tick
    (within TICK_SLACK_US; `t_us` its replay time), then `step(tick_us)`. A silence in the log is stepped
    through for `silence_s` (the daemon sees it as in flight: stale inputs, failsafe), then the rest of it
    is cut out: later entries are replayed that much earlier (the daemon's clock runs on, as it would through
    a clock jump closed up), so the cost grows with the log's entries, not its time span.
    Returns {"steps", "gaps_skipped", "skipped_s", "cuts": [(log time of the entry after a cut [µs], the
    time cut out up to there [µs])]}."""
    with gc_frozen():  # the read log: not walked again by every full collection
        return _in_log_time(t_us, loop_hz, take, step, silence_s)


def _in_log_time(t_us, loop_hz: float, take, step, silence_s: float) -> dict:
    period, n, i, k = 1e6 / loop_hz, len(t_us), 0, 0
    hold, shift = silence_s * 1e6, 0
    steps, gaps, cuts = 0, 0, []
    while True:
        tick = k * period
        while i < n and t_us[i] - shift <= tick + TICK_SLACK_US:
            take(i, min(t_us[i] - shift, tick))
            i += 1
        step(tick)
        steps += 1
        if i >= n:
            return {"steps": steps, "gaps_skipped": gaps, "skipped_s": shift / 1e6, "cuts": cuts}
        k += 1
        nxt = t_us[i] - shift
        if i and k * period - (t_us[i - 1] - shift) > hold and nxt > (k + 1) * period:
            shift += nxt - (k + 1) * period  # the next entry falls due at the next tick
            gaps += 1
            cuts.append((t_us[i], shift))


# The in-flight daemon's NAMED_VALUE_FLOATs against the replay (`in_flight`). A value is stamped when the
# logger received it: it was computed up to one NVF period (0.5 s) plus the routing before that, from the
# autopilot packets the logger received at about the same time as the daemon did. So it is compared with
# every replayed sample in [t − ALIGN_BEFORE_S, t + ALIGN_AFTER_S] and differs by the *smallest* difference
# there (a step in D_od or V_max is not a difference when the two cross it a sample apart).
ALIGN_BEFORE_S = 0.6
ALIGN_AFTER_S = 0.15
TOLERANCE = {"v_max": 0.2, "d_od": 0.3, "e_tr": 0.1}  # [m/s, m, m]: beyond these a value differs
# the in-flight daemon's state STATUSTEXTs (`supervisor`: "CG: <state> (<reason>)"): engaged while active/holding
ENGAGED_TEXT = ("CG: active", "CG: holding")
DISENGAGED_TEXT = ("CG: standby", "CG: failsafe", "CG: contract-guard stopping")
WARM_UP_S = 2.0  # with no state text at all (a shadow flight): skip the in-flight daemon's first seconds
WHY = {  # what a difference in each value points at, in the order a reviewer should read them
    "d_od": "D_od differs: the sensors (range, field of view, orientation) or the obstacle data in the tlog are "
            "not the flight's",
    "e_tr": "E_tr differs: another E_tr floor or window, another table's controller contract (E_tr_pred), or "
            "the commanded path is not in the tlog",
    "v_max": "V_max differs where D_od and E_tr agree: another table, R_obst or thrust estimate than the flight's",
}


def engaged_spans(texts, srcs, t_end_s: float) -> tuple[list[tuple[float, float]], str]:
    """Spans [s] in which the in-flight daemon was engaged (active or holding), from its own STATUSTEXTs;
    with none, everything after its warm-up. Returns (spans, what was compared)."""
    mine = [(t / 1e6, text) for t, sy, cp, text in texts if (sy, cp) in srcs]
    if not any(text.startswith(ENGAGED_TEXT + DISENGAGED_TEXT) for _, text in mine):
        return [], "all"
    spans, start = [], None
    for t, text in mine:
        if text.startswith(ENGAGED_TEXT) and start is None:
            start = t
        elif text.startswith(DISENGAGED_TEXT) and start is not None:
            spans.append((start, t))
            start = None
    if start is not None:
        spans.append((start, t_end_s))
    return spans, "engaged"


def in_flight(scan: Scan, samples, columns: tuple, target_system: int) -> dict | None:
    """The in-flight daemon's values (NAMED_VALUE_FLOAT, STATUSTEXT, commands) against the replay, aligned
    in time (see ALIGN_BEFORE_S) and over the part of the flight in which it was engaged (its STATUSTEXTs
    say when; a flight it never engaged in is compared after its warm-up). `samples()`: the replay's state
    samples as rows of `columns` (read only when the tlog holds the in-flight daemon's values)."""
    srcs = {(sy, cp) for _, sy, cp, _, _ in scan.in_flight} | {(sy, cp) for _, sy, cp, _ in scan.texts}
    srcs = {s for s in srcs if s[0] == target_system}
    if not srcs:
        return None
    ti = columns.index("t")
    rows = [r for r in samples() if isinstance(r[ti], (int, float))]
    times = [r[ti] for r in rows]
    mine = [(t / 1e6, name, value) for t, sy, cp, name, value in scan.in_flight if (sy, cp) in srcs]
    spans, part = engaged_spans(scan.texts, srcs, scan.t_us[-1] / 1e6 if len(scan.t_us) else 0.0)
    if part == "all" and mine:
        spans = [(mine[0][0] + WARM_UP_S, float("inf"))]
    diffs: dict[str, list[tuple[float, float]]] = {v: [] for v in IN_FLIGHT.values()}
    for t, name, value in mine:
        if value == -1.0 or not any(a <= t <= b for a, b in spans):
            continue  # -1: the daemon's "not finite"; outside the compared part
        lo = bisect.bisect_left(times, t - ALIGN_BEFORE_S)
        hi = bisect.bisect_right(times, t + ALIGN_AFTER_S)
        k = columns.index(IN_FLIGHT[name])
        near = [rows[j][k] for j in range(lo, hi) if isinstance(rows[j][k], (int, float))]
        if near:
            diffs[IN_FLIGHT[name]].append((t, min(abs(v - value) for v in near)))
    commands = Counter(name for _, sy, cp, name, _, _ in scan.commands if (sy, cp) in srcs)
    worst = {k: max(v, key=lambda x: x[1]) if v else None for k, v in diffs.items()}
    return {
        "components": sorted(srcs),
        "compared_part": part,
        "engaged_spans": [[a, b] for a, b in spans] if part == "engaged" else None,
        "alignment_s": [-ALIGN_BEFORE_S, ALIGN_AFTER_S],
        "tolerance": TOLERANCE,
        "compared": {k: len(v) for k, v in diffs.items()},
        "max_abs_diff": {k: w[1] if w else None for k, w in worst.items()},
        "max_abs_diff_t": {k: w[0] if w else None for k, w in worst.items()},
        "mean_abs_diff": {k: sum(d for _, d in v) / len(v) if v else None for k, v in diffs.items()},
        "differing": {k: sum(1 for _, d in v if d > TOLERANCE[k]) for k, v in diffs.items()},
        "statustext": [{"t": t / 1e6, "text": text} for t, sy, cp, text in scan.texts if (sy, cp) in srcs][:LISTED],
        "commands": dict(commands),
    }


def differs(fl: dict) -> str | None:
    """One finding line when the replay really differs from the in-flight daemon, saying where and why."""
    bad = {k: n for k, n in fl["differing"].items() if n}
    if not bad:
        return None
    what = ", ".join(f"{k} by up to {fl['max_abs_diff'][k]:.2f} at t = {fl['max_abs_diff_t'][k]:.2f} s "
                     f"({n} of {fl['compared'][k]} values beyond {TOLERANCE[k]:g})" for k, n in bad.items())
    why = [WHY[k] for k in ("d_od", "e_tr") if k in bad] or [WHY["v_max"]]
    part = "while it was engaged" if fl["compared_part"] == "engaged" else "after its warm-up"
    return f"replay differs from the in-flight daemon {part}: {what}; {'; '.join(why)}"


def _needed(cfg: Config) -> dict[str, tuple[str, ...]]:
    """What the daemon reads from the autopilot, by what it is for."""
    need = {"attitude": ("ATTITUDE",), "landed state": ("EXTENDED_SYS_STATE",),
            "navigation health": ("ESTIMATOR_STATUS", "EKF_STATUS_REPORT"),
            "commanded path (E_tr)": ("POSITION_TARGET_LOCAL_NED",)}
    if cfg.thrust.source == "hover":
        need["hover throttle"] = ("VFR_HUD",)
    return need


class Replay(Origin):
    """A `.tlog` replayed: the report's `replay` section, what the tlog lacked or spoiled, and its text."""

    key = "replay"

    def findings(self) -> list[str]:
        """Lines a reviewer must see about the replay itself (what the tlog lacked or spoiled)."""
        info, out = self.info, []
        if info["corrupt_packets"] or info["truncated_tail"]:
            what = [f"{info['corrupt_packets']} corrupt stretch(es) skipped"] if info["corrupt_packets"] else []
            what += ["last packet torn"] if info["truncated_tail"] else []
            out.append(f"tlog damaged: {' and '.join(what)} ({info['skipped_bytes']} bytes lost)")
        if info["missing_streams"]:
            out.append("tlog lacks " + "; ".join(f"{k} ({' or '.join(v)})" for k, v in info["missing_streams"].items())
                       + ": the replay ran without them")
        for s in info["slow_streams"]:
            out.append(f"{s['stream']} at {s['rate_hz']:.1f} Hz in the tlog, too slow for the daemon's {s['timeout_s']} s "
                       "staleness limit: stale-data findings may be the log's, not the flight's")
        if info["time_jumps"]:
            out.append(f"{len(info['time_jumps'])} clock jump(s) in the tlog stamps closed up")
        if info.get("bad_stamps"):
            out.append(f"tlog damaged: {info['bad_stamps']} packet stamp(s) too large to be a time, taken as the one before")
        if info.get("capped"):
            out.append(f"tlog longer than {MAX_SAMPLES} packets: only the first {MAX_SAMPLES} replayed")
        if info.get("gaps_skipped"):
            out.append(silences(info))
        gaps = gaps_finding(info.get("flight"), "ground-station telemetry gaps" if info.get("recorder")
                            else "telemetry gaps in the tlog", "the autopilot's HEARTBEAT absent from the tlog")
        if gaps:
            out.append(gaps)
        fl = info.get("in_flight")
        line = differs(fl) if fl else None
        if line:
            out.append(line)
        return out

    def lines(self) -> list[str]:
        rp, ap = self.info, self.info["autopilot"]
        out = [f"  replayed {rp['packets']} packets ({rp['corrupt_packets']} corrupt stretch(es) skipped"
               + (", torn tail" if rp["truncated_tail"] else "") + f") through {rp['table']} "
               f"({rp['contract']} contract, shadow mode); autopilot {ap['kind']} "
               f"{ap['system']}/{ap['component']} ({ap['from']}); event log: {rp['event_log'] or 'not kept'}"]
        fl = rp.get("in_flight")
        if fl:
            part = "while engaged" if fl["compared_part"] == "engaged" else "after its warm-up"
            out.append(f"  in-flight daemon vs replay ({part}, aligned within {ALIGN_BEFORE_S:g} s), max |difference|: "
                       + ", ".join(f"{k} {fmt_value(v)} ({fl['compared'][k]} values)"
                                   for k, v in fl["max_abs_diff"].items()))
        return out + _checked_line(rp.get("checked_params")) + not_forward_lines(rp.get("other_sensors", []))

    def flight_end(self, daemon_end: dict | None) -> dict | None:
        return flight_end(self.info.get("flight"), daemon_end)

    def title(self) -> str:
        return f"replayed from {Path(self.info['tlog']).name}"


def _checked_line(checked: dict | None) -> list[str]:
    """Where the tlog holds the parameters the start-up checks read (a replay cannot ask for them: it has what the
    tlog's recorder asked for, when it did)."""
    if not checked:
        return []
    held = [f"{k} (t = {t:.1f} s)" for k, t in checked.items() if t is not None]
    lacks = [k for k, t in checked.items() if t is None]
    return [f"  the start-up checks' parameters in the tlog: {', '.join(held) or 'none'}"
            + (f"; not in it: {', '.join(lacks)}" if lacks else "")]


def replay_tlog(path, log_dir: Path, *, config=None, vehicle=None, table=None) -> Replay:
    """Replay the tlog at `path` into an event log (`LOG_FILE`) in `log_dir` (see the module docstring)."""
    path = Path(path)
    if not path.exists():
        raise ContractError(f"no such file or directory: {path}")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ContractError(f"cannot read {path}: {err.strerror or err}") from None
    if not data:
        raise ContractError(f"{path}: empty .tlog")
    with gc_paused():
        scan = scan_tlog(data)
    if not scan.packets:
        raise ContractError(f"{path}: no MAVLink packets in {len(data)} bytes (not a .tlog?)")
    cfg, tab, contract, chosen = resolve(scan, path, config, vehicle, table)
    run = replay(data, scan, cfg, tab, log_dir, contract, str(path))
    columns = ("t", *IN_FLIGHT.values())
    samples = lambda: [tuple(r.get(k) for k in columns) for r in read_events(log_dir / LOG_FILE)  # noqa: E731
                       if r.get("kind") == "state"]
    target = (cfg.link.target_system, cfg.link.target_component)
    kinds = sorted({s.kind.upper() for s in cfg.sensors})
    to = cfg.timeouts
    slow = []
    streams = [("LOCAL_POSITION_NED", target, to.telemetry_s), ("HEARTBEAT", target, to.heartbeat_s)]
    for stream, src, timeout in streams + [(k, target[0], to.obstacle_s) for k in kinds]:
        r = scan.rate_hz(src, stream)
        if 0 < r < 1.25 / timeout:  # a mean interval over 0.8 of the staleness limit: stale at every jitter
            slow.append({"stream": stream, "rate_hz": r, "timeout_s": timeout})
    missing = {what: ks for what, ks in _needed(cfg).items() if not any(scan.counts[(*target, k)] for k in ks)}
    elsewhere = Counter()  # DISTANCE_SENSOR samples of the autopilot's system that look where no sensor is configured
    for o in run["other_sensors"]:
        if o.get("system") == target[0]:
            elsewhere["DISTANCE_SENSOR"] += o["samples"]
    for kind in kinds:
        if sum(c for (sy, _, k), c in scan.counts.items() if sy == target[0] and k == kind) <= elsewhere[kind]:
            missing[f"obstacle data ({kind}: D_od is 0 throughout)"] = (kind,)
    info = {
        "tlog": str(path),
        "bytes": len(data),
        "packets": scan.packets,
        "corrupt_packets": scan.corrupt,
        "skipped_bytes": scan.skipped_bytes,
        "truncated_tail": scan.truncated_tail,
        "bad_stamps": scan.bad_stamps,
        "capped": scan.capped,
        "unknown_messages": scan.unknown,
        "t0_unix": scan.raw_us[0] / 1e6,
        "span_s": scan.t_us[-1] / 1e6,
        "time_jumps": scan.time_jumps[:LISTED],
        "autopilot": {"system": target[0], "component": target[1], "kind": cfg.link.autopilot, "from": chosen},
        "config": None if config is None else str(config),
        "vehicle": tab.vehicle.name,
        "table": str(tab.path),
        "contract": contract,
        "loop_hz": cfg.loop_hz,
        "steps": run["steps"],
        "gaps_skipped": run["gaps_skipped"],
        "skipped_s": run["skipped_s"],
        "daemon_messages": run["messages"],
        "missing_streams": {k: list(v) for k, v in missing.items()},
        "flight": run["flight"],
        "other_sensors": run["other_sensors"],
        "checked_params": run["checked_params"],  # the start-up checks' parameters → when the tlog first has one
        # who recorded the tlog: a ground station (its own HEARTBEAT, or the telemetry radio's status) or not said
        "recorder": "ground station" if any(ty == mavlink.MAV_TYPE_GCS for ty, _ in scan.heartbeats.values())
        or any(k == "RADIO_STATUS" for _, _, k in scan.counts) else None,
        "slow_streams": slow,
        "event_log": None,  # where the replayed event log is kept, if it is (see companion.cli)
        "in_flight": in_flight(replace(scan, in_flight=[(cut_time(run["cuts"], t), *r) for t, *r in scan.in_flight],
                                       texts=[(cut_time(run["cuts"], t), *r) for t, *r in scan.texts],
                                       commands=[(cut_time(run["cuts"], t), *r) for t, *r in scan.commands]),
                               samples, columns, target[0]),
        "notes": ["shadow replay: the controller guarantee (contour error vs E_tr_pred at the commanded limit) "
                  "is evaluated only against a commanded limit, so it is not checked here"]
        + ([ASSUMED_NOTE] if config is None else []),
    }
    return Replay([str(path)], finite_copy(info))


# ============================================================================ the flight, for calibrate


def read_tlog(path) -> Feed:
    """A `.tlog` as the ops of `loginput`, its packets decoded as the replay decodes them: the autopilot's messages
    (the last HEARTBEAT of a component 1 that is an autopilot names it), and in `Feed.commands` the mode commands
    on the link (t [s], mode name) from any sender but the autopilot (a ground station, or the daemon)."""
    data = Path(path).read_bytes()
    with gc_paused():
        scan = scan_tlog(data)
    parser = mavlink.MAVLink(None)
    ops, cmds, ap_sys, autopilot, mav_type = [], [], None, "px4", 0
    for i in range(scan.packets):
        try:
            m = _message(data, scan.offset[i] + 8, scan.length[i], scan.common[i], parser)
        except Exception:  # noqa: BLE001 — as the replay: a packet the dialect refuses is skipped
            continue
        # the stamp [µs] as calibrate has always taken it, through pymavlink's float seconds: 1 µs short on about a
        # third of the packets; kept, so that a calibration stays what it was
        kind, t_us = m.get_type(), int(scan.raw_us[i] * 1.0e-6 * 1e6)
        src = (m.get_srcSystem(), m.get_srcComponent())
        if kind == "HEARTBEAT" and m.autopilot not in NOT_AUTOPILOT and src[1] == 1:
            ap_sys, mav_type = src[0], m.type
            autopilot = "ardupilot" if m.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA else "px4"
            ops.append((t_us, "mode", (m.base_mode, m.custom_mode)))
        elif kind == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_DO_SET_MODE and src != (ap_sys, 1):
            cmds.append((t_us, (m.param1, m.param2, m.param3)))
        elif ap_sys is not None and src == (ap_sys, 1):
            op = _op(m, kind)
            if op is not None:
                ops.append((t_us, *op))
    not_multirotor(mav_type, path, "the autopilot's HEARTBEAT")
    ad = adapter_for(autopilot)
    t_first = min([o[0] for o in ops] + [c[0] for c in cmds]) if ops else 0
    ordered, jumps = order([(t - t_first, op, a) for t, op, a in ops])
    # a .tlog stamps each packet with the UNIX time it was logged [µs]: the log's wall clock at t = 0
    return Feed(ordered, {"format": "MAVLink tlog", "time_jumps": jumps}, autopilot, t_first / 1e6,
                [((t - t_first) / 1e6, _commanded_mode(ad, p)) for t, p in cmds])


def _op(m, kind: str) -> tuple | None:
    """(op, args) of an autopilot message calibrate reads (`loginput`'s ops), else None."""
    if kind == "LOCAL_POSITION_NED":
        return "pos", (m.x, m.y, m.z, m.vx, m.vy, m.vz)
    if kind == "ATTITUDE":
        return "att", (m.roll, m.pitch, m.yaw)
    if kind == "POSITION_TARGET_LOCAL_NED":
        return "target", (math.nan, math.nan) if m.type_mask & 0b11 else (m.x, m.y)
    if kind == "VFR_HUD":
        return "thr", (m.throttle / 100.0,)
    if kind == "EXTENDED_SYS_STATE":
        return "landed", (m.landed_state,)
    return None


def _commanded_mode(ad, p) -> str:
    """The mode a MAV_CMD_DO_SET_MODE's params ask for (base_mode, then PX4's main/sub mode or ArduPilot's number)."""
    if ad.name == "ardupilot":
        return ad.mode_name(int(p[0]), int(p[1]))
    custom = (int(p[1]) & 0xFF) << 16 | (int(p[2]) & 0xFF) << 24
    return ad.mode_name(int(p[0]), custom)
