"""The reader's enclosing-disc answer (lookup.ReactLookup), no solver calls."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from contracts.lookup import ReactLookup
from contracts.vehicle import G

RHO = np.geomspace(0.05, 0.95, 9)  # deliberately coarse


def react_fixed_point(c0, r_k, rho, f, t_r):
    """One query of the reader's exact reaction-time solver (enclosing discs included)."""
    return ReactLookup(rho, np.asarray(f)[None, :], [max(t_r, 1e-9)])(c0, np.array([[r_k]]))[0, 0]


def stop_f(a):
    return np.sqrt(2.0 * a / G * (1.0 - RHO))  # the pure stop branch, exact on the grid


@settings(max_examples=200, deadline=None)
@given(c0=st.floats(0.5, 30.0), frac=st.floats(0.01, 0.9), t_r=st.floats(0.0, 0.5), a=st.floats(0.5, 8.0))
def test_enclosing_answer_is_the_exact_stop_law_on_a_coarse_grid(c0, frac, t_r, a):
    r_k = frac * c0
    s = c0 - r_k
    v_exact = a * (-t_r + math.sqrt(t_r * t_r + 2.0 * s / a))  # V·t_r + V²/(2a) = s
    enc = float(react_fixed_point(c0, r_k, RHO, stop_f(a), t_r))
    assert enc <= v_exact * (1 + 1e-9)
    if r_k / (c0 - v_exact * t_r) <= RHO[-1] * 0.999:  # the reaction-shifted ρ is inside the grid
        assert enc >= v_exact * (1 - 1e-6)


@settings(max_examples=200, deadline=None)
@given(d=st.floats(0.0, 20.0), r=st.floats(0.05, 3.0), dr=st.floats(0.0, 3.0), t_r=st.floats(0.0, 0.4))
def test_enclosing_answer_non_increasing_in_r_obst(d, r, dr, t_r):
    f = np.maximum(1.0 / np.sqrt(2 * RHO), np.sqrt(2 * (1 - RHO))) * 0.4  # a pass+stop shaped F
    v1 = float(react_fixed_point(d + r, r + 0.1, RHO, f, t_r))
    v2 = float(react_fixed_point(d + r + dr, r + dr + 0.1, RHO, f, t_r))
    assert v2 <= v1 + 1e-9
