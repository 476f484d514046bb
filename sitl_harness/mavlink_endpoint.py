"""The vehicle's MAVLink side: decode what a client sends, encode telemetry. Transport-free.

`MavlinkEndpoint.receive(datagram)` parses one datagram of real MAVLink bytes (MAVLink 2, dialect
ardupilotmega ⊃ common), acts on the messages addressed to the vehicle (target system and component
0 or its own) and returns every good message (for routing to other clients, `serve.Router`);
`take_output()` returns the packets the vehicle sent since the last call. Sockets (`serve.py`) and
the in-memory lock-step link (`lockstep.py`) only move these bytes.

Robustness: a datagram is parsed on its own (a truncated tail is counted and discarded, never
glued to the next datagram); packets with a bad CRC, a bad prefix or (when a signing key is set) a
missing or wrong signature are dropped and counted in `stats`; an exception in a handler (e.g. a
NaN where an integer is needed) drops that message, is counted, and the vehicle keeps flying.

Telemetry (default rates, Hz, changeable with MAV_CMD_SET_MESSAGE_INTERVAL): HEARTBEAT 1 (and at
once after an arming or mode change),
SYS_STATUS 2, EXTENDED_SYS_STATE 1, ATTITUDE 50, ATTITUDE_QUATERNION 10, LOCAL_POSITION_NED 30,
GLOBAL_POSITION_INT 10, GPS_RAW_INT 5, HOME_POSITION 0.5, VFR_HUD 10, POSITION_TARGET_LOCAL_NED
10, ESTIMATOR_STATUS (PX4) / EKF_STATUS_REPORT (ArduPilot) 2, BATTERY_STATUS 1, SYSTEM_TIME 1,
TIMESYNC 1, MISSION_CURRENT 1; at the sensor's rate its messages (the sector sensor: DISTANCE_SENSOR and
OBSTACLE_DISTANCE; a depth camera: OBSTACLE_DISTANCE; a single beam: DISTANCE_SENSOR; sensor_models.py); on
request AUTOPILOT_VERSION; on events COMMAND_ACK, STATUSTEXT, MISSION_ITEM_REACHED, PARAM_VALUE.
"""

from __future__ import annotations

import math
import os
import time

os.environ["MAVLINK20"] = "1"

from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from .autopilot import ACCEPTED, DENIED, UNSUPPORTED, MissionItem, _finite  # noqa: E402
from .control import S_ACCSP, S_THR, S_VSP, SP_POS, SP_YAW  # noqa: E402
from .physics import euler_from_quat  # noqa: E402

SENSORS = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
           | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mav.MAV_SYS_STATUS_SENSOR_GPS
           | mav.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL | mav.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
           | mav.MAV_SYS_STATUS_SENSOR_YAW_POSITION | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
           | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
           | mav.MAV_SYS_STATUS_GEOFENCE)  # GEOFENCE present+healthy: MAVProxy reports a breach otherwise
DEFAULT_RATES_HZ = {
    mav.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mav.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
    mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mav.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mav.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    mav.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mav.MAVLINK_MSG_ID_VFR_HUD: 10.0,
    mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 10.0,
    mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 2.0,
    mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT: 2.0,
    mav.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mav.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    mav.MAVLINK_MSG_ID_TIMESYNC: 1.0,
    mav.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
}
SENSOR_MSGS = (mav.MAVLINK_MSG_ID_DISTANCE_SENSOR, mav.MAVLINK_MSG_ID_OBSTACLE_DISTANCE)
ONCE_ONLY = (mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION,)
EPOCH_UNIX_S = 1_767_225_600  # 2026-01-01T00:00:00Z: SYSTEM_TIME origin in simulated time


def target_of(m) -> tuple[int, int]:
    """(target_system, target_component) of a decoded message; 0 for broadcast or no such field."""
    return getattr(m, "target_system", 0), getattr(m, "target_component", 0)


class _Sink:
    """File-like target of the encoder: collects each packet's bytes."""

    def __init__(self):
        self.packets: list[bytes] = []

    def write(self, b) -> None:
        self.packets.append(bytes(b))


