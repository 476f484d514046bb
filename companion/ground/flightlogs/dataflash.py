"""ArduPilot DataFlash (`.bin`) reader: `read_dataflash(path) -> Feed` of `companion/ground/flightlogs/loginput.py` ops, with
pymavlink's `DFReader_binary`.

Message → op, fields and units from ArduPilot's log message documentation
(ardupilot.org/copter/docs/logmessages.html; converted here, once):

| message            | fields used                                              | op      |
|--------------------|----------------------------------------------------------|---------|
| XKF1 (EKF3 core 0; NKF1 for EKF2) | PN PE PD [m NED from the EKF origin], VN VE VD [m/s], Roll Pitch Yaw [deg] | pos, att (no ATT) |
| ATT                | Roll, Pitch, Yaw [deg]                                   | att     |
| PSCN + PSCE        | TPN, TPE: target position [m NED from the EKF origin]    | target  |
| CTUN               | ThO: throttle output [0–1] (what VFR_HUD.throttle carries) | thr   |
| QTUN (a quadplane) | ThO: the VTOL motors' throttle, motors->get_throttle() [0–1] (ArduPlane's CTUN.ThO is the forward motor's) | thr |
| MODE               | ModeNum / Mode: the Copter mode number (= HEARTBEAT custom_mode); a quadplane's ArduPlane number, translated (`PLANE_AS_COPTER`) | mode |
| QTUN               | its presence: logged at 25 Hz while a quadplane's VTOL motors are active (QuadPlane::update) | fixed-wing phases |
| VER                | FWS: the firmware string ("ArduPlane V4.5.7 …"), as the boot MSG | — |
| ARM                | ArmState                                                 | mode (armed flag) |
| EV                 | Id 18 LAND_COMPLETE, 28 NOT_LANDED, 10 ARMED, 11 DISARMED | landed |
| XKF4 (core 0)      | SS: nav_filter_status bits (= EKF_STATUS_REPORT.flags)   | nav     |
| RFND               | Dist [m], Stat (4 Good; 3 OutOfRangeHigh: nothing within RNGFND1_MAX_CM), Orient (MAV_SENSOR_ORIENTATION) | range |
| PRX (AP_Proximity LogStructure.h) | He, D0…D315: nearest object per 45° body sector [m] (0: no data; ≥ PRX1_MAX: none within range) | bins |
| GUIP (ArduCopter Log.cpp) | pX, pY: GUIDED position target, NEU from the EKF origin; cm in Copter 4.x (FMTU multiplier B), m where FMTU says so | target (when no PSCN/PSCE) |
| GPS                | Status (3: 3D fix), GWk, GMS: GPS week and ms → the log's UTC (wall0) | —     |
| PARM               | Name, Value (ANGLE_MAX cdeg, WPNAV_ACCEL cm/s², WPNAV_JERK, …) | param |

A quadplane (ArduPlane with Q_ENABLE ≥ 1) is judged only where it flies as a multirotor: its fixed-wing
phases are cut out of the ops (`plane_fixed_wing_spans`, `loginput.exclude`) and said once, as for a PX4 VTOL.

A file DFReader cannot read (empty, another format) ends in one `ContractError` line; DFReader skips a
corrupt stretch by searching for the next message header, and stops at a torn last message (both said).

Speed (a 20-minute log is to be reviewed in under 10 s): DFReader's index (`offsets` per message type, its
Cython indexer) finds the messages; the wanted types are then unpacked all at once with numpy from the
mapped file (`_columns`, DFReader's own format table and multipliers), not message by message. DFReader's
clock search, a walk of the whole log looking for GPS time, is skipped (`_Reader`): the ops use TimeUS.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from pathlib import Path

import numpy as np

from contracts.errors import ContractError

from .flightspan import off_path_sensors
from .loginput import Feed, exclude, finite_param, lacking, order, read_head, unreadable_params

HEAD = b"\xa3\x95"
TYPES = ["XKF1", "NKF1", "ATT", "PSCN", "PSCE", "CTUN", "MODE", "ARM", "EV", "XKF4", "NKF4", "RFND", "PRX", "GUIP",
         "PARM", "MSG", "GPS", "VER", "QTUN"]
GPS_EPOCH_UNIX_S, GPS_LEAP_S, GPS_FIX_3D = 315_964_800, 18, 3  # 1980-01-06; GPS − UTC since 2017; AP_GPS status
PARAMS = ("ANGLE_MAX", "WPNAV_ACCEL", "WPNAV_JERK", "WPNAV_SPEED", "GUID_TIMEOUT", "MOT_THST_HOVER", "FRAME_CLASS",
          "Q_ENABLE", "AVOID_ENABLE", "PRX1_TYPE", "PRX1_MAX", "RNGFND1_TYPE", "RNGFND1_MIN_CM", "RNGFND1_MAX_CM")
EV_LANDED = {18: 1, 28: 2}  # LAND_COMPLETE → on ground, NOT_LANDED → in air (AP_Logger LogEvent)
RFND_GOOD, RFND_OUT_OF_RANGE_HIGH = 4, 3  # AP_RangeFinder::Status
MAX_T_US = 1 << 62
# ArduPlane Mode::Number (ArduPlane/mode.h). The Q-modes fly as a multirotor; AUTO, RTL and GUIDED may fly either
# way (a VTOL_TAKEOFF/VTOL_LAND mission item, Q_RTL_MODE, Q_GUIDED_MODE), which QTUN tells; the others are
# fixed-wing modes (an assisted fixed-wing flight, Q_ASSIST, included)
PLANE_VTOL_MODES = {17, 18, 19, 20, 21, 22, 23}  # QSTABILIZE QHOVER QLOITER QLAND QRTL QAUTOTUNE QACRO
PLANE_EITHER_MODES = {10, 11, 15}  # AUTO RTL GUIDED
PLANE_UNSET_MODES = {16}  # INITIALISING: not flying yet
# a quadplane's mode as the ArduCopter mode of the same behaviour (the adapter's numbering); any other: not a
# Copter mode ("other")
PLANE_AS_COPTER = {17: 0, 18: 2, 19: 5, 20: 9, 21: 6, 22: 15, 23: 1, 10: 3, 11: 6, 15: 4}
PLANE_OTHER = 1000
QTUN_GAP_US = 500_000  # QTUN at 25 Hz while the VTOL motors are active or were within 0.25 s: a longer gap, not active
QTUN_PERIOD_US = 40_000
# a quadplane's VTOL parameters (QuadPlane var_info: Q_ANGLE_MAX; the groups Q_WP_ of AC_WPNav and Q_M_ of the
# motors) → the ArduCopter names the daemon's start-up checks read (the log's own names stay in `params`)
QUADPLANE_PARAMS = {"Q_ANGLE_MAX": "ANGLE_MAX", "Q_WP_ACCEL": "WPNAV_ACCEL", "Q_WP_JERK": "WPNAV_JERK",
                    "Q_WP_SPEED": "WPNAV_SPEED", "Q_M_THST_HOVER": "MOT_THST_HOVER"}
PRX_SECTORS = ("D0", "D45", "D90", "D135", "D180", "D225", "D270", "D315")
# the columns each message must have to be read ("A|B": either); a damaged FMT entry may name others
_EKF1 = ("TimeUS", "PN", "PE", "PD", "VN", "VE", "VD", "Roll", "Pitch", "Yaw")
NEEDED = {"XKF1": _EKF1, "NKF1": _EKF1, "ATT": ("TimeUS", "Roll", "Pitch", "Yaw"), "PSCN": ("TimeUS", "TPN"),
          "PSCE": ("TimeUS", "TPE"), "CTUN": ("TimeUS", "ThO"), "QTUN": ("TimeUS",), "MODE": ("TimeUS", "ModeNum|Mode"),
          "ARM": ("TimeUS", "ArmState"), "EV": ("TimeUS", "Id"), "XKF4": ("TimeUS", "SS"), "NKF4": ("TimeUS", "SS"),
          "RFND": ("TimeUS", "Dist", "Stat", "Orient"), "PRX": ("TimeUS", "He|Health", *PRX_SECTORS),
          "GUIP": ("TimeUS", "pX", "pY"), "PARM": ("TimeUS", "Name", "Value"), "MSG": ("Message",), "VER": ("FWS",),
          "GPS": ("TimeUS",)}
# DataFlash format characters → numpy (LogStructure.h; DFReader's FORMAT_TO_STRUCT gives the multipliers)
NP_TYPES = {"a": ("<i2", (32,)), "b": "i1", "B": "u1", "g": "<f2", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4",
            "f": "<f4", "n": "S4", "N": "S16", "Z": "S64", "c": "<i2", "C": "<u2", "e": "<i4", "E": "<u4", "L": "<i4",
            "d": "<f8", "M": "u1", "q": "<i8", "Q": "<u8"}


def _reader_class():
    from pymavlink import DFReader

    class _Reader(DFReader.DFReader_binary):
        """DFReader without its clock search (a walk of the whole log for GPS time): TimeUS is used as is."""

        def init_clock(self):
            self.init_clock_usec()

    return _Reader


@contextlib.contextmanager
def _quiet_stderr():
    """File descriptor 2 to /dev/null for the block (the indexer writes from C as well as from Python)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _skipped(df) -> int:
    """Bytes DFReader's index does not cover: skipped over a corrupt stretch or torn at the end."""
    covered = sum(df.counts[k] * df.formats[k].len for k in range(256) if df.counts[k] and k in df.formats)
    return max(0, df.data_len - covered)


