"""`contract-guard review LOG`: a contract-violation report for one flight, from the daemon's event log.

`review(paths, out_dir=None) -> dict` reads the log (a directory's rotated set, a file, or several),
`summarise(records)` (pure) builds the report, `findings(report)` is what it concludes, and
`format_report(report)` renders it for a person. The same pass checks where the vehicle went and what the
autopilot did with the daemon's commands (`companion.ground.review_checks`: keep-out entries, collisions as far as the
log tells, mode commands and speed limits not taken in time). This module reads event logs only: a raw log is first
turned into one by a converter (`companion.ground.flightlogs.tlog` for a `.tlog`; `companion.cli` picks it), which hands
over an `Origin` (its own report section and findings). With
`out_dir`: `review.png` (speed limit and ground speed, Γ, `d_od`, `e_tr`, `thrust_ratio`, `r_obst` over
time) and `plan.png` (the track from above), both drawn by `companion.ground.review_plots` with holds, failsafes,
stand-downs, link-down spans, collisions and violations marked, `samples.csv` and `review.json`. A log
without obstacle data (D_od 0 throughout) is judged by the detection range it needed
(`companion.ground.detection_need`). Bad or missing input ends in one `ContractError` line.

The record schema (state fields with units, events with their fields) is `companion.onboard.logschema`. The
reader also takes what today's daemon does not write: `failsafe_clear` (cause, optional: clears that
cause, else all), a `command`'s `result`, and `link` status `reconnect`.

Report semantics: time integrals hold each sample's value until the next sample of the same daemon run
(`boot`), and do not bridge gaps longer than `gap_s` (default 1 s) or backwards steps of `t` (those are
counted as `sample_gaps`). "The limit" is `v_cmd` where the daemon commanded one, else `v_max`. A
violation still open when its daemon run ends is closed at that run's last record and marked
`ended_by: "restart"` or `"end of log"`.
"""

from __future__ import annotations

import datetime as _dt
import functools
import json
import math
from pathlib import Path
from typing import Iterable

from companion.onboard.eventlog import file_set, finite_copy, read_events
from companion.onboard.logschema import LINK_COUNTERS, LOG_FILE, STATE_FIELDS, SUBSYSTEMS
from companion.onboard.modes import MODES
from companion.onboard.states import CYCLE_COMPLETES, REFERENCE_ON
from contracts import csvfile
from contracts.errors import ContractError

from . import review_checks
from .review_checks import SPEED_TOLERANCE_M_S, Checks, RunFacts, command_text, facts_of_start, refused
from .review_html import PAGE, verdict, write_flight_page

SCHEMA = "contract-guard/review"
SCHEMA_VERSION = 1
CSV_COLUMNS = ("boot", "seq", "t", "wall", *STATE_FIELDS)
RANGE_FIELDS = ("v_max", "v_cmd", "ground_speed", "v_safe", "gamma", "gamma_flown", "d_od", "d_od_stated", "e_tr",
                "e_tr_measured", "thrust_ratio", "r_obst", "tilt_deg", "withheld", *LINK_COUNTERS)
# ground speed above the limit by up to this fraction of it (plus `tolerance_m_s`) is a tracking overshoot, the
# controller's business (covered by E_tr), not a broken limit: the supervisor's own rule ("speed limit not in
# force" needs 1.05 × limit + margin). Above V_safe is always a finding (outside_contract).
OVERSHOOT = 0.05
MAX_LISTED = 1000  # longest list kept per kind of event in the report (the rest are counted)
# the daemon's failsafe reason for the autopilot's heartbeat lost (`supervisor`): in a replay, the log fell silent
LOG_LINK = "autopilot heartbeat lost"
NOT_REPORTED = "autopilot did not report "  # a start-up check's reason for a parameter not answered (`startup`)
NOT_LATENESS = (CYCLE_COMPLETES, REFERENCE_ON)  # guidance's guarantees whose `observed` is not a cycle's gap


