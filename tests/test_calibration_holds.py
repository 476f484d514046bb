"""Issue 15: the daemon flies the calibration plan's hold legs in governor mode (config `calibration.legs`,
companion/onboard/calibration_holds.py). Real SITL, real MAVLink, lock-step: a short plan (2 hold legs, 2 and 3 m/s, no
zig-zag) flown by the "real aircraft" of the calibration evidence, both personalities; a negative control without
the option; a pilot's mode change mid-leg; bad legs files; the state machine's safety rules on their own."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from companion.ground.calibrate import read_log, trace_of
from companion.ground.calibrate_plan import write_plan_files
from companion.onboard.calibration_holds import REST_SPEED_M_S, CalibrationHolds, read_legs
from companion.onboard.config import config_from_dict
from companion.onboard.mission import Home
from contracts.errors import ContractError
from contracts.vehicle import load_vehicle
from tests.calibration_flights import fly_calibration, truth_vehicle

ROOT = Path(__file__).resolve().parents[1]
LOOP_DT = 1 / 50.0
SPEEDS = [2.0, 3.0]


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    return write_plan_files(load_vehicle("x500"), tmp_path_factory.mktemp("plan"), SPEEDS, zigzag=False)


def mission_file(plan, personality):
    return Path(plan["plan"] if personality == "px4" else plan["waypoints"])


class Track:
    """The pilot's eye (truth from the SITL): where the vehicle was each cycle; optionally a mode change of the
    pilot's own once the daemon's Hold of the first leg is in force."""

    def __init__(self, take_over: str | None = None):
        self.take_over, self.rows, self.t_over = take_over, [], None

    def __call__(self, rig) -> bool:
        ap = rig.sim.autopilot
        self.rows.append((rig.sim.time_s, float(ap.pos[0]), float(ap.pos[1]), ap.traj.speed_xy, ap.mode, ap.mission_seq))
        cal = rig.daemon.calibration
        if self.take_over and self.t_over is None and cal is not None and cal.phase == "holding":
            self.t_over = rig.sim.time_s
            from companion.onboard.autopilots import adapter_for

            ad = adapter_for(rig.cfg.link.autopilot)
            rig.command(176, *ad.set_mode_params(self.take_over, True))  # MAV_CMD_DO_SET_MODE, the pilot's
        return self.t_over is not None and rig.sim.time_s > self.t_over + 10.0

    def at(self, t):
        return min(self.rows, key=lambda r: abs(r[0] - t))


def fly(plan, personality, tmp_path, holds="daemon", pilot=None):
    return fly_calibration(mission_file(plan, personality), tmp_path / f"{personality}.tlog", truth=truth_vehicle(),
                           personality=personality, wind_m_s=5.0, max_s=240.0, holds=holds, pilot=pilot)


def named(events, name, **match):
    return [e for e in events if e["event"] == name and all(e.get(k) == v for k, v in match.items())]


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_the_daemon_flies_both_hold_legs(plan, personality, tmp_path):
    track = Track()
    r = fly(plan, personality, tmp_path, pilot=track)
    assert r["finished"] and r["holds_by"] == "daemon"
    ev = r["events"]
    legs = read_legs(mission_file(plan, personality)).holds
    commanded, resumed = named(ev, "calibration_hold", status="commanded"), named(ev, "calibration_hold", status="resumed")
    assert [e["leg"] for e in commanded] == [0, 1] and [e["leg"] for e in resumed] == [0, 1]
    assert not named(ev, "calibration_hold", status="abandoned")
    seq_key = "seq_plan" if personality == "px4" else "seq_waypoints"
    for leg, c, res in zip(legs, commanded, resumed):
        assert c["seq"] == getattr(leg, seq_key) and c["leg_speed_m_s"] == leg.speed_m_s
        # Hold commanded within hold_before_m (+ one cycle's travel) of the waypoint, by the SITL's own geometry
        wp = r["waypoints_local"][c["seq"]]
        t, x, y, v, mode, seq = track.at(c["t"])
        d = math.hypot(x - wp[0], y - wp[1])
        assert leg.hold_before_m - 2 * leg.speed_m_s * LOOP_DT <= d <= leg.hold_before_m + leg.speed_m_s * LOOP_DT
        assert mode == "mission" and seq == c["seq"] and v > 0.8 * leg.speed_m_s  # at speed, flying the leg
        # the command went out on the link: Hold, then (at rest for rest_s) the mission
        cmds = [e for e in named(ev, "command") if c["t"] <= e["t"] <= res["t"] and e["cmd"] in ("hold", "mission")]
        assert [e["cmd"] for e in cmds] == ["hold", "mission"]
        rest = [row for row in track.rows if c["t"] <= row[0] <= cmds[1]["t"]]
        assert min(row[3] for row in rest) < REST_SPEED_M_S and all(row[4] == "hold" for row in rest[60:])
        assert res["at_rest"] and res["rest_s"] >= leg.rest_s
        assert track.at(res["t"] + 1.0)[4] == "mission"
    # a .tlog beside it has the daemon's Hold commands (as a router forwards them), which calibrate times stops from
    tr = trace_of("x", *read_log(tmp_path / f"{personality}.tlog"))
    held = [t for t, src in tr.holds if src == "command"]
    assert len(held) == 2 and abs((held[1] - held[0]) - (commanded[1]["t"] - commanded[0]["t"])) < 0.05


@pytest.mark.parametrize("personality", ["px4"])
def test_negative_control_without_the_option_nothing_holds(plan, personality, tmp_path):
    track = Track()
    r = fly(plan, personality, tmp_path, holds="none", pilot=track)
    assert r["finished"] and r["holds_by"] == "none"
    ev = r["events"]
    assert not named(ev, "calibration_hold") and not [e for e in named(ev, "command") if e["cmd"] in ("hold", "mission")]
    start = next(k for k, row in enumerate(track.rows) if row[4] == "mission")
    last = max(row[5] for row in track.rows)  # (the plan ends in Hold at its last item)
    assert not [row for row in track.rows[start:] if row[4] != "mission" and row[5] < last]
    for leg in read_legs(mission_file(plan, personality)).holds:  # it flew through each hold leg's stopping zone
        wp = r["waypoints_local"][leg.seq_plan]
        zone = [row[3] for row in track.rows if row[5] == leg.seq_plan and math.hypot(row[1] - wp[0], row[2] - wp[1])
                <= leg.hold_before_m]
        assert zone and min(zone) > 0.5 * leg.speed_m_s  # (the SITL eases into a waypoint; never near rest)


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_pilots_mode_change_mid_leg_abandons_it(plan, personality, tmp_path):
    track = Track(take_over="position")
    r = fly(plan, personality, tmp_path, pilot=track)
    ev = r["events"]
    gone = named(ev, "calibration_hold", status="abandoned")
    assert len(gone) == 1 and gone[0]["leg"] == 0 and "set by someone else" in gone[0]["reason"]
    assert not named(ev, "calibration_hold", status="resumed")
    after = [e for e in named(ev, "command") if e["t"] >= track.t_over and e["cmd"] in ("hold", "mission")]
    assert not after, after  # the daemon never fights the pilot
    changes = [e for e in named(ev, "mode_change") if e["t"] >= track.t_over and e["by"] == "other"]
    assert changes and changes[0]["to"] == "position" and changes[0]["from"] == "hold"
    assert named(ev, "mode_change")[-1] is changes[0]  # the pilot's mode to the end


# ----------------------------------------------------------------------------- the legs file, the config


def test_legs_files_agree(plan):
    a, b, c = (read_legs(plan[k]) for k in ("legs_file", "plan", "waypoints"))
    assert len(a.holds) == len(SPEEDS) and a.holds == b.holds and a.speeds == b.speeds == c.speeds
    for x, y in zip(a.holds, c.holds):  # a .waypoints keeps 8 decimals of a degree (~1 mm)
        assert abs(x.lat_deg - y.lat_deg) < 1e-7 and abs(x.lon_deg - y.lon_deg) < 1e-7
        assert (x.seq_plan, x.seq_waypoints, x.speed_m_s, x.hold_before_m, x.rest_s) == \
            (y.seq_plan, y.seq_waypoints, y.speed_m_s, y.hold_before_m, y.rest_s)


def bad_legs(tmp_path, plan):
    good = json.loads(Path(plan["legs_file"]).read_text())
    cases = {"missing": None, "garbage": b"\x00\xff\x00 not json", "no_legs": {"kind": "x"},
             "no_holds": {**good, "legs": [leg for leg in good["legs"] if leg["kind"] != "hold"]},
             "negative": {**good, "legs": [{**leg, "hold_before_m": -1.0} if leg["kind"] == "hold" else leg
                                           for leg in good["legs"]]},
             "nan_lat": {**good, "legs": [{**leg, "lat_deg": "north"} if leg["kind"] == "hold" else leg
                                          for leg in good["legs"]]}}
    out = {}
    for name, body in cases.items():
        p = tmp_path / f"{name}.json"
        if body is not None:
            p.write_bytes(body if isinstance(body, bytes) else json.dumps(body).encode())
        out[name] = p
    return out


def governor(legs, mode="governor"):
    return {"vehicle": "x500", "mode": mode, "sensors": [{"h_fov_deg": 30, "max_range_m": 10}],
            "calibration": {"legs": str(legs)}}


def test_bad_legs_files_are_one_config_line(plan, tmp_path):
    for name, p in bad_legs(tmp_path, plan).items():
        with pytest.raises(ContractError) as err:
            config_from_dict(governor(p))
        line = str(err.value)
        assert "\n" not in line and line.startswith("config: calibration.legs: calibration legs"), (name, line)
    for mode in ("shadow", "offboard"):
        with pytest.raises(ContractError, match="governor mode only"):
            config_from_dict({**governor(plan["legs_file"], mode), "route": {"waypoints": [[0, 0], [9, 0]]}})
    assert config_from_dict(governor(plan["plan"])).calibration.legs == Path(plan["plan"])


def test_run_with_a_bad_legs_file_exits_with_one_line(plan, tmp_path):
    import yaml

    cfg = tmp_path / "cg.yaml"
    cfg.write_text(yaml.safe_dump(governor(bad_legs(tmp_path, plan)["negative"])))
    r = subprocess.run([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg)], capture_output=True,
                       text=True, cwd=ROOT, timeout=120)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert len(lines) == 1 and "hold_before_m" in lines[0], r.stderr


# ----------------------------------------------------------------------------- the state machine on its own


def machine(plan):
    legs = read_legs(plan["legs_file"])
    m = CalibrationHolds(legs, item0_is_home=False)
    lat, lon, _ = 47.397742, 8.545594, 488.0
    m.take_home(Home(lat, lon, 488.0))
    leg = legs.holds[0]
    return m, leg, m.waypoint(leg)


def step(m, t, wp, leg, *, dx=0.0, mode="mission", speed=2.0, active=True, safety=None, taken_over=False,
         undelivered=None):
    """One cycle of the hold legs, as the cycle hands it over (its `Turn`: the parts the legs read); the mode the
    part asks for, its events."""
    from companion.onboard.authority import Requester
    from companion.onboard.states import State

    decision = SimpleNamespace(hold=safety is not None, hold_causes=[safety] if safety else [],
                               state=State.ACTIVE if active else State.STANDBY)
    view = SimpleNamespace(undelivered=lambda by: undelivered if by == Requester.CALIBRATION else None)
    turn = SimpleNamespace(t=t, i=SimpleNamespace(mode=mode, taken_over=taken_over, ground_speed=speed,
                                                  telemetry_ok=True),
                           d=decision, view=view,
                           tel=SimpleNamespace(mission_seq=leg.seq_plan, x=wp[0] - dx, y=wp[1]))
    part = m.step(turn)
    return SimpleNamespace(command=part.requests[0].mode if part.requests else None, events=part.events,
                           texts=part.texts)


def test_machine_waits_for_the_distance_and_a_safety_hold_wins(plan):
    m, leg, wp = machine(plan)
    assert step(m, 0.0, wp, leg, dx=leg.hold_before_m + 0.5).command is None
    assert step(m, 0.0, wp, leg, dx=leg.hold_before_m + 0.5, safety="no safe speed").command is None
    a = step(m, 0.1, wp, leg, dx=leg.hold_before_m - 0.01)
    assert a.command == "hold" and a.events[0][1]["status"] == "commanded"
    step(m, 0.2, wp, leg, mode="hold", speed=1.0)  # Hold seen
    a = step(m, 0.3, wp, leg, mode="hold", speed=0.5, safety="obstacle inside the stop distance")
    assert a.command is None and a.events[0][1]["status"] == "abandoned" and "obstacle" in a.events[0][1]["reason"]
    for k in range(200):  # at rest long after: no mission command (the safety hold stays), and never again
        assert step(m, 1.0 + k * 0.1, wp, leg, mode="hold", speed=0.0).command is None
    assert step(m, 30.0, wp, leg, dx=1.0).command is None


def test_machine_rest_then_mission_and_a_refused_hold(plan):
    m, leg, wp = machine(plan)
    assert step(m, 0.0, wp, leg, dx=0.5).command == "hold"
    assert step(m, 0.5, wp, leg, mode="hold", speed=0.05).command is None  # at rest from 0.5 s
    assert step(m, 0.5 + leg.rest_s - 0.02, wp, leg, mode="hold", speed=0.05).command is None
    assert step(m, 0.5 + leg.rest_s, wp, leg, mode="hold", speed=0.05).command == "mission"
    a = step(m, 3.0, wp, leg, mode="mission", speed=0.3)
    assert a.events[0][1]["status"] == "resumed" and a.events[0][1]["at_rest"]
    m2, leg2, wp2 = machine(plan)
    assert step(m2, 0.0, wp2, leg2, dx=0.5).command == "hold"
    assert not step(m2, 3.5, wp2, leg2, dx=0.1).events  # not shown yet: the mode authority's to judge
    a = step(m2, 3.52, wp2, leg2, dx=0.1, undelivered="hold not shown within 1.2 s")  # the autopilot never took Hold
    assert a.events and a.events[0][1]["status"] == "abandoned" and "did not take Hold" in a.events[0][1]["reason"]


def test_mission_speed_follows_the_plans_speed_items(plan):
    legs = read_legs(plan["plan"])
    px4, ap = CalibrationHolds(legs, False), CalibrationHolds(legs, True)
    first = legs.speeds[0]
    assert math.isnan(px4.mission_speed(first[0] - 1)) if first[0] > 0 else True
    assert px4.mission_speed(legs.holds[0].seq_plan) == SPEEDS[0] == ap.mission_speed(legs.holds[0].seq_waypoints)
    assert px4.mission_speed(legs.holds[1].seq_plan) == SPEEDS[1] == ap.mission_speed(legs.holds[1].seq_waypoints)
