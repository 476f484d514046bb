"""Before/after check for a speed-up of `contract-guard review`: the same logs reviewed by two
checkouts must give the same report, field by field, and the same replayed event log, record by record.

    python benchmarks/review_identity.py logs DIR [--minutes 20] [--px4-logs D]  # write the logs once (any checkout)
    python benchmarks/review_identity.py snapshot DIR OUT          # review each with this process's code
    python benchmarks/review_identity.py compare OUT_A OUT_B       # field-by-field differences (exit 1 if any)

The logs: the bench's DataFlash log and `.tlog` (`bench_review.py`'s straight flight, `--minutes` long), the
SITL's own ULog and DataFlash of a hover by a column, lock-step SITL flights recorded as the daemon's `.tlog` plus the
autopilot's own log (a hidden-fog flight on PX4, an offboard flight on PX4, an unguarded one on ArduPilot;
each with the flight's config), the real PX4 logs in ../shared/logs/px4 (or `--px4-logs`) and the real ArduPilot ones in
../shared/logs/ardupilot (or `--ardupilot-logs`) when present.
`snapshot` runs `contract-guard review LOG --json --out D` in a fresh process per log, with D at one fixed path (so the
paths in the report agree between checkouts), and keeps stdout, review.json, samples.csv and the replayed
event log. Compared: every field and value exactly (a float by its every bit; the JSON text is parsed, so
key order and spacing are not compared), less what differs between any two runs (`PER_RUN`). Each review
runs in this checkout (its directory is the child's working directory, first on
sys.path): to snapshot the code before a change, run a copy of this script in an unpacked `git archive` of
the base commit.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "logs" / "px4"
SHARED_ARDUPILOT = ROOT.parent / "shared" / "logs" / "ardupilot"
# the one --out path of every review (the same for both checkouts; CG_IDENTITY_WORK moves it, e.g. when two
# checks share a machine)
WORK = Path(os.environ.get("CG_IDENTITY_WORK", "/tmp/contract-guard-review-identity-out"))
KEPT = ("stdout.json", "review.json", "samples.csv", "replay-events.jsonl")
# what differs between any two runs of one checkout, so it is not compared: the daemon run's random id and
# the process id (`boot`, `pid`); and the checkout's own folder in paths (the shipped table's), written as <root>
PER_RUN = ("boot", "pid")


def write_logs(where: Path, minutes: float, px4_logs: Path = SHARED, ardupilot_logs: Path = SHARED_ARDUPILOT) -> None:
    """Every log of the check, with a `logs.json` manifest: name → (path, extra review arguments)."""
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "tests"))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_review import sitl_log, write_tlog
    from test_flight_logs import write_bin

    from tests.test_daemon_lockstep import column_scenario, fly
    from tests.test_offboard_lockstep import engage_and_fly, offboard_config, offboard_scenario
    from tests.test_replay import record

    where.mkdir(parents=True, exist_ok=True)
    logs: dict[str, list] = {"bench_dataflash": [str(write_bin(where / "bench.bin", speed=3.0, dur=minutes * 60)),
                                                 ["--vehicle", "x500"]]}
    logs["bench_tlog"] = [str(write_tlog(where / "bench.tlog", minutes * 60)), ["--vehicle", "x500"]]
    for personality in ("px4", "ardupilot"):
        path = sitl_log(where / f"hover-{personality}", personality, 120.0)
        logs[f"sitl_hover_{personality}"] = [str(path), ["--vehicle", "x500"]]
    flights = {
        "fog_hidden_px4": (column_scenario(1, x_col=40.0, faults=[{"at_s": 5.0, "fog": {"visibility_m": 3.0,
                                                                                         "report": "hidden"}}]),
                           "px4", {"seconds": 20.0, "flight": fly}),
        "offboard_px4": (offboard_scenario(1, personality="px4"), "px4",
                         {"config": offboard_config(), "flight": engage_and_fly, "seconds": 22.0}),
        "no_guard_ardupilot": (column_scenario(1, x_col=28.0, cruise=8.0), "ardupilot",
                               {"config": {"mode": "shadow"}, "seconds": 12.0, "flight": fly}),
    }
    for name, (sc, personality, kw) in flights.items():
        d = where / name
        d.mkdir()
        cfg = record(d, sc, personality, log_dir=d / "autopilot", **kw)
        logs[f"{name}_tlog"] = [str(d / "raw.tlog"), ["--config", str(cfg)]]
        own = sorted((d / "autopilot").iterdir())
        logs[f"{name}_own"] = [str(own[0]), ["--config", str(cfg)]]
    for p in sorted(px4_logs.glob("*.ulg")) if px4_logs.is_dir() else []:
        logs[f"shared_{p.stem}"] = [str(p), ["--vehicle", "x500"]]
    for p in sorted((*ardupilot_logs.glob("*.tlog"), *ardupilot_logs.glob("*.bin"))) if ardupilot_logs.is_dir() else []:
        logs[f"shared_{p.stem}"] = [str(p), ["--vehicle", "x500"]]  # (a fixed wing among them: refused in one line)
    (where / "logs.json").write_text(json.dumps(logs, indent=1))


def snapshot(logs_dir: Path, out: Path) -> None:
    logs = json.loads((logs_dir / "logs.json").read_text())
    out.mkdir(parents=True, exist_ok=True)
    (out / "root.txt").write_text(str(ROOT))
    for name, (path, extra) in logs.items():
        shutil.rmtree(WORK, ignore_errors=True)
        cli = "import sys; from companion.cli import main; sys.exit(main())"
        r = subprocess.run([sys.executable, "-c", cli, "review", path, "--json", "--out", str(WORK), *extra],
                           capture_output=True, text=True, cwd=ROOT)
        WORK.mkdir(parents=True, exist_ok=True)  # a log refused in one line writes nothing there
        (WORK / "stdout.json").write_text(r.stdout)
        (WORK / "stderr.txt").write_text(r.stderr + f"\nexit {r.returncode}\n")
        dest = out / name
        shutil.rmtree(dest, ignore_errors=True)
        dest.mkdir()
        for f in (*KEPT, "stderr.txt"):
            if (WORK / f).exists():
                shutil.copyfile(WORK / f, dest / f)
        print(f"{name}: exit {r.returncode}", flush=True)


def normal(v, root: str):
    """A JSON value without what differs between runs (`PER_RUN` keys dropped, the checkout's folder as <root>)."""
    if isinstance(v, dict):
        return {k: normal(x, root) for k, x in v.items() if k not in PER_RUN}
    if isinstance(v, list):
        return [normal(x, root) for x in v]
    return v.replace(root, "<root>") if isinstance(v, str) else v


def csv_rows(path: Path, root: str) -> list:
    import csv

    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    drop = [i for i, name in enumerate(rows[0]) if name in PER_RUN] if rows else []
    return [[c.replace(root, "<root>") for i, c in enumerate(r) if i not in drop] for r in rows]


def differences(a, b, where: str = "") -> list[str]:
    """Every path at which two JSON values differ (exact: a float differs by any bit)."""
    if type(a) is not type(b):
        return [f"{where}: {a!r} != {b!r}"]
    if isinstance(a, dict):
        out = [f"{where}.{k}: only in {'A' if k in a else 'B'}" for k in sorted(set(a) ^ set(b))]
        for k in a:
            if k in b:
                out += differences(a[k], b[k], f"{where}.{k}")
        return out
    if isinstance(a, list):
        out = [] if len(a) == len(b) else [f"{where}: length {len(a)} != {len(b)}"]
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, f"{where}[{i}]")
        return out
    return [] if a == b or (a != a and b != b) else [f"{where}: {a!r} != {b!r}"]


