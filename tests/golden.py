"""A fixed set of lock-step flights whose event logs (every state sample and every event, all fields)
are kept under `tests/data/golden/` — the proof that a change of the house changes no behaviour.

    python -m tests.golden --write [NAME ...]   # record (only after a deliberate, stated change)
    python -m tests.golden [NAME ...]           # fly and compare, print the first difference

`tests/test_golden_logs.py` flies each and compares field for field (floats to 1e-9).
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
from pathlib import Path

import numpy as np

from tests import test_daemon_lockstep as gov
from tests import test_inflight_figures as figs
from tests import test_mission as mission
from tests import test_offboard_lockstep as off
from tests.lockstep import Rig
from tests.test_detection_range import hide_the_medium

DIR = Path(__file__).resolve().parent / "data" / "golden"
WIND = {"mean_m_s": 1.0, "from_deg": 90, "gust_m_s": 0.5}


def _governor(scenario: dict, personality: str, seconds: float, config: dict | None = None, setup=None) -> Rig:
    rig = Rig(scenario, personality, config=config)
    if setup is not None:
        setup(rig)
    gov.fly(rig, seconds)
    return rig


def _offboard(scenario: dict, personality: str, seconds: float, config: dict | None = None) -> Rig:
    rig = Rig(scenario, personality, config=config or off.offboard_config())
    off.engage_and_fly(rig, seconds)
    return rig


def _medium_withheld(rig: Rig) -> Rig:
    """A rig whose obstacle logic does not get the returns counted as the medium's (a negative control only)."""
    hide_the_medium(rig.daemon.cycle)
    return rig


def _mission_flight() -> Rig:
    rig = Rig(mission.scenario("ardupilot"), "ardupilot", config=mission.MISSION_CONFIG)
    rig.run(0.5)
    mission.upload(rig, mission.mission_items(rig, "ardupilot", mission.SQUARE, [2.0] * 4, accept_m=1.5))
    mission.engage(rig, 25.0, until_done=True)
    return rig


def _corner(personality: str, corner: str) -> Rig:
    return off.route_flight(personality, off.CORNER_ROUTES[corner])[0]


FLIGHTS = {
    "governor_px4_column": lambda: _governor(gov.column_scenario(1, wind=WIND), "px4", 25.0),
    "governor_ardupilot_column": lambda: _governor(gov.column_scenario(2, wind=WIND), "ardupilot", 25.0),
    "governor_px4_honest_fog": lambda: _governor(gov.column_scenario(
        1, x_col=200.0, faults=[{"at_s": 10.0, "fog": {"visibility_m": 3.0, "report": "honest"}}]), "px4", 16.0),
    "governor_ardupilot_hidden_fog": lambda: _governor(gov.column_scenario(
        1, x_col=40.0, faults=[{"at_s": 5.0, "fog": {"visibility_m": 3.0, "report": "hidden"}}]), "ardupilot", 20.0),
    "governor_px4_thrust_drop": lambda: _governor(gov.column_scenario(
        1, x_col=300.0, faults=[{"at_s": 10.0, "thrust_ratio": 0.5}]), "px4", 16.0, {"thrust": {"tau_s": 0.5}}),
    "shadow_px4_column": lambda: _governor(gov.column_scenario(1, cruise=4.0), "px4", 20.0, {"mode": "shadow"}),
    "offboard_px4_column": lambda: _offboard(off.offboard_scenario(1, wind=WIND), "px4", 22.0),
    "offboard_ardupilot_column": lambda: _offboard(
        off.offboard_scenario(2, wind=WIND, personality="ardupilot"), "ardupilot", 22.0),
    "offboard_x500_px4_column": lambda: _offboard(
        off.offboard_scenario(1, wind={"mean_m_s": 3.0, "from_deg": 90, "gust_m_s": 1.0}, vehicle="x500"),
        "px4", 22.0),
    "offboard_px4_hidden_fog": lambda: off.fog_flight("px4", 1, off.VIS_AVOIDABLE, 12.0)[0],
    # the negative control `hide_the_medium`: the same hidden-fog flights, the medium's returns withheld from the
    # obstacle logic
    "governor_ardupilot_hidden_fog_medium_withheld": lambda: _governor(gov.column_scenario(
        1, x_col=40.0, faults=[{"at_s": 5.0, "fog": {"visibility_m": 3.0, "report": "hidden"}}]), "ardupilot", 20.0,
        setup=_medium_withheld),
    "offboard_px4_hidden_fog_medium_withheld": lambda: off.fog_flight("px4", 1, off.VIS_AVOIDABLE, 12.0,
                                                                      withhold_the_medium=True)[0],
    "offboard_ardupilot_corner_90": lambda: _corner("ardupilot", "90deg"),
    "offboard_ardupilot_mission_square": _mission_flight,
    "figure_17": lambda: figs.fly_scenario("fig17"),
    "figure_18": lambda: figs.fly_scenario("fig18"),
}


