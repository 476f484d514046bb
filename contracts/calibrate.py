"""Calibrating the contract from the aircraft's own flights: the statistics, pure (no I/O, no logs).

`companion/ground/calibrate.py` reads the logs and calls these; the daemon never imports this module.

**Controller contract** (the table's `E_tr_pred` slot, Figure 12). The logged flight is cut into
windows of `WINDOW_S`; each window gives one sample: its worst contour error `e` (the shortest distance
from the vehicle to the commanded path, Figure 11, `contracts.contour`), the largest horizontal speed
`v` and total tilt seen in the window and the `LOOKBACK_S` before it (an error that lags a manoeuvre is
charged to the manoeuvre's speed and tilt), and the flight's thrust_ratio. A sample belongs to the cell
whose grid speed and tilt are the first at or above its own (the conservative corner of DESIGN.md §2:
`hurts_index`) and whose thrust_ratio is the last at or below (`helps_index`).

Upper bound per cell (distribution-free order statistic): the largest of the cell's n window maxima
exceeds the `quantile` q of a window's worst error with confidence 1 − qⁿ; a cell is *covered* when
n ≥ n_min = ⌈ln(1 − confidence) / ln q⌉. The calibrated value of a covered cell is that maximum times
(1 + margin) plus `margin_abs_m` (the SITL build's own margin rule). An uncovered cell is never
optimistic (the neighbour rule): `max(E_sitl, E_sitl · ρ_nb, its own windows' bound)`, with ρ_nb
the largest measured/predicted ratio (bound / E_sitl) over the covered cells within `NEIGHBOUR_STEPS` grid
steps of it in every axis, or, where no covered cell is that near, ρ* — the largest ratio over all covered
cells (1 when none is covered). Never below the SITL prediction. The result is made monotone upward
(`lookup.repair_monotone`, "up"), so a covered cell is never below a smaller speed's or tilt's calibrated
value either.

**Evidence to go below the SITL prediction** (a cell that would make the contract faster than stock). A covered
cell takes its bound where that is above the SITL's value; below it only with at least `MIN_WINDOWS_BELOW_FACTOR`
× n_min windows from at least `MIN_FLIGHTS_BELOW` distinct flights, and never below `BELOW_FLOOR` × the SITL's
value (the margin: no amount of logged flight takes a cell below half of what the model predicts). Else it keeps
max(SITL, bound). Flights are told apart by what was flown, not by time stamps or file hashes (`same_flight`): two
logs whose velocity time series agree once their time offsets are removed are one flight, however they are
stamped (the caller, companion/ground/calibrate.py, also takes identical files and logs whose time spans overlap as
one flight). Any cell left below the SITL's value is reported (`faster`): the caller refuses it unless a person
accepts it.

**Braking** (the stop contract, `contracts/stop.py`): from each logged stop (Hold/Brake commanded at
speed) the reaction (command → braking onset), the peak deceleration, the jerk of its rise, the
distance from the command to rest, and the closed form's distance for the same speed with the vehicle
file's limits; calibrated limits are never better than the file's (min of deceleration and jerk, max of
the switch time, enlarged until the closed form covers every logged stop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .contour import contour_errors
from .lookup import NONE, helps_index, hurts_index, repair_monotone
from .stop import braking_distance, stopping_distance

WINDOW_S = 1.0  # one sample per window of flight [s]
# a window's speed and tilt include this much before it [s]: an error that lingers after a manoeuvre (the settling
# after a stop or a turn) is charged to the manoeuvre's speed and tilt, not to the slow flight that follows it.
# Measured (benchmarks/calibrate_evidence.py, the X500 with gains x0.6, +60 ms actuator delay, 5 m/s wind): at 4 s,
# windows at rest 0.3 m/s after a Hold from 8 m/s still carried 0.9 m and made the 1 m/s cells 1.6 m (monotone
# upward from there); at 8 s the held-out median rose 0.11 -> 0.26 (per window), worst 0.31 -> 0.76; 12 s as 8 s
LOOKBACK_S = 8.0
CONTOUR_WINDOW_S = 1.0  # the commanded path near a sample: ± this [s] (as the SITL build)
QUANTILE = 0.9
CONFIDENCE = 0.9
MARGIN_REL = 0.25  # the SITL build's margin (its table's `e_tr_pred.margin`)
MARGIN_ABS_M = 0.02
ETR_DIRS = (+1, +1, -1)  # E_tr_pred grows with v_max and tilt, falls with thrust_ratio
NEIGHBOUR_STEPS = 1  # an uncovered cell's neighbours: covered cells at most this many grid steps away per axis
# Evidence a cell needs before its value may go below the SITL's E_tr_pred (faster than the stock contract).
# 3 flights: one flight is one wind, one battery, one tuning; two can agree by chance; a third is the least that
# shows the aircraft, not the day. 2 × n_min windows: the order-statistic bound needs n_min for the quantile at all;
# below the model we ask for twice that (at q = c = 0.9: 44 windows, the bound then holds with 1 − 0.9^44 = 0.99)
MIN_FLIGHTS_BELOW = 3
MIN_WINDOWS_BELOW_FACTOR = 2
# the margin: never below this fraction of the SITL's value, whatever the logs say (the SITL models the airframe's
# dynamics; a log claiming half its tracking error more likely measured the wrong path than a better aircraft)
BELOW_FLOOR = 0.5


# One flight, however stamped: logs are compared by their flown samples. A flight's series is its horizontal
# speed and vertical velocity resampled every SAME_DT_S from its own first sample (so a new time stamp, or a
# rotated or moved frame, changes nothing); two series are one flight when, at some time shift, they overlap for at
# least SAME_MIN_SHARE of the shorter one (and SAME_MIN_S) and 90 % of the overlap agrees within SAME_TOL_M_S.
# Two real flights never agree that closely: an autopilot's velocity estimate carries noise of several cm/s, and
# wind and battery differ between flights; a copy, a re-stamped copy, or a log cut from another agrees exactly (up
# to resampling). Where two flights cannot be told apart by what was flown, they count once (never optimistic).
SAME_DT_S = 0.1
SAME_TOL_M_S = 0.05
SAME_MIN_SHARE = 0.5
SAME_MIN_S = 5.0
SAME_LAGS = 5  # the time shifts tried: the best few of the speeds' cross-correlation, and none


def flight_series(t, vel) -> np.ndarray:
    """A flight's content for `same_flight`: (horizontal speed, vertical velocity) [m/s] at every `SAME_DT_S` from
    its first sample, (n, 2). `t` (n,) [s], `vel` (n, 3) NED [m/s]; non-finite samples dropped."""
    t = np.asarray(t, float)
    vel = np.asarray(vel, float).reshape(len(t), -1)
    ok = np.isfinite(t) & np.all(np.isfinite(vel), axis=1)
    t, vel = t[ok], vel[ok]
    if len(t) < 2:
        return np.zeros((0, 2))
    order = np.argsort(t, kind="stable")
    t, vel = t[order], vel[order]
    grid = t[0] + np.arange(int((t[-1] - t[0]) / SAME_DT_S) + 1) * SAME_DT_S
    speed = np.hypot(vel[:, 0], vel[:, 1])
    return np.column_stack([np.interp(grid, t, speed), np.interp(grid, t, vel[:, 2])])


def same_flight(a: np.ndarray, b: np.ndarray) -> float | None:
    """The time shift [s] at which series `b` (`flight_series`) is series `a`'s flight, or None: another flight
    (or too short to tell)."""
    n, m = len(a), len(b)
    need = max(SAME_MIN_SHARE * min(n, m), SAME_MIN_S / SAME_DT_S)
    if min(n, m) < need:
        return None
    sa, sb = a[:, 0] - a[:, 0].mean(), b[:, 0] - b[:, 0].mean()
    size = 1 << int(math.ceil(math.log2(n + m)))
    xc = np.fft.irfft(np.fft.rfft(sa, size) * np.conj(np.fft.rfft(sb, size)), size)
    # xc[k]: b shifted k samples later lines up with a (k < 0 wraps to the end)
    lags = [0] + [int(k) if k < size // 2 else int(k) - size for k in np.argsort(xc)[::-1][:SAME_LAGS]]
    for k in dict.fromkeys(lags):
        lo, hi = max(0, k), min(n, m + k)  # a[lo:hi] against b[lo - k: hi - k]
        if hi - lo < need:
            continue
        d = np.max(np.abs(a[lo:hi] - b[lo - k:hi - k]), axis=1)
        if np.quantile(d, 0.9) <= SAME_TOL_M_S:
            return k * SAME_DT_S
    return None


def n_min(quantile: float = QUANTILE, confidence: float = CONFIDENCE) -> int:
    """Smallest n for which the largest of n samples bounds the q-quantile with the confidence."""
    return math.ceil(math.log(1.0 - confidence) / math.log(quantile))


@dataclass(frozen=True)
class Windows:
    """The samples of one flight: per window its worst contour error [m], speed [m/s], tilt [rad], time [s]."""

    e: np.ndarray
    v: np.ndarray
    tilt: np.ndarray
    t: np.ndarray


def windows(t, xy, speed, tilt, t_path, xy_path, airborne=None, window_s=WINDOW_S, lookback_s=None) -> Windows:
    """Cut a flight into window samples. `t` (n,), `xy` (n, 2) position, `speed` (n,) horizontal speed,
    `tilt` (n,) total tilt [rad] (all at the position samples); `t_path`, `xy_path` the commanded path;
    `airborne` (n,) bool: samples outside it (on the ground, taking off, landing) and samples with no
    commanded path within `CONTOUR_WINDOW_S` are left out."""
    lookback_s = LOOKBACK_S if lookback_s is None else lookback_s
    t = np.asarray(t, float)
    if len(t) == 0 or len(t_path) == 0:
        return Windows(*(np.zeros(0) for _ in range(4)))
    t_path = np.asarray(t_path, float)
    e = contour_errors(np.asarray(xy, float), t, t_path, np.asarray(xy_path, float), CONTOUR_WINDOW_S)
    near = np.searchsorted(t_path, t - CONTOUR_WINDOW_S) < np.searchsorted(t_path, t + CONTOUR_WINDOW_S)
    ok = near & np.isfinite(e) & (np.ones(len(t), bool) if airborne is None else np.asarray(airborne, bool))
    speed, tilt = np.asarray(speed, float), np.asarray(tilt, float)
    k = np.floor((t - t[0]) / window_s).astype(int)
    out = ([], [], [], [])
    for w in np.unique(k[ok]):
        sel = ok & (k == w)
        if np.count_nonzero(sel) < 3 or np.count_nonzero(k == w) != np.count_nonzero(sel):
            continue  # a window only partly airborne or partly without a path: left out whole
        t0, t1 = t[0] + w * window_s, t[0] + (w + 1) * window_s
        back = (t >= t0 - lookback_s) & (t < t1)
        out[0].append(float(np.max(e[sel])))
        out[1].append(float(np.nanmax(speed[back])))
        out[2].append(float(np.nanmax(tilt[back])))
        out[3].append(t0)
    return Windows(*(np.array(a) for a in out))


def cell_of(axes, v: float, tilt: float, thrust_ratio: float) -> tuple[int, int, int] | None:
    """The E_tr_pred cell a sample is evidence for (None: above the speed/tilt grid or below its thrust)."""
    i, j = hurts_index(axes[0], v), hurts_index(axes[1], tilt)
    k = helps_index(axes[2], thrust_ratio)
    return None if NONE in (i, j, k) else (i, j, k)


@dataclass
class EtrCalibration:
    values: np.ndarray  # calibrated E_tr_pred
    counts: np.ndarray  # window samples per cell (int)
    covered: np.ndarray  # bool per cell: n ≥ n_min
    measured_max: np.ndarray  # largest window error per cell (NaN: no sample)
    ratio: float  # ρ*: largest measured/predicted over covered cells (1 if none)
    rho: np.ndarray  # measured/predicted (bound / E_sitl) per covered cell (NaN elsewhere)
    scale: np.ndarray  # the ratio each cell's SITL value was scaled by (covered cells: NaN)
    from_neighbours: np.ndarray  # bool per cell: uncovered and scaled by its neighbours' ratio (else ρ*)
    repairs: int  # cells raised by the monotone repair
    outside: int  # samples outside the grid (not used)
    n_min: int
    flights: np.ndarray = None  # distinct flights with a window in each cell (int)
    below_ok: np.ndarray = None  # bool per cell: evidence enough to go below the SITL's value
    faster: np.ndarray = None  # bool per cell: the calibrated value is below the SITL's (faster than stock)


def calibrate_etr(stock: np.ndarray, axes, samples: list[tuple[float, float, float, float]], *, flights=None,
                  quantile=QUANTILE, confidence=CONFIDENCE, margin=MARGIN_REL, margin_abs_m=MARGIN_ABS_M) -> EtrCalibration:
    """The calibrated E_tr_pred grid from window samples `(e, v, tilt, thrust_ratio)` (see the module). `flights`:
    each sample's flight (any hashable, one per distinct flight); None: all from one flight."""
    stock = np.asarray(stock, float)
    counts = np.zeros(stock.shape, int)
    worst = np.full(stock.shape, np.nan)
    seen: dict[tuple, set] = {}
    outside = 0
    for n, (e, v, tilt, tr) in enumerate(samples):
        c = cell_of(axes, v, tilt, tr)
        if c is None or not math.isfinite(e):
            outside += 1
            continue
        counts[c] += 1
        worst[c] = e if not counts[c] > 1 else max(worst[c], e)
        seen.setdefault(c, set()).add(None if flights is None else flights[n])
    n_flights = np.zeros(stock.shape, int)
    for c, f in seen.items():
        n_flights[c] = len(f)
    nm = n_min(quantile, confidence)
    covered = counts >= nm
    below_ok = covered & (counts >= MIN_WINDOWS_BELOW_FACTOR * nm) & (n_flights >= MIN_FLIGHTS_BELOW)
    bound = worst * (1.0 + margin) + margin_abs_m
    # a covered cell's value: its bound, but not below the SITL's without the evidence, nor below the floor with it
    measured = np.where(below_ok, np.fmax(bound, BELOW_FLOOR * stock), np.fmax(bound, stock))
    fin = covered & np.isfinite(stock) & (stock > 0)
    rho = np.where(fin, bound / np.where(fin, stock, 1.0), np.nan)  # measured/predicted per covered cell
    ratio = float(max(1.0, np.nanmax(rho))) if np.any(fin) else 1.0
    scale, near = neighbour_ratio(rho, ratio)
    scale[covered] = np.nan
    near &= ~covered
    # uncovered: the SITL's value scaled by its neighbours' ratio (or ρ*), never below the SITL's value nor
    # below what its own few windows showed
    vals = np.where(covered, measured, np.fmax(np.maximum(stock, stock * np.nan_to_num(scale, nan=ratio)), bound))
    vals, repairs = repair_monotone(vals, ETR_DIRS, "up")
    faster = vals < stock
    return EtrCalibration(vals, counts, covered, worst, ratio, rho, scale, near, repairs, outside, nm, n_flights,
                          below_ok, faster)


