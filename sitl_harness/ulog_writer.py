"""A PX4 ULog (`.ulg`) file writer, per the ULog File Format spec (docs.px4.io/main/en/dev_log/ulog_file_format):
little-endian; a 16-byte header (magic `ULog\\x01\\x12\\x35`, version 1, uint64 start time in µs); then
messages, each `uint16 msg_size, uint8 msg_type` and its payload:

- Definitions: `B` flag bits (first; 8 compat + 8 incompat flag bytes, 3 uint64 appended offsets), `F` format
  (`"name:type field;type field;..."`), `I` info (`uint8 key_len`, `"type name"`, value bytes), `P` parameter
  (as `I`; `float` or `int32_t`).
- Data: `A` add-logged (`uint8 multi_id, uint16 msg_id, name`), `D` data (`uint16 msg_id`, the packed
  fields), `L` logged string (`uint8 level` ('0'..'7'), `uint64 timestamp`, text), and `P` for a parameter
  changed in flight.

No alignment padding is written (the spec allows any layout; `pyulog` reads it). pyulog 1.3 has a writer
only for a ULog it has read, so this one is our own; it is checked by reading back with pyulog.
"""

from __future__ import annotations

import struct
from pathlib import Path

MAGIC = b"ULog\x01\x12\x35\x01"
TYPES = {"int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i", "uint32_t": "I",
         "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d", "bool": "?", "char": "c"}


def _fields(spec: str) -> list[tuple[str, int, str]]:
    """"uint64_t timestamp;float[4] q" → [(struct char, count, name), …]."""
    out = []
    for item in filter(None, (s.strip() for s in spec.split(";"))):
        typ, name = item.split()
        n = 1
        if "[" in typ:
            typ, n = typ[:-1].split("[")
            n = int(n)
        out.append((TYPES[typ], n, name))
    return out


class ULogWriter:
    """`define(name, spec)` each topic (before the first `add`), `info`/`param` definitions, then
    `add(name, multi_id) → msg_id` and `data(msg_id, values)`; `close()`."""

    def __init__(self, path: str | Path, start_us: int = 0):
        self.path = Path(path)
        self._fh = open(self.path, "wb")  # noqa: SIM115 — open for the whole flight, closed by close()
        self._fh.write(MAGIC + struct.pack("<Q", start_us))
        self._msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
        self._formats: dict[str, list] = {}
        self._structs: dict[int, tuple[struct.Struct, list]] = {}
        self._next_id = 0
        self._in_data = False

    def _msg(self, kind: bytes, payload: bytes) -> None:
        self._fh.write(struct.pack("<HB", len(payload), kind[0]) + payload)

    def define(self, name: str, spec: str) -> None:
        """A topic's format; `spec` in the spec's own `"type field;…"` form, `uint64_t timestamp` first."""
        self._formats[name] = _fields(spec)
        self._msg(b"F", f"{name}:{spec.rstrip(';')};".encode())

    @staticmethod
    def _kv(typ: str, name: str, value) -> bytes:
        if typ.startswith("char"):
            raw = str(value).encode()
            key = f"char[{len(raw)}] {name}".encode()
        else:
            raw = struct.pack("<" + TYPES[typ], value)
            key = f"{typ} {name}".encode()
        return bytes([len(key)]) + key + raw

    def info(self, name: str, value, typ: str = "char") -> None:
        self._msg(b"I", self._kv(typ, name, value))

    def param(self, name: str, value, integer: bool = False) -> None:
        """A parameter (`int32_t` or `float`): initial before the data, a change during it."""
        self._msg(b"P", self._kv("int32_t" if integer else "float", name, int(value) if integer else float(value)))

    def add(self, name: str, multi_id: int = 0) -> int:
        fields = self._formats[name]
        msg_id = self._next_id
        self._next_id += 1
        self._structs[msg_id] = (struct.Struct("<" + "".join(f"{n}{c}" for c, n, _ in fields)), fields)
        self._msg(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())
        self._in_data = True
        return msg_id

    def data(self, msg_id: int, values: dict) -> None:
        """One sample: `values[field]` (a sequence for an array field; a missing field is 0)."""
        st, fields = self._structs[msg_id]
        flat = []
        for c, n, name in fields:
            v = values.get(name, 0)
            if n == 1:
                flat.append(v)
            else:
                v = list(v) if not isinstance(v, (int, float)) else [v] * n
                flat.extend((v + [0] * n)[:n])
        self._msg(b"D", struct.pack("<H", msg_id) + st.pack(*flat))

    def log(self, t_us: int, text: str, level: int = 6) -> None:
        """A logged string (`L`; level as syslog: 6 INFO, 4 WARNING, 2 CRITICAL)."""
        self._msg(b"L", bytes([ord("0") + level]) + struct.pack("<Q", t_us) + text.encode()[:200])

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()