def _open(path: Path):
    head = read_head(path, "a DataFlash log")
    if not head.startswith(HEAD):
        what = "it looks like a PX4 ULog" if head.startswith(b"ULog") else f"starts with {head[:8].hex()}"
        raise ContractError(f"{path}: not an ArduPilot DataFlash log (no 0xA3 0x95 header; {what})")
    try:
        with _quiet_stderr():  # DFReader's indexer prints a line per byte of a corrupt stretch: counted instead
            return _reader_class()(str(path), zero_time_base=False)
    except Exception as err:  # noqa: BLE001 — DFReader raises anything on a broken file: one line
        raise ContractError(f"{path}: unreadable DataFlash log ({type(err).__name__}: {str(err)[:120]})") from None


def _columns(df, name: str) -> tuple[dict, int]:
    """({column: numpy array}, torn bytes) of every `name` message, unpacked at once from DFReader's index;
    multipliers of the format characters applied (c, C, e, E: ×0.01; L: ×1e-7), strings decoded later."""
    from pymavlink.DFReader import FORMAT_TO_STRUCT

    mtype = df.name_to_id.get(name)
    if mtype is None or not df.counts[mtype]:
        return {}, 0
    fmt = df.formats[mtype]
    n_body = fmt.len - 3
    offs = np.asarray(df.offsets[mtype], dtype=np.int64)
    whole = offs + fmt.len <= df.data_len
    torn = int(df.data_len - offs[~whole][-1]) if not whole.all() else 0
    offs = offs[whole]
    dtype = np.dtype([(c or f"_{i}", *((NP_TYPES[f],) if isinstance(NP_TYPES[f], str) else NP_TYPES[f]))
                      for i, (c, f) in enumerate(zip(fmt.columns, fmt.format))])
    if dtype.itemsize != n_body or not len(offs):
        return {}, torn
    buf = np.frombuffer(df.data_map, dtype=np.uint8)
    rows = buf[offs[:, None] + 3 + np.arange(n_body)].view(dtype).ravel()
    out = {}
    for c, f in zip(fmt.columns, fmt.format):
        col = rows[c]
        mul = FORMAT_TO_STRUCT[f][1]
        out[c] = col.astype(float) * mul if mul is not None else col
    return out, torn


