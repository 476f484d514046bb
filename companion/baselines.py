"""What a campaign compares the contract with: the autopilots' own avoidance laws flown as governors, and
negative controls of our own. Pure (no I/O); never an on-board default. Each is a speed policy
(companion/supervisor.py `ContractSpeed` says what one has), passed to the daemon's supervisor
(`Rig(policy=...)`, `Daemon(policy=...)`) for a campaign or a test only.

A law acts as a governor through the same daemon: each cycle it turns the same MAVLink-derived sensor data
(`Inputs`: the nearest obstacle on the path, the sensor's range, the ground speed, sensor health) into a
speed limit, which the daemon sends as `MAV_CMD_DO_CHANGE_SPEED`; a limit below 0.2 m/s is a Hold (the
daemon's "no safe speed"). The daemon's own stop-distance Hold is off under a law (the law is the whole
answer); its failsafes (link, stale position, bad navigation) and its check that the autopilot slows to the
limit in time (else Hold: "speed limit not in force") stay — a governor acts through DO_CHANGE_SPEED, slower
than PX4's law inside its own position loop, and that check is what a governor has to make up for it. The laws (checked against their sources):

- **PX4 Collision Prevention** (`src/lib/collision_prevention/CollisionPrevention.cpp`,
  `_constrainAccelerationSetpoint`; `src/lib/mathlib/math/TrajMath.hpp` `computeMaxSpeedFromDistance`): per
  bin, `s = max(0, d − D − v·(CP_DELAY + age))` with `D = max(sensor min distance, CP_DIST)` (the age term
  only for a reading inside the sensor's range), `v_max = min(MPC_XY_P·s, −2a²/J + sqrt(4a⁴/J² + 2a·s))`
  (`computeMaxSpeedFromDistance(J, a, s, 0)`: `b = 4a²/J`, `c = −2a·s`, `(−b + sqrt(b² − 4c))/2`), with
  `a = MPC_ACC_HOR`, `J = MPC_JERK_MAX`; a bin with no data (stale beyond `RANGE_STREAM_TIMEOUT_US` 0.5 s)
  allows no motion and the vehicle is switched to Loiter (here: the limit is 0 at once, so Hold). It ignores
  the tracking error, the thrust left and the obstacle's size. A bin with no obstacle reports the sensor's
  range, which then limits the speed too (`distance = max_distance` in the code above).
- **ArduPilot AC_Avoid** (`libraries/AC_Avoidance/AC_Avoid.cpp`, `adjust_velocity_proximity` →
  `limit_velocity_2D` → `get_max_speed` → `sqrt_controller` of `AP_Math/control.cpp`): `e = d − AVOID_MARGIN`,
  `v = kP·e` for `e ≤ a/kP²`, else `sqrt(2a·(e − a/(2kP²)))`, `kP = PSC_POSXY_P`, `a = min(AVOID_ACCEL_MAX,
  AC_AVOID_ACCEL_CMSS_MAX = 1 m/s²)`; no delay term; when the proximity sensor is not healthy it returns
  without limiting (fail-open: the mission's cruise speed). The `dt` clamp of `sqrt_controller`
  (`|e|/dt`, at 400 Hz) never binds at these distances and is left out.
- **no guard**: the daemon off, the mission at its cruise speed.
- negative controls: the contract's speed × k (`Scaled`, 1.15 and 1.3), and the contract without the
  E_tr inflation (`WithoutEtr`).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

from contracts.table import Omega

from .supervisor import ContractSpeed

MIN_SPEED = 0.2  # the supervisor's MIN_SPEED_CMD: a limit below it is a Hold


def px4_max_speed_from_distance(jerk: float, accel: float, s: float, final_speed: float = 0.0) -> float:
    """PX4 `math::trajectory::computeMaxSpeedFromDistance` (TrajMath.hpp), same algebra."""
    b = 4.0 * accel * accel / jerk
    c = -2.0 * accel * s - final_speed * final_speed
    return max(0.5 * (-b + math.sqrt(b * b - 4.0 * c)), final_speed)


def px4_cp_speed(d: float, v: float, *, cp_dist: float, min_distance: float, cp_delay: float = 0.4,
                 age: float = 0.0, acc_hor: float = 3.0, jerk_max: float = 8.0, xy_p: float = 0.95,
                 in_range: bool = True) -> float:
    """PX4 Collision Prevention's speed limit towards one bin at distance `d` (CollisionPrevention.cpp)."""
    delay = max(v, 0.0) * (cp_delay + (age if in_range else 0.0))
    s = max(0.0, d - max(min_distance, cp_dist) - delay)
    return min(xy_p * s, px4_max_speed_from_distance(jerk_max, acc_hor, s, 0.0))


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
    """ArduPilot AC_Avoid's speed limit towards an obstacle at `d` (AC_Avoid.cpp `get_max_speed`)."""
    return max(0.0, sqrt_controller(d - margin, kp, min(accel, 1.0)))


