"""The controller-contract sweep (issue 6, item 1): references, flights, a tiny build through the writer."""

import math
import shutil

import numpy as np
import pytest

from contracts.flat import horizontal_accel_limit
from contracts.lookup import is_monotone
from contracts.table import SLOTS, verify
from contracts.vehicle import DATA_DIR, load_vehicle
from sitl_harness import etr_sweep as es
from sitl_harness import maneuvers as mn

MAMBO = load_vehicle("mambo")
TABLE = DATA_DIR / "mambo.npz"


def test_zoh_reference_matches_the_planner_propagation_at_the_nodes():
    from contracts.planner import propagate

    rng = np.random.default_rng(3)
    w = np.zeros((7, 4))
    w[:, :2] = rng.uniform(-2, 2, (7, 2))
    q0 = (0.0, 3.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0)
    ts = 0.1
    ref = mn.zoh_reference("x", q0, w, ts, coast_s=0.5)
    q = propagate(np.array(q0), w, ts)
    for k in range(8):
        i = int(round(k * ts / mn.DT_NAV))
        assert np.allclose(ref.p[i], q[k, [0, 2]], atol=1e-9)
        assert np.allclose(ref.v[i], q[k, [1, 3]], atol=1e-9)
    # between the nodes: the planner's own dense re-simulation
    from contracts.planner import dense_states

    t, qd, _ = dense_states(np.array(q0), w, ts, 10)
    for i in range(0, len(t) - 1, 3):
        j = int(round(t[i] / mn.DT_NAV))
        assert np.allclose(ref.p[j], qd[i, [0, 2]], atol=1e-9)
    # after the last interval: ballistic coast, no acceleration
    assert np.allclose(ref.a[-1], 0.0)
    assert np.allclose(ref.p[-1], q[-1, [0, 2]] + 0.5 * q[-1, [1, 3]], atol=1e-9)
    # before t = 0: the entry line
    p, v, a = ref.at(-1.0)
    assert np.allclose(p, [-3.0, -0.5]) and np.allclose(v, [3.0, 0.5]) and np.allclose(a, 0.0)


def test_speed_step_reaches_its_target_speed():
    ref = mn.speed_step_reference("s", 6.0, 0.0, 2.0)
    assert abs(ref.v[-1, 0]) < 1e-9 and ref.p[-1, 0] == pytest.approx(9.0)
    up = mn.speed_step_reference("u", 2.0, 4.0, 1.0)
    assert up.v[-1, 0] == pytest.approx(4.0)


def test_contour_error_grows_with_speed():
    """Figure 12's trend in the SITL: the same manoeuvre set is tracked worse at higher speed."""
    tilt = math.radians(9.0)
    e = []
    for v in (2.0, 6.0):
        refs = es.cell_references(None, MAMBO, v, tilt, 0.8, (0, 0))
        e.append(max(mn.worst_contour_error(MAMBO, r, 0.8, 0) for r in refs))
    assert e[1] > 1.5 * e[0] > 0.0


def test_lost_vehicle_is_an_unbounded_cell():
    """Thrust far below hover: the vehicle falls, the cell has no bound (+inf), never a number."""
    ref = mn.cruise_reference(2.0, duration=3.0)
    assert mn.worst_contour_error(MAMBO, ref, 0.3, 0) == math.inf


def _online(v, tilt_deg, tr, rho):
    t = verify(TABLE, MAMBO)
    tilt = math.radians(tilt_deg)
    j, k = es._avoid_index(t, tilt, tr)
    i = int(np.argmin(np.abs(t.avoid.axes[0] - rho)))
    a_h = horizontal_accel_limit(tilt, MAMBO.t_max(tr), MAMBO.mass_kg)
    return t, (i, j, k), a_h, es.online_reference(TABLE, i, j, k, v, a_h)


def test_online_geometry_is_the_offboard_contracts_speed_and_the_plan_is_the_planners():
    """online@ρ: the head-on disc at ρ whose offboard contract speed OFFBOARD_CAP × V_safe is the cell's
    speed; the daemon's own planner plans it with the cell's V_max and a_h, and it is verified."""
    from contracts.online_planner import OFFBOARD_CAP, exact_check

    t, (i, j, k), a_h, ref = _online(6.0, 20.0, 1.0, 0.2)
    d = ref.disc
    assert d.y == 0.0 and d.r / d.x == pytest.approx(t.avoid.axes[0][i])
    f = t.avoid.values[i, j, k]  # reduced form: V_safe = sqrt(g c) F (DESIGN.md §2)
    assert OFFBOARD_CAP * math.sqrt(9.80665 * d.x) * f == pytest.approx(6.0, rel=1e-3)
    p = ref.plan
    assert p.ok and p.kind in ("pass", "stop") and np.allclose(p.v[0], [6.0, 0.0], atol=1e-3) \
        and np.allclose(p.p[0], 0.0, atol=1e-3)
    assert exact_check(p.p, p.v, p.a, p.t[1] - p.t[0], [d], 6.0, a_h)[0]
    assert ref.name == f"online@rho={t.avoid.axes[0][i]:.3g}"


