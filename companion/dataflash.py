"""ArduPilot DataFlash (`.bin`) reader: `read_dataflash(path) -> Feed` of `companion/loginput.py` ops, with
pymavlink's `DFReader_binary`.

Message → op, fields and units from ArduPilot's log message documentation
(ardupilot.org/copter/docs/logmessages.html; converted here, once):

| message            | fields used                                              | op      |
|--------------------|----------------------------------------------------------|---------|
| XKF1 (EKF3 core 0; NKF1 for EKF2) | PN PE PD [m NED from the EKF origin], VN VE VD [m/s], Roll Pitch Yaw [deg] | pos, att (no ATT) |
| ATT                | Roll, Pitch, Yaw [deg]                                   | att     |
| PSCN + PSCE        | TPN, TPE: target position [m NED from the EKF origin]    | target  |
| CTUN               | ThO: throttle output [0–1] (what VFR_HUD.throttle carries) | thr   |
| MODE               | ModeNum / Mode: the Copter mode number (= HEARTBEAT custom_mode) | mode |
| ARM                | ArmState                                                 | mode (armed flag) |
| EV                 | Id 18 LAND_COMPLETE, 28 NOT_LANDED, 10 ARMED, 11 DISARMED | landed |
| XKF4 (core 0)      | SS: nav_filter_status bits (= EKF_STATUS_REPORT.flags)   | nav     |
| RFND               | Dist [m], Stat (4 = good), Orient (MAV_SENSOR_ORIENTATION) | range |
| PARM               | Name, Value (ANGLE_MAX cdeg, WPNAV_ACCEL cm/s², WPNAV_JERK, …) | param |

A file DFReader cannot read (empty, another format) ends in one `ContractError` line; DFReader skips a
corrupt stretch by searching for the next message header, and stops at a torn last message (both said).
"""

from __future__ import annotations

import math
from pathlib import Path

from contracts.errors import ContractError

from .loginput import Feed, lacking, order, read_head

HEAD = b"\xa3\x95"
TYPES = ["XKF1", "NKF1", "ATT", "PSCN", "PSCE", "CTUN", "MODE", "ARM", "EV", "XKF4", "NKF4", "RFND", "PARM", "MSG"]
PARAMS = ("ANGLE_MAX", "WPNAV_ACCEL", "WPNAV_JERK", "WPNAV_SPEED", "GUID_TIMEOUT", "MOT_THST_HOVER", "FRAME_CLASS",
          "Q_ENABLE", "AVOID_ENABLE", "PRX1_TYPE", "RNGFND1_TYPE", "RNGFND1_MIN_CM", "RNGFND1_MAX_CM")
EV_LANDED = {18: 1, 28: 2}  # LAND_COMPLETE → on ground, NOT_LANDED → in air (AP_Logger LogEvent)
RFND_GOOD = 4  # AP_RangeFinder Status::Good
MAX_T_US = 1 << 62


def _open(path: Path):
    from pymavlink import DFReader

    head = read_head(path, "a DataFlash log")
    if not head.startswith(HEAD):
        what = "it looks like a PX4 ULog" if head.startswith(b"ULog") else f"starts with {head[:8].hex()}"
        raise ContractError(f"{path}: not an ArduPilot DataFlash log (no 0xA3 0x95 header; {what})")
    try:
        return DFReader.DFReader_binary(str(path), zero_time_base=False)
    except Exception as err:  # noqa: BLE001 — DFReader raises anything on a broken file: one line
        raise ContractError(f"{path}: unreadable DataFlash log ({type(err).__name__}: {str(err)[:120]})") from None


def torn_tail(data: bytes, lengths: dict) -> int:
    """Bytes of a last message cut short by the end of the file (0: none, or the framing was lost to a
    corrupt stretch first, which DFReader's resynchronisation handles)."""
    pos = 0
    while pos + 3 <= len(data):
        n = lengths.get(data[pos + 2]) if data[pos:pos + 2] == HEAD else None
        if not n:
            return 0
        pos += n
    return len(data) - (pos - n) if pos > len(data) else (len(data) - pos)


