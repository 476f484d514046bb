"""The calibration plan's hold legs, flown by the daemon in governor mode (config `calibration.legs`).

`contract-guard calibrate plan` marks the legs the daemon commands itself (companion/ground/calibrate_plan.py): at
`hold_before_m` before a hold leg's waypoint, while at the leg's speed, Hold (PX4 Hold / ArduPilot Brake); at
rest (ground speed < `REST_SPEED_M_S`) for `rest_s`; the mission again. `read_legs` reads them (from
`calibration-legs.json`, or the `.plan` / `.waypoints` that carries the same record), one line on any fault;
`CalibrationHolds` is the pure state machine the daemon steps once a cycle:

    waiting → commanded (Hold sent) → holding (Hold seen) → resuming (mission sent) → done
                                 ↘ abandoned: a safety hold or failsafe of the daemon's own (it wins), a mode
                                   change by someone else (the daemon never fights the pilot), a command not taken

Each leg once. It acts only while the supervisor is active (engaged, flying, no hold of its own) and the
autopilot flies its mission; the waypoint is placed in the local frame from HOME_POSITION (as the mission's own
waypoints are: companion/onboard/mission.py). `mission_speed(seq)`: the speed the mission's own DO_CHANGE_SPEED items set
at that item, which the governor sends in place of the autopilot's cruise parameter when its limit is higher (it
would otherwise speed the plan's slow legs up, or cap its fast ones at the cruise parameter): the legs file must
be the mission the autopilot flies (best: give the `.plan` / `.waypoints` itself).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from contracts.errors import ContractError
from contracts.geodesy import ne_from_geo
from contracts.missionfile import WPL_HEADER, read_mission

from .authority import HOLD, ModeRequest, Requester
from .mission import Home
from .states import State
from .turn import Part, Turn

REST_SPEED_M_S = 0.1  # at rest below this ground speed
REST_TIMEOUT_S = 20.0  # not at rest this long after Hold was seen: the mission is resumed anyway (said so)
MAX_LEGS_BYTES = 16 << 20
MAV_CMD_DO_CHANGE_SPEED = 178


@dataclass(frozen=True)
class HoldLeg:
    """One hold leg, its mission item in both numberings (the `.plan`'s, PX4's; the `.waypoints`', ArduPilot's)."""

    number: int  # its place among the file's hold legs, from 0
    seq_plan: int
    seq_waypoints: int
    speed_m_s: float
    hold_before_m: float
    rest_s: float
    lat_deg: float
    lon_deg: float


@dataclass(frozen=True)
class CalibrationLegs:
    path: str
    holds: tuple[HoldLeg, ...]
    speeds: tuple[tuple[int, int, float], ...]  # the mission's speed items: (seq_plan, seq_waypoints, speed)


def _bad(path, why: str) -> ContractError:
    return ContractError(f"calibration legs {path}: {why}")


def _number(leg: dict, key: str, path, where: str, lo: float = -math.inf, lo_open: bool = False) -> float:
    v = leg.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < lo or (lo_open and v == lo):
        raise _bad(path, f"{where}: {key} must be a finite number {'>' if lo_open else '>='} {lo:g} (got {v!r})")
    return float(v)


def _seq(leg: dict, key: str, path, where: str) -> int:
    v = leg.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise _bad(path, f"{where}: {key} must be a mission sequence number >= 0 (got {v!r})")
    return v


def read_legs(path: str | Path) -> CalibrationLegs:
    """The hold legs of `calibration-legs.json`, or of a `.plan` / `.waypoints` carrying the record (there the
    waypoint and the speed items come from the mission's own items). One `ContractError` line on any fault."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            data = fh.read(MAX_LEGS_BYTES + 1)
    except OSError as err:
        raise _bad(p, f"cannot read ({err.strerror or err})") from None
    if len(data) > MAX_LEGS_BYTES:
        raise _bad(p, f"larger than {MAX_LEGS_BYTES >> 20} MiB: not a legs file")
    try:
        text = data.decode()
        doc = None if text.startswith(WPL_HEADER) else json.loads(text)
    except (UnicodeDecodeError, ValueError):
        raise _bad(p, "neither calibration-legs.json (JSON) nor a .plan / .waypoints mission") from None
    items = None
    if doc is None or isinstance(doc, dict) and doc.get("fileType") == "Plan":
        mp = read_mission(p)  # its own one-line errors
        record, items = mp.extra, mp.items
    else:
        record = doc
    if not isinstance(record, dict) or not isinstance(record.get("legs"), list):
        raise _bad(p, "no calibration legs in it (a `legs` list: write it with `contract-guard calibrate plan`)")
    holds = []
    for k, leg in enumerate(record["legs"]):
        if not isinstance(leg, dict):
            raise _bad(p, f"legs[{k}] is not a record")
        if leg.get("kind") != "hold":
            continue
        where = f"legs[{k}] (hold)"
        sp, sw = _seq(leg, "mission_seq_plan", p, where), _seq(leg, "mission_seq_waypoints", p, where)
        if items is not None:  # the mission itself says where the waypoint is
            if sp >= len(items) or items[sp].command != 16:
                raise _bad(p, f"{where}: mission item {sp} is not a waypoint of this mission")
            lat, lon = items[sp].x, items[sp].y
        else:
            lat, lon = _number(leg, "lat_deg", p, where, -90.0), _number(leg, "lon_deg", p, where, -180.0)
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
            raise _bad(p, f"{where}: no valid waypoint latitude/longitude")
        holds.append(HoldLeg(len(holds), sp, sw, _number(leg, "speed_m_s", p, where, 0.0, True),
                             _number(leg, "hold_before_m", p, where, 0.0, True), _number(leg, "rest_s", p, where, 0.0),
                             lat, lon))
    if not holds:
        raise _bad(p, "no hold legs in it (nothing for the daemon to command)")
    if items is not None:
        speeds = tuple((k, k + 1, it.params[1]) for k, it in enumerate(items)
                       if it.command == MAV_CMD_DO_CHANGE_SPEED and math.isfinite(it.params[1]) and it.params[1] > 0)
    else:
        raw = record.get("mission_speeds", [])
        if not isinstance(raw, list) or not all(isinstance(r, dict) for r in raw):
            raise _bad(p, "mission_speeds must be a list of records")
        speeds = tuple((_seq(r, "mission_seq_plan", p, f"mission_speeds[{k}]"),
                        _seq(r, "mission_seq_waypoints", p, f"mission_speeds[{k}]"),
                        _number(r, "speed_m_s", p, f"mission_speeds[{k}]", 0.0, True)) for k, r in enumerate(raw))
    return CalibrationLegs(str(p), tuple(holds), tuple(sorted(speeds)))


@dataclass
class Actions:
    command: str | None = None  # HOLD | "mission": the mode to send now
    events: list[tuple[str, dict]] = field(default_factory=list)
    texts: list[tuple[int, str]] = field(default_factory=list)

    def part(self) -> Part:
        requests = () if self.command is None else (ModeRequest(self.command, Requester.CALIBRATION),)
        return Part(requests=requests, events=tuple(self.events), texts=tuple(self.texts))


class CalibrationHolds:
    """The hold legs of one flight (see the module). `item0_is_home`: this autopilot numbers the mission as the
    `.waypoints` does (ArduPilot), else as the `.plan` (PX4)."""

    def __init__(self, legs: CalibrationLegs, item0_is_home: bool):
        self.legs = legs
        self._seq_of = (lambda leg: leg.seq_waypoints) if item0_is_home else (lambda leg: leg.seq_plan)
        self.by_seq = {self._seq_of(leg): leg for leg in legs.holds}
        self._speed_seqs = [(sw if item0_is_home else sp, v) for sp, sw, v in legs.speeds]
        self.home: Home | None = None
        self.done: set[int] = set()  # leg numbers flown or abandoned
        self.leg: HoldLeg | None = None  # the leg in progress
        self.phase = "waiting"
        self._t = 0.0  # when the current phase began
        self._t_rest: float | None = None
        self._rested: float | None = None  # the time at rest before the mission was sent (None: never at rest)
        self._wp: dict[int, tuple[float, float]] = {}

    def take_home(self, home: Home | None) -> None:
        if home is not None and home != self.home:
            self.home, self._wp = home, {}

    def mission_speed(self, seq: int) -> float:
        """The speed the mission's own speed items set by item `seq` (NaN: none yet)."""
        v = math.nan
        for s, speed in self._speed_seqs:
            if s > seq:
                break
            v = speed
        return v

    def waypoint(self, leg: HoldLeg) -> tuple[float, float] | None:
        """The leg's waypoint in the local frame (north, east) [m]; None before HOME_POSITION."""
        h = self.home
        if h is None:
            return None
        if leg.number not in self._wp:
            n, e = ne_from_geo(leg.lat_deg, leg.lon_deg, h.lat_deg, h.lon_deg)
            self._wp[leg.number] = (h.x + n, h.y + e)
        return self._wp[leg.number]

    def _event(self, acts: Actions, status: str, **fields) -> None:
        leg = self.leg
        acts.events.append(("calibration_hold", {"status": status, "leg": leg.number, "seq": self._seq_of(leg),
                                                 "leg_speed_m_s": leg.speed_m_s, **fields}))

    def _end(self, acts: Actions, status: str, **fields) -> None:
        self._event(acts, status, **fields)
        if status == "abandoned":
            acts.texts.append((4, f"CG: calibration hold {self.leg.number + 1} abandoned: {fields.get('reason', '')}"))
        self.done.add(self.leg.number)
        self.leg, self.phase, self._t_rest = None, "waiting", None

    def step(self, turn: Turn) -> Part:
        """One cycle (the cycle's actor shape: companion/onboard/turn.py). A hold or failsafe of the supervisor's own
        this cycle wins (the leg is abandoned), as does standing by; someone else's mode change (the mode
        authority's judgement) abandons the leg, never fought; so does the leg's last mode command not delivered."""
        i, d, tel = turn.i, turn.d, turn.tel
        safety = (d.hold_causes[0] if d.hold_causes else "hold") if d.hold else \
            (f"state {d.state}" if d.state in (State.HOLDING, State.FAILSAFE) else None)
        active = d.state == State.ACTIVE
        acts = Actions()
        if self.leg is not None:
            if safety is not None or not active:
                self._end(acts, "abandoned", reason=f"the daemon's own {'hold' if safety else 'stand-by'}: "
                                                    f"{safety or 'not active'}")
            else:
                self._fly(turn, acts)
            return acts.part()
        leg = self.by_seq.get(tel.mission_seq)
        if leg is None or leg.number in self.done or not active or safety is not None or i.mode != "mission" \
                or not i.telemetry_ok:
            return acts.part()
        wp = self.waypoint(leg)
        if wp is None or not (math.isfinite(tel.x) and math.isfinite(tel.y)):
            return acts.part()
        dist = math.hypot(tel.x - wp[0], tel.y - wp[1])
        if dist <= leg.hold_before_m:
            self.leg, self.phase, self._t = leg, "commanded", turn.t
            acts.command = HOLD
            self._event(acts, "commanded", speed_m_s=i.ground_speed, distance_m=dist, hold_before_m=leg.hold_before_m)
        return acts.part()

    def _fly(self, turn: Turn, acts: Actions) -> None:
        t, mode, speed = turn.t, turn.i.mode, turn.i.ground_speed
        undelivered = turn.view.undelivered(Requester.CALIBRATION)
        if turn.i.taken_over:
            self._end(acts, "abandoned", reason=f"mode {mode} set by someone else")
            return
        if undelivered is not None and self.phase in ("commanded", "resuming"):
            what = "Hold" if self.phase == "commanded" else "the mission"
            self._end(acts, "abandoned", reason=f"the autopilot did not take {what}: {undelivered}")
            return
        if self.phase == "commanded":
            if mode != "hold":
                return
            self.phase, self._t = "holding", t  # (and at rest from now, if it is)
        if self.phase == "holding":
            if self._t_rest is None and speed < REST_SPEED_M_S:
                self._t_rest = t
            at_rest = self._t_rest is not None
            if at_rest and t - self._t_rest >= self.leg.rest_s or not at_rest and t - self._t > REST_TIMEOUT_S:
                self.phase, acts.command = "resuming", "mission"
                self._rested = (t - self._t_rest) if at_rest else None
                self._t = t
            return
        # resuming: the mission sent
        if mode == "mission":
            rested = self._rested
            self._end(acts, "resumed", rest_s=rested, at_rest=rested is not None,
                      **({} if rested is not None else {"reason": f"not at rest within {REST_TIMEOUT_S:g} s"}))
