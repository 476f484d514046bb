"""The daemon's own protocols, decided as a sample arrives rather than once a cycle: its parameters (CG_*: a
refused engage said everywhere, each time it is asked), the start-up checks and autopilot restarts, the
autopilot's parameters, command acknowledgements, the mission download (route source: mission), and implausible
input (counted, logged at most once a second per kind). Each answer is an `Outbox` (companion/onboard/outbox.py) that the
daemon logs at once and sends with the next cycle's outbox; none of them commands a mode (that is the cycle's,
through the mode authority)."""

from __future__ import annotations

import math

from .mavlink_in import refusal_text
from .mavlink_out import ParamServer
from .mission import MissionSource
from .outbox import EMPTY, Outbox
from .samples import (
    AutopilotParam,
    AutopilotRestart,
    CommandAck,
    Implausible,
    MissionMessage,
    ParamRequest,
    SourceRefused,
)


def _outbox(acts) -> Outbox:
    """A mission download's actions (companion/onboard/mission.py `Actions`) as an outbox."""
    return Outbox(messages=tuple(acts.send), events=tuple(acts.events), texts=tuple(acts.texts))


class Protocols:
    def __init__(self, cfg, adapter, cycle, checks, out, counters, save_signing):
        """`out`: MAVLink-out (it encodes the parameters' answers and the stream requests); `save_signing()`:
        persist the signing timestamp."""
        self.cycle, self.checks, self.out, self.counters, self.save_signing = cycle, checks, out, counters, save_signing
        self.params = ParamServer(
            out, cfg.link.component_id,
            {"CG_ENGAGE": float(cfg.engage), "CG_MODE": float(ParamServer.MODES.index(cfg.mode)),
             "CG_R_OBST": cfg.contract.r_obst_m},
            ranges={"CG_ENGAGE": frozenset({0.0, 1.0}), "CG_R_OBST": tuple(cfg.contract.r_obst_range_m)},
            setters=tuple(cfg.link.gcs_system_ids), unsigned_refused=cfg.link.unsigned_param_refusal)
        self.mission: MissionSource | None = None  # route.source: mission — the route comes from the autopilot
        if cfg.daemon_mode.flies_route and cfg.route.source == "mission":
            lk = cfg.link
            self.mission = MissionSource(adapter.mission_item0_is_home, lk.target_system, lk.target_component,
                                         lk.target_system, lk.component_id, cfg.route.level_tolerance_m,
                                         corner_cut_m=cfg.route.corner_cut_m)
        self._implausible_seen: dict[str, tuple[float, int]] = {}  # kind → (last logged, count since)
        self._hold_seats()

    def take(self, s, t_now: float) -> Outbox:
        """One sample that is not the estimators' alone; `t_now`: the daemon's time (a PARAM_SET carries none)."""
        if isinstance(s, ParamRequest):
            return self._param_request(s.msg, t_now)
        if isinstance(s, AutopilotRestart):
            return self._restarted(s)
        if isinstance(s, CommandAck):
            self.cycle.command_ack(s.command, s.result)
            return Outbox(events=(("command_ack", {"command": s.command, "result": s.result}),))
        if isinstance(s, AutopilotParam):
            return self._autopilot_param(s)
        if isinstance(s, SourceRefused):
            if s.what in ("contested", "uncontested"):  # no engaging while two addresses claim one source
                self.checks.contest(s.ids, refusal_text(_fields(s)) if s.what == "contested" else None)
            return _source_refused(s)
        self.cycle.take(s)
        if isinstance(s, MissionMessage):
            return _outbox(self.mission.take(s.t, s.msg)) if self.mission is not None else EMPTY
        return self._implausible(s) if isinstance(s, Implausible) else EMPTY

    def _hold_seats(self) -> None:
        """Engaged (CG_ENGAGE 1), no seat on the link moves (a link without seats has no `hold_seats`)."""
        hold = getattr(self.out.conn, "hold_seats", None)
        if hold is not None:
            hold(self.params.values["CG_ENGAGE"] >= 0.5)

    def mission_request(self, t: float, why: str) -> Outbox:
        return _outbox(self.mission.request(t, why)) if self.mission is not None else EMPTY

    def _autopilot_param(self, s: AutopilotParam) -> Outbox:
        """The cruise speed, logged when it changes (a governor never sends more); the start-up checks' answers."""
        before = self.cycle.sensing.v_cruise
        self.cycle.take(s)
        now = self.cycle.sensing.v_cruise
        events = () if now == before or math.isnan(now) and math.isnan(before) else \
            (("cruise_speed", {"param": s.name, "v": now}),)
        box = Outbox(events=events)
        if self.checks.take(s.name, s.value):
            verdict = self.checks.finish(s.t)
            box = Outbox(events=box.events + verdict.events, texts=verdict.texts)
        return box

    def _implausible(self, s: Implausible) -> Outbox:
        """Counted always; logged at the first of a kind and then at most once a second per kind."""
        self.counters.implausible += 1
        last, count = self._implausible_seen.get(s.kind, (-math.inf, 0))
        if s.t - last < 1.0:
            self._implausible_seen[s.kind] = (last, count + 1)
            return EMPTY
        self._implausible_seen[s.kind] = (s.t, 0)
        return Outbox(events=(("implausible_input", {"message": s.kind, "why": s.why, "count": count + 1}),))

    def _restarted(self, s: AutopilotRestart) -> Outbox:
        """A restarted autopilot may come back with other parameters: the start-up checks run again."""
        if not self.checks.restarted(s.t):  # a boot clock that keeps going back is a fault
            self.cycle.take(Implausible(s.t, "time_boot_ms", "the autopilot's boot clock keeps going back"))
            return EMPTY
        return self.out.stream_requests(self.checks.wanted()).then(Outbox(
            events=(("autopilot_restart", {"boot_s_before": s.from_s, "boot_s_now": s.to_s}),),
            texts=((4, "CG: autopilot restarted: start-up checks again"),)))

    def _param_request(self, msg, t: float) -> Outbox:
        """PARAM_REQUEST_* and PARAM_SET of the daemon's parameters. CG_ENGAGE 1 while the start-up checks refuse
        is refused: the value stays 0 (echoed so), and the refusal is logged and said with its reason."""
        ps = self.params
        changed, answers = ps.handle(msg)
        events = [("param_refused", {"param": name, "value": value, "source": source, "why": why})
                  for name, value, source, why in ps.refused]
        ps.refused.clear()
        if changed is None:
            return Outbox(messages=answers, events=tuple(events))
        name, old, new = changed
        texts, box = [], EMPTY
        if name == "CG_ENGAGE" and new >= 0.5 and self.checks.ok is False:
            ps.values[name] = old
            events.append(("engage_refused", {"reason": self.checks.reason}))
            texts.append((3, f"CG: engage REFUSED: {self.checks.reason}"))
        else:
            if name == "CG_ENGAGE" and new >= 0.5 and old < 0.5:
                self.cycle.engage_requested()
                box = self.mission_request(t, "engage requested")  # the mission as it is now (it may be edited)
            events.append(("param_set", {"param": name, "old": old, "new": new}))
            self._hold_seats()
        self.save_signing()  # a set taken is never taken again, even after a kill -9
        return Outbox(messages=(ps.value(name),)).then(box).then(Outbox(events=tuple(events), texts=tuple(texts)))


def _fields(s: SourceRefused) -> dict:
    return dict(what=s.what, system=s.ids[0], component=s.ids[1], autopilot=s.autopilot, address=s.address,
                pinned=s.pinned, count=s.count, held=s.held)


def _source_refused(s: SourceRefused) -> Outbox:
    """Whom MAVLink-in or the link refused, in the event log; a pinned source's ids from another address (a second
    autopilot, a spoofed sensor), a contested seat, a signature that does not verify, or a move also to the ground
    stations (and the autopilot's seat, if held) and the console."""
    fields = _fields(s)
    severity = 2 if s.what in ("refused", "contested", "bad_signature") else 4
    texts = () if s.what == "unknown" else ((severity, "CG: " + refusal_text(fields)),)
    return Outbox(events=(("source_refused", fields),), texts=texts)
