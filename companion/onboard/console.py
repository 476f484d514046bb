"""What `contract-guard run` says on stdout: a start banner (vehicle, table and its contracts, mode, link,
sensors, the defaults that shape the contract), then one line per thing a person watching wants to
know — link up/down, start-up verdict, engaging, holds, violations, parameter sets, errors — and a summary
at exit. Under systemd (`$JOURNAL_STREAM` set) each line carries its syslog priority (`<2>` … `<6>`), as
journald reads it; `--quiet` says nothing.

`ConsoleLog` wraps the event log: every record still goes to the log; the console only reads events.
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
from collections import Counter

from contracts.lookup import kernel_name

from .estimators import LATE_WINDOW_S
from .mavlink_in import refusal_text
from .states import BRAKE_SWITCH, CYCLE_COMPLETES

CRIT, ERR, WARNING, NOTICE, INFO = 2, 3, 4, 5, 6

# C0 controls but tab and newline, DEL, C1 controls (ESC sequences, a carriage return overwriting a line) and
# Unicode's bidirectional overrides (text shown in another order than it is)
_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")


def for_terminal(text: str) -> str:
    """`text` with every control character a log could carry to the terminal shown as "?" (a log's strings —
    its hardware name, a status text, its file name — must not move the cursor, recolour or hide a line)."""
    return _CONTROL.sub("?", text)


def _fmt(v) -> str:
    return f"{v:.2f}" if isinstance(v, float) and math.isfinite(v) else str(v)


def event_line(name: str, f: dict) -> tuple[int, str] | None:
    """The console line of one event (priority, text), or None for events a person need not watch."""
    if name == "link":
        return (INFO, "autopilot link up") if f["status"] == "up" else (WARNING, "autopilot link DOWN")
    if name == "startup_check":
        return (INFO, "start-up checks: ok") if f["ok"] else (ERR, f"start-up checks: REFUSING TO ENGAGE: {f['reason']}")
    if name == "state_change":
        return (NOTICE if f["to"] != "holding" else WARNING, f"state {f['from']} → {f['to']} ({f['reason']})")
    if name in ("failsafe", "hold_trigger"):  # a "no safe speed" names its input and how to resume
        return WARNING, f"HOLD: {f['cause']}" + (f": {f['why']}; resume: {f['resume']}" if f.get("why") else "")
    if name == "thrust_start":
        return (INFO if f["covered"] else WARNING), f["reason"]
    if name == "violation_start" and f["guarantee"] == BRAKE_SWITCH:  # the recovery brake's switch refused
        return CRIT, (f"VIOLATION autopilot: the recovery brake's switch REFUSED at {_fmt(f.get('observed'))} m/s, "
                      f"above the Hold's limit {_fmt(f.get('assumed'))} m/s; {f['action']}: the stop is NOT "
                      "guaranteed")
    if name == "delivery" and f["outcome"] != "shown":  # a mode refused or not shown: its fallback, or given up
        then = f"; asking for {f['next']} instead" if f.get("next") else ""
        return WARNING, f"{f['cmd']} {f['outcome']} after {f['waited_s']:.2f} s ({f.get('why', '')}){then}"
    if name == "violation_start":
        return ERR, (f"VIOLATION {f['subsystem']}: {f['guarantee']} (assumed {_fmt(f.get('assumed'))}, observed "
                     f"{_fmt(f.get('observed'))}); {f['action']}")
    if name == "violation_end" and f["guarantee"] == CYCLE_COMPLETES:
        return NOTICE, f"violation over: guidance (cycles complete again after {f.get('observed')} that failed)"
    if name == "violation_end":  # the daemon's own lateness: one late cycle, its aftermath is `reaction_time`'s
        return None if f["subsystem"] == "guidance" else (NOTICE, f"violation over: {f['subsystem']}")
    if name == "reaction_time":
        return (NOTICE, f"cycles on time again: reaction time back to {f['t_react_s']:.2f} s") if not f["late_s"] else \
            (WARNING, f"the daemon's cycles run late: reaction time {f['t_react_s']:.2f} s (+{f['late_s'] * 1e3:.0f} ms) "
                      f"for the next {LATE_WINDOW_S:.0f} s, a lower speed")
    if name == "would_hold" and f["causes"]:
        return WARNING, f"shadow: would HOLD: {', '.join(f['causes'])}" + (f" ({f['why']})" if f.get("why") else "")
    if name == "limit_change" and "sent" in f:
        return INFO, f"speed limit {f['v_max']:.2f} m/s; sent {f['sent']:.2f} m/s, the autopilot's own cruise"
    if name == "limit_change" and "overshoot_budget_m_s" in f:
        return INFO, (f"speed limit sent {f['v_max']:.2f} m/s: V_max − {f['overshoot_budget_m_s']:.2f} m/s, the "
                      "autopilot's overshoot budget")
    if name == "limit_change":
        return INFO, f"speed limit {f['v_max']:.2f} m/s"
    if name == "cruise_speed":
        return INFO, f"autopilot cruise speed {f['v']:.2f} m/s ({f['param']}): the limit sent is never above it"
    if name == "mode_change" and f["by"] == "other":
        return NOTICE, f"autopilot mode {f['from']} → {f['to']} (not by us)"
    if name == "param_set":
        return NOTICE, f"parameter {f['param']}: {f['old']:g} → {f['new']:g}"
    if name == "engage_refused":
        return ERR, f"engage REFUSED: {f['reason']}"
    if name == "shutdown" and f["hold"]:
        return (WARNING, "stopping in flight: Hold commanded, the autopilot shows it") if f["confirmed"] else \
            (ERR, f"stopping in flight: Hold commanded, NOT confirmed in {f['waited_s']:.1f} s: the autopilot's own "
                  "companion-loss failsafe decides now")
    if name == "param_refused":
        return WARNING, f"parameter {f['param']} = {f['value']:g} from system {f['source']} refused: {f['why']}"
    if name == "offboard":
        return NOTICE, f"offboard {f['from']} → {f['to']} ({f['reason']})"
    if name == "no_avoiding_plan":
        return WARNING, "no avoiding plan: braking"
    if name == "back_off":
        return WARNING, f"stopped {_fmt(f['inside_m'])} m inside a keep-out: backing off {_fmt(f['path_m'])} m the way it came"
    if name == "dead_end":
        return WARNING, f"dead end: {f['reason']} ({_fmt(f['obstacle_m'])} m)"
    if name == "mission" and f["status"] in ("ready", "refused"):
        return (INFO, f"mission route ready: {f.get('waypoints')} waypoints") if f["status"] == "ready" else \
            (ERR, f"mission refused: {f.get('reason')}")
    if name == "source_refused":
        return (NOTICE if f["what"] == "unknown" else ERR if f["what"] in ("refused", "contested", "bad_signature")
                else WARNING), refusal_text(f)
    if name == "log_failing":
        return ERR, f"EVENT LOG FAILING: {f['error']} (records are kept in memory and written when it can)"
    if name in ("loop_error", "implausible_input", "autopilot_restart", "log_recovered", "log_writing"):
        detail = f.get("error") or f.get("why") or ""
        return ERR if name == "loop_error" else WARNING, f"{name.replace('_', ' ')}: {f.get('message', '')} {detail}".strip()
    return None


class ConsoleLog:
    """An event log that also tells the console (see the module docstring)."""

    def __init__(self, log, quiet: bool = False, out=sys.stdout, clock=time.monotonic):
        self.log, self.quiet, self.out, self.clock = log, quiet, out, clock
        self.journal = bool(os.environ.get("JOURNAL_STREAM"))
        self.counts: Counter = Counter()
        self.t0 = clock()

    def say(self, text: str, priority: int = INFO) -> None:
        if self.quiet:
            return
        try:
            print(f"<{priority}>{text}" if self.journal else f"contract-guard: {text}", file=self.out, flush=True)
        except (OSError, ValueError):
            pass  # a closed terminal must not stop the daemon

    def event(self, t, name, **fields):
        self.counts[name] += 1
        if name == "violation_start":
            self.counts[f"violation:{fields.get('subsystem')}"] += 1
        if name == "shutdown" and fields.get("hold"):
            self.counts["shutdown_hold"] += 1
        line = event_line(name, fields)
        quiet_now = (name == "state_change" and fields.get("to") == "failsafe" and not self.counts["link"]  # never up
                     or line is not None and line[1] == self._last_line  # e.g. the same limit re-sent
                    and name != "engage_refused")  # (a refusal is said each time it is asked)
        if line is not None and not quiet_now:
            self.say(line[1], line[0])
            self._last_line = line[1]
        return self.log.event(t, name, **fields)

    _last_line = ""

    def tick(self) -> None:
        """Called every loop: while no autopilot has been heard, say so now and then."""
        if not self.counts["link"] and self.clock() - self.t0 >= self._next_reminder:
            self.say(f"still no autopilot heartbeat after {self._next_reminder:.0f} s", WARNING)
            self._next_reminder *= 3
        self.log.tick()

    _next_reminder = 10.0

    def __getattr__(self, name):  # state, raw, close: the log's
        return getattr(self.log, name)

    def summary(self, counters) -> str:
        c = counters
        by = ", ".join(f"{k.split(':', 1)[1]} {n}" for k, n in sorted(self.counts.items()) if k.startswith("violation:"))
        return (f"stopped after {self.clock() - self.t0:.0f} s: {c.messages} messages ({c.bad_packets} malformed, "
                f"{c.implausible} implausible), {c.commands_sent} commands, "
                f"{self.counts['failsafe'] + self.counts['hold_trigger'] + self.counts['shutdown_hold']} holds, "
                f"violations: {by or 'none'}, {c.loop_errors} loop errors, {c.log_errors} log errors; link: "
                f"{c.unknown_source} from unknown sources, {c.refused_address} from refused addresses, "
                f"{c.rejected_signature} badly signed, {c.link_dropped} not MAVLink, {c.kernel_drops} dropped by "
                "the kernel")


def controller_coverage(table) -> str:
    """How much of the controller contract the aircraft's own flights measured (`contract-guard calibrate`)."""
    if table.e_pred is None:
        return "no controller contract"
    c = (table.e_pred.info or {}).get("calibration")
    if not c:
        return "built in the SITL from the vehicle file (not measured on this aircraft)"
    logs = sum(1 for lg in c.get("logs", []) if not lg.get("error"))
    return (f"measured on {c['covered_cells']} of {c['cells']} cells ({100 * c['covered_fraction']:.1f} % of the "
            f"envelope) from {c['samples']} windows of {logs} flight log(s); the rest is the SITL's prediction "
            f"scaled by {c['ratio']:.2f} (never below it)"
            + (f"; {c['faster_cells']} cell(s) FASTER than stock, accepted by a person" if c.get("faster_cells") else ""))


