"""A flight without obstacle data, judged for what a team can act on: the detection range the contract would
have needed at the speeds flown, and what a stated sensor would have cost.

Without a range sensor `D_od` is 0 and the contract allows no speed, so "flown outside the contract" is true
of every metre and says nothing. Instead, for each state sample flown at ground speed `v`:

- the **required detection range**: the smallest `d_od` with `V_max(d_od, R_obst, E_tr, thrust_ratio) ≥ v`
  under the flight's contract (the table's own lookup `ContractTable.omega`, its V_max being the largest speed
  with Γ ≤ 0 at that `d_od`; V_max rises with `d_od`, so a bisection finds it);
- with an **assumed sensor** of range `range_m` (and a field of view, stated): the limit the contract would
  have set (`omega(d_od).v_max`), the time flown above it and the time flying those stretches at the
  limit would have added (distance ÷ limit − time taken). With a field of view, `d_od` is what the sensor, pointed
  along the direction of travel, covers of the swept corridor r_body + E_tr at each sample (the daemon's own rule,
  `companion.onboard.coverage`: 0 where it covers it nowhere); without one, its range.

Conservative rounding: speeds and E_tr rounded up, thrust down, before a cached lookup; a required range is the
upper end of its bisection. Pure (no I/O): samples are rows of `review.CSV_COLUMNS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from companion.onboard.coverage import Beam, covered_d_od, half_width
from contracts.errors import ContractError

MIN_SPEED = 0.2  # m/s: below this the vehicle hovers (the supervisor's own least speed command)
STRETCH_S = 10.0  # the flight is cut into stretches this long (each gets its needed range)
D_TOL = 0.05  # m: bisection tolerance on d_od
D_MAX = 1000.0  # m: beyond this no range is reported (the table's speeds end first)
RANGES_M = (5.0, 10.0, 20.0, 40.0)  # the usual sensors' ranges (lidar, ToF, stereo, radar), for the coverage line
QUANTILES = (0.5, 0.9, 0.99)
E_TR_LEAST = 0.3  # m: the daemon's default E_tr floor, the least tracking error an assumed sensor's corridor holds


@dataclass(frozen=True)
class Sensor:
    """A hypothetical forward range sensor: `range_m` along the direction of travel, field of view `fov_deg`."""

    range_m: float
    fov_deg: float | None = None

    def d_od(self, r_body_m: float, e_tr_m: float) -> float:
        """The D_od this sensor guarantees along the direction of travel for the swept corridor r_body + E_tr
        (its range when no field of view is stated)."""
        if self.fov_deg is None:
            return self.range_m
        return covered_d_od([Beam(0.0, self.fov_deg, self.range_m)], half_width(r_body_m, e_tr_m))

    @classmethod
    def parse(cls, text: str) -> "Sensor":
        """`RANGE_M[,FOV_DEG]`, e.g. `10` or `12,60`; one line saying what is wrong otherwise."""
        parts = [p.strip() for p in str(text).split(",")]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            vals = []
        if not 1 <= len(vals) <= 2 or not all(math.isfinite(v) for v in vals) or not 0 < vals[0] <= D_MAX \
                or (len(vals) == 2 and not 0 < vals[1] <= 360):
            raise ContractError(f"--assume-sensor {text!r}: expected RANGE_M[,FOV_DEG] with 0 < RANGE_M ≤ {D_MAX:g} "
                                "and 0 < FOV_DEG ≤ 360 (e.g. 10,60)")
        return cls(vals[0], vals[1] if len(vals) == 2 else None)

    def describe(self) -> str:
        return f"{self.range_m:g} m" + (f" / {self.fov_deg:g}° field of view" if self.fov_deg else "") + " sensor"


def _up(x: float, step: float) -> float:
    return math.ceil(x / step - 1e-9) * step


def _down(x: float, step: float) -> float:
    return math.floor(x / step + 1e-9) * step


class Lookup:
    """The table's V_max at a `d_od`, and the least `d_od` for a speed, cached on a conservative grid."""

    def __init__(self, table):
        self.table = table
        self.v_top = None
        self._v: dict[tuple, float] = {}
        self._d: dict[tuple, float] = {}

    def key(self, contract, r_obst, e_tr, thrust_ratio) -> tuple:
        """The lookup's inputs rounded the safe way (thrust not below the table's lowest: `thrust_ratio` ≥ it)."""
        lo = self.table.vehicle.thrust_ratio_range[0]
        return (contract if contract in ("stop", "avoid") else "stop", _up(r_obst, 0.05), _up(e_tr, 0.05),
                max(_down(thrust_ratio, 0.02), lo))

    def v_max(self, d_od: float, key: tuple) -> float:
        k = (round(d_od, 3), key)
        if k not in self._v:
            contract, r_obst, e_tr, thrust = key
            if contract == "avoid" and self.table.avoid is None:
                contract = "stop"
            self._v[k] = self.table.omega(d_od, r_obst, e_tr, thrust, contract=contract).v_max
        return self._v[k]

    def needed(self, v: float, key: tuple) -> float:
        """The least d_od [m] whose V_max reaches `v` (upper end, within D_TOL); inf when none up to D_MAX."""
        v = _up(v, 0.1)
        k = (v, key)
        if k not in self._d:
            hi = 4.0
            while self.v_max(hi, key) < v and hi < D_MAX:
                hi = min(hi * 2, D_MAX)
            if self.v_max(hi, key) < v:
                self._d[k] = math.inf
            else:
                lo = 0.0
                while hi - lo > D_TOL:
                    mid = (lo + hi) / 2
                    lo, hi = (lo, mid) if self.v_max(mid, key) >= v else (mid, hi)
                self._d[k] = hi
        return self._d[k]


