"""The actors that only ask for Hold (companion/onboard/turn.py's shape): the start-up checks failing again in
flight, and the shutdown (stop means stop)."""

from __future__ import annotations

from .authority import HOLD, ModeRequest, Requester
from .turn import Part, Turn

SHUTDOWN_WAIT_S = 1.0  # stop means stop: the shutdown waits this long at most for the autopilot to show its Hold
RECHECK_FAILED = "start-up checks failed in flight"  # a failed re-check while engaged in flight: Hold


class Recheck:
    """A start-up check that fails while the daemon was engaged in flight (the last cycle) holds, and says so."""

    def __init__(self):
        self._engaged_in_flight = False

    def step(self, turn: Turn) -> Part:
        was, self._engaged_in_flight = self._engaged_in_flight, turn.engaged_flying
        if turn.startup_ok is not False or not was or not turn.i.link_ok:
            return Part()
        return Part(requests=(ModeRequest(HOLD, Requester.FAILSAFE),),
                    events=(("failsafe", {"cause": RECHECK_FAILED, "action": "hold"}),),
                    texts=((2, f"CG: {RECHECK_FAILED}: holding"),))


class Shutdown:
    """Stop means stop: a daemon that stops while engaged in flight asks for Hold (the mode authority delivers it),
    waits until the autopilot shows it (`hold_mode`), SHUTDOWN_WAIT_S at most, and says so; on the ground, or not
    engaged, it just stops. `done` once decided."""

    def __init__(self, t: float, hold_mode: str):
        self.t0, self.hold_mode = t, hold_mode
        self.hold: bool | None = None  # a Hold was needed (None: not decided yet)
        self.confirmed = False
        self.done = False

    def step(self, turn: Turn) -> Part:
        if self.done:
            return Part()
        i, asked = turn.i, Part()
        if self.hold is None:
            self.hold = turn.engaged_flying and i.link_ok
            if not self.hold:
                self.done = True
                return Part(events=(("shutdown", {"hold": False, "reason": "not engaged in flight" if i.link_ok
                                                  else "no autopilot link"}),))
            asked = Part(requests=(ModeRequest(HOLD, Requester.SHUTDOWN),),
                         texts=((2, "CG: stopping in flight: Hold"),))
        if i.mode == self.hold_mode:  # the autopilot shows Hold (ours, or already someone else's)
            self.confirmed = True
        elif turn.t - self.t0 < SHUTDOWN_WAIT_S:
            return asked
        self.done = True
        texts = () if self.confirmed else \
            ((2, f"CG: Hold not confirmed in {SHUTDOWN_WAIT_S:g} s: the autopilot's own failsafe applies"),)
        return Part(requests=asked.requests, texts=asked.texts + texts,
                    events=(("shutdown", {"hold": True, "confirmed": self.confirmed, "waited_s": turn.t - self.t0}),))
