"""Issue 13 item 8: long table builds are checkpointed and resumable, and show progress only to a person.

An interrupted `table build` / `table etr` (SIGINT as from Ctrl-C, SIGTERM as from systemd or a CI timeout)
exits 130 with one line, keeps its finished tasks in `<out>.partial/`, refuses to start over that checkpoint
without `--resume`, and `--resume` gives exactly the arrays of an uninterrupted build. Real solves (IPOPT) and
real SITL flights, in subprocesses; on the old code there was no checkpoint and no `--resume` (both fail)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
VEHICLE = ROOT / "examples" / "vehicles" / "quad-1600g.yaml"
# the shipped small grid (examples/vehicles/grid-small.yaml) at half its ρ cells and two tilts: 16 cells, 8 tasks
GRID_YAML = ("rho: {min: 0.02, max: 0.9, n: 4, spacing: geometric}\ntilt_deg: {min: 10, n: 2}\n"
             "thrust_ratio: {n: 2}\nn_intervals: 20\nstarts: 1\nchunk: 2\n")


def _as_foreground_job():
    """The child's SIGINT at its default, as a terminal's foreground job has it: a process started with SIGINT
    ignored keeps ignoring it (POSIX; Python then installs no KeyboardInterrupt), and a pytest worker of the
    suite on several workers was seen to pass an ignored SIGINT on."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # (a blocked signal mask is inherited too)


def cg(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "companion.cli", *map(str, args)], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_as_foreground_job, **kw)


def interrupt_when_checkpointed(args, partial: Path, sig, timeout_s: float = 300.0):
    """Start `args`, send `sig` once the first task is in the checkpoint; (returncode, stderr)."""
    p = cg(*args)
    deadline = time.time() + timeout_s
    while time.time() < deadline and p.poll() is None and not list(partial.glob("task-*.pkl")):
        time.sleep(0.05)
    assert p.poll() is None, f"the build ended before it could be interrupted: {p.communicate()}"
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    return p.returncode, err


def arrays(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files if k != "metadata_json"}


def assert_same_arrays(a: Path, b: Path) -> None:
    x, y = arrays(a), arrays(b)
    assert sorted(x) == sorted(y)
    for k in x:
        assert np.array_equal(x[k], y[k]), k


def finished(args) -> dict:
    r = subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args), "--json"], check=False, cwd=ROOT, env=ENV,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "it/s" not in r.stderr and "cells/s" not in r.stderr and "%|" not in r.stderr  # no bar off a terminal
    return json.loads(r.stdout)


def test_interrupted_avoid_build_resumes_to_the_same_table(tmp_path):
    out, grid = tmp_path / "quad.npz", tmp_path / "grid.yaml"
    grid.write_text(GRID_YAML)
    build = ["table", "build", "--vehicle", VEHICLE, "--grid", grid, "--out", out, "--workers", "2"]
    rc, err = interrupt_when_checkpointed(build, tmp_path / "quad.npz.partial", signal.SIGINT)
    assert rc == 130, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines[-1].startswith("contract-guard: interrupted after") and "--resume" in lines[-1], err
    assert "Traceback" not in err
    assert not out.exists() and (tmp_path / "quad.npz.partial" / "key.json").exists()
    # over a checkpoint, a build without --resume refuses in one line instead of silently starting again
    r = subprocess.run([sys.executable, "-m", "companion.cli", *map(str, build)], check=False, cwd=ROOT, env=ENV,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--resume" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    resumed = finished([*build, "--resume"])
    assert resumed["resumed_cells"] > 0
    assert not (tmp_path / "quad.npz.partial").exists()  # removed once the table is written
    ref = tmp_path / "ref.npz"
    fresh = finished(["table", "build", "--vehicle", VEHICLE, "--grid", grid, "--out", ref, "--workers", "2"])
    assert fresh["resumed_cells"] == 0
    assert_same_arrays(out, ref)


def test_a_checkpoint_of_another_grid_is_refused(tmp_path):
    from contracts.errors import ContractError
    from contracts.runner import Checkpoint

    Checkpoint(tmp_path / "t.npz", {"grid": 1}, resume=False)
    with pytest.raises(ContractError, match="another vehicle, grid or table"):
        Checkpoint(tmp_path / "t.npz", {"grid": 2}, resume=True)
    assert Checkpoint(tmp_path / "t.npz", {"grid": 1}, resume=True).load(3) == {}


def test_interrupted_etr_sweep_resumes_to_the_same_controller_contract(tmp_path):
    """SIGTERM this time, in-process (--workers 1): three columns of SITL flights on the shipped x500 table."""
    grid = tmp_path / "etr.yaml"
    grid.write_text("v_max: [2.0]\ntilt_deg: [30]\nthrust_ratio: [0.7, 0.85, 1.0]\nrhos: [0.35]\nseeds: [0]\n")
    out = tmp_path / "x500-etr.npz"
    etr = ["table", "etr", "--table", "x500", "--grid", grid, "--out", out, "--workers", "1"]
    rc, err = interrupt_when_checkpointed(etr, tmp_path / "x500-etr.npz.partial", signal.SIGTERM)
    assert rc == 130 and "interrupted after 1 of 3 cells" in err and "Traceback" not in err, err
    resumed = finished([*etr, "--resume"])
    assert resumed["resumed_cells"] == 1
    ref = tmp_path / "ref.npz"
    finished(["table", "etr", "--table", "x500", "--grid", grid, "--out", ref, "--workers", "1"])
    assert_same_arrays(out, ref)


def test_a_progress_bar_on_a_terminal(tmp_path):
    """On a terminal (a pty of 24×100) `table etr` draws its tqdm bar on stderr, and still ends in one line."""
    import fcntl
    import pty
    import struct
    import termios

    grid = tmp_path / "etr.yaml"
    grid.write_text("v_max: [2.0]\ntilt_deg: [30]\nthrust_ratio: [0.7, 1.0]\nrhos: [0.35]\nseeds: [0]\n")
    pid, fd = pty.fork()
    if pid == 0:  # the child: a terminal of 24 rows and 100 columns, as a person's
        fcntl.ioctl(0, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
        os.chdir(ROOT)
        os.execve(sys.executable, [sys.executable, "-m", "companion.cli", "table", "etr", "--table", "x500", "--grid",
                                   str(grid), "--out", str(tmp_path / "t.npz"), "--workers", "1"], ENV)
    out = b""
    while True:
        try:
            chunk = os.read(fd, 65536)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    _, status = os.waitpid(pid, 0)
    text = out.decode(errors="replace")
    assert os.waitstatus_to_exitcode(status) == 0, text
    assert "E_tr cells: 100%" in text and "2/2" in text, text
    assert text.replace("\r", "\n").strip().splitlines()[-1].startswith("wrote E_tr_pred into"), text
