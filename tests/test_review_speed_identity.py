"""A speed-up of `contract-guard review` must not change a review: each log reviewed as shipped and along the
straightforward path (`STRAIGHT`: the cyclic GC as usual, every `.tlog` frame decoded by pymavlink's own
`MAVLink.decode`) gives the same report, samples and replayed event log, field by field, a float by its every
bit (`benchmarks/review_identity.py`'s comparison; it compares two checkouts on 20-minute logs the same way).

Logs: a DataFlash log and a `.tlog` of the bench's straight flight (a minute each), and real ones from
../shared/logs (or $CG_SHARED_LOGS): two PX4 ULogs and 400 kB from the middle of an ArduCopter `.tlog`, skipped
with the reason when absent (a user's clone has none).
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import shutil
from pathlib import Path

import pytest

from companion.cli import review_log
from companion.flightlogs import logreplay, tlog

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("CG_SHARED_LOGS", ROOT.parent / "shared" / "logs"))
# what each speed-up replaced, put back (module, name, the straightforward stand-in)
STRAIGHT = [(tlog, "_plain_v2", lambda data, at, parser: None), (tlog, "_plain_frame", lambda data, at, parser: None),
            (tlog, "gc_paused", contextlib.nullcontext),
            (tlog, "gc_frozen", contextlib.nullcontext), (logreplay, "gc_paused", contextlib.nullcontext)]


def _bench(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


identity = _bench("review_identity")


def reviewed(path: Path, out: Path) -> dict:
    """review.json, samples.csv and the replayed event log of `path` (reviewed into `out`, emptied first)."""
    shutil.rmtree(out, ignore_errors=True)
    review_log(path, out, vehicle="x500")
    return {"review.json": identity.normal(json.loads((out / "review.json").read_text()), str(ROOT)),
            "samples.csv": identity.csv_rows(out / "samples.csv", str(ROOT)),
            "replay-events.jsonl": [identity.normal(json.loads(x), str(ROOT))
                                    for x in (out / "replay-events.jsonl").read_text().splitlines()]}


def same_review(path: Path, out: Path, monkeypatch) -> None:
    fast = reviewed(path, out)
    with monkeypatch.context() as m:
        for mod, name, plain in STRAIGHT:
            m.setattr(mod, name, plain)
        straight = reviewed(path, out)
    diffs = identity.differences(fast, straight)
    assert not diffs, "\n".join(diffs[:20])
    assert fast["replay-events.jsonl"] and fast["samples.csv"]


def test_a_written_dataflash_log_reviews_the_same_along_the_straightforward_path(tmp_path, monkeypatch):
    from test_flight_logs import write_bin

    same_review(write_bin(tmp_path / "flight.bin", speed=3.0, dur=60.0), tmp_path / "out", monkeypatch)


def test_a_written_tlog_reviews_the_same_along_the_straightforward_path(tmp_path, monkeypatch):
    path = _bench("bench_review").write_tlog(tmp_path / "flight.tlog", 60.0)
    same_review(path, tmp_path / "out", monkeypatch)


# the second real ULog is the same evidence again: make test-all
@pytest.mark.parametrize("name, part", [pytest.param("px4/sample_px4_events.ulg", slice(None), marks=pytest.mark.slow),
                                        ("px4/sample.ulg", slice(None)),
                                        ("ardupilot/arducopter-2015-23min.tlog", slice(1_100_000, 1_500_000))])
def test_a_real_log_reviews_the_same_along_the_straightforward_path(name, part, tmp_path, monkeypatch):
    src = SHARED / name
    if not src.is_file():
        pytest.skip(f"the shared real logs are not here ({src}; a user's clone has none; $CG_SHARED_LOGS moves them)")
    path = tmp_path / src.name
    path.write_bytes(src.read_bytes()[part])  # of a long log, minutes with positions (cut mid-packet: said alike)
    same_review(path, tmp_path / "out", monkeypatch)