def _num(x) -> float | None:
    """A finite float, or None (null, NaN written as null, text, bool)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x) if math.isfinite(x) else None


def _hashable(v):
    return v if isinstance(v, (str, int, float, bool, type(None))) else repr(v)


def _utc(wall) -> str | None:
    w = _num(wall)
    if w is None:
        return None
    try:
        return _dt.datetime.fromtimestamp(w, _dt.timezone.utc).isoformat(timespec="seconds")
    except (OverflowError, OSError, ValueError):
        return None


class _Range:
    __slots__ = ("lo", "hi", "missing")

    def __init__(self):
        self.lo, self.hi, self.missing = math.inf, -math.inf, 0

    def add(self, v) -> None:
        v = _num(v)
        if v is None:
            self.missing += 1
        else:
            self.lo, self.hi = min(self.lo, v), max(self.hi, v)

    def out(self) -> dict:
        ok = self.lo <= self.hi
        return {"min": self.lo if ok else None, "max": self.hi if ok else None, "missing": self.missing}


class _Spans:
    """Stretches of state samples where a condition holds: [{start_t, end_t, duration_s, worst, worst_t}];
    a span ends at the first sample where it no longer holds (or at the end of its daemon run)."""

    def __init__(self, key: str):
        self.key = key
        self.spans: list[dict] = []
        self.open: dict | None = None
        self.worst: dict | None = None  # over every sample, held or not
        self.count = 0

    def add(self, t, on: bool, value) -> None:
        if value is not None and (self.worst is None or value > self.worst[self.key]):
            self.worst = {self.key: value, "t": t}
        if on and self.open is None:
            self.open = {"start_t": t, "end_t": t, "duration_s": 0.0, "worst": value, "worst_t": t}
        elif on:
            self.open["end_t"] = t
            if value is not None and (self.open["worst"] is None or value > self.open["worst"]):
                self.open.update(worst=value, worst_t=t)
        elif self.open is not None:
            self._close(t)

    def _close(self, t) -> None:
        sp, self.open = self.open, None
        sp["end_t"] = t
        sp["duration_s"] = None if sp["start_t"] is None or t is None else max(t - sp["start_t"], 0.0)
        self.count += 1
        if len(self.spans) < MAX_LISTED:
            self.spans.append(sp)

    def end(self) -> None:
        if self.open is not None:
            self._close(self.open["end_t"])  # closed at the run's last sample where it held


# ============================================================================ the pure part


class _Summary:
    """One pass over the records; `result()` is the report dict."""

    def __init__(self, gap_s: float, tolerance_m_s: float, facts_of=facts_of_start, replayed: bool = False):
        self.gap_s, self.tol = gap_s, tolerance_m_s
        # a replay: the daemon's link is the log's recording, so its losses are gaps in the log (`LOG_LINK`)
        self.replayed = replayed
        self.facts_of = facts_of  # a run's `start` record → its RunFacts (vehicle radius, braking, budgets)
        self.checks = Checks(gap_s)  # keep-out and delivery (companion/ground/review_checks.py)
        self.records = 0
        self.not_records = 0
        self.t_first = self.t_last = self.wall_first = self.wall_last = None
        self.boots: dict[str, dict] = {}
        self.boot = None
        self.states = 0
        self.sampled_s = self.gamma_pos_s = self.gamma_unknown_s = self.over_s = 0.0
        self.sample_gaps = 0
        self.prev = None  # previous state sample of this boot: (t, gamma, over, limit known)
        self.ranges = {k: _Range() for k in RANGE_FIELDS}
        self.excess = None  # worst ground_speed − limit: dict
        self.excess_vmax = None
        self.excess_far = None  # worst ground_speed − limit among the samples beyond the overshoot allowed
        # the flight itself against the contract (what shadow mode would have enforced): ground speed above
        # V_safe (gamma_flown > tolerance) and above the limit, as spans
        self.flown = _Spans("gamma_flown")
        self.fallen_back = _Spans("v_max")  # offboard flown under the stop contract (its avoid contract's fallback)
        # this daemon run flies the avoid contract (offboard): its `start` record says so, or it said which contract
        # is in force, or a state sample was flown under it
        self.avoid_run = False
        self.over = _Spans("excess_m_s")
        self.flown_s = 0.0
        self.would: list[dict] = []  # shadow mode: the holds the daemon would have commanded, as spans
        self.would_open: dict | None = None
        self.would_empty = 0  # would_hold records with no cause: the end of a would-be hold
        self.modes: dict[str, int] = {}  # daemon mode per `start` event
        self.open_viol: dict[tuple, dict] = {}
        self.violations: list[dict] = []  # the first MAX_LISTED; counted in full in by_sub
        self.by_sub: dict[str, dict] = {}
        self.open_fs: list[dict] = []
        self.failsafes: list[dict] = []
        self.thrust_starts: list[dict] = []  # `thrust_start`: the thrust ratio taken before the estimate settled
        self.lists = {k: [] for k in ("mode_changes", "state_changes", "link", "startup_checks", "commands_failed",
                                      "log_gaps", "starts", "stops", "back_offs", "one_frame_splits",
                                      "loop_errors")}
        self.counts = {"limit_changes": 0, "commands": 0, "failsafes": 0, "one_frame_splits": 0}
        self.link_down_at = None
        self.link_down_s = 0.0
        # marks for the plots: spans {start_t, end_t, what} and points {t, what}
        self.marks = {k: [] for k in ("holds", "failsafe_states", "link_down", "calibration_holds")}
        self.points = {k: [] for k in ("stand_downs", "collisions")}
        self.open_marks: dict[str, dict] = {}
        self.failsafe_entries = 0  # state changes into `failsafe` (the link lost: no failsafe event is written)
        self.log_silence_entries = 0  # a replay's: into `failsafe` because the log fell silent (not a failsafe)
        self.flight_end: dict | None = None  # why the flight stopped flying on: the last cause not resumed from
        self._cause: tuple | None = None  # the last hold or failsafe cause (t, cause), for the Hold it led to
        self.obstacle_seen = False  # any finite obstacle_m, or any d_od > 0: the log has obstacle data
        self.dod_seen = False  # any d_od recorded (a log with none says nothing of its obstacle data)
        self.route = None  # the commanded route (a `mission` event's waypoints, local NED)
        self.tables: list[dict] = []  # the `start` events' vehicle and table
        self.other_events: dict[str, int] = {}
        self.unknown_subsystems = 0
        self.last_t_of_boot = None

    # ---------------------------------------------------------------- feeding

    def add(self, rec) -> None:
        if not isinstance(rec, dict) or rec.get("kind") not in ("state", "event"):
            self.not_records += 1
            return
        self.records += 1
        boot = rec.get("boot")
        boot = boot if isinstance(boot, str) else str(boot)
        t, wall = _num(rec.get("t")), _num(rec.get("wall"))
        if boot != self.boot:
            self._end_boot("restart")
            self.boot, self.prev = boot, None
        b = self.boots.setdefault(boot, {"boot": boot, "records": 0, "t_first": None, "t_last": None,
                                         "wall_first": wall, "clean_stop": False, "seq_missing": 0, "_seq": None})
        b["records"] += 1
        seq = rec.get("seq")
        if isinstance(seq, int) and not isinstance(seq, bool):
            if b["_seq"] is not None and seq > b["_seq"] + 1:
                b["seq_missing"] += seq - b["_seq"] - 1
            b["_seq"] = seq
        if t is not None:
            if self.t_first is None:
                self.t_first = t
            self.t_last = t
            b["t_first"] = t if b["t_first"] is None else b["t_first"]
            b["t_last"] = t
            self.last_t_of_boot = t
        if wall is not None:
            self.wall_first = wall if self.wall_first is None else self.wall_first
            self.wall_last = wall
        if rec["kind"] == "state":
            self._state(rec, t)
        else:
            self._event(rec, t, b)
        self.checks.record(self.boot, t, rec)

    def _state(self, rec, t) -> None:
        self.states += 1
        for k, r in self.ranges.items():
            r.add(rec.get(k))
        gs, v_max, v_cmd, gamma = (_num(rec.get(k)) for k in ("ground_speed", "v_max", "v_cmd", "gamma"))
        limit, source = (v_cmd, "v_cmd") if v_cmd is not None else (v_max, "v_max")
        over = None
        if gs is not None and limit is not None:
            over = gs - limit
            if self.excess is None or over > self.excess["excess_m_s"]:
                self.excess = {"excess_m_s": over, "t": t, "ground_speed": gs, "limit": limit, "limit_source": source,
                               "allowed_m_s": self.tol + OVERSHOOT * limit}
            if over > self.tol + OVERSHOOT * limit and (self.excess_far is None or over > self.excess_far["excess_m_s"]):
                self.excess_far = {"excess_m_s": over, "t": t, "ground_speed": gs, "limit": limit,
                                   "limit_source": source, "allowed_m_s": self.tol + OVERSHOOT * limit}
        if gs is not None and v_max is not None and (self.excess_vmax is None or gs - v_max > self.excess_vmax["excess_m_s"]):
            self.excess_vmax = {"excess_m_s": gs - v_max, "t": t, "ground_speed": gs, "v_max": v_max}
        if not self.obstacle_seen:
            ob, dod = _num(rec.get("obstacle_m")), _num(rec.get("d_od"))
            self.obstacle_seen = ob is not None or (dod is not None and dod > 0)
            self.dod_seen = self.dod_seen or dod is not None
        gf = _num(rec.get("gamma_flown"))
        # above the limit by more than a tracking overshoot (the supervisor's own rule: 5 % + tolerance)
        over_far = over is not None and over > self.tol + OVERSHOOT * limit
        self.flown.add(t, gf is not None and gf > self.tol, gf)
        self.avoid_run = self.avoid_run or rec.get("contract") == "avoid"
        self.fallen_back.add(t, self.avoid_run and rec.get("contract") == "stop", _num(rec.get("v_max")))
        self.over.add(t, over_far, over)
        if self.prev is not None and t is not None:
            pt, pgamma, pover, pflown = self.prev
            dt = t - pt
            if 0 < dt <= self.gap_s:
                self.sampled_s += dt
                if pgamma is None:
                    self.gamma_unknown_s += dt
                elif pgamma > 0:
                    self.gamma_pos_s += dt
                if pover:
                    self.over_s += dt
                if pflown is not None and pflown > self.tol:
                    self.flown_s += dt
            elif dt != 0:
                self.sample_gaps += 1
        if t is not None:
            self.prev = (t, gamma, over_far, gf)

    def _ending(self, name: str, t, g) -> None:
        """Why the flight ended (`flight_end`): the last event that stopped it — the route done, a fail-safe Hold
        (with the cause that led to it), a stand-down, the link lost, the daemon stopping — unless flying resumed."""
        why = None
        if name in ("failsafe", "hold_trigger"):
            self._cause = (t, g("cause"))
            why = f"{'failsafe' if name == 'failsafe' else 'hold'}: {g('cause')}"
        elif name == "offboard" and g("to") == "flying" or name == "state_change" and g("to") == "active":
            self.flight_end = None
        elif name == "offboard" and g("to") == "done":
            why = "route complete"
        elif name == "offboard" and g("to") in ("held", "stood_down"):
            after = f" after {self._cause[1]} at t = {_fmt_t(self._cause[0])}" if self._cause else ""
            why = f"offboard {g('to')}{after}: {g('reason')}"
        elif name == "state_change" and g("to") == "failsafe" and g("reason") != "no autopilot heartbeat yet":
            why = None if self._log_silence(g("reason")) else f"failsafe: {g('reason')}"
        elif name == "link" and g("status") == "down" and not self.replayed:
            why = "autopilot link down"
        elif name == "shutdown" and g("hold"):
            why = "the daemon stopped in flight (Hold)"
        if why is not None:
            self.flight_end = {"t": t, "why": why}

    def _event(self, rec, t, b) -> None:
        name = rec.get("event")
        name = name if isinstance(name, str) else str(name)
        g = rec.get
        self._ending(name, t, g)
        if name == "start":
            self.avoid_run = g("contract") == "avoid"
        elif name == "contract_in_force":
            self.avoid_run = True
        if name == "violation_start":
            key = (self.boot, _hashable(g("subsystem")), _hashable(g("guarantee")))
            if key not in self.open_viol:
                if g("subsystem") not in SUBSYSTEMS:
                    self.unknown_subsystems += 1
                self.open_viol[key] = {
                    "subsystem": g("subsystem"), "guarantee": g("guarantee"), "assumed": g("assumed"),
                    "observed": g("observed"), "action": g("action"), "start_t": t, "start_wall": _num(g("wall")),
                    "end_t": None, "duration_s": None, "observed_end": None, "action_end": None, "ended_by": None,
                    "boot": self.boot,
                }
        elif name == "violation_end":
            key = (self.boot, _hashable(g("subsystem")), _hashable(g("guarantee")))
            v = self.open_viol.pop(key, None)
            if v is None:  # an end without a start (the start was rotated out or lost)
                v = {"subsystem": g("subsystem"), "guarantee": g("guarantee"), "assumed": g("assumed"),
                     "observed": None, "action": None, "start_t": None, "start_wall": None, "boot": self.boot}
            v.update(end_t=t, observed_end=g("observed"), action_end=g("action"), ended_by="violation_end")
            v["duration_s"] = None if v["start_t"] is None or t is None else max(t - v["start_t"], 0.0)
            self._close_violation(v)
        elif name == "failsafe":
            self.counts["failsafes"] += 1
            fs = {"t": t, "cause": g("cause"), "action": g("action"), "cleared_t": None, "boot": self.boot}
            fs.update({k: str(g(k)) for k in ("input", "why", "resume") if g(k) is not None})  # no safe speed: why
            self.open_fs.append(fs)
            self._keep(self.failsafes, fs)
        elif name == "failsafe_clear":
            cause = g("cause")
            for fs in [f for f in self.open_fs if cause is None or f["cause"] == cause]:
                fs["cleared_t"] = t
                self.open_fs.remove(fs)
        elif name == "mode_change":
            self._keep(self.lists["mode_changes"], {"t": t, "from": g("from"), "to": g("to"), "by": g("by")})
        elif name == "loop_error":
            self._keep(self.lists["loop_errors"], {"t": t, "error": str(g("error")),
                                                   "consecutive": _num(g("consecutive")),
                                                   "action": str(g("action"))})
        elif name == "back_off":
            self._keep(self.lists["back_offs"], {"t": t, "inside_m": _num(g("inside_m")), "path_m": _num(g("path_m"))})
        elif name == "one_frame_split":
            self.counts["one_frame_splits"] += 1
            self._keep(self.lists["one_frame_splits"], {"t": t, **{k: _num(g(k)) for k in
                                                                  ("told", "counted", "nearest_m", "v_ref", "v_stop")}})
        elif name == "state_change":
            self._keep(self.lists["state_changes"], {"t": t, "from": g("from"), "to": g("to"), "reason": g("reason")})
            to, why = g("to"), g("reason")
            # not linked yet, or a replayed log fallen silent: no failsafe
            yet = why == "no autopilot heartbeat yet" or self._log_silence(why)
            for state, kind in (("holding", "holds"), ("failsafe", "failsafe_states")):
                self._mark(kind, t, to == state and not (yet and kind == "failsafe_states"), why)
            if to == "failsafe" and not yet:
                self.failsafe_entries += 1
            elif to == "failsafe" and self._log_silence(why):
                self.log_silence_entries += 1
            if isinstance(why, str) and "standing down" in why:
                self._keep(self.points["stand_downs"], {"t": t, "what": why})
        elif name == "calibration_hold":
            st = g("status")
            self._mark("calibration_holds", t, st == "commanded", f"calibration hold leg {g('leg')}: {st}"
                       + (f" ({g('reason')})" if g("reason") else ""))
        elif name == "mission" and g("status") == "ready" and isinstance(g("waypoints"), list):
            self.route = [p for p in g("waypoints") if isinstance(p, list) and len(p) == 2
                          and all(_num(c) is not None for c in p)]
        elif name == "limit_change":
            self.counts["limit_changes"] += 1
        elif name == "command":  # sent; its result, if any, comes with it or in a later command_ack
            self.counts["commands"] += 1
            if g("result") is not None and refused(g("result")):
                self._keep(self.lists["commands_failed"],
                           {"t": t, "name": g("cmd") or g("name"), "params": g("params"), "result": g("result")})
        elif name == "command_ack":
            if refused(g("result")):
                self._keep(self.lists["commands_failed"], {"t": t, "name": g("command"), "result": g("result")})
        elif name == "link":
            status = g("status")
            self._keep(self.lists["link"], {"t": t, "status": status})
            self._mark("link_down", t, status == "down", "link down")
            if status == "down" and self.link_down_at is None:
                self.link_down_at = t
            elif status in ("up", "reconnect") and self.link_down_at is not None:
                if t is not None:
                    self.link_down_s += max(t - self.link_down_at, 0.0)
                self.link_down_at = None
        elif name == "startup_check":
            self._keep(self.lists["startup_checks"], {"t": t, "ok": g("ok"), "reason": g("reason")})
        elif name == "would_hold":
            causes = g("causes")
            causes = [str(c) for c in causes] if isinstance(causes, list) else ([] if causes is None else [str(causes)])
            if self.would_open is not None and causes != self.would_open["causes"]:
                self._close_would(t, "released" if not causes else "causes changed")
            if not causes:
                self.would_empty += 1
            elif self.would_open is None:
                self.would_open = {"start_t": t, "causes": causes, "end_t": None, "duration_s": None,
                                   "ended_by": None, "boot": self.boot}
                if g("why") is not None:
                    self.would_open["why"] = str(g("why"))
        elif name == "thrust_start":
            self._keep(self.thrust_starts, {"t": t, "thrust_ratio": _num(g("thrust_ratio")), "covered": g("covered"),
                                            "vehicle_min": _num(g("vehicle_min")), "table_min": _num(g("table_min")),
                                            "reason": str(g("reason"))})
        elif name == "start":
            mode = g("mode")
            if isinstance(mode, str):
                self.modes[mode] = self.modes.get(mode, 0) + 1
            self._keep(self.lists["starts"], {"t": t, "wall": _num(g("wall")), "boot": self.boot})
            vehicle = g("vehicle").get("name") if isinstance(g("vehicle"), dict) else g("vehicle")
            if isinstance(vehicle, str):
                self.tables.append({"vehicle": vehicle, "table": g("table") if isinstance(g("table"), str) else None})
            self.checks.start(self.facts_of(rec), mode)
        elif name == "stop":
            b["clean_stop"] = True
            self._keep(self.lists["stops"], {"t": t, "wall": _num(g("wall")), "boot": self.boot})
        elif name == "log_recovered":
            self._keep(self.lists["log_gaps"], {"t": t, "wall": _num(g("wall")), "since_wall": g("since_wall"),
                                                "dropped_records": g("dropped_records"), "error": g("error")})
        elif name != "log_open":
            self.other_events[name] = self.other_events.get(name, 0) + 1

    def _log_silence(self, why) -> bool:
        """A replay's failsafe state for the link lost: the log fell silent there (see `LOG_LINK`)."""
        return self.replayed and why == LOG_LINK

    def _close_violation(self, v: dict) -> None:
        s = self.by_sub.setdefault(str(v["subsystem"]), {"count": 0, "total_s": 0.0})
        s["count"] += 1
        s["total_s"] += v["duration_s"] or 0.0
        observed = _num(v.get("observed"))  # (guidance's: its cycles' lateness [s], not its failed cycles or jumps [m])
        if observed is not None and math.isfinite(observed) and v.get("guarantee") not in NOT_LATENESS:
            s["worst_observed"] = max(s.get("worst_observed", -math.inf), observed)
        self._keep(self.violations, v)

    def _keep(self, lst: list, item: dict) -> None:
        if len(lst) < MAX_LISTED:
            lst.append(item)
        else:
            self.other_events["(not listed: over the list limit)"] = self.other_events.get("(not listed: over the list limit)", 0) + 1

    def _mark(self, kind: str, t, on: bool, what) -> None:
        """Open a span of `kind` (a hold, the failsafe state, the link down, a calibration hold) or close it."""
        if on and kind not in self.open_marks:
            self.open_marks[kind] = {"start_t": t, "end_t": None, "what": str(what)}
        elif not on and kind in self.open_marks:
            sp = self.open_marks.pop(kind)
            sp["end_t"] = t
            self._keep(self.marks[kind], sp)

    def _close_would(self, t, why: str) -> None:
        w, self.would_open = self.would_open, None
        w.update(end_t=t, ended_by=why)
        w["duration_s"] = None if w["start_t"] is None or t is None else max(t - w["start_t"], 0.0)
        self._keep(self.would, w)

    def _end_boot(self, why: str) -> None:
        """Close what the ending daemon run left open."""
        self.checks.end_run()
        if self.would_open is not None:
            self._close_would(self.last_t_of_boot, why)
        self.flown.end()
        self.over.end()
        self.fallen_back.end()
        self.avoid_run = False
        for v in self.open_viol.values():
            v.update(end_t=self.last_t_of_boot, ended_by=why)
            st = v["start_t"]
            v["duration_s"] = None if st is None or self.last_t_of_boot is None else max(self.last_t_of_boot - st, 0.0)
            self._close_violation(v)
        self.open_viol = {}
        self.open_fs = []
        for kind in list(self.open_marks):
            self._mark(kind, self.last_t_of_boot, False, why)
        if self.link_down_at is not None and self.last_t_of_boot is not None:
            self.link_down_s += max(self.last_t_of_boot - self.link_down_at, 0.0)
        self.link_down_at = None
        self.last_t_of_boot = None

    # ---------------------------------------------------------------- result

    def result(self) -> dict:
        self._end_boot("end of log")
        self.violations.sort(key=lambda v: (v["start_t"] is None, v["start_t"] if v["start_t"] is not None else 0.0))
        boots = []
        for b in self.boots.values():
            b = {k: v for k, v in b.items() if not k.startswith("_")}
            boots.append(b)
        duration = None if self.t_first is None else self.t_last - self.t_first
        rep = {
            "schema": SCHEMA,
            "schema_version": SCHEMA_VERSION,
            "records": self.records,
            "not_records": self.not_records,
            "span": {
                "t_first": self.t_first, "t_last": self.t_last, "duration_s": duration,
                "wall_first": self.wall_first, "wall_last": self.wall_last,
                "utc_first": _utc(self.wall_first), "utc_last": _utc(self.wall_last),
            },
            "boots": boots,
            "state_samples": self.states,
            "sampled_s": self.sampled_s,
            "sample_gaps": self.sample_gaps,
            "gamma_positive_s": self.gamma_pos_s,
            "gamma_unknown_s": self.gamma_unknown_s,
            "over_limit": {
                "tolerance_m_s": self.tol,
                "overshoot_ratio": OVERSHOOT,
                "time_over_limit_s": self.over_s,
                "worst": self.excess,
                "worst_beyond_allowed": self.excess_far,
                "worst_vs_v_max": self.excess_vmax,
            },
            "outside_contract": {
                "tolerance_m_s": self.tol,
                "flown_above_v_safe_s": self.flown_s,
                "flown_above_v_safe": self.flown.spans,
                "worst_gamma_flown": self.flown.worst,
                "above_limit": self.over.spans,
            },
            # offboard: the spans flown under the stop contract where the avoid contract's assumptions were not there
            "stop_contract": {"spans": self.fallen_back.spans, "count": self.fallen_back.count},
            "would_hold": self.would,
            "would_hold_count": len(self.would),
            "modes": self.modes,
            "ranges": {k: r.out() for k, r in self.ranges.items()},
            "violations": self.violations,
            "violation_count": sum(v["count"] for v in self.by_sub.values()),
            "violations_by_subsystem": self.by_sub,
            "unknown_subsystems": self.unknown_subsystems,
            "failsafes": self.failsafes,
            "thrust_starts": self.thrust_starts,
            # where they happened: failsafe events (a cause made the daemon hold) and entries into the failsafe
            # state (the link lost: nothing can be commanded, and no failsafe event is written)
            "failsafe_count": self.counts["failsafes"] + self.failsafe_entries,
            "failsafe_events": self.counts["failsafes"],
            "failsafe_state_entries": self.failsafe_entries,
            "log_silence_entries": self.log_silence_entries,
            "flight_end": self.flight_end,
            "marks": {**self.marks, **self.points},
            # False: D_od 0 throughout and no obstacle ever seen (a log without an obstacle sensor)
            "obstacle_data": self.obstacle_seen or not self.dod_seen,
            "route": self.route,
            "tables": self.tables,
            "mode_changes": self.lists["mode_changes"],
            "back_offs": self.lists["back_offs"],
            "loop_errors": self.lists["loop_errors"],  # the daemon's cycles that raised (logged 1st, 10th, 100th…)
            # offboard: obstacles one frame told apart, counted as one while the stop contract stopped short of them
            "one_frame_splits": self.lists["one_frame_splits"],
            "one_frame_split_count": self.counts["one_frame_splits"],  # all of them, the list kept up to MAX_LISTED
            "state_changes": self.lists["state_changes"],
            # of_the_log: a replay's link is the log's recording (its losses are the log's gaps, `LOG_LINK`)
            "link": {"events": self.lists["link"], "down_s": self.link_down_s, "of_the_log": self.replayed},
            "limit_changes": self.counts["limit_changes"],
            "commands": {"count": self.counts["commands"], "failed": self.lists["commands_failed"]},
            "startup_checks": self.lists["startup_checks"],
            "log_gaps": self.lists["log_gaps"],
            "other_events": self.other_events,
            **self.checks.result(self.violations),  # keep_out, delivery
            "findings": None,  # set by conclude(), once the report is whole
            "ok": None,
        }
        return rep