def cell_evidence(axes, stock, values, counts, flights, worst) -> list[dict]:
    """Per cell with windows (or below the SITL's value): its grid point, windows, distinct flights, worst measured
    contour error and calibrated/SITL ratio — what the report and `table show` print. Pure."""
    rows = []
    for idx in zip(*np.nonzero((np.asarray(counts) > 0) | (np.asarray(values) < np.asarray(stock)))):
        i, j, k = (int(x) for x in idx)
        e0, e1, w = float(stock[i, j, k]), float(values[i, j, k]), float(worst[i, j, k])
        rows.append({"cell": [i, j, k], "v_max": float(axes[0][i]), "tilt_deg": math.degrees(float(axes[1][j])),
                     "thrust_ratio": float(axes[2][k]), "windows": int(counts[i, j, k]), "flights": int(flights[i, j, k]),
                     "worst_m": w if math.isfinite(w) else None, "calibrated_m": e1, "stock_m": e0,
                     "ratio": e1 / e0 if e0 > 0 and math.isfinite(e0) else None, "faster": e1 < e0})
    return rows


def table_evidence(table) -> list[str]:
    """`table show`'s lines on a calibrated table's evidence: flights, the faster-than-stock cells, and each cell
    with windows (`cell_evidence`); [] for a table not calibrated from flight logs."""
    c = ((table.e_pred.info or {}).get("calibration") if table.e_pred is not None else None) or {}
    if "flights_per_cell" not in c:
        return []
    axes, values = table.e_pred.axes, table.e_pred.values
    stock = np.asarray(c.get("stock_values", values), float)
    worst = np.asarray(c["worst_m"], float)
    rows = cell_evidence(axes, stock, values, np.asarray(c["counts"]), np.asarray(c["flights_per_cell"]),
                         np.where(worst < 0, np.nan, worst))
    head = (f"  calibration evidence: {c.get('flights')} distinct flight(s); {c.get('faster_cells', 0)} cell(s) faster "
            f"than stock{' (accepted by a person: --accept-faster)' if c.get('faster_accepted') else ''}")
    return [head] + [f"    {evidence_line(r)}" for r in rows]