def reaction_budget(cfg, vehicle) -> str:
    """The decision part of the vehicle's t_react, in words (the start banner): one loop period and the stated jitter
    allowance (docs/daemon.md, Timeliness), and what happens to a cycle later than that."""
    to, period = cfg.timeouts, 1.0 / cfg.loop_hz
    line = (f"reaction time: t_react {vehicle.t_react_s:.2f} s holds one {period * 1e3:.0f} ms cycle and a "
            f"{to.cycle_jitter_s * 1e3:.0f} ms jitter allowance (timeouts.cycle_jitter_s); a later cycle is a guidance "
            f"violation and counts as reaction time for {LATE_WINDOW_S:.0f} s, {to.cycle_late_s * 1e3:.0f} ms late "
            "hands over to Hold")
    if period + to.cycle_jitter_s >= vehicle.t_react_s:
        line += (f"; WARNING: one cycle and the allowance ({(period + to.cycle_jitter_s) * 1e3:.0f} ms) fill the whole "
                 "t_react: the vehicle file's t_react leaves nothing for the sensor and the autopilot")
    return line


def table_trust(table) -> str:
    """A table's signature and serial in words (the banner's first line)."""
    sig = table.signature
    if not sig["signed"]:
        return "unsigned"
    how = "verified with table_public_key" if sig["verified"] else "signature not checked (no table_public_key)"
    return f"signed by key {sig['key_id']}, {how}, serial {table.serial if table.serial is not None else 'none'}"


