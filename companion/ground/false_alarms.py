"""False alarms in clear air: lock-step flights of the real daemon against the real SITL (`flights.Rig`) through
cluttered worlds with no fog, every hold, "no safe speed" stop, violation and `no_avoiding_plan` the daemon logs
judged by a perfect observer that reads the SITL's truth (the world's true shapes, the vehicle's true pose).

The observer's questions, one per kind of event (`judge`):

- **hold for an obstacle** (the stop contract's Hold): was a true surface near the path (`corridor_m` either side of
  the direction of travel: D_od's band, which holds the swept corridor and its bins' slack; near rest anywhere
  ahead; where offboard swerves under the stop contract, that far either side of the path its plan flies, as its
  Hold judges) really within what the daemon's Hold judged (the supervisor's `ahead_m`, the nearest hit in the swept
  corridor, plus the sensor's noise)? A hold on a return with nothing there is unfounded;
- **navigation, "every obstacle within D_od is detected"** (D_od lowered): was D_od really shorter than stated?
  In clear air the range at which a surface of reflectivity ρ is detected is the lidar equation's
  (contracts/lidar.py `detection_range` with α = 0); a first detection (the daemon's late first detection, judged
  at its first sight, or the evidence's "a target first seen at r m") is founded only where the surface it hit
  could not have been detected at the range assumed. A first sight of a surface that was occluded, outside the
  field of view or whose bin was dropped, and a lowering for a medium (clear air has none), are unfounded;
- **environment, "no obstacle wider than R_obst"** and **"one obstacle in view at a time"**, the two faces of the
  avoid contract's one assumption that the beams cannot always tell apart (two poles in adjacent bins are one wide
  run; a wall whose middle bins returned nothing is two): is a surface wider than R_obst (a wall, a polygon, a box,
  or a column of radius above R_obst), or more than one obstacle, really within the stated range?
- **no safe speed**: founded unless it rests on a D_od lowered by an unfounded navigation violation;
- **no avoiding plan**, and offboard's **dead end** (at rest on a stop, no pass found; one said with the stop
  contract's Hold is that Hold's): was a true surface within the stated range in the corridor ahead (something to
  plan round)? If the corridor was truly clear, the planner stopped on a phantom;
- the rest (the controller's contour error, measured on the SITL's true position; command delivery; the daemon's
  own lateness; a silent sensor, which really sent nothing) are measurements of the truth itself: founded.

A flight's row (`fly`) says what it flew (mode, sensor model, world family, seed, seconds airborne), whether the
daemon guarded it at all (`guarded`; `refused`: the start-up check that kept it from engaging) and each event with
its verdict and the truth behind it. `benchmarks/false_alarms.py` flies many and sums them per
flight-hour.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from contracts.geometry import wrap_array
from contracts.lidar import RATED_REFLECTIVITY, detection_range

from companion.onboard.ahead import TRAVEL_SPEED_M_S
from companion.onboard.contract_in_force import path_obstacle_m

from .flights import Rig, engage_and_fly, fly_mission
from .worlds import CLEAR as WORLDS
from .worlds import clear_world

MODES = ("governor", "offboard")
MODELS = ("sector", "depth_camera", "single_beam")
ALT_M = 2.0
CRUISE_M_S = 1.5  # the shipped clutter scenarios' cruise speed (the Mambo's)
R_OBST_M = 1.0
NOISE_SIGMAS = 3.0  # a return within this many σ of the sensor's noise of a true surface is that surface
TRUTH_RAYS = 721  # rays of the observer's fan over the half-plane ahead (0.25°)


def scenario_of(mode: str, model: str, family: str, seed: int, sensor: dict | None = None) -> dict:
    """The scenario of one flight; `sensor`: keys over the model's defaults (e.g. `spurious_rate`)."""
    world, route = clear_world(family, seed)
    base = {"model": model} if model != "sector" else {"fov_deg": 60, "max_range_m": 10.0, "rate_hz": 20}
    sensor = {**base, **(sensor or {})} if model != "sector" else base
    sim_seed = 1000 * seed + 10 * WORLDS.index(family) + MODELS.index(model)  # each cell its own sensor faults
    sc = {"name": f"clear_{family}", "vehicle": "mambo", "seed": sim_seed, "world": world, "sensor": sensor,
          "route": {"altitude_m": ALT_M, "cruise_speed_m_s": CRUISE_M_S, "waypoints": route}}
    if mode == "offboard":
        sc["start"] = {"alt_m": ALT_M}
        sc["params"] = {"COM_OBL_RC_ACT": 5}  # a companion-only aircraft holds when offboard is lost
    return sc


