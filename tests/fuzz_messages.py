"""A seeded generator of well-formed MAVLink messages with hostile field values, of every type the daemon
decodes — for the fuzz test (tests/test_fuzz_link.py, a small count) and benchmarks/bench_fuzz.py (≥ 1 M).

Each field takes, by its MAVLink type, one of the values an attacker or a broken sensor would send:
non-finite and huge floats, the integer type's extremes, zero, or a random value; arrays element by element.
"""

from __future__ import annotations

import math
import os

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

# every message type the daemon decodes (companion/onboard/mavlink_in.py), and who sends it
DECODED = {
    "HEARTBEAT": (1, 1), "LOCAL_POSITION_NED": (1, 1), "ATTITUDE": (1, 1), "POSITION_TARGET_LOCAL_NED": (1, 1),
    "VFR_HUD": (1, 1), "EXTENDED_SYS_STATE": (1, 1), "ESTIMATOR_STATUS": (1, 1), "EKF_STATUS_REPORT": (1, 1),
    "SYSTEM_TIME": (1, 1), "MISSION_CURRENT": (1, 1), "COMMAND_ACK": (1, 1), "PARAM_VALUE": (1, 1),
    "MISSION_COUNT": (1, 1), "MISSION_ITEM_INT": (1, 1), "HOME_POSITION": (1, 1),
    "DISTANCE_SENSOR": (1, 1), "OBSTACLE_DISTANCE": (1, 1),  # as PX4 and ArduPilot forward them: the configured source
    "PARAM_SET": (255, 190), "PARAM_REQUEST_READ": (255, 190), "PARAM_REQUEST_LIST": (255, 190),
}
# fields whose non-finite value MAVLink-in must find implausible (the vehicle's state)
VALIDATED = {"LOCAL_POSITION_NED": ("x", "y", "z", "vx", "vy", "vz"), "ATTITUDE": ("roll", "pitch", "yaw"),
             "POSITION_TARGET_LOCAL_NED": ("x", "y")}
HOSTILE_FLOATS = (math.nan, math.inf, -math.inf, 1e30, -1e30, 3.4e38, 0.0, -0.0, 1e-30)
INT_RANGE = {"int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-2 ** 15, 2 ** 15 - 1), "uint16_t": (0, 65535),
             "int32_t": (-2 ** 31, 2 ** 31 - 1), "uint32_t": (0, 2 ** 32 - 1), "int64_t": (-2 ** 63, 2 ** 63 - 1),
             "uint64_t": (0, 2 ** 64 - 1)}


def _cls(name: str):
    return mav.mavlink_map[getattr(mav, f"MAVLINK_MSG_ID_{name}")]


def _value(rng: np.random.Generator, ftype: str):
    if ftype in ("float", "double"):
        return float(HOSTILE_FLOATS[rng.integers(len(HOSTILE_FLOATS))]) if rng.random() < 0.6 \
            else float(rng.normal(0, 10.0 ** rng.integers(0, 7)))
    if ftype == "char":
        return bytes(rng.integers(32, 127, size=int(rng.integers(0, 17))).astype(np.uint8))
    lo, hi = INT_RANGE[ftype]
    r = rng.random()
    return lo if r < 0.2 else hi if r < 0.4 else 0 if r < 0.5 else int(rng.integers(lo, hi, endpoint=True, dtype=np.uint64)
                                                                      if lo >= 0 else rng.integers(lo, hi))


def hostile_message(rng: np.random.Generator, name: str | None = None):
    """(message, (system, component), whether a validated field is not finite)."""
    name = name or list(DECODED)[rng.integers(len(DECODED))]
    cls = _cls(name)
    args = []
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))  # array lengths are in wire order
    for fname, ftype in zip(cls.fieldnames, cls.fieldtypes):
        n = lengths[fname]
        if ftype == "char" and n:
            args.append(_value(rng, "char")[:n])
        elif n:
            args.append([_value(rng, ftype) for _ in range(n)])
        else:
            args.append(_value(rng, ftype))
    msg = cls(*args)
    bad = any(not math.isfinite(getattr(msg, f)) for f in VALIDATED.get(name, ()))
    if name == "POSITION_TARGET_LOCAL_NED" and msg.type_mask & 3:
        bad = False  # the position is flagged as unused: it may be NaN
    return msg, DECODED[name], bad


def packed(rng: np.random.Generator, encoders: dict, name: str | None = None):
    """The bytes of one hostile message, packed by its sender's encoder (`encoders` caches them)."""
    msg, src, bad = hostile_message(rng, name)
    enc = encoders.setdefault(src, mav.MAVLink(None, srcSystem=src[0], srcComponent=src[1]))
    return msg.pack(enc), msg.get_type(), bad
