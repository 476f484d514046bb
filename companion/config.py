"""The daemon's configuration: one YAML file, validated on load (an unknown key or a bad value is one
error line naming it). Degrees only where a key says `_deg`; everything else SI."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from contracts.yamlfile import load_model, model_from_dict

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


MavId = Annotated[int, Field(ge=1, le=255)]


def udp_address(text: str | None) -> tuple[str, int] | None:
    """`HOST:PORT` → (IPv4 address, port); raises ValueError naming what is wrong."""
    if text is None:
        return None
    import socket

    host, _, port = text.rpartition(":")
    try:
        addr = (socket.gethostbyname(host), int(port))
    except (ValueError, OSError):
        raise ValueError(f"{text!r} is not HOST:PORT") from None
    if not 0 < addr[1] < 65536:
        raise ValueError(f"{text!r}: port outside 1–65535")
    return addr


class SensorConfig(_Strict):
    """One obstacle sensor as mounted: which messages are its (the source: system, component, sensor id,
    orientation), where it looks, how wide. A message from any other source is counted and dropped."""

    kind: Literal["distance_sensor", "obstacle_distance"] = "distance_sensor"
    id: int | None = None  # DISTANCE_SENSOR.id to match (None: any id with this orientation)
    # the MAVLink source of its messages (None: the autopilot's, as PX4 and ArduPilot forward their range sensors
    # as DISTANCE_SENSOR / OBSTACLE_DISTANCE of their own component)
    system_id: MavId | None = None
    component_id: MavId | None = None
    # over UDP (udpin), the address its messages come from (None: the first heard; a sensor with the autopilot's
    # ids is the autopilot's address)
    address: str | None = None
    orientation_deg: float = 0.0  # sensor axis yaw in the body frame, clockwise from forward
    h_fov_deg: Annotated[float, Field(gt=0, le=360)]
    min_quality: Annotated[int, Field(ge=0, le=100)] = 50  # signal_quality below this: not trusted
    # the sensor's rated range [m]: what its messages may claim (max_distance) is capped by it; required
    # in governor and offboard mode (a sensor's word is not taken for its range)
    max_range_m: Pos | None = None

    @field_validator("address")
    @classmethod
    def _address(cls, text: str | None) -> str | None:
        udp_address(text)
        return text


NETWORK_LINKS = ("udpin:", "udpout:", "udp:", "udpbcast:", "tcp:", "tcpin:")  # pymavlink URLs of a network


class LinkConfig(_Strict):
    connect: str = "udpin:0.0.0.0:14540"  # pymavlink URL: udpin:/udpout:/tcp:/serial path
    baud: int = 921600
    autopilot: str = "px4"  # an adapter's name (companion/autopilots.py)
    target_system: int = 1
    target_component: int = 1
    component_id: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    gcs_system_ids: list[Annotated[int, Field(ge=1, le=255)]] = [255]  # ground stations that may set CG_* parameters
    # over UDP (udpin), the address the autopilot sends from (HOST:PORT; None: the first address its HEARTBEAT
    # comes from). Another address claiming its ids is refused, and said
    autopilot_address: str | None = None
    # over a network link the daemon's parameters are set only by signed messages; true accepts unsigned
    # ones (weaker: anyone who can reach the link as a ground station's system id can disengage the guard)
    unsigned_params: bool = False
    # the autopilot's clock rate against the host's: 1 for a real aircraft, K for a SITL sped up K times;
    # daemon time runs at it, and an autopilot clock running otherwise is a fault
    clock_rate: Annotated[float, Field(ge=0.1, le=20)] = 1.0
    signing_key_file: Path | None = None  # 32-byte key (raw or 64 hex chars), readable only by us
    signing_timestamp_file: Path | None = None  # persisted across restarts (no RTC on many boards)

    @field_validator("autopilot")
    @classmethod
    def _known(cls, name: str) -> str:
        from .autopilots import ADAPTERS

        if name not in ADAPTERS:
            raise ValueError(f"unknown autopilot {name!r} (known: {', '.join(ADAPTERS)})")
        return name

    @field_validator("autopilot_address")
    @classmethod
    def _address(cls, text: str | None) -> str | None:
        udp_address(text)
        return text

    @property
    def network(self) -> bool:
        """Whether the link is a network (UDP, TCP): anyone who can reach it can send."""
        return self.connect.startswith(NETWORK_LINKS)

    @property
    def unsigned_param_refusal(self) -> str | None:
        """Why an unsigned set of the daemon's parameters is refused on this link, or None when it is not: over
        a network link, unless `unsigned_params` (weaker) — with a signing key the link itself takes only
        signed messages, so what reaches the parameter server was signed (or is a replay of what was)."""
        if not self.network or self.unsigned_params or self.signing_key_file is not None:
            return None
        return ("unsigned over a network link (sign the ground station's messages: link.signing_key_file; or "
                "accept unsigned sets, weaker: link.unsigned_params)")

    def trust(self) -> list[str]:
        """Who the daemon takes its parameters from, in words (for the banner); WEAKENED where it is weaker
        than the default."""
        ids = "/".join(map(str, self.gcs_system_ids))
        if self.network and self.unsigned_params:
            return [f"WEAKENED link.unsigned_params: CG_* parameters accept UNSIGNED sets from system {ids} over "
                    f"{self.connect} (anyone who can reach the link can disengage the guard)"]
        if self.unsigned_param_refusal is not None:
            return [f"CG_* parameters: signed sets only over {self.connect}, and no signing key is configured: "
                    "they cannot be set over the link"]
        return []

    def sensor_source(self, s: "SensorConfig") -> tuple[int, int]:
        """The (system, component) a configured sensor's messages come from."""
        return (s.system_id or self.target_system, s.component_id or self.target_component)

    def pins(self, sensors: list[SensorConfig]) -> dict[tuple[int, int], tuple[str, int] | None]:
        """The sources a UDP link (udpin) takes from one address only: the autopilot, and each sensor with ids of
        its own — (system, component) → the configured address, or None (the first heard). A sensor with the
        autopilot's ids comes from the autopilot's address."""
        ap = (self.target_system, self.target_component)
        pins = {ap: udp_address(self.autopilot_address)}
        for s in sensors:
            ids = self.sensor_source(s)
            if ids != ap and pins.get(ids) is None:
                pins[ids] = udp_address(s.address)
        return pins


