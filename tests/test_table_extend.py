"""`table build --extend BASE`: a built avoid table rebuilt on a finer ρ axis keeps every verified cell of its base
and solves only the new ρ points (real IPOPT solves on a small grid), carries the base's E_tr_pred slots with a
note of the avoid cells they flew, and refuses a base whose cells were solved for another problem."""

import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("casadi")

from contracts import sweep  # noqa: E402
from contracts.errors import ContractError  # noqa: E402
from contracts.planner import Limits, check_trajectory, head_on_problem  # noqa: E402
from contracts.table import Slot, slot_sha256, verify, write_table  # noqa: E402
from contracts.trajectories import limiting_trajectory, trajectories_path  # noqa: E402
from contracts.vehicle import load_vehicle  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
AXES = {"tilt_deg": [5, 13], "thrust_ratio": [0.6, 1.0], "starts": 1}
BASE_RHO, FINE_RHO = [0.05, 0.3], [0.05, 0.15, 0.3, 0.6]
MAMBO = load_vehicle("mambo")


def _with_controller_slots(base: Path, out: Path) -> Path:
    """The base table with E_tr_pred slots beside its avoid slot (as `table etr` leaves it) and its trajectories."""
    t = verify(base, MAMBO)
    axes = (np.array([1.0, 2.0]), t.avoid.axes[1], t.avoid.axes[2])
    e = np.full((2, 2, 2), 0.2)
    e[1] = 0.3
    write_table(out, MAMBO, avoid=t.avoid,
                e_tr_pred=Slot(axes, e, {"grid": {"avoid_rhos": [0.05, 0.2]}, "method": "test"}),
                e_tr_pred_stop=Slot(axes, 0.5 * e, {"method": "test"}), method={"avoid": "test"})
    shutil.copy(trajectories_path(base), trajectories_path(out))
    return out


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("extend")
    sweep.build_avoid_table(MAMBO, d / "b0.npz", grid={**AXES, "rho": BASE_RHO}, workers=1, progress=False,
                            partial_grid=True)
    base = _with_controller_slots(d / "b0.npz", d / "base.npz")
    ext = sweep.build_avoid_table(MAMBO, d / "fine.npz", grid={**AXES, "rho": FINE_RHO}, workers=1, progress=False,
                                  partial_grid=True, extend=base)
    full = sweep.build_avoid_table(MAMBO, d / "full.npz", grid={**AXES, "rho": FINE_RHO}, workers=1, progress=False,
                                   partial_grid=True)
    return d, base, ext, full


def test_extension_solves_only_the_new_points_and_keeps_every_base_cell(built):
    d, base, ext, full = built
    b, f = verify(base, MAMBO), verify(d / "fine.npz", MAMBO)
    assert np.array_equal(f.avoid.axes[0], FINE_RHO)
    e = ext["extends"]
    assert (e["kept_class_cells"], e["solved_class_cells"]) == (2, 2)
    assert e["kept_cells_lowered"] == 0 and e["kept_cells_raised"] == 0
    assert np.array_equal(f.avoid.values[[0, 2]], b.avoid.values)  # bit for bit
    with np.load(trajectories_path(base)) as zb, np.load(trajectories_path(d / "fine.npz")) as zf:
        for k in ("v", "v_hi", "w", "ts", "branch"):
            assert np.array_equal(zf[k][:, [0, 2]], zb[k]), k
    # negative control: the same grid from scratch solves all four ρ points
    assert full["extends"] is None and full["solves"] > ext["solves"]
    assert f.meta["contracts"]["avoid"]["extends"]["base_avoid_sha256"] == slot_sha256("avoid", b.avoid)


def test_new_cells_are_verified_and_tight(built):
    d, _, _, _ = built
    out = d / "fine.npz"
    t = verify(out, MAMBO)
    for i, j, k, c in ((1, 0, 0, 6.1), (3, 1, 1, 2.4)):
        tr = limiting_trajectory(out, i, j, k, c)
        lim = Limits.from_vehicle(MAMBO, float(t.avoid.axes[1][j]), float(t.avoid.axes[2][k]))
        assert check_trajectory(head_on_problem(lim, tr["v"], c, tr["r_k"], n=len(tr["w"])), tr["w"], tr["ts"],
                                tol=0.0)["ok"]
        fast = head_on_problem(lim, tr["v"] * 1.02, c, tr["r_k"], n=len(tr["w"]))
        assert not check_trajectory(fast, tr["w"], tr["ts"], tol=0.0)["ok"]