def _num(x):
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def detection_need(samples: Iterable[tuple], columns: tuple, table, sensor: Sensor | None = None,
                   gap_s: float = 1.0) -> dict:
    """The required detection range over the flight (per stretch and its worst), the share of the flown time
    the usual sensors' ranges cover, and with `sensor` the limits it would have set and their cost.
    `samples`: rows in `columns` order, read once (a generator will do)."""
    col = {k: columns.index(k) for k in ("boot", "t", "ground_speed", "contract", "r_obst", "e_tr_measured",
                                          "thrust_ratio", "x", "y")}
    look = Lookup(table)
    lo_thrust = table.vehicle.thrust_ratio_range[0]
    weak = {"s": 0.0, "thrust_ratio": None}  # flown below the table's thrust range: no range suffices there
    flown_s = 0.0
    need_time: list[tuple[float, float]] = []  # (required d_od, dt) over flown time
    stretches: dict[int, dict] = {}
    worst = None
    beyond = {"s": 0.0, "v_max": None}  # flown faster than any d_od allows (the table's speeds end)
    cost = {"above_s": 0.0, "extra_s": 0.0, "spans": [], "limit_min": None, "limit_max": None, "no_speed_s": 0.0,
            "d_od_min": None, "uncovered_s": 0.0}
    span = None
    prev = None
    for row in samples:
        t, v = _num(row[col["t"]]), _num(row[col["ground_speed"]])
        if t is None:
            continue
        boot = row[col["boot"]]
        dt = 0.0
        if prev is not None and prev[0] == boot and 0 < t - prev[1] <= gap_s:
            dt = t - prev[1]
        p = prev
        prev = (boot, t, v, row)
        if p is None or p[2] is None or dt == 0.0:
            continue
        # the previous sample's values hold until this one (the review's own rule)
        pv, prow = p[2], p[3]
        if pv < MIN_SPEED:
            continue
        thrust = _num(prow[col["thrust_ratio"]])
        r_obst = _num(prow[col["r_obst"]])
        e_tr = _num(prow[col["e_tr_measured"]]) or 0.0
        if thrust is None or r_obst is None:
            continue
        flown_s += dt
        t0 = p[1]
        if thrust < lo_thrust:  # no safe speed below the table's thrust: no range suffices (never optimistic)
            weak["s"] += dt
            weak["thrust_ratio"] = thrust if weak["thrust_ratio"] is None else min(weak["thrust_ratio"], thrust)
            need, key = math.inf, None
        else:
            key = look.key(prow[col["contract"]], r_obst, e_tr, thrust)
            need = look.needed(pv, key)
        if math.isinf(need) and key is not None:
            beyond["s"] += dt
            beyond["v_max"] = max(beyond["v_max"] or 0.0, pv)
        need_time.append((need, dt))
        if worst is None or need > worst["d_od_m"]:
            worst = {"d_od_m": need, "t": t0, "ground_speed": pv}
        st = stretches.setdefault(int(t0 // STRETCH_S), {"start_t": t0, "end_t": t, "d_od_m": 0.0, "ground_speed": 0.0,
                                                        "flown_s": 0.0})
        st["end_t"], st["flown_s"] = t, st["flown_s"] + dt
        if need >= st["d_od_m"]:
            st["d_od_m"], st["ground_speed"], st["at_t"] = need, max(st["ground_speed"], pv), t0
        if sensor is not None:
            d_od = sensor.d_od(table.vehicle.r_body_m, max(key[2] if key is not None else e_tr, E_TR_LEAST))
            cost["d_od_min"] = d_od if cost["d_od_min"] is None else min(cost["d_od_min"], d_od)
            cost["uncovered_s"] += dt if d_od <= 0.0 else 0.0
            lim = 0.0 if key is None or d_od <= 0.0 else look.v_max(d_od, key)
            cost["limit_min"] = lim if cost["limit_min"] is None else min(cost["limit_min"], lim)
            cost["limit_max"] = lim if cost["limit_max"] is None else max(cost["limit_max"], lim)
            if pv > lim:
                cost["above_s"] += dt
                if lim >= MIN_SPEED:
                    cost["extra_s"] += dt * (pv / lim - 1.0)
                else:
                    cost["no_speed_s"] += dt
                if span is None or span["end_t"] < t0 - gap_s:
                    span = {"start_t": t0, "end_t": t, "worst_m_s": pv, "limit_m_s": lim, "worst_t": t0}
                    cost["spans"].append(span)
                span["end_t"] = t
                if pv > span["worst_m_s"]:
                    span.update(worst_m_s=pv, limit_m_s=lim, worst_t=t0)
    out = {
        "flown_s": flown_s, "min_speed_m_s": MIN_SPEED, "stretch_s": STRETCH_S,
        "table": str(getattr(table, "path", "") or ""), "vehicle": table.vehicle.name,
        "worst": _finite(worst), "quantiles_m": {}, "coverage": [], "beyond_table_s": beyond["s"],
        "beyond_table_speed_m_s": beyond["v_max"], "below_thrust_s": weak["s"],
        "below_thrust_ratio": weak["thrust_ratio"], "thrust_ratio_min": lo_thrust, "table_top_speed_m_s": look.v_max(D_MAX, look.key("stop", 0, 0, 1)),
        "stretches": [_finite(s) for s in sorted(stretches.values(), key=lambda s: s["start_t"])],
    }
    if need_time:
        need_time.sort()
        total = sum(dt for _, dt in need_time)
        acc, qs = 0.0, list(QUANTILES)
        for need, dt in need_time:
            acc += dt
            while qs and acc >= qs[0] * total - 1e-9:
                out["quantiles_m"][f"{qs.pop(0):g}"] = None if math.isinf(need) else need
        for r in RANGES_M:
            covered = sum(dt for need, dt in need_time if need <= r)
            out["coverage"].append({"range_m": r, "share": covered / total})
    if sensor is not None:
        out["sensor"] = {"range_m": sensor.range_m, "fov_deg": sensor.fov_deg, **cost,
                         "spans_count": len(cost["spans"]), "spans": cost["spans"][:200]}
    out["findings"] = _findings(out)
    return out