def read_dataflash(path) -> Feed:
    path = Path(path)
    if not path.exists():
        raise ContractError(f"no such file or directory: {path}")
    df = _open(path)
    ops: list = []
    used: dict[str, str] = {}
    counts: dict[str, int] = {}
    params: dict[str, float] = {}
    texts: list[str] = []
    base, custom, armed = 1, 0, False
    pscn = None  # (TimeUS, TPN): PSCN and PSCE are written as a pair
    have_att = False

    def add(t, op, args, src):
        if 0 < t < MAX_T_US:
            ops.append((t, op, args))
            used.setdefault(op, src)

    try:
        while True:
            m = df.recv_match(type=TYPES)
            if m is None:
                break
            kind = m.get_type()
            counts[kind] = counts.get(kind, 0) + 1
            t = int(getattr(m, "TimeUS", 0))
            if kind in ("XKF1", "NKF1"):
                if getattr(m, "C", 0) != 0:
                    continue  # core 0 only (the primary core may differ: said in the notes)
                add(t, "pos", (m.PN, m.PE, m.PD, m.VN, m.VE, m.VD), kind)
                if not have_att:
                    add(t, "att", tuple(math.radians(v) for v in (m.Roll, m.Pitch, m.Yaw)), kind)
            elif kind == "ATT":
                have_att = True
                add(t, "att", tuple(math.radians(v) for v in (m.Roll, m.Pitch, m.Yaw)), "ATT")
            elif kind == "PSCN":
                pscn = (t, m.TPN)
            elif kind == "PSCE" and pscn is not None and abs(pscn[0] - t) < 5000:
                add(t, "target", (pscn[1], m.TPE), "PSCN/PSCE")
            elif kind == "CTUN":
                add(t, "thr", (m.ThO,), "CTUN")
            elif kind == "MODE":
                custom = int(getattr(m, "ModeNum", m.Mode))
                add(t, "mode", (base | (128 if armed else 0), custom), "MODE")
            elif kind == "ARM":
                armed = bool(m.ArmState)
                add(t, "mode", (base | (128 if armed else 0), custom), "MODE")
            elif kind == "EV":
                if m.Id in EV_LANDED:
                    add(t, "landed", (EV_LANDED[m.Id],), "EV")
            elif kind in ("XKF4", "NKF4"):
                if getattr(m, "C", 0) == 0:
                    add(t, "nav", ("EKF_STATUS_REPORT", int(m.SS)), kind)
            elif kind == "RFND":
                o = int(m.Orient)
                if o < 8:  # ROTATION_YAW_45·k (clockwise); down-facing (25) covers no path
                    # RFND has no min/max: the RNGFND1_MIN_CM/MAX_CM parameters give them; without them, or
                    # unless Stat is Good, a reading is unknown (invalid), never free space
                    lo, hi = params.get("RNGFND1_MIN_CM", 0.0) / 100, params.get("RNGFND1_MAX_CM", 0.0) / 100
                    good = int(m.Stat) == RFND_GOOD and hi > 0
                    add(t, "range", (math.radians(45 * o), float(m.Dist), lo, hi if good else 0.0, 0 if good else 1), "RFND")
            elif kind == "PARM":
                name = m.Name if isinstance(m.Name, str) else m.Name.decode(errors="replace")
                if name in PARAMS:
                    params[name] = float(m.Value)
                    add(max(t, 1), "param", (name, float(m.Value)), "PARM")
            elif kind == "MSG" and len(texts) < 20:
                texts.append(str(m.Message))
    except Exception as err:  # noqa: BLE001 — DFReader may raise deep inside a broken file: what was read stands
        texts.append(f"reader stopped: {type(err).__name__}")
        used.setdefault("_stopped", f"{type(err).__name__}: {str(err)[:80]}")
    stopped = used.pop("_stopped", None)
    if not any(op == "pos" for _, op, _ in ops):
        raise ContractError(f"{path}: no usable telemetry: the DataFlash log has no XKF1/NKF1 (EKF position) "
                            f"(messages: {', '.join(sorted(counts)) or 'none'})")
    ops, jumps = order(ops)
    fw = next((x for x in texts if x.startswith(("ArduCopter", "ArduPlane", "ArduRover", "APM:"))), None)
    plane = fw is not None and "Plane" in fw
    if plane and params.get("Q_ENABLE", 0) < 1:
        raise ContractError(f"{path}: a fixed-wing log ({fw}): the contract is for multirotors; not reviewed")
    missing = lacking(used, {"obstacle sensing": "RFND, PRX", "commanded path": "PSCN/PSCE", "thrust": "CTUN",
                             "navigation health": "XKF4", "modes and arming": "MODE, ARM",
                             "landed state": "EV LAND_COMPLETE / NOT_LANDED"})
    size = path.stat().st_size
    damaged = []
    if stopped:
        damaged.append(f"the reader stopped early ({stopped}): the rest of the file is not reviewed")
    tail = torn_tail(path.read_bytes(), {k: f.len for k, f in df.formats.items()})
    if tail:
        damaged.append(f"the file ends inside a message (truncated: the last {tail} bytes lost)")

    span = ops[-1][0] / 1e6
    rates = {k: round((counts.get(k, 0) - 1) / span, 2) for k in counts if span > 0}
    info = {
        "log": str(path),
        "format": "ArduPilot DataFlash",
        "bytes": size,
        "vehicle": {"hardware": next((x for x in texts if x.startswith(("CubeOrange", "Pixhawk", "fmuv", "ChibiOS"))), None),
                    "airframe": "VTOL quadplane" if plane else
                    (f"copter, FRAME_CLASS {int(params['FRAME_CLASS'])}" if "FRAME_CLASS" in params else "copter"),
                    "mav_type": None, "sys_autostart": None, "vtol": plane, "fixed_wing_s": 0.0},
        "firmware": {"name": fw or "ArduPilot (no version message in the log)", "release": None, "git": None,
                     "branch": None, "os": None},
        "span_s": span,
        "sources": used,
        "lacking": missing,
        "rates_hz": rates,
        "params": params,
        "dropouts": 0,
        "dropout_s": 0.0,
        "damaged": damaged,
        "time_jumps": jumps[:100],
    }
    return Feed(ops=ops, info=info, autopilot="ardupilot")
