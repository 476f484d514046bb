"""`contract-guard keys DIR`: one MAVLink 2 signing key for the whole aircraft, in the form each party expects;
`keys DIR --table`: an ed25519 key pair that signs Γ tables (`table sign`, `--sign-key`).

The signing key is derived from a passphrase as MAVProxy derives it, so that one secret serves everyone:
- MAVProxy: key = SHA-256 of the ASCII passphrase (`signing setup PASSPHRASE` sends it to the autopilot in a
  SETUP_SIGNING message and signs the link; `signing key PASSPHRASE` signs the link only; `~/.mavproxy/signing.keys`
  lines "DEVICE PASSPHRASE" sign a link by its device name) — MAVProxy/modules/mavproxy_signing.py,
  `passphrase_to_key`, `cmd_signing_setup`, `find_signing_passphrase`;
- QGroundControl: its own passphrase derivation is PBKDF2-SHA256 with an application salt (not MAVProxy's), so the
  key is given to it raw, 64 hex characters ("add raw key") — qgroundcontrol src/MAVLink/Signing/
  MAVLinkSigningKeys.cc, `addKey` / `addRawKey`;
- PX4: SETUP_SIGNING (e.g. MAVProxy's `signing setup`, over USB) stores the key; or the file
  `mavlink/mavlink-signing-key.bin` under the board's root directory (the SD card): 32 key bytes then the 8-byte
  initial timestamp in the board's byte order (little-endian) — PX4-Autopilot src/modules/mavlink/
  mavlink_sign_control.h (MAVLINK_SECRET_FILE), mavlink_sign_control.cpp / mavlink_signing_storage.cpp. Whether
  unsigned messages are still accepted is the parameter MAV_SIGN_CFG: 0 optional, 1 required except on USB,
  2 always required (`MavlinkSignControl::PROTO_SIGN`);
- ArduPilot: SETUP_SIGNING stores the key (with its timestamp) in the board's storage; USB (channel 0) always
  accepts unsigned messages — ArduPilot libraries/GCS_MAVLink/GCS_Signing.cpp, `handle_setup_signing`;
- this daemon: `link.signing_key_file` (64 hex characters, mode 600) and `link.signing_timestamp_file`.
Timestamps: 10 µs units since 2015-01-01 00:00 UTC (the MAVLink 2 signing specification).
"""

from __future__ import annotations

import hashlib
import os
import secrets
import struct
import time
from pathlib import Path

from companion.onboard.link import SIGNING_EPOCH
from contracts.errors import ContractError

KEY_FILE, PASSPHRASE_FILE, PX4_FILE = "mavlink-signing.key", "mavlink-signing.passphrase", "mavlink-signing-key.bin"
TIMESTAMP_FILE = "mavlink-signing.timestamp"
TABLE_PRIVATE, TABLE_PUBLIC = "table-signing.pem", "table-signing.pub.pem"


def passphrase_to_key(passphrase: str) -> bytes:
    """The 32-byte signing key of a passphrase, as MAVProxy makes it: SHA-256 of its ASCII bytes."""
    try:
        raw = passphrase.encode("ascii")
    except UnicodeEncodeError:
        raise ContractError("signing passphrase: ASCII only (MAVProxy encodes it as ASCII)") from None
    if not raw or any(c in b" \t\r\n" for c in raw):
        raise ContractError("signing passphrase: one word without spaces (MAVProxy takes one argument)")
    return hashlib.sha256(raw).digest()


def signing_timestamp(unix_s: float) -> int:
    """A MAVLink 2 signing timestamp: 10 µs units since 2015-01-01 UTC."""
    return max(0, int((unix_s - SIGNING_EPOCH) * 1e5))


def px4_key_file(key: bytes, timestamp: int) -> bytes:
    """PX4's `mavlink/mavlink-signing-key.bin`: the key, then the initial timestamp (uint64, little-endian)."""
    return bytes(key) + struct.pack("<Q", timestamp)


