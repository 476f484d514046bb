"""What the contract takes before it measures (DESIGN.md §4–5): the floor under E_tr, where the controller
contract's E_tr comes from, and the thrust ratio until the hover estimate settles."""

from __future__ import annotations

from contracts.online_planner import offboard_cap
from contracts.table import THRUST_AXIS_TOL, ContractTable

from .config import Config
from .estimators import SETTLE_S


def e_tr_floor(cfg: Config, table: ContractTable) -> float:
    """The smallest E_tr the contract may use with this table (`least_e_tr`)."""
    return least_e_tr(cfg, table.e_pred is not None)


def least_e_tr(cfg: Config, controller_contract: bool) -> float:
    """The smallest E_tr the contract may use: the configured floor, and without a controller contract in
    the table at least the configured assumption (without either, the start-up checks refuse)."""
    assumed = None if controller_contract else cfg.contract.e_tr_assumed_m
    return max(cfg.contract.e_tr_floor_m, assumed or 0.0)


def controller_contract(cfg: Config, table: ContractTable) -> str:
    """In words: where the contract's E_tr comes from (the start banner, the `start` record)."""
    if table.e_pred is not None:
        flown = table.etr_offboard_cap
        return ("E_tr_pred from the table (the controller contract)" + ("" if not cfg.daemon_mode.flies_route else
                f"; offboard flies {offboard_cap(flown):.2f} x V_safe (its online plans were flown at "
                f"{'an unrecorded cap' if flown is None else f'{flown:.2f}'} x V_safe)"))
    if cfg.contract.e_tr_assumed_m is not None:
        return f"no E_tr_pred in the table: E_tr assumed {e_tr_floor(cfg, table):.2f} m (contract.e_tr_assumed_m)"
    return "no E_tr_pred in the table and no contract.e_tr_assumed_m: refuses to engage"


def start_thrust(table: ContractTable, contract: str) -> tuple[float, dict]:
    """The thrust ratio the contract takes before the hover estimate settles, and the `thrust_start` event's fields.
    The bottom of the vehicle's `thrust_ratio_range` is what it may have until measured (a tired battery, a
    damaged propeller); where the table covers it, the start is the lowest thrust the table's lookup answers for
    (`ContractTable.thrust_floor`: the axis' own first value, never NONE at the start). A table whose thrust axis
    starts above that bottom (`table build --partial-grid`) cannot vouch for the vehicle until it is measured: the
    start stays at the bottom, where there is no safe speed, and says so."""
    lo, floor = table.vehicle.thrust_ratio_range[0], table.thrust_floor(contract)
    covered = floor <= lo + THRUST_AXIS_TOL
    start = floor if covered else lo
    until = f"until the hover estimate settles (airborne and steady for {SETTLE_S:g} s)"
    reason = (f"thrust_ratio taken as {start:.2f} {until}: the lowest the vehicle may have" if covered else
              f"thrust_ratio not yet estimated: the vehicle may have {lo:.2f} (its thrust_ratio_range) and the table "
              f"covers {floor:.2f} and up: no safe speed {until} at {floor:.2f} or more")
    return start, {"thrust_ratio": start, "vehicle_min": lo, "table_min": floor, "covered": covered, "reason": reason}
