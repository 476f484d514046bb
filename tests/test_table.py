import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from contracts.errors import ContractError
from contracts.lookup import is_monotone, repair_monotone
from contracts.table import SLOTS, Slot, arrays_sha256, load_for_vehicle, shipped_table, verify, write_table
from contracts.vehicle import G, load_vehicle

MAMBO = load_vehicle("mambo")
TILT_TOP = MAMBO.tilt_max


# ----------------------------------------------------------------------------- synthetic tables


def grid(draw, lo, hi, n_min=2, n_max=6):
    xs = draw(st.lists(st.floats(lo, hi), min_size=n_min, max_size=n_max, unique=True))
    xs = np.unique(np.round(xs, 6))
    if len(xs) < n_min:
        xs = np.linspace(lo, hi, n_min)
    return xs


@st.composite
def avoid_tables(draw):
    rho = grid(draw, 0.02, 0.95)
    tilt = grid(draw, 0.05, TILT_TOP - 0.01)
    tr = grid(draw, 0.6, 1.0, 1, 3)
    seed = draw(st.integers(0, 2**31 - 1))
    raw = np.random.default_rng(seed).uniform(0.0, 1.5, (len(rho), len(tilt), len(tr)))
    f, _ = repair_monotone(raw, SLOTS["avoid"][2], "down")
    return Slot((rho, tilt, tr), f, {"method": "synthetic"})


@st.composite
def etr_tables(draw):
    v = grid(draw, 0.3, 12.0)
    tilt = grid(draw, 0.05, TILT_TOP)
    tr = grid(draw, 0.6, 1.0, 1, 3)
    seed = draw(st.integers(0, 2**31 - 1))
    raw = np.random.default_rng(seed).uniform(0.0, 1.0, (len(v), len(tilt), len(tr)))
    e, _ = repair_monotone(raw, SLOTS["e_tr_pred"][2], "up")
    return Slot((v, tilt, tr), e, {})


def make(tmp_path, avoid=None, e_tr_pred=None, name="t.npz"):
    p = tmp_path / name
    write_table(p, MAMBO, avoid=avoid, e_tr_pred=e_tr_pred)
    return verify(p, MAMBO)


PROP = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


# ----------------------------------------------------------------------------- properties


@PROP
@given(avoid_tables(), st.floats(0.0, 1.0), st.floats(0.0, 0.6), st.floats(0.55, 1.05))
def test_lookup_never_exceeds_any_corner_of_its_cell(tmp_path, slot, rho, tilt, tr):
    t = make(tmp_path, avoid=slot)
    rg, tg, kg = slot.axes
    f = t.f_lookup(rho, tilt, tr)
    # the cell: neighbours on each axis (clamped), per DESIGN.md §2's out-of-grid rules
    if rho > rg[-1] or tilt < tg[0] or tr < kg[0]:
        assert f == 0.0
        return
    i_hi = np.searchsorted(rg, rho)  # rho is "hurts": the worst corner is the upper neighbour
    i_lo = max(i_hi - 1, 0)
    j_lo = np.searchsorted(tg, tilt, side="right") - 1
    j_hi = min(j_lo + 1, len(tg) - 1)
    k_lo = np.searchsorted(kg, tr, side="right") - 1
    k_hi = min(k_lo + 1, len(kg) - 1)
    for i in (i_lo, i_hi):
        for j in (j_lo, j_hi):
            for k in (k_lo, k_hi):
                assert f <= slot.values[i, j, k]
    assert f == slot.values[i_hi, j_lo, k_lo]


@PROP
@given(avoid_tables(), st.floats(0.0, 30.0), st.floats(0.0, 2.0), st.floats(0.0, 1.5), st.floats(0.06, 0.45),
       st.floats(0.6, 1.0))
def test_reaction_fixed_point_is_never_optimistic_and_tight(tmp_path, slot, d_od, r_obst, e_tr, tilt, tr):
    t = make(tmp_path, avoid=slot)
    v = t.v_safe(d_od, r_obst, e_tr, tilt, tr)
    assert v >= 0.0
    rg, tg = slot.axes[0], slot.axes[1]
    if tilt < tg[0] or tr < slot.axes[2][0]:
        assert v == 0.0
        return
    r_k = r_obst + e_tr + MAMBO.r_body_m
    c0 = d_od + r_obst
    tilts = [x for x in tg if x <= min(tilt, TILT_TOP)]  # a tilt limit allows every smaller tilt

    def ok(speed):
        """Independent check, by speed: is there a disc that holds the keep-out disc, touches its near
        point, and lets the vehicle pass or stop after covering speed·t_r at this speed? (raw lookups)"""
        for tau in tilts:
            t_r = MAMBO.reaction_time(tau)
            for rho_j in rg:
                # the largest enclosing disc (radius r_k + δ, centre c0 + δ) whose ρ stays in cell j
                delta = (rho_j * (c0 - speed * t_r) - r_k) / (1 - rho_j)
                if delta < 0:
                    continue
                c = c0 + delta - speed * t_r
                if speed * speed <= G * c * t.f_lookup(rho_j, tau, tr) ** 2 * (1 + 1e-9):
                    return True
        return False

    if v > 0:
        assert ok(v)
    speeds = np.linspace(0.0, 40.0, 4001)
    feasible = [s for s in speeds[1:] if ok(s)]
    assert max(feasible, default=0.0) <= v + (speeds[1] - speeds[0]) + 1e-9


