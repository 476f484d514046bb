"""PX4 personality: how PX4 (multicopter, v1.14+) answers, numbers its modes and times out.

Facts (shared/reference/mavlink-facts.md): custom_mode = main << 16 | sub << 24
(`px4_custom_mode.h`); HEARTBEAT.autopilot = MAV_AUTOPILOT_PX4 (12); DO_CHANGE_SPEED always
ACCEPTED, param2 > 0 sets the Navigator's cruising speed (used by the auto modes only, not by
OFFBOARD), ≤ 0 resets it to MPC_XY_CRUISE, and NAV_TAKEOFF resets it (`navigator_main.cpp`);
NAV_TAKEOFF param7 is AMSL (`FlightTaskTakeoff.cpp`), raised to at least home + MIS_TAKEOFF_ALT,
NaN → home + MIS_TAKEOFF_ALT (Navigator `takeoff.cpp`); OFFBOARD needs a setpoint younger than COM_OF_LOSS_T (else
TEMPORARILY_REJECTED) and on loss does COM_OBL_RC_ACT; setpoints only in MAV_FRAME_LOCAL_NED and
MAV_FRAME_BODY_NED, per-axis NaN = not controlled; INT32 parameters are encoded bytewise.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from pymavlink.dialects.v20 import ardupilotmega as mav

from .autopilot import ACCEPTED, DENIED, TEMP_REJECTED, ParamSpec, Personality, Settings, _finite, _masked

MAIN = {"manual": 3, "hold": 4, "takeoff": 4, "land": 4, "mission": 4, "rtl": 4, "offboard": 6}
SUB = {"hold": 3, "takeoff": 2, "land": 6, "mission": 4, "rtl": 5}
AUTO_SUB_MODE = {1: "hold", 2: "takeoff", 3: "hold", 4: "mission", 5: "rtl", 6: "land"}
STICK_MAINS = (1, 2, 3, 5, 7, 8)  # MANUAL, ALTCTL, POSCTL, ACRO, STABILIZED, RATTITUDE
DEG = math.pi / 180.0
I32 = mav.MAV_PARAM_TYPE_INT32

# COM_OBL_RC_ACT: 0 Position, 1 Altitude, 2 Stabilized, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm
OBL_ACTIONS = {3: "rtl", 4: "land", 5: "hold"}


def _dcm(q) -> np.ndarray:
    """Rotation matrix body → NED of quaternion q = (w, x, y, z)."""
    w, x, y, z = (float(c) for c in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def custom_mode_of(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


class Px4(Personality):
    name = "px4"
    autopilot_id = mav.MAV_AUTOPILOT_PX4
    airborne_start_mode = "hold"  # scenario start.alt_m > 0
    initial_mode = "hold"
    estimator_status_msg = mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS
    hold_after_disarm_in = ("land", "takeoff", "rtl", "mission")  # the navigator leaves its auto modes
    capabilities = (mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
                    | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                    | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                    | mav.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET)
    params = (
        ParamSpec("MPC_TILTMAX_AIR", "tilt_max", DEG),  # deg
        ParamSpec("MPC_ACC_HOR", "acc_hor"),  # m/s²
        ParamSpec("MPC_JERK_AUTO", "jerk"),  # m/s³
        ParamSpec("MPC_XY_CRUISE", "cruise_default"),
        ParamSpec("MPC_XY_VEL_MAX", "vel_xy_max"),
        ParamSpec("MPC_Z_VEL_MAX_UP", "vel_up"),
        ParamSpec("MPC_Z_VEL_MAX_DN", "vel_dn"),
        ParamSpec("MPC_LAND_SPEED", "land_speed"),
        ParamSpec("MPC_TKO_SPEED", "takeoff_speed"),
        ParamSpec("MIS_TAKEOFF_ALT", "takeoff_alt"),
        ParamSpec("COM_OF_LOSS_T", "of_loss_t"),
        ParamSpec("COM_OBL_RC_ACT", "obl_action", 1.0, I32),
        ParamSpec("COM_DISARM_LAND", "disarm_land_s"),
        ParamSpec("NAV_ACC_RAD", "acc_rad"),
        ParamSpec("MPC_THR_HOVER", "hover_thrust"),  # reads the live hover-thrust estimate
        ParamSpec("MAV_SYS_ID", "sysid", 1.0, I32, read_only=True),
    )

    def init_settings(self, s: Settings) -> None:
        pass  # Settings' defaults are PX4's

    # ----- modes
    def default_custom(self, mode: str) -> int:
        return custom_mode_of(MAIN[mode], SUB.get(mode, 0))

    def takeoff_custom(self, ap) -> int:
        return self.default_custom("takeoff")

    def mode_from_custom(self, custom: int):
        main, sub = (custom >> 16) & 0xFF, (custom >> 24) & 0xFF
        if main in STICK_MAINS:
            return "manual", custom_mode_of(main)
        if main == 4 and sub in AUTO_SUB_MODE:
            return AUTO_SUB_MODE[sub], custom_mode_of(4, 3 if sub == 1 else sub)
        if main == 6:
            return "offboard", custom_mode_of(6)
        return None

    def mode_from_request(self, base_mode, p2, p3):
        if not (_finite(base_mode) and int(base_mode) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and _finite(p2)):
            return None
        sub = int(p3) if _finite(p3) else 0
        return self.mode_from_custom(custom_mode_of(int(p2) & 0xFF, sub & 0xFF))

    def base_mode_flags(self, ap) -> int:
        f = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        if ap.mode != "manual":
            f |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        if ap.mode in ("mission", "takeoff", "land", "rtl", "hold"):
            f |= mav.MAV_MODE_FLAG_AUTO_ENABLED
        if ap.armed:
            f |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        return f

    def auto_start_state(self, ap, old: str):
        """FlightTaskAuto::activate: the position smoothing restarts from the last trajectory setpoint's
        position, velocity and acceleration (a NaN component: the current position / velocity, zero
        acceleration). Out of OFFBOARD that is the last position target streamed (an attitude target has
        none); out of another auto mode, the reference it was flying; out of a stick mode, the vehicle's
        state (its setpoint tracks the sticks, not modelled: the filtered acceleration, as before)."""
        if old in ("hold", "takeoff", "land", "mission", "rtl") and ap.in_air:
            return ap.traj.p.copy(), ap.traj.v.copy(), ap.traj.a.copy()
        if old != "offboard" or not ap.in_air:
            return super().auto_start_state(ap, old)
        ob = ap.ob
        if ob.q is not None:
            return ap.pos, ap.model.vel, np.zeros(3)
        p = np.where(np.isfinite(ob.pos), ob.pos, ap.pos)
        v = np.where(np.isfinite(ob.vel), ob.vel, ap.model.vel)
        a = np.where(np.isfinite(ob.acc), ob.acc, 0.0) * (1.0, 1.0, 0.0)
        return p, v, a

    # ----- parameters: INT32 bytewise in the float field
    def encode_param(self, value: float, ptype: int) -> float:
        if ptype == I32:
            return struct.unpack("<f", struct.pack("<i", int(round(value))))[0]
        return float(value)

    def decode_param(self, wire: float, ptype: int) -> float:
        if ptype == I32:
            return float(struct.unpack("<i", struct.pack("<f", wire))[0])
        return float(wire)

    # ----- commands
    def change_speed(self, ap, p) -> int:
        """Navigator: param2 > 0 → cruising speed; else back to MPC_XY_CRUISE. Always ACCEPTED;
        only the auto modes use it (OFFBOARD bypasses the Navigator)."""
        if _finite(p[1]) and p[1] > 0:
            ap.cruise = float(p[1])
        else:
            ap.cruise = ap.settings.cruise_default
        return ACCEPTED

    def takeoff(self, ap, p) -> int:
        """param7 is the take-off altitude AMSL. As PX4's Navigator (takeoff.cpp): below home +
        MIS_TAKEOFF_ALT it is raised to that (critical message); NaN → home + MIS_TAKEOFF_ALT (info);
        below the current altitude → stay at the current altitude."""
        if not ap.armed:
            ap.text(mav.MAV_SEVERITY_CRITICAL, "Takeoff denied: disarmed")
            return DENIED
        ap.cruise = ap.settings.cruise_default  # NAV_TAKEOFF resets the cruising speed
        min_alt = ap.settings.takeoff_alt
        msg = f"Using minimum takeoff altitude: {min_alt:.2f} m"
        if _finite(p[6]):
            alt_rel = float(p[6]) - ap.home_geo[2]
            if alt_rel < min_alt:
                ap.text(mav.MAV_SEVERITY_CRITICAL, msg)
                alt_rel = min_alt
        else:
            ap.text(mav.MAV_SEVERITY_INFO, msg)
            alt_rel = min_alt
        if alt_rel < -ap.pos[2]:
            ap.text(mav.MAV_SEVERITY_CRITICAL, "Already higher than takeoff altitude")
            alt_rel = -ap.pos[2]
        return ap.takeoff_to(alt_rel)

    def takeoff_done(self, ap) -> None:
        ap.set_mode("hold")

    def extra_command(self, ap, cmd: int, p: tuple, frame) -> int | None:
        """MAV_CMD_DO_REPOSITION (192): Hold at a location (param1 ground speed > 0 sets the cruising
        speed, param5/6 lat/lon — degrees, or 1e7·degrees from COMMAND_INT — param7 altitude AMSL;
        NaN keeps the current value)."""
        if cmd != mav.MAV_CMD_DO_REPOSITION:
            return None
        if not ap.in_air:
            return DENIED
        lat, lon, alt = p[4], p[5], p[6]
        if frame is not None and _finite(lat) and _finite(lon):  # COMMAND_INT: degE7
            lat, lon = lat * 1e-7, lon * 1e-7
        here = ap.geo_from_local(ap.pos)
        lat = lat if _finite(lat) else here[0]
        lon = lon if _finite(lon) else here[1]
        alt = alt if _finite(alt) else here[2]
        ap.set_mode("hold")
        if _finite(p[0]) and p[0] > 0:
            ap.cruise = float(p[0])
        ap.target = ap.local_from_geo(lat, lon, alt)
        return ACCEPTED

    # ----- offboard
    def can_enter_offboard(self, ap) -> int:
        if ap.time - ap.ob.time < ap.settings.of_loss_t:
            return ACCEPTED
        ap.text(mav.MAV_SEVERITY_CRITICAL, "Switching to Offboard is currently not available")
        return TEMP_REJECTED

    def offboard_setpoint(self, ap, dt: float) -> None:
        ob = ap.ob
        if ap.time - ob.time > ap.settings.of_loss_t:
            self._offboard_lost(ap)
            ap.update_mode_after_failsafe(dt)
            return
        if ob.q is not None:
            ap.set_attitude(ob.q, ob.thrust)
        else:
            ap.set_direct(ob.pos, ob.vel, ob.acc, ob.yaw, ob.yaw_rate)

    def _offboard_lost(self, ap) -> None:
        act = int(ap.settings.obl_action)
        ap.failsafe = "offboard lost"
        if act in OBL_ACTIONS:
            ap.set_mode(OBL_ACTIONS[act], reason=f"Failsafe: offboard lost, {OBL_ACTIONS[act]}")
        elif act in (6, 7):
            ap.set_mode("hold")
            ap.disarm(True, "Failsafe: offboard lost, " + ("terminate" if act == 6 else "disarm"))
        else:  # Position/Altitude/Stabilized need RC; without RC the SITL holds
            ap.set_mode("hold", reason="Failsafe: offboard lost, no RC for Position: Hold")

    def parse_position_target(self, ap, frame, mask, pos, vel, acc, yaw, yaw_rate):
        """As PX4's mavlink_receiver: LOCAL_NED per axis (ignored → NaN); BODY_NED rotates velocity
        and acceleration by the attitude (ignored axes of a used group → 0) and ignores position;
        FORCE_SET with an acceleration, another frame, or nothing valid → refused with a message."""
        if frame == mav.MAV_FRAME_LOCAL_NED:
            p, v, a = _masked(mask, pos, vel, acc)
        elif frame == mav.MAV_FRAME_BODY_NED:
            r = _dcm(ap.model.quat)
            p = np.full(3, math.nan)
            v, a = np.full(3, math.nan), np.full(3, math.nan)
            if not mask & 0o070 == 0o070:
                v = r @ np.where([(mask >> (3 + i)) & 1 for i in range(3)], 0.0, vel)
            if not mask & 0o700 == 0o700:
                a = r @ np.where([(mask >> (6 + i)) & 1 for i in range(3)], 0.0, acc)
        else:
            ap.text(mav.MAV_SEVERITY_CRITICAL, f"SET_POSITION_TARGET_LOCAL_NED coordinate frame {frame} unsupported")
            return None
        has_acc = bool(np.any(np.isfinite(a)))
        if has_acc and mask & mav.POSITION_TARGET_TYPEMASK_FORCE_SET:
            ap.text(mav.MAV_SEVERITY_CRITICAL, "SET_POSITION_TARGET_LOCAL_NED force not supported")
            return None
        if not (np.any(np.isfinite(p)) or np.any(np.isfinite(v)) or has_acc):
            ap.text(mav.MAV_SEVERITY_CRITICAL, "SET_POSITION_TARGET_LOCAL_NED invalid")
            return None
        yw = yaw if not mask & mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE else math.nan
        yr = yaw_rate if not mask & mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE else math.nan
        return p, v, a, yw, yr

    def mission_end(self, ap) -> None:
        ap.set_mode("hold", reason="Mission finished, loitering")
