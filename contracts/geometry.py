"""Plane geometry shared by the daemon, its estimators and the harness (angles in radians)."""

from __future__ import annotations

import math


def wrap(a: float) -> float:
    """Angle to (−π, π]."""
    return math.atan2(math.sin(a), math.cos(a))


def wrap_array(a):
    """Angles (an array) to [−π, π)."""
    return (a + math.pi) % (2 * math.pi) - math.pi
