"""Behaviour is kept: a fixed set of lock-step flights logs what it logged when recorded (tests/golden.py),
every state sample and event, field for field, floats to 1e-9."""

import pytest

from tests import golden


@pytest.mark.parametrize("name", [n for n in golden.FLIGHTS if n not in golden.FLOWN_ELSEWHERE])
def test_flight_logs_what_was_recorded(name):
    want = golden.load(name)
    got = golden.plain(golden.record(name))
    assert want["states"] and want["events"]
    assert golden.first_difference(want, got) is None


def test_the_flights_compared_elsewhere_are_compared_there():
    for name, path in golden.FLOWN_ELSEWHERE.items():
        assert f'difference("{name}", rig)' in (golden.DIR.parents[2] / path).read_text(), (name, path)


def test_the_comparison_sees_a_small_difference():  # the test above can fail
    want = golden.load("governor_px4_column")
    got = golden.load("governor_px4_column")
    s = next(s for s in got["states"] if isinstance(s.get("v_max"), float) and s["v_max"] > 0)
    s["v_max"] += 1e-6
    assert "v_max" in golden.first_difference(want, got)
    got = golden.load("governor_px4_column")
    got["events"].pop()
    assert "length" in golden.first_difference(want, got)
    got = golden.load("governor_px4_column")
    got["states"][3]["new_field"] = 1
    assert "keys" in golden.first_difference(want, got)
