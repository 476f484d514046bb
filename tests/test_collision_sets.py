"""Collision sets eq. (20)–(28) and the analytical-vs-numerical cross-check (issue 8)."""

import itertools
import math

import numpy as np
import pytest

from contracts import collision_sets as cs
from contracts.flat import zoh
from contracts.vehicle import G, load_vehicle

RNG = np.random.default_rng(8)


def _box(a_x, a_y):
    return np.array([[a_x, a_y], [-a_x, a_y], [-a_x, -a_y], [a_x, -a_y]])


def _step_positions(q0, seqs, ts):
    """Positions after len(seq) ZOH steps from states q0 (n, 4) under input sequences seqs (s, k, 2)
    → (n, s, 2), by the eq. (12)–(13) matrices."""
    f_hat, g_hat = zoh(ts, 2)
    q = np.broadcast_to(q0[:, None, :], (len(q0), len(seqs), 4)).copy()
    for j in range(seqs.shape[1]):
        q = q @ f_hat.T + seqs[None, :, j, :] @ g_hat.T
    return q[..., 0::2]


def _inside(c0, d0, pos):
    n = c0[:, 0::2]
    return np.all(pos @ n.T <= d0 + 1e-12, axis=-1)


# ============================================================================ eq. (24)–(26)


def test_condensed_rows_equal_intersection_of_per_vertex_constraints():
    """Eq. (26) against eq. (25) (and eq. 24 itself) on random points, rotated square, cone polygon."""
    ts = 0.15
    f_hat, g_hat = zoh(ts, 2)
    c0, d0 = cs.square_obstacle(1.3, centre=(0.4, -0.2), angle=0.37)
    w = cs.cone_vertices(1.7, 8)
    c, d = c0, d0
    for _k in range(1, 5):
        d_kj = cs.vertex_offsets(c, d, g_hat, w)  # eq. (25), one offset vector per vertex
        c_k, d_min = cs.propagate(c, d, f_hat, g_hat, w)  # eq. (25)–(26)
        assert np.allclose(c_k, c @ f_hat) and d_kj.shape == (len(w), len(d))
        q = np.column_stack([RNG.uniform(-3, 3, 4000), RNG.uniform(-4, 4, 4000),
                             RNG.uniform(-3, 3, 4000), RNG.uniform(-4, 4, 4000)])
        per_vertex = np.all(np.all(q @ c_k.T <= d_kj[:, None, :], axis=-1), axis=0)  # ∩_j {C_k q ≤ D_kj}
        condensed = np.all(q @ c_k.T <= d_min, axis=-1)
        eq24 = np.all([np.all((q @ f_hat.T + g_hat @ wj) @ c.T <= d, axis=-1) for wj in w], axis=0)
        assert np.array_equal(per_vertex, condensed)
        assert np.array_equal(eq24, condensed)
        assert 0 < condensed.sum() < len(q) or _k > 2  # the test is not vacuous early on
        c, d = c_k, d_min


def test_brute_force_agrees_with_the_recursion_definition():
    """C_k ∋ q ⇔ q lands in the obstacle at step k under *every* input sequence: members hit at step k
    under all vertex sequences (exhaustive) and random interior sequences; non-members have a vertex
    sequence that does not."""
    ts, side = 0.2, 1.0
    c0, d0 = cs.square_obstacle(side, centre=(0.5, 0.0), angle=0.2)
    w = _box(1.0, 0.6)
    sets = cs.collision_sets(ts, c0, d0, w)
    assert sets.r >= 3
    f_hat, _ = zoh(ts, 2)
    for k in (1, 2, 3):
        # states whose zero-input trajectory is in the obstacle at step k (about half are members)
        p_t = RNG.uniform([0.0, -0.5], [1.0, 0.5], (1500, 2))
        v = RNG.uniform(-3, 3, (1500, 2))
        qt = np.column_stack([p_t[:, 0], v[:, 0], p_t[:, 1], v[:, 1]])
        q0 = qt @ np.linalg.matrix_power(np.linalg.inv(f_hat), k).T
        member = sets.member_of(k, q0)
        assert 50 < member.sum() < len(q0) - 50
        vertex_seqs = np.array(list(itertools.product(w, repeat=k)))  # m^k sequences
        hit_all_vertex = np.all(_inside(c0, d0, _step_positions(q0, vertex_seqs, ts)), axis=1)
        assert np.array_equal(member, hit_all_vertex)
        lam = RNG.dirichlet(np.ones(len(w)), (200, k))  # random sequences inside W^C
        hit_random = np.all(_inside(c0, d0, _step_positions(q0[member], lam @ w, ts)), axis=1)
        assert np.all(hit_random)


