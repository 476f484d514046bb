"""One flat-earth geodesy for the daemon and the SITL (contracts.geodesy)."""

import math

import pytest

from contracts.geodesy import R_EARTH_M, geo_from_ne, ne_from_geo

LAT0, LON0 = 47.397742, 8.545594


@pytest.mark.parametrize("north,east", [(0.0, 0.0), (33.0, -30.0), (-800.0, 1200.0), (5000.0, 5000.0)])
def test_geo_from_ne_is_the_inverse_of_ne_from_geo(north, east):
    lat, lon = geo_from_ne(north, east, LAT0, LON0)
    assert ne_from_geo(lat, lon, LAT0, LON0) == pytest.approx((north, east), abs=1e-9)


def test_longitude_wraps_at_the_antimeridian():
    lat, lon = geo_from_ne(0.0, 2000.0, 0.0, 179.99)
    assert -180.0 <= lon < -179.99
    n, e = ne_from_geo(lat, lon, 0.0, 179.99)
    assert (n, e) == pytest.approx((0.0, 2000.0), abs=1e-6)
    assert math.radians(0.01) * R_EARTH_M < 2000.0
