"""The event log: JSON Lines, append-only, crash-safe, never raises into the control loop (DESIGN.md §5).

Files in the log directory:

- `events.jsonl` — the current file; rotated by size to `events.1.jsonl` (newest) … `events.<keep>.jsonl`
  (oldest), so the set holds at most `keep + 1` files. `read_events(dir)` reads it oldest first.
- `raw.tlog` (with `tlog=True`) — raw MAVLink as MAVProxy/QGroundControl write it: per packet an
  8-byte big-endian UNIX time in µs, then the packet bytes (`pymavlink.mavutil.mavlink_connection`
  reads it back). A new process starts a new `raw.tlog` (the previous one is rotated to `raw.1.tlog`),
  so a packet torn by a crash never misaligns the next run's packets.

Record schema (one JSON object per line; every name is defined in `companion/onboard/logschema.py`):

    {"kind": "state", "t": 12.34, "wall": 1790000000.123, "seq": 17, "boot": "3f9c0a1b2d4e", ...fields}
    {"kind": "event", "t": 12.36, "wall": ..., "seq": 18, "boot": ..., "event": "violation_start", ...fields}

- `t` vehicle/sim time [s] as passed in; `wall` UNIX time [s] from the injected wall clock;
- `seq` counts every record of this process from 0 (a gap in `seq` within one `boot` means lost records);
- `boot` a random id per `EventLog` instance (a new id per daemon start);
- non-finite floats (NaN, ±inf) anywhere in a record are written as `null` and their dotted names listed
  in `"nonfinite"` (e.g. `["d_od", "params.v"]`), so every line is strict JSON (RFC 8259);
- numpy scalars and arrays are written as plain numbers and lists; any other object as its `str()`;
- a field named like a reserved key (`kind t wall seq boot event nonfinite`) is stored with a trailing
  underscore (`seq_`) instead of overwriting it.

The log writes two events of its own: `log_open` (pid, `torn_tail` when the previous run's last line
was cut, which is then ended with a newline so the new run starts on a fresh line) and `log_recovered`
(after a write failure: how many records were dropped and the first error).

Durability, by `commit`: `"event"` (the default) — `event()` writes and fsyncs at once (with any buffered state
samples before it) and returns True only when the record is on disk; `"none"` — handed to the OS, never fsync'd
(a log replay's); `"cycle"` (the daemon's log) — `event()` hands the record to the OS at once and `tick()`, once a
cycle, fsyncs all of the cycle's events together: a cycle that logs five events pays one fsync, not five (each
took 2–5 ms on a loaded 2-core host, enough together to make the next cycle late). `state()` only encodes and
buffers; the buffer goes to the OS at least every `flush_s` (default 1 s, checked on each call), on the next event,
or when it holds `buffer_bytes`. After `kill -9` everything handed to the OS survives; after a power cut, everything
up to the last fsync (the last event, or with `commit="cycle"` the last cycle's events, or the last rotation/close).

Failure handling: no method raises. A full disk (ENOSPC), a read-only or vanished directory or a failed
fsync is counted (`write_errors`), the unwritten records stay pending (up to `pending_bytes`; beyond
that, state samples are dropped first, then the oldest events; counted in `dropped_records`), and the
next flush retries (re-creating the directory and reopening the file). A partially written batch is cut
back to its last whole line (`ftruncate`), so a disk-full episode leaves no broken line behind.
`healthy` is False from a failure until a later write succeeds. The calls are synchronous: a disk that
*hangs* (rather than fails) stalls the caller; the daemon's watchdog covers that case.

Thread-safe (one lock; `raw()` may come from the link-reader thread while the loop calls `state()`).
One process per directory: two writers would interleave their rotations.
"""

from __future__ import annotations

import errno
import json
import math
import os
import struct
import threading
import time
import uuid
from itertools import repeat
from pathlib import Path
from typing import Callable, Iterable, Iterator