def test_propagation_stops_at_the_first_empty_set():
    a_x, a_y, side, ts = 0.9, 0.5, 1.5, 0.05
    c0, d0 = cs.square_obstacle(side, centre=(3.0, 1.0))
    sets = cs.collision_sets(ts, c0, d0, _box(a_x, a_y))
    # axis-aligned square, box inputs: C_k non-empty iff (k·t_s)²·max(a_x, a_y) ≤ side
    r_closed = math.floor(math.sqrt(side / max(a_x, a_y)) / ts)
    assert sets.r == r_closed and sets.first_empty == r_closed + 1
    assert all(not cs.is_empty(c, d) for c, d in zip(sets.c, sets.d))
    f_hat, g_hat = zoh(ts, 2)
    c_next, d_next = cs.propagate(sets.c[-1], sets.d[-1], f_hat, g_hat, sets.w)
    assert cs.is_empty(c_next, d_next)
    with pytest.raises(RuntimeError):
        cs.collision_sets(ts, c0, d0, _box(a_x, a_y), k_max=r_closed - 1)


def test_lp_emptiness_is_a_real_decision():
    c0, d0 = cs.square_obstacle(1.0)
    assert not cs.is_empty(c0, d0)
    assert cs.is_empty(c0, d0 - 0.6)  # opposite faces cross: empty
    assert not cs.is_empty(c0, d0 - 0.4)


def test_union_membership():
    c0, d0 = cs.square_obstacle(2.0, centre=(1.0, 0.0))
    sets = cs.collision_sets(0.1, c0, d0, _box(1.0, 1.0))
    assert sets.contains(np.array([1.0, 0.0, 0.0, 0.0]))  # inside the obstacle: C_0
    assert sets.contains(np.array([-1.0, 2.0, 0.0, 0.0]))  # 1 m ahead at 2 m/s cannot stop (a = 1)
    assert not sets.contains(np.array([-3.0, 1.0, 0.0, 0.0]))  # 3 m ahead at 1 m/s can


# ============================================================================ eq. (28), Figure 4


@pytest.mark.parametrize("a_x,a_y,side,ts", [(0.858, 0.858, math.sqrt(2), 0.02), (2.0, 1.2, 2.0, 0.05)])
def test_head_on_lines_match_the_hand_derived_closed_form(a_x, a_y, side, ts):
    """Double integrator, box inputs, square met face-on with its face at x = 0, head-on state
    q = (−D, V, 0, 0): C_k's face row is x + k·t_s·Ẋ ≥ (k·t_s)²·a_x/2, i.e. D·1 + V·(−k·t_s) ≤ −(k·t_s)²·a_x/2;
    its lateral rows are the constants 0 ≤ side/2 − (k·t_s)²·a_y/2; the last set is r = ⌊T_r/t_s⌋."""
    lines = cs.analytical_square_curve(side, _box(a_x, a_y), ts)
    k = np.arange(len(lines.c11))
    t = k * ts
    assert len(k) - 1 == math.floor(math.sqrt(side / max(a_x, a_y)) / ts)
    face = lines.c12[1].argmin()  # the only row that depends on V
    assert np.allclose(lines.c11[:, face], 1.0)
    assert np.allclose(lines.c12[:, face], -t)
    assert np.allclose(lines.d[:, face], -0.5 * t**2 * a_x)
    lat = [i for i in range(lines.c11.shape[1]) if i != face]
    assert len(lat) == 2 and np.allclose(lines.c11[:, lat], 0.0) and np.allclose(lines.c12[:, lat], 0.0)
    assert np.allclose(lines.d[:, lat], (0.5 * side - 0.5 * t**2 * a_y)[:, None])
    d_ob = np.linspace(0.0, 10.0, 201)
    v_closed = np.min(d_ob[:, None] / t[None, 1:] + 0.5 * a_x * t[None, 1:], axis=1)
    v_closed[0] = 0.0
    assert np.allclose(lines.v_max(d_ob), v_closed)
    # the sampled curve lies above the continuous-time one (t_s → 0), by less than the sampling allows
    v_cont = cs.continuous_head_on_v_max(d_ob, side, a_x, a_y)
    assert np.all(lines.v_max(d_ob) >= v_cont - 1e-12)
    t_r = math.sqrt(side / max(a_x, a_y))
    assert np.all(lines.v_max(d_ob) <= v_cont * (1 + ts / (t_r - ts)) + a_x * ts)
    # the union of half-planes is exactly the region at or above the curve
    v_probe = lines.v_max(d_ob[1:])
    assert np.all(lines.unsafe(d_ob[1:], v_probe * 1.001 + 1e-9))
    assert not np.any(lines.unsafe(d_ob[1:], v_probe * 0.999))


