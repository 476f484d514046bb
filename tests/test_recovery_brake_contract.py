"""The recovery brake inside its own controller contract (docs/daemon.md, "The recovery brake"): the stop it flies
is flown in the E_tr sweep (the table's `e_tr_pred_brake` slot), its stop contract brakes as it flies, and the
supervisor predicts and judges its tracking error against that surface while the brake flies the stops."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from companion.onboard.flying import NOT_COVERED, RecoveryBrake
from contracts.stop import (
    airframe_decel,
    braking_decel,
    recovery_brake,
    recovery_brake_stop,
    stop_jerk,
)
from contracts.table import Slot, load_for_vehicle, verify, write_table
from contracts.vehicle import load_vehicle
from sitl_harness import etr_sweep as es
from sitl_harness.maneuvers import (
    BrakeReference,
    smooth_step_reference,
    worst_contour_error,
)
from companion.onboard.overshoot import DEFAULT as OVERSHOOT
from tests.test_recovery_brake_lockstep import two_stops

SECOND = 70.0  # the second column's x (tests/test_recovery_brake_lockstep.py `two_stops`)


def controller_violations(rig) -> list[dict]:
    return [e for e in rig.log.named("violation_start") if e["subsystem"] == "controller"]


def judged_as_the_holds(rig) -> None:
    """A negative control: the supervisor takes the autopilot's Hold's controller contract (`e_tr_pred_stop`) while the
    brake flies the stops — how the brake was judged and limited before its own surface."""
    sup = rig.daemon.cycle.sup
    use = sup.use_recovery_brake
    sup.use_recovery_brake = lambda loop_dt, flies=False: use(loop_dt, False)


@functools.cache
def brake_flight(vehicle: str, own_surface: bool = True):
    from tests.lockstep import Rig

    if own_surface:
        return two_stops("px4", True, SECOND, vehicle=vehicle)
    orig = Rig.__init__

    def init(self, *a, **kw):  # the rig's daemon, judged as the Hold's from its first cycle
        orig(self, *a, **kw)
        judged_as_the_holds(self)

    Rig.__init__ = init
    try:
        return two_stops("px4", True, SECOND, vehicle=vehicle)
    finally:
        Rig.__init__ = orig


@pytest.mark.parametrize("vehicle", ["x500", "mambo"])
def test_the_brake_stops_twice_with_no_controller_violation(vehicle):
    """Lock-step SITL, real MAVLink: the first stop shows the switch, the second flies from the brake's own limit;
    both are the brake's (offboard asked, then Hold at rest), no collision, and the tracking error measured against
    the stop the brake streams stays within the brake's E_tr_pred throughout."""
    rig = brake_flight(vehicle)
    assert not rig.truth["collisions"], rig.truth["collisions"]
    cmds = [e["cmd"] for e in rig.log.named("command") if e["cmd"] in ("hold", "offboard")]
    assert cmds == ["offboard", "hold"] * 2
    assert rig.log.named("recovery_brake")[-1]["proven"]
    assert controller_violations(rig) == []
    # the brake's limit, with its own surface (the Hold's limit before its switch is shown)
    table = rig.daemon.table
    fast = max(s["v_max"] or 0.0 for s in rig.log.states)
    assert fast == pytest.approx(OVERSHOOT.sent(table.omega(6.0, 1.0, 0.3, 1.0, contract="stop", recovery_dt=0.02,
                                                            t_cmd=0.1, t_silent=0.15, e_brake=True).v_max), rel=1e-6)
    # it really was tested: the error it made in its stops is most of the Hold's surface at that speed
    worst = max(s["e_tr_measured"] for s in rig.log.states)
    assert worst > 0.8 * table.e_tr_pred(fast, table.vehicle.tilt_max, 1.0, "stop")


def test_negative_control_the_brake_judged_by_the_holds_contract_breaks_it():
    """The same X500 flight with the supervisor taking the autopilot's Hold's surface for the brake's stops (as before
    the brake had its own): the brake's stops break the controller contract."""
    rig = brake_flight("x500", own_surface=False)
    bad = controller_violations(rig)
    assert bad, "the brake's stop must exceed the Hold's E_tr_pred"
    stops = [e["t"] for e in rig.log.named("hold_trigger")]
    assert all(any(0.0 <= v["t"] - t0 <= 2.0 for t0 in stops) for v in bad)  # during a brake's stop
    assert max(v["observed"] for v in bad) > max(v["assumed"] for v in bad) + 0.05


# ----------------------------------------------------------------------------- the pieces, without a flight

@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
def test_the_contract_brakes_as_the_brake_flies(vehicle):
    """One (a, j) for the stop the daemon streams and for its stop contract: the airframe's braking at the
    attitude-rate jerk (the vehicle's lag behind it is E_tr, not a share of the deceleration)."""
    veh = load_vehicle(vehicle)
    for tr in (veh.thrust_ratio_range[0], 1.0):
        a, j = recovery_brake_stop(veh, tr)
        assert a == pytest.approx(max(airframe_decel(veh, tr), braking_decel(veh, tr)))
        assert j == pytest.approx(stop_jerk(veh))
        assert recovery_brake(veh, tr, 0.02)[:2] == (a, j)


