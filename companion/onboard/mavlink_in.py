"""MAVLink in: every message from the link becomes typed, timestamped samples (companion/onboard/samples.py), or
nothing. Here, and only here: which sources are accepted, the daemon's clock following the vehicle's,
the autopilot's state snapshot (`Telemetry`), sensor matching, unit and frame conversion (every sensor
kind normalised into one `Scan`), and counting what is malformed. No decisions.

A new sensor kind is one decoder here (a function returning its `Scan` from the message's source, and an
`Implausible` when the message contradicts itself) and one entry in `SENSOR_KINDS`.
"""

from __future__ import annotations

import math
import time

import numpy as np

from contracts.geometry import wrap_array

from .autopilot_base import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_DO_SET_MODE
from .config import Config
from .detection_range import RangeNoise
from .ground import ground_claim_m, ground_range_m
from .samples import (
    AutopilotParam,
    AutopilotRestart,
    CommandAck,
    Heading,
    Implausible,
    MissionMessage,
    NavStatus,
    ParamRequest,
    PathTarget,
    Position,
    Scan,
    SourceRefused,
    Throttle,
)
from .telemetry import Telemetry

UINT16_MAX = 65535
MAV_FRAME_BODY_FRD = 12
PARAM_MSGS = ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET")
MISSION_MSGS = ("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_ACK", "HOME_POSITION")
SENSOR_MSGS = ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE")  # accepted from the configured sensors' sources
MAX_UNKNOWN_REPORTED = 32  # unknown sources reported (once each) at most; the rest are counted only
RESTART_BACK_MS = 2000  # the autopilot's boot clock going back by more than this: it restarted
PLAUSIBLE_XY_M = 1e6  # |x|, |y| of a local position (1000 km from its origin)
PLAUSIBLE_Z_M = 1e5
PLAUSIBLE_SPEED_M_S = 100.0  # no multirotor flies faster


class VehicleClock:
    """Daemon time: the host's monotonic clock at the vehicle's configured rate (`rate`: 1 for a real
    aircraft, K for a SITL sped up K times), so it never jumps, never runs backwards and judges staleness
    in host time whatever any message says. The autopilot's `time_boot_ms` is only *checked* against it:
    over a window of host time D (judged from `MIN_S` on, a new window every `WINDOW_S`), the boot clock must
    advance rate·D within rate·(RATE_TOLERANCE·D + LAG_S). `LAG_S` is a simulator's own tick jitter: a SITL
    paces its ticks to the host's clock, starts them late when the host is busy and catches up afterwards (it
    gives up catching up beyond about a second), so its clock lags by up to that much and then runs fast back
    to its schedule — no fault. A clock at the wrong rate drifts out of any fixed allowance (×0.01 within
    ~1.1 s) and a jump leaves it at once: a fault (`fault`, the reason, until a window is right again); going
    back is the autopilot restarting (reported by MAVLink-in, not here)."""

    RATE_TOLERANCE = 0.1  # a rate off by more (×0.5, ×2: a wrong link.clock_rate) shows within 1-3 s
    LAG_S = 1.0  # [s of host time] a simulator's clock may lag its schedule this much and catch up (tick jitter)
    MIN_S = 1.0
    WINDOW_S = 10.0

    def __init__(self, local=time.monotonic, rate: float = 1.0):
        self.local, self.rate = local, rate
        self._t0 = local()
        self._ref: tuple[float, float] | None = None  # (vehicle s, local s) of the window's start
        self.fault: str | None = None

    def observe(self, time_boot_ms: int) -> None:
        tv, tl = time_boot_ms / 1000.0, self.local()
        if self._ref is None or tv < self._ref[0]:
            self._ref = (tv, tl)
            return
        dl = tl - self._ref[1]
        if dl < self.MIN_S:
            return
        dv = tv - self._ref[0]
        off = abs(dv - self.rate * dl) > self.rate * (self.RATE_TOLERANCE * dl + self.LAG_S)
        if off:
            self.fault = (f"the autopilot's clock runs at {dv / dl:.3g}× the host's, expected {self.rate:g}× "
                          f"(over {dl:.1f} s, beyond {self.LAG_S:g} s of a simulator's tick jitter)")
        elif dl >= self.WINDOW_S:
            self.fault = None
        if off or dl >= self.WINDOW_S:
            self._ref = (tv, tl)

    def __call__(self) -> float:
        return (self.local() - self._t0) * self.rate


