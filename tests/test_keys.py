"""`contract-guard keys`: one signing key in the forms the daemon, MAVProxy, QGroundControl and PX4 take."""

import hashlib
import json
import stat
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.ground.keys import mavlink_key, passphrase_to_key, px4_key_file, signing_timestamp, table_key_pair
from companion.onboard.link import SIGNING_EPOCH, load_signing_key
from contracts.errors import ContractError

ROOT = Path(__file__).resolve().parents[1]


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=str(ROOT), timeout=60)


def _signed_heartbeat(key: bytes) -> bytes:
    """A HEARTBEAT signed with `key` by pymavlink, as MAVProxy signs once given the key (`setup_signing`)."""
    m = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    m.signing.secret_key = key
    m.signing.sign_outgoing = True
    m.signing.timestamp = signing_timestamp(time.time())
    return m.heartbeat_encode(6, 8, 0, 0, 0).pack(m)


def _accepts(key: bytes, packet: bytes) -> bool:
    r = mav.MAVLink(None)
    r.signing.secret_key = key
    r.signing.allow_unsigned_callback = lambda *a: False
    r.robust_parsing = True
    msgs = [m for m in (r.parse_buffer(packet) or []) if m.get_type() != "BAD_DATA"]
    return bool(msgs)


def test_every_form_is_the_same_key(tmp_path):
    k = mavlink_key(tmp_path / "keys")
    d = tmp_path / "keys"
    key = load_signing_key(d / "mavlink-signing.key")  # the daemon's form (it refuses group/other-readable files)
    assert key == hashlib.sha256(k["passphrase"].encode("ascii")).digest()  # MAVProxy's passphrase_to_key
    assert bytes.fromhex(k["key_hex"]) == key and len(k["key_hex"]) == 64  # QGroundControl's raw key
    px4 = (d / "mavlink-signing-key.bin").read_bytes()  # PX4: 32 key bytes + uint64 timestamp, little-endian
    assert len(px4) == 40 and px4[:32] == key
    ts = struct.unpack("<Q", px4[32:])[0]
    assert abs(ts / 1e5 + SIGNING_EPOCH - time.time()) < 60
    for f in ("mavlink-signing.key", "mavlink-signing.passphrase", "mavlink-signing-key.bin"):
        assert stat.S_IMODE((d / f).stat().st_mode) == 0o600, f
    # a packet MAVProxy signs with the passphrase's key is accepted with the daemon's key file; another key is not
    pkt = _signed_heartbeat(passphrase_to_key(k["passphrase"]))
    assert _accepts(key, pkt)
    assert not _accepts(passphrase_to_key("another-passphrase"), pkt)


def test_shown_again_never_overwritten_and_from_a_given_passphrase(tmp_path):
    a = mavlink_key(tmp_path / "k")
    b = mavlink_key(tmp_path / "k")
    assert a["created"] and not b["created"] and a["key_hex"] == b["key_hex"]
    with pytest.raises(ContractError, match="already holds another key"):
        mavlink_key(tmp_path / "k", "something-else")
    c = mavlink_key(tmp_path / "given", "my-mavproxy-phrase")
    assert c["key_hex"] == hashlib.sha256(b"my-mavproxy-phrase").hexdigest()
    with pytest.raises(ContractError, match="without spaces"):
        mavlink_key(tmp_path / "bad", "two words")
    (tmp_path / "k" / "mavlink-signing.key").write_text("00" * 32 + "\n")
    with pytest.raises(ContractError, match="does not match"):
        mavlink_key(tmp_path / "k")
    assert px4_key_file(bytes(32), 1) == bytes(32) + b"\x01" + bytes(7)


def test_cli_keys_and_the_table_key_pair_sign_a_table(tmp_path):
    r = _cli("keys", tmp_path / "k", "--json")
    assert r.returncode == 0, r.stderr
    k = json.loads(r.stdout)
    r = _cli("keys", tmp_path / "k")
    assert "found MAVLink signing key " + k["key_id"] in r.stdout and "QGroundControl" in r.stdout
    assert "MAV_SIGN_CFG" in r.stdout and "signing setup" in r.stdout
    r = _cli("keys", tmp_path / "k", "--table", "--json")
    t = json.loads(r.stdout)
    assert r.returncode == 0 and t["created"] and table_key_pair(tmp_path / "k")["key_id"] == t["key_id"]
    out = tmp_path / "signed.npz"
    assert _cli("table", "sign", "mambo", "--key", t["private_key"], "--out", out).returncode == 0
    r = _cli("table", "verify", out, "--public-key", t["public_key"])
    assert r.returncode == 0 and f"verified with public key {t['key_id']}" in r.stdout, r.stdout + r.stderr
    (tmp_path / "file").write_text("x")
    r = _cli("keys", tmp_path / "file")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "not a directory" in r.stderr


