"""The fast avoid Ω (ReactLookup.step_fixed_point, .at, .best) gives the answers of the full-grid reference it
replaced (kept below, verbatim but for names): same V_max and tilt (and E_tr, V_safe, Γ, reason), on
random tables and queries, out-of-range inputs included; V_safe too. No solver calls.

On a cone table stating its scaling law (the shipped ones), the reference has the law's row too (issue 18),
computed here on its own: each corner of the cell scaled to the point by √(a_h(p)/a_h(c)), the least taken,
through the reference solver at the point's reaction time."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_table import MAMBO, avoid_tables, etr_tables, make

from contracts.flat import horizontal_accel_limit
from contracts.lookup import NONE, ReactLookup, helps_index, hurts_index
from contracts.table import LAW_CLAIM, LAW_MARGIN, Omega, load_for_vehicle
from contracts.vehicle import G

SHIPPED = load_for_vehicle(MAMBO)
TOL = 1e-12  # round-off only: the fast path decides "V_safe ≥ v" in closed form, not by comparing lim ≥ v


# ----------------------------------------------------------------------------- the reference (before)


class RefReactLookup:
    """contracts.lookup.ReactLookup as it was: every tilt × speed cell × ρ cell per call."""

    def __init__(self, rho, f, t_r, g=G):
        self.rho = np.asarray(rho, dtype=float)
        f = np.atleast_2d(np.asarray(f, dtype=float))
        self.k, self.n = f.shape
        self.t_r = np.asarray(t_r, dtype=float).reshape(self.k, 1)
        gf2 = g * f * f
        self._b = gf2 * self.t_r
        self._b2 = self._b * self._b
        self._4gf2 = 4.0 * gf2
        self._row = np.arange(self.k, dtype=float)[:, None]
        self._row_start = (np.arange(self.k) * self.n)[:, None]
        self._rho_prev = np.concatenate([[np.inf], self.rho])
        self._h = gf2 / (1.0 - self.rho)
        self._ht = self._h * self.t_r
        self._ht2 = self._ht * self._ht
        self._u = self.rho / (1.0 - self.rho)

    def __call__(self, c0, r_k, lo=0, hi=None):
        c0 = max(float(c0), 0.0)
        sl = slice(lo, hi)
        t_r = self.t_r[sl]
        v_quad = 0.5 * (np.sqrt(self._b2[sl] + self._4gf2[sl] * c0) - self._b[sl])
        k = v_quad.shape[0]
        lift = self._row[:k] * (c0 + 1.0)
        big_r = self.rho * (c0 - t_r * v_quad) + lift
        r_k = np.minimum(r_k, c0 + 0.5)
        j = np.searchsorted(big_r.ravel(), (r_k + lift).ravel()).reshape(r_k.shape) - self._row_start[:k]
        n = self.n
        vq = np.where(j < n, v_quad.ravel()[np.minimum(j, n - 1) + self._row_start[:k]], 0.0)
        vl = np.where(j > 0, (c0 - r_k / self._rho_prev[j]) / t_r, 0.0)
        gap = np.maximum(c0 - r_k, 0.0)[..., None]
        h, ht = self._h[sl][:, None, :], self._ht[sl][:, None, :]
        v_star = 0.5 * (np.sqrt(self._ht2[sl][:, None, :] + 4.0 * h * gap) - ht)
        ok = (gap - v_star * t_r[..., None]) * self._u >= r_k[..., None]
        ve = np.max(np.where(ok, v_star, 0.0), axis=-1)
        return np.maximum(np.maximum(np.maximum(vq, vl), ve), 0.0) * (1.0 - 1e-9)


def ref_step_fixed_point(v_grid, limit_on_grid):
    cand = np.minimum(v_grid, limit_on_grid)
    return cand.max(axis=-1), cand.argmax(axis=-1)


_REF = {}


def ref_react(t):
    if id(t) not in _REF:
        rho, tilts, trs = t.avoid.axes
        t_r = np.array([t.vehicle.reaction_time(x) for x in tilts])
        _REF[id(t)] = (t, [RefReactLookup(rho, t.avoid.values[:, :, k].T, t_r) for k in range(len(trs))])
    return _REF[id(t)][1]


def ref_law_row(t, tilt, thrust_ratio, check_only=False):
    """(reference solver, tilt) of the law's row at (tilt, thrust), or None (no law, a grid point, corners disagree)."""
    if t.tilt_model != "cone" or not str(t.avoid.info.get("scaling", "")).startswith(LAW_CLAIM):
        return None
    if check_only:
        return True
    rho, tilts, trs = t.avoid.axes
    veh = t.vehicle
    tilt_c, tr_c = min(tilt, veh.tilt_max, tilts[-1]), min(thrust_ratio, trs[-1])
    j, k = helps_index(tilts, tilt_c), helps_index(trs, tr_c)
    if NONE in (j, k):
        return None
    a_h = lambda x, y: horizontal_accel_limit(x, veh.t_max(y), veh.mass_kg)
    a_p = a_h(tilt_c, tr_c)
    if not a_p > a_h(tilts[j], trs[k]) * (1 + 1e-12):
        return None
    corners = {(jj, kk) for jj in (j, min(j + 1, len(tilts) - 1)) for kk in (k, min(k + 1, len(trs) - 1))}
    norm = np.array([t.avoid.values[:, jj, kk] / math.sqrt(a_h(tilts[jj], trs[kk])) for jj, kk in corners])
    if np.any(norm.max(axis=0) - norm.min(axis=0) > 1e-12 * norm.max(axis=0)):
        return None  # the law does not hold in this cell: the worst corner only
    f_p = np.min(norm, axis=0) * math.sqrt(a_p)
    return RefReactLookup(rho, f_p[None], [veh.reaction_time(tilt_c)]), tilt_c