def summarise(records: Iterable[dict], *, gap_s: float = 1.0, tolerance_m_s: float = SPEED_TOLERANCE_M_S,
              facts_of=facts_of_start) -> dict:
    """The report for a sequence of records (oldest first). Pure: no I/O; never raises on odd records.

    `tolerance_m_s`: ground speed above the limit by no more than this is not a finding (the autopilot holds a
    commanded speed within a few tenths: limit + 0.2 m/s after a limit drop is accepted). `facts_of`: a `start` record → its run's `RunFacts` (the default reads
    the record alone; `review` also looks its vehicle up: `run_facts`).
    """
    return conclude(_summary(records, gap_s, tolerance_m_s, facts_of))


def _summary(records: Iterable[dict], gap_s: float, tolerance_m_s: float, facts_of=facts_of_start,
             replayed: bool = False) -> dict:
    s = _Summary(gap_s, tolerance_m_s, facts_of, replayed)
    for rec in records:
        s.add(rec)
    return s.result()


def conclude(rep: dict, extra: Iterable[str] = ()) -> dict:
    """Set the report's `findings` (the log's, then `extra`: what a conversion lacked) and `ok`."""
    rep["findings"] = findings(rep) + list(extra)
    rep["ok"] = not rep["findings"]
    return rep


def _worst(subsystem: str, v: dict) -> str:
    """What the worst violation of a subsystem means, where a number says it plainly (the daemon's own cycle, the
    autopilot refusing the recovery brake)."""
    if subsystem == "guidance" and "worst_observed" in v:
        return f"; cycles up to {v['worst_observed'] * 1e3:.0f} ms apart: the companion computer was late"
    if subsystem == "autopilot":  # observed: the speed it was refused at
        at = f" at {v['worst_observed']:.2f} m/s" if "worst_observed" in v else ""
        return f"; the recovery brake's switch refused{at}, above the Hold's limit: the stop was not guaranteed"
    return ""