from .logschema import LOG_NAME, LOG_SUFFIX, RECORD_KEYS

TLOG_NAME = "raw"
TLOG_SUFFIX = ".tlog"
RESERVED = frozenset(RECORD_KEYS)
_SEP = (",", ":")
_FLAT = (str, int, float, type(None))  # a flat record's value types, subclasses too (a StrEnum, bool; `encode_record`)


def sparse(n: int) -> bool:
    """Whether the n-th of a repeated fault is logged: the 1st, 10th, 100th and every 1000th."""
    return n in (1, 10, 100) or n % 1000 == 0


# ============================================================================ encoding (pure)


def _default(obj):
    """json fallback: numpy scalars/arrays as plain values, sets as lists, anything else as its str()."""
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        try:
            return tolist()
        except Exception:  # noqa: BLE001 — an odd object must not stop the log
            pass
    if isinstance(obj, (set, frozenset)):
        return sorted(obj, key=str)
    return str(obj)


def finite_copy(obj, path: str = "", bad: list[str] | None = None, depth: int = 0):
    """A copy of `obj` with non-finite floats replaced by None (their dotted paths appended to `bad`)."""
    bad = [] if bad is None else bad
    if depth > 32:
        return str(obj)
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        bad.append(path)
        return None
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, dict):
        return {str(k): finite_copy(v, f"{path}.{k}" if path else str(k), bad, depth + 1) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_copy(v, f"{path}[{i}]", bad, depth + 1) for i, v in enumerate(obj)]
    converted = _default(obj)
    if converted is obj or isinstance(converted, str):
        return converted
    return finite_copy(converted, path, bad, depth + 1)


def encode_record(rec: dict) -> str:
    """One strict-JSON line (with the newline) for a record; never raises.

    Fast path: `json.dumps(allow_nan=False)`; only a record that holds NaN/inf (or an object json cannot
    encode) takes the slow path that writes them as null and lists them in `"nonfinite"`. A flat record (str
    keys; str, int, float, bool or None values, or of their subclasses such as a `State`: every state sample)
    holding NaN/inf — a state sample with no obstacle in sight has `obstacle_m` inf — is cleaned in one pass and
    encoded once, to the same line.
    """
    nonfinite = [k for k, v in rec.items() if isinstance(v, float) and not math.isfinite(v)]
    if nonfinite and set(map(type, rec)) == {str} and all(map(isinstance, rec.values(), repeat(_FLAT))):
        clean = {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in rec.items()}
        clean["nonfinite"] = nonfinite
        return json.dumps(clean, allow_nan=False, separators=_SEP) + "\n"
    try:
        return json.dumps(rec, allow_nan=False, separators=_SEP, default=_default) + "\n"
    except (ValueError, TypeError, RecursionError):
        pass
    try:
        bad: list[str] = []
        clean = finite_copy(rec, "", bad)
        if bad:
            clean["nonfinite"] = bad
        return json.dumps(clean, allow_nan=False, separators=_SEP, default=str) + "\n"
    except Exception as err:  # noqa: BLE001 — last resort: keep the header, say why
        head = {k: rec.get(k) for k in ("kind", "seq", "boot", "event") if isinstance(rec.get(k), (str, int))}
        head["encode_error"] = f"{type(err).__name__}: {err}"
        return json.dumps(head, separators=_SEP) + "\n"


def _record(kind: str, t, wall: float, seq: int, boot: str, event: str | None, fields: dict) -> dict:
    rec = {"kind": kind, "t": t, "wall": wall, "seq": seq, "boot": boot}
    if event is not None:
        rec["event"] = event
    if fields:
        if RESERVED.isdisjoint(fields):
            rec.update(fields)
        else:
            for k, v in fields.items():
                rec[k + "_" if k in RESERVED else k] = v
    return rec


# ============================================================================ file set


