"""`quick_init` (companion/frozen.py): a frozen record built in one step is the one dataclasses builds — the same
fields in the same order, equal, as frozen, with defaults and default factories as dataclasses gives them."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import pytest

from companion.frozen import quick_init
from companion.outbox import Outbox
from companion.supervisor import Decision, Inputs


def _pair():
    def make():
        @dataclass(frozen=True)
        class Rec:
            a: float
            b: str = "x"
            c: dict = field(default_factory=dict)

        return Rec

    return make(), quick_init(make())


def test_a_quick_record_has_the_fields_defaults_and_factories_dataclasses_gives():
    plain, quick = _pair()
    for args, kw in (((1.0,), {}), ((1.0, "y"), {}), ((), {"a": 2.0, "c": {"k": 1}})):
        p, q = plain(*args, **kw), quick(*args, **kw)
        assert list(vars(p).items()) == list(vars(q).items())
        assert dataclasses.astuple(p) == dataclasses.astuple(q) and repr(p)[3:] == repr(q)[3:]
    assert quick(1.0).c is not quick(1.0).c  # a fresh dict each, as the factory gives
    assert quick(1.0) == quick(1.0) and hash(quick(1.0, "z", None)) == hash(quick(1.0, "z", None))
    assert dataclasses.replace(quick(1.0), b="w") == quick(1.0, "w")


def test_a_quick_record_is_still_frozen():
    _, quick = _pair()
    q = quick(1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        q.a = 2.0
    with pytest.raises(TypeError):
        quick()  # a field without a default is still required


def test_only_a_plain_frozen_dataclass_is_taken():
    @dataclass
    class Mutable:
        a: float

    @dataclass(frozen=True, slots=True)
    class Slotted:
        a: float

    for cls in (Mutable, Slotted):
        with pytest.raises(TypeError):
            quick_init(cls)


def test_the_cycle_records_are_still_frozen():
    for cls in (Inputs, Decision, Outbox):
        assert cls.__dataclass_params__.frozen
    with pytest.raises(dataclasses.FrozenInstanceError):
        Outbox().speed = 1.0