def plain(v):
    """A log value as JSON can hold it (non-finite floats as strings, numpy as Python, tuples as lists)."""
    if isinstance(v, dict):
        return {str(k): plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        v = float(v)
        return v if math.isfinite(v) else repr(v)
    if isinstance(v, str):
        return str(v)  # an enum of the daemon's vocabulary (companion/onboard/states.py) as the log writes it
    return v


# flown by their own test file, which compares them here (`difference`) instead of flying them twice
FLOWN_ELSEWHERE = {"figure_17": "tests/test_inflight_figures.py", "figure_18": "tests/test_inflight_figures.py"}


def logged(rig: Rig) -> dict:
    """What a flight logged, as recorded: every state sample and every event."""
    return {"states": plain(rig.log.states), "events": plain(rig.log.events)}


def record(name: str) -> dict:
    return logged(FLIGHTS[name]())


def difference(name: str, rig: Rig) -> str | None:
    """Where the flight `rig` (the recorded flight `name`, flown) logged other than recorded, or None."""
    return first_difference(load(name), logged(rig))


def first_difference(want, got, path: str = "") -> str | None:
    """Where two recorded logs differ (floats equal to 1e-9), or None."""
    if isinstance(want, float) or isinstance(got, float):
        if isinstance(want, (int, float)) and isinstance(got, (int, float)) and not isinstance(want, bool) \
                and not isinstance(got, bool) and math.isclose(want, got, rel_tol=1e-9, abs_tol=1e-9):
            return None
        return f"{path}: {want!r} != {got!r}"
    if type(want) is not type(got):
        return f"{path}: {want!r} != {got!r}"
    if isinstance(want, dict):
        if set(want) != set(got):
            return f"{path}: keys {sorted(set(want) ^ set(got))} differ"
        for k in want:
            if (d := first_difference(want[k], got[k], f"{path}.{k}")) is not None:
                return d
        return None
    if isinstance(want, list):
        for k, (a, b) in enumerate(zip(want, got)):
            if (d := first_difference(a, b, f"{path}[{k}]")) is not None:
                return d
        return None if len(want) == len(got) else f"{path}: length {len(want)} != {len(got)}"
    return None if want == got else f"{path}: {want!r} != {got!r}"


def path_of(name: str) -> Path:
    return DIR / f"{name}.json.gz"


def load(name: str) -> dict:
    with gzip.open(path_of(name), "rt") as f:
        return json.load(f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", default=list(FLIGHTS))
    ap.add_argument("--write", action="store_true")
    a = ap.parse_args()
    DIR.mkdir(parents=True, exist_ok=True)
    for name in a.names:
        got = plain(json.loads(json.dumps(record(name))))
        if a.write:
            with gzip.GzipFile(path_of(name), "wb", mtime=0) as f:
                f.write(json.dumps(got, separators=(",", ":")).encode())
            print(f"{name}: {len(got['states'])} states, {len(got['events'])} events written")
        else:
            print(f"{name}: {first_difference(load(name), got) or 'same'}")


if __name__ == "__main__":
    main()
