"""The typed, timestamped samples MAVLink-in makes of the autopilot's and the sensors' messages, in SI
units and the frames of DESIGN.md §2 (local NED; body bearings clockwise from forward, radians). The
cycle (`companion/onboard/cycle.py`) takes nothing else, so any source of these — a live link or a flight
log — drives the same estimators.

Every obstacle sensor, whatever its message, becomes one `Scan`: the hits it sees now (body bearing,
range), the range it claims, its quality, and either its bins' span or nothing (a single beam, as wide
as its configured field of view).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Position:
    """The vehicle's horizontal position [m] (LOCAL_POSITION_NED): the contour error's measured side."""

    t: float
    x: float
    y: float


@dataclass(frozen=True, slots=True)
class Heading:
    """Yaw [rad] and ground speed [m/s] now (ATTITUDE with the last velocity)."""

    t: float
    yaw: float
    ground_speed: float


@dataclass(frozen=True, slots=True)
class PathTarget:
    """A point of the commanded path [m] as the autopilot reports it (POSITION_TARGET_LOCAL_NED)."""

    t: float
    x: float
    y: float


@dataclass(frozen=True, slots=True)
class Throttle:
    """Collective throttle (fraction) with the attitude [rad], vertical speed [m/s, down] and air state."""

    t: float
    throttle: float
    roll: float
    pitch: float
    vz_down: float
    in_air: bool | None  # None: the autopilot has not said (MAV_LANDED_STATE_UNDEFINED)


@dataclass(frozen=True, slots=True)
class NavStatus:
    """The autopilot's estimator flags, by message kind (ESTIMATOR_STATUS, EKF_STATUS_REPORT)."""

    t: float
    source: str
    flags: int


@dataclass(frozen=True, slots=True)
class Scan:
    """One obstacle sensor's sample. `hits`: (body bearing, range) of what it sees within `max_m` now;
    `known`: body bearings of the bins that report (a bin reporting nothing known is not free space;
    None: a single beam); `increment`: bin width [rad] (None: a single beam). An inconsistent message
    becomes a scan with quality 1 (invalid): it covers nothing."""

    t: float
    sensor: int  # index in the configured sensors
    hits: tuple[tuple[float, float], ...]
    max_m: float
    quality: int  # 0 unknown, 1 invalid, 2–100 (MAVLink signal_quality)
    known: tuple[float, ...] | None = None
    increment: float | None = None
    source: tuple | None = None  # who sent it: (system, component, DISTANCE_SENSOR id); None: the sensor's only source


@dataclass(frozen=True, slots=True)
class SourceRefused:
    """Messages refused for who sent them: ids no configured autopilot, sensor or ground station has
    (`what` "unknown"), or a pinned source's ids from another address (`what` "refused": a second autopilot,
    a spoofed sensor), a pinned source that followed a new address after falling silent ("moved"), a seat two
    addresses claim ("contested", until "uncontested"; `address`: every claimant) or a signed message whose
    signature does not verify under our key ("bad_signature")."""

    t: float
    what: str
    ids: tuple[int, int]
    autopilot: bool  # the ids are the autopilot's
    address: str | None = None  # where the refused messages came from (a UDP link's; None: not known)
    pinned: str | None = None  # the address the source is taken from
    count: int = 1  # refused since the last report
    held: str | None = None  # why no seat may move now ("engaged", "armed"), or None


@dataclass(frozen=True, slots=True)
class Implausible:
    """A message whose fields are not finite, out of range or inconsistent: dropped, counted, and — for
    the vehicle's state — a fault of the navigation estimate (the safe action follows)."""

    t: float
    kind: str  # message type
    why: str


@dataclass(frozen=True, slots=True)
class AutopilotRestart:
    """The autopilot's boot clock went back: it restarted (its parameters may have changed)."""

    t: float
    from_s: float
    to_s: float


@dataclass(frozen=True, slots=True)
class CommandAck:
    t: float
    command: int
    result: int


@dataclass(frozen=True, slots=True)
class AutopilotParam:
    """One of the autopilot's parameters, decoded to a number (the adapter knows the encoding)."""

    t: float
    name: str
    value: float


@dataclass(frozen=True, slots=True)
class MissionMessage:
    """A mission-protocol message for the mission download (companion/onboard/mission.py)."""

    t: float
    msg: object


@dataclass(frozen=True, slots=True)
class ParamRequest:
    """A parameter-protocol message addressed to the daemon (any ground station)."""

    msg: object
