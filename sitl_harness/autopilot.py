"""Autopilot emulation shared by both personalities: modes, arming, auto trajectories, offboard.

Internal modes (personalities map them to their own mode numbers, `px4.py`, `ardupilot.py`):
`manual` (a stick mode with no RC: holds position in the air, idles on the ground), `hold`,
`takeoff`, `land`, `mission`, `offboard` (PX4 OFFBOARD / ArduPilot GUIDED), `rtl`.

Everything a personality does differently (mode numbers, DO_CHANGE_SPEED, take-off altitude
reference, offboard/guided time-outs, parameter names and encodings, position-target rules) lives
in its module behind the small `Personality` interface below; this module has the behaviour both
share. No I/O: the MAVLink endpoint calls `handle_command`, `handle_position_target`, … and reads
the state; `update` writes the cascade's setpoint.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from contracts.geodesy import geo_from_ne, ne_from_geo

from .control import (C_TILT_MAX, C_VEL_DN_MAX, C_VEL_UP_MAX, C_VEL_XY_MAX, M_ATT, M_IDLE, M_OFF, M_POS, S_ACCF,
                      S_HOVER, SP_ACC, SP_HTE, SP_MODE, SP_POS, SP_Q, SP_THRUST, SP_VEL, SP_YAW, SP_YAWRATE)
from .kernel import VehicleModel
from .physics import euler_from_quat
from .trajectory import AutoTrajectory

ACCEPTED = mav.MAV_RESULT_ACCEPTED
DENIED = mav.MAV_RESULT_DENIED
FAILED = mav.MAV_RESULT_FAILED
UNSUPPORTED = mav.MAV_RESULT_UNSUPPORTED
TEMP_REJECTED = mav.MAV_RESULT_TEMPORARILY_REJECTED
FORCE_MAGIC = 21196  # COMPONENT_ARM_DISARM param2: force (common.xml)


@dataclass(frozen=True)
class ParamSpec:
    """A parameter as the personality names it: internal value = `value · scale` (SI)."""

    name: str
    field: str
    scale: float = 1.0
    ptype: int = mav.MAV_PARAM_TYPE_REAL32
    read_only: bool = False


@dataclass
class Settings:
    """The autopilot's tunables in SI units (set from personality parameters)."""

    tilt_max: float
    acc_hor: float
    jerk: float
    cruise_default: float = 5.0  # PX4 MPC_XY_CRUISE default
    vel_xy_max: float = 12.0
    vel_up: float = 3.0
    vel_dn: float = 1.5
    land_speed: float = 0.7  # PX4 MPC_LAND_SPEED default
    takeoff_speed: float = 1.5  # PX4 MPC_TKO_SPEED default
    takeoff_alt: float = 2.5  # PX4 MIS_TAKEOFF_ALT default
    of_loss_t: float = 1.0  # PX4 COM_OF_LOSS_T default
    obl_action: float = 0.0  # PX4 COM_OBL_RC_ACT default (Position)
    guid_timeout: float = 3.0  # ArduPilot GUID_TIMEOUT default
    disarm_land_s: float = 2.0  # PX4 COM_DISARM_LAND default
    acc_rad: float = 2.0  # PX4 NAV_ACC_RAD default
    hover_thrust: float = 0.5
    sysid: float = 1.0


@dataclass
class MissionItem:
    seq: int
    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: float  # lat (deg) or local x (m)
    y: float
    z: float
    local: np.ndarray | None = None  # resolved NED target (NaN where unused)


@dataclass
class OffboardTarget:
    pos: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    vel: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    acc: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    yaw: float = math.nan
    yaw_rate: float = math.nan
    q: np.ndarray | None = None  # attitude target (SET_ATTITUDE_TARGET)
    thrust: float = math.nan
    time: float = -math.inf


