"""Mission files: QGroundControl `.plan` (JSON) and the MAVLink `QGC WPL 110` text mission (`.waypoints`,
what MAVProxy and Mission Planner load). Pure format I/O, shared by the calibration plan writer
(`companion/ground/calibrate_plan.py`) and the SITL's mission loading (`sitl_harness/sim.py`).

`MissionPlan` holds home and the items in MAVLink terms (command, frame, param1–4, x = lat, y = lon,
z = alt); NaN params are written as `null` in a `.plan` (QGC's convention) and as `nan` in a `.waypoints`
(pymavlink `mavwp` reads both). A `.plan` has no home item in `mission.items` (QGC keeps it in
`plannedHomePosition`); a `.waypoints` has home as item 0 (Mission Planner's and ArduPilot's convention).
Extra information a ground station ignores (the calibration legs) goes into the `.plan`'s top-level
`contractGuard` record, and into `#` comment lines of a `.waypoints` (pymavlink `mavwp` skips them).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from .errors import ContractError

WPL_HEADER = "QGC WPL 110"
MAV_CMD_NAV_WAYPOINT = 16
MAV_FRAME_GLOBAL = 0
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3


@dataclass(frozen=True)
class Item:
    """One mission item (MAVLink MISSION_ITEM fields)."""

    command: int
    frame: int
    params: tuple[float, float, float, float]
    x: float  # latitude [deg] (or local x)
    y: float  # longitude [deg]
    z: float  # altitude [m] in the frame's sense


@dataclass
class MissionPlan:
    home: tuple[float, float, float]  # lat [deg], lon [deg], alt AMSL [m]
    items: list[Item] = field(default_factory=list)
    extra: dict = field(default_factory=dict)  # the `.plan`'s `contractGuard` record
    cruise_speed_m_s: float = 5.0


def _num(v):
    return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v


def _flt(v) -> float:
    return math.nan if v is None else float(v)


def plan_json(mp: MissionPlan) -> dict:
    """The QGroundControl `.plan` document (fileType Plan, mission version 2)."""
    items = [{"type": "SimpleItem", "autoContinue": True, "command": it.command, "doJumpId": i + 1,
              "frame": it.frame, "params": [_num(p) for p in (*it.params, it.x, it.y, it.z)]}
             for i, it in enumerate(mp.items)]
    return {
        "fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": mp.cruise_speed_m_s,
                    "hoverSpeed": mp.cruise_speed_m_s, "plannedHomePosition": list(mp.home), "items": items},
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
        "contractGuard": mp.extra,
    }


def wpl_text(mp: MissionPlan) -> str:
    """The `QGC WPL 110` text: item 0 is home, tab-separated
    `seq current frame command p1 p2 p3 p4 x y z autocontinue`."""
    lat, lon, alt = mp.home
    rows = [(MAV_FRAME_GLOBAL, MAV_CMD_NAV_WAYPOINT, (0.0, 0.0, 0.0, 0.0), lat, lon, alt)]
    rows += [(it.frame, it.command, it.params, it.x, it.y, it.z) for it in mp.items]
    out = [WPL_HEADER]
    for legs_line in json.dumps(mp.extra).splitlines() if mp.extra else []:
        out.append("# contractGuard " + legs_line)
    for seq, (frame, cmd, p, x, y, z) in enumerate(rows):
        vals = "\t".join(_g(v) for v in (*p, x, y, z))
        out.append(f"{seq}\t{1 if seq == 0 else 0}\t{frame}\t{cmd}\t{vals}\t1")
    return "\n".join(out) + "\n"


def _g(v: float) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.8f}".rstrip("0").rstrip(".") if v != int(v) else str(int(v))


def write_plan(path: str | Path, mp: MissionPlan) -> None:
    Path(path).write_text(json.dumps(plan_json(mp), indent=1) + "\n")


def write_waypoints(path: str | Path, mp: MissionPlan) -> None:
    Path(path).write_text(wpl_text(mp))


def read_mission(path: str | Path) -> MissionPlan:
    """A `.plan` or `.waypoints` file (told by its content), or one `ContractError` line."""
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise ContractError(f"mission {p}: cannot read ({getattr(err, 'strerror', None) or err})") from None
    if text.startswith(WPL_HEADER):
        return _read_wpl(p, text)
    try:
        doc = json.loads(text)
    except ValueError:
        raise ContractError(f"mission {p}: neither a QGroundControl .plan (JSON) nor a '{WPL_HEADER}' file") from None
    return _read_plan(p, doc)


def _read_plan(p: Path, doc) -> MissionPlan:
    try:
        if doc.get("fileType") != "Plan":
            raise ValueError("fileType is not Plan")
        m = doc["mission"]
        home = tuple(float(v) for v in m["plannedHomePosition"][:3])
        items = []
        for raw in m["items"]:
            if raw.get("type") != "SimpleItem":
                raise ValueError(f"item type {raw.get('type')!r} (only SimpleItem is read)")
            pr = [_flt(v) for v in raw["params"]]
            items.append(Item(int(raw["command"]), int(raw["frame"]), tuple(pr[:4]), pr[4], pr[5], pr[6]))
        return MissionPlan(home, items, dict(doc.get("contractGuard") or {}), float(m.get("cruiseSpeed") or 5.0))
    except (AttributeError, KeyError, TypeError, ValueError, IndexError) as err:
        raise ContractError(f"mission {p}: not a readable .plan ({err})") from None


def _read_wpl(p: Path, text: str) -> MissionPlan:
    rows, extra = [], []
    for n, line in enumerate(text.splitlines()[1:], start=2):
        if line.startswith("# contractGuard "):
            extra.append(line[len("# contractGuard "):])
            continue
        if not line.strip() or line.startswith("#"):
            continue
        f = line.split()
        if len(f) != 12:
            raise ContractError(f"mission {p}: line {n} has {len(f)} fields, a '{WPL_HEADER}' item has 12")
        try:
            rows.append((int(f[2]), int(f[3]), tuple(float(v) for v in f[4:8]), *(float(v) for v in f[8:11])))
        except ValueError:
            raise ContractError(f"mission {p}: line {n} is not numeric") from None
    if not rows:
        raise ContractError(f"mission {p}: no items (item 0, home, is required)")
    _, _, _, lat, lon, alt = rows[0]
    items = [Item(cmd, frame, prm, x, y, z) for frame, cmd, prm, x, y, z in rows[1:]]
    try:
        ext = json.loads("\n".join(extra)) if extra else {}
    except ValueError:
        ext = {}
    return MissionPlan((lat, lon, alt), items, ext)
