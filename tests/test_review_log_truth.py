"""What a replayed log says of the flight, told truthfully: a silence of the link that recorded the log (a ground
station's radio dropping out) is a gap in the recording, not a failsafe of the vehicle or of the daemon; the
flight ends where the vehicle disarms, not where the replay's daemon lost the recording; a range sensor that looks
off the path (a downward rangefinder) is named and said not to be an obstacle sensor. A crafted ground-station
`.tlog` and DataFlash log of known truth, then the real ArduCopter and PX4 logs beside the repository.

Each replay's own event log, read as the live daemon's (no replay origin), shows what the review used to say:
the negative control that each rule is the review's and can fail."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from crafted_logs import copter_sample

from companion.ground.commands import review_log
from companion.ground.flightlogs.flightspan import flight_end, off_path_sensors
from companion.ground.review import format_report, review
from companion.onboard.logschema import REPLAY_LOG_FILE
from sitl_harness.flightlog import DataFlashWriter

ROOT = Path(__file__).resolve().parents[1]
LOGS = ROOT.parent / "shared" / "logs"
ARDUCOPTER = LOGS / "ardupilot" / "arducopter-2015-23min.tlog"
PX4_GAPPY = LOGS / "px4" / "sample_appended_multiple.ulg"
needs_arducopter = pytest.mark.skipif(not ARDUCOPTER.exists(),
                                      reason=f"../shared/logs not present: {ARDUCOPTER} (a user's clone has none)")
needs_px4 = pytest.mark.skipif(not PX4_GAPPY.exists(),
                               reason=f"../shared/logs not present: {PX4_GAPPY} (a user's clone has none)")


def _as_live_daemons(out: Path) -> dict:
    """The replay's event log reviewed as if the daemon had written it in flight: the old reading."""
    return review(out / REPLAY_LOG_FILE)


# ------------------------------------------------------------------ a ground station's tlog of known truth

ARM_S, GAP_AT_S, GAP_S, DISARM_S, STREAM_END_S, LOG_END_S = 2.0, 20.0, 4.0, 40.0, 45.0, 100.0
PARAM_AT_S = 10  # after the replay's start-up checks gave up waiting (5 s)


def ground_station_tlog(path: Path) -> Path:
    """A quadrotor's stream as a ground station records it: its own HEARTBEAT (GCS, 255/190) every second to the
    end; the autopilot's HEARTBEAT at 1 Hz and position, attitude and a downward DISTANCE_SENSOR (id 3,
    orientation 25) at 5 Hz; armed at ARM_S, the radio silent for GAP_S from GAP_AT_S, disarmed at DISARM_S, the
    autopilot's stream gone at STREAM_END_S (the vehicle powered off) while the ground station logs on to LOG_END_S;
    ANGLE_MAX, asked for by the ground station, at PARAM_AT_S."""
    from pymavlink.dialects.v20 import common as mav

    ap, gcs = mav.MAVLink(None, srcSystem=1, srcComponent=1), mav.MAVLink(None, srcSystem=255, srcComponent=190)
    t0_us = 1_790_000_000_000_000
    with open(path, "wb") as out:
        for k in range(int(LOG_END_S * 5) + 1):
            t = k / 5
            stamp = struct.pack(">Q", t0_us + round(t * 1e6))
            if k % 5 == 0:
                out.write(stamp + gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs))
            if t >= STREAM_END_S or GAP_AT_S < t < GAP_AT_S + GAP_S:
                continue
            ms = round(t * 1000)
            if k == PARAM_AT_S * 5:  # the one checked parameter the ground station asked for, late
                out.write(stamp + ap.param_value_encode(b"ANGLE_MAX", 3500.0, 9, 500, 7).pack(ap))
            if k % 5 == 0:
                armed = 128 if ARM_S <= t < DISARM_S else 0
                out.write(stamp + ap.heartbeat_encode(2, 3, 1 | armed, 5, 4).pack(ap))
            out.write(stamp + ap.local_position_ned_encode(ms, 0.0, 0.0, -5.0, 0.0, 0.0, 0.0).pack(ap))
            out.write(stamp + ap.attitude_encode(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).pack(ap))
            out.write(stamp + ap.distance_sensor_encode(ms, 20, 700, 480, 0, 3, 25, 100).pack(ap))
            if k % 25 == 0:  # and a side-looking one no configured sensor matches (the assumed one looks forward)
                out.write(stamp + ap.distance_sensor_encode(ms, 20, 4000, 900, 0, 4, 2, 100).pack(ap))
    return path


