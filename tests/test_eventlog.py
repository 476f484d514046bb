"""The event log: schema, strict JSON, buffering, rotation, crash safety, failures that never raise, tlog."""

import errno
import json
import math
import os
import random
import shutil
import signal
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from companion.onboard import eventlog as el
from companion.onboard.eventlog import EventLog, encode_record, file_set, read_events

ROOT = Path(__file__).resolve().parents[1]


def strict_loads(line):
    """json.loads that refuses NaN/Infinity (RFC 8259), as a reviewer's tool would."""

    def refuse(name):
        raise ValueError(f"non-standard constant {name}")

    return json.loads(line, parse_constant=refuse)


def lines_of(path):
    return Path(path).read_bytes().decode().splitlines()


class FakeClock:
    def __init__(self, t=0.0):
        self.t = t

    def __call__(self):
        return self.t


# ============================================================================ schema and encoding


def test_records_carry_the_header_and_fields(tmp_path):
    wall = FakeClock(1_700_000_000.0)
    log = EventLog(tmp_path / "new" / "dir", clock=wall)
    log.state(1.5, state="cruise", v_max=3.0, engaged=True)
    wall.t += 0.25
    assert log.event(1.52, "mode_change", **{"from": "AUTO.MISSION", "to": "AUTO.LOITER", "by": "other"}) is True
    log.close()
    recs = [strict_loads(ln) for ln in lines_of(tmp_path / "new" / "dir" / "events.jsonl")]
    assert [r["kind"] for r in recs] == ["event", "state", "event"]
    assert recs[0]["event"] == "log_open" and recs[0]["pid"] == os.getpid() and recs[0]["torn_tail"] is False
    s, e = recs[1], recs[2]
    assert (s["t"], s["wall"], s["state"], s["v_max"], s["engaged"]) == (1.5, 1_700_000_000.0, "cruise", 3.0, True)
    assert (e["event"], e["from"], e["to"], e["by"], e["wall"]) == ("mode_change", "AUTO.MISSION", "AUTO.LOITER", "other", 1_700_000_000.25)
    assert [r["seq"] for r in recs] == [0, 1, 2]
    assert len({r["boot"] for r in recs}) == 1 and len(recs[0]["boot"]) == 12


def test_nonfinite_values_become_null_and_are_named():
    rec = el._record("state", math.nan, 1.0, 3, "b", None,
                     {"d_od": math.inf, "e_tr": -math.inf, "ok": 1.0, "params": {"v": math.nan, "w": [1.0, math.nan]},
                      "np32": np.float32("nan"), "np64": np.float64(2.5), "arr": np.array([1.0, np.inf]),
                      "flag": np.bool_(True), "n": np.int64(7)})
    line = encode_record(rec)
    assert line.endswith("\n") and line.count("\n") == 1
    out = strict_loads(line)
    assert out["t"] is None and out["d_od"] is None and out["e_tr"] is None and out["ok"] == 1.0
    assert out["params"] == {"v": None, "w": [1.0, None]} and out["np32"] is None and out["np64"] == 2.5
    assert out["arr"] == [1.0, None] and out["flag"] is True and out["n"] == 7
    assert sorted(out["nonfinite"]) == sorted(["t", "d_od", "e_tr", "params.v", "params.w[1]", "np32", "arr[1]"])


