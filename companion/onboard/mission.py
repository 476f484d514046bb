"""The offboard route from the autopilot's mission (MAVLink mission protocol, download side). Pure, no I/O.

- `MissionDownload`: a non-blocking client fed with received messages and a clock; it returns the
  messages to send: MISSION_REQUEST_LIST → MISSION_COUNT → MISSION_REQUEST_INT(seq) ↔ MISSION_ITEM_INT
  … → MISSION_ACK. Timeouts and retries as mavlink.io recommends (services/mission.md, "Timeouts and
  Retries": 1500 ms, 250 ms for items, at most 5 retries).
- `route_from_items`: the downloaded items → waypoints at one altitude, or one line saying why not.
- `MissionSource`: what the daemon holds: downloads when asked, keeps HOME_POSITION, converts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from contracts.geodesy import ne_from_geo

from .guidance import Route
from .link import mavlink

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
NAV_WAYPOINT, NAV_RTL, NAV_LAND, NAV_TAKEOFF = 16, 20, 21, 22
DO_JUMP, DO_CHANGE_SPEED = 177, 178
NAV_LAST = 95  # MAV_CMD_NAV_LAST: commands below it are navigation commands (common.xml)
GLOBAL_FRAMES = (0, 3, 5, 6, 10, 11)  # MAV_FRAME_GLOBAL(_INT), _RELATIVE_ALT(_INT), _TERRAIN_ALT(_INT)
LOCAL_FRAMES = (1, 4, 7, 8, 9, 12, 20, 21)  # int fields carry metres × 1e4 in MISSION_ITEM_INT
RELATIVE_ALT, AMSL = (3, 6), (0, 5)
MAX_RANGE_M = 10_000.0  # beyond this from home the tangent plane is no place for a route


def _name(enum: str, value: int) -> str:
    e = mavlink.enums.get(enum, {}).get(value)
    return e.name if e is not None else f"{enum} {value}"


def _cmd(command: int) -> str:
    return _name("MAV_CMD", command).removeprefix("MAV_CMD_") + f" ({command})"


@dataclass(frozen=True)
class Item:
    """One mission item, positions decoded: degrees for global frames, metres for local ones."""

    seq: int
    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: float
    y: float
    z: float


def decode_item(msg) -> Item:
    """MISSION_ITEM_INT (lat/lon × 1e7, local metres × 1e4) or MISSION_ITEM (floats as sent) → `Item`.
    A non-INT global frame in MISSION_ITEM_INT is decoded × 1e7 too ("in practice, many systems" do: mavlink.io)."""
    scale = 1.0
    if msg.get_type() == "MISSION_ITEM_INT":
        scale = 1e-7 if msg.frame in GLOBAL_FRAMES else 1e-4 if msg.frame in LOCAL_FRAMES else 1.0
    return Item(int(msg.seq), int(msg.frame), int(msg.command),
                (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4)),
                float(msg.x) * scale, float(msg.y) * scale, float(msg.z))


class MissionDownload:
    """Mission download client (mavlink.io services/mission.md, "Download a Mission from the Vehicle").

    `start(t)`, `take(t, msg)` and `poll(t)` return the messages to send. The caller passes only the
    autopilot's messages; those not addressed to us or not of mission_type MISSION are ignored. Items
    arrive in order: an item ahead of the one requested is dropped and the request resent, a repeat is
    counted and ignored, a malformed one (seq out of range, unknown frame) is counted and dropped. Each
    request is resent after its timeout up to `retries` times, then the download fails (`reason`).
    `state`: idle → count → items → done | failed."""

    def __init__(self, target_system: int, target_component: int, own_system: int, own_component: int,
                 timeout_s: float = 1.5, item_timeout_s: float = 0.25, retries: int = 5):
        self.target = (target_system, target_component)
        self.own = (own_system, own_component)
        self.timeout_s, self.item_timeout_s, self.retries = timeout_s, item_timeout_s, retries
        self.state = "idle"
        self.reason = ""
        self.count = 0
        self.items: list[Item] = []
        self.stats = {"resent": 0, "duplicates": 0, "out_of_order": 0, "malformed": 0}
        self._t_sent = 0.0
        self._tries = 0

    # ---- messages out
    def _request(self, t: float):
        self._t_sent = t
        if self.state == "count":
            return [mavlink.MAVLink_mission_request_list_message(*self.target, MISSION)]
        return [mavlink.MAVLink_mission_request_int_message(*self.target, len(self.items), MISSION)]

    def _ack(self, result: int):
        return [mavlink.MAVLink_mission_ack_message(*self.target, result, MISSION)]

    def _fail(self, reason: str, cancel: bool):
        self.state, self.reason = "failed", reason
        return self._ack(mavlink.MAV_MISSION_OPERATION_CANCELLED) if cancel else []

    def _resend(self, t: float, why: str):
        self._tries += 1
        if self._tries > self.retries:
            what = "MISSION_COUNT" if self.state == "count" else f"mission item {len(self.items)} of {self.count}"
            return self._fail(f"{what} {why} after {self.retries + 1} requests", cancel=self.state == "items")
        self.stats["resent"] += 1
        return self._request(t)

    # ---- the protocol
    def start(self, t: float):
        self.state, self.reason, self.count, self.items, self._tries = "count", "", 0, [], 0
        return self._request(t)

    def poll(self, t: float):
        if self.state in ("count", "items"):
            timeout = self.timeout_s if self.state == "count" else self.item_timeout_s
            if t - self._t_sent > timeout:
                return self._resend(t, "did not arrive")
        return []

    def take(self, t: float, msg):
        if self.state not in ("count", "items"):
            return []
        kind = msg.get_type()
        if kind not in ("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_ACK"):
            return []
        if getattr(msg, "target_system", 0) not in (self.own[0], 0) or \
                getattr(msg, "target_component", 0) not in (self.own[1], 0) or \
                getattr(msg, "mission_type", MISSION) != MISSION:
            return []
        if kind == "MISSION_ACK":  # the autopilot ended the operation (an error, or it cancelled)
            return self._fail(f"the autopilot ended the download: {_name('MAV_MISSION_RESULT', msg.type)}", False)
        if kind == "MISSION_COUNT":
            if self.state == "items" and msg.count == self.count:
                self.stats["duplicates"] += 1  # a late answer to a repeated MISSION_REQUEST_LIST
                return []
            self.state, self.count, self.items, self._tries = "items", int(msg.count), [], 0
            if self.count == 0:
                self.state = "done"
                return self._ack(mavlink.MAV_MISSION_ACCEPTED)
            return self._request(t)
        if self.state != "items":
            return []
        try:
            item = decode_item(msg)
        except (ValueError, TypeError, OverflowError, AttributeError):
            item = None
        if item is None or not 0 <= item.seq < self.count or item.frame not in mavlink.enums["MAV_FRAME"]:
            self.stats["malformed"] += 1
            return []
        if item.seq < len(self.items):
            self.stats["duplicates"] += 1
            return []
        if item.seq > len(self.items):
            self.stats["out_of_order"] += 1
            return self._resend(t, "was answered out of order")
        self.items.append(item)
        self._tries = 0
        if len(self.items) == self.count:
            self.state = "done"
            return self._ack(mavlink.MAV_MISSION_ACCEPTED)
        return self._request(t)


# ---------------------------------------------------------------------------------------------- conversion
class MissionRefused(ValueError):
    """The mission cannot be flown as an offboard route; the message is one line saying why."""


class HomeNeeded(MissionRefused):
    """Global-frame waypoints and no HOME_POSITION yet."""


@dataclass(frozen=True)
class Home:
    """HOME_POSITION: geodetic (degrees, AMSL metres) and where home is in the local NED frame."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    @classmethod
    def from_msg(cls, msg) -> "Home | None":
        h = cls(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3, msg.x, msg.y, msg.z)
        ok = all(math.isfinite(v) for v in (h.x, h.y, h.z)) and abs(h.lat_deg) <= 90 and abs(h.lon_deg) <= 180
        return h if ok else None