def findings(rep: dict) -> list[str]:
    """One line per thing a safety reviewer must look at; empty when the flight kept its contract."""
    out = review_checks.findings(rep)  # first: the vehicle where it must not be, commands not taken
    if rep["violation_count"]:
        parts = ", ".join(f"{k} ×{v['count']} ({v['total_s']:.1f} s{_worst(k, v)})"
                          for k, v in sorted(rep["violations_by_subsystem"].items()))
        out.append(f"{rep['violation_count']} contract violation(s): {parts}")
    if rep["gamma_positive_s"] > 0:
        out.append(f"Γ > 0 for {rep['gamma_positive_s']:.2f} s (speed limit above the safe speed)")
    if rep["gamma_unknown_s"] > 0:
        out.append(f"Γ unknown (null/NaN) for {rep['gamma_unknown_s']:.2f} s")
    oc = rep.get("outside_contract") or {}
    wf = oc.get("worst_gamma_flown")
    blind = not rep.get("obstacle_data", True) and rep["state_samples"] > 0
    if blind and (oc.get("flown_above_v_safe") or rep["over_limit"].get("worst_beyond_allowed")):
        # D_od 0 throughout: the contract allows no speed, so "outside it" is true of every metre and says nothing
        out.append(f"no obstacle data: D_od 0 throughout, where the contract allows no speed — the "
                   f"{oc.get('flown_above_v_safe_s', 0.0):.0f} s flown above V_safe are not judged; judged instead: "
                   "the detection range each stretch needed" + ("" if rep.get("detection_need") else
                                                              " (not computed: no table for this vehicle)"))
        out += (rep.get("detection_need") or {}).get("findings", [])
    elif oc.get("flown_above_v_safe"):
        n = len(oc["flown_above_v_safe"])
        out.append(f"flown outside the contract: ground speed above V_safe by up to {wf['gamma_flown']:.2f} m/s at "
                   f"t = {_fmt_t(wf['t'])}; {oc['flown_above_v_safe_s']:.2f} s above V_safe + "
                   f"{oc['tolerance_m_s']:.2f} m/s in {n} span(s)")
    w = rep["over_limit"].get("worst_beyond_allowed")
    if w and not (blind and w["limit_source"] == "v_max"):
        src = w["limit_source"] + (", the limit it would have commanded" if w["limit_source"] == "v_max" else "")
        out.append(f"ground speed above the limit ({src}) by up to {w['excess_m_s']:.2f} m/s "
                   f"at t = {_fmt_t(w['t'])}; {rep['over_limit']['time_over_limit_s']:.2f} s above limit × "
                   f"{1 + rep['over_limit']['overshoot_ratio']:.2f} + {rep['over_limit']['tolerance_m_s']:.2f} m/s")
    if rep.get("would_hold"):
        causes = sorted({c for wh in rep["would_hold"] for c in wh["causes"]})
        out.append(f"shadow mode: the daemon would have held {rep['would_hold_count']}× "
                   f"(first at t = {_fmt_t(rep['would_hold'][0]['start_t'])}; {'; '.join(causes)})")
    errs = rep.get("loop_errors") or []
    if errs:
        e, most = errs[0], max(x["consecutive"] or 1 for x in errs)
        out.append(f"the daemon's cycle ended in an internal error (up to {most:.0f} in a row), first at t = "
                   f"{_fmt_t(e['t'])}: {e['error']}; action: {e['action']} — no decision in those cycles, what the "
                   "contract flown assumes (guidance's guarantee)")
    cols = (rep.get("marks") or {}).get("collisions")
    if cols:
        out.append(f"{len(cols)} collision(s) (simulator truth), first at t = {_fmt_t(cols[0]['t'])}")
    if rep["failsafe_count"]:
        parts = [f"{n} {what}" for n, what in ((rep.get("failsafe_events", rep["failsafe_count"]), "failsafe event(s)"),
                                               (rep.get("failsafe_state_entries", 0), "× into the failsafe state "
                                                "(link lost)")) if n]
        out.append(f"{rep['failsafe_count']} failsafe(s): {', '.join(parts)}")
    if not rep["link"].get("of_the_log") and (rep["link"]["down_s"] > 0
                                               or any(e["status"] == "down" for e in rep["link"]["events"])):
        out.append(f"autopilot link down for {rep['link']['down_s']:.1f} s")
    short = [s for s in rep.get("thrust_starts", []) if s["covered"] is False]
    if short:
        s = short[0]
        out.append(f"the table's thrust axis starts at {fmt_value(s['table_min'])}, above the vehicle's lowest "
                   f"{fmt_value(s['vehicle_min'])}: no safe speed after take-off until the thrust estimate settled "
                   f"({len(short)} flight(s)); build the table over the whole thrust_ratio_range")
    bad_checks = [c for c in rep["startup_checks"] if c["ok"] is not True]
    if bad_checks:
        why = bad_checks[0]["reason"]
        if rep["link"].get("of_the_log") and isinstance(why, str) and why.startswith(NOT_REPORTED):
            # a replay cannot ask: it has the parameters the log holds, when the log's recorder had them
            why = f"the log holds no {why[len(NOT_REPORTED):]} in time for the replay's check"
        out.append(f"{len(bad_checks)} failed start-up check(s): {why}")
    failed = rep["commands"]["failed"]
    if failed:
        out.append(f"{len(failed)} command(s) not accepted by the autopilot, the first at t = "
                   f"{_fmt_t(failed[0]['t'])}: {command_text(failed[0]['name'], failed[0]['result'])}")
    unclean = [b for b in rep["boots"][:-1] if not b["clean_stop"]]
    if unclean:
        out.append(f"daemon restarted {len(unclean)}× without a clean stop (crash, kill or power loss)")
    missing = sum(b["seq_missing"] for b in rep["boots"])
    dropped = sum(g["dropped_records"] or 0 for g in rep["log_gaps"] if isinstance(g["dropped_records"], int))
    if missing or dropped or rep["log_gaps"]:
        out.append(f"log incomplete: {missing} record(s) missing by seq, {dropped} reported dropped "
                   f"by the logger ({len(rep['log_gaps'])} write-failure episode(s))")
    if rep["sample_gaps"]:
        out.append(f"{rep['sample_gaps']} gap(s) in the state samples longer than the gap limit")
    bad = [b for b in rep.get("bad_lines", []) if b["kind"] != "tail"]
    if bad:
        out.append(f"{len(bad)} unparsable line(s) inside the log ({', '.join(sorted({b['kind'] for b in bad}))})")
    return out


