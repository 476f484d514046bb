"""What a campaign compares the contract with: the autopilots' own avoidance laws flown as governors, and
negative controls of our own. Pure (no I/O); never an on-board default. Each is a speed policy
(companion/onboard/supervisor.py `ContractSpeed` says what one has), passed to the daemon's supervisor
(`Rig(policy=...)`, `Daemon(policy=...)`) for a campaign or a test only; the daemon's cycle feeds a policy
every sample it takes (`take`).

A law is an object with `take(sample)` (every sample of `companion/onboard/samples.py`; unknown kinds are ignored)
and `omega(inputs, sup=None) -> Omega`. Like the firmware it copies, each law keeps **its own obstacle map built from
the sensor messages** (the `Scan`s MAVLink-in makes of DISTANCE_SENSOR / OBSTACLE_DISTANCE) — never the
daemon's D_od estimate or its corridor. From `inputs` it reads the clock `t` and the ground speed only. Its
speed limit is sent as `MAV_CMD_DO_CHANGE_SPEED`; below 0.2 m/s it is a Hold (the daemon's "no safe speed").
The daemon's own stop-distance Hold is off under a law (the law is the whole answer); its failsafes and its
check that the autopilot slows to the limit in time stay.

A governor commands one speed along the vehicle's heading (in a mission the autopilot yaws along the leg).
Both firmwares bound the velocity component towards each obstacle direction θ (a bin, a boundary segment):
`v·cos θ ≤ v_k`. The governor's limit is the tightest of these, `min_k v_k / cos θ_k` over the directions
ahead (cos θ > 0).

**PX4 Collision Prevention** — `src/lib/collision_prevention/CollisionPrevention.cpp` and `.hpp` of
PX4-Autopilot (the stored version 001d722; the older 970e500 has the same law on 10° bins and no
`MPC_XY_P·s` cap either), `src/lib/mathlib/math/TrajMath.hpp` `computeMaxSpeedFromDistance`:

- the map: `BIN_COUNT = 36` bins, `BIN_SIZE = 360 / BIN_COUNT` (10°); bin i points at i·10° (body frame,
  clockwise) (`_getVelocityCompensationAcceleration`: `bin_angle = yaw + radians(i * BIN_SIZE + angle_offset)`);
- DISTANCE_SENSOR (`_addDistanceSensorData`): `distance_reading = min(current_distance, max_distance)`;
  "discard values below min range" (`distance_reading > min_distance`); bins from
  `floor((yaw_deg − h_fov/2) / BIN_SIZE)` to `floor((yaw_deg + h_fov/2) / BIN_SIZE)` ("floor values above
  zero, ceil values below zero": a negative bound +1); a reading below the maximum is scaled by the cosine of
  the pitch in the sensor's frame; the bin's range is `max_distance` (cm, rounded); `_enterData` decides
  between sensors (in range beats out of range; of two in range, the shorter-range sensor);
- OBSTACLE_DISTANCE (`_addObstacleSensorData`, body frame): bin i takes message bin
  `ceil(wrap_360(i·BIN_SIZE − angle_offset) / increment)` unless it is UINT16_MAX;
- staleness: `RANGE_STREAM_TIMEOUT_US{500_ms}`: a bin not refreshed for 0.5 s is reset to UINT16_MAX, and
  "obstacle data present" needs a bin with data and a map message younger than 0.5 s
  (`_updateObstacleData`). Without it: "allow no movement" (`setpoint_accel.setZero()`), and after
  `TIMEOUT_HOLD_US{5_s}` Loiter — here the limit is 0 at once (a Hold). The bin the motion points into must
  have data unless `CP_GO_NO_DATA` (`_checkSetpointDirectionFeasability`);
- per bin with `min_distance < distance < UINT16_MAX` (`_getVelocityCompensationAcceleration`):
  `delay = v∥·CP_DELAY`, plus `v∥·data_age` "if (distance < max_range)" — the data-age term, the age of the
  bin's reading; `stop_distance = max(0, distance − max(min_distance, CP_DIST) − delay)`;
  `max_vel = computeMaxSpeedFromDistance(MPC_JERK_MAX, MPC_ACC_HOR, stop_distance, 0)`
  (`b = 4a²/J`, `c = −2a·s`, `(−b + sqrt(b² − 4c))/2`). There is no `MPC_XY_P·s` term (MPC_XY_P only
  scales the stick input, `_getScale`). A bin whose reading is out of range holds `max_distance` and so
  limits the speed too, without the age term.
- the jerk: the firmware passes MPC_JERK_MAX (default 8 m/s³; its Position mode slews the stick acceleration at
  it, `FlightTaskManualAcceleration` / `StickAccelerationXY`: `setSlewRate(_param_mpc_jerk_max.get())`). The
  law here does the same (`jerk`, `jerk_param` MPC_JERK_MAX; MPC_ACC_HOR the autopilot's), arm `px4_cp`. A
  mission (auto mode) brakes at MPC_JERK_AUTO instead, which slows the law where it is drawn low (at 5 m:
  jerk 8 → 3.67 m/s, 4 → 2.59, 1 → 0.81): that variant is the separate arm `px4_cp_auto_jerk`, never the peer.
- no latch: the firmware only bounds the velocity, so a limit that dips to 0 and rises again lets the vehicle go
  on. Flown as a governor, a limit below 0.2 m/s is the daemon's Hold, which a governor keeps until someone
  changes the mode; the campaign's rig resumes the mission as soon as the law's limit is back (`campaign.
  FirmwareResume`), as the firmware would.

**ArduPilot AC_Avoid** (Copter's default `AVOID_BEHAVE` Slide) — `libraries/AC_Avoidance/AC_Avoid.cpp`
`adjust_velocity` → `adjust_velocity_proximity` → `limit_velocity_3D` → `limit_velocity_2D` →
`get_max_speed` → `sqrt_controller` (`AP_Math/control.cpp`), with the proximity library
`libraries/AP_Proximity/AP_Proximity_MAV.cpp` and `AP_Proximity_Boundary_3D.cpp`:

- DISTANCE_SENSOR (`handle_distance_sensor_msg`): face = the orientation's 45° sector; "if (distance <=
  _distance_max && distance >= _distance_min)" the face is set, else it is reset: **a reading beyond the
  maximum is dropped** (no obstacle there, however short the range); OBSTACLE_DISTANCE: each face takes the
  nearest of its message bins within [min, max]; a face with none is reset;
- faces are 45° sectors centred on 0°, 45°, … (`get_face`: `wrap_360(yaw + 22.5) / 45`); each keeps a
  low-pass filtered distance (`set_filtered_distance`, cutoff 0.25 Hz, reset after
  `PROXIMITY_FILT_RESET_TIME` 1000 ms), and a face not updated for `PROXIMITY_FACE_RESET_MS` 1000 ms is
  reset (`check_face_timeout`): with no data the sensor has no obstacles and AC_Avoid "proximity avoidance
  did nothing" — **fail-open** (`get_obstacle_count` 0 → return: the mission's own speed);
- the boundary (`update_boundary`): a point on each sector edge (mid ± 22.5°) at the shorter filtered
  distance of its two sectors (a missing neighbour takes the valid one's: the "cup"), at least
  `PROXIMITY_BOUNDARY_DIST_MIN` 0.6 m, 100 m where neither has data; obstacle k is the point of the line
  between edge points k and k+1 closest to the vehicle (`get_obstacle`), valid when sector k, k+1 or k+2
  has data (`convert_obstacle_num_to_face`);
- per obstacle: `distance_from_fence_xy = max(|obstacle_xy| − AVOID_MARGIN, 0)`, and the velocity component
  towards it `≤ get_max_speed = sqrt_controller(distance, PSC_POSXY_P, accel)` with
  `accel = MIN(accel_cmss, AC_AVOID_ACCEL_CMSS_MAX)` (1 m/s²): `kP·e` up to `e = a/kP²`, else
  `sqrt(2a·(e − a/(2kP²)))` (its `|e|/dt` clamp at 400 Hz never binds here). No delay term, and the
  sensor's range caps nothing (an out-of-range reading is no obstacle).
- The rate limit `limit_accel` (AVOID_ACCEL_MAX) on the avoidance's velocity change is the autopilot's
  response, not the limit: left out, as is backing away (`BACKUP_SPD`).

Negative controls: the contract's speed × k (`Scaled`, 1.15 and 1.3), the contract without the E_tr
inflation (`WithoutEtr`), and the contract believing the sensor's stated range (`TrustTheClaim`: D_od without
the evidence of companion/onboard/detection_range.py). **no guard**: the daemon off, the mission at its cruise speed.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace

from companion.onboard.detection_range import DetectionRange
from companion.onboard.samples import AutopilotParam, Scan, Throttle
from companion.onboard.supervisor import ContractSpeed
from contracts.table import Omega

MIN_SPEED = 0.2  # the supervisor's MIN_SPEED_CMD: a limit below it is a Hold
UINT16_MAX = 65535


@dataclass(frozen=True)
class SensorMount:
    """Where a configured sensor looks (its `Scan.sensor` index): yaw clockwise from forward, field of view."""

    orientation_deg: float = 0.0
    h_fov_deg: float = 60.0


def mounts(sensors) -> tuple[SensorMount, ...]:
    """The mounts of the daemon's configured sensors (`Config.sensors`)."""
    return tuple(SensorMount(s.orientation_deg, s.h_fov_deg) for s in sensors)


