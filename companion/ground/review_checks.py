"""What the flight did against where it had to stay and what it was told: the review's keep-out and delivery
checks (DESIGN.md §1: a review never calls a flight "kept" where the vehicle entered its keep-out disc or a
command did not take effect on time). `companion.ground.review` feeds `Checks` every record of its one pass; the
judgements themselves are the pure functions at the top. No I/O.

Keep-out. A state sample's `obstacle_m` is the nearest obstacle surface a sensor saw near the path, taken from
the vehicle's centre. The commanded path keeps out of the keep-out disc, R_obst + E_tr + r_body around the
obstacle's centre, and the vehicle stays within E_tr of its path (the controller's guarantee), so the vehicle keeps
out of the obstacle grown by its own radius: a return closer than r_body is the vehicle inside its keep-out, whatever
the obstacle's size (up to R_obst); within NEAR_MISS_M more it is a near miss, said all the same. (The E_tr band
is the path's margin for the vehicle's tracking error: a vehicle in it is within the contract.) What the log can say of a collision: a return at or inside
r_body (the surface at the body); a return closing in so fast, so near, that not even braking at
`ABRUPT_STOP_M_S2` stops the body short of it; or a stop faster than that with a return within the distance flown
meanwhile. A sensor says nothing below its minimum range, so a vehicle that flies into an obstacle may show only
a return closing in and then gone.

Delivery. A mode command (`command` hold / offboard / mission) is taken when the autopilot shows that mode (a
`mode_change` to it, or a state sample's `mode`) within the run's mode budget (`start.delivery.t_mode_s`, else
`MODE_BUDGET_S`); re-sends of the same mode keep the first one's clock. A speed limit (`change_speed`) is flown
when ground speed is at most limit × 1.05 + 0.3 m/s once the autopilot had time to slow down from the speed it
was at (`speed_budget_s`), until the next different limit or mode.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from companion.onboard.config import DeliveryConfig
from companion.onboard.modes import MODES

MODE_BUDGET_S = DeliveryConfig().t_mode_s  # [s] a mode command is shown within this: the daemon's default budget
MODE_COMMANDS = ("hold", "offboard", "mission")  # `command.cmd` asking for the autopilot mode of that name
# [m/s] ground speed above V_safe (Γ_flown) by up to this is not a finding: the review's default, and the campaign's
# strict classifier's (a flight whose Γ_flown exceeds it was flown outside the contract)
SPEED_TOLERANCE_M_S = 0.2
NEAR_MISS_M = 0.1  # [m] a return this close to the body is a near miss (the contract's own bound is the body)
SPEED_OVERSHOOT = 0.05  # a limit is flown up to limit × (1 + this) + SPEED_MARGIN_M_S (the supervisor's own rule)
SPEED_MARGIN_M_S = 0.3
SPEED_SLACK_S = 1.0  # [s] on top of the braking time: the autopilot's jerk ramp and its reaction
BRAKE_FALLBACK_M_S2 = 1.0  # braking assumed where the log names no vehicle (a slow one: the longer budget)
ABRUPT_STOP_M_S2 = 2 * 9.81  # faster than any multirotor brakes (1 g at 45° of tilt): it hit something
# a return closing faster than the ground speed by more than this (× 1.2 + 0.5 m/s) is another obstacle taking over
# as the nearest, not one approached
CLOSING_RATIO, CLOSING_SLACK_M_S = 1.2, 0.5
COLLISION_GAP_S = 2.0  # samples showing a collision no further apart than this are one collision
MAX_LISTED = 1000


@dataclass(frozen=True)
class RunFacts:
    """What one daemon run's checks need of its vehicle and budgets, and where it came from."""

    r_body_m: float | None = None  # the vehicle's radius; None: unknown (taken as 0, said)
    brake_m_s2: float | None = None  # the autopilot's braking in auto modes
    t_mode_s: float = MODE_BUDGET_S
    source: str = "no vehicle in the log"


def _num(x) -> float | None:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x) if math.isfinite(x) else None


def _pos(x) -> float | None:
    x = _num(x)
    return x if x is not None and x > 0 else None


