"""What a replayed log says of the flight itself, apart from what the shadow daemon made of it: when the vehicle was
armed (where the flight ends), where the autopilot's stream fell silent in the log, and which range sensors it
carries that look elsewhere than along the path.

A log records the autopilot through whatever wrote it: a `.tlog` through the ground station's radio, a ULog or
DataFlash log through the autopilot's own logger. A silence there is a gap in the recording: the replay's daemon goes
stale and fails safe as it would have in flight ("autopilot heartbeat lost"), but that is the recording's link, not
the link the daemon has on board, nor the autopilot's own failsafe. So the review counts those as the log's
telemetry gaps, a data-quality note, never as failsafes of the vehicle or of the daemon, nor as violations; and the
flight ends where the vehicle disarms (or, armed to the last, where the autopilot's stream ends), not where the
replay's daemon lost the recording's link.
"""

from __future__ import annotations

LISTED = 100
# MAV_SENSOR_ORIENTATION of a range sensor that looks off the horizontal plane (the path), by name
FACING = {24: "up", 25: "down"}
ARMED = 128  # MAV_MODE_FLAG_SAFETY_ARMED in a HEARTBEAT's base_mode (and a log's `mode` op)
HORIZONTAL = 8  # MAV_SENSOR_ORIENTATION below this: horizontal (ROTATION_YAW_45·k)


def facing(orientation: int) -> str:
    """A MAV_SENSOR_ORIENTATION as a person reads it: up, down, a horizontal one by its rotation's name (for one
    that no configured sensor has), or the rotation's number."""
    if 0 <= orientation < HORIZONTAL:
        name = f"ROTATION_YAW_{45 * orientation}" if orientation else "ROTATION_NONE"
        return f"facing {name}, where no configured sensor looks"
    return FACING.get(orientation, f"orientation {orientation}, not horizontal")


class Watch:
    """Follows the autopilot's own stream through a replay: `stream(t, t_log)` for each of its messages that tells it
    is alive (a HEARTBEAT for a `.tlog`, any op of an autopilot's own log), `armed(t, on)` where it says whether it is
    armed; `t` in the replay's time [s] (the review's), `t_log` in the log's own (a silence the replay cut is still
    whole there). `limit_s`: the daemon's heartbeat time-out, beyond which a silence made it fail safe."""

    def __init__(self, limit_s: float):
        self.limit_s = limit_s
        self.last: tuple[float, float] | None = None  # (t, t_log) of the stream's last message
        self.gaps: list[dict] = []  # the first LISTED
        self.count, self.total_s, self.longest = 0, 0.0, None
        self.spans: list[list] = []  # armed [start, end] (end None while armed): the first LISTED − 1, and the last
        self.armings = 0
        self.known = False  # a message said whether the vehicle was armed

    def stream(self, t: float, t_log: float) -> None:
        if self.last is not None:
            silent = t_log - self.last[1]
            if silent > self.limit_s:
                gap = {"t": self.last[0], "silent_s": silent}
                self.count += 1
                self.total_s += silent
                if self.longest is None or silent > self.longest["silent_s"]:
                    self.longest = gap
                if len(self.gaps) < LISTED:
                    self.gaps.append(gap)
        self.last = (t, t_log)

    def armed(self, t: float, on: bool) -> None:
        self.known = True
        open_ = bool(self.spans) and self.spans[-1][1] is None
        if on and not open_:
            self.armings += 1
            if len(self.spans) >= LISTED:  # bounded: the last one replaces the one before it
                self.spans.pop()
            self.spans.append([t, None])
        elif not on and open_:
            self.spans[-1][1] = t

    def result(self, log_end_t: float) -> dict:
        """The report's `flight` section: the gaps, the armed spans, the stream's and the log's end [s]."""
        return {"gap_limit_s": self.limit_s, "gaps": self.count, "gaps_s": self.total_s, "longest_gap": self.longest,
                "gap_list": self.gaps, "armed_known": self.known, "armed_spans": self.spans,
                "armed_count": self.armings, "stream_end_t": None if self.last is None else self.last[0],
                "log_end_t": log_end_t}


