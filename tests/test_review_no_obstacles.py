"""A log without obstacle data (no range sensor: D_od 0 throughout) is reviewed for what a team can act on:
the detection range each stretch needed under the contract (checked against the table's own lookup), and with
an assumed sensor the limits it would have set and the time they would have cost — not "outside the
contract" everywhere. A scripted flight of known speeds, then the real ArduCopter and PX4 logs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from companion.ground.commands import review_log
from companion.ground.detection_need import Sensor
from companion.onboard.eventlog import EventLog
from companion.ground.review import format_report, review
from contracts.table import load_for_vehicle

# the public logs beside the repository (not in a user's clone): the first ancestor holding shared/logs
LOGS = next((p / "shared" / "logs" for p in Path(__file__).resolve().parents if (p / "shared" / "logs").is_dir()), None)
ARDUCOPTER = LOGS / "ardupilot" / "arducopter-2015-23min.tlog" if LOGS else None
PX4_LOGS = sorted((LOGS / "px4").glob("*.ulg")) if LOGS else []
needs_arducopter = pytest.mark.skipif(not (ARDUCOPTER and ARDUCOPTER.exists()),
                                      reason="the shared ArduCopter log is not here (a user's clone has none)")
needs_px4 = pytest.mark.skipif(not PX4_LOGS, reason="the shared PX4 logs are not here (a user's clone has none)")

TABLE = load_for_vehicle("x500")
R_OBST, E_TR, THRUST = 0.5, 0.3, 1.0


def blind_flight(directory: Path, legs=((20.0, 3.0), (10.0, 6.0), (5.0, 0.0)), thrust=THRUST) -> None:
    """Legs of (seconds, ground speed) at 10 Hz, D_od 0 and no obstacle (no sensor), as the daemon writes it."""
    log = EventLog(directory, commit="none")
    log.event(0.0, "start", mode="shadow", vehicle="x500", table=str(TABLE.path))
    t, x = 0.0, 0.0
    for dur, v in legs:
        for _ in range(int(round(dur * 10))):
            log.state(round(t, 3), state="standby", mode="mission", contract="stop", engaged=False, x=x, y=0.0,
                      z=-10.0, vx=v, vy=0.0, vz=0.0, ground_speed=v, d_od=0.0, e_tr=E_TR, e_tr_measured=E_TR,
                      r_obst=R_OBST, thrust_ratio=thrust, v_max=0.0, tilt_deg=35.0, v_safe=0.0, gamma=0.0,
                      gamma_flown=v, v_cmd=None, obstacle_m=None)
            t, x = t + 0.1, x + 0.1 * v
    log.event(round(t, 3), "stop")
    log.close()


def least_d_od(v: float, tol: float = 0.005) -> float:
    """The smallest d_od whose V_max reaches v, by a finer bisection than the review's."""
    lo, hi = 0.0, 200.0
    while hi - lo > tol:
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if TABLE.omega(mid, R_OBST, E_TR, THRUST, contract="stop").v_max >= v else (mid, hi)
    return hi


@pytest.fixture(scope="module")
def blind(tmp_path_factory):
    d = tmp_path_factory.mktemp("blind")
    blind_flight(d / "log")
    return d / "log"


def test_a_blind_flight_gets_the_range_it_needed_not_outside_the_contract(blind):
    rep = review(blind)
    f = rep["findings"]
    assert rep["obstacle_data"] is False
    assert not [x for x in f if x.startswith(("flown outside the contract", "ground speed above the limit"))]
    assert sum("no obstacle data" in x for x in f) == 1
    need = rep["detection_need"]
    # 6 m/s needs what the table says it needs (upper end of the review's bisection, within its 5 cm)
    want6, want3 = least_d_od(6.0), least_d_od(3.0)
    assert want6 <= need["worst"]["d_od_m"] <= want6 + 0.06 and need["worst"]["ground_speed"] == 6.0
    assert TABLE.omega(need["worst"]["d_od_m"], R_OBST, E_TR, THRUST, contract="stop").v_max >= 6.0
    # 20 s at 3 m/s, 10 s at 6 m/s (the hover is not flown time): median at 3 m/s' need, 90 % at 6 m/s'
    assert need["flown_s"] == pytest.approx(30.0, abs=0.15)
    assert want3 <= need["quantiles_m"]["0.5"] <= want3 + 0.06 and need["quantiles_m"]["0.9"] == need["worst"]["d_od_m"]
    shares = {c["range_m"]: c["share"] for c in need["coverage"]}
    for r, share in shares.items():  # the share of the flown time each usual range covers
        assert share == pytest.approx((20 * (want3 <= r) + 10 * (want6 <= r)) / 30, abs=0.01), r
    stretch = max(need["stretches"], key=lambda s: s["d_od_m"])
    assert 20.0 <= stretch["start_t"] and stretch["end_t"] <= 30.0 + 0.15
    text = format_report(rep)
    assert "not judged" in text and "needs" in text and "span(s)" not in text


