"""The avoid table between its r_k/c grid points: the default build axis halves the shipped one's log step
(the worst corner in ρ loses up to half of it in speed, F ∝ ρ^(-1/2) where a pass is possible) and keeps
every shipped point, so a rebuild only adds cells."""

import math

import numpy as np

from contracts.sweep import default_grid
from contracts.table import load_for_vehicle
from contracts.vehicle import load_vehicle


def test_the_default_rho_axis_halves_the_120_point_log_step_and_keeps_its_points():
    """The default build axis (the shipped tables') is the 120-point axis with its geometric midpoints."""
    coarse = np.geomspace(0.01, 0.97, 120)
    for name in ("mambo", "x500"):
        veh = load_vehicle(name)
        rho = default_grid(veh).rho
        assert np.allclose(load_for_vehicle(veh).avoid.axes[0], rho, rtol=1e-12, atol=0)
        assert np.allclose(rho[::2], coarse, rtol=1e-12, atol=0)  # every 120-point cell is a cell of it
        step = float(np.max(rho[1:] / rho[:-1]))
        assert step <= math.sqrt(float(np.max(coarse[1:] / coarse[:-1]))) * (1 + 1e-12) < 1.02


def test_where_a_pass_is_possible_f_falls_as_the_inverse_square_root_of_rho():
    """The slope the axis spacing is sized by: d ln F / d ln ρ = −1/2 over the pass branch of every column."""
    t = load_for_vehicle(load_vehicle("mambo"))
    rho, f = t.avoid.axes[0], t.avoid.values
    sel = (rho > 0.1) & (rho < 0.5)
    slope = np.diff(np.log(f[sel]), axis=0) / np.diff(np.log(rho[sel]))[:, None, None]
    assert np.allclose(slope, -0.5, atol=2e-3)
