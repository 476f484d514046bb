"""`table build` and your own vehicle: the grid covers the vehicle, and a stop-only table needs no SITL keys.

A table whose thrust axis starts above the vehicle's `thrust_ratio_range` gives no safe speed below it:
in flight the thrust estimate starts at the range's bottom until airborne and settled, so engaging right
after take-off held the aircraft for the whole flight. `table build` now refuses such a grid (with
`--partial-grid` it builds and warns), and the quick grids of docs/vehicle-file.md take their thrust and
tilt axes from the vehicle file instead of repeating 0.65–1.0. Before, a vehicle file with
`thrust_ratio_range: [0.6, 1.0]` built from grid-small.yaml without a word."""

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from companion import cli
from contracts.errors import ContractError
from contracts.table import shipped_vehicles
from contracts.vehicle import SITL_KEYS, load_vehicle

ROOT = Path(__file__).resolve().parents[1]
VEHICLES = ROOT / "examples" / "vehicles"
QUAD = VEHICLES / "quad-1600g.yaml"


def vehicle_file(tmp_path: Path, drop=(), **changes) -> Path:
    """quad-1600g with `changes` to its keys and the keys in `drop` left out."""
    data = yaml.safe_load(QUAD.read_text())
    data.update(changes)
    for k in drop:
        data.pop(k)
    out = tmp_path / "vehicle.yaml"
    out.write_text(yaml.safe_dump(data))
    return out


def grid_file(tmp_path: Path, **axes) -> Path:
    out = tmp_path / "grid.yaml"
    out.write_text(yaml.safe_dump({"rho": [0.3, 0.6], "n_intervals": 12, "starts": 1, "chunk": 2, **axes}))
    return out


def test_a_grid_below_the_vehicles_thrust_range_is_refused_with_one_line(tmp_path, capsys):
    veh = vehicle_file(tmp_path, thrust_ratio_range=[0.6, 1.0])
    grid = grid_file(tmp_path, tilt_deg=[15, 30], thrust_ratio=[0.65, 1.0])
    rc = cli.main(["table", "build", "--vehicle", str(veh), "--grid", str(grid), "--out", str(tmp_path / "t.npz")])
    err = capsys.readouterr().err
    assert rc == cli.EXIT_USER_ERROR and len(err.strip().splitlines()) == 1, err
    assert "thrust_ratio axis starts at 0.65 above the vehicle's 0.6" in err and "--partial-grid" in err
    assert not (tmp_path / "t.npz").exists()


@pytest.mark.parametrize("axes, words", [
    ({"tilt_deg": [15, 25], "thrust_ratio": [0.65, 1.0]}, "tilt axis ends at 25° below the vehicle's tilt limit 30°"),
    ({"tilt_deg": [15, 30], "thrust_ratio": [0.65, 0.9]}, "thrust_ratio axis ends at 0.9 below the vehicle's 1"),
])
def test_a_grid_short_of_the_vehicles_limits_is_named(axes, words, tmp_path):
    from contracts.sweep import grid_coverage, load_grid

    veh = load_vehicle(QUAD)
    assert [words] == [g.split(" (")[0] for g in grid_coverage(load_grid(grid_file(tmp_path, **axes), veh), veh)]


def test_partial_grid_builds_and_warns(tmp_path, capsys):
    pytest.importorskip("casadi")
    veh = vehicle_file(tmp_path, thrust_ratio_range=[0.6, 1.0])
    grid = grid_file(tmp_path, tilt_deg=[30], thrust_ratio=[0.65, 1.0])
    out = tmp_path / "t.npz"
    assert cli.main(["table", "build", "--vehicle", str(veh), "--grid", str(grid), "--out", str(out), "--workers", "1",
                     "--partial-grid", "--json"]) == 0
    err = capsys.readouterr().err
    assert "warning: the grid does not cover the vehicle: thrust_ratio axis starts at 0.65" in err
    from contracts.table import verify

    table = verify(out)
    assert table.v_safe(8.0, 0.5, 0.3, math.radians(30), 0.62) == 0.0  # below the axis: no safe speed, as warned
    assert table.v_safe(8.0, 0.5, 0.3, math.radians(30), 0.7) > 0.0


