"""How the demo runs the SITL and the daemon: SCHED_FIFO at the service unit's priority where the user may, else the
default, said on its console (`companion/ground/demo.py` `_scheduling`)."""

import os
import re
from pathlib import Path

from companion.ground import demo

UNIT = Path(__file__).resolve().parents[1] / "systemd" / "contract-guard.service"


def test_the_demo_asks_for_the_units_priority_and_says_so_when_refused(monkeypatch):
    assert f"CPUSchedulingPriority={demo.FIFO_PRIORITY}\n" in UNIT.read_text()
    asked = []
    monkeypatch.setattr(os, "sched_setscheduler", lambda pid, policy, param: asked.append((pid, policy, param)))
    setup, said = demo._scheduling()
    assert callable(setup) and f"SCHED_FIFO {demo.FIFO_PRIORITY}" in said
    assert asked[0][1] == os.SCHED_FIFO | os.SCHED_RESET_ON_FORK and asked[-1][1] == os.SCHED_OTHER  # given back
    setup()
    assert asked[-1] == (0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(demo.FIFO_PRIORITY))

    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    setup, said = demo._scheduling()
    assert setup is None and re.search(r"default priority: SCHED_FIFO is not permitted .*Operation not permitted", said)


def test_the_console_says_how_the_demo_ran():
    r = {"scenario": "fig17", "collisions": 0, "min_clearance_m": 0.5, "violations": 0, "failsafes": 0,
         "mean_speed_m_s": 4.0, "max_speed_m_s": 6.0, "route_progress_m": 270, "route_length_m": 270,
         "v_max_steps": [], "scheduling": "SITL and daemon at SCHED_FIFO 50, as the service unit runs the daemon",
         "event_log": "log/events.jsonl", "review_ok": True, "review": "review.json", "review_findings": [],
         "verdict": "SAFE", "safe": True}
    assert "  scheduling: SITL and daemon at SCHED_FIFO 50" in demo.format_summary(r)
    assert "planning" not in demo.format_summary(r)  # governor mode, or no obstacle: no plan was waited for
    r["planning"] = {"answers": 12, "first_s": 0.04, "median_s": 0.02, "max_s": 0.2}
    assert ("  planning: 12 plans waited for; the first 0.04 s after it was asked, median 0.02 s, slowest 0.20 s "
            "(vehicle time)") in demo.format_summary(r)
