"""Offline inputs and the config as a hostile hand would prepare them:
- `table sign` and `calibrate --sign-key` sign over a base table only when its signature verifies or it is the
  shipped table of its vehicle; an edited unsigned base is refused naming what differs (`--accept-edited-base`);
- a signed table carries a serial; the daemon shows it (banner, start record), keeps the last it accepted and
  refuses an older one (a rollback) unless the config allows it, loudly;
- `run --check` refuses what `run` would (one line, exit 2): non-finite sensor angles, a port outside 1-65535, a
  MAVLink id above 255, an event log too small to keep a flight, duplicate YAML keys, a nominal hover throttle
  that pins thrust_ratio at its top;
- ArduPilot offboard: GUID_TIMEOUT is read at the start-up checks and refused unset, too long or too short.
Each against the real CLI (`python -m companion.cli`) in a subprocess, and the GUID_TIMEOUT check in a lock-step
flight of the real daemon against the SITL over MAVLink."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.ground.keys import table_key_pair
from contracts.table import arrays_sha256, shipped_table, sign_table, verify

ROOT = Path(__file__).resolve().parents[1]


def _cli(*args, timeout=180):
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=str(ROOT), timeout=timeout)


def _one_line(r, *words):
    assert r.returncode == 2, r.stdout + r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in r.stderr, r.stderr


def _edited(dst: Path, name="x500", note=False, old=False):
    """The shipped table with its controller contract halved (a faster contract) and the hash recomputed: what a
    hand with a text editor and numpy makes; unsigned. `old`: without the slot the old code did not know (`_as_old`)."""
    with np.load(shipped_table(name)) as z:
        a = {k: z[k].copy() for k in z.files}
    meta = json.loads(a.pop("metadata_json").tobytes())
    a["etr_e"] = a["etr_e"] * 0.5
    if old:
        _drop_brake(a, meta)
    meta["arrays_sha256"] = arrays_sha256(a)
    if note:
        meta["method"] = {**meta.get("method", {}), "by": "someone"}
    np.savez(dst, metadata_json=np.frombuffer(json.dumps(meta).encode(), np.uint8), **a)
    return dst


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    return table_key_pair(tmp_path_factory.mktemp("keys"))


# ----------------------------------------------------------------------------- the base a signature vouches for


def test_table_sign_refuses_an_edited_unsigned_base_naming_what_differs(keys, tmp_path):
    bad = _edited(tmp_path / "edited.npz", note=True)
    verify(bad)  # integrity only: it passes
    r = _cli("table", "sign", bad, "--key", keys["private_key"], "--out", tmp_path / "s.npz")
    _one_line(r, "not the shipped table of x500", "array etr_e", "metadata method", "--accept-edited-base")
    assert not (tmp_path / "s.npz").exists()
    r = _cli("table", "sign", bad, "--key", keys["private_key"], "--out", tmp_path / "s.npz", "--accept-edited-base")
    assert r.returncode == 0 and "accepted with --accept-edited-base" in r.stdout and "array etr_e" in r.stdout, r.stderr
    # the shipped table itself, and a table already signed by this key, are signed without a word
    r = _cli("table", "sign", "x500", "--key", keys["private_key"], "--out", tmp_path / "ok.npz")
    assert r.returncode == 0 and "identical to the shipped table of x500" in r.stdout, r.stderr
    r = _cli("table", "sign", tmp_path / "ok.npz", "--key", keys["private_key"])
    assert r.returncode == 0 and "signature verified" in r.stdout, r.stderr


def test_a_base_signed_by_another_key_needs_its_public_key(keys, tmp_path):
    other = table_key_pair(tmp_path / "other")
    theirs = tmp_path / "theirs.npz"
    sign_table(shipped_table("mambo"), other["private_key"], theirs)
    _one_line(_cli("table", "sign", theirs, "--key", keys["private_key"], "--out", tmp_path / "m.npz"),
              f"signed by key {other['key_id']}", "--base-public-key")
    r = _cli("table", "sign", theirs, "--key", keys["private_key"], "--out", tmp_path / "m.npz", "--base-public-key",
             other["public_key"])
    assert r.returncode == 0, r.stderr


def test_negative_control_without_the_base_check_an_edit_is_signed_and_verifies(keys, tmp_path):
    """What `table sign` did: the edited table signed as it was, and then verified by the daemon's public key."""
    bad = _edited(tmp_path / "edited.npz")
    sign_table(bad, keys["private_key"], tmp_path / "laundered.npz")  # the library call: no base check
    t = verify(tmp_path / "laundered.npz", public_key=keys["public_key"])
    assert t.signature["verified"] and np.all(t.e_pred.values < verify(shipped_table("x500")).e_pred.values)


