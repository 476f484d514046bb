"""The command line as a user runs it: a real process, its exit status, stdout and stderr."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from contracts.table import load_for_vehicle

ROOT = Path(__file__).resolve().parents[1]
MAMBO_TABLE = ROOT / "contracts" / "data" / "mambo.npz"


def cg(*args):
    return subprocess.run(
        [sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True, cwd=ROOT
    )


def test_table_show_json_has_the_documented_keys():
    r = cg("table", "show", MAMBO_TABLE, "--json")
    assert r.returncode == 0, r.stderr
    m = json.loads(r.stdout)
    for k in ("mass_kg", "t_nom_n", "r_body_m", "t_react_s"):
        assert k in m["vehicle"]
    assert m["tilt_model"] in ("cone", "box") and "axes" in m
    assert m["vehicle"]["mass_kg"] == 0.063


def test_table_query_json_keys_and_values():
    r = cg("table", "query", MAMBO_TABLE, "--d-od", 6, "--r-obst", 1, "--e-tr", 0.3, "--thrust-ratio", 0.8,
           "--contract", "stop", "--json")
    assert r.returncode == 0, r.stderr
    q = json.loads(r.stdout)
    for k in ("v_safe", "v_max", "tilt_deg", "e_tr", "gamma", "v_stop"):
        assert isinstance(q[k], float), k
    assert q["gamma"] <= 1e-9 and q["v_max"] <= q["v_stop"] + 1e-9
    # the E_tr_pred fixed point: V_max is v_stop itself, or the edge of E_tr_pred's speed cell where the next
    # cell's larger E_tr would give less (here 3.0 m/s, v_stop 3.04, since the rebuilt E_tr_pred of issue 19 item 9)
    speeds = load_for_vehicle("mambo").e_pred.axes[0]
    assert q["v_max"] == pytest.approx(q["v_stop"]) or min(abs(speeds - q["v_max"])) < 1e-9
    # Γ at a proposed speed: positive when faster than the contract allows
    r2 = cg("table", "query", MAMBO_TABLE, "--d-od", 6, "--r-obst", 1, "--e-tr", 0.3, "--thrust-ratio", 0.8,
            "--contract", "stop", "--v-max", q["v_max"] + 1, "--json")
    # at least 1: with E_tr_pred in the table the faster speed also predicts a larger E_tr (issue 6)
    assert json.loads(r2.stdout)["gamma"] >= 1.0 - 1e-6


@pytest.mark.parametrize(
    "args, needle",
    [
        (("table", "show", "/nonexistent/t.npz"), "no such file"),
        (("table", "verify", MAMBO_TABLE, "--vehicle", "x500"), "another vehicle"),
        (("table", "build", "--vehicle", "/nonexistent/v.yaml", "--out", "/tmp/x.npz", "--stop-only"), "cannot read"),
    ],
)
def test_user_errors_are_one_line_and_non_zero(args, needle):
    r = cg(*args)
    assert r.returncode != 0
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0]


def test_the_demos_daemon_logs_where_the_demo_reads_it_from_a_relative_out(tmp_path, monkeypatch):
    """`make demo` writes to ./demo-out: the daemon's config there must name the log the demo watches (a relative
    path in a config is the config file's directory's; the daemon once logged to demo-out/demo-out/log and the demo
    ended in "the daemon did not connect to the SITL")."""
    import yaml

    from companion.onboard.config import load_config
    from companion.ground.demo import daemon_config
    from sitl_harness.scenario import load_scenario

    monkeypatch.chdir(tmp_path)
    out = Path("demo-out")
    out.mkdir()
    (out / "daemon.yaml").write_text(yaml.safe_dump(daemon_config(load_scenario("fig17"), 14550, 2.0, "px4",
                                                                  out / "log")))
    assert Path(load_config(out / "daemon.yaml").log.dir) == tmp_path / "demo-out" / "log"


def test_the_demo_reads_its_childrens_output_as_it_comes():
    """A child that writes more than a pipe holds (64 KiB) before it ends is not blocked by the demo, which keeps
    its last line (the SITL's summary, the daemon's reason for stopping)."""
    import subprocess
    import sys

    from companion.ground.demo import _Tail

    child = subprocess.Popen([sys.executable, "-c", "import sys\nfor k in range(4000): print('x' * 60, k, "
                              "file=sys.stderr)\nprint('the last word', file=sys.stderr)"],
                             stderr=subprocess.PIPE, text=True)
    tail = _Tail(child.stderr)
    assert child.wait(timeout=30) == 0  # blocked for ever on a full pipe if nothing read it
    assert tail.last() == "the last word"


@pytest.mark.slow
def test_demo_flies_the_in_flight_scenario_safely(tmp_path):
    """`contract-guard demo`: SITL and daemon as processes on loopback UDP (about a minute)."""
    r = cg("demo", "--out", tmp_path / "demo", "--json")
    out = json.loads(r.stdout)
    assert r.returncode == (0 if out["verdict"] == "SAFE" else 1)  # one verdict: the exit status, the summary's
    assert out["verdict"] == ("SAFE" if out["safe"] and out["review_ok"] else "NOT SAFE" if not out["safe"]
                              else "REVIEW NEEDED")
    assert json.loads((tmp_path / "demo" / "review" / "review.json").read_text())["ok"] is out["review_ok"]
    assert out["collisions"] == 0 and out["min_clearance_m"] > 0
    assert out["planning"]["answers"] > 0  # the daemon's account of its planning, from its event log
    assert (tmp_path / "demo" / "log" / "events.jsonl").exists() and (tmp_path / "demo" / "review" / "review.png").exists()


def test_a_stop_only_table_says_so(tmp_path):
    out = tmp_path / "stop.npz"
    r = cg("table", "build", "--vehicle", "mambo", "--out", out, "--stop-only")
    assert r.returncode == 0, r.stderr
    shown = json.loads(cg("table", "show", out, "--json").stdout)
    assert shown["available"] == ["stop"] and "stop contract only" in shown["note"]
    r = cg("table", "query", out, "--d-od", 6, "--r-obst", 1, "--e-tr", 0.3, "--thrust-ratio", 0.8, "--contract", "avoid")
    assert r.returncode != 0 and "no avoid contract" in r.stderr and "Traceback" not in r.stderr
    q = json.loads(cg("table", "query", out, "--d-od", 6, "--r-obst", 1, "--e-tr", 0.3, "--thrust-ratio", 0.8,
                      "--json").stdout)
    assert q["contract"] == "stop"
