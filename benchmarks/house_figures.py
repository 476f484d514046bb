"""The house's figures, printed as one JSON object: lines of the cycle and the daemon, the supervisor's `_decide`,
string tests of the daemon's mode, outbox apply sites and direct sends in the daemon, the most parameters of a
cycle actor's method, the ground modules the daemon's start loads. `python benchmarks/house_figures.py [ROOT]`."""

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1])
MODES = {"shadow", "governor"}  # ("offboard" is an autopilot mode too: counted only against the config's mode)


def find(name: str) -> Path:
    for sub in ("companion/onboard", "companion"):
        if (ROOT / sub / name).exists():
            return ROOT / sub / name
    raise FileNotFoundError(name)


def lines(name: str) -> int:
    return len(find(name).read_text().splitlines())


def decide_lines() -> int:
    tree = ast.parse(find("supervisor.py").read_text())
    f = next(n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name == "_decide")
    return f.end_lineno - f.lineno + 1


def mode_string_tests() -> int:
    """Comparisons of the daemon's mode with its names, outside the mode classes (modes.py)."""
    n = 0
    for p in list(ROOT.glob("companion/**/*.py")):
        if p.name == "modes.py":
            continue
        src = p.read_text()
        for node in ast.walk(ast.parse(src)):
            if not isinstance(node, ast.Compare):
                continue
            parts = [node.left, *node.comparators]
            consts = {c.value for c in parts if isinstance(c, ast.Constant) and isinstance(c.value, str)}
            for c in parts:  # `x in ("governor", ...)`
                if isinstance(c, (ast.Tuple, ast.Set, ast.List)):
                    consts |= {e.value for e in c.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}
            text = ast.get_segment(src, node) if hasattr(ast, "get_segment") else ast.get_source_segment(src, node)
            daemon_mode = any(k in text for k in ("cfg.mode", "config.mode", "self.mode", "daemon_mode", "mode_name"))
            if consts & MODES or ("offboard" in consts and daemon_mode and "i.mode" not in text):
                n += 1
    return n


def calls_in(path: Path, attr: str) -> int:
    return sum(1 for node in ast.walk(ast.parse(path.read_text()))
               if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == attr)


def direct_sends(path: Path) -> int:
    """Messages the daemon sends itself rather than through an outbox (`out.send`, `out.statustext`, `*_send`)."""
    n = 0
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            a = node.func.attr
            if a in ("send", "statustext", "send_statustext") or a.endswith("_send"):
                n += 1
    return n


ACTORS = {"cycle.py": None, "flying.py": None, "holds.py": None, "sensing.py": None,
          "offboard.py": ("OffboardController",), "calibration_holds.py": ("CalibrationHolds",)}


def actor_params() -> dict:
    """The most parameters (self not counted) of a method, constructors aside, of the cycle and its actors."""
    worst = (0, "")
    for name, classes in ACTORS.items():
        try:
            tree = ast.parse(find(name).read_text())
        except FileNotFoundError:
            continue
        for c in tree.body:
            if isinstance(c, ast.ClassDef) and (classes is None or c.name in classes):
                for m in c.body:
                    if isinstance(m, ast.FunctionDef) and m.name != "__init__":
                        a = m.args
                        n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) - (a.args[:1] and a.args[0].arg == "self")
                        worst = max(worst, (n, f"{c.name}.{m.name}"))
    return {"max": worst[0], "where": worst[1]}


def ground_modules_at_start() -> int:
    daemon_module = "companion.onboard.daemon" if (ROOT / "companion" / "onboard").exists() else "companion.daemon"
    code = (f"import sys, importlib; importlib.import_module('companion.cli'); importlib.import_module({daemon_module!r}); "
            "ground = ('review', 'campaign', 'calibrate', 'flightlogs', 'demo', 'baselines', 'flights', 'ground'); "
            "print(sum(1 for m in sys.modules if m.startswith('companion') and any(g in m for g in ground)))")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                       env={"PYTHONPATH": str(ROOT), "PATH": ""})
    return int(r.stdout.strip() or -1)


daemon = find("daemon.py")
print(json.dumps({
    "root": str(ROOT), "cycle_py_lines": lines("cycle.py"), "daemon_py_lines": lines("daemon.py"),
    "supervisor_decide_lines": decide_lines(), "daemon_mode_string_tests": mode_string_tests(),
    "outbox_apply_call_sites_in_daemon": calls_in(daemon, "apply"),
    "direct_sends_in_daemon": direct_sends(daemon), "actor_method_params": actor_params(),
    "ground_modules_loaded_by_the_daemons_start": ground_modules_at_start(),
}, indent=1))
