"""Config values that switch a failsafe off are refused (one line naming the key, exit 2 from `run`); a value
inside its safe range but weaker than the default is named in the start banner."""

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from companion.onboard.config import config_from_dict, load_config, weakened
from contracts.errors import ContractError

ROOT = Path(__file__).resolve().parents[1]

# (key path, a value outside its safe range): the review's values first
OUTSIDE = [
    (("timeouts", "obstacle_s"), 1e9), (("timeouts", "cycle_late_s"), 1e9), (("loop_hz",), 0.2),
    (("timeouts", "heartbeat_s"), 60.0), (("timeouts", "telemetry_s"), 10.0), (("timeouts", "nav_s"), 30.0),
    (("timeouts", "cycle_jitter_s"), 0.5), (("loop_hz",), 19.0), (("speed_overshoot", "base_m_s"), 5.0), (("speed_overshoot", "fraction"), 0.9),
    (("contract", "dwell_s"), 0.0), (("contract", "e_tr_window_s"), 0.1), (("contract", "late_detection_hold_s"), 0.0),
    (("contract", "late_detection_tolerance_m"), 10.0), (("contract", "e_tr_floor_m"), 1e6),
    (("thrust", "tau_s"), 1e9), (("contract", "r_obst_m"), 0.05),
]


def _nest(path, value, base=None):
    d = dict(base or {})
    cur = d
    for k in path[:-1]:
        cur = cur.setdefault(k, {})
    cur[path[-1]] = value
    return d


@pytest.mark.parametrize("path,value", OUTSIDE, ids=[".".join(p) for p, _ in OUTSIDE])
def test_a_value_outside_its_safe_range_is_refused_naming_the_key(path, value):
    with pytest.raises(ContractError) as e:
        config_from_dict(_nest(path, value))
    msg = str(e.value)
    assert "\n" not in msg and path[-1] in msg, msg


def test_r_obst_m_must_lie_inside_its_own_range():
    with pytest.raises(ContractError, match=r"r_obst_m: 0.3 m is outside r_obst_range_m \(0.5-2 m\)"):
        config_from_dict({"contract": {"r_obst_m": 0.3, "r_obst_range_m": [0.5, 2.0]}})
    with pytest.raises(ContractError, match="not a range"):
        config_from_dict({"contract": {"r_obst_m": 1.0, "r_obst_range_m": [2.0, 0.5]}})
    config_from_dict({"contract": {"r_obst_m": 0.5, "r_obst_range_m": [0.5, 2.0]}})


@pytest.mark.parametrize("value", ["1e9", "0.2"])
def test_run_exits_2_with_one_line(tmp_path, value):
    cfg = tmp_path / "cg.yaml"
    key = "timeouts: {obstacle_s: %s}" % value if value == "1e9" else "loop_hz: %s" % value
    cfg.write_text(f"vehicle: mambo\n{key}\nlog: {{dir: {tmp_path / 'log'}}}\n")
    r = subprocess.run([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg)], capture_output=True,
                       text=True, cwd=str(ROOT), timeout=60)
    assert r.returncode == 2, r.stdout + r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert ("obstacle_s" if value == "1e9" else "loop_hz") in r.stderr


def test_the_shipped_examples_load():
    for f in sorted((ROOT / "examples").glob("*.yaml")):
        if not f.name.startswith("campaign-"):
            load_config(f)


def test_weakened_names_each_weaker_value_and_nothing_at_the_defaults():
    assert weakened(config_from_dict({})) == []
    stronger = config_from_dict({"timeouts": {"obstacle_s": 0.2, "heartbeat_s": 1.0}, "loop_hz": 100,
                                 "contract": {"dwell_s": 5.0, "e_tr_floor_m": 0.5}})
    assert weakened(stronger) == []
    weak = config_from_dict({"timeouts": {"obstacle_s": 1.5, "cycle_late_s": 0.8}, "loop_hz": 25,
                             "contract": {"dwell_s": 0.5, "r_obst_range_m": [0.05, 10.0]},
                             "thrust": {"source": "configured", "value": 0.9}})
    lines = "\n".join(weakened(weak))
    for key in ("timeouts.obstacle_s 1.5", "timeouts.cycle_late_s 0.8", "loop_hz 25", "contract.dwell_s 0.5",
                "r_obst_range_m from 0.05", "thrust.source configured"):
        assert key in lines, lines
    assert len(weakened(weak)) == 6