def facts_of_start(rec: dict, vehicle: dict | None = None, source: str = "") -> RunFacts:
    """A run's facts from its `start` record: the radius and braking of its `vehicle` when the record holds the
    vehicle's parameters (as a table's metadata does), else of `vehicle` (found by the caller from the record's
    table or vehicle name; `source` says which); the mode budget from `delivery.t_mode_s`."""
    own = rec.get("vehicle")
    veh, where = (own, "the log's start record") if isinstance(own, dict) else (vehicle or {}, source)
    braking = veh.get("braking") if isinstance(veh.get("braking"), dict) else {}
    delivery = rec.get("delivery") if isinstance(rec.get("delivery"), dict) else {}
    r_body = _pos(veh.get("r_body_m"))
    return RunFacts(r_body, _pos(braking.get("accel_max_m_s2")), _pos(delivery.get("t_mode_s")) or MODE_BUDGET_S,
                    where if r_body is not None else "no vehicle in the log")


def keep_out_margin(r_body_m: float | None) -> float:
    """r_body and NEAR_MISS_M: how close to an obstacle's surface the vehicle's centre comes before the review says
    so (an unknown radius counts 0)."""
    return (r_body_m or 0.0) + NEAR_MISS_M


def abrupt_stop(gs0: float, gs1: float, dt: float, obstacle0: float | None, r_body_m: float | None) -> bool:
    """Whether ground speed fell from gs0 to gs1 in dt faster than a multirotor brakes, with the return seen
    before it (obstacle0) within the distance flown meanwhile plus the body."""
    return (dt > 0 and (gs0 - gs1) / dt >= ABRUPT_STOP_M_S2 and obstacle0 is not None
            and obstacle0 <= gs0 * dt + (r_body_m or 0.0))


def closing_too_fast(ob0: float, ob1: float, dt: float, gs: float, r_body_m: float | None) -> float | None:
    """The closing speed of a return that came from ob0 to ob1 in dt, where even braking at `ABRUPT_STOP_M_S2`
    cannot stop the body short of it (closing no faster than ground speed `gs` allows: one static obstacle
    approached); None otherwise."""
    closing = (ob0 - ob1) / dt if dt > 0 else 0.0
    if not 0 < closing <= gs * CLOSING_RATIO + CLOSING_SLACK_M_S:
        return None
    return closing if ob1 - (r_body_m or 0.0) < closing * closing / (2 * ABRUPT_STOP_M_S2) else None


def speed_ceiling(v_cmd: float) -> float:
    """The most ground speed that still flies a limit of v_cmd."""
    return v_cmd * (1 + SPEED_OVERSHOOT) + SPEED_MARGIN_M_S


def speed_budget_s(v0: float | None, v_cmd: float, brake_m_s2: float | None) -> float:
    """How long an autopilot may take to slow from v0 to a new limit v_cmd: the braking time at its braking
    acceleration (else `BRAKE_FALLBACK_M_S2`), plus `SPEED_SLACK_S`."""
    return max((v0 or 0.0) - v_cmd, 0.0) / (brake_m_s2 or BRAKE_FALLBACK_M_S2) + SPEED_SLACK_S


def explain(t: float, boot, violations: list[dict], overdue: list[dict]) -> list[str]:
    """Whose guarantee was broken at time t of run `boot`: the subsystems with a violation open then, and
    `delivery` for a command overdue then; empty when nothing in the log explains it."""
    subs = {str(v.get("subsystem")) for v in violations if v.get("boot") == boot and v.get("start_t") is not None
            and v["start_t"] <= t <= (v["end_t"] if v.get("end_t") is not None else math.inf)}
    if any(o["boot"] == boot and o["from_t"] <= t <= o["to_t"] for o in overdue):
        subs.add("delivery")
    return sorted(subs)