def test_calibrate_sign_key_refuses_an_edited_base(keys, tmp_path):
    from tests.test_calibrate_evidence import crafted_tlog

    log = crafted_tlog(tmp_path / "f.tlog", cruise_s=10.0)
    bad = _edited(tmp_path / "base.npz")
    out = tmp_path / "cal.npz"
    cmd = ["calibrate", log, "--vehicle", "x500", "--table", bad, "--out", out, "--sign-key", keys["private_key"]]
    _one_line(_cli(*cmd), "base table", "array etr_e", "--accept-edited-base")
    assert not out.exists()
    # unsigned result: no signature vouches for anything, calibrate runs as before
    assert _cli(*cmd[:-2]).returncode == 0
    r = _cli(*cmd, "--accept-edited-base")
    assert r.returncode == 0 and "the base table: unsigned and not the shipped table of x500" in r.stdout, r.stderr
    r = _cli("calibrate", log, "--vehicle", "x500", "--table", "x500", "--out", out, "--sign-key", keys["private_key"])
    assert r.returncode == 0 and "identical to the shipped table of x500" in r.stdout, r.stderr


# ----------------------------------------------------------------------------- serial and rollback


def _config(tmp_path, table, pub, extra=""):
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(f"vehicle: mambo\ntable: {table}\ntable_public_key: {pub}\nlog: {{dir: {tmp_path / 'log'}}}\n"
                   f"table_state_file: {tmp_path / 'state' / 'table-serial.json'}\n"
                   f"link: {{connect: 'udpin:127.0.0.1:0'}}\n{extra}")
    return cfg


def _start(cfg, seconds=4.0):
    """`run` started for real (the link opened on a free loopback port), stopped politely: (rc, stdout, stderr)."""
    p = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg)], cwd=str(ROOT),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and p.poll() is None and not (Path(cfg).parent / "log" / "events.jsonl").exists():
            time.sleep(0.1)
        time.sleep(seconds if p.poll() is None else 0)
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    return p.returncode, out, err


def _events(tmp_path, name):
    lines = (tmp_path / "log" / "events.jsonl").read_text().splitlines()
    return [e for e in map(json.loads, lines) if e.get("event") == name]


def test_the_serial_is_shown_recorded_and_an_older_table_refused(keys, tmp_path):
    old, new = tmp_path / "old.npz", tmp_path / "new.npz"
    s_old = sign_table(shipped_table("mambo"), keys["private_key"], old, serial=100)["serial"]
    s_new = sign_table(shipped_table("mambo"), keys["private_key"], new, serial=200)["serial"]
    assert (verify(old).serial, verify(new).serial) == (s_old, s_new) == (100, 200)
    r = _cli("table", "verify", new, "--public-key", keys["public_key"])
    assert "serial 200" in r.stdout
    served = tmp_path / "in-service.npz"
    shutil.copy(new, served)
    cfg = _config(tmp_path, served, keys["public_key"])
    rc, out, err = _start(cfg)
    assert rc == 0, err
    assert "serial 200" in out and "the first accepted" in out
    start = _events(tmp_path, "start")[-1]
    assert start["table_serial"] == 200 and start["table_signature"]["verified"]
    assert json.loads((tmp_path / "state" / "table-serial.json").read_text())["serial"] == 200
    # the older signed table copied over the one in service: refused by --check and by run, one line
    shutil.copy(old, served)
    _one_line(_cli("run", "--config", cfg, "--check"), "serial 100", "older than serial 200", "rollback")
    _one_line(_cli("run", "--config", cfg), "older than serial 200")
    # the same serial, another table: refused too
    shutil.copy(shipped_table("mambo"), tmp_path / "m.npz")
    sign_table(tmp_path / "m.npz", keys["private_key"], served, serial=200)  # an unchanged copy: accepted
    assert _cli("run", "--config", cfg, "--check").returncode == 0
    _edited(tmp_path / "e.npz", "mambo")
    sign_table(tmp_path / "e.npz", keys["private_key"], served, serial=200)
    _one_line(_cli("run", "--config", cfg, "--check"), "another table with the serial of the last accepted")


