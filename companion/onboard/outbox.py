"""One cycle's outbox: everything the daemon sends in a cycle, as one frozen record that MAVLink-out applies in one
call (`MavlinkOut.apply`), in this order: the mode command (the mode authority's winner), the speed command, the
protocol messages (mission download, home request, parameter values and requests), the other commands (message
rates), the offboard setpoint, then the events and the texts, and last the daemon's own heartbeat and named values.
The cycle's box, what samples and the link asked for since the last cycle, and what the periodic work adds are
joined into one with `then`."""

from __future__ import annotations

from dataclasses import dataclass

from .authority import ModeCommand


@dataclass(frozen=True, slots=True)
class Outbox:
    mode: ModeCommand | None = None  # DO_SET_MODE (companion/onboard/authority.py: the one winner of the cycle)
    speed: float | None = None  # DO_CHANGE_SPEED [m/s] (governor mode)
    messages: tuple = ()  # MAVLink messages of the daemon's protocols, sent as they are
    commands: tuple[tuple[int, tuple, str], ...] = ()  # other COMMAND_LONGs: (command, params, what), logged as sent
    setpoint: object | None = None  # guidance.Setpoint: SET_POSITION_TARGET_LOCAL_NED (offboard)
    end_stream: bool = False  # the offboard setpoint stream stopped this cycle
    events: tuple[tuple[str, dict], ...] = ()  # (name, fields) for the event log
    texts: tuple[tuple[int, str], ...] = ()  # (MAV_SEVERITY, text) as STATUSTEXT
    heartbeat: str | None = None  # the daemon's state for its HEARTBEAT (companion/onboard/mavlink_out.py HEARTBEAT_STATE)
    values: tuple[tuple[str, float], ...] = ()  # NAMED_VALUE_FLOAT (name, value)

    def then(self, later: Outbox) -> Outbox:
        """This box and a `later` one as one: the sequences joined in that order; the mode, speed, setpoint and
        heartbeat are one box's each (the later one's where both carry one)."""
        pick = lambda a, b: a if b is None else b  # noqa: E731
        return Outbox(mode=pick(self.mode, later.mode), speed=pick(self.speed, later.speed),
                      messages=self.messages + later.messages, commands=self.commands + later.commands,
                      setpoint=pick(self.setpoint, later.setpoint), end_stream=self.end_stream or later.end_stream,
                      events=self.events + later.events, texts=self.texts + later.texts,
                      heartbeat=pick(self.heartbeat, later.heartbeat), values=self.values + later.values)


EMPTY = Outbox()