def ref_grid_rows(t, k, thrust_ratio):
    """The reference solver over every grid tilt at thrust column k; on a law table with the thrust law: each
    tilt's column scaled from thrust_k to the thrust by √(a_h(tilt, thrust)/a_h(tilt, thrust_k)) where both
    thrust corners obey the law (issue 18)."""
    if ref_law_row(t, 0.0, 0.0, check_only=True) is None:
        return ref_react(t)[k]
    rho, tilts, trs = t.avoid.axes
    veh = t.vehicle
    a_h = lambda x, y: horizontal_accel_limit(x, veh.t_max(y), veh.mass_kg)
    tr_c, k1 = min(thrust_ratio, trs[-1]), min(k + 1, len(trs) - 1)
    f = t.avoid.values[:, :, k].T.copy()
    for j, x in enumerate(tilts):
        n0, n1 = f[j] / math.sqrt(a_h(x, trs[k])), t.avoid.values[:, j, k1] / math.sqrt(a_h(x, trs[k1]))
        if np.all(np.abs(n0 - n1) <= 1e-12 * np.maximum(n0, n1)):
            f[j] = f[j] * math.sqrt(a_h(x, tr_c) / a_h(x, trs[k]))
    return RefReactLookup(rho, f, np.array([veh.reaction_time(x) for x in tilts]))


def ref_cells(t, tilt, thrust_ratio):
    k = helps_index(t.avoid.axes[2], thrust_ratio)
    top = helps_index(t.avoid.axes[1], min(tilt, t.vehicle.tilt_max))
    return ([], k) if NONE in (k, top) else (list(range(top + 1)), k)


def ref_e_column(t, e_tilt_idx, thrust_ratio, e_meas):
    ev, _, er = t.e_pred.axes
    kk = helps_index(er, thrust_ratio)
    idx = np.asarray(e_tilt_idx)
    if kk == NONE:
        return np.full((len(idx), len(ev)), np.inf)
    e = t.e_pred.values[:, np.maximum(idx, 0), kk].T
    return np.maximum(np.where((idx == NONE)[:, None], np.inf, e), e_meas)