@PROP
@given(avoid_tables(), etr_tables(), st.floats(0.5, 30.0), st.floats(0.0, 2.0), st.floats(0.0, 1.0),
       st.floats(0.6, 1.0))
def test_etr_fixed_point_is_never_optimistic(tmp_path, a, e, d_od, r_obst, e_meas, tr):
    t = make(tmp_path, avoid=a, e_tr_pred=e)
    om = t.omega(d_od, r_obst, e_meas, tr)
    if om.v_max > 0:
        e_used = max(e_meas, t.e_tr_pred(om.v_max, om.tilt, tr))
        assert om.e_tr >= e_used - 1e-12
        assert om.v_max <= t.v_safe(d_od, r_obst, e_used, om.tilt, tr) + 1e-9
        assert om.gamma <= 1e-9
    # no grid tilt up to the vehicle's limit does better at any speed on a fine scan
    for tilt in a.axes[1]:
        for v in np.linspace(0.05, 15.0, 120):
            ev = max(e_meas, t.e_tr_pred(v, tilt, tr))
            if math.isfinite(ev) and v <= t.v_safe(d_od, r_obst, ev, tilt, tr):
                assert v <= om.v_max + 1e-9


@PROP
@given(etr_tables(), st.floats(0.0, 15.0), st.floats(0.0, 0.6), st.floats(0.5, 1.1))
def test_etr_lookup_is_the_largest_corner_and_infinite_outside(tmp_path, e, v, tilt, tr):
    t = make(tmp_path, e_tr_pred=e)
    vg, tg, kg = e.axes
    got = t.e_tr_pred(v, tilt, tr)
    if v > vg[-1] or tilt > tg[-1] or tr < kg[0]:
        assert got == math.inf
        return
    i = np.searchsorted(vg, v)
    j = np.searchsorted(tg, tilt)
    k = np.searchsorted(kg, tr, side="right") - 1
    assert got == e.values[i, j, k]
    assert got >= e.values[max(i - 1, 0), max(j - 1, 0), min(k + 1, len(kg) - 1)]


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from(["down", "up"]))
def test_repair_is_one_sided_and_counts(seed, safe):
    raw = np.random.default_rng(seed).uniform(0, 1, (4, 5, 3))
    dirs = (-1, 1, 1)
    fixed, n = repair_monotone(raw, dirs, safe)
    assert is_monotone(fixed, dirs)
    assert n == np.count_nonzero(fixed != raw)
    assert np.all(fixed <= raw) if safe == "down" else np.all(fixed >= raw)
    again, n2 = repair_monotone(fixed, dirs, safe)
    assert n2 == 0 and np.array_equal(again, fixed)


# ----------------------------------------------------------------------------- worked values


def test_stop_only_table_says_so_and_uses_the_closed_form(tmp_path):
    t = make(tmp_path)
    assert t.available == ["stop"] and "stop contract only" in t.meta["note"]
    om = t.omega(6.0, 1.0, 0.2, 1.0, contract="stop")
    assert om.v_max == pytest.approx(t.v_stop(6.0, 1.0, 0.2, 1.0)) and om.v_max > 0
    bad = t.omega(6.0, 1.0, 0.2, 1.0, contract="avoid")
    assert bad.v_max == 0.0 and "no avoid" in bad.reason


def test_reduced_form_and_the_reaction_fixed_point_on_a_worked_column():
    from contracts.lookup import ReactLookup

    rho = np.array([0.1, 0.2, 0.4, 0.8])
    f = np.array([[0.9, 0.7, 0.5, 0.2]])
    c0, r_k = 10.0, 4.0  # ρ(0) = 0.4 exactly on a grid point
    # (almost) no reaction time, just inside the ρ ≤ 0.4 cell: the best disc holding the keep-out disc
    # with the same near point (gap s = c0 − r_k) has ρ = 0.4: V = √(g·F²·s/(1 − ρ)), above √(g·c0)·F
    tiny = ReactLookup(rho, f, [1e-9])
    s = c0 - (r_k - 1e-3)
    assert tiny(c0, np.array([[r_k - 1e-3]]))[0, 0] == pytest.approx(math.sqrt(G * 0.25 * s / 0.6), rel=1e-6)
    assert math.sqrt(G * 0.25 * s / 0.6) > math.sqrt(G * c0) * 0.5
    # with t_r = 0.5: cell ρ ≤ 0.8 caps V at √(g(c0 − 0.5V))·0.2 directly; enclosing discs of cell 0.8
    # give V² + h t_r V − h s = 0 with h = g·0.04/0.2; the answer is the better of the two
    v = ReactLookup(rho, f, [0.5])(c0, np.array([[r_k]]))[0, 0]
    b = G * 0.04 * 0.5
    direct = (-b + math.sqrt(b * b + 4 * G * 0.04 * c0)) / 2
    h = G * 0.04 / 0.2
    star = (-h * 0.5 + math.sqrt((h * 0.5) ** 2 + 4 * h * (c0 - r_k))) / 2
    assert v == pytest.approx(max(direct, star), rel=1e-8)
    assert v < math.sqrt(G * c0) * 0.5