@pytest.mark.parametrize("mode", ["governor", "offboard"])
def test_unsigned_network_link_in_governor_or_offboard_refuses_unless_accepted_by_name(mode):
    """Secure by default: over a network link (not loopback, not serial) a commanding mode refuses to engage
    unsigned (one line, the start-up checks' reason); `link.accept_unsigned: true` engages, WEAKENED in the
    banner. Before, it engaged unsigned with a warning only."""
    from companion.onboard.startup import unsigned_refusal

    sensors = [{"h_fov_deg": 30, "max_range_m": 10}]
    net = {"mode": mode, "sensors": sensors, "link": {"connect": "udpin:0.0.0.0:14540"}}
    if mode == "offboard":
        net["route"] = {"waypoints": [[0, 0], [20, 0]], "altitude_m": 5}
    why = unsigned_refusal(config_from_dict(net))
    assert why is not None and f"{mode} mode engages only with signing" in why and "accept_unsigned" in why
    accepted = {**net, "link": {**net["link"], "accept_unsigned": True}}
    assert unsigned_refusal(config_from_dict(accepted)) is None
    assert any(x.startswith("WEAKENED link.accept_unsigned") for x in weakened(config_from_dict(accepted)))
    quiet = [{**net, "mode": "shadow"}, {**net, "link": {"connect": "/dev/ttyAMA0"}},
             {**net, "link": {"connect": "udpout:127.0.0.1:14540"}}, {**net, "link": {"connect": "udpin:127.0.0.1:14540"}},
             {**net, "link": {"connect": "udpin:0.0.0.0:14540", "signing_key_file": "/etc/cg/key"}}]
    for q in quiet:
        if q["mode"] == "shadow":
            q = {k: v for k, v in q.items() if k != "route"}
        c = config_from_dict(q)
        assert unsigned_refusal(c) is None and not any("unsigned" in x for x in weakened(c)), q


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def daemon_output_until(cfg: Path, marker: str, timeout_s: float = 60.0) -> str:
    """`contract-guard run --config cfg` until a line with `marker` (or its end), then SIGTERM: what it printed."""
    p = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg)], cwd=str(ROOT),
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = []
    try:
        deadline = time.time() + timeout_s
        while time.time() < deadline:
            line = p.stdout.readline()
            if not line:
                break
            out.append(line)
            if marker in line:
                break
        p.send_signal(signal.SIGTERM)
        p.wait(30)
    finally:
        if p.poll() is None:
            p.kill()
    return "".join(out)


def test_the_start_banner_prints_the_weakened_values(tmp_path):
    port = free_udp_port()
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(yaml.safe_dump({
        "vehicle": "mambo", "mode": "governor", "link": {"connect": f"udpin:0.0.0.0:{port}"},
        "sensors": [{"h_fov_deg": 30, "max_range_m": 10}], "timeouts": {"obstacle_s": 1.5},
        "log": {"dir": str(tmp_path / "log")}}))
    text = daemon_output_until(cfg, "REFUSING TO ENGAGE")
    assert "timeouts.obstacle_s 1.5 (default 0.5)" in text, text
    assert "REFUSING TO ENGAGE: unsigned on the network link" in text, text
    assert "link: OPEN — first speaker" in text, text  # the banner says how the autopilot's seat is given


@pytest.mark.parametrize("accept", [False, True], ids=["refused", "accepted by name"])
def test_run_check_says_in_one_line_that_an_unsigned_network_link_refuses_to_engage(tmp_path, accept):
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(yaml.safe_dump({
        "vehicle": "mambo", "mode": "governor", "link": {"connect": "udpin:0.0.0.0:14540", "accept_unsigned": accept},
        "sensors": [{"h_fov_deg": 30, "max_range_m": 10}], "log": {"dir": str(tmp_path / "log")}}))
    r = subprocess.run([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg), "--check"],
                       capture_output=True, text=True, cwd=str(ROOT), timeout=120)
    assert r.returncode == 0, r.stderr
    refused = [ln for ln in r.stdout.splitlines() if "REFUSING TO ENGAGE" in ln]
    weak = [ln for ln in r.stdout.splitlines() if ln.startswith("WEAKENED link.accept_unsigned")]
    if accept:
        assert refused == [] and len(weak) == 1, r.stdout
    else:
        assert len(refused) == 1 and "unsigned on the network link udpin:0.0.0.0:14540" in refused[0], r.stdout
        assert weak == []


def test_the_banner_says_how_the_link_takes_the_autopilot():
    def line(link, sensors=({"h_fov_deg": 30, "max_range_m": 6},)):
        c = config_from_dict({"link": link, "sensors": list(sensors)})
        return c.link.seats(c.sensors)

    assert line({"connect": "udpin:0.0.0.0:14540", "autopilot_address": "192.168.1.10:14580"}) \
        .startswith("link: pinned to 192.168.1.10:14580")
    assert line({"connect": "udpin:127.0.0.1:14540"}).startswith("link: loopback only")
    assert line({"connect": "udpin:0.0.0.0:14540"}).startswith("link: OPEN — first speaker")
    own = [{"h_fov_deg": 30, "max_range_m": 6, "component_id": 158}]  # a sensor with ids of its own, no address
    assert "OPEN for sensors 1/158" in line({"connect": "udpin:0.0.0.0:14540", "autopilot_address": "10.0.0.2:1"}, own)
    assert line({"connect": "/dev/serial0"}).startswith("link: /dev/serial0")
