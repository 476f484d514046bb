"""Flat-earth geodesy about a reference point: north/east metres ↔ latitude/longitude. Pure maths.

ArduPilot's `Location::get_distance_NE` and `Location::offset` (libraries/AP_Common/Location.cpp): the
latitude difference times the radius, the longitude difference times the radius and the cosine of the
*mean* latitude of the two points; the two are exact inverses of each other. PX4's azimuthal-equidistant
`MapProjection` (src/lib/geo/geo.cpp) agrees within millimetres over a route's extent; the radius
(WGS-84 a here, ArduPilot 6378100 m, PX4 6371000 m) scales distances by at most 0.11 %.
"""

from __future__ import annotations

import math

R_EARTH_M = 6378137.0  # WGS-84 semi-major axis


def ne_from_geo(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    """North/east metres of (lat, lon) [deg] from (lat0, lon0) on the local tangent plane."""
    north = math.radians(lat - lat0) * R_EARTH_M
    dlon = (lon - lon0 + 180.0) % 360.0 - 180.0
    east = math.radians(dlon) * R_EARTH_M * math.cos(math.radians(0.5 * (lat + lat0)))
    return north, east


def geo_from_ne(north: float, east: float, lat0: float, lon0: float) -> tuple[float, float]:
    """(lat, lon) [deg] `north`, `east` metres from (lat0, lon0): the inverse of `ne_from_geo`."""
    lat = lat0 + math.degrees(north / R_EARTH_M)
    lon = lon0 + math.degrees(east / (R_EARTH_M * math.cos(math.radians(0.5 * (lat + lat0)))))
    if lon >= 180.0:
        lon -= 360.0
    elif lon < -180.0:
        lon += 360.0
    return lat, lon
