"""The compiled Ω kernel (`contracts.lookup._fixed_point_kernel`, numba) gives the same bits as the numpy path
of `ReactLookup.step_fixed_point` it stands in for (issue 18 item 3): on the shipped tables and on random
synthetic ones, every field of Ω compared with `==`, out-of-range and edge inputs included. And the kernel's
source run as plain Python (`py_func`) gives the compiled answers: `fastmath=False` keeps IEEE order."""

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_table import MAMBO, PROP, avoid_tables, etr_tables, make

import contracts.lookup as lookup
from contracts.jit import HAVE_NUMBA
from contracts.table import load_for_vehicle

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed (the `fast` extra): no kernel")


def omegas(table, queries, kernel: bool) -> list:
    old = lookup.USE_KERNEL
    lookup.USE_KERNEL = kernel
    try:
        return [table.omega(*q) for q in queries]
    finally:
        lookup.USE_KERNEL = old


def queries(vehicle, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = vehicle.thrust_ratio_range
    q = np.column_stack([rng.uniform(0, 16, n), rng.uniform(0, 2.5, n), rng.uniform(0, 2.0, n),
                         rng.uniform(lo - 0.05, hi + 0.1, n)]).tolist()
    edges = [[0.0, 0.5, 0.0, 1.0], [1e-9, 0.0, 0.0, hi], [100.0, 0.1, 0.0, hi], [3.0, 0.5, 50.0, 1.0],
             [0.3, 2.0, 0.0, lo], [16.0, 0.0, 0.0, lo]]
    return q + edges


def as_tuple(o):
    return (o.contract, o.v_max, o.tilt, o.e_tr, o.v_safe, o.gamma, o.reason)


@pytest.mark.parametrize("name", ["mambo", "x500"])
def test_kernel_and_numpy_give_the_same_omega_on_the_shipped_tables(name):
    t = load_for_vehicle(name)
    q = queries(t.vehicle, 4000, 7)
    fast, ref = omegas(t, q, True), omegas(t, q, False)
    diff = [(qq, as_tuple(a), as_tuple(b)) for qq, a, b in zip(q, fast, ref) if as_tuple(a) != as_tuple(b)]
    assert not diff, diff[:3]
    assert sum(o.v_max > 0 for o in fast) > 3000  # the queries reach answers, not only "no safe speed"


@PROP
@given(avoid_tables(), etr_tables(), st.integers(0, 2**31 - 1))
def test_kernel_and_numpy_agree_on_random_tables(tmp_path, avoid, etr, seed):
    t = make(tmp_path, avoid=avoid, e_tr_pred=etr)
    q = queries(MAMBO, 150, seed)
    assert [as_tuple(o) for o in omegas(t, q, True)] == [as_tuple(o) for o in omegas(t, q, False)]


def test_the_kernels_source_as_python_gives_the_compiled_bits():
    t = load_for_vehicle("x500")
    react = t._react[-1]
    rng = np.random.default_rng(3)
    k, m = react.k, len(react._v)
    e = np.maximum.accumulate(rng.uniform(0.05, 1.5, (k, m)), axis=1)
    seen = set()
    for c0 in rng.uniform(0.0, 20.0, 300):
        r_k = 0.3 + e * rng.uniform(0.5, 2.0)
        lam = rng.uniform(1.0, 1.3, k)
        args = (float(c0), r_k, react._wt, react._w2, react._v, react.rho, react._u, react._h, react._hsuf2,
                react._t_col, lam)
        a, b = lookup._fixed_point_kernel(*args), lookup._fixed_point_kernel.py_func(*args)
        assert a == b
        seen.add(a[0] >= 0)
        assert all(math.isfinite(x) for x in a[2:])
    assert seen == {True, False}  # both outcomes (an answer; "no row reaches v_0", left to numpy) are exercised


MDWE_PROBE = """
import ctypes, mmap, sys
if ctypes.CDLL(None, use_errno=True).prctl(65, 1, 0, 0, 0) != 0:  # PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN
    print("unsupported"); sys.exit(0)
try:
    mmap.mmap(-1, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
    print("unsupported"); sys.exit(0)
except OSError:
    pass
import contracts.lookup as lookup
from contracts.table import load_for_vehicle
o = load_for_vehicle("x500").omega(8.0, 0.5, 0.3, 1.0)
print(lookup.USE_KERNEL, lookup.kernel_name(), o.v_max)
"""


def test_no_executable_memory_falls_back_to_numpy_and_still_answers():
    """The service unit's MemoryDenyWriteExecute=yes forbids a JIT: numba's import raises PermissionError there.
    The lookup must then load and answer on its numpy path, not fail (run under the kernel's PR_SET_MDWE)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, "-c", MDWE_PROBE], capture_output=True, text=True, cwd=root, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    if p.stdout.strip() == "unsupported":
        pytest.skip("this kernel has no PR_SET_MDWE (Linux < 6.3): cannot forbid executable memory here")
    kernel, *name, v = p.stdout.split()
    assert kernel == "False" and "numpy" in " ".join(name)
    ref = omegas(load_for_vehicle("x500"), [[8.0, 0.5, 0.3, 1.0]], True)[0]
    assert float(v) == pytest.approx(ref.v_max, rel=0, abs=1e-9) and ref.v_max > 0


@pytest.mark.skipif(not lookup.USE_KERNEL, reason="numba is not installed: the lookup has no kernel to compile")
def test_the_daemon_compiles_the_kernel_at_its_start_and_a_tool_that_reads_a_table_never_does(tmp_path):
    """In a fresh process: loading a table leaves the kernel uncompiled (`table show` never pays for it); the
    daemon's construction compiles it (or loads numba's cache), before its first cycle."""
    child = textwrap.dedent(f"""
        from companion.onboard.config import config_from_dict
        from companion.onboard.daemon import Daemon
        from companion.onboard.link import MemoryMavfile
        from contracts.lookup import _fixed_point_kernel
        from contracts.table import load_for_vehicle

        cfg = config_from_dict({{"vehicle": "mambo", "mode": "governor", "link": {{"connect": "memory"}},
                                 "sensors": [{{"kind": "distance_sensor", "h_fov_deg": 30, "max_range_m": 6}}],
                                 "log": {{"dir": {str(tmp_path)!r}}}}})
        table = load_for_vehicle(cfg.vehicle)
        print(len(_fixed_point_kernel.signatures))
        Daemon(cfg, table, MemoryMavfile(lambda: b"", lambda b: None), None, clock=lambda: 0.0, planning="inline")
        print(len(_fixed_point_kernel.signatures))
    """)
    run = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["0", "1"]