def _ahead(limits) -> float:
    """The governor's speed from per-direction bounds [(v_k, θ_k)]: v·cos θ_k ≤ v_k for every θ_k ahead."""
    return min((v / math.cos(th) for v, th in limits if math.cos(th) > 1e-9), default=math.inf)


def _omega(v: float, tilt: float, reason: str) -> Omega:
    return Omega(contract="stop", v_max=v, tilt=tilt, e_tr=0.0, v_safe=v, gamma=0.0, reason=reason)


# ----------------------------------------------------------------------------- PX4 Collision Prevention

PX4_BIN_COUNT = 36  # CollisionPrevention.hpp: BIN_COUNT = 36
PX4_BIN_SIZE = 360 // PX4_BIN_COUNT  # BIN_SIZE = 360 / BIN_COUNT (10°)
PX4_RANGE_STREAM_TIMEOUT_S = 0.5  # RANGE_STREAM_TIMEOUT_US{500_ms}


def px4_max_speed_from_distance(jerk: float, accel: float, s: float, final_speed: float = 0.0) -> float:
    """PX4 `math::trajectory::computeMaxSpeedFromDistance` (TrajMath.hpp), same algebra."""
    b = 4.0 * accel * accel / jerk
    c = -2.0 * accel * s - final_speed * final_speed
    return max(0.5 * (-b + math.sqrt(b * b - 4.0 * c)), final_speed)


