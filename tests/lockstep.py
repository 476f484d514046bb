"""Test rig: the daemon and a ground station on one lock-step SITL link, real MAVLink bytes both ways.

The rig is product code (`companion/ground/flights.py`, which the campaign flies too); re-exported here so the
tests keep their imports. There is one rig.
"""

from companion.ground.flights import Recorder, Rig, engage_and_fly, fly_mission, mav  # noqa: F401