def _trailing(df) -> int:
    """Bytes after the last whole message DFReader indexed (a torn last message; 0 when none)."""
    ends = [df.offsets[k][-1] + df.formats[k].len for k in range(256) if df.counts[k] and k in df.formats]
    return max(0, df.data_len - max(ends)) if ends else 0


FMT_TYPE, FMT_LEN = 0x80, 89  # the FMT message: type 128, 3 header bytes + BBnNZ (LogStructure.h)


def stopped_at(data, end: int) -> str | None:
    """Why a reader that indexed messages up to byte `end` of `data` read no further, when it is not a torn
    last message: a damaged format entry, or a whole message it could not take (None: a torn tail). Pure."""
    rest = len(data) - end
    if rest < 3 or data[end:end + 2] != HEAD:
        return None if rest < FMT_LEN else f"unrecognised bytes at byte {end}"
    kind = data[end + 2]
    if kind == FMT_TYPE and rest >= FMT_LEN:
        typ, length = data[end + 3], data[end + 4]
        name = bytes(data[end + 5:end + 9]).split(b"\0")[0].decode(errors="replace")
        return (f"a damaged format entry (FMT) at byte {end}, defining message type {typ} {name!r} with length "
                f"{length}")
    return None if rest < FMT_LEN else f"a message of type {kind} it cannot take at byte {end}"