def sensor_orientation(yaw_deg_clockwise: float) -> int:
    """MAV_SENSOR_ORIENTATION of a horizontal sensor. The spec's yaw rotations turn to the left
    (left-facing = ROTATION_YAW_90, right-facing = ROTATION_YAW_270), our yaw turns clockwise."""
    return round((-yaw_deg_clockwise % 360) / 45) % 8


def range_scan(t: float, sensor: int, bearing: float, current_m: float, min_m: float, max_m: float,
               quality: int, rated_m: float | None = None, source: tuple | None = None) -> Scan:
    """A single range beam along body bearing `bearing`. PX4's convention: a reading at or beyond the
    maximum sees nothing within it; a reading below the minimum is unknown, never free (the scan is
    invalid: quality 1), and so is a message whose minimum exceeds its maximum; a reading at the minimum is a
    return there or nearer (drivers clamp a too-close return to it): a hit. The claimed maximum is capped by
    the sensor's rated range. `source`: who sent it (`Scan.source`)."""
    if min_m > max_m or current_m < min_m:
        return Scan(t, sensor, (), 0.0, 1, None, None, source)
    cap = max_m if rated_m is None else min(max_m, rated_m)
    hits = ((bearing, current_m),) if current_m < max_m - 0.01 and current_m < cap else ()
    return Scan(t, sensor, hits, cap, quality, None, None, source)


def bins_scan(t: float, sensor: int, bearings: np.ndarray, ranges_m: np.ndarray, max_m: float,
              increment: float, rated_m: float | None = None, source: tuple | None = None) -> Scan:
    """Bins of a sector sensor: body bearings of the bins that report and their ranges (inf: nothing
    within max; the caller leaves out the bins that report nothing known). The claimed maximum is capped
    by the sensor's rated range."""
    cap = max_m if rated_m is None else min(max_m, rated_m)
    hits = tuple((float(b), float(r)) for b, r in zip(bearings, ranges_m) if r < cap)
    return Scan(t, sensor, hits, cap, 0, tuple(float(b) for b in bearings), increment, source)


def _distance_sensor(cfg: Config, sensor_of: dict, t: float, msg, tel: Telemetry, source: tuple) -> list:
    """DISTANCE_SENSOR: the configured sensor of this source (`sensor_of`), id (or any id) and orientation;
    cm → m."""
    i = sensor_of.get(("distance_sensor", msg.id, msg.orientation),
                      sensor_of.get(("distance_sensor", None, msg.orientation)))
    if i is None:
        return []
    c = cfg.sensors[i]
    axis = math.radians(c.orientation_deg)
    rated = ground_cap(cfg, c, tel, [axis], math.radians(c.h_fov_deg) / 2)
    scan = range_scan(t, i, axis, msg.current_distance / 100, msg.min_distance / 100,
                      msg.max_distance / 100, getattr(msg, "signal_quality", 0), rated, source)
    bad = msg.min_distance > msg.max_distance
    return [scan, Implausible(t, "DISTANCE_SENSOR", "min_distance above max_distance")] if bad else [scan]


