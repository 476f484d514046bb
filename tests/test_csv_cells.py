"""Text that a spreadsheet would run as a formula never reaches a CSV cell as such: `samples.csv` of a review (the
real `contract-guard review` on an event log whose text fields start like formulas) and every other CSV the tools
write go through one helper (`contracts.csvfile`); numbers are untouched."""

from __future__ import annotations

import csv
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from contracts import csvfile

ROOT = Path(__file__).resolve().parents[1]
HOSTILE = ["=HYPERLINK(\"http://x\",\"y\")", "+1+1", "-2+3", "@SUM(A1)", "\t=1+1", "\r=1+1"]


def test_formula_text_is_quoted_and_numbers_are_not():
    for text in HOSTILE:
        assert csvfile.safe_cell(text) == "'" + text
    for n in (-1.5, 0, 3, 2.5e-7, float("nan"), True, None):
        assert csvfile.safe_cell(n) is n
    for s in ("-0.25", "+3", "1e-3", "-1.5E+02", ".5", "mission", "", "'=already"):
        assert csvfile.safe_cell(s) == s
    buf = io.StringIO()
    w = csvfile.DictWriter(buf, fieldnames=["a", "b"])
    w.writeheader()
    w.writerow({"a": "=1+1", "b": -2.0})
    assert list(csv.reader(io.StringIO(buf.getvalue()))) == [["a", "b"], ["'=1+1", "-2.0"]]


def _hostile_event_log(directory: Path) -> Path:
    from companion.onboard.logschema import LOG_FILE, STATE_FIELDS

    directory.mkdir(parents=True, exist_ok=True)
    boot = "=cmd|' /C calc'!A0"
    lines = [{"kind": "event", "t": 0.0, "wall": 1_790_000_000.0, "seq": 0, "boot": boot, "event": "start",
              "mode": "shadow"}]
    for k in range(20):
        state = {f: None for f in STATE_FIELDS}
        state.update(state="@SUM(1+1)", mode="+mission", contract="stop", engaged=False, x=-1.25, y=0.0, z=-5.0,
                     vx=0.0, vy=0.0, vz=0.0, ground_speed=0.0, d_od=6.0, e_tr=0.3, e_tr_measured=0.1, r_obst=0.5,
                     thrust_ratio=1.0, v_max=3.0, tilt_deg=20.0, v_safe=4.0, gamma=-1.0, gamma_flown=-4.0)
        lines.append({"kind": "state", "t": 1.0 + k * 0.1, "wall": 1_790_000_001.0 + k * 0.1, "seq": k + 1,
                      "boot": boot, **state})
    (directory / LOG_FILE).write_text("".join(json.dumps(r) + "\n" for r in lines))
    return directory


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_review_samples_csv_neutralises_formula_text(tmp_path):
    run = _hostile_event_log(tmp_path / "run")
    r = subprocess.run([sys.executable, "-m", "companion.cli", "review", str(run), "--out", str(tmp_path / "out")],
                       capture_output=True, text=True, cwd=str(ROOT), timeout=300)
    assert "Traceback" not in r.stderr, r.stderr
    rows = _rows(tmp_path / "out" / "samples.csv")
    assert rows
    for row in rows:
        assert row["boot"] == "'=cmd|' /C calc'!A0" and row["mode"] == "'+mission" and row["state"] == "'@SUM(1+1)"
        assert row["x"] == "-1.25" and row["gamma"] == "-1.0"  # numbers as they were
        assert not any(str(v).startswith(tuple(csvfile.FORMULA_START)) and not re.fullmatch(r"[-+0-9.eE]+", v)
                       for v in row.values())


def test_negative_control_without_the_helper_the_cells_are_formulas(tmp_path, monkeypatch):
    """The same review with the helper made a no-op: the old samples.csv, whose cells a spreadsheet would run."""
    from companion.ground.commands import review_log

    monkeypatch.setattr(csvfile, "safe_cell", lambda v: v)
    run = _hostile_event_log(tmp_path / "run")
    review_log(run, tmp_path / "out")
    row = _rows(tmp_path / "out" / "samples.csv")[0]
    assert row["boot"].startswith("=") and row["mode"] == "+mission" and row["state"].startswith("@")


SOURCES = [p for d in ("companion", "contracts", "sitl_harness", "benchmarks") for p in (ROOT / d).rglob("*.py")]


@pytest.mark.parametrize("pattern", [r"csv\.writer\(", r"csv\.DictWriter\("])
def test_every_csv_writer_goes_through_the_helper(pattern):
    """No module but the helper makes a csv writer of its own."""
    users = [str(p.relative_to(ROOT)) for p in SOURCES if re.search(pattern, p.read_text())
             and p != ROOT / "contracts" / "csvfile.py"]
    assert users == []
    writers = [p for p in SOURCES if re.search(r"csvfile\.(writer|DictWriter)\(", p.read_text())]
    assert len(writers) >= 4  # the review, the collision-set comparison, the avoid plots, the SITL figures
