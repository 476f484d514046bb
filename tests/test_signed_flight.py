"""A signed flight end to end, over real UDP with separate processes: `contract-guard keys` makes the key, the
SITL (`--signing-key-hex`) signs as the autopilot, the daemon (`link.signing_key_file`) in governor mode over a
network link, and the shipped ground station (`examples/ground_station.py --signing-key FILE`) arms, takes off,
starts the mission and sets CG_ENGAGE 1 — every message signed. Secure by default: the same flight without the
daemon's key refuses to engage (negative control); with a wrong key the daemon says "signature mismatch … wrong
key?" at once (console and event log), not only "no heartbeat"."""

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), MAVLINK20="1")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cg(*args, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "companion.cli", *map(str, args)], cwd=kw.pop("cwd", ROOT),
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def make_key(d: Path) -> tuple[Path, str]:
    r = subprocess.run([sys.executable, "-m", "companion.cli", "keys", str(d), "--json"], env=ENV, cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    key = d / "mavlink-signing.key"
    return key, key.read_text().strip()


def fly(tmp_path: Path, daemon_key: Path | None, sitl_hex: str | None, gcs_key: Path | None, seconds: float = 20.0,
        wait_s: float = 30.0, **link_options) -> dict:
    """The SITL listening on all interfaces, the daemon reaching it over the network link udpout:0.0.0.0:PORT (not
    the loopback: signing is required there), and the ground station; what each said."""
    port = free_port()
    cfg = tmp_path / "cg.yaml"
    link = {"connect": f"udpout:0.0.0.0:{port}", "autopilot": "px4", **link_options}
    if daemon_key is not None:
        link.update(signing_key_file=str(daemon_key), signing_timestamp_file=str(tmp_path / "signing.ts"))
    cfg.write_text(yaml.safe_dump({"vehicle": "mambo", "mode": "governor", "engage": False, "link": link,
                                   "sensors": [{"kind": "distance_sensor", "h_fov_deg": 30, "max_range_m": 6}],
                                   "log": {"dir": str(tmp_path / "log")}}))
    sitl = cg("sitl", "--personality", "px4", "--listen", f"udp:0.0.0.0:{port}", "--scenario", "column_ahead",
              *(["--signing-key-hex", sitl_hex] if sitl_hex else []))
    assert "listening" in sitl.stderr.readline()
    daemon = cg("run", "--config", cfg)
    try:
        gcs = subprocess.run([sys.executable, str(ROOT / "examples" / "ground_station.py"), "--connect",
                              f"udpout:127.0.0.1:{port}", *(["--signing-key", str(gcs_key)] if gcs_key else []),
                              "--seconds", str(seconds), "--wait-s", str(wait_s)], env=ENV, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    finally:
        daemon.send_signal(signal.SIGTERM)
        console, derr = daemon.communicate(timeout=30)
        sitl.send_signal(signal.SIGINT)
        sitl_out, sitl_err = sitl.communicate(timeout=30)
    log = tmp_path / "log" / "events.jsonl"
    events = [json.loads(ln) for ln in log.read_text().splitlines() if ln.strip()] if log.exists() else []
    return {"gcs": gcs.stdout + gcs.stderr, "console": console + derr, "events": events, "sitl": sitl_out + sitl_err}


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    d = tmp_path_factory.mktemp("keys")
    right, right_hex = make_key(d / "right")
    wrong, _ = make_key(d / "wrong")
    return right, right_hex, wrong


def test_a_signed_flight_with_the_shipped_ground_station_engages_and_holds_at_the_column(keys, tmp_path):
    right, right_hex, _ = keys
    f = fly(tmp_path, right, right_hex, right)
    for step in ("(signed)", "arm: accepted", "mode mission: accepted", "param set CG_ENGAGE 1: echoed 1",
                 "1:191 says: CG: active (limit in force)", "1:191 says: CG: holding"):
        assert step in f["gcs"], (step, f["gcs"])
    assert "mismatch" not in f["gcs"] + f["console"] and "REFUSING" not in f["console"]
    assert "start-up checks: ok" in f["console"], f["console"]
    acks = [e for e in f["events"] if e.get("event") == "command_ack" and e.get("command") == 178 and e["result"] == 0]
    assert acks, "the speed limit, signed, acknowledged by the signed autopilot"
    stop = next(e for e in f["events"] if e.get("event") == "stop")
    assert stop["counters"]["rejected_signature"] == 0


@pytest.mark.parametrize("accepted", [False, True], ids=["unsigned: refused", "link.accept_unsigned"])
def test_the_same_flight_unsigned_on_the_network_link_engages_only_when_accepted_by_name(tmp_path, accepted):
    """Negative control: the same flight with no key anywhere (the daemon's parameters accept unsigned sets,
    link.unsigned_params, so that it is the engage gate that answers). Before, it engaged unsigned; now only
    with link.accept_unsigned (WEAKENED in the banner)."""
    f = fly(tmp_path, None, None, None, seconds=6.0, unsigned_params=True, accept_unsigned=accepted)
    if accepted:
        assert "WEAKENED link.accept_unsigned" in f["console"] and "REFUSING" not in f["console"], f["console"]
        assert "param set CG_ENGAGE 1: echoed 1" in f["gcs"] and "1:191 says: CG: active" in f["gcs"], f["gcs"]
        return
    assert "REFUSING TO ENGAGE: unsigned on the network link" in f["console"], f["console"]
    assert "param set CG_ENGAGE 1: echoed 0" in f["gcs"], f["gcs"]
    assert "engage REFUSED: unsigned on the network link" in f["gcs"].replace("  ", " ") or \
        [e for e in f["events"] if e.get("event") == "engage_refused" and "unsigned" in e["reason"]]
    assert "CG: active" not in f["gcs"]


def test_a_wrong_key_is_said_as_a_signature_mismatch_at_once(keys, tmp_path):
    """The autopilot and the ground station sign with one key, the daemon has another: within seconds the
    daemon says "signature mismatch from ADDR ids 1/1: wrong key?" on the console and in the event log."""
    right, right_hex, wrong = keys
    f = fly(tmp_path, wrong, right_hex, right, seconds=1.0, wait_s=8.0)
    print(f["console"])
    said = [ln for ln in f["console"].splitlines() if "signature mismatch from" in ln and "ids 1/1" in ln]
    assert said and said[0].rstrip().endswith("refused)") and "wrong key?" in said[0], f["console"]
    ev = [e for e in f["events"] if e.get("event") == "source_refused" and e["what"] == "bad_signature"]
    assert ev and (ev[0]["system"], ev[0]["component"]) == (1, 1)
    start = next(e["wall"] for e in f["events"] if e.get("event") == "start")
    assert ev[0]["wall"] - start < 5.0  # at once: the first of them, not after a time-out
    assert "1:191 says" not in f["gcs"]  # the ground station hears nothing it can verify from the daemon


def test_the_ground_station_with_a_wrong_key_says_so_not_only_no_heartbeat(keys, tmp_path):
    right, right_hex, wrong = keys
    port = free_port()
    sitl = cg("sitl", "--personality", "px4", "--listen", f"udp:127.0.0.1:{port}", "--signing-key-hex", right_hex)
    assert "listening" in sitl.stderr.readline()
    try:
        gcs = subprocess.run([sys.executable, str(ROOT / "examples" / "ground_station.py"), "--connect",
                              f"udpout:127.0.0.1:{port}", "--signing-key", str(wrong), "--wait-s", "4"], env=ENV,
                             cwd=tmp_path, capture_output=True, text=True, timeout=120)
    finally:
        sitl.send_signal(signal.SIGINT)
        sitl.communicate(timeout=30)
    assert gcs.returncode == 1
    assert "gcs: signature mismatch from 1:1: wrong key?" in gcs.stdout, gcs.stdout + gcs.stderr
    assert "no autopilot heartbeat" in gcs.stdout
