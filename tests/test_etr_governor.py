"""Issue 28 item 2: the governor's E_tr_pred flown on what a governed vehicle flies (cruise, speed steps, the
autopilot's own braking stop), never a swerve — on a small grid."""

import math

import numpy as np
import pytest

from contracts.stop import braking_decel, braking_distance
from contracts.table import load_for_vehicle
from contracts.vehicle import load_vehicle
from sitl_harness import etr_sweep as es
from sitl_harness.maneuvers import DT_NAV, smooth_step_reference

MAMBO = load_vehicle("mambo")


@pytest.mark.parametrize("v", [0.5, 2.0, 6.0])
def test_hold_is_the_autopilots_jerk_limited_stop(v):
    a, j = 3.0, 4.0
    ref = smooth_step_reference("hold", v, 0.0, a, j)
    assert np.all(ref.v[-1] == 0.0) and ref.p[-1, 1] == 0.0
    assert ref.p[-1, 0] == pytest.approx(braking_distance(v, a, j), rel=2e-3)
    assert np.max(-ref.a[:, 0]) <= a * (1 + 1e-9) and np.all(ref.a[:, 0] <= 1e-12)
    assert np.max(np.abs(np.diff(ref.a[:, 0]))) <= 2 * j * DT_NAV * 1.01  # no step (ZOH of a jerk-limited stop)
    up = smooth_step_reference("smooth_up", 0.5 * v, v, a, j)
    assert up.v[-1, 0] == pytest.approx(v) and np.min(up.a[:, 0]) >= 0.0 and np.max(up.a[:, 0]) <= a * (1 + 1e-9)


@pytest.fixture(scope="module")
def governor_cells():
    grid = es.EtrGrid(v=np.array([2.0, 4.0]), tilt=np.radians([25.0]), thrust_ratio=np.array([1.0]), seeds=(0,))
    return grid, es.governor_surface(MAMBO, grid, workers=1, progress=False)


def test_the_governor_surface_flies_no_swerve_and_keeps_the_margin(governor_cells):
    grid, (e, per, repairs) = governor_cells
    assert set(per) == set(es.GOVERNOR_MANEUVERS) and "avoid" not in per and "online" not in per
    worst = np.max(np.stack(list(per.values())), axis=0)
    assert np.all(worst > 0) and np.all(np.isfinite(e))
    assert np.all(e >= worst * (1 + es.MARGIN_REL) + es.MARGIN_ABS - 1e-12)
    assert np.all(np.diff(e[:, 0, 0]) >= 0) and repairs >= 0


def test_the_governor_surface_is_below_the_offboard_one(governor_cells):
    """What the governor buys: the shipped surface bounds swerves a governed vehicle never flies."""
    grid, (e, _, _) = governor_cells
    t = load_for_vehicle(MAMBO)
    for i, v in enumerate(grid.v):
        assert e[i, 0, 0] < t.e_tr_pred(float(v), math.radians(25.0), 1.0)


def test_the_governors_stop_brakes_at_the_autopilots_deceleration():
    refs = es.cell_references(None, MAMBO, 3.0, math.radians(25.0), 1.0, (0, 0), governor=True)
    assert [r.name for r in refs] == list(es.GOVERNOR_MANEUVERS)
    hold = refs[-1]
    assert np.max(-hold.a[:, 0]) == pytest.approx(braking_decel(MAMBO, 1.0, math.radians(25.0)), rel=1e-6)


def test_a_table_carrying_the_governor_surface_answers_the_stop_contract_with_it(tmp_path):
    """`build_governor_etr` writes the `e_tr_pred_stop` slot next to the others (kept exactly); the stop contract's
    Ω and Γ then use it, the avoid contract keeps the general surface, and V_max never exceeds v_stop."""
    from contracts.table import verify

    from contracts.table import write_table

    shipped = load_for_vehicle(MAMBO)
    base = tmp_path / "mambo.npz"  # the shipped table without its governor slot (a table from before it)
    write_table(base, MAMBO, tilt_model=shipped.tilt_model, avoid=shipped.avoid, e_tr_pred=shipped.e_pred,
                method={k: v for k, v in shipped.meta["method"].items() if k != "e_tr_pred_stop"})
    out = tmp_path / "mambo_gov.npz"
    grid = {"v_max": [1.0, 2.0, 3.0, 4.0, 5.0], "tilt_deg": [25.0], "thrust_ratio": [0.6, 1.0], "seeds": [0]}
    es.build_governor_etr(base, MAMBO, grid, workers=1, progress=False, out=out)
    stock, gov = verify(base, MAMBO), verify(out, MAMBO)
    assert "e_tr_pred_stop" in gov.available and "e_tr_pred_stop" not in stock.available
    assert np.array_equal(gov.e_pred.values, stock.e_pred.values) and np.array_equal(gov.avoid.values, stock.avoid.values)
    tilt = math.radians(25.0)
    for d_od in (4.0, 8.0):
        s, g = stock.omega(d_od, 1.0, 0.1, 1.0, "stop"), gov.omega(d_od, 1.0, 0.1, 1.0, "stop")
        assert s.v_max <= g.v_max <= gov.v_stop(d_od, 1.0, g.e_tr, 1.0) + 1e-12
        assert g.e_tr == pytest.approx(max(0.1, gov.e_tr_pred(g.v_max, tilt, 1.0, "stop")))
        assert gov.gamma(g.v_max, d_od, 1.0, 0.1, 1.0, contract="stop") <= 1e-12
        assert gov.omega(d_od, 1.0, 0.1, 1.0, "avoid").v_max == stock.omega(d_od, 1.0, 0.1, 1.0, "avoid").v_max
    assert gov.e_tr_pred(2.0, tilt, 1.0, "stop") < gov.e_tr_pred(2.0, tilt, 1.0) == stock.e_tr_pred(2.0, tilt, 1.0)
    assert gov.e_tr_pred(5.5, tilt, 1.0, "stop") == math.inf  # above the governor grid: no bound
