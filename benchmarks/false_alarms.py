"""False alarms in clear air, per flight-hour (one JSON object on stdout).

Lock-step flights of the real daemon against the real SITL over real MAVLink bytes (companion/ground/flights.py),
no fog, through plain and cluttered worlds (a route past columns; a facade flown through its doorway; a stand of
poles flown beside; a corridor with a turn), with each of the SITL's sensor models (the sector sensor, the
RealSense-class depth camera, the TFmini-class single beam), in both modes (governor: the SITL's mission flies
under the daemon's limits and holds; offboard: the daemon flies). Every hold, "no safe speed" stop, violation (by
subsystem) and "no avoiding plan" the daemon logs is judged by a perfect observer reading the SITL's truth
(companion/ground/false_alarms.py): founded or unfounded.

A flight ends at the route's end, or 3 s after the daemon's first stop (the pilot takes over): its flight-hours
are counted up to that stop, airborne only. Each (mode, sensor model, world) cell flies seeds 1, 2, … until it has
its share of `--hours` or `--max-flights` flights.

    python benchmarks/false_alarms.py [--hours 0.2] [--max-flights 12] [--modes governor offboard]
        [--models sector depth_camera single_beam] [--worlds plain columns doorway cluster corridor]
        [--spurious-rate R] [--first-seed 1] [--workers 1] [--rows FILE.jsonl]
    python benchmarks/false_alarms.py --report-only FILE.jsonl [FILE.jsonl ...]

`--spurious-rate`: the depth camera's and the single beam's spurious close returns per bin and frame (their
defaults: 0.002 and 0.0005, sitl_harness/sensor_models.py), to measure the alarms that are theirs alone.
`--first-seed`: the seed each cell starts from, so that more hours add flights unlike those flown already.
`--rows`: each flight is appended to this file as one JSON line the moment it lands, so a run stopped part-way keeps
every flight it flew; run again with the same file, it resumes (a flight already there is read, not flown again).
`--report-only`: the summary of the rows in these files (several runs' rows together), nothing flown.
Per cell and per (mode, model): flights, hours, routes completed (`arrived`), flights the daemon guarded at all
(`guarded`: it left standby; a set-up whose sensors cannot cover the swept corridor is refused at start-up and only
watches), events per hour by kind, unfounded per hour, and the 95 % upper bound of the unfounded rate (Poisson:
3.0 / hours with none seen); the first unfounded events, with the truth behind them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.ground.false_alarms import MODELS, MODES, WORLDS, fly

# the 95 % upper bound of a Poisson mean for k = 0..5 events seen (Garwood, one-sided)
POISSON_95 = (3.0, 4.74, 6.30, 7.75, 9.15, 10.51)


def upper_per_hour(k: int, hours: float) -> float | None:
    if hours <= 0:
        return None
    return (POISSON_95[k] if k < len(POISSON_95) else k + 1.645 * math.sqrt(k) + 1.0) / hours


def _fly(task) -> dict:
    mode, model, world, seed, spurious = task
    return fly(mode, model, world, seed, sensor=None if spurious is None else {"spurious_rate": spurious})


def summarise(rows: list[dict]) -> dict:
    hours = sum(r["flown_s"] for r in rows) / 3600.0
    events, unfounded, causes = Counter(), Counter(), Counter()
    for r in rows:
        for e in r["events"]:
            events[e["kind"]] += 1
            if not e["founded"]:
                unfounded[e["kind"]] += 1
                causes[e.get("cause", "other")] += 1
    n_bad = sum(unfounded.values())
    per = (lambda c: {k: round(v / hours, 1) for k, v in sorted(c.items())}) if hours > 0 else (lambda c: {})
    return {"flights": len(rows), "hours": round(hours, 4), "arrived": sum(r["arrived"] for r in rows),
            "guarded": sum(r.get("guarded", True) for r in rows),
            "collisions": sum(r["collisions"] for r in rows), "events": dict(sorted(events.items())),
            "unfounded": dict(sorted(unfounded.items())), "unfounded_by_cause": dict(sorted(causes.items())),
            "events_per_hour": per(events),
            "unfounded_per_hour": per(unfounded),
            "unfounded_total_per_hour": round(n_bad / hours, 1) if hours > 0 else None,
            "unfounded_upper95_per_hour": round(upper_per_hour(n_bad, hours), 1) if hours > 0 else None}


def read_rows(path: Path) -> list[dict]:
    """The rows a run appended; a last line cut short by a kill is skipped (its flight is flown again)."""
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows


def report(rows: list[dict], cells: list[tuple], head: dict) -> dict:
    modes = sorted({c[0] for c in cells}, key=MODES.index)
    models = sorted({c[1] for c in cells}, key=MODELS.index)
    mine = lambda c: [r for r in rows if (r["mode"], r["model"], r["world"]) == c]
    return {"benchmark": "false_alarms", **head,
            "all": summarise(rows),
            "per_mode": {m: summarise([r for r in rows if r["mode"] == m]) for m in modes},
            "per_mode_model": {f"{m}/{s}": summarise([r for r in rows if r["mode"] == m and r["model"] == s])
                               for m in modes for s in models},
            "cells": [{"mode": m, "model": s, "world": w, **summarise(mine((m, s, w)))} for m, s, w in cells],
            "unfounded_examples": [{"mode": r["mode"], "model": r["model"], "world": r["world"], "seed": r["seed"], **e}
                                   for r in rows for e in r["events"] if not e["founded"]][:40]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=0.2, help="flight-hours to fly in all (shared by the cells)")
    ap.add_argument("--max-flights", type=int, default=12, help="at most this many flights a cell")
    ap.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    ap.add_argument("--worlds", nargs="+", choices=WORLDS, default=list(WORLDS))
    ap.add_argument("--spurious-rate", type=float, default=None)
    ap.add_argument("--first-seed", type=int, default=1, help="the seed each cell starts from")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--rows", type=Path, default=None, help="append each flight here as it lands; resume from it")
    ap.add_argument("--report-only", type=Path, nargs="+", default=None, metavar="FILE",
                    help="summarise the rows in these files; fly nothing")
    a = ap.parse_args()
    if a.report_only:
        try:
            rows = [r for f in a.report_only for r in read_rows(f)]
        except OSError as e:
            ap.exit(2, f"false_alarms.py: cannot read {e.filename}: {e.strerror}\n")
        seen = {(r["mode"], r["model"], r["world"]) for r in rows}
        cells = [(m, s, w) for m in MODES for s in MODELS for w in WORLDS if (m, s, w) in seen]
        print(json.dumps(report(rows, cells, {"rows_from": [str(f) for f in a.report_only]})))
        return
    if not a.hours > 0 or a.max_flights < 1 or a.workers < 1 or a.first_seed < 1 or \
            (a.spurious_rate is not None and not 0.0 <= a.spurious_rate <= 1.0):
        ap.exit(2, "false_alarms.py: --hours must be > 0, --max-flights, --workers and --first-seed ≥ 1, "
                   "--spurious-rate in [0, 1]\n")
    cells = [(m, s, w) for m in a.modes for s in a.models for w in a.worlds]
    share_s = a.hours * 3600.0 / len(cells)
    t0 = time.time()
    rows: dict[tuple, list[dict]] = {c: [] for c in cells}
    done = {}
    if a.rows is not None and a.rows.exists():
        done = {(r["mode"], r["model"], r["world"], r["seed"]): r for r in read_rows(a.rows)
                if r.get("spurious_rate") == a.spurious_rate}
    sink = a.rows.open("a") if a.rows is not None else None
    if sink is not None and sink.tell() > 0 and not a.rows.read_bytes().endswith(b"\n"):
        sink.write("\n")  # a line cut short by a kill stays a line of its own, skipped when read
    seed = a.first_seed - 1
    with ProcessPoolExecutor(a.workers) if a.workers > 1 else _Inline() as pool:
        while True:
            seed += 1
            todo = [c for c in cells if sum(r["flown_s"] for r in rows[c]) < share_s and len(rows[c]) < a.max_flights]
            if not todo:
                break
            fly_now = [c for c in todo if (*c, seed) not in done]
            flown = dict(zip(fly_now, pool.map(_fly, [(*c, seed, a.spurious_rate) for c in fly_now])))
            for c in todo:
                row = done.get((*c, seed)) or flown[c]
                rows[c].append(row)
                if c in flown and sink is not None:
                    sink.write(json.dumps({**row, "spurious_rate": a.spurious_rate}) + "\n")
                    sink.flush()
                print(f"{'/'.join(c)} seed {seed}: {row['flown_s']:.1f} s, "
                      f"{sum(not e['founded'] for e in row['events'])} unfounded", file=sys.stderr, flush=True)
    if sink is not None:
        sink.close()
    head = {"hours_asked": a.hours, "max_flights": a.max_flights, "first_seed": a.first_seed,
            "spurious_rate": a.spurious_rate, "wall_s": round(time.time() - t0, 1)}
    print(json.dumps(report([r for c in cells for r in rows[c]], cells, head)))


class _Inline:
    """`map` in this process (one worker)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def map(self, f, items):
        return [f(x) for x in items]


if __name__ == "__main__":
    main()