def key_id(key: bytes) -> str:
    """A name for a key that reveals nothing of it: the first 16 hex digits of SHA-256 of the key."""
    return hashlib.sha256(key).hexdigest()[:16]


def _not_a_link(path: Path) -> Path:
    """`path`, refused (one line) where it is a symbolic link, dangling or not: a key file is never written or
    trusted through a link (a link could put the key, or the public key the daemon trusts, anywhere)."""
    if path.is_symlink():
        raise ContractError(f"keys: {path} is a symbolic link (to {os.readlink(path)}): refused, a key file is never "
                            "written through a link; remove the link")
    return path


def _write_file(path: Path, data: bytes, mode: int = 0o600) -> None:
    """Create `path` (never an existing file, never through a link: O_EXCL | O_NOFOLLOW) with `mode`."""
    _not_a_link(path)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), mode)
    except FileExistsError:
        raise ContractError(f"keys: {path} appeared while writing the key set; move it away and run again") from None
    except OSError as err:
        raise ContractError(f"keys: cannot write {path} ({err.strerror or err})") from None
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _write_set(files: list[tuple[Path, bytes, int]]) -> None:
    """Write a set of files that belong together, all or none: each is written beside its place and the set is
    moved in only when every one is written (a failure leaves no part of a new set behind)."""
    tmp = [(path.with_name(path.name + ".new"), path, data, mode) for path, data, mode in files]
    try:
        for t, _, data, mode in tmp:
            if t.is_symlink() or t.exists():
                _not_a_link(t)
                t.unlink()
            _write_file(t, data, mode)
        for _, path, _, _ in tmp:  # every place still free before any file is moved in
            _not_a_link(path)
            if path.exists():
                raise ContractError(f"keys: {path} appeared while writing the key set; move it away and run again")
        for t, path, _, _ in tmp:
            os.replace(t, path)
    finally:
        for t, _, _, _ in tmp:
            if t.exists() and not t.is_symlink():
                t.unlink()


def _read_text(path: Path, what: str) -> str:
    _not_a_link(path)
    try:
        return path.read_text()[:256].strip()
    except (OSError, UnicodeDecodeError) as err:
        raise ContractError(f"keys: cannot read {what} {path} ({getattr(err, 'strerror', None) or type(err).__name__})") \
            from None


