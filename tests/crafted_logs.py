"""Small flight logs of every format the review reads, crafted for the bounds tests and the reader fuzz:
`n` samples of a hovering multirotor `gap_s` apart (each sample: position, attitude, commanded path,
throttle, mode, estimator health, a forward range reading), as a PX4 ULog, an ArduPilot DataFlash log, a
ground station's MAVLink `.tlog` and the daemon's own event log. Written with the harness's writers (the
ULog and DataFlash writers of `sitl_harness`, pymavlink's encoder), so the bytes are the formats' own."""

from __future__ import annotations

import json
import struct
from pathlib import Path

from sitl_harness.flightlog import DataFlashWriter, Px4Log
from sitl_harness.ulog_writer import ULogWriter

T0_US = 1_000_000  # the first sample's time since boot [µs]
RANGE_M = 12.0


def gappy_ulog(path: Path, n: int = 60, gap_s: float = 299.0, *, range_m: float = RANGE_M, ver_hw: str = "PX4_SITL",
               mav_type: int = 2, speed: float = 0.0) -> Path:
    topics = ("vehicle_local_position", "vehicle_attitude", "vehicle_local_position_setpoint",
              "vehicle_thrust_setpoint", "vehicle_status", "vehicle_land_detected", "estimator_status",
              "distance_sensor")
    w = ULogWriter(path, T0_US)
    for name in topics:
        w.define(name, Px4Log.TOPICS[name])
    w.info("sys_name", "PX4")
    w.info("ver_hw", ver_hw)
    w.param("MAV_TYPE", mav_type, True)
    ids = {name: w.add(name) for name in topics}
    for k in range(n):
        us = T0_US + round(k * gap_s * 1e6)
        x = speed * k * gap_s
        w.data(ids["vehicle_local_position"], {"timestamp": us, "xy_valid": True, "z_valid": True, "v_xy_valid": True,
                                               "v_z_valid": True, "x": x, "z": -5.0, "vx": speed})
        w.data(ids["vehicle_attitude"], {"timestamp": us, "q": [1.0, 0.0, 0.0, 0.0]})
        w.data(ids["vehicle_local_position_setpoint"], {"timestamp": us, "x": x, "z": -5.0})
        w.data(ids["vehicle_thrust_setpoint"], {"timestamp": us, "xyz": [0.0, 0.0, -0.45]})
        w.data(ids["vehicle_status"], {"timestamp": us, "nav_state": 3, "arming_state": 2, "vehicle_type": 1})
        w.data(ids["vehicle_land_detected"], {"timestamp": us, "landed": False})
        w.data(ids["estimator_status"], {"timestamp": us, "solution_status_flags": 1 | 2 | 8 | 16 | 32})
        w.data(ids["distance_sensor"], {"timestamp": us, "min_distance": 0.2, "max_distance": 40.0,
                                        "current_distance": range_m, "signal_quality": 100, "orientation": 0})
    w.close()
    return path


def gappy_bin(path: Path, n: int = 60, gap_s: float = 299.0, *, range_m: float = RANGE_M, speed: float = 0.0,
              params: dict | None = None) -> Path:
    """`params`: more PARM entries (name → value) after the usual three."""
    with DataFlashWriter(path) as w:
        w.write("MSG", 500, "ArduCopter V4.5.7 (abc1234)")
        for name, v in {"ANGLE_MAX": 3000, "RNGFND1_MAX_CM": 4000, "RNGFND1_MIN_CM": 20, **(params or {})}.items():
            w.write("PARM", 600, name, float(v))
        w.write("ARM", 700, 1, 0, 0)
        w.write("MODE", 800, 5, 5, 0)  # LOITER
        w.write("EV", 900, 28)
        for k in range(n):
            us = T0_US + round(k * gap_s * 1e6)
            copter_sample(w, us, speed * k * gap_s, speed, range_m=range_m)
    return path


