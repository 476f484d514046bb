"""DESIGN.md §3's dependency rules, read from the source (every import, at module level or in a function):
`contracts/` imports neither of the others; `sitl_harness/` never imports `companion/`; `companion/`
imports `sitl_harness/` only from its wiring modules (the command line, the ground commands that fly or draw
with it, and `companion/ground/flights.py`, the lock-step flight of the daemon against the SITL that tests and
campaigns fly); the on-board package (`companion/onboard/`) never imports the ground package
(`companion/ground/`) or the command line, directly or through another module, nor a ground-only dependency;
no module imports itself round a circle; and the daemon's start loads no ground module, no CasADi and no
matplotlib."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("contracts", "companion", "sitl_harness")
# the companion modules that may import the harness: the CLI (wires `sitl`, `demo`) and the lock-step flight
WIRING = ("companion.cli", "companion.ground.commands", "companion.ground.flights")
ONBOARD, GROUND = "companion.onboard", "companion.ground"
# what only the ground tools need (the `ground` and `build` extras): never imported on board
GROUND_ONLY = ("pyulog", "tqdm", "matplotlib", "casadi", "dask", "distributed")


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _type_checking(node) -> bool:
    return isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"


def imports_of(path: Path) -> set[str]:
    """Every module of ours that `path` imports (relative imports resolved), anywhere in the file."""
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    out = set()
    tree = ast.parse(path.read_text())
    typing_only = {id(n) for block in ast.walk(tree) if _type_checking(block) for s in block.body for n in ast.walk(s)}
    for node in ast.walk(tree):
        if id(node) in typing_only:  # `if TYPE_CHECKING:` imports are for annotations: nothing is loaded
            continue
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
                out.append(f"{mod} imports {dep}: only {', '.join(WIRING)} may import the harness")
            if in_package(mod, ONBOARD) and not in_package(dep, ONBOARD) and dtop == "companion":
                out.append(f"{mod} imports {dep}: the on-board package imports no ground module")
    return out


def in_package(mod: str, package: str) -> bool:
    return mod == package or mod.startswith(package + ".")


def ground_reached(g: dict[str, set[str]]) -> dict[str, list[str]]:
    """For each on-board module that reaches a companion module outside the on-board package through any chain of
    imports: the chain."""
    out = {}
    for start in sorted(m for m in g if in_package(m, ONBOARD)):
        seen, frontier = {start: [start]}, [start]
        while frontier:
            m = frontier.pop()
            for d in sorted(g.get(m, ())):
                if d not in seen:
                    seen[d] = seen[m] + [d]
                    frontier.append(d)
        bad = [d for d in seen if d.split(".")[0] == "companion" and not in_package(d, ONBOARD) and d != "companion"]
        if bad:
            out[start] = seen[sorted(bad)[0]]
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


def test_no_onboard_module_reaches_a_ground_one():
    assert ground_reached(graph()) == {}


def third_party_imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out


def test_the_onboard_package_imports_no_ground_only_dependency():
    found = {str(p.relative_to(ROOT)): sorted(third_party_imports(p) & set(GROUND_ONLY))
             for p in (ROOT / "companion" / "onboard").rglob("*.py")}
    assert {k: v for k, v in found.items() if v} == {}


def test_the_aircraft_install_brings_no_ground_only_dependency():
    """`pip install contract-guard` is the aircraft's install; the ground tools' packages come with the `ground`
    extra (`contract-guard[ground]`)."""
    import re
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    name = lambda req: re.split(r"[<>=!~\[; ]", req, maxsplit=1)[0].lower()  # noqa: E731
    assert {name(r) for r in project["dependencies"]} & set(GROUND_ONLY) == set()
    assert {"pyulog", "tqdm", "matplotlib"} <= {name(r) for r in project["optional-dependencies"]["ground"]}


def test_no_import_circles():
    assert cycles(graph()) == []


def test_the_checks_can_fail():
    g = {"contracts.table": {"companion.onboard.config"}, "sitl_harness.sim": {"companion.onboard.daemon"},
         "companion.ground.demo": {"sitl_harness.scenario"}, "companion.cli": {"sitl_harness.scenario"},
         "companion.ground.flights": {"sitl_harness"}, "companion.ground.campaign": {"sitl_harness.sim"},
         "companion.ground.review": {"companion.ground.flightlogs.tlog"}, "companion.ground.flightlogs.tlog": {"companion.ground.review"}}
    assert len(violations(g)) == 4
    assert cycles(g) == [["companion.ground.flightlogs.tlog", "companion.ground.review"]]
    g = {"companion.onboard.cycle": {"companion.onboard.samples"}, "companion.onboard.samples": {"companion.onboard.x"},
         "companion.onboard.x": {"companion.ground.review"}, "companion.ground.review": set(),
         "companion.onboard.daemon": {"companion.cli"}}
    assert [v.split(":")[0] for v in violations(g)] == ["companion.onboard.daemon imports companion.cli",
                                                         "companion.onboard.x imports companion.ground.review"]
    assert ground_reached(g)["companion.onboard.cycle"] == ["companion.onboard.cycle", "companion.onboard.samples",
                                                             "companion.onboard.x", "companion.ground.review"]
    # relative imports inside functions are seen too
    src = ROOT / "companion" / "ground" / "_probe_for_test.py"
    src.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .demo import run_demo\n"
                   "def f():\n    from .review import review\n    from ...sitl_harness import scenario\n")
    try:
        found = imports_of(src)
        assert found >= {"companion.ground.review", "sitl_harness", "sitl_harness.scenario"}
        assert "companion.ground.demo" not in found  # for annotations only: nothing is loaded
    finally:
        src.unlink()


@pytest.mark.parametrize("heavy", ["companion.ground", *GROUND_ONLY])
def test_the_daemons_start_loads_no_ground_module(heavy):
    """What `contract-guard run` loads: the CLI and its parser, the on-board command, the daemon and everything it
    wires, a table read."""
    code = ("import sys, companion.cli, companion.onboard.commands, companion.onboard.daemon, "
            "companion.onboard.service, companion.onboard.eventlog, companion.onboard.console; "
            "companion.cli.build_parser().parse_args(['run', '--config', 'x.yaml']); "
            "from contracts.table import verify; verify('contracts/data/mambo.npz'); "
            f"assert {heavy!r} not in sys.modules, sorted(m for m in sys.modules if m.startswith({heavy!r}))")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_the_start_check_can_fail():
    code = "import sys, companion.ground.commands; assert 'companion.ground' not in sys.modules"
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True).returncode != 0


def test_every_command_has_its_handler():
    """Each subcommand names a function of the package that runs it (loaded only when it runs)."""
    import argparse

    from companion import cli
    from companion.ground import commands as ground
    from companion.onboard import commands as onboard

    p = cli.build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    handlers = {}
    for name, parser in sub.choices.items():
        d = parser._defaults
        if "handler" in d:
            handlers[name] = (d["func"], d["handler"])
        for a in parser._actions:  # `table show` etc.
            if isinstance(a, argparse._SubParsersAction):
                handlers |= {f"{name} {n}": (sp._defaults["func"], sp._defaults["handler"]) for n, sp in a.choices.items()}
    assert handlers["run"] == (cli._onboard, "cmd_run") and callable(onboard.cmd_run)
    assert len(handlers) >= 15
    for name, (func, handler) in handlers.items():
        assert callable(getattr(ground if func is cli._ground else onboard, handler)), name


def test_the_qp_solver_loads_only_where_plans_are_made(tmp_path):
    """OSQP and scipy.sparse (≈0.6 s to import) serve the avoidance planner only: a log review's shadow daemon
    never plans, so reviewing a log loads neither; a cycle in offboard mode loads them when it is made (with a route
    from the mission its planner is made later, in the loop: the first plan must not wait for an import). numba,
    where installed (the compiled Ω lookup), imports scipy's core and linalg itself, not scipy.sparse."""
    from tests.test_flight_logs import write_bin

    log = write_bin(tmp_path / "f.bin", dur=3.0)
    review = ("import sys; from companion.ground.commands import review_log; "
              f"rep, _ = review_log({str(log)!r}, vehicle='x500'); assert rep['state_samples'] > 0; "
              "loaded = sorted(m for m in sys.modules if m.split('.')[0] == 'osqp' or m.startswith('scipy.sparse')); "
              "assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", review], check=True, cwd=ROOT)
    offboard = ("import sys; from companion.onboard.config import Config; from companion.onboard.cycle import Cycle; "
                "from companion.onboard.guidance import InlinePlanning; from contracts.table import load_for_vehicle; "
                "from companion.onboard.autopilots import adapter_for; "
                "cfg = Config(vehicle='x500', mode='offboard', route={'source': 'mission'}, "
                "sensors=[{'kind': 'obstacle_distance', 'h_fov_deg': 60, 'max_range_m': 10}]); "
                "assert 'osqp' not in sys.modules; "
                "Cycle(cfg, load_for_vehicle(cfg.vehicle, cfg.table), adapter_for('px4'), 'avoid', InlinePlanning); "
                "assert {'osqp', 'scipy.sparse'} <= set(sys.modules)")
    subprocess.run([sys.executable, "-c", offboard], check=True, cwd=ROOT)