def test_the_finer_axis_is_never_slower_and_faster_between_base_points(built):
    d, base, _, _ = built
    b, f = verify(base, MAMBO), verify(d / "fine.npz", MAMBO)
    rng = np.random.default_rng(3)
    gained = 0
    for _ in range(200):
        c = rng.uniform(3.0, 12.0)
        r_k = c * math.exp(rng.uniform(math.log(0.05), math.log(0.3)))  # inside the base's ρ span
        r_obst = min(0.5 * r_k, c - 0.5)
        e_tr = max(r_k - r_obst - MAMBO.r_body_m, 0.0)
        args = (c - r_obst, r_obst, e_tr, math.radians(rng.uniform(5.0, 13.0)), rng.uniform(0.6, 1.0))
        vb, vf = b.v_safe(*args), f.v_safe(*args)
        assert vf >= vb * (1 - 1e-12)
        gained += vf > vb * 1.001
    assert gained > 20


def test_controller_slots_are_carried_with_the_avoid_cells_they_flew(built):
    d, base, _, _ = built
    b, f = verify(base, MAMBO), verify(d / "fine.npz", MAMBO)
    assert f.available == ["stop", "avoid", "e_tr_pred", "e_tr_pred_stop"]
    assert np.array_equal(f.e_pred.values, b.e_pred.values) and np.array_equal(f.e_pred_stop.values,
                                                                                 b.e_pred_stop.values)
    flown = f.e_pred.info["avoid_cells_flown"]
    assert flown["avoid_sha256_flown"] == slot_sha256("avoid", b.avoid)
    assert flown["rho"] == [0.05, 0.3] and set(flown["rho"]) <= set(f.avoid.axes[0].tolist())
    # the trajectories are tied to the avoid slot itself, not to the whole table (whose E_tr arrays differ)
    with np.load(trajectories_path(d / "fine.npz")) as z:
        import json

        tied = json.loads(z["metadata_json"].tobytes().decode())["arrays_sha256"]
    assert tied == slot_sha256("avoid", f.avoid) and tied != f.meta["arrays_sha256"]


@pytest.mark.parametrize("grid,match", [
    ({**AXES, "rho": FINE_RHO, "tilt_deg": [5, 14]}, "tilt and thrust axes"),
    ({**AXES, "rho": [0.05, 0.15, 0.6]}, "not on the new axis"),
    ({**AXES, "rho": FINE_RHO, "starts": 2}, "solver setting starts"),
])
def test_a_base_solved_for_another_problem_is_refused_before_any_solve(built, grid, match, tmp_path, monkeypatch):
    _, base, _, _ = built
    monkeypatch.setattr(sweep, "run_tasks", lambda *a, **k: pytest.fail("solved before refusing"))
    with pytest.raises(ContractError, match=match):
        sweep.build_avoid_table(MAMBO, tmp_path / "x.npz", grid=grid, workers=1, progress=False, partial_grid=True,
                                extend=base)


def test_a_base_with_another_tables_trajectories_is_refused(built, tmp_path):
    d, base, _, _ = built
    shutil.copy(base, tmp_path / "base.npz")
    shutil.copy(trajectories_path(d / "fine.npz"), trajectories_path(tmp_path / "base.npz"))
    with pytest.raises(ContractError, match="not the trajectories file"):
        sweep.build_avoid_table(MAMBO, tmp_path / "x.npz", grid={**AXES, "rho": FINE_RHO}, workers=1,
                                progress=False, partial_grid=True, extend=tmp_path / "base.npz")


@pytest.mark.parametrize("extra,match", [
    (["--stop-only"], "does not go with --stop-only"),
    ([], "no such file"),
])
def test_cli_refusals_are_one_line(tmp_path, extra, match):
    p = subprocess.run([sys.executable, "-m", "companion.cli", "table", "build", "--vehicle", "mambo", "--out",
                        str(tmp_path / "x.npz"), "--extend", str(tmp_path / "missing.npz"), *extra], cwd=ROOT,
                       capture_output=True, text=True, timeout=120, check=False,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin"})
    assert p.returncode != 0 and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and match in p.stderr
