"""Calibration cannot outrun its evidence: a cell goes below the SITL's E_tr_pred (a contract faster than stock)
only on windows from enough distinct flights; copies of a log and logs of one flight count once; a faster table
is refused unless a person accepts it; the evidence is shown per cell (report, `table show`)."""

from __future__ import annotations

import json
import math
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.ground.calibrate import calibrate, flights_of
from contracts.errors import ContractError
from contracts.table import load_for_vehicle, verify
from contracts.vehicle import load_vehicle

ROOT = Path(__file__).resolve().parents[1]
DAY_US = 86_400_000_000
EPOCH_US = 1_790_000_000_000_000
PX4_MISSION = (4 << 16) | (4 << 24)  # PX4 custom mode: main AUTO, sub MISSION


def crafted_tlog(path: Path, day: int = 0, cruise_s: float = 60.0, v: float = 5.99, tilt_deg: float = 34.0,
                 extra: bytes = b"", wiggle: int = 0) -> Path:
    """A ground station's .tlog of a flight that never was: 30 s of hover (so the hover throttle says thrust 1.0),
    then `cruise_s` at `v` m/s and `tilt_deg`, the commanded path exactly where the vehicle is (no tracking error):
    at the X500's D_od 6 m, R_obst 0.5 m fixed point (6 m/s, 35°). `day`: the same flight stamped that many days
    later; `wiggle` > 0: another flight, its cruise speed dipping up to 0.15 m/s every 2 + `wiggle` s (its windows
    the same cells: a window's speed is the largest in it and the 8 s before)."""
    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()
    t0 = EPOCH_US + day * DAY_US

    def put(t, msg):
        out.extend(struct.pack(">Q", t0 + int(t * 1e6)) + msg.pack(m))

    x = 0.0
    for n in range(int((30.0 + cruise_s) * 10)):
        t = n / 10.0
        moving = t >= 30.0
        vx = v if moving else 0.0
        if moving and wiggle:
            vx -= 0.15 * (1.0 - math.cos(2 * math.pi * (t - 30.0) / (2.0 + wiggle))) / 2
        x += vx * 0.1
        if n % 10 == 0:
            put(t, m.heartbeat_encode(2, 12, 1 | 128, PX4_MISSION, 4))
            put(t, m.extended_sys_state_encode(0, 2))  # MAV_LANDED_STATE_IN_AIR
        tms = int(t * 1000)
        put(t, m.local_position_ned_encode(tms, x, 0.0, -5.0, vx, 0.0, 0.0))
        put(t, m.attitude_encode(tms, 0.0, -math.radians(tilt_deg) if moving else 0.0, 0.0, 0.0, 0.0, 0.0))
        put(t, m.position_target_local_ned_encode(tms, 1, 0, x, 0.0, -5.0, vx, 0, 0, 0, 0, 0, 0, 0))
        put(t, m.vfr_hud_encode(vx, vx, 0, 58, -5.0, 0.0))  # throttle 58 % (the X500's hover: 0.585)
    path.write_bytes(bytes(out) + extra)
    return path


@pytest.fixture(scope="module")
def x500():
    return load_vehicle("x500"), load_for_vehicle("x500")


def _v_max(table):
    return table.omega(6.0, 0.5, 0.0, 1.0).v_max  # the review's scenario: D_od 6 m, R_obst 0.5 m, thrust 1.0


def test_one_crafted_flight_no_longer_raises_v_max(x500, tmp_path):
    """One .tlog flown perfectly at 6 m/s and 35° covers the fixed point's cell (60 windows): today's calibrate takes
    it below the SITL's value there and V_max at D_od 6 m rises 5.98 -> 6.18 m/s; one flight is not the evidence."""
    veh, stock = x500
    log = crafted_tlog(tmp_path / "crafted.tlog")
    s = calibrate([log], veh, stock, tmp_path / "new.npz", report=False)
    new = verify(tmp_path / "new.npz")
    assert s["coverage"]["covered_cells"] >= 1 and s["flights"] == 1
    assert np.all(new.e_pred.values >= stock.e_pred.values)
    assert _v_max(new) <= _v_max(stock) + 1e-9
    assert s["faster_cells"] == 0 and not any("FASTER" in f for f in s["findings"])
    cell = [r for r in s["evidence"] if r["windows"] >= 22]
    assert cell and all(r["flights"] == 1 and r["worst_m"] == pytest.approx(0.0, abs=1e-6) for r in cell)