def item_position(it: Item, home: Home | None) -> tuple[float, float, float]:
    """A navigation item's position in local NED [m] (z down); MissionRefused if it has none."""
    where = f"mission item {it.seq}"
    if not all(math.isfinite(v) for v in (it.x, it.y, it.z)):
        raise MissionRefused(f"{where}: position or altitude is not a number")
    if it.frame == mavlink.MAV_FRAME_LOCAL_NED:
        return it.x, it.y, it.z
    if it.frame not in RELATIVE_ALT + AMSL:
        raise MissionRefused(f"{where}: frame {_name('MAV_FRAME', it.frame)} not supported "
                             "(LOCAL_NED or GLOBAL(_RELATIVE_ALT)(_INT))")
    if abs(it.x) > 90 or abs(it.y) > 180 or (it.x == 0 and it.y == 0):
        raise MissionRefused(f"{where}: no valid latitude/longitude")
    if home is None:
        raise HomeNeeded(f"{where}: global waypoints need HOME_POSITION, none received")
    north, east = ne_from_geo(it.x, it.y, home.lat_deg, home.lon_deg)
    if math.hypot(north, east) > MAX_RANGE_M:
        raise MissionRefused(f"{where}: {math.hypot(north, east) / 1000:.0f} km from home")
    up = it.z if it.frame in RELATIVE_ALT else it.z - home.alt_m  # above home
    return home.x + north, home.y + east, home.z - up


