"""PX4 ULog (`.ulg`) reader: `read_ulog(path) -> Feed` of `companion/ground/flightlogs/loginput.py` ops, with pyulog.

Topic → op, each field's meaning from PX4's `msg/*.msg` (units and frames converted here, once):

| topic (PX4 msg file)                                   | fields used                           | op       |
|--------------------------------------------------------|---------------------------------------|----------|
| vehicle_local_position (VehicleLocalPosition.msg)      | x y z [m NED], vx vy vz [m/s NED], xy_valid, v_xy_valid | pos, nav (no estimator flags) |
| vehicle_attitude (VehicleAttitude.msg)                 | q[4] Hamilton, FRD→NED, w first       | att      |
| vehicle_local_position_setpoint (VehicleLocalPositionSetpoint.msg) | x y [m NED], NaN = not controlled | target |
| trajectory_setpoint (TrajectorySetpoint.msg)           | position[0..1] (older: x y)           | target (when the above is absent) |
| position_setpoint_triplet (PositionSetpointTriplet.msg)| current.lat/lon [deg], current.valid  | target (placed about vehicle_local_position ref_lat/ref_lon) when neither above exists |
| vehicle_thrust_setpoint (VehicleThrustSetpoint.msg)    | xyz[2] normalised thrust, FRD (−: up) | thr (−xyz[2], what PX4's VFR_HUD stream sends) |
| actuator_controls_0 (older PX4)                        | control[3] throttle 0–1               | thr      |
| hover_thrust_estimate (HoverThrustEstimate.msg)        | hover_thrust, valid                   | thr (only when no thrust setpoint is logged) |
| vehicle_status (VehicleStatus.msg)                     | nav_state, arming_state (2 = ARMED), vehicle_type / is_rotary_wing, is_vtol | mode |
| vehicle_land_detected (VehicleLandDetected.msg)        | landed                                | landed   |
| estimator_status (EstimatorStatus.msg), the primary instance | solution_status_flags (= MAVLink ESTIMATOR_STATUS.flags) | nav |
| estimator_selector_status (EstimatorSelectorStatus.msg) | primary_instance: which estimator_status instance is the primary (0 without it); a change of primary is said | — |
| distance_sensor (DistanceSensor.msg)                   | current/min/max_distance [m], orientation (ROTATION_*), signal_quality (−1 unknown, 0 invalid) | range |
| obstacle_distance (ObstacleDistance.msg)               | distances[72] [cm], increment [deg], angle_offset [deg], min/max_distance [cm], frame | bins |
| mission_result (MissionResult.msg)                     | seq_current                           | seq      |
| parameters (initial and changed)                       | MPC_TILTMAX_AIR, MPC_ACC_HOR, MPC_JERK_AUTO, COM_OBL_RC_ACT, … | param |

A log that pyulog cannot parse (empty, another format, a broken header) ends in one `ContractError` line;
a truncated file or a corrupt stretch is read as far as pyulog recovers, and said.
"""

from __future__ import annotations

import contextlib
import io
import math
import mmap
import os
from pathlib import Path

import numpy as np

from contracts.errors import ContractError
from contracts.geodesy import ne_from_geo

from .flightspan import off_path_sensors
from .loginput import (
    MAV_TYPES,
    VTOL_TYPES,
    Feed,
    exclude,
    finite_param,
    firmware_release,
    lacking,
    order,
    quat_euler,
    read_head,
    unreadable_params,
)

ULOG_MAGIC = b"ULog\x01\x12\x35"
TOPICS = ["vehicle_local_position", "vehicle_attitude", "vehicle_local_position_setpoint", "trajectory_setpoint",
          "position_setpoint_triplet", "vehicle_thrust_setpoint", "actuator_controls_0", "hover_thrust_estimate",
          "vehicle_status", "vehicle_land_detected", "estimator_status", "distance_sensor", "obstacle_distance",
          "mission_result", "vehicle_gps_position", "sensor_gps", "estimator_selector_status"]