def config_of(mode: str, route: list, model: str = "sector") -> dict:
    """The daemon's config: the sector sensor read as its bins (OBSTACLE_DISTANCE, as the demo reads it), the
    other models as the rig takes them."""
    cfg = {"mode": mode, "contract": {"r_obst_m": R_OBST_M}}
    if model == "sector":
        cfg["sensors"] = [{"kind": "obstacle_distance", "h_fov_deg": 60}]
    if mode == "offboard":
        cfg["route"] = {"waypoints": route, "altitude_m": ALT_M}
    return cfg


# ----------------------------------------------------------------------------- the observer

@dataclass
class Truth:
    """What the perfect observer knows at one moment: the vehicle's true pose and the world's true surfaces."""

    x: float
    y: float
    alt: float
    yaw: float
    ground_m: float  # where the sensor's lowest ray straight ahead meets the ground (inf: not within range)
    course: float  # the direction of travel (the heading when at rest)
    rays: np.ndarray  # compass angles of the fan
    ranges: np.ndarray  # true range along each (inf: nothing within 30 m)
    owners: list = field(default_factory=list)  # the obstacle each ray hits (None: none)


class Observer:
    """Reads the SITL's truth once per daemon cycle (`sample`) and answers for events at those times."""

    def __init__(self, rig: Rig):
        self.rig = rig
        self.world = rig.sim.world
        self.samples: list[tuple[float, Truth]] = []
        # (t, the obstacle its Hold judged, d_od, stated, ground speed) the daemon judged
        self.seen: list[tuple[float, float, float, float, float]] = []
        self.paths: dict[float, tuple] = {}  # t → (pose, path): where the Hold judged the path its swerve flies
        self.late: list[tuple[float, float]] = []  # (t declared, t first seen) of the daemon's late first detections

    def daemon_saw(self, t: float) -> tuple[float, float, float, float]:
        """(the obstacle its Hold judged, d_od, stated, ground speed) of the daemon's cycle at `t` (the inputs its
        supervisor judged)."""
        past = [s for s in self.seen if s[0] <= t + 1e-9]
        return past[-1][1:] if past else (math.inf, math.nan, math.nan, math.nan)

    def watch(self) -> None:
        """Once a daemon cycle: the truth now (`sample`) and what the daemon's supervisor judged this cycle."""
        self.sample()
        daemon = self.rig.daemon
        i, d = getattr(daemon, "_last_in", None), getattr(daemon, "last", None)  # read only
        if i is not None and d is not None:
            ahead = daemon.cycle.sup.ahead_m(i, d.omega)
            self.seen.append((i.t, ahead, i.dod.d_od, i.dod.stated_m, i.ground_speed))
            if daemon.cycle.sup.swerves and i.path:
                self.paths[i.t] = (i.pose, i.path)
            if i.dod.late is not None:
                self.late.append((i.t, i.dod.late.t))

    def first_seen(self, t: float) -> float:
        """When the late first detection the daemon declared at `t` was first seen (declared once the following
        frames confirmed it); `t` itself where none was declared then."""
        return next((first for at, first in reversed(self.late) if abs(at - t) <= 1e-6), t)

    def airborne_s(self, until: float = math.inf) -> float:
        """The seconds sampled airborne (above 0.5 m) up to `until`."""
        return sum(1 for t, tr in self.samples if tr.alt > 0.5 and t <= until) / self.rig.cfg.loop_hz

    def sample(self) -> None:
        t = self.rig.sim.truth()
        x, y = float(t["pos"][0]), float(t["pos"][1])
        vx, vy = float(t["vel"][0]), float(t["vel"][1])
        course = math.atan2(vy, vx) if math.hypot(vx, vy) > 0.2 else float(t["yaw"])
        rays = course + np.linspace(-math.pi / 2, math.pi / 2, TRUTH_RAYS)
        ranges = self.world.ray_cast(x, y, ALT_M, rays, 30.0)
        sensor = self.rig.sim.sensor
        alt = -float(t["pos"][2])
        ground = float(sensor.ground_ranges(np.zeros(1), alt, float(t["pitch"]))[0]) \
            if hasattr(sensor, "ground_ranges") else math.inf
        self.samples.append((self.rig.sim.time_s, Truth(x, y, alt, float(t["yaw"]), ground, course, rays, ranges)))

    def at(self, t: float) -> Truth:
        k = min(range(len(self.samples)), key=lambda j: abs(self.samples[j][0] - t))
        return self.samples[k][1]

    def path_judged(self, t: float) -> tuple | None:
        """(pose, path) where the daemon's Hold at `t` judged the path its swerve flies (None: the line of travel)."""
        past = [s[0] for s in self.seen if s[0] <= t + 1e-9]
        return self.paths.get(past[-1]) if past else None

    def nearest_on_path(self, tr: Truth, half_width: float, pose, path) -> float:
        """The distance along `path` (from `pose`) to where it first comes within `half_width` of a true surface:
        the daemon's own measure (`path_obstacle_m`) on the truth's rays."""
        ok = np.isfinite(tr.ranges)
        hits = [(float(a) - pose[2], float(r), 1e-4, True) for a, r in zip(tr.rays[ok], tr.ranges[ok])]
        return path_obstacle_m(hits, (tr.x, tr.y, pose[2]), path, half_width)

    def nearest_in_corridor(self, tr: Truth, half_width: float, course: float | None = None) -> float:
        """The nearest true surface ahead whose offset from the line of travel is at most `half_width`."""
        c = tr.course if course is None else course
        ok = np.isfinite(tr.ranges)
        r, a = tr.ranges[ok], tr.rays[ok] - c
        lateral, along = np.abs(r * np.sin(a)), r * np.cos(a)
        inside = (lateral <= half_width) & (along > 0.0)
        return float(r[inside].min()) if inside.any() else math.inf

    def reflectivity_near(self, tr: Truth, r_seen: float, tol: float) -> float | None:
        """The reflectivity of the true surface in view at a range within `tol` of `r_seen` (None: nothing there)."""
        ok = np.isfinite(tr.ranges) & (np.abs(tr.ranges - r_seen) <= tol)
        if not ok.any():
            return None
        a = tr.rays[ok][np.argmin(np.abs(tr.ranges[ok] - r_seen))]
        _, rho = self.world.ray_cast(tr.x, tr.y, ALT_M, np.array([a]), 30.0, reflectivity=True)
        return float(rho[0]) if rho[0] > 0 else None

    def sensor_before(self, t: float, tr: Truth, r_seen: float, assumed: float) -> str | None:
        """What the SITL's own sensor, noise-free, had in its frame one period before where the surface first seen
        now at `r_seen` is: "out of view", "something" within `assumed` (it, or what hid it), or "missed" — its rays,
        as its model casts them, stepped over it (a thin column between them). None: no true surface at `r_seen`."""
        ok = np.isfinite(tr.ranges)
        if not ok.any():
            return None
        k = int(np.argmin(np.where(ok, np.abs(tr.ranges - r_seen), np.inf)))
        a = float(tr.rays[k])  # the target's compass bearing now
        if abs(tr.ranges[k] - r_seen) > 1.0:
            return None
        target = (tr.x + tr.ranges[k] * math.cos(a), tr.y + tr.ranges[k] * math.sin(a))
        sensor = self.rig.sim.sensor
        before = self.at(t - 1.0 / sensor.cfg.rate_hz)
        pos = np.array([before.x, before.y, -before.alt])
        true = sensor.true_ranges(self.world, pos, before.yaw)
        bearing = math.atan2(target[1] - before.y, target[0] - before.x) - before.yaw
        off = np.abs(wrap_array(sensor.offsets - bearing))
        j = int(np.argmin(off))
        if off[j] > sensor.inc / 2 + 1e-9:
            return "out of view"
        return "something" if true[j] <= assumed else "missed"

    def several_in_view(self, tr: Truth, reach: float) -> bool:
        """Two or more obstacles whose surfaces are within `reach`."""
        return int(np.count_nonzero(self.world.distances(tr.x, tr.y) <= reach)) > 1

    def wide_in_view(self, tr: Truth, reach: float, r_obst: float) -> bool:
        """A surface wider than R_obst within `reach` ahead: a wall, polygon or box, or a column of radius > R_obst."""
        near = self.world.distances(tr.x, tr.y) <= reach
        return any(hit and (getattr(o, "radius", None) is None or o.radius > r_obst + 0.05)
                   for hit, o in zip(near, self.world.obstacles))


