"""The autopilot's own flight log of a SITL flight: the PX4 personality writes a ULog (`.ulg`, `Px4Log`, with
`ulog_writer.ULogWriter`), the ArduPilot personality a DataFlash log (`.bin`, `ArduPilotLog`, with
`DataFlashWriter`), so that the whole chain — flight, log, review — is tested with known truth, and so that
tests can make damaged logs of a known shape. `Sim(..., log_dir=DIR)` (or `sim.start_log(DIR)`) records;
`sim.close_log()` finishes the file. The recorders only read the simulator's state (the same state the
MAVLink endpoint sends) and never change it.

Topics/messages, fields and units are the real formats' (so that the readers' conversions are exercised):
PX4 `msg/*.msg` (VehicleLocalPosition, VehicleAttitude, VehicleLocalPositionSetpoint, TrajectorySetpoint,
VehicleThrustSetpoint, HoverThrustEstimate, VehicleStatus, VehicleLandDetected, EstimatorStatus,
EstimatorSelectorStatus, DistanceSensor, ObstacleDistance, MissionResult, SensorGps); ArduPilot's log message
documentation (ardupilot.org/copter/docs/logmessages.html; LogStructure.h, AP_Proximity/LogStructure.h,
ArduCopter/Log.cpp). Rates: PX4's are those of the real PX4 v1.15 SITL log `sample_px4_events.ulg` in
`../shared/logs/px4/` (vehicle_local_position 10 Hz, vehicle_attitude 20, vehicle_local_position_setpoint 10,
trajectory_setpoint 5, vehicle_thrust_setpoint 50, hover_thrust_estimate 10, vehicle_status 2,
estimator_status 5, vehicle_land_detected on change); ArduPilot Copter's 10 Hz logging loop for its
messages (Copter.cpp `ten_hz_logging_loop`), events on change; the range sensors at the sensor's rate.

The file format (ArduPilot AP_Logger, LogStructure.h): every message is `0xA3 0x95 <type>` then its
packed little-endian payload; `FMT` messages (type 128) first define each type's name, length, format
characters and column names. Format characters used here: B uint8, I uint32, Q uint64, f float,
N char[16], M uint8 flight mode.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import ClassVar

import numpy as np

from .control import S_ACCSP, S_THR, S_VSP, SP_YAW
from .physics import euler_from_quat
from .ulog_writer import ULogWriter

HEAD = b"\xa3\x95"
FMT_TYPE = 128
STRUCT = {"B": "B", "I": "I", "Q": "Q", "f": "f", "N": "16s", "M": "B", "n": "4s", "Z": "64s", "i": "i", "h": "h",
          "b": "b", "d": "d"}

# name → (format, columns); a subset of each message's real columns, with the real names and units
MESSAGES = {
    "PARM": ("QNf", "TimeUS,Name,Value"),
    "MODE": ("QMBB", "TimeUS,Mode,ModeNum,Rsn"),
    "ARM": ("QBIB", "TimeUS,ArmState,ArmChecks,Method"),
    "EV": ("QB", "TimeUS,Id"),
    "XKF1": ("QBffffffffff", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD"),  # deg, m/s NED, m NED
    "XKF4": ("QBI", "TimeUS,C,SS"),  # SS: nav_filter_status bits (= EKF_STATUS_REPORT.flags)
    "ATT": ("Qffffff", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),  # deg
    "PSCN": ("Qffff", "TimeUS,TPN,PN,TVN,VN"),  # m, m/s (north)
    "PSCE": ("Qffff", "TimeUS,TPE,PE,TVE,VE"),  # m, m/s (east)
    "CTUN": ("Qfff", "TimeUS,ThI,ThO,ThH"),  # throttle in, out, hover estimate (0–1)
    "RFND": ("QBfBB", "TimeUS,Instance,Dist,Stat,Orient"),  # m; Orient: MAV_SENSOR_ORIENTATION
    # AP_Proximity LogStructure.h: nearest object per 45° sector about the body's forward axis [m]
    "PRX": ("QBBfffffffffff", "TimeUS,Layer,He,D0,D45,D90,D135,D180,D225,D270,D315,DUp,CAn,CDis"),
    # ArduCopter/Log.cpp: GUIDED position target, NEU from the EKF origin, cm (FMTU multiplier B)
    "GUIP": ("QBfffbffffff", "TimeUS,Type,pX,pY,pZ,Terrain,vX,vY,vZ,aX,aY,aZ"),
    "UNIT": ("QbZ", "TimeUS,Id,Label"),
    "MULT": ("Qbd", "TimeUS,Id,Mult"),
    "FMTU": ("QBNN", "TimeUS,FmtType,UnitIds,MultIds"),
    "MSG": ("QZ", "TimeUS,Message"),  # text, e.g. the firmware version at boot
}


class DataFlashWriter:
    """Write a DataFlash log: `write(name, TimeUS, *values)` after `open`; `close()` at the end."""

    def __init__(self, path: str | Path, messages: dict | None = None):
        self.path = Path(path)
        self.messages = dict(MESSAGES if messages is None else messages)
        self._fh = open(self.path, "wb")
        self._types: dict[str, tuple[int, struct.Struct]] = {}
        fmt_struct = struct.Struct("<BB4s16s64s")
        self._fh.write(HEAD + bytes([FMT_TYPE]) + fmt_struct.pack(FMT_TYPE, 3 + fmt_struct.size, b"FMT", b"BBnNZ",
                                                                  b"Type,Length,Name,Format,Columns"))
        for k, (name, (fmt, cols)) in enumerate(self.messages.items()):
            st = struct.Struct("<" + "".join(STRUCT[c] for c in fmt))
            self._types[name] = (129 + k, st)
            self._fh.write(HEAD + bytes([FMT_TYPE]) + fmt_struct.pack(129 + k, 3 + st.size, name.encode(), fmt.encode(),
                                                                      cols.encode()))

    def type_of(self, name: str) -> int:
        return self._types[name][0]

    def write(self, name: str, *values) -> None:
        kind, st = self._types[name]
        vals = [v.encode() if isinstance(v, str) else v for v in values]
        self._fh.write(HEAD + bytes([kind]) + st.pack(*vals))

    def close(self) -> None:
        self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ----------------------------------------------------------------------------- the recorders

BOOT_US = 1  # a log's timestamps are µs of simulated time since boot (+1: a zero timestamp means "unset")
# px4_custom_mode.h (main, sub) → VehicleStatus.msg NAVIGATION_STATE_*
PX4_NAV_STATE = {(1, 0): 0, (2, 0): 1, (3, 0): 2, (4, 2): 17, (4, 3): 4, (4, 4): 3, (4, 5): 5, (4, 6): 18,
                 (4, 8): 19, (4, 9): 20, (5, 0): 10, (6, 0): 14, (7, 0): 15}
EV_ARMED, EV_DISARMED, EV_LAND_COMPLETE, EV_NOT_LANDED = 10, 11, 18, 28  # AP_Logger LogEvent
RFND_NO_DATA, RFND_OUT_OF_RANGE_HIGH, RFND_GOOD = 1, 3, 4  # AP_RangeFinder::Status
PX4_SW_RELEASE = 0x010F0000  # v1.15.0, as the SITL's AUTOPILOT_VERSION says


def estimator_flags(nav_fault: bool) -> int:
    """ESTIMATOR_STATUS_FLAGS (= EKF_STATUS_FLAGS bit for bit) the SITL's estimator reports: attitude and
    vertical position only during a navigation fault, a full solution otherwise (as MAVLink sends them)."""
    if nav_fault:
        return 1 | 32  # ATTITUDE | POS_VERT_ABS
    return 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512  # + VELOCITY_HORIZ/VERT, POS_HORIZ_REL/ABS, PRED_POS_HORIZ_REL/ABS


class _Due:
    """Per-topic schedule on the simulated clock."""

    def __init__(self, rates: dict[str, float]):
        self.iv = {k: 1.0 / r for k, r in rates.items()}
        self.next = dict.fromkeys(rates, 0.0)

    def __call__(self, name: str, t: float) -> bool:
        if t + 1e-9 < self.next[name]:
            return False
        nd = self.next[name] + self.iv[name]
        self.next[name] = nd if nd > t + 1e-9 else t + self.iv[name]
        return True


class FlightLog:
    """Base of the two recorders: `tick(sim)` after each simulator tick, `close()` at the end."""

    suffix = ""
    RATES: ClassVar[dict[str, float]] = {}

    def __init__(self, sim, path: Path):
        self.path = Path(path)
        self.due = _Due(self.RATES)
        self._sensor_seq = sim.sensor_seq
        self._state = None
        self._texts_seen = 0
        self._params = self.param_values(sim)

    @staticmethod
    def param_values(sim) -> dict[str, tuple[float, bool]]:
        """name → (wire value, integer) of the personality's parameters, as PARAM_VALUE states them."""
        ap = sim.autopilot
        out = {}
        for spec in ap.pers.params:
            value = (ap.hover_thrust() if spec.field == "hover_thrust" else getattr(ap.settings, spec.field)) / spec.scale
            out[spec.name] = (round(value) if spec.ptype != 9 else value, spec.ptype != 9)  # 9: MAV_PARAM_TYPE_REAL32
        return out

    def new_texts(self, sim) -> list[tuple[int, str]]:
        """The autopilot's texts since the last tick (peeked: the MAVLink endpoint sends them after)."""
        texts = list(sim.autopilot.texts)
        out = texts[self._texts_seen:] if self._texts_seen <= len(texts) else texts
        self._texts_seen = len(texts)
        return out

    def fresh_reading(self, sim):
        if sim.reading is None or sim.sensor_seq == self._sensor_seq:
            return None
        self._sensor_seq = sim.sensor_seq
        return sim.reading

    def tick(self, sim) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class Px4Log(FlightLog):
    """The PX4 personality's ULog (topics and fields of PX4's msg/*.msg; SI units, NED, FRD)."""

    suffix = ".ulg"
    RATES: ClassVar[dict[str, float]] = {"vehicle_local_position": 10, "vehicle_attitude": 20, "vehicle_local_position_setpoint": 10,
             "trajectory_setpoint": 5, "vehicle_thrust_setpoint": 50, "hover_thrust_estimate": 10,
             "vehicle_status": 2, "estimator_status": 5, "estimator_selector_status": 1, "mission_result": 1,
             "sensor_gps": 5, "params": 1}
    TOPICS: ClassVar[dict[str, str]] = {
        "vehicle_local_position": "uint64_t timestamp;uint64_t timestamp_sample;bool xy_valid;bool z_valid;"
        "bool v_xy_valid;bool v_z_valid;float x;float y;float z;float vx;float vy;float vz;float heading;"
        "double ref_lat;double ref_lon;float ref_alt",
        "vehicle_attitude": "uint64_t timestamp;uint64_t timestamp_sample;float[4] q",
        "vehicle_local_position_setpoint": "uint64_t timestamp;float x;float y;float z;float vx;float vy;float vz;"
        "float[3] acceleration;float[3] thrust;float yaw;float yawspeed",
        "trajectory_setpoint": "uint64_t timestamp;float[3] position;float[3] velocity;float[3] acceleration;"
        "float[3] jerk;float yaw;float yawspeed",
        "vehicle_thrust_setpoint": "uint64_t timestamp;uint64_t timestamp_sample;float[3] xyz",
        "hover_thrust_estimate": "uint64_t timestamp;uint64_t timestamp_sample;float hover_thrust;"
        "float hover_thrust_var;bool valid",
        "vehicle_status": "uint64_t timestamp;uint8_t nav_state;uint8_t arming_state;uint8_t vehicle_type;"
        "bool is_vtol;bool failsafe",
        "vehicle_land_detected": "uint64_t timestamp;bool landed;bool maybe_landed;bool ground_contact",
        "estimator_status": "uint64_t timestamp;uint64_t timestamp_sample;uint16_t solution_status_flags;"
        "float pos_test_ratio;float vel_test_ratio",
        "estimator_selector_status": "uint64_t timestamp;uint8_t primary_instance;uint8_t instances_available;"
        "uint32_t instance_changed_count",
        "distance_sensor": "uint64_t timestamp;uint32_t device_id;float min_distance;float max_distance;"
        "float current_distance;float variance;int8_t signal_quality;uint8_t type;float h_fov;float v_fov;"
        "uint8_t orientation",
        "obstacle_distance": "uint64_t timestamp;uint8_t frame;uint16_t[72] distances;float increment;"
        "uint16_t min_distance;uint16_t max_distance;float angle_offset",
        "mission_result": "uint64_t timestamp;int32_t seq_current;uint16_t seq_total;bool valid;bool finished",
        "sensor_gps": "uint64_t timestamp;double latitude_deg;double longitude_deg;double altitude_msl_m;"
        "uint64_t time_utc_usec;uint8_t fix_type",
    }

    def __init__(self, sim, path: Path):
        super().__init__(sim, path)
        w = self.w = ULogWriter(self.path, BOOT_US + round(sim.time_s * 1e6))
        for name, spec in self.TOPICS.items():
            w.define(name, spec)
        for key, value in (("sys_name", "PX4"), ("ver_hw", "PX4_SITL"), ("ver_sw", "contract-guard-sitl"),
                           ("sys_os_name", "Linux"), ("sys_toolchain", "python")):
            w.info(key, value)
        w.info("ver_sw_release", PX4_SW_RELEASE, "uint32_t")
        for name, (value, integer) in self._params.items():
            w.param(name, value, integer)
        w.param("MAV_TYPE", 2, True)  # MAV_TYPE_QUADROTOR
        w.param("SYS_AUTOSTART", 4001, True)  # the x500 airframe (PX4 SITL gz_x500)
        self.ids = {name: w.add(name) for name in self.TOPICS}
        self._landed = None

    def tick(self, sim) -> None:
        t = sim.time_s
        us = BOOT_US + round(t * 1e6)
        m, ap, w, ids, due = sim.model, sim.autopilot, self.w, self.ids, self.due
        for sev, text in self.new_texts(sim):
            w.log(us, text, min(7, max(0, sev)))
        if due("vehicle_local_position", t):
            lat0, lon0, alt0 = ap.geo_from_local((0.0, 0.0, 0.0))
            ok = not sim.nav_fault
            p, v = m.pos, m.vel
            w.data(ids["vehicle_local_position"], {
                "timestamp": us, "timestamp_sample": us, "xy_valid": ok, "z_valid": True, "v_xy_valid": ok,
                "v_z_valid": True, "x": p[0], "y": p[1], "z": p[2], "vx": v[0], "vy": v[1], "vz": v[2],
                "heading": ap.yaw, "ref_lat": lat0, "ref_lon": lon0, "ref_alt": alt0})
        if due("vehicle_attitude", t):
            w.data(ids["vehicle_attitude"], {"timestamp": us, "timestamp_sample": us, "q": [float(c) for c in m.quat]})
        lps, traj = due("vehicle_local_position_setpoint", t), due("trajectory_setpoint", t)
        if lps or traj:
            sp, s = m.sp, m.s
            pos = [float(sp[i]) for i in range(3)]  # NaN: that axis is not position-controlled
            vel = [float(s[S_VSP + i]) for i in range(3)]
            acc = [float(s[S_ACCSP + i]) for i in range(3)]
            if lps:
                w.data(ids["vehicle_local_position_setpoint"], {
                    "timestamp": us, "x": pos[0], "y": pos[1], "z": pos[2], "vx": vel[0], "vy": vel[1], "vz": vel[2],
                    "acceleration": acc, "thrust": [0.0, 0.0, -float(s[S_THR])], "yaw": float(sp[SP_YAW]),
                    "yawspeed": math.nan})
            if traj:
                w.data(ids["trajectory_setpoint"], {"timestamp": us, "position": pos, "velocity": vel,
                                                    "acceleration": acc, "jerk": [math.nan] * 3,
                                                    "yaw": float(sp[SP_YAW]), "yawspeed": math.nan})
        if due("vehicle_thrust_setpoint", t):
            thr = float(m.s[S_THR]) if ap.armed else 0.0
            w.data(ids["vehicle_thrust_setpoint"], {"timestamp": us, "timestamp_sample": us, "xyz": [0.0, 0.0, -thr]})
        if due("hover_thrust_estimate", t):
            w.data(ids["hover_thrust_estimate"], {"timestamp": us, "timestamp_sample": us,
                                                  "hover_thrust": ap.hover_thrust(), "hover_thrust_var": 1e-4,
                                                  "valid": ap.in_air})
        state = (ap.armed, ap.custom, bool(ap.failsafe))
        if due("vehicle_status", t) or state != self._state:
            self._state = state
            nav = PX4_NAV_STATE.get(((ap.custom >> 16) & 0xFF, (ap.custom >> 24) & 0xFF), 0)
            w.data(ids["vehicle_status"], {"timestamp": us, "nav_state": nav, "arming_state": 2 if ap.armed else 1,
                                           "vehicle_type": 1, "is_vtol": False, "failsafe": bool(ap.failsafe)})
        landed = not ap.in_air
        if landed != self._landed:
            self._landed = landed
            w.data(ids["vehicle_land_detected"], {"timestamp": us, "landed": landed, "maybe_landed": landed,
                                                  "ground_contact": landed})
        if due("estimator_status", t):
            w.data(ids["estimator_status"], {"timestamp": us, "timestamp_sample": us,
                                             "solution_status_flags": estimator_flags(sim.nav_fault),
                                             "pos_test_ratio": 2.0 if sim.nav_fault else 0.05,
                                             "vel_test_ratio": 1.5 if sim.nav_fault else 0.05})
        if due("estimator_selector_status", t):
            w.data(ids["estimator_selector_status"], {"timestamp": us, "primary_instance": 0, "instances_available": 1})
        if due("mission_result", t):
            w.data(ids["mission_result"], {"timestamp": us, "seq_current": ap.mission_seq, "seq_total": len(ap.mission),
                                           "valid": bool(ap.mission), "finished": ap.mission_seq >= len(ap.mission)})
        if due("sensor_gps", t):
            lat, lon, alt = ap.geo_from_local(m.pos)
            w.data(ids["sensor_gps"], {"timestamp": us, "latitude_deg": lat, "longitude_deg": lon, "altitude_msl_m": alt,
                                       "time_utc_usec": round((sim.endpoint.unix_epoch_s + t) * 1e6), "fix_type": 3})
        if (r := self.fresh_reading(sim)) is not None:
            q = r.signal_quality  # MAVLink 0 unknown, 1 invalid, 2..100 → PX4 −1 unknown, 0 invalid, 1..100
            w.data(ids["distance_sensor"], {
                "timestamp": us, "device_id": 1, "min_distance": r.min_cm / 100, "max_distance": r.max_cm / 100,
                "current_distance": r.current_cm / 100, "variance": 0.0, "signal_quality": -1 if q == 0 else 0 if q == 1 else q,
                "type": 0, "h_fov": r.fov_rad, "v_fov": 0.05, "orientation": 0})  # ROTATION_NONE: forward
            w.data(ids["obstacle_distance"], {
                "timestamp": us, "frame": 12, "distances": r.distances_cm, "increment": r.increment_deg,
                "min_distance": r.min_cm, "max_distance": r.max_cm, "angle_offset": r.angle_offset_deg})
        if due("params", t):
            for name, (value, integer) in self.param_values(sim).items():
                if self._params.get(name) != (value, integer) and name != "MPC_THR_HOVER":
                    w.param(name, value, integer)
                    self._params[name] = (value, integer)

    def close(self) -> None:
        self.w.close()


