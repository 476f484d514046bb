"""False alarms in clear air: what a perfect observer (the SITL's truth) calls unfounded, and the daemon-side rules
that kept a clear-air flight from being called unsafe (companion/ground/false_alarms.py)."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.onboard.config import config_from_dict
from companion.onboard.mavlink_in import MavlinkIn
from companion.onboard.samples import Implausible, Scan

SENSOR = mav.MAVLink(None, srcSystem=1, srcComponent=158)


def _decode(distances, inc_f):
    cfg = config_from_dict({"mode": "shadow", "sensors": [{"kind": "obstacle_distance", "h_fov_deg": 87}]})
    inp = MavlinkIn(cfg, None, lambda: 0.0, None)
    msg = mav.MAVLink_obstacle_distance_message(0, 0, list(distances), 0, 30, 1000, inc_f, -87.0 / 2 + inc_f / 2, 12)
    return inp.samples(0.0, "OBSTACLE_DISTANCE", msg)


def test_a_camera_of_87_degrees_in_17_bins_is_read_and_only_bins_in_use_are_judged():
    """A RealSense-class camera's 87° in 17 bins of 5.12°: 72 × 5.12° is past a circle, but the 55 bins after the
    17th are UINT16_MAX, "not used" (MAVLink common.xml OBSTACLE_DISTANCE); the 17 it uses span 87°."""
    inc = 87.0 / 17
    d = [1001] * 17 + [65535] * 55
    d[8] = 420  # straight ahead
    out = _decode(d, inc)
    assert not [s for s in out if isinstance(s, Implausible)]
    (scan,) = [s for s in out if isinstance(s, Scan)]
    assert scan.quality != 1 and len(scan.known) == 17
    assert [r for _, r in scan.hits] == [4.2] and abs(scan.hits[0][0]) < 1e-9


def test_bins_in_use_past_a_circle_are_still_refused():
    """Negative control: the same increment with bins in use up to the 72nd (368°, overlapping the first)."""
    inc = 87.0 / 17
    d = [1001] * 72
    out = _decode(d, inc)
    assert [s for s in out if isinstance(s, Implausible)]
    assert [s.quality for s in out if isinstance(s, Scan)] == [1]