def test_a_flat_record_with_nonfinite_values_is_encoded_once_to_the_same_line(monkeypatch):
    """A state sample with no obstacle in sight holds inf (`obstacle_m`): one pass, one `json.dumps`, and the
    very line of the general path (every non-finite value found, anywhere, nulled and named)."""
    def general(rec):
        bad = []
        clean = el.finite_copy(rec, "", bad)
        clean["nonfinite"] = bad
        return json.dumps(clean, allow_nan=False, separators=(",", ":"), default=str) + "\n"

    recs = [el._record("state", 1.5, 2.0, 3, "b", None, {"obstacle_m": math.inf, "d_od": 4.0, "v_cmd": None,
                                                          "engaged": False, "state": "standby", "n": 7}),
            {"kind": "state", "t": math.nan, "a": -math.inf, "b": math.inf, "nonfinite": "x", "ok": True},
            {"kind": "state", "z": float("nan")}]
    dumps, calls = json.dumps, []
    monkeypatch.setattr(el.json, "dumps", lambda *a, **kw: calls.append(1) or dumps(*a, **kw))
    for rec in recs:
        calls.clear()
        line = encode_record(rec)
        assert len(calls) == 1
        assert line == general(rec)
    assert strict_loads(encode_record(recs[0]))["nonfinite"] == ["obstacle_m"]
    calls.clear()  # not flat (a list, a numpy float): the general path, as before
    assert encode_record({"kind": "state", "w": [math.inf], "x": np.float64("inf")}) == \
        general({"kind": "state", "w": [math.inf], "x": np.float64("inf")}) and len(calls) == 3


def test_finite_records_have_no_nonfinite_key_and_odd_objects_do_not_break_encoding():
    class Odd:
        def __str__(self):
            return "odd!"

    circular = []
    circular.append(circular)
    out = strict_loads(encode_record({"kind": "state", "a": Odd(), "p": Path("/x"), "s": {2, 1}, "c": circular}))
    assert "nonfinite" not in out and out["a"] == "odd!" and out["p"] == "/x" and out["s"] == [1, 2]
    assert out["kind"] == "state"


def test_reserved_field_names_do_not_overwrite_the_header(tmp_path):
    log = EventLog(tmp_path)
    log.event(2.0, "command", seq=99, kind="x", boot="y", t=5, name="n")
    log.close()
    r = strict_loads(lines_of(log.path)[-1])
    assert r["kind"] == "event" and r["seq"] == 1 and r["boot"] == log.boot and r["t"] == 2.0
    assert (r["seq_"], r["kind_"], r["boot_"], r["t_"], r["name"]) == (99, "x", "y", 5, "n")


# ============================================================================ buffering and durability


def test_events_are_on_disk_at_once_and_states_within_the_flush_interval(tmp_path):
    mono = FakeClock(100.0)
    log = EventLog(tmp_path, monotonic=mono, flush_s=1.0)
    n0 = len(lines_of(log.path))
    for i in range(10):
        mono.t += 0.02
        log.state(i * 0.02, v_max=1.0)
    assert len(lines_of(log.path)) == n0, "state samples are buffered"
    mono.t += 1.0
    log.state(1.0, v_max=1.0)  # crosses the 1 s deadline
    assert len(lines_of(log.path)) == n0 + 11
    log.state(1.02, v_max=1.0)
    log.event(1.03, "failsafe", cause="stale_obstacle_data", action="hold")
    recs = [strict_loads(x) for x in lines_of(log.path)]  # before close: the event forced the sample out
    assert recs[-2]["kind"] == "state" and recs[-1]["event"] == "failsafe"
    mono.t += 5
    log.state(2.0, v_max=1.0)
    log.tick()
    assert strict_loads(lines_of(log.path)[-1])["t"] == 2.0
    log.close()
    log.state(3.0)  # after close: no raise, counted as dropped
    log.event(3.0, "stop")
    assert log.dropped_records == 2


# ============================================================================ rotation and reader


def test_rotation_keeps_keep_files_and_the_reader_returns_them_in_order(tmp_path):
    log = EventLog(tmp_path, max_bytes=4_000, keep=3)
    for i in range(400):
        log.state(i * 0.1, i=i, pad="x" * 40)
        if i % 50 == 0:
            log.event(i * 0.1, "limit_change", v_max=float(i), reason="test")
    log.close()
    files = file_set(tmp_path)
    assert [p.name for p in files] == ["events.3.jsonl", "events.2.jsonl", "events.1.jsonl", "events.jsonl"]
    assert all(p.stat().st_size <= 4_000 for p in files)
    reader = read_events(tmp_path)
    seqs = [r["seq"] for r in reader]
    assert seqs == list(range(seqs[0], seqs[-1] + 1)), "oldest first, no gaps inside the kept set"
    assert seqs[-1] == log.seq and seqs[0] > 0, "the oldest records were rotated out"
    assert reader.bad_lines == [] and reader.records == len(seqs)
    assert [r["seq"] for r in read_events(files[-1])] == seqs[-reader.files[-1].read_text().count("\n"):]