MAV_FRAME_GLOBAL = 0
MAV_FRAME_LOCAL_NED = 1
ARMING_STATE_ARMED = 2  # VehicleStatus.msg
VEHICLE_TYPE_FIXED_WING = 2  # VehicleStatus.msg VEHICLE_TYPE_*
# VehicleStatus.msg NAVIGATION_STATE_* → PX4 custom mode (main, sub) as px4_custom_mode.h and HEARTBEAT carry it
NAV_STATE = {0: (1, 0), 1: (2, 0), 2: (3, 0), 3: (4, 4), 4: (4, 3), 5: (4, 5), 10: (5, 0), 12: (4, 6), 14: (6, 0),
             15: (7, 0), 17: (4, 2), 18: (4, 6), 19: (4, 8), 20: (4, 9), 21: (3, 0), 22: (4, 2)}
# ESTIMATOR_STATUS_FLAGS the daemon needs (attitude, horizontal velocity, relative horizontal position),
# stated from vehicle_local_position's validity flags where no estimator_status flags are logged
NAV_FROM_VALIDITY = 1 | 2 | 8
PARAMS = ("MPC_TILTMAX_AIR", "MPC_ACC_HOR", "MPC_JERK_AUTO", "COM_OBL_RC_ACT", "MPC_XY_CRUISE", "MPC_XY_VEL_MAX",
          "MPC_THR_HOVER", "MAV_TYPE", "SYS_AUTOSTART", "CP_DIST")
MAX_DT_US = 1 << 62


def _open(path: Path):
    """(pyulog's ULog, what pyulog printed while reading: its warnings about a damaged file)."""
    import pyulog

    head = read_head(path, "a ULog")
    if not head.startswith(ULOG_MAGIC[:4]):
        raise ContractError(f"{path}: not a PX4 ULog (no 'ULog' header; {_sniff(head)})")
    with _mapped(path) as data:  # walked, not copied: a long log stays on disk
        formats, loop_at = definitions(data)
        padded = None if loop_at is None else io.BytesIO(bytes(data) + bytes(65_538))
    why = nesting_refused(formats)
    if why:
        raise ContractError(f"{path}: unreadable ULog ({why})")
    said = io.StringIO()
    if loop_at is not None:  # pyulog would loop for ever on it: see `definitions`
        said.write(f"a corrupt message header at byte {loop_at} runs past the end of the file\n")
    try:
        with contextlib.redirect_stdout(said):  # pyulog prints its warnings: kept off stdout, said as damage
            # padded past the longest message (uint16 size + header) with zeros (type 0: skipped byte by byte),
            # every read is whole and pyulog's step back over a corrupt header is one byte forward
            source = str(path) if padded is None else padded
            ulog = pyulog.ULog(source, TOPICS, disable_str_exceptions=True)
    except Exception as err:  # noqa: BLE001 — pyulog raises anything on a broken file: one line
        raise ContractError(f"{path}: unreadable ULog ({type(err).__name__}: {str(err)[:120]})") from None
    return ulog, [line.strip() for line in said.getvalue().splitlines() if line.strip()]


DEFINITION_TYPES = frozenset(b"IMFPQB")  # what pyulog's definitions reader takes; A, L, C end the section


def definitions(data: bytes) -> tuple[dict, int | None]:
    """({format name: [(type, array size)]}, where pyulog's definitions reader would loop for ever, or None).
    Walks the definitions section as pyulog 1.x does (ULog spec: the messages before the first `A`, `L` or
    `C`). pyulog steps over a header of an unknown type with size 0, type 0 or a size above 10 000 by seeking
    back to one byte past it — relative to what it read, so a header whose size runs past the end of the file
    sends it backwards, for ever; the walk returns that header's offset. Pure."""
    import pyulog

    formats, pos, n = {}, 16, len(data)
    while pos + 3 <= n:
        size, kind = int.from_bytes(data[pos:pos + 2], "little"), data[pos + 2]
        if kind in b"ALC":
            break
        got = min(size, n - pos - 3)
        if kind == ord("F") and got == size:
            try:
                f = pyulog.ULog.MessageFormat(data[pos + 3:pos + 3 + size], None)
                formats[f.name] = [(t, k) for t, k, _ in f.fields]
            except Exception:  # noqa: BLE001 — a format pyulog cannot parse: pyulog says so itself
                pass
        if kind not in DEFINITION_TYPES and (kind == 0 or size == 0 or size > 10_000):
            back = pos + 3 + got - 2 - size
            if back <= pos:
                return formats, pos
            pos = back
            continue
        pos += 3 + got
    return formats, None