def home_request(target_system: int, target_component: int):
    """MAV_CMD_REQUEST_MESSAGE for HOME_POSITION (where global waypoints are placed from)."""
    return mavlink.MAVLink_command_long_message(target_system, target_component, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                float(mavlink.MAVLINK_MSG_ID_HOME_POSITION), 0, 0, 0, 0, 0, 0)


@dataclass
class MissionPath:
    waypoints: list[tuple[float, float]]  # local NED (x, y) [m]
    altitude_m: float  # above the local origin (z = −altitude)
    notes: list[str] = field(default_factory=list)  # items ignored, and why
    accept_m: list[float | None] = field(default_factory=list)  # per waypoint: its acceptance radius (param2), if set


def route_from_items(items: list[Item], *, skip_home: bool, home: Home | None,
                     level_tol_m: float = 0.5) -> MissionPath:
    """The offboard route of a mission: its NAV_WAYPOINT items, in order, at one altitude.

    ArduPilot's item 0 (home) is skipped with `skip_home`. A leading NAV_TAKEOFF and a trailing
    NAV_LAND / NAV_RETURN_TO_LAUNCH are ignored (offboard starts in the air and ends in Hold at the last
    waypoint); other non-navigation items (DO_CHANGE_SPEED, …) are ignored with a note. Refused, with
    one line: any other navigation command, DO_JUMP, an unsupported frame, altitudes that differ by
    more than `level_tol_m` (the contract assumes level flight), fewer than two waypoints. A waypoint's
    acceptance radius (param2 > 0) is kept: the route's corner there passes that close."""
    rest = items[1:] if skip_home and items else list(items)
    if not rest:
        raise MissionRefused("the autopilot holds no mission")
    notes: list[str] = []
    wps: list[tuple[float, float, float, float | None]] = []
    ending: Item | None = None  # a NAV_LAND / NAV_RETURN_TO_LAUNCH after the waypoints
    for it in rest:
        c = it.command
        if c == NAV_WAYPOINT:
            if ending is not None:
                raise MissionRefused(f"mission item {ending.seq}: {_cmd(ending.command)} before the last waypoint")
            x, y, z = item_position(it, home)
            r = it.params[1]
            wps.append((x, y, -z, r if math.isfinite(r) and r > 0 else None))
            if math.isfinite(it.params[0]) and it.params[0] > 0:
                notes.append(f"mission item {it.seq}: hold time {it.params[0]:g} s ignored (the route flies through)")
        elif c == NAV_TAKEOFF and not wps:
            notes.append(f"mission item {it.seq}: {_cmd(c)} ignored (offboard starts in the air)")
        elif c in (NAV_LAND, NAV_RTL) and wps:
            ending = ending or it
            notes.append(f"mission item {it.seq}: {_cmd(c)} ignored (the route ends in Hold at the last waypoint)")
        elif c < NAV_LAST:
            raise MissionRefused(f"mission item {it.seq}: {_cmd(c)} not supported (only NAV_WAYPOINT)")
        elif c == DO_JUMP:
            raise MissionRefused(f"mission item {it.seq}: {_cmd(c)} not supported (it repeats part of the route)")
        else:
            why = "the contract sets the speed" if c == DO_CHANGE_SPEED else "not a navigation command"
            notes.append(f"mission item {it.seq}: {_cmd(c)} ignored ({why})")
    if len(wps) < 2:
        raise MissionRefused(f"mission has {len(wps)} NAV_WAYPOINT item(s): a route needs at least 2")
    alts = [w[2] for w in wps]
    lo, hi = min(alts), max(alts)
    if hi - lo > level_tol_m:
        raise MissionRefused(f"waypoint altitudes {lo:.1f}-{hi:.1f} m differ by more than {level_tol_m:g} m "
                             "(level flight only)")
    alt = sum(alts) / len(alts)
    if alt <= 0:
        raise MissionRefused(f"waypoint altitude {alt:.1f} m is not above the local origin")
    pts = [(w[0], w[1]) for w in wps]
    if all(math.hypot(p[0] - pts[0][0], p[1] - pts[0][1]) < 0.01 for p in pts):
        raise MissionRefused("all waypoints are at one place: a route needs a path")
    return MissionPath(pts, alt, notes, [w[3] for w in wps])


