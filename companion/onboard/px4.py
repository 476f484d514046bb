"""PX4 specifics (shared/reference/mavlink-facts.md §1, §3; PX4 px4_custom_mode.h, Navigator)."""

from __future__ import annotations

import math

from .autopilot_base import (
    MAV_CMD_DO_SET_MODE,
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    Adapter,
    ParamCheck,
    bytewise,
)

# custom_mode = main << 16 | sub << 24
MAIN = {1: "manual", 2: "altitude", 3: "position", 5: "manual", 6: "offboard", 7: "manual", 8: "manual"}
AUTO_SUB = {1: "other", 2: "takeoff", 3: "hold", 4: "mission", 5: "rtl", 6: "land", 7: "rtl", 8: "other"}
TO_MAIN_SUB = {"position": (3, 0), "offboard": (6, 0), "takeoff": (4, 2), "hold": (4, 3), "mission": (4, 4),
               "rtl": (4, 5), "land": (4, 6)}


class PX4(Adapter):
    name = "px4"
    autopilot_id = 12  # MAV_AUTOPILOT_PX4

    def mode_name(self, base_mode: int, custom_mode: int) -> str:
        if not base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return "other"
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        return AUTO_SUB.get(sub, "other") if main == 4 else MAIN.get(main, "other")

    def limit_applies(self, mode: str) -> bool:
        # Navigator's cruising speed is used by AUTO modes; not by Position/Offboard (MPC_XY_VEL_MAX there)
        return mode in ("mission", "hold", "rtl")

    def set_mode_params(self, mode: str, armed: bool) -> tuple[float, ...]:
        main, sub = TO_MAIN_SUB[mode]
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        return (float(base), float(main), float(sub), math.nan, math.nan, math.nan, math.nan)

    def reserved(self) -> float:
        return math.nan

    def decode_param(self, value: float, param_type: int) -> float:
        return bytewise(value, param_type)  # PX4 encodes integer parameters bytewise

    def takeoff_commands(self, alt_m: float) -> list[tuple[int, tuple[float, ...]]]:
        # AUTO.TAKEOFF climbs to MIS_TAKEOFF_ALT (the parameter, not alt_m)
        return [(MAV_CMD_DO_SET_MODE, (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MAV_MODE_FLAG_SAFETY_ARMED),
                                       *map(float, TO_MAIN_SUB["takeoff"]), 0.0, 0.0, 0.0, 0.0))]

    cruise_param = ("MPC_XY_CRUISE", 1.0)  # m/s; DO_CHANGE_SPEED ≤ 0 resets to it (Navigator)
    param_checks = (
        ParamCheck("MPC_TILTMAX_AIR", 1.0, "tilt_max_deg"),
        ParamCheck("MPC_ACC_HOR", 1.0, "braking.accel_max_m_s2"),
        ParamCheck("MPC_JERK_AUTO", 1.0, "braking.jerk_max_m_s3"),
        ParamCheck("COM_OBL_RC_ACT", 1.0, "offboard-loss action (4 Land or 5 Hold for companion-only flight)",
                   offboard_allowed=(4, 5), offboard_need="4 (Land) or 5 (Hold)"),
    )