def _obstacle_distance(cfg: Config, sensor_of: dict, t: float, msg, tel: Telemetry, source: tuple) -> list:
    """OBSTACLE_DISTANCE: bin k at angle_offset + k·increment (clockwise; MAV_FRAME_GLOBAL is north-aligned,
    rotated into the body frame here); UINT16_MAX is a bin that knows nothing ("unknown/not used", common.xml),
    beyond max_distance is free; cm → m. Bins in use reaching past a circle (they would overlap the first), or a
    minimum above the maximum: an invalid scan. The trailing unused bins span nothing: a camera of 87° in 17 bins
    of 5.12° fills 17 of the 72 and is judged on those 17."""
    i = sensor_of.get(("obstacle_distance", None, None))
    if i is None:
        return []
    inc = msg.increment_f if getattr(msg, "increment_f", 0) else float(msg.increment)
    offset = getattr(msg, "angle_offset", 0.0)
    d = np.asarray(msg.distances, dtype=float)
    used = d != UINT16_MAX
    span = int(np.flatnonzero(used)[-1]) + 1 if used.any() else 0  # bins up to the last one in use
    if not (math.isfinite(inc) and math.isfinite(offset)) or inc < 0 or msg.min_distance > msg.max_distance \
            or inc * span > 360.0 + 1e-6:
        why = "increment or angle_offset not finite, bins in use past a circle, or min_distance above max_distance"
        return [Scan(t, i, (), 0.0, 1, (), 0.0, source), Implausible(t, "OBSTACLE_DISTANCE", why)]
    if inc == 0:
        return []  # PX4 ignores increment 0 too
    ang = np.radians(offset + inc * np.arange(len(d)))
    if getattr(msg, "frame", MAV_FRAME_BODY_FRD) != MAV_FRAME_BODY_FRD:
        ang = ang - tel.yaw
    rng = np.where(d > msg.max_distance, np.inf, d / 100.0)
    c, half = cfg.sensors[i], math.radians(inc) / 2
    off_axis = ang[used] - math.radians(c.orientation_deg)
    factors = None
    if c.depth == "axis_depth":
        rng = rng / axis_depth_factor(ang - math.radians(c.orientation_deg), math.radians(inc))
        # a pixel at the bin's far edge reads its range times cos(far edge) / cos(near edge)
        factors = np.cos(np.minimum(np.abs(wrap_array(off_axis)) + half, math.radians(89.0))) \
            / axis_depth_factor(off_axis, 2 * half)
    rated = ground_cap(cfg, c, tel, ang[used], half, factors)
    return [bins_scan(t, i, ang[used], rng[used], msg.max_distance / 100.0, math.radians(inc), rated, source)]


def ground_cap(cfg: Config, c, tel: Telemetry, azimuths, half_width: float, factors=None) -> float | None:
    """Sensor `c`'s rated range, capped where its lowest ray meets the ground now (companion/onboard/ground.py;
    only for a sensor fixed to the airframe, `v_fov_deg` set); None or inf: no rated range and no ground in view."""
    if c.v_fov_deg is None:
        return c.max_range_m
    err = math.radians(cfg.detection.attitude_error_deg)
    roll_lo, roll_hi, pitch = tel.attitude_span()
    g = ground_range_m(-tel.z, azimuths, half_width, math.radians(c.v_fov_deg), math.radians(c.mount_pitch_deg),
                       (roll_lo, roll_hi), pitch, err, factors)
    return ground_claim_m(math.inf if c.max_range_m is None else c.max_range_m, g, RangeNoise.of(cfg.detection))


def axis_depth_factor(off_axis: np.ndarray, increment: float) -> np.ndarray:
    """cos of the bin's edge nearest the sensor's axis (1 for a bin the axis crosses): a pixel at depth z along the
    axis, off it by a, is z / cos a away, and no pixel of a bin centred `off_axis` [rad] from the axis is nearer
    to the axis than that edge — z over this is the least range the bin's depth allows, never more than the true
    range of its nearest pixel."""
    edge = np.maximum(np.abs(wrap_array(off_axis)) - increment / 2.0, 0.0)
    return np.cos(np.minimum(edge, np.radians(89.0)))


def implausible_position(x: float, y: float, z: float, vx: float, vy: float, vz: float) -> str | None:
    """`implausible` of a local position [m] and velocity [m/s] (LOCAL_POSITION_NED's fields; a log's `pos`)."""
    isfinite = math.isfinite
    if not (isfinite(x) and isfinite(y) and isfinite(z) and isfinite(vx) and isfinite(vy) and isfinite(vz)):
        return "position or velocity not finite"
    if max(abs(x), abs(y)) > PLAUSIBLE_XY_M or abs(z) > PLAUSIBLE_Z_M:
        return f"position beyond {PLAUSIBLE_XY_M:g} m"
    if math.hypot(vx, vy) > PLAUSIBLE_SPEED_M_S or abs(vz) > PLAUSIBLE_SPEED_M_S:
        return f"speed above {PLAUSIBLE_SPEED_M_S:g} m/s"
    return None


def implausible_attitude(roll: float, pitch: float, yaw: float) -> str | None:
    """`implausible` of an attitude [rad] (ATTITUDE's fields; a log's `att`)."""
    if not (math.isfinite(roll) and math.isfinite(pitch) and math.isfinite(yaw)):
        return "attitude not finite"
    if max(abs(roll), abs(pitch)) > math.pi + 1e-3 or abs(yaw) > 2 * math.pi + 1e-3:
        return "attitude out of range"
    return None