# ----------------------------------------------------------------------------- links and stale files

BASE = "14fca95"  # the commit before key files were refused through links (the negative controls run its keys.py)


def _old_keys_module(tmp_path):
    """`companion/ground/keys.py` as it was at BASE, importable (None: no git history here)."""
    import importlib.util

    r = subprocess.run(["git", "show", f"{BASE}:companion/ground/keys.py"], capture_output=True, text=True,
                       cwd=str(ROOT))
    if r.returncode != 0:
        return None
    f = tmp_path / "old_keys.py"
    f.write_text(r.stdout)
    spec = importlib.util.spec_from_file_location("old_keys", f)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _one_line(r, *words):
    assert r.returncode == 2, r.stdout + r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in r.stderr, r.stderr


def test_the_public_key_is_never_written_through_a_link(tmp_path):
    d = tmp_path / "k"
    d.mkdir()
    target = tmp_path / "elsewhere.pem"
    target.write_text("the daemon's trusted key\n")
    (d / "table-signing.pub.pem").symlink_to(target)
    _one_line(_cli("keys", d, "--table"), "symbolic link", "table-signing.pub.pem")
    assert target.read_text() == "the daemon's trusted key\n" and not (d / "table-signing.pem").exists()
    old = _old_keys_module(tmp_path)
    if old is None:
        pytest.skip("no git history: the negative control needs the old keys.py")
    old.table_key_pair(d)  # the old behaviour: the new public key written over the link's target
    assert "PUBLIC KEY" in target.read_text()


@pytest.mark.parametrize("name", ["mavlink-signing.passphrase", "mavlink-signing.key", "mavlink-signing-key.bin"])
def test_a_link_in_a_key_files_place_dangling_or_not_is_one_line(tmp_path, name):
    for dangling in (True, False):
        d = tmp_path / f"k{dangling}"
        d.mkdir()
        target = tmp_path / f"target{dangling}"
        if not dangling:
            target.write_text("x\n")
        (d / name).symlink_to(target)
        _one_line(_cli("keys", d), "symbolic link", name)
        assert sorted(p.name for p in d.iterdir()) == [name]  # nothing else written
        assert target.exists() != dangling


def test_a_dangling_link_was_a_traceback(tmp_path):
    d = tmp_path / "k"
    d.mkdir()
    (d / "mavlink-signing.passphrase").symlink_to(tmp_path / "nowhere")
    old = _old_keys_module(tmp_path)
    if old is None:
        pytest.skip("no git history")
    with pytest.raises(FileExistsError):  # not a ContractError: the CLI printed a traceback
        old.mavlink_key(d)


def test_a_stale_px4_key_file_is_one_line_and_the_set_stays_one_key(tmp_path):
    d = tmp_path / "k"
    first = mavlink_key(d)
    # the key and passphrase moved away, PX4's file of that key left behind: no new set over it
    (d / "mavlink-signing.key").unlink()
    (d / "mavlink-signing.passphrase").unlink()
    _one_line(_cli("keys", d), "mavlink-signing-key.bin", "without the passphrase file")
    assert sorted(p.name for p in d.iterdir()) == ["mavlink-signing-key.bin"]
    # a set whose PX4 file is another key's: refused, left as it is
    e = tmp_path / "e"
    mavlink_key(e)
    (e / "mavlink-signing-key.bin").write_bytes((d / "mavlink-signing-key.bin").read_bytes())
    _one_line(_cli("keys", e), "mavlink-signing-key.bin", "stale PX4 key file")
    # moved away, the matching one is written: the set is one key again
    (e / "mavlink-signing-key.bin").unlink()
    r = _cli("keys", e, "--json")
    assert r.returncode == 0, r.stderr
    k = json.loads(r.stdout)
    assert (e / "mavlink-signing-key.bin").read_bytes()[:32] == bytes.fromhex(k["key_hex"]) != bytes.fromhex(
        first["key_hex"])
    assert stat.S_IMODE((e / "mavlink-signing-key.bin").stat().st_mode) == 0o600


def test_negative_control_a_stale_px4_file_was_a_traceback_and_a_mismatched_set(tmp_path):
    old = _old_keys_module(tmp_path)
    if old is None:
        pytest.skip("no git history")
    d = tmp_path / "k"
    first = old.mavlink_key(d)
    (d / "mavlink-signing.key").unlink()
    (d / "mavlink-signing.passphrase").unlink()
    with pytest.raises(FileExistsError):
        old.mavlink_key(d)
    second = old.mavlink_key(d)  # run again: "found", with PX4's file of the first key
    assert (d / "mavlink-signing-key.bin").read_bytes()[:32] == bytes.fromhex(first["key_hex"]) \
        != bytes.fromhex(second["key_hex"])
