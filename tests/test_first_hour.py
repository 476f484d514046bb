"""A drone engineer's first hour (issue 13): no silent, optimistic defaults. A table without the
controller contract does not fly on the E_tr floor alone; a config must name its vehicle and, to govern
or fly, its sensors; a wrong table never starts the daemon in any mode."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from contracts.table import load_for_vehicle, verify, write_table
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly

ROOT = Path(__file__).resolve().parents[1]


def cg(*args, **kw):
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=120, **kw)


@pytest.fixture(scope="module")
def no_etr_table(tmp_path_factory):
    """The shipped Mambo avoid table without its controller contract (as `table build` alone writes it)."""
    t = load_for_vehicle("mambo")
    path = tmp_path_factory.mktemp("tables") / "mambo-no-etr.npz"
    write_table(path, t.vehicle, tilt_model=t.meta["tilt_model"], avoid=t.avoid)
    return path


def governed(table_path, **contract):
    rig = Rig(column_scenario(1, x_col=400.0), "px4", table_wrapper=lambda t: verify(table_path, t.vehicle),
              config={"contract": contract} if contract else None)
    fly(rig, 8.0)
    return rig


def test_a_table_without_the_controller_contract_refuses_to_engage(no_etr_table):
    rig = governed(no_etr_table)
    checks = rig.log.named("startup_check")
    assert checks and checks[0]["ok"] is False and "no controller contract" in checks[0]["reason"]
    assert all(s["v_cmd"] is None and not s["engaged"] for s in rig.log.states)
    assert not [e for e in rig.log.named("command") if e["cmd"] == "change_speed"]
    assert any("refusing to engage" in t and "controller contract" in t for t in rig.daemon_texts())


def test_a_stated_e_tr_assumption_flies_with_it_and_never_below(no_etr_table):
    rig = governed(no_etr_table, e_tr_assumed_m=1.0)
    flown = [s for s in rig.log.states if s["v_cmd"]]
    assert flown and min(s["e_tr"] for s in flown) >= 1.0 - 1e-9
    stock = governed(ROOT / "contracts" / "data" / "mambo.npz")  # the same flight on the E_tr floor (0.3 m)
    v_stock = max(s["v_cmd"] or 0 for s in stock.log.states)
    assert max(s["v_cmd"] for s in flown) < v_stock  # the stated, larger E_tr costs speed


def test_table_show_and_query_say_when_the_controller_contract_is_missing(no_etr_table):
    shown = cg("table", "show", no_etr_table)
    assert shown.returncode == 0 and "controller contract (E_tr_pred): NONE" in shown.stdout
    assert json.loads(cg("table", "show", no_etr_table, "--json").stdout)["controller_contract"] is False
    q = cg("table", "query", no_etr_table, "--d-od", 6, "--r-obst", 1, "--e-tr", 0.3, "--thrust-ratio", 1)
    assert q.returncode == 0 and "no controller contract" in q.stdout
    shipped = json.loads(cg("table", "show", ROOT / "contracts" / "data" / "x500.npz", "--json").stdout)
    assert shipped["controller_contract"] is True


@pytest.mark.parametrize("config,needle", [
    ({"mode": "governor", "sensors": [{"h_fov_deg": 30, "max_range_m": 8}]}, "which aircraft"),
    ({"mode": "shadow"}, "which aircraft"),
    ({"vehicle": "x500", "mode": "governor"}, "sensors: at least one obstacle sensor"),
    ({"vehicle": "x500", "mode": "offboard", "route": {"waypoints": [[0, 0], [10, 0]]},
      "sensors": [{"h_fov_deg": 60}]}, "max_range_m"),
    ({"vehicle": "x500", "table": str(ROOT / "contracts" / "data" / "mambo.npz"), "mode": "shadow"},
     "built for another vehicle"),
])
def test_run_refuses_what_it_would_otherwise_assume_in_one_line(config, needle, tmp_path):
    """Silent defaults are gone: no vehicle, no sensors, no rated range, another vehicle's table. A wrong
    table ends the daemon in shadow mode too (exit 2, which the systemd unit does not restart)."""
    p = tmp_path / "cg.yaml"
    p.write_text(yaml.safe_dump({**config, "link": {"connect": "udpin:127.0.0.1:0"}, "log": {"dir": str(tmp_path)}}))
    r = cg("run", "--config", p, stdin=subprocess.DEVNULL)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and needle in lines[0], r.stderr


def test_the_service_unit_does_not_restart_a_configuration_error():
    unit = (ROOT / "systemd" / "contract-guard.service").read_text()
    assert "RestartPreventExitStatus=2" in unit


def test_the_service_runs_at_the_priority_the_flood_benchmark_measures():
    """The loop keeps its period on a loaded host only at a raised priority; benchmarks/bench_daemon.py runs the daemon
    at the unit's Nice= and SCHED_FIFO priority by default, so the two cannot drift."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_daemon", ROOT / "benchmarks" / "bench_daemon.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert int(bench.unit_setting("Nice", "0")) < 0 and "RestrictRealtime=yes" in bench.UNIT.read_text()
    assert bench.unit_setting("CPUSchedulingPolicy", "other") == "fifo" and bench.FIFO > 0


def test_a_second_daemon_on_the_same_udp_port_is_refused(tmp_path):
    import socket
    import time

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    p = tmp_path / "cg.yaml"
    p.write_text(yaml.safe_dump({"vehicle": "mambo", "mode": "shadow", "link": {"connect": f"udpin:127.0.0.1:{port}"},
                                 "log": {"dir": str(tmp_path / "log")}}))
    first = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(p)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        banner = []
        while len(banner) < 20 and not any("waiting for the autopilot" in ln for ln in banner):
            banner.append(first.stdout.readline())
        assert any("waiting for the autopilot" in ln for ln in banner), banner
        time.sleep(0.5)
        second = cg("run", "--config", p, stdin=subprocess.DEVNULL)
        lines = [ln for ln in second.stderr.splitlines() if ln.strip()]
        assert second.returncode == 2 and len(lines) == 1 and "port is taken" in lines[0], second.stderr
        assert first.poll() is None  # the first one runs on
    finally:
        first.terminate()
        first.wait(30)
