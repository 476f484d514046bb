"""The autopilots the daemon knows: one adapter class each (px4.py, ardupilot.py), found by the config's
name or by HEARTBEAT.autopilot. A third autopilot is one module with an `Adapter` subclass and one line here."""

from __future__ import annotations

from .ardupilot import ArduPilot
from .autopilot_base import Adapter
from .px4 import PX4

ADAPTERS: dict[str, type[Adapter]] = {a.name: a for a in (PX4, ArduPilot)}


def adapter_for(name: str) -> Adapter:
    """The adapter of an autopilot by config name (`px4`, `ardupilot`)."""
    return ADAPTERS[name]()


def name_for_heartbeat(autopilot_id: int) -> str | None:
    """The config name of the autopilot a HEARTBEAT.autopilot value stands for (None: not one we know)."""
    return next((n for n, a in ADAPTERS.items() if a.autopilot_id == autopilot_id), None)
