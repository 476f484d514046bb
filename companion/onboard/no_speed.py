"""Why the contract has no safe speed, and how the flight resumes: the `input`, `why` and `resume` of a `no safe
speed` Hold (and of a shadow flight's would-be Hold). Pure, no I/O.

The input is found from the values, by looking Ω up again with one input made good (never from the wording of a
reason): the thrust ratio below the lowest the table covers; else, at these inputs the contract has a speed and
the daemon's own lateness (or the speed policy flown) took it; else no D_od at all gives a speed (the table has
none for this vehicle); else a smaller E_tr (down to its floor) would give one at this D_od; else D_od is too
short. The thresholds a speed needs again are found by bisection on the same lookup.

How a flight resumes is the supervisor's rule (companion/onboard/supervisor.py): a governor keeps its Hold until the pilot
or a ground station changes the mode, and a cause it stood down from re-arms only when it clears; offboard's
fail-safe Hold is latched until CG_ENGAGE is set anew or the mode is changed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from contracts.table import ContractTable

from .estimators import LATE_WINDOW_S, SETTLE_S
from .modes import Mode, mode_of
from .supervisor import MIN_SPEED_CMD, Inputs

D_OD_TOP_M = 1000.0  # [m] no D_od beyond this is looked at: none up to it gives a speed ⇒ the table has none
RESOLUTION = 0.01  # [m] of the thresholds said (then rounded to cm, towards the safe side)


@dataclass(frozen=True)
class NoSpeed:
    """The input that put Ω at no safe speed, in words."""

    input: str  # thrust_ratio | d_od | e_tr | late_s | policy | table | non-finite
    why: str  # its value against what the contract needs
    needs: str  # what brings a speed back ("thrust_ratio ≥ 0.65")
    short: str  # `why` in a few ASCII words (STATUSTEXT)
    needs_short: str  # `needs` likewise

    def resume(self, mode: str | Mode) -> str:
        """How the flight resumes in the daemon's `mode`, as the supervisor's rules are."""
        if self.input == "table":
            return "not with this table: land, and build a table that covers the vehicle"
        return mode_of(mode).resume(self.needs)

    def fields(self, mode: str | Mode) -> dict:
        """The hold event's fields."""
        return {"input": self.input, "why": self.why, "resume": self.resume(mode)}

    def statustext(self, mode: str | Mode) -> str:
        then = mode_of(mode).resume_short
        if self.input == "table":
            return f"CG: no safe speed: {self.short}; land"
        return f"CG: no safe speed: {self.short}; resume when {self.needs_short}" + (f", then {then}" if then else "")


def _apart(a: float, b: float) -> tuple[str, str]:
    """`a` and `b` with the fewest decimals (2 to 4) that show them apart (0.59987 is not "0.60 < 0.60")."""
    for n in (2, 3, 4):
        if f"{a:.{n}f}" != f"{b:.{n}f}":
            break
    return f"{a:.{n}f}", f"{b:.{n}f}"


def _edge(speed, good: float, bad: float) -> float:
    """The boundary between `good` (a speed) and `bad` (none) of a monotone input, approached from the good side
    to `RESOLUTION` (a few lookups: the cycle that holds must stay on time)."""
    while abs(good - bad) > RESOLUTION:
        mid = 0.5 * (good + bad)
        if speed(mid):
            good = mid
        else:
            bad = mid
    return good