def test_eleven_identical_copies_are_one_flight(x500, tmp_path):
    """A short crafted flight (10 cruise windows: its cell not covered) copied eleven times: today 110 windows cover it;
    the copies share a content hash and count once."""
    veh, stock = x500
    one = crafted_tlog(tmp_path / "f0.tlog", cruise_s=10.0)
    logs = [one] + [Path(shutil.copy(one, tmp_path / f"copy{k}.tlog")) for k in range(1, 11)]
    s1 = calibrate([one], veh, stock, tmp_path / "one.npz", report=False)
    s11 = calibrate(logs, veh, stock, tmp_path / "eleven.npz", report=False)
    assert s11["flights"] == 1 and s11["samples"] == s1["samples"]
    assert s11["coverage"]["covered_cells"] == s1["coverage"]["covered_cells"]  # (the hover's cell only)
    cruise = [r for r in s11["evidence"] if r["v_max"] == 6.0 and round(r["tilt_deg"]) == 35 and r["thrust_ratio"] == 1.0]
    assert cruise and cruise[0]["windows"] < 22 and cruise[0]["flights"] == 1  # 10 windows: not covered
    assert sum("not_counted" in lg for lg in s11["logs"]) == 10
    assert all("identical content" in lg["not_counted"] for lg in s11["logs"][1:])
    assert np.array_equal(verify(tmp_path / "eleven.npz").e_pred.values, verify(tmp_path / "one.npz").e_pred.values)


def test_logs_of_one_flight_overlapping_in_time_count_once(x500, tmp_path):
    """A second log of the same flight (other bytes, the same hours): one flight."""
    veh, stock = x500
    a = crafted_tlog(tmp_path / "gcs.tlog")
    b = crafted_tlog(tmp_path / "router.tlog", extra=b"\x00" * 8)  # other content, same time span
    c = crafted_tlog(tmp_path / "next-day.tlog", day=1, wiggle=1)  # another flight, the next day
    assert flights_of([{"sha256": "a", "wall_span": (0, 10)}, {"sha256": "b", "wall_span": (5, 20)},
                       {"sha256": "c", "wall_span": (20, 30)}, {"error": "x"}, {"sha256": "a", "wall_span": None}]) \
        == [0, 0, 2, None, 0]
    s = calibrate([a, b, c], veh, stock, tmp_path / "n.npz", report=False)
    assert s["flights"] == 2
    assert "overlapping time span" in s["logs"][1]["not_counted"] and "not_counted" not in s["logs"][2]


def test_faster_than_stock_is_refused_without_the_flag_and_shown_per_cell(x500, tmp_path):
    """Three distinct crafted flights are evidence enough to go below the SITL's value: that makes the table faster
    than stock, which calibrate refuses (one line, exit 2, the report written) unless --accept-faster."""
    logs = [crafted_tlog(tmp_path / f"day{d}.tlog", day=d, wiggle=d) for d in range(3)]
    out = tmp_path / "fast.npz"
    cmd = [sys.executable, "-m", "companion.cli", "calibrate", *map(str, logs), "--vehicle", "x500", "--table", "x500",
           "--out", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=str(ROOT), timeout=300)
    assert r.returncode == 2, r.stdout + r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert "faster than the stock table" in r.stderr and "--accept-faster" in r.stderr and "3 flight(s)" in r.stderr
    assert not out.exists()  # nothing the daemon could load
    rep = json.loads(out.with_suffix(".report.json").read_text())
    assert rep["faster_cells"] >= 1 and any(e["faster"] and e["flights"] == 3 for e in rep["evidence"])
    assert "FASTER than stock" in out.with_suffix(".report.html").read_text()
    from companion.ground.keys import table_key_pair

    keys = table_key_pair(tmp_path / "keys")
    r = subprocess.run([*cmd, "--accept-faster", "--sign-key", keys["private_key"]], capture_output=True, text=True,
                       cwd=str(ROOT), timeout=300)
    assert r.returncode == 0, r.stderr
    assert "accepted with --accept-faster" in r.stdout and "signed with key" in r.stdout
    _, stock = x500
    new = verify(out, public_key=keys["public_key"])  # the accepted table, signed by the person who accepted it
    assert _v_max(new) > _v_max(stock)  # what was accepted: a faster contract, by a person
    assert np.all(new.e_pred.values >= 0.5 * stock.e_pred.values - 1e-12)  # never below the floor
    show = subprocess.run([sys.executable, "-m", "companion.cli", "table", "show", str(out)], capture_output=True,
                          text=True, cwd=str(ROOT), timeout=120)
    assert "calibration evidence: 3 distinct flight(s)" in show.stdout and "accepted by a person" in show.stdout
    assert "windows from 3 flight(s)" in show.stdout and "FASTER than stock" in show.stdout
    from companion.onboard.console import controller_coverage  # the daemon's start banner

    assert "FASTER than stock, accepted by a person" in controller_coverage(new)