def omega_reference(t, d_od, r_obst, e_meas, thrust_ratio, tilt=None) -> Omega:
    """ContractTable.omega(..., contract="avoid") as it was."""
    tilt = t.vehicle.tilt_max if tilt is None else tilt
    bad = t._bad_inputs(d_od, r_obst, e_meas, thrust_ratio, tilt)
    if not bad and t.avoid is None:
        bad = "no avoid contract in this table"
    if bad:
        return Omega("avoid", 0.0, tilt if math.isfinite(tilt) else 0.0, e_meas, 0.0, 0.0, bad)
    tilts = t.avoid.axes[1]
    js, k = ref_cells(t, tilt, thrust_ratio)
    if not js:
        return Omega("avoid", 0.0, tilt, e_meas, 0.0, 0.0, "tilt or thrust below the table's grid")
    react, c0, r0 = ref_grid_rows(t, k, thrust_ratio), d_od + r_obst, r_obst + t.vehicle.r_body_m
    if t.e_pred is None:
        lim = react(c0, np.full((len(js), 1), r0 + e_meas), js[0], js[-1] + 1)[:, 0]
        best = int(np.argmax(lim))
        v_max, e_b, v_s = float(lim[best]), e_meas, float(lim[best])
    else:
        e_tilt_of = np.array([hurts_index(t.e_pred.axes[1], x) for x in tilts])
        e = ref_e_column(t, e_tilt_of[js], thrust_ratio, e_meas)
        finite = np.isfinite(e)
        lim = np.where(finite, react(c0, r0 + np.where(finite, e, 0.0), js[0], js[-1] + 1), 0.0)
        v_cand, jv = ref_step_fixed_point(t.e_pred.axes[0], lim)
        best = int(np.argmax(v_cand))
        v_max, e_b, v_s = float(v_cand[best]), float(e[best, jv[best]]), float(lim[best, jv[best]])
    tilt_b = float(tilts[js[best]])
    law = ref_law_row(t, tilt, thrust_ratio)
    if law is not None:
        ref, tilt_l = law
        if t.e_pred is None:
            e_l = np.array([[e_meas]])
        else:
            e_l = ref_e_column(t, [hurts_index(t.e_pred.axes[1], tilt_l)], thrust_ratio, e_meas)
        fin = np.isfinite(e_l)
        lim_l = np.where(fin, ref(c0, r0 + np.where(fin, e_l, 0.0)), 0.0) * LAW_MARGIN
        if t.e_pred is None:
            v_l, jl = float(lim_l[0, 0]), 0
            cand = (v_l, e_meas, v_l)
        else:
            vc, jv_l = ref_step_fixed_point(t.e_pred.axes[0], lim_l)
            jl = int(jv_l[0])
            cand = (float(vc[0]), float(e_l[0, jl]), float(lim_l[0, jl]))
        if cand[0] > v_max:
            (v_max, e_b, v_s), tilt_b = cand, tilt_l
    reason = "ok" if v_max > 0 else "no safe speed at this D_od, R_obst, E_tr"
    return Omega("avoid", v_max, tilt_b, e_b, v_s, v_max - v_s, reason)


def v_safe_reference(t, d_od, r_obst, e_tr, tilt, thrust_ratio) -> float:
    if t._bad_inputs(d_od, r_obst, e_tr, thrust_ratio, tilt):
        return 0.0
    js, k = ref_cells(t, tilt, thrust_ratio)
    if not js:
        return 0.0
    r_k = np.full((len(js), 1), r_obst + e_tr + t.vehicle.r_body_m)
    v = float(np.max(ref_grid_rows(t, k, thrust_ratio)(d_od + r_obst, r_k, js[0], js[-1] + 1)))
    law = ref_law_row(t, tilt, thrust_ratio)
    if law is not None:
        v = max(v, float(law[0](d_od + r_obst, r_k[:1])[0, 0]) * LAW_MARGIN)
    return v


# ----------------------------------------------------------------------------- sameness


def close(a, b):
    return a == b or math.isclose(a, b, rel_tol=TOL, abs_tol=TOL) or (math.isnan(a) and math.isnan(b))


def same(fast: Omega, ref: Omega):
    assert (fast.contract, fast.tilt, fast.reason) == (ref.contract, ref.tilt, ref.reason), (fast, ref)
    assert all(close(getattr(fast, f), getattr(ref, f)) for f in ("v_max", "e_tr", "v_safe", "gamma")), (fast, ref)


# queries reach past every edge: negative, beyond the grids, NaN/inf (→ the V_safe 0 rules)
odd = st.sampled_from([math.nan, math.inf, -math.inf])
d_ods = st.one_of(st.floats(-1.0, 40.0), odd)
r_obsts = st.one_of(st.floats(-0.2, 5.0), odd)
e_meass = st.one_of(st.floats(-0.1, 3.0), odd)
thrusts = st.one_of(st.floats(0.3, 1.3), odd)
tilts = st.one_of(st.none(), st.floats(-0.05, 0.7), odd)
PROP = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@PROP
@given(d_ods, r_obsts, e_meass, thrusts, tilts)
def test_fast_omega_equals_the_reference_on_the_shipped_table(d_od, r_obst, e_meas, tr, tilt):
    same(SHIPPED.omega(d_od, r_obst, e_meas, tr, tilt=tilt), omega_reference(SHIPPED, d_od, r_obst, e_meas, tr, tilt))
    if tilt is not None:
        v_ref = v_safe_reference(SHIPPED, d_od, r_obst, e_meas, tilt, tr)
        assert close(SHIPPED.v_safe(d_od, r_obst, e_meas, tilt, tr), v_ref)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(avoid_tables(), st.one_of(st.none(), etr_tables()), st.lists(st.tuples(d_ods, r_obsts, e_meass, thrusts, tilts),
                                                                  min_size=1, max_size=8))