# ============================================================================ I/O


class Origin:
    """What a converted event log was made from (a raw log replayed through the daemon): the report names
    its `files` and holds `info` as section `key`; a converter subclasses it for its findings and text."""

    key = "source"

    def __init__(self, files: list[str], info: dict):
        self.files, self.info = files, info

    def findings(self) -> list[str]:
        """Lines a reviewer must see about the conversion itself."""
        return []

    def lines(self) -> list[str]:
        """The conversion, for a person (after the report's span)."""
        return []

    def title(self) -> str:
        """A note for the plot's title."""
        return ""

    def flight_end(self, daemon_end: dict | None) -> dict | None:
        """Where the flight ended, as the raw log says it (its arming), given where the replay's daemon stopped."""
        return daemon_end


def run_facts(rec: dict) -> RunFacts:
    """A daemon run's `RunFacts` from its `start` record, its vehicle looked up where the record only names it:
    the table it flew (where that file is here), else the shipped vehicle of that name."""
    found = None if isinstance(rec.get("vehicle"), dict) else _named_vehicle(
        rec.get("vehicle") if isinstance(rec.get("vehicle"), str) else None,
        rec.get("table") if isinstance(rec.get("table"), str) else None)
    return facts_of_start(rec, *found) if found else facts_of_start(rec)