def test_a_rollback_flies_only_when_allowed_and_loudly(keys, tmp_path):
    old, new = tmp_path / "old.npz", tmp_path / "new.npz"
    sign_table(shipped_table("mambo"), keys["private_key"], old, serial=100)
    sign_table(shipped_table("mambo"), keys["private_key"], new, serial=200)
    state = tmp_path / "state" / "table-serial.json"
    state.parent.mkdir()
    state.write_text(json.dumps({"serial": 200, "arrays_sha256": verify(new).meta["arrays_sha256"],
                                 "table": str(new), "accepted_utc": "2026-01-01T00:00:00+00:00"}) + "\n")
    cfg = _config(tmp_path, old, keys["public_key"], "allow_table_rollback: true\n")
    r = _cli("run", "--config", cfg, "--check")
    assert r.returncode == 0 and "WEAKENED allow_table_rollback" in r.stdout, r.stderr
    rc, out, err = _start(cfg)
    assert rc == 0 and "WEAKENED allow_table_rollback" in out, err
    ev = _events(tmp_path, "table_rollback")
    assert ev and ev[0]["serial"] == 100 and ev[0]["last_serial"] == 200
    assert json.loads(state.read_text())["serial"] == 200  # never lowered: the next start asks again
    state.write_text("{not json")
    _one_line(_cli("run", "--config", cfg, "--check"), "table state file", "damaged")


def test_negative_control_without_a_state_file_an_older_table_starts_unnoticed(keys, tmp_path):
    """The old behaviour, kept where no state file is configured: nothing remembers the last serial, so the older
    table starts — and the banner says that rollback is not checked."""
    old = tmp_path / "old.npz"
    sign_table(shipped_table("mambo"), keys["private_key"], old, serial=100)
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(f"vehicle: mambo\ntable: {old}\ntable_public_key: {keys['public_key']}\n"
                   f"log: {{dir: {tmp_path / 'log'}}}\nlink: {{connect: 'udpin:127.0.0.1:0'}}\n")
    r = _cli("run", "--config", cfg, "--check")
    assert r.returncode == 0 and "rollback to an older table not checked" in r.stdout, r.stderr


def test_the_state_file_sits_beside_the_signing_timestamp_file(tmp_path):
    from companion.onboard.config import config_from_dict
    from companion.onboard.inputs import state_path

    cfg = config_from_dict({"link": {"signing_timestamp_file": str(tmp_path / "ts" / "signing.ts")}})
    assert state_path(cfg) == tmp_path / "ts" / "table-serial.json"
    assert state_path(config_from_dict({})) is None


# ----------------------------------------------------------------------------- run --check refuses what run would

GOVERNOR = "vehicle: x500\nmode: governor\nsensors: [{h_fov_deg: 10, max_range_m: 10}]\n"
BAD = [
    ("sensors: [{orientation_deg: .nan, h_fov_deg: 10, max_range_m: 10}]\n", "orientation_deg"),
    ("sensors: [{orientation_deg: .inf, h_fov_deg: 10, max_range_m: 10}]\n", "orientation_deg"),
    ("link: {connect: 'udpin:0.0.0.0:99999'}\n", "port 99999"),
    ("link: {connect: 'udpout:10.0.0.1:0'}\n", "port 0"),
    ("link: {target_system: 300}\n", "target_system"),
    ("link: {component_id: 0}\n", "component_id"),
    ("log: {max_bytes: 1, keep: 0}\n", "log.max_bytes"),
    ("log: {keep: 0}\n", "log.keep"),
    ("thrust: {hover_throttle_nominal: 0.99}\n", "hover_throttle_nominal"),
    ("loop_hz: 50\nloop_hz: 20\n", "duplicate key 'loop_hz' (line"),
    ("timeouts:\n  obstacle_s: 0.5\n  obstacle_s: 1.9\n", "duplicate key 'obstacle_s'"),
]


@pytest.mark.parametrize("text,word", BAD, ids=[w for _, w in BAD])
def test_run_check_refuses_what_run_would_in_one_line(tmp_path, text, word):
    body = text if text.startswith("sensors") else GOVERNOR + text
    if text.startswith("sensors"):
        body = "vehicle: x500\nmode: governor\n" + text
    (tmp_path / "c.yaml").write_text(body)
    _one_line(_cli("run", "--check", "--config", tmp_path / "c.yaml"), word)