def copter_sample(w: DataFlashWriter, us: int, x: float, speed: float, y: float = 0.0, range_m: float | None = RANGE_M):
    """One 50 Hz sample of a level Copter flight along +x at `speed`, at `x` (and `y`) 5 m up, on its commanded
    path, healthy, in the air: EKF position, health, attitude, target, throttle and (unless None) a forward
    rangefinder reading `range_m` (Good)."""
    w.write("XKF1", us, 0, 0.0, 0.0, 0.0, speed, 0.0, 0.0, 0.0, x, y, -5.0)
    w.write("XKF4", us, 0, 1 | 2 | 4 | 8 | 16 | 32)
    w.write("ATT", us, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    w.write("PSCN", us, x, x, speed, speed)
    w.write("PSCE", us + 10, 0.0, y, 0.0, 0.0)
    w.write("CTUN", us, 0.45, 0.45, 0.45)
    if range_m is not None:
        w.write("RFND", us, 0, range_m, 4, 0)


def gappy_tlog(path: Path, n: int = 60, gap_s: float = 299.0, *, range_m: float = RANGE_M, mav_type: int = 2,
               autopilot: int = 12) -> Path:
    from pymavlink.dialects.v20 import common as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    t0_us = 1_790_000_000_000_000  # UNIX µs
    with open(path, "wb") as out:
        for k in range(n):
            t = T0_US + round(k * gap_s * 1e6)
            ms = (t // 1000) & 0xFFFFFFFF

            def put(msg, t=t):
                out.write(struct.pack(">Q", t0_us + t) + msg.pack(m))

            put(m.heartbeat_encode(mav_type, autopilot, 1 | 4 | 8 | 16 | 128, (4 << 16) | (3 << 24), 4))
            put(m.estimator_status_encode(t, 1 | 2 | 8 | 16 | 32, 0, 0, 0, 0, 0, 0, 0, 0))
            put(m.extended_sys_state_encode(0, 2))
            put(m.local_position_ned_encode(ms, 0.0, 0.0, -5.0, 0.0, 0.0, 0.0))
            put(m.attitude_encode(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
            put(m.position_target_local_ned_encode(ms, 1, 0b110111111000, 0.0, 0.0, -5.0, 0, 0, 0, 0, 0, 0, 0, 0))
            put(m.vfr_hud_encode(0.0, 0.0, 0, 45, -5.0, 0.0))
            put(m.distance_sensor_encode(ms, 20, 4000, round(range_m * 100), 0, 0, 0, 100))
    return path


def gappy_events(directory: Path, n: int = 60, gap_s: float = 299.0) -> Path:
    """The daemon's own event log (`events.jsonl`): a start event, then `n` state samples `gap_s` apart."""
    from companion.onboard.logschema import LOG_FILE, STATE_FIELDS

    directory.mkdir(parents=True, exist_ok=True)
    wall0 = 1_790_000_000.0
    lines = [{"kind": "event", "t": 0.0, "wall": wall0, "seq": 0, "boot": "0123456789ab", "event": "start",
              "mode": "shadow"}]
    for k in range(n):
        t = 1.0 + k * gap_s
        state = {f: None for f in STATE_FIELDS}
        state.update(state="active", mode="mission", contract="stop", engaged=True, x=0.0, y=0.0, z=-5.0, vx=0.0,
                     vy=0.0, vz=0.0, ground_speed=0.0, d_od=RANGE_M, e_tr=0.3, e_tr_measured=0.1, r_obst=0.5,
                     thrust_ratio=1.0, v_max=3.0, tilt_deg=20.0, v_safe=4.0, gamma=-1.0, gamma_flown=-4.0)
        lines.append({"kind": "state", "t": t, "wall": wall0 + t, "seq": k + 1, "boot": "0123456789ab", **state})
    path = directory / LOG_FILE
    path.write_text("".join(json.dumps(r) + "\n" for r in lines))
    return path


MAKERS = {".ulg": gappy_ulog, ".bin": gappy_bin, ".tlog": gappy_tlog}