@functools.lru_cache(maxsize=16)
def _named_vehicle(name: str | None, table: str | None) -> tuple[dict, str] | None:
    """(the vehicle's parameters, where they came from) for a run's vehicle name and table, or None."""
    from contracts.table import shipped_vehicles, verify
    from contracts.vehicle import load_vehicle

    try:
        if table and Path(table).is_file():
            return verify(table).vehicle.metadata(), f"the table {table}"
    except (ContractError, OSError, ValueError):
        pass
    try:
        if name in shipped_vehicles():  # a name only: never a path a log names
            return load_vehicle(name).metadata(), f"the shipped vehicle {name}"
    except (ContractError, OSError, ValueError):
        pass
    return None


def _log_files(paths) -> list[Path]:
    if isinstance(paths, (str, Path)):
        paths = [paths]
    files: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise ContractError(f"no such file or directory: {p}")
        if p.is_dir():
            found = file_set(p)
            if not found:
                raise ContractError(f"{p} holds no event log ({LOG_FILE})")
            files.extend(found)
        else:
            files.append(p)
    if not files:
        raise ContractError("no event log given")
    return files


def review(paths, out_dir: str | Path | None = None, *, gap_s: float = 1.0, tolerance_m_s: float = SPEED_TOLERANCE_M_S,
           origin: Origin | None = None, sensor=None, collisions=None, world: dict | None = None) -> dict:
    """Read the event log(s) at `paths` and report; with `out_dir`, also write the plot, CSV and JSON.
    `origin`: what a converter made the log from (its section and findings join the report). A log without
    obstacle data gets the detection range it needed (`companion.ground.detection_need`; `sensor`: an assumed one).
    `collisions`: a simulator's truth, [{t, x, y, what}] (the daemon cannot know them), marked on the plots.
    `world`: the true world from above where the flight's scenario is known (a SITL scenario's `world.outline()`:
    {"columns": [[x, y, r, name]], "polygons": [[[x, y], …]]}, local NED metres), drawn on the plan view."""
    files = _log_files(paths)
    rep, samples = analyse(files, gap_s=gap_s, tolerance_m_s=tolerance_m_s, keep_samples=out_dir is not None,
                           origin=origin)
    if not rep["obstacle_data"] and rep["state_samples"]:
        from .detection_need import for_report

        rows = samples if samples is not None else (_row(r) for r in read_events(files) if _is_state(r))  # 2nd pass
        rep["detection_need"] = for_report(rep, rows, CSV_COLUMNS, sensor, gap_s)
        conclude(rep, origin.findings() if origin else ())
    if collisions:
        rep["marks"]["collisions"] = [{"t": _num(c.get("t")), "x": _num(c.get("x")), "y": _num(c.get("y")),
                                       "what": str(c.get("what") or "collision")} for c in collisions][:MAX_LISTED]
        conclude(rep, origin.findings() if origin else ())
    if world:
        rep["world"] = world_outline(world)
    if out_dir is not None:
        rep["outputs"] = write_outputs(rep, samples, Path(out_dir), origin.title() if origin else "")
        write_flight_page(Path(out_dir), rep, format_report(rep, origin), Path(rep["files"][0]).name)
    return rep


MAX_WORLD_SHAPES = 5000  # columns and polygons each: the plan view draws no more


def world_outline(world: dict) -> dict:
    """The drawable part of a `world` outline: finite numbers only, at most `MAX_WORLD_SHAPES` of each kind."""
    def point(p):
        return [_num(p[0]), _num(p[1])] if isinstance(p, (list, tuple)) and len(p) >= 2 else [None, None]

    columns = []
    for c in list(world.get("columns") or [])[:MAX_WORLD_SHAPES]:
        x, y, r = (_num(v) for v in (list(c) + [None] * 3)[:3])
        if None not in (x, y, r):
            columns.append([x, y, r, str(c[3]) if len(c) > 3 else ""])
    polygons = []
    for poly in list(world.get("polygons") or [])[:MAX_WORLD_SHAPES]:
        pts = [point(p) for p in poly]
        if len(pts) >= 3 and all(None not in p for p in pts):
            polygons.append(pts)
    return {"columns": columns, "polygons": polygons}


def analyse(files: list[Path], *, gap_s: float = 1.0, tolerance_m_s: float = SPEED_TOLERANCE_M_S,
            keep_samples: bool = False, origin: Origin | None = None) -> tuple[dict, list[tuple] | None]:
    """(report, state rows in `CSV_COLUMNS` order or None) for event-log files."""
    reader = read_events(files)
    samples: list[tuple] | None = [] if keep_samples else None

    def records():
        for rec in reader:
            if samples is not None and _is_state(rec):
                samples.append(_row(rec))  # a row, not the dict: 1 h at 50 Hz fits
            yield rec

    try:
        rep = _summary(records(), gap_s, tolerance_m_s, run_facts, replayed=origin is not None)
    except OSError as err:
        raise ContractError(f"cannot read {err.filename or files[0]}: {err.strerror or err}") from err
    rep["files"] = origin.files if origin else [str(f) for f in files]
    rep["bad_lines"] = [{"file": f, "line": n, "kind": k} for f, n, k in reader.bad_lines]
    if rep["records"] == 0:
        raise ContractError(f"{files[0]} is not a contract-guard event log (no records)")
    rep = finite_copy(rep)  # a foreign log's NaN/Infinity tokens: the report stays strict JSON
    if origin is not None:
        rep[origin.key] = finite_copy(origin.info)
        rep["flight_end"] = origin.flight_end(rep["flight_end"])
    return conclude(rep, origin.findings() if origin else ()), samples


def _is_state(rec) -> bool:
    return isinstance(rec, dict) and rec.get("kind") == "state"