def rotated_name(stem: str, suffix: str, index: int) -> str:
    """`events.jsonl` for index 0, `events.3.jsonl` for index 3."""
    return f"{stem}{suffix}" if index == 0 else f"{stem}.{index}{suffix}"


def _index_of(name: str, stem: str, suffix: str) -> int | None:
    """0 for `events.jsonl`, 3 for `events.3.jsonl`, None for any other name."""
    if not (name.startswith(stem + ".") and name.endswith(suffix)):
        return None
    middle = name[len(stem) : len(name) - len(suffix)]
    if middle == "":
        return 0
    digits = middle[1:]
    return int(digits) if middle[0] == "." and digits.isdigit() and digits.isascii() else None


def file_set(directory: str | Path, stem: str = LOG_NAME, suffix: str = LOG_SUFFIX) -> list[Path]:
    """The rotated set in a directory, oldest first (`events.N.jsonl` … `events.1.jsonl`, `events.jsonl`)."""
    directory = Path(directory)
    try:
        names = os.listdir(directory)
    except OSError:
        return []
    found = [(i, directory / n) for n in names if (i := _index_of(n, stem, suffix)) is not None]
    return [p for _, p in sorted(found, key=lambda x: -x[0])]


class _AppendFile:
    """One size-rotated, append-only file.

    `write()` raises `WriteFailed` carrying how many bytes of the batch are in the file (whole lines for
    the JSON log, because a partial write is cut back), so the caller re-sends only the rest.
    """

    def __init__(self, directory: Path, stem: str, suffix: str, max_bytes: int, keep: int, fresh: bool):
        self.directory, self.stem, self.suffix = directory, stem, suffix
        self.path = directory / rotated_name(stem, suffix, 0)
        self.max_bytes, self.keep = max(int(max_bytes), 1), max(int(keep), 0)
        self.fresh = fresh  # rotate an existing non-empty file away on the first open (tlog)
        self.lines = suffix == LOG_SUFFIX  # a line-oriented file: split batches and repair torn tails
        self.fd: int | None = None
        self.size = 0
        self.ident: tuple[int, int] | None = None
        self.torn_tail = False  # the file we opened ended without a newline
        self.last_fsync_s = 0.0
        self.max_fsync_s = 0.0

    # ---------------------------------------------------------------- open / close

    def _open(self) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        if self.fresh:
            self.fresh = False
            try:
                if self.path.stat().st_size > 0:
                    self._rotate_files()
            except FileNotFoundError:
                pass
        fd = os.open(self.path, os.O_RDWR | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o640)
        try:
            st = os.fstat(fd)
            self.size, self.ident = st.st_size, (st.st_dev, st.st_ino)
            if self.lines and self.size > 0 and os.pread(fd, 1, self.size - 1) != b"\n":
                os.write(fd, b"\n")  # a torn last line (kill -9, power cut): start on a fresh line
                self.size += 1
                self.torn_tail = True
        except BaseException:
            os.close(fd)
            raise
        self.fd = fd

    def close(self, sync: bool = True) -> None:
        fd, self.fd = self.fd, None
        if fd is None:
            return
        try:
            if sync:
                os.fsync(fd)
        finally:
            os.close(fd)

    def _still_ours(self) -> bool:
        """False when the file was removed or replaced under us (directory deleted, external rotation)."""
        try:
            st = os.stat(self.path)
        except OSError:
            return False
        return (st.st_dev, st.st_ino) == self.ident

    def _rotate_files(self) -> None:
        """events.jsonl → events.1.jsonl → … ; files beyond `keep` are deleted (one listdir, no stat chain)."""
        for path in file_set(self.directory, self.stem, self.suffix):  # oldest (highest index) first
            i = _index_of(path.name, self.stem, self.suffix)
            if i >= self.keep:
                path.unlink()
            else:
                os.replace(path, self.directory / rotated_name(self.stem, self.suffix, i + 1))
        _fsync_dir(self.directory)

    def _rotate(self) -> None:
        self.close(sync=True)
        self._rotate_files()
        self._open()

    # ---------------------------------------------------------------- writing

    def ensure_open(self, check: bool) -> None:
        """Open if closed; with `check`, reopen when the file vanished or was replaced."""
        if self.fd is not None and check and not self._still_ours():
            try:
                self.close(sync=False)
            except OSError:
                pass
        if self.fd is None:
            self._open()

    def write(self, data: bytes, sync: bool, check: bool) -> None:
        """Append `data`, rotating at line boundaries (JSON log) so no file exceeds `max_bytes` unless a
        single line does; fsync with `sync`. Raises `WriteFailed` saying how much of `data` is in the file."""
        done = 0
        try:
            self.ensure_open(check)
            while done < len(data):
                end = len(data)
                room = self.max_bytes - self.size
                if end - done > room:
                    cut = data.rfind(b"\n", done, done + room) + 1 if self.lines and room > 0 else 0
                    if cut > done:
                        end = cut
                    elif self.size > 0:
                        self._rotate()
                        continue
                    elif self.lines:  # one line longer than max_bytes: it goes whole into an empty file
                        end = data.find(b"\n", done) + 1 or len(data)
                if self.lines and end - done > CHUNK_BYTES:  # whole lines, a chunk at a time: as space allows
                    end = data.rfind(b"\n", done, done + CHUNK_BYTES) + 1 or end
                self._append(data[done:end])
                done = end
        except OSError as err:
            raise WriteFailed(done, err) from err
        if sync:
            try:
                self.sync()
            except OSError as err:
                # The bytes are in the file but may never reach the disk; say so, do not re-send them.
                raise WriteFailed(done, err) from err

    def _append(self, chunk: bytes) -> None:
        """One chunk, all or nothing: a short or failed write is cut back (raises OSError)."""
        start = self.size
        try:
            n = os.write(self.fd, chunk)
            while n < len(chunk):  # a short write: try the rest once more, then give up on the chunk
                m = os.write(self.fd, chunk[n:])
                if m <= 0:
                    raise OSError(errno.ENOSPC, "short write")
                n += m
        except OSError:
            self._cut_back(start)
            raise
        self.size = start + n

    def _cut_back(self, good_size: int) -> None:
        """After a failed or partial write, remove any partial bytes so the file ends on a whole line."""
        try:
            os.ftruncate(self.fd, good_size)
            self.size = good_size
        except OSError:
            # Could not cut: close so the next open sees the torn tail and starts a fresh line.
            try:
                self.close(sync=False)
            except OSError:
                pass

    def sync(self) -> None:
        if self.fd is not None:
            t0 = time.perf_counter()
            os.fsync(self.fd)
            dt = time.perf_counter() - t0
            self.last_fsync_s, self.max_fsync_s = dt, max(self.max_fsync_s, dt)