def test_curve_converges_downwards_as_the_sample_time_shrinks():
    a = G * math.tan(math.radians(13.0))
    d_ob = np.array([0.5, 1.0, 3.0, 5.0, 10.0])
    cont = cs.continuous_head_on_v_max(d_ob, 2.0, a, a)
    prev = None
    for ts in (0.16, 0.08, 0.04, 0.02, 0.01):  # nested grids of T = k·t_s
        v = cs.analytical_square_curve(2.0, _box(a, a), ts).v_max(d_ob)
        assert np.all(v >= cont - 1e-12)
        if prev is not None:
            assert np.all(v <= prev + 1e-12)
        prev = v
    assert np.allclose(prev, cont, rtol=0.012)


def test_rotated_square_and_cone_inputs_give_a_monotone_curve():
    c0, d0 = cs.square_obstacle(1.5, centre=(0.0, 0.0), angle=math.pi / 4)  # corner first
    w = cs.input_vertices(math.radians(10.0), "cone")
    lines = cs.head_on_lines(cs.collision_sets(0.02, c0, d0, w), c0, d0)
    assert lines.c11.shape[1] == 2  # two faces look at the vehicle
    v = lines.v_max(np.linspace(0, 10, 101))
    assert v[0] == 0.0 and np.all(np.diff(v) >= -1e-12) and v[-1] > 0


def test_same_step_recursion_is_a_subset_of_eq20_so_its_curve_is_optimistic():
    """A thin wide wall (depth 0.3 m, width 6 m), box 5°: the recursion ends when the positions reached
    at step k no longer fit in the wall's *depth*, long before a swerve could clear its half-width. A
    head-on state just below the recursion's curve is then certified (bounds valid for every input
    sequence) to hit the wall at some step — it is in eq. (20)'s set, the recursion calls it safe."""
    a = G * math.tan(math.radians(5.0))
    depth, width, ts = 0.3, 6.0, 0.02
    c0, d0 = cs.polygon_obstacle([[1, 0], [-1, 0], [0, 1], [0, -1]], [depth, 0.0, width / 2, width / 2])
    sets = cs.collision_sets(ts, c0, d0, _box(a, a))
    assert sets.r == math.floor(math.sqrt(depth / a) / ts)  # depth-limited, not width-limited
    lines = cs.head_on_lines(sets, c0, d0)
    d_ob = 5.0
    v = 0.99 * float(lines.v_max(d_ob))
    assert not lines.unsafe(d_ob, v)
    # certificate: every sequence reaches the face plane (x ≥ 0) by step K (braking-at-full lower bound),
    # with |y| ≤ a·t²/2 < width/2 until then, and advances < depth per step, so it stops inside the wall
    k = np.arange(1, 2000)
    t = k * ts
    x_lo = -d_ob + v * t - 0.5 * a * t**2
    big_k = int(k[np.argmax(x_lo >= 0)])
    assert x_lo[big_k - 1] >= 0 and 0.5 * a * (big_k * ts) ** 2 < width / 2
    v_bound = v + a * big_k * ts  # |Ẋ| bound up to step K
    assert v_bound * ts + 0.5 * a * ts**2 < depth
    # and the optimism is large: the same-step curve is far above the wall's true limit
    t_w = math.sqrt(width / a)
    v_true = max(math.sqrt(2 * a * d_ob), d_ob / t_w + 0.5 * a * t_w)
    assert v > 1.5 * v_true
    # sampled sequences agree: all hit the wall at some step
    seqs = _box(a, a)[RNG.integers(0, 4, (300, big_k))]
    q0 = np.array([[-d_ob, v, 0.0, 0.0]])
    f_hat, g_hat = zoh(ts, 2)
    q = np.repeat(q0, len(seqs), axis=0)
    hit = np.zeros(len(seqs), bool)
    for j in range(big_k):
        q = q @ f_hat.T + seqs[:, j] @ g_hat.T
        hit |= _inside(c0, d0, q[:, 0::2])
    assert np.all(hit)


