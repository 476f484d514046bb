"""Issue 13 item 11, against a real MAVProxy (1.8.75): the daemon's STATUSTEXT reaches MAVProxy's console
through the SITL's routing when MAVProxy runs as docs/sitl.md says (`--target-system 1 --target-component 0`),
and — the cause of the report — does not with MAVProxy's default target (the autopilot's 1:1).

Slow, and skipped without MAVProxy: `pip install MAVProxy` (a scratch venv is fine) and point `CG_MAVPROXY`
at its `mavproxy.py`, or have `mavproxy.py` on PATH."""

import os
import shutil
import subprocess
import sys
import time

import pytest
import yaml
from sitl_process import ROOT, sitl_process

MAVPROXY = os.environ.get("CG_MAVPROXY") or shutil.which("mavproxy.py")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not MAVPROXY, reason="MAVProxy not installed (set CG_MAVPROXY to its mavproxy.py)")]
REFUSAL = "CG: refusing to engage: no configured sensor looks forward"


def console_of_mavproxy(tmp_path, extra: list[str]) -> str:
    with sitl_process("empty", "px4", 2.0) as port:
        cfg = {"vehicle": "mambo", "mode": "governor", "link": {"connect": f"udpout:127.0.0.1:{port}", "clock_rate": 2.0},
               # a sensor looking backwards: the start-up check refuses to engage and says so by STATUSTEXT
               "sensors": [{"kind": "distance_sensor", "h_fov_deg": 30, "max_range_m": 6, "orientation_deg": 180}],
               "log": {"dir": str(tmp_path / "log")}}
        (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
        d = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", tmp_path / "c.yaml", "--quiet"],
                             cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
        state = tmp_path / f"mavproxy{len(extra)}"
        state.mkdir()
        mp = subprocess.Popen([MAVPROXY, f"--master=udpout:127.0.0.1:{port}", f"--state-basedir={state}",
                               "--cmd=set param_ftp 0", *extra], cwd=state, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            time.sleep(25)  # MAVProxy connects, the daemon hears the autopilot and runs its start-up check
            out, _ = mp.communicate("status STATUSTEXT\n", timeout=30)
        finally:
            if mp.poll() is None:
                mp.kill()
            d.terminate()
            d.wait(15)
    return out


def test_mavproxy_console_prints_the_daemons_statustext_with_the_documented_target(tmp_path):
    out = console_of_mavproxy(tmp_path, ["--target-system", "1", "--target-component", "0"])
    assert "Detected vehicle 1:191" in out, out
    assert f"AP: {REFUSAL}" in out, out  # MAVProxy's console line for a STATUSTEXT


def test_mavproxy_default_target_hides_them(tmp_path):
    out = console_of_mavproxy(tmp_path, [])
    assert "Detected vehicle 1:191" in out, out
    assert f"AP: {REFUSAL}" not in out, out
