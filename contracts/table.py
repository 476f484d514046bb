"""The Γ table: one `.npz` holding the contract's arrays and a JSON metadata record (DESIGN.md §4.7).

Slots:
- `avoid` (offboard, the daemon can brake and swerve): F(ρ; tilt, thrust_ratio) in the reduced form
  V_safe = √(g·c)·F(r_k/c), built at t_react = 0 (the lookup applies the reaction time);
- `e_tr_pred` (the controller contract, Figure 12): E_tr_pred(v_max, tilt, thrust_ratio);
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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ContractError
from .lookup import NONE, helps_index, hurts_index, is_monotone, react_fixed_point, step_fixed_point
from .stop import braking_decel, stop_dead_time, stop_speed
from .vehicle import G, Vehicle, vehicle_from_dict

SCHEMA = "contract-guard/gamma-table"
SCHEMA_VERSION = 1
MAX_REPAIR_FRACTION = 0.01  # the build fails if more cells than this needed a monotonicity repair

# slot → (value array, axis arrays, per-axis monotone direction of the values, safe repair direction)
SLOTS = {
    "avoid": ("avoid_f", ("avoid_rho", "avoid_tilt", "avoid_thrust_ratio"), (-1, +1, +1), "down"),
    "e_tr_pred": ("etr_e", ("etr_v", "etr_tilt", "etr_thrust_ratio"), (+1, +1, -1), "up"),
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


# ============================================================================ writer


def write_table(
    path: str | Path,
    vehicle: Vehicle,
    *,
    tilt_model: str | None = None,
    avoid: Slot | None = None,
    e_tr_pred: Slot | None = None,
    method: dict | None = None,
) -> dict:
    """Write a table; refuses slots that are not monotone (repair them first, `lookup.repair_monotone`)."""
    arrays: dict[str, np.ndarray] = {}
    contracts: dict[str, dict | None] = {
        "stop": {
            "method": "closed-form jerk-limited braking (contracts/stop.py)",
            "braking": vehicle.braking.model_dump(),
        }
    }
    for name, slot in (("avoid", avoid), ("e_tr_pred", e_tr_pred)):
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


def _read(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise ContractError(f"table {path}: no such file") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as err:
        raise ContractError(f"table {path}: unreadable or truncated ({type(err).__name__})") from None
    raw = arrays.pop("metadata_json", None)
    if raw is None:
        raise ContractError(f"table {path}: no metadata record (not a contract-guard table)")
    try:
        meta = json.loads(raw.tobytes().decode())
        assert isinstance(meta, dict)
    except (ValueError, AssertionError):
        raise ContractError(f"table {path}: metadata is not valid JSON") from None
    return meta, arrays


def verify(path: str | Path, vehicle: Vehicle | None = None) -> "ContractTable":
    """Load and verify a table; raise `ContractError` (one line) if anything is wrong."""
    path = Path(path)
    meta, arrays = _read(path)
    if meta.get("schema") != SCHEMA:
        raise ContractError(f"table {path}: not a contract-guard Γ table (schema {meta.get('schema')!r})")
    if meta.get("schema_version") != SCHEMA_VERSION:
        raise ContractError(
            f"table {path}: schema version {meta.get('schema_version')} (this reader knows {SCHEMA_VERSION})"
        )
    if arrays_sha256(arrays) != meta.get("arrays_sha256"):
        raise ContractError(f"table {path}: array hash mismatch (file altered or corrupted)")
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
    return ContractTable(meta, tv, slots.get("avoid"), slots.get("e_tr_pred"), path)


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


class ContractTable:
    """A verified table with the conservative lookups of DESIGN.md §2, precomputed for its vehicle."""

    def __init__(self, meta: dict, vehicle: Vehicle, avoid: Slot | None, e_tr_pred: Slot | None, path=None):
        self.meta, self.vehicle, self.avoid, self.e_pred, self.path = meta, vehicle, avoid, e_tr_pred, path
        self.tilt_model = meta["tilt_model"]
        v = vehicle
        self._r_body = v.r_body_m
        self._tr_lo, self._tr_hi = v.thrust_ratio_range
        if avoid is not None:
            self._rho, self._tilts, self._trs = avoid.axes
            self._f = avoid.values
            self._t_r = np.array([v.reaction_time(t) for t in self._tilts])  # folded reaction per grid tilt

    # ---- shape of the table
    @property
    def available(self) -> list[str]:
        return ["stop"] + [n for n, s in (("avoid", self.avoid), ("e_tr_pred", self.e_pred)) if s is not None]

    # ---- raw conservative lookups
    def f_lookup(self, rho: float, tilt: float, thrust_ratio: float) -> float:
        """F at the worst grid corner (0 where the grid has no answer)."""
        if self.avoid is None:
            raise ContractError("this table carries no avoid contract")
        i, j, k = hurts_index(self._rho, rho), helps_index(self._tilts, tilt), helps_index(self._trs, thrust_ratio)
        return 0.0 if NONE in (i, j, k) else float(self._f[i, j, k])

    def e_tr_pred(self, v: float, tilt: float, thrust_ratio: float) -> float:
        """E_tr_pred at the worst grid corner (inf where the grid has no answer; 0 if no slot)."""
        if self.e_pred is None:
            return 0.0
        vg, tg, rg = self.e_pred.axes
        i, j, k = hurts_index(vg, v), hurts_index(tg, tilt), helps_index(rg, thrust_ratio)
        return math.inf if NONE in (i, j, k) else float(self.e_pred.values[i, j, k])

    # ---- contract speeds
    def _bad_inputs(self, d_od, r_obst, e_tr, thrust_ratio, tilt=0.0) -> str | None:
        vals = (d_od, r_obst, e_tr, thrust_ratio, tilt)
        if not all(isinstance(x, (int, float, np.floating, np.integer)) and math.isfinite(x) for x in vals):
            return "non-finite input"
        if d_od < 0 or r_obst < 0 or e_tr < 0 or tilt < 0:
            return "negative input"
        if thrust_ratio < self._tr_lo:
            return f"thrust_ratio {thrust_ratio:.3g} below the vehicle's range (no safe speed)"
        return None

    def v_safe(self, d_od, r_obst, e_tr, tilt, thrust_ratio) -> float:
        """Avoid-contract speed with the reaction-time fixed point V ≤ V_safe(d_od − V·t_react)."""
        if self._bad_inputs(d_od, r_obst, e_tr, thrust_ratio, tilt):
            return 0.0
        j, k = helps_index(self._tilts, min(tilt, self.vehicle.tilt_max)), helps_index(self._trs, thrust_ratio)
        if NONE in (j, k):
            return 0.0
        r_k = r_obst + e_tr + self._r_body
        # A tilt limit also allows every smaller tilt, whose folded reaction time is shorter: the
        # answer is the best grid tilt up to the limit (keeps V_safe non-decreasing in tilt).
        f = self._f[:, : j + 1, k].T  # (j+1, n_rho)
        return float(np.max(react_fixed_point(d_od + r_obst, r_k, self._rho, f, self._t_r[: j + 1], enclosing=True)))

    def v_stop(self, d_od, r_obst, e_tr, thrust_ratio, tilt=None) -> float:
        """Stop-contract speed (closed form, contracts/stop.py)."""
        tilt = self.vehicle.tilt_max if tilt is None else tilt
        if self._bad_inputs(d_od, r_obst, e_tr, thrust_ratio, tilt):
            return 0.0
        return float(self._stop(d_od, np.asarray(e_tr, dtype=float), min(thrust_ratio, self._tr_hi), tilt))

    def _stop(self, d_od, e_tr, thrust_ratio, tilt):
        v = self.vehicle
        a = braking_decel(v, thrust_ratio, tilt)
        return stop_speed(d_od - e_tr - self._r_body, a, v.braking.jerk_max_m_s3, stop_dead_time(v))

    # ---- operating point Ω
    def omega(self, d_od, r_obst, e_tr_meas, thrust_ratio, contract="avoid", tilt=None) -> Omega:
        """Ω = (V_max, tilt) maximising V_max subject to Γ ≤ 0, with e_tr = max(measured, E_tr_pred(V_max)).

        `tilt` fixes the tilt; otherwise the avoid contract picks the best tilt of its grid up to the
        vehicle's limit and the stop contract uses the autopilot's limit. Safe-first: any doubt → 0.
        """
        t_fix = tilt
        tilt = self.vehicle.tilt_max if tilt is None else tilt
        bad = self._bad_inputs(d_od, r_obst, e_tr_meas, thrust_ratio, tilt)
        if contract == "avoid" and self.avoid is None:
            bad = bad or "no avoid contract in this table"
        if bad:
            return Omega(contract, 0.0, 0.0 if not math.isfinite(tilt) else tilt, e_tr_meas, 0.0, 0.0, bad)
        # candidate tilts and their speed-limit function of e_tr (vectorised over an array of e)
        if contract == "avoid":
            k = helps_index(self._trs, thrust_ratio)
            top = min(tilt, self.vehicle.tilt_max)
            js = [helps_index(self._tilts, top)] if t_fix is not None else list(
                range(helps_index(self._tilts, top) + 1)
            )
            js = [j for j in js if j != NONE]
            if k == NONE or not js:
                return Omega(contract, 0.0, tilt, e_tr_meas, 0.0, 0.0, "tilt or thrust below the table's grid")
            tilts = self._tilts[js]

            def limit(e, idx):  # e: (len(idx), n) errors → (len(idx), n) speeds
                j = np.asarray(js)[idx]
                f = self._f[:, j, k].T[:, None, :]  # (len(idx), 1, n_rho)
                return react_fixed_point(d_od + r_obst, r_obst + e + self._r_body, self._rho, f, self._t_r[j][:, None],
                                         enclosing=True)
        else:
            tilts = np.array([min(tilt, self.vehicle.tilt_max)])
            tr = min(thrust_ratio, self._tr_hi)

            def limit(e, idx):
                return self._stop(d_od, e, tr, tilts[0])

        idx = np.arange(len(tilts))
        if self.e_pred is None:
            e_used = np.full((len(tilts), 1), float(e_tr_meas))
            v_cand = limit(e_used, idx)[:, 0]
        else:
            vg, tg, rg = self.e_pred.axes
            kk = helps_index(rg, thrust_ratio)
            jj = np.array([hurts_index(tg, t) for t in tilts])
            if kk == NONE:
                e_grid = np.full((len(tilts), len(vg)), np.inf)
            else:
                e_grid = np.where(jj[:, None] == NONE, np.inf, self.e_pred.values[:, jj, kk].T)
            e_used = np.maximum(e_grid, e_tr_meas)  # (n_tilt, n_v)
            finite = np.isfinite(e_used)
            lim = np.where(finite, limit(np.where(finite, e_used, 0.0), idx), 0.0)
            v_cand, jv = step_fixed_point(vg, lim)
            e_used = np.take_along_axis(e_used, jv[:, None], axis=1)
        best = int(np.argmax(v_cand))  # ties → the smaller tilt (first)
        v_max = float(v_cand[best])
        e_b = float(e_used[best, 0])
        v_safe = float(limit(np.array([[e_b]]), np.array([best]))[0, 0]) if math.isfinite(e_b) else 0.0
        reason = "ok" if v_max > 0 else "no safe speed at this D_od, R_obst, E_tr"
        return Omega(contract, v_max, float(tilts[best]), e_b, v_safe, v_max - v_safe, reason)

    def gamma(self, v_max, d_od, r_obst, e_tr_meas, thrust_ratio, tilt=None, contract="avoid") -> float:
        """Γ = V_max − V_safe at a proposed V_max (e_tr = max(measured, E_tr_pred(V_max)))."""
        tilt = self.vehicle.tilt_max if tilt is None else tilt
        e = max(e_tr_meas, self.e_tr_pred(v_max, tilt, thrust_ratio))
        if not math.isfinite(e):
            return math.inf
        vs = self.v_safe(d_od, r_obst, e, tilt, thrust_ratio) if contract == "avoid" else self.v_stop(
            d_od, r_obst, e, thrust_ratio, tilt
        )
        return float(v_max - vs)