# ---------------------------------------------------------------------------------------------- the daemon's view
@dataclass
class Actions:
    send: list = field(default_factory=list)  # MAVLink messages
    events: list[tuple[str, dict]] = field(default_factory=list)
    texts: list[tuple[int, str]] = field(default_factory=list)  # STATUSTEXT (severity, text)


class MissionSource:
    """The offboard route from the autopilot's mission. `request(t, why)` (on start-up and each engage
    request) starts a download and drops the route held; `take` / `poll` feed it. `route` is set only
    when a download completed and the mission converted; otherwise `status` and `reason` say why not.
    status: idle → downloading → (waiting_home →) ready | refused."""

    def __init__(self, skip_home: bool, target_system: int, target_component: int, own_system: int,
                 own_component: int, level_tol_m: float = 0.5, home_timeout_s: float = 5.0,
                 corner_cut_m: float = 1.0, **download):
        """`skip_home`: the autopilot's mission item 0 is its home position (the adapter says)."""
        if not isinstance(skip_home, bool):
            raise TypeError("skip_home must be a bool")
        self.skip_home = skip_home
        self.ids = (target_system, target_component, own_system, own_component)
        self.level_tol_m, self.home_timeout_s, self.download_kw = level_tol_m, home_timeout_s, download
        self.corner_cut_m = corner_cut_m  # where a waypoint sets no acceptance radius
        self.status, self.reason = "idle", ""
        self.route: Route | None = None
        self.path: MissionPath | None = None
        self.home: Home | None = None
        self.download: MissionDownload | None = None
        self._t_wait = 0.0
        self._t_home_asked = -math.inf

    def _ask_home(self, t: float, acts: Actions) -> None:
        self._t_home_asked = t
        acts.send.append(home_request(*self.ids[:2]))

    def request(self, t: float, why: str) -> Actions:
        acts = Actions()
        self.route, self.path, self.reason = None, None, ""
        self.status = "downloading"
        self.download = MissionDownload(*self.ids, **self.download_kw)
        acts.send += self.download.start(t)
        if self.home is None:
            self._ask_home(t, acts)
        acts.events.append(("mission", {"status": "downloading", "why": why}))
        acts.texts.append((6, f"CG: downloading the mission ({why})"))
        return acts

    def take(self, t: float, msg) -> Actions:
        acts = Actions()
        if msg.get_type() == "HOME_POSITION":
            self.home = Home.from_msg(msg) or self.home
            if self.status == "waiting_home" and self.home is not None:
                self._convert(t, acts)
            return acts
        if self.status == "downloading" and self.download is not None:
            acts.send += self.download.take(t, msg)
            self._after_download(t, acts)
        return acts

    def poll(self, t: float) -> Actions:
        acts = Actions()
        if self.status == "downloading" and self.download is not None:
            acts.send += self.download.poll(t)
            self._after_download(t, acts)
        elif self.status == "waiting_home":
            if t - self._t_wait > self.home_timeout_s:
                self._refuse(f"no HOME_POSITION in {self.home_timeout_s:g} s: cannot place global waypoints", acts)
            elif t - self._t_home_asked >= 1.0:
                self._ask_home(t, acts)
        return acts

    def _after_download(self, t: float, acts: Actions) -> None:
        d = self.download
        if d.state == "done":
            self._convert(t, acts)
        elif d.state == "failed":
            self._refuse(f"mission download failed: {d.reason}", acts)

    def _convert(self, t: float, acts: Actions) -> None:
        try:
            path = route_from_items(self.download.items, skip_home=self.skip_home, home=self.home,
                                    level_tol_m=self.level_tol_m)
        except HomeNeeded:
            if self.status != "waiting_home":
                self.status, self._t_wait = "waiting_home", t
                acts.events.append(("mission", {"status": "waiting_home"}))
            return
        except MissionRefused as err:
            self._refuse(str(err), acts)
            return
        cuts = [self.corner_cut_m if r is None else r for r in path.accept_m]
        self.path, self.route = path, Route(path.waypoints, path.altitude_m, cuts)
        self.status = "ready"
        acts.events.append(("mission", {"status": "ready", "waypoints": [list(p) for p in path.waypoints],
                                        "altitude_m": path.altitude_m, "items": len(self.download.items),
                                        "notes": path.notes, **self.download.stats}))
        acts.texts.append((6, f"CG: mission route: {len(path.waypoints)} waypoints at {path.altitude_m:.1f} m"))

    def _refuse(self, reason: str, acts: Actions) -> None:
        self.status, self.reason, self.route = "refused", reason, None
        stats = self.download.stats if self.download is not None else {}
        acts.events.append(("mission", {"status": "refused", "reason": reason, **stats}))
        acts.texts.append((3, f"CG: refusing to engage: {reason}"))
