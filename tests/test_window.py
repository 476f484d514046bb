import numpy as np

from contracts.window import WindowMax


def test_window_max_is_the_max_of_the_window():
    """Against the plain max over the samples still in the window, with ties, repeated times and gaps."""
    rng = np.random.default_rng(5)
    w, kept, t = WindowMax(3.0), [], 0.0
    assert w.max is None
    for _ in range(5000):
        t += rng.choice([0.0, 0.02, 0.02, 0.5, 4.0])
        v = float(rng.choice([0.0, 1.0, rng.uniform(0.0, 2.0)]))
        w.add(t, v)
        kept = [(s, x) for s, x in kept if s >= t - 3.0] + [(t, v)]
        assert w.max == max(x for _, x in kept)
    w.clear()
    assert w.max is None


def test_the_window_read_at_a_later_time_forgets_what_left_it():
    w = WindowMax(2.0)
    w.add(0.0, 5.0)
    w.add(1.0, 3.0)
    assert w.value(1.5) == 5.0 and w.value(2.5) == 3.0  # 5 left the window at t = 2
    assert w.value(3.5) == 0.0 and w.value(3.5, empty=-1.0) == -1.0 and w.max is None
