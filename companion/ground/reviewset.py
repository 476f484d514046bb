"""Many flights at once: `contract-guard review LOG...` with several raw logs (files, or folders holding
`.tlog`/`.ulg`/`.bin` files) reviews each on its own and gives one summary table — per flight: duration,
time in each mode, max Γ, time outside the contract, worst measured E_tr against the contract's, findings
— plus each flight's report; with `--out`, each flight's PNG/CSV/JSON under `flights/<name>/` and an HTML
report (an `index.html` linking one page per flight, plots embedded) a reviewer opens as one file.

A flight that cannot be reviewed (an unreadable file) is a row with its one-line reason: the others
are still reviewed.
"""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

from contracts.errors import ContractError

from .review_html import PAGE, flight_page, page

SCHEMA = "contract-guard/review-set"


def expand(paths, suffixes) -> list[Path]:
    """The raw logs among `paths`, folders expanded (sorted), in the order given."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(q for q in p.rglob("*") if not q.is_dir() and q.suffix.lower() in suffixes)  # a device: said
        elif p.suffix.lower() in suffixes:
            out.append(p)
        elif not p.exists():
            raise ContractError(f"no such file or directory: {p}")
    return out


def _mode_time(rep: dict) -> dict[str, float]:
    """Seconds in each mode, from the mode changes over the report's span."""
    sp = rep["span"]
    t0, t1 = sp.get("t_first"), sp.get("t_last")
    if t0 is None or t1 is None:
        return {}
    changes = [m for m in rep["mode_changes"] if m.get("t") is not None]
    out: dict[str, float] = {}
    mode, t = (changes[0]["from"] if changes else "unknown"), t0
    for m in changes:
        out[mode] = out.get(mode, 0.0) + max(0.0, m["t"] - t)
        mode, t = m["to"], m["t"]
    out[mode] = out.get(mode, 0.0) + max(0.0, t1 - t)
    return {k: round(v, 1) for k, v in out.items()}


def row(path: Path, rep: dict | None, error: str | None) -> dict:
    if rep is None:
        return {"log": str(path), "ok": None, "error": error}
    src = rep.get("flight_log") or rep.get("replay") or {}
    veh, fw = src.get("vehicle"), src.get("firmware") or {}
    if not fw and isinstance(src.get("autopilot"), dict):  # a .tlog: the autopilot family its HEARTBEAT named
        fw = {"name": {"px4": "PX4", "ardupilot": "ArduPilot"}.get(src["autopilot"].get("kind"),
                                                                  src["autopilot"].get("kind"))}
    e_tr = src.get("e_tr") or {}
    return {
        "log": str(path), "ok": rep["ok"], "error": None,
        "format": src.get("format", "MAVLink tlog" if "replay" in rep else None),
        "vehicle": veh.get("hardware") if isinstance(veh, dict) else veh,
        "firmware": " ".join(x for x in (fw.get("name"), fw.get("release")) if x) or None,
        "duration_s": rep["span"]["duration_s"],
        "mode_time_s": _mode_time(rep),
        "gamma_max": rep["ranges"]["gamma"]["max"],
        "outside_contract_s": rep["gamma_positive_s"],
        "e_tr_measured_max_m": e_tr.get("measured_max_m", rep["ranges"]["e_tr_measured"]["max"]),
        "e_tr_contract_m": e_tr.get("used_at_max_m", rep["ranges"]["e_tr"]["max"]),
        "findings": len(rep["findings"]),
        "obstacle_data": rep.get("obstacle_data", True),
        # no obstacle data: the detection range the flight needed at its worst (None: faster than any range allows)
        "d_od_needed_m": ((rep.get("detection_need") or {}).get("worst") or {}).get("d_od_m"),
    }


def need_text(f: dict) -> str:
    """The index's word on obstacle data: `sensed`, or the detection range the flight needed without it."""
    if f.get("obstacle_data", True):
        return "sensed"
    if f.get("d_od_needed_m") is None:
        return "no data; needed: —"
    return f"no data; needed ≤ {f['d_od_needed_m']:.1f} m"


def review_set(paths, suffixes, review_one, out_dir: Path | None = None) -> dict:
    """Review every raw log among `paths` with `review_one(path, out_dir) -> (report, origin)`."""
    from .review import format_report

    logs = expand(paths, suffixes)
    if not logs:
        raise ContractError(f"no flight logs ({', '.join(sorted(suffixes))}) in {', '.join(map(str, paths))}")
    flights, texts = [], []
    names = _names(logs)
    for path, name in zip(logs, names):
        sub = None if out_dir is None else Path(out_dir) / "flights" / name
        try:
            rep, origin = review_one(path, sub)
        except Exception as err:  # noqa: BLE001 — one flight's damage never stops the others: its row says why
            why = str(err) if isinstance(err, ContractError) else f"{path}: unreadable ({type(err).__name__}: {err})"
            flights.append(row(path, None, why))
            texts.append(f"contract-guard review: {path}\n  not reviewed: {why}")
            continue
        flights.append({**row(path, rep, None), "page": f"flights/{name}/{PAGE}", "report": rep})
        texts.append(format_report(rep, origin))
    result = {"schema": SCHEMA, "flights": flights, "ok": all(f["ok"] for f in flights)}
    if out_dir is not None:
        result["outputs"] = write_html(result, texts, Path(out_dir))
    return result, texts


