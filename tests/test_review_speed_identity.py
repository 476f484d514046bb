"""A speed-up of `contract-guard review` must not change a review: each log reviewed as shipped and along the
straightforward path (`STRAIGHT`: the cyclic GC as usual, every `.tlog` frame decoded by pymavlink's own
`MAVLink.decode`, a `.tlog` scanned frame by frame) gives the same report, samples and replayed event log, field by field, a float by its every
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

from companion.ground.commands import review_log
from companion.ground.flightlogs import logreplay, tlog

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("CG_SHARED_LOGS", ROOT.parent / "shared" / "logs"))
SCAN = tlog.scan_tlog
# what each speed-up replaced, put back (module, name, the straightforward stand-in)
STRAIGHT = [(tlog, "scan_tlog", lambda data, runs=True: SCAN(data, runs=False)),
            (tlog, "_plain_v2", lambda data, at, parser, crc=True: None),
            (tlog, "_plain_frame", lambda data, at, parser, crc=True: None),
            (tlog, "_message", lambda data, at, n, msg_id, parser: parser.decode(bytearray(data[at:at + n]))),
            (tlog, "gc_paused", contextlib.nullcontext), (tlog, "gc_frozen", contextlib.nullcontext),
            (logreplay, "gc_paused", contextlib.nullcontext)]


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


def _frames(data: bytes):
    """(offset of the frame after its stamp) of each packet a tlog's scan keeps."""
    return [at + 8 for at in tlog.scan_tlog(data).offset]


def _crafted_tlog() -> bytes:
    """Frames of every shape the common kind takes: strings, arrays, a payload cut short by MAVLink 2's trailing-zero
    truncation (zeros at its end), extensions, several sources."""
    import struct

    out = bytearray()
    for k in range(20):
        m = tlog.mavlink.MAVLink(None, srcSystem=1 + k % 2, srcComponent=1 + 157 * (k % 3 == 0))
        for msg in (m.heartbeat_encode(2, 12, 1, k, 4), m.statustext_encode(6, f"CG: text {k}".encode()),
                    m.named_value_float_encode(k, b"CG_VMAX", 0.5 * k),
                    m.obstacle_distance_encode(k, 0, [k * 10 + j for j in range(72)], 5, 20, 1200, 2.5, 0.0, 12),
                    m.distance_sensor_encode(k, 20, 1200, 0, 0, 0, 0, 0),  # ends in zeros: truncated
                    m.param_value_encode(b"MPC_XY_CRUISE", 5.0, 9, 100, k),
                    m.command_long_encode(1, 1, 178, 0, 1, 3.0, -1, 0, 0, 0, 0)):
            m.seq = (m.seq + 37) % 256  # (`send` counts it, `pack` does not)
            out += struct.pack(">Q", 1_790_000_000_000_000 + k * 20_000) + msg.pack(m)
    return bytes(out)


@pytest.mark.parametrize("source", ["bench", "crafted"])
def test_a_plain_frame_decodes_to_pymavlinks_own_message_attribute_for_attribute(source, tmp_path):
    """`_plain_v2`'s message against `MAVLink.decode`'s: every attribute and the header's, in the same order."""
    if source == "bench":
        data = _bench("bench_review").write_tlog(tmp_path / "f.tlog", 2.0).read_bytes()
    else:
        data = _crafted_tlog()
    parser = tlog.mavlink.MAVLink(None)
    kinds, plain = set(), 0
    for at in _frames(data):
        fast = tlog._plain_v2(data, at, parser)
        n = tlog._frame_len(data, at - 8)
        ref = parser.decode(bytearray(data[at:at + n]))
        kinds.add(ref.get_type())
        if fast is None:  # not of the common kind (MAVLink 1, signed): pymavlink's own decode
            continue
        plain += 1
        assert fast[0] == n
        mine, theirs = vars(fast[1]), vars(ref)
        assert list(mine) == list(theirs)
        assert {k: v for k, v in mine.items() if k != "_header"} == {k: v for k, v in theirs.items() if k != "_header"}
        assert list(vars(mine["_header"]).items()) == list(vars(theirs["_header"]).items())
    assert plain > 100 and len(kinds) >= 5