def _text(v) -> str:
    return (v if isinstance(v, str) else bytes(v).split(b"\0")[0].decode(errors="replace")).strip()


def _spans(times, gap_us: int, tail_us: int) -> list[tuple[int, int]]:
    """[first, last + tail) of each run of `times` (sorted µs) with no gap longer than `gap_us`."""
    out: list[tuple[int, int]] = []
    for t in times:
        if out and t - (out[-1][1] - tail_us) <= gap_us:
            out[-1] = (out[-1][0], t + tail_us)
        else:
            out.append((t, t + tail_us))
    return out


def _minus(spans, holes) -> list[tuple[int, int]]:
    """`spans` less `holes` (both [t0, t1) lists, `holes` sorted and disjoint)."""
    out = []
    for a, b in spans:
        for h0, h1 in holes:
            if h1 <= a or h0 >= b:
                continue
            if h0 > a:
                out.append((a, h0))
            a = max(a, h1)
            if a >= b:
                break
        if a < b:
            out.append((a, b))
    return out


def plane_fixed_wing_spans(modes, armed, qtun, t_end: int) -> list[tuple[int, int]]:
    """[t0, t1) µs spans in which a quadplane flew as a fixed wing: armed, in a fixed-wing mode, or in AUTO/RTL/
    GUIDED with its VTOL motors inactive (no QTUN). `modes`: (t, ArduPlane mode number) in time order; `armed`:
    (t, armed) in time order, empty when the log has no ARM (then armed throughout); `qtun`: QTUN times. Before
    the first MODE the mode is unknown: kept. Pure."""
    active = _spans(sorted(qtun), QTUN_GAP_US, QTUN_PERIOD_US)
    fw = []
    for k, (t, m) in enumerate(modes):
        end = modes[k + 1][0] if k + 1 < len(modes) else t_end
        if end <= t or m in PLANE_VTOL_MODES or m in PLANE_UNSET_MODES:
            continue
        fw += _minus([(t, end)], active) if m in PLANE_EITHER_MODES else [(t, end)]
    if armed:  # disarmed: not flying either way (kept: the daemon sees it on the ground)
        marks = [(0, not armed[0][1]), *armed]  # before the first ARM: the state it changed from
        disarmed = [(t, marks[k + 1][0] if k + 1 < len(marks) else t_end) for k, (t, on) in enumerate(marks) if not on]
        fw = _minus(fw, [s for s in disarmed if s[1] > s[0]])
    merged: list[tuple[int, int]] = []
    for a, b in sorted(fw):
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(b, merged[-1][1]))
        elif b > a:
            merged.append((a, b))
    return merged


