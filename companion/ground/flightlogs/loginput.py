"""A flight log's input to the daemon: what `mavlink_in.py` is for the link, this is for an autopilot's own
log (PX4 ULog: `companion/ground/flightlogs/ulog.py`; ArduPilot DataFlash: `companion/ground/flightlogs/dataflash.py`).

A reader turns its format's topics/messages into `Op`s — `(t_us, op, args)` in SI units and the frames
of DESIGN.md §2, converted there, once — and a `Feed` (the ops in log-time order plus what the reader saw).
`LogIn.apply` turns one op into the daemon's `Telemetry` snapshot fields and the same typed samples
(`companion/onboard/samples.py`) MAVLink-in makes of the equivalent MAVLink message, with the same validation
(`mavlink_in.implausible`, `range_scan`, `bins_scan`), so one replay path (`companion/ground/flightlogs/logreplay.py`)
serves `.tlog`, `.ulg` and `.bin` alike.

The ops:

| op        | args                                      | MAVLink equivalent            | sample(s)          |
|-----------|-------------------------------------------|-------------------------------|--------------------|
| `mode`    | base_mode, custom_mode                    | HEARTBEAT                     | —                  |
| `pos`     | x, y, z [m NED], vx, vy, vz [m/s NED]     | LOCAL_POSITION_NED            | Position           |
| `att`     | roll, pitch, yaw [rad]                    | ATTITUDE                      | Heading            |
| `target`  | x, y [m NED] (NaN: not position-controlled)| POSITION_TARGET_LOCAL_NED    | PathTarget         |
| `thr`     | collective throttle [0–1]                 | VFR_HUD.throttle              | Throttle           |
| `landed`  | MAV_LANDED_STATE                          | EXTENDED_SYS_STATE            | —                  |
| `nav`     | source, ESTIMATOR_STATUS_FLAGS bits       | ESTIMATOR_STATUS / EKF_STATUS | NavStatus          |
| `range`   | bearing [rad cw], current, min, max [m], quality (MAVLink) | DISTANCE_SENSOR | Scan         |
| `bins`    | bearings [rad], ranges [m, inf free], max [m], increment [rad], north-aligned | OBSTACLE_DISTANCE | Scan |
| `param`   | name, value                               | PARAM_VALUE                   | AutopilotParam     |
| `seq`     | mission item                              | MISSION_CURRENT               | —                  |

The log is the autopilot's own: while it writes, the autopilot is alive, so every op refreshes the
snapshot's heartbeat time (a ULog writes `vehicle_status` only when it changes).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from companion.onboard.config import Config
from companion.onboard.mavlink_in import bins_scan, implausible_attitude, implausible_position, range_scan
from companion.onboard.samples import (
    AutopilotParam,
    Heading,
    Implausible,
    NavStatus,
    PathTarget,
    Position,
    Scan,
    Throttle,
)
from companion.onboard.telemetry import Telemetry

# a silence longer than this between two ops is a clock jump (closed up, listed): a replay never steps
# through hours of nothing, and a corrupt timestamp near 2⁶⁴ µs cannot make it hang
MAX_GAP_US = 300_000_000


@dataclass
class Feed:
    """A flight log read: its ops in log-time order (µs from the first), and what the reader saw.
    `info`: vehicle, firmware, topics found and lacking, damage, clock jumps (the report's section)."""

    ops: list = field(default_factory=list)  # (t_us, op, args)
    info: dict = field(default_factory=dict)
    autopilot: str = "px4"
    wall0: float = 0.0  # UNIX time of t = 0, when the log knows it (else 0)
    commands: list = field(default_factory=list)  # (t [s], mode name) asked on the link: a .tlog's, for calibrate


def read_head(path, what: str) -> bytes:
    """The first 16 bytes of a log file (to tell its format), or one `ContractError` line."""
    from contracts.errors import ContractError

    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as err:
        raise ContractError(f"cannot read {path}: {err.strerror or err}") from None
    if not head:
        raise ContractError(f"{path}: empty file (zero bytes), not {what}")
    return head


# what a log lacking an input means for the verdict (said once in the review): op(s) → (what, meaning)
LACKING = (
    (("range", "bins"), "obstacle sensing",
     "D_od is unknown: the navigation guarantee is not judged, and the replay's D_od is 0 (no safe speed)"),
    (("target",), "commanded path", "E_tr cannot be measured: the controller guarantee is judged on E_tr_pred alone"),
    (("thr",), "thrust", "thrust_ratio is the configured fallback: the actuator guarantee is not judged"),
    (("nav",), "navigation health", "the estimator is taken as unhealthy: every sample a failsafe"),
    (("mode",), "modes and arming", "modes unknown: time in each mode not reported"),
    (("landed",), "landed state", "in-air state unknown: thrust is not estimated"),
)


def finite_param(value) -> float | None:
    """A logged parameter's value as a finite float; None when the log's entry is not one (damaged: text, NaN,
    infinite), which is then no setting of the autopilot's."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return v if math.isfinite(v) else None


def unreadable_params(names) -> str:
    """The damage finding of the parameters whose logged value is not a finite number (`finite_param`)."""
    bad = sorted(set(map(str, names)))
    return (f"{len(bad)} parameter(s) not a finite number, ignored: {', '.join(map(repr, bad[:5]))}"
            + (" …" if len(bad) > 5 else ""))


def lacking(used: dict, sources: dict[str, str]) -> dict[str, str]:
    """{"obstacle sensing (distance_sensor, …)": what it means} for each input no op came from;
    `sources`: the input's name → the format's topics/messages for it."""
    return {f"{what} ({sources[what]})": means for ops, what, means in LACKING if not any(op in used for op in ops)}


def order(ops: list) -> tuple[list, list]:
    """(ops sorted by time from the first, clock jumps closed up). Pure."""
    ops.sort(key=lambda o: o[0])
    if not ops:
        return ops, []
    jumps, shift, last, out = [], -ops[0][0], 0, []
    prev_raw = ops[0][0]
    for t, op, args in ops:
        step = t - prev_raw
        if step > MAX_GAP_US:
            jumps.append({"t": last / 1e6, "jump_s": step / 1e6})
            shift = last - t
        prev_raw = t
        last = t + shift
        out.append((last, op, args))
    return out, jumps


def exclude(ops: list, spans: list[tuple[int, int]]) -> tuple[list, list]:
    """(ops without those inside the `spans` [t0, t1) µs, later ones moved earlier by the time cut out; the
    cuts as {"t": log time of the cut [s], "cut_s": its length}). For a VTOL's fixed-wing phases, where the
    multirotor contract does not apply: cut out rather than left as a silence the daemon would find stale.
    Pure; `ops` need not be sorted."""
    if not spans:
        return ops, []
    spans = sorted(spans)
    starts = [a for a, _ in spans]
    cum, total = [], 0
    for a, b in spans:
        total += b - a
        cum.append(total)
    out = []
    for t, op, args in ops:
        k = bisect.bisect_right(starts, t) - 1  # the last span starting at or before t
        if k >= 0 and t < spans[k][1]:
            continue
        out.append((t - (cum[k] if k >= 0 else 0), op, args))
    t_first = min((o[0] for o in out), default=0)
    cuts = [{"t": (a - (cum[i - 1] if i else 0) - t_first) / 1e6, "cut_s": (b - a) / 1e6} for i, (a, b) in enumerate(spans)]
    return out, cuts


def quat_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) [rad] of a Hamilton quaternion rotating body FRD into NED (PX4
    `msg/VehicleAttitude.msg` q, w first); ZYX Tait–Bryan, as MAVLink ATTITUDE."""
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


class LogIn:
    """Ops → the daemon's `Telemetry` fields and samples (the log's MavlinkIn)."""

    def __init__(self, cfg: Config, tel: Telemetry, autopilot_id: int):
        self.cfg, self.tel, self.autopilot_id = cfg, tel, autopilot_id
        self._ranges = [i for i, s in enumerate(cfg.sensors) if s.kind == "distance_sensor"]
        self._bins_of = [i for i, s in enumerate(cfg.sensors) if s.kind == "obstacle_distance"]
        self._beam_of: dict[float, int | None] = {}  # a `range` op's bearing → its configured sensor (`_beam`)
        self._ops = {"pos": self._pos, "att": self._att, "target": self._target, "thr": self._thr, "mode": self._mode,
                     "landed": self._landed, "nav": self._nav, "range": self._range, "bins": self._bins,
                     "param": self._param, "seq": self._seq}

    def apply(self, t: float, op: str, args: tuple) -> list:
        tel = self.tel
        tel.t_heartbeat, tel.autopilot = t, self.autopilot_id
        do = self._ops.get(op)
        return do(t, *args) if do is not None else []

    def _pos(self, t: float, *args) -> list:
        why = implausible_position(*args)
        if why is not None:
            return [Implausible(t, "LOCAL_POSITION_NED", why)]
        tel = self.tel
        tel.t_local = t
        tel.x, tel.y, tel.z, tel.vx, tel.vy, tel.vz = args
        return [Position(t, tel.x, tel.y)]

    def _att(self, t: float, *args) -> list:
        why = implausible_attitude(*args)
        if why is not None:
            return [Implausible(t, "ATTITUDE", why)]
        tel = self.tel
        tel.roll, tel.pitch, tel.yaw = args
        return [Heading(t, tel.yaw, tel.ground_speed)]

    def _target(self, t: float, *args) -> list:
        x, y = args
        if not (math.isfinite(x) and math.isfinite(y)):
            return []  # not position-controlled now (PX4 publishes NaN), as POSITION_TARGET's IGNORE_XY
        self.tel.target, self.tel.t_target = (x, y), t
        return [PathTarget(t, x, y)]

    def _thr(self, t: float, *args) -> list:
        thr = args[0]
        if not (math.isfinite(thr) and 0.0 <= thr <= 1.0):
            return [Implausible(t, "VFR_HUD", "throttle outside 0–100 %")]
        tel = self.tel
        tel.throttle = thr
        air = tel.in_air if tel.landed_state else None  # UNDEFINED: not said
        return [Throttle(t, thr, tel.roll, tel.pitch, tel.vz, air)] if math.isfinite(tel.vz) else []

    def _mode(self, t: float, *args) -> list:
        self.tel.base_mode, self.tel.custom_mode = args
        return []

    def _landed(self, t: float, *args) -> list:
        self.tel.landed_state = args[0]
        return []

    def _nav(self, t: float, *args) -> list:
        return [NavStatus(t, args[0], int(args[1]))]

    def _bins(self, t: float, *args) -> list:
        bearings, ranges, max_m, inc, north_aligned = args
        known = ~np.isnan(np.asarray(ranges, dtype=float))  # a NaN bin knows nothing: not free
        bearings, ranges = np.asarray(bearings, dtype=float)[known], np.asarray(ranges, dtype=float)[known]
        if not (math.isfinite(max_m) and max_m > 0):
            max_m, bearings, ranges = 0.0, bearings[:0], ranges[:0]
        if north_aligned:  # MAV_FRAME_GLOBAL bins: rotated into the body frame, as MAVLink-in does
            bearings = bearings - self.tel.yaw
        return [bins_scan(t, i, bearings, ranges, max_m, inc, self.cfg.sensors[i].max_range_m) for i in self._bins_of]

    def _param(self, t: float, *args) -> list:
        return [AutopilotParam(t, args[0], float(args[1]))]

    def _seq(self, t: float, *args) -> list:
        self.tel.mission_seq = int(args[0])
        return []

    def _range(self, t: float, bearing: float, current: float, lo: float, hi: float, quality: int) -> list:
        """The configured single-beam sensor looking along `bearing` (as MAVLink-in matches orientation). A
        reading or limit that is not a number (NaN, inf) is no reading: an invalid scan, unknown, never free."""
        i = self._beam_of[bearing] if bearing in self._beam_of else self._beam(bearing)
        if i is None:
            return []
        if not (math.isfinite(current) and math.isfinite(lo) and math.isfinite(hi)):
            return [Scan(t, i, (), 0.0, 1)]
        c = self.cfg.sensors[i]
        return [range_scan(t, i, math.radians(c.orientation_deg), current, lo, hi, quality, c.max_range_m)]

    def _beam(self, bearing: float) -> int | None:
        """The first configured single beam within 1° of `bearing` (remembered for the first few bearings)."""
        i = next((i for i in self._ranges
                  if abs((math.degrees(bearing) - self.cfg.sensors[i].orientation_deg + 180) % 360 - 180) < 1), None)
        if len(self._beam_of) < 64:
            self._beam_of[bearing] = i
        return i


def firmware_release(v: int | None) -> str | None:
    """PX4's `ver_sw_release` (0xAABBCCTT: major, minor, patch, type) in words (ULog spec, `ver_sw_release`)."""
    if not v:
        return None
    v = int(v)
    tt = v & 0xFF
    kind = "release" if tt == 255 else "rc" if tt >= 192 else "beta" if tt >= 128 else "alpha" if tt >= 64 else "dev"
    return f"v{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF} ({kind})"


# MAVLink MAV_TYPE (common.xml) of the airframes a reviewer sees in logs
MAV_TYPES = {0: "generic", 1: "fixed wing", 2: "quadrotor", 3: "coaxial", 4: "helicopter", 10: "ground rover",
             13: "hexarotor", 14: "octorotor", 15: "tricopter", 19: "VTOL tailsitter duorotor",
             20: "VTOL tailsitter quadrotor", 21: "VTOL tiltrotor", 22: "VTOL quadplane", 29: "dodecarotor"}
MULTIROTOR_TYPES = {2, 3, 4, 13, 14, 15, 29}
VTOL_TYPES = {19, 20, 21, 22, 23, 24, 25}


def not_multirotor(mav_type: int, path, said_by: str) -> None:
    """One `ContractError` line when the MAV_TYPE a log states (`said_by`: where) is neither a multirotor, a
    VTOL nor generic (0): the contract is for multirotors, and a fixed wing judged as one would be flagged
    for speeds it flies by design."""
    if mav_type in MULTIROTOR_TYPES or mav_type in VTOL_TYPES or mav_type == 0:
        return
    from contracts.errors import ContractError

    kind = MAV_TYPES.get(mav_type, f"MAV_TYPE {mav_type}")
    hint = "; a quadplane's own DataFlash log says when it flew as a multirotor: review that" if mav_type == 1 else ""
    raise ContractError(f"{path}: a {'fixed-wing' if mav_type == 1 else kind} log ({said_by} type {mav_type}, {kind}): "
                        f"the contract is for multirotors; not reviewed{hint}")