def _row(rec: dict) -> tuple:
    """A state record as a row in `CSV_COLUMNS` order."""
    return tuple(rec.get(k) for k in CSV_COLUMNS)


def write_outputs(rep: dict, samples: list[tuple], out_dir: Path, note: str = "") -> dict:
    """`samples.csv`, `review.json` and `review.png` in `out_dir`; returns their paths."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        csv_path = out_dir / "samples.csv"
        with open(csv_path, "w", newline="") as fh:
            w = csvfile.writer(fh)
            w.writerow(CSV_COLUMNS)
            for row in samples:
                w.writerow([_cell(v) for v in row])
        png_path = out_dir / "review.png"
        json_path = out_dir / "review.json"
        outputs = {"csv": str(csv_path), "png": str(png_path), "json": str(json_path),
                   "html": str(out_dir / PAGE)}  # the page `review` writes once the report is whole
        missing = missing_plot_extra()
        if missing:  # the report, CSV and JSON without the plot; said in one line
            png_path.unlink(missing_ok=True)
            outputs["png"] = outputs["plan"] = None
            outputs["png_skipped"] = missing
        else:
            outputs["plan"] = str(plot(rep, samples, png_path, note))
        json_path.write_text(json.dumps({**rep, "outputs": outputs}, indent=1, default=str, allow_nan=False))
    except OSError as err:
        raise ContractError(f"cannot write the review to {out_dir}: {err.strerror or err}") from err
    return outputs


PLOT_EXTRA = "no plot: it needs matplotlib (pip install 'contract-guard[plot]')"


def missing_plot_extra() -> str | None:
    """None when plots can be drawn, else the one line naming the extra to install."""
    import importlib.util

    return None if importlib.util.find_spec("matplotlib") is not None else PLOT_EXTRA


def _cell(v):
    if v is None:
        return ""
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, (dict, list)):
        return json.dumps(v)
    return v


def plot(rep: dict, samples: list[tuple], path: Path, note: str = "") -> Path:
    """`path` (the time series) and `plan.png` beside it (the plan view): `companion.ground.review_plots`, with
    every hold, failsafe, stand-down, link-down span, collision and violation marked; `note` goes into the
    title (e.g. "replayed from FLIGHT.tlog"). Returns the plan view's path."""
    try:
        from . import review_plots as rp
    except ImportError as err:
        raise ContractError("plots need matplotlib (pip install 'contract-guard[plot]')") from err
    title = plot_title(rep, note)
    rp.save(rp.time_figure(rep, samples, CSV_COLUMNS, title), path)
    plan = path.with_name("plan.png")
    rp.save(rp.plan_figure(rep, samples, CSV_COLUMNS, "plan view — " + title), plan)
    return plan


def plot_title(rep: dict, note: str = "") -> str:
    """The plot's title: what it shows and the verdict (a shadow flight's would-be holds and the time it flew
    above V_safe are there, not only the daemon's own violations)."""
    title = f"contract-guard review — {rep['state_samples']} samples, {rep['violation_count']} violation(s)"
    oc = rep.get("outside_contract") or {}
    need = rep.get("detection_need") or {}
    if not rep.get("obstacle_data", True) and need.get("worst"):
        w = need["worst"]["d_od_m"]
        title += ", no obstacle data: detection range needed up to " + ("more than any" if w is None else f"{w:.1f} m")
    elif oc.get("flown_above_v_safe"):
        title += f", {oc['flown_above_v_safe_s']:.1f} s above V_safe"
    if rep.get("would_hold"):
        title += f", would hold {rep['would_hold_count']}×"
    if rep["span"]["utc_first"]:
        title += f", from {rep['span']['utc_first']}"
    if note:
        title += f" ({note})"
    return title + ("" if rep["ok"] else " — " + verdict(rep))


# ============================================================================ text


def _fmt_t(t) -> str:
    return "?" if t is None else f"{t:.2f} s"


def fmt_value(v, unit="") -> str:
    """A value for a person: 3 significant digits, — for none."""
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.3g}{unit}"
    return f"{v}{unit}"


def _need_lines(need: dict | None) -> list[str]:
    """A log without obstacle data: the detection range it needed, per stretch, and an assumed sensor's cost."""
    if not need:
        return ["  no obstacle data: time above V_safe not judged; no table to compute the detection range needed"]
    q = need["quantiles_m"]
    if need["worst"] is None:
        return [f"  no obstacle data; nothing flown above {need['min_speed_m_s']:g} m/s: no detection range needed"]
    lines = [f"  no obstacle data: time above V_safe not judged. Detection range needed under the {need['vehicle']} "
             f"contract over the {need['flown_s']:.0f} s flown above {need['min_speed_m_s']:g} m/s: "
             + ", ".join(f"{100 * float(k):g} % ≤ {fmt_value(v, ' m')}" for k, v in q.items())
             + ("; " + ", ".join(f"{c['range_m']:g} m covers {100 * c['share']:.0f} %" for c in need["coverage"])
                if need["coverage"] else "")]
    st = [x for x in need["stretches"] if x.get("d_od_m") is not None or x.get("at_t") is not None]
    worst = sorted(st, key=lambda x: -(x["d_od_m"] if x["d_od_m"] is not None else float("inf")))[:5]
    if worst:
        lines.append(f"    worst {len(worst)} of {len(st)} stretches ({need['stretch_s']:g} s each):")
        for x in sorted(worst, key=lambda x: x["start_t"]):
            lines.append(f"    {_fmt_t(x['start_t'])} … {_fmt_t(x['end_t'])}  needs {fmt_value(x['d_od_m'], ' m')} "
                         f"(up to {x['ground_speed']:.2f} m/s)")
    s = need.get("sensor")
    if s and s.get("spans"):
        lines.append(f"    with the assumed sensor ({s['range_m']:g} m): faster than its limit in {s['spans_count']} "
                     f"stretch(es), the longest:")
        for x in sorted(s["spans"], key=lambda x: x["start_t"] - x["end_t"])[:5]:
            lines.append(f"    {_fmt_t(x['start_t'])} … {_fmt_t(x['end_t'])}  up to {x['worst_m_s']:.2f} m/s "
                         f"against {x['limit_m_s']:.2f} m/s")
    return lines


