"""Fuzz of every flight-log reader (`benchmarks/bench_fuzz_logs.py`): mutated ULog, DataFlash, .tlog and event
logs — from real public logs when present, crafted logs and the SITL's own logs — each read
in a memory-capped process within a per-file time bound: every file is read or refused in one line, none
raises, hangs or runs out of memory. ~50 files per format here; the full ≥ 1 000 per format is `slow`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def fuzz(per_format: int, seed: int, *extra: str) -> dict:
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_fuzz_logs.py"), "--per-format",
                          str(per_format), "--seed", str(seed), *extra], capture_output=True, text=True, check=True,
                         timeout=7200)
    return json.loads(out.stdout.strip().splitlines()[-1])


def check(res: dict, per_format: int) -> None:
    assert set(res["formats"]) == {".ulg", ".bin", ".tlog", ".jsonl"}
    for suffix, st in res["formats"].items():
        assert st["files"] == per_format and st["read"] + st["one_line"] == per_format, (suffix, st)
        assert st["failures"] == [], (suffix, st["failures"])
        assert st["replayed"] >= 1
    assert res["failures"] == 0


@pytest.mark.parametrize("per_format", [pytest.param(48, marks=pytest.mark.slow), 16])
def test_every_reader_survives_mutated_logs(per_format):
    res = fuzz(per_format, 3, "--replay-every", "12")
    check(res, per_format)
    assert any("sitl-" in s for s in res["formats"][".ulg"]["seeds"])  # the SITL's own log among the seeds


@pytest.mark.slow
def test_every_reader_survives_a_thousand_mutated_logs_per_format():
    check(fuzz(1000, 1), 1000)