def test_refusal_from_the_api_is_one_contract_error(x500, tmp_path):
    veh, stock = x500
    logs = [crafted_tlog(tmp_path / f"d{d}.tlog", day=d, wiggle=d) for d in range(3)]
    with pytest.raises(ContractError, match="faster than the stock table") as e:
        calibrate(logs, veh, stock, tmp_path / "x.npz", report=False)
    assert "\n" not in str(e.value)


# ----------------------------------------------------------------------------- one flight, however stamped


def test_one_flight_restamped_by_one_and_two_days_is_one_flight(x500, tmp_path):
    """The same flown samples stamped a day and two days later (other bytes, other time spans): one flight, so
    no evidence to go below the SITL's value, the table not faster than stock."""
    veh, stock = x500
    logs = [crafted_tlog(tmp_path / f"day{d}.tlog", day=d) for d in range(3)]
    assert len({lg.read_bytes() for lg in logs}) == 3  # other files, other time stamps
    s = calibrate(logs, veh, stock, tmp_path / "n.npz", report=False)
    assert s["flights"] == 1 and s["faster_cells"] == 0
    assert [("same flown samples" in lg.get("not_counted", "")) for lg in s["logs"]] == [False, True, True]
    assert "+24.0 h" in s["logs"][1]["not_counted"] and "+48.0 h" in s["logs"][2]["not_counted"]
    assert _v_max(verify(tmp_path / "n.npz")) <= _v_max(stock) + 1e-9


def test_negative_control_judged_by_stamps_and_hashes_the_restamped_flight_was_three(x500, tmp_path, monkeypatch):
    """The old rule (time stamps and file hashes only, the content never compared): the same three logs are three
    distinct flights, enough evidence for calibrate to make the contract faster than stock."""
    from contracts import calibrate as cal

    veh, stock = x500
    logs = [crafted_tlog(tmp_path / f"day{d}.tlog", day=d) for d in range(3)]
    monkeypatch.setattr(cal, "same_flight", lambda a, b: None)
    with pytest.raises(ContractError, match=r"faster than the stock table .* on evidence from 3 flight\(s\)"):
        calibrate(logs, veh, stock, tmp_path / "n.npz", report=False)


def test_content_tells_flights_apart_not_stamps():
    """Pure: a flight's series against itself shifted, cut, re-framed, and against other flights."""
    from contracts.calibrate import flight_series, same_flight

    rng = np.random.default_rng(1)
    t = np.arange(0, 300, 0.1)
    v = np.column_stack([3 + np.sin(t / 7), np.cos(t / 5), 0.1 * np.sin(t)]) + rng.normal(0, 0.05, (len(t), 3))
    a = flight_series(t, v)
    assert same_flight(a, flight_series(t + 86400.0, v)) == 0.0  # re-stamped
    rot = np.column_stack([-v[:, 1], v[:, 0], v[:, 2]])  # the frame turned 90°
    assert same_flight(a, flight_series(t, rot)) == 0.0
    cut = same_flight(a, flight_series(t[500:] + 3600.0, v[500:]))  # the first 50 s cut off, stamped an hour on
    assert cut == pytest.approx(50.0)
    other = v + rng.normal(0, 0.05, v.shape)  # the same plan flown again: other noise
    assert same_flight(a, flight_series(t, other)) is None
    assert same_flight(a, flight_series(t[:30], v[:30])) is None  # 3 s: too short to tell