def nesting_refused(formats: dict) -> str | None:
    """Why the ULog's formats cannot be read within the bounds (`companion.ground.flightlogs`: MAX_DEPTH levels of
    nested formats, MAX_FIELDS fields of a topic flattened, no format containing itself), else None. pyulog
    flattens every logged topic's nested formats field by field as it reads the definitions: a few kB of
    nested arrays would expand to billions of fields."""
    import pyulog

    from .bounds import MAX_DEPTH, MAX_FIELDS

    basic = pyulog.ULog._UNPACK_TYPES
    memo: dict[str, tuple[int, int]] = {}  # name → (fields flattened, depth)

    def measure(name: str, stack: tuple) -> tuple[int, int]:
        if name in memo:
            return memo[name]
        if name in stack:
            raise ValueError(f"format {name!r} contains itself")
        if len(stack) > MAX_DEPTH:
            raise ValueError(f"formats nested more than {MAX_DEPTH} deep (format {name!r})")
        fields, depth = 0, 1
        for typ, n in formats[name]:
            if typ in formats:
                sub, d = measure(typ, (*stack, name))
                fields, depth = fields + max(n, 1) * sub, max(depth, d + 1)
            else:
                fields += max(n, 1) if typ in basic else 1
            if fields > MAX_FIELDS:
                raise ValueError(f"format {name!r} flattens to more than {MAX_FIELDS} fields (nested arrays)")
        if depth > MAX_DEPTH:
            raise ValueError(f"formats nested more than {MAX_DEPTH} deep (format {name!r})")
        memo[name] = (fields, depth)
        return memo[name]

    try:
        for name in formats:
            measure(name, ())
    except ValueError as err:
        return str(err)
    return None


ULOG_TYPES = frozenset(b"BFIMPQADLCSOR")  # the ULog message types (ULog file format, "Definitions section")


def torn_tail(path: Path) -> bool:
    """Whether the file ends inside a message (walks the ULog framing: uint16 size, uint8 type). A walk that
    loses the framing (a corrupt stretch) says nothing: pyulog's own recovery reports that."""
    with _mapped(path) as data:
        pos = 16
        while pos + 3 <= len(data):
            size, kind = int.from_bytes(data[pos:pos + 2], "little"), data[pos + 2]
            if kind not in ULOG_TYPES:
                return False
            pos += 3 + size
        return pos != len(data)


@contextlib.contextmanager
def _mapped(path: Path):
    """The file's bytes, memory-mapped read-only (b"" for an empty file)."""
    with open(path, "rb") as fh:
        if os.fstat(fh.fileno()).st_size == 0:
            yield b""
            return
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as m:
            yield m


def _sniff(head: bytes) -> str:
    """What a file with the wrong contents seems to be, for the error line."""
    if head[:2] == b"\xa3\x95":
        return "it looks like an ArduPilot DataFlash log"
    if len(head) >= 9 and head[8] in (0xFD, 0xFE):
        return "it looks like a MAVLink .tlog"
    if head.lstrip()[:1] in (b"{", b"["):
        return "it looks like JSON"
    return f"starts with {head[:8].hex()}"


