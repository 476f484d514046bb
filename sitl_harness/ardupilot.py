"""ArduPilot Copter personality: mode numbers, GUIDED semantics, DO_CHANGE_SPEED, parameters.

Facts (shared/reference/mavlink-facts.md): HEARTBEAT.autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA (3),
custom_mode = the Copter mode number (STABILIZE 0, ACRO 1, ALT_HOLD 2, AUTO 3, GUIDED 4, LOITER 5,
RTL 6, LAND 9, POSHOLD 16, BRAKE 17, SMART_RTL 21); DO_CHANGE_SPEED (GCS_Mavlink.cpp): param2 ≤ 0
→ DENIED, a mode other than Auto/Guided → FAILED, speed type 0/1 horizontal, 2 climb, 3 descent;
a mode change reloads the WPNAV speeds; NAV_TAKEOFF only in GUIDED and armed, param7 *relative*
altitude; SET_POSITION_TARGET_LOCAL_NED in GUIDED: position, velocity and acceleration each all
three axes or none, frames LOCAL_NED, LOCAL_OFFSET_NED, BODY_NED, BODY_OFFSET_NED; velocity and
acceleration targets stop the vehicle when not refreshed within GUID_TIMEOUT, position targets
never time out (no mode failsafe); parameters C-cast encoded; mission item 0 is home.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from .autopilot import ACCEPTED, DENIED, FAILED, ParamSpec, Personality, Settings, _finite, _masked, _rot

MODES = {0: "manual", 1: "manual", 2: "manual", 3: "mission", 4: "offboard", 5: "hold", 6: "rtl", 9: "land",
         16: "hold", 17: "hold", 21: "rtl"}
DEFAULT = {"manual": 0, "mission": 3, "offboard": 4, "takeoff": 4, "hold": 5, "rtl": 6, "land": 9}
CDEG = math.pi / 18000.0
CM = 0.01
I16 = mav.MAV_PARAM_TYPE_INT16
I8 = mav.MAV_PARAM_TYPE_INT8


class ArduPilot(Personality):
    name = "ardupilot"
    autopilot_id = mav.MAV_AUTOPILOT_ARDUPILOTMEGA
    airborne_start_mode = "offboard"  # scenario start.alt_m > 0
    initial_mode = "manual"  # STABILIZE
    mission_skips_home = True
    estimator_status_msg = mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT
    capabilities = (mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
                    | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                    | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED)
    params = (
        ParamSpec("ANGLE_MAX", "tilt_max", CDEG, I16),  # centidegrees
        ParamSpec("WPNAV_ACCEL", "acc_hor", CM),  # cm/s²
        ParamSpec("WPNAV_JERK", "jerk"),  # m/s³
        ParamSpec("WPNAV_SPEED", "cruise_default", CM),  # cm/s
        ParamSpec("WPNAV_SPEED_UP", "vel_up", CM),
        ParamSpec("WPNAV_SPEED_DN", "vel_dn", CM),
        ParamSpec("LAND_SPEED", "land_speed", CM, I16),
        ParamSpec("WPNAV_RADIUS", "acc_rad", CM),
        ParamSpec("GUID_TIMEOUT", "guid_timeout"),
        ParamSpec("MOT_THST_HOVER", "hover_thrust"),  # reads the live (learned) hover thrust
        ParamSpec("SYSID_THISMAV", "sysid", 1.0, I16, read_only=True),
    )

    def init_settings(self, s: Settings) -> None:
        s.cruise_default = 10.0  # WPNAV_SPEED 1000 cm/s (AC_WPNav.cpp, Copter 4.x; older 500)
        s.land_speed = 0.5  # LAND_SPEED 50 cm/s
        s.vel_up = 2.5  # WPNAV_SPEED_UP 250 cm/s
        s.takeoff_speed = 2.5
        s.disarm_land_s = 1.0  # LAND disarms shortly after touchdown (not DISARM_DELAY's 10 s rule)

    # ----- modes
    def default_custom(self, mode: str) -> int:
        return DEFAULT[mode]

    def takeoff_custom(self, ap) -> int:
        return DEFAULT["offboard"]  # the take-off runs inside GUIDED

    def mode_from_custom(self, custom: int):
        mode = MODES.get(int(custom))
        return None if mode is None else (mode, int(custom))

    def mode_from_request(self, base_mode, p2, p3):
        if not _finite(p2):
            return None
        return self.mode_from_custom(int(p2))

    def base_mode_flags(self, ap) -> int:
        f = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        if ap.mode in ("offboard", "takeoff", "mission", "rtl", "land", "hold"):
            f |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        if ap.mode == "mission":
            f |= mav.MAV_MODE_FLAG_AUTO_ENABLED
        if ap.armed:
            f |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        return f

    # ----- parameters: C-cast (the value itself in the float)
    def encode_param(self, value: float, ptype: int) -> float:
        return float(round(value)) if ptype in (I16, I8, mav.MAV_PARAM_TYPE_INT32) else float(value)

    def decode_param(self, wire: float, ptype: int) -> float:
        if not math.isfinite(wire):
            return math.nan
        return float(round(wire)) if ptype in (I16, I8, mav.MAV_PARAM_TYPE_INT32) else float(wire)

    def on_mode_change(self, ap, old: str, new: str) -> None:
        # every mode's init reloads WPNAV_SPEED / _UP / _DN
        ap.cruise = ap.settings.cruise_default
        ap.speed_up = ap.speed_down = None
        if new == "offboard" and not (old == "takeoff"):
            ap.target = None
            ap.guided_direct = False
            ap.traj.reset(ap.pos, ap.model.vel)
            ap.ob.time = -math.inf  # targets sent before GUIDED are not acted on

    # ----- commands
    def change_speed(self, ap, p) -> int:
        if not _finite(p[1]) or p[1] <= 0.0:
            return DENIED
        if ap.mode not in ("mission", "offboard"):
            return FAILED
        kind = int(p[0]) if _finite(p[0]) else 1
        if kind in (0, 1):
            ap.cruise = float(p[1])
        elif kind == 2:
            ap.speed_up = float(p[1])
        elif kind == 3:
            ap.speed_down = float(p[1])
        else:
            return FAILED
        return ACCEPTED

    def takeoff(self, ap, p) -> int:
        """GUIDED and armed only; param7 is the altitude *relative* to home [m]."""
        if ap.mode != "offboard" or not ap.armed or ap.in_air:
            return FAILED
        if not _finite(p[6]) or p[6] <= 0:
            return FAILED
        return ap.takeoff_to(float(p[6]))

    def takeoff_done(self, ap) -> None:
        ap.set_mode("offboard", DEFAULT["offboard"])
        ap.target = ap.takeoff_target.copy()
        ap.guided_direct = False

    # ----- guided
    def can_enter_offboard(self, ap) -> int:
        return ACCEPTED

    def on_new_target(self, ap) -> None:
        ob = ap.ob
        if ob.q is None and np.all(np.isnan(ob.vel)) and np.all(np.isnan(ob.acc)):
            ap.target = ob.pos.copy()  # position-only: waypoint navigation at the WPNAV speed
            if getattr(ap, "guided_direct", False):
                ap.traj.reset(ap.pos, ap.model.vel)
            ap.guided_direct = False

    def offboard_setpoint(self, ap, dt: float) -> None:
        ob = ap.ob
        fresh = ap.time - ob.time <= ap.settings.guid_timeout
        direct = ob.time > -math.inf and (ob.q is not None or not (np.all(np.isnan(ob.vel)) and np.all(np.isnan(ob.acc))))
        if direct and fresh:
            ap.guided_direct = True
            if ob.q is not None:
                ap.set_attitude(ob.q, ob.thrust)
            else:
                ap.set_direct(ob.pos, ob.vel, ob.acc, ob.yaw, ob.yaw_rate)
            return
        if direct and not fresh and getattr(ap, "guided_direct", False):
            # velocity/acceleration/attitude target timed out: stop and hold
            ap.text(mav.MAV_SEVERITY_WARNING, "Guided: target timed out, stopping")
            ap.traj.reset(ap.pos, ap.model.vel)
            ap.target = None
            ap.guided_direct = False
            ob.time = -math.inf
        if ob.time > -math.inf and _finite(ob.yaw):
            ap.yaw_sp = ob.yaw
        ap._fly_traj(dt, ap.target, face=not _finite(ob.yaw) and ob.time > -math.inf)

    def parse_position_target(self, ap, frame, mask, pos, vel, acc, yaw, yaw_rate):
        if frame not in (mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_OFFSET_NED, mav.MAV_FRAME_BODY_NED,
                         mav.MAV_FRAME_BODY_OFFSET_NED):
            return None
        groups = [(mask >> k) & 7 for k in (0, 3, 6)]
        if any(g not in (0, 7) for g in groups) or all(g == 7 for g in groups):
            return None  # each of pos/vel/acc needs all three axes, and one of them is required
        p, v, a = _masked(mask, pos, vel, acc)
        c, s = math.cos(ap.yaw), math.sin(ap.yaw)
        if frame == mav.MAV_FRAME_LOCAL_OFFSET_NED:
            p = p + ap.pos
        elif frame == mav.MAV_FRAME_BODY_NED:
            v, a = _rot(v, c, s), _rot(a, c, s)
        elif frame == mav.MAV_FRAME_BODY_OFFSET_NED:
            p = _rot(p, c, s) + ap.pos
            v, a = _rot(v, c, s), _rot(a, c, s)
        yw = yaw if not mask & mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE else math.nan
        yr = yaw_rate if not mask & mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE else math.nan
        return p, v, a, yw, yr

    def mission_end(self, ap) -> None:
        pass  # Copter stays in AUTO and hovers at the last waypoint