class ArduPilotLog(FlightLog):
    """The ArduPilot personality's DataFlash log (ArduPilot's messages, fields and units)."""

    suffix = ".bin"
    RATES: ClassVar[dict[str, float]] = dict.fromkeys(("XKF1", "XKF4", "ATT", "PSC", "CTUN", "GUIP", "params"), 10.0)

    def __init__(self, sim, path: Path):
        super().__init__(sim, path)
        w = self.w = DataFlashWriter(self.path)
        us = BOOT_US + round(sim.time_s * 1e6)
        for uid, label in (("s", "s"), ("m", "m"), ("n", "m/s"), ("o", "m/s/s"), ("-", "")):
            w.write("UNIT", us, ord(uid), label)
        for mid, mult in (("-", 0.0), ("F", 1e-6), ("B", 1e-2), ("0", 1.0)):
            w.write("MULT", us, ord(mid), mult)
        w.write("FMTU", us, w.type_of("GUIP"), "s-mmm-nnnooo", "F-BBB-BBBBBB")
        w.write("MSG", us, "ArduCopter V4.5.0 (contract-guard SITL)")
        w.write("MSG", us, "Frame: QUAD/X")
        rng = sim.sensor.cfg
        self._params.update({"FRAME_CLASS": (1, True), "RNGFND1_TYPE": (100, True),  # 100: SITL
                             "RNGFND1_MIN_CM": (round(rng.min_range_m * 100), True),
                             "RNGFND1_MAX_CM": (round(rng.max_range_m * 100), True),
                             "RNGFND1_ORIENT": (0, True), "PRX1_TYPE": (10, True),  # 10: SITL
                             "PRX1_MAX": (rng.max_range_m, False), "AVOID_ENABLE": (0, True)})
        for name, (value, _) in self._params.items():
            w.write("PARM", us, name, float(value))
        self._armed = self._mode = self._landed = None

    def tick(self, sim) -> None:
        t = sim.time_s
        us = BOOT_US + round(t * 1e6)
        m, ap, w, due = sim.model, sim.autopilot, self.w, self.due
        for _, text in self.new_texts(sim):
            w.write("MSG", us, text[:64])
        if ap.armed != self._armed:
            self._armed = ap.armed
            w.write("ARM", us, int(ap.armed), 0, 0)
            w.write("EV", us, EV_ARMED if ap.armed else EV_DISARMED)
        if ap.custom != self._mode:
            self._mode = ap.custom
            w.write("MODE", us, ap.custom, ap.custom, 0)
        landed = not ap.in_air
        if landed != self._landed:
            if self._landed is not None or not landed:
                w.write("EV", us, EV_LAND_COMPLETE if landed else EV_NOT_LANDED)
            self._landed = landed
        r, p, y = (math.degrees(a) for a in euler_from_quat(m.quat))
        if due("XKF1", t):
            pos, v = m.pos, m.vel
            w.write("XKF1", us, 0, r, p, y % 360.0, v[0], v[1], v[2], v[2], pos[0], pos[1], pos[2])
        if due("XKF4", t):
            w.write("XKF4", us, 0, estimator_flags(sim.nav_fault))
        if due("ATT", t):
            w.write("ATT", us, r, r, p, p, y % 360.0, y % 360.0)
        if due("PSC", t):
            sp, s = m.sp, m.s
            w.write("PSCN", us, float(sp[0]), m.pos[0], float(s[S_VSP]), m.vel[0])
            w.write("PSCE", us, float(sp[1]), m.pos[1], float(s[S_VSP + 1]), m.vel[1])
        if due("CTUN", t):
            thr = float(m.s[S_THR]) if ap.armed else 0.0
            w.write("CTUN", us, thr, thr, ap.hover_thrust())
        if due("GUIP", t) and ap.mode == "offboard" and np.all(np.isfinite(ap.ob.pos[:2])):
            ob = ap.ob
            pz = -float(ob.pos[2]) * 100 if math.isfinite(ob.pos[2]) else 0.0
            vel = [float(c) * 100 if math.isfinite(c) else 0.0 for c in ob.vel]
            w.write("GUIP", us, 1, float(ob.pos[0]) * 100, float(ob.pos[1]) * 100, pz, 0,
                    vel[0], vel[1], -vel[2], 0.0, 0.0, 0.0)  # cm, cm/s, NEU (z up)
        if (rd := self.fresh_reading(sim)) is not None:
            stat = RFND_OUT_OF_RANGE_HIGH if rd.current_cm > rd.max_cm else RFND_GOOD
            w.write("RFND", us, 0, min(rd.current_cm, rd.max_cm) / 100, stat, 0)
            w.write("PRX", us, 2, 1, *prx_sectors(rd), 0.0, *prx_closest(rd))
        if due("params", t):
            for name, (value, integer) in self.param_values(sim).items():
                if self._params.get(name) != (value, integer) and name != "MOT_THST_HOVER":
                    w.write("PARM", us, name, float(value))
                    self._params[name] = (value, integer)

    def close(self) -> None:
        self.w.close()