def diagnose(table: ContractTable, contract: str, i: Inputs, *, e_tr_floor: float, thrust_basis: str,
             policy: str = "contract", t_cmd: float = 0.0) -> NoSpeed:
    """Which input put Ω at no safe speed (< MIN_SPEED_CMD) at the cycle's inputs `i`; `e_tr_floor`: the smallest
    E_tr the contract uses; `thrust_basis`: what the thrust ratio is (`ThrustEstimator.basis`); `policy`: the
    speed policy's name; `t_cmd`: the command-delivery budget the stop contract takes."""
    names = ("d_od", "r_obst", "e_tr", "thrust_ratio")
    vals = (i.dod.d_od, i.r_obst, i.e_tr_measured, i.thrust_ratio)
    bad = [n for n, v in zip(names, vals) if not math.isfinite(v)]
    if bad:
        return NoSpeed("non-finite", f"{', '.join(bad)} not finite", "every input is finite again",
                       f"{bad[0]} not finite", "inputs finite")
    d, r, e, thr = vals
    floor = table.thrust_floor(contract)
    if thr < floor:
        now, lowest = _apart(thr, floor)
        if thrust_basis == "start":
            why = (f"thrust_ratio not yet estimated: taken as {now}, the bottom of the vehicle's "
                   f"thrust_ratio_range, below the lowest the table covers ({lowest})")
            needs = f"the hover estimate (airborne and steady for {SETTLE_S:g} s) reads thrust_ratio ≥ {lowest}"
        else:
            src = "configured (thrust.value)" if thrust_basis == "configured" else "estimated from the hover throttle"
            why = f"thrust_ratio {now} ({src}) below the lowest the table covers ({lowest})"
            needs = f"thrust_ratio ≥ {lowest}"
        return NoSpeed("thrust_ratio", why, needs, f"thrust_ratio {now} < {lowest}", f"thrust_ratio >= {lowest}")

    def speed(d_od: float = d, e_tr: float = e) -> bool:
        return table.omega(d_od, r, e_tr, thr, contract=contract, t_cmd=t_cmd,
                           t_silent=i.dod.silence_s).v_max >= MIN_SPEED_CMD

    if speed():  # the contract has a speed at these inputs: the daemon's lateness, or the policy flown, took it
        if i.late_s > 0.0:
            return NoSpeed("late_s", f"the daemon's own cycles ran late: {i.late_s * 1e3:.0f} ms counted as reaction "
                           f"time leave no safe speed at D_od {d:.2f} m",
                           f"the cycles have run on time for {LATE_WINDOW_S:g} s",
                           f"companion late {i.late_s * 1e3:.0f} ms", f"on time {LATE_WINDOW_S:g} s")
        return NoSpeed("policy", f"the speed policy flown ({policy}) allows none; the contract would",
                       "the policy allows a speed", f"policy {policy}", "policy allows")
    top = max(2.0 * d, 1.0)  # the D_od a speed needs: bracketed by doubling, then bisected
    while top < D_OD_TOP_M and not speed(d_od=top):
        top = min(2.0 * top, D_OD_TOP_M)
    if not speed(d_od=top):
        return NoSpeed("table", f"the table has no speed at any D_od at E_tr {e:.2f} m and thrust_ratio {thr:.2f} "
                       "(its tilt or controller-contract axes do not reach the vehicle's)",
                       "a table that covers the vehicle", "table has none", "a covering table")
    if e > e_tr_floor + 1e-9 and speed(e_tr=e_tr_floor):
        e_ok = max(math.floor(_edge(lambda x: speed(e_tr=x), e_tr_floor, e) * 100.0) / 100.0, e_tr_floor)
        return NoSpeed("e_tr", f"E_tr {e:.2f} m (the tracking error measured) leaves no safe speed at D_od "
                       f"{d:.2f} m: at most {e_ok:.2f} m would", f"E_tr ≤ {e_ok:.2f} m (or a longer D_od)",
                       f"E_tr {e:.2f} m > {e_ok:.2f} m", f"E_tr <= {e_ok:.2f} m")
    d_ok = math.ceil(_edge(lambda x: speed(d_od=x), top, d) * 100.0) / 100.0
    return NoSpeed("d_od", f"D_od {d:.2f} m, below the {d_ok:.2f} m any safe speed needs; D_od is what it is "
                   f"because: {i.dod.reason}",
                   f"D_od ≥ {d_ok:.2f} m", f"D_od {d:.2f} m < {d_ok:.2f} m", f"D_od >= {d_ok:.2f} m")