CHUNK_BYTES = 16 * 1024  # a backlog goes to the file in chunks of whole lines, each all or nothing
OUTAGE_STATE_BYTES = 16 * 1024  # state samples kept pending while the disk is full (the oldest go first)


class WriteFailed(OSError):
    """A write that failed after `written` bytes of the batch (whole lines) reached the file."""

    def __init__(self, written: int, cause: OSError):
        super().__init__(cause.errno, f"{cause.strerror or cause}")
        self.written, self.cause = written, cause


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# ============================================================================ the log


COMMITS = ("event", "cycle", "none")  # when an event is fsync'd: at once, at the cycle's `tick()`, never


class EventLog:
    """Append-only JSON Lines event log with optional raw MAVLink `.tlog`; see the module docstring."""

    def __init__(
        self,
        directory: str | Path,
        *,
        max_bytes: int = 50_000_000,
        keep: int = 10,
        clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
        commit: str = "event",
        tlog: bool = False,
        flush_s: float = 1.0,
        buffer_bytes: int = 256_000,
        pending_bytes: int = 4_000_000,
    ):
        self.directory = Path(directory)
        self.clock, self.monotonic = clock, monotonic
        if commit not in COMMITS:
            raise ValueError(f"commit must be one of {', '.join(COMMITS)}, not {commit!r}")
        self.commit = commit
        self._uncommitted = False  # with `commit="cycle"`: an event handed to the OS and not yet fsynced
        self.flush_s, self.buffer_bytes, self.pending_bytes = flush_s, buffer_bytes, pending_bytes
        self.boot = uuid.uuid4().hex[:12]
        self.seq = -1  # the seq of the last record made
        self.write_errors = 0
        self.dropped_records = 0
        self.records_written = 0
        self.last_error: str | None = None
        self.closed = False
        self._pending: list[tuple[str, bool]] = []  # (line, is_event), oldest first
        self._pending_size = 0
        self._last_flush = monotonic()
        self._failing_since: float | None = None  # wall time of the first failure of an episode
        self._first_error: str | None = None
        self._dropped_at_failure = 0
        self._healthy = True
        self._lock = threading.RLock()
        self._file = _AppendFile(self.directory, LOG_NAME, LOG_SUFFIX, max_bytes, keep, fresh=False)
        self._tlog = _AppendFile(self.directory, TLOG_NAME, TLOG_SUFFIX, max_bytes, keep, fresh=True) if tlog else None
        self._tlog_buf: list[bytes] = []
        self._tlog_size = 0
        self.tlog_errors = 0
        self.tlog_dropped = 0
        try:
            self._file.ensure_open(check=False)
        except Exception as err:  # noqa: BLE001
            self._fail(err)
        self.event(None, "log_open", pid=os.getpid(), torn_tail=self._file.torn_tail)

    # ---------------------------------------------------------------- public API

    @property
    def healthy(self) -> bool:
        """False from a failed write until a later write succeeds (or while records are pending)."""
        return self._healthy and not self.closed

    @property
    def path(self) -> Path:
        return self._file.path

    @property
    def max_fsync_s(self) -> float:
        """Slowest fsync of the event file so far [s]."""
        return self._file.max_fsync_s

    def state(self, t, /, **fields) -> None:
        """Buffer one state sample (cheap: encode and append; written at least every `flush_s`)."""
        with self._lock:
            try:
                self.seq += 1
                line = encode_record(_record("state", t, self.clock(), self.seq, self.boot, None, fields))
                self._pending.append((line, False))
                self._pending_size += len(line)
                if self.monotonic() - self._last_flush >= self.flush_s or (
                    self._pending_size >= self.buffer_bytes and self._healthy
                ):
                    self._flush(sync=False)
            except Exception as err:  # noqa: BLE001 — never into the control loop
                self._fail(err)

    def event(self, t, name: str, /, **fields) -> bool:
        """Write one event now (with the buffered samples before it) and fsync; True when durable (with group
        commit: True when handed to the OS, durable at the next `tick()`)."""
        with self._lock:
            try:
                self.seq += 1
                line = encode_record(_record("event", t, self.clock(), self.seq, self.boot, str(name), fields))
                self._pending.append((line, True))
                self._pending_size += len(line)
                if self.commit == "cycle":
                    self._uncommitted = True
                    return self._flush(sync=False)
                return self._flush(sync=self.commit == "event")
            except Exception as err:  # noqa: BLE001
                self._fail(err)
                return False

    def raw(self, t_usec: int, msgbuf: bytes) -> None:
        """Buffer one raw MAVLink packet for the `.tlog`: 8-byte big-endian UNIX time [µs] + the bytes."""
        if self._tlog is None:
            return
        with self._lock:
            try:
                chunk = struct.pack(">Q", int(t_usec) & 0xFFFFFFFFFFFFFFFF) + bytes(msgbuf)
                if self.closed or self._tlog_size + len(chunk) > self.pending_bytes:
                    self.tlog_dropped += 1
                    return
                self._tlog_buf.append(chunk)
                self._tlog_size += len(chunk)
                if self._tlog_size >= self.buffer_bytes:
                    self._flush_tlog()
            except Exception:  # noqa: BLE001
                self.tlog_errors += 1

    def flush(self, sync: bool = False) -> bool:
        """Write everything pending now (fsync with `sync`); True when nothing is left pending."""
        with self._lock:
            try:
                return self._flush(sync=sync)
            except Exception as err:  # noqa: BLE001
                self._fail(err)
                return False

    def tick(self) -> None:
        """Call from the loop once a cycle: with `commit="cycle"`, fsyncs the cycle's events (one fsync for all of
        them); honours the `flush_s` deadline."""
        if self._uncommitted:
            self._uncommitted = False  # (an event logged by the flush itself, log_recovered, sets it again)
            if not self.flush(sync=True):
                self._uncommitted = True
        elif self.monotonic() - self._last_flush >= self.flush_s:
            self.flush()

    def close(self) -> None:
        """Flush, fsync and close both files (idempotent; never raises)."""
        with self._lock:
            if self.closed:
                return
            if not self.flush(sync=True):  # the last records (`stop`) before the samples of an outage
                self._drop_old_states(0)
                self.flush(sync=True)
            for f in (self._file, self._tlog):
                if f is not None:
                    try:
                        f.close(sync=True)
                    except Exception:  # noqa: BLE001
                        self.write_errors += 1
            self.closed = True

    def stats(self) -> dict:
        """Counters for the daemon's status report."""
        return {
            "healthy": self.healthy,
            "records_written": self.records_written,
            "write_errors": self.write_errors,
            "dropped_records": self.dropped_records,
            "pending_records": len(self._pending),
            "last_error": self.last_error,
            "max_fsync_s": self._file.max_fsync_s,
            "tlog_errors": self.tlog_errors,
            "tlog_dropped": self.tlog_dropped,
        }

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    # ---------------------------------------------------------------- internals

    def _flush(self, sync: bool) -> bool:
        self._last_flush = self.monotonic()
        if self._tlog is not None and self._tlog_buf:
            self._flush_tlog()
        if self.closed:
            self._drop_all()
            return False
        was_failing = self._failing_since is not None
        if not self._pending:
            if not sync:
                return True
            try:
                self._file.sync()
            except OSError as err:
                self._fail(err)
                return False
        else:
            lines = self._pending
            data = "".join(line for line, _ in lines).encode("utf-8", "replace")
            try:
                self._file.write(data, sync=sync, check=True)
            except WriteFailed as err:
                self._written(lines, err.written)
                self._fail(err.cause)
                return False
            except Exception as err:  # noqa: BLE001
                self._fail(err)
                return False
            self._written(lines, len(data))
        self._healthy = True
        if was_failing:
            self._recovered()
        return True

    def _written(self, lines, nbytes: int) -> None:
        """Drop from the pending list the lines that are in the file (the first `nbytes`; ASCII lines)."""
        k, size = 0, 0
        while k < len(lines) and size + len(lines[k][0]) <= nbytes:
            size += len(lines[k][0])
            k += 1
        self.records_written += k
        self._pending = lines[k:]
        self._pending_size -= size

    def _recovered(self) -> None:
        info = {
            "dropped_records": self.dropped_records - self._dropped_at_failure,
            "write_errors": self.write_errors,
            "since_wall": self._failing_since,
            "error": self._first_error,
        }
        self._failing_since = None
        self._first_error = None
        self.event(None, "log_recovered", **info)

    def _fail(self, err: BaseException) -> None:
        self.write_errors += 1
        if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
            self._drop_old_states(OUTAGE_STATE_BYTES)  # the newest, and every event, first when space returns
        self._healthy = False
        self.last_error = f"{type(err).__name__}: {err}"
        if self._failing_since is None:
            try:
                self._failing_since = self.clock()
            except Exception:  # noqa: BLE001
                self._failing_since = None
            self._first_error = self.last_error
            self._dropped_at_failure = self.dropped_records
        self._trim_pending()

    def _drop_old_states(self, keep_bytes: int) -> None:
        """Drop the oldest pending state samples until at most `keep_bytes` of them are left (counted)."""
        states = sum(len(ln) for ln, ev in self._pending if not ev)
        if states <= keep_bytes:
            return
        kept = []
        for ln, ev in self._pending:
            if not ev and states > keep_bytes:
                states -= len(ln)
                self._pending_size -= len(ln)
                self.dropped_records += 1
            else:
                kept.append((ln, ev))
        self._pending = kept

    def _trim_pending(self) -> None:
        """Keep the pending backlog bounded: drop state samples first, then the oldest events."""
        if self._pending_size <= self.pending_bytes:
            return
        kept = [(ln, ev) for ln, ev in self._pending if ev]
        self.dropped_records += len(self._pending) - len(kept)
        size = sum(len(ln) for ln, _ in kept)
        while kept and size > self.pending_bytes:
            size -= len(kept[0][0])
            kept.pop(0)
            self.dropped_records += 1
        self._pending, self._pending_size = kept, size

    def _drop_all(self) -> None:
        self.dropped_records += len(self._pending)
        self._pending, self._pending_size = [], 0

    def _flush_tlog(self) -> None:
        data = b"".join(self._tlog_buf)
        count = len(self._tlog_buf)
        self._tlog_buf, self._tlog_size = [], 0
        try:
            self._tlog.write(data, sync=False, check=True)
        except Exception:  # noqa: BLE001 — the tlog is a convenience; its loss is counted, not retried
            self.tlog_errors += 1
            self.tlog_dropped += count


