"""The autopilot's state as last reported, with the daemon-clock time each part arrived. Pure: fed
with decoded MAVLink messages (`update(t, msg)`), read by the daemon's cycle."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

MAV_LANDED_STATE_IN_AIR, MAV_LANDED_STATE_TAKEOFF, MAV_LANDED_STATE_LANDING = 2, 3, 4
MAV_MODE_FLAG_SAFETY_ARMED = 128
# [s] the attitudes of this long ago are kept: a sensor's frame may have been taken at any of them
# (the sensor's lag and its frame's own time, ATTITUDE's period)
ATTITUDE_WINDOW_S = 0.2
POSITION_TARGET_IGNORE_XY = 1 | 2


@dataclass
class Telemetry:
    t_heartbeat: float = -math.inf
    base_mode: int = 0
    custom_mode: int = 0
    autopilot: int = 0
    t_local: float = -math.inf
    x: float = math.nan
    y: float = math.nan
    z: float = math.nan
    vx: float = math.nan
    vy: float = math.nan
    vz: float = math.nan
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    throttle: float = math.nan  # fraction
    landed_state: int = 0
    target: tuple[float, float] | None = None  # commanded horizontal position
    t_target: float = -math.inf
    mission_seq: int = -1
    time_boot_ms: int | None = None
    attitudes: deque = field(default_factory=deque)  # (t, roll, pitch) of the last ATTITUDE_WINDOW_S

    def attitude_span(self) -> tuple[float, float, float]:
        """(least roll, most roll, most nose-down pitch) [rad] over the last ATTITUDE_WINDOW_S (the last reported
        where none is kept)."""
        if not self.attitudes:
            return self.roll, self.roll, self.pitch
        rolls = [a[1] for a in self.attitudes]
        return min(rolls), max(rolls), min(a[2] for a in self.attitudes)

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def in_air(self) -> bool:
        return self.landed_state in (MAV_LANDED_STATE_IN_AIR, MAV_LANDED_STATE_TAKEOFF, MAV_LANDED_STATE_LANDING)

    @property
    def ground_speed(self) -> float:
        return math.hypot(self.vx, self.vy)

    def update(self, t: float, msg) -> str | None:
        """Take one message from the autopilot; returns its type if it was used."""
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.t_heartbeat, self.base_mode, self.custom_mode = t, msg.base_mode, msg.custom_mode
            self.autopilot = msg.autopilot
        elif kind == "LOCAL_POSITION_NED":
            self.t_local = t
            self.x, self.y, self.z, self.vx, self.vy, self.vz = msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz
        elif kind == "ATTITUDE":
            self.roll, self.pitch, self.yaw = msg.roll, msg.pitch, msg.yaw
            self.attitudes.append((t, msg.roll, msg.pitch))
            while self.attitudes[0][0] < t - ATTITUDE_WINDOW_S:
                self.attitudes.popleft()
        elif kind == "VFR_HUD":
            self.throttle = msg.throttle / 100.0
        elif kind == "EXTENDED_SYS_STATE":
            self.landed_state = msg.landed_state
        elif kind == "POSITION_TARGET_LOCAL_NED":
            if not msg.type_mask & POSITION_TARGET_IGNORE_XY:
                self.target, self.t_target = (msg.x, msg.y), t
        elif kind == "MISSION_CURRENT":
            self.mission_seq = msg.seq
        else:
            return None
        tb = getattr(msg, "time_boot_ms", None)
        if tb is not None:
            self.time_boot_ms = tb
        return kind