def _names(logs: list[Path]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for p in logs:
        base = re.sub(r"[^A-Za-z0-9_.-]", "_", p.name)
        seen[base] = seen.get(base, 0) + 1
        out.append(base if seen[base] == 1 else f"{base}-{seen[base]}")
    return out


def _fmt(v, unit=""):
    if v is None:
        return "—"
    return f"{v:.3g}{unit}" if isinstance(v, float) else f"{v}{unit}"


def summary_lines(result: dict) -> list[str]:
    head = f"{'flight':<44} {'duration':>9} {'max Γ':>7} {'Γ>0 s':>6} {'E_tr meas/contract':>19} {'findings':>8}  verdict"
    lines = [f"contract-guard review: {len(result['flights'])} flight(s)", head]
    for f in result["flights"]:
        name = Path(f["log"]).name[:44]
        if f["error"]:
            lines.append(f"{name:<44} not reviewed: {f['error']}")
            continue
        etr = f"{_fmt(f['e_tr_measured_max_m'])} / {_fmt(f['e_tr_contract_m'])} m"
        lines.append(f"{name:<44} {_fmt(f['duration_s'], ' s'):>9} {_fmt(f['gamma_max']):>7} "
                     f"{f['outside_contract_s']:>6.1f} {etr:>19} {f['findings']:>8}  "
                     + ("kept" if f["ok"] else "REVIEW NEEDED"))
        modes = ", ".join(f"{k} {v:g} s" for k, v in f["mode_time_s"].items())
        lines.append(f"{'':<44} {f.get('vehicle') or '?'}, {f.get('firmware') or '?'}; modes: {modes or '—'}; "
                     f"obstacles: {need_text(f)}")
    return lines


def write_html(result: dict, texts: list[str], out: Path) -> dict:
    """`index.html` (the summary table) and one page per flight (report text and its plot, embedded)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        rows = []
        for f, text in zip(result["flights"], texts):
            name = html.escape(Path(f["log"]).name)
            if f["error"]:
                rows.append(f"<tr><td>{name}</td><td colspan='8' class='bad'>not reviewed: {html.escape(f['error'])}</td></tr>")
                continue
            # the flight's own page, again with its way back to the table
            flight_page(out / f["page"], f["report"], text, Path(f["log"]).name, back="../../index.html")
            verdict = "<span class='ok'>kept</span>" if f["ok"] else "<span class='bad'>REVIEW NEEDED</span>"
            modes = ", ".join(f"{html.escape(k)} {v:g} s" for k, v in f["mode_time_s"].items())
            rows.append(f"<tr><td><a href='{f['page']}'>{name}</a></td><td>{html.escape(str(f.get('vehicle') or '?'))}<br>"
                        f"{html.escape(str(f.get('firmware') or '?'))}</td><td>{_fmt(f['duration_s'], ' s')}</td>"
                        f"<td>{modes}</td><td>{_fmt(f['gamma_max'])}</td><td>{f['outside_contract_s']:.1f}</td>"
                        f"<td>{_fmt(f['e_tr_measured_max_m'])} / {_fmt(f['e_tr_contract_m'])}</td>"
                        f"<td>{html.escape(need_text(f))}</td><td>{f['findings']}</td><td>{verdict}</td></tr>")
        head = ("<tr><th>flight</th><th>vehicle, firmware</th><th>duration</th><th>time in mode</th><th>max Γ [m/s]</th>"
                "<th>Γ &gt; 0 [s]</th><th>E_tr measured / contract [m]</th><th>obstacle data</th><th>findings</th>"
                "<th>verdict</th></tr>")
        index = out / "index.html"
        index.write_text(page("contract-guard review", f"<h1>contract-guard review: {len(result['flights'])} flight(s)</h1>"
                               f"<table>{head}{''.join(rows)}</table>"))
        js = out / "review-set.json"
        js.write_text(json.dumps(result, indent=1, default=str, allow_nan=False))
    except OSError as err:
        raise ContractError(f"cannot write the review to {out}: {err.strerror or err}") from err
    return {"html": str(index), "json": str(js)}
