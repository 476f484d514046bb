"""Before the thrust estimate settles, and a "no safe speed" Hold that says why.

Until the aircraft is airborne and steady the daemon cannot measure its thrust ratio; it takes the lowest the
vehicle may have (the bottom of `thrust_ratio_range`), at the thrust axis' own first value where the table covers
it, and says so once per flight (`thrust_start`). A table whose thrust axis starts above that bottom (built with
`--partial-grid`) cannot vouch for the aircraft until it is measured: the honest answer is no safe speed, and the
Hold names that input and how the flight resumes. Before, such a flight (vehicle 0.6–1.0, table from 0.65,
engaged at take-off) held for the whole flight as `HOLD: no safe speed`, naming neither."""

import math

import numpy as np
import pytest
from types import SimpleNamespace

from companion.onboard.autopilots import adapter_for
from companion.onboard.config import config_from_dict
from companion.onboard.console import event_line
from companion.onboard.cycle import Cycle
from companion.onboard.estimators import DodEstimate
from companion.ground.review import format_report, summarise
from companion.onboard.supervisor import Inputs
from contracts.table import Slot, load_for_vehicle, verify, write_table
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly

MAMBO = load_for_vehicle("mambo")  # thrust_ratio_range 0.6–1.0; its axes start at 0.6


def mambo_table(path, thrust_from: float):
    """The shipped Mambo table with both thrust axes starting at `thrust_from` ≥ 0.6 (what `table build
    --partial-grid` and `table etr` write for a grid from there): the avoid columns below it dropped, E_tr_pred's
    lowest column (0.6) stated at `thrust_from` (E_tr_pred at a lower thrust bounds a higher one's)."""
    rho, tilt, tr = MAMBO.avoid.axes
    keep = tr >= thrust_from - 1e-12
    tr_avoid = np.concatenate([[thrust_from], tr[keep][1:]]) if not np.isclose(tr[keep][0], thrust_from) else tr[keep]
    avoid = Slot((rho, tilt, tr_avoid), MAMBO.avoid.values[:, :, np.flatnonzero(keep)], MAMBO.avoid.info)
    v, et, er = MAMBO.e_pred.axes
    e_tr_pred = Slot((v, et, np.concatenate([[thrust_from], er[1:]])), MAMBO.e_pred.values, MAMBO.e_pred.info)
    write_table(path, MAMBO.vehicle, tilt_model=MAMBO.meta["tilt_model"], avoid=avoid, e_tr_pred=e_tr_pred)
    return verify(path, MAMBO.vehicle)


@pytest.fixture(scope="module")
def partial(tmp_path_factory):
    return tmp_path_factory.mktemp("tables") / "mambo-from-065.npz"


@pytest.fixture(scope="module")
def partial_table(partial):
    return mambo_table(partial, 0.65)


def failsafes(rig):
    return [e for e in rig.log.named("failsafe") if e["cause"] == "no safe speed"]


# ----------------------------------------------------------------------------- flights


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_table_above_the_vehicles_thrust_range_holds_at_take_off_names_why_and_resumes(personality, partial,
                                                                                           partial_table):
    rig = Rig(column_scenario(1, x_col=400.0), personality, table_wrapper=lambda t: verify(partial, t.vehicle))
    fly(rig, 8.0)  # engaged from the start: take-off, then the mission
    fs = failsafes(rig)
    assert fs, "no safe speed at take-off: the thrust ratio is not measured yet and the table starts above 0.6"
    assert fs[0]["input"] == "thrust_ratio"
    assert "not yet estimated" in fs[0]["why"] and "0.60" in fs[0]["why"] and "(0.65)" in fs[0]["why"]
    assert "thrust_ratio ≥ 0.65" in fs[0]["resume"] and "change the flight mode" in fs[0]["resume"]
    said = rig.log.named("thrust_start")
    assert len(said) == 1 and said[0]["t"] <= fs[0]["t"] and said[0]["covered"] is False
    assert (said[0]["vehicle_min"], said[0]["table_min"]) == (0.6, 0.65)
    assert "no safe speed" in said[0]["reason"]
    assert any(t.startswith("CG: no safe speed: thrust_ratio 0.60 < 0.65; resume when thrust_ratio >= 0.65")
               for t in rig.daemon_texts())
    assert "thrust_ratio not yet estimated" in event_line("failsafe", fs[0])[1]
    # held, hovering: the estimate settles, and the cause clears — but the Hold stays (the pilot decides)
    assert rig.daemon.last.state == "holding" and rig.log.states[-1]["thrust_ratio"] >= 0.65
    assert rig.log.states[-1]["v_max"] > 0.2
    # what the resume says: the pilot changes the mode back to the mission, and the flight goes on, limited
    t_resume = rig.sim.time_s
    rig.command(176, *adapter_for(personality).set_mode_params("mission", True))
    rig.run(8.0)
    assert len(failsafes(rig)) == len(fs) and rig.daemon.last.state == "active"
    sent = [e for e in rig.log.named("command") if e["cmd"] == "change_speed" and e["t"] > t_resume]
    assert sent and max(s["ground_speed"] for s in rig.log.states if s["t"] > t_resume) > 1.0
    # and the review says it
    recs = [{"kind": "event", **e} for e in rig.log.events] + [{"kind": "state", **s} for s in rig.log.states]
    text = format_report(summarise(sorted(recs, key=lambda r: r["t"])))
    assert "thrust_ratio not yet estimated" in text and "resume: once the hover estimate" in text
    assert any("thrust axis starts at 0.65" in f for f in summarise(recs)["findings"])


