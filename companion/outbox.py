"""One cycle's outbox: everything the cycle wants sent, as one frozen record that MAVLink-out applies in one call
(`MavlinkOut.apply`), in this order: the mode command (the mode authority's winner), the speed command, the
protocol messages (mission download, home request), the offboard setpoint, then the events and the texts."""

from __future__ import annotations

from dataclasses import dataclass

from .authority import ModeCommand


@dataclass(frozen=True, slots=True)
class Outbox:
    mode: ModeCommand | None = None  # DO_SET_MODE (companion/authority.py: the one winner of the cycle)
    speed: float | None = None  # DO_CHANGE_SPEED [m/s] (governor mode)
    messages: tuple = ()  # MAVLink messages of the daemon's protocols, sent as they are
    setpoint: object | None = None  # guidance.Setpoint: SET_POSITION_TARGET_LOCAL_NED (offboard)
    end_stream: bool = False  # the offboard setpoint stream stopped this cycle
    events: tuple[tuple[str, dict], ...] = ()  # (name, fields) for the event log
    texts: tuple[tuple[int, str], ...] = ()  # (MAV_SEVERITY, text) as STATUSTEXT


EMPTY = Outbox()
