"""The avoid sweep: a small table built in CI (≤ 20 solves), grid files, repair limit, Dask path."""

import math

import numpy as np
import pytest

pytest.importorskip("casadi")

from contracts import sweep  # noqa: E402
from contracts.avoid_limit import policy_limit_f, stop_speed_kinematic  # noqa: E402
from contracts.errors import ContractError  # noqa: E402
from contracts.flat import horizontal_accel_limit  # noqa: E402
from contracts.lookup import is_monotone  # noqa: E402
from contracts.planner import check_trajectory, head_on_problem  # noqa: E402
from contracts.table import verify  # noqa: E402
from contracts.trajectories import limiting_trajectory  # noqa: E402
from contracts.vehicle import G, load_vehicle  # noqa: E402

CI_GRID = {"rho": [0.05, 0.15, 0.3, 0.6], "tilt_deg": [5, 13], "thrust_ratio": [0.6, 1.0], "starts": 1}
# these grids stop short of the Mambo's 25° tilt limit and thrust range on purpose (seconds, not minutes):
# partial_grid builds them anyway (tests/test_grid_coverage.py checks the refusal without it)


@pytest.fixture(scope="module")
def ci_table(tmp_path_factory):
    veh = load_vehicle("mambo")
    out = tmp_path_factory.mktemp("avoid") / "ci.npz"
    summary = sweep.build_avoid_table(veh, out, grid=CI_GRID, workers=1, progress=False,
                                     partial_grid=True)
    return veh, out, summary


def test_ci_table_is_small_verifies_and_is_monotone(ci_table):
    veh, out, summary = ci_table
    assert summary["solves"] <= 20
    table = verify(out, veh)  # schema, hash, monotonicity, vehicle
    f = table.avoid.values
    assert is_monotone(f, (-1, +1, +1))
    assert summary["verify_fallbacks"] == 0
    assert table.meta["contracts"]["avoid"]["tilt_model"] == "cone"


def test_ci_table_between_stop_branch_and_physical_limit(ci_table):
    veh, out, _ = ci_table
    table = verify(out, veh)
    rho, tilt, tr = table.avoid.axes
    for j, t in enumerate(tilt):
        for k, r in enumerate(tr):
            a_g = horizontal_accel_limit(t, veh.t_max(r), veh.mass_kg) / G
            f_stop = np.sqrt(2 * a_g * (1 - rho))
            assert np.all(table.avoid.values[:, j, k] >= f_stop * (1 - 1e-6))
    for i in (0, 2):  # against the independent open-loop estimate: never above it by > 0.1 %
        a_g = horizontal_accel_limit(tilt[0], veh.t_max(tr[0]), veh.mass_kg) / G
        est = policy_limit_f(rho[i], a_g)
        assert table.avoid.values[i, 0, 0] <= 1.001 * est
        assert table.avoid.values[i, 0, 0] >= 0.93 * est


def test_ci_trajectories_side_file_re_simulates_at_another_scale(ci_table):
    veh, out, _ = ci_table
    table = verify(out, veh)
    from contracts.planner import Limits

    for i, j, k, c in ((0, 0, 0, 7.3), (3, 1, 1, 2.2)):
        tr = limiting_trajectory(out, i, j, k, c)
        lim = Limits.from_vehicle(veh, float(table.avoid.axes[1][j]), float(table.avoid.axes[2][k]))
        pr = head_on_problem(lim, tr["v"], c, tr["r_k"], n=len(tr["w"]))
        assert check_trajectory(pr, tr["w"], tr["ts"], tol=0.0)["ok"]
        assert tr["v"] == pytest.approx(table.avoid.values[i, j, k] * math.sqrt(G * c), rel=1e-6)
        # negative control: the limiting trajectory is tight, flown 2 % faster it hits the disc
        pr_fast = head_on_problem(lim, tr["v"] * 1.02, c, tr["r_k"], n=len(tr["w"]))
        assert not check_trajectory(pr_fast, tr["w"], tr["ts"], tol=0.0)["ok"]


def test_grid_file_format_and_errors(tmp_path):
    veh = load_vehicle("mambo")
    p = tmp_path / "g.yaml"
    p.write_text("rho: {min: 0.02, max: 0.9, n: 7, spacing: geometric}\ntilt_deg: [4, 8]\n"
                 "thrust_ratio: {min: 0.6, max: 1.0, step: 0.2}\nn_intervals: 30\n")
    g = sweep.load_grid(p, veh)
    assert len(g.rho) == 7 and g.rho[0] == pytest.approx(0.02) and g.rho[-1] == pytest.approx(0.9)
    assert np.allclose(np.degrees(g.tilt), [4, 8]) and np.allclose(g.thrust_ratio, [0.6, 0.8, 1.0])
    assert g.n_intervals == 30
    for bad in ("rho: [0.5, 0.2]", "rho: [0.0, 0.5]", "speed: 3", "tilt_deg: nope"):
        p.write_text(bad)
        with pytest.raises(ContractError):
            sweep.load_grid(p, veh)


def test_build_fails_when_more_than_one_percent_of_cells_need_repair(tmp_path, monkeypatch):
    """Fake solver output (valid pure stops, non-monotone in ρ): the build must refuse, not ship."""
    veh = load_vehicle("mambo")

    def fake_run(tasks, workers, scheduler, progress, total, fn=None, desc=None, checkpoint=None):
        out = []
        for t in tasks:
            res = []
            for m, rho in enumerate(t["rhos"]):
                a_b = sweep.brake_accel(t["limits"])
                v = float(stop_speed_kinematic(a_b, 1.0, rho)) * (0.5 if m % 2 == 0 else 1.0)
                w, ts = sweep.stop_trajectory(a_b, v, t["n"])
                res.append(sweep.CellResult(rho, v, math.inf, "stop", w, ts, []))
            out.append(res)
        return out

    monkeypatch.setattr(sweep, "run_tasks", fake_run)
    with pytest.raises(ContractError, match="monotonicity repair"):
        sweep.build_avoid_table(veh, tmp_path / "bad.npz", grid={"rho": [0.1, 0.2, 0.3, 0.4], "tilt_deg": [5],
                                                               "thrust_ratio": [1.0]}, workers=1, progress=False,
                                partial_grid=True)
    assert not (tmp_path / "bad.npz").exists() and not (tmp_path / "bad.npz.partial").exists()


def test_dask_scheduler_path(tmp_path):
    distributed = pytest.importorskip("distributed")
    veh = load_vehicle("mambo")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        s = sweep.build_avoid_table(veh, tmp_path / "d.npz", grid={"rho": [0.2, 0.5], "tilt_deg": [9],
                                                                  "thrust_ratio": [1.0], "starts": 1},
                                    scheduler=lc.scheduler_address, progress=False, partial_grid=True)
    assert s["solves"] <= 8
    verify(tmp_path / "d.npz", veh)
