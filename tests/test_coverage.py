"""The swept-coverage geometry (contracts/coverage.py, issue 19 item 2), against brute-force sampling."""

import math

import numpy as np

from contracts.coverage import covered_distance, ray_intervals, sample_sectors


def inside(q, sec) -> bool:
    """Point q in the wedge (apex, [θ_lo, θ_hi], radius), by its bearing and distance."""
    ax, ay, lo, hi, r = sec
    d = math.hypot(q[0] - ax, q[1] - ay)
    if d > r:
        return False
    if d < 1e-12:
        return True
    a = math.atan2(q[1] - ay, q[0] - ax)
    return (a - lo) % (2 * math.pi) <= (hi - lo) + 1e-9


def test_the_stretch_of_a_ray_in_a_wedge_matches_sampling():
    rng = np.random.default_rng(7)
    s = np.linspace(0.0, 12.0, 4801)
    for _ in range(300):
        lo = rng.uniform(-math.pi, math.pi)
        sec = (rng.uniform(-3, 3), rng.uniform(-3, 3), lo, lo + rng.uniform(0.05, 3.0), rng.uniform(0.5, 8.0))
        p, th = rng.uniform(-3, 3, 2), rng.uniform(-math.pi, math.pi)
        (s0, s1), = ray_intervals(p, th, np.array([sec]))
        hit = np.array([inside(p + si * np.array([math.cos(th), math.sin(th)]), sec) for si in s])
        if not hit.any():
            assert s1 <= s0 + 1e-6
            continue
        assert abs(s[hit].min() - s0) < 0.01 and abs(s[hit].max() - s1) < 0.01


def test_covered_distance_chains_overlapping_stretches_and_stops_at_a_break():
    # a vehicle flew +x from (-4, 0) to (0, 0), its ±30° sensor (4 m) looking along +x; now it moves at 60°
    half = math.radians(30)
    past = np.array([(x, 0.0, -half, half, 4.0) for x in np.linspace(-4.0, 0.0, 9)])
    th = math.radians(60)
    d = covered_distance((0.0, 0.0), th, past)
    u = np.array([math.cos(th), math.sin(th)])
    every = [s * u for s in np.linspace(0, d, 400)]
    assert all(any(inside(q, sec) for sec in past) for q in every)  # never more than was seen…
    assert not any(inside((d + 0.01) * u, sec) for sec in past)  # …and all of it
    # the wedge from (-2.5, 0) ends the run where its 4 m reach crosses the ray: s² + 2.5 s − 9.75 = 0
    assert abs(d - (-2.5 + math.sqrt(2.5 ** 2 + 4 * 9.75)) / 2) < 1e-9
    # a wedge further out along the ray, not touching the covered run, adds nothing
    far = np.vstack([past, [(*(3.5 * u + [0.5, 0.0]), th - 0.2, th + 0.2, 5.0)]])
    assert ray_intervals((0.0, 0.0), th, far[-1:])[0, 0] > d
    assert covered_distance((0.0, 0.0), th, far) == d
    # …and one that bridges from the run outwards extends it
    bridge = np.vstack([past, [(*(1.0 * u), th - 0.2, th + 0.2, 3.0)]])
    assert abs(covered_distance((0.0, 0.0), th, bridge) - 4.0) < 1e-9
    # a direction never seen from where the vehicle is: nothing
    assert covered_distance((0.0, 2.5), math.radians(90), past) == 0.0
    assert covered_distance((0.0, 0.0), 0.0, np.zeros((0, 5))) == 0.0


def test_a_bin_with_a_hit_is_free_only_to_the_hit():
    inc = math.radians(5)
    bearings = np.radians(np.arange(-30, 31, 5.0))
    ranges = np.full(len(bearings), np.inf)
    ranges[6] = 2.0  # the middle bin sees something at 2 m
    sec = sample_sectors((0.0, 0.0), 0.0, bearings, inc, ranges, 6.0)
    assert len(sec) == 3  # free bins either side merged, the hit bin on its own
    assert covered_distance((0.0, 0.0), 0.0, np.array(sec)) == 2.0
    assert covered_distance((0.0, 0.0), math.radians(20), np.array(sec)) == 6.0
    assert covered_distance((0.0, 0.0), math.radians(40), np.array(sec)) == 0.0  # outside the field of view
