"""The review's HTML: one page per flight (`review.html`: verdict, findings, the plan view and the time series
embedded, the text report) and the page frame the many-flights index (`companion.ground.reviewset`) shares. Imports
nothing of the review, so the review and the index both use it."""

from __future__ import annotations

import base64
import html
from pathlib import Path

from companion.onboard.states import BRAKE_SWITCH, RAMP_FOLLOWED
from contracts.errors import ContractError

STYLE = ("body{font-family:sans-serif;margin:1.5em;max-width:1200px}table{border-collapse:collapse}"
         "td,th{border:1px solid #bbb;padding:4px 8px;font-size:14px}th{background:#eee}.bad{color:#b00;font-weight:bold}"
         ".ok{color:#070;font-weight:bold}pre{background:#f6f6f6;padding:1em;white-space:pre-wrap;font-size:13px}"
         "img{max-width:100%;border:1px solid #ccc}")
PLOTS = (("plan.png", "Plan view"), ("review.png", "Over time"))  # beside the page, in this order
PAGE = "review.html"


def page(title: str, body: str) -> str:
    """A whole HTML document around `body` (already HTML)."""
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head><body>{body}</body></html>\n")


REFUSED = "the autopilot refused the recovery brake's switch above the Hold's limit: the stop was not guaranteed"
RAMP_BROKEN = ("the autopilot accelerated harder than the approach ramp allows: the stop was not guaranteed while it "
               "did")
AUTOPILOT_BROKE = {BRAKE_SWITCH: REFUSED, RAMP_FOLLOWED: RAMP_BROKEN}


def verdict(rep: dict) -> str:
    """A review report's verdict in a few words, naming what must not be missed: a collision or the keep-out disc
    entered, a command refused or not taken in time (the review's own checks, or a `delivery` violation the
    daemon logged), the daemon's own cycle ending in an internal error, and the autopilot breaking an assumption a
    faster governor limit rests on (refusing the recovery brake above the Hold's limit, accelerating harder than the
    approach ramp allows)."""
    if rep["ok"]:
        return "contract kept (no findings)"
    ko, dl = rep.get("keep_out") or {}, rep.get("delivery") or {}
    said = []
    if ko.get("collisions"):
        said.append("a collision, as far as the log tells")
    elif ko.get("entries"):
        said.append("the vehicle entered its keep-out disc")
    if (dl.get("modes_not_taken") or dl.get("limits_not_flown") or (rep.get("commands") or {}).get("failed")
            or "delivery" in rep["violations_by_subsystem"]):
        said.append("a command was refused or not taken in time")
    if rep.get("loop_errors"):
        said.append("the daemon's own cycle failed")
    if "autopilot" in rep["violations_by_subsystem"]:
        broke = "the autopilot broke an assumption the limit rests on"
        said += list(dict.fromkeys(AUTOPILOT_BROKE.get(v.get("guarantee"), broke) for v in rep["violations"]
                                   if v.get("subsystem") == "autopilot")) or [broke]
    return "REVIEW NEEDED" + (": " + "; ".join(said) if said else "")


def flight_page(path: Path, rep: dict, text: str, name: str, back: str | None = None) -> None:
    """One flight's page at `path`: the verdict and findings, its plots (plan view first, embedded: one file to
    send) and the text report; `back`: a link to the index of many flights."""
    imgs = "".join(f"<h2>{title}</h2><img alt='{title.lower()}' src='data:image/png;base64,"
                   f"{base64.b64encode((path.parent / png).read_bytes()).decode()}'>"
                   for png, title in PLOTS if (path.parent / png).exists()) or "<p>no plot</p>"
    findings = "".join(f"<li>{html.escape(x)}</li>" for x in rep["findings"]) or "<li>none</li>"
    said = "<p class='ok'>contract kept</p>" if rep["ok"] else f"<p class='bad'>{html.escape(verdict(rep))}</p>"
    path.write_text(page(f"review — {name}", (f"<p><a href='{html.escape(back)}'>← all flights</a></p>" if back else "")
                         + f"<h1>{html.escape(name)}</h1>{said}<h2>Findings</h2><ul>{findings}</ul>{imgs}"
                         f"<h2>Report</h2><pre>{html.escape(text)}</pre>"))


def write_flight_page(out: Path, rep: dict, text: str, name: str) -> str:
    """`review.html` in `out` for one flight (beside its PNGs, CSV and JSON); its path."""
    path = Path(out) / PAGE
    try:
        flight_page(path, rep, text, name)
    except OSError as err:
        raise ContractError(f"cannot write the review to {out}: {err.strerror or err}") from err
    return str(path)
