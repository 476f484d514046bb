"""The full contract with the shipped E_tr_pred (issue 6, items 2–3 and the evidence).

- Ω with e_tr = max(measured, E_tr_pred(V_max, tilt, thrust_ratio)): exact on the speed grid,
  conservative between; `table query` shows tilt, V_max, E_tr, Γ; `--tilt-deg` caps the tilt.
- Held-out validation: manoeuvres (avoid geometries) and wind seeds not used in the build, at
  off-grid speeds/tilts/thrusts: the measured contour error never exceeds the prediction.
- The three demonstration flights (Figures 14–16), revealed at D_od at full V_max: never touch the
  real obstacle, stay within the assumed E_tr; the negative controls' clearances are reported.
- Thrust below the table's range: no safe speed.
"""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from contracts.lookup import is_monotone
from contracts.table import SLOTS, arrays_sha256, verify
from contracts.vehicle import DATA_DIR, load_vehicle
from sitl_harness import etr_sweep as es
from sitl_harness import maneuvers as mn

MAMBO = load_vehicle("mambo")
TABLE_PATH = DATA_DIR / "mambo.npz"
TABLE = verify(TABLE_PATH, MAMBO)
AVOID_SHA256 = "b752073180643ab7ae0aa24315e4ff4490f6465bf528856db22ab316c27f401d"  # the shipped avoid slot (239-point ρ axis)


def test_shipped_mambo_table_carries_a_monotone_etr_slot_and_the_untouched_avoid_slot():
    assert TABLE.available == ["stop", "avoid", "e_tr_pred", "e_tr_pred_stop", "e_tr_pred_brake"]
    e = TABLE.e_pred.values
    assert is_monotone(e, SLOTS["e_tr_pred"][2]) and np.all(e > 0)
    g = TABLE.e_pred_stop  # the governor's own: on the same axes, monotone, never above the general surface
    assert all(np.array_equal(a, b) for a, b in zip(g.axes, TABLE.e_pred.axes))
    assert is_monotone(g.values, SLOTS["e_tr_pred"][2]) and np.all(g.values > 0) and np.all(g.values <= e)
    v, tilt, tr = TABLE.e_pred.axes
    assert tr[0] == MAMBO.thrust_ratio_range[0] and tr[-1] == MAMBO.thrust_ratio_range[1]
    assert math.isclose(math.degrees(tilt[-1]), MAMBO.tilt_max_deg)
    with np.load(TABLE_PATH) as z:
        name, axes, _, _ = SLOTS["avoid"]
        assert arrays_sha256({k: z[k] for k in (name, *axes)}) == AVOID_SHA256
    info = TABLE.e_pred.info
    assert info["margin"]["relative"] > 0 and info["build_wall_s"] > 0


# ---------------------------------------------------------------------------- the full contract (Ω)


POINTS = [(6.0, 1.0, 0.0, 0.6), (6.0, 0.3, 0.0, 0.8), (3.0, 0.6, 0.0, 1.0), (10.0, 0.5, 0.2, 0.75),
          (2.0, 0.2, 0.5, 0.65), (20.0, 1.5, 0.0, 0.95), (4.0, 0.1, 0.05, 0.9)]


@pytest.mark.parametrize("d_od,r_obst,e_meas,tr", POINTS)
@pytest.mark.parametrize("cap_deg", [None, 7.03, 9.0, 15.0])
def test_omega_solves_the_etr_fixed_point_exactly_on_the_grid(d_od, r_obst, e_meas, tr, cap_deg):
    cap = None if cap_deg is None else math.radians(cap_deg)
    om = TABLE.omega(d_od, r_obst, e_meas, tr, tilt=cap)
    assert om.v_max > 0 and om.reason == "ok"
    if cap is not None:
        assert om.tilt <= cap + 1e-12
    # the E_tr used is the worse of measured and predicted at the chosen V_max and tilt
    e_used = max(e_meas, TABLE.e_tr_pred(om.v_max, om.tilt, tr))
    assert om.e_tr >= e_used - 1e-12
    # Γ ≤ 0 with that E_tr (the contract holds at the answer)
    assert om.v_max <= TABLE.v_safe(d_od, r_obst, om.e_tr, om.tilt, tr) + 1e-9
    assert TABLE.gamma(om.v_max, d_od, r_obst, e_meas, tr, om.tilt) <= 1e-9
    # exact on the grid: at the next speed grid point no grid tilt up to the cap satisfies the contract
    v_grid = TABLE.e_pred.axes[0]
    nxt = v_grid[v_grid > om.v_max + 1e-9]
    tilts = TABLE.avoid.axes[1]
    top = MAMBO.tilt_max if cap is None else min(cap, MAMBO.tilt_max)
    if len(nxt):
        for t in tilts[tilts <= top + 1e-12]:
            e = max(e_meas, TABLE.e_tr_pred(nxt[0], t, tr))
            assert not (math.isfinite(e) and TABLE.v_safe(d_od, r_obst, e, t, tr) >= nxt[0])