def _bins(rd) -> tuple[np.ndarray, np.ndarray]:
    """(bearing [deg, clockwise from forward], range [m], inf beyond max) of a reading's used bins."""
    d = np.asarray(rd.distances_cm, dtype=float)
    n = int(np.sum(d != 65535))
    ang = rd.angle_offset_deg + rd.increment_deg * np.arange(n)
    rng = np.where(d[:n] > rd.max_cm, np.inf, d[:n] / 100)
    return ang, rng


def prx_sectors(rd) -> list[float]:
    """PRX D0…D315: the nearest object in each 45° sector about 0°, 45°, … [m]; a sector the sensor covers
    and finds empty logs its maximum range, one it does not cover logs 0 (no data)."""
    ang, rng = _bins(rd)
    sector = np.round((ang % 360) / 45).astype(int) % 8
    out = []
    for k in range(8):
        here = rng[sector == k]
        out.append(0.0 if not len(here) else float(min(np.min(here), rd.max_cm / 100)))
    return out


def prx_closest(rd) -> tuple[float, float]:
    """PRX CAn [deg], CDis [m]: the closest object's bearing and distance (max range when none)."""
    ang, rng = _bins(rd)
    if not len(rng) or not np.isfinite(np.min(rng)):
        return 0.0, rd.max_cm / 100
    i = int(np.argmin(rng))
    return float(ang[i] % 360), float(rng[i])


LOGGERS = {"px4": Px4Log, "ardupilot": ArduPilotLog}


def start_log(sim, where: str | Path) -> FlightLog:
    """The personality's recorder of `sim`; `where` a directory (a new `flight-NNN` file in it) or a file."""
    where = Path(where)
    cls = LOGGERS[sim.autopilot.pers.name]
    if where.suffix in (".ulg", ".bin"):
        where.parent.mkdir(parents=True, exist_ok=True)
        path = where
    else:
        where.mkdir(parents=True, exist_ok=True)
        n = 1
        while (where / f"flight-{n:03d}{cls.suffix}").exists():
            n += 1
        path = where / f"flight-{n:03d}{cls.suffix}"
    return cls(sim, path)
