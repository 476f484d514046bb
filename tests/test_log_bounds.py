"""Every flight-log reader is bounded: the review's cost grows with a log's size, not the time it spans (a
long silence is stepped through only until the daemon has gone stale, then cut out), in every format the
review takes — PX4 ULog, ArduPilot DataFlash, MAVLink .tlog and the daemon's own event log. Bounded by
counts (loop steps, state samples written), never by wall time."""

from __future__ import annotations

import csv

import pytest

from companion.ground.commands import review_log
from companion.onboard.config import Config
from companion.ground.flightlogs.tlog import stepped_silence
from crafted_logs import MAKERS, gappy_events

N, GAP_S = 15, 299.0  # a small log spanning 70 minutes (the bound is per silence: 15 show it as 60 would)


@pytest.mark.parametrize("suffix", sorted(MAKERS))
def test_a_long_silence_is_cut_not_stepped_through(tmp_path, suffix):
    path = MAKERS[suffix](tmp_path / f"gappy{suffix}", N, GAP_S)
    rep, origin = review_log(path, tmp_path / "out", vehicle="x500")
    info = origin.info
    cfg = Config()
    per_gap = stepped_silence(cfg) * cfg.loop_hz + 2  # steps through one silence before it is cut
    assert info["steps"] <= N * per_gap  # before the cut: 15 × 299 s × 50 Hz ≈ 224 000 steps
    assert info["gaps_skipped"] == N - 1 and info["skipped_s"] > (N - 1) * (GAP_S - 10)
    assert rep["state_samples"] <= N * stepped_silence(cfg) * 10 + 20  # ≤ 10 Hz of state samples while stepped
    with open(tmp_path / "out" / "samples.csv") as fh:
        assert sum(1 for _ in csv.reader(fh)) - 1 == rep["state_samples"]
    assert rep["span"]["duration_s"] < N * (stepped_silence(cfg) + 1)
    assert sum("silence(s) in the log" in f and "cut out" in f for f in rep["findings"]) == 1


def test_an_event_log_with_long_silences_costs_its_records(tmp_path):
    """The daemon's own log is read record by record: 60 samples 299 s apart are 60 rows, not 5 h of them."""
    log = gappy_events(tmp_path / "run", N, GAP_S)
    rep, origin = review_log(log.parent, tmp_path / "out")
    assert origin is None and rep["state_samples"] == N
    assert rep["span"]["duration_s"] == pytest.approx(1.0 + (N - 1) * GAP_S)  # from the start event at 0
    with open(tmp_path / "out" / "samples.csv") as fh:
        assert sum(1 for _ in csv.reader(fh)) - 1 == N


def test_the_wall_time_bound_stops_a_reader_and_nests(tmp_path):
    """A reader that never returns is stopped by the registry's bound, as one line; an inner bound leaves the
    outer one running."""
    import time

    from companion.ground import flightlogs
    from companion.ground.flightlogs import _Timeout, guarded, time_bound
    from contracts.errors import ContractError

    def forever():
        while True:
            time.sleep(0.01)

    path = MAKERS[".bin"](tmp_path / "x.bin", 3, 0.02)
    saved = flightlogs.MAX_SECONDS
    flightlogs.MAX_SECONDS = 0.2
    try:
        with pytest.raises(ContractError, match="took longer than 0.2 s"):
            guarded(path, "test log", forever)
    finally:
        flightlogs.MAX_SECONDS = saved
    with pytest.raises(_Timeout):
        with time_bound(0.3):
            with time_bound(10.0):
                pass
            forever()  # the outer bound still fires after the inner one ended


def test_the_in_flight_daemons_values_are_moved_with_the_cuts():
    """A .tlog's in-flight NAMED_VALUE_FLOATs are compared with the replay on the replay's time axis: after a
    silence is cut out, their log times move earlier by what was cut before them."""
    from companion.ground.flightlogs.tlog import cut_time, in_log_time

    t = [0, 20_000, 100_000_000, 100_020_000, 400_000_000]
    seen = []
    run = in_log_time(t, 50.0, lambda i, at: seen.append(at), lambda tick: None, 4.0)
    assert run["gaps_skipped"] == 2 and len(run["cuts"]) == 2
    assert [cut_time(run["cuts"], x) for x in t] == pytest.approx(seen, abs=1)  # the replay's own times
    assert cut_time(run["cuts"], 10_000) == 10_000