# ----------------------------------------------------------------------------- flights and verdicts

def noise_m(rig: Rig, r: float) -> float:
    """The sensor's 1 σ range noise at `r`, plus its centimetre quantisation."""
    c = rig.sim.sensor.cfg
    return max(c.noise_sd_m, c.noise_rel * r, getattr(c, "noise_quad_per_m", 0.0) * r * r) + 0.01


def _state_at(rig: Rig, t: float) -> dict:
    past = [s for s in rig.log.states if s["t"] <= t + 1e-9]
    return past[-1] if past else rig.log.states[0]


def likely_cause(rig: Rig, tr: Truth, seen: float | None) -> str:
    """What an unfounded reaction most likely rests on: the ground in the sensor's view (pitched, or low), a
    spurious close return (no surface within the noise of what was seen, nearer than the model's spurious
    returns reach), or something else."""
    c = rig.sim.sensor.cfg
    if tr.ground_m <= c.max_range_m:
        return "ground in view"
    if seen is not None and seen <= getattr(c, "spurious_max_m", 0.0) + 0.05 and getattr(c, "spurious_rate", 0.0) > 0:
        return "spurious close return"
    return "other"


def judge(rig: Rig, obs: Observer, e: dict, nav_verdicts: list) -> tuple[str, bool, dict]:
    """(kind, founded, why) of one event the daemon logged (module docstring)."""
    t = e["t"]
    tr = obs.at(t)
    st = _state_at(rig, t)
    name = e["event"]
    r_body = rig.daemon.cycle.sup.table.vehicle.r_body_m
    e_tr = st.get("e_tr") or 0.0
    r_obst = rig.cfg.contract.r_obst_m
    corridor = 2 * r_obst + e_tr + r_body
    stated = rig.sim.sensor.cfg.max_range_m
    if name == "hold_trigger" and e["cause"] == OBSTACLE:
        seen, _, _, speed = obs.daemon_saw(t)
        judged = obs.path_judged(t)
        if judged is not None:  # offboard's swerve under the stop contract: the Hold judged the path it flies
            true = obs.nearest_on_path(tr, corridor, *judged)
        else:  # near rest the Hold judges anything in view (companion/onboard/ahead.py): the truth anywhere ahead
            true = obs.nearest_in_corridor(tr, corridor if speed > TRAVEL_SPEED_M_S else math.inf)
        tol = NOISE_SIGMAS * noise_m(rig, min(seen, stated)) + 0.1
        # the depth camera reports depth along its axis, less than the range off it: what it saw is no farther
        # than the true range, so a surface truly within seen/cos(half the field of view) is what it saw
        half = 0.5 * rig.sim.sensor.n_used * rig.sim.sensor.inc if hasattr(rig.sim.sensor, "n_used") else 0.0
        reach = (seen + tol) / max(math.cos(half), 0.5) if rig.sim.sensor.cfg.reports == "z_depth" else seen + tol
        return "hold (obstacle)", true <= reach, {"obstacle_seen_m": seen, "obstacle_true_m": true}
    if name == "hold_trigger":
        return f"hold ({e['cause']})", True, {}
    if name == "failsafe" and e.get("cause") == "no safe speed":
        lowered = (st.get("d_od") or 0.0) < (st.get("d_od_stated") or 0.0) - 0.01
        bad = [v for v in nav_verdicts if v[0] <= t + 1e-9 and not v[1]]
        founded = not (e.get("input") == "d_od" and lowered and bad)
        return "no safe speed", founded, {"input": e.get("input"), "why": e.get("why")}
    if name == "failsafe":
        return f"failsafe ({e.get('cause')})", True, {}
    if name in ("no_avoiding_plan", "dead_end"):  # (a dead end said with the Hold's trigger is that Hold's)
        ahead = obs.nearest_in_corridor(tr, corridor)
        return name.replace("_", " "), ahead <= stated, {"obstacle_true_m": ahead, "notes": e.get("notes")}
    if name == "violation_start":
        sub = e["subsystem"]
        g = e.get("guarantee", "")
        if sub == "navigation" and g == "every obstacle within D_od is detected":
            action = e.get("action", "")
            first = FIRST_SEEN.search(action)
            if ":" in action and first is None:  # lowered by the evidence of a medium (or a disagreement): clear air
                return "violation (navigation)", False, {"action": action}  # has no medium
            # a late first detection, the estimator's or the evidence's ("a target first seen at r m"): the truth
            seen, assumed = float(first.group(1) if first else e["observed"]), float(e["assumed"])
            t = obs.first_seen(t)  # the truth when it was first seen
            tr = obs.at(t)
            tol = NOISE_SIGMAS * noise_m(rig, seen) + 0.1
            rho = obs.reflectivity_near(tr, seen, tol + 0.5)
            if rho is None:
                return "violation (navigation)", False, {"observed": seen, "assumed": assumed, "surface": None}
            c = rig.sim.sensor.cfg
            reach = detection_range(0.0, rho, c.max_range_m, getattr(c, "rated_reflectivity", RATED_REFLECTIVITY))
            # a surface its rays stepped over a frame before (a thin column between them) was truly not seen
            stepped_over = obs.sensor_before(t, tr, seen, assumed) == "missed"
            return "violation (navigation)", reach < assumed - tol or stepped_over, {
                "observed": seen, "assumed": assumed, "reflectivity": rho, "true_reach_m": reach,
                "rays_missed_it": stepped_over}
        if sub == "environment":  # the avoid contract's "one obstacle no wider than R_obst at a time", either face:
            # one wide thing seen as several runs of bins, or several seen as one wide run, breaks it as truly
            founded = obs.several_in_view(tr, stated) or obs.wide_in_view(tr, stated, r_obst)
            return "violation (environment)", founded, {"observed": e.get("observed"), "guarantee": g}
        return f"violation ({sub})", True, {"guarantee": g}
    raise ValueError(name)


