"""Issue 18 item 2: between grid points a cone table answers by the build's own scaling law
F = √(a_h/g)·G(ρ) (contracts/sweep.py), only where the table states it and every corner of the cell obeys it,
never above any corner's verified value scaled to the point by the law, monotone, and never less tight than
the worst corner. No solver calls (the fresh references below are `bench_tightness` figures)."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_omega_lookup import v_safe_reference
from test_table import MAMBO, make

from contracts.flat import horizontal_accel_limit
from contracts.lookup import law_cells, repair_monotone
from contracts.table import LAW_CLAIM, SLOTS, Slot, load_for_vehicle
from contracts.vehicle import G, load_vehicle

TABLES = {n: load_for_vehicle(load_vehicle(n)) for n in ("mambo", "x500")}


def a_grid(t):
    _, tilts, trs = t.avoid.axes
    v = t.vehicle
    return np.array([[horizontal_accel_limit(x, v.t_max(y), v.mass_kg) for y in trs] for x in tilts])


def worst_corner(t, d_od, r_obst, e_tr, tilt, tr):
    """The answer before issue 18: the grid rows only (the worst corner in thrust, grid tilts ≤ tilt)."""
    top, k = t._avoid_cells(tilt, tr)
    if t._bad_inputs(d_od, r_obst, e_tr, tr, tilt) or -1 in (top, k):
        return 0.0
    react, c0, r_k = t._react[k], d_od + r_obst, r_obst + e_tr + t.vehicle.r_body_m
    return react.best(c0, r_k, top, react.at(c0, r_k, top))


@pytest.mark.parametrize("name", sorted(TABLES))
def test_the_scaling_law_holds_exactly_in_every_cell_of_the_shipped_tables(name):
    """F/√(a_h/g) is the same curve in every tilt × thrust cell (to round-off), the table states the law, and the
    loader found it in every cell."""
    t = TABLES[name]
    assert t.tilt_model == "cone" and t.avoid.info["scaling"].startswith(LAW_CLAIM)
    norm = t.avoid.values / np.sqrt(a_grid(t) / G)[None]
    assert np.max(np.abs(norm / norm[:, :1, :1] - 1.0)) < 1e-12
    g_hat, holds = law_cells(t.avoid.values, a_grid(t))
    assert holds.all() and t._law is not None and t._law["holds"].all()
    assert np.allclose(g_hat, norm, rtol=1e-12, atol=0.0)


# bench_tightness (seed 18, 50 points) points where the worst corner lost most: (point, fresh bracket)
LOOSEST = [
    ("mambo", (6.66, 0.486, 0.836, 3.89, 0.992), 3.2719, 3.27517),
    ("mambo", (4.804, 0.377, 0.056, 3.91, 0.632), 3.7574, 3.76113),
    ("x500", (6.66, 0.486, 0.836, 3.89, 0.994), 2.9428, 2.94570),
    ("x500", (13.494, 0.659, 0.539, 4.96, 0.895), 6.7478, 6.75454),
]


@pytest.mark.parametrize("name, point, lo, hi", LOOSEST)
def test_the_law_answers_within_5_percent_where_the_worst_corner_lost_12(name, point, lo, hi):
    """Before: 0.874–0.902 of the fresh planner bisection here (failed); now ≥ 0.95 and below its upper end."""
    t = TABLES[name]
    d, r, e, tilt_deg, tr = point
    v = t.v_safe(d, r, e, math.radians(tilt_deg), tr)
    assert worst_corner(t, d, r, e, math.radians(tilt_deg), tr) < 0.91 * lo  # the old answer
    assert 0.95 * lo <= v < hi


points = st.tuples(st.floats(0.0, 20.0), st.floats(0.0, 2.5), st.floats(0.0, 1.5), st.floats(0.0, 0.7),
                   st.floats(0.55, 1.1))
PROP = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@PROP
@given(st.sampled_from(sorted(TABLES)), points)
def test_never_above_a_law_scaled_corner_never_below_the_worst_corner(name, p):
    """v_safe ≤ the reference (`test_omega_lookup.v_safe_reference`: each grid tilt's column scaled in thrust from
    its own two thrust corners, and the least corner of the cell scaled to the point at its reaction time, ×
    LAW_MARGIN, all computed there on its own) and ≥ the worst corner."""
    t = TABLES[name]
    v, old = t.v_safe(*p), worst_corner(t, *p)
    assert old <= v <= v_safe_reference(t, *p) * (1 + 1e-12)


@PROP
@given(st.sampled_from(sorted(TABLES)), points, st.sampled_from([0, 1, 2, 4]), st.floats(1e-6, 0.3))
def test_monotone_in_d_od_r_obst_e_tr_and_thrust(name, p, axis, step):
    """More D_od or thrust never lowers the answer; more R_obst or E_tr never raises it."""
    t = TABLES[name]
    q = list(p)
    q[axis] += step
    v0, v1 = t.v_safe(*p), t.v_safe(*q)
    if axis in (1, 2):
        assert v1 <= v0 * (1 + 1e-12)
    else:
        assert v1 >= v0 * (1 - 1e-12), (p, q, v0, v1)


def test_in_tilt_never_below_a_smaller_grid_tilt():
    """Every 0.01° from 3° to the top, at random obstacles: never below the answer at any grid tilt ≤ the tilt
    (the old lookup's monotonicity). NOT monotone between grid tilts: at low speed the law's row can fall as
    the tilt rises (a larger tilt takes longer to reach, t_react + tilt/rate, and the ρ step's bound
    (c0 − r_k/ρ_j)/t_r falls with it); measured dips are listed, bounded here by what was measured."""
    rng = np.random.default_rng(5)
    dips = {}
    for name, t in TABLES.items():
        _, grid_tilts, _ = t.avoid.axes
        tilts = np.radians(np.arange(3.0, t.vehicle.tilt_max_deg, 0.01))
        below = np.searchsorted(grid_tilts, tilts, side="right") - 1
        worst = 0.0
        for _ in range(20):
            d, r, e, tr = rng.uniform(0, 20), rng.uniform(0, 2.5), rng.uniform(0, 1.5), rng.uniform(0.6, 1.0)
            v = np.array([t.v_safe(d, r, e, x, tr) for x in tilts])
            on_grid = np.maximum.accumulate(np.array([t.v_safe(d, r, e, float(x), tr) for x in grid_tilts]))
            assert np.all(v >= on_grid[below] * (1 - 1e-12))
            run = np.maximum.accumulate(v)
            worst = max(worst, float(np.max((run - v) / np.maximum(run, 1e-300))))
        dips[name] = worst
    print({"largest dip in tilt": dips})
    assert max(dips.values()) < 0.03


def _law_table(tmp_path, f, info, name="law.npz"):
    rho, tilts, trs = TABLES["mambo"].avoid.axes
    return make(tmp_path, avoid=Slot((rho, tilts, trs), f, info), name=name)


def test_the_law_only_where_the_table_states_it_and_every_corner_obeys_it(tmp_path):
    """One cell lowered by 10 % (a fall-back the build would record): the four cells it is a corner of answer
    by the worst corner, the others by the law; without the stated law, or for a box table: the worst corner."""
    shipped = TABLES["mambo"]
    f = shipped.avoid.values.copy()
    f[:, 6, 4] *= 0.9
    f, _ = repair_monotone(f, SLOTS["avoid"][2], "down")
    t = _law_table(tmp_path, f, dict(shipped.avoid.info))
    holds = t._law["holds"]
    bad = {(j, k) for j in range(len(holds)) for k in range(holds.shape[1]) if not holds[j, k]}
    assert {(5, 3), (5, 4), (6, 3), (6, 4)} <= bad and holds.mean() > 0.9
    _, tilts, trs = t.avoid.axes
    q = (4.0, 0.5, 0.2)
    inside = (0.5 * (tilts[5] + tilts[6]), 0.5 * (trs[3] + trs[4]))  # the cell (5, 3): worst corner only
    assert t.v_safe(*q, *inside) == worst_corner(t, *q, *inside)
    elsewhere = (0.5 * (tilts[10] + tilts[11]), 0.5 * (trs[3] + trs[4]))  # a cell the lowering did not touch
    assert t.v_safe(*q, *elsewhere) > 1.01 * worst_corner(t, *q, *elsewhere)
    assert t.v_safe(*q, *elsewhere) == shipped.v_safe(*q, *elsewhere)
    no_claim = _law_table(tmp_path, shipped.avoid.values, {}, "no_claim.npz")
    assert no_claim._law is None
    assert no_claim.v_safe(*q, *elsewhere) == worst_corner(shipped, *q, *elsewhere)


def test_omega_at_a_tilt_cap_between_grid_tilts_uses_the_law():
    """Ω capped between grid tilts: at least the worst corner's V_max, at a tilt no more than the cap."""
    for t in TABLES.values():
        _, tilts, _ = t.avoid.axes
        cap = 0.5 * (tilts[3] + tilts[4])
        om = t.omega(8.0, 0.5, 0.1, 0.9, tilt=cap)
        om_grid = t.omega(8.0, 0.5, 0.1, 0.9, tilt=float(tilts[3]))
        # the law is used: strictly more than the worst (lower) grid tilt gives (shipped tables: +0.05 m/s Mambo, +0.16 X500; without
        # the law the two are equal)
        assert om.v_max > om_grid.v_max + 0.02 and om.tilt == pytest.approx(cap) and om.tilt <= cap
        assert om.gamma <= 0 and om.reason == "ok"


def test_a_synthetic_random_table_has_no_law(tmp_path):
    """Random monotone cells (the other tests' tables) do not obey the law: the loader finds no cell to use."""
    rng = np.random.default_rng(3)
    rho, tilts, trs = TABLES["mambo"].avoid.axes
    f, _ = repair_monotone(rng.uniform(0, 1.5, (len(rho), len(tilts), len(trs))), SLOTS["avoid"][2], "down")
    t = _law_table(tmp_path, f, dict(TABLES["mambo"].avoid.info), "random.npz")
    holds = np.zeros((1, 1), bool) if t._law is None else t._law["holds"]
    assert holds.mean() < 0.05  # (cells whose corners are all 0 agree: they answer 0 either way)
    assert MAMBO.name == "mambo"
    for p in rng.uniform([0, 0, 0, 0.05, 0.6], [20, 2.5, 1.5, 0.43, 1.0], (300, 5)).tolist():
        top, k = t._avoid_cells(p[3], p[4])
        if not holds[top, k]:
            assert t.v_safe(*p) == worst_corner(t, *p)
