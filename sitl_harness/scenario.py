"""Scenario files: world, start, route, wind, sensor, autopilot parameters and a fault timeline.

YAML validated with pydantic; an unknown key or a bad value ends with one `ScenarioError` line
naming the field. Lengths in metres, angles in degrees where the key says `_deg`, times in
seconds of simulated time. Example (see `sitl_harness/scenarios/*.yaml`)::

    name: column_ahead
    vehicle: mambo
    seed: 1
    actuator_delay_s: 0.0                 # extra rotor-command latency of the simulated aircraft
    start: {x_m: 0, y_m: 0, yaw_deg: 0}   # add alt_m: 2 to start armed and hovering
    world:
      columns: [{x_m: 12, y_m: 0, radius_m: 0.5, reflectivity: 0.1},   # a dark column (default 0.5)
                {x_m: 30, y_m: 0, radius_m: 0.3, appears_within_m: 1.8}]  # revealed 1.8 m ahead
      boxes: [{x_m: 20, y_m: 5, length_m: 2, width_m: 1, yaw_deg: 30}]
      walls: [{points: [[40, -10], [40, 10]], thickness_m: 0.3, gaps: [{at_m: 10, width_m: 1.2}]}]  # a doorway
      polygons: [{points: [[50, 2], [54, 2], [52, 6]]}]
      clusters: [{x_m: 60, y_m: 0, radius_m: 6, count: 12, column_radius_m: [0.1, 0.4], min_gap_m: 1.5, seed: 3}]
      corridors: [{points: [[70, 0], [90, 0], [90, 20]], width_m: 3, end_width_m: 2, closed_end: false}]
    sensor: {fov_deg: 60, max_range_m: 8}   # or {model: depth_camera} / {model: single_beam} (sensor_models.py)
    wind: {mean_m_s: 1.0, from_deg: 90, gust_m_s: 0.3}
    route: {altitude_m: 2, cruise_speed_m_s: 2, waypoints: [[0, 0], [25, 0]]}
    params: {MPC_XY_CRUISE: 2.0}
    faults:
      - {at_s: 10, thrust_ratio: 0.7}
      - {at_s: 12, fog: {visibility_m: 3, report: hidden}}
      - {at_s: 20, fog: clear}
      - {at_s: 15, sensor_dropout_s: 1.0}
      - {at_s: 25, link_dropout_s: 2.0}
      - {at_s: 28, nav_fault_s: 3.0}
      - {at_s: 30, gust: {peak_m_s: 3, duration_s: 2, from_deg: 0}}
      - {at_s: 5, speed_commands_ignored: true}
      - {at_s: 5, mode_delay: {delay_s: 0.3, only: hold}}
      - {at_s: 5, offboard_refused: silently}
    gcs:                                # the ground station's actions (the SITL ignores them)
      - {at_s: 45, param_set: {component: daemon, name: CG_R_OBST, value: 0.6}}
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from contracts.errors import ContractError
from contracts.lidar import RATED_REFLECTIVITY, REFERENCE_REFLECTIVITY
from contracts.yamlfile import load_model, model_from_dict, resolve_named

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Num = Annotated[float, Field(allow_inf_nan=False)]
SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"


class ScenarioError(ContractError):
    """A one-line, user-facing error about a scenario file, personality or address (a
    `ContractError`, so one `except ContractError` in the CLI covers vehicle files too)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Start(_Strict):
    """Where the vehicle starts; with `alt_m` > 0 it starts armed and hovering there (PX4 in Hold,
    ArduPilot in GUIDED), hover-thrust estimate converged — saves the take-off in tests."""

    x_m: Num = 0.0
    y_m: Num = 0.0
    yaw_deg: Num = 0.0
    alt_m: NonNeg = 0.0


class Home(_Strict):
    lat_deg: Annotated[float, Field(ge=-90, le=90)] = 47.397742  # PX4 SITL's default home
    lon_deg: Annotated[float, Field(ge=-180, le=180)] = 8.545594
    alt_m: Num = 488.0


Reflectivity = Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)]