def test_etr_inflation_lowers_the_speed_and_below_range_thrust_has_no_safe_speed():
    no_e = TABLE.v_safe(6.0, 1.0, 0.0, math.radians(9), 0.8)
    om = TABLE.omega(6.0, 1.0, 0.0, 0.8, tilt=math.radians(9))
    assert om.e_tr > 0 and om.v_max < no_e
    for tr in (0.59, 0.5, 0.0):
        om = TABLE.omega(6.0, 1.0, 0.0, tr)
        assert om.v_max == 0.0 and "no safe speed" in om.reason
        assert TABLE.e_tr_pred(3.0, math.radians(9), tr) == math.inf
        assert TABLE.gamma(1.0, 6.0, 1.0, 0.0, tr) > 0


def cg(*args):
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True)


def test_table_query_shows_the_chosen_tilt_vmax_etr_and_gamma_and_tilt_deg_caps():
    base = ("table", "query", TABLE_PATH, "--d-od", 6, "--r-obst", 1, "--e-tr", 0, "--thrust-ratio", 0.6, "--json")
    free = json.loads(cg(*base).stdout)
    capped = json.loads(cg(*base, "--tilt-deg", 7.03).stdout)
    om = TABLE.omega(6.0, 1.0, 0.0, 0.6)
    assert free["v_max"] == pytest.approx(om.v_max) and free["tilt_deg"] == pytest.approx(math.degrees(om.tilt))
    assert free["e_tr"] == pytest.approx(om.e_tr) and free["e_tr"] > 0 and free["gamma"] <= 1e-9
    assert capped["tilt_deg"] <= 7.03 and capped["v_max"] <= free["v_max"]
    r = cg("table", "query", TABLE_PATH, "--d-od", 6, "--r-obst", 1, "--e-tr", 0, "--thrust-ratio", 0.5)
    assert r.returncode == 0 and "V_max 0.000" in r.stdout and "no safe speed" in r.stdout
    assert "E_tr" in cg(*base[:-1]).stdout and "Γ" in cg(*base[:-1]).stdout


# ---------------------------------------------------------------------------- held-out validation


# off the E_tr grid in every axis, on the avoid grid (its limiting trajectories are flown)
HELD_OUT_CELLS = [(3.2, 8.0, 0.65), (4.7, 6.0, 0.75), (5.8, 10.0, 0.85), (2.3, 13.0, 0.95), (6.6, 4.0, 0.9),
                  (7.4, 11.0, 0.7)]


def held_out_ratios(cells, seeds):
    """Measured / predicted contour error for held-out manoeuvres and seeds at `cells`."""
    out = []
    for v, tilt_deg, tr in cells:
        tilt = math.radians(tilt_deg)
        pred = TABLE.e_tr_pred(v, tilt, tr)
        idx = es._avoid_index(TABLE, tilt, tr)
        refs = es.cell_references(TABLE_PATH, MAMBO, v, tilt, tr, idx, rhos=es.HELD_OUT_RHOS)
        for ref in refs:
            for seed in seeds:
                e = mn.worst_contour_error(MAMBO, ref, tr, seed)
                out.append((e / pred, v, tilt_deg, tr, ref.name, seed, e, pred))
    return out


@pytest.mark.slow  # held-out flights, a small campaign (test_held_out_validation_campaign is the large one)
def test_held_out_manoeuvres_and_seeds_never_exceed_the_prediction():
    assert not set(es.HELD_OUT_SEEDS) & set(TABLE.e_pred.info["grid"]["seeds"])
    assert not set(es.HELD_OUT_RHOS) & set(TABLE.e_pred.info["grid"]["avoid_rhos"])
    rows = held_out_ratios(HELD_OUT_CELLS, es.HELD_OUT_SEEDS[:1])
    worst = max(rows)
    print(f"held-out worst ratio measured/predicted {worst[0]:.3f} at {worst[1:]}")
    assert worst[0] <= 1.0, worst