def test_reader_skips_and_classifies_bad_lines(tmp_path):
    good = json.dumps({"kind": "state", "t": 0, "seq": 0, "boot": "a"})
    p = tmp_path / "events.jsonl"
    p.write_text("\n".join([good, "{garbage", good, "[" * 100_000, good, '{"kind": "sta']))
    reader = read_events(p)
    assert len(list(reader)) == 3
    assert [(n, k) for _, n, k in reader.bad_lines] == [(2, "corrupt"), (4, "corrupt"), (6, "tail")]
    (tmp_path / "bin.jsonl").write_bytes(b"\xff\xfe\x00garbage\n\x89PNG")
    r2 = read_events(tmp_path / "bin.jsonl")
    assert list(r2) == [] and len(r2.bad_lines) == 2


def test_restart_appends_on_a_fresh_line_after_a_torn_tail(tmp_path):
    log = EventLog(tmp_path)
    log.event(1.0, "start")
    log.close()
    before = log.path.read_bytes()
    with open(log.path, "ab") as fh:
        fh.write(b'{"kind":"state","t":1.02,"wa')  # what kill -9 in the middle of a write leaves
    log2 = EventLog(tmp_path)
    log2.event(5.0, "start")
    log2.close()
    after = log.path.read_bytes()
    assert after.startswith(before)
    reader = read_events(tmp_path)
    recs = list(reader)
    assert [r["boot"] for r in recs] == [log.boot] * 2 + [log2.boot] * 2
    assert recs[2]["event"] == "log_open" and recs[2]["torn_tail"] is True
    assert [k for _, _, k in reader.bad_lines] == ["torn"]


# ============================================================================ kill -9

CHILD = textwrap.dedent(
    """
    import sys
    from companion.onboard.eventlog import EventLog
    log = EventLog(sys.argv[1], max_bytes=int(sys.argv[2]), keep=100000)
    print("ready", flush=True)
    i = 0
    while True:
        i += 1
        log.state(i * 0.02, i=i, state="cruise", v_max=3.0, gamma=-0.2, pad="p" * (i % 97))
        if i % 7 == 0 and log.event(i * 0.02, "limit_change", v_max=i * 0.01, reason="child"):
            print(log.seq, flush=True)
    """
)