def test_online_flight_replans_from_the_measured_state_and_records_the_sent_path():
    _, _, _, ref = _online(6.0, 20.0, 1.0, 0.2)
    run = ref.flight()
    fl = mn.fly(MAMBO, run.setpoint, ref.t_end, 1.0, mn.wind_for_seed(MAMBO, 0), ref.p[0] - ref.v[0] * mn.SETTLE_S,
                ref.v[0])
    assert fl.ok and run.adopted + run.kept == es.ONLINE_REPLANS == 1
    path_t, path_p = run.path()
    assert path_t[0] == pytest.approx(-mn.WINDOW_S) and np.all(np.diff(path_t) > 0)
    if run.adopted:  # the new plan starts where the vehicle was measured, not on the old plan
        assert run.plan_t == pytest.approx(es.REPLAN_S) and run.plan is not ref.plan
        k = int(np.argmin(np.abs(fl.t - es.REPLAN_S)))
        assert np.allclose(run.plan.p[0], fl.pos[k, :2], atol=1e-4)  # (to the QP tolerance)
    # before the manoeuvre the path is the entry line; the same flight flown twice gives the same error
    assert np.allclose(path_p[0], [-6.0 * mn.WINDOW_S, 0.0], atol=1e-3)
    assert mn.worst_contour_error(MAMBO, ref, 1.0, 0) == mn.worst_contour_error(MAMBO, ref, 1.0, 0)


def test_online_geometries_without_a_verified_plan_are_skipped_and_counted():
    t = verify(TABLE, MAMBO)
    tilt = math.radians(25.0)
    idx = es._avoid_index(t, tilt, 1.0)
    skipped = []
    refs = es.cell_references(TABLE, MAMBO, 6.0, tilt, 1.0, idx, rhos=(0.03, 0.2), skipped=skipped)
    names = [r.name for r in refs]
    rho = t.avoid.axes[0]
    low, mid = (f"{rho[int(np.argmin(np.abs(rho - r)))]:.3g}" for r in (0.03, 0.2))  # the grid cells flown
    assert skipped == [f"online@rho={low}"] and f"online@rho={low}" not in names  # the planner brakes there
    assert f"online@rho={mid}" in names and f"avoid@rho={low}" in names


@pytest.fixture(scope="module")
def tiny_build(tmp_path_factory):
    d = tmp_path_factory.mktemp("etr")
    out = d / "mambo.npz"
    shutil.copy(TABLE, out)
    shutil.copy(DATA_DIR / "mambo.trajectories.npz", d / "mambo.trajectories.npz")
    grid = es.EtrGrid(v=np.array([2.0, 4.0]), tilt=np.radians([5.0, 9.0]), thrust_ratio=np.array([0.6, 1.0]),
                      rhos=(0.1, 0.35), seeds=(0,))
    before = verify(out, MAMBO)
    summary = es.build_etr(out, MAMBO, grid, workers=1, progress=False)
    return before, verify(out, MAMBO), summary


def test_tiny_build_writes_a_monotone_slot_and_keeps_the_avoid_slot(tiny_build):
    before, after, summary = tiny_build
    assert after.available == ["stop", "avoid", "e_tr_pred", "e_tr_pred_stop", "e_tr_pred_brake"]
    assert np.array_equal(after.e_pred_stop.values, before.e_pred_stop.values)  # the governor's slots kept exactly
    assert np.array_equal(after.e_pred_brake.values, before.e_pred_brake.values)
    e = after.e_pred.values
    assert e.shape == (2, 2, 2) and np.all(np.isfinite(e)) and np.all(e > es.MARGIN_ABS)
    assert is_monotone(e, SLOTS["e_tr_pred"][2])
    for a, b in zip(before.avoid.axes, after.avoid.axes):
        assert np.array_equal(a, b)
    assert np.array_equal(before.avoid.values, after.avoid.values)
    assert before.avoid.info == after.avoid.info
    assert after.meta["method"]["avoid"] == before.meta["method"]["avoid"]
    assert after.meta["method"]["e_tr_pred"] == "sitl_harness.etr_sweep.build_etr"
    info = after.e_pred.info
    assert info["margin"]["relative"] == es.MARGIN_REL and info["grid"]["seeds"] == [0]
    assert summary["cells"] == 8 and summary["wall_s"] > 0