def test_fast_omega_equals_the_reference_on_random_tables(tmp_path, a, e, queries):
    t = make(tmp_path, avoid=a, e_tr_pred=e)
    for d_od, r_obst, e_meas, tr, tilt in queries:
        same(t.omega(d_od, r_obst, e_meas, tr, tilt=tilt), omega_reference(t, d_od, r_obst, e_meas, tr, tilt))
        if tilt is not None:
            assert t.v_safe(d_od, r_obst, e_meas, tilt, tr) == v_safe_reference(t, d_od, r_obst, e_meas, tilt, tr)


@pytest.mark.parametrize("n", [pytest.param(20000, marks=pytest.mark.slow), 2000])
def test_fast_omega_equals_the_reference_on_a_dense_random_sweep(n):
    """20 000 queries (2 000 in the default run) over the benchmark's ranges and beyond, every tilt cap: the same
    answers."""
    rng = np.random.default_rng(7)
    lo, hi = MAMBO.thrust_ratio_range
    q = np.column_stack([rng.uniform(0, 20, n), rng.uniform(0, 2.5, n), rng.uniform(0, 2, n),
                         rng.uniform(lo - 0.05, hi + 0.05, n), rng.uniform(0.0, 0.5, n)])
    v_grid = SHIPPED.e_pred.axes[0]
    exact, kinds = 0, np.zeros(4, int)  # answer below the grid, a lim between grid speeds, a grid speed, the top
    for d_od, r_obst, e_meas, tr, tilt in q.tolist():
        cap = None if tilt > 0.45 else tilt
        fast = SHIPPED.omega(d_od, r_obst, e_meas, tr, tilt=cap)
        ref = omega_reference(SHIPPED, d_od, r_obst, e_meas, tr, cap)
        same(fast, ref)
        exact += fast == ref
        assert fast.v_max <= ref.v_max * (1 + TOL) and fast.v_safe <= ref.v_safe * (1 + TOL)
        kinds[0 if fast.v_max < v_grid[0] else 3 if fast.v_max == v_grid[-1] else 2 if fast.v_max in v_grid else 1] += 1
    # bit for bit on the grid's rows but where the scalar path takes V* at the largest h_j rather than the
    # largest V*_j (the stop branch's h_j are equal but for round-off); the law's row (most tilt caps here
    # are off the grid) is computed another way: round-off apart, and never above
    assert exact >= 0.1 * n
    assert np.all(kinds > n // 50), kinds  # every path of step_fixed_point taken


def test_fast_omega_at_the_grid_speeds_and_edges():
    """Queries whose answer is a grid speed, the top speed, no speed at all, or thrust/tilt on grid points."""
    v_grid = SHIPPED.e_pred.axes[0]
    for d_od in (0.0, 0.3, 1.0, 2.0, 5.0, 8.0, 30.0, 1e4):
        for tr in (MAMBO.thrust_ratio_range[0], 0.8, 1.0, 1.2):
            for tilt in (None, SHIPPED.avoid.axes[1][0], SHIPPED.avoid.axes[1][0] - 1e-9, math.radians(9.0), 0.0):
                fast = SHIPPED.omega(d_od, 0.5, 0.1, tr, tilt=tilt)
                same(fast, omega_reference(SHIPPED, d_od, 0.5, 0.1, tr, tilt))
    assert SHIPPED.omega(1e4, 0.5, 0.0, 1.0).v_max == v_grid[-1]


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 30.0), st.floats(0.0, 1.3), st.floats(0.01, 0.6))
def test_one_column_in_scalars_equals_the_vectorised_lookup(seed, c0, frac, t_r):
    """ReactLookup.at (Ω's path) and ReactLookup.__call__ (v_safe's) give the same bits, and the reference's."""
    rng = np.random.default_rng(seed)
    rho = np.unique(np.round(rng.uniform(0.01, 0.97, rng.integers(1, 40)), 6))
    f = np.minimum.accumulate(rng.uniform(0.0, 1.5, (3, len(rho))), axis=1)  # non-increasing in ρ
    tr = np.array([t_r, t_r * 1.5, t_r * 2.0])
    r_k = np.array([[frac * c0 + 0.01]] * 3)
    fast = ReactLookup(rho, f, tr)(c0, r_k)[:, 0]
    ref = RefReactLookup(rho, f, tr)(c0, r_k)[:, 0]
    for row in range(3):
        assert ReactLookup(rho, f, tr).at(c0, float(r_k[row, 0]), row) == fast[row] == ref[row]