# ============================================================================ reader


class EventReader:
    """Iterates the records of one file, a list of files or a log directory's rotated set, oldest first.

    Unparsable lines are skipped and listed in `bad_lines` as (path, line number, kind): `"tail"` for the
    last line of the set (a write cut by a crash), `"torn"` for a line whose next record has a new `boot`
    (a crash, then a restart that started a fresh line), `"corrupt"` for anything else. A file that
    cannot be opened raises OSError.
    """

    def __init__(self, source: str | Path | Iterable[str | Path]):
        if isinstance(source, (str, Path)):
            p = Path(source)
            self.files = file_set(p) if p.is_dir() else [p]
        else:
            self.files = []
            for s in source:
                p = Path(s)
                self.files.extend(file_set(p) if p.is_dir() else [p])
        self.bad_lines: list[tuple[str, int, str]] = []
        self.records = 0

    def __iter__(self) -> Iterator[dict]:
        last_boot = None
        suspect: tuple[str, int] | None = None  # an unparsable line, judged by the record after it
        for path in self.files:
            with open(path, "rb") as fh:
                for lineno, raw in enumerate(fh, 1):
                    if not raw.strip():
                        continue
                    try:
                        rec = json.loads(raw)
                        if not isinstance(rec, dict):
                            raise ValueError("not an object")
                    except (ValueError, RecursionError):
                        if suspect is not None:
                            self.bad_lines.append((*suspect, "corrupt"))
                        suspect = (str(path), lineno)
                        continue
                    if suspect is not None:
                        self.bad_lines.append((*suspect, "torn" if rec.get("boot") != last_boot else "corrupt"))
                        suspect = None
                    last_boot = rec.get("boot")
                    self.records += 1
                    yield rec
        if suspect is not None:
            self.bad_lines.append((*suspect, "tail"))


def read_events(path_or_dir: str | Path | Iterable[str | Path]) -> EventReader:
    """Records of an event log (a file, files, or a directory's rotated set), oldest first; see `EventReader`."""
    return EventReader(path_or_dir)
