"""The ground side's one flight-log input: which reader takes which file (`READERS`), and the bounds every
reader runs in.

| suffix | format                     | read into a `loginput.Feed` (calibrate)  | replayed into an event log (review) |
|--------|----------------------------|------------------------------------------|-------------------------------------|
| .tlog  | MAVLink ground-station log | `tlog.read_tlog` (from `tlog.scan_tlog`) | `tlog.replay_tlog`                  |
| .ulg   | PX4 ULog                   | `ulog.read_ulog`                         | `logreplay.replay_flight_log`       |
| .bin   | ArduPilot DataFlash        | `dataflash.read_dataflash`               | `logreplay.replay_flight_log`       |
| other  | contract-guard event log   | `companion.onboard.eventlog.read_events`         | — (reviewed as it is)               |

Both replays step the shadow daemon with one loop (`tlog.in_log_time`). `review`, the multi-flight review and
`calibrate` all go through `replay_log` / `read_feed` here, so every file is bounded alike: a regular file (not a
device, a pipe or a link to one) of at most `MAX_BYTES`, at most `MAX_SAMPLES` samples, nested formats at most
`MAX_DEPTH` deep (the ULog reader's own check), and at most `MAX_SECONDS` of wall time (`bounds.py`). A damaged file is one
`ContractError` line — never a traceback — and nothing a reader prints reaches stdout (where `--json` writes its
one JSON document).
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import stat
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from contracts.errors import ContractError

from .bounds import MAX_BYTES, MAX_SECONDS


@dataclass(frozen=True)
class Reader:
    """A raw flight-log format: its name, the file suffix that tells it, and what reads it."""

    name: str
    suffix: str
    read: Callable  # (path) -> loginput.Feed: the flight, for calibrate
    replay: Callable  # (path, log_dir, *, config, vehicle, table) -> review.Origin: its event log, for review


# The readers import their modules when first called: importing them costs ~0.3 s (numpy, pymavlink, pydantic),
# which every ground command would pay at start.


def _read_tlog(path):
    from .tlog import read_tlog

    return read_tlog(path)


def _replay_tlog(path, log_dir, **kw):
    from .tlog import replay_tlog

    return replay_tlog(path, log_dir, **kw)


def _read_ulog(path):
    import importlib.util

    if importlib.util.find_spec("pyulog") is None:  # the aircraft's install has no ground-only package
        raise ContractError(f"{path}: reading a PX4 ULog needs pyulog: pip install 'contract-guard[ground]'")
    from .ulog import read_ulog

    return read_ulog(path)


def _replay_ulog(path, log_dir, **kw):
    from .logreplay import replay_flight_log

    return replay_flight_log(_read_ulog, path, log_dir, **kw)


def _read_dataflash(path):
    from .dataflash import read_dataflash

    return read_dataflash(path)


def _replay_dataflash(path, log_dir, **kw):
    from .logreplay import replay_flight_log

    return replay_flight_log(_read_dataflash, path, log_dir, **kw)


READERS = {r.suffix: r for r in (
    Reader("MAVLink tlog", ".tlog", _read_tlog, _replay_tlog),
    Reader("PX4 ULog", ".ulg", _read_ulog, _replay_ulog),
    Reader("ArduPilot DataFlash", ".bin", _read_dataflash, _replay_dataflash),
)}


def reader_of(path) -> Reader | None:
    """The reader of `path` by its suffix (None: an event log or another file)."""
    return READERS.get(Path(path).suffix.lower())


def check_file(path, what: str = "a flight log") -> Path:
    """`path` if it is a regular file of at most MAX_BYTES; else one `ContractError` line. A device such as
    /dev/zero, a pipe, or a link to one is refused before a byte is read (it never ends)."""
    path = Path(path)
    try:
        st = os.stat(path)  # follows a link: what would be read
    except FileNotFoundError:
        raise ContractError(f"no such file or directory: {path}") from None
    except OSError as err:
        raise ContractError(f"cannot read {path}: {err.strerror or err}") from None
    if stat.S_ISDIR(st.st_mode):
        raise ContractError(f"{path} is a directory, not {what}")
    if not stat.S_ISREG(st.st_mode):
        raise ContractError(f"{path}: not a regular file (a device, pipe or socket), not {what}")
    if st.st_size > MAX_BYTES:
        raise ContractError(f"{path}: {st.st_size / 2**20:.0f} MiB, larger than the {MAX_BYTES / 2**20:.0f} MiB a "
                            "flight log may be: not read (split it, or review the part that matters)")
    return path


class _Timeout(BaseException):
    """Raised in the reading thread by the wall-time bound (a BaseException: no reader's `except
    Exception` swallows it)."""


@contextlib.contextmanager
def time_bound(seconds: float):
    """Raise `_Timeout` in the block after `seconds` of wall time (SIGALRM: only in the main thread; in
    another thread the block runs unbounded, as there is no safe way to stop it there)."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "setitimer"):
        yield
        return

    def _alarm(signum, frame):
        raise _Timeout

    old = signal.signal(signal.SIGALRM, _alarm)
    left, _ = signal.getitimer(signal.ITIMER_REAL)  # an enclosing bound's time left (0: none)
    t0 = time.monotonic()
    signal.setitimer(signal.ITIMER_REAL, seconds if not left else min(seconds, left))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        if left:  # the enclosing bound runs on (at once if it has expired meanwhile)
            signal.setitimer(signal.ITIMER_REAL, max(1e-3, left - (time.monotonic() - t0)))


def guarded(path, what: str, fn, *args, **kw):
    """`fn(*args, **kw)` on the log at `path` within the bounds: a file check first, MAX_SECONDS of wall
    time, anything printed kept off stdout, and any failure one `ContractError` line naming the file."""
    path = Path(path)
    if not path.is_dir():  # an event log's folder: its files are checked by the caller
        check_file(path, what)
    try:
        with time_bound(MAX_SECONDS), contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numpy on damaged columns: what counts is said as damage or one line
            return fn(*args, **kw)
    except ContractError:
        raise
    except _Timeout:
        raise ContractError(f"{path}: not read: reading and replaying it took longer than {MAX_SECONDS:g} s") from None
    except MemoryError:
        raise ContractError(f"{path}: not read: it needs more memory than this machine has") from None
    except (RecursionError, Exception) as err:  # noqa: BLE001 — a reader tripped on damaged bytes: one line
        raise ContractError(f"{path}: unreadable {what} ({type(err).__name__}: {str(err)[:120]})") from None


def replay_log(path, log_dir: Path, **kw):
    """Replay a raw log into an event log in `log_dir` (`review.Origin` of what it was made from) by its reader."""
    reader = reader_of(path)
    if reader is None:
        raise ContractError(f"{path}: not a raw flight log ({', '.join(READERS)})")
    return guarded(path, reader.name, reader.replay, path, log_dir, **kw)


def read_feed(path):
    """The `loginput.Feed` of a raw log, for calibrate."""
    reader = reader_of(path)
    if reader is None:
        raise ContractError(f"{path}: calibrate reads {', '.join(READERS)} flight logs")
    return guarded(path, reader.name, reader.read, Path(path))