class Personality:
    """What differs between autopilots; one subclass per module (`px4.Px4`, `ardupilot.ArduPilot`).

    Every hook gets the `Autopilot` and returns a MAV_RESULT where a command is answered."""

    name = "generic"
    autopilot_id = mav.MAV_AUTOPILOT_GENERIC
    initial_mode = "manual"
    airborne_start_mode = "hold"
    params: tuple[ParamSpec, ...] = ()
    capabilities = 0
    mission_skips_home = False  # ArduPilot: mission item 0 is home
    estimator_status_msg = mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS  # the estimator-health message it streams
    hold_after_disarm_in: tuple[str, ...] = ()  # modes a disarm leaves for Hold (PX4: the auto modes)

    def init_settings(self, s: Settings) -> None: ...
    def default_custom(self, mode: str) -> int: raise NotImplementedError
    def takeoff_custom(self, ap: "Autopilot") -> int: raise NotImplementedError
    def mode_from_request(self, base_mode, p2, p3) -> tuple[str, int] | None: raise NotImplementedError
    def mode_from_custom(self, custom: int) -> tuple[str, int] | None: raise NotImplementedError
    def base_mode_flags(self, ap: "Autopilot") -> int: raise NotImplementedError
    def encode_param(self, value: float, ptype: int) -> float: raise NotImplementedError
    def decode_param(self, wire: float, ptype: int) -> float: raise NotImplementedError
    def change_speed(self, ap: "Autopilot", p: tuple) -> int: raise NotImplementedError
    def takeoff(self, ap: "Autopilot", p: tuple) -> int: raise NotImplementedError
    def takeoff_done(self, ap: "Autopilot") -> None: raise NotImplementedError
    def can_enter_offboard(self, ap: "Autopilot") -> int: raise NotImplementedError
    def offboard_setpoint(self, ap: "Autopilot", dt: float) -> None: raise NotImplementedError
    def parse_position_target(self, ap, frame, mask, pos, vel, acc, yaw, yaw_rate): raise NotImplementedError
    def on_new_target(self, ap: "Autopilot") -> None: ...
    def on_mode_change(self, ap: "Autopilot", old: str, new: str) -> None: ...

    def auto_start_state(self, ap: "Autopilot", old: str):
        """(p, v, a) an auto mode's jerk-limited reference starts from when entered from mode `old`. Here
        ArduPilot's (AC_PosControl::init_xy_controller: the current position and velocity, and the acceleration
        of the current lean angles — the filtered acceleration; none vertically)."""
        acc = ap.model.s[S_ACCF:S_ACCF + 3] * (1.0, 1.0, 0.0) if ap.in_air else np.zeros(3)
        return ap.pos, ap.model.vel, acc

    def mission_end(self, ap: "Autopilot") -> None: raise NotImplementedError
    def extra_command(self, ap: "Autopilot", cmd: int, p: tuple, frame) -> int | None: return None


