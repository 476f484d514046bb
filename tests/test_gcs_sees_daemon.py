"""Issue 13 item 11: the daemon's STATUSTEXTs reach a ground station through the SITL's routing, as component
1:191 — and why MAVProxy's console did not print them: MAVProxy prints a STATUSTEXT only from its target
(system, component), which it takes from the autopilot's HEARTBEAT (1:1), unless started with
`--target-component 0` (docs/sitl.md). The rule is `LinkModule.message_is_from_primary_vehicle` in MAVProxy's
`modules/mavproxy_link.py`; `shown_by_mavproxy` below is that rule."""

import os
import subprocess
import sys
import time

import yaml
from pymavlink import mavutil

from sitl_process import ROOT, sitl_process


def shown_by_mavproxy(m, target_system: int, target_component: int) -> bool:
    return (target_system in (0, m.get_srcSystem())) and (target_component in (0, m.get_srcComponent()))


def test_the_daemons_statustext_reaches_a_ground_station_through_the_sitl(tmp_path):
    with sitl_process("empty", "px4", 2.0) as port:
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        cfg = {"vehicle": "mambo", "mode": "governor", "link": {"connect": f"udpout:127.0.0.1:{port}", "clock_rate": 2.0},
               # a sensor looking backwards: the start-up check refuses to engage and says so by STATUSTEXT
               "sensors": [{"kind": "distance_sensor", "h_fov_deg": 30, "max_range_m": 6, "orientation_deg": 180}],
               "log": {"dir": str(tmp_path / "log")}}
        (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        d = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", tmp_path / "c.yaml", "--quiet"],
                             cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        texts, hb = [], 0.0
        try:
            deadline = time.time() + 60
            while time.time() < deadline and not any("forward" in t for _, t in texts):
                if time.time() - hb > 1.0:
                    gcs.mav.heartbeat_send(6, 8, 0, 0, 0)  # a ground station: the SITL routes to known clients
                    hb = time.time()
                m = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=0.2)
                if m is not None:
                    texts.append((m, m.text))
        finally:
            d.terminate()
            d.wait(15)
            gcs.close()
    mine = [(m, t) for m, t in texts if (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)]
    joined = " ".join("".join(t for _, t in mine).split())  # chunks end at words, padded to 50 bytes with spaces
    assert "CG: refusing to engage: no configured sensor looks forward" in joined
    refusal = next(m for m, t in mine if "refusing" in t)
    assert refusal.severity <= mavutil.mavlink.MAV_SEVERITY_ERROR  # shown in red by ground stations
    # MAVProxy with its default target (the autopilot's 1:1) drops them; with --target-component 0 it shows them
    assert not any(shown_by_mavproxy(m, 1, 1) for m, _ in mine)
    assert all(shown_by_mavproxy(m, 1, 0) for m, _ in mine)


def test_sitl_help_names_its_scenarios_and_the_recipe_config_matches_it():
    from companion.onboard.config import load_config

    r = subprocess.run([sys.executable, "-m", "companion.cli", "sitl", "--help"], cwd=ROOT, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and "usage: contract-guard sitl" in r.stdout
    out = " ".join(r.stdout.split())
    assert "column_ahead" in out and "default: empty" in out and "mission" in out
    cfg = load_config(ROOT / "examples" / "sitl-px4.yaml")
    assert cfg.link.connect == "udpout:127.0.0.1:14540"  # docs/sitl.md: the SITL listens on udp:127.0.0.1:14540