@pytest.fixture(scope="module")
def gcs_replay(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gcs")
    out = tmp / "out"
    rep, origin = review_log(ground_station_tlog(tmp / "gcs.tlog"), out, vehicle="x500")
    return rep, origin, format_report(rep, origin), out


def test_a_ground_stations_radio_gap_is_a_gap_in_the_recording_not_a_failsafe(gcs_replay):
    rep, _, text, _ = gcs_replay
    assert rep["failsafe_count"] == 0 and "failsafes: 0" in text
    assert not any("failsafe(s)" in f or "link down" in f for f in rep["findings"])
    gaps = [f for f in rep["findings"] if f.startswith("ground-station telemetry gaps: 1 ")]
    assert len(gaps) == 1 and "not failsafes of the vehicle or of the daemon" in gaps[0]
    fl = rep["replay"]["flight"]
    assert fl["gaps"] == 1 and fl["longest_gap"]["silent_s"] == pytest.approx(GAP_S, abs=0.01)
    assert fl["longest_gap"]["t"] == pytest.approx(GAP_AT_S, abs=0.01)
    assert rep["log_silence_entries"] == 2  # the gap, and the autopilot's stream's end


def test_a_ground_stations_radio_gap_read_as_the_live_daemons_log_is_a_failsafe(gcs_replay):
    """Negative control: the same records without the replay's origin: the old "failsafe(s)" and "link down"."""
    old = _as_live_daemons(gcs_replay[3])
    assert old["failsafe_count"] == 2
    assert any("× into the failsafe state (link lost)" in f for f in old["findings"])
    assert any(f.startswith("autopilot link down") for f in old["findings"])
    assert old["flight_end"]["why"] == "failsafe: autopilot heartbeat lost"


def test_the_flight_ends_where_the_vehicle_disarms_not_where_the_recording_stops(gcs_replay):
    rep, _, text, out = gcs_replay
    fe = rep["flight_end"]
    assert fe["why"] == "disarmed" and fe["t"] == pytest.approx(DISARM_S, abs=0.05)
    assert f"the autopilot's stream ends at t = {STREAM_END_S - 1:.1f} s" in fe["note"]
    assert f"runs on to t = {LOG_END_S:.1f} s" in fe["note"]
    assert f"flight ended: disarmed (t = {DISARM_S:.2f} s)" in text
    # negative control: the live daemon's reading ends it where the replay lost the recording's link
    old = _as_live_daemons(out)["flight_end"]
    assert old["t"] > STREAM_END_S and old["why"].startswith("failsafe")


def test_a_downward_rangefinder_is_named_and_not_taken_as_d_od(gcs_replay):
    rep, _, text, _ = gcs_replay
    down, side = rep["replay"]["other_sensors"]  # by id
    assert down["what"] == "DISTANCE_SENSOR id 3 from 1/1" and down["facing"] == "down" and down["samples"] == 206
    assert side["what"] == "DISTANCE_SENSOR id 4 from 1/1" and side["facing"].startswith("facing ROTATION_YAW_90")
    assert ("a rangefinder (DISTANCE_SENSOR id 4 from 1/1, facing ROTATION_YAW_90, where no configured sensor looks; "
            in text and "it is not one of the configured obstacle sensors" in text)
    assert ("a downward rangefinder (DISTANCE_SENSOR id 3 from 1/1, orientation down; " in text
            and "it is not an obstacle sensor: its readings are not taken as D_od" in text)
    assert rep["ranges"]["d_od"]["max"] == 0.0  # not D_od: the assumed sensor looks forward
    assert "obstacle data (DISTANCE_SENSOR: D_od is 0 throughout)" in rep["replay"]["missing_streams"]


def test_a_parameter_the_tlog_holds_late_is_not_said_unreported(gcs_replay):
    """The replay cannot ask for the parameters its start-up checks read: it has those the ground station asked
    for, when it did. The finding says so, and where the tlog holds each."""
    rep, _, text, out = gcs_replay
    assert "1 failed start-up check(s): the log holds no ANGLE_MAX in time for the replay's check" in rep["findings"]
    assert (f"the start-up checks' parameters in the tlog: ANGLE_MAX (t = {PARAM_AT_S:.1f} s); not in it: "
            "WPNAV_ACCEL, WPNAV_JERK, GUID_TIMEOUT") in text
    # negative control: read as the live daemon's log, the autopilot "did not report" it
    assert "1 failed start-up check(s): autopilot did not report ANGLE_MAX" in _as_live_daemons(out)["findings"]


# ------------------------------------------------------------------ the rule itself

def _flight(spans, stream_end, log_end, known=True):
    return {"armed_known": known, "armed_spans": spans, "armed_count": len(spans), "stream_end_t": stream_end,
            "log_end_t": log_end, "gap_limit_s": 1.5}


def test_flight_end_by_arming():
    daemon = {"t": 50.0, "why": "failsafe: autopilot heartbeat lost"}
    assert flight_end(_flight([[1.0, 9.0], [12.0, 30.0]], 60.0, 60.0), daemon) == {
        "t": 30.0, "why": "disarmed", "note": "armed 2× in the log, the last from t = 12.0 s"}
    end = flight_end(_flight([[12.0, None]], 60.0, 60.0), None)
    assert end["t"] == 60.0 and end["why"].startswith("still armed at the log's end")
    end = flight_end(_flight([[12.0, None]], 40.0, 60.0), None)
    assert end["t"] == 40.0 and "not in the log" in end["why"] and "runs on to t = 60.0 s" in end["note"]
    assert flight_end(_flight([], 60.0, 60.0), daemon) == {"t": None, "why": "the log never shows the vehicle armed"}
    assert flight_end(_flight([], 60.0, 60.0, known=False), daemon) is daemon  # no arming in the log: the daemon's
    hold = {"t": 20.0, "why": "hold: no safe speed"}
    assert "last stopped on hold: no safe speed at t = 20.0 s" in flight_end(_flight([[12.0, 30.0]], 60, 60), hold)["note"]


def test_the_last_of_many_armings_ends_the_flight():
    from companion.ground.flightlogs.flightspan import LISTED, Watch

    w = Watch(1.5)
    for k in range(3 * LISTED):
        w.stream(float(k), float(k))
        w.armed(float(k), k % 2 == 0)
    r = w.result(3.0 * LISTED)
    assert len(r["armed_spans"]) == LISTED and r["armed_count"] == 3 * LISTED // 2
    assert flight_end(r, None)["t"] == 3 * LISTED - 1  # the last disarm, not the LISTED-th


def test_off_path_sensors_by_orientation():
    assert off_path_sensors("RFND", [0, 25, 25, 24, 7, 12]) == [
        {"what": "RFND", "facing": "orientation 12, not horizontal", "samples": 1},
        {"what": "RFND", "facing": "up", "samples": 1}, {"what": "RFND", "facing": "down", "samples": 2}]


# ------------------------------------------------------------------ a DataFlash log of known truth

def test_a_dataflash_logs_downward_rangefinder_and_its_disarm(tmp_path):
    """A Copter flight with a downward rangefinder only (RFND Orient 25), disarmed at 15 s, logging on to 20 s."""
    path = tmp_path / "down.bin"
    with DataFlashWriter(path) as w:
        w.write("MSG", 500, "ArduCopter V4.5.7 (abc1234)")
        for n, v in {"ANGLE_MAX": 3500, "WPNAV_ACCEL": 250, "RNGFND1_MAX_CM": 700, "RNGFND1_MIN_CM": 20}.items():
            w.write("PARM", 1000, n, float(v))
        w.write("ARM", 2000, 1, 0, 0)
        w.write("MODE", 3000, 5, 5, 0)
        w.write("EV", 4000, 28)
        t = 0.01
        while t < 20.0:
            us = int(t * 1e6)
            copter_sample(w, us, 0.0, 0.0, range_m=None)
            w.write("RFND", us, 0, 4.8, 4, 25)
            if abs(t - 15.0) < 0.01:
                w.write("ARM", us, 0, 0, 0)
            t += 0.02
    rep, origin = review_log(path, vehicle="x500")
    text = format_report(rep, origin)
    assert rep["flight_log"]["other_sensors"] == [{"what": "RFND", "facing": "down", "samples": 1000}]
    assert "a downward rangefinder (RFND, orientation down; 1000 samples) is present; it is not an obstacle sensor" in text
    assert sum("D_od is unknown" in f for f in rep["findings"]) == 1  # and still no obstacle sensing
    assert rep["flight_end"]["why"] == "disarmed" and rep["flight_end"]["t"] == pytest.approx(15.0, abs=0.05)


# ------------------------------------------------------------------ the real logs

@pytest.fixture(scope="module")
def arducopter(tmp_path_factory):
    out = tmp_path_factory.mktemp("arducopter") / "out"
    rep, origin = review_log(ARDUCOPTER, out, vehicle="x500")
    return rep, origin, format_report(rep, origin), out


@needs_arducopter
def test_the_real_arducopters_radio_dropouts_are_telemetry_gaps(arducopter):
    rep, _, text, out = arducopter
    assert rep["failsafe_count"] == 0 and "failsafe(s)" not in text
    fl = rep["replay"]["flight"]
    assert rep["replay"]["recorder"] == "ground station"
    assert fl["gaps"] == 15 and fl["longest_gap"]["silent_s"] == pytest.approx(6.9, abs=0.1)
    assert sum(f.startswith("ground-station telemetry gaps: 15 ") for f in rep["findings"]) == 1
    # negative control: the same event log read as a live daemon's: the "16 failsafes" the review used to print
    assert "16 failsafe(s): 16 × into the failsafe state (link lost)" in _as_live_daemons(out)["findings"]


@needs_arducopter
def test_the_real_arducopters_flight_ends_at_its_last_disarm(arducopter):
    rep, _, text, out = arducopter
    fe = rep["flight_end"]
    assert fe["why"] == "disarmed" and fe["t"] == pytest.approx(1037.7, abs=0.2)
    assert "armed 7× in the log" in fe["note"] and "runs on to t = 1377.0 s (325 s) without it" in fe["note"]
    assert rep["replay"]["other_sensors"] == []  # it carries no rangefinder (RNGFND_TYPE 0): none named
    assert "rangefinder" not in text
    old = _as_live_daemons(out)["flight_end"]  # negative control: where the replay lost the recording's link
    assert old == {"t": pytest.approx(1053.26, abs=0.1), "why": "failsafe: autopilot heartbeat lost"}


# ------------------------------------------------------------------ a ULog's snapshot from before its start

SNAPSHOT_BEFORE_S, ULOG_START_US, ULOG_S = 20.0, 30_000_000, 10.0


def snapshot_ulog(path: Path) -> Path:
    """A PX4 hover logged for ULOG_S from ULOG_START_US, whose `vehicle_status` (armed) is the logger's snapshot
    at its start: one sample published SNAPSHOT_BEFORE_S before logging began, as PX4's logger writes it."""
    from sitl_harness.flightlog import Px4Log
    from sitl_harness.ulog_writer import ULogWriter

    topics = ("vehicle_local_position", "vehicle_attitude", "vehicle_status", "vehicle_land_detected")
    w = ULogWriter(path, ULOG_START_US)
    for name in topics:
        w.define(name, Px4Log.TOPICS[name])
    w.info("sys_name", "PX4")
    w.info("ver_hw", "PX4_SITL")
    w.param("MAV_TYPE", 2, True)
    ids = {name: w.add(name) for name in topics}
    w.data(ids["vehicle_status"], {"timestamp": ULOG_START_US - round(SNAPSHOT_BEFORE_S * 1e6), "nav_state": 4,
                                   "arming_state": 2, "vehicle_type": 1})
    for k in range(int(ULOG_S * 10) + 1):
        us = ULOG_START_US + k * 100_000
        w.data(ids["vehicle_local_position"], {"timestamp": us, "xy_valid": True, "z_valid": True, "v_xy_valid": True,
                                               "v_z_valid": True, "z": -5.0})
        w.data(ids["vehicle_attitude"], {"timestamp": us, "q": [1.0, 0.0, 0.0, 0.0]})
        w.data(ids["vehicle_land_detected"], {"timestamp": us, "landed": False})
    w.close()
    return path


def test_a_ulogs_snapshot_from_before_its_start_is_no_gap(tmp_path):
    from pyulog import ULog

    path = snapshot_ulog(tmp_path / "snapshot.ulg")
    raw = ULog(str(path))  # the trap is in the file: a sample stamped 20 s before the log's start
    status = next(d for d in raw.data_list if d.name == "vehicle_status")
    assert raw.start_timestamp - int(status.data["timestamp"][0]) == SNAPSHOT_BEFORE_S * 1e6
    rep, origin = review_log(path, vehicle="x500")
    info = rep["flight_log"]
    assert info["span_s"] == pytest.approx(ULOG_S, abs=0.01)  # was 30 s "of a 10 s log"
    assert info["stamped_before_start"] == ["vehicle_status"] and "predates the log's start" in format_report(rep, origin)
    assert info["flight"]["gaps"] == 0 and not info.get("gaps_skipped")  # was a 20 s silence at t = 0, cut out
    assert rep["failsafe_count"] == 0
    assert rep["flight_end"]["why"].startswith("still armed at the log's end")


@needs_px4
def test_the_real_ulogs_say_no_failsafe_and_span_no_more_than_the_log(tmp_path):
    for path in sorted(PX4_GAPPY.parent.glob("*.ulg")):
        rep, _ = review_log(path, vehicle="x500")
        info = rep["flight_log"]
        assert rep["failsafe_count"] == 0, path.name
        assert info["span_s"] <= info["log_duration_s"] + 0.5, path.name  # was 19.7 s of a 9.77 s log, and others
        assert not any("gaps in the autopilot's log" in f for f in rep["findings"]), path.name  # none is gappy
