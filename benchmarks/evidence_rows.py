"""The rows of a long campaign kept beside the code: a campaign that takes longer than one machine's day (the
10⁴-flight evidence campaign, docs/evidence.md) is flown in parts, on any machine, and its figures can be
recomputed by anyone from the rows themselves.

    python benchmarks/evidence_rows.py save OUT [--into DIR]      # OUT/results.jsonl → DIR (compressed parts)
    python benchmarks/evidence_rows.py restore OUT [--from DIR]   # DIR → OUT/results.jsonl, merged with OUT's own

DIR (default `benchmarks/evidence-10k`) holds the campaign's `campaign.json` and its rows in parts of
`PART_FLIGHTS` consecutive flights, `rows-K.jsonl.xz` (flight indices K·PART_FLIGHTS and up), each row the line
the campaign wrote, sorted by flight index. A part's bytes depend only on its rows, so a part already complete is
rewritten identically. After `restore`, the campaign's own command resumes (`contract-guard campaign SPEC --out
OUT`) or reports (`--report-only`).
"""

from __future__ import annotations

import argparse
import json
import lzma
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from companion.ground import campaign as cg  # noqa: E402
DEFAULT = ROOT / "benchmarks" / "evidence-10k"
PART_FLIGHTS = 3000  # flights per part (1 000 scenarios of three arms)


def run_lines(out: Path) -> dict[int, str]:
    """flight index → its row's line, of a campaign's OUT/results.jsonl (the campaign's own reader: a torn line is
    left out; `row_json` gives back the line as the campaign wrote it)."""
    return {r["index"]: cg.row_json(r) for r in cg.read_rows(out)}


def part_lines(directory: Path) -> dict[int, str]:
    rows: dict[int, str] = {}
    for part in sorted(directory.glob("rows-*.jsonl.xz")):
        for line in lzma.decompress(part.read_bytes()).decode().splitlines():
            rows[int(json.loads(line)["index"])] = line
    return rows


def save(out: Path, into: Path) -> int:
    rows = part_lines(into) if into.is_dir() else {}
    rows |= run_lines(out)  # the run's rows over the parts' (the same flight)
    if not rows:
        raise SystemExit(f"evidence_rows: no rows in {out / 'results.jsonl'}")
    into.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / "campaign.json", into / "campaign.json")
    parts: dict[int, list[int]] = {}
    for i in sorted(rows):
        parts.setdefault(i // PART_FLIGHTS, []).append(i)
    for k, idx in parts.items():
        text = "".join(rows[i] + "\n" for i in idx).encode()
        (into / f"rows-{k:03d}.jsonl.xz").write_bytes(lzma.compress(text, preset=9))
    return len(rows)


def restore(out: Path, source: Path) -> int:
    rows = part_lines(source)
    if not rows:
        raise SystemExit(f"evidence_rows: no rows in {source}")
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "campaign.json").exists():
        shutil.copyfile(source / "campaign.json", out / "campaign.json")
    rows |= run_lines(out)  # the run's own rows win (the same flight, flown here)
    tmp = out / "results.jsonl.tmp"
    tmp.write_text("".join(rows[i] + "\n" for i in sorted(rows)))
    tmp.replace(out / "results.jsonl")
    return len(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sv = sub.add_parser("save", help="a campaign's rows into the parts")
    sv.add_argument("out", type=Path)
    sv.add_argument("--into", type=Path, default=DEFAULT)
    rs = sub.add_parser("restore", help="the parts into a campaign's --out directory")
    rs.add_argument("out", type=Path)
    rs.add_argument("--from", dest="source", type=Path, default=DEFAULT)
    args = ap.parse_args()
    n = save(args.out, args.into) if args.cmd == "save" else restore(args.out, args.source)
    print(json.dumps({"cmd": args.cmd, "rows": n}))


if __name__ == "__main__":
    sys.exit(main())