def test_engaged_once_the_estimate_has_settled_the_same_table_flies(partial, partial_table):
    """The start line's advice: engage after the hover estimate settles, and the partial table flies."""
    rig = Rig(column_scenario(1, x_col=400.0), "px4", table_wrapper=lambda t: verify(partial, t.vehicle),
              config={"engage": False})
    fly(rig, 4.0)
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9))
    rig.run(8.0)
    assert not failsafes(rig) and rig.daemon.last.state == "active"
    assert [e for e in rig.log.named("command") if e["cmd"] == "change_speed"]


def test_a_shadow_flight_names_the_input_of_its_would_be_hold(partial, partial_table):
    rig = Rig(column_scenario(1, x_col=400.0), "px4", table_wrapper=lambda t: verify(partial, t.vehicle),
              config={"mode": "shadow"})
    fly(rig, 8.0)
    would = [e for e in rig.log.named("would_hold") if "no safe speed" in e["causes"]]
    assert would and would[0]["input"] == "thrust_ratio" and "not yet estimated" in would[0]["why"]
    assert "no speed until the hover estimate" in would[0]["resume"]
    assert rig.log.named("would_hold")[-1]["causes"] == []  # measured: the would-be Hold is over
    recs = [{"kind": "event", **e} for e in rig.log.events] + [{"kind": "state", **s} for s in rig.log.states]
    assert "(thrust_ratio not yet estimated" in format_report(summarise(sorted(recs, key=lambda r: r["t"])))


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_the_start_value_is_said_once_per_flight_and_has_a_speed(personality):
    rig = Rig(column_scenario(1, x_col=400.0), personality)
    fly(rig, 6.0)
    said = rig.log.named("thrust_start")
    assert len(said) == 1 and said[0]["covered"] is True and said[0]["thrust_ratio"] == 0.6
    at_start = [s for s in rig.log.states if s["t"] >= said[0]["t"] and s["thrust_ratio"] == 0.6]
    assert at_start and all(s["v_max"] > 0.2 for s in at_start)  # the lookup answers at the start value
    assert not failsafes(rig)


# ----------------------------------------------------------------------------- pure pieces


def test_the_start_value_is_the_axis_own_first_value_where_the_table_covers_the_vehicle(tmp_path):
    """An axis starting within the build's tolerance above the range's bottom covers it (`table build` accepts it):
    the start must be that axis value — at the bottom itself the lookup answers NONE (no safe speed)."""
    edge = 0.6 + 5e-10
    table = mambo_table(tmp_path / "edge.npz", edge)
    assert table.omega(6.0, 0.5, 0.3, 0.6, contract="stop").v_max == 0.0  # the trap
    cfg = config_from_dict({"vehicle": "mambo", "mode": "governor", "link": {"connect": "memory"},
                            "sensors": [{"h_fov_deg": 30, "max_range_m": 6.0}]})
    cycle = Cycle(cfg, table, adapter_for("px4"), "stop", None)
    start, _ = cycle.sensing.thrust.value(0.0)
    assert start == edge and table.omega(6.0, 0.5, 0.3, start, contract="stop").v_max > 1.0
    from companion.onboard.assumptions import start_thrust  # (imported here: the flights above run on older code too)

    assert start_thrust(table, "stop")[1]["covered"] is True


def test_the_start_value_on_the_shipped_and_a_partial_table(partial_table):
    from companion.onboard.assumptions import start_thrust

    assert start_thrust(MAMBO, "stop")[0] == 0.6 and start_thrust(MAMBO, "avoid")[0] == 0.6
    start, said = start_thrust(partial_table, "avoid")
    assert start == 0.6 and said["covered"] is False and partial_table.thrust_floor("avoid") == 0.65


def inputs(d_od=6.0, e_tr=0.3, thrust_ratio=1.0, late_s=0.0, reason="sensor 0 reports range 6.00 m"):
    dod = DodEstimate(d_od, (0,) if d_od > 0 else (), math.inf, None, reason)
    return Inputs(t=0.0, link_ok=True, telemetry_ok=True, nav_ok=True, armed=True, in_air=True, mode="mission",
                  limit_applies=True, mode_by_daemon=False, ground_speed=1.0, dod=dod, e_tr_measured=e_tr,
                  thrust_ratio=thrust_ratio, r_obst=0.5, engaged=True, late_s=late_s)


