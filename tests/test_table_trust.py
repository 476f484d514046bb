"""Tables as untrusted input: an ed25519 signature over arrays and metadata, and files refused before they are read
(pickles, non-numeric members, members larger than the grid, deep JSON, zip bombs): one line, no large allocation."""

import io
import json
import shutil
import subprocess
import sys
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from cryptography.hazmat.primitives.serialization import (Encoding, NoEncryption, PrivateFormat,
                                                          PublicFormat)

from contracts.errors import ContractError
from contracts.table import arrays_sha256, load_for_vehicle, shipped_table, sign_table, verify

ROOT = Path(__file__).resolve().parents[1]


def _pair(tmp_path, name="table"):
    k = Ed25519PrivateKey.generate()
    priv, pub = tmp_path / f"{name}.pem", tmp_path / f"{name}.pub.pem"
    priv.write_bytes(k.private_bytes(Encoding.PEM, PrivateFormat.PKCS8, NoEncryption()))
    pub.write_bytes(k.public_key().public_bytes(Encoding.PEM, PublicFormat.SubjectPublicKeyInfo))
    return priv, pub


def _members(path):
    with np.load(path) as z:
        return {k: z[k].copy() for k in z.files}


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "companion.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=str(ROOT), timeout=120)


def _one_line_refusal(r, match):
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert match in r.stderr, r.stderr


@pytest.fixture
def signed(tmp_path):
    priv, pub = _pair(tmp_path)
    p = tmp_path / "mambo.npz"
    shutil.copy(shipped_table("mambo"), p)
    sign_table(p, priv)
    return p, priv, pub


def _faster(src, dst):
    """The hostile edit: avoid_f × 1.3 and etr_e × 0.5, the hash recomputed (the signature member kept)."""
    a = _members(src)
    meta = json.loads(a.pop("metadata_json").tobytes())
    sig = a.pop("signature_json", None)
    a["avoid_f"] = a["avoid_f"] * 1.3
    a["etr_e"] = a["etr_e"] * 0.5
    meta["arrays_sha256"] = arrays_sha256(a)
    extra = {} if sig is None else {"signature_json": sig}
    np.savez(dst, metadata_json=np.frombuffer(json.dumps(meta).encode(), np.uint8), **extra, **a)


# ----------------------------------------------------------------------------- signature


def test_a_faster_table_with_its_hash_recomputed_fails_against_the_key(signed, tmp_path):
    p, _, pub = signed
    t = verify(p, public_key=pub)
    assert t.signature["verified"] and t.signature["signed"]
    bad = tmp_path / "faster.npz"
    _faster(p, bad)
    fast = verify(bad)  # integrity only: the hash is a checksum, it passes
    assert not fast.signature["verified"]
    assert fast.omega(6.0, 0.5, 0.0, 1.0).v_max > t.omega(6.0, 0.5, 0.0, 1.0).v_max  # the edit is faster
    with pytest.raises(ContractError, match="signature does not verify") as e:
        verify(bad, public_key=pub)
    assert "\n" not in str(e.value)
    # the metadata alone: a signed table whose vehicle description is edited (and hash kept) is refused too
    a = _members(p)
    meta = json.loads(a.pop("metadata_json").tobytes())
    meta["note"] = "edited"
    np.savez(tmp_path / "meta.npz", metadata_json=np.frombuffer(json.dumps(meta).encode(), np.uint8), **a)
    verify(tmp_path / "meta.npz")
    with pytest.raises(ContractError, match="signature does not verify"):
        verify(tmp_path / "meta.npz", public_key=pub)


def test_unsigned_or_another_keys_table_is_refused_when_a_key_is_configured(signed, tmp_path):
    p, _, pub = signed
    _, other_pub = _pair(tmp_path, "other")
    with pytest.raises(ContractError, match="signature does not verify"):
        verify(p, public_key=other_pub)
    with pytest.raises(ContractError, match="unsigned, but a table public key is configured"):
        verify(shipped_table("mambo"), public_key=pub)
    with pytest.raises(ContractError, match="unsigned, but"):
        load_for_vehicle("mambo", None, pub)
    (tmp_path / "junk.pem").write_text("not a key")
    with pytest.raises(ContractError, match="not an ed25519 public key"):
        verify(p, public_key=tmp_path / "junk.pem")


