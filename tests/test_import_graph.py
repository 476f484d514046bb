"""DESIGN.md §3's dependency rules, read from the source (every import, at module level or in a function):
`contracts/` imports neither of the others; `sitl_harness/` never imports `companion/`; `companion/`
imports `sitl_harness/` only from its two wiring modules (the command line, and `companion/flights.py`, the
lock-step flight of the daemon against the SITL that tests and campaigns fly — DESIGN.md §3 names only the
first); no module imports itself round a circle; and
the on-board path loads no CasADi and no matplotlib."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("contracts", "companion", "sitl_harness")
# the companion modules that may import the harness: the CLI (wires `sitl`, `demo`) and the lock-step flight
WIRING = ("companion.cli", "companion.flights")


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Every module of ours that `path` imports (relative imports resolved), anywhere in the file."""
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        out |= {n for n in names if n.split(".")[0] in PACKAGES}
    return out


def graph(root: Path = ROOT) -> dict[str, set[str]]:
    files = [p for pkg in PACKAGES for p in (root / pkg).rglob("*.py")]
    known = {module_name(p) for p in files}
    return {module_name(p): {m for m in imports_of(p) if m in known and m != module_name(p)} for p in files}


def violations(g: dict[str, set[str]]) -> list[str]:
    out = []
    for mod, deps in sorted(g.items()):
        top = mod.split(".")[0]
        for dep in sorted(deps):
            dtop = dep.split(".")[0]
            if top == "contracts" and dtop != "contracts":
                out.append(f"{mod} imports {dep}: contracts/ is the ground floor")
            if top == "sitl_harness" and dtop == "companion":
                out.append(f"{mod} imports {dep}: the harness never imports the companion")
            if top == "companion" and dtop == "sitl_harness" and mod not in WIRING:
                out.append(f"{mod} imports {dep}: only {' and '.join(WIRING)} may import the harness")
    return out


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Import circles among our modules (strongly connected components of more than one module)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_dependency_direction_of_design_section_3():
    assert violations(graph()) == []


def test_no_import_circles():
    assert cycles(graph()) == []


def test_the_checks_can_fail():
    g = {"contracts.table": {"companion.config"}, "sitl_harness.sim": {"companion.daemon"},
         "companion.demo": {"sitl_harness.scenario"}, "companion.cli": {"sitl_harness.scenario"},
         "companion.flights": {"sitl_harness"}, "companion.campaign": {"sitl_harness.sim"},
         "companion.review": {"companion.flightlogs.tlog"}, "companion.flightlogs.tlog": {"companion.review"}}
    assert len(violations(g)) == 4
    assert cycles(g) == [["companion.flightlogs.tlog", "companion.review"]]
    # relative imports inside functions are seen too
    src = ROOT / "companion" / "_probe_for_test.py"
    src.write_text("def f():\n    from .review import review\n    from ..sitl_harness import scenario\n")
    try:
        assert imports_of(src) >= {"companion.review", "sitl_harness", "sitl_harness.scenario"}
    finally:
        src.unlink()


@pytest.mark.parametrize("heavy", ["casadi", "matplotlib"])
def test_the_onboard_path_loads_neither_casadi_nor_matplotlib(heavy):
    """What `contract-guard run` loads: the CLI, the daemon and everything it wires, a table read."""
    code = ("import sys, companion.cli, companion.daemon, companion.service, companion.eventlog; "
            "from contracts.table import verify; verify('contracts/data/mambo.npz'); "
            f"assert {heavy!r} not in sys.modules, sorted(m for m in sys.modules if m.startswith({heavy!r}))")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_the_qp_solver_loads_only_where_plans_are_made(tmp_path):
    """OSQP and scipy.sparse (≈0.6 s to import) serve the avoidance planner only: a log review's shadow daemon
    never plans, so reviewing a log loads neither; a cycle in offboard mode loads them when it is made (with a route
    from the mission its planner is made later, in the loop: the first plan must not wait for an import). numba,
    where installed (the compiled Ω lookup), imports scipy's core and linalg itself, not scipy.sparse."""
    from tests.test_flight_logs import write_bin

    log = write_bin(tmp_path / "f.bin", dur=3.0)
    review = ("import sys; from companion.cli import review_log; "
              f"rep, _ = review_log({str(log)!r}, vehicle='x500'); assert rep['state_samples'] > 0; "
              "loaded = sorted(m for m in sys.modules if m.split('.')[0] == 'osqp' or m.startswith('scipy.sparse')); "
              "assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", review], check=True, cwd=ROOT)
    offboard = ("import sys; from companion.config import Config; from companion.cycle import Cycle; "
                "from companion.guidance import InlinePlanning; from contracts.table import load_for_vehicle; "
                "from companion.autopilots import adapter_for; "
                "cfg = Config(vehicle='x500', mode='offboard', route={'source': 'mission'}, "
                "sensors=[{'kind': 'obstacle_distance', 'h_fov_deg': 60, 'max_range_m': 10}]); "
                "assert 'osqp' not in sys.modules; "
                "Cycle(cfg, load_for_vehicle(cfg.vehicle, cfg.table), adapter_for('px4'), 'avoid', InlinePlanning); "
                "assert {'osqp', 'scipy.sparse'} <= set(sys.modules)")
    subprocess.run([sys.executable, "-c", offboard], check=True, cwd=ROOT)
