"""The autopilot's speed overshoot above the limit sent, budgeted in the stop contract and judged in flight.

The guarantee (supervisor.py SPEED_OVERSHOOT): in its auto modes the autopilot keeps the ground speed within
δ_v(v) = base + fraction · v of the speed limit v it was sent (DO_CHANGE_SPEED). The mission reference itself never
passes its target speed, but the position loop lags the reference while it speeds up and catches up above it once
the reference levels off, and wind adds its gusts: measured per vehicle and personality by
benchmarks/bench_speed_overshoot.py (X500 0.12 m/s at 1 m/s to 0.31 m/s at 6 m/s in its design wind; Mambo at most
0.19 m/s), and on an aircraft from its own flight log (`overshoot_of`, used by `contract-guard calibrate`).

The stop contract assumes the vehicle flies at most V_max (eq. of the stop distance in contracts/stop.py), so the
governor sends the largest v with v + δ_v(v) ≤ V_max (`sent`): the flown speed stays within the contract's V_max
while the autopilot keeps its guarantee. The same allowance is the only tolerance the supervisor gives a limit it
judges flown (`Supervisor._over_limit`, `_judge_limit`, the recovery brake's refusal, the approach ramp), so the
budget and the judgement are one number. Broken (`OvershootWatch`), the excess measured becomes the budget for the
rest of the flight: a lower limit from then on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace


@dataclass(frozen=True, slots=True)
class OvershootBudget:
    """δ_v(v) = base_m_s + fraction · v [m/s] above a limit v sent (both ≥ 0)."""

    base_m_s: float
    fraction: float

    def allowance(self, v_sent: float) -> float:
        """How far above the limit `v_sent` the autopilot's guarantee lets the ground speed go [m/s]."""
        return self.base_m_s + self.fraction * max(v_sent, 0.0)

    def top(self, v_sent: float) -> float:
        """The fastest ground speed the guarantee allows under the limit `v_sent`."""
        return v_sent + self.allowance(v_sent)

    def sent(self, v_max: float) -> float:
        """The limit to send so that the flown speed stays ≤ `v_max`: the v with v + δ_v(v) = v_max (0 when the
        budget alone exceeds it; an infinite limit stays infinite)."""
        if not math.isfinite(v_max):
            return v_max
        return max((v_max - self.base_m_s) / (1.0 + self.fraction), 0.0)

    def raised(self, v_sent: float, flown: float) -> "OvershootBudget":
        """The budget after the autopilot flew `flown` under the limit `v_sent`: its base raised so that this
        excess is covered (never lowered)."""
        need = flown - v_sent - self.fraction * max(v_sent, 0.0)
        return self if need <= self.base_m_s else replace(self, base_m_s=need)

    def line(self) -> str:
        """The banner's words for it."""
        return (f"speed limit sent V_max − δ_v: autopilot overshoot budget δ_v = {self.base_m_s:g} m/s + "
                f"{self.fraction:g} × limit (the ground speed flown above the limit sent; measured above it, the budget "
                "is raised for the rest of the flight)")


DEFAULT = OvershootBudget(0.1, 0.04)  # the shipped vehicles' worst (module docstring; config.SpeedOvershootConfig)


class OvershootWatch:
    """Judges the guarantee: once the vehicle has flown within the allowance of the limit in force (it met the
    limit, from below or after slowing down to it), a ground speed above `top(limit)` breaks it. While the vehicle
    still slows down to a lower limit it is not judged here (the slow-down is `Supervisor._judge_limit`'s)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._limit: float | None = None
        self._met = False

    def judge(self, budget: OvershootBudget, limit: float | None, speed: float) -> tuple[float, float] | None:
        """(allowed, flown) while the guarantee is broken, else None. `limit`: the limit in force (None: none)."""
        if limit is None or not math.isfinite(speed):
            self.reset()
            return None
        if self._limit is None or limit < self._limit - 1e-6:
            self._met = False  # a lower limit: met again once the vehicle has slowed down to it
        self._limit = limit
        top = budget.top(limit)
        if speed <= top:
            self._met = True
            return None
        return (top, speed) if self._met else None


def overshoot_of(t, speed, limit) -> dict:
    """The overshoot a flight log shows: over samples (t, ground speed, limit sent), the largest ground speed above
    the limit once the vehicle had met it (flown at or below it since the limit was last lowered), per limit.
    {"overshoot_m_s", "at_limit_m_s", "samples"} — the calibration's evidence for `speed_overshoot`."""
    worst, at, met, last, n = -math.inf, math.nan, False, None, 0
    for tk, v, lim in zip(t, speed, limit):
        if not (math.isfinite(v) and lim is not None and math.isfinite(lim) and lim > 0):
            met, last = False, None
            continue
        if last is None or lim < last - 1e-6:
            met = False
        last = lim
        met = met or v <= lim
        if met:
            n += 1
            if v - lim > worst:
                worst, at = v - lim, lim
    return {"overshoot_m_s": worst if n else None, "at_limit_m_s": at if n else None, "samples": n}