@dataclass
class Px4CollisionPrevention:
    """PX4's law as a governor. `cp_dist_m`: CP_DIST (PX4's default −1 disables the feature; a user who
    enables it picks a distance — the campaign spec states it)."""

    cp_dist_m: float = 1.0
    min_distance_m: float = 0.1  # the sensor's own minimum distance
    cp_delay_s: float = 0.4  # CP_DELAY
    acc_hor: float = 3.0  # MPC_ACC_HOR
    jerk_max: float = 8.0  # MPC_JERK_MAX
    xy_p: float = 0.95  # MPC_XY_P
    tilt: float = 0.0  # the tilt Ω carries (for the log only)
    name: str = "px4_cp"

    stop_hold = False  # the law is the whole answer to an obstacle
    inflate_e_tr = True

    def take(self, sample) -> None:
        pass

    def omega(self, i, sup=None) -> Omega:
        if not i.dod.covered_by or not math.isfinite(i.ground_speed):  # no data: no motion (then Loiter)
            return _omega(0.0, self.tilt, "px4 collision prevention: no data")
        in_range = math.isfinite(i.dod.obstacle_m)
        d = min(i.dod.obstacle_m, i.dod.d_od)
        return _omega(px4_cp_speed(d, i.ground_speed, cp_dist=self.cp_dist_m, min_distance=self.min_distance_m,
                                   cp_delay=self.cp_delay_s, acc_hor=self.acc_hor, jerk_max=self.jerk_max,
                                   xy_p=self.xy_p, in_range=in_range), self.tilt, "px4 collision prevention")


@dataclass
class ArduPilotAcAvoid:
    """AC_Avoid's law as a governor; fail-open at `cruise_m_s` when no sensor is healthy."""

    cruise_m_s: float
    margin_m: float = 2.0  # AVOID_MARGIN
    kp: float = 1.0  # PSC_POSXY_P
    accel: float = 1.0  # AVOID_ACCEL_MAX, capped at AC_AVOID_ACCEL_CMSS_MAX (1 m/s²)
    tilt: float = 0.0
    name: str = "ac_avoid"

    stop_hold = False
    inflate_e_tr = True

    def take(self, sample) -> None:
        pass

    def omega(self, i, sup=None) -> Omega:
        if not i.dod.covered_by:  # proximity not healthy: AC_Avoid returns without limiting
            return _omega(self.cruise_m_s, self.tilt, "ac_avoid: proximity unhealthy, not limiting")
        d = min(i.dod.obstacle_m, i.dod.d_od)
        return _omega(min(self.cruise_m_s, ac_avoid_speed(d, margin=self.margin_m, kp=self.kp, accel=self.accel)),
                      self.tilt, "ac_avoid")


def _omega(v: float, tilt: float, reason: str) -> Omega:
    return Omega(contract="stop", v_max=v, tilt=tilt, e_tr=0.0, v_safe=v, gamma=0.0, reason=reason)


# ----------------------------------------------------------------------------- negative controls (speed policies)

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