def _directory(out: Path) -> Path:
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ContractError(f"keys: {out} is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as err:
        raise ContractError(f"keys: cannot create {out} ({err.strerror or err})") from None
    return out


def mavlink_key(out: Path, passphrase: str | None = None, now: float | None = None) -> dict:
    """Create the signing key in `out` (from `passphrase`, else a new random one), or read the one there; return
    every form of it and where it went. The set (passphrase, key file, PX4 key file) is always one key: a new set
    is written only where none of its files exists, and a set found is checked whole; a file of another key, or a
    link in the place of one, is refused (one line), nothing written."""
    out = _directory(out)
    kp, pp, px = out / KEY_FILE, out / PASSPHRASE_FILE, out / PX4_FILE
    for f in (pp, kp, px):
        _not_a_link(f)
    created = not pp.exists()
    if created:
        stale = [f for f in (kp, px) if f.exists()]
        if stale:
            raise ContractError(f"keys: {', '.join(map(str, stale))} exist(s) without the passphrase file {pp.name} "
                                "(left from another key?): refused, nothing written; move it away first")
        phrase = passphrase if passphrase is not None else secrets.token_urlsafe(24)
        key = passphrase_to_key(phrase)
        _write_set([(pp, (phrase + "\n").encode(), 0o600), (kp, (key.hex() + "\n").encode(), 0o600),
                    (px, px4_key_file(key, signing_timestamp(time.time() if now is None else now)), 0o600)])
    else:
        phrase = _read_text(pp, "the passphrase file")
        key = passphrase_to_key(phrase)
        if passphrase is not None and passphrase_to_key(passphrase) != key:
            raise ContractError(f"keys: {out} already holds another key (key id {key_id(key)})")
        from companion.onboard.link import load_signing_key

        if not kp.exists() or load_signing_key(kp) != key:
            raise ContractError(f"keys: {kp} does not match {pp} (edited?); move both away and create a new key")
        try:
            on_card = px.read_bytes()[:64] if px.exists() else None
        except OSError as err:
            raise ContractError(f"keys: cannot read {px} ({err.strerror or err})") from None
        if on_card is None:  # the set completed: PX4's file of the key found
            _write_set([(px, px4_key_file(key, signing_timestamp(time.time() if now is None else now)), 0o600)])
        elif len(on_card) != 40 or on_card[:32] != key:
            raise ContractError(f"keys: {px} is not the key of {pp} (key id {key_id(key)}; a stale PX4 key file?): "
                                "refused, an autopilot given it would reject the daemon; move it away and run again "
                                "to write the matching one")
    return {"created": created, "key_id": key_id(key), "passphrase": phrase, "key_hex": key.hex(),
            "key_file": str(kp), "passphrase_file": str(pp), "px4_file": str(px),
            "timestamp_file": str(out / TIMESTAMP_FILE)}


def table_key_pair(out: Path) -> dict:
    """Create (or read) the ed25519 key pair that signs tables: the private key (PEM, mode 600) and its public key."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.serialization import Encoding, NoEncryption, PrivateFormat, PublicFormat

    from contracts.table import key_id as table_key_id
    from contracts.table import load_private_key, load_public_key

    out = _directory(out)
    priv, pub = out / TABLE_PRIVATE, out / TABLE_PUBLIC
    for f in (priv, pub):
        _not_a_link(f)
    created = not priv.exists()
    if created:
        if pub.exists():
            raise ContractError(f"keys: {pub} exists without its private key {priv.name} (left from another key?): "
                                "refused, nothing written; move it away first")
        k = Ed25519PrivateKey.generate()
        _write_set([(priv, k.private_bytes(Encoding.PEM, PrivateFormat.PKCS8, NoEncryption()), 0o600),
                    (pub, k.public_key().public_bytes(Encoding.PEM, PublicFormat.SubjectPublicKeyInfo), 0o644)])
    k = load_private_key(priv)
    if not pub.exists() or table_key_id(load_public_key(pub)) != table_key_id(k.public_key()):
        raise ContractError(f"keys: {pub} is not the public key of {priv}")
    return {"created": created, "key_id": table_key_id(k.public_key()), "private_key": str(priv), "public_key": str(pub)}


def describe(k: dict) -> str:
    """How to use the signing key with each party (the text of `contract-guard keys`)."""
    head = "created" if k["created"] else "found"
    return "\n".join([
        f"{head} MAVLink signing key {k['key_id']} (id = SHA-256 of the key, first 16 hex digits)",
        f"  this daemon (config): link: {{signing_key_file: {k['key_file']}, signing_timestamp_file: "
        f"{k['timestamp_file']}}}",
        f"  passphrase (MAVProxy, and the source of the key): {k['passphrase']}",
        "  MAVProxy, connected to the autopilot over USB: signing setup PASSPHRASE  (sends SETUP_SIGNING: PX4 and "
        "ArduPilot store the key), then on every link: signing key PASSPHRASE, or a line 'DEVICE PASSPHRASE' in "
        "~/.mavproxy/signing.keys",
        f"  QGroundControl: add the key as a raw key (64 hex characters): {k['key_hex']}",
        f"  PX4: parameter MAV_SIGN_CFG 1 (required except on USB) or 2 (always); the key by SETUP_SIGNING as above, "
        f"or copy {k['px4_file']} to mavlink/mavlink-signing-key.bin on the SD card",
        "  ArduPilot: the key by SETUP_SIGNING as above; USB stays unsigned",
        "  keep the passphrase: an autopilot that requires signing ignores every ground station without it",
    ])