def test_an_assumed_sensor_gives_the_limits_and_the_time_they_cost(blind):
    rep = review(blind, sensor=Sensor(8.0, 60.0))
    s = rep["detection_need"]["sensor"]
    limit = TABLE.omega(8.0, R_OBST, E_TR, THRUST, contract="stop").v_max
    assert 3.0 < limit < 6.0 and s["limit_min"] == pytest.approx(limit) == s["limit_max"]
    # only the 10 s at 6 m/s were faster; flying them at the limit takes 60 m / limit instead of 10 s
    assert s["above_s"] == pytest.approx(10.0, abs=0.15) and s["spans_count"] == 1
    assert s["extra_s"] == pytest.approx(10.0 * (6.0 / limit - 1.0), rel=0.02)
    line = next(x for x in rep["findings"] if x.startswith("with a 8 m / 60° field of view sensor"))
    assert f"{limit:.2f} m/s" in line and f"added {s['extra_s']:.0f} s" in line


def test_an_assumed_narrow_beam_is_judged_by_its_cover_of_the_corridor_as_the_daemon_does(blind):
    """A 3° lidar rated 12 m covers the X500's corridor (r_body 0.38 + E_tr 0.3 m) at no range: the contract's
    limit with it is 0 (the daemon's own D_od); a 12 m / 60° sensor gets its range (the negative control)."""
    rep = review(blind, sensor=Sensor(12.0, 3.0))
    s = rep["detection_need"]["sensor"]
    assert s["d_od_min"] == 0.0 and s["limit_max"] == 0.0 and s["uncovered_s"] == pytest.approx(30.0, abs=0.15)
    assert any("covers the vehicle's swept corridor (r_body + E_tr) at no range" in x for x in rep["findings"])
    wide = review(blind, sensor=Sensor(12.0, 60.0))["detection_need"]["sensor"]
    assert wide["d_od_min"] == 12.0 and wide["uncovered_s"] == 0.0
    assert wide["limit_min"] == pytest.approx(TABLE.omega(12.0, R_OBST, E_TR, THRUST, contract="stop").v_max)
    # a beam that covers the corridor only beyond its range at the flown E_tr: 8° at 5 m covers ±0.35 m
    assert review(blind, sensor=Sensor(5.0, 8.0))["detection_need"]["sensor"]["d_od_min"] == 0.0


def test_thrust_below_the_tables_range_needs_more_than_any_range(tmp_path):
    lo = TABLE.vehicle.thrust_ratio_range[0]
    blind_flight(tmp_path, legs=((10.0, 2.0),), thrust=lo - 0.05)
    need = review(tmp_path, sensor=Sensor(20.0))["detection_need"]
    # never optimistic: no d_od gives a safe speed there, and an assumed sensor's limit is 0 (a hold)
    assert need["below_thrust_s"] == pytest.approx(10.0, abs=0.15) and need["worst"]["d_od_m"] is None
    assert need["sensor"]["limit_max"] == 0.0 and need["sensor"]["no_speed_s"] == pytest.approx(10.0, abs=0.15)
    assert any("below the table's" in f for f in need["findings"])


def test_a_log_with_obstacle_data_is_judged_as_before(tmp_path):
    log = EventLog(tmp_path, commit="none")
    for i in range(50):
        log.state(i * 0.1, ground_speed=5.0, d_od=4.0, v_max=2.0, v_safe=2.0, gamma=0.0, gamma_flown=3.0,
                  obstacle_m=None, x=0.0, y=0.0)
    log.close()
    rep = review(tmp_path)
    assert rep["obstacle_data"] is True and "detection_need" not in rep
    assert any(f.startswith("flown outside the contract") for f in rep["findings"])