class ColumnSpec(_Strict):
    x_m: Num
    y_m: Num
    radius_m: Pos
    height_m: Pos | None = None
    name: str = ""
    reflectivity: Reflectivity = REFERENCE_REFLECTIVITY  # diffuse, at the range sensor's wavelength (world.py)
    # absent until the vehicle comes within this distance of its surface (an obstacle revealed close by: a door
    # opening, something moved into the way); None: there from the start
    appears_within_m: Pos | None = None


class BoxSpec(_Strict):
    x_m: Num
    y_m: Num
    length_m: Pos
    width_m: Pos
    yaw_deg: Num = 0.0
    height_m: Pos | None = None
    name: str = ""
    reflectivity: Reflectivity = REFERENCE_REFLECTIVITY


XY = tuple[Num, Num]


class _Solid(_Strict):
    """What every wall-like obstacle has besides its shape."""

    height_m: Pos | None = None
    name: str = ""
    reflectivity: Reflectivity = REFERENCE_REFLECTIVITY


class GapSpec(_Strict):
    """A gap in a wall (a doorway): `width_m` of it taken out, centred `at_m` along the wall from its first point."""

    at_m: NonNeg
    width_m: Pos


class WallSpec(_Solid):
    """A wall along a polyline (two points: a straight wall), `thickness_m` thick, centred on its points."""

    points: Annotated[list[XY], Field(min_length=2, max_length=200)]
    thickness_m: Pos = 0.2
    gaps: list[GapSpec] = []

    @model_validator(mode="after")
    def _fits(self) -> "WallSpec":
        steps = [math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(self.points, self.points[1:])]
        if min(steps) <= 0.0:
            raise ValueError("two consecutive points are the same")
        for g in self.gaps:
            if g.at_m > sum(steps):
                raise ValueError(f"a gap at {g.at_m:g} m is beyond the wall's end ({sum(steps):.2f} m)")
        return self


class PolygonSpec(_Solid):
    """A solid polygon (`points` in order, not repeated at the end; no holes)."""

    points: Annotated[list[XY], Field(min_length=3, max_length=200)]

    @model_validator(mode="after")
    def _area(self) -> "PolygonSpec":
        p = self.points
        area = 0.5 * sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(p, [*p[1:], p[0]]))
        if abs(area) < 1e-6:
            raise ValueError("the polygon has no area")
        return self


class ClusterSpec(_Solid):
    """`count` columns placed from `seed` in the disc of `radius_m` about (x_m, y_m), radii uniform in
    `column_radius_m`, surfaces at least `min_gap_m` apart (sitl_harness/world_build.py)."""

    x_m: Num
    y_m: Num
    radius_m: Pos
    count: Annotated[int, Field(ge=1, le=500)]
    column_radius_m: tuple[Pos, Pos] = (0.2, 0.5)
    min_gap_m: NonNeg = 1.0
    seed: int = 0

    @model_validator(mode="after")
    def _placeable(self) -> "ClusterSpec":
        lo, hi = self.column_radius_m
        if lo > hi:
            raise ValueError("column_radius_m: the smallest radius is above the largest")
        from .world_build import cluster_columns

        cluster_columns(self.x_m, self.y_m, self.radius_m, self.count, lo, hi, self.min_gap_m, self.seed)
        return self


class CorridorSpec(_Solid):
    """Two walls either side of the centre polyline `points`, inner faces `width_m` apart at the start and
    `end_width_m` (default: the same) at the end; `closed_end`: a wall across the end (a dead end)."""

    points: Annotated[list[XY], Field(min_length=2, max_length=200)]
    width_m: Pos
    end_width_m: NonNeg | None = None
    thickness_m: Pos = 0.2
    closed_end: bool = False

    @model_validator(mode="after")
    def _steps(self) -> "CorridorSpec":
        if min(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(self.points, self.points[1:])) <= 0.0:
            raise ValueError("two consecutive points are the same")
        return self


