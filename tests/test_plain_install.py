"""Issue 13 item 10: a plain `pip install` works. The built wheel, installed without extras into a fresh
venv in another directory, answers `--help`, `table query x500` by shipped name (and the README's
`contracts/data/mambo.npz` path) and flies `demo` to a summary (the plot skipped with one line naming the
extra when matplotlib is missing); commands that need an extra say which, in one line, before any work."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_tables_by_shipped_name_from_any_directory(tmp_path):
    env_cwd = dict(cwd=tmp_path, capture_output=True, text=True, timeout=120)
    for name in ("x500", "contracts/data/mambo.npz", "mambo.npz"):
        r = subprocess.run([sys.executable, "-m", "companion.cli", "table", "query", name, "--d-od", "6", "--r-obst", "1",
                            "--e-tr", "0.3", "--thrust-ratio", "0.8"], env={"PYTHONPATH": str(ROOT), "PATH": ""},
                           **env_cwd)
        assert r.returncode == 0 and "contract: V_max" in r.stdout, (name, r.stderr)


@pytest.mark.slow
def test_the_wheel_without_extras_runs_the_first_commands(tmp_path):
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", dist, ROOT], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", venv], check=True, timeout=300)
    py = venv / "bin" / "python"
    wheel = next(dist.glob("contract_guard-*.whl"))
    r = subprocess.run([py, "-m", "pip", "install", "-q", wheel], capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-2000:]
    cg = venv / "bin" / "contract-guard"
    work = tmp_path / "elsewhere"
    work.mkdir()

    def run(*args, timeout=300):
        return subprocess.run([cg, *map(str, args)], cwd=work, capture_output=True, text=True, timeout=timeout)

    assert run("--help").returncode == 0
    q = run("table", "query", "x500", "--d-od", "6", "--r-obst", "1", "--e-tr", "0.3", "--thrust-ratio", "0.8")
    assert q.returncode == 0 and "V_max" in q.stdout, q.stderr
    b = run("table", "build", "--vehicle", "mambo", "--out", "m.npz")
    assert b.returncode == 2 and "contract-guard[build]" in b.stderr and "Traceback" not in b.stderr
    d = run("demo", "--duration", "20", "--speedup", "4", timeout=900)
    assert "contract-guard demo" in d.stdout and "Traceback" not in d.stderr, d.stderr[-2000:]
    assert "contract-guard[plot]" in d.stdout or "plot:" in d.stdout