def test_a_bad_assumed_sensor_is_one_line(blind):
    from contracts.errors import ContractError

    for bad in ("0", "ten", "10,0", "10,400", "nan", "10,60,3", ""):
        with pytest.raises(ContractError, match=r"RANGE_M\[,FOV_DEG\]"):
            Sensor.parse(bad)
    assert Sensor.parse(" 12 , 60 ") == Sensor(12.0, 60.0) and Sensor.parse("7") == Sensor(7.0)
    r = subprocess.run([sys.executable, "-m", "companion.cli", "review", str(blind), "--assume-sensor", "10,400"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "RANGE_M[,FOV_DEG]" in r.stderr, r.stderr


@needs_arducopter
def test_the_real_arducopter_log_says_what_range_it_needed_and_what_a_sensor_costs(tmp_path):
    rep, origin = review_log(ARDUCOPTER, tmp_path / "out", vehicle="x500", sensor=Sensor(10.0, 60.0))
    f = rep["findings"]
    # main: "flown outside the contract by up to 7.99 m/s … 398 s above V_safe in 73 spans" and the v_max line
    assert not [x for x in f if x.startswith(("flown outside the contract", "ground speed above the limit"))]
    assert sum(x.startswith("no obstacle data") for x in f) == 1
    need = rep["detection_need"]
    w = need["worst"]
    assert w["ground_speed"] == pytest.approx(rep["ranges"]["ground_speed"]["max"])
    # the worst stretch needs the least d_od whose V_max reaches its speed (the table's lookup, recomputed here
    # at the flight's own R_OBST, E_TR and thrust from the state samples)
    r, e, k = (rep["ranges"][x]["max"] for x in ("r_obst", "e_tr_measured", "thrust_ratio"))
    assert TABLE.omega(w["d_od_m"], r, e, k, contract="stop").v_max >= w["ground_speed"]
    assert TABLE.omega(w["d_od_m"] - 0.1, r, e, k, contract="stop").v_max < w["ground_speed"]
    assert need["quantiles_m"]["0.5"] <= need["quantiles_m"]["0.9"] <= need["quantiles_m"]["0.99"] <= w["d_od_m"]
    s = need["sensor"]
    assert s["limit_min"] == pytest.approx(TABLE.omega(10.0, r, e, k, contract="stop").v_max)
    assert 0 < s["above_s"] < need["flown_s"] and s["extra_s"] > 0
    assert any(x.startswith("with a 10 m / 60° field of view sensor") for x in f)
    # every output names it: the text, the plot's title, the HTML-ready PNGs
    text = format_report(rep, origin)
    assert "Detection range needed" in text and "stretches" in text
    assert (tmp_path / "out" / "plan.png").exists() and (tmp_path / "out" / "review.png").exists()
    # the index of many flights says it too, with the .tlog's autopilot family as its firmware
    from companion.ground.reviewset import need_text, row

    r = row(ARDUCOPTER, rep, None)
    assert r["firmware"] == "ArduPilot" and r["d_od_needed_m"] == w["d_od_m"]
    assert need_text(r) == f"no data; needed ≤ {w['d_od_m']:.1f} m"


@needs_px4
@pytest.mark.parametrize("path", PX4_LOGS, ids=lambda p: p.name)
def test_the_real_px4_logs_say_no_obstacle_data_once_and_what_was_flown(path):
    rep, origin = review_log(path, vehicle="x500", sensor=Sensor(8.0))
    assert rep["obstacle_data"] is False and rep["detection_need"] is not None
    assert sum("D_od is unknown" in x for x in rep["findings"]) == 1  # the log's own line, once
    assert not [x for x in rep["findings"] if x.startswith("flown outside the contract")]
    need = rep["detection_need"]
    moving = need["flown_s"] > 0
    # these logs barely move (bench and take-off logs): the review says so rather than inventing a need
    if not moving:
        assert need["worst"] is None and "nothing flown above" in format_report(rep, origin)
    else:
        assert need["worst"]["d_od_m"] is None or need["worst"]["d_od_m"] > 0
