"""What differs between autopilots, behind one interface (one module per autopilot: px4.py, ardupilot.py;
the registry that finds them by name or HEARTBEAT id: autopilots.py).

Normalised mode names used across the daemon: takeoff, mission, hold, rtl, land, offboard (PX4
OFFBOARD / ArduPilot GUIDED), position, altitude, manual, other.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
INT_PARAM_TYPES = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}  # MAV_PARAM_TYPE → struct


def bytewise(value: float, param_type: int) -> float:
    """PX4's bytewise parameter encoding: an integer's bytes travel inside the float."""
    fmt = INT_PARAM_TYPES.get(param_type)
    if fmt is None:
        return float(value)
    raw = struct.pack("<f", value)
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])


@dataclass(frozen=True)
class ParamCheck:
    """An autopilot parameter the contract depends on: its name, how to turn its value into SI, and
    what the vehicle file assumes."""

    name: str
    scale: float  # SI = raw · scale
    what: str  # vehicle-file quantity it must agree with
    offboard_allowed: tuple[int, ...] = ()  # values offboard mode needs (empty: no such rule)
    offboard_need: str = ""  # those values in words, for the refusal line
    # the autopilot's setpoint time-out in offboard [s after `scale`]: checked against the daemon's setpoint period
    # (`startup.setpoint_timeout_problem`)
    setpoint_timeout: bool = False


class Adapter:
    name = "generic"
    autopilot_id = 0  # HEARTBEAT.autopilot

    def mode_name(self, base_mode: int, custom_mode: int) -> str:
        raise NotImplementedError

    def limit_applies(self, mode: str) -> bool:
        """Whether DO_CHANGE_SPEED is in force in this mode."""
        raise NotImplementedError

    def set_mode_params(self, mode: str, armed: bool) -> tuple[float, ...]:
        """COMMAND_LONG params 1–7 of MAV_CMD_DO_SET_MODE for a normalised mode name."""
        raise NotImplementedError

    def hold_mode(self) -> str:
        """The mode the daemon uses to stop (PX4 Hold, ArduPilot Brake)."""
        return "hold"

    # the next way to stop when Hold is refused or not shown in time (companion/onboard/authority.py): Land, which both
    # autopilots accept in flight in every state a Hold may be refused in (it needs no position estimate) and
    # which holds the horizontal position while it descends where it has one
    hold_fallbacks: tuple[str, ...] = ("land",)

    def speed_params(self, v: float) -> tuple[float, ...]:
        """MAV_CMD_DO_CHANGE_SPEED: ground speed v (> 0 always), throttle unchanged."""
        if not v > 0:
            raise ValueError("a speed command must be positive")
        return (1.0, float(v), -1.0, 0.0, 0.0, 0.0, 0.0)

    def reserved(self) -> float:
        """What unused COMMAND_LONG params carry (MAVSDK: NaN for PX4, 0 for ArduPilot)."""
        return 0.0

    def decode_param(self, value: float, param_type: int) -> float:
        """PARAM_VALUE.param_value as a number: ArduPilot casts integers to float (the default)."""
        return float(value)

    def takeoff_commands(self, alt_m: float) -> list[tuple[int, tuple[float, ...]]]:
        """COMMAND_LONGs (command, params 1–7) a ground station sends to take off to `alt_m` when armed."""
        raise NotImplementedError

    mission_item0_is_home = False  # the mission's item 0 is the home position, not a waypoint
    param_checks: tuple[ParamCheck, ...] = ()
    # the autopilot's own cruise speed in its auto modes (name, SI = raw · scale): a governor's speed
    # command sets that speed, so the daemon sends min(limit, cruise) and never speeds a mission up
    cruise_param: tuple[str, float] | None = None