class Checks:
    """Keep-out entries, collisions as far as the log tells, mode commands and speed limits against what the
    autopilot then showed and flew; fed in log order, one daemon run after another."""

    def __init__(self, gap_s: float = 1.0):
        self.gap_s = gap_s
        self.facts = RunFacts()
        self.run_facts: list[RunFacts] = []
        self.boot = None
        self.shadow = False  # this run commanded nothing
        self.last_t = None
        self.entries: list[dict] = []
        self.entry_count = 0
        self.open_entry: dict | None = None
        self.collisions: list[dict] = []
        self.hit_t = None  # the run's last sample that showed a collision
        self.prev = None  # (t, ground speed, obstacle_m) of the run's previous sample
        self.mode = None  # the autopilot mode last shown
        self.modes: list[dict] = []  # every mode command, judged
        self.pending: dict | None = None  # the mode command not shown yet
        self.speed: dict | None = None  # the speed limit in force: its window
        self.speeds: list[dict] = []  # the limits not flown
        self.limits = 0
        self.v_last = None  # the run's last ground speed

    # ---------------------------------------------------------------- feeding

    def start(self, facts: RunFacts, mode) -> None:
        self.facts = facts
        known = MODES.get(mode) if isinstance(mode, str) else None  # the start record's mode, as logged
        self.shadow = known is not None and not known.commands
        if facts not in self.run_facts:
            self.run_facts.append(facts)

    def record(self, boot, t: float | None, rec: dict) -> None:
        """One record of run `boot` (the caller ends the previous run first)."""
        self.boot = boot
        if t is None:
            return
        self.last_t = t
        p = self.pending
        if p is not None and t > p["t"] + p["budget_s"]:
            p["overdue"] = True
        if rec.get("kind") == "state":
            self._state(t, rec)
        elif rec.get("event") == "mode_change":
            self._mode_seen(t, rec.get("to"))
        elif rec.get("event") == "command":
            self._command(t, rec.get("cmd"), rec.get("params"))

    def _state(self, t: float, rec: dict) -> None:
        self._mode_seen(t, rec.get("mode"))
        ob, gs = _num(rec.get("obstacle_m")), _num(rec.get("ground_speed"))
        r_body = self.facts.r_body_m
        margin = keep_out_margin(r_body)
        if ob is not None and ob < margin:
            e = self.open_entry
            if e is None:
                self.entry_count += 1
                e = self.open_entry = {"start_t": t, "end_t": t, "closest_m": ob, "t": t, "margin_m": margin,
                                       "x": _num(rec.get("x")), "y": _num(rec.get("y")), "boot": self.boot,
                                       "shadow": self.shadow}
            e["end_t"] = t
            if ob < e["closest_m"]:
                e.update(closest_m=ob, t=t, margin_m=margin, x=_num(rec.get("x")), y=_num(rec.get("y")))
        else:
            self._close_entry()
        if ob is not None and r_body is not None and ob <= r_body:
            self._collision(t, rec, f"a return at {ob:.2f} m, at or inside the vehicle's radius {r_body:.2f} m")
        t0, gs0, ob0 = self.prev if self.prev is not None else (None, None, None)
        if t0 is not None and 0 < t - t0 <= self.gap_s and gs is not None and gs0 is not None:
            closing = None if ob0 is None or ob is None else closing_too_fast(ob0, ob, t - t0, max(gs0, gs), r_body)
            if closing is not None:
                self._collision(t, rec, f"a return {ob:.2f} m away closing at {closing:.2f} m/s: not even braking "
                                        f"at {ABRUPT_STOP_M_S2 / 9.81:g} g stops the body short of it")
            elif abrupt_stop(gs0, gs, t - t0, ob0, r_body):
                self._collision(t, rec, f"stopped from {gs0:.2f} to {gs:.2f} m/s in {t - t0:.2f} s with a return "
                                        f"{ob0:.2f} m away")
        self.prev = (t, gs, ob)
        w = self.speed
        if w is not None and gs is not None:
            if w["budget_s"] is None:
                w["budget_s"] = speed_budget_s(gs, w["v_cmd"], self.facts.brake_m_s2)
            over = t >= w["t"] + w["budget_s"] and gs > speed_ceiling(w["v_cmd"])
            if over:
                if w["first_over_t"] is None:
                    w["first_over_t"] = t
                elif w["_was_over"] and t - w["last_over_t"] <= self.gap_s:
                    w["over_s"] += t - w["last_over_t"]
                w["last_over_t"] = t
                if gs > w["worst_m_s"]:
                    w.update(worst_m_s=gs, worst_t=t)
            w["_was_over"] = over
        if gs is not None:
            self.v_last = gs

    def _collision(self, t: float, rec: dict, how: str) -> None:
        last, self.hit_t = self.hit_t, t
        if last is not None and t - last < COLLISION_GAP_S:
            return  # the same one, still in contact
        if len(self.collisions) < MAX_LISTED:
            self.collisions.append({"t": t, "x": _num(rec.get("x")), "y": _num(rec.get("y")), "how": how,
                                    "boot": self.boot, "shadow": self.shadow})

    def _close_entry(self) -> None:
        e, self.open_entry = self.open_entry, None
        if e is not None and len(self.entries) < MAX_LISTED:
            e["duration_s"] = e["end_t"] - e["start_t"]
            self.entries.append(e)

    def _mode_seen(self, t: float, mode) -> None:
        if not isinstance(mode, str):
            return
        p = self.pending
        if p is not None and mode == p["cmd"]:
            p.update(shown_t=t, delay_s=t - p["t"])
            self._judge(p, "shown late" if p["delay_s"] > p["budget_s"] else "shown", t)
        w = self.speed
        if w is not None and w["mode"] is None:
            w["mode"] = mode
        elif w is not None and mode != w["mode"]:
            self._close_speed(f"mode {mode}")  # another mode may not fly the limit: a new one is sent for it
        self.mode = mode

    def _command(self, t: float, cmd, params) -> None:
        if cmd in MODE_COMMANDS:
            p = self.pending
            if p is not None and p["cmd"] == cmd:
                return  # a re-send: the first one's clock runs on
            if p is not None:
                self._judge(p, "not shown" if p["overdue"] else "superseded", t, f"a {cmd} command")
            self.pending = {"cmd": cmd, "t": t, "budget_s": self.facts.t_mode_s, "shown_t": None, "delay_s": None,
                            "overdue": False, "boot": self.boot}
        elif cmd == "change_speed":
            v = _pos(params[1]) if isinstance(params, list) and len(params) > 1 else None
            if v is None or (self.speed is not None and self.speed["v_cmd"] == v):
                return  # unreadable, or a re-send of the limit in force
            self._close_speed("a new limit")
            self.limits += 1
            v0 = self.v_last
            self.speed = {"v_cmd": v, "t": t, "boot": self.boot, "mode": self.mode, "v_at_command": v0,
                          "budget_s": None if v0 is None else speed_budget_s(v0, v, self.facts.brake_m_s2),
                          "first_over_t": None, "last_over_t": None, "_was_over": False, "over_s": 0.0,
                          "worst_m_s": -math.inf, "worst_t": None}

    def _judge(self, p: dict, outcome: str, t: float, by: str | None = None) -> None:
        """Close mode command p: shown, shown late, not shown (ended at t, by `by`), superseded in time."""
        self.pending = None
        p["outcome"] = outcome
        p["closed_t"] = t
        p["mode_seen"] = self.mode
        if by:
            p["ended_by"] = by
        if len(self.modes) < MAX_LISTED:
            self.modes.append(p)

    def _close_speed(self, why: str) -> None:
        w, self.speed = self.speed, None
        if w is not None and w["first_over_t"] is not None and len(self.speeds) < MAX_LISTED:
            w["ended_by"] = why
            self.speeds.append({k: v for k, v in w.items() if not k.startswith("_")})

    def end_run(self) -> None:
        """The run ended (a restart, or the end of the log): judge what it left open."""
        self._close_entry()
        p = self.pending
        if p is not None:
            late = self.last_t is not None and self.last_t > p["t"] + p["budget_s"]
            self._judge(p, "not shown" if late else "unjudged", self.last_t, "the end of the run")
        self._close_speed("the end of the run")
        self.prev, self.mode, self.v_last, self.last_t, self.hit_t = None, None, None, None, None
        self.facts, self.shadow = RunFacts(), False

    # ---------------------------------------------------------------- result

    def result(self, violations: list[dict]) -> dict:
        """The report's `keep_out` and `delivery` sections; `violations`: the review's (to explain an entry)."""
        self.end_run()
        failed = [m for m in self.modes if m["outcome"] in ("not shown", "shown late")]
        overdue = [{"boot": m["boot"], "from_t": m["t"] + m["budget_s"],
                    "to_t": m["shown_t"] if m["shown_t"] is not None else m["closed_t"]} for m in failed]
        overdue += [{"boot": s["boot"], "from_t": s["first_over_t"], "to_t": s["last_over_t"]} for s in self.speeds]
        for e in self.entries:
            e["explained_by"] = explain(e["t"], e["boot"], violations, overdue)
            e["last_mode_command"] = self._last_mode_before(e["t"], e["boot"])
        for c in self.collisions:
            c["explained_by"] = explain(c["t"], c["boot"], violations, overdue)
        delays = [m["delay_s"] for m in self.modes if m["delay_s"] is not None]
        return {
            "keep_out": {"vehicles": [asdict(f) for f in self.run_facts], "entries": self.entries,
                         "entry_count": self.entry_count, "collisions": self.collisions},
            "delivery": {"mode_commands": len(self.modes), "mode_delay_max_s": max(delays) if delays else None,
                         "modes_not_taken": failed,
                         "modes_unjudged": [m for m in self.modes if m["outcome"] == "unjudged"],
                         "speed_limits": self.limits, "limits_not_flown": self.speeds},
        }

    def _last_mode_before(self, t: float, boot) -> dict | None:
        before = [m for m in self.modes if m["boot"] == boot and m["t"] <= t]
        return None if not before else {k: before[-1][k] for k in ("cmd", "t", "shown_t", "delay_s")}


