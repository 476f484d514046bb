"""The 10⁴-flight evidence campaign's rows kept beside the code (benchmarks/evidence_rows.py): they go into
parts and come back as the campaign wrote them, the campaign resumes from them, and the shipped rows are what
this code flies — a few of them re-flown, to the row (floats to 1e-9, as the golden logs: another machine's
floating point may differ in its last bits)."""

from __future__ import annotations

import importlib.util
import json
import lzma
from pathlib import Path

import pytest

from companion.ground import campaign as cg
from tests.golden import first_difference

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "examples" / "campaign-evidence-10k.yaml"

_spec = importlib.util.spec_from_file_location("evidence_rows", ROOT / "benchmarks" / "evidence_rows.py")
er = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(er)


def test_rows_go_into_parts_and_come_back_and_the_campaign_resumes_from_them(tmp_path, monkeypatch):
    monkeypatch.setattr(er, "PART_FLIGHTS", 2)
    small = cg.spec_from_dict({"name": "rows", "seed": 3, "scenarios": 2, "vehicles": ["mambo"],
                               "personalities": ["px4"], "arms": ["governor", "offboard"], "duration_s": 12})
    out = tmp_path / "c"
    cg.run(small, out, progress=False, limit=3)
    written = {json.loads(x)["index"]: x for x in (out / "results.jsonl").read_text().splitlines()}
    assert er.save(out, tmp_path / "parts") == 3
    assert sorted(p.name for p in (tmp_path / "parts").glob("rows-*")) == ["rows-000.jsonl.xz", "rows-001.jsonl.xz"]
    first = (tmp_path / "parts" / "rows-000.jsonl.xz").read_bytes()
    assert er.save(out, tmp_path / "parts") == 3 and (tmp_path / "parts" / "rows-000.jsonl.xz").read_bytes() == first
    elsewhere = tmp_path / "elsewhere"
    assert er.restore(elsewhere, tmp_path / "parts") == 3
    assert (elsewhere / "results.jsonl").read_text().splitlines() == [written[i] for i in sorted(written)]
    rows = cg.run(small, elsewhere, progress=False)  # only the fourth flight is flown
    assert [r["index"] for r in rows] == [0, 1, 2, 3]
    assert er.save(elsewhere, tmp_path / "parts") == 4
    assert len(lzma.decompress((tmp_path / "parts" / "rows-001.jsonl.xz").read_bytes()).splitlines()) == 2


def test_the_shipped_evidence_rows_are_what_this_code_flies():
    shipped = er.part_lines(er.DEFAULT) if er.DEFAULT.is_dir() else {}
    if not shipped:
        pytest.skip(f"no evidence rows in {er.DEFAULT}")
    stored = json.loads((er.DEFAULT / "campaign.json").read_text())
    if "stale" in stored:  # flown by an earlier contract: kept as that contract's evidence until re-flown
        pytest.skip(f"the shipped evidence rows are {stored['stale']}")
    spec = cg.load_spec(SPEC)
    assert cg.same_campaign(stored["spec"], spec), "the shipped rows are of another campaign than " + str(SPEC)
    arms = len(spec.arms)
    for i in {max(i for i in shipped if i % arms == a) for a in range(arms)}:  # the last of each arm flown
        again = json.loads(cg.row_json(cg.fly(spec, i)))
        where = first_difference(json.loads(shipped[i]), again)
        assert where is None, f"flight {i} no longer flies to its shipped row: {where}"