BASE = "14fca95"  # the commit before these checks: the negative controls run its CLI


@pytest.fixture(scope="module")
def old_checkout(tmp_path_factory):
    """The package as it was at BASE (git archive), to run its CLI; skipped without the git history."""
    d = tmp_path_factory.mktemp("old")
    arch = subprocess.run(["git", "archive", BASE], capture_output=True, cwd=str(ROOT))
    if arch.returncode != 0:
        pytest.skip("no git history: the negative controls need the old code")
    subprocess.run(["tar", "-x", "-C", str(d)], input=arch.stdout, check=True)
    return d


def test_negative_control_the_old_check_passed_them_and_run_crashed(tmp_path, old_checkout):
    """The old `run --check` passed every one of these configs (exit 0), and the old `run` ended the NaN angle and
    the port 99999 in a traceback."""
    def old(*args, timeout=60):
        return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True,
                              text=True, cwd=str(old_checkout), timeout=timeout)

    for k, (text, _) in enumerate(BAD):
        body = ("vehicle: x500\nmode: governor\n" + text) if text.startswith("sensors") else GOVERNOR + text
        (tmp_path / f"{k}.yaml").write_text(body)
        r = old("run", "--check", "--config", tmp_path / f"{k}.yaml")
        assert r.returncode == 0, (text, r.stderr)
    for k in (0, 2):  # the NaN orientation, the port 99999: run itself
        cfg = tmp_path / f"run{k}.yaml"
        text = BAD[k][0] + ("" if k == 2 else "link: {connect: 'udpin:127.0.0.1:0'}\n")
        cfg.write_text(("vehicle: x500\nmode: governor\n" if k == 0 else GOVERNOR) + text
                       + f"log: {{dir: {tmp_path / 'log'}}}\n")
        try:
            r = old("run", "--config", cfg, "--quiet", timeout=20)
            err = r.stderr
        except subprocess.TimeoutExpired as e:
            err = (e.stderr or b"").decode() if isinstance(e.stderr, bytes) else (e.stderr or "")
        assert "Traceback" in err, err


def test_hover_nominal_bound_follows_the_vehicle_file():
    from companion.onboard.config import config_from_dict
    from companion.onboard.inputs import HOVER_NOMINAL_MAX_ABOVE, hover_nominal_problem
    from contracts.vehicle import load_vehicle

    veh = load_vehicle("x500")
    top = veh.controller.thr_hover * (1 + HOVER_NOMINAL_MAX_ABOVE)
    ok = config_from_dict({"thrust": {"hover_throttle_nominal": round(top - 1e-3, 4)}})
    assert hover_nominal_problem(ok, veh) is None
    bad = config_from_dict({"thrust": {"hover_throttle_nominal": round(top + 1e-3, 4)}})
    assert "never seen" in hover_nominal_problem(bad, veh)
    lower = config_from_dict({"thrust": {"hover_throttle_nominal": 0.3}})  # reads less thrust: slower, accepted
    assert hover_nominal_problem(lower, veh) is None


def test_the_demo_and_shipped_configs_pass_the_new_checks(tmp_path):
    from tests.test_examples_start import CONFIGS, on_this_machine

    for k, c in enumerate(CONFIGS):
        d = tmp_path / str(k)
        d.mkdir()
        r = _cli("run", "--check", "--config", on_this_machine(c, d))
        assert r.returncode == 0, (c.name, r.stderr)


# ----------------------------------------------------------------------------- GUID_TIMEOUT (ArduPilot offboard)


def test_guid_timeout_bounds():
    from companion.onboard.config import config_from_dict
    from companion.onboard.startup import setpoint_timeout_problem

    cfg = config_from_dict({})
    assert setpoint_timeout_problem("GUID_TIMEOUT", 3.0, cfg) is None  # ArduPilot's default
    assert setpoint_timeout_problem("GUID_TIMEOUT", 0.5, cfg) is None
    assert "unset" in setpoint_timeout_problem("GUID_TIMEOUT", None, cfg)
    assert "unset" in setpoint_timeout_problem("GUID_TIMEOUT", 0.0, cfg)
    assert "blind" in setpoint_timeout_problem("GUID_TIMEOUT", 5.0, cfg)
    assert "between setpoints" in setpoint_timeout_problem("GUID_TIMEOUT", 0.1, cfg)