# ============================================================================ what the review says

COMMAND_NAMES = {176: "DO_SET_MODE", 178: "DO_CHANGE_SPEED", 511: "SET_MESSAGE_INTERVAL"}
RESULT_NAMES = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED",
                5: "IN_PROGRESS", 6: "CANCELLED"}
ACCEPTED = {"0", "5", "accepted", "in_progress", "mav_result_accepted", "mav_result_in_progress", "ok", "true"}


def refused(result) -> bool:
    """Whether a command's result is a refusal (anything but accepted or in progress, by number or name)."""
    return str(result).strip().lower() not in ACCEPTED


def command_text(name, result) -> str:
    """A command and its result for a person: `DO_SET_MODE: FAILED (4)`."""
    name = COMMAND_NAMES.get(name, name) if isinstance(name, int) else name
    said = RESULT_NAMES.get(result) if isinstance(result, int) and not isinstance(result, bool) else None
    return f"{name}: {said} ({result})" if said else f"{name}: {result}"


def _t(t) -> str:
    return "?" if t is None else f"{t:.2f} s"


def _why(explained_by: list[str], shadow: bool = False) -> str:
    if explained_by:
        return "with " + ", ".join(explained_by) + "'s guarantee broken then"
    return "unexplained" + (" (shadow mode: the daemon commanded nothing)" if shadow else " by the log's violations")


