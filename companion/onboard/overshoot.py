"""The autopilot's speed overshoot above the limit sent, budgeted in the stop contract and judged in flight.

The guarantee (supervisor.py SPEED_OVERSHOOT): in its auto modes the autopilot keeps the ground speed within
δ_v(v) = base + fraction · v of the speed limit v it was sent (DO_CHANGE_SPEED). The mission reference itself never
passes its target speed, but the position loop lags the reference while it speeds up and catches up above it once
the reference levels off, and wind adds its gusts: measured per vehicle and personality by
benchmarks/bench_speed_overshoot.py (X500 0.12 m/s at a 1 m/s limit to 0.32 m/s at 5–6 m/s in its design wind;
Mambo at most 0.24 m/s: 0.123 m/s + 0.04 × limit covers every X500 flight), and on an aircraft from the daemon's
own event log of its governor flights (`overshoot_of`, docs/calibration.md).

The stop contract assumes the vehicle flies at most V_max (the stopping distance of contracts/stop.py starts from
it), so the
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

    def raised(self, v_sent: float, flown: float) -> OvershootBudget:
        """The budget after the autopilot flew `flown` under the limit `v_sent`: its base raised so that this
        excess is covered (never lowered)."""
        need = flown - v_sent - self.fraction * max(v_sent, 0.0)
        return self if need <= self.base_m_s else replace(self, base_m_s=need)

    def line(self) -> str:
        """The banner's words for it."""
        return (f"speed limit sent V_max − δ_v: autopilot overshoot budget δ_v = {self.base_m_s:g} m/s + "
                f"{self.fraction:g} × limit (the ground speed flown above the limit sent; measured above it, the "
                "budget is raised for the rest of the flight)")


# the shipped vehicles' worst, rounded up (module docstring; config.SpeedOvershootConfig)
DEFAULT = OvershootBudget(0.15, 0.04)


def ramped_out(speed: float, accel: float, jerk: float) -> float:
    """The speed the vehicle still reaches while its acceleration `accel` (along its velocity) is ramped out at the
    autopilot's jerk: speed + a²/(2j) when speeding up (the autopilot's jerk-limited reference cannot stop speeding
    up sooner). NaN when the acceleration is not known."""
    return speed + max(accel, 0.0) ** 2 / (2.0 * jerk) if math.isfinite(accel) else math.nan


class OvershootWatch:
    """Judges the guarantee: once the vehicle has met the limit in force — it would reach no more than the limit and
    its allowance with its acceleration ramped out (`ramped_out`), speeding up toward it from below or after slowing
    down to a lower one — a ground speed above `top(limit)` breaks it. A limit lowered while the vehicle speeds up
    past it is not judged here until met (that slow-down, from the acceleration it found, is
    `Supervisor._judge_limit`'s)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._limit: float | None = None
        self._met = False

    def judge(self, budget: OvershootBudget, limit: float | None, speed: float, reach: float
              ) -> tuple[float, float] | None:
        """(allowed, flown) while the guarantee is broken, else None. `limit`: the limit in force (None: none);
        `reach`: the speed the vehicle reaches with its acceleration ramped out (`ramped_out`; NaN: not known)."""
        if limit is None or not math.isfinite(speed):
            self.reset()
            return None
        if self._limit is None or limit < self._limit - 1e-6:
            self._met = False  # a lower limit: met again once the vehicle has slowed down to it
        self._limit = limit
        top = budget.top(limit)
        self._met = self._met or reach <= top
        return (top, speed) if self._met and speed > top else None

    @property
    def met(self) -> bool:
        """The vehicle has met the limit in force (the last `judge`)."""
        return self._met


def overshoot_of(t, speed, limit, jerk: float, window_s: float = 0.3) -> dict:
    """The overshoot a flight log shows: over samples (t, ground speed, limit in force), the largest ground speed
    above the limit once the vehicle had met it (as `OvershootWatch` judges it: its acceleration, Δv over
    `window_s`, ramped out at the autopilot's `jerk` reaching no more than the limit).
    {"overshoot_m_s", "at_limit_m_s", "samples"} — the calibration's evidence for `speed_overshoot`."""
    worst, at, n = -math.inf, math.nan, 0
    watch, exact = OvershootWatch(), OvershootBudget(0.0, 0.0)  # met as the daemon judges it, against the limit itself
    past: list[tuple[float, float]] = []
    for tk, v, lim in zip(t, speed, limit):
        if not (math.isfinite(v) and lim is not None and math.isfinite(lim) and lim > 0):
            watch.reset()
            past = []
            continue
        past = [p for p in past if tk - p[0] <= window_s + 1e-9] + [(tk, v)]
        accel = (v - past[0][1]) / (tk - past[0][0]) if tk - past[0][0] >= 0.5 * window_s else math.nan
        watch.judge(exact, lim, v, ramped_out(v, accel, jerk))
        if watch.met:
            n += 1
            if v - lim > worst:
                worst, at = v - lim, lim
    return {"overshoot_m_s": worst if n else None, "at_limit_m_s": at if n else None, "samples": n}