def test_margin_and_upward_repair_are_what_the_slot_says(tiny_build):
    """E_tr_pred ≥ worst·(1 + rel) + abs of the flights it was built from (re-flown here)."""
    _, after, _ = tiny_build
    v, tilts, trs = after.e_pred.axes
    j, k = 1, 0
    idx = es._avoid_index(after, float(tilts[j]), float(trs[k]))
    refs = es.cell_references(after.path, MAMBO, float(v[1]), float(tilts[j]), float(trs[k]), idx, rhos=(0.1, 0.35))
    worst = max(mn.worst_contour_error(MAMBO, r, float(trs[k]), 0) for r in refs)
    assert after.e_pred.values[1, j, k] >= worst * (1 + es.MARGIN_REL) + es.MARGIN_ABS - 1e-12


def test_the_sweep_uses_the_avoid_sweeps_pool_mechanism():
    from contracts import runner, sweep

    assert sweep.run_tasks is runner.run_tasks is es.run_tasks  # one mechanism, public, shared
    out = runner.run_tasks([{"x": 1}, {"x": 2}], 1, None, False, 2, fn=_echo, desc="t")
    assert out == [[1], [2]]


def _echo(task):
    return [task["x"]]


def test_dask_path_gives_the_same_surface_as_in_process(tmp_path):
    distributed = pytest.importorskip("distributed")
    grid = es.EtrGrid(v=np.array([2.0]), tilt=np.radians([9.0]), thrust_ratio=np.array([0.8]), rhos=(0.1,),
                      seeds=(0,))
    local, _, _ = es.measure_surface(TABLE, MAMBO, grid, workers=1, progress=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        remote, _, _ = es.measure_surface(TABLE, MAMBO, grid, scheduler=lc.scheduler_address, progress=False)
    assert np.array_equal(local, remote) and local[0, 0, 0] > 0


def test_the_default_grid_reaches_each_vehicles_tilt_limit():
    """No tilt above the E_tr grid is usable (the lookup has no bound there), so the grid must reach the
    vehicle's limit: 25° for the Mambo, 35° for the X500."""
    for name in ("mambo", "x500"):
        veh = load_vehicle(name)
        assert math.degrees(es.default_etr_grid(veh).tilt[-1]) == pytest.approx(veh.tilt_max_deg)


def test_failsafe_flight_brakes_mid_swerve_from_the_measured_state():
    """Issue 19 item 9: ``failsafe@ρ`` flies the online plan and, at FAILSAFE_FRAC of it, the daemon's
    fail-safe braking stop (`best_stop` from the measured state at the cell's a_h), then rests. It is part
    of the cell's manoeuvre set next to ``online@ρ``."""
    _, (i, j, k), a_h, _ = _online(6.0, 20.0, 1.0, 0.2)
    ref = es.online_reference(TABLE, i, j, k, 6.0, a_h, "failsafe")
    assert ref.name.startswith("failsafe@rho=") and ref.failsafe_frac == es.FAILSAFE_FRAC
    run = ref.flight()
    fl = mn.fly(MAMBO, run.setpoint, ref.t_end, 1.0, mn.wind_for_seed(MAMBO, 0), ref.p[0] - ref.v[0] * mn.SETTLE_S,
                ref.v[0])
    assert fl.ok and run.stop is not None
    assert run.stop_t == pytest.approx(es.FAILSAFE_FRAC * ref.plan.t[-1], abs=mn.DT_NAV + 1e-9)
    kk = int(np.argmin(np.abs(fl.t - run.stop_t)))
    assert np.allclose(run.stop.p[0], fl.pos[kk, :2], atol=0.05)  # from where the vehicle was measured
    assert np.hypot(*run.stop.v[-1]) < 1e-6  # it ends at rest
    assert np.max(np.hypot(*run.stop.a.T)) <= a_h * (1 + 1e-9)  # at the cell's acceleration
    refs = es.cell_references(TABLE, MAMBO, 6.0, math.radians(20.0), 1.0, (j, k), rhos=(0.2,))
    assert {r.name.split("@")[0] for r in refs} >= {"online", "failsafe"}
