"""Start the SITL as a separate process on a free loopback UDP port (for the UDP smoke tests)."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def sitl_process(scenario: str = "empty", personality: str = "px4", speedup: float = 1.0, extra=()):
    port = free_udp_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "sitl_harness", "--scenario", scenario, "--personality", personality,
           "--listen", f"udp:127.0.0.1:{port}", "--speedup", str(speedup), *extra]
    proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        import selectors

        sel = selectors.DefaultSelector()
        sel.register(proc.stderr, selectors.EVENT_READ)
        ready = sel.select(timeout=120.0)  # first start may compile the numba kernel
        sel.close()
        line = proc.stderr.readline() if ready else "(no output within 120 s)"
        if "listening" not in line:  # "SITL px4 listening on 127.0.0.1:PORT" once bound
            proc.kill()
            raise RuntimeError(f"SITL did not start: {line}{proc.stderr.read()}")
        yield port
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stderr.close()
        proc.stdout.close()
        time.sleep(0.05)
