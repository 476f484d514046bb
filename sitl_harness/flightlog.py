"""Autopilot flight-log writers for the SITL: an ArduPilot DataFlash `.bin` (`DataFlashWriter`), with the
messages and units of ArduPilot's log message documentation (ardupilot.org/copter/docs/logmessages.html),
so that the whole chain — flight, log, review — can be tested with known truth, and so that tests can make
damaged logs of a known shape.

The file format (ArduPilot AP_Logger, LogStructure.h): every message is `0xA3 0x95 <type>` then its
packed little-endian payload; `FMT` messages (type 128) first define each type's name, length, format
characters and column names. Format characters used here: B uint8, I uint32, Q uint64, f float,
N char[16], M uint8 flight mode.
"""

from __future__ import annotations

import struct
from pathlib import Path

HEAD = b"\xa3\x95"
FMT_TYPE = 128
STRUCT = {"B": "B", "I": "I", "Q": "Q", "f": "f", "N": "16s", "M": "B", "n": "4s", "Z": "64s", "i": "i", "h": "h"}

# name → (format, columns); a subset of each message's real columns, with the real names and units
MESSAGES = {
    "PARM": ("QNf", "TimeUS,Name,Value"),
    "MODE": ("QMBB", "TimeUS,Mode,ModeNum,Rsn"),
    "ARM": ("QBIB", "TimeUS,ArmState,ArmChecks,Method"),
    "EV": ("QB", "TimeUS,Id"),
    "XKF1": ("QBffffffffff", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD"),  # deg, m/s NED, m NED
    "XKF4": ("QBI", "TimeUS,C,SS"),  # SS: nav_filter_status bits (= EKF_STATUS_REPORT.flags)
    "ATT": ("Qffffff", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),  # deg
    "PSCN": ("Qffff", "TimeUS,TPN,PN,TVN,VN"),  # m, m/s (north)
    "PSCE": ("Qffff", "TimeUS,TPE,PE,TVE,VE"),  # m, m/s (east)
    "CTUN": ("Qfff", "TimeUS,ThI,ThO,ThH"),  # throttle in, out, hover estimate (0–1)
    "RFND": ("QBfBB", "TimeUS,Instance,Dist,Stat,Orient"),  # m; Orient: MAV_SENSOR_ORIENTATION
    "MSG": ("QZ", "TimeUS,Message"),  # text, e.g. the firmware version at boot
}


class DataFlashWriter:
    """Write a DataFlash log: `write(name, TimeUS, *values)` after `open`; `close()` at the end."""

    def __init__(self, path: str | Path, messages: dict | None = None):
        self.path = Path(path)
        self.messages = dict(MESSAGES if messages is None else messages)
        self._fh = open(self.path, "wb")
        self._types: dict[str, tuple[int, struct.Struct]] = {}
        fmt_struct = struct.Struct("<BB4s16s64s")
        self._fh.write(HEAD + bytes([FMT_TYPE]) + fmt_struct.pack(FMT_TYPE, 3 + fmt_struct.size, b"FMT", b"BBnNZ",
                                                                  b"Type,Length,Name,Format,Columns"))
        for k, (name, (fmt, cols)) in enumerate(self.messages.items()):
            st = struct.Struct("<" + "".join(STRUCT[c] for c in fmt))
            self._types[name] = (129 + k, st)
            self._fh.write(HEAD + bytes([FMT_TYPE]) + fmt_struct.pack(129 + k, 3 + st.size, name.encode(), fmt.encode(),
                                                                      cols.encode()))

    def write(self, name: str, *values) -> None:
        kind, st = self._types[name]
        vals = [v.encode() if isinstance(v, str) else v for v in values]
        self._fh.write(HEAD + bytes([kind]) + st.pack(*vals))

    def close(self) -> None:
        self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