def px4_bin_speed(distance: float, v_par: float, *, keep: float, cp_delay: float, age: float, in_range: bool,
                  acc_hor: float, jerk: float) -> float:
    """`max_vel` of one bin (`_getVelocityCompensationAcceleration`): the speed towards it PX4 allows."""
    delay = v_par * cp_delay + (v_par * age if in_range else 0.0)
    return px4_max_speed_from_distance(jerk, acc_hor, max(0.0, distance - keep - delay), 0.0)


def px4_sensor_bins(yaw_deg: float, h_fov_deg: float) -> list[int]:
    """The map bins a DISTANCE_SENSOR fills (`_addDistanceSensorData`'s lower/upper bound)."""
    yaw = yaw_deg % 360.0
    lo = math.floor((yaw - h_fov_deg / 2.0) / PX4_BIN_SIZE)
    hi = math.floor((yaw + h_fov_deg / 2.0) / PX4_BIN_SIZE)
    lo += lo < 0  # "floor values above zero, ceil values below zero"
    hi += hi < 0
    return [b % PX4_BIN_COUNT for b in range(lo, hi + 1)]


@dataclass
class Px4CollisionPrevention:
    """PX4's law as a governor, on its own obstacle map. `cp_dist_m`: CP_DIST (PX4's default −1 disables
    the feature; a user who enables it picks a distance — the campaign spec states it); `acc_hor`, `jerk`:
    the braking the law assumes (MPC_ACC_HOR, and the jerk of the mode flown — see the module docstring);
    `cruise_m_s`: the speed when nothing ahead limits it."""

    sensors: tuple[SensorMount, ...] = (SensorMount(),)
    cp_dist_m: float = 1.0
    min_distance_m: float = 0.1  # the sensor's own minimum distance (the map's min_distance)
    cp_delay_s: float = 0.4  # CP_DELAY
    acc_hor: float = 3.0  # MPC_ACC_HOR
    jerk: float = 8.0  # MPC_JERK_MAX's default, as CollisionPrevention.cpp computes the speed
    jerk_param: str = "MPC_JERK_MAX"  # the parameter `jerk` is (a report of it overrides): MPC_JERK_AUTO in the variant
    go_no_data: bool = False  # CP_GO_NO_DATA
    cruise_m_s: float = math.inf
    tilt: float = 0.0  # the tilt Ω carries (for the log only)
    name: str = "px4_cp"
    # the autopilot's parameters that override the above when it reports them (AutopilotParam), with `jerk_param`
    PARAMS = {"CP_DIST": "cp_dist_m", "CP_DELAY": "cp_delay_s", "MPC_ACC_HOR": "acc_hor"}
    stop_hold = False  # the law is the whole answer to an obstacle: the daemon's stop-distance Hold is off
    inflate_e_tr = True

    def __post_init__(self):
        self.dist_cm = [UINT16_MAX] * PX4_BIN_COUNT  # _obstacle_map_body_frame.distances
        self.range_cm = [0] * PX4_BIN_COUNT  # _data_maxranges
        self.t_bin = [-math.inf] * PX4_BIN_COUNT  # _data_timestamps
        self.t_map = -math.inf  # _obstacle_map_body_frame.timestamp
        self.roll = self.pitch = 0.0

    # ---- the map (_updateObstacleMap)
    def take(self, s) -> None:
        if isinstance(s, Scan):
            self.t_map = max(self.t_map, s.t)  # every fresh message updates the map's timestamp
            if s.known is None:
                self._add_distance_sensor(s)
            elif s.quality != 1:
                self._add_obstacle_distance(s)
        elif isinstance(s, Throttle):
            self.roll, self.pitch = s.roll, s.pitch
        elif isinstance(s, AutopilotParam) and math.isfinite(s.value):
            if s.name in self.PARAMS:
                setattr(self, self.PARAMS[s.name], s.value)
            elif s.name == self.jerk_param:
                self.jerk = s.value

    def _enter(self, i: int, sensor_range: float, reading: float) -> bool:
        """`_enterData`: in range beats out of range; of two in range, the shorter-range sensor's."""
        range_cm = int(100.0 * sensor_range + 0.5)
        d, mr = self.dist_cm[i], self.range_cm[i]
        if reading < sensor_range:
            return (d < mr and range_cm <= mr) or d >= mr
        return (d >= mr and range_cm >= mr) or (d < mr and range_cm == mr)

    def _put(self, i: int, cm: int, sensor_range: float, t: float) -> None:
        self.dist_cm[i], self.range_cm[i], self.t_bin[i] = cm, int(100.0 * sensor_range + 0.5), t

    def _add_distance_sensor(self, s: Scan) -> None:
        if s.sensor >= len(self.sensors):
            return  # (signal_quality is not read: only a reading below min_distance is discarded, below)
        m = self.sensors[s.sensor]
        reading = min(s.hits[0][1], s.max_m) if s.hits else s.max_m  # "clamp at maximum sensor range"
        if reading <= self.min_distance_m:
            return
        if reading < s.max_m:  # projected by the pitch in the sensor's frame
            psi = math.radians(m.orientation_deg)
            sin_th = math.sin(self.pitch) * math.cos(psi) - math.sin(self.roll) * math.cos(self.pitch) * math.sin(psi)
            reading *= math.sqrt(max(0.0, 1.0 - sin_th * sin_th))
        for b in px4_sensor_bins(m.orientation_deg, m.h_fov_deg):
            if self._enter(b, s.max_m, reading):
                self._put(b, int(100.0 * reading + 0.5), s.max_m, self.t_map)

    def _add_obstacle_distance(self, s: Scan) -> None:
        inc = math.degrees(s.increment or 0.0)
        if inc <= 0.0:
            return
        hit = {round(math.degrees(b) % 360.0, 6): r for b, r in s.hits}
        known = [math.degrees(b) % 360.0 for b in s.known]
        for i in range(PX4_BIN_COUNT):
            # the message bin `ceil((i·BIN_SIZE − angle_offset) / increment)`: the one at or just after the bin
            j = [b for b in known if -1e-6 <= (b - i * PX4_BIN_SIZE) % 360.0 < inc - 1e-6
                 or (b - i * PX4_BIN_SIZE) % 360.0 > 360.0 - 1e-6]
            if not j:
                continue  # UINT16_MAX: that bin knows nothing
            reading = hit.get(round(j[0], 6), s.max_m + 0.01)  # nothing seen: max_distance + 1 cm
            if self._enter(i, s.max_m, reading):
                self._put(i, int(round(100.0 * reading)), s.max_m, self.t_map)

    # ---- the law (_updateObstacleData, _calculateConstrainedSetpoint, _getVelocityCompensationAcceleration)
    def omega(self, i, sup=None) -> Omega:
        now = i.t
        for k in range(PX4_BIN_COUNT):
            if now - self.t_bin[k] > PX4_RANGE_STREAM_TIMEOUT_S:  # stale: the bin is reset
                self.dist_cm[k] = UINT16_MAX
        present = any(d < UINT16_MAX for d in self.dist_cm) and now - self.t_map < PX4_RANGE_STREAM_TIMEOUT_S
        if not present:
            return _omega(0.0, self.tilt, "px4 collision prevention: no obstacle data, not moving")
        if not math.isfinite(i.ground_speed):  # no velocity for the delay terms: the slower answer
            return _omega(0.0, self.tilt, "px4 collision prevention: no velocity")
        if self.dist_cm[0] == UINT16_MAX and not self.go_no_data:  # the setpoint's bin has no data
            return _omega(0.0, self.tilt, "px4 collision prevention: no data ahead")
        min_cm = int(self.min_distance_m * 100.0)
        keep = max(min_cm / 100.0, self.cp_dist_m)
        v = max(i.ground_speed, 0.0)
        limits = []
        for k, cm in enumerate(self.dist_cm):
            if not min_cm < cm < UINT16_MAX:
                continue
            th = math.radians(k * PX4_BIN_SIZE)
            d = cm * 0.01
            limits.append((px4_bin_speed(d, v * max(math.cos(th), 0.0), keep=keep, cp_delay=self.cp_delay_s,
                                         age=now - self.t_bin[k], in_range=d < self.range_cm[k] * 0.01,
                                         acc_hor=self.acc_hor, jerk=self.jerk), th))
        return _omega(min(self.cruise_m_s, _ahead(limits)), self.tilt, "px4 collision prevention")