@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
def test_the_shipped_tables_carry_the_brakes_surface_above_the_holds(vehicle):
    t = load_for_vehicle(vehicle)
    assert "e_tr_pred_brake" in t.available and t.e_pred_brake is not None
    b, s = t.e_pred_brake, t.e_pred_stop
    assert all(np.array_equal(x, y) for x, y in zip(b.axes, s.axes))
    assert np.all(b.values >= s.values - 1e-12)  # the governor's manoeuvres are flown in it too
    assert "brake" in b.info["per_maneuver_worst_m"]
    # at the vehicle's tilt, where the brake flies, its own stop is the worst manoeuvre at the speeds it brakes from
    assert np.all(b.values[2:7, -1, -1] > s.values[2:7, -1, -1])  # 2 to 4 m/s
    veh = t.vehicle
    assert t.e_tr_pred(4.0, veh.tilt_max, 1.0, "brake") == pytest.approx(b.values[6, -1, -1])


def test_the_brakes_stop_tracks_worse_than_the_holds():
    """Why the brake needs its own controller contract: the X500's stop at the airframe's braking lags more behind
    its reference than the autopilot's gentler Hold (same SITL cascade, same wind)."""
    veh = load_vehicle("x500")
    brake = BrakeReference("brake", 4.0, *recovery_brake_stop(veh, 1.0))
    hold = smooth_step_reference("hold", 4.0, 0.0, veh.braking.accel_max_m_s2, veh.braking.jerk_max_m_s3)
    e_brake, e_hold = worst_contour_error(veh, brake, 1.0, 0), worst_contour_error(veh, hold, 1.0, 0)
    assert math.isfinite(e_brake) and e_brake > 1.3 * e_hold


def test_the_brake_cell_flies_the_governors_manoeuvres_and_the_brake():
    veh = load_vehicle("mambo")
    refs = es.cell_references(None, veh, 3.0, veh.tilt_max, 1.0, (0, 0), governor="brake")
    assert [r.name for r in refs] == list(es.BRAKE_MANEUVERS)
    assert (refs[-1].a_stop, refs[-1].jerk) == recovery_brake_stop(veh, 1.0, veh.tilt_max)


def test_without_the_brakes_surface_the_brake_is_unavailable_and_its_limit_is_none(tmp_path):
    shipped = load_for_vehicle("mambo")
    path = tmp_path / "old.npz"
    write_table(path, shipped.vehicle, tilt_model=shipped.tilt_model, avoid=shipped.avoid, e_tr_pred=shipped.e_pred,
                e_tr_pred_stop=shipped.e_pred_stop)
    old = verify(path, shipped.vehicle)
    assert old.e_pred_brake is None and "e_tr_pred_brake" not in old.available
    om = old.omega(6.0, 1.0, 0.3, 1.0, contract="stop", recovery_dt=0.02, e_brake=True)
    assert om.v_max == 0.0 and "recovery brake" in om.reason
    assert old.e_tr_pred(3.0, 0.3, 1.0, "brake") == math.inf
    brake = RecoveryBrake(shipped.vehicle, 0.22, covered=False)
    part = brake.available((True, "ok"))
    assert not brake.ready and part.events[0][1]["reason"] == NOT_COVERED


def test_the_brakes_slot_round_trips_with_its_hash(tmp_path):
    shipped = load_for_vehicle("x500")
    path = tmp_path / "t.npz"
    b = shipped.e_pred_brake
    write_table(path, shipped.vehicle, tilt_model=shipped.tilt_model, avoid=shipped.avoid, e_tr_pred=shipped.e_pred,
                e_tr_pred_stop=shipped.e_pred_stop, e_tr_pred_brake=Slot(b.axes, b.values, b.info))
    again = verify(path, shipped.vehicle)
    assert np.array_equal(again.e_pred_brake.values, b.values)
    assert again.meta["arrays_sha256"] == shipped.meta["arrays_sha256"]


def test_the_brakes_surface_is_written_beside_the_others_kept_exactly(tmp_path):
    """`table etr --brake` (`build_governor_etr(brake=True)`): the `e_tr_pred_brake` slot written from the governor's
    manoeuvres and the brake's stop, every other slot kept bit for bit, the hash over them all."""
    shipped = load_for_vehicle("mambo")
    grid = es.EtrGrid(v=np.array([2.0, 4.0]), tilt=np.radians([25.0]), thrust_ratio=np.array([1.0]), seeds=(0,))
    out = tmp_path / "t.npz"
    es.build_governor_etr(shipped.path, "mambo", grid, workers=1, progress=False, out=out, brake=True)
    t = verify(out, shipped.vehicle)
    for name in ("avoid", "e_pred", "e_pred_stop"):
        assert np.array_equal(getattr(t, name).values, getattr(shipped, name).values)
    info = t.e_pred_brake.info
    assert set(info["per_maneuver_worst_m"]) == set(es.BRAKE_MANEUVERS) and "recovery brake" in info["method"]
    worst = max(info["per_maneuver_worst_m"].values())
    assert t.e_pred_brake.values.max() >= worst * (1 + es.MARGIN_REL) + es.MARGIN_ABS - 1e-12
