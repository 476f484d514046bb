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