@pytest.mark.parametrize("name", [*shipped_vehicles(), str(QUAD)])
def test_the_default_grid_covers_every_vehicle(name):
    from contracts.sweep import default_grid, grid_coverage

    veh = load_vehicle(name)
    assert grid_coverage(default_grid(veh), veh) == []


def test_the_default_grid_ends_at_limits_off_its_steps(tmp_path):
    from contracts.sweep import default_grid, grid_coverage

    veh = load_vehicle(vehicle_file(tmp_path, thrust_ratio_range=[0.62, 1.0], tilt_max_deg=30.1))
    g = default_grid(veh)
    assert g.thrust_ratio[0] == 0.62 and g.thrust_ratio[-1] == 1.0 and math.isclose(math.degrees(g.tilt[-1]), 30.1)
    assert np.all(np.diff(g.thrust_ratio) > 0) and np.all(np.diff(g.tilt) > 0)
    assert grid_coverage(g, veh) == []


@pytest.mark.parametrize("lo, tilt", [(0.6, 30.0), (0.65, 30.0), (0.7, 35.0), (0.62, 27.5)])
def test_the_quick_grids_of_the_guide_follow_the_vehicle_file(lo, tilt, tmp_path):
    from contracts.sweep import grid_coverage, load_grid
    from sitl_harness.etr_sweep import load_etr_grid

    veh = load_vehicle(vehicle_file(tmp_path, thrust_ratio_range=[lo, 1.0], tilt_max_deg=tilt))
    g = load_grid(VEHICLES / "grid-small.yaml", veh)
    assert grid_coverage(g, veh) == [] and list(g.thrust_ratio) == [lo, 1.0]
    e = load_etr_grid(VEHICLES / "etr-small.yaml", veh)
    assert list(e.thrust_ratio) == [lo, 1.0] and math.isclose(math.degrees(e.tilt[-1]), tilt)
    # the E_tr grid's points lie on the avoid grid's axes (`table etr` requires it)
    assert all(np.isclose(g.tilt, t).any() for t in e.tilt) and all(np.isclose(g.thrust_ratio, r).any()
                                                                   for r in e.thrust_ratio)


def test_an_axis_without_min_or_max_outside_a_vehicle_grid_is_one_line():
    from contracts.gridspec import axis

    with pytest.raises(ContractError, match="v_max needs min and max"):
        axis({"n": 3}, "v_max")
    with pytest.raises(ContractError, match="takes min, max"):
        axis({"min": 1, "max": 2}, "tilt_deg", span=(3, 30))


def test_a_stop_only_table_needs_no_sitl_keys(tmp_path, capsys):
    veh = vehicle_file(tmp_path, drop=SITL_KEYS)
    assert all(getattr(load_vehicle(veh), k) is None for k in SITL_KEYS)
    out = tmp_path / "stop.npz"
    assert cli.main(["table", "build", "--vehicle", str(veh), "--stop-only", "--out", str(out)]) == 0
    capsys.readouterr()
    assert cli.main(["table", "verify", str(out), "--vehicle", str(veh)]) == 0


def test_the_avoid_table_and_the_sitl_name_the_keys_they_need(tmp_path, capsys):
    veh = vehicle_file(tmp_path, drop=SITL_KEYS)
    rc = cli.main(["table", "build", "--vehicle", str(veh), "--out", str(tmp_path / "t.npz")])
    err = capsys.readouterr().err
    assert rc == cli.EXIT_USER_ERROR and "inertia_kg_m2, yaw_moment_max_nm required for the avoid table" in err
    from sitl_harness.sim import Sim

    with pytest.raises(ContractError, match="inertia_kg_m2, yaw_moment_max_nm, rotor required for the SITL"):
        Sim(None, vehicle=load_vehicle(veh))
