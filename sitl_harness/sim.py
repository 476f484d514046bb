"""One simulated vehicle in its world, on a simulated clock: the harness's own (truth) API.

`Sim(scenario, personality)` assembles the plant + cascade (`kernel.VehicleModel`), the autopilot
emulation with its personality, the world, the forward range sensor, wind, the collision monitor,
the fault timeline and the MAVLink endpoint. `sim.tick()` advances one navigation tick
(`1 / tick_hz`, default 10 ms: inbound bytes already delivered → autopilot → wind → physics at
`physics_hz` → collisions → sensor → telemetry); `sim.step(dt)` runs whole ticks.

Truth (true state, world, collisions) is for tests and summaries only: `sim.collisions`, `sim.revealed`,
`sim.truth()`. Anything acting as the companion computer must use MAVLink (`lockstep.LockstepLink`
or `serve.serve`).
"""

from __future__ import annotations

import math
from collections import deque


from contracts.vehicle import G, load_vehicle

from .ardupilot import ArduPilot
from .autopilot import Autopilot, MissionItem
from .kernel import VehicleModel
from .mavlink_endpoint import MavlinkEndpoint, mav
from .physics import X_R, euler_from_quat
from .px4 import Px4
from .scenario import Scenario, ScenarioError, load_scenario
from .sensor_models import make_sensor
from .wind import Wind
from .world import Box, Column, CollisionMonitor, World
from .world_build import built

PERSONALITIES = {"px4": Px4, "ardupilot": ArduPilot}
BATTERY_MAH = 5000.0


def make_personality(name: str):
    if name not in PERSONALITIES:
        raise ScenarioError(f"personality {name!r}: expected px4 or ardupilot")
    return PERSONALITIES[name]()