def compare(a: Path, b: Path) -> int:
    bad, ra, rb = 0, (a / "root.txt").read_text().strip(), (b / "root.txt").read_text().strip()
    for d in sorted(p for p in a.iterdir() if p.is_dir()):
        other, diffs, checked = b / d.name, [], []
        for f in KEPT:
            fa, fb = d / f, other / f
            if not fa.exists() and not fb.exists():
                continue
            if not (fa.exists() and fb.exists()):
                diffs.append(f"{f}: only in {'A' if fa.exists() else 'B'}")
                continue
            checked.append(f)
            if f.endswith(".json"):
                diffs += [f"{f}{x}" for x in differences(normal(json.loads(fa.read_text() or "null"), ra),
                                                          normal(json.loads(fb.read_text() or "null"), rb))]
            elif f.endswith(".jsonl"):
                la, lb = fa.read_text().splitlines(), fb.read_text().splitlines()
                if len(la) != len(lb):
                    diffs.append(f"{f}: {len(la)} != {len(lb)} records")
                for i, (x, y) in enumerate(zip(la, lb)):
                    diffs += [f"{f}[{i}]{z}" for z in differences(normal(json.loads(x), ra), normal(json.loads(y), rb))]
            else:
                ca, cb = csv_rows(fa, ra), csv_rows(fb, rb)
                diffs += [f"{f}: row {i}: {x} != {y}" for i, (x, y) in enumerate(zip(ca, cb)) if x != y]
                if len(ca) != len(cb):
                    diffs.append(f"{f}: {len(ca)} != {len(cb)} rows")
        bad += bool(diffs)
        print(f"{d.name}: {'IDENTICAL' if not diffs else f'{len(diffs)} difference(s)'} ({', '.join(checked)})")
        for x in diffs[:20]:
            print("   ", x)
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    lg = sub.add_parser("logs")
    lg.add_argument("dir", type=Path)
    lg.add_argument("--minutes", type=float, default=20.0)
    lg.add_argument("--px4-logs", type=Path, default=SHARED, help=f"the real PX4 logs (default {SHARED})")
    lg.add_argument("--ardupilot-logs", type=Path, default=SHARED_ARDUPILOT,
                    help=f"the real ArduPilot logs (default {SHARED_ARDUPILOT})")
    sn = sub.add_parser("snapshot")
    sn.add_argument("dir", type=Path)
    sn.add_argument("out", type=Path)
    cp = sub.add_parser("compare")
    cp.add_argument("a", type=Path)
    cp.add_argument("b", type=Path)
    args = ap.parse_args()
    if args.cmd == "logs":
        write_logs(args.dir, args.minutes, args.px4_logs, args.ardupilot_logs)
        return 0
    if args.cmd == "snapshot":
        snapshot(args.dir, args.out)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