def banner(cfg, table, controller_contract: str) -> list[str]:
    """The start banner: what the daemon will enforce, on what, and the defaults that shape it."""
    lk, ct = cfg.link, cfg.contract
    sensors = "; ".join(f"[{k}] {s.kind} at {s.orientation_deg:g}°, {s.h_fov_deg:g}° wide, "
                        f"rated {'(none: claims trusted, shadow only)' if s.max_range_m is None else f'{s.max_range_m:g} m'}"
                        for k, s in enumerate(cfg.sensors)) or "none (D_od is 0: no speed is safe)"
    engage = "engaged from the start" if cfg.engage else "engages when asked (CG_ENGAGE 1)"
    from .assumptions import e_tr_floor, start_thrust
    from .contract_in_force import banner_line as swerve_line
    from .coverage import banner_line
    from .detection_range import evidence_line

    _, thrust = start_thrust(table, cfg.daemon_mode.contract)
    short = [] if thrust["covered"] else [  # a --partial-grid table: said before the first flight
        f"WARNING: the table covers thrust_ratio {thrust['table_min']:g} and up, the vehicle's range starts at "
        f"{thrust['vehicle_min']:g}: in flight no speed is safe until the hover estimate settles (airborne and "
        "steady); engage after that, or build the table over the whole thrust_ratio_range"]
    return [
        f"vehicle {table.vehicle.name}, table {table.path} (contracts: {', '.join(table.available)}; "
        f"Ω lookup {kernel_name()}; {table_trust(table)})",
        f"controller contract: {controller_contract}; {controller_coverage(table)}",
        f"{cfg.mode} mode ({cfg.daemon_mode.contract} contract), {engage}",
        *short,
        *([cfg.speed_overshoot.budget().line()] if cfg.daemon_mode.contract == "stop" else []),
        *([] if not cfg.governor.recovery_brake else [
            "recovery brake on: a stop is flown by the daemon in offboard at the airframe's braking, then Hold, its "
            "tracking error within its own E_tr_pred (the table's e_tr_pred_brake: without it the brake is "
            "unavailable); the limit is its own stop contract's once its switch has been shown in this flight and its "
            "start-up checks pass (offboard mode, offboard-loss action Hold or Land); until then, or once the "
            "autopilot refuses the switch, the autopilot's Hold's limit. It assumes the "
            "autopilot accepts the switch: refused above the Hold's limit, the stop is not guaranteed (logged as the "
            "autopilot's violation)"]),
        f"sensors: {sensors}",
        banner_line(cfg.sensors, table.vehicle.r_body_m, e_tr_floor(cfg, table)),
        *([] if cfg.daemon_mode.contract != "avoid" else [swerve_line(
            cfg.sensors, ct.r_obst_m + e_tr_floor(cfg, table) + table.vehicle.r_body_m, ct.r_obst_m,
            max((s.max_range_m or 0.0 for s in cfg.sensors), default=0.0))]),
        evidence_line(cfg.sensors),
        f"contract settings: R_obst {ct.r_obst_m:g} m (CG_R_OBST {ct.r_obst_range_m[0]:g}–{ct.r_obst_range_m[1]:g} m "
        f"from systems {', '.join(map(str, lk.gcs_system_ids))}), E_tr floor {ct.e_tr_floor_m:g} m over "
        f"{ct.e_tr_window_s:g} s, dwell {ct.dwell_s:g} s, navigation margin {ct.nav_margin:g} of each sensor's claimed "
        f"range{'' if ct.nav_margin else ' (claims trusted in full)'}, loop {cfg.loop_hz:g} Hz, event log {cfg.log.dir}",
        reaction_budget(cfg, table.vehicle),
        lk.seats(cfg.sensors),
        *lk.trust(),
        f"waiting for the autopilot ({lk.autopilot}, system {lk.target_system} component {lk.target_component}) "
        f"on {lk.connect}{f' from {lk.autopilot_address}' if lk.autopilot_address else ''}",
    ]