class Sim:
    def __init__(self, scenario: Scenario | str | None = None, personality: str = "px4", *,
                 vehicle=None, seed: int | None = None, tick_hz: float = 100.0,
                 signing_key: bytes | None = None, unix_epoch_s: float | None = None, log_dir=None,
                 actuator_delay_s: float | None = None):
        sc = scenario if isinstance(scenario, Scenario) else (
            load_scenario(scenario) if scenario is not None else Scenario())
        self.scenario = sc
        self.vehicle = vehicle if vehicle is not None else load_vehicle(sc.vehicle)
        self.seed = sc.seed if seed is None else seed
        v = self.vehicle
        self.tick_dt = 1.0 / tick_hz
        # the aircraft's command latency (the scenario's, or this keyword's): a truth property, not the file's
        delay = sc.actuator_delay_s if actuator_delay_s is None else actuator_delay_s
        self.model = VehicleModel(v, physics_hz=sc.physics_hz, yaw=math.radians(sc.start.yaw_deg),
                                  pos=(sc.start.x_m, sc.start.y_m, 0.0), actuator_delay_s=delay)
        self.n_phys = max(1, round(self.tick_dt / self.model.dt))
        self.autopilot = Autopilot(self.model, make_personality(personality),
                                   home=(sc.home.lat_deg, sc.home.lon_deg, sc.home.alt_m),
                                   cruise_speed=sc.route.cruise_speed_m_s)
        columns = [(Column(c.x_m, c.y_m, c.radius_m, c.height_m or math.inf, c.name, c.reflectivity),
                    c.appears_within_m) for c in sc.world.columns]
        # columns absent until the vehicle comes within their distance of them (`_reveal`)
        self._unrevealed = [(c, within) for c, within in columns if within is not None]
        self.revealed: list[tuple[float, Column]] = []  # (time, column) of each that appeared (truth)
        built_columns, polygons = built(sc.world)  # clusters, walls, corridors, polygons
        self.world = World(
            [c for c, within in columns if within is None] + built_columns,
            [Box(b.x_m, b.y_m, b.length_m, b.width_m, math.radians(b.yaw_deg), b.height_m or math.inf, b.name,
                 b.reflectivity) for b in sc.world.boxes], polygons)
        self.sensor = make_sensor(sc.sensor, self.seed)
        w = sc.wind
        self.wind = Wind(v.wind.mean_m_s if w.mean_m_s is None else w.mean_m_s, w.from_deg,
                         v.wind.gust_m_s if w.gust_m_s is None else w.gust_m_s, w.length_m, seed=self.seed)
        self.wind_now = self.wind.value()
        self.monitor = CollisionMonitor(self.world, v.r_body_m)
        self.time_s = 0.0
        self.reading = None
        self._frames: deque = deque()  # (time due, frame) — frames waiting out the sensor's latency
        self.sensor_seq = 0
        self._next_sensor = 0.0
        self._sensor_dropout_until = -1.0
        self.link_down_until = -1.0
        self.link_dropped = 0
        self.nav_fault_until = -1.0
        self.faults = sorted(sc.faults, key=lambda f: f.at_s)
        self._fault_idx = 0
        self.energy_j = 0.0
        self.endpoint = MavlinkEndpoint(self, sysid=1, signing_key=signing_key,
                                        **({} if unix_epoch_s is None else {"unix_epoch_s": unix_epoch_s}))
        for name, value in sc.params.items():
            self.set_param(name, value)
        if sc.route.mission:
            self._load_mission_file(sc.route.mission)
        elif sc.route.waypoints:
            self._load_route()
        if sc.start.alt_m > 0:
            self._start_airborne(sc.start.alt_m)
        self.flight_log = None  # the autopilot's own log (flightlog.py), when asked for
        if log_dir is not None:
            self.start_log(log_dir)

    # ------------------------------------------------------------------ the autopilot's own flight log
    def start_log(self, where):
        """Record the autopilot's own log: a ULog (PX4) or DataFlash `.bin` (ArduPilot) in directory `where`
        (`flight-NNN.ulg`/`.bin`) or at file `where`. Returns its path; `close_log()` finishes it."""
        from .flightlog import start_log

        self.close_log()
        self.flight_log = start_log(self, where)
        return self.flight_log.path

    def close_log(self):
        """Finish the flight log (if any); returns its path."""
        fl, self.flight_log = self.flight_log, None
        if fl is None:
            return None
        fl.close()
        return fl.path

    # ------------------------------------------------------------------ configuration
    def set_param(self, name: str, value: float) -> None:
        """Set an autopilot parameter by its personality's name (wire units)."""
        ap = self.autopilot
        spec = next((p for p in ap.pers.params if p.name == name), None)
        if spec is None:
            raise ScenarioError(f"params.{name}: not a {ap.pers.name} parameter of this SITL")
        if spec.field == "hover_thrust":
            ap.set_hover_thrust(value * spec.scale)
        setattr(ap.settings, spec.field, value * spec.scale)
        if spec.field == "cruise_default":
            ap.cruise = ap.settings.cruise_default
        ap.apply_limits()

    def _start_airborne(self, alt: float) -> None:
        m, ap, v = self.model, self.autopilot, self.vehicle
        m.x[2] = -alt
        m.x[X_R:X_R + 4] = math.sqrt(v.mass_kg * G / (4 * m.thrust_ratio * v.rotor.k_thrust))
        m.fifo[:] = m.x[X_R]  # the delayed commands in flight: the hover command
        ap.set_hover_thrust(v.mass_kg * G / (m.thrust_ratio * v.t_nom_n))
        m.resting = False
        ap.armed = True
        ap.ever_airborne = True
        ap.landed_since = None
        ap.set_mode(ap.pers.airborne_start_mode)
        ap.traj.reset(m.pos, (0.0, 0.0, 0.0))

    def _load_route(self) -> None:
        ap = self.autopilot
        r = self.scenario.route
        items = []
        if ap.pers.mission_skips_home:
            lat, lon, alt = ap.home_geo
            items.append(MissionItem(0, mav.MAV_FRAME_GLOBAL, mav.MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0), lat, lon, alt))
        for x, y in r.waypoints:
            lat, lon, _ = ap.geo_from_local((x, y, 0.0))
            items.append(MissionItem(len(items), mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_NAV_WAYPOINT,
                                     (0.0, 0.0, 0.0, math.nan), lat, lon, r.altitude_m))
        ap.load_mission(items)

    def _load_mission_file(self, path: str) -> None:
        """A .plan or .waypoints file (contracts/missionfile.py) as the autopilot's mission. A `.waypoints`
        item 0 is home: kept where the personality's mission starts with home (ArduPilot), else dropped;
        a `.plan` has none: home is put first for ArduPilot, as `_load_route` does."""
        from contracts.missionfile import read_mission

        ap = self.autopilot
        mp = read_mission(path)
        lat, lon, alt = ap.home_geo
        items = [MissionItem(0, mav.MAV_FRAME_GLOBAL, mav.MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0), lat, lon, alt)] \
            if ap.pers.mission_skips_home else []
        for it in mp.items:
            items.append(MissionItem(len(items), it.frame, it.command, it.params, it.x, it.y, it.z))
        ap.load_mission(items)

    # ------------------------------------------------------------------ I/O hooks (bytes only)
    def deliver(self, datagram: bytes) -> list:
        """Inbound MAVLink datagram from a client (dropped while the link is down); returns its good
        messages (`MavlinkEndpoint.receive`)."""
        if self.time_s < self.link_down_until:
            self.link_dropped += 1
            return []
        return self.endpoint.receive(datagram)

    def take_output(self) -> list[bytes]:
        """Outbound MAVLink packets since the last call (discarded while the link is down)."""
        out = self.endpoint.take_output()
        if self.time_s < self.link_down_until:
            self.link_dropped += len(out)
            return []
        return out

    # ------------------------------------------------------------------ time
    def step(self, dt: float) -> None:
        end = self.time_s + dt - 1e-9
        while self.time_s < end:
            self.tick()

    def tick(self) -> None:
        t = self.time_s
        self._apply_faults(t)
        ap = self.autopilot
        ap.prearm_ok = not self.nav_fault
        ap.update(t, self.tick_dt)
        self.wind_now = self.wind.step(self.tick_dt)
        self.model.set_wind(self.wind_now)
        self.model.step(self.n_phys)
        self.time_s = t = t + self.tick_dt
        self._battery_update()
        if self._unrevealed:
            self._reveal()
        hit = self.monitor.update(t, self.model.pos)
        if hit is not None:
            p = hit.position
            ap.text(mav.MAV_SEVERITY_CRITICAL,
                    f"COLLISION {hit.obstacle_name} t={hit.time_s:.2f} at {p[0]:.1f},{p[1]:.1f},{p[2]:.1f}")
        if t + 1e-9 >= self._next_sensor:
            self._next_sensor += 1.0 / self.sensor.cfg.rate_hz
            self.sensor.dropout = t < self._sensor_dropout_until
            if not self.sensor.dropout:
                _, pitch, yaw = euler_from_quat(self.model.quat)
                frame = self.sensor.read(self.world, self.model.pos, yaw, pitch)
                if frame is not None:  # None: a frame the sensor does not send (sensor_models.SingleBeam)
                    self._frames.append((t + self.scenario.sensor.latency_s, frame))
        while self._frames and self._frames[0][0] <= t + 1e-9:  # sensor latency: seen then, sent now
            self.reading = self._frames.popleft()[1]
            self.sensor_seq += 1
        if self.flight_log is not None:
            self.flight_log.tick(self)
        self.endpoint.emit()

    def _reveal(self) -> None:
        """Put into the world each column whose surface the vehicle has come within `appears_within_m` of
        (horizontally)."""
        x, y = float(self.model.pos[0]), float(self.model.pos[1])
        near = [(c, w) for c, w in self._unrevealed if math.hypot(x - c.x, y - c.y) - c.radius <= w]
        for c, w in near:
            self.world.add(c)
            self.revealed.append((self.time_s, c))
        self._unrevealed = [u for u in self._unrevealed if u not in near]

    @property
    def nav_fault(self) -> bool:
        """The estimator reports a bad position/velocity solution (flags only; control uses truth)."""
        return self.time_s < self.nav_fault_until

    def _apply_faults(self, t: float) -> None:
        while self._fault_idx < len(self.faults) and self.faults[self._fault_idx].at_s <= t + 1e-9:
            f = self.faults[self._fault_idx]
            self._fault_idx += 1
            if f.thrust_ratio is not None:
                self.model.thrust_ratio = f.thrust_ratio
            elif f.fog is not None:
                if f.fog == "clear":
                    self.sensor.visibility_m = math.inf
                else:
                    self.sensor.visibility_m = f.fog.visibility_m
                    self.sensor.honest = f.fog.report == "honest"
            elif f.sensor_dropout_s is not None:
                self._sensor_dropout_until = t + f.sensor_dropout_s
            elif f.link_dropout_s is not None:
                self.link_down_until = t + f.link_dropout_s
            elif f.nav_fault_s is not None:
                self.nav_fault_until = t + f.nav_fault_s
            elif f.gust is not None:
                self.wind.add_gust(t, f.gust.duration_s, f.gust.peak_m_s, f.gust.from_deg)
            elif f.speed_commands_ignored:
                self.autopilot.speed_commands_ignored = True
                self.autopilot.cruise = self.autopilot.settings.cruise_default
            elif f.mode_delay is not None:
                self.autopilot.mode_delay_s, self.autopilot.mode_delay_only = f.mode_delay.delay_s, f.mode_delay.only
            elif f.offboard_refused is not None:
                self.autopilot.offboard_refused = f.offboard_refused

    # ------------------------------------------------------------------ battery (simple)
    def _battery_update(self) -> None:
        self.energy_j += self.battery_voltage() * self.battery_current() * self.tick_dt

    def battery_current(self) -> float:
        """Electrical current [A]: hover power ∝ thrust^1.5 (momentum theory), scaled to the airframe."""
        if not self.autopilot.armed:
            return 0.2
        t = self.vehicle.rotor.k_thrust * self.model.thrust_ratio * sum(float(w) * float(w) for w in self.model.rotor_speeds)
        r = self.vehicle.rotor.radius_m
        p_ideal = t ** 1.5 / math.sqrt(2 * 1.225 * 4 * math.pi * r * r)
        return 0.5 + p_ideal / 0.6 / max(self.battery_voltage(), 1.0)

    def consumed_mah(self) -> float:
        return self.energy_j / 14.8 / 3.6

    def battery_remaining(self) -> float:
        return max(0.0, 100.0 * (1.0 - self.consumed_mah() / BATTERY_MAH))

    def battery_voltage(self) -> float:
        return 14.0 + 2.8 * max(0.0, 1.0 - self.energy_j / 14.8 / 3.6 / BATTERY_MAH)

    # ------------------------------------------------------------------ truth (tests, summaries)
    @property
    def collisions(self):
        return self.monitor.collisions

    def truth(self) -> dict:
        m = self.model
        r, p, y = euler_from_quat(m.quat)
        return {"time_s": self.time_s, "pos": m.pos.copy(), "vel": m.vel.copy(), "roll": r, "pitch": p, "yaw": y,
                "thrust_ratio": m.thrust_ratio, "hover_thrust": m.hover_thrust,
                "min_clearance_m": self.monitor.min_clearance, "collisions": list(self.collisions)}