def _offboard_ardupilot(guid_timeout):
    from tests.lockstep import Rig
    from tests.test_offboard_lockstep import offboard_config, offboard_scenario

    sc = offboard_scenario(1, x_col=300.0, personality="ardupilot")
    sc["params"] = {"GUID_TIMEOUT": guid_timeout}
    rig = Rig(sc, "ardupilot", config=offboard_config())
    rig.run(8.0)
    return rig


def test_ardupilot_offboard_refuses_a_guid_timeout_too_long_read_at_start_up():
    rig = _offboard_ardupilot(5.0)
    chk = rig.log.named("startup_check")
    assert chk and not chk[-1]["ok"] and "GUID_TIMEOUT = 5 s" in chk[-1]["reason"], chk
    assert f"CG: refusing to engage: {chk[-1]['reason']}" in rig.daemon_texts()
    assert not rig.log.named("offboard") or all(e["to"] != "flying" for e in rig.log.named("offboard"))


def test_negative_control_without_the_check_the_same_guid_timeout_passed(monkeypatch):
    from companion.onboard import startup

    monkeypatch.setattr(startup, "setpoint_timeout_problem", lambda *a: None)
    rig = _offboard_ardupilot(5.0)
    chk = rig.log.named("startup_check")
    assert chk and chk[-1]["ok"], chk


def _drop_brake(a: dict, meta: dict) -> None:
    """A table's arrays and metadata without the recovery brake's E_tr_pred slot (newer than the old code)."""
    for k in [k for k in a if k.startswith("etrb_")]:
        del a[k]
    meta["available"] = [x for x in meta["available"] if x != "e_tr_pred_brake"]
    for key in ("contracts", "axes", "method"):
        meta.get(key, {}).pop("e_tr_pred_brake", None)


def _as_old(name: str, dst: Path) -> Path:
    """The shipped table as the old code can read it (`_drop_brake`), its hash recomputed."""
    with np.load(shipped_table(name)) as z:
        a = {k: z[k].copy() for k in z.files}
    meta = json.loads(a.pop("metadata_json").tobytes())
    _drop_brake(a, meta)
    meta["arrays_sha256"] = arrays_sha256(a)
    np.savez(dst, metadata_json=np.frombuffer(json.dumps(meta).encode(), np.uint8), **a)
    return dst


def _old(old_checkout, *args, timeout=120):
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=str(old_checkout), timeout=timeout)


def test_negative_control_the_old_cli_signed_an_edit_and_could_not_tell_tables_apart(keys, tmp_path, old_checkout):
    """The old `table sign` signed the edited table (exit 0) and the daemon's public key then verified it; the old
    `run --check` started an older signed table after a newer one, its banner the same but for the file name."""
    bad = _edited(tmp_path / "edited.npz", old=True)
    r = _old(old_checkout, "table", "sign", bad, "--key", keys["private_key"], "--out", tmp_path / "laundered.npz")
    assert r.returncode == 0, r.stderr
    assert verify(tmp_path / "laundered.npz", public_key=keys["public_key"]).signature["verified"]
    old, new = tmp_path / "old.npz", tmp_path / "new.npz"
    shipped = _as_old("mambo", tmp_path / "shipped-as-old.npz")
    sign_table(shipped, keys["private_key"], old, serial=100)
    sign_table(shipped, keys["private_key"], new, serial=200)
    said = {}
    for name, table in (("new", new), ("old", old)):
        served = tmp_path / "in-service.npz"
        shutil.copy(table, served)
        cfg = _config(tmp_path, served, keys["public_key"]).read_text().replace(
            f"table_state_file: {tmp_path / 'state' / 'table-serial.json'}\n", "")
        (tmp_path / "old-cg.yaml").write_text(cfg)
        r = _old(old_checkout, "run", "--config", tmp_path / "old-cg.yaml", "--check")
        assert r.returncode == 0, r.stderr
        said[name] = r.stdout
    assert said["old"] == said["new"] and "serial" not in said["old"]


def test_table_etr_sign_key_checks_its_base_before_flying(keys, tmp_path):
    bad = _edited(tmp_path / "base.npz")
    t0 = time.monotonic()
    r = _cli("table", "etr", "--table", bad, "--vehicle", "x500", "--out", tmp_path / "e.npz", "--sign-key",
             keys["private_key"])
    _one_line(r, "base table", "array etr_e", "--accept-edited-base")
    assert time.monotonic() - t0 < 60 and not (tmp_path / "e.npz").exists()  # refused before the sweep
