"""The mode authority: the one owner of every mode command the daemon sends (DESIGN.md §5, "Authority").

Pure, no I/O. It keeps the one record of what the daemon commanded and when; it applies the one rule of
authority — someone else changed the mode: log it and stand down, never fight — once a cycle, in `observe`,
for every part of the daemon at once (`ModeView.taken_over`); and it arbitrates the cycle's mode requests by
priority (`Requester`: the lower value wins):

    failsafe Hold > offboard's own stop (braking stop, route done) > shutdown Hold > calibration legs > offboard entry

Every part that wants a mode asks here (a `ModeRequest` in the cycle's requests); nothing else sends or
records one. The winner goes into the cycle's outbox (companion/outbox.py), which MAVLink-out applies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from .frozen import quick_init

TAKE_S = 3.0  # a mode commanded and not seen in a heartbeat this long after was not taken (heartbeats are 1 Hz)


class Requester(IntEnum):
    """Who asks for a mode, in order of priority (the lower value wins)."""

    FAILSAFE = 0  # the supervisor's Hold: a fail-safe, or a stop it cannot fly out
    OFFBOARD_STOP = 1  # offboard's own Hold (and the recovery brake's): at the end of its braking stop, or of the route
    SHUTDOWN = 2  # the daemon stops while engaged in flight
    CALIBRATION = 3  # the calibration plan's hold legs: Hold, then the mission again
    OFFBOARD_ENTRY = 4  # offboard (or the recovery brake) asks for OFFBOARD / GUIDED


HOLD = "hold"  # a request's mode for the autopilot's Hold (PX4 Hold, ArduPilot Brake: the adapter's name)


@dataclass(frozen=True)
class ModeRequest:
    mode: str  # HOLD, "mission" or "offboard"
    by: Requester


@dataclass(frozen=True)
class ModeCommand:
    """The arbitrated request, as MAVLink-out sends it: the adapter's mode name and what the command record says."""

    mode: str  # the autopilot's mode (the adapter's name: "hold" / "brake", "mission", "offboard")
    what: str  # the `command` event's `cmd`: "hold", "mission", "offboard"
    by: Requester


@quick_init
@dataclass(frozen=True)
class ModeView:
    """What the autopilot's mode says this cycle, judged once for every part of the daemon."""

    mode: str  # the adapter's name ("other" while the link is down)
    by_daemon: bool  # the current mode is one the daemon commanded
    taken_over: bool  # someone else changed the mode this cycle: stand down, never fight
    event: tuple[str, dict] | None = None  # the `mode_change` record, when the mode changed


class ModeAuthority:
    def __init__(self, hold_mode: str):
        """`hold_mode`: the adapter's name of the autopilot's Hold (PX4 Hold, ArduPilot Brake)."""
        self.hold_mode = hold_mode
        self.commanded: tuple[str, float, bool] | None = None  # (mode, when, seen in a heartbeat yet)
        self.last: ModeCommand | None = None  # the last command granted
        self._mode: str | None = None  # the mode last seen with the link up

    def observe(self, t: float, mode: str, link_ok: bool) -> ModeView:
        """This cycle's mode: whether the daemon commanded it, and whether someone else just changed it (with the
        link down the mode is unknown, not changed)."""
        by_daemon = False
        if self.commanded is not None:
            want, t_cmd, seen = self.commanded
            if mode == want:
                self.commanded, by_daemon = (want, t_cmd, True), True
            elif seen or t - t_cmd > TAKE_S:  # left it since, or never took it
                self.commanded = None
        event, taken_over = None, False
        if link_ok and mode != self._mode:
            if self._mode is not None:
                taken_over = not by_daemon
                event = ("mode_change", {"from": self._mode, "to": mode, "by": "other" if taken_over else "daemon"})
            self._mode = mode
        return ModeView(mode, by_daemon, taken_over, event)

    def arbitrate(self, t: float, requests) -> ModeCommand | None:
        """The request that wins this cycle (None: none asked), recorded as the daemon's command."""
        if not requests:
            return None
        r = min(requests, key=lambda q: q.by)
        mode = self.hold_mode if r.mode == HOLD else r.mode
        self.commanded = (mode, t, False)
        self.last = ModeCommand(mode, r.mode, r.by)
        return self.last

    def shows(self, mode: str) -> bool:
        """The autopilot's heartbeat shows `mode` (HOLD: its Hold), commanded by the daemon."""
        want = self.hold_mode if mode == HOLD else mode
        return self.commanded is not None and self.commanded[0] == want and self.commanded[2]

    def since(self, t: float) -> float:
        """How long ago the last command was sent (inf: never)."""
        return t - self.commanded[1] if self.commanded is not None else math.inf
