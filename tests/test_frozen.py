"""The records the daemon's cycle builds every loop period are frozen: a part of the daemon that is handed one
cannot rewrite it for the others (a changed copy is made with `dataclasses.replace`)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from companion.onboard.authority import ModeView
from companion.onboard.detection_range import DetectionRangeEstimate
from companion.onboard.estimators import DodEstimate
from companion.onboard.outbox import Outbox
from companion.onboard.states import State
from companion.onboard.supervisor import Decision, Inputs
from contracts.table import Omega

DOD = DodEstimate(8.0, (0,), math.inf, None, "test")
RECORDS = [
    Inputs(t=0.0, link_ok=True, telemetry_ok=True, nav_ok=True, armed=True, in_air=True, mode="mission",
           limit_applies=True, mode_by_daemon=False, ground_speed=3.0, dod=DOD, e_tr_measured=0.3, thrust_ratio=2.0,
           r_obst=0.5, engaged=True),
    Decision(State.ACTIVE, Omega("avoid", 3.0, 0.3, 0.3, 3.5, -0.5), 3.0),
    DOD,
    ModeView("mission", False, False),
    Outbox(speed=3.0),
    DetectionRangeEstimate(8.0, 8.0, 1.0, 0.0, "test"),
]


@pytest.mark.parametrize("rec", RECORDS, ids=lambda r: type(r).__name__)
def test_a_cycle_record_cannot_be_rewritten(rec):
    name = dataclasses.fields(rec)[0].name
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(rec, name, None)
    with pytest.raises((AttributeError, TypeError)):
        rec.not_a_field = 1  # no room for anything but its fields


@pytest.mark.parametrize("rec", RECORDS, ids=lambda r: type(r).__name__)
def test_a_changed_copy_is_made_with_replace(rec):
    name = dataclasses.fields(rec)[0].name
    copy = dataclasses.replace(rec, **{name: "changed"})
    assert getattr(copy, name) == "changed" and getattr(rec, name) != "changed"
    assert dataclasses.replace(rec) == rec


def test_a_default_factory_gives_each_record_its_own():
    a, b = (DetectionRangeEstimate(8.0, 8.0, 1.0, 0.0, "test") for _ in range(2))
    assert a.evidence == {} and a.evidence is not b.evidence
