"""`contract-guard calibrate LOG... --vehicle FILE --table TABLE --out NEW.npz`: the contract of this aircraft.

Reads each flight log — a MAVLink `.tlog`, a PX4 ULog `.ulg`, an ArduPilot DataFlash `.bin` — into the
ops of `companion/ground/flightlogs/loginput.py` by the readers the review replays them with (`companion.ground.flightlogs`),
then into one `Trace` per log (position, velocity, attitude, commanded path, throttle,
modes, Hold commands), and hands the numbers to the pure statistics of `contracts/calibrate.py`:
- `E_tr_pred` measured per cell (window samples, order-statistic bound, coverage, the never-optimistic
  rule for uncovered cells, monotone upward), written into a copy of the table with its avoid slot;
- braking and reaction from the logged stops, a finding where the vehicle file is optimistic, and a
  calibrated vehicle file beside the table (`NEW.yaml`), which the new table embeds;
- hover throttle and its spread;
- provenance (log SHA-256s, sample counts, the rule) in the table's metadata;
- evidence per cell (windows, distinct flights, worst measured, calibrated/SITL ratio): logs whose flown samples
  are the same flight's (however they are time-stamped: `contracts.calibrate.same_flight`), identical files and
  logs whose time spans overlap are one flight (`flight_groups`); a cell may go below the SITL's E_tr_pred only on the
  evidence `contracts/calibrate.py` states, and a table faster than stock anywhere is refused unless a person
  accepts it (`accept_faster`, the command's `--accept-faster`);
- a report: `NEW.report.json`, `NEW.report.html` and, with matplotlib, `NEW.report.png`.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
from dataclasses import dataclass, field
from html import escape as html_escape
from pathlib import Path

import numpy as np

from companion.onboard.autopilots import adapter_for
from contracts import calibrate as cal
from contracts.errors import ContractError

from .flightlogs.loginput import Feed

IN_AIR = 2  # MAV_LANDED_STATE_IN_AIR
POSITION_MODES = ("mission", "hold", "offboard", "position", "rtl")
HOVER_MIN = 200  # hover samples a log needs before its hover throttle may lower the vehicle file's
HOVER_IQR = 0.05
# a switch to Hold seen only as the mode (ULog, DataFlash) from below this speed is no braking evidence: the
# calibration plan stops from 1 m/s up, and PX4 itself switches to Hold at a mission's end, perhaps still drifting
MIN_SWITCH_STOP_M_S = 1.0


# ----------------------------------------------------------------------------- reading


def read_log(path: Path) -> tuple[Feed, list[tuple[float, str]]]:
    """Any supported flight log → (Feed, the mode commands it holds), by its reader in `companion.ground.flightlogs`
    within the readers' bounds. Damage is the reader's to report."""
    from .flightlogs import read_feed

    feed = read_feed(Path(path))
    return feed, feed.commands


@dataclass
class Trace:
    """One flight, as arrays at the position samples (SI, NED)."""

    name: str
    autopilot: str
    t: np.ndarray
    xy: np.ndarray
    vel: np.ndarray  # (n, 3)
    tilt: np.ndarray
    airborne: np.ndarray
    t_path: np.ndarray
    xy_path: np.ndarray
    hover: dict
    holds: list  # (t_cmd, source)
    mode_at: list = field(default_factory=list)  # (t, mode name) changes


def trace_of(name: str, feed: Feed, commands: list[tuple[float, str]]) -> Trace:
    ad = adapter_for(feed.autopilot if feed.autopilot in ("px4", "ardupilot") else "px4")
    pos, att, tgt, thr, modes, landed = [], [], [], [], [], []
    for t_us, op, a in feed.ops:
        t = t_us / 1e6
        if op == "pos" and all(math.isfinite(v) for v in a):
            pos.append((t, *a))
        elif op == "att" and all(math.isfinite(v) for v in a):
            att.append((t, a[0], a[1]))
        elif op == "target" and math.isfinite(a[0]) and math.isfinite(a[1]):
            tgt.append((t, a[0], a[1]))
        elif op == "thr" and math.isfinite(a[0]):
            thr.append((t, a[0]))
        elif op == "mode":
            name_ = ad.mode_name(int(a[0]), int(a[1]))
            if not modes or modes[-1][1] != name_:
                modes.append((t, name_))
        elif op == "landed":
            landed.append((t, int(a[0])))
    P = np.array(pos, float).reshape(-1, 7)
    t = P[:, 0]
    A = np.array(att, float).reshape(-1, 3)
    roll = np.interp(t, A[:, 0], A[:, 1]) if len(A) else np.zeros(len(t))
    pitch = np.interp(t, A[:, 0], A[:, 2]) if len(A) else np.zeros(len(t))
    tilt = np.arccos(np.clip(np.cos(roll) * np.cos(pitch), -1, 1))
    mode_now = _step_lookup(modes, t, "other")
    if landed:
        in_air = _step_lookup(landed, t, 0) == IN_AIR
    else:  # no landed state: more than 1 m above the lowest point of the flight
        in_air = P[:, 3] < (np.max(P[:, 3]) - 1.0) if len(P) else np.zeros(0, bool)
    steady_z = np.abs(P[:, 6]) < 0.5
    airborne = in_air & steady_z & np.isin(mode_now, POSITION_MODES)
    T = np.array(tgt, float).reshape(-1, 3)
    H = np.array(thr, float).reshape(-1, 2)
    if len(H) and len(t):
        hover = cal.hover_throttle(H[:, 1], np.interp(H[:, 0], t, roll), np.interp(H[:, 0], t, pitch),
                                   np.interp(H[:, 0], t, P[:, 6]), np.interp(H[:, 0], t, in_air.astype(float)) > 0.5)
    else:
        hover = cal.hover_throttle([], [], [], [], [])
    holds = [(tc, "command") for tc, m in commands if m == "hold"]
    if not holds:  # no commands logged: the autopilot's own switch to Hold/Brake (the reaction excludes it)
        holds = [(tm, "mode switch") for (tm, m), (_, prev) in zip(modes[1:], modes[:-1]) if m == "hold" and prev != "hold"]
    return Trace(name, feed.autopilot, t, P[:, 1:3], P[:, 4:7], tilt, airborne, T[:, 0], T[:, 1:3], hover, holds, modes)


def _step_lookup(changes: list, t: np.ndarray, before):
    """The value of a piecewise-constant record [(t, value)] at times `t`."""
    if not changes:
        return np.array([before] * len(t), dtype=object if isinstance(before, str) else int)
    ts = np.array([c[0] for c in changes])
    vals = np.array([c[1] for c in changes] + [before], dtype=object if isinstance(before, str) else int)
    idx = np.searchsorted(ts, t, side="right") - 1
    return vals[np.where(idx < 0, len(changes), idx)]


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# ----------------------------------------------------------------------------- calibration


def flight_thrust_ratio(trace: Trace, hover_nominal: float, top: float) -> float | None:
    """thrust_ratio of the flight: nominal hover throttle over the logged one (None: not estimable)."""
    h = trace.hover.get("median")
    return None if not h else min(top, hover_nominal / h)


def flight_groups(logs: list[dict], series: list | None = None) -> list[tuple[int | None, str | None]]:
    """Per log (`sha256`, `wall_span`: (start, end) UNIX s or None) and its flown samples (`series[n]`:
    `contracts.calibrate.flight_series`, or None), (the index of the log that stands for its flight, why it is that
    flight): itself (why None), or an earlier log with the same flown samples (judged by content: time stamps and
    file hashes aside), identical content, or an overlapping time span (one aircraft flies one flight at a time: a
    .tlog and the autopilot's .ulg of the same flight, or a copy, are one flight); (None, None) for a log that was
    not read. Of a group, the first log stands for it. Pure."""
    out: list[tuple[int | None, str | None]] = []
    for n, lg in enumerate(logs):
        if "sha256" not in lg:
            out.append((None, None))
            continue
        found: tuple[int | None, str | None] = (n, None)
        for m in range(n):
            other = logs[m]
            if out[m][0] is None:
                continue
            a, b = lg.get("wall_span"), other.get("wall_span")
            shift = (None if series is None or series[n] is None or series[m] is None
                     else cal.same_flight(series[m], series[n]))
            if other["sha256"] == lg["sha256"]:
                why = "identical content"
            elif a and b and a[0] < b[1] and b[0] < a[1]:
                why = "overlapping time span"
            elif shift is not None:
                why = "the same flown samples, time offset removed" + (
                    f"; its time stamps {(a[0] - b[0] - shift) / 3600:+.1f} h from the other's" if a and b else "")
            else:
                continue
            found = (out[m][0], why)
            break
        out.append(found)
    return out


def flights_of(logs: list[dict], series: list | None = None) -> list[int | None]:
    """Per log, the index of the log that stands for its flight (`flight_groups`)."""
    return [rep for rep, _ in flight_groups(logs, series)]


def calibrate(paths: list[Path], vehicle, table, out: Path, *, quantile=cal.QUANTILE, confidence=cal.CONFIDENCE,
              report: bool = True, accept_faster: bool = False) -> dict:
    """Calibrate `table` (a verified `ContractTable` for `vehicle`) from the logs; write `out` (+ .yaml, report).
    A result faster than the stock table anywhere (a cell below its SITL prediction) is refused (one line, the
    report written) unless `accept_faster`."""
    from contracts.table import Slot, write_table
    from contracts.vehicle import vehicle_from_dict

    if table.e_pred is None:
        raise ContractError(f"table {table.path}: no controller contract (E_tr_pred) to calibrate")
    axes = table.e_pred.axes
    hover_nominal = vehicle.controller.thr_hover
    logs, samples, stops, traces, read, series = [], [], [], [], [], []
    for p in paths:
        p = Path(p)
        try:
            feed, cmds = read_log(p)
            tr = trace_of(p.name, feed, cmds)
        except ContractError as err:
            logs.append({"log": str(p), "error": str(err)})
            series.append(None)
            continue
        except Exception as err:  # noqa: BLE001 — a log the readers could not make sense of: said, not fatal
            logs.append({"log": str(p), "error": f"unreadable ({type(err).__name__}: {err})"})
            series.append(None)
            continue
        series.append(cal.flight_series(tr.t, tr.vel))
        ratio = flight_thrust_ratio(tr, hover_nominal, float(axes[2][-1]))
        w = cal.windows(tr.t, tr.xy, np.hypot(tr.vel[:, 0], tr.vel[:, 1]), tr.tilt, tr.t_path, tr.xy_path, tr.airborne)
        # no hover estimate: the grid's lowest thrust_ratio (the cell that helps least, never optimistic)
        r_used = ratio if ratio is not None else float(axes[2][0])
        flight_stops = [(src, s) for tc, src in tr.holds if (s := cal.measure_stop(tr.t, tr.vel[:, :2], tc)) is not None
                        and (src == "command" or s.v0 >= MIN_SWITCH_STOP_M_S)]
        read.append((len(logs), [(e, v, ti, r_used) for e, v, ti in zip(w.e, w.v, w.tilt)],
                     [(p.name, src, s) for src, s in flight_stops], tr))
        wall = feed.wall0 if math.isfinite(feed.wall0) and feed.wall0 > 0 else None
        logs.append({"log": str(p), "sha256": sha256_file(p), "format": feed.info.get("format", p.suffix),
                     "wall_span": None if wall is None or not len(tr.t) else (wall + float(tr.t[0]), wall + float(tr.t[-1])),
                     "autopilot": feed.autopilot, "span_s": float(tr.t[-1] - tr.t[0]) if len(tr.t) else 0.0,
                     "airborne_s": float(np.count_nonzero(tr.airborne) / max(len(tr.t), 1) * (tr.t[-1] - tr.t[0]))
                     if len(tr.t) > 1 else 0.0,
                     "windows": len(w.e), "path_samples": len(tr.t_path), "holds": len(tr.holds),
                     "stops_measured": len(flight_stops), "hover": tr.hover, "thrust_ratio": ratio})
    if not read:
        raise ContractError("no log could be read: " + "; ".join(x["error"] for x in logs))
    # one flight, one vote: a copy of a log, the same flight stamped anew, or a second log of the same flight
    # (overlapping in time) adds nothing
    groups = flight_groups(logs, series)
    rep = [r for r, _ in groups]
    flight_ids = []
    for n, s_, st, tr in read:
        lg = logs[n]
        lg["flight"] = Path(logs[rep[n]]["log"]).name
        if rep[n] != n:
            lg["not_counted"] = f"the same flight as {lg['flight']} ({groups[n][1]}): counted once"
            continue
        samples += s_
        flight_ids += [n] * len(s_)
        stops += st
        traces.append(tr)
    n_flights = len(set(r for r in rep if r is not None))
    ec = cal.calibrate_etr(table.e_pred.values, axes, samples, flights=flight_ids, quantile=quantile,
                           confidence=confidence)
    evidence = cal.cell_evidence(axes, table.e_pred.values, ec.values, ec.counts, ec.flights, ec.measured_max)
    b = vehicle.braking
    t_dead = b.hold_switch_s
    stop_rows = []
    for name, src, s in stops:
        pred = cal.predicted_stop(s.v0, b.accel_max_m_s2, b.jerk_max_m_s3, t_dead)
        stop_rows.append({"log": name, "source": src, "t_cmd": s.t_cmd, "v0": s.v0, "reaction_s": s.reaction_s,
                          "decel_peak_m_s2": s.decel_peak, "jerk_m_s3": s.jerk, "distance_m": s.distance_m,
                          "predicted_m": pred, "overshoot_m": s.distance_m - pred})
    # a stop timed from the autopilot's mode switch (ULog, DataFlash: no command logged) measures only part
    # of the reaction, a lower bound of it: it may lengthen the switch time, never shorten it
    brk = cal.calibrate_braking([s for _, _, s in stops], b.accel_max_m_s2, b.jerk_max_m_s3, b.hold_switch_s)
    findings = []
    over = [r for r in stop_rows if r["overshoot_m"] > 0.05]
    if over:
        worst = max(over, key=lambda r: r["overshoot_m"])
        findings.append(f"the vehicle file's braking is optimistic: {len(over)} of {len(stop_rows)} logged stops ran "
                        f"longer than the stop contract's closed form (worst {worst['distance_m']:.2f} m against "
                        f"{worst['predicted_m']:.2f} m from {worst['v0']:.1f} m/s)")
    if ec.ratio > 1.0:
        findings.append(f"the aircraft tracks worse than its SITL model: measured/predicted E_tr up to {ec.ratio:.2f} "
                        "on the covered cells (the uncovered cells are scaled by their covered neighbours' ratio, "
                        "or by it where they have none)")
    vdict = vehicle.metadata()
    vdict["braking"] = {**vdict["braking"], "accel_max_m_s2": brk["accel_max_m_s2"], "jerk_max_m_s3": brk["jerk_max_m_s3"],
                        "hold_switch_s": brk["hold_switch_s"]}
    # the thrust_ratio estimator's nominal: a lower nominal reads as less thrust (never optimistic), so the
    # file's value is only lowered, and only from steady hover records (≥ HOVER_MIN samples, IQR ≤ HOVER_IQR)
    h_all = [lg["hover"]["median"] for lg in logs if (lg.get("hover") or {}).get("median") and "not_counted" not in lg
             and lg["hover"]["samples"] >= HOVER_MIN and lg["hover"]["iqr"] <= HOVER_IQR]
    if h_all:
        vdict["controller"] = {**vdict["controller"], "thr_hover": min(vehicle.controller.thr_hover, float(np.median(h_all)))}
    vdict["description"] = (vehicle.description + f" — calibrated from {len(traces)} flight log(s)").strip(" —")
    veh_cal = vehicle_from_dict(vdict, "calibrated vehicle")
    n_cells = int(ec.counts.size)
    info = dict(table.e_pred.info)
    info["method"] = "calibrated from flight logs (contracts/calibrate.py) over the SITL-built E_tr_pred: " + str(
        info.get("method", ""))[:200]
    info["calibration"] = {
        "rule": {"sample": f"worst contour error per {cal.WINDOW_S:g} s window, speed and tilt the largest in the "
                           f"window and the {cal.LOOKBACK_S:g} s before it, the flight's thrust_ratio",
                 "bound": f"covered cell (n >= {ec.n_min}): the largest of its n window maxima, which exceeds the "
                          f"{quantile:g}-quantile with confidence 1 - {quantile:g}^n >= {confidence:g}; times "
                          f"(1 + {cal.MARGIN_REL:g}) plus {cal.MARGIN_ABS_M:g} m",
                 "uncovered": f"max(E_sitl, E_sitl * rho_nb, the bound of its own windows): rho_nb the largest "
                              "measured/predicted ratio of the covered cells within "
                              f"{cal.NEIGHBOUR_STEPS} grid step(s) in every axis; where there is none, rho* = "
                              f"{ec.ratio:.3f} (the largest ratio over all covered cells, at least 1)",
                 "neighbour_steps": cal.NEIGHBOUR_STEPS,
                 "monotone": "repaired upward", "quantile": quantile, "confidence": confidence, "n_min": ec.n_min},
        "counts": ec.counts.tolist(), "covered": ec.covered.astype(int).tolist(),
        "covered_cells": int(np.count_nonzero(ec.covered)), "cells": n_cells,
        "covered_fraction": float(np.count_nonzero(ec.covered)) / n_cells,
        "samples": len(samples), "samples_outside_grid": ec.outside, "ratio": ec.ratio,
        "uncovered_from_neighbours": int(np.count_nonzero(ec.from_neighbours)),
        "rho_covered": [[int(i), int(j), int(k), round(float(ec.rho[i, j, k]), 4)] for i, j, k in zip(*np.nonzero(np.isfinite(ec.rho)))],
        "monotone_repairs_up": ec.repairs, "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "logs": [{k: lg.get(k) for k in ("log", "sha256", "format", "windows", "span_s", "flight", "not_counted", "error")
                  if k in lg} for lg in logs],
        "flights": n_flights,
        # per cell: distinct flights and the worst window (-1: none), the evidence rule for going below the SITL
        "flights_per_cell": ec.flights.tolist(),
        "worst_m": np.where(np.isfinite(ec.measured_max), ec.measured_max, -1.0).round(4).tolist(),
        "evidence_below_stock": {"min_flights": cal.MIN_FLIGHTS_BELOW,
                                 "min_windows": cal.MIN_WINDOWS_BELOW_FACTOR * ec.n_min, "floor": cal.BELOW_FLOOR},
        "faster_cells": int(np.count_nonzero(ec.faster)), "faster_accepted": bool(accept_faster and ec.faster.any()),
        "stock_values": np.asarray(table.e_pred.values, float).tolist(),  # the SITL's E_tr_pred (the ratios' base)
        "stock_table": str(table.path), "stock_arrays_sha256": table.meta.get("arrays_sha256"),
    }
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_table(out, veh_cal, tilt_model=table.tilt_model, avoid=table.avoid,
                e_tr_pred=Slot(axes, ec.values, info), method=table.meta.get("method"))
    yaml_path = out.with_suffix(".yaml")
    _write_vehicle_yaml(yaml_path, veh_cal, vehicle)
    from contracts.table import verify

    new = verify(out, veh_cal)
    scen = v_max_changes(table, new)
    faster = [r for r in evidence if r["faster"]]
    lowest = min([r["ratio"] for r in faster if r["ratio"] is not None], default=0.0)  # 0: a cell with no SITL bound
    up = [(row["scenario"], c, row[c]) for row in scen for c in ("avoid", "stop") if c in row
          and row[c]["calibrated"] > row[c]["stock"] + 1e-9]
    if faster:
        findings.append(f"FASTER than stock: {len(faster)} cell(s) below the SITL's E_tr_pred (down to "
                        f"{lowest:.2f} of it) on evidence from {n_flights} flight(s)"
                        + "".join(f"; V_max {c} at {sc} {v['stock']:.2f} -> {v['calibrated']:.2f} m/s" for sc, c, v in up)
                        + (" (accepted with --accept-faster)" if accept_faster else ""))
    summary = {
        "table": str(out), "vehicle_file": str(yaml_path), "logs": logs, "samples": len(samples),
        "flights": n_flights, "evidence": evidence, "faster_cells": len(faster), "faster_accepted": bool(accept_faster and faster),
        "coverage": {"covered_cells": info["calibration"]["covered_cells"], "cells": n_cells,
                     "covered_fraction": info["calibration"]["covered_fraction"], "n_min": ec.n_min},
        "ratio_measured_over_predicted": ec.ratio, "monotone_repairs_up": ec.repairs,
        "braking": {"file": b.model_dump(), "calibrated": brk, "stops": stop_rows},
        "hover": {"nominal": hover_nominal, "per_log": [lg.get("hover") for lg in logs if "hover" in lg]},
        "v_max": scen, "findings": findings,
    }
    if report:
        write_report(out, summary, table, new, ec, traces)
    if faster and not accept_faster:
        for f in (out, yaml_path):
            f.unlink(missing_ok=True)
        raise ContractError(
            f"calibrate: refused: {len(faster)} cell(s) would be faster than the stock table (E_tr_pred down to "
            f"{lowest:.2f} of the SITL's"
            + (f"; V_max {up[0][1]} at {up[0][0]} {up[0][2]['stock']:.2f} -> {up[0][2]['calibrated']:.2f} m/s" if up else "")
            + f") on evidence from {n_flights} flight(s); check the per-cell evidence"
            + (f" in {out.with_suffix('')}.report.html" if report else "") + " and accept it with --accept-faster")
    return summary


def _write_vehicle_yaml(path: Path, veh, stock) -> None:
    import yaml

    d = veh.metadata()
    head = (f"# {veh.name}: calibrated by `contract-guard calibrate` from flight logs; braking and hover thrust "
            "measured (never better than the original file's).\n# Original vehicle: "
            f"{stock.name} (sha256 {stock.fingerprint()[:16]}).\n")
    path.write_text(head + yaml.safe_dump(d, sort_keys=False))


# the paper's scenarios and typical conditions: (label, d_od, r_obst, thrust_ratio)
SCENARIOS = (("D_od 4 m, R_obst 0.5 m", 4.0, 0.5, 1.0), ("D_od 8 m, R_obst 0.5 m", 8.0, 0.5, 1.0),
             ("D_od 8 m, thrust 0.85", 8.0, 0.5, 0.85), ("D_od 12 m, R_obst 1 m", 12.0, 1.0, 1.0))


def v_max_changes(stock, new) -> list[dict]:
    rows = []
    for label, d, r, k in SCENARIOS:
        row = {"scenario": label, "d_od": d, "r_obst": r, "thrust_ratio": k}
        for contract in ("avoid", "stop"):
            if contract == "avoid" and (stock.avoid is None or new.avoid is None):
                continue
            a, b = stock.omega(d, r, 0.0, k, contract), new.omega(d, r, 0.0, k, contract)
            row[contract] = {"stock": a.v_max, "calibrated": b.v_max}
        rows.append(row)
    return rows


def format_summary(s: dict) -> str:
    c = s["coverage"]
    lines = [(f"calibrated {s['table']} from {sum(1 for x in s['logs'] if 'error' not in x)} log(s) of "
              f"{s['flights']} distinct flight(s), {s['samples']} window samples; vehicle file {s['vehicle_file']}"),
             (f"  controller contract measured on {c['covered_cells']} of {c['cells']} cells "
              f"({100 * c['covered_fraction']:.1f} % of the envelope; a cell needs >= {c['n_min']} windows); "
              f"measured/predicted up to {s['ratio_measured_over_predicted']:.2f}")]
    for lg in s["logs"]:
        if "error" in lg:
            lines.append(f"  {lg['log']}: skipped: {lg['error']}")
        elif "not_counted" in lg:
            lines.append(f"  {Path(lg['log']).name}: not counted: {lg['not_counted']}")
        else:
            h = lg["hover"]
            lines.append(f"  {Path(lg['log']).name}: {lg['format']}, {lg['span_s']:.0f} s, {lg['windows']} windows, "
                         f"{lg['stops_measured']}/{lg['holds']} stops measured, hover throttle "
                         + (f"{h['median']:.3f} (5-95 % {h['p05']:.3f}-{h['p95']:.3f})" if h.get("median") else "unknown"))
    br = s["braking"]["calibrated"]
    lines.append(f"  braking: {br['stops']} stop(s); decel {br['accel_max_m_s2']:.2f} m/s^2, jerk "
                 f"{br['jerk_max_m_s3']:.2f} m/s^3, hold switch {br['hold_switch_s']:.3f} s"
                 + (" (changed from the vehicle file)" if br.get("changed") else " (as the vehicle file)"))
    for row in s["v_max"]:
        parts = [f"{k} {row[k]['stock']:.2f} -> {row[k]['calibrated']:.2f} m/s" for k in ("avoid", "stop") if k in row]
        lines.append(f"  V_max at {row['scenario']}: " + ", ".join(parts))
    for f in s["findings"]:
        lines.append(f"  finding: {f}")
    lines += ["  evidence per cell (cells with windows, or faster than stock):"] + [
        f"    {cal.evidence_line(r)}" for r in s["evidence"]]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- report


def write_report(out: Path, summary: dict, stock, new, ec, traces) -> None:
    base = out.with_suffix("")
    Path(f"{base}.report.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    png = _plot(Path(f"{base}.report.png"), stock, new, ec, summary)
    esc = html_escape  # everything from a log (its file name above all) is text, never markup
    rows = "".join(f"<tr><td>{esc(str(r['log']))}</td><td>{esc(str(r['source']))}</td><td>{r['v0']:.2f}</td><td>{r['reaction_s']:.3f}</td>"
                   f"<td>{r['decel_peak_m_s2']:.2f}</td><td>{r['jerk_m_s3']:.2f}</td><td>{r['distance_m']:.2f}</td>"
                   f"<td>{r['predicted_m']:.2f}</td><td>{r['overshoot_m']:+.2f}</td></tr>"
                   for r in summary["braking"]["stops"])
    vm = "".join(f"<tr><td>{esc(str(r['scenario']))}</td>" + "".join(
        f"<td>{r[k]['stock']:.2f} → {r[k]['calibrated']:.2f}</td>" if k in r else "<td>—</td>" for k in ("avoid", "stop"))
        + "</tr>" for r in summary["v_max"])
    text = esc(format_summary(summary))
    html = f"""<!doctype html><html><head><meta charset="utf-8"><title>calibration {esc(out.name)}</title>
<style>body{{font-family:sans-serif;max-width:70em;margin:1em auto}}td,th{{padding:2px 8px;border-bottom:1px solid #ccc}}</style>
</head><body><h1>Calibration: {esc(out.name)}</h1><pre>{text}</pre>
{f'<img src="{esc(Path(png).name)}" style="max-width:100%">' if png else '<p>(no plot: pip install contract-guard[plot])</p>'}
<h2>Logged stops against the stop contract's closed form</h2><table><tr><th>log</th><th>from</th><th>v0 m/s</th>
<th>reaction s</th><th>decel m/s²</th><th>jerk m/s³</th><th>distance m</th><th>closed form m</th><th>overshoot m</th></tr>{rows}</table>
<h2>V_max, stock → calibrated [m/s]</h2><table><tr><th>scenario</th><th>avoid</th><th>stop</th></tr>{vm}</table>
</body></html>"""
    Path(f"{base}.report.html").write_text(html)


def _plot(path: Path, stock, new, ec, summary) -> str | None:
    import importlib.util

    if importlib.util.find_spec("matplotlib") is None:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v, tilt, tr = stock.e_pred.axes
    k = len(tr) - 1
    fig, ax = plt.subplots(1, 3, figsize=(16, 4.6))
    tilt_deg = np.degrees(tilt)
    for j in range(0, len(tilt), max(1, len(tilt) // 4)):
        line, = ax[0].plot(v, stock.e_pred.values[:, j, k], "--", lw=1)
        ax[0].plot(v, new.e_pred.values[:, j, k], "-", color=line.get_color(), label=f"tilt {tilt_deg[j]:.0f}°")
        m = ec.covered[:, j, k]
        ax[0].plot(v[m], ec.measured_max[m, j, k], "o", color=line.get_color(), ms=4)
    ax[0].set(xlabel="V_max [m/s]", ylabel="E_tr_pred [m]",
              title=f"E_tr_pred at thrust_ratio {tr[k]:g}: SITL (dashed), calibrated (solid), measured max (dots)")
    ax[0].title.set_fontsize(8)
    ax[0].legend(fontsize=7)
    cov = ec.counts.sum(axis=2).T
    im = ax[1].imshow(cov, origin="lower", aspect="auto", cmap="viridis",
                      extent=(v[0] - 0.25, v[-1] + 0.25, 0, len(tilt)))
    ax[1].set_yticks(np.arange(len(tilt)) + 0.5, [f"{d:.0f}" for d in tilt_deg])
    cv = ec.covered.any(axis=2).T
    for (jj, ii) in zip(*np.nonzero(cv)):
        ax[1].text(v[ii], jj + 0.5, "✓", color="w", ha="center", va="center", fontsize=8)
    ax[1].set(xlabel="V_max [m/s]", ylabel="tilt [deg]", title="window samples per cell (✓ covered)")
    fig.colorbar(im, ax=ax[1])
    rows = summary["braking"]["stops"]
    if rows:
        vv = np.array([r["v0"] for r in rows])
        ax[2].plot(vv, [r["distance_m"] for r in rows], "o", label="logged stops (command → rest)")
        vs = np.linspace(0, max(vv) * 1.05, 50)
        b, c = summary["braking"]["file"], summary["braking"]["calibrated"]
        ax[2].plot(vs, [cal.predicted_stop(x, b["accel_max_m_s2"], b["jerk_max_m_s3"], b["hold_switch_s"]) for x in vs],
                   "--", label="closed form, vehicle file")
        ax[2].plot(vs, [cal.predicted_stop(x, c["accel_max_m_s2"], c["jerk_max_m_s3"], c["hold_switch_s"]) for x in vs],
                   "-", label="closed form, calibrated")
        ax[2].legend(fontsize=7)
    ax[2].set(xlabel="speed at the Hold command [m/s]", ylabel="stopping distance [m]", title="braking")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return str(path)