def evidence_line(r: dict) -> str:
    """One cell's evidence, for a person."""
    worst = "no window" if r["worst_m"] is None else f"worst {r['worst_m']:.3f} m"
    ratio = "" if r["ratio"] is None else f", calibrated/stock {r['ratio']:.2f}"
    return (f"cell V_max {r['v_max']:g} m/s, tilt {r['tilt_deg']:.0f}°, thrust {r['thrust_ratio']:g}: {r['windows']} "
            f"windows from {r['flights']} flight(s), {worst}, E_tr_pred {r['stock_m']:.3f} -> {r['calibrated_m']:.3f} m"
            f"{ratio}{' FASTER than stock' if r['faster'] else ''}")


def neighbour_ratio(rho: np.ndarray, fallback: float, steps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per cell, the largest of `rho` (measured/predicted of the covered cells, NaN elsewhere) over the cells at
    most `steps` grid steps away in every axis (itself included), and whether there was any; `fallback` where
    there was none (`steps` default: `NEIGHBOUR_STEPS`). Pure."""
    from scipy.ndimage import maximum_filter  # here, not at import: `table show` reads this module (0.3 s)

    steps = NEIGHBOUR_STEPS if steps is None else steps
    src = np.where(np.isfinite(rho), rho, -np.inf)
    best = maximum_filter(src, size=2 * steps + 1, mode="constant", cval=-np.inf)
    near = np.isfinite(best)
    return np.where(near, best, fallback), near


# ----------------------------------------------------------------------------- braking


@dataclass(frozen=True)
class Stop:
    """One logged stop: commanded at `t_cmd` at speed `v0`."""

    t_cmd: float
    v0: float  # [m/s]
    reaction_s: float  # command → braking onset
    decel_peak: float  # [m/s²]
    jerk: float  # rise of the deceleration, 20 % → 80 % of its peak [m/s³]
    distance_m: float  # command → rest, along the initial direction
    t_rest: float


ONSET_M_S2 = 0.5  # the deceleration that marks the onset of braking
REST_M_S = 0.1


def measure_stop(t, vel_xy, t_cmd: float, smooth_s: float = 0.1) -> Stop | None:
    """The stop commanded at `t_cmd` in the velocity record `vel_xy` (n, 2) at times `t` (None: not a stop
    from speed, or the record ends before rest)."""
    t, vel = np.asarray(t, float), np.asarray(vel_xy, float)
    i0 = int(np.searchsorted(t, t_cmd))
    if i0 >= len(t) - 3:
        return None
    u = vel[i0] / max(np.linalg.norm(vel[i0]), 1e-9)
    v0 = float(np.linalg.norm(vel[i0]))
    if v0 < 0.5:
        return None
    s = vel[i0:] @ u
    tt = t[i0:]
    # rest: the speed along the initial direction has fallen to REST_M_S (a side wind's drift is not motion
    # towards the obstacle; a resumed mission after a stop that never came to rest is not integrated)
    rest = np.nonzero(s < REST_M_S)[0]
    if len(rest) == 0:
        return None
    n = int(rest[0]) + 1
    tt, s = tt[:n + 1], s[:n + 1]
    if len(tt) < 4:
        return None
    # deceleration by differences over `smooth_s`
    h = max(1, round(float(smooth_s / max(np.median(np.diff(tt)), 1e-6))))
    a = np.zeros(len(s))
    a[h:-h] = -(s[2 * h:] - s[:-2 * h]) / (tt[2 * h:] - tt[:-2 * h]) if len(s) > 2 * h else 0.0
    on = np.nonzero(a >= ONSET_M_S2)[0]
    if len(on) == 0:
        return None
    t_on = float(tt[on[0]])
    a_pk = float(np.max(a))
    i20 = np.nonzero(a >= 0.2 * a_pk)[0][0]
    i80 = np.nonzero(a >= 0.8 * a_pk)[0][0]
    jerk = 0.6 * a_pk / max(float(tt[i80] - tt[i20]), 1e-3)
    dist = float(np.sum(0.5 * (s[1:] + s[:-1]) * np.diff(tt)))
    return Stop(t_cmd, v0, t_on - t_cmd, a_pk, jerk, dist, float(tt[-1]))


def predicted_stop(v0: float, a: float, j: float, t_dead: float) -> float:
    """The stop contract's closed form (contracts/stop.py): dead time, then the jerk-limited stop."""
    return stopping_distance(v0, a, j, t_dead)


def calibrate_braking(stops: list[Stop], accel: float, jerk: float, hold_switch_s: float) -> dict:
    """Braking limits never better than the file's: min of the file's and the lowest measured deceleration
    (of the stops fast enough to reach it) and jerk, max of the file's switch time and the longest measured reaction, then the switch time enlarged
    until the closed form's stop (without the daemon's own t_react, which no log measures) covers every
    logged stop. Returns the calibrated values and per-stop overshoots against the file's closed form."""
    if not stops:
        return {"accel_max_m_s2": accel, "jerk_max_m_s3": jerk, "hold_switch_s": hold_switch_s, "stops": 0,
                "changed": False}
    # the deceleration limit is reached only from v ≥ a²/j (below, the S-curve peaks at √(v·j))
    full = [s for s in stops if s.v0 >= 1.5 * accel * accel / jerk]
    a_c = min([accel] + [s.decel_peak for s in full])
    j_c = min(jerk, min(s.jerk for s in stops))
    h_c = max(hold_switch_s, max(s.reaction_s for s in stops))
    for s in stops:  # v·h + braking ≥ measured ⇒ h ≥ (measured − braking)/v
        need = (s.distance_m - braking_distance(s.v0, a_c, j_c)) / s.v0
        h_c = max(h_c, need)
    h_c = math.ceil(h_c * 1000.0) / 1000.0
    return {"accel_max_m_s2": a_c, "jerk_max_m_s3": j_c, "hold_switch_s": h_c, "stops": len(stops),
            "changed": (a_c, j_c, h_c) != (accel, jerk, hold_switch_s)}


# ----------------------------------------------------------------------------- hover thrust


HOVER_MAX_TILT = math.radians(10)


def hover_throttle(throttle, roll, pitch, vz, in_air, max_vz=0.3, max_tilt=HOVER_MAX_TILT) -> dict:
    """Hover throttle from level, steady samples: throttle·cos φ·cos θ (the thrust_ratio estimator's
    nominal), its median and spread (5–95 % and the interquartile range), and the sample count."""
    thr, roll, pitch, vz = (np.asarray(a, float) for a in (throttle, roll, pitch, vz))
    c = np.cos(roll) * np.cos(pitch)
    ok = np.asarray(in_air, bool) & (np.abs(vz) < max_vz) & (np.arccos(np.clip(c, -1, 1)) < max_tilt) & (thr > 0.05)
    h = thr[ok] * c[ok]
    if len(h) < 10:
        return {"samples": len(h), "median": None, "p05": None, "p95": None, "iqr": None}
    p05, p25, p50, p75, p95 = np.percentile(h, [5, 25, 50, 75, 95])
    return {"samples": len(h), "median": float(p50), "p05": float(p05), "p95": float(p95), "iqr": float(p75 - p25)}
