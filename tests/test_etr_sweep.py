"""The controller-contract sweep (issue 6, item 1): references, flights, a tiny build through the writer."""

import math
import shutil

import numpy as np
import pytest

from contracts.lookup import is_monotone
from contracts.table import SLOTS, verify
from contracts.vehicle import DATA_DIR, load_vehicle
from sitl_harness import etr_sweep as es

MAMBO = load_vehicle("mambo")
TABLE = DATA_DIR / "mambo.npz"


def test_zoh_reference_matches_the_planner_propagation_at_the_nodes():
    from contracts.planner import propagate

    rng = np.random.default_rng(3)
    w = np.zeros((7, 4))
    w[:, :2] = rng.uniform(-2, 2, (7, 2))
    q0 = (0.0, 3.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0)
    ts = 0.1
    ref = es.zoh_reference("x", q0, w, ts, coast_s=0.5)
    q = propagate(np.array(q0), w, ts)
    for k in range(8):
        i = int(round(k * ts / es.DT_NAV))
        assert np.allclose(ref.p[i], q[k, [0, 2]], atol=1e-9)
        assert np.allclose(ref.v[i], q[k, [1, 3]], atol=1e-9)
    # between the nodes: the planner's own dense re-simulation
    from contracts.planner import dense_states

    t, qd, _ = dense_states(np.array(q0), w, ts, 10)
    for i in range(0, len(t) - 1, 3):
        j = int(round(t[i] / es.DT_NAV))
        assert np.allclose(ref.p[j], qd[i, [0, 2]], atol=1e-9)
    # after the last interval: ballistic coast, no acceleration
    assert np.allclose(ref.a[-1], 0.0)
    assert np.allclose(ref.p[-1], q[-1, [0, 2]] + 0.5 * q[-1, [1, 3]], atol=1e-9)
    # before t = 0: the entry line
    p, v, a = ref.at(-1.0)
    assert np.allclose(p, [-3.0, -0.5]) and np.allclose(v, [3.0, 0.5]) and np.allclose(a, 0.0)


def test_speed_step_reaches_its_target_speed():
    ref = es.speed_step_reference("s", 6.0, 0.0, 2.0)
    assert abs(ref.v[-1, 0]) < 1e-9 and ref.p[-1, 0] == pytest.approx(9.0)
    up = es.speed_step_reference("u", 2.0, 4.0, 1.0)
    assert up.v[-1, 0] == pytest.approx(4.0)


def test_contour_error_grows_with_speed():
    """Figure 12's trend in the SITL: the same manoeuvre set is tracked worse at higher speed."""
    tilt = math.radians(9.0)
    e = []
    for v in (2.0, 6.0):
        refs = es.cell_references(None, MAMBO, v, tilt, 0.8, (0, 0))
        e.append(max(es.worst_contour_error(MAMBO, r, 0.8, 0) for r in refs))
    assert e[1] > 1.5 * e[0] > 0.0


def test_lost_vehicle_is_an_unbounded_cell():
    """Thrust far below hover: the vehicle falls, the cell has no bound (+inf), never a number."""
    ref = es.cruise_reference(2.0, duration=3.0)
    assert es.worst_contour_error(MAMBO, ref, 0.3, 0) == math.inf


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
    assert after.available == ["stop", "avoid", "e_tr_pred"]
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
    worst = max(es.worst_contour_error(MAMBO, r, float(trs[k]), 0) for r in refs)
    assert after.e_pred.values[1, j, k] >= worst * (1 + es.MARGIN_REL) + es.MARGIN_ABS - 1e-12


def test_the_sweep_uses_the_avoid_sweeps_pool_mechanism():
    from contracts import sweep

    assert sweep._run_tasks is sweep.run_tasks  # one mechanism, public, shared
    out = sweep.run_tasks([{"x": 1}, {"x": 2}], 1, None, False, 2, fn=_echo, desc="t")
    assert out == [[1], [2]]


def _echo(task):
    return [task["x"]]


def test_dask_path_gives_the_same_surface_as_in_process(tmp_path):
    distributed = pytest.importorskip("distributed")
    grid = es.EtrGrid(v=np.array([2.0]), tilt=np.radians([9.0]), thrust_ratio=np.array([0.8]), rhos=(0.1,),
                      seeds=(0,))
    local, _ = es.measure_surface(TABLE, MAMBO, grid, workers=1, progress=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        remote, _ = es.measure_surface(TABLE, MAMBO, grid, scheduler=lc.scheduler_address, progress=False)
    assert np.array_equal(local, remote) and local[0, 0, 0] > 0
