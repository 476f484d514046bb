"""Hostile and damaged flight logs: each is one clear line or one finding in the review, never a hang or a
traceback, never another flight's loss in a multi-flight review, and never a fake verdict — nested ULog
formats, huge or missing timestamps, devices posing as logs, bogus DataFlash formats, a NaN range, control
characters and HTML in what a log says, and a fixed wing's .tlog."""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import sys

import pytest

from companion.ground.commands import review_log
from companion.ground.reviewset import review_set
from contracts.errors import ContractError
from crafted_logs import MAKERS, gappy_bin, gappy_tlog, gappy_ulog
from sitl_harness.ulog_writer import ULogWriter
from test_flight_logs import SHARED


def cli(*args, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def nested_ulog(path, levels: int = 4, size: int = 255):
    """A ~1 kB ULog whose formats nest arrays of arrays: `size`^`levels` fields once flattened."""
    w = ULogWriter(path, 1)
    w._msg(b"F", b"n0:uint8_t[%d] a;" % size)
    for k in range(1, levels):
        w._msg(b"F", b"n%d:n%d[%d] a;" % (k, k - 1, size))
    w._msg(b"F", b"vehicle_local_position:uint64_t timestamp;n%d[%d] x;" % (levels - 1, size))
    w._msg(b"A", struct.pack("<BH", 0, 0) + b"vehicle_local_position")
    w.close()
    return path


def test_nested_ulog_formats_are_refused_in_one_line_before_they_expand(tmp_path):
    """On main pyulog flattens 255⁵ fields (3 GiB after 30 s): review and calibrate hang."""
    path = nested_ulog(tmp_path / "nested.ulg")
    assert path.stat().st_size < 15_000
    r = cli("review", path, "--vehicle", "x500", "--json", timeout=60)
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    assert "flattens to more than" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    from companion.ground.calibrate import calibrate
    from contracts.table import load_for_vehicle
    from contracts.vehicle import load_vehicle

    with pytest.raises(ContractError, match="no log could be read.*flattens to more than"):
        calibrate([path], load_vehicle("x500"), load_for_vehicle("x500"), tmp_path / "cal.npz", report=False)
    # a format containing itself, and nesting deeper than a real log's
    w = ULogWriter(tmp_path / "loop.ulg", 1)
    w._msg(b"F", b"vehicle_local_position:uint64_t timestamp;vehicle_local_position x;")
    w._msg(b"A", struct.pack("<BH", 0, 0) + b"vehicle_local_position")
    w.close()
    with pytest.raises(ContractError, match="contains itself"):
        review_log(tmp_path / "loop.ulg", vehicle="x500")
    with pytest.raises(ContractError, match="nested more than"):
        review_log(nested_ulog(tmp_path / "deep.ulg", levels=12, size=1), vehicle="x500")


def huge_stamp_tlog(path):
    gappy_tlog(path, 100, 0.02)
    data = bytearray(path.read_bytes())
    data[0:8] = struct.pack(">Q", 2**64 - 5)
    path.write_bytes(bytes(data))
    return path


def no_timeus_bin(path):
    gappy_bin(path, 100, 0.02)
    path.write_bytes(path.read_bytes().replace(b"TimeUS,C,Roll", b"TimeXX,C,Roll"))  # XKF1's FMT entry
    return path


def test_damaged_logs_are_a_finding_or_one_line_never_a_traceback(tmp_path):
    """On main: OverflowError (a .tlog stamp near 2⁶⁴), KeyError (a .bin whose XKF1 has no TimeUS)."""
    rep, _ = review_log(huge_stamp_tlog(tmp_path / "huge.tlog"), vehicle="x500")
    assert rep["replay"]["bad_stamps"] == 1 and rep["state_samples"] > 10
    assert any("too large to be a time" in f for f in rep["findings"])
    with pytest.raises(ContractError, match=r"not read, their format entry lacking a column: XKF1 \(no TimeUS\)"):
        review_log(no_timeus_bin(tmp_path / "notime.bin"), vehicle="x500")


@pytest.mark.parametrize("target", ["/dev/zero", "link.tlog", "link.ulg", "link.bin", "events.jsonl"])
def test_a_device_posing_as_a_log_is_refused_before_it_is_read(tmp_path, target):
    """On main `review /dev/zero` (or a .tlog linked to it) reads until MemoryError."""
    if target != "/dev/zero":
        os.symlink("/dev/zero", tmp_path / target)
        target = tmp_path / target
    r = cli("review", target, "--vehicle", "x500", timeout=60) if str(target).endswith(("tlog", "ulg", "bin")) \
        else cli("review", target, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "not a regular file" in r.stderr


def test_one_damaged_flight_never_stops_the_others(tmp_path):
    folder = tmp_path / "flights"
    folder.mkdir()
    gappy_bin(folder / "a-good.bin", 200, 0.02)
    huge_stamp_tlog(folder / "b-huge.tlog")
    no_timeus_bin(folder / "c-notime.bin")
    nested_ulog(folder / "d-nested.ulg")
    os.symlink("/dev/zero", folder / "e-zero.tlog")
    (folder / "f-junk.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + os.urandom(3000))
    gappy_ulog(folder / "g-good.ulg", 200, 0.02)
    result, _ = review_set([folder], {".tlog", ".ulg", ".bin"},
                           lambda p, o: review_log(p, o, vehicle="x500"))
    rows = {os.path.basename(f["log"]): f for f in result["flights"]}
    assert len(rows) == 7
    assert rows["a-good.bin"]["error"] is None and rows["g-good.ulg"]["error"] is None
    assert rows["b-huge.tlog"]["error"] is None
    for bad in ("c-notime.bin", "d-nested.ulg", "e-zero.tlog", "f-junk.ulg"):
        assert rows[bad]["error"] and "\n" not in rows[bad]["error"]


def bogus_fmt_bin(path):
    """A DataFlash log with a format entry of length 2 (less than a message header) half-way through."""
    src = gappy_bin(path, 500, 0.02).read_bytes()
    cut = src.index(b"\xa3\x95", len(src) // 2)
    bogus = b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", 202, 2, b"BOGU", b"Q", b"TimeUS")
    path.write_bytes(src[:cut] + bogus + src[cut:])
    return path, len(src) - cut


def test_a_bogus_dataflash_format_entry_is_said_not_called_truncation(tmp_path):
    """On main: 'the file ends inside a message (truncated …)' while half the log was dropped."""
    path, lost = bogus_fmt_bin(tmp_path / "bogus.bin")
    rep, _ = review_log(path, vehicle="x500")
    said = [f for f in rep["findings"] if "damaged format entry (FMT)" in f]
    assert len(said) == 1 and "type 202 'BOGU' with length 2" in said[0] and f"remaining {lost + 89} bytes" in said[0]  # the 89-byte FMT too
    assert not any("truncated" in f for f in rep["findings"])
    torn = tmp_path / "torn.bin"  # a real truncation is still called one
    torn.write_bytes(gappy_bin(tmp_path / "ok.bin", 100, 0.02).read_bytes()[:-7])
    rep, _ = review_log(torn, vehicle="x500")
    assert any("truncated" in f for f in rep["findings"]) and not any("FMT" in f for f in rep["findings"])


def test_pyulog_warnings_never_reach_stdout_under_json(tmp_path):
    """A ULog with data of a topic never subscribed (msg_id 999): pyulog prints 'Warning: no subscription found
    …' to stdout; on main that broke --json."""
    src = gappy_ulog(tmp_path / "ok.ulg", 300, 0.02).read_bytes()
    (tmp_path / "corrupt.ulg").write_bytes(src + struct.pack("<HBH", 10, ord("D"), 999) + bytes(8))
    r = cli("review", tmp_path / "corrupt.ulg", "--vehicle", "x500", "--json")
    assert "Traceback" not in r.stderr
    rep = json.loads(r.stdout)  # the whole of stdout is the one JSON document
    assert sum("the ULog reader said: Warning: no subscription found" in f for f in rep["findings"]) == 1


@pytest.mark.parametrize("suffix", [".ulg", ".bin"])
def test_a_nan_range_is_no_reading_never_free_space(tmp_path, suffix):
    """On main a NaN range counted as free to the sensor's maximum: a flight flown blind reviewed as kept."""
    maker = MAKERS[suffix]
    seen, _ = review_log(maker(tmp_path / f"seen{suffix}", 500, 0.02, range_m=12.0, speed=2.0), vehicle="x500")
    assert seen["ranges"]["d_od"]["max"] == pytest.approx(40.0)  # the control: a reading, D_od its claimed range
    assert not any("flown outside the contract" in f for f in seen["findings"])
    blind, _ = review_log(maker(tmp_path / f"blind{suffix}", 500, 0.02, range_m=math.nan, speed=2.0), vehicle="x500")
    assert not blind["ok"] and not (blind["ranges"]["d_od"]["max"] or 0) > 0
    # every reading unusable is no obstacle data: said, with the time flown above V_safe it leaves unjudged
    assert any(f.startswith("no obstacle data") and "flown above V_safe" in f for f in blind["findings"])


def braking_bin(path, v=3.0, a=2.5):
    """A Copter flying AUTO at `v` along +x, switched to BRAKE at t = 10 s, stopping at `a`, then hovering."""
    from sitl_harness.flightlog import DataFlashWriter

    with DataFlashWriter(path) as w:
        w.write("MSG", 500, "ArduCopter V4.5.7 (abc1234)")
        w.write("ARM", 700, 1, 0, 0)
        w.write("MODE", 800, 3, 3, 0)
        w.write("EV", 900, 28)
        t, x = 0.02, 0.0
        while t < 16.0:
            us = round(t * 1e6)
            if abs(t - 10.0) < 0.01:
                w.write("MODE", us, 17, 17, 0)
            speed = v if t < 10.0 else max(0.0, v - a * (t - 10.0))
            x += speed * 0.02
            w.write("XKF1", us, 0, 0.0, 0.0, 0.0, speed, 0.0, 0.0, 0.0, x, 0.0, -5.0)
            w.write("ATT", us, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            w.write("CTUN", us, 0.45, 0.45, 0.45)
            t += 0.02
    return path


def test_the_calibrate_report_escapes_what_a_log_names(tmp_path):
    """On main a log named `<img src=x onerror=…>.bin` became markup in the report's table of stops."""
    from companion.ground.calibrate import calibrate
    from contracts.table import load_for_vehicle
    from contracts.vehicle import load_vehicle

    name = "<img src=x onerror=alert(1)>.bin"
    s = calibrate([braking_bin(tmp_path / name)], load_vehicle("x500"), load_for_vehicle("x500"), tmp_path / "cal.npz")
    assert [r["log"] for r in s["braking"]["stops"]] == [name]  # the stop is in the table
    page = (tmp_path / "cal.report.html").read_text()
    assert "<img src=x" not in page and "&lt;img src=x onerror=alert(1)&gt;.bin" in page


def test_control_characters_from_a_log_never_reach_the_terminal(tmp_path):
    """On main a ULog's ver_hw with ESC sequences printed a fake verdict line and hid the real one."""
    fake = "\x1b[2K\r\x1b[32mcontract kept\x1b[0m\x1b[8m"
    path = gappy_ulog(tmp_path / "esc\x1b[1m.ulg", 300, 0.02, ver_hw=fake)
    r = cli("review", path, "--vehicle", "x500")
    assert "Traceback" not in r.stderr and r.stdout
    for ch in ("\x1b", "\r", "\x9b"):
        assert ch not in r.stdout and ch not in r.stderr
    assert "?[32mcontract kept" in r.stdout  # shown, harmless
    r = cli("review", tmp_path / "gone\x1b[8m.ulg", "--vehicle", "x500")  # the error line too
    assert r.returncode == 2 and "\x1b" not in r.stderr and "gone?[8m.ulg" in r.stderr
    rep = json.loads(cli("review", path, "--vehicle", "x500", "--json").stdout)  # JSON keeps it, escaped
    assert rep["flight_log"]["vehicle"]["hardware"] == fake


ARDUPILOT_LOGS = SHARED.parent / "ardupilot"  # the real public ArduPilot logs, found as `test_flight_logs` finds the PX4 ones
VTOL_TLOG = ARDUPILOT_LOGS / "arduplane-vtol-2018.tlog"


@pytest.mark.skipif(not VTOL_TLOG.exists(), reason=f"the shared ArduPilot logs are not here ({ARDUPILOT_LOGS}; a "
                    "user's clone has none)")
def test_a_real_arduplane_tlog_is_recognised_as_a_fixed_wing():
    """On main this quadplane's .tlog (HEARTBEAT type 1) was judged as a multirotor: 'flown outside the
    contract … by up to 27.78 m/s', 120 spans."""
    with pytest.raises(ContractError, match=r"a fixed-wing log \(.*HEARTBEAT type 1, fixed wing\).*not reviewed"):
        review_log(VTOL_TLOG, vehicle="x500")
    # the control, a real quadrotor's .tlog still reviewed: tests/test_review_no_obstacles.py reviews the 23-minute
    # ArduCopter log in full; a .tlog of each multirotor type: the test below


def test_a_tlogs_vehicle_type_decides_whether_it_is_reviewed(tmp_path):
    for mav_type, kind in ((1, "fixed-wing"), (10, "ground rover")):
        with pytest.raises(ContractError, match=f"a {kind} log .*not reviewed"):
            review_log(gappy_tlog(tmp_path / f"t{mav_type}.tlog", 50, 0.02, mav_type=mav_type), vehicle="x500")
        from companion.ground.calibrate import read_log

        with pytest.raises(ContractError, match=f"a {kind} log"):
            read_log(tmp_path / f"t{mav_type}.tlog")
    for mav_type in (2, 13, 22, 0):  # a quadrotor, a hexarotor, a VTOL quadplane, generic: reviewed
        rep, _ = review_log(gappy_tlog(tmp_path / f"ok{mav_type}.tlog", 50, 0.02, mav_type=mav_type), vehicle="x500")
        assert rep["state_samples"] > 5


def test_calibrate_on_a_full_disk_is_one_line(tmp_path):
    """On main a write that fails (here: the file-size limit, as a full disk fails it) ended in a traceback."""
    import resource
    import signal

    def small_files():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    log = braking_bin(tmp_path / "stop.bin")
    r = subprocess.run([sys.executable, "-m", "companion.cli", "calibrate", str(log), "--vehicle", "x500", "--table",
                        "contracts/data/x500.npz", "--out", str(tmp_path / "out" / "cal.npz")], capture_output=True,
                       text=True, timeout=300, preexec_fn=small_files)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "cannot write the calibration to" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_damage_the_fuzz_found_is_read_past(tmp_path):
    """Two files the reader fuzz made: a ULog topic whose format has no timestamp (on main: KeyError), and a
    DataFlash MODE stamped past int64 (on main: OverflowError). Each is reviewed, the damaged part left out."""
    from sitl_harness.flightlog import DataFlashWriter

    src = gappy_ulog(tmp_path / "ok.ulg", 200, 0.02).read_bytes()
    (tmp_path / "notime.ulg").write_bytes(src.replace(b"vehicle_status:uint64_t timestamp;",
                                                      b"vehicle_status:uint64_t timeXXXXX;"))
    rep, origin = review_log(tmp_path / "notime.ulg", vehicle="x500")  # pyulog reads little past it
    assert "vehicle_status" not in origin.info["sources"].values()
    assert any(f.startswith("log lacks modes and arming (vehicle_status)") for f in rep["findings"])
    src = gappy_bin(tmp_path / "ok.bin", 200, 0.02).read_bytes()
    with DataFlashWriter(tmp_path / "probe.bin") as w:
        mode = bytes([w.type_of("MODE")])
    stamp = b"\xa3\x95" + mode + struct.pack("<Q", 800)
    assert src.count(stamp) == 1
    (tmp_path / "bigtime.bin").write_bytes(src.replace(stamp, b"\xa3\x95" + mode + struct.pack("<Q", 2**64 - 1)))
    rep, _ = review_log(tmp_path / "bigtime.bin", vehicle="x500")
    assert rep["state_samples"] > 10


def test_a_ulog_parameter_that_is_not_a_number_is_a_finding(tmp_path):
    """A ULog parameter whose type the fuzz changed to characters (`char[4] MAV_TYPE`: its value is text, not a
    number; on 7bd4f49 the reader raised ValueError, and the log was one error line, not reviewed) is left out and
    said, the rest of the log reviewed."""
    src = gappy_ulog(tmp_path / "ok.ulg", 200, 0.02).read_bytes()
    assert src.count(b"int32_t MAV_TYPE") == 1
    (tmp_path / "textparam.ulg").write_bytes(src.replace(b"int32_t MAV_TYPE", b"char[4] MAV_TYPE"))
    rep, origin = review_log(tmp_path / "textparam.ulg", vehicle="x500")
    assert "log damaged: 1 parameter(s) not a finite number, ignored: 'MAV_TYPE'" in rep["findings"]
    assert rep["state_samples"] > 10 and "MAV_TYPE" not in origin.info["params"]


def test_a_dataflash_parameter_that_is_not_finite_is_a_finding(tmp_path):
    """A PARM value the fuzz made infinite or NaN (FRAME_CLASS inf; on 7bd4f49: OverflowError from `int`, the log one
    error line) is no setting of the autopilot's: left out and said, the rest of the log reviewed."""
    path = gappy_bin(tmp_path / "inf.bin", 200, 0.02, params={"FRAME_CLASS": math.inf, "ANGLE_MAX": math.nan})
    rep, origin = review_log(path, vehicle="x500")
    assert "log damaged: 2 parameter(s) not a finite number, ignored: 'ANGLE_MAX', 'FRAME_CLASS'" in rep["findings"]
    assert rep["state_samples"] > 10 and origin.info["vehicle"]["airframe"] == "copter"