FIRST_SEEN = re.compile(r"a target first seen at ([0-9.]+) m")  # the evidence's first detection (detection_range.py)
OBSTACLE = "obstacle inside the stop distance"  # the stop contract's hold (companion/onboard/states.py Cause)
AFTER_STOP_S = 3.0  # a flight ends this long after the daemon's first Hold or braking stop (the pilot takes over)
JUDGED = ("hold_trigger", "failsafe", "no_avoiding_plan", "dead_end", "violation_start")
STOPS = ("hold_trigger", "failsafe", "no_avoiding_plan", "dead_end")


def fly(mode: str, model: str, family: str, seed: int, seconds: float | None = None, rig_kw: dict | None = None,
        sensor: dict | None = None, world: dict | None = None) -> dict:
    """One clear-air flight and its judged events (module docstring); `sensor`: as `scenario_of`'s; `world`: the
    scenario's world instead of the family's (its route kept)."""
    sc = scenario_of(mode, model, family, seed, sensor)
    if world is not None:
        sc["world"] = world
    route = sc["route"]["waypoints"]
    length = sum(math.dist(a, b) for a, b in pairwise(route))
    seconds = seconds if seconds is not None else length / CRUISE_M_S + 15.0
    rig = Rig(sc, "px4", config=config_of(mode, route, model), **(rig_kw or {}))
    obs = Observer(rig)
    end = route[-1]

    stopped: list[float] = []

    def watch(r) -> bool:
        obs.watch()
        tr = obs.samples[-1][1]
        if not stopped and any(e["event"] in STOPS for e in r.log.events[-8:]):
            stopped.append(r.sim.time_s)
        return (math.hypot(tr.x - end[0], tr.y - end[1]) < 1.0 and r.sim.time_s > 5.0) or \
            (bool(stopped) and r.sim.time_s >= stopped[0] + AFTER_STOP_S)

    (engage_and_fly if mode == "offboard" else fly_mission)(rig, seconds, until=watch)
    cut = stopped[0] if stopped else math.inf  # flight-hours count to the first stop: after it the pilot flies
    events = judged_events(rig, obs)
    tr = obs.samples[-1][1]
    refused = next((e["reason"] for e in rig.log.named("startup_check") if not e["ok"]), None)
    return {"mode": mode, "model": model, "world": family, "seed": seed, "flown_s": round(obs.airborne_s(cut), 2),
            "arrived": math.hypot(tr.x - end[0], tr.y - end[1]) < 1.0, "stopped_s": stopped[0] if stopped else None,
            "collisions": len(rig.truth["collisions"]), "guarded": guarded(rig), "refused": refused, "events": events}


