"""MAVLink out: everything the daemon sends, and nothing it decides, in one outbox a cycle (`apply`): commands (the
Hold command in one place), STATUSTEXT (chunked), offboard setpoints, the daemon's own HEARTBEAT and
NAMED_VALUE_FLOATs. It also encodes what goes into an outbox: the stream and parameter requests to the autopilot,
and the parameter server's answers for the daemon's `CG_*` parameters. A send that fails is dropped (the
supervisor sees the link time out).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from .autopilot_base import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_DO_SET_MODE
from .link import mavlink
from .modes import MODES as DAEMON_MODES
from .outbox import Outbox

MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_STANDBY, MAV_STATE_ACTIVE, MAV_STATE_CRITICAL = 3, 4, 5
MAV_PARAM_TYPE_REAL32 = 9
HEARTBEAT_STATE = {"holding": MAV_STATE_CRITICAL, "failsafe": MAV_STATE_CRITICAL, "active": MAV_STATE_ACTIVE}
SETPOINT_TYPE_MASK = 2048  # position, velocity, acceleration and yaw; no yaw rate

# message id → interval [µs] the daemon asks for (SET_MESSAGE_INTERVAL)
STREAMS = {
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 20_000,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 20_000,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 50_000,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 100_000,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 500_000,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 200_000,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 500_000,
    mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR: 50_000,
    mavlink.MAVLINK_MSG_ID_OBSTACLE_DISTANCE: 50_000,
}


STATUSTEXT_BYTES = 50  # STATUSTEXT.text (MAVLink common.xml)


def text_chunks(text: str, n: int = STATUSTEXT_BYTES) -> list[bytes]:
    """`text` in chunks of `n` bytes that break after a space (a word longer than `n` is cut); every chunk but
    the last padded with spaces to exactly `n` bytes, the last shorter than `n` (or an empty one after it). The
    space stays in the chunk it ends, so a receiver that joins the chunks as they are reads the words apart."""
    data = text.encode()
    if len(data) <= n:
        return [data]
    out, rest = [], data
    while len(rest) >= n:
        cut = rest.rfind(b" ", 0, n) + 1  # after the last space that fits
        cut = n if cut <= 0 else cut
        out.append(rest[:cut].ljust(n))
        rest = rest[cut:]
    return out + [rest]


@dataclass
class Counters:
    messages: int = 0  # decoded messages of the dialect
    unknown_messages: int = 0  # well-framed messages of an id the dialect does not define
    bad_packets: int = 0
    rejected_signature: int = 0  # unsigned or wrongly signed, where signing is on
    unknown_source: int = 0  # messages from ids no configured autopilot, sensor or ground station has
    refused_address: int = 0  # UDP datagrams claiming a pinned source's ids from another address, or beyond the clients
    link_dropped: int = 0  # UDP datagrams dropped unread: not MAVLink, or a frame cut at the datagram's end
    kernel_drops: int = 0  # UDP datagrams the kernel dropped (receive buffer full), where it says
    commands_sent: int = 0
    log_errors: int = 0
    loop_errors: int = 0
    implausible: int = 0  # messages dropped as implausible (not finite, out of range, inconsistent)
    poll_budget_hits: int = 0  # cycles that left messages for the next one (a flood)
    params_refused: int = 0
    setpoints_sent: int = 0
    setpoint_gap_max_s: float = 0.0  # longest gap between offboard setpoints while streaming (daemon time)


class MavlinkOut:
    """`event(t, name, **fields)` logs what was sent where the log wants it (commands)."""

    def __init__(self, conn, link_cfg, adapter, counters: Counters, event: Callable[..., None]):
        self.conn, self.link, self.adapter, self.counters, self.event = conn, link_cfg, adapter, counters, event
        self._text_id = 0  # STATUSTEXT.id of the last chunked text
        self._t_last_sp: float | None = None  # when the last offboard setpoint went out

    def send(self, msg) -> None:
        try:
            self.conn.mav.send(msg)
        except Exception:
            pass  # the link is down; the supervisor sees the heartbeat time out

    def command(self, t: float, cmd: int, params: tuple[float, ...], what: str, send: int = 1) -> None:
        """One COMMAND_LONG, logged (`send` > 1: the mode authority's re-send of the same command)."""
        self.counters.commands_sent += 1
        self.send(self.conn.mav.command_long_encode(self.link.target_system, self.link.target_component, cmd, 0,
                                                    *params))
        self.event(t, "command", cmd=what, params=[p if math.isfinite(p) else None for p in params],
                   **({"send": send} if send > 1 else {}))

    def set_mode(self, t: float, mode: str, what: str, send: int = 1) -> None:
        self.command(t, MAV_CMD_DO_SET_MODE, self.adapter.set_mode_params(mode, True), what, send)

    def apply(self, t: float, box: Outbox) -> None:
        """One cycle's outbox (companion/onboard/outbox.py), in its order: the mode command (the only place a mode is
        sent), the speed command, the protocols' messages, the other commands, the setpoint, the events and the
        texts, then the heartbeat and the named values."""
        if box.mode is not None:
            self.set_mode(t, box.mode.mode, box.mode.what, box.mode.send)
        if box.speed is not None:
            self.command(t, MAV_CMD_DO_CHANGE_SPEED, self.adapter.speed_params(box.speed), "change_speed")
        for msg in box.messages:
            self.send(msg)
        for cmd, params, what in box.commands:
            self.command(t, cmd, params, what)
        if box.end_stream:
            self.end_stream()
        if box.setpoint is not None:
            self.setpoint(t, box.setpoint)
        for name, fields in box.events:
            self.event(t, name, **fields)
        for severity, text in box.texts:
            self.statustext(severity, text)
        if box.heartbeat is not None:
            self.heartbeat(box.heartbeat)
        if box.values:
            self.named_values(t, box.values)

    def statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT; longer than 50 bytes, in chunks (MAVLink 2 `id`, `chunk_seq`) that end at word boundaries:
        each but the last padded with spaces to the full 50 bytes (a shorter chunk ends the text for a ground
        station that joins them), so one that shows the chunks one by one never splits a word."""
        chunks = text_chunks(text)
        if len(chunks) == 1:
            self.send(self.conn.mav.statustext_encode(severity, chunks[0]))
            return
        self._text_id = self._text_id % 65535 + 1
        for k, chunk in enumerate(chunks):
            self.send(self.conn.mav.statustext_encode(severity, chunk, self._text_id, k))

    def setpoint(self, t: float, sp) -> None:
        """One offboard setpoint (SET_POSITION_TARGET_LOCAL_NED: position, velocity, acceleration, yaw)."""
        if self._t_last_sp is not None:
            self.counters.setpoint_gap_max_s = max(self.counters.setpoint_gap_max_s, t - self._t_last_sp)
        self._t_last_sp = t
        self.counters.setpoints_sent += 1
        self.send(self.conn.mav.set_position_target_local_ned_encode(
            int(t * 1000) & 0xFFFFFFFF, self.link.target_system, self.link.target_component,
            mavlink.MAV_FRAME_LOCAL_NED, SETPOINT_TYPE_MASK,
            float(sp.p[0]), float(sp.p[1]), float(sp.z), float(sp.v[0]), float(sp.v[1]), 0.0,
            float(sp.a[0]), float(sp.a[1]), 0.0, float(sp.yaw), 0.0))

    def end_stream(self) -> None:
        self._t_last_sp = None

    def stream_requests(self, param_names) -> Outbox:
        """On link up and after an autopilot restart: the autopilot parameters the start-up checks need, and the
        message rates."""
        lk = self.link
        return Outbox(messages=tuple(self.conn.mav.param_request_read_encode(lk.target_system, lk.target_component,
                                                                             name.encode(), -1)
                                     for name in param_names),
                      commands=tuple((mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                      (float(msg_id), float(interval), 0, 0, 0, 0, 0), "set_message_interval")
                                     for msg_id, interval in STREAMS.items()))

    def heartbeat(self, state: str) -> None:
        self.send(self.conn.mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0,
                                                 HEARTBEAT_STATE.get(state, MAV_STATE_STANDBY)))

    def named_values(self, t: float, values) -> None:
        """NAMED_VALUE_FLOAT each of the (name, value) pairs (−1 for a value that is not finite)."""
        tb = int(t * 1000) & 0xFFFFFFFF
        for name, v in values:
            self.send(self.conn.mav.named_value_float_encode(tb, name.encode(), v if math.isfinite(v) else -1.0))


class ParamServer:
    """The daemon's parameters over the MAVLink parameter protocol. Anyone addressing the daemon (its
    system, or broadcast; its component, or broadcast) may read them; only the configured ground
    stations may set them — over a network link only with a signed message (`unsigned_refused`: why an
    unsigned one is refused, None where it is not; MAVLink 2 signing is verified by the link, and pymavlink
    marks such a message `get_signed()`) — each within its range
    (`ranges`: name → (lo, hi) or a set of values; a name without one is read-only, such as CG_MODE, which
    reports the mode the daemon runs in). A refused set is answered with the current value (PARAM_VALUE:
    the protocol's acknowledgement) and reported."""

    NAMES = ("CG_ENGAGE", "CG_MODE", "CG_R_OBST")
    MODES = tuple(DAEMON_MODES)  # CG_MODE's values

    def __init__(self, out: MavlinkOut, component_id: int, values: dict[str, float], ranges: dict,
                 setters: tuple[int, ...], unsigned_refused: str | None = None):
        self.out, self.component_id, self.values = out, component_id, values
        self.ranges, self.setters, self.unsigned_refused = ranges, setters, unsigned_refused
        self.refused: list[tuple[str, float, int, str]] = []  # (name, value, source system, why) since read

    def _refusal(self, msg, v: float) -> str | None:
        if msg.get_srcSystem() not in self.setters:
            return f"system {msg.get_srcSystem()} is not a configured ground station"
        if self.unsigned_refused is not None and not msg.get_signed():
            return self.unsigned_refused
        allowed = self.ranges.get(msg.param_id)
        if allowed is None:
            return "read-only"
        if not math.isfinite(v):
            return "not finite"
        if isinstance(allowed, tuple) and not allowed[0] <= v <= allowed[1]:
            return f"outside {allowed[0]:g}–{allowed[1]:g}"
        if isinstance(allowed, frozenset) and v not in allowed:
            return f"not one of {sorted(allowed)}"
        return None

    def handle(self, msg) -> tuple[tuple[str, float, float] | None, tuple]:
        """Answer one request: (name, old, new) when a PARAM_SET changed a value (else None), and the PARAM_VALUEs
        that answer it (a set that was taken is answered by the caller, with the value that stands)."""
        link = self.out.link
        if msg.target_system not in (link.target_system, 0) or msg.target_component not in (self.component_id, 0):
            return None, ()
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return None, tuple(self.value(name) for name in self.NAMES)
        if kind == "PARAM_REQUEST_READ":
            names = self.NAMES
            name = msg.param_id if msg.param_index < 0 else names[msg.param_index] if msg.param_index < len(names) \
                else None
            return None, (self.value(name),) if name in self.values else ()
        if kind == "PARAM_SET" and msg.param_id in self.values:
            v = float(msg.param_value)
            why = self._refusal(msg, v)
            if why is not None:
                self.out.counters.params_refused += 1
                self.refused.append((msg.param_id, v, msg.get_srcSystem(), why))
                return None, (self.value(msg.param_id),)  # refused: echo the current value
            old = self.values[msg.param_id]
            self.values[msg.param_id] = v
            return (msg.param_id, old, v), ()
        return None, ()

    def value(self, name: str):
        """PARAM_VALUE of one of the daemon's parameters."""
        return self.out.conn.mav.param_value_encode(name.encode(), self.values[name], MAV_PARAM_TYPE_REAL32,
                                                    len(self.NAMES), self.NAMES.index(name))
