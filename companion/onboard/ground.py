"""Where a body-fixed sensor's lowest ray meets the ground: the range its claim holds to. Pure maths.

A sensor fixed to the airframe (`sensors[k].v_fov_deg` set: each reading the nearest over that many degrees of
elevation, the lowest ray half of it below the sensor's axis, the axis pitched up by `mount_pitch_deg`) pitches
with the vehicle. Nose-down to accelerate, or low over the ground, its lowest ray meets the ground within its
rated range: every reading beyond that is the ground's, and nothing farther is seen. The ground is not an
obstacle, nor evidence of a medium, nor a target first seen late; it is where the sensor stops looking. So the
range the sensor claims is capped at the nearest place, over the bins it uses, where a ray of theirs meets flat
ground within that range at the vehicle's altitude above its local origin (the take-off point), less three σ of
the configured range noise there (`detection_range.RangeNoise`): a ground return is beyond the claim, and a return
nearer than it is what it always was — an obstacle. The attitude is taken at its worst over the last moments (a
frame is taken some time before it arrives: `telemetry.ATTITUDE_WINDOW_S`) and `attitude_error_deg` more
nose-down and rolled still (the estimate's error); the ground is assumed flat and level with the origin.

A ray at body azimuth a (clockwise from forward) and elevation −h (below the axis) of a sensor pitched up by m has
the body direction (cos h cos(a)·cos m + sin h·sin m, cos h sin a, sin h cos m − cos h cos(a)·sin m) (x forward,
y right, z down); its downward component in the local frame after roll φ and pitch θ (ZYX Euler, ATTITUDE's) is
−sin θ·x + sin φ cos θ·y + cos φ cos θ·z, and it meets the ground at altitude / that component.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .detection_range import RangeNoise


def ray_down(azimuth: float, h: float, mount_pitch: float, roll: float, pitch: float) -> float:
    """The downward component (local frame) of the unit ray at body `azimuth` and `h` below a sensor's axis pitched
    up by `mount_pitch`, the vehicle at `roll`, `pitch` [rad] (module docstring)."""
    ca, sa, ch, sh = math.cos(azimuth), math.sin(azimuth), math.cos(h), math.sin(h)
    x = ch * ca * math.cos(mount_pitch) + sh * math.sin(mount_pitch)
    y = ch * sa
    z = sh * math.cos(mount_pitch) - ch * ca * math.sin(mount_pitch)
    return -math.sin(pitch) * x + math.sin(roll) * math.cos(pitch) * y + math.cos(roll) * math.cos(pitch) * z


def ground_range_m(altitude: float, azimuths: Sequence[float], half_width: float, v_fov: float,
                   mount_pitch: float, rolls: tuple[float, float], pitch: float, error: float,
                   factors: Sequence[float] | None = None) -> float:
    """[m] the nearest range at which a ray of the bins centred at body `azimuths` (each `half_width` either side)
    meets the ground, each bin's times its `factor` (the least a ground return there can read as, over its true
    range: 1 for a range, less for an axis depth read as the least range it allows; inf: no ray meets the ground).
    Each bin's edges and centre, at the bottom of the field of view, with the attitude anywhere in the span the
    frame may have been taken at (`rolls`: least and most roll; `pitch`: the most nose-down) and `error` [rad]
    worse. An altitude not known (nan) or at or below the ground: 0, the sensor may be looking at it anywhere."""
    if not altitude > 0.0:
        return 0.0
    h = 0.5 * v_fov
    nearest = math.inf
    for k, a in enumerate(azimuths):
        down = 0.0
        for e in (a - half_width, a, a + half_width):
            for roll in (rolls[0] - error, rolls[1] + error):
                down = max(down, ray_down(e, h, mount_pitch, roll, pitch - error))
        if down > 0.0:
            nearest = min(nearest, altitude / down * (1.0 if factors is None else factors[k]))
    return nearest


def ground_claim_m(claim: float, ground_m: float, noise: RangeNoise) -> float:
    """The sensor's claim [m] capped where the ground is in view, within it: three σ of range noise short of the
    ground (never negative). Ground beyond the claim is not reported at all (a sensor reports no return beyond its
    rated range)."""
    if ground_m > claim or math.isinf(ground_m):
        return claim
    return max(0.0, ground_m - noise.short_m(ground_m))