class MavlinkEndpoint:
    """One vehicle (sysid, compid 1) speaking MAVLink 2 for the simulation `sim` (`sim.Sim`)."""

    def __init__(self, sim, sysid: int = 1, compid: int = 1, signing_key: bytes | None = None,
                 unix_epoch_s: float = EPOCH_UNIX_S):
        self.sim = sim
        self.ap = sim.autopilot
        self.sysid = sysid
        self.compid = compid
        self.unix_epoch_s = unix_epoch_s
        self._sink = _Sink()
        self.tx = mav.MAVLink(self._sink, srcSystem=sysid, srcComponent=compid)
        self.rx = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.rx.robust_parsing = True
        if signing_key is not None:
            if len(signing_key) != 32:
                raise ValueError("signing key must be 32 bytes")
            # signing timestamps are wall-clock based (10 µs since 2015-01-01; receivers reject a
            # stream more than 60 s behind their own clock), so signed output is not byte-identical
            # between runs even in lock-step
            stamp = int((time.time() - 1_420_070_400) * 1e5)
            for m in (self.tx, self.rx):
                m.signing.secret_key = signing_key
                m.signing.link_id = 0
                m.signing.timestamp = stamp
            self.tx.signing.sign_outgoing = True
            self.rx.signing.allow_unsigned_callback = None
        self.stats = {"rx_datagrams": 0, "rx_messages": 0, "rx_bad": 0, "rx_truncated_bytes": 0,
                      "rx_handler_errors": 0, "rx_not_for_us": 0, "rx_refused_targets": 0,
                      "tx_packets": 0}
        self.intervals = {k: 1.0 / v for k, v in DEFAULT_RATES_HZ.items()}
        carried = {getattr(mav, f"MAVLINK_MSG_ID_{name}") for name in sim.sensor.MESSAGES}  # the sensor model's
        self.intervals.update({k: 1.0 / sim.sensor.cfg.rate_hz for k in SENSOR_MSGS if k in carried})
        self.sensor_type = getattr(mav, f"MAV_DISTANCE_SENSOR_{sim.sensor.SENSOR_TYPE}")
        for est in (mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS, mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT):
            if est != self.ap.pers.estimator_status_msg:  # only the personality's own is streamed
                self.intervals.pop(est)
        self._defaults = dict(self.intervals)
        self.next_due = {k: 0.0 for k in self.intervals}
        self.once: list[int] = []
        self._senders = {
            mav.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            mav.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._ext_state,
            mav.MAVLINK_MSG_ID_ATTITUDE: self._attitude,
            mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._attitude_q,
            mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._local_pos,
            mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._global_pos,
            mav.MAVLINK_MSG_ID_GPS_RAW_INT: self._gps_raw,
            mav.MAVLINK_MSG_ID_HOME_POSITION: self._home,
            mav.MAVLINK_MSG_ID_VFR_HUD: self._vfr_hud,
            mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: self._pos_target,
            mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS: self._estimator_status,
            mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT: self._ekf_status,
            mav.MAVLINK_MSG_ID_BATTERY_STATUS: self._battery,
            mav.MAVLINK_MSG_ID_SYSTEM_TIME: self._system_time,
            mav.MAVLINK_MSG_ID_TIMESYNC: self._timesync,
            mav.MAVLINK_MSG_ID_MISSION_CURRENT: self._mission_current,
            mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
            mav.MAVLINK_MSG_ID_DISTANCE_SENSOR: self._distance_sensor,
            mav.MAVLINK_MSG_ID_OBSTACLE_DISTANCE: self._obstacle_distance,
        }
        self._upload: dict | None = None
        self._param_specs = {p.name: p for p in self.ap.pers.params}
        self._sensor_seq_sent = {k: -1 for k in SENSOR_MSGS}
        self._hb_state = (self.ap.armed, self.ap.custom)
        self.last_handler_error = ""

    # ------------------------------------------------------------------ time
    @property
    def t(self) -> float:
        return self.sim.time_s

    def boot_ms(self) -> int:
        return int(self.t * 1000.0) & 0xFFFFFFFF

    def usec(self) -> int:
        return int(self.t * 1e6)

    # ------------------------------------------------------------------ input
    def receive(self, datagram: bytes) -> list:
        """Parse one datagram, act on the good messages addressed to us; return all good messages."""
        self.stats["rx_datagrams"] += 1
        try:
            msgs = self.rx.parse_buffer(bytes(datagram)) or []
        except Exception:  # pymavlink raises on some malformed input even in robust mode
            msgs = []
            self.stats["rx_bad"] += 1
        left = self.rx.buf_len()
        if left > 0:  # truncated packet at the end of the datagram: drop it, resynchronise
            self.stats["rx_truncated_bytes"] += left
            self.rx.buf = bytearray()
            self.rx.buf_index = 0
            self.rx.expected_length = mav.HEADER_LEN_V1 + 2
        good = []
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                self.stats["rx_bad"] += 1
                continue
            self.stats["rx_messages"] += 1
            good.append(m)
            sys_, comp = target_of(m)
            if sys_ not in (0, self.sysid) or (sys_ and comp not in (0, self.compid)):
                self.stats["rx_not_for_us"] += 1
                continue
            try:
                self._handle(m)
            except Exception as err:  # never let one message stop the vehicle
                self.stats["rx_handler_errors"] += 1
                self.last_handler_error = f"{m.get_type()}: {type(err).__name__}: {err}"
        return good

    def _handle(self, m) -> None:
        kind = m.get_type()
        h = getattr(self, "_on_" + kind.lower(), None)
        if h is not None:
            h(m)

    def _ack(self, m, command: int, result: int) -> None:
        self.tx.command_ack_send(command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent())

    def _on_command_long(self, m) -> None:
        p = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        self._ack(m, m.command, self._command(m.command, p, None))

    def _on_command_int(self, m) -> None:
        p = (m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z)
        self._ack(m, m.command, self._command(m.command, p, m.frame))

    def _command(self, cmd: int, p: tuple, frame) -> int:
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not _finite(p[0]) or not _finite(p[1]):
                return DENIED
            mid, us = int(p[0]), float(p[1])
            if mid not in self._senders or mid in ONCE_ONLY:
                return UNSUPPORTED
            if us < 0:
                self.intervals.pop(mid, None)
            elif us == 0:
                if mid in self._defaults:
                    self.intervals[mid] = self._defaults[mid]
                else:
                    self.intervals.pop(mid, None)
            else:
                self.intervals[mid] = max(us * 1e-6, 0.005)
                self.next_due[mid] = self.t
            return ACCEPTED
        if cmd == mav.MAV_CMD_REQUEST_MESSAGE:
            if not _finite(p[0]) or int(p[0]) not in self._senders:
                return UNSUPPORTED
            self.once.append(int(p[0]))
            return ACCEPTED
        if cmd == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self.once.append(mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            return ACCEPTED
        if cmd == mav.MAV_CMD_GET_HOME_POSITION:
            self.once.append(mav.MAVLINK_MSG_ID_HOME_POSITION)
            return ACCEPTED
        return self.ap.handle_command(cmd, p, frame)

    def _on_set_mode(self, m) -> None:
        if m.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            self.ap.request_custom_mode(m.custom_mode)

    def _on_set_position_target_local_ned(self, m) -> None:
        ok = self.ap.handle_position_target(m.coordinate_frame, m.type_mask, (m.x, m.y, m.z),
                                            (m.vx, m.vy, m.vz), (m.afx, m.afy, m.afz), m.yaw, m.yaw_rate)
        if not ok:
            self.stats["rx_refused_targets"] += 1

    def _on_set_position_target_global_int(self, m) -> None:
        ap = self.ap
        alt = m.alt if m.coordinate_frame in (mav.MAV_FRAME_GLOBAL_INT, mav.MAV_FRAME_GLOBAL) else ap.home_geo[2] + m.alt
        if m.coordinate_frame not in (mav.MAV_FRAME_GLOBAL_INT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                      mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT):
            self.stats["rx_refused_targets"] += 1
            return
        p = ap.local_from_geo(m.lat_int * 1e-7, m.lon_int * 1e-7, alt)
        ok = ap.handle_position_target(mav.MAV_FRAME_LOCAL_NED, m.type_mask, p, (m.vx, m.vy, m.vz),
                                       (m.afx, m.afy, m.afz), m.yaw, m.yaw_rate)
        if not ok:
            self.stats["rx_refused_targets"] += 1

    def _on_set_attitude_target(self, m) -> None:
        self.ap.handle_attitude_target(tuple(m.q), m.thrust, bool(m.type_mask & 128))

    def _on_timesync(self, m) -> None:
        if m.tc1 == 0:  # a request: answer with our clock (ns)
            self.tx.timesync_send(max(1, round(self.t * 1e9)), m.ts1)

    def _on_ping(self, m) -> None:
        if m.target_system == 0:
            self.tx.ping_send(m.time_usec, m.seq, m.get_srcSystem(), m.get_srcComponent())

    # ----- parameters
    def _param_value(self, spec, index: int) -> None:
        s = self.ap.settings
        if spec.field == "hover_thrust":
            s.hover_thrust = self.ap.hover_thrust()
        value = getattr(s, spec.field) / spec.scale
        wire = self.ap.pers.encode_param(value, spec.ptype)
        self.tx.param_value_send(spec.name.encode(), wire, spec.ptype, len(self.ap.pers.params), index)

    def _on_param_request_list(self, m) -> None:
        for i, spec in enumerate(self.ap.pers.params):
            self._param_value(spec, i)

    def _on_param_request_read(self, m) -> None:
        specs = self.ap.pers.params
        name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else m.param_id.decode().rstrip("\x00")
        if m.param_index >= 0:
            if m.param_index < len(specs):
                self._param_value(specs[m.param_index], m.param_index)
            return
        if name in self._param_specs:
            self._param_value(self._param_specs[name], specs.index(self._param_specs[name]))

    def _on_param_set(self, m) -> None:
        name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else m.param_id.decode().rstrip("\x00")
        spec = self._param_specs.get(name)
        if spec is None:
            self.ap.text(mav.MAV_SEVERITY_WARNING, f"Unknown parameter {name}")
            return
        value = self.ap.pers.decode_param(m.param_value, spec.ptype)
        if not spec.read_only and math.isfinite(value) and value >= 0:
            self.sim.set_param(name, value)
        self._param_value(spec, self.ap.pers.params.index(spec))

    # ----- mission protocol (vehicle side)
    def _on_mission_count(self, m) -> None:
        if getattr(m, "mission_type", 0) != mav.MAV_MISSION_TYPE_MISSION:
            self.tx.mission_ack_send(m.get_srcSystem(), m.get_srcComponent(), mav.MAV_MISSION_UNSUPPORTED,
                                     m.mission_type)
            return
        if m.count == 0:
            self.ap.load_mission([])
            self.tx.mission_ack_send(m.get_srcSystem(), m.get_srcComponent(), mav.MAV_MISSION_ACCEPTED)
            return
        self._upload = {"count": m.count, "items": [], "peer": (m.get_srcSystem(), m.get_srcComponent()),
                        "last": self.t, "tries": 0}
        self._request_item()

    def _request_item(self) -> None:
        u = self._upload
        self.tx.mission_request_int_send(u["peer"][0], u["peer"][1], len(u["items"]))
        u["last"] = self.t

    def _store_item(self, m, x: float, y: float) -> None:
        u = self._upload
        if u is None or getattr(m, "mission_type", 0) != mav.MAV_MISSION_TYPE_MISSION:
            return
        if m.seq != len(u["items"]):
            self._request_item()
            return
        u["items"].append(MissionItem(m.seq, m.frame, m.command, (m.param1, m.param2, m.param3, m.param4),
                                      x, y, m.z))
        u["tries"] = 0
        if len(u["items"]) == u["count"]:
            self.ap.load_mission(u["items"])
            self.tx.mission_ack_send(u["peer"][0], u["peer"][1], mav.MAV_MISSION_ACCEPTED)
            self._upload = None
        else:
            self._request_item()

    def _on_mission_item_int(self, m) -> None:
        local = m.frame in (mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_OFFSET_NED)
        k = 1e-4 if local else 1e-7
        self._store_item(m, m.x * k, m.y * k)

    def _on_mission_item(self, m) -> None:
        self._store_item(m, m.x, m.y)

    def _on_mission_request_list(self, m) -> None:
        self.tx.mission_count_send(m.get_srcSystem(), m.get_srcComponent(), len(self.ap.mission))

    def _on_mission_request_int(self, m) -> None:
        if 0 <= m.seq < len(self.ap.mission):
            it = self.ap.mission[m.seq]
            local = it.frame in (mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_OFFSET_NED)
            k = 1e4 if local else 1e7
            self.tx.mission_item_int_send(m.get_srcSystem(), m.get_srcComponent(), it.seq, it.frame, it.command,
                                          int(it.seq == self.ap.mission_seq), 1, *it.params,
                                          int(round(it.x * k)), int(round(it.y * k)), it.z)

    _on_mission_request = _on_mission_request_int

    def _on_mission_clear_all(self, m) -> None:
        self.ap.load_mission([])
        self.tx.mission_ack_send(m.get_srcSystem(), m.get_srcComponent(), mav.MAV_MISSION_ACCEPTED)

    def _on_mission_set_current(self, m) -> None:
        if 0 <= m.seq < len(self.ap.mission):
            self.ap.mission_seq = m.seq
            self.ap.mission_phase = ""
            self._mission_current()

    # ------------------------------------------------------------------ output
    def emit(self) -> None:
        """Send what is due at the current simulated time (called once per tick)."""
        t = self.t
        ap = self.ap
        while ap.texts:
            sev, txt = ap.texts.popleft()
            self.tx.statustext_send(sev, txt.encode()[:50])
        while ap.reached:
            self.tx.mission_item_reached_send(ap.reached.popleft())
        u = self._upload
        if u is not None and t - u["last"] > 1.5:
            u["tries"] += 1
            if u["tries"] > 5:
                self.tx.mission_ack_send(u["peer"][0], u["peer"][1], mav.MAV_MISSION_OPERATION_CANCELLED)
                self._upload = None
            else:
                self._request_item()
        state = (ap.armed, ap.custom)
        if state != self._hb_state:  # announce arming and mode changes at once (clients wait on them)
            self._hb_state = state
            self.next_due[mav.MAVLINK_MSG_ID_HEARTBEAT] = t
        while self.once:
            self._senders[self.once.pop(0)]()
        for mid, iv in self.intervals.items():
            if t + 1e-9 >= self.next_due.get(mid, 0.0):
                if mid in SENSOR_MSGS:
                    if self.sim.sensor_seq == self._sensor_seq_sent[mid] or self.sim.reading is None:
                        continue
                    self._sensor_seq_sent[mid] = self.sim.sensor_seq
                self._senders[mid]()
                nd = self.next_due.get(mid, 0.0) + iv
                self.next_due[mid] = nd if nd > t else t + iv

    def take_output(self) -> list[bytes]:
        out = self._sink.packets
        self._sink.packets = []
        self.stats["tx_packets"] += len(out)
        return out

    # ----- senders
    def _heartbeat(self) -> None:
        ap = self.ap
        if ap.failsafe and ap.armed:
            status = mav.MAV_STATE_CRITICAL
        else:
            status = mav.MAV_STATE_ACTIVE if ap.armed else mav.MAV_STATE_STANDBY
        self.tx.heartbeat_send(mav.MAV_TYPE_QUADROTOR, ap.pers.autopilot_id, ap.pers.base_mode_flags(ap),
                               ap.custom, status)

    def _sys_status(self) -> None:
        present = SENSORS | mav.MAV_SYS_STATUS_PREARM_CHECK | mav.MAV_SYS_STATUS_SENSOR_PROXIMITY
        health = SENSORS
        sim = self.sim
        if sim.nav_fault:
            health &= ~mav.MAV_SYS_STATUS_SENSOR_GPS
        if not sim.sensor.dropout:
            health |= mav.MAV_SYS_STATUS_SENSOR_PROXIMITY
        if self.ap.prearm_ok and not self.ap.armed:
            health |= mav.MAV_SYS_STATUS_PREARM_CHECK
        b = sim.battery_remaining()
        self.tx.sys_status_send(present, present, health, 200, int(sim.battery_voltage() * 1000),
                                int(sim.battery_current() * 100), int(b), 0, 0, 0, 0, 0, 0)

    def _ext_state(self) -> None:
        ap = self.ap
        if not ap.in_air:
            ls = mav.MAV_LANDED_STATE_ON_GROUND
        elif ap.mode == "takeoff":
            ls = mav.MAV_LANDED_STATE_TAKEOFF
        elif ap.mode == "land" or (ap.mode == "rtl" and ap.mission_phase == "rtl_land"):
            ls = mav.MAV_LANDED_STATE_LANDING
        else:
            ls = mav.MAV_LANDED_STATE_IN_AIR
        self.tx.extended_sys_state_send(mav.MAV_VTOL_STATE_UNDEFINED, ls)

    def _attitude(self) -> None:
        m = self.sim.model
        r, p, y = euler_from_quat(m.quat)
        w = m.rates
        self.tx.attitude_send(self.boot_ms(), r, p, y, w[0], w[1], w[2])

    def _attitude_q(self) -> None:
        m = self.sim.model
        q = m.quat
        w = m.rates
        self.tx.attitude_quaternion_send(self.boot_ms(), q[0], q[1], q[2], q[3], w[0], w[1], w[2])

    def _local_pos(self) -> None:
        m = self.sim.model
        p, v = m.pos, m.vel
        self.tx.local_position_ned_send(self.boot_ms(), p[0], p[1], p[2], v[0], v[1], v[2])

    def _geo(self):
        lat, lon, alt = self.ap.geo_from_local(self.sim.model.pos)
        return int(round(lat * 1e7)), int(round(lon * 1e7)), alt

    def _global_pos(self) -> None:
        lat, lon, alt = self._geo()
        v = self.sim.model.vel
        hdg = int(round(math.degrees(self.ap.yaw) % 360.0 * 100)) % 36000
        self.tx.global_position_int_send(self.boot_ms(), lat, lon, int(alt * 1000), int(-self.sim.model.pos[2] * 1000),
                                         int(v[0] * 100), int(v[1] * 100), int(v[2] * 100), hdg)

    def _gps_raw(self) -> None:
        lat, lon, alt = self._geo()
        v = self.sim.model.vel
        gs = math.hypot(v[0], v[1])
        cog = int(round(math.degrees(math.atan2(v[1], v[0])) % 360.0 * 100)) % 36000 if gs > 0.1 else 65535
        self.tx.gps_raw_int_send(self.usec(), mav.GPS_FIX_TYPE_3D_FIX, lat, lon, int(alt * 1000), 80, 120,
                                 int(gs * 100), cog, 14)

    def _home(self) -> None:
        lat, lon, alt = self.ap.home_geo
        h = self.ap.home
        self.tx.home_position_send(int(round(lat * 1e7)), int(round(lon * 1e7)), int(alt * 1000), h[0], h[1], h[2],
                                   [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, self.usec())

    def _vfr_hud(self) -> None:
        m = self.sim.model
        v = m.vel
        w = self.sim.wind_now
        air = math.sqrt((v[0] - w[0]) ** 2 + (v[1] - w[1]) ** 2 + (v[2] - w[2]) ** 2)
        thr = int(round(100.0 * m.s[S_THR])) if self.ap.armed else 0  # PX4: 0 when disarmed
        hdg = int(round(math.degrees(self.ap.yaw) % 360.0)) % 360
        self.tx.vfr_hud_send(air, math.hypot(v[0], v[1]), hdg, thr, self.ap.home_geo[2] - m.pos[2], -v[2])

    def _pos_target(self) -> None:
        m = self.sim.model
        sp, s = m.sp, m.s
        pos = [sp[SP_POS + i] for i in range(3)]
        mask = sum(1 << i for i in range(3) if math.isnan(pos[i]))
        pos = [0.0 if math.isnan(c) else c for c in pos]
        yaw = sp[SP_YAW]
        if math.isnan(yaw):
            mask |= mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE
            yaw = 0.0
        mask |= mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
        self.tx.position_target_local_ned_send(self.boot_ms(), mav.MAV_FRAME_LOCAL_NED, mask, *pos,
                                               s[S_VSP], s[S_VSP + 1], s[S_VSP + 2],
                                               s[S_ACCSP], s[S_ACCSP + 1], s[S_ACCSP + 2], yaw, 0.0)

    def _estimator_status(self) -> None:
        if self.sim.nav_fault:  # attitude only, GPS glitch, test ratios above 1 (failing)
            flags = mav.ESTIMATOR_ATTITUDE | mav.ESTIMATOR_POS_VERT_ABS | mav.ESTIMATOR_GPS_GLITCH
            self.tx.estimator_status_send(self.usec(), flags, 1.5, 2.0, 0.3, 0.1, 0.0, 0.0, 10.0, 1.0)
            return
        flags = (mav.ESTIMATOR_ATTITUDE | mav.ESTIMATOR_VELOCITY_HORIZ | mav.ESTIMATOR_VELOCITY_VERT
                 | mav.ESTIMATOR_POS_HORIZ_REL | mav.ESTIMATOR_POS_HORIZ_ABS | mav.ESTIMATOR_POS_VERT_ABS
                 | mav.ESTIMATOR_PRED_POS_HORIZ_REL | mav.ESTIMATOR_PRED_POS_HORIZ_ABS)
        self.tx.estimator_status_send(self.usec(), flags, 0.1, 0.1, 0.1, 0.1, 0.0, 0.0, 0.05, 0.05)

    def _ekf_status(self) -> None:
        if self.sim.nav_fault:  # ArduPilot: position flags dropped, variances above 1
            flags = mav.EKF_ATTITUDE | mav.EKF_POS_VERT_ABS
            self.tx.ekf_status_report_send(flags, 1.5, 2.0, 0.3, 0.1, 0.0)
            return
        flags = (mav.EKF_ATTITUDE | mav.EKF_VELOCITY_HORIZ | mav.EKF_VELOCITY_VERT | mav.EKF_POS_HORIZ_REL
                 | mav.EKF_POS_HORIZ_ABS | mav.EKF_POS_VERT_ABS | mav.EKF_PRED_POS_HORIZ_REL
                 | mav.EKF_PRED_POS_HORIZ_ABS)
        self.tx.ekf_status_report_send(flags, 0.1, 0.1, 0.1, 0.1, 0.0)

    def _battery(self) -> None:
        sim = self.sim
        cell = int(sim.battery_voltage() / 4 * 1000)
        volts = [cell] * 4 + [65535] * 6
        self.tx.battery_status_send(0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_LIPO, 32767, volts,
                                    int(sim.battery_current() * 100), int(sim.consumed_mah()), -1,
                                    int(sim.battery_remaining()))

    def _system_time(self) -> None:
        self.tx.system_time_send(int((self.unix_epoch_s + self.t) * 1e6), self.boot_ms())

    def _timesync(self) -> None:
        self.tx.timesync_send(0, max(1, round(self.t * 1e9)))

    def _mission_current(self) -> None:
        ap = self.ap
        n = len(ap.mission)
        if n == 0:
            state = mav.MISSION_STATE_NO_MISSION
        elif ap.mission_seq >= n:
            state = mav.MISSION_STATE_COMPLETE
        elif ap.mode == "mission":
            state = mav.MISSION_STATE_ACTIVE
        else:
            state = mav.MISSION_STATE_PAUSED if ap.mission_seq > 0 else mav.MISSION_STATE_NOT_STARTED
        self.tx.mission_current_send(min(ap.mission_seq, max(n - 1, 0)), n, state, int(ap.mode == "mission"))

    def _autopilot_version(self) -> None:
        ap = self.ap
        self.tx.autopilot_version_send(ap.pers.capabilities, 0x010F0000, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8,
                                       0, 0, 0x5349544C)

    def _distance_sensor(self) -> None:
        r = self.sim.reading
        self.tx.distance_sensor_send(self.boot_ms(), r.min_cm, r.max_cm, r.current_cm, self.sensor_type,
                                     0, mav.MAV_SENSOR_ROTATION_NONE, 255, r.fov_rad, 0.0, [0.0] * 4,
                                     r.signal_quality)

    def _obstacle_distance(self) -> None:
        r = self.sim.reading
        inc = max(1, min(255, round(r.increment_deg)))  # uint8 degrees too, for readers that ignore increment_f
        self.tx.obstacle_distance_send(self.usec(), self.sensor_type, r.distances_cm, inc, r.min_cm,
                                       r.max_cm, r.increment_deg, r.angle_offset_deg, mav.MAV_FRAME_BODY_FRD)