def implausible(kind: str, msg) -> str | None:
    """Why the vehicle-state fields of a message cannot be true (not finite, out of any multirotor's
    range), or None. Sensor messages are judged by their decoders."""
    if kind == "LOCAL_POSITION_NED":
        return implausible_position(msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
    if kind == "ATTITUDE":
        return implausible_attitude(msg.roll, msg.pitch, msg.yaw)
    if kind == "VFR_HUD" and not 0 <= msg.throttle <= 100:
        return "throttle outside 0–100 %"
    elif kind == "POSITION_TARGET_LOCAL_NED" and not msg.type_mask & 3 \
            and not (math.isfinite(msg.x) and math.isfinite(msg.y)):  # an unused position may be NaN (PX4 sends it)
        return "target not finite"
    return None


def refusal_text(f: dict) -> str:
    """One line for a `source_refused` event's fields (STATUSTEXT and the console say the same)."""
    who = "autopilot" if f["autopilot"] else "source"
    ids = f"{f['system']}/{f['component']}"
    if f["what"] == "unknown":
        return f"messages from {ids}, not a configured autopilot, sensor or ground station: dropped"
    if f["what"] == "moved":
        return f"{who} {ids} now taken from {f['address']} (was {f['pinned']}, silent)"
    if f["what"] == "contested":
        heard = (f"said to the seat {f['pinned']} and the ground stations" if f["pinned"] else
                 "no seat held: said to the ground stations only")
        return (f"{f['count']} addresses claim the {who} {ids}: {f['address']}: refusing to engage until one is "
                f"silent (pin its address in the config; {heard})")
    if f["what"] == "uncontested":
        return f"the {who} {ids} is claimed from one address again ({f['pinned'] or 'no seat taken yet'})"
    if f["what"] == "bad_signature":
        return f"signature mismatch from {f['address']} ids {ids}: wrong key? ({f['count']} refused)"
    held = f" (seat held: {f['held']})" if f.get("held") else ""
    return f"a second {who} {ids} from {f['address']} REFUSED ({f['count']}): it is {f['pinned']}{held}"


SENSOR_KINDS = {"DISTANCE_SENSOR": _distance_sensor, "OBSTACLE_DISTANCE": _obstacle_distance}


class MavlinkIn:
    """Accepts the autopilot's, its sensors' and the ground stations' messages — each from the ids the config
    gives it (`link.target_system`/`target_component`, `sensors[k].system_id`/`component_id`, `link.gcs_system_ids`)
    — keeps the `Telemetry` snapshot, and turns each message into samples. A message from any other source is
    counted (`counters.unknown_source`) and dropped; the first of each such source is reported (SourceRefused).
    `clock` is the daemon's clock; `vclock` (if any) follows `time_boot_ms`."""

    def __init__(self, cfg: Config, adapter, clock, vclock: VehicleClock | None, counters=None):
        self.cfg, self.adapter, self.clock, self.vclock, self.counters = cfg, adapter, clock, vclock, counters
        self.tel = Telemetry()
        self._last_boot_ms: int | None = None  # the autopilot's time_boot_ms last seen
        lk = cfg.link
        self.autopilot = (lk.target_system, lk.target_component)
        # sensor source (system, component) → {(kind, DISTANCE_SENSOR id or None, MAV_SENSOR_ORIENTATION or None):
        # index in cfg.sensors}
        self._sensors_of: dict[tuple[int, int], dict] = {}
        for i, s in enumerate(cfg.sensors):
            orientation = sensor_orientation(s.orientation_deg) if s.kind == "distance_sensor" else None
            self._sensors_of.setdefault(lk.sensor_source(s), {}).setdefault((s.kind, s.id, orientation), i)
        self._unknown: set[tuple[int, int]] = set()  # unknown sources reported

    def accept(self, msg) -> list:
        """Samples of one decoded message from the link (BAD_DATA is the caller's to count)."""
        kind = msg.get_type()
        if kind in PARAM_MSGS:
            return [ParamRequest(msg)]  # the parameter server checks the ground station (and its signature)
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src != self.autopilot:
            if kind in SENSOR_MSGS and src in self._sensors_of:  # a sensor with ids of its own
                return self.samples(self.clock(), kind, msg, src)
            return self._unknown_source(src)
        t = self.clock()
        out = self.samples(t, kind, msg)
        tb = getattr(msg, "time_boot_ms", None)
        if tb is not None:  # the autopilot's clock, no one else's
            last, self._last_boot_ms = self._last_boot_ms, tb
            if last is not None and tb + RESTART_BACK_MS < last:
                out.insert(0, AutopilotRestart(t, last / 1000, tb / 1000))
            if self.vclock is not None:
                self.vclock.observe(tb)
                if self.vclock.fault is not None:
                    out.append(Implausible(t, "time_boot_ms", self.vclock.fault))
        return out

    def _unknown_source(self, src: tuple[int, int]) -> list:
        """A message from none of the configured sources (a ground station's other messages are not for us)."""
        if src in self._sensors_of or src[0] in self.cfg.link.gcs_system_ids:
            return []
        if self.counters is not None:
            self.counters.unknown_source += 1
        if src in self._unknown or len(self._unknown) >= MAX_UNKNOWN_REPORTED:
            return []
        self._unknown.add(src)
        return [SourceRefused(self.clock(), "unknown", src, False)]

    def from_link(self, conn) -> list:
        """After a poll: the link's counts into the counters, and what it refused as samples (a UDP link's;
        other links have neither)."""
        stats = getattr(conn, "stats", None)
        if not isinstance(stats, dict):
            return []
        c = self.counters
        if c is not None:
            c.refused_address = stats.get("foreign_autopilot", 0) + stats.get("foreign_source", 0) \
                + stats.get("refused_sources", 0)
            c.link_dropped = stats.get("not_mavlink", 0) + stats.get("truncated_datagrams", 0)
            c.kernel_drops = stats.get("kernel_drops", 0)
        refusals = conn.take_refusals() if hasattr(conn, "take_refusals") else ()
        return [SourceRefused(self.clock(), r["what"], tuple(r["ids"]), r["autopilot"], r["address"], r["pinned"],
                              r["count"], r.get("held")) for r in refusals]

    def samples(self, t: float, kind: str, msg, src: tuple[int, int] | None = None) -> list:
        """The samples of one accepted message at daemon time t (may raise on nonsense: the caller counts it);
        `src`: a sensor message's (system, component), None: the autopilot's."""
        why = implausible(kind, msg)
        if kind == "HEARTBEAT" and msg.autopilot != self.adapter.autopilot_id:
            why = f"HEARTBEAT of autopilot type {msg.autopilot}, not the configured {self.adapter.name}"
        if why is not None:
            return [Implausible(t, kind, why)]  # not taken into the snapshot
        tel = self.tel
        tel.update(t, msg)
        if kind == "LOCAL_POSITION_NED":
            return [Position(t, msg.x, msg.y)]
        if kind == "ATTITUDE":
            return [Heading(t, msg.yaw, tel.ground_speed)]
        if kind == "POSITION_TARGET_LOCAL_NED":
            return [PathTarget(t, *tel.target)] if tel.target is not None and tel.t_target == t else []
        if kind == "VFR_HUD":
            air = tel.in_air if tel.landed_state else None  # MAV_LANDED_STATE_UNDEFINED: not said
            return [Throttle(t, tel.throttle, tel.roll, tel.pitch, tel.vz, air)] if math.isfinite(tel.vz) else []
        if kind in ("ESTIMATOR_STATUS", "EKF_STATUS_REPORT"):
            return [NavStatus(t, kind, msg.flags)]
        if kind in SENSOR_KINDS:
            src = src or self.autopilot
            key = (*src, getattr(msg, "id", None))  # the scan's source: per source the estimator keeps its state
            return SENSOR_KINDS[kind](self.cfg, self._sensors_of.get(src, {}), t, msg, tel, key)
        if kind == "COMMAND_ACK":
            return [CommandAck(t, msg.command, msg.result)] \
                if msg.command in (MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_DO_SET_MODE) else []
        if kind == "PARAM_VALUE":
            name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else str(msg.param_id)
            return [AutopilotParam(t, name, self.adapter.decode_param(msg.param_value, msg.param_type))]
        if kind in MISSION_MSGS:
            return [MissionMessage(t, msg)]
        return []
