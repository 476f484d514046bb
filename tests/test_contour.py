import numpy as np
import pytest

from contracts.contour import ContourWindow, contour_errors, distance_to_polyline


def test_point_to_segment_closed_forms():
    seg = [[0.0, 0.0], [4.0, 0.0]]
    assert distance_to_polyline([2.0, 3.0], seg) == pytest.approx(3.0)  # foot inside
    assert distance_to_polyline([-3.0, 4.0], seg) == pytest.approx(5.0)  # beyond the start
    assert distance_to_polyline([7.0, -4.0], seg) == pytest.approx(5.0)  # beyond the end
    assert distance_to_polyline([1.0, 1.0, 1.0], [[0, 0, 0], [2, 0, 0]]) == pytest.approx(np.sqrt(2))


def test_polyline_corner_uses_the_vertex():
    # an L: (0,0)→(2,0)→(2,2); the point (3,-1) is nearest the corner
    path = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]]
    assert distance_to_polyline([3.0, -1.0], path) == pytest.approx(np.sqrt(2))
    # inside the corner: nearest is one of the legs, not the vertex
    assert distance_to_polyline([1.5, 0.5], path) == pytest.approx(0.5)


def test_degenerate_segments_and_single_points():
    assert distance_to_polyline([3.0, 4.0], [[0.0, 0.0]]) == pytest.approx(5.0)
    assert distance_to_polyline([3.0, 4.0], [[0.0, 0.0], [0.0, 0.0]]) == pytest.approx(5.0)


@pytest.mark.parametrize("n", [200, 2000])
def test_finely_sampled_circle(n):
    r, delta = 5.0, 0.3
    th = np.linspace(0, 2 * np.pi, n + 1)
    circle = np.column_stack([r * np.cos(th), r * np.sin(th)])
    sag = r * (1 - np.cos(np.pi / n))  # chord sagitta: the polyline's largest inward deviation
    rng = np.random.default_rng(1)
    for a in rng.uniform(0, 2 * np.pi, 20):
        p = (r + delta) * np.array([np.cos(a), np.sin(a)])
        e = distance_to_polyline(p, circle)
        assert delta - 1e-12 <= e <= delta + sag + 1e-12
        q = (r - delta) * np.array([np.cos(a), np.sin(a)])
        assert delta - sag - 1e-12 <= distance_to_polyline(q, circle) <= delta + 1e-12


def test_window_keeps_a_self_crossing_path_from_hiding_the_error():
    # out along x and back 1 m to the side: a sample at t=1 off by 1 m is 0 m from the return leg
    t_path = np.linspace(0, 10, 101)
    x = np.where(t_path <= 5, t_path, 10 - t_path)
    y = np.where(t_path <= 5, 0.0, 1.0)
    path = np.column_stack([x, y])
    e = contour_errors([[1.0, 1.0]], [1.0], t_path, path, window_s=1.0)
    assert e[0] == pytest.approx(1.0)
    e_all = contour_errors([[1.0, 1.0]], [1.0], t_path, path, window_s=100.0)
    assert e_all[0] == pytest.approx(0.0)


def test_contour_window_tracks_the_worst_over_its_window():
    w = ContourWindow(window_s=1.0, path_span_s=2.0)
    assert w.measure(0.0, [0.0, 0.0]) is None
    for k in range(60):
        t = 0.1 * k
        w.command(t, [t, 0.0])
    w.measure(1.0, [1.0, 0.5])
    assert w.worst == pytest.approx(0.5)
    w.measure(1.5, [1.5, 0.1])
    assert w.worst == pytest.approx(0.5)  # still inside the window
    w.measure(2.6, [2.6, 0.2])
    assert w.worst == pytest.approx(0.2)  # the 0.5 sample has left the window
    w.reset()
    assert w.worst == 0.0


def _first_distance(p, pts) -> float:
    """distance_to_polyline as first written (one function, nothing cached): the reference of the tests below."""
    pts, p = np.asarray(pts, dtype=float), np.asarray(p, dtype=float)
    if len(pts) == 1:
        return float(np.linalg.norm(p - pts[0]))
    a = pts[:-1]
    ab = pts[1:] - a
    ap = p - a
    den = np.einsum("ij,ij->i", ab, ab)
    s = np.clip(np.einsum("ij,ij->i", ap, ab) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    d = ap - s[:, None] * ab
    return float(np.sqrt(np.einsum("ij,ij->i", d, d).min()))


@pytest.mark.parametrize("dim", [2, 3])
def test_distance_to_polyline_is_bit_identical_to_the_first_one(dim):
    rng = np.random.default_rng(dim)
    for n in (1, 2, 3, 17, 200):
        for _ in range(50):
            pts = rng.normal(size=(n, dim)) * rng.choice([1e-3, 1.0, 1e3])
            if n > 2:
                pts[n // 2] = pts[n // 2 - 1]  # a zero-length segment
            p = rng.normal(size=dim)
            assert distance_to_polyline(p, pts) == _first_distance(p, pts)


def test_the_window_gives_the_errors_of_a_plain_restacking_of_its_path():
    """The sliding path is sliced from one array and its segments computed once; a reference that re-stacks
    the kept samples at every measurement (the window's first implementation) gives bit-identical errors,
    across new plans, repeated path points and the arrays' growth."""
    from collections import deque

    rng = np.random.default_rng(3)
    w, path, span = ContourWindow(window_s=2.0, path_span_s=2.0), deque(), 2.0
    t = 0.0
    for _ in range(6000):
        t += 0.02
        if rng.random() < 0.7:
            tc = t + (rng.uniform(-0.5, 1.5) if rng.random() < 0.05 else 0.5)
            q = path[-1][1] if path and rng.random() < 0.1 else rng.normal(size=2)  # now and then: the same point
            if path and tc < path[-1][0]:
                path.clear()
            path.append((tc, q))
            w.command(tc, q)
        p = rng.normal(size=2)
        while len(path) > 1 and path[1][0] < t - span:
            path.popleft()
        kept = [q for s, q in path if s <= t + span] or ([path[0][1]] if path else [])
        want = _first_distance(p, np.array(kept)) if kept else None
        assert w.measure(t, p) == want
