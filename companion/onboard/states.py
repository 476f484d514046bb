"""The daemon's vocabulary as enums: its states, offboard's states, the kinds of setpoint guidance streams, the
causes of a Hold and the subsystems whose guarantees the contract watches. Logic compares members, never a
message's wording; each member's value is the string the event log has always written (a `StrEnum` is a `str`,
so it is written, compared with a log's strings and shown unchanged)."""

from __future__ import annotations

from enum import StrEnum


class State(StrEnum):
    """The supervisor's state (companion/onboard/supervisor.py)."""

    STANDBY = "standby"  # not engaged, not flying, or shadow mode
    ACTIVE = "active"  # the speed limit is commanded and checked
    HOLDING = "holding"  # the daemon commanded Hold
    FAILSAFE = "failsafe"  # the link to the autopilot is lost: nothing can be commanded


class OffboardState(StrEnum):
    """Offboard mode's control of the autopilot (companion/onboard/offboard.py)."""

    OFF = "off"
    ENTERING = "entering"
    FLYING = "flying"
    BRAKING = "braking"
    HELD = "held"
    DONE = "done"
    STOOD_DOWN = "stood_down"


# offboard streams setpoints in these states
STREAMING = frozenset((OffboardState.ENTERING, OffboardState.FLYING, OffboardState.BRAKING))
# offboard is over until asked anew (CG_ENGAGE off and on)
FINISHED = frozenset((OffboardState.DONE, OffboardState.STOOD_DOWN, OffboardState.HELD))


class SetpointKind(StrEnum):
    """What an offboard setpoint is doing (`guidance.Setpoint.mode`)."""

    CRUISE = "cruise"
    AVOID = "avoid"
    BRAKE = "brake"
    PLANNING = "planning"  # braking for the first plan
    HOLD = "hold"
    DONE = "done"


class Cause(StrEnum):
    """Why the supervisor stops the vehicle (each a `failsafe` or `hold_trigger` event's `cause`)."""

    NON_FINITE = "non-finite telemetry"
    STALE = "stale telemetry"
    BAD_NAV = "bad navigation estimate"
    NO_SAFE_SPEED = "no safe speed"
    LATE = "companion computer late"  # a cycle later than timeouts.cycle_late_s
    OBSTACLE = "obstacle inside the stop distance"
    NOT_IN_FORCE = "speed limit not in force"


AT_REST_M_S = 0.3  # [m/s] below this ground speed a stop is over (offboard's braking stop, the recovery brake's)

FAILSAFE_CAUSES = frozenset((Cause.NON_FINITE, Cause.STALE, Cause.BAD_NAV, Cause.NO_SAFE_SPEED, Cause.LATE))
# causes the daemon can fly out itself (its state estimate is sound): a braking stop, then Hold — offboard's fail-safe
# stop, and governor mode's recovery brake (the obstacle inside the stop distance: governor mode's alone)
BRAKE_STOP_CAUSES = frozenset((Cause.NO_SAFE_SPEED, Cause.NOT_IN_FORCE, Cause.OBSTACLE))


class Subsystem(StrEnum):
    """Whose guarantee a violation breaks (`violation_start.subsystem`)."""

    NAVIGATION = "navigation"
    CONTROLLER = "controller"
    ENVIRONMENT = "environment"
    ACTUATORS = "actuators"
    GUIDANCE = "guidance"
    AUTOPILOT = "autopilot"  # the autopilot accepts the recovery brake's switch (BRAKE_SWITCH), follows the
    # governor's approach ramp (RAMP_FOLLOWED)
    DELIVERY = "delivery"  # the link and the autopilot: a command reaches the autopilot and takes effect in time


# the autopilot's guarantees the governor's faster limits rest on (violation_start.guarantee of Subsystem.AUTOPILOT)
BRAKE_SWITCH = "accepts the recovery brake's switch"
CYCLE_COMPLETES = "every cycle decides (none ends in an internal error)"  # the daemon's own, guidance's
# guidance's too: its reference goes on from where it was; one put metres off the vehicle is flown to at the whole
# acceleration the autopilot allows, wherever that goes (the sensors' view, the speed limit)
REFERENCE_ON = "the reference flies on from where it was (no jump away from the vehicle)"
RAMP_FOLLOWED = "follows the governor's approach ramp"