def test_nan_and_out_of_range_inputs_give_no_speed(tmp_path):
    t = make(tmp_path)
    for args in [(math.nan, 1, 0.1, 1.0), (5, math.inf, 0.1, 1.0), (5, 1, -0.1, 1.0), (5, 1, 0.1, 0.3)]:
        om = t.omega(*args, contract="stop")
        assert om.v_max == 0.0 and om.reason != "ok"


# ----------------------------------------------------------------------------- refusing bad files


def _rewrite(src, dst, mutate, rehash=False):
    with np.load(src) as z:
        arrays = {k: z[k].copy() for k in z.files}
    meta = json.loads(arrays.pop("metadata_json").tobytes())
    mutate(meta, arrays)
    if rehash:
        meta["arrays_sha256"] = arrays_sha256(arrays)
    np.savez(dst, metadata_json=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)


@pytest.fixture
def good(tmp_path):
    rho = np.array([0.1, 0.5, 0.9])
    tilt = np.array([0.1, 0.3])
    tr = np.array([0.6, 1.0])
    f = np.array([0.8, 0.5, 0.1])[:, None, None] * np.ones((3, 2, 2))
    p = tmp_path / "good.npz"
    write_table(p, MAMBO, avoid=Slot((rho, tilt, tr), f))
    return p


def _refused(path, match, vehicle=None):
    with pytest.raises(ContractError, match=match) as e:
        verify(path, vehicle)
    assert "\n" not in str(e.value)


def test_tampered_array_is_refused(good, tmp_path):
    bad = tmp_path / "bad.npz"
    _rewrite(good, bad, lambda m, a: a["avoid_f"].__setitem__((0, 0, 0), 0.9))
    _refused(bad, "hash mismatch")


def test_truncated_and_garbage_files_are_refused(good, tmp_path):
    data = good.read_bytes()
    for n in (10, len(data) // 2, len(data) - 5):
        p = tmp_path / f"trunc{n}.npz"
        p.write_bytes(data[:n])
        _refused(p, "unreadable|truncated|no metadata")
    g = tmp_path / "garbage.npz"
    g.write_bytes(b"\x00\xff" * 500)
    _refused(g, "unreadable|truncated")
    _refused(tmp_path / "missing.npz", "no such file")


def test_non_monotone_table_with_a_valid_hash_is_refused(good, tmp_path):
    bad = tmp_path / "nonmono.npz"
    _rewrite(good, bad, lambda m, a: a["avoid_f"].__setitem__((2, 1, 1), 0.95), rehash=True)
    _refused(bad, "not monotone")


def test_schema_version_and_vehicle_mismatch_are_refused(good, tmp_path):
    bad = tmp_path / "v2.npz"
    _rewrite(good, bad, lambda m, a: m.__setitem__("schema_version", 99))
    _refused(bad, "schema version 99")
    _refused(good, "built for another vehicle", load_vehicle("x500"))
    edited = tmp_path / "edited.npz"
    _rewrite(good, edited, lambda m, a: m["vehicle"].__setitem__("r_body_m", 0.01))
    _refused(edited, "does not match its recorded hash")


def test_writer_refuses_a_non_monotone_slot(tmp_path):
    f = np.array([0.1, 0.5, 0.8])[:, None, None] * np.ones((3, 1, 1))  # increases with rho: wrong
    with pytest.raises(ContractError, match="not monotone"):
        write_table(tmp_path / "x.npz", MAMBO, avoid=Slot((np.array([0.1, 0.5, 0.9]), np.array([0.2]), np.array([1.0])), f))


def test_shipped_tables_verify_against_their_vehicles():

    for name in ("mambo", "x500"):
        t = load_for_vehicle(name)
        assert "stop" in t.available


def test_on_board_modules_never_import_casadi():
    code = (
        "import sys; import contracts.table, contracts.lookup, contracts.flat, contracts.contour, "
        "contracts.stop, companion.cli, companion.onboard.daemon, companion.onboard.estimators, companion.onboard.supervisor, "
        "companion.onboard.link, companion.onboard.telemetry; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('casadi', 'sitl_harness')]; "
        "assert not bad, bad"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(__import__("pathlib").Path(__file__).parents[1]))
    assert r.returncode == 0, r.stderr


def test_load_for_vehicle_takes_the_shipped_table_and_checks_the_vehicle():
    t = load_for_vehicle("mambo")
    assert t.path == shipped_table("mambo") and t.vehicle.name == "mambo"
    assert load_for_vehicle(load_vehicle("x500")).vehicle.name == "x500"
    assert load_for_vehicle(None, shipped_table("x500")).vehicle.name == "x500"  # a table alone: its own vehicle
    with pytest.raises(ContractError, match="built for another vehicle"):
        load_for_vehicle("x500", shipped_table("mambo"))
