"""What `run` checks of its inputs before it opens the link, beyond each file's own validation: the same checks
for `run --check` (which changes nothing) and for `run` (which then records what it accepted).

- the configured nominal hover throttle against the vehicle file's (`hover_nominal_problem`);
- the signing key file, readable and well formed (`link.signing_key_file`);
- the table's serial against the last one accepted (`TableSerial`): a signed table carries a serial in its
  signed metadata (`contracts.table.sign_table`); the daemon keeps the largest it has accepted in a small state
  file and refuses an older one (a table copied back over the one in service: a rollback) unless the config says
  `allow_table_rollback: true`, which is then said as WEAKENED in the banner and logged (`table_rollback`).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from contracts.errors import ContractError
from contracts.yamlfile import read_bounded

from .config import Config

# thrust.hover_throttle_nominal may exceed the vehicle file's controller.thr_hover by at most this fraction of it.
# The estimator reads thrust_ratio = nominal / measured hover throttle, capped at the top of the range
# (`estimators.ThrustEstimator`): a nominal k times the file's reads every thrust_ratio k times too high, so a
# thrust loss down to 1/k of the nominal is never seen (thrust_ratio stays pinned at the top; at 0.99 against the
# X500's 0.585, a loss of 41 %). 5 %: what goes unseen stays within one step of the shipped tables' thrust axis
# (0.05 of T_nom), the resolution the contract is looked up at anyway. A lower nominal reads as less thrust
# (slower, never optimistic), so there is no lower bound beyond the config's own (> 0).
HOVER_NOMINAL_MAX_ABOVE = 0.05
STATE_FILE = "table-serial.json"  # beside link.signing_timestamp_file when table_state_file is not configured


def hover_nominal_problem(cfg: Config, vehicle) -> str | None:
    """Why `thrust.hover_throttle_nominal` is refused for `vehicle` (one line), or None. The bound is
    `HOVER_NOMINAL_MAX_ABOVE` above the vehicle file's `controller.thr_hover` (see there)."""
    h = cfg.thrust.hover_throttle_nominal
    if h is None or cfg.thrust.source != "hover":
        return None
    file_h = vehicle.controller.thr_hover
    top = file_h * (1.0 + HOVER_NOMINAL_MAX_ABOVE)
    if h > top:
        return (f"thrust.hover_throttle_nominal: {h:g} is above the vehicle file's controller.thr_hover {file_h:g} "
                f"by more than {HOVER_NOMINAL_MAX_ABOVE:.0%} (at most {top:.3f}): thrust_ratio would read "
                f"{h / file_h:.2f} times too high, a thrust loss of up to {1 - file_h / h:.0%} never seen")
    return None


def state_path(cfg: Config) -> Path | None:
    """Where the last accepted table serial is kept: `table_state_file`, else beside the signing timestamp file,
    else nowhere (rollback not checked, said in the banner)."""
    if cfg.table_state_file is not None:
        return Path(cfg.table_state_file)
    ts = cfg.link.signing_timestamp_file
    return Path(ts).parent / STATE_FILE if ts is not None else None


@dataclass
class TableSerial:
    """The table's serial judged against the last accepted one (`judge`), and recorded once `run` starts
    (`accept`). `lines`: what the banner says of it; `rollback`: an older table flown by
    `allow_table_rollback` (None: not a rollback)."""

    path: Path | None
    serial: int | None
    arrays_sha256: str | None
    table: str
    last: dict | None = None
    lines: list[str] = field(default_factory=list)
    rollback: dict | None = None

    @classmethod
    def judge(cls, cfg: Config, table) -> "TableSerial":
        """Raises ContractError (one line) for a table older than the last accepted, unless allowed."""
        path = state_path(cfg)
        me = cls(path, table.serial, table.meta.get("arrays_sha256"), str(table.path))
        shown = f"serial {me.serial}" if me.serial is not None else "no serial (unsigned)"
        if path is None:
            if me.serial is not None:
                me.lines.append(f"table {shown}: rollback to an older table not checked (no state file: set "
                                "table_state_file, or link.signing_timestamp_file)")
            return me
        me.last = _read_state(path)
        if me.last is None:
            me.lines.append(f"table {shown}: the first accepted (state file {path})")
            return me
        last = me.last["serial"]
        older = (me.serial or 0) < last
        other = me.serial == last and me.arrays_sha256 != me.last.get("arrays_sha256")
        if not (older or other):
            me.lines.append(f"table {shown}; last accepted serial {last} (state file {path})")
            return me
        why = (f"table {table.path}: {shown}, " + (f"older than serial {last}" if older else
               f"another table with the serial of the last accepted ({last})")
               + f", accepted from {me.last.get('table')} on {me.last.get('accepted_utc')} (state file {path})")
        if not cfg.allow_table_rollback:
            raise ContractError(f"{why}: refused as a rollback; fly the newer table, or state "
                                "allow_table_rollback: true (said as WEAKENED at every start)")
        me.rollback = {"serial": me.serial, "last_serial": last, "last_table": me.last.get("table"),
                       "state_file": str(path)}
        me.lines.append(f"WEAKENED allow_table_rollback: {why}; flown because the config allows a rollback")
        return me

    def accept(self) -> None:
        """Record the serial as the last accepted (never lowering it: a rollback flown by permission stays one)."""
        if self.path is None or self.rollback is not None or self.serial is None:
            return  # an unsigned table has no serial to record
        if self.last is not None and (self.serial or 0) <= self.last["serial"]:
            return
        data = {"serial": self.serial, "arrays_sha256": self.arrays_sha256, "table": self.table,
                "accepted_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
        tmp = self.path.with_name(self.path.name + ".new")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(data) + "\n")
            os.replace(tmp, self.path)
        except OSError as err:
            raise ContractError(f"table state file {self.path}: cannot write ({err.strerror or err})") from None


def _read_state(path: Path) -> dict | None:
    """The last accepted serial's record; None when there is none yet. A damaged file is refused (one line):
    forgetting the serial would accept any older table."""
    if not path.exists():
        return None
    raw = read_bounded(path, "table state file", limit=64 * 1024)
    try:
        data = json.loads(raw.decode())
        assert isinstance(data, dict) and isinstance(data.get("serial"), int) and not isinstance(data["serial"], bool)
    except (ValueError, AssertionError, UnicodeDecodeError):
        raise ContractError(f"table state file {path}: not the daemon's record of the last table serial (damaged?); "
                            "refused: check the table in service, then remove the file to accept it afresh") from None
    return data


@dataclass
class Inputs:
    """The checked inputs: the banner's lines on them and the table serial to record."""

    lines: list[str]
    serial: TableSerial
    signing_key: bytes | None


def check_inputs(cfg: Config, table) -> Inputs:
    """Everything `run` refuses before it opens the link, beyond the config's and the table's own validation;
    ContractError (one line) for the first refusal. Changes nothing (`Inputs.serial.accept` records)."""
    from .link import load_signing_key

    why = hover_nominal_problem(cfg, table.vehicle)
    if why:
        raise ContractError(why)
    key = load_signing_key(cfg.link.signing_key_file) if cfg.link.signing_key_file else None
    serial = TableSerial.judge(cfg, table)
    return Inputs(list(serial.lines), serial, key)