def format_report(rep: dict, origin: Origin | None = None) -> str:
    """The report as text for a person (the CLI prints it; `--json` prints the dict instead)."""
    sp = rep["span"]
    lines = [f"contract-guard review: {', '.join(rep.get('files', [])) or '(records)'}"]
    lines.append(f"  span: t {_fmt_t(sp['t_first'])} … {_fmt_t(sp['t_last'])} ({fmt_value(sp['duration_s'], ' s')})"
                 + (f", {sp['utc_first']} … {sp['utc_last']}" if sp["utc_first"] else ""))
    lines.append(f"  {rep['records']} records, {rep['state_samples']} state samples covering {rep['sampled_s']:.1f} s, "
                 f"{len(rep['boots'])} daemon run(s)")
    lines += origin.lines() if origin else []
    lines.append("  verdict: " + verdict(rep))
    for f in rep["findings"]:
        lines.append(f"    - {f}")
    modes = rep.get("modes") or {}
    # the log's modes by name; a name the daemon does not know counts as commanding (what it did is not said away)
    commanded_nothing = bool(modes) and not any(m not in MODES or MODES[m].commands for m in modes)
    if modes:
        lines.append(f"  daemon mode: {', '.join(sorted(modes))}"
                     + ("  (commanded nothing: what it would have done is below)" if commanded_nothing else ""))
    lines.append(f"  Γ > 0 for {rep['gamma_positive_s']:.2f} s (limit in force − V_safe)")
    oc = rep.get("outside_contract")
    if not rep.get("obstacle_data", True) and rep["state_samples"]:
        lines += _need_lines(rep.get("detection_need"))
    elif oc is not None:
        lines.append(f"  flown outside the contract (ground speed − V_safe > {oc['tolerance_m_s']:.2f} m/s): "
                     f"{oc['flown_above_v_safe_s']:.2f} s in {len(oc['flown_above_v_safe'])} span(s)")
        for sp in oc["flown_above_v_safe"]:
            lines.append(f"    {_fmt_t(sp['start_t'])} … {_fmt_t(sp['end_t'])}  up to {fmt_value(sp['worst'], ' m/s')} "
                         f"over V_safe at {_fmt_t(sp['worst_t'])}")
        for sp in oc["above_limit"]:
            lines.append(f"    above the limit: {_fmt_t(sp['start_t'])} … {_fmt_t(sp['end_t'])}  up to "
                         f"{fmt_value(sp['worst'], ' m/s')} at {_fmt_t(sp['worst_t'])}")
    fb = rep.get("stop_contract")
    if fb and fb["count"]:
        lines.append(f"  flown under the stop contract (offboard; the avoid contract's assumptions not there): "
                     f"{fb['count']} span(s)")
        for sp in fb["spans"]:
            lines.append(f"    {_fmt_t(sp['start_t'])} … {_fmt_t(sp['end_t'])}")
    splits = rep.get("one_frame_splits") or []
    if splits:
        lines.append(f"  obstacles one sensor frame told apart, counted as one until a second frame did (offboard): "
                     f"{rep.get('one_frame_split_count', len(splits))}")
        for sp in splits:
            lines.append(f"    {_fmt_t(sp['t'])}  {fmt_value(sp['told'])} told apart, counted as "
                         f"{fmt_value(sp['counted'])}: the stop contract stops short of them (the nearest waiting "
                         f"{fmt_value(sp['nearest_m'], ' m')} away, {fmt_value(sp['v_ref'], ' m/s')} flown, "
                         f"{fmt_value(sp['v_stop'], ' m/s')} its speed there)")
    if rep.get("would_hold") is not None and (rep["would_hold"] or commanded_nothing):
        lines.append(f"  would have held (shadow mode): {rep['would_hold_count']}")
        for wh in rep["would_hold"]:
            lines.append(f"    {_fmt_t(wh['start_t'])} … {_fmt_t(wh['end_t'])} ({wh['ended_by']})  "
                         f"{'; '.join(wh['causes'])}" + (f" ({wh['why']})" if wh.get("why") else ""))
    w = rep["over_limit"]["worst"]
    if w:
        lines.append(f"  ground speed − limit: max {w['excess_m_s']:+.2f} m/s at t = {_fmt_t(w['t'])} "
                     f"({w['ground_speed']:.2f} m/s vs {w['limit_source']} {w['limit']:.2f} m/s)")
    lines.append("  ranges (min … max):")
    for k in ("v_max", "v_cmd", "ground_speed", "gamma", "d_od", "e_tr", "thrust_ratio", "r_obst"):
        r = rep["ranges"][k]
        miss = f"  ({r['missing']} null)" if r["missing"] else ""
        lines.append(f"    {k:<13} {fmt_value(r['min'])} … {fmt_value(r['max'])}{miss}")
    withheld = (rep["ranges"].get("withheld") or {}).get("max")
    if withheld:  # cumulative: the last is the flight's
        lines.append(f"  returns within a sensor's clutter withheld until confirmed: {int(withheld)} (frame by frame; "
                     "one confirmed where the sensor had looked past is a navigation violation below)")
    link = {k: rep["ranges"][k]["max"] for k in LINK_COUNTERS if (rep["ranges"].get(k) or {}).get("max")}
    if link:  # cumulative counts: the last is the flight's
        lines.append("  link, not believed: " + ", ".join(f"{int(n)} {k.replace('_', ' ')}" for k, n in link.items()))
    lines.append(f"  violations: {rep['violation_count']}" + (f" (first {len(rep['violations'])} listed)"
                 if rep["violation_count"] > len(rep["violations"]) else ""))
    for v in rep["violations"]:
        end = _fmt_t(v["end_t"]) + ("" if v["ended_by"] == "violation_end" else f" ({v['ended_by']})")
        lines.append(f"    {_fmt_t(v['start_t'])} … {end}  {fmt_value(v['duration_s'], ' s')}  {v['subsystem']}: "
                     f"{v['guarantee']}; assumed {fmt_value(v['assumed'])}, observed {fmt_value(v['observed'])}; "
                     f"action {fmt_value(v['action'])}")
    lines += review_checks.lines(rep)
    fe = rep.get("flight_end")
    if fe:
        lines.append(f"  flight ended: {fe['why']}" + (f" (t = {_fmt_t(fe['t'])})" if fe["t"] is not None else "")
                     + (f"; {fe['note']}" if fe.get("note") else ""))
    lines.append(f"  failsafes: {rep['failsafe_count']}" + (
        f" ({rep.get('failsafe_events', 0)} event(s), {rep['failsafe_state_entries']}× into the failsafe state)"
        if rep.get("failsafe_state_entries") else ""))
    for fs in rep["failsafes"]:
        cleared = f", cleared at {_fmt_t(fs['cleared_t'])}" if fs["cleared_t"] is not None else ", not cleared"
        lines.append(f"    {_fmt_t(fs['t'])}  {fs['cause']} → {fs['action']}{cleared}")
        if fs.get("why"):  # a no safe speed: the input that caused it, and how the flight resumes
            lines.append(f"      {fs['why']}; resume: {fs.get('resume', '?')}")
    for b in rep.get("back_offs", []):  # offboard: a braking stop at rest inside a keep-out, backed out blind
        lines.append(f"  backed off at {_fmt_t(b['t'])}: at rest {fmt_value(b['inside_m'], ' m')} inside a keep-out, "
                     f"{fmt_value(b['path_m'], ' m')} back the way it came (sensors facing away: above V_safe there)")
    for ts in rep.get("thrust_starts", []):
        lines.append(f"  thrust ratio before the estimate settled (t = {_fmt_t(ts['t'])}): {ts['reason']}")
    lines.append(f"  mode changes: {len(rep['mode_changes'])}")
    for m in rep["mode_changes"]:
        lines.append(f"    {_fmt_t(m['t'])}  {m['from']} → {m['to']} (by {m['by']})")
    lines.append(f"  link events: {len(rep['link']['events'])}, down {rep['link']['down_s']:.1f} s"
                 + (f" (the link that recorded the log, not one in flight: the replay's daemon lost it "
                    f"{rep['log_silence_entries']}× where the log fell silent, not counted as failsafes)"
                    if rep["link"].get("of_the_log") and rep.get("log_silence_entries") else ""))
    for e in rep["link"]["events"]:
        lines.append(f"    {_fmt_t(e['t'])}  {e['status']}")
    lines.append(f"  state changes: {len(rep['state_changes'])}, limit changes: {rep['limit_changes']}, "
                 f"commands: {rep['commands']['count']} ({len(rep['commands']['failed'])} not accepted)")
    if rep.get("bad_lines"):
        lines.append(f"  unparsable lines skipped: {len(rep['bad_lines'])} "
                     f"({', '.join(b['kind'] for b in rep['bad_lines'][:5])})")
    for k, v in rep.get("outputs", {}).items():
        if k == "png_skipped":
            lines.append(f"  {v}")
        elif v is not None:
            lines.append(f"  wrote {k}: {v}")
    return "\n".join(lines)