def _finite(d):
    if d is None:
        return None
    return {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in d.items()}


def _findings(out: dict) -> list[str]:
    """What a team can act on, one line each."""
    lines = []
    w = out["worst"]
    if w is None:
        return ["no obstacle data, and no stretch flown above "
                f"{out['min_speed_m_s']:g} m/s: no detection range needed"]
    q = out["quantiles_m"]

    def m(x):
        return "more than any range" if x is None else f"{x:.1f} m"

    cover = ", ".join(f"{c['range_m']:g} m covers {100 * c['share']:.0f} %" for c in out["coverage"])
    worst = "more than any range (see below)" if w["d_od_m"] is None else f"{w['d_od_m']:.1f} m"
    lines.append(f"detection range this flight needed under the {out['vehicle']} contract: median {m(q.get('0.5'))}, "
                 f"90 % of the {out['flown_s']:.0f} s flown {m(q.get('0.9'))}, worst {worst} at t = {w['t']:.1f} s "
                 f"({w['ground_speed']:.2f} m/s); of the flown time {cover}")
    if out["beyond_table_s"] > 0:
        lines.append(f"{out['beyond_table_s']:.1f} s flown faster (up to {out['beyond_table_speed_m_s']:.2f} m/s) than "
                     f"the table's top speed {out['table_top_speed_m_s']:.2f} m/s: no sensor makes that inside "
                     "this table's contract")
    if out["below_thrust_s"] > 0:
        lines.append(f"{out['below_thrust_s']:.1f} s flown with thrust_ratio down to {out['below_thrust_ratio']:.2f}, "
                     f"below the table's {out['thrust_ratio_min']:.2f}: the contract has no safe speed there, with any "
                     "sensor")
    s = out.get("sensor")
    if s is not None:
        what = Sensor(s["range_m"], s["fov_deg"]).describe()
        if s.get("uncovered_s"):
            lines.append(f"with a {what}: the sensor covers the vehicle's swept corridor (r_body + E_tr) at no range "
                         f"for {s['uncovered_s']:.0f} s of the flight: D_od 0 there, no speed is safe (a wider sensor)")
        elif s.get("d_od_min") is not None and s["d_od_min"] < s["range_m"]:
            lines.append(f"with a {what}: its beam covers the swept corridor only out to {s['d_od_min']:.1f} m at the "
                         "widest tracking error flown: that is its D_od, not its range")
        if s["limit_min"] is None:
            lines.append(f"with a {what}: nothing flown to judge")
        elif s["above_s"] == 0:
            lines.append(f"with a {what}: the contract's limit ({s['limit_min']:.2f}–{s['limit_max']:.2f} m/s) "
                         f"is above every speed flown: it would have cost no time")
        else:
            extra = f"{s['extra_s']:.0f} s ({100 * s['extra_s'] / out['flown_s']:.0f} % of the {out['flown_s']:.0f} s flown)"
            lines.append(f"with a {what}: the contract would have limited the speed to {s['limit_min']:.2f}"
                         + (f"–{s['limit_max']:.2f}" if s["limit_max"] - s["limit_min"] > 0.005 else "")
                         + f" m/s; the flight was faster for {s['above_s']:.0f} s in {s['spans_count']} stretch(es); "
                         f"flying them at the limit would have added {extra}"
                         + (f"; {s['no_speed_s']:.0f} s with no safe speed at all (the vehicle would have held)"
                            if s["no_speed_s"] else ""))
    return lines


def for_report(rep: dict, samples: Iterable[tuple], columns: tuple, sensor: Sensor | None, gap_s: float) -> dict | None:
    """`detection_need` with the table the log's daemon run used (its `start` event: the table file, else the
    vehicle's shipped one); None when there is none to load (the finding says so)."""
    from contracts.table import load_for_vehicle

    for st in reversed(rep.get("tables") or []):
        for vehicle, path in ((None, st.get("table")), (st.get("vehicle"), None)):
            try:
                if vehicle is None and not (path and Path(path).is_file()):
                    continue
                table = load_for_vehicle(vehicle, path)
            except (ContractError, OSError, ValueError):
                continue
            return detection_need(samples, columns, table, sensor, gap_s)
    return None