def read_dataflash(path) -> Feed:
    path = Path(path)
    if not path.exists():
        raise ContractError(f"no such file or directory: {path}")
    df = _open(path)
    ops: list = []
    used: dict[str, str] = {}
    params: dict[str, float] = {}
    counts: dict[str, int] = {}
    torn = 0
    stopped = None

    def add(times, op, rows, src):
        times = np.asarray(times)
        if times.dtype.kind == "u":  # a damaged TimeUS past int64: not a time (0, dropped below)
            times = np.where(times < MAX_T_US, times, 0)
        times = times.astype(np.int64)
        n0 = len(ops)
        ops.extend((t, op, r) for t, r in zip(times.tolist(), rows) if 0 < t < MAX_T_US)
        if len(ops) > n0:
            used.setdefault(op, src)

    col: dict[str, dict] = {}
    unusable = []
    try:
        for kind in TYPES:
            col[kind], tail = _columns(df, kind)
            torn = max(torn, tail)
            lacks = [c for c in NEEDED.get(kind, ("TimeUS",)) if col[kind] and not any(a in col[kind] for a in c.split("|"))]
            if lacks:  # its FMT entry names other columns than the message has: not read, said
                unusable.append(f"{kind} (no {', '.join(lacks)})")
                col[kind] = {}
            if col[kind]:
                counts[kind] = len(col[kind].get("TimeUS", ()))
    except Exception as err:  # noqa: BLE001 — a format DFReader accepted but numpy cannot lay out: what was read stands
        stopped = f"{type(err).__name__}: {str(err)[:80]}"
    # parameters first: RFND needs RNGFND1_MIN/MAX_CM, PRX its PRX1_MAX
    parms, unreadable = [], []
    if (d := col.get("PARM")):
        for t, name, value in zip(d["TimeUS"].tolist(), d["Name"].tolist(), d["Value"].tolist()):
            name = _text(name)
            if name in PARAMS or name in QUADPLANE_PARAMS:
                if (v := finite_param(value)) is None:
                    unreadable.append(name)
                    continue
                params[name] = v
                parms.append((max(int(t), 1), name, v))
    texts = [_text(m) for m in (col.get("VER") or {}).get("FWS", [])[:1]]
    texts += [_text(m) for m in (col.get("MSG") or {}).get("Message", [])[:20]]
    fw = next((x for x in texts if x.startswith(("ArduCopter", "ArduPlane", "ArduRover", "APM:"))), None)
    plane = fw is not None and "Plane" in fw
    if plane and params.get("Q_ENABLE", 0) < 1:
        raise ContractError(f"{path}: a fixed-wing log ({fw}): the contract is for multirotors; not reviewed")
    for t, name, value in parms:  # a quadplane's VTOL parameters stand for the Copter ones the daemon checks
        if plane:
            name = QUADPLANE_PARAMS.get(name, None if name in QUADPLANE_PARAMS.values() else name)
        elif name in QUADPLANE_PARAMS:
            name = None
        if name is not None:
            add([t], "param", [(name, value)], "PARM")
    ekf = "XKF1" if col.get("XKF1") else "NKF1"
    have_att = bool(col.get("ATT"))
    if (d := col.get(ekf)):
        core0 = d["C"] == 0 if "C" in d else np.ones(len(d["TimeUS"]), bool)  # core 0 only (the primary may differ)
        t = d["TimeUS"][core0]
        pos = np.stack([d[k][core0].astype(float) for k in ("PN", "PE", "PD", "VN", "VE", "VD")], axis=1)
        add(t, "pos", [tuple(r) for r in pos.tolist()], ekf)
        if not have_att:
            att = np.radians(np.stack([d[k][core0].astype(float) for k in ("Roll", "Pitch", "Yaw")], axis=1))
            add(t, "att", [tuple(r) for r in att.tolist()], ekf)
    if have_att:
        # at most one sample per 20 ms, as the ULog reader: the daemon's loop takes no more, and Copter logs
        # ATT at up to 400 Hz with fast attitude logging
        d = col["ATT"]
        t = d["TimeUS"].astype(np.int64)
        keep = np.concatenate(([True], np.diff(t // 20_000) > 0))
        att = np.radians(np.stack([d[k][keep].astype(float) for k in ("Roll", "Pitch", "Yaw")], axis=1))
        add(t[keep], "att", [tuple(r) for r in att.tolist()], "ATT")
    if col.get("PSCN") and col.get("PSCE"):  # written as a pair: each PSCE with the PSCN at most 5 ms before
        n, e = col["PSCN"], col["PSCE"]
        k = np.searchsorted(n["TimeUS"], e["TimeUS"], side="right") - 1
        ok = (k >= 0) & (np.abs(e["TimeUS"].astype(np.int64) - n["TimeUS"][np.maximum(k, 0)].astype(np.int64)) < 5000)
        add(e["TimeUS"][ok], "target", list(zip(n["TPN"][k[ok]].astype(float).tolist(), e["TPE"][ok].astype(float).tolist())),
            "PSCN/PSCE")
    if "target" not in used and (d := col.get("GUIP")):
        fmt = df.formats[df.name_to_id["GUIP"]]
        units = fmt.units or []
        scale = 1.0 if len(units) > 2 and units[fmt.colhash["pX"]] == "m" else 0.01  # Copter 4.x: cm (FMTU "B")
        add(d["TimeUS"], "target", list(zip((d["pX"] * scale).tolist(), (d["pY"] * scale).tolist())),
            "GUIP (GUIDED target)")
    if plane and (d := col.get("QTUN")) and "ThO" in d:  # a quadplane's lift motors (its CTUN.ThO: the forward motor)
        add(d["TimeUS"], "thr", [(v,) for v in d["ThO"].astype(float).tolist()], "QTUN")
    elif not plane and (d := col.get("CTUN")):
        add(d["TimeUS"], "thr", [(v,) for v in d["ThO"].astype(float).tolist()], "CTUN")
    # MODE and ARM together make HEARTBEAT's (base_mode, custom_mode): in time order, with the state between
    events = []
    if (d := col.get("MODE")):
        nums = d["ModeNum"] if "ModeNum" in d else d["Mode"]
        events += [(t, 0, int(v)) for t, v in zip(d["TimeUS"].tolist(), nums.tolist())]
    if (d := col.get("ARM")):
        events += [(t, 1, int(v)) for t, v in zip(d["TimeUS"].tolist(), d["ArmState"].tolist())]
    custom, armed = 0, False
    for t, which, v in sorted(events):
        if which == 0 and plane:  # a quadplane's mode, in the Copter numbering the adapter reads
            v = PLANE_AS_COPTER.get(v, PLANE_OTHER + v)
        custom, armed = (v, armed) if which == 0 else (custom, bool(v))
        add([t], "mode", [(1 | (128 if armed else 0), custom)], "MODE")
    if (d := col.get("EV")):
        ids = d["Id"].tolist()
        keep = [i for i, v in enumerate(ids) if v in EV_LANDED]
        add(d["TimeUS"][keep], "landed", [(EV_LANDED[ids[i]],) for i in keep], "EV")
    ekf4 = "XKF4" if col.get("XKF4") else "NKF4"
    if (d := col.get(ekf4)):
        core0 = d["C"] == 0 if "C" in d else np.ones(len(d["TimeUS"]), bool)
        add(d["TimeUS"][core0], "nav", [("EKF_STATUS_REPORT", int(v)) for v in d["SS"][core0].tolist()], ekf4)
    off_path: list[dict] = []  # range sensors looking off the path (up, down): named in the review
    if (d := col.get("RFND")):
        # RFND has no min/max: the RNGFND1_MIN_CM/MAX_CM parameters give them. Stat Good: a reading;
        # OutOfRangeHigh: nothing within the maximum (what MAVLink's DISTANCE_SENSOR says with a distance
        # beyond max_distance, and MAVLink-in reads as free to the maximum); any other status, or no
        # maximum known: unknown (invalid), never free space
        lo, hi = params.get("RNGFND1_MIN_CM", 0.0) / 100, params.get("RNGFND1_MAX_CM", 0.0) / 100
        o = d["Orient"].astype(int)
        fwd = o < 8  # ROTATION_YAW_45·k (clockwise); down-facing (25) covers no path
        off_path = off_path_sensors("RFND", o)
        stat = d["Stat"].astype(int)
        good = ((stat == RFND_GOOD) | (stat == RFND_OUT_OF_RANGE_HIGH)) & (hi > 0)
        dist = np.where(stat == RFND_OUT_OF_RANGE_HIGH, max(hi, 0.0) + 0.01, d["Dist"].astype(float))
        rows = [(math.radians(45 * oo), float(dd), lo, hi if g else 0.0, 0 if g else 1)
                for oo, dd, g in zip(o[fwd].tolist(), dist[fwd].tolist(), good[fwd].tolist())]
        add(d["TimeUS"][fwd], "range", rows, "RFND")
    if (d := col.get("PRX")):
        layer = d["Layer"] if "Layer" in d else np.full(len(d["TimeUS"]), 2)
        mid = layer == 2  # AP_Proximity: layer 2 is the horizontal one (−15° to 15° of pitch)
        mat = np.stack([d[k][mid].astype(float) for k in PRX_SECTORS], axis=1)
        healthy = (d["He"] if "He" in d else d["Health"])[mid] > 0
        cap = params.get("PRX1_MAX", math.inf)
        bearings = np.radians(45.0 * np.arange(8))
        rows = []
        for row, ok in zip(mat, healthy.tolist()):
            known = row > 0  # 0: that sector has no data
            if not ok:
                rows.append((np.zeros(0), np.zeros(0), 0.0, 0.0, False))
                continue
            rows.append((bearings[known], np.where(row[known] >= cap - 0.005, np.inf, row[known]),
                         cap if math.isfinite(cap) else float(np.max(row, initial=0.0)), math.radians(45), False))
        add(d["TimeUS"][mid], "bins", rows, "PRX")
    wall0 = 0.0
    if (d := col.get("GPS")) and "GWk" in d and "GMS" in d and ops:  # the log's UTC, from the first 3D fix
        fix = np.nonzero((d["Status"] >= GPS_FIX_3D) & (d["GWk"] > 0))[0] if "Status" in d else np.zeros(0, int)
        if len(fix):
            k = int(fix[0])
            utc = GPS_EPOCH_UNIX_S + int(d["GWk"][k]) * 604_800 + int(d["GMS"][k]) / 1000 - GPS_LEAP_S
            wall0 = utc - (int(d["TimeUS"][k]) - min(t for t, _, _ in ops)) / 1e6
    if not any(op == "pos" for _, op, _ in ops):
        raise ContractError(f"{path}: no usable telemetry: the DataFlash log has no XKF1/NKF1 (EKF position) "
                            f"(messages: {', '.join(sorted(df.name_to_id)) or 'none'}"
                            + (f"; not read, their format entry lacking a column: {'; '.join(unusable)})" if unusable else ")"))
    cuts, fixed_wing_s = [], None
    if plane and (d := col.get("MODE")):  # a quadplane's fixed-wing phases: not the multirotor contract's
        nums = d["ModeNum"] if "ModeNum" in d else d["Mode"]
        arm = col.get("ARM") or {}
        spans = plane_fixed_wing_spans(
            list(zip(d["TimeUS"].tolist(), nums.astype(int).tolist())),
            list(zip(arm.get("TimeUS", np.zeros(0)).tolist(), (arm.get("ArmState", np.zeros(0)) > 0).tolist())),
            (col.get("QTUN") or {}).get("TimeUS", np.zeros(0, np.int64)).tolist(), max(t for t, _, _ in ops) + 1)
        ops, cuts = exclude(ops, spans)
        fixed_wing_s = sum(c["cut_s"] for c in cuts)
        if not any(op == "pos" for _, op, _ in ops):
            raise ContractError(f"{path}: a quadplane log ({fw}) that flew as a fixed wing throughout "
                                f"({fixed_wing_s:.0f} s): nothing for the multirotor contract to judge; not reviewed")
    ops, jumps = order(ops)
    missing = lacking(used, {"obstacle sensing": "RFND, PRX", "commanded path": "PSCN/PSCE, GUIP",
                             "thrust": "QTUN" if plane else "CTUN",
                             "navigation health": "XKF4", "modes and arming": "MODE, ARM",
                             "landed state": "EV LAND_COMPLETE / NOT_LANDED"})
    damaged = [unreadable_params(unreadable)] if unreadable else []
    if unusable:
        damaged.append(f"messages whose format entry lacks a column the review reads, not read: {'; '.join(unusable)}")
    if stopped:
        damaged.append(f"the reader stopped early ({stopped}): the rest of the file is not reviewed")
    tail = _trailing(df)
    why = stopped_at(df.data_map, df.data_len - tail) if tail else None
    if why:  # not a torn message: the reader stopped there, and everything after it is lost
        damaged.append(f"{why} stopped the reader: the remaining {tail} bytes ({tail / max(df.data_len, 1):.0%} of "
                       "the file) are not reviewed")
    else:
        torn = max(torn, tail)
    if (skipped := _skipped(df) - torn - (tail if why else 0)) > 0:
        damaged.append(f"{skipped} bytes of corrupt data skipped (the reader resynchronised on the next message "
                       "header): the messages there are lost")
    if torn:
        damaged.append(f"the file ends inside a message (truncated: the last {torn} bytes lost)")
    span = ops[-1][0] / 1e6
    rates = {k: round((n - 1) / span, 2) for k, n in counts.items() if span > 0}
    info = {
        "log": str(path),
        "format": "ArduPilot DataFlash",
        "bytes": path.stat().st_size,
        "vehicle": {"hardware": next((x for x in texts if x.startswith(("CubeOrange", "Pixhawk", "fmuv", "ChibiOS"))), None),
                    "airframe": "VTOL quadplane" if plane else
                    (f"copter, FRAME_CLASS {int(params['FRAME_CLASS'])}" if "FRAME_CLASS" in params else "copter"),
                    "mav_type": None, "sys_autostart": None, "vtol": plane,
                    "fixed_wing_s": fixed_wing_s if plane else 0.0, "fixed_wing_cut": cuts,
                    "fixed_wing_from": "MODE, ARM and QTUN messages" if plane and fixed_wing_s is not None else None},
        "firmware": {"name": fw or "ArduPilot (no version message in the log)", "release": None, "git": None,
                     "branch": None, "os": None},
        "span_s": span,
        "sources": used,
        "lacking": missing,
        "other_sensors": off_path,
        "rates_hz": rates,
        "params": params,
        "dropouts": 0,
        "dropout_s": 0.0,
        "damaged": damaged,
        "time_jumps": jumps[:100],
    }
    return Feed(ops=ops, info=info, autopilot="ardupilot", wall0=wall0)