class Autopilot:
    """A small multicopter autopilot flying a `VehicleModel` (see module docstring)."""

    def __init__(self, model: VehicleModel, personality: Personality, home=(47.397742, 8.545594, 488.0),
                 cruise_speed: float | None = None):
        self.model = model
        self.pers = personality
        v = model.vehicle
        self.settings = Settings(tilt_max=v.tilt_max, acc_hor=v.braking.accel_max_m_s2,
                                 jerk=v.braking.jerk_max_m_s3, hover_thrust=v.controller.thr_hover)
        personality.init_settings(self.settings)
        if cruise_speed is not None:
            self.settings.cruise_default = cruise_speed
        self.traj = AutoTrajectory(self.settings.acc_hor, self.settings.jerk)
        self.home_geo = tuple(float(h) for h in home)
        self.home = np.zeros(3)
        self.armed = False
        self.mode = personality.initial_mode
        self.custom = personality.default_custom(self.mode)
        self.time = 0.0
        self.cruise = self.settings.cruise_default  # current auto-mode speed (DO_CHANGE_SPEED)
        # misbehaviours (scenario faults, or set by a test): DO_CHANGE_SPEED accepted, not applied; a requested mode
        # accepted at once and entered `mode_delay_s` later (`mode_delay_only`: only "offboard" or only "hold"; None:
        # every mode); OFFBOARD / GUIDED refused ("denied": the answer says so; "silently": accepted, never entered)
        self.speed_commands_ignored = False
        self.mode_delay_s = 0.0
        self.mode_delay_only: str | None = None
        self.offboard_refused: str | None = None
        self.pending_mode: tuple[str, int, float] | None = None  # (mode, custom, when it is entered)
        self.speed_up: float | None = None  # ArduPilot climb/descent overrides
        self.speed_down: float | None = None
        self.target: np.ndarray | None = None  # goto target of hold/guided navigation
        self.ob = OffboardTarget()
        self.mission: list[MissionItem] = []
        self.mission_seq = 0
        self.mission_phase = ""
        self.last_nav_target: np.ndarray | None = None
        self.loiter_until = 0.0
        self.landed_since: float | None = 0.0
        self.armed_since = 0.0
        self.ever_airborne = False
        self.failsafe = ""
        self.prearm_ok = True
        self.texts: deque[tuple[int, str]] = deque(maxlen=64)
        self.reached: deque[int] = deque(maxlen=64)
        self.yaw_sp = self.yaw
        self.apply_limits()

    # ------------------------------------------------------------------ state helpers
    @property
    def pos(self) -> np.ndarray:
        return self.model.pos

    @property
    def yaw(self) -> float:
        return euler_from_quat(self.model.quat)[2]

    @property
    def in_air(self) -> bool:
        return self.armed and not self.model.resting

    def text(self, severity: int, msg: str) -> None:
        self.texts.append((severity, msg))

    def apply_limits(self) -> None:
        """Push parameter-backed limits into the cascade and the trajectory generator."""
        s = self.settings
        cp = self.model.cp
        cp[C_TILT_MAX] = s.tilt_max
        cp[C_VEL_XY_MAX] = s.vel_xy_max
        cp[C_VEL_UP_MAX] = s.vel_up
        cp[C_VEL_DN_MAX] = s.vel_dn
        self.traj.acc_hor = s.acc_hor
        self.traj.jerk = s.jerk

    def hover_thrust(self) -> float:
        return float(self.model.s[S_HOVER])

    def set_hover_thrust(self, value: float) -> None:
        self.model.s[S_HOVER] = value

    # ------------------------------------------------------------------ geodesy (flat earth)
    def local_from_geo(self, lat: float, lon: float, alt_amsl: float) -> np.ndarray:
        lat0, lon0, alt0 = self.home_geo
        x, y = ne_from_geo(lat, lon, lat0, lon0)
        return np.array([x, y, -(alt_amsl - alt0)])

    def geo_from_local(self, p) -> tuple[float, float, float]:
        lat0, lon0, alt0 = self.home_geo
        lat, lon = geo_from_ne(p[0], p[1], lat0, lon0)
        return lat, lon, alt0 - p[2]

    def frame_to_local(self, frame: int, x: float, y: float, z: float) -> np.ndarray | None:
        """A mission/command position in `frame` → NED (NaN components kept NaN); None if unsupported."""
        if frame in (mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT):
            p = self.local_from_geo(x, y, z) if math.isfinite(x) and math.isfinite(y) else np.array(
                [math.nan, math.nan, -(z - self.home_geo[2])])
            return p
        if frame in (mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            if math.isfinite(x) and math.isfinite(y) and (x != 0 or y != 0):
                p = self.local_from_geo(x, y, self.home_geo[2] + z)
            else:
                p = np.array([math.nan, math.nan, -z])
            return p
        if frame == mav.MAV_FRAME_LOCAL_NED:
            return np.array([x, y, z], dtype=float)
        return None

    # ------------------------------------------------------------------ modes
    def set_mode(self, mode: str, custom: int | None = None, reason: str = "") -> None:
        old = self.mode
        if mode != old or (custom is not None and custom != self.custom):
            self.mode = mode
            self.custom = self.pers.default_custom(mode) if custom is None else custom
            if mode in ("hold", "takeoff", "land", "mission", "rtl", "manual"):
                self.traj.reset(*self.pers.auto_start_state(self, old))
                self.target = None
            if mode == "offboard":
                self.target = None
            self.mission_phase = ""  # an interrupted mission phase (climb, land, RTL landing) ends
            self.yaw_sp = self.yaw
            self.pers.on_mode_change(self, old, mode)
            if reason:
                self.text(mav.MAV_SEVERITY_INFO, reason)

    def request_mode(self, base_mode: float, p2: float, p3: float) -> int:
        req = self.pers.mode_from_request(base_mode, p2, p3)
        if req is None:
            return UNSUPPORTED
        return self._enter(*req)

    def request_custom_mode(self, custom: int) -> int:
        req = self.pers.mode_from_custom(custom)
        if req is None:
            return UNSUPPORTED
        return self._enter(*req)

    def _enter(self, mode: str, custom: int) -> int:
        """A mode change asked for over MAVLink (it also ends a reported failsafe state)."""
        self.failsafe = ""
        self.pending_mode = None  # a newer request replaces one not yet entered
        if mode == "offboard":
            if self.offboard_refused == "denied":
                return DENIED
            if self.offboard_refused == "silently":
                return ACCEPTED
            res = self.pers.can_enter_offboard(self)
            if res != ACCEPTED:
                return res
        if mode == "mission" and not self.mission:
            self.text(mav.MAV_SEVERITY_WARNING, "Mission rejected: no mission")
            return DENIED
        if mode == "takeoff":  # selecting the take-off mode: climb MIS_TAKEOFF_ALT above here
            if not self.armed:
                return DENIED
            if self.in_air:
                self.set_mode("hold")
                return ACCEPTED
            return self.takeoff_to(-self.pos[2] + self.settings.takeoff_alt)
        if self.mode_delay_s > 0.0 and self.mode_delay_only in (None, mode):
            self.pending_mode = (mode, custom, self.time + self.mode_delay_s)
            return ACCEPTED
        self.set_mode(mode, custom)
        return ACCEPTED

    # ------------------------------------------------------------------ arming
    def arm(self, force: bool) -> int:
        if self.armed:
            return ACCEPTED
        if not force:
            if not self.model.resting:
                self.text(mav.MAV_SEVERITY_CRITICAL, "Arming denied: not landed")
                return DENIED
            if not self.prearm_ok:
                self.text(mav.MAV_SEVERITY_CRITICAL, "Arming denied: pre-arm checks failed")
                return DENIED
            if self.mode in ("land", "rtl"):
                self.text(mav.MAV_SEVERITY_CRITICAL, "Arming denied: mode not armable")
                return DENIED
        self.armed = True
        self.armed_since = self.time
        self.ever_airborne = False
        self.landed_since = self.time
        self.text(mav.MAV_SEVERITY_INFO, "Armed")
        return ACCEPTED

    def disarm(self, force: bool, reason: str = "Disarmed") -> int:
        if not self.armed:
            return ACCEPTED
        if self.in_air and not force:
            self.text(mav.MAV_SEVERITY_CRITICAL, "Disarming denied: in air")
            return DENIED
        self.armed = False
        self.failsafe = ""
        self.text(mav.MAV_SEVERITY_INFO, reason)
        if self.mode in self.pers.hold_after_disarm_in:
            self.set_mode("hold")
        return ACCEPTED

    # ------------------------------------------------------------------ commands
    def handle_command(self, cmd: int, p: tuple, frame: int | None = None) -> int:
        """COMMAND_LONG/COMMAND_INT semantics common to both autopilots (p = param1..7)."""
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            force = _finite(p[1]) and int(p[1]) == FORCE_MAGIC
            if not _finite(p[0]):
                return DENIED
            return self.arm(force) if p[0] > 0.5 else self.disarm(force)
        if cmd == mav.MAV_CMD_NAV_TAKEOFF:
            return self.pers.takeoff(self, p)
        if cmd == mav.MAV_CMD_NAV_LAND:
            if not self.armed:
                return DENIED
            self.set_mode("land")
            return ACCEPTED
        if cmd == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            if not self.armed:
                return DENIED
            self.set_mode("rtl")
            return ACCEPTED
        if cmd == mav.MAV_CMD_NAV_LOITER_UNLIM:
            self.set_mode("hold")
            return ACCEPTED
        if cmd == mav.MAV_CMD_DO_SET_MODE:
            return self.request_mode(p[0], p[1], p[2])
        if cmd == mav.MAV_CMD_DO_CHANGE_SPEED:
            return ACCEPTED if self.speed_commands_ignored else self.pers.change_speed(self, p)
        if cmd == mav.MAV_CMD_MISSION_START:
            if not self.mission:
                return DENIED
            if _finite(p[0]) and 0 <= int(p[0]) < len(self.mission):
                self.mission_seq = int(p[0])
            return self._enter("mission", self.pers.default_custom("mission"))
        if cmd == mav.MAV_CMD_DO_SET_MISSION_CURRENT:
            if _finite(p[0]) and 0 <= int(p[0]) < len(self.mission):
                self.mission_seq = int(p[0])
                self.mission_phase = ""
                return ACCEPTED
            return DENIED
        res = self.pers.extra_command(self, cmd, p, frame)
        return UNSUPPORTED if res is None else res

    def takeoff_to(self, alt_rel: float) -> int:
        """Common take-off: climb vertically to `alt_rel` m above home (personality checks first)."""
        if not self.armed:
            self.text(mav.MAV_SEVERITY_CRITICAL, "Takeoff denied: disarmed")
            return DENIED
        if not math.isfinite(alt_rel) or alt_rel <= 0.0:
            return DENIED
        self.takeoff_target = np.array([self.pos[0], self.pos[1], self.home[2] - alt_rel])
        self.set_mode("takeoff", self.pers.takeoff_custom(self))
        self.traj.reset(self.pos, self.model.vel)
        return ACCEPTED

    # ------------------------------------------------------------------ offboard targets
    def handle_position_target(self, frame: int, mask: int, pos, vel, acc, yaw: float, yaw_rate: float) -> bool:
        """SET_POSITION_TARGET_LOCAL_NED (type_mask bit set = ignore, NaN = ignore). False if refused."""
        parsed = self.pers.parse_position_target(self, frame, mask, np.array(pos, float), np.array(vel, float),
                                                 np.array(acc, float), yaw, yaw_rate)
        if parsed is None:
            return False
        p, v, a, yw, yr = parsed
        self.ob = OffboardTarget(p, v, a, yw, yr, None, math.nan, self.time)
        if self.mode == "offboard":
            self.pers.on_new_target(self)
        return True

    def handle_attitude_target(self, q, thrust: float, ignore_attitude: bool) -> None:
        """SET_ATTITUDE_TARGET: flies attitude + thrust in offboard, otherwise only a keep-alive."""
        t = self.ob
        if ignore_attitude or not all(_finite(c) for c in q) or not _finite(thrust):
            t.time = self.time
            return
        self.ob = OffboardTarget(q=np.array(q, float), thrust=float(thrust), time=self.time)

    # ------------------------------------------------------------------ the navigation tick
    def update(self, t: float, dt: float) -> None:
        """Advance the autopilot by one navigation tick and write the cascade's setpoint."""
        self.time = t
        # `time` at a request is the tick before the one it arrived in: entered `mode_delay_s` after its arrival
        if self.pending_mode is not None and t > self.pending_mode[2] + 1e-9:
            mode, custom, _ = self.pending_mode
            self.pending_mode = None
            self.set_mode(mode, custom)
        m = self.model
        sp = m.sp
        if m.resting:
            if self.landed_since is None:
                self.landed_since = t
        else:
            self.landed_since = None
            if self.armed:
                self.ever_airborne = True
        if not self.armed:
            sp[SP_MODE] = M_OFF
            sp[SP_HTE] = 0.0
            return
        # auto-disarm: after landing (COM_DISARM_LAND) or when armed but never flown (10 s)
        if self.landed_since is not None:
            idle_for = t - self.landed_since
            if (self.ever_airborne and idle_for > self.settings.disarm_land_s) or (
                    not self.ever_airborne and idle_for > 10.0 and self.mode not in ("takeoff", "offboard", "mission")):
                self.disarm(False, "Disarmed (landed)")
                sp[SP_MODE] = M_OFF
                return
        sp[SP_HTE] = 0.0 if m.resting else 1.0
        self._dispatch(dt)

    def update_mode_after_failsafe(self, dt: float) -> None:
        """Run the mode a failsafe just switched to within the same tick."""
        if self.mode != "offboard" and self.armed:
            self._dispatch(dt)

    def _dispatch(self, dt: float) -> None:
        m = self.model
        mode = self.mode
        if mode == "offboard":
            self.pers.offboard_setpoint(self, dt)
        elif mode == "takeoff":
            self._fly_traj(dt, self.takeoff_target, up=self.settings.takeoff_speed)
            if abs(self.pos[2] - self.takeoff_target[2]) < 0.1 and abs(self.model.vel[2]) < 0.3:
                self.text(mav.MAV_SEVERITY_INFO, "Takeoff complete")
                self.pers.takeoff_done(self)
        elif mode == "land":
            self._land(dt)
        elif mode == "rtl":
            self._rtl(dt)
        elif mode == "mission":
            self._mission(dt)
        else:  # hold, manual
            if m.resting and self.target is None:
                self._idle()
            else:
                self._fly_traj(dt, self.target)

    def _idle(self) -> None:
        self.model.sp[SP_MODE] = M_IDLE
        self.traj.reset(self.pos, (0, 0, 0))
        self.yaw_sp = self.yaw

    def set_direct(self, pos, vel, acc, yaw: float, yaw_rate: float) -> None:
        sp = self.model.sp
        sp[SP_MODE] = M_POS
        sp[SP_POS:SP_POS + 3] = pos
        sp[SP_VEL:SP_VEL + 3] = vel
        sp[SP_ACC:SP_ACC + 3] = acc
        if _finite(yaw):
            self.yaw_sp = yaw
        sp[SP_YAW] = yaw if _finite(yaw) else (math.nan if _finite(yaw_rate) else self.yaw_sp)
        sp[SP_YAWRATE] = yaw_rate

    def set_attitude(self, q, thrust: float) -> None:
        sp = self.model.sp
        sp[SP_MODE] = M_ATT
        sp[SP_Q:SP_Q + 4] = q
        sp[SP_THRUST] = thrust

    def _fly_traj(self, dt: float, target, speed: float | None = None, up: float | None = None,
                  down: float | None = None, face: bool = False) -> None:
        s = self.settings
        spd = self.cruise if speed is None else speed
        self.traj.step(dt, target, spd, up or self.speed_up or s.vel_up, down or self.speed_down or s.vel_dn)
        if face and target is not None:
            d = np.asarray(target[:2], float) - self.pos[:2]
            if np.all(np.isfinite(d)) and np.hypot(*d) > max(1.0, 2.0 * self.model.vehicle.r_body_m):
                self.yaw_sp = math.atan2(d[1], d[0])
        if self.model.resting and (target is None or not (np.isfinite(target[2]) and target[2] < self.pos[2] - 0.05)):
            self._idle()
            return
        self.set_direct(self.traj.p, self.traj.v, self.traj.a, self.yaw_sp, math.nan)

    def _land(self, dt: float) -> None:
        if self.model.resting and self.ever_airborne:
            self._idle()
            return
        tgt = np.array([self.traj.p[0] if self.target is None else self.target[0],
                        self.traj.p[1] if self.target is None else self.target[1], 1e3])
        self.target = tgt
        self._fly_traj(dt, tgt, down=self.settings.land_speed)

    def _rtl(self, dt: float) -> None:
        tgt = np.array([self.home[0], self.home[1], min(self.pos[2], self.traj.p[2])])
        if self.mission_phase != "rtl_land":
            if self.target is None:
                self.target = tgt
            self._fly_traj(dt, self.target, face=True)
            if np.linalg.norm(self.pos[:2] - self.home[:2]) < 0.3 and self.traj.speed_xy < 0.05:
                self.mission_phase = "rtl_land"
                self.target = None
        else:
            self._land(dt)

    # ------------------------------------------------------------------ mission
    def load_mission(self, items: list[MissionItem]) -> None:
        for it in items:
            it.local = self.frame_to_local(it.frame, it.x, it.y, it.z)
        self.mission = items
        self.last_nav_target = None
        self.mission_seq = 1 if (self.pers.mission_skips_home and len(items) > 1) else 0
        self.mission_phase = ""

    def _mission(self, dt: float) -> None:
        if self.mission_seq >= len(self.mission):
            end = self.last_nav_target
            self.pers.mission_end(self)
            if self.mode in ("mission", "hold") and end is not None and self.target is None:
                self.target = end  # loiter at the last waypoint itself, not where it was accepted
            if self.mode == "mission":
                self._fly_traj(dt, self.target)
            return
        it = self.mission[self.mission_seq]
        c = it.command
        here = self.pos
        if not self.ever_airborne and self.model.resting and self.mission_phase == "" and c != mav.MAV_CMD_NAV_TAKEOFF:
            # on the ground: climb to the first item's altitude first (implicit take-off)
            alt = -it.local[2] if it.local is not None and np.isfinite(it.local[2]) else self.settings.takeoff_alt
            self.mission_phase = "climb"
            self.mission_climb = np.array([here[0], here[1], -max(alt, 0.5)])
        if self.mission_phase == "climb":
            self._fly_traj(dt, self.mission_climb, up=self.settings.takeoff_speed)
            if abs(here[2] - self.mission_climb[2]) < 0.15:
                self.mission_phase = ""
            return
        if c in (mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_LOITER_TIME, mav.MAV_CMD_NAV_TAKEOFF,
                 mav.MAV_CMD_NAV_LAND):
            tgt = np.array(it.local if it.local is not None else (math.nan,) * 3, float)
            if c == mav.MAV_CMD_NAV_TAKEOFF or not np.all(np.isfinite(tgt[:2])):
                tgt[:2] = self.traj.p[:2] if c != mav.MAV_CMD_NAV_TAKEOFF else here[:2]
            if not np.isfinite(tgt[2]):
                tgt[2] = self.traj.p[2]
            if c == mav.MAV_CMD_NAV_LAND:
                if self.mission_phase != "land":
                    tgt[2] = self.traj.p[2]
                    self._fly_traj(dt, tgt, face=True)
                    if np.linalg.norm(here[:2] - tgt[:2]) < 0.3 and self.traj.speed_xy < 0.05:
                        self.mission_phase = "land"
                        self.target = None
                else:
                    self._land(dt)
                    if self.model.resting:
                        self._item_reached(it)
                return
            self._fly_traj(dt, tgt, face=True, up=self.settings.takeoff_speed if c == mav.MAV_CMD_NAV_TAKEOFF else None)
            if c == mav.MAV_CMD_NAV_LOITER_TIME and self.mission_phase.startswith("loiter"):
                if self.time >= self.loiter_until:
                    self._item_reached(it)
                return
            rad = it.params[1] if (c == mav.MAV_CMD_NAV_WAYPOINT and _finite(it.params[1]) and it.params[1] > 0) \
                else self.settings.acc_rad
            if c == mav.MAV_CMD_NAV_TAKEOFF:
                done = abs(here[2] - tgt[2]) < 0.15
            else:
                done = float(np.linalg.norm(here - tgt)) < rad
            if done:
                self.last_nav_target = tgt.copy()
                if c == mav.MAV_CMD_NAV_LOITER_TIME:
                    self.mission_phase = "loiter"
                    self.loiter_until = self.time + (it.params[0] if _finite(it.params[0]) else 0.0)
                else:
                    self._item_reached(it)
            return
        if c == mav.MAV_CMD_DO_CHANGE_SPEED:
            if _finite(it.params[1]) and it.params[1] > 0:
                self.cruise = float(it.params[1])
            self._next_item()
            return
        if c == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._item_reached(it)
            self.set_mode("rtl")
            return
        self._next_item()  # unsupported items are skipped

    def _item_reached(self, it: MissionItem) -> None:
        self.reached.append(it.seq)
        self._next_item()

    def _next_item(self) -> None:
        self.mission_seq += 1
        self.mission_phase = ""


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _masked(mask: int, pos, vel, acc):
    """Apply type_mask (bit set = ignore) per axis; NaN stays NaN (= not controlled)."""
    p, v, a = pos.copy(), vel.copy(), acc.copy()
    for i in range(3):
        if mask & (1 << i):
            p[i] = math.nan
        if mask & (1 << (3 + i)):
            v[i] = math.nan
        if mask & (1 << (6 + i)):
            a[i] = math.nan
    return p, v, a


def _rot(v, c, s):
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])
