"""The nearest obstacle the stop contract stops short of (pure).

The stop contract (DESIGN.md §1: the governor's Hold, and offboard's braking stop once fallen back from the avoid
contract) guarantees a stop short of the keep-out disc of whatever lies in the swept corridor — the band of
half-width w = r_body + E_tr about the direction of travel (companion/onboard/coverage.py: a surface is touched
where it enters that band). D_od's estimator judges its own guarantee over a wider band, the corridor a column of
radius R_obst must reach before it touches the swept one (2·R_obst + E_tr + r_body); that band is what the state
samples log as `obstacle_m`. The stop contract's Hold judges the swept corridor itself: a wall beside the route is
in the wider band but nowhere on the path, and holding for it stops a flight that nothing threatens.
"""

from __future__ import annotations

import math

from contracts.geometry import wrap

# [m/s] below this the velocity's direction is drift, not the direction of travel: the cycle takes D_od along the
# heading there (stopping from it takes ~0.3 m, inside the E_tr floor) unless the vehicle creeps out of view
TRAVEL_SPEED_M_S = 1.0
# [m/s] above this the velocity is motion, not a hover's noise (a hovering multirotor's velocity estimate wanders
# by ~0.1 m/s)
CREEP_SPEED_M_S = 0.3


class Creep:
    """The direction of travel D_od is judged along (body frame, rad; above TRAVEL_SPEED_M_S the Hold's swept
    corridor too, `stop_obstacle_m`): the velocity's above TRAVEL_SPEED_M_S; below it the heading's (0) — the
    velocity's bearing is a hover's drift there — unless the vehicle creeps (faster than CREEP_SPEED_M_S) along
    bearings no sensor looks along for longer than an allowance: from then on the velocity's, so D_od is what was
    seen free that way (estimators.DodEstimator: the swept coverage), not the sensor's range along a heading the
    vehicle is not flying (a vehicle sliding sideways at walking pace into a column it never saw). The allowance is
    the tracking error E_tr the contract carries: the swept corridor about the heading is r_body + E_tr wide, so a
    creep shorter than E_tr stays in what D_od judges (a velocity swinging past the field of view's edge while a
    turn's yaw catches up)."""

    def __init__(self):
        self._t = math.nan
        self.out_m = 0.0  # [m] crept out of view since the velocity last pointed into view (or the vehicle stopped)

    def bearing(self, t: float, vx: float, vy: float, yaw: float, in_view, allowance_m: float) -> float:
        """`in_view(beta)`: whether a fresh, trusted sensor looks along body bearing beta; a speed that is not
        finite (no telemetry) gives the heading."""
        dt = t - self._t if t > self._t else 0.0
        self._t = t
        speed = math.hypot(vx, vy)
        if not math.isfinite(speed) or speed <= CREEP_SPEED_M_S:
            self.out_m = 0.0
            return 0.0
        beta = wrap(math.atan2(vy, vx) - yaw)
        if speed > TRAVEL_SPEED_M_S or in_view(beta):
            self.out_m = 0.0
            return beta if speed > TRAVEL_SPEED_M_S else 0.0
        self.out_m += speed * dt
        return beta if self.out_m > allowance_m else 0.0


def swept_obstacle_m(hits, beta: float, half_width_m: float) -> float:
    """[m] the nearest hit in the swept corridor — the band of half-width `half_width_m` (r_body + E_tr) about the
    direction of travel `beta` (body frame) — whatever its shape. A bin's hit may lie anywhere in its sector
    (± its uncertainty): it counts where the sector's nearest bearing to the line of travel is inside the band, so a
    column whose surface enters the band is counted from any bin that sees that part of it (the ray towards a point
    of the surface inside the band meets the surface no farther, and no farther off the line). A single beam's hit
    is taken as on the path (its bearing is unknown within its field of view); a hit behind the line's normal counts
    by its range (inf: none)."""
    nearest = math.inf
    for b, r, h, bins in hits:
        if r >= nearest:
            continue
        off = abs((b - beta + math.pi) % (2 * math.pi) - math.pi)
        gap = max(off - h, 0.0)  # the sector's nearest bearing to the line of travel
        lateral = r * math.sin(gap) if gap < math.pi / 2 else r  # behind the line's normal: its range
        if not bins or lateral <= half_width_m:
            nearest = r
    return nearest


def stop_obstacle_m(hits, beta: float, ground_speed: float, half_width_m: float) -> float:
    """[m] the nearest obstacle the stop contract stops short of: the nearest hit in the swept corridor
    (`swept_obstacle_m`) about the direction of travel `beta`. At or below TRAVEL_SPEED_M_S (or an unknown speed)
    the direction of travel is not known — `beta` is the heading there, and near rest the cause, and the release of a
    stood-down one, must not come and go as the drift's bearing swings — so the nearest hit in any direction the
    sensors see: the stop distance from that speed
    is short, so only a thing close to the vehicle holds it, and a hit in the wider band is in this set too
    (inf: none)."""
    if not ground_speed > TRAVEL_SPEED_M_S:
        return min((r for _, r, _, _ in hits), default=math.inf)
    return swept_obstacle_m(hits, beta, half_width_m)
