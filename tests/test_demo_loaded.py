"""`make demo` (`contract-guard demo`) on a loaded computer: the SITL and the daemon as real processes on loopback
UDP with two busy processes beside them (`python -c "while True: pass"` ×2). It exits 0 when the flight was safe and
within the contract, and says why it ended (about 90 s of wall time on a 2-core host: the demo flies in real time).

The demo runs the SITL and the daemon at SCHED_FIFO where the user may (the service unit's scheduling): on the
2-core build VM, already loaded by other jobs (load average 6-10), it passed 5 times in 5. Without real-time
scheduling single cycles there came later than the budget allows and it failed, as it should (docs/evidence.md,
the daemon's timeliness on a loaded computer).
Hence `-m slow`: the suite itself runs on every core, which is not the load this test names."""

import json
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_the_demo_is_safe_and_within_the_contract_with_two_busy_processes_beside_it(tmp_path):
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        run = subprocess.run([sys.executable, "-m", "companion.cli", "demo", "--out", str(tmp_path / "demo"), "--json"],
                             capture_output=True, text=True, timeout=900)
    finally:
        for b in busy:
            b.kill()
            b.wait()
    r = json.loads(run.stdout)
    assert r["safe"] and r["collisions"] == 0
    assert r["flight_end"] is not None and r["flight_end"]["why"] == "route complete", r["flight_end"]
    assert r["route_progress_m"] >= r["route_length_m"] - 1.0
    assert run.returncode == 0, r["review_findings"]
