"""Fuzz every flight-log reader: N mutated files per format, each read in a process whose memory is capped,
bounded in wall time; one JSON object on stdout.

    python benchmarks/bench_fuzz_logs.py [--per-format 1000] [--seed 1] [--replay-every 25] [--no-sitl]

Seeds per format: PX4 ULog — the real public PX4 logs when present (their first 96 KiB:
definitions and the first data) and a crafted one (tests/crafted_logs.py); ArduPilot DataFlash — the real
ArduPlane log, a crafted Copter log and the SITL's own log of a 10 s hover; MAVLink .tlog — the real ArduPilot
logs' first 96 KiB and a crafted one; the event log — one the replay of a crafted log wrote. The SITL's own ULog
joins the ULog seeds. Mutations (seeded, reproducible): bit flips, boundary bytes, boundary 8-byte integers,
NaN/inf floats, inserted, deleted and duplicated stretches, truncation, splices of two seeds.

Each mutated file goes through the readers themselves, as review and calibrate call them — `read_ulog`,
`read_dataflash`, `scan_tlog` and calibrate's `read_tlog`, the event-log reader and summary — and every
`--replay-every`-th one also through the replay and the review (without the registry's net, which would
turn a traceback into a line: a traceback is seen). A `ContractError`
(one line) or a result is a pass; anything else raised, a hang past the per-file bound or a memory error
is a failure, listed with the file's seed and mutation so it can be made again. The readers run under
RLIMIT_AS = --mem-gib (a memory blow-up is a MemoryError, not a swapped machine).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import resource
import struct
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "benchmarks")]
SHARED = ROOT.parent / "shared" / "logs"
SEED_BYTES = 96 * 1024
PER_FILE_S = 60.0  # a reader taking longer than this on a ≤ 100 KiB file is a hang
SUFFIXES = (".ulg", ".bin", ".tlog", ".jsonl")

BOUNDARY = [0, 1, 0x7F, 0x80, 0xFF]
BOUNDARY_Q = [0, 1, 2**31, 2**32 - 1, 2**63 - 1, 2**63, 2**64 - 1]
NAN_INF = [struct.pack("<f", float("nan")), struct.pack("<f", float("inf")), struct.pack("<d", float("nan")),
           struct.pack(">d", float("-inf"))]


def mutate(data: bytes, rng: random.Random, other: bytes) -> tuple[bytes, str]:
    """One to four mutations of `data` (`other`: another seed of the format, for splices); (bytes, what)."""
    b = bytearray(data)
    what = []
    for _ in range(rng.randint(1, 4)):
        if not b:
            b += other[:64]
        k = rng.randrange(10)
        i = rng.randrange(len(b))
        if k == 0:
            b[i] ^= 1 << rng.randrange(8)
            what.append(f"flip@{i}")
        elif k == 1:
            b[i] = rng.choice(BOUNDARY)
            what.append(f"byte@{i}")
        elif k == 2:
            q = struct.pack(rng.choice("<>") + "Q", rng.choice(BOUNDARY_Q))
            b[i:i + 8] = q
            what.append(f"q@{i}")
        elif k == 3:
            f = rng.choice(NAN_INF)
            b[i:i + len(f)] = f
            what.append(f"nan@{i}")
        elif k == 4:
            n = rng.choice([1, 2, 3, 8, 64, 512])
            b[i:i] = bytes(rng.randrange(256) for _ in range(n))
            what.append(f"insert{n}@{i}")
        elif k == 5:
            n = rng.choice([1, 3, 16, 300, 4096])
            del b[i:i + n]
            what.append(f"delete{n}@{i}")
        elif k == 6:
            n = rng.choice([3, 89, 500, 5000])
            b[i:i] = b[i:i + n] * rng.choice([1, 2, 10])
            what.append(f"dup{n}@{i}")
        elif k == 7:
            del b[i:]
            what.append(f"truncate@{i}")
        elif k == 8:
            j = rng.randrange(len(other)) if other else 0
            b[i:] = other[j:j + rng.randrange(1, 20_000)]
            what.append(f"splice@{i}")
        else:  # a run of one byte value (a header-looking stretch or zeros)
            n = rng.choice([16, 256, 4096])
            b[i:i + n] = bytes([rng.choice(BOUNDARY + [0xA3, 0x95, 0xFD, 0xFE])]) * n
            what.append(f"run{n}@{i}")
    return bytes(b), ",".join(what)


def seeds(work: Path, sitl: bool) -> dict[str, list[tuple[str, bytes]]]:
    from crafted_logs import gappy_bin, gappy_tlog, gappy_ulog

    from companion.ground.commands import review_log

    out: dict[str, list[tuple[str, bytes]]] = {s: [] for s in SUFFIXES}
    for suffix, folder in ((".ulg", "px4"), (".bin", "ardupilot"), (".tlog", "ardupilot")):
        for p in sorted((SHARED / folder).glob(f"*{suffix}")) if (SHARED / folder).is_dir() else []:
            out[suffix].append((p.name, p.read_bytes()[:SEED_BYTES]))
    out[".ulg"].append(("crafted.ulg", gappy_ulog(work / "c.ulg", 200, 0.02, speed=2.0).read_bytes()))
    out[".bin"].append(("crafted.bin", gappy_bin(work / "c.bin", 200, 0.02, speed=2.0).read_bytes()))
    out[".tlog"].append(("crafted.tlog", gappy_tlog(work / "c.tlog", 200, 0.02).read_bytes()))
    if sitl:
        from bench_review import sitl_log

        for personality in ("px4", "ardupilot"):
            p = sitl_log(work / f"sitl-{personality}", personality, 10.0)
            out[p.suffix].append((f"sitl-{personality}{p.suffix}", p.read_bytes()[:SEED_BYTES]))
    review_log(work / "c.bin", work / "ev", vehicle="x500")  # the event log its replay wrote
    out[".jsonl"].append(("replay-events.jsonl", (work / "ev" / "replay-events.jsonl").read_bytes()[:SEED_BYTES]))
    return out


def read(path: Path, suffix: str, full: bool):
    """The readers as review and calibrate call them, without the registry's net (which would turn a reader's
    traceback into a line), and, `full`, the replay and the review."""
    from companion.ground.flightlogs.dataflash import read_dataflash
    from companion.onboard.eventlog import read_events
    from companion.ground.flightlogs import READERS
    from companion.ground.flightlogs.tlog import read_tlog, scan_tlog
    from companion.ground.review import review, summarise
    from companion.ground.flightlogs.ulog import read_ulog

    if suffix == ".ulg":
        read_ulog(path)
    elif suffix == ".bin":
        read_dataflash(path)
    elif suffix == ".tlog":
        scan_tlog(path.read_bytes())
        read_tlog(path)
    else:
        summarise(read_events(path))
    if not full:
        return
    if suffix == ".jsonl":
        review(path)
        return
    out = path.parent / "replay"
    out.mkdir()
    origin = READERS[suffix].replay(path, out, vehicle="x500")
    review(out / "events.jsonl", origin=origin)


def run(per_format: int, seed: int, replay_every: int, sitl: bool, mem_gib: float) -> dict:
    from companion.ground.flightlogs import _Timeout, time_bound
    from contracts.errors import ContractError

    res: dict = {"bench": "fuzz_logs", "per_format": per_format, "seed": seed, "replay_every": replay_every,
                 "per_file_bound_s": PER_FILE_S, "mem_limit_gib": mem_gib, "formats": {}}
    with tempfile.TemporaryDirectory(prefix="cg-fuzz-") as tmp:
        work = Path(tmp)
        all_seeds = seeds(work, sitl)
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        limit = int(mem_gib * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit if hard == resource.RLIM_INFINITY else min(limit, hard), hard))
        try:
            for suffix in SUFFIXES:
                pool = all_seeds[suffix]
                rng = random.Random(f"{seed}{suffix}")
                st = {"seeds": [n for n, _ in pool], "files": 0, "one_line": 0, "read": 0, "replayed": 0,
                      "failures": [], "max_s": 0.0, "total_s": 0.0}
                for k in range(per_format):
                    name, data = pool[k % len(pool)]
                    blob, what = mutate(data, rng, rng.choice(pool)[1])
                    d = work / f"f{suffix[1:]}{k}"
                    d.mkdir()
                    path = d / f"fuzz{suffix}"
                    path.write_bytes(blob)
                    full = replay_every > 0 and k % replay_every == 0
                    t0 = time.perf_counter()
                    try:
                        with time_bound(PER_FILE_S), contextlib.redirect_stdout(sys.stderr), warnings.catch_warnings():
                            warnings.simplefilter("ignore")  # numpy's casts of garbage: what is said is the result
                            read(path, suffix, full)
                        st["read"] += 1
                    except ContractError as err:
                        st["one_line"] += 1
                        if "\n" in str(err):
                            st["failures"].append({"seed": name, "k": k, "mutation": what, "error": "multi-line"})
                    except _Timeout:
                        st["failures"].append({"seed": name, "k": k, "mutation": what, "error": "hang"})
                    except BaseException as err:  # noqa: BLE001 — a traceback a user would have seen
                        tb = traceback.extract_tb(err.__traceback__)[-1]
                        st["failures"].append({"seed": name, "k": k, "mutation": what,
                                               "error": f"{type(err).__name__}: {str(err)[:120]}",
                                               "at": f"{Path(tb.filename).name}:{tb.lineno}"})
                    dt = time.perf_counter() - t0
                    st["files"] += 1
                    st["replayed"] += full
                    st["max_s"], st["total_s"] = max(st["max_s"], dt), st["total_s"] + dt
                    for f in d.iterdir():
                        if f.is_file():
                            f.unlink()
                        else:
                            import shutil

                            shutil.rmtree(f)
                    d.rmdir()
                st["failure_count"] = len(st["failures"])
                st["failures"] = st["failures"][:20]
                res["formats"][suffix] = st
        finally:
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    res["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    res["failures"] = sum(st["failure_count"] for st in res["formats"].values())
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-format", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--replay-every", type=int, default=25, help="every k-th file also goes through the whole review")
    ap.add_argument("--no-sitl", action="store_true", help="no SITL-made seed logs")
    ap.add_argument("--mem-gib", type=float, default=4.0)
    args = ap.parse_args()
    os.chdir(ROOT)
    print(json.dumps(run(args.per_format, args.seed, args.replay_every, not args.no_sitl, args.mem_gib)))


if __name__ == "__main__":
    main()
