"""ArduPilot Copter specifics (shared/reference/mavlink-facts.md §2, §3; ArduCopter mode numbers)."""

from __future__ import annotations

from .autopilot_base import (
    MAV_CMD_DO_SET_MODE,
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    Adapter,
    ParamCheck,
)

MAV_CMD_NAV_TAKEOFF = 22

MODES = {0: "manual", 1: "manual", 2: "altitude", 3: "mission", 4: "offboard", 5: "position", 6: "rtl",
         9: "land", 16: "position", 17: "hold", 20: "other", 21: "rtl"}
TO_NUMBER = {"mission": 3, "offboard": 4, "position": 5, "rtl": 6, "land": 9, "hold": 17}  # hold = BRAKE


class ArduPilot(Adapter):
    name = "ardupilot"
    autopilot_id = 3  # MAV_AUTOPILOT_ARDUPILOTMEGA

    def mode_name(self, base_mode: int, custom_mode: int) -> str:
        return MODES.get(custom_mode, "other")

    def limit_applies(self, mode: str) -> bool:
        # only Auto and Guided implement set_speed_NE (GCS_Mavlink.cpp handle_MAV_CMD_DO_CHANGE_SPEED)
        return mode in ("mission", "offboard")

    def set_mode_params(self, mode: str, armed: bool) -> tuple[float, ...]:
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        return (float(base), float(TO_NUMBER[mode]), 0.0, 0.0, 0.0, 0.0, 0.0)

    def takeoff_commands(self, alt_m: float) -> list[tuple[int, tuple[float, ...]]]:
        # GUIDED, then NAV_TAKEOFF to a relative altitude (param 7)
        return [(MAV_CMD_DO_SET_MODE, self.set_mode_params("offboard", True)),
                (MAV_CMD_NAV_TAKEOFF, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, float(alt_m)))]

    mission_item0_is_home = True

    cruise_param = ("WPNAV_SPEED", 0.01)  # cm/s; every mode's init reloads it (AC_WPNav)
    param_checks = (
        ParamCheck("ANGLE_MAX", 0.01, "tilt_max_deg"),  # centidegrees
        ParamCheck("WPNAV_ACCEL", 0.01, "braking.accel_max_m_s2"),  # cm/s²
        ParamCheck("WPNAV_JERK", 1.0, "braking.jerk_max_m_s3"),
        ParamCheck("GUID_TIMEOUT", 1.0, "guided time-out [s]", setpoint_timeout=True),
    )