def guarded(rig: Rig) -> bool:
    """Whether the daemon guarded the flight at all: its supervisor left standby (a limit in force, a Hold, its own
    offboard flight). A daemon that refused to engage (its start-up checks failed: the sensors cannot cover the swept
    corridor) watches a flight it does not guard; its events are still logged and judged."""
    return any(s["state"] != "standby" for s in rig.log.states)


def judged_events(rig: Rig, obs: Observer) -> list[dict]:
    """Every event of `JUDGED` the daemon logged, in time order, with its verdict (`judge`), the truth behind it and,
    when unfounded, its likely cause (one resting on an earlier unfounded lowering of D_od: that one's)."""
    events, nav = [], []
    held_at = {e["t"] for e in rig.log.events if e["event"] == "hold_trigger"}
    for e in sorted((e for e in rig.log.events if e["event"] in JUDGED and
                     not (e["event"] == "dead_end" and e["t"] in held_at)), key=lambda e: e["t"]):
        kind, founded, why = judge(rig, obs, e, nav)
        inherited = kind == "no safe speed" or "after a late first detection" in why.get("action", "")
        if not founded and inherited:  # it rests on an earlier unfounded lowering of D_od: that one's cause
            why["cause"] = next((c for _, ok, c in reversed(nav) if not ok), "other")
        elif not founded:
            seen = why.get("obstacle_seen_m", why.get("observed"))
            why["cause"] = likely_cause(rig, obs.at(e["t"]), seen if seen is not None else obs.daemon_saw(e["t"])[0])
        if kind == "violation (navigation)":
            nav.append((e["t"], founded, why.get("cause")))
        events.append({"t": round(e["t"], 2), "kind": kind, "founded": founded,
                       **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in why.items()}})
    return events
