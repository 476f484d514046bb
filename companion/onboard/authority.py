"""The mode authority: the one owner of every mode command the daemon sends (DESIGN.md §5, "Authority").

Pure, no I/O. It keeps the one record of what the daemon commanded and when; it applies the one rule of
authority — someone else changed the mode: log it and stand down, never fight — once a cycle, in `observe`,
for every part of the daemon at once (`ModeView.taken_over`); it arbitrates the cycle's mode requests by
priority (`Requester`: the lower value wins):

    failsafe Hold > offboard's own stop (braking stop, route done) > shutdown Hold > calibration legs > offboard entry

and it owns their delivery, the command-delivery subsystem's guarantee (docs/guarantee.md): a requested mode is
re-sent every cycle until the autopilot answers it (COMMAND_ACK) or shows it (HEARTBEAT) — past the delivery
budget `t_cmd_s` every RESEND_LATE_S, so a link that is down is not flooded —; it is shown within
`t_mode_s` of the first send. A Hold refused, or not shown in time, takes the adapter's next way to stop
(`Adapter.hold_fallbacks`: e.g. Land); any other mode is given up. Every part that wants a mode asks here (a
`ModeRequest` in the cycle's requests) and learns the outcome here (`ModeView.settled`); nothing else sends,
re-sends or times one. The winner goes into the cycle's outbox (companion/onboard/outbox.py), which MAVLink-out applies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum, StrEnum

ACCEPTED_RESULTS = (0, 5)  # MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS
RESEND_LATE_S = 0.2  # [s] a command past its delivery budget is re-sent this often (within it: every cycle)


class Requester(IntEnum):
    """Who asks for a mode, in order of priority (the lower value wins)."""

    FAILSAFE = 0  # the supervisor's Hold: a fail-safe, or a stop it cannot fly out
    OFFBOARD_STOP = 1  # offboard's own Hold (and the recovery brake's): at the end of its braking stop, or of the route
    SHUTDOWN = 2  # the daemon stops while engaged in flight
    CALIBRATION = 3  # the calibration plan's hold legs: Hold, then the mission again
    OFFBOARD_ENTRY = 4  # offboard (or the recovery brake) asks for OFFBOARD / GUIDED


class Delivery(StrEnum):
    """Where a mode command is on its way (`delivery` events' `outcome`)."""

    SENDING = "sending"  # sent every cycle, not answered yet
    ACCEPTED = "accepted"  # answered ACCEPTED, not shown yet
    SHOWN = "shown"  # the autopilot's HEARTBEAT shows it
    REFUSED = "refused"  # answered with a refusal (no fallback left)
    NOT_SHOWN = "not shown"  # not shown within t_mode_s (no fallback left)


HOLD = "hold"  # a request's mode for the autopilot's Hold (PX4 Hold, ArduPilot Brake: the adapter's name)


@dataclass(frozen=True)
class ModeRequest:
    mode: str  # HOLD, "mission" or "offboard"
    by: Requester
    within_s: float | None = None  # [s] its own budget to be shown (None: the authority's t_mode_s)


@dataclass(frozen=True)
class ModeCommand:
    """The arbitrated request, as MAVLink-out sends it: the adapter's mode name and what the command record says."""

    mode: str  # the autopilot's mode (the adapter's name: "hold" / "brake", "mission", "offboard", "land")
    what: str  # the `command` event's `cmd`: "hold", "mission", "offboard", "land"
    by: Requester
    send: int = 1  # 1: the first send, more: a re-send of the same command


@dataclass(frozen=True)
class Settled:
    """A mode request's delivery that ended this cycle, as its requester learns it."""

    what: str  # the request's mode (HOLD, "mission", "offboard")
    by: Requester
    outcome: Delivery  # SHOWN, REFUSED or NOT_SHOWN
    why: str = ""  # for a refusal or a time-out, in words


@dataclass(frozen=True)
class Late:
    """A command past its delivery budget: the subsystem's broken guarantee (`violation_start` fields)."""

    guarantee: str
    assumed: float  # [s] the budget
    observed: float  # [s] how long it has been on its way
    action: str


@dataclass(frozen=True, slots=True)
class ModeView:
    """What the autopilot's mode says this cycle, judged once for every part of the daemon."""

    mode: str  # the adapter's name ("other" while the link is down)
    by_daemon: bool  # the current mode is one the daemon commanded
    taken_over: bool  # someone else changed the mode this cycle: stand down, never fight
    event: tuple[str, dict] | None = None  # the `mode_change` record, when the mode changed
    settled: Settled | None = None  # a delivery that ended this cycle
    late: Late | None = None  # the command on its way is past its budget (None: on time, or none)
    events: tuple[tuple[str, dict], ...] = ()  # `delivery` records: a fallback taken, a delivery ended

    def undelivered(self, by: Requester) -> str | None:
        """Why `by`'s mode request failed this cycle (refused, or not shown in time); None: it did not."""
        s = self.settled
        return s.why if s is not None and s.by == by and s.outcome != Delivery.SHOWN else None


class _Pending:
    """A mode command on its way: sent every cycle until answered or shown."""

    def __init__(self, t: float, mode: str, what: str, by: Requester, asked: str, chain: tuple[str, ...],
                 t_mode: float):
        self.t0, self.mode, self.what, self.by, self.asked, self.t_mode = t, mode, what, by, asked, t_mode
        self.t_asked = t  # when the request itself was first sent (a fallback keeps its request's)
        self.t_heard = t  # the mode-shown clock's start: the first send, or the link's return after a loss
        self.chain = chain  # the ways to stop still left after this one (a Hold's fallbacks)
        self.state = Delivery.SENDING
        self.sends = 0
        self.t_sent = -math.inf
        self.refusal: str | None = None  # the autopilot's answer, when it refused


GUARANTEE_ANSWERED = "a command reaches the autopilot within t_cmd (re-sent every cycle)"
GUARANTEE_SHOWN = "a requested mode is shown within t_mode"


class ModeAuthority:
    def __init__(self, hold_mode: str, t_cmd_s: float = 0.1, t_mode_s: float = 1.2,
                 hold_fallbacks: tuple[str, ...] = ()):
        """`hold_mode`: the adapter's name of the autopilot's Hold (PX4 Hold, ArduPilot Brake); `t_cmd_s`: the time
        within which a command reaches the autopilot (answered or shown; the stop contract budgets it);
        `t_mode_s`: within which a requested mode is shown; `hold_fallbacks`: the adapter's next ways to stop when
        Hold is refused or not shown (in order)."""
        self.hold_mode, self.t_cmd_s, self.t_mode_s = hold_mode, t_cmd_s, t_mode_s
        self.hold_fallbacks = tuple(hold_fallbacks)
        self.pending: _Pending | None = None  # the command on its way, or the last one delivered
        self._mode: str | None = None  # the mode last seen with the link up

    # ------------------------------------------------------------------ the autopilot's side
    def answer(self, result: int) -> None:
        """A COMMAND_ACK of DO_SET_MODE: the command on its way is accepted, or refused."""
        p = self.pending
        if p is None or p.state != Delivery.SENDING:
            return
        if result in ACCEPTED_RESULTS:
            p.state = Delivery.ACCEPTED
        else:
            p.refusal = f"DO_SET_MODE answered {result}"

    def observe(self, t: float, mode: str, link_ok: bool) -> ModeView:
        """This cycle's mode: whether the daemon commanded it, whether someone else just changed it (with the
        link down the mode is unknown, not changed), and how the command on its way fares."""
        p, settled, events = self.pending, None, []
        if p is not None and p.state in (Delivery.SENDING, Delivery.ACCEPTED) and not link_ok:
            p.t_heard = t  # the mode is unknown: not judged until the link is back
        elif p is not None and p.state in (Delivery.SENDING, Delivery.ACCEPTED):
            if mode == p.mode:
                p.state = Delivery.SHOWN
                settled = Settled(p.asked, p.by, Delivery.SHOWN)
            elif p.refusal is not None or t - p.t_heard > p.t_mode:
                why = p.refusal or f"{p.what} not shown within {p.t_mode:g} s"
                settled = self._failed(t, p, why, events)
            if settled is not None:
                events.append(("delivery", {"cmd": p.what, "outcome": settled.outcome, "sends": p.sends,
                                            "waited_s": t - p.t0, "by": p.by.name.lower()}
                               | ({"why": settled.why} if settled.why else {})))
        p = self.pending
        changed = link_ok and mode != self._mode and self._mode is not None
        if p is not None and p.state == Delivery.SHOWN and mode != p.mode and link_ok:
            self.pending = p = None  # left it since: a later return to that mode is not ours
        by_daemon = p is not None and p.state == Delivery.SHOWN
        event, taken_over = None, False
        if link_ok and mode != self._mode:
            if changed:
                taken_over = not by_daemon
                event = ("mode_change", {"from": self._mode, "to": mode, "by": "other" if taken_over else "daemon"})
                if taken_over:
                    self.pending = None  # someone else decided: what was on its way is not sent again
            self._mode = mode
        return ModeView(mode, by_daemon, taken_over, event, settled, self._late(t), tuple(events))

    def _failed(self, t: float, p: _Pending, why: str, events: list) -> Settled | None:
        """A command refused or not shown in time: a Hold takes its next fallback (None: still on its way), any
        other mode is given up."""
        if p.chain:
            nxt = _Pending(t, p.chain[0], p.chain[0], p.by, p.asked, p.chain[1:], self.t_mode_s)
            nxt.t_asked = p.t_asked
            events.append(("delivery", {"cmd": p.what, "outcome": "fallback", "why": why, "next": nxt.what,
                                        "sends": p.sends, "waited_s": t - p.t0, "by": p.by.name.lower()}))
            self.pending = nxt
            return None
        p.state = Delivery.REFUSED if p.refusal is not None else Delivery.NOT_SHOWN
        return Settled(p.asked, p.by, p.state, why)

    def _late(self, t: float) -> Late | None:
        """The delivery guarantee broken now: a command neither answered nor shown within t_cmd_s; a Hold refused or
        not shown within t_mode_s (from then until someone else decides: its fallback flies meanwhile). Another
        mode refused is its requester's to judge (the recovery brake's switch, offboard's entry)."""
        p = self.pending
        if p is None:
            return None
        waited = t - p.t0
        if p.asked == HOLD and (p.what != HOLD or p.state in (Delivery.REFUSED, Delivery.NOT_SHOWN)):
            now = f"{p.what} {p.state}" if p.what != HOLD else f"Hold {p.state}: given up"
            return Late(GUARANTEE_SHOWN, self.t_mode_s, t - p.t_asked, f"Hold not taken: {now}")
        if p.state == Delivery.SENDING and waited > self.t_cmd_s:
            action = f"re-sending {p.what}" + (f", then {', '.join(p.chain)}" if p.chain else "")
            return Late(GUARANTEE_ANSWERED, self.t_cmd_s, waited, action)
        return None

    # ------------------------------------------------------------------ the daemon's side
    def arbitrate(self, t: float, requests) -> ModeCommand | None:
        """The command to send this cycle (None: none): the request that wins, or the one on its way, re-sent
        every cycle until the autopilot answers or shows it. A request never displaces one of higher priority
        that is still on its way (or shown); the same mode asked again continues its delivery (its clock keeps
        running), or, shown, is not sent again."""
        p = self.pending
        on_way = p is not None and p.state in (Delivery.SENDING, Delivery.ACCEPTED)
        if requests:
            r = min(requests, key=lambda q: q.by)
            mode = self.hold_mode if r.mode == HOLD else r.mode
            # on its way, or shown and not left since: nothing new to send
            same = p is not None and p.asked == r.mode and (on_way or p.state == Delivery.SHOWN)
            if not same and (not on_way or r.by <= p.by):
                chain = self.hold_fallbacks if r.mode == HOLD else ()
                p = self.pending = _Pending(t, mode, r.mode, r.by, r.mode, chain, r.within_s or self.t_mode_s)
        if p is None or p.state != Delivery.SENDING:
            return None
        if t - p.t0 > self.t_cmd_s and t - p.t_sent < RESEND_LATE_S:  # past its budget: a link that is down is
            return None  # not flooded; within it, every cycle
        p.sends += 1
        p.t_sent = t
        return ModeCommand(p.mode, p.what, p.by, p.sends)