@pytest.mark.parametrize("source", ["bench", "crafted"])
def test_the_replays_light_message_reads_as_pymavlinks_own(source, tmp_path, monkeypatch):
    """What the replay feeds the daemon of a frame (`_message`: a `Light` of the kinds the daemon reads field by
    field) against `MAVLink.decode`'s message: every field, the type, the source's ids, `id`, the frame's bytes.
    From a fresh process's state (no message class decoded before the scan)."""
    monkeypatch.setattr(tlog, "_PLAIN", {})
    if source == "bench":
        data = _bench("bench_review").write_tlog(tmp_path / "f.tlog", 2.0).read_bytes()
    else:
        data = _crafted_tlog()
    scan, parser = tlog.scan_tlog(data), tlog.mavlink.MAVLink(None)
    light = set()
    for at, n, msg_id in zip(scan.offset, scan.length, scan.common):
        mine = tlog._message(data, at + 8, n, msg_id, parser)
        ref = parser.decode(bytearray(data[at + 8:at + 8 + n]))
        if not isinstance(mine, tlog.Light):
            assert vars(mine).keys() == vars(ref).keys() and mine.get_type() == ref.get_type()
            continue
        light.add(ref.get_type())
        assert {f: getattr(mine, f) for f in ref.get_fieldnames()} == {f: getattr(ref, f) for f in ref.get_fieldnames()}
        assert (mine.get_type(), mine.get_srcSystem(), mine.get_srcComponent(), mine.id, mine.get_msgbuf()) == \
            (ref.get_type(), ref.get_srcSystem(), ref.get_srcComponent(), ref.id, ref.get_msgbuf())
        assert getattr(mine, "time_boot_ms", None) == getattr(ref, "time_boot_ms", None)
    assert light == ({"HEARTBEAT", "OBSTACLE_DISTANCE", "DISTANCE_SENSOR"} if source == "crafted" else
                     {"HEARTBEAT", "ESTIMATOR_STATUS", "EXTENDED_SYS_STATE", "LOCAL_POSITION_NED", "ATTITUDE",
                      "POSITION_TARGET_LOCAL_NED", "VFR_HUD", "DISTANCE_SENSOR"})


def _same_scan(data: bytes) -> list[str]:
    """The fields in which the scan by runs (`_clean_run`) differs from the scan frame by frame (order included)."""
    a, b = vars(tlog.scan_tlog(data, runs=False)), vars(tlog.scan_tlog(data))
    return [k for k in a if a[k] != b[k] or isinstance(a[k], dict) and list(a[k].items()) != list(b[k].items())]


def test_a_tlog_scanned_by_runs_is_indexed_as_frame_by_frame_through_damage_jumps_and_caps(tmp_path, monkeypatch):
    """The vectorised scan against the frame-by-frame one on mutated tlogs (the fuzz benchmark's mutations), on
    stamps set back, forward, past 2⁶³ (clock jumps, reordering, bad stamps inside a run), and with small run
    chunks and sample caps: every field of the index the same."""
    import random
    import struct

    from crafted_logs import gappy_tlog

    mutate = _bench("bench_fuzz_logs").mutate
    seeds = [_bench("bench_review").write_tlog(tmp_path / "b.tlog", 20.0).read_bytes(),
             gappy_tlog(tmp_path / "c.tlog", 200, 0.02).read_bytes()]
    seeds += [p.read_bytes()[:96 * 1024] for p in sorted((SHARED / "ardupilot").glob("*.tlog"))]
    rng, runs = random.Random(5), []
    monkeypatch.setattr(tlog, "_clean_run", lambda *a, f=tlog._clean_run: runs.append(r := f(*a)) or r)
    for _ in range(200):
        data, what = mutate(rng.choice(seeds), rng, rng.choice(seeds))
        assert not _same_scan(data), what
    for k in range(120):
        data = bytearray(rng.choice(seeds[:2]))
        offsets = list(tlog.scan_tlog(bytes(data), runs=False).offset)
        for j in range(rng.randint(1, 6)):
            at = offsets[0] if j == 0 and k % 3 == 0 else rng.choice(offsets)  # (the first: no time to jump from)
            raw = struct.unpack_from(">Q", data, at)[0]
            struct.pack_into(">Q", data, at, rng.choice([raw - 500_000, raw - 1_000_000, raw - 1_000_001, raw - 2_000_000,
                                                        raw + 299_000_000, raw + 400_000_000, 2**63 - 1, 2**63, 0]))
        with monkeypatch.context() as m:
            if k % 2:
                m.setattr(tlog, "RUN_CHUNK", rng.choice([256, 300, 1000]))
                m.setattr(tlog, "MAX_SAMPLES", rng.choice([300, 1000, 4000]))
            assert not _same_scan(bytes(data))
    assert sum(r[1] for r in runs) > 100_000 and any(0 < r[1] < 1000 for r in runs)  # runs taken, some cut short


def test_the_crc_of_many_frames_at_once_is_mavlinks():
    """`x25_frames` against pymavlink's own CRC (fastcrc's MCRF4XX) on random byte ranges and CRC_EXTRAs."""
    import numpy as np

    rng = np.random.default_rng(3)
    u8 = rng.integers(0, 256, 5000, dtype=np.uint8)
    start, length = rng.integers(0, 4700, 400), rng.integers(0, 265, 400)
    extra = rng.integers(0, 256, 400)
    crc = tlog.x25_frames(u8, start, length, extra)
    for k in range(400):
        ref = tlog.mcrf4xx(bytes([int(extra[k])]), tlog.mcrf4xx(u8[start[k]:start[k] + length[k]].tobytes(), 0xFFFF))
        assert crc[k] == ref