class WorldSpec(_Strict):
    columns: list[ColumnSpec] = []
    boxes: list[BoxSpec] = []
    walls: list[WallSpec] = []
    polygons: list[PolygonSpec] = []
    clusters: list[ClusterSpec] = []
    corridors: list[CorridorSpec] = []

    def outline(self) -> dict:
        """Plain data of the world from above, for a plan view (`world_build.outline`)."""
        from .world_build import outline

        return outline(self)


# the keys only the body-fixed models have (their defaults: sensor_models.MODEL_DEFAULTS)
MODEL_KEYS = ("v_fov_deg", "mount_pitch_deg", "noise_quad_per_m", "dropout_rate", "dropped_as", "spurious_rate",
              "spurious_max_m", "ground_reflectivity", "rated_reflectivity", "reports")


class SensorSpec(_Strict):
    """The forward obstacle sensor. `model`: `sector` (the default: a levelled scanning sensor, sensors.py),
    `depth_camera` or `single_beam` (body-fixed, sensor_models.py, with their datasheet defaults for every key
    not given)."""

    model: Literal["sector", "depth_camera", "single_beam"] = "sector"
    fov_deg: Annotated[float, Field(gt=0, le=360)] = 60.0
    increment_deg: Annotated[float, Field(gt=0, le=90)] = 5.0
    min_range_m: NonNeg = 0.1
    max_range_m: Pos = 10.0
    noise_sd_m: NonNeg = 0.02
    noise_rel: NonNeg = 0.01
    rate_hz: Annotated[float, Field(gt=0, le=100)] = 20.0
    latency_s: Annotated[float, Field(ge=0, le=1)] = 0.0  # a frame is sent this long after it was seen
    # body-fixed models only
    v_fov_deg: Annotated[float, Field(gt=0, le=90)] = 1.2
    mount_pitch_deg: Annotated[float, Field(ge=-45, le=45)] = 0.0
    noise_quad_per_m: NonNeg = 0.0
    dropout_rate: Annotated[float, Field(ge=0, le=1)] = 0.0
    dropped_as: Literal["unknown", "free"] = "unknown"
    spurious_rate: Annotated[float, Field(ge=0, le=1)] = 0.0
    spurious_max_m: Pos = 1.0
    ground_reflectivity: Reflectivity = 0.3
    rated_reflectivity: Reflectivity = RATED_REFLECTIVITY
    reports: Literal["range", "z_depth"] = "range"

    @model_validator(mode="before")
    @classmethod
    def _model_defaults(cls, data):
        if not isinstance(data, dict):
            return data
        model = data.get("model", "sector")
        if model == "sector":
            extra = [k for k in MODEL_KEYS if k in data and data[k] != cls.model_fields[k].default]  # a dump: defaults
            if extra:
                raise ValueError(f"{', '.join(extra)}: only for model depth_camera or single_beam")
            return data
        from .sensor_models import MODEL_DEFAULTS

        return {**MODEL_DEFAULTS.get(model, {}), **data}


class WindSpec(_Strict):
    mean_m_s: NonNeg | None = None  # default: the vehicle file's design wind
    from_deg: Num = 0.0
    gust_m_s: NonNeg | None = None
    length_m: Pos = 20.0


class Route(_Strict):
    altitude_m: Pos = 2.0
    cruise_speed_m_s: Pos | None = None
    waypoints: list[tuple[Num, Num]] = []
    # or a mission file the autopilot loads as it is: a QGroundControl .plan or a `QGC WPL 110` .waypoints
    # (relative paths from the current directory); e.g. `contract-guard calibrate plan`'s output
    mission: str | None = None

    @model_validator(mode="after")
    def _one_route(self) -> "Route":
        if self.mission and self.waypoints:
            raise ValueError("give either waypoints or a mission file, not both")
        return self


class Fog(_Strict):
    """A medium of extinction α in front of the range sensor. `visibility_m` is the range to which the default
    target (reflectivity 0.5) is still seen; the sensor model derives α from it by the lidar equation, so
    darker targets are seen less far and brighter ones farther (sitl_harness/sensors.py, contracts/lidar.py).
    `honest`: the sensor lowers its stated range to it; `hidden`: it keeps stating its nominal range."""

    visibility_m: Pos
    report: Literal["honest", "hidden"] = "honest"


