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


# ------------------------------------------------------------------ a hovering camera that drops its centre bin
def _hover_with_a_dropped_centre_bin(monkeypatch=None, start_m=None):
    """A 17-bin camera (5°) hovering, its position drifting 1 mm back a frame; every bin free for 1 s, then one
    frame without the centre bin (UINT16_MAX: unknown). D_od along the heading then."""
    from companion.onboard import estimators
    from companion.onboard.config import ContractConfig, SensorConfig
    from companion.onboard.mavlink_in import bins_scan

    if start_m is not None:
        monkeypatch.setattr(estimators, "SWEPT_START_M", start_m)
    cam = SensorConfig(kind="obstacle_distance", h_fov_deg=85.0, max_range_m=10.0)
    e = estimators.DodEstimator([cam], ContractConfig(), stale_s=0.5, cover=False)
    inc = math.radians(5.0)
    bearings = (np.arange(17) - 8) * inc
    t = 0.0
    for k in range(31):
        t = k / 30.0
        e.add_position(t, -0.001 * k, 0.0)
        e.add_heading(t, 0.0)
        keep = np.ones(17, bool) if k < 30 else np.arange(17) != 8
        e.add_scan(bins_scan(t, 0, bearings[keep], np.full(keep.sum(), np.inf), 10.0, inc, 10.0))
        est = e.estimate(t, 0.0)
    return est


def test_a_hovering_camera_that_drops_its_centre_bin_keeps_what_it_just_saw_free():
    """A dropped bin is unknown, not free: D_od along it is what the last frames saw free (the swept coverage,
    less its position margin), not zero — zero is a "no safe speed" stop on one bin of one frame in clear air."""
    est = _hover_with_a_dropped_centre_bin()
    assert est.swept and 9.5 < est.d_od < 10.0


def test_negative_control_a_chain_that_must_start_at_the_centre_leaves_a_drifting_hover_nothing(monkeypatch):
    est = _hover_with_a_dropped_centre_bin(monkeypatch, start_m=0.0)
    assert est.d_od == 0.0


def test_the_swept_chain_starts_only_within_start_m_and_joins_no_gap_beyond_it():
    from contracts.coverage import covered_distance

    wedge = np.array([(0.03, 0.0, -0.3, 0.3, 5.0)])  # seen from 3 cm ahead
    assert covered_distance((0.0, 0.0), 0.0, wedge) == 0.0
    assert abs(covered_distance((0.0, 0.0), 0.0, wedge, start_m=0.05) - 5.03) < 1e-9
    assert covered_distance((0.0, 0.0), 0.0, np.array([(0.08, 0.0, -0.3, 0.3, 5.0)]), start_m=0.05) == 0.0
    two = np.array([(0.03, 0.0, -0.3, 0.3, 2.0), (2.06, 0.0, -0.3, 0.3, 3.0)])  # a 3 cm break at 2.03 m
    assert abs(covered_distance((0.0, 0.0), 0.0, two, start_m=0.05) - 2.03) < 1e-9