def run_and_kill(directory, seed, max_bytes):
    """Start a logging child, SIGKILL it at a random moment; return the seqs it acknowledged as fsync'd."""
    rng = random.Random(seed)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(directory), str(max_bytes)],
                             stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        assert child.stdout.readline().strip() == "ready"
        first_ack = child.stdout.readline()
        time.sleep(rng.uniform(0.05, 0.4))
        child.send_signal(signal.SIGKILL)
        out, _ = child.communicate(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == -signal.SIGKILL
    return [int(x) for x in (first_ack + out).split()]


def check_boot(recs, acked):
    seqs = [r["seq"] for r in recs]
    assert seqs == list(range(len(seqs))), "every record of the run up to the kill, in order, no gaps"
    events = {r["seq"] for r in recs if r["kind"] == "event"}
    missing = set(acked) - events
    assert acked and not missing, f"acknowledged events missing after kill -9: {sorted(missing)[:5]}"


def kill_restart_scenario(tmp_path, seed, max_bytes):
    """Run, kill -9, check; run again in the same directory, kill -9, check. Returns figures for a report."""
    acked1 = run_and_kill(tmp_path, seed, max_bytes)
    r1 = read_events(tmp_path)
    first = list(r1)
    assert all(k == "tail" for _, _, k in r1.bad_lines) and len(r1.bad_lines) <= 1, r1.bad_lines
    check_boot(first, acked1)

    acked2 = run_and_kill(tmp_path, seed + 100, max_bytes)
    r2 = read_events(tmp_path)
    both = list(r2)
    boots = list(dict.fromkeys(r["boot"] for r in both))
    assert len(boots) == 2
    assert [r for r in both if r["boot"] == boots[0]] == first, "the first run's records are intact"
    second = [r for r in both if r["boot"] == boots[1]]
    check_boot(second, acked2)
    assert second[0]["event"] == "log_open"
    # a torn line of the first run (if any) is now mid-file, followed by the new boot; at most a tail after it
    kinds = [k for _, _, k in r2.bad_lines]
    assert kinds.count("corrupt") == 0 and kinds.count("tail") <= 1
    assert kinds.count("torn") == (1 if r1.bad_lines else 0)
    return {"acked": [len(acked1), len(acked2)], "torn_tail": bool(r1.bad_lines), "files": len(file_set(tmp_path)),
            "records": len(both)}


@pytest.mark.parametrize("seed", range(4))
def test_kill_9_loses_no_acknowledged_event_and_restart_keeps_the_log(tmp_path, seed):
    max_bytes = [4_000, 50_000_000, 10_000, 50_000_000][seed]  # with and without rotations during the run
    kill_restart_scenario(tmp_path, seed, max_bytes)


BIG_WRITER = textwrap.dedent(
    """
    import sys
    from companion.onboard.eventlog import EventLog
    log = EventLog(sys.argv[1], buffer_bytes=16_000_000, pending_bytes=64_000_000)
    print("ready", flush=True)
    i = 0
    while True:
        i += 1
        log.state(i * 0.02, i=i, pad="p" * 20_000)
    """
)


def test_a_real_torn_write_from_kill_9_is_repaired_on_restart(tmp_path):
    """Multi-megabyte writes can be cut by SIGKILL; the next run must start on a fresh line."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for attempt in range(10):
        d = tmp_path / f"a{attempt}"
        child = subprocess.Popen([sys.executable, "-c", BIG_WRITER, str(d)], stdout=subprocess.PIPE, text=True,
                                 env=env, cwd=ROOT)
        assert child.stdout.readline().strip() == "ready"
        time.sleep(random.Random(attempt).uniform(0.3, 0.9))
        child.kill()
        child.wait(timeout=10)
        r = read_events(d)
        n_before = sum(1 for _ in r)
        if r.bad_lines:
            break
        shutil.rmtree(d)
    else:
        pytest.skip("no write was cut by SIGKILL in 10 attempts (the synthetic torn-tail test covers the repair)")
    assert [k for _, _, k in r.bad_lines] == ["tail"]
    log = EventLog(d)
    log.event(99.0, "start")
    log.close()
    r2 = read_events(d)
    recs = list(r2)
    assert len(recs) == n_before + 2 and recs[-2]["event"] == "log_open" and recs[-2]["torn_tail"] is True
    assert [k for _, _, k in r2.bad_lines] == ["torn"]
    shutil.rmtree(d)  # tens of MB: do not leave them in pytest's kept temp dirs


# ============================================================================ failures never raise


@pytest.fixture
def enospc(monkeypatch):
    """Make writes to the log fail with ENOSPC while `state['full']` is True."""
    state = {"full": True}
    real_write = os.write

    def write(fd, data):
        if state["full"] and fd > 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(el.os, "write", write)
    return state


def test_full_disk_is_counted_never_raised_and_recovers(tmp_path, enospc):
    enospc["full"] = False
    mono = FakeClock(0.0)
    log = EventLog(tmp_path, monotonic=mono, pending_bytes=3_000)
    enospc["full"] = True
    assert log.event(1.0, "failsafe", cause="x", action="hold") is False
    assert not log.healthy and log.write_errors == 1 and "No space left" in log.last_error
    for i in range(200):
        mono.t += 0.1
        log.state(1 + i * 0.1, pad="s" * 30)
    assert log.event(30.0, "violation_start", subsystem="navigation", guarantee="g", assumed=6, observed=2, action="hold") is False
    assert log.dropped_records > 0 and log.write_errors > 2
    enospc["full"] = False
    assert log.event(31.0, "failsafe_clear") is True and log.healthy
    log.close()
    recs = list(read_events(tmp_path))
    names = [r.get("event") for r in recs if r["kind"] == "event"]
    assert names == ["log_open", "failsafe", "violation_start", "failsafe_clear", "log_recovered"]
    rec = recs[-1]
    assert rec["dropped_records"] == log.dropped_records and rec["error"].startswith("OSError")
    kept_states = sum(r["kind"] == "state" for r in recs)
    assert kept_states + log.dropped_records == 200, "every sample is either written or counted as dropped"


def test_failed_fsync_is_reported_not_raised(tmp_path, monkeypatch):
    log = EventLog(tmp_path)

    def bad_fsync(fd):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(el.os, "fsync", bad_fsync)
    assert log.event(1.0, "failsafe", cause="x", action="hold") is False
    assert not log.healthy and log.write_errors == 1
    monkeypatch.undo()
    assert log.event(2.0, "failsafe_clear") is True and log.healthy
    log.close()
    assert [r.get("event") for r in read_events(tmp_path)][-3:] == ["failsafe", "failsafe_clear", "log_recovered"]


def test_a_cycle_commit_hands_each_event_to_the_os_at_once_and_fsyncs_a_cycles_events_once(tmp_path, monkeypatch):
    """The daemon's log: a cycle's events are in the file (they survive a kill) as each is logged, and one fsync at
    the cycle's end (`tick`) makes them all durable; a failed commit is retried at the next tick."""
    log = EventLog(tmp_path, commit="cycle")
    log.tick()  # log_open
    synced = []
    real_fsync = el.os.fsync
    monkeypatch.setattr(el.os, "fsync", lambda fd: synced.append(fd) or real_fsync(fd))
    for k in range(5):
        assert log.event(1.0, "state_change", to=f"s{k}") is True
        assert sum('"state_change"' in x for x in lines_of(log.path)) == k + 1  # in the file at once
    assert synced == []
    log.tick()
    assert len(synced) == 1
    log.tick()  # nothing new: no fsync
    assert len(synced) == 1

    def bad_fsync(fd):
        raise OSError(errno.EIO, "Input/output error")

    log.event(2.0, "failsafe", cause="x", action="hold")
    monkeypatch.setattr(el.os, "fsync", bad_fsync)
    log.tick()
    assert not log.healthy and log.write_errors == 1
    monkeypatch.setattr(el.os, "fsync", lambda fd: synced.append(fd) or real_fsync(fd))
    log.tick()  # the failed commit again
    assert len(synced) == 2 and log.healthy
    log.close()


def test_commit_none_never_fsyncs_and_an_unknown_commit_is_refused(tmp_path, monkeypatch):
    synced = []
    real_fsync = el.os.fsync
    monkeypatch.setattr(el.os, "fsync", lambda fd: synced.append(fd) or real_fsync(fd))
    log = EventLog(tmp_path / "a", commit="none")
    assert log.event(1.0, "state_change", to="s") is True
    log.tick()
    assert synced == [] and sum('"state_change"' in x for x in lines_of(log.path)) == 1
    log.close()
    with pytest.raises(ValueError, match="commit must be one of event, cycle, none"):
        EventLog(tmp_path / "b", commit="group")


def test_vanished_directory_is_recreated(tmp_path):
    d = tmp_path / "logs"
    log = EventLog(d)
    log.event(1.0, "start")
    for p in d.iterdir():
        p.unlink()
    d.rmdir()
    assert log.event(2.0, "stop") is True
    log.close()
    recs = list(read_events(d))
    assert [r.get("event") for r in recs] == ["stop"] and log.write_errors == 0


def test_uncreatable_directory_never_raises(tmp_path):
    (tmp_path / "file").write_text("not a directory")
    log = EventLog(tmp_path / "file" / "logs")
    log.state(0.0, v_max=1.0)
    assert log.event(0.0, "start") is False and not log.healthy and log.write_errors >= 2
    log.close()


def mount(*args):
    return subprocess.run(["mount", *args], capture_output=True, text=True)


@pytest.fixture
def tiny_fs(tmp_path):
    """A real 64 KiB tmpfs (needs root and mount rights; skipped otherwise)."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    r = mount("-t", "tmpfs", "-o", "size=64k,mode=0755", "tmpfs", str(mnt))
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or 'not root'}); the monkeypatched ENOSPC test covers the logic")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_real_full_filesystem(tiny_fs):
    mono = FakeClock(0.0)
    log = EventLog(tiny_fs, monotonic=mono, pending_bytes=20_000)
    acked = []
    for i in range(3000):  # ~300 kB of samples into 64 KiB
        mono.t += 0.02
        log.state(i * 0.02, i=i, pad="x" * 60)
        if i % 100 == 0 and log.event(i * 0.02, "limit_change", v_max=float(i), reason="t"):
            acked.append(log.seq)
    assert log.write_errors > 0 and log.dropped_records > 0 and not log.healthy
    full = read_events(tiny_fs)
    assert set(acked) <= {r["seq"] for r in full if r["kind"] == "event"}
    assert full.bad_lines == [], "partial writes were cut back to whole lines"
    assert len(acked) < 30, "the disk did fill up"
    assert mount("-o", "remount,size=4m", str(tiny_fs)).returncode == 0
    assert log.event(61.0, "stop") is True and log.healthy
    log.close()
    reader = read_events(tiny_fs)
    recs = list(reader)
    assert reader.bad_lines == []
    assert {r["seq"] for r in recs if r["kind"] == "event"} >= set(acked)
    recovered = [r for r in recs if r.get("event") == "log_recovered"]
    assert recs[-1]["event"] == "log_recovered"
    assert sum(r["dropped_records"] for r in recovered) == log.dropped_records, "the log says what it lost"
    written = len(recs)
    assert written + log.dropped_records == log.seq + 1, "every record is written or counted as dropped"


def test_real_read_only_directory(tiny_fs, tmp_path):
    """A read-only bind mount (root ignores permission bits, so chmod would prove nothing)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    assert mount("--bind", str(tiny_fs), str(ro)).returncode == 0
    try:
        assert mount("-o", "remount,bind,ro", str(ro)).returncode == 0
        log = EventLog(ro / "logs")
        log.state(1.0, v_max=1.0)
        assert log.event(1.1, "failsafe", cause="x", action="hold") is False
        assert not log.healthy and log.write_errors >= 2 and "Read-only" in log.last_error
        assert mount("-o", "remount,bind,rw", str(ro)).returncode == 0
        assert log.event(2.0, "failsafe_clear") is True and log.healthy
        log.close()
    finally:
        subprocess.run(["umount", "-l", str(ro)], capture_output=True)
    recs = list(read_events(tiny_fs / "logs"))
    assert [r.get("event") or r["kind"] for r in recs] == ["log_open", "state", "failsafe", "failsafe_clear", "log_recovered"]


# ============================================================================ tlog


def heartbeat_bytes(seq):
    from pymavlink.dialects.v20 import common as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=191)
    m.seq = seq
    return m.heartbeat_encode(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(m)


def test_tlog_is_readable_by_pymavlink(tmp_path):
    from pymavlink import mavutil

    log = EventLog(tmp_path, tlog=True)
    t0 = 1_700_000_000_000_000
    for i in range(20):
        log.raw(t0 + i * 100_000, heartbeat_bytes(i))
    log.close()
    raw = (tmp_path / "raw.tlog").read_bytes()
    assert struct.unpack(">Q", raw[:8])[0] == t0
    conn = mavutil.mavlink_connection(str(tmp_path / "raw.tlog"))
    msgs = []
    while (m := conn.recv_match(blocking=False)) is not None:
        msgs.append(m)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT"] * 20
    assert msgs[5]._timestamp == pytest.approx((t0 + 500_000) * 1e-6)
    assert [m.get_seq() for m in msgs] == list(range(20))
    # a new process starts a new tlog; the previous one is kept whole
    log2 = EventLog(tmp_path, tlog=True)
    log2.raw(t0, heartbeat_bytes(0))
    log2.close()
    assert (tmp_path / "raw.1.tlog").read_bytes() == raw and (tmp_path / "raw.tlog").stat().st_size == len(raw) // 20


def test_raw_from_the_link_thread_while_the_loop_logs(tmp_path):
    import threading

    from pymavlink import mavutil

    log = EventLog(tmp_path, tlog=True, buffer_bytes=2_000)  # small buffer: many flushes race with raw()
    packets = [heartbeat_bytes(i % 256) for i in range(3000)]

    def link():
        for i, p in enumerate(packets):
            log.raw(1_700_000_000_000_000 + i, p)

    th = threading.Thread(target=link)
    th.start()
    for i in range(3000):
        log.state(i * 0.02, v_max=1.0)
        if i % 100 == 0:
            log.event(i * 0.02, "limit_change", v_max=1.0, reason="t")
    th.join()
    log.close()
    conn = mavutil.mavlink_connection(str(tmp_path / "raw.tlog"))
    n = 0
    while conn.recv_match(blocking=False) is not None:
        n += 1
    assert n == 3000 and log.tlog_errors == 0 and log.tlog_dropped == 0
    assert [r["seq"] for r in read_events(tmp_path)] == list(range(log.seq + 1))


@pytest.mark.parametrize("freed", ["filler", "log file"])
def test_the_log_comes_back_as_soon_as_a_little_space_is_free(tiny_fs, freed):
    """A full disk with a large backlog: freeing 40 KB (or deleting the log file) brings new lines at once —
    the backlog goes in chunks of whole lines, the oldest samples of the outage dropped first and counted —
    and `stop` is written at close."""
    filler = tiny_fs / "filler"
    filler.write_bytes(b"\0" * 40_000)
    mono = FakeClock(0.0)
    log = EventLog(tiny_fs / "logs", monotonic=mono)
    i = 0
    while log.write_errors == 0 or i < 4000:  # well past full: a backlog of ~300 kB
        mono.t += 0.02
        log.state(i * 0.02, i=i, pad="x" * 60)
        i += 1
    assert not log.healthy
    (filler if freed == "filler" else tiny_fs / "logs" / "events.jsonl").unlink()
    mono.t += 2.0
    assert log.event(100.0, "failsafe", cause="after", action="hold") is True and log.healthy
    log.event(101.0, "stop", counters={})
    log.close()
    recs = list(read_events(tiny_fs / "logs"))
    names = [r.get("event") for r in recs if r["kind"] == "event"]
    assert names[-3:] == ["failsafe", "log_recovered", "stop"] or names[-3:] == ["log_recovered", "failsafe", "stop"]
    rec = next(r for r in recs if r.get("event") == "log_recovered")
    assert rec["dropped_records"] > 0  # the log says what it lost


def test_stop_is_written_at_close_even_while_a_backlog_does_not_fit(tiny_fs):
    mono = FakeClock(0.0)
    log = EventLog(tiny_fs / "logs", monotonic=mono, pending_bytes=10_000_000)
    (tiny_fs / "filler").write_bytes(b"\0" * 20_000)
    for i in range(6000):
        mono.t += 0.02
        log.state(i * 0.02, i=i, pad="x" * 60)
    (tiny_fs / "filler").unlink()  # 20 KB free again: less than the backlog, enough for the last records
    log.event(200.0, "stop", counters={})
    log.close()
    names = [r.get("event") for r in read_events(tiny_fs / "logs") if r["kind"] == "event"]
    assert "stop" in names