def test_input_sets():
    t = math.radians(13.0)
    w = cs.input_vertices(t, "box")
    assert np.allclose(np.abs(w), G * math.tan(t))
    wc = cs.input_vertices(t, "cone", n_cone=16)
    assert len(wc) == 16 and np.allclose(np.linalg.norm(wc, axis=1), G * math.tan(t))
    assert any(np.allclose(v, [-G * math.tan(t), 0.0], atol=1e-9) for v in wc)  # full braking is a vertex
    # a thrust limit below the rectangle's corner clips it (all vertices inside the thrust disc)
    wt = cs.box_vertices(t, t, a_thrust=1.2 * G * math.tan(t))
    assert len(wt) > 4 and np.all(np.linalg.norm(wt, axis=1) <= 1.2 * G * math.tan(t) + 1e-9)


# ============================================================================ Figures 6–7: the paper's claim


@pytest.fixture(scope="module")
def cross_check():
    pytest.importorskip("casadi")
    from contracts import collision_compare as cc

    veh = load_vehicle("mambo")
    d_od = np.array([1.0, 3.0, 5.0])
    out = {}
    for tilt_deg in (5.0, 13.0):
        tilt = math.radians(tilt_deg)
        lines = cc.analytical_lines(veh, tilt, "box")
        num = cc.numerical_circle_curve(veh, tilt, d_od, "box", n=30, cpu_time=1.5)
        out[tilt_deg] = {pl: cc.analytical_curves(lines, d_od, placement=pl) for pl in cc.PLACEMENTS}
        out[tilt_deg]["numerical"] = num
    return out


TOL_REL = 0.03  # stated tolerance of the "between" check, see COLLISION_SETS.md


@pytest.mark.parametrize("tilt_deg", [5.0, 13.0])
def test_circle_between_the_squares_when_they_are_nested(cross_check, tilt_deg):
    """Concentric squares (paper Figure 5: inscribed ⊂ circle ⊂ circumscribed): the numerical circle
    lies between the two analytical curves for D_od ≤ 5 m, within TOL_REL (relative)."""
    r = cross_check[tilt_deg]
    num, ana = r["numerical"], r["concentric"]
    assert np.all(num >= ana["circumscribed"] * (1 - TOL_REL))
    assert np.all(num <= ana["inscribed"] * (1 + TOL_REL))


@pytest.mark.parametrize("tilt_deg", [5.0, 13.0])
def test_with_d_od_to_each_near_face_the_circle_is_above_both_squares(cross_check, tilt_deg):
    """The issue's placement (each obstacle's near surface at D_od) does NOT show the paper's claim:
    the inscribed square's front corners stand ahead of the circle's arc, so at small D_od the circle
    is easier than the inscribed square and its curve lies above both squares' curves. Asserted as
    found (not tuned away); see COLLISION_SETS.md."""
    r = cross_check[tilt_deg]
    num, ana = r["numerical"], r["face"]
    assert np.all(num >= ana["circumscribed"])
    assert num[0] > 1.08 * ana["inscribed"][0]  # D_od = 1 m: clearly outside the band


@pytest.mark.parametrize("tilt_deg,side", [(5.0, math.sqrt(2)), (13.0, 2.0)])
def test_analytical_square_curve_matches_the_planner_for_the_same_square(tilt_deg, side):
    """Face-on square: the same-step recursion loses nothing here, so the analytical curve (t_s = 0.02 s)
    must agree with the planner's verified speed for that square (no keep-out margin) within 2 %."""
    pytest.importorskip("casadi")
    from contracts import collision_compare as cc

    veh = load_vehicle("mambo")
    tilt = math.radians(tilt_deg)
    lines = cc.analytical_square_curve(side, cs.input_vertices(tilt, "box"), cs.TS_DEFAULT)
    for d in (3.0, 5.0):
        v_num = cc.numerical_square_speed(veh, tilt, side, d)
        assert v_num == pytest.approx(float(lines.v_max(d)), rel=0.02)