class ContractConfig(_Strict):
    r_obst_m: NonNeg = 1.0  # expected obstacle radius (also the R_OBST parameter)
    r_obst_range_m: tuple[Pos, Pos] = (0.1, 10.0)  # what a ground station may set CG_R_OBST to
    e_tr_floor_m: NonNeg = 0.3  # smallest tracking error ever assumed (braking overshoot included)
    # the tracking error to assume when the table carries no controller contract (E_tr_pred, `table etr`):
    # without a controller contract the daemon refuses to engage unless this is stated
    e_tr_assumed_m: NonNeg | None = None
    e_tr_window_s: Pos = 2.0  # E_tr is the worst contour error over this window
    dwell_s: NonNeg = 2.0  # a higher limit takes effect only after holding this long
    late_detection_hold_s: NonNeg = 10.0  # how long a late first detection lowers D_od
    late_detection_tolerance_m: NonNeg = 0.3
    # navigation margin (issue 19 item 8): the part of a sensor's claimed range not trusted, D_od = (1 − m) ×
    # the claim; 0 is the paper's contract (the claim is the guarantee). m survives a hidden shortfall of up to
    # m (the sensor silently seeing only 1 − m of what it claims), at a lower speed limit
    nav_margin: Annotated[float, Field(ge=0, le=0.9, allow_inf_nan=False)] = 0.0


class ThrustConfig(_Strict):
    source: Literal["hover", "configured"] = "hover"
    value: Annotated[float, Field(gt=0, le=1)] | None = None  # configured thrust ratio (default: range bottom)
    hover_throttle_nominal: Annotated[float, Field(gt=0, lt=1)] | None = None  # default: the vehicle file's
    tau_s: Pos = 2.0  # low-pass time constant of the hover-throttle estimate