def test_cli_sign_verify_show_and_the_daemon_refuses_a_faster_table(tmp_path):
    priv, pub = _pair(tmp_path)
    r = _cli("table", "verify", "mambo")
    assert r.returncode == 0 and "unsigned: integrity only" in r.stdout, r.stderr
    out = tmp_path / "signed.npz"
    r = _cli("table", "sign", "mambo", "--key", priv, "--out", out)
    assert r.returncode == 0, r.stderr
    r = _cli("table", "verify", out, "--public-key", pub, "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["signature"]["verified"], r.stderr
    r = _cli("table", "show", out)
    assert "signed by key" in r.stdout and "not checked" in r.stdout
    bad = tmp_path / "faster.npz"
    _faster(out, bad)
    assert _cli("table", "verify", bad).returncode == 0  # integrity only
    _one_line_refusal(_cli("table", "verify", bad, "--public-key", pub), "signature does not verify")
    _one_line_refusal(_cli("table", "show", bad, "--public-key", pub), "signature does not verify")
    # signed as it is written (`table build --sign-key`)
    built = tmp_path / "stop-only.npz"
    r = _cli("table", "build", "--vehicle", "mambo", "--stop-only", "--out", built, "--sign-key", priv)
    assert r.returncode == 0 and "signed with key" in r.stdout, r.stderr
    assert verify(built, public_key=pub).signature["verified"]
    # the daemon: a configured public key refuses the faster table before any link is opened
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(f"vehicle: mambo\ntable: {bad}\ntable_public_key: {pub}\nlog: {{dir: {tmp_path / 'log'}}}\n"
                   "link: {connect: 'udpin:127.0.0.1:0'}\n")
    _one_line_refusal(_cli("run", "--config", cfg, "--quiet"), "signature does not verify")


# ----------------------------------------------------------------------------- refused before read


def _npy(arr_header: dict, data: bytes) -> bytes:
    """An .npy member with a header of our choosing (what it declares need not be what it holds)."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, arr_header)
    return buf.getvalue() + data


def _zip(path, members: dict[str, bytes], compress=zipfile.ZIP_STORED):
    with zipfile.ZipFile(path, "w", compress) as zf:
        for name, raw in members.items():
            zf.writestr(name + ".npy", raw)


def _stock_members():
    out = {}
    for k, v in _members(shipped_table("mambo")).items():
        b = io.BytesIO()
        np.save(b, v)
        out[k] = b.getvalue()
    return out


def _refused_small(path, match):
    """Refused in one line, allocating no more than a few MB on the way."""
    tracemalloc.start()
    try:
        with pytest.raises(ContractError, match=match) as e:
            verify(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "\n" not in str(e.value)
    assert peak < 8 << 20, peak
    return str(e.value)


def test_a_pickled_member_is_refused_in_one_line(tmp_path):
    m = _stock_members()
    b = io.BytesIO()
    np.save(b, np.array([{"x": 1}, None], dtype=object), allow_pickle=True)
    m["avoid_rho"] = b.getvalue()
    _zip(tmp_path / "pickle.npz", m)
    _refused_small(tmp_path / "pickle.npz", "pickle")
    r = _cli("table", "verify", tmp_path / "pickle.npz")
    _one_line_refusal(r, "pickle")


def test_a_non_numeric_member_is_refused(tmp_path):
    m = _stock_members()
    b = io.BytesIO()
    np.save(b, np.array(["a", "bc"]))
    m["etr_v"] = b.getvalue()
    _zip(tmp_path / "text.npz", m)
    _refused_small(tmp_path / "text.npz", "not numeric")


def test_a_member_declaring_37_gib_is_refused_without_allocating(tmp_path):
    m = _stock_members()
    # avoid_f declaring 120 × 23 × 1.8 M float64 cells (37 GiB) with 800 bytes of data
    m["avoid_f"] = _npy({"descr": "<f8", "fortran_order": False, "shape": (120, 23, 1_800_000)}, b"\0" * 800)
    _zip(tmp_path / "big.npz", m)
    _refused_small(tmp_path / "big.npz", "larger than, or not, what the table's grid implies")
    m = _stock_members()  # an axis declaring 5 G points
    m["avoid_rho"] = _npy({"descr": "<f8", "fortran_order": False, "shape": (5_000_000_000,)}, b"\0" * 800)
    _zip(tmp_path / "axis.npz", m)
    _refused_small(tmp_path / "axis.npz", "larger than")
    m = _stock_members()  # metadata declaring 37 GiB
    m["metadata_json"] = _npy({"descr": "|u1", "fortran_order": False, "shape": (37 << 30,)}, b"{}")
    _zip(tmp_path / "meta.npz", m)
    _refused_small(tmp_path / "meta.npz", "larger than")
    _one_line_refusal(_cli("table", "verify", tmp_path / "big.npz"), "grid implies")


def test_deep_json_metadata_is_refused(tmp_path):
    m = _stock_members()
    deep = b"[" * 200_000 + b"]" * 200_000
    b = io.BytesIO()
    np.save(b, np.frombuffer(deep, np.uint8))
    m["metadata_json"] = b.getvalue()
    _zip(tmp_path / "deep.npz", m)
    _refused_small(tmp_path / "deep.npz", "nested deeper")
    _one_line_refusal(_cli("table", "show", tmp_path / "deep.npz"), "nested deeper")


def test_a_zip_bomb_is_refused_by_its_declared_size(tmp_path):
    m = _stock_members()
    m["avoid_f"] = m["avoid_f"][:128] + b"\0" * 50_000_000  # 50 MB of zeros: deflates to about 50 KB
    p = tmp_path / "bomb.npz"
    _zip(p, m, zipfile.ZIP_DEFLATED)
    assert p.stat().st_size < 200_000
    raw = bytearray(p.read_bytes())
    # declare 2.2 GB in the central directory (what zipfile believes): refused before anything is inflated
    cd = raw.index(b"PK\x01\x02")  # the first central directory entry, then entry by entry
    while True:
        name_len = int.from_bytes(raw[cd + 28: cd + 30], "little")
        extra, comment = (int.from_bytes(raw[cd + o: cd + o + 2], "little") for o in (30, 32))
        if raw[cd + 46: cd + 46 + name_len] == b"avoid_f.npy":
            raw[cd + 24: cd + 28] = (2_200_000_000).to_bytes(4, "little")
            break
        cd += 46 + name_len + extra + comment
    (tmp_path / "declared.npz").write_bytes(bytes(raw))
    _refused_small(tmp_path / "declared.npz", "declares 2200000000 bytes")
    # as written (declared truthfully, 50 MB, above the bound): refused by its declared size, nothing inflated
    _refused_small(p, "avoid_f declares 50000128 bytes")
    # declaring the size its .npy header implies (a lie: the stream inflates to 50 MB): read no further than that
    raw[cd + 24: cd + 28] = (128 + 120 * 23 * 9 * 8).to_bytes(4, "little")
    (tmp_path / "lying.npz").write_bytes(bytes(raw))
    _refused_small(tmp_path / "lying.npz", "unreadable or truncated")


def test_unknown_members_and_non_files_are_refused(tmp_path):
    m = _stock_members()
    m["extra"] = m["etr_v"]
    _zip(tmp_path / "extra.npz", m)
    _refused_small(tmp_path / "extra.npz", "not .or twice. a table member")
    with pytest.raises(ContractError, match="not a regular file"):
        verify(tmp_path)


def test_the_daemon_starts_on_a_table_signed_by_its_configured_key(signed, tmp_path):
    from tests.test_config_ranges import daemon_output_until, free_udp_port

    p, _, pub = signed
    cfg = tmp_path / "cg.yaml"
    cfg.write_text(f"vehicle: mambo\ntable: {p}\ntable_public_key: {pub}\nlog: {{dir: {tmp_path / 'log'}}}\n"
                   f"link: {{connect: 'udpin:127.0.0.1:{free_udp_port()}'}}\n")
    out = daemon_output_until(cfg, "waiting for the autopilot")
    assert "waiting for the autopilot" in out, out