def gaps_finding(flight: dict | None, what: str, silent: str) -> str | None:
    """The data-quality line of the log's telemetry gaps, or None. `what`: their name, saying whose recording;
    `silent`: what fell silent in the log (what the replay's daemon takes as the autopilot alive)."""
    if not flight or not flight.get("gaps"):
        return None
    lg = flight["longest_gap"]
    return (f"{what}: {flight['gaps']} ({silent} for more than {flight['gap_limit_s']:g} s; {flight['gaps_s']:.0f} s "
            f"in all), longest {lg['silent_s']:.1f} s at t = {lg['t']:.1f} s: gaps in the recording, not failsafes of "
            "the vehicle or of the daemon; the replay's daemon had no fresh data there, so nothing is judged there")


def flight_end(flight: dict | None, daemon_end: dict | None) -> dict | None:
    """Where the flight ends, by the autopilot's arming: the last disarm; armed to the last, the end of the autopilot's
    stream (or of the log); never armed, none. `daemon_end`: what the replay's daemon last stopped on, said beside it
    where it fell in the last armed span. Without arming in the log, `daemon_end` as it is. Pure."""
    if not flight or not flight.get("armed_known"):
        return daemon_end
    spans, end, stream, limit = flight["armed_spans"], flight["log_end_t"], flight["stream_end_t"], flight["gap_limit_s"]
    if not spans:
        return {"t": None, "why": "the log never shows the vehicle armed"}
    start, stop = spans[-1]
    n = flight["armed_count"]
    notes = [f"armed {n}× in the log, the last from t = {start:.1f} s" if n > 1 else f"armed from t = {start:.1f} s"]
    cut = stream is not None and end - stream > limit  # the log runs on without the autopilot
    if stop is not None:
        out = {"t": stop, "why": "disarmed"}
    elif cut:
        out = {"t": stream, "why": "still armed where the autopilot's stream ends: the flight's end is not in the log"}
    else:
        out = {"t": end, "why": "still armed at the log's end: the log ends before the flight does"}
    if cut:
        notes.append(f"the autopilot's stream ends at t = {stream:.1f} s and the log runs on to t = {end:.1f} s "
                     f"({end - stream:.0f} s) without it")
    if daemon_end and daemon_end.get("t") is not None and start <= daemon_end["t"] <= out["t"]:
        notes.append(f"the replay's daemon last stopped on {daemon_end['why']} at t = {daemon_end['t']:.1f} s")
    out["note"] = "; ".join(notes)
    return out


def off_path_sensors(what: str, orientations) -> list[dict]:
    """The range sensors of a log's topic or message `what` that look off the horizontal plane, by orientation
    (`orientations`: MAV_SENSOR_ORIENTATION of each sample): {what, facing, samples}."""
    counts: dict[int, int] = {}
    for o in orientations:
        if int(o) >= HORIZONTAL:
            counts[int(o)] = counts.get(int(o), 0) + 1
    return [{"what": what, "facing": facing(o), "samples": n} for o, n in sorted(counts.items())]


def not_forward_lines(sensors: list[dict]) -> list[str]:
    """One line per range sensor the log carries that does not look along the path (`sensors`: {what, facing,
    samples}; `facing` from `facing`, or what is known of it): named, and said not to be an obstacle sensor."""
    out = []
    for s in sensors:
        f = s["facing"]
        kind = f"{f}ward rangefinder" if f in FACING.values() else "rangefinder"
        where = f"orientation {f}" if f in FACING.values() else f
        what = ("one of the configured obstacle sensors (give the flight's --config with it)"
                if f.startswith("facing") else "an obstacle sensor")
        out.append(f"  a {kind} ({s['what']}, {where}; {s['samples']} samples) is present; it is not {what}: its "
                   "readings are not taken as D_od")
    return out