def _mode_said(m: dict) -> str:
    if m["outcome"] == "shown late":
        return f"{m['cmd']} at t = {_t(m['t'])} shown {m['delay_s']:.2f} s later"
    return (f"{m['cmd']} at t = {_t(m['t'])} not shown (the mode {m['mode_seen'] or 'unknown'} until "
            f"{m.get('ended_by', 'the end of the run')} at t = {_t(m['closed_t'])})")


def findings(rep: dict) -> list[str]:
    """The report's lines for a reviewer from the `keep_out` and `delivery` sections."""
    ko, dl = rep.get("keep_out"), rep.get("delivery")
    if ko is None or dl is None:
        return []
    out = []
    if ko["collisions"]:
        c = ko["collisions"][0]
        out.append(f"collision as far as the log tells ({len(ko['collisions'])}×), first at t = {_t(c['t'])}: "
                   f"{c['how']}; {_why(c['explained_by'], c['shadow'])}")
    if ko["entries"]:
        e = min(ko["entries"], key=lambda e: e["closest_m"])
        last = e.get("last_mode_command")
        after = "" if last is None else f"; the last mode command before it: {last['cmd']} at t = {_t(last['t'])}, " + (
            f"shown {last['delay_s']:.2f} s later" if last["delay_s"] is not None else "not shown")
        whys = {}
        for x in ko["entries"]:
            k = ", ".join(x["explained_by"]) or "unexplained"
            whys[k] = whys.get(k, 0) + 1
        each = f" (entries: {', '.join(f'{k} ×{n}' for k, n in whys.items())})" if len(whys) > 1 else ""
        known = ko["vehicles"] and all(v["r_body_m"] for v in ko["vehicles"])
        unknown = "" if known else "; vehicle radius unknown, taken as 0"
        out.append(f"the vehicle entered its keep-out disc {ko['entry_count']}×: closest {e['closest_m']:.2f} m from "
                   f"an obstacle's surface at t = {_t(e['t'])}, inside r_body + {NEAR_MISS_M:g} m = {e['margin_m']:.2f} m; "
                   f"{_why(e['explained_by'], e.get('shadow', False))}{after}{each}{unknown}")
    bad = dl["modes_not_taken"]
    if bad:
        out.append(f"{len(bad)} mode command(s) not taken within their {bad[0]['budget_s']:.2f} s: "
                   + "; ".join(_mode_said(m) for m in bad[:3]) + ("; …" if len(bad) > 3 else ""))
    slow = dl["limits_not_flown"]
    if slow:
        s = slow[0]
        out.append(f"{len(slow)} speed limit(s) not flown: {s['v_cmd']:.2f} m/s commanded at t = {_t(s['t'])}, "
                   f"ground speed up to {s['worst_m_s']:.2f} m/s at t = {_t(s['worst_t'])} — above "
                   f"{speed_ceiling(s['v_cmd']):.2f} m/s for {s['over_s']:.1f} s after the {s['budget_s']:.2f} s it "
                   "had to slow down")
    return out


