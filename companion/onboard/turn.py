"""The one shape of the cycle's actors (DESIGN.md §5): each reads one frozen `Turn` — the cycle as the supervisor
decided it — and returns its `Part`: the modes it asks for, its events and STATUSTEXTs, and (the flying actors)
its setpoint. The cycle joins the parts into its one outbox; what a part asks of the supervisor (`latch`,
`switch_refused`) the cycle hands to the supervisor, which alone decides.

    actor                                   module                 wants
    offboard flight (offboard mode)         flying.py              OFFBOARD / GUIDED, its Hold, setpoints
    recovery brake (governor mode)          flying.py              OFFBOARD / GUIDED, its Hold, setpoints
    calibration hold legs (governor mode)   calibration_holds.py   Hold, then the mission
    re-check in flight                      cycle.py               Hold (the start-up checks failed in flight)
    shutdown                                cycle.py               Hold (stop means stop)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from .authority import ModeRequest

if TYPE_CHECKING:
    from .authority import ModeView
    from .guidance import Route, Setpoint
    from .supervisor import Decision, Inputs
    from .telemetry import Telemetry


@dataclass(frozen=True, slots=True)
class Turn:
    """One cycle as the actors read it."""

    t: float
    tel: Telemetry  # the vehicle as last reported
    i: Inputs  # what the supervisor judged
    d: Decision  # what it decided
    view: ModeView  # the mode, as the mode authority judged it
    startup_ok: bool | None  # the start-up checks (None: pending)
    engaged_flying: bool  # engaged, armed, in the air, in a mode that commands
    stopping: bool  # the daemon is stopping (the shutdown began)
    tilt: float | None  # the tilt of the last Ω with a speed to fly (the one flown), None before the first
    mission_route: Route | None = None  # the route downloaded from the autopilot's mission, if the route is that
    a0: tuple[float, float] | None = None  # the acceleration measured over the recovery brake's window [m/s²]


@dataclass(frozen=True, slots=True)
class Part:
    """One actor's part of the cycle's outbox, and what it asks of the supervisor."""

    requests: tuple[ModeRequest, ...] = ()
    events: tuple[tuple[str, dict], ...] = ()
    texts: tuple[tuple[int, str], ...] = ()
    setpoint: Setpoint | None = None  # SET_POSITION_TARGET_LOCAL_NED (the flying actors)
    end_stream: bool = False  # the setpoint stream ended this cycle
    braking: bool = False  # the supervisor's Hold is flown out as a braking stop (the Hold comes at rest)
    latch: str | None = None  # the supervisor's Hold is latched, for this reason
    switch_refused: tuple[bool, float] | None = None  # the recovery brake's switch: (refused now, judged at speed)


NOTHING = Part()