def _topics(ulog) -> tuple[dict, list[str]]:
    """(topic name → data dict of its primary instance, notes). The primary is instance 0, except for
    estimator_status: the instance estimator_selector_status names primary most of the time (PX4 runs
    several EKF instances and switches between them; each switch is said)."""
    out, notes = {}, []
    for d in ulog.data_list:
        if d.multi_id == 0 or d.name not in out:
            if d.name in out and d.multi_id != 0:
                continue
            out[d.name] = d.data
    sel = out.get("estimator_selector_status")
    if sel is not None and len(p := np.asarray(sel.get("primary_instance", []), dtype=int)):
        primary = int(np.bincount(p).argmax())
        inst = {d.multi_id: d.data for d in ulog.data_list if d.name == "estimator_status"}
        if primary in inst:
            out["estimator_status"] = inst[primary]
        switches = int(np.count_nonzero(np.diff(p)))
        if switches:
            notes.append(f"the primary estimator changed {switches}× (estimator_selector_status); estimator_status "
                         f"instance {primary}, the primary most of the flight, is the one judged")
    return out, notes


def _col(data: dict, *names):
    for n in names:
        if n in data:
            return np.asarray(data[n], dtype=float)
    return None


def read_ulog(path) -> Feed:
    path = Path(path)
    if not path.exists():
        raise ContractError(f"no such file or directory: {path}")
    ulog, said = _open(path)
    top, selector_notes = _topics(ulog)
    ops: list = []
    ts = {k: np.asarray(v["timestamp"], dtype=np.int64) for k, v in top.items() if len(v.get("timestamp", ()))}
    top = {k: v for k, v in top.items() if k in ts}  # a topic without timestamps (a damaged format): not read
    used: dict[str, str] = {}
    # PX4's logger starts by writing each topic's last sample, stamped when it was published, which may be long
    # before logging began: taken as the topic's value at the log's start (no pause before it is made up)
    start, early = int(getattr(ulog, "start_timestamp", 0) or 0), set()

    def add(topic, times, op, rows):
        for t, row in zip(times.tolist(), rows):
            if 0 < t < MAX_DT_US:  # a zero or absurd timestamp is a corrupt sample: not fed
                if t < start:
                    t = start
                    early.add(topic)
                ops.append((t, op, row))
        used[op] = used.get(op) or topic

    ref, damaged_notes = None, []
    if (d := top.get("vehicle_local_position")) is not None and "vehicle_local_position" in ts:
        cols = [_col(d, k) for k in ("x", "y", "z", "vx", "vy", "vz")]
        if all(c is not None for c in cols):
            add("vehicle_local_position", ts["vehicle_local_position"], "pos", list(zip(*(c.tolist() for c in cols))))
        xv, vv = _col(d, "xy_valid"), _col(d, "v_xy_valid")
        if xv is not None and len(xv) and not np.all(xv > 0):
            invalid = float(np.mean(xv <= 0))
            damaged_notes.append(f"vehicle_local_position xy_valid false in {invalid:.0%} of its samples (no horizontal "
                                 "position estimate there: the estimator is unhealthy, the contract not judged there)")
        if "estimator_status" not in top or "solution_status_flags" not in top["estimator_status"]:
            if xv is not None and vv is not None:
                flags = np.where((xv > 0) & (vv > 0), NAV_FROM_VALIDITY, 0)
                add("vehicle_local_position (xy_valid, v_xy_valid)", ts["vehicle_local_position"], "nav",
                    [("ESTIMATOR_STATUS", int(f)) for f in flags])
        lat0, lon0 = _col(d, "ref_lat"), _col(d, "ref_lon")
        if lat0 is not None and lon0 is not None and len(lat0):
            ref = (float(lat0[-1]), float(lon0[-1]))
    if (d := top.get("vehicle_attitude")) is not None:
        q = [_col(d, f"q[{i}]") for i in range(4)]
        if all(c is not None for c in q):
            # at most one sample per 20 ms: the daemon's loop takes no more (a 200 Hz topic costs 4× for nothing)
            t = ts["vehicle_attitude"]
            keep = np.concatenate(([True], np.diff(t // 20_000) > 0)) if len(t) else np.zeros(0, bool)
            rows = [quat_euler(*r) for r in zip(*(c[keep].tolist() for c in q))]
            add("vehicle_attitude", t[keep], "att", rows)
    for topic, xs in (("vehicle_local_position_setpoint", ("x", "y")), ("trajectory_setpoint", ("position[0]", "x"))):
        d = top.get(topic)
        if d is None or "target" in used:
            continue
        x = _col(d, *xs)
        y = _col(d, "position[1]" if xs[0] == "position[0]" else "y", "y")
        if x is not None and y is not None:
            add(topic, ts[topic], "target", list(zip(x.tolist(), y.tolist())))
    if "target" not in used and (d := top.get("position_setpoint_triplet")) is not None and ref is not None:
        lat, lon, valid = _col(d, "current.lat"), _col(d, "current.lon"), _col(d, "current.valid")
        if lat is not None and lon is not None:
            rows = [ne_from_geo(a, b, *ref) if (v is None or v > 0) and math.isfinite(a) and math.isfinite(b)
                    else (math.nan, math.nan)
                    for a, b, v in zip(lat.tolist(), lon.tolist(), valid.tolist() if valid is not None else [None] * len(lat))]
            add("position_setpoint_triplet (current, about the local origin)", ts["position_setpoint_triplet"],
                "target", rows)
    if (d := top.get("vehicle_thrust_setpoint")) is not None and (z := _col(d, "xyz[2]")) is not None:
        add("vehicle_thrust_setpoint", ts["vehicle_thrust_setpoint"], "thr", [(-v,) for v in z.tolist()])
    elif (d := top.get("actuator_controls_0")) is not None and (c := _col(d, "control[3]")) is not None:
        add("actuator_controls_0", ts["actuator_controls_0"], "thr", [(v,) for v in c.tolist()])
    elif (d := top.get("hover_thrust_estimate")) is not None and (h := _col(d, "hover_thrust")) is not None:
        add("hover_thrust_estimate", ts["hover_thrust_estimate"], "thr", [(v,) for v in h.tolist()])
    fixed_wing_s, vtype, fw_spans = 0.0, None, []
    if (d := top.get("vehicle_status")) is not None:
        nav, arm = _col(d, "nav_state"), _col(d, "arming_state")
        if nav is not None and arm is not None:
            rows = []
            for n, a in zip(nav.astype(int).tolist(), arm.astype(int).tolist()):
                main, sub = NAV_STATE.get(n, (0, 0))
                rows.append((1 | (128 if a == ARMING_STATE_ARMED else 0), main << 16 | sub << 24))
            add("vehicle_status", ts["vehicle_status"], "mode", rows)
        vt = _col(d, "vehicle_type")
        if vt is None and (rw := _col(d, "is_rotary_wing")) is not None:
            vt = np.where(rw > 0, 1, 2)
        if vt is not None and len(vt) > 1:
            t = ts["vehicle_status"]
            fw = vt[:-1] == VEHICLE_TYPE_FIXED_WING
            fixed_wing_s = float(np.sum(np.diff(t)[fw]) / 1e6)
            vtype = int(vt[-1])
            for i in np.nonzero(fw)[0]:  # consecutive fixed-wing samples make one phase
                if fw_spans and fw_spans[-1][1] == int(t[i]):
                    fw_spans[-1] = (fw_spans[-1][0], int(t[i + 1]))
                else:
                    fw_spans.append((int(t[i]), int(t[i + 1])))
    if (d := top.get("vehicle_land_detected")) is not None and (c := _col(d, "landed")) is not None:
        add("vehicle_land_detected", ts["vehicle_land_detected"], "landed", [(1 if v > 0 else 2,) for v in c.tolist()])
    if (d := top.get("estimator_status")) is not None and (c := _col(d, "solution_status_flags")) is not None:
        add("estimator_status", ts["estimator_status"], "nav", [("ESTIMATOR_STATUS", int(v)) for v in c.tolist()])
    off_path: list[dict] = []  # range sensors looking off the path (up, down): named in the review
    if (d := top.get("distance_sensor")) is not None:
        cur, lo, hi = _col(d, "current_distance"), _col(d, "min_distance"), _col(d, "max_distance")
        ori, q = _col(d, "orientation"), _col(d, "signal_quality")
        if cur is not None and lo is not None and hi is not None:
            ori = ori if ori is not None else np.zeros(len(cur))
            off_path = off_path_sensors("distance_sensor", ori)
            q = q if q is not None else -np.ones(len(cur))
            rows = [(math.radians(45 * o), c, a, b, 0 if s < 0 else 1 if s == 0 else max(2, int(s)))
                    for c, a, b, o, s in zip(cur.tolist(), lo.tolist(), hi.tolist(), ori.astype(int).tolist(), q.tolist())
                    if o < 8]  # ROTATION_YAW_45·k, clockwise in FRD; up/down-facing (24, 25) cover no path
            add("distance_sensor", ts["distance_sensor"][ori < 8], "range", rows)
    if (d := top.get("obstacle_distance")) is not None:
        dist = [_col(d, f"distances[{k}]") for k in range(72)]
        inc, off = _col(d, "increment"), _col(d, "angle_offset")
        lo, hi, frame = _col(d, "min_distance"), _col(d, "max_distance"), _col(d, "frame")
        if all(c is not None for c in dist) and inc is not None and hi is not None:
            mat = np.stack(dist, axis=1)
            off = off if off is not None else np.zeros(len(inc))
            frame = frame if frame is not None else np.full(len(inc), 12.0)
            rows = []
            for k in range(len(inc)):
                row, used_bins = mat[k], mat[k] != 65535  # UINT16_MAX: a bin that knows nothing
                if not inc[k] > 0 or inc[k] * 72 > 360 + 1e-6 or (lo is not None and lo[k] > hi[k]):
                    rows.append((np.zeros(0), np.zeros(0), 0.0, 0.0, False))
                    continue
                ang = np.radians(off[k] + inc[k] * np.arange(72))[used_bins]
                rng = np.where(row[used_bins] > hi[k], np.inf, row[used_bins] / 100.0)
                rows.append((ang, rng, hi[k] / 100.0, math.radians(inc[k]), frame[k] in (MAV_FRAME_GLOBAL, MAV_FRAME_LOCAL_NED)))
            add("obstacle_distance", ts["obstacle_distance"], "bins", rows)
    if (d := top.get("mission_result")) is not None and (c := _col(d, "seq_current")) is not None:
        add("mission_result", ts["mission_result"], "seq", [(v,) for v in c.tolist()])

    params, unreadable = {}, []  # the parameters read (a number each; one that is not is damage, said)
    for name, value in ulog.initial_parameters.items():
        if name not in PARAMS:
            continue
        if (v := finite_param(value)) is None:
            unreadable.append(name)
        else:
            params[name] = v
    t_first = min((t for t, _, _ in ops), default=0)
    for name in PARAMS:
        if name in params:
            ops.append((max(t_first, 1), "param", (name, params[name])))
    for t, name, value in ulog.changed_parameters:
        if name in PARAMS and 0 < t < MAX_DT_US:
            if (v := finite_param(value)) is None:
                unreadable.append(name)
            else:
                ops.append((t, "param", (name, v)))
    if unreadable:
        damaged_notes.append(unreadable_params(unreadable))
    if not any(op == "pos" for _, op, _ in ops):
        raise ContractError(f"{path}: no usable telemetry: the ULog has no vehicle_local_position "
                            f"(topics: {', '.join(sorted(d.name for d in ulog.data_list)[:12]) or 'none'})")
    info_msgs = ulog.msg_info_dict
    is_vtol = _col(top.get("vehicle_status") or {}, "is_vtol")
    mav_type = int(params["MAV_TYPE"]) if "MAV_TYPE" in params else None
    vtol = mav_type in VTOL_TYPES or (is_vtol is not None and bool(np.any(is_vtol > 0)))
    cuts = []
    if vtol and fw_spans:  # a VTOL's fixed-wing phases: not the multirotor contract's; cut out, said once
        ops, cuts = exclude(ops, fw_spans)
    ops, jumps = order(ops)
    kind = MAV_TYPES.get(mav_type, f"MAV_TYPE {mav_type}") if mav_type is not None else "unknown airframe"
    if mav_type == 1 or (not vtol and vtype == VEHICLE_TYPE_FIXED_WING):
        raise ContractError(f"{path}: a fixed-wing log ({kind}, {info_msgs.get('ver_hw', '?')}): the contract is "
                            "for multirotors; not reviewed")
    wall0 = 0.0
    for gps in ("vehicle_gps_position", "sensor_gps"):
        d = top.get(gps)
        if d is not None and (u := _col(d, "time_utc_usec")) is not None:
            ok = np.nonzero(u > 1e15)[0]
            if len(ok):
                wall0 = (u[ok[0]] - ts[gps][ok[0]] + t_first) / 1e6
                break
    # what the replay lacks, by what it is for (said once in the review)
    missing = lacking(used, {
        "obstacle sensing": "distance_sensor, obstacle_distance",
        "commanded path": "vehicle_local_position_setpoint, trajectory_setpoint, position_setpoint_triplet",
        "thrust": "vehicle_thrust_setpoint, actuator_controls_0, hover_thrust_estimate",
        "navigation health": "estimator_status", "modes and arming": "vehicle_status",
        "landed state": "vehicle_land_detected"})
    rates = {}
    for topic, t in ts.items():
        if len(t) > 1 and t[-1] > t[0]:
            rates[topic] = (len(t) - 1) / ((t[-1] - t[0]) / 1e6)
    corrupt = bool(getattr(ulog, "file_corruption", False))
    info = {
        "log": str(path),
        "format": "PX4 ULog",
        "bytes": path.stat().st_size,
        "vehicle": {"hardware": info_msgs.get("ver_hw"), "airframe": kind, "mav_type": mav_type,
                    "sys_autostart": int(params["SYS_AUTOSTART"]) if "SYS_AUTOSTART" in params else None,
                    "vtol": bool(vtol), "fixed_wing_s": fixed_wing_s,
                    "fixed_wing_cut": cuts},
        "firmware": {"name": info_msgs.get("sys_name", "PX4"), "release": firmware_release(info_msgs.get("ver_sw_release")),
                     "git": info_msgs.get("ver_sw"), "branch": info_msgs.get("ver_sw_branch"),
                     "os": info_msgs.get("sys_os_name")},
        "span_s": ops[-1][0] / 1e6 if ops else 0.0,
        "sources": used,
        "lacking": missing,
        "other_sensors": off_path,
        "rates_hz": {k: round(v, 2) for k, v in sorted(rates.items())},
        "params": {k: params[k] for k in PARAMS if k in params},
        "dropouts": len(ulog.dropouts),
        "dropout_s": float(sum(d.duration for d in ulog.dropouts) / 1000.0),
        "log_duration_s": (ulog.last_timestamp - ulog.start_timestamp) / 1e6,
        "damaged": (["corrupt data skipped by the ULog reader (file_corruption)"] if corrupt else [])
        + (["the file ends inside a message (truncated: the last message is lost)"] if torn_tail(path) else [])
        + damaged_notes
        + ([f"the ULog reader said: {'; '.join(said[:3])}" + (f" (and {len(said) - 3} more)" if len(said) > 3 else "")]
           if said else []),
        "estimator_notes": selector_notes,
        "time_jumps": jumps[:100],
        "stamped_before_start": sorted(early),  # topics whose first sample predates logging (taken at its start)
    }
    return Feed(ops=ops, info=info, autopilot="px4", wall0=wall0)
