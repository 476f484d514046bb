"""The Γ table: one `.npz` holding the contract's arrays and a JSON metadata record (DESIGN.md §4.7).

Slots:
- `avoid` (offboard, the daemon can brake and swerve): F(ρ; tilt, thrust_ratio) in the reduced form
  V_safe = √(g·c)·F(r_k/c), built at t_react = 0 (the lookup applies the reaction time);
- `e_tr_pred` (the controller contract, Figure 12): E_tr_pred(v_max, tilt, thrust_ratio);
- `e_tr_pred_stop` (the governor's controller contract: what a governed vehicle flies, the autopilot's Hold) and
  `e_tr_pred_brake` (the same and the daemon's own recovery brake, flown as the daemon flies it);
- `stop` (governor, the autopilot brakes): closed form from the vehicle's braking limits, always there.

The loader verifies schema, SHA-256 of the arrays, axes, finiteness, monotonicity and (when given) the
vehicle, and refuses a bad file with one `ContractError` line. This module never imports CasADi.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import math
import zipfile
from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ContractError
from .flat import thrust_limited_accel
from .lookup import (
    MARGIN,
    NONE,
    ReactLookup,
    crossing_fixed_point,
    helps_index,
    hurts_index,
    is_monotone,
    law_cells,
    reaches,
    react_speed,
)
from .stop import approach_stop_speed, braking_decel, recovery_brake, stop_dead_time
from .vehicle import DATA_DIR, G, Vehicle, load_vehicle, vehicle_from_dict

SCHEMA = "contract-guard/gamma-table"
SCHEMA_VERSION = 1
MAX_REPAIR_FRACTION = 0.01  # the build fails if more cells than this needed a monotonicity repair
LAW_CLAIM = "cone: F = sqrt(a_h/g)*G(rho)"  # how a cone build states its scaling law (contracts/sweep.py)
# The law's row answers between grid tilts, at points no planner checked with the folded reaction time
# t_react + tilt/rate (DESIGN.md §2). Against the rate-limited planner that folding holds only to within
# the planners' 1e-3 brackets (measured: at 7° it is 0.07 % above it), so the law's row keeps
# two brackets of margin (0.2 %); the worst corner it replaces loses up to 13 % a degree at small tilts.
LAW_MARGIN = 1.0 - 2e-3
SILENT_TOL_M_S = 1e-3  # [m/s] the sensors' silence budget's fixed point is solved to this (`_omega_silent`)

# slot → (value array, axis arrays, per-axis monotone direction of the values, safe repair direction)
SLOTS = {
    "avoid": ("avoid_f", ("avoid_rho", "avoid_tilt", "avoid_thrust_ratio"), (-1, +1, +1), "down"),
    "e_tr_pred": ("etr_e", ("etr_v", "etr_tilt", "etr_thrust_ratio"), (+1, +1, -1), "up"),
    # the governor's: flown on what a governed vehicle flies, no swerve; the stop contract's if present
    "e_tr_pred_stop": ("etrs_e", ("etrs_v", "etrs_tilt", "etrs_thrust_ratio"), (+1, +1, -1), "up"),
    # the governor with its recovery brake: the governor's manoeuvres and the brake's own stop
    "e_tr_pred_brake": ("etrb_e", ("etrb_v", "etrb_tilt", "etrb_thrust_ratio"), (+1, +1, -1), "up"),
}
AXIS_INFO = {
    "avoid": [
        {"name": "rho", "symbol": "r_k/c", "unit": "1", "effect": "hurts"},
        {"name": "tilt", "unit": "rad", "effect": "helps"},
        {"name": "thrust_ratio", "unit": "1", "effect": "helps"},
    ],
    "e_tr_pred": [
        {"name": "v_max", "unit": "m/s", "effect": "hurts"},
        {"name": "tilt", "unit": "rad", "effect": "hurts"},
        {"name": "thrust_ratio", "unit": "1", "effect": "helps"},
    ],
}
AXIS_INFO["e_tr_pred_stop"] = AXIS_INFO["e_tr_pred_brake"] = AXIS_INFO["e_tr_pred"]


@dataclass(frozen=True)
class Slot:
    """One gridded contract: `values` over the three `axes` (ascending)."""

    axes: tuple[np.ndarray, np.ndarray, np.ndarray]
    values: np.ndarray
    info: dict = field(default_factory=dict)  # method, solver settings, repairs, margins …


def arrays_sha256(arrays: dict[str, np.ndarray]) -> str:
    """Canonical hash: name, dtype, shape and C-order bytes of every array, by name."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def slot_sha256(name: str, slot: Slot) -> str:
    """The hash one slot's arrays would have alone (`arrays_sha256` of a table holding only it): what ties the
    avoid slot's limiting trajectories to it, whatever slots a table adds beside it later."""
    vname, anames, _, _ = SLOTS[name]
    arrays = {an: np.asarray(ax, dtype=np.float64) for an, ax in zip(anames, slot.axes)}
    arrays[vname] = np.asarray(slot.values, dtype=np.float64)
    return arrays_sha256(arrays)


# ============================================================================ writer