def why(i, contract="stop", basis="hover", table=MAMBO, policy="contract"):
    from companion.onboard.no_speed import diagnose

    return diagnose(table, contract, i, e_tr_floor=0.3, thrust_basis=basis, policy=policy)


def test_no_safe_speed_names_a_stale_sensor_and_the_d_od_it_needs():
    w = why(inputs(d_od=0.0, reason="no fresh, trusted sensor covers the direction of travel"))
    assert w.input == "d_od" and "no fresh, trusted sensor" in w.why
    need = float(w.needs.split("≥ ")[1].split(" m")[0])
    assert MAMBO.omega(need, 0.5, 0.3, 1.0, contract="stop").v_max >= 0.2  # enough, and barely
    assert MAMBO.omega(need - 0.03, 0.5, 0.3, 1.0, contract="stop").v_max < 0.2  # (to RESOLUTION, rounded up)
    assert "change the flight mode" in w.resume("governor") and "CG_ENGAGE 0 then 1" in w.resume("offboard")


def test_no_safe_speed_names_a_large_tracking_error_where_its_floor_would_fly():
    d = 1.2
    assert MAMBO.omega(d, 0.5, 0.3, 1.0, contract="stop").v_max >= 0.2  # at the E_tr floor: a speed
    w = why(inputs(d_od=d, e_tr=1.5))
    assert w.input == "e_tr" and w.why.startswith("E_tr 1.50 m")
    e_ok = float(w.needs.split("≤ ")[1].split(" m")[0])
    assert 0.3 <= e_ok < 1.5 and MAMBO.omega(d, 0.5, e_ok, 1.0, contract="stop").v_max >= 0.2


def test_no_safe_speed_names_thrust_measured_below_the_table_and_lateness():
    w = why(inputs(thrust_ratio=0.55))
    assert w.input == "thrust_ratio" and "estimated from the hover throttle" in w.why and "(0.60)" in w.why
    assert why(inputs(), policy="px4_cp").input == "policy"
    assert why(inputs(late_s=0.5)).input == "late_s"


def test_the_start_banner_says_so_before_the_first_flight(partial, partial_table):
    from companion.onboard.console import banner

    cfg = config_from_dict({"vehicle": "mambo", "table": str(partial), "mode": "governor",
                            "sensors": [{"h_fov_deg": 30, "max_range_m": 6.0}]})
    said = [x for x in banner(cfg, partial_table, "E_tr_pred") if "thrust_ratio" in x]
    assert said and "covers thrust_ratio 0.65 and up" in said[0] and "starts at 0.6" in said[0]
    assert not [x for x in banner(cfg, MAMBO, "E_tr_pred") if "thrust_ratio" in x]  # a table that covers it: quiet


def test_thrust_start_is_said_once_airborne_and_again_when_the_estimate_is_lost():
    """Through the cycle's own `_say`: on the ground nothing; airborne on the start value once; the hover estimate
    settles (quiet); its samples stop for more than 2 s (the start value again, said again); after a landing, anew."""
    from companion.onboard.samples import Throttle
    from companion.onboard.telemetry import Telemetry

    cfg = config_from_dict({"vehicle": "mambo", "mode": "governor", "link": {"connect": "memory"},
                            "sensors": [{"h_fov_deg": 30, "max_range_m": 6.0}]})
    cycle = Cycle(cfg, MAMBO, adapter_for("px4"), "stop", None)
    tel, said = Telemetry(), []

    def at(t, landed_state):
        tel.landed_state = landed_state
        events = []
        cycle._explain(SimpleNamespace(t=t, tel=tel, i=inputs()), events, [])
        said.extend(round(t, 2) for name, _ in events if name == "thrust_start")

    cycle.take(Throttle(0.0, 0.1, 0.0, 0.0, 0.0, False))
    at(0.0, 1)  # on the ground
    for k in range(50):  # lift-off at 1 s; steady hover samples from then on
        t = 1.0 + 0.1 * k
        cycle.take(Throttle(t, MAMBO.vehicle.controller.thr_hover, 0.0, 0.0, 0.0, True))
        at(t, 2)
    assert said == [1.0] and cycle.sensing.thrust.basis(5.9) == "hover"
    at(8.5, 2)  # no throttle sample for 2.6 s: the start value again
    at(8.6, 2)
    assert said == [1.0, 8.5]
    cycle.take(Throttle(9.0, 0.1, 0.0, 0.0, 0.0, False))
    at(9.0, 1)  # landed
    at(9.1, 2)  # and off again
    assert said == [1.0, 8.5, 9.1]