# ----------------------------------------------------------------------------- ArduPilot AC_Avoid

AP_SECTORS = 8  # PROXIMITY_NUM_SECTORS (45° each)
AP_SECTOR_DEG = 360.0 / AP_SECTORS
AP_MAV_TIMEOUT_S = 0.5  # PROXIMITY_MAV_TIMEOUT_MS (the sensor's health)
AP_FACE_RESET_S = 1.0  # PROXIMITY_FACE_RESET_MS
AP_FILT_RESET_S = 1.0  # PROXIMITY_FILT_RESET_TIME
AP_FILT_HZ = 0.25  # _filtered_distance cutoff
AP_BOUNDARY_MIN_M = 0.6  # PROXIMITY_BOUNDARY_DIST_MIN
AP_BOUNDARY_DEFAULT_M = 100.0  # PROXIMITY_BOUNDARY_DIST_DEFAULT
AC_AVOID_ACCEL_MAX = 1.0  # AC_AVOID_ACCEL_CMSS_MAX 100 cm/s²


def sqrt_controller(error: float, p: float, second_ord_lim: float) -> float:
    """ArduPilot `sqrt_controller` (AP_Math/control.cpp), positive side, without its dt clamp."""
    if second_ord_lim <= 0.0:
        return error * p
    if p == 0.0:
        return math.sqrt(max(2.0 * second_ord_lim * error, 0.0))
    linear_dist = second_ord_lim / (p * p)
    if error > linear_dist:
        return math.sqrt(2.0 * second_ord_lim * (error - linear_dist / 2.0))
    return error * p