def write_table(
    path: str | Path,
    vehicle: Vehicle,
    *,
    tilt_model: str | None = None,
    avoid: Slot | None = None,
    e_tr_pred: Slot | None = None,
    method: dict | None = None,
    e_tr_pred_stop: Slot | None = None,
    e_tr_pred_brake: Slot | None = None,
) -> dict:
    """Write a table; refuses slots that are not monotone (repair them first, `lookup.repair_monotone`)."""
    arrays: dict[str, np.ndarray] = {}
    contracts: dict[str, dict | None] = {
        "stop": {
            "method": "closed-form jerk-limited braking (contracts/stop.py)",
            "braking": vehicle.braking.model_dump(),
        }
    }
    for name, slot in (("avoid", avoid), ("e_tr_pred", e_tr_pred), ("e_tr_pred_stop", e_tr_pred_stop),
                       ("e_tr_pred_brake", e_tr_pred_brake)):
        if slot is None:
            contracts[name] = None
            continue
        vname, anames, dirs, _ = SLOTS[name]
        for an, ax in zip(anames, slot.axes):
            arrays[an] = np.asarray(ax, dtype=np.float64)
        arrays[vname] = np.asarray(slot.values, dtype=np.float64)
        problem = _check_slot(name, arrays)
        if problem:
            raise ContractError(f"cannot write table: {problem}")
        contracts[name] = dict(slot.info)
    meta = {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "package_version": __version__,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "vehicle": vehicle.metadata(),
        "vehicle_sha256": vehicle.fingerprint(),
        "tilt_model": tilt_model or vehicle.tilt_model,
        "contracts": contracts,
        "available": [k for k, v in contracts.items() if v is not None],
        "axes": {k: AXIS_INFO[k] for k in SLOTS if contracts[k] is not None},
        "t_react_applied_at_lookup": True,
        "method": method or {},
        "arrays_sha256": arrays_sha256(arrays),
    }
    if avoid is None:
        meta["note"] = "stop contract only: no avoid table (offboard mode unavailable)"
    buf = io.BytesIO()
    np.savez_compressed(buf, metadata_json=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    Path(path).write_bytes(buf.getvalue())
    return meta


def _check_slot(name: str, arrays: dict[str, np.ndarray]) -> str | None:
    vname, anames, dirs, _ = SLOTS[name]
    missing = [a for a in (vname, *anames) if a not in arrays]
    if missing:
        return f"{name}: missing array {missing[0]}"
    axes = [arrays[a] for a in anames]
    vals = arrays[vname]
    for an, ax in zip(anames, axes):
        if ax.ndim != 1 or len(ax) < 1 or not np.all(np.isfinite(ax)) or np.any(np.diff(ax) <= 0):
            return f"{name}: axis {an} must be finite and strictly increasing"
    if vals.shape != tuple(len(a) for a in axes):
        return f"{name}: {vname} has shape {vals.shape}, axes say {tuple(len(a) for a in axes)}"
    if name == "avoid" and (axes[0][0] <= 0 or axes[0][-1] >= 1):
        return "avoid: rho axis must lie in (0, 1)"
    if np.any(np.isnan(vals)) or np.any(vals < 0) or (name == "avoid" and not np.all(np.isfinite(vals))):
        return f"{name}: {vname} has negative, NaN or infinite values"
    if not is_monotone(vals, dirs):
        return f"{name}: {vname} is not monotone (required {dirs} along its axes)"
    return None


# ============================================================================ reader


# Bounds a table file is read within (refused before anything is read: one line, no large allocation).
# Shipped tables: 239 × 33 × 7 avoid cells, 7 KB of metadata, 81 KB on disk.
MAX_FILE_BYTES = 256 << 20  # the whole .npz on disk
MAX_AXIS_POINTS = 4096  # per axis (the shipped grids have ≤ 239)
MAX_CELLS = 1 << 22  # per value array (32 MiB of float64; the shipped tables have ≤ 56 000)
MAX_META_BYTES = 4 << 20  # the JSON metadata record (calibration provenance included)
MAX_JSON_DEPTH = 32  # nesting of the metadata (the writer's is ≤ 6)
MAX_NPY_HEADER = 4096  # an .npy member's header (numpy writes 128 bytes)
META_MEMBER, SIGNATURE_MEMBER = "metadata_json", "signature_json"
_BYTES_MEMBERS = (META_MEMBER, SIGNATURE_MEMBER)  # 1-D uint8
_AXIS_MEMBERS = {a for _, anames, _, _ in SLOTS.values() for a in anames}
_VALUE_MEMBERS = {vname: anames for vname, anames, _, _ in SLOTS.values()}


def _member_headers(zf: zipfile.ZipFile) -> dict[str, tuple]:
    """name → (ZipInfo, shape, fortran_order, dtype, header bytes) of every member, from the zip directory and
    the .npy headers only; a member that could not be a table's is refused here, before its data is read."""
    out = {}
    infos = zf.infolist()
    if len(infos) > len(_BYTES_MEMBERS) + len(_AXIS_MEMBERS) + len(_VALUE_MEMBERS):
        raise ValueError(f"{len(infos)} members (a table has at most "
                         f"{len(_BYTES_MEMBERS) + len(_AXIS_MEMBERS) + len(_VALUE_MEMBERS)})")
    for info in infos:
        name = info.filename[:-4] if info.filename.endswith(".npy") else None
        if name not in (*_BYTES_MEMBERS, *_AXIS_MEMBERS, *_VALUE_MEMBERS) or name in out:
            raise ValueError(f"member {info.filename[:60]!r} is not (or twice) a table member")
        # a zip bomb: the declared size is bounded before anything is inflated (and the reads below never take
        # more than the .npy header states, which is bounded in turn)
        if info.file_size > MAX_NPY_HEADER + 8 * MAX_CELLS + MAX_META_BYTES:
            raise ValueError(f"member {name} declares {info.file_size} bytes (a zip bomb or not a table)")
        with zf.open(info) as f:
            version = np.lib.format.read_magic(f)
            read_header = {(1, 0): np.lib.format.read_array_header_1_0}.get(version, np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = read_header(f, max_header_size=MAX_NPY_HEADER)
            out[name] = (info, tuple(int(n) for n in shape), bool(fortran), dtype, f.tell())
    for name, (_, shape, _, dtype, _) in out.items():
        if dtype.hasobject:
            raise ValueError(f"member {name} holds Python objects (a pickle): refused")
        if dtype.fields is not None or dtype.kind not in "biuf" or dtype.itemsize > 8:
            raise ValueError(f"member {name} is not numeric (dtype {dtype.str})")
        if name in _BYTES_MEMBERS:
            ok = dtype == np.uint8 and len(shape) == 1 and shape[0] <= MAX_META_BYTES
        elif name in _AXIS_MEMBERS:
            ok = dtype.kind == "f" and len(shape) == 1 and shape[0] <= MAX_AXIS_POINTS
        else:  # a value array: exactly its axes' grid
            axes = [out.get(a) for a in _VALUE_MEMBERS[name]]
            ok = dtype.kind == "f" and None not in axes and shape == tuple(ax[1][0] for ax in axes if ax[1])
            ok = ok and math.prod(shape) <= MAX_CELLS
        if not ok:
            raise ValueError(f"member {name} has shape {shape[:4]} and dtype {dtype.str}: larger than, or not, "
                             "what the table's grid implies")
    return out


def _read_member(zf: zipfile.ZipFile, header: tuple) -> np.ndarray:
    """The array of one member whose header `_member_headers` accepted: exactly the bytes it states."""
    info, shape, fortran, dtype, offset = header
    n = math.prod(shape) * dtype.itemsize
    with zf.open(info) as f:
        f.read(offset)
        data = f.read(n)
    if len(data) != n:
        raise EOFError
    return np.frombuffer(data, dtype).reshape(shape, order="F" if fortran else "C")


def _json_depth(raw: bytes) -> int:
    """The nesting depth of a JSON text, counted without parsing it (brackets outside strings)."""
    import re

    b = np.frombuffer(re.sub(rb'"(?:[^"\\]|\\.)*"', b"", raw), np.uint8)
    step = np.isin(b, (ord("["), ord("{"))).astype(np.int64) - np.isin(b, (ord("]"), ord("}")))
    return int(np.max(np.cumsum(step), initial=0))


@dataclass(frozen=True)
class _File:
    meta: dict
    arrays: dict[str, np.ndarray]
    meta_raw: bytes  # the metadata record as stored (what a signature covers, with the arrays)
    signature: dict | None  # the signature record, if signed


def _read(path: Path) -> _File:
    try:
        if not path.is_file():
            raise FileNotFoundError if not path.exists() else ValueError("not a regular file")
        if path.stat().st_size > MAX_FILE_BYTES:
            raise ValueError(f"{path.stat().st_size} bytes (a table is at most {MAX_FILE_BYTES})")
        with zipfile.ZipFile(path) as zf:
            headers = _member_headers(zf)
            arrays = {name: _read_member(zf, h) for name, h in headers.items()}
    except FileNotFoundError:
        raise ContractError(f"table {path}: no such file") from None
    except ValueError as err:
        raise ContractError(f"table {path}: refused: {' '.join(str(err).split())[:200]}") from None
    except (OSError, zipfile.BadZipFile, EOFError, KeyError, NotImplementedError, RuntimeError) as err:
        raise ContractError(f"table {path}: unreadable or truncated ({type(err).__name__})") from None
    raw = arrays.pop(META_MEMBER, None)
    if raw is None:
        raise ContractError(f"table {path}: no metadata record (not a contract-guard table)")
    sig = arrays.pop(SIGNATURE_MEMBER, None)
    meta_raw = raw.tobytes()
    if _json_depth(meta_raw) > MAX_JSON_DEPTH:
        raise ContractError(f"table {path}: metadata nested deeper than {MAX_JSON_DEPTH} levels (refused)")
    try:
        meta = json.loads(meta_raw.decode())
        assert isinstance(meta, dict)
        signature = None if sig is None else json.loads(sig.tobytes().decode())
        assert signature is None or isinstance(signature, dict)
    except (ValueError, AssertionError, RecursionError):
        raise ContractError(f"table {path}: metadata or signature is not valid JSON") from None
    return _File(meta, arrays, meta_raw, signature)


# ============================================================================ signature
# An ed25519 signature (RFC 8032, the `cryptography` package) over the metadata record as stored and the
# arrays' canonical hash: a table edited and re-hashed no longer verifies against the builder's public key.
# The hash alone (`arrays_sha256`) is integrity only.

SIGNATURE_DOMAIN = b"contract-guard/gamma-table/ed25519/v1\n"


def signed_message(meta_raw: bytes, arrays: dict[str, np.ndarray]) -> bytes:
    """What a table's signature signs: a domain tag, SHA-256 of the metadata as stored, the arrays' hash."""
    return SIGNATURE_DOMAIN + hashlib.sha256(meta_raw).hexdigest().encode() + b"\n" + arrays_sha256(arrays).encode()


def _pem(path, what: str) -> bytes:
    try:
        data = Path(path).read_bytes()[: 1 << 16]
    except OSError as err:
        raise ContractError(f"{what} {path}: cannot read it ({err.strerror or type(err).__name__})") from None
    return data


def load_private_key(path):
    """An ed25519 private key from a PEM file (`contract-guard keys --table` writes one)."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    try:
        key = load_pem_private_key(_pem(path, "table signing key"), password=None)
    except (ValueError, TypeError):
        key = None
    if not isinstance(key, Ed25519PrivateKey):
        raise ContractError(f"table signing key {path}: not an unencrypted ed25519 private key (PEM)")
    return key


def load_public_key(path):
    """An ed25519 public key from a PEM file (the `.pub` that `contract-guard keys --table` writes)."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
    from cryptography.hazmat.primitives.serialization import load_pem_public_key

    try:
        key = load_pem_public_key(_pem(path, "table public key"))
    except (ValueError, TypeError):
        key = None
    if not isinstance(key, Ed25519PublicKey):
        raise ContractError(f"table public key {path}: not an ed25519 public key (PEM)")
    return key


def key_id(public_key) -> str:
    """A short name of a public key: the first 16 hex digits of SHA-256 of its 32 raw bytes."""
    from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

    return hashlib.sha256(public_key.public_bytes(Encoding.Raw, PublicFormat.Raw)).hexdigest()[:16]


def next_serial(current: int | None, now: _dt.datetime | None = None) -> int:
    """A new signing's serial: the UTC time of signing as the integer YYYYMMDDHHMMSS (readable, and larger for a
    later signing on a clock that is right), or one more than `current` where that is larger."""
    now = now or _dt.datetime.now(_dt.timezone.utc)
    return max(int(now.strftime("%Y%m%d%H%M%S")), (current or 0) + 1)


def table_serial(meta: dict) -> int | None:
    """The serial a signed table's metadata carries (None: none, or not a positive integer)."""
    v = meta.get("serial")
    return v if isinstance(v, int) and not isinstance(v, bool) and v > 0 else None


def sign_table(path: str | Path, private_key_path, out: str | Path | None = None, serial: int | None = None) -> dict:
    """Sign a verified table (in place, or into `out`): its arrays are kept byte for byte, its metadata record gets
    the signing's `serial` (a positive integer above the table's own, default `next_serial`: the daemon refuses an
    older serial than the last it accepted) and a `signature_json` member is added (replacing an older one), over
    both. Returns the signature record (with the serial)."""
    import base64
    import os

    path = Path(path)
    key = load_private_key(private_key_path)
    verify(path)  # only a table that verifies is signed
    f = _read(path)
    old = table_serial(f.meta)
    if serial is None:
        serial = next_serial(old)
    elif isinstance(serial, bool) or not isinstance(serial, int) or serial <= 0 or serial <= (old or 0):
        raise ContractError(f"table {path}: serial {serial!r} refused: a positive integer above the table's own "
                            f"({old or 'none'}) is needed")
    meta_raw = json.dumps({**f.meta, "serial": serial}).encode()
    sig = {"algorithm": "ed25519", "key_id": key_id(key.public_key()),
           "signature": base64.b64encode(key.sign(signed_message(meta_raw, f.arrays))).decode(),
           "signed_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
    buf = io.BytesIO()
    np.savez_compressed(buf, **{META_MEMBER: np.frombuffer(meta_raw, np.uint8),
                                SIGNATURE_MEMBER: np.frombuffer(json.dumps(sig).encode(), np.uint8)}, **f.arrays)
    dest = Path(out) if out is not None else path
    tmp = dest.with_name(dest.name + ".signing")
    tmp.write_bytes(buf.getvalue())
    os.replace(tmp, dest)
    return {**sig, "serial": serial}


# metadata that says when and by which release a table was written, not what it holds: a table rebuilt
# identically differs only there (and in what signing adds)
BOOKKEEPING = ("created_utc", "package_version", "serial")


def table_differences(path: str | Path, reference: str | Path) -> list[str]:
    """What in table `path` differs from table `reference`: the arrays by name, and the metadata's keys (the
    first differing path inside each), bookkeeping aside; [] when they hold the same contract."""
    a, b = _read(Path(path)), _read(Path(reference))
    out = [f"array {n}" + (" (missing)" if n not in a.arrays else " (added)" if n not in b.arrays else "")
           for n in sorted(set(a.arrays) | set(b.arrays))
           if n not in a.arrays or n not in b.arrays or a.arrays[n].shape != b.arrays[n].shape
           or a.arrays[n].dtype != b.arrays[n].dtype or not np.array_equal(a.arrays[n], b.arrays[n], equal_nan=True)]
    for k in sorted(set(a.meta) | set(b.meta)):
        if k not in BOOKKEEPING and a.meta.get(k) != b.meta.get(k):
            out.append(f"metadata {_first_difference(a.meta.get(k), b.meta.get(k), k + '.')}")
    return out


def base_trust(path: str | Path, signer_public_key=None, public_key=None, accept_edited: bool = False) -> str:
    """Whether a table may be signed over (`table sign`) or calibrated and the result signed (`calibrate
    --sign-key`), in words: its signature verifies (with `public_key`, a PEM path or key, else the signer's own
    `signer_public_key`), or it holds exactly the shipped table of its vehicle. Else — unsigned and edited, or
    signed by a key not given — a `ContractError` naming what differs from the shipped table (or whose key it
    is), unless `accept_edited`: then the same words, said as accepted."""
    path = Path(path)
    f = _read(path)
    sig = f.signature
    if sig is not None:
        keys = [k for k in (public_key, signer_public_key) if k is not None]
        for k in keys:
            try:
                st = _check_signature(path, f, k)
                return f"signed by key {st['key_id']}, signature verified"
            except ContractError:
                continue
        why = (f"signed by key {sig.get('key_id')}, which does not verify with "
               + ("the key given" if public_key is not None else "the signing key's own public key")
               + " (give its public key: --base-public-key)")
    else:
        name = ((f.meta.get("vehicle") or {}).get("name") if isinstance(f.meta.get("vehicle"), dict) else None)
        ref = shipped_table(str(name)) if isinstance(name, str) and name.replace("-", "").replace("_", "").isalnum() \
            else None
        if ref is not None and ref.exists():
            diff = table_differences(path, ref)
            if not diff:
                return f"unsigned, identical to the shipped table of {name}"
            shown = ", ".join(diff[:6]) + (f" and {len(diff) - 6} more" if len(diff) > 6 else "")
            why = f"unsigned and not the shipped table of {name}: differs in {shown}"
        else:
            why = f"unsigned, and no shipped table of vehicle {name!r} to compare it with"
    if accept_edited:
        return f"{why} — accepted with --accept-edited-base"
    raise ContractError(f"base table {path}: {why}; refused: signing it would vouch for an edit nobody signed "
                        "(sign as you build: table build --sign-key; or accept it: --accept-edited-base)")


def _check_signature(path: Path, f: _File, public_key) -> dict:
    """The table's signature status; with `public_key` (a PEM path or key) a missing or wrong signature is refused."""
    import base64

    from cryptography.exceptions import InvalidSignature

    sig = f.signature
    status = {"signed": sig is not None, "key_id": (sig or {}).get("key_id"), "verified": False}
    if public_key is None:
        return status
    key = load_public_key(public_key) if isinstance(public_key, (str, Path)) else public_key
    if sig is None:
        raise ContractError(f"table {path}: unsigned, but a table public key is configured (key {key_id(key)}); "
                            "sign it: contract-guard table sign")
    try:
        if sig.get("algorithm") != "ed25519":
            raise InvalidSignature
        key.verify(base64.b64decode(str(sig.get("signature", "")), validate=True),
                   signed_message(f.meta_raw, f.arrays))
    except (InvalidSignature, ValueError):
        raise ContractError(f"table {path}: signature does not verify with public key {key_id(key)} (table altered "
                            "after signing, or signed by another key)") from None
    return {**status, "key_id": key_id(key), "verified": True}


def verify(path: str | Path, vehicle: Vehicle | None = None, public_key=None) -> "ContractTable":
    """Load and verify a table; raise `ContractError` (one line) if anything is wrong. With `public_key` (an
    ed25519 public key or its PEM file) the table must carry a signature that verifies with it."""
    path = Path(path)
    f = _read(path)
    meta, arrays = f.meta, f.arrays
    if meta.get("schema") != SCHEMA:
        raise ContractError(f"table {path}: not a contract-guard Γ table (schema {meta.get('schema')!r})")
    if meta.get("schema_version") != SCHEMA_VERSION:
        raise ContractError(
            f"table {path}: schema version {meta.get('schema_version')} (this reader knows {SCHEMA_VERSION})"
        )
    if arrays_sha256(arrays) != meta.get("arrays_sha256"):
        raise ContractError(f"table {path}: array hash mismatch (file altered or corrupted)")
    signature = _check_signature(path, f, public_key)
    try:
        tv = vehicle_from_dict(meta.get("vehicle"), "embedded vehicle")
    except ContractError as err:
        raise ContractError(f"table {path}: {err}") from None
    if tv.fingerprint() != meta.get("vehicle_sha256"):
        raise ContractError(f"table {path}: embedded vehicle does not match its recorded hash")
    if vehicle is not None and vehicle.fingerprint() != tv.fingerprint():
        diff = _first_difference(tv.metadata(), vehicle.metadata())
        raise ContractError(f"table {path}: built for another vehicle ({tv.name}; differs in {diff})")
    contracts = meta.get("contracts") or {}
    if not isinstance(contracts, dict) or "stop" not in contracts:
        raise ContractError(f"table {path}: metadata lists no contracts")
    slots = {}
    for name in SLOTS:
        if contracts.get(name) is None:
            continue
        problem = _check_slot(name, arrays)
        if problem:
            raise ContractError(f"table {path}: {problem}")
        vname, anames, _, _ = SLOTS[name]
        slots[name] = Slot(tuple(arrays[a] for a in anames), arrays[vname], contracts[name])
    if meta.get("tilt_model") not in ("cone", "box"):
        raise ContractError(f"table {path}: unknown tilt_model {meta.get('tilt_model')!r}")
    table = ContractTable(meta, tv, slots.get("avoid"), slots.get("e_tr_pred"), path, slots.get("e_tr_pred_stop"),
                          slots.get("e_tr_pred_brake"))
    table.signature = signature
    table.serial = table_serial(meta) if signature["signed"] else None
    return table


def shipped_table(name: str) -> Path:
    """A shipped table by vehicle name: `mambo` → contracts/data/mambo.npz."""
    return DATA_DIR / f"{name}.npz"


def shipped_vehicles() -> list[str]:
    """Names of the vehicles whose tables ship with the package."""
    return sorted(p.stem for p in DATA_DIR.glob("*.yaml") if (DATA_DIR / f"{p.stem}.npz").exists())


def load_for_vehicle(vehicle: str | Path | Vehicle | None, table_path: str | Path | None = None,
                     public_key=None) -> "ContractTable":
    """The verified table for a vehicle (shipped name, vehicle file or `Vehicle`): `table_path`, else the
    vehicle's shipped table; refused if built for another vehicle. No vehicle: `table_path` with its own.
    `public_key`: the table must be signed by its private key (`verify`)."""
    if vehicle is None:
        if table_path is None:
            raise ContractError("which aircraft? state `vehicle:` (a vehicle file, or a shipped name: "
                                f"{', '.join(shipped_vehicles())}) or a table")
        return verify(table_path, public_key=public_key)
    veh = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
    return verify(shipped_table(veh.name) if table_path is None else table_path, veh, public_key)


def _first_difference(a, b, prefix="") -> str:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if a.get(k) != b.get(k):
                return _first_difference(a.get(k), b.get(k), f"{prefix}{k}.")
    return prefix.rstrip(".") or "value"


# ============================================================================ queries


@dataclass(frozen=True)
class Omega:
    """The operating point chosen under one contract, and why."""

    contract: str  # "avoid" or "stop"
    v_max: float  # the speed limit to enforce [m/s]
    tilt: float  # tilt limit it goes with [rad]
    e_tr: float  # tracking error used (max of measured and predicted) [m]
    v_safe: float  # the contract's safe speed at that tilt and e_tr [m/s]
    gamma: float  # Γ = v_max − v_safe (≤ 0 when the contract holds)
    reason: str = "ok"  # why the answer is what it is, for the event log


# a thrust axis that starts this little above the vehicle's range bottom covers it (`sweep.grid_coverage`); the
# daemon's thrust estimate then starts at the axis' own first value (`thrust_floor`), where the lookup answers
THRUST_AXIS_TOL = 1e-9


def _columns(slot: Slot) -> tuple[list, list, list, list]:
    """A stop contract's E_tr_pred surface as Python lists for `_e_list`: (speeds, tilts, thrust ratios, the speed
    column per (tilt, thrust) cell)."""
    v, t, r = (a.tolist() for a in slot.axes)
    return v, t, r, [[slot.values[:, i, kk].tolist() for kk in range(len(r))] for i in range(len(t))]


class ContractTable:
    """A verified table with the conservative lookups of DESIGN.md §2, precomputed for its vehicle."""

    def __init__(self, meta: dict, vehicle: Vehicle, avoid: Slot | None, e_tr_pred: Slot | None, path=None,
                 e_tr_pred_stop: Slot | None = None, e_tr_pred_brake: Slot | None = None):
        self.meta, self.vehicle, self.avoid, self.e_pred, self.path = meta, vehicle, avoid, e_tr_pred, path
        # the stop contract's E_tr_pred: the governor's surface where the table has one, else the general one;
        # with the recovery brake flying the stops, the brake's surface (none: no controller contract covers it)
        self.e_pred_stop, self.e_pred_brake = e_tr_pred_stop, e_tr_pred_brake
        self._stop_slot = e_tr_pred_stop if e_tr_pred_stop is not None else e_tr_pred
        self._stop_cols = {name: _columns(slot) for name, slot in (("stop", self._stop_slot),
                                                                   ("brake", e_tr_pred_brake)) if slot is not None}
        self.signature = {"signed": False, "key_id": None, "verified": False}  # set by `verify`
        self.serial: int | None = None  # a signed table's serial (`sign_table`), set by `verify`
        self.tilt_model = meta["tilt_model"]
        v = vehicle
        self._r_body = v.r_body_m
        self._tr_lo, self._tr_hi = v.thrust_ratio_range
        self._t_dead = stop_dead_time(v)
        self._tilt_max = v.tilt_max  # read on every query (a property computing radians)
        if avoid is not None:
            self._rho, self._tilts, self._trs = avoid.axes
            self._f = avoid.values
            self._tilt_list, self._tr_list = self._tilts.tolist(), self._trs.tolist()  # for bisect
            t_r = np.array([v.reaction_time(t) for t in self._tilts])  # folded reaction per grid tilt
            v_grid = None if e_tr_pred is None else e_tr_pred.axes[0]  # the E_tr fixed point's speeds
            # one exact reaction-time solver per thrust column, over all tilts (precomputed)
            self._react = [ReactLookup(self._rho, self._f[:, :, k].T, t_r, v_grid=v_grid)
                           for k in range(len(self._trs))]
            self._law = self._scaling_law(avoid)
        if e_tr_pred is not None:
            self._ev, self._et, self._er = e_tr_pred.axes
            self._ev_l, self._et_l, self._er_l = (a.tolist() for a in e_tr_pred.axes)
            # E_tr_pred over the speed grid per (E tilt cell, thrust cell), as Python floats (`_e_list`)
            self._e_lists = [[e_tr_pred.values[:, i, kk].tolist() for kk in range(len(self._er))]
                             for i in range(len(self._et))]
            if avoid is not None:  # per E_tr thrust cell, E_tr_pred (avoid tilt, v) at each avoid tilt's E_tr cell
                e_tilt_of = np.array([hurts_index(self._et, t) for t in self._tilts])
                self._e_rows_n = int(np.count_nonzero(e_tilt_of != NONE))  # tilts above the E_tr grid: no bound
                cells = e_tilt_of[: self._e_rows_n]
                self._e_rows = [e_tr_pred.values[:, cells, kk].T.copy() for kk in range(len(self._er))]
                self._er_list = self._er.tolist()

    def warm(self) -> None:
        """Ready the compiled lookup (`ReactLookup.warm`): the daemon's start, not its first cycle."""
        for react in getattr(self, "_react", ()):
            react.warm()

    def _scaling_law(self, avoid: Slot):
        """Between grid points, the cone build's own law F = √(a_h/g)·G(ρ): where the table states it
        and every corner of a cell obeys it (`lookup.law_cells`, checked here at load over every cell), the
        answer at (tilt, thrust) scales the cell's corners to that point's a_h. Derived at load from the
        hashed arrays and the verified vehicle (nothing stored). None: worst corner only (box tables, …)."""
        if self.tilt_model != "cone" or not str(avoid.info.get("scaling", "")).startswith(LAW_CLAIM):
            return None
        v = self.vehicle
        a = np.array([[self._a_h(t, k) for k in self._tr_list] for t in self._tilt_list])
        g_hat, holds = law_cells(self._f, a)
        if not holds.any():
            return None
        h = g_hat * g_hat / (1.0 - self._rho)[:, None, None]  # h_j = a_h·Ĝ_j²/(1 − ρ_j) at a_h = 1
        hsuf = np.zeros((len(self._rho) + 1, *a.shape))
        hsuf[:-1] = np.maximum.accumulate(h[::-1], axis=0)[::-1]
        cells = [[(h[:, j, k].tolist(), hsuf[:, j, k].tolist()) if holds[j, k] else None
                  for k in range(a.shape[1])] for j in range(a.shape[0])]
        # the thrust law on the grid's own tilts (`_thrust_lam`): where the edge (j, k)–(j, k+1) obeys it
        k1 = np.minimum(np.arange(a.shape[1]) + 1, a.shape[1] - 1)
        g_n = self._f / np.sqrt(a / G)[None]
        edge = np.all(np.abs(g_n - g_n[:, :, k1]) <= 1e-12 * np.maximum(g_n, g_n[:, :, k1]), axis=0) & (a > 0)
        return {"a": a.tolist(), "a_grid": a, "cells": cells, "tilt_top": min(self._tilt_list[-1], v.tilt_max),
                "tr_top": self._tr_list[-1], "holds": holds, "g_tan": G * np.tan(self._tilts), "edge": edge,
                "acc": [thrust_limited_accel(v.t_max(x), v.mass_kg) for x in self._tr_list]}

    def _a_h(self, tilt: float, thrust_ratio: float) -> float:
        """The cone's horizontal acceleration limit min(g·tan tilt, √((T_max/m)² − g²)) (`flat.horizontal_accel_limit`)."""
        return min(G * math.tan(tilt), thrust_limited_accel(self.vehicle.t_max(thrust_ratio), self.vehicle.mass_kg))

    def _law_row(self, tilt, thrust_ratio, top, k):
        """(a_h, tilt, reaction time, cell) of the law's row at the actual (tilt, thrust), clipped to the grid's
        top, in the cell (top, k); None where the law does not hold there or adds nothing (a grid point)."""
        law = self._law
        if law is None or law["cells"][top][k] is None:
            return None
        tilt = min(tilt, law["tilt_top"])
        lam = self._a_h(tilt, min(thrust_ratio, law["tr_top"]))
        if not lam > law["a"][top][k] * (1.0 + 1e-12):
            return None
        return lam, tilt, self.vehicle.reaction_time(tilt), law["cells"][top][k]

    def _thrust_lam(self, thrust_ratio, top, k):
        """Per grid tilt 0 … top, the thrust law's a_h(tilt_j, thrust)/a_h(tilt_j, thrust_k) (≥ 1; 1 where the
        edge does not obey it), or None where thrust binds at no row (all 1: the grid's rows as they are)."""
        law = self._law
        if law is None or law["acc"][k] >= law["g_tan"][top]:  # thrust limits no row at the corner
            return None
        acc = thrust_limited_accel(self.vehicle.t_max(min(thrust_ratio, law["tr_top"])), self.vehicle.mass_kg)
        if not acc > law["acc"][k]:
            return None
        lam = np.minimum(law["g_tan"][: top + 1], acc) / law["a_grid"][: top + 1, k]
        return np.where(law["edge"][: top + 1, k], lam, 1.0)

    def _law_speed(self, row, k, c0, r_k) -> float:
        """The reaction-time fixed point on the law's row (`lookup.react_speed`), times LAW_MARGIN."""
        lam, _, t_r, (h, hsuf) = row
        react = self._react[k]
        return react_speed(c0, r_k, t_r, lam, react._rho_l, react._u_l, h, hsuf) * LAW_MARGIN

    # ---- shape of the table
    @property
    def etr_offboard_cap(self) -> float | None:
        """The factor on V_safe at which the E_tr sweep flew the online planner's plans (`online@ρ`, recorded
        in the E_tr_pred slot); None without an E_tr_pred slot or an older record. Offboard must not fly a
        larger factor than its controller contract was flown at."""
        if self.e_pred is None:
            return None
        cap = ((self.e_pred.info.get("grid") or {}).get("online") or {}).get("offboard_cap")
        return float(cap) if isinstance(cap, (int, float)) and math.isfinite(cap) and 0 < cap <= 1 else None

    def thrust_floor(self, contract: str = "avoid") -> float:
        """The lowest thrust_ratio the lookups of `contract` answer for: the vehicle's range bottom (`_bad_inputs`),
        raised to the bottom of each thrust axis the lookup reads — the avoid table's (avoid contract) and
        E_tr_pred's (both). Below it Ω has no safe speed (`helps_index` answers NONE)."""
        axes = [self._er_l[0]] if self.e_pred is not None else []
        if contract == "avoid" and self.avoid is not None:
            axes.append(self._tr_list[0])
        return max([self._tr_lo, *axes])

    @property
    def available(self) -> list[str]:
        return ["stop"] + [n for n, s in (("avoid", self.avoid), ("e_tr_pred", self.e_pred),
                                          ("e_tr_pred_stop", self.e_pred_stop),
                                          ("e_tr_pred_brake", self.e_pred_brake)) if s is not None]

    # ---- raw conservative lookups
    def f_lookup(self, rho: float, tilt: float, thrust_ratio: float) -> float:
        """F at the worst grid corner (0 where the grid has no answer)."""
        if self.avoid is None:
            raise ContractError("this table carries no avoid contract")
        i, j, k = hurts_index(self._rho, rho), helps_index(self._tilts, tilt), helps_index(self._trs, thrust_ratio)
        return 0.0 if NONE in (i, j, k) else float(self._f[i, j, k])

    def e_tr_pred(self, v: float, tilt: float, thrust_ratio: float, contract: str = "avoid") -> float:
        """E_tr_pred at the worst grid corner (inf where the grid has no answer; 0 if no slot); `contract` "stop":
        the governor's surface where the table has one; "brake": the governor's with its recovery brake (inf
        without that surface: no controller contract covers the brake)."""
        if contract == "brake":
            if self.e_pred_brake is None:
                return math.inf
            slot = self.e_pred_brake
        else:
            slot = self._stop_slot if contract == "stop" else self.e_pred
        if slot is None:
            return 0.0
        ev, et, er = slot.axes
        i, j, k = hurts_index(ev, v), hurts_index(et, tilt), helps_index(er, thrust_ratio)
        return math.inf if NONE in (i, j, k) else float(slot.values[i, j, k])

    # ---- contract speeds
    def _bad_inputs(self, d_od, r_obst, e_tr, thrust_ratio, tilt=0.0) -> str | None:
        try:
            if not math.isfinite(d_od + r_obst + e_tr + thrust_ratio + tilt) and not all(
                    math.isfinite(x) for x in (d_od, r_obst, e_tr, thrust_ratio, tilt)):  # (the sum can overflow)
                return "non-finite input"
        except TypeError:
            return "non-numeric input"
        if d_od < 0 or r_obst < 0 or e_tr < 0 or tilt < 0:
            return "negative input"
        if thrust_ratio < self._tr_lo:
            return f"thrust_ratio {thrust_ratio:.3g} below the vehicle's range (no safe speed)"
        return None

    def _avoid_cells(self, tilt, thrust_ratio):
        """The worst-corner grid tilt of `tilt` (a tilt limit also allows every smaller grid tilt, whose
        folded reaction time is shorter) and the thrust index (`helps_index`); top NONE: no answer."""
        k = bisect_right(self._tr_list, thrust_ratio) - 1
        top = bisect_right(self._tilt_list, min(tilt, self._tilt_max)) - 1
        return (NONE if k == NONE else top), k

    def v_safe(self, d_od, r_obst, e_tr, tilt, thrust_ratio) -> float:
        """Avoid-contract speed with the reaction-time fixed point V ≤ V_safe(d_od − V·t_react)."""
        if self.avoid is None:
            raise ContractError("this table carries no avoid contract")
        if self._bad_inputs(d_od, r_obst, e_tr, thrust_ratio, tilt):
            return 0.0
        top, k = self._avoid_cells(tilt, thrust_ratio)
        if top == NONE:
            return 0.0
        c0, r_k, react = d_od + r_obst, r_obst + e_tr + self._r_body, self._react[k]
        row, lam = self._law_row(tilt, thrust_ratio, top, k), self._thrust_lam(thrust_ratio, top, k)
        if row is not None:  # the law's row, then any grid tilt ≤ top that beats it (a shorter reaction time)
            return react.best(c0, r_k, top + 1, self._law_speed(row, k, c0, r_k), lam)
        return react.best(c0, r_k, top, react.at(c0, r_k, top, 1.0 if lam is None else float(lam[top])), lam)

    def v_stop(self, d_od, r_obst, e_tr, thrust_ratio, tilt=None, t_cmd=0.0) -> float:
        """Stop-contract speed (closed form, contracts/stop.py), at the autopilot's tilt unless given; `t_cmd`: the
        command-delivery budget [s] added to the dead time (the Hold re-sent until it arrives)."""
        tilt = self._tilt_max if tilt is None else tilt
        if self._bad_inputs(d_od, r_obst, e_tr, thrust_ratio, tilt):
            return 0.0
        return self._stop(d_od, e_tr, self._hold_brake(thrust_ratio, tilt, t_cmd))

    def _hold_brake(self, thrust_ratio: float, tilt: float, t_cmd: float = 0.0) -> tuple[float, float, float]:
        """(a, j, t_r) of the autopilot's Hold: its braking deceleration at this thrust and tilt, its jerk, the
        dead time (contracts/stop.py) with the command-delivery budget `t_cmd`."""
        return (braking_decel(self.vehicle, min(thrust_ratio, self._tr_hi), tilt), self.vehicle.braking.jerk_max_m_s3,
                self._t_dead + t_cmd)

    def _stop(self, d_od: float, e_tr: float, brake: tuple[float, float, float], a0_max: float = math.inf) -> float:
        """The joint bound's speed (`approach_stop_speed`) for the stop `brake` = (a, j, t_r), the approach's
        acceleration at most `a0_max`."""
        return approach_stop_speed(d_od - e_tr - self._r_body, *brake, a0_max)

    def _e_list(self, tilt, thrust_ratio, stop: str | None = None):
        """E_tr_pred over the speed grid at the worst corner of (tilt, thrust), a list; None: no bound (∞).
        `stop`: of a stop contract's surface ("stop": the governor's where the table has one; "brake": the
        governor's with its recovery brake)."""
        et, er, lists = (self._stop_cols[stop][1:] if stop else (self._et_l, self._er_l, self._e_lists))
        i, kk = bisect_left(et, tilt), bisect_right(er, thrust_ratio) - 1
        return None if i == len(et) or kk == NONE else lists[i][kk]

    # ---- operating point Ω
    def omega(self, d_od, r_obst, e_tr_meas, thrust_ratio, contract="avoid", tilt=None, recovery_dt=None,
              a0_max=None, t_cmd=0.0, t_silent=0.0, e_brake=False) -> Omega:
        """Ω = (V_max, tilt) maximising V_max subject to Γ ≤ 0, with e_tr = max(measured, E_tr_pred(V_max)).

        `tilt` caps the tilt (default: the vehicle's limit); the avoid contract picks the best grid tilt
        up to it, the stop contract brakes at it. `recovery_dt` (the stop contract): the daemon's recovery brake
        stops, its loop period that [s] (contracts/stop.py `recovery_brake`); None: the autopilot's Hold.
        `a0_max` (the stop contract): the approach's acceleration is held below it (the governor's approach ramp,
        contracts/stop.py `ramp_accel`); None: any approach the autopilot's smoothing flies. `t_cmd` (the stop
        contract): the command-delivery budget [s], added to the stop's dead time. `t_silent`: the obstacle sensors'
        silence budget [s], the time the vehicle may fly on a last reading before a dead sensor is noticed: dead
        time of the stop (added to it, as `t_cmd`) and reaction time of the avoid contract
        (V ≤ V_safe(d_od − V·t_silent), `_omega_silent`). `e_brake` (the stop contract): the recovery brake flies
        the stops, so E_tr_pred is its surface (`e_tr_pred_brake`; without it, no safe speed).
        Safe-first: any doubt → 0.
        """
        tilt = self._tilt_max if tilt is None else tilt
        bad = self._bad_inputs(d_od, r_obst, e_tr_meas, thrust_ratio, tilt)
        if not bad and contract == "avoid" and self.avoid is None:
            bad = "no avoid contract in this table"
        if bad:
            return Omega(contract, 0.0, tilt if math.isfinite(tilt) else 0.0, e_tr_meas, 0.0, 0.0, bad)
        if contract == "avoid":
            return self._omega_silent(d_od, t_silent, lambda d: self._omega_avoid(d, r_obst, e_tr_meas, thrust_ratio,
                                                                                    tilt))
        return self._omega_stop(d_od, e_tr_meas, thrust_ratio, tilt, recovery_dt, a0_max, t_cmd + t_silent,
                                "brake" if e_brake else "stop")

    @staticmethod
    def _omega_silent(d_od: float, t_silent: float, omega_at) -> Omega:
        """Ω with `t_silent` of reaction time more: the largest V with V ≤ V_safe(d_od − V·t_silent), as the
        reaction-time fold (DESIGN.md §2), from `omega_at(d)` (Ω at detection range d, its V_max not decreasing
        with d). V₀ = V(d_od) bounds it; V₁ = V(d_od − V₀·t_silent) ≤ V₀ is safe at its own speed (a shorter D_od
        never gives a higher V_max); between them a bisection keeps the largest speed found safe at its own
        range (to SILENT_TOL_M_S), answered with the Ω of that range, its V_max lowered to that speed."""
        om0 = omega_at(d_od)
        if t_silent <= 0.0 or om0.v_max <= 0.0:
            return om0
        best = omega_at(max(d_od - om0.v_max * t_silent, 0.0))
        lo, hi = best.v_max, om0.v_max
        while hi - lo > SILENT_TOL_M_S:
            mid = 0.5 * (lo + hi)
            om = omega_at(max(d_od - mid * t_silent, 0.0))
            if om.v_max >= mid:
                lo, best = mid, replace(om, v_max=mid, gamma=mid - om.v_safe)
            else:
                hi = mid
        return best

    def _omega_avoid(self, d_od, r_obst, e_meas, thrust_ratio, tilt) -> Omega:
        top, k = self._avoid_cells(tilt, thrust_ratio)
        if top == NONE:
            return Omega("avoid", 0.0, tilt, e_meas, 0.0, 0.0, "tilt or thrust below the table's grid")
        react, c0, r0 = self._react[k], d_od + r_obst, r_obst + self._r_body
        lam = self._thrust_lam(thrust_ratio, top, k)  # None unless thrust binds at a grid tilt ≤ top
        if self.e_pred is None:
            lim = react(c0, np.full((top + 1, 1), r0 + e_meas), slice(0, top + 1), lam)[:, 0]
            best = int(np.argmax(lim))  # ties → the smaller tilt
            v_max, e_b, v_s = float(lim[best]), e_meas, float(lim[best])
        else:
            kk = bisect_right(self._er_list, thrust_ratio) - 1
            rows = min(top + 1, self._e_rows_n)  # tilts with an E_tr bound (the others: no safe speed)
            if kk == NONE or rows == 0:
                best, v_max, e_b, v_s = 0, 0.0, math.inf, 0.0
            else:  # e_tr = max(measured, E_tr_pred) on the speed grid, the fixed point solved on it
                e = np.maximum(self._e_rows[kk][:rows], e_meas)
                best, jv, v_max, v_s = react.step_fixed_point(c0, r0 + e, lam)
                e_b = float(e[best, jv])
        tilt_b = float(self._tilts[best])
        row = self._law_row(tilt, thrust_ratio, top, k)
        if row is not None:  # the law's row at the actual tilt and thrust, if it beats the grid's (ties: the grid)
            v_l, e_l, s_l = self._law_omega(row, k, c0, r0, e_meas, thrust_ratio)
            if v_l > v_max:
                v_max, e_b, v_s, tilt_b = v_l, e_l, s_l, row[1]
        reason = "ok" if v_max > 0 else "no safe speed at this D_od, R_obst, E_tr"
        return Omega("avoid", v_max, tilt_b, e_b, v_s, v_max - v_s, reason)

    def _law_omega(self, row, k, c0, r0, e_meas, thrust_ratio):
        """(V, e_tr, V_safe) of the E_tr fixed point on the law's row (E_tr_pred at its worst corner)."""
        if self.e_pred is None:
            v = self._law_speed(row, k, c0, r0 + e_meas)
            return v, e_meas, v
        col = self._e_list(row[1], thrust_ratio)
        if col is None:
            return 0.0, math.inf, 0.0
        lim = lambda j: self._law_speed(row, k, c0, r0 + max(col[j], e_meas))  # noqa: E731
        lam, _, t_r, (_, hsuf) = row
        rho, c0p, ev = self._react[k]._rho_l, max(c0, 0.0), self._ev_l

        def decide(j):  # v_j ≥ lim_j for sure where the unscaled speed misses v_j/(MARGIN·LAW_MARGIN) by 1e-9
            v = ev[j]
            if not v > 0.0:
                return None
            w = v / (MARGIN * LAW_MARGIN)
            r = r0 + max(col[j], e_meas)
            if not reaches(c0p, r, w * (1.0 - 1e-9), t_r, lam, rho, hsuf):
                return True
            if reaches(c0p, r, w * (1.0 + 1e-9), t_r, lam, rho, hsuf):
                return False
            return None

        v, j, lim_j = crossing_fixed_point(ev, lim, decide)
        return v, max(col[j], e_meas), lim_j

    def _omega_stop(self, d_od, e_meas, thrust_ratio, tilt, recovery_dt=None, a0_max=None, t_cmd=0.0,
                    surface: str = "stop") -> Omega:
        tilt, tr = min(tilt, self._tilt_max), min(thrust_ratio, self._tr_hi)
        brake = self._hold_brake(tr, tilt, t_cmd) if recovery_dt is None else \
            recovery_brake(self.vehicle, tr, recovery_dt, tilt, t_cmd)
        a0_max = math.inf if a0_max is None else a0_max
        if surface == "brake" and surface not in self._stop_cols:
            return Omega("stop", 0.0, tilt, math.inf, 0.0, 0.0, "no E_tr_pred for the recovery brake in this table")
        if surface not in self._stop_cols:
            v = self._stop(d_od, e_meas, brake, a0_max)
            v_max, e_b, v_s = v, e_meas, v
        else:
            col = self._e_list(tilt, thrust_ratio, stop=surface)
            if col is None:  # no E_tr bound at this tilt or thrust: no safe speed
                v_max, e_b, v_s = 0.0, math.inf, 0.0
            else:
                lim = lambda k: self._stop(d_od, max(col[k], e_meas), brake, a0_max)  # noqa: E731
                v_max, k, v_s = crossing_fixed_point(self._stop_cols[surface][0], lim)
                e_b = max(col[k], e_meas)
        reason = "ok" if v_max > 0 else "no safe speed at this D_od, E_tr"
        return Omega("stop", v_max, tilt, e_b, v_s, v_max - v_s, reason)

    def gamma(self, v_max, d_od, r_obst, e_tr_meas, thrust_ratio, tilt=None, contract="avoid", t_cmd=0.0) -> float:
        """Γ = V_max − V_safe at a proposed V_max (e_tr = max(measured, E_tr_pred(V_max)))."""
        tilt = self._tilt_max if tilt is None else tilt
        e = max(e_tr_meas, self.e_tr_pred(v_max, tilt, thrust_ratio, contract))
        if not math.isfinite(e):
            return math.inf
        if contract == "avoid":
            return float(v_max - self.v_safe(d_od, r_obst, e, tilt, thrust_ratio))
        return float(v_max - self.v_stop(d_od, r_obst, e, thrust_ratio, tilt, t_cmd))