@pytest.mark.slow
def test_held_out_validation_campaign():
    rng = np.random.default_rng(6)
    tilts = [4.0, 6.0, 8.0, 10.0, 11.0, 13.0, 14.0, 17.0, 19.0, 22.0]
    trs = [0.65, 0.7, 0.75, 0.85, 0.9, 0.95]
    cells = [(float(rng.uniform(1.2, 7.9)), float(rng.choice(tilts)), float(rng.choice(trs))) for _ in range(40)]
    rows = held_out_ratios(cells, es.HELD_OUT_SEEDS)
    worst = max(rows)
    print(f"held-out campaign: {len(rows)} flights, worst ratio {worst[0]:.3f} at {worst[1:]}")
    assert worst[0] <= 1.0, worst


# ---------------------------------------------------------------------------- demonstration flights


@pytest.fixture(scope="module")
def demo():
    from sitl_harness.demo_flights import demo_set

    return demo_set(TABLE, seeds=(0,))


def stop_branch_covers(f) -> bool:
    """Straight braking from f.v_max after the folded reaction time stops short of the inflated obstacle."""
    from contracts.planner import Limits
    from contracts.sweep import brake_accel

    veh = TABLE.vehicle
    tilt = math.radians(f.tilt_deg)
    a = brake_accel(Limits.from_vehicle(veh, tilt, f.thrust_ratio, tilt_model=TABLE.tilt_model))
    return f.v_max * veh.reaction_time(tilt) + f.v_max ** 2 / (2 * a) <= f.d_od - f.e_tr - veh.r_body_m


@pytest.mark.slow  # 18 demonstration flights (the paper's Figures 14-16, `contract-guard figures`): make test-all
def test_demonstration_flights_never_touch_and_stay_within_the_assumed_etr(demo):
    contract = [f for f in demo if f.variant == "contract"]
    assert len(contract) == 6  # three scenarios × (paper tilt, chosen tilt)
    for f in contract:
        print(f"{f.name} cap {f.tilt_cap_deg} tilt {f.tilt_deg:.2f} V_max {f.v_max:.2f} E_tr {f.e_tr:.3f} "
              f"clearance {f.min_clearance:.3f} contour {f.contour_max:.3f}")
        # a verified pass, or else the contract's speed is one its stop branch covers (straight braking at the
        # cell's full deceleration after the folded reaction time ends short of the inflated obstacle): since
        # E_tr_pred bounds the fail-safe stop mid-swerve (issue 19 item 9) the larger E_tr leaves fig16's pass
        # infeasible at full tilt, and the flight brakes
        assert f.plan_ok or stop_branch_covers(f), f.summary()
        assert not f.touched and f.min_clearance > 0, f.summary()
        assert f.contour_max <= f.e_tr, f.summary()
        assert f.v_flown == f.v_max  # at full V_max


@pytest.mark.slow  # the same 18 flights
def test_negative_controls_come_closer_than_the_contract_and_touch_without_inflation(demo):
    """The test can fail: without E_tr inflation the plan grazes R_obst + r_body and the tracking error
    carries the vehicle into the obstacle; entering 1.15 × V_max with the same manoeuvre cuts the
    clearance (whether it touches is reported, DESIGN.md §8)."""
    by = {(f.name, f.tilt_cap_deg, f.variant): f for f in demo}
    touched_no_inflation = 0
    for (name, cap, variant), f in by.items():
        if variant == "contract":
            continue
        ref = by[(name, cap, "contract")]
        print(f"{name} cap {cap} {variant}: clearance {f.min_clearance:+.3f} m (contract {ref.min_clearance:+.3f})"
              f"{' TOUCHED' if f.touched else ''}")
        assert f.min_clearance < ref.min_clearance
        touched_no_inflation += variant == "no_inflation" and f.touched
    assert touched_no_inflation >= 1


@pytest.mark.slow
def test_demonstration_flights_over_seeds():
    from sitl_harness.demo_flights import demo_set

    for f in demo_set(TABLE, seeds=(0, 1, 2, 3, 4)):
        if f.variant == "contract":
            assert not f.touched and f.contour_max <= f.e_tr, f.summary()
