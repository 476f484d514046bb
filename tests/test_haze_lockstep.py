"""Haze in lock-step: the real daemon (governor, PX4) against the real SITL over real MAVLink bytes, the SITL's range
sensor read as one DISTANCE_SENSOR (the nearest return of its 12 bins of 5°), hidden haze of 200 m meteorological
visibility from the start (α = 3.912 / 200 m: the default target seen to 13 m, past the sensor's 8 m).

Such haze shortens no range, so the detection range from evidence must cost nothing: D_od stays the stated range and
the route is flown as in clear air — when the sensor's 12 shots a frame are counted as 12 (`shots_per_frame`). Counted
as one shot a frame (the reading when the configuration does not say), the same flight cuts D_od and slows down.

The medium's own returns reach the obstacle logic in the daemon as flown, and one of them inside the stop distance
holds the governor whatever D_od is (docs/detection-range.md); these flights withhold them from it
(`hide_the_medium`, a negative-control setting the daemon never flies) to show what D_od's evidence does."""

from __future__ import annotations

import numpy as np
import pytest

from contracts.lidar import REFERENCE_REFLECTIVITY, extinction_from_met_visibility, visibility_for_extinction
from tests.lockstep import Rig, fly_mission
from tests.test_detection_range import hide_the_medium

RANGE_M = 8.0
SECONDS = 14.0


def scenario(haze: bool) -> dict:
    vis = visibility_for_extinction(extinction_from_met_visibility(200.0), REFERENCE_REFLECTIVITY, RANGE_M)
    return {"name": "haze", "vehicle": "mambo", "seed": 4,
            "world": {"columns": [{"x_m": 400.0, "y_m": 0.0, "radius_m": 0.5, "name": "far"}]},
            "sensor": {"fov_deg": 60, "increment_deg": 5, "max_range_m": RANGE_M, "rate_hz": 20},
            "route": {"altitude_m": 2.0, "cruise_speed_m_s": 8.0, "waypoints": [[0, 0], [300, 0]]},
            "faults": [{"at_s": 0.0, "fog": {"visibility_m": vis, "report": "hidden"}}] if haze else []}


def flight(haze: bool, shots_per_frame: int | None) -> dict:
    sensor = {"kind": "distance_sensor", "h_fov_deg": 60,
              **({} if shots_per_frame is None else {"shots_per_frame": shots_per_frame})}
    rig = Rig(scenario(haze), "px4", config={"sensors": [sensor]})
    hide_the_medium(rig.daemon.cycle)
    fly_mission(rig, SECONDS)
    states = [x for x in rig.log.states if x.get("engaged") and x["t"] >= 3.0]
    return {"d_od": np.array([x["d_od"] for x in states]), "stated": np.array([x["d_od_stated"] for x in states]),
            "x": float(rig.sim.model.pos[0]), "collisions": rig.truth["collisions"]}


@pytest.fixture(scope="module")
def clear():
    return flight(False, 12)


def test_haze_costs_nothing_when_each_frame_counts_its_shots(clear):
    hazy = flight(True, 12)
    assert not hazy["collisions"]
    assert np.all(hazy["d_od"] == hazy["stated"]) and np.all(hazy["stated"] == RANGE_M)
    assert hazy["x"] == pytest.approx(clear["x"], rel=0.02)  # the same distance flown as in clear air


def test_negative_control_one_shot_per_frame_reads_the_haze_as_fog(clear):
    hazy = flight(True, None)
    ratio = hazy["d_od"] / hazy["stated"]
    assert np.mean(ratio < 1.0) > 0.25 and ratio.min() < 0.5  # measured: 47 % of the samples, down to 0.29
    assert hazy["x"] < 0.8 * clear["x"]  # measured: 21.5 m against 38.3 m