class Gust(_Strict):
    peak_m_s: Num
    duration_s: Pos
    from_deg: Num = 0.0


class ModeDelay(_Strict):
    """A requested mode accepted at once and entered `delay_s` later; `only` that mode (None: every mode)."""

    delay_s: Pos
    only: Literal["offboard", "hold"] | None = None


FAULT_KINDS = ("thrust_ratio", "fog", "sensor_dropout_s", "link_dropout_s", "nav_fault_s", "gust",
               "speed_commands_ignored", "mode_delay", "offboard_refused")


class Fault(_Strict):
    """One timeline event: exactly one of the optional fields."""

    at_s: NonNeg
    thrust_ratio: Annotated[float, Field(gt=0, le=1.5)] | None = None
    fog: Fog | Literal["clear"] | None = None
    sensor_dropout_s: Pos | None = None
    link_dropout_s: Pos | None = None
    nav_fault_s: Pos | None = None  # estimator reports a bad position/velocity estimate (flags only)
    gust: Gust | None = None
    # the autopilot from now on accepts DO_CHANGE_SPEED but ignores it, back at its own cruise speed (a misbehaving
    # autopilot: the governor's limit and approach ramp not followed)
    speed_commands_ignored: Literal[True] | None = None
    # from now on: requested modes entered late; OFFBOARD / GUIDED refused (`denied`: the answer says so, `silently`:
    # accepted and never entered)
    mode_delay: ModeDelay | None = None
    offboard_refused: Literal["denied", "silently"] | None = None

    @model_validator(mode="after")
    def _one(self) -> "Fault":
        set_ = [k for k in FAULT_KINDS if getattr(self, k) is not None]
        if len(set_) != 1:
            raise ValueError(f"a fault needs exactly one of {', '.join(FAULT_KINDS)} (got {', '.join(set_) or 'none'})")
        return self


COMPONENT_IDS = {"autopilot": 1, "daemon": 191}  # MAV_COMP_ID_AUTOPILOT1, MAV_COMP_ID_ONBOARD_COMPUTER


class ParamSet(_Strict):
    component: Literal["daemon", "autopilot"] = "daemon"
    name: Annotated[str, Field(min_length=1, max_length=16)]  # MAVLink param_id is char[16]
    value: Num

    @property
    def component_id(self) -> int:
        return COMPONENT_IDS[self.component]


class GcsAction(_Strict):
    """A ground-station action at `at_s` of vehicle time (or as soon as the ground station is
    connected, if later), sent over MAVLink to system 1. Performed by `contract-guard demo` and the
    lock-step tests; the SITL ignores it."""

    at_s: NonNeg
    param_set: ParamSet


class Scenario(_Strict):
    name: str = "empty"
    description: str = ""
    vehicle: str = "mambo"
    seed: int = 0
    physics_hz: Annotated[float, Field(ge=500, le=10000)] = 1000.0
    # the simulated aircraft's extra command latency [s]: rotor commands reach the motors this much later
    # (a FIFO of round(delay · physics_hz) physics steps, kernel.py); a truth property, not in the vehicle file
    actuator_delay_s: Annotated[float, Field(ge=0, le=1)] = 0.0
    home: Home = Home()
    start: Start = Start()
    world: WorldSpec = WorldSpec()
    sensor: SensorSpec = SensorSpec()
    wind: WindSpec = WindSpec()
    route: Route = Route()
    params: dict[str, Num] = {}
    faults: list[Fault] = []
    gcs: list[GcsAction] = []


def scenario_from_dict(data: object, source: str = "scenario") -> Scenario:
    return model_from_dict(Scenario, data, source, ScenarioError, empty_ok=True)


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A path as given, or a shipped scenario by name (`column_ahead`)."""
    return resolve_named(name_or_path, SCENARIO_DIR)


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A scenario file by path, or a shipped one by name (`column_ahead`)."""
    return load_model(Scenario, resolve_scenario_path(name_or_path), "scenario file", ScenarioError, empty_ok=True)