def lines(rep: dict) -> list[str]:
    """The `keep_out` and `delivery` sections for a person (the text report)."""
    ko, dl = rep.get("keep_out"), rep.get("delivery")
    if ko is None or dl is None:
        return []
    radius = "; ".join(f"r_body {v['r_body_m']:.2f} m from {v['source']}" if v["r_body_m"] else
                       f"{v['source']}: r_body 0" for v in ko["vehicles"]) or "no vehicle in the log: r_body 0"
    n = ko["entry_count"]
    out = [f"  keep-out (a return closer than r_body + {NEAR_MISS_M:g} m; {radius}): {n} entr{'y' if n == 1 else 'ies'}, "
           f"{len(ko['collisions'])} collision(s) as far as the log tells"]
    for e in sorted(ko["entries"], key=lambda e: e["closest_m"])[:5]:
        out.append(f"    {_t(e['start_t'])} … {_t(e['end_t'])}  closest {e['closest_m']:.2f} m at {_t(e['t'])} "
                   f"(r_body + {NEAR_MISS_M:g} m: {e['margin_m']:.2f} m)  {', '.join(e['explained_by']) or 'unexplained'}")
    for c in ko["collisions"][:5]:
        out.append(f"    collision at {_t(c['t'])}: {c['how']}")
    delay = dl["mode_delay_max_s"]
    shown = "" if delay is None else f", shown at most {delay:.2f} s after"
    out.append(f"  mode commands: {dl['mode_commands']}{shown}; not taken in time: {len(dl['modes_not_taken'])}")
    for m in dl["modes_not_taken"][:5] + dl["modes_unjudged"][:5]:
        out.append(f"    {_mode_said(m)}" if m["outcome"] != "unjudged" else
                   f"    {m['cmd']} at t = {_t(m['t'])}: not judged, the log ends {m['closed_t'] - m['t']:.2f} s after")
    out.append(f"  speed limits commanded: {dl['speed_limits']}; not flown: {len(dl['limits_not_flown'])}")
    return out