class Timeouts(_Strict):
    heartbeat_s: Pos = 1.5
    telemetry_s: Pos = 0.5
    obstacle_s: Pos = 0.5  # PX4 collision prevention drops range data older than 0.5 s
    nav_s: Pos = 2.0
    # the daemon's own cycle (companion/estimators.py Timeliness): lateness beyond one period up to this is sleep
    # jitter inside t_react's budget; beyond it, it counts as reaction time (a lower speed); a cycle this late
    # beyond its period breaks the daemon's guarantee outright: the autopilot is handed Hold
    cycle_jitter_s: NonNeg = 0.01
    cycle_late_s: Pos = 0.25


class RouteConfig(_Strict):
    """The route offboard mode flies: local NED waypoints [m] at a constant altitude (`source: config`),
    or the autopilot's mission, downloaded when engaging (`source: mission`, companion/mission.py)."""

    source: Literal["config", "mission"] = "config"
    waypoints: Annotated[list[tuple[float, float]], Field(min_length=2)] | None = None
    altitude_m: Pos = 2.0
    level_tolerance_m: NonNeg = 0.5  # mission: all waypoint altitudes within this (the contract assumes level flight)
    corner_cut_m: NonNeg = 1.0  # corners flown as arcs passing this far inside the waypoint (0: stop there)

    @model_validator(mode="after")
    def _fits_source(self):
        if self.source == "config" and self.waypoints is None:
            raise ValueError("waypoints are required with source: config")
        if self.source == "mission" and {"waypoints", "altitude_m"} & self.model_fields_set:
            raise ValueError("waypoints and altitude_m come from the mission with source: mission")
        return self


class CalibrationConfig(_Strict):
    """The calibration plan's hold legs, flown by the daemon in governor mode (companion/calibration_holds.py):
    `calibration-legs.json` of `contract-guard calibrate plan`, or the `.plan` / `.waypoints` it wrote."""

    legs: Path

    @field_validator("legs")
    @classmethod
    def _readable(cls, path: Path) -> Path:
        from contracts.errors import ContractError

        from .calibration_holds import read_legs

        try:
            read_legs(path)
        except ContractError as err:
            raise ValueError(str(err)) from None
        return path


class LogConfig(_Strict):
    dir: Path = Path("/var/log/contract-guard")
    max_bytes: int = 50_000_000
    keep: int = 10
    tlog: bool = False
    state_hz: Pos = 10.0


class Config(_Strict):
    vehicle: str | None = None  # shipped name or path to a vehicle file: which aircraft the contract is for
    table: Path | None = None  # default: the shipped table of the vehicle
    mode: Literal["shadow", "governor", "offboard"] = "shadow"
    engage: bool = False  # engage only when asked (also the CG_ENGAGE parameter)
    loop_hz: Pos = 50.0
    speed_margin_m_s: NonNeg = 0.2  # ground speed this far above the limit counts as "not in force"
    link: LinkConfig = LinkConfig()
    sensors: list[SensorConfig] = []  # the obstacle sensors as mounted (none: D_od is 0, no speed is safe)
    contract: ContractConfig = ContractConfig()
    thrust: ThrustConfig = ThrustConfig()
    timeouts: Timeouts = Timeouts()
    log: LogConfig = LogConfig()
    route: RouteConfig | None = None  # offboard mode: the route to fly
    offboard_entry_s: Pos = 1.0  # setpoints streamed before asking for OFFBOARD (PX4 needs > 0.5 s)
    calibration: CalibrationConfig | None = None  # governor mode: the daemon flies the calibration plan's hold legs

    @model_validator(mode="after")
    def _sensors_rated(self):
        if self.mode != "shadow" and not self.sensors:
            raise ValueError(f"sensors: at least one obstacle sensor is required in {self.mode} mode")
        if self.mode != "shadow":
            for k, s in enumerate(self.sensors):
                if s.max_range_m is None:
                    raise ValueError(f"sensors[{k}].max_range_m (the sensor's rated range) is required in {self.mode} "
                                     "mode: a message's max_distance is capped by it")
        if self.calibration is not None and self.mode != "governor":
            raise ValueError(f"calibration.legs: the daemon flies the hold legs in governor mode only (mode is "
                             f"{self.mode})")
        return self


def config_from_dict(data: object, source: str = "config") -> Config:
    return model_from_dict(Config, data, source, empty_ok=True)


def load_config(path: str | Path) -> Config:
    return load_model(Config, path, "config", empty_ok=True)