def ac_avoid_speed(d: float, *, margin: float = 2.0, kp: float = 1.0, accel: float = 1.0) -> float:
    """AC_Avoid's speed towards an obstacle point at `d` (`limit_velocity_3D` → `get_max_speed`)."""
    return max(0.0, sqrt_controller(max(d - margin, 0.0), kp, min(accel, AC_AVOID_ACCEL_MAX)))


def ap_face(yaw_deg: float) -> int:
    """`AP_Proximity_Boundary_3D::get_face`: the 45° sector of a body yaw."""
    return int(((yaw_deg + AP_SECTOR_DEG / 2.0) % 360.0) // AP_SECTOR_DEG) % AP_SECTORS


def _closest_on_segment(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    """The point of segment a–b closest to the vehicle (the origin)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    n = dx * dx + dy * dy
    u = 0.0 if n == 0.0 else min(1.0, max(0.0, -(a[0] * dx + a[1] * dy) / n))
    return a[0] + u * dx, a[1] + u * dy


@dataclass
class ArduPilotAcAvoid:
    """AC_Avoid's law as a governor, on its own proximity boundary; fail-open at `cruise_m_s`."""

    cruise_m_s: float
    sensors: tuple[SensorMount, ...] = (SensorMount(),)
    margin_m: float = 2.0  # AVOID_MARGIN
    kp: float = 1.0  # PSC_POSXY_P
    accel: float = 1.0  # the position controller's acceleration, capped at AC_AVOID_ACCEL_CMSS_MAX (1 m/s²)
    tilt: float = 0.0
    name: str = "ac_avoid"
    PARAMS = {"AVOID_MARGIN": "margin_m", "PSC_POSXY_P": "kp"}
    stop_hold = False  # the law is the whole answer to an obstacle: the daemon's stop-distance Hold is off
    inflate_e_tr = True

    def __post_init__(self):
        self.valid = [False] * AP_SECTORS  # _distance_valid (middle layer)
        self.filt = [0.0] * AP_SECTORS  # _filtered_distance
        self.t_face = [-math.inf] * AP_SECTORS  # _last_update_ms
        self.edge = [AP_BOUNDARY_DEFAULT_M] * AP_SECTORS  # _boundary_points: distance on edge k (mid + 22.5°)
        self.t_msg = -math.inf  # _last_update_ms of the driver (its health)

    def take(self, s) -> None:
        if isinstance(s, Scan):
            self.t_msg = s.t
            if s.known is None:
                self._distance_sensor(s)
            elif s.quality != 1:
                self._obstacle_distance(s)
        elif isinstance(s, AutopilotParam) and s.name in self.PARAMS and math.isfinite(s.value):
            setattr(self, self.PARAMS[s.name], s.value)

    def healthy(self, t: float) -> bool:
        """`AP_Proximity_MAV::update`: Good while messages arrive within PROXIMITY_MAV_TIMEOUT_MS."""
        return t - self.t_msg <= AP_MAV_TIMEOUT_S

    def _distance_sensor(self, s: Scan) -> None:
        if s.sensor >= len(self.sensors):
            return
        face = ap_face(45.0 * round(self.sensors[s.sensor].orientation_deg / 45.0))  # the orientation's sector
        if s.hits:  # within [min, max] (signal_quality is not read)
            self._set(face, s.hits[0][1], s.t)
        else:  # beyond the maximum, below the minimum: "reset distance for this face"
            self._reset(face)

    def _obstacle_distance(self, s: Scan) -> None:
        near: dict[int, float] = {}
        for b, r in s.hits:  # bins beyond max_distance (or unused) are skipped: their faces are left as they are
            f = ap_face(math.degrees(b))
            near[f] = min(r, near.get(f, math.inf))
        for f, r in near.items():
            self._set(f, r, s.t)

    def _set(self, k: int, d: float, t: float) -> None:
        """`set_face_attributes` → `set_filtered_distance` (LowPassFilterFloat, 0.25 Hz) → `update_boundary`."""
        dt = t - self.t_face[k]
        if dt < AP_FILT_RESET_S:
            alpha = dt / (dt + 1.0 / (2.0 * math.pi * AP_FILT_HZ))
            self.filt[k] += (d - self.filt[k]) * alpha
        else:
            self.filt[k] = d
        self.t_face[k] = t
        self.valid[k] = True
        self._update_boundary(k)

    def _reset(self, k: int) -> None:
        self.valid[k] = False
        self._update_boundary(k)

    def _update_boundary(self, k: int) -> None:
        """`AP_Proximity_Boundary_3D::update_boundary`: the edge points either side of sector k."""
        n, p = (k + 1) % AP_SECTORS, (k - 1) % AP_SECTORS
        for edge, a, b, cup in ((k, k, n, n), (p, p, k, (p - 1) % AP_SECTORS)):
            ds = [self.filt[x] for x in (a, b) if self.valid[x]]
            d = min(ds) if ds else AP_BOUNDARY_DEFAULT_M
            if edge == k:
                d = max(d, AP_BOUNDARY_MIN_M)  # (the source clamps only this edge)
            self.edge[edge] = d
            if not self.valid[cup]:  # the "cup": a sector without data takes the same distance
                self.edge[cup] = d

    def obstacles(self, t: float) -> list[tuple[float, float]]:
        """The boundary's obstacle points (body frame: x forward, y right) — `get_obstacle`."""
        for k in range(AP_SECTORS):  # check_face_timeout
            if self.valid[k] and t - self.t_face[k] > AP_FACE_RESET_S:
                self._reset(k)
        pts = []
        for k in range(AP_SECTORS):
            if not any(self.valid[(k + j) % AP_SECTORS] for j in range(3)):  # convert_obstacle_num_to_face
                continue
            ends = []
            for e in ((k + 1) % AP_SECTORS, k):
                a = math.radians(e * AP_SECTOR_DEG + AP_SECTOR_DEG / 2.0)
                ends.append((self.edge[e] * math.cos(a), self.edge[e] * math.sin(a)))
            pts.append(_closest_on_segment(*ends))
        return pts

    def omega(self, i, sup=None) -> Omega:
        pts = self.obstacles(i.t)
        if not pts:  # no obstacle count: "proximity avoidance did nothing"
            why = "ac_avoid: no proximity data, not limiting" if not self.healthy(i.t) else "ac_avoid"
            return _omega(self.cruise_m_s, self.tilt, why)
        lim = _ahead([(ac_avoid_speed(math.hypot(x, y), margin=self.margin_m, kp=self.kp, accel=self.accel),
                       math.atan2(y, x)) for x, y in pts])
        return _omega(min(self.cruise_m_s, lim), self.tilt, "ac_avoid")


# ----------------------------------------------------------------------------- negative controls (table wrappers)

class Scaled(ContractSpeed):
    """The contract with every speed raised by a factor `k` (a negative control only)."""

    def __init__(self, k: float):
        super().__init__(k)
        self.name = f"contract x {k:g}"


class WithoutEtr(ContractSpeed):
    """The contract with no tracking-error budget (a negative control only): Ω at E_tr = 0 — neither the measured
    error nor E_tr_pred — so V_max is the contract's for a perfectly tracking vehicle; and no E_tr in the keep-out
    discs either (they are R_obst + r_body alone)."""

    name = "contract without E_tr"
    inflate_e_tr = False

    def __init__(self):
        super().__init__()
        self._bare = None

    def omega(self, i, sup) -> Omega:
        if self._bare is None:
            self._bare = copy.copy(sup.table)
            self._bare.e_pred = None  # only in this copy: Ω without E_tr_pred
        return self._bare.omega(i.dod.d_od, i.r_obst, 0.0, i.thrust_ratio, contract=sup.contract)


class SilenceUnbudgeted(ContractSpeed):
    """The contract taking none of the obstacle sensors' silence as dead time (a negative control only): Ω as if a
    sensor that dies were noticed at once, while the daemon flies on its last reading for its whole silence budget."""

    name = "contract without the silence budget"

    def omega(self, i, sup) -> Omega:
        return sup.contract_omega(replace(i, dod=replace(i.dod, silence_s=0.0)))


class OvershootUnbudgeted(ContractSpeed):
    """The contract sending V_max itself, with no room for the autopilot's speed overshoot (a negative control
    only): the flown speed then goes above V_safe by what the autopilot overshoots, while the limit is judged with
    the same allowance (companion/onboard/overshoot.py)."""

    name = "contract without the overshoot budget"

    def omega(self, i, sup) -> Omega:
        om = sup.contract_omega(i)
        v = min(sup.overshoot.top(om.v_max), om.v_safe) if om.v_max > 0 else om.v_max
        return replace(om, v_max=v, gamma=v - om.v_safe)


class TrustTheClaim(DetectionRange):
    """The detection-range estimator that believes the sensor's stated range (a negative control only; flown as
    the `_claim` arms): D_od is the claim."""

    def estimate(self, t, stated_m):
        return replace(super().estimate(t, stated_m), d_od=stated_m)
