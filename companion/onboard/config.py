"""The daemon's configuration: one YAML file, validated on load (an unknown key or a bad value is one
error line naming it). Degrees only where a key says `_deg`; everything else SI."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from contracts.lidar import BACKSCATTER_LENGTH_M, RATED_REFLECTIVITY, REFERENCE_REFLECTIVITY
from contracts.yamlfile import load_model, model_from_dict

from .modes import Mode, mode_of
from .overshoot import DEFAULT as OVERSHOOT
from .overshoot import OvershootBudget

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


def _beside_config(path: Path, info: ValidationInfo) -> Path:
    """A relative path in a config file is relative to the file's directory (`load_config`), not to the
    directory the daemon was started in."""
    base = (info.context or {}).get("config_dir")
    return base / path if base is not None and not path.is_absolute() else path


def _vehicle_beside_config(ref: str, info: ValidationInfo) -> str:
    """`vehicle:` is a shipped name (`x500`) or a vehicle file, relative to the config file's directory."""
    p = Path(ref)
    return str(_beside_config(p, info)) if p.suffix in (".yaml", ".yml") or len(p.parts) > 1 else ref


FilePath = Annotated[Path, AfterValidator(_beside_config)]
VehicleRef = Annotated[str, AfterValidator(_vehicle_beside_config)]

def Bounded(lo: float, hi: float, lo_open: bool = False):
    """A finite number in its safe range: [lo, hi] (or (lo, hi] with `lo_open`). A value that weakens a guarantee
    (a longer time-out, a shorter dwell …) is bounded where the guarantee would stop meaning anything; between the
    default and that bound it is accepted and named in the start banner (`weakened`)."""
    return Annotated[float, Field(**{"gt" if lo_open else "ge": lo}, le=hi, allow_inf_nan=False)]


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
    # over UDP (udpin), the address its messages come from (None: the one address heard alone claiming its ids
    # for a while; two claiming them refuse engaging; a sensor with the autopilot's ids is the autopilot's address)
    address: str | None = None
    # sensor axis yaw in the body frame, clockwise from forward (a finite angle, one turn either way at most)
    orientation_deg: Annotated[float, Field(ge=-360, le=360, allow_inf_nan=False)] = 0.0
    h_fov_deg: Annotated[float, Field(gt=0, le=360, allow_inf_nan=False)]
    min_quality: Annotated[int, Field(ge=0, le=100)] = 50  # signal_quality below this: not trusted
    # the beams (shots) one frame gathers, shared evenly by its reports (OBSTACLE_DISTANCE's bins, DISTANCE_SENSOR's
    # one range, each the nearest of its shots): what the fog's backscatter rate is counted per. None: one shot per
    # report (a bin one shot, a DISTANCE_SENSOR's frame one shot, as a single narrow beam or a flash sensor takes
    # it); a sensor that reports the nearest of many beams then reads the fog thicker than it is
    shots_per_frame: Annotated[int, Field(ge=1, le=100_000)] | None = None
    # the sensor's rated range [m]: what its messages may claim (max_distance) is capped by it; required
    # in governor and offboard mode (a sensor's word is not taken for its range)
    max_range_m: Pos | None = None
    # what an OBSTACLE_DISTANCE bin's distance is: `range` along the bin, or `axis_depth`, the depth along the
    # sensor's axis of the bin's nearest pixel (a stereo camera's obstacle line, as d4xx_to_mavlink.py sends it),
    # read as the least range that depth allows anywhere in the bin (mavlink_in.py)
    depth: Literal["range", "axis_depth"] = "range"
    # fixed to the airframe, it pitches with it (companion/onboard/ground.py): each reading the nearest over
    # `v_fov_deg` of elevation about its axis, the axis pitched up by `mount_pitch_deg`; where its lowest ray meets
    # the ground, its claim stops. None: levelled (a gimbal), or the ground never in its view
    v_fov_deg: Annotated[float, Field(gt=0, le=90, allow_inf_nan=False)] | None = None
    mount_pitch_deg: Annotated[float, Field(ge=-90, le=90, allow_inf_nan=False)] = 0.0
    # [m] the sensor's own clutter: within this its spurious returns come (a propeller in view, rain or dust at the
    # lens). A return this near where a recent frame looked past waits for the frames that confirm it before the
    # obstacle logic takes it (companion/onboard/late_detection.py); 0: every return at once. At most 2 m
    clutter_m: Annotated[float, Field(ge=0, le=2, allow_inf_nan=False)] = 0.0
    # the fraction of its reports that are its own spurious returns in clear air (measured in the same hover): the
    # fog's backscatter comes at the same ranges and is counted beyond them (detection_range.py). At most 0.1
    spurious_rate: Annotated[float, Field(ge=0, le=0.1, allow_inf_nan=False)] = 0.0

    def trusts(self, quality: int) -> bool:
        """Whether a reading of MAVLink signal_quality `quality` is trusted: unknown (0) is, invalid (1) never is, and
        2–100 from `min_quality` up."""
        return quality == 0 or quality >= max(self.min_quality, 2)

    @field_validator("address")
    @classmethod
    def _address(cls, text: str | None) -> str | None:
        udp_address(text)
        return text


NETWORK_LINKS = ("udpin:", "udpout:", "udp:", "udpbcast:", "tcp:", "tcpin:")  # pymavlink URLs of a network
LISTENING = ("udpin:", "udp:", "tcpin:")  # a network URL the daemon binds: port 0 lets the system choose one


def connect_url(text: str) -> str:
    """A pymavlink URL `run` can open: a network one is SCHEME:HOST:PORT with a port in 1–65535 (0 too where the
    daemon listens: the system picks a free port); anything else is a serial device (checked when it is opened).
    Raises ValueError naming what is wrong."""
    if not text.startswith(NETWORK_LINKS):
        if not text or text.strip() != text:
            raise ValueError(f"{text!r} is not a pymavlink URL (udpin:HOST:PORT, tcp:HOST:PORT or a serial device)")
        return text
    scheme, _, rest = text.partition(":")
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ValueError(f"{text!r} is not {scheme}:HOST:PORT")
    lo = 0 if text.startswith(LISTENING) else 1
    if not lo <= int(port) <= 65535:
        raise ValueError(f"{text!r}: port {int(port)} outside {lo}–65535")
    return text


class LinkConfig(_Strict):
    connect: str = "udpin:0.0.0.0:14540"  # pymavlink URL: udpin:/udpout:/tcp:/serial path
    baud: Annotated[int, Field(gt=0)] = 921600
    autopilot: str = "px4"  # an adapter's name (companion/onboard/autopilots.py)
    # MAVLink ids are one byte, 0 meaning "all": an id outside 1–255 never matches a message
    target_system: MavId = 1
    target_component: MavId = 1
    component_id: MavId = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    gcs_system_ids: list[Annotated[int, Field(ge=1, le=255)]] = [255]  # ground stations that may set CG_* parameters
    # over UDP (udpin), the address the autopilot sends from (HOST:PORT; None: the one address heard alone
    # claiming its ids for a while). Another address claiming its ids is refused, and said; two claiming the
    # autopilot's seat refuse engaging
    autopilot_address: str | None = None
    # over a network link the daemon's parameters are set only by signed messages; true accepts unsigned
    # ones (weaker: anyone who can reach the link as a ground station's system id can disengage the guard)
    unsigned_params: bool = False
    # over a network link (not loopback) governor and offboard engage only with signing on; true accepts
    # unsigned operation (weaker: anyone who can reach the link can send sensor data and forge addresses)
    accept_unsigned: bool = False
    # the autopilot's clock rate against the host's: 1 for a real aircraft, K for a SITL sped up K times;
    # daemon time runs at it, and an autopilot clock running otherwise is a fault
    clock_rate: Annotated[float, Field(ge=0.1, le=20)] = 1.0
    signing_key_file: FilePath | None = None  # 32-byte key (raw or 64 hex chars), readable only by us
    signing_timestamp_file: FilePath | None = None  # persisted across restarts (no RTC on many boards)

    @field_validator("connect")
    @classmethod
    def _url(cls, text: str) -> str:
        return connect_url(text)

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

    def seats(self, sensors: list[SensorConfig]) -> str:
        """Who the link takes the autopilot and the sensors from, in one line (for the banner): pinned to
        configured addresses, loopback only, or OPEN (a claimant heard alone for a while takes a seat)."""
        from .link import SEAT_SETTLE_S

        if not self.connect.startswith("udpin:"):
            return f"link: {self.connect}: the autopilot is the peer of this link"
        host = self.connect.split(":")[1].strip("[]").lower()
        ap = (self.target_system, self.target_component)
        unpinned = sorted({"%d/%d" % self.sensor_source(s) for s in sensors
                           if self.sensor_source(s) != ap and s.address is None})
        first = f"the first claimant heard alone for {SEAT_SETTLE_S:g} s takes"
        if self.autopilot_address is not None and not unpinned:
            return (f"link: pinned to {self.autopilot_address} (the autopilot; sensors with ids of their own at their "
                    "configured addresses); an address is no authentication, only signing is")
        if host == "localhost" or host.startswith("127.") or host == "::1":
            return (f"link: loopback only ({self.connect}; a router such as mavlink-router forwards the autopilot); "
                    f"{first} a seat, two claimants refuse engaging")
        if self.autopilot_address is not None:
            return (f"link: pinned to {self.autopilot_address} (the autopilot); OPEN for sensors "
                    f"{', '.join(unpinned)}: {first} the seat (pin it: sensors[k].address)")
        return (f"link: OPEN — first speaker: {first} the autopilot's seat on {self.connect} (pin it: "
                "link.autopilot_address; or listen on 127.0.0.1 behind a router)")

    def sensor_source(self, s: "SensorConfig") -> tuple[int, int]:
        """The (system, component) a configured sensor's messages come from."""
        return (s.system_id or self.target_system, s.component_id or self.target_component)

    def pins(self, sensors: list[SensorConfig]) -> dict[tuple[int, int], tuple[str, int] | None]:
        """The sources a UDP link (udpin) takes from one address only: the autopilot, and each sensor with ids of
        its own — (system, component) → the configured address, or None (given by the link's seat rules). A sensor with the
        autopilot's ids comes from the autopilot's address."""
        ap = (self.target_system, self.target_component)
        pins = {ap: udp_address(self.autopilot_address)}
        for s in sensors:
            ids = self.sensor_source(s)
            if ids != ap and pins.get(ids) is None:
                pins[ids] = udp_address(s.address)
        return pins


class ContractConfig(_Strict):
    r_obst_m: NonNeg = 1.0  # expected obstacle radius (also the R_OBST parameter); inside r_obst_range_m
    r_obst_range_m: tuple[Pos, Pos] = (0.1, 10.0)  # what a ground station may set CG_R_OBST to
    # smallest tracking error ever assumed (braking overshoot included). Up to 5 m: a larger floor only slows the
    # aircraft (no upper bound is needed for safety; 5 m catches a unit slip, mm for m). Below the default: banner
    e_tr_floor_m: Bounded(0.0, 5.0) = 0.3
    # the tracking error to assume when the table carries no controller contract (E_tr_pred, `table etr`):
    # without a controller contract the daemon refuses to engage unless this is stated
    e_tr_assumed_m: NonNeg | None = None
    # E_tr is the worst contour error over this window. At least 0.5 s: an avoidance manoeuvre's error peaks and
    # settles over 1-2 s (the E_tr_pred sweep's contour window is 1 s), a shorter window forgets it mid-manoeuvre
    e_tr_window_s: Bounded(0.5, 60.0) = 2.0
    # a higher limit takes effect only after holding this long (limits go down at once and up slowly). At least
    # 0.5 s: 25 cycles at 50 Hz, so one good sample between bad ones cannot raise the speed
    dwell_s: Bounded(0.5, 600.0) = 2.0
    # how long a late first detection lowers D_od. At least 1 s: the lowered D_od must outlast the detection
    # that caused it by more than the sensors' time-out (timeouts.obstacle_s ≤ 1 s)
    late_detection_hold_s: Bounded(1.0, 3600.0) = 10.0
    # a first detection this much inside the claimed range is not late. At most 2 m: a tolerance larger than the
    # keep-out margins it protects (r_obst + e_tr floor, about 1 m) would hide every real shortfall
    late_detection_tolerance_m: Bounded(0.0, 2.0) = 0.3
    # a return first seen inside D_od is declared a late detection (D_od lowered, a navigation violation) only once
    # the sensor has seen it again at a consistent place in this many following frames: a real surface persists, a
    # spurious close return (a propeller, rain) is new in every frame. The return is an obstacle from its first frame,
    # except within its sensor's clutter (`sensors[k].clutter_m`), where it waits as long. At most 5: neither may
    # wait more than a few frames (0: every single frame counts, at once)
    late_detection_confirm_frames: Annotated[int, Field(ge=0, le=5)] = 2
    # navigation margin: the part of a sensor's claimed range not trusted, D_od = (1 − m) ×
    # the claim; 0 is the paper's contract (the claim is the guarantee). m survives a hidden shortfall of up to
    # m (the sensor silently seeing only 1 − m of what it claims), at a lower speed limit
    nav_margin: Annotated[float, Field(ge=0, le=0.9, allow_inf_nan=False)] = 0.0

    @model_validator(mode="after")
    def _r_obst_in_range(self):
        lo, hi = self.r_obst_range_m
        if lo > hi:
            raise ValueError(f"r_obst_range_m: ({lo:g}, {hi:g}) is not a range (low above high)")
        if not lo <= self.r_obst_m <= hi:  # else CG_R_OBST could not even be set back to the configured value
            raise ValueError(f"r_obst_m: {self.r_obst_m:g} m is outside r_obst_range_m ({lo:g}-{hi:g} m)")
        return self


class ThrustConfig(_Strict):
    source: Literal["hover", "configured"] = "hover"
    value: Annotated[float, Field(gt=0, le=1)] | None = None  # configured thrust ratio (default: range bottom)
    hover_throttle_nominal: Annotated[float, Field(gt=0, lt=1)] | None = None  # default: the vehicle file's
    # low-pass time constant of the hover-throttle estimate: a thrust loss shows after about this long. At most
    # 10 s: slower, a motor failing over a minute's flight would never lower thrust_ratio in time to matter
    tau_s: Bounded(0.0, 10.0, lo_open=True) = 2.0


class DetectionConfig(_Strict):
    """D_od from evidence (companion/onboard/detection_range.py, docs/detection-range.md): what the estimator needs to
    know of the sensors and the obstacles. The defaults are the SITL's sensors'."""

    # the darkest obstacle D_od is to guarantee (diffuse reflectivity at the sensor's wavelength: a dark
    # column 0.1, grey 0.5, a white wall 0.9). Higher is weaker: a darker obstacle is then seen later than D_od
    reference_reflectivity: Bounded(0.01, 1.0) = REFERENCE_REFLECTIVITY
    # the target the sensors' stated range is rated at (datasheets: 10 %, a dark target)
    rated_reflectivity: Bounded(0.01, 1.0) = RATED_REFLECTIVITY
    # the sensor's backscatter length L_bs [m]: a shot sees the medium with p = 1 − e^(−α·L_bs); measure it on one
    # fog flight. Higher is weaker: a larger L_bs reads a thinner fog from the same backscatter
    backscatter_length_m: Bounded(0.01, 10.0) = BACKSCATTER_LENGTH_M
    # the sensors' range noise, 1 σ = range_noise_m + range_noise_rel × range: a target is first seen up to three of
    # it short of the stated range by noise alone, which is no evidence of a shorter one. TFmini Plus datasheet:
    # ±5 cm to 5 m, ±1 % to 12 m; a RealSense D435 < 2 % at 2 m. Higher is weaker: a larger shortfall passes as
    # on time (lower: a noisy sensor's first sightings read as a shorter range — slower, never less safe)
    range_noise_m: Bounded(0.0, 0.5) = 0.03
    range_noise_rel: Bounded(0.0, 0.05) = 0.01
    # ... + range_noise_quad_per_m × range²: a stereo camera's (RMS ∝ depth²; a RealSense D435 about 0.01 per m)
    range_noise_quad_per_m: Bounded(0.0, 0.05) = 0.0
    # [deg] how far the reported attitude may be off: a body-fixed sensor's ground (sensors[k].v_fov_deg) is placed
    # with the vehicle this much more nose-down and rolled. Lower is weaker: the ground read as an obstacle's return
    attitude_error_deg: Bounded(0.0, 10.0) = 1.0


class Timeouts(_Strict):
    """How long each input stays believed. Every one is a failsafe: longer means a silent source is trusted longer
    (an obstacle sensor gone quiet keeps its last "free" reading), so each has a ceiling of a few seconds at most."""

    # the autopilot's HEARTBEAT (1 Hz): at most 5 s, the MAVLink heartbeat protocol's "lost" time
    # (mavlink.io/en/services/heartbeat.html: a component is lost after missing heartbeats for about 5 s)
    heartbeat_s: Bounded(0.0, 5.0, lo_open=True) = 1.5
    # the vehicle's position and velocity (LOCAL_POSITION_NED, ≥ 10 Hz on a companion link): at most 2 s, at
    # 8 m/s already 16 m flown on a stale position
    telemetry_s: Bounded(0.0, 2.0, lo_open=True) = 0.5
    # obstacle readings: PX4 collision prevention drops range data older than 0.5 s
    # (CollisionPrevention.cpp RANGE_STREAM_TIMEOUT_US 500 ms); at most 2 s, beyond it a silent sensor's last
    # "free" reading would cover more than a D_od at cruise speed
    obstacle_s: Bounded(0.0, 2.0, lo_open=True) = 0.5
    # a sensor counts as silent (dead) once it has sent nothing for this many of its own periods, the mean
    # interval of its last 16 samples as the daemon received them, never less than obstacle_min_s nor more
    # than obstacle_s (obstacle_s until 16 intervals are measured). The stop and avoid contracts take that
    # silence as dead time (the vehicle flies on the last reading that long), so a shorter one is a faster
    # limit: a 20 Hz sensor's 3 periods (0.15 s) cost the governor 2-3 % of its limit at D_od 3-10 m, with the
    # recovery brake 5-11 %, offboard 0-15 %, where 0.5 s would cost 8-18 %, 17-31 %, 19-37 %
    # (benchmarks/bench_stale_cost.py). Fewer periods, or a lower floor, declare a sensor whose samples are
    # jittered dead more often (D_od without it: a Hold where it was the only one)
    obstacle_periods: Bounded(1.5, 20.0) = 3.0
    obstacle_min_s: Bounded(0.02, 2.0) = 0.1
    # the autopilot's estimator health (ESTIMATOR_STATUS / EKF_STATUS_REPORT, 1-10 Hz): at most 5 s
    nav_s: Bounded(0.0, 5.0, lo_open=True) = 2.0
    # the daemon's own cycle (companion/onboard/estimators.py Timeliness). cycle_jitter_s is the jitter allowance: the
    # vehicle file's t_react holds one loop period of decision time plus this (docs/daemon.md, Timeliness), so a cycle up to this
    # much later than its period is inside the budget (an event, `cycle_jitter`); a later one is a guidance
    # violation and counts as reaction time for 10 s (a lower speed); a cycle cycle_late_s late breaks the daemon's
    # guarantee outright: the autopilot is handed Hold. Default 20 ms: on a 2-core host with two busy processes
    # beside the daemon, 99.9 % of cycles came within 8 ms (benchmarks/bench_daemon.py, BENCH_BUSY=2; docs/daemon.md).
    # At most 0.05 s: the vehicle files' whole t_react is 0.10-0.15 s, so a larger uncounted lateness would be a
    # third of it or more. Late at most 1 s: beyond that the daemon is not deciding at all.
    cycle_jitter_s: Bounded(0.0, 0.05) = 0.02
    cycle_late_s: Bounded(0.0, 1.0, lo_open=True) = 0.25


class DeliveryConfig(_Strict):
    """What the link and the autopilot guarantee of the daemon's commands: the command-delivery subsystem
    (docs/guarantee.md). A mode command is re-sent every cycle until the autopilot answers it (COMMAND_ACK) or
    shows it (HEARTBEAT); the stop contract's dead time includes `t_cmd_s`, so a Hold lost on the link, or delayed,
    for up to that long still stops short. Beyond either budget the daemon says so (a `delivery` violation) and a
    Hold takes the autopilot's next way to stop (Land)."""

    # [s] a command reaches the autopilot within this of its first send. Default 0.1 s: five 50 Hz cycles lost in
    # a row, or a 100 ms delay; it costs the governor 1.6-2.1 % of its limit, 4-9 % with the recovery brake
    # (benchmarks/bench_delivery_cost.py); 0 budgets no loss at all. At most 1 s
    t_cmd_s: Bounded(0.0, 1.0) = 0.1
    # [s] a requested mode is shown in the autopilot's HEARTBEAT within this of the first send. PX4 and ArduPilot
    # send HEARTBEAT at 1 Hz, so one period and the switch (hold_switch_s, 0.1 s) with a margin: 1.2 s. Refused, or
    # not shown by then: a Hold's fallback, any other mode given up. At most 5 s
    t_mode_s: Bounded(0.2, 5.0) = 1.2


class RouteConfig(_Strict):
    """The route offboard mode flies: local NED waypoints [m] at a constant altitude (`source: config`),
    or the autopilot's mission, downloaded when engaging (`source: mission`, companion/onboard/mission.py)."""

    source: Literal["config", "mission"] = "config"  # config: the waypoints below; mission: the autopilot's
    waypoints: Annotated[list[tuple[float, float]], Field(min_length=2)] | None = None  # [[north, east], …] [m]
    altitude_m: Pos = 2.0  # the flight altitude with source: config [m]
    # mission: all waypoint altitudes within this (the contract assumes level flight). At most 2 m: more is a
    # climbing route, which the contract (planned in the horizontal plane) does not cover
    level_tolerance_m: Bounded(0.0, 2.0) = 0.5
    corner_cut_m: NonNeg = 1.0  # corners flown as arcs passing this far inside the waypoint (0: stop there)

    @model_validator(mode="after")
    def _fits_source(self):
        if self.source == "config" and self.waypoints is None:
            raise ValueError("waypoints are required with source: config")
        if self.source == "mission" and {"waypoints", "altitude_m"} & self.model_fields_set:
            raise ValueError("waypoints and altitude_m come from the mission with source: mission")
        return self


class SpeedOvershootConfig(_Strict):
    """The autopilot's guarantee that the ground speed stays within base_m_s + fraction × limit of the speed limit
    sent (DO_CHANGE_SPEED). Defaults: the larger of the shipped vehicles' measured in the SITL, in their design wind,
    both personalities (benchmarks/bench_speed_overshoot.py: X500 0.12 m/s at 1 m/s to 0.32 m/s at 5–6 m/s). For an
    aircraft: its governor flights' event log says the overshoot its autopilot flew (`overshoot.overshoot_of`,
    docs/calibration.md). At most 1 m/s and 0.5: a larger budget would accept a limit that is not obeyed."""

    base_m_s: Bounded(0.0, 1.0) = OVERSHOOT.base_m_s
    fraction: Bounded(0.0, 0.5) = OVERSHOOT.fraction

    def budget(self) -> OvershootBudget:
        return OvershootBudget(self.base_m_s, self.fraction)


class GovernorConfig(_Strict):
    """Governor mode's own settings."""

    # the recovery brake (docs/daemon.md, "The recovery brake"): when the stop contract calls for a
    # stop, the daemon switches to OFFBOARD / GUIDED and flies a jerk-limited stop at the airframe's own braking
    # (its tilt limit, the thrust left), then hands over to Hold. The speed limit is then the brake's own stop
    # contract (higher); when the brake is unavailable (its start-up checks, the switch refused) it is the
    # autopilot's Hold's, at once. The gain assumes the autopilot accepts the switch: refused above the Hold's
    # limit, that Hold's stop is not guaranteed (logged as the autopilot's violation); off where that is not
    # acceptable
    recovery_brake: bool = False
    # the approach ramp (docs/daemon.md, "The approach ramp") [m/s]: the speed command is raised at most this far
    # above the speed flown, so the autopilot speeds up gently and a Hold never finds it accelerating hard; the
    # stop contract then allows a higher limit (checked: an autopilot that accelerates harder than the ramp allows
    # loses it at once, the autopilot's violation). Slower speed-ups; off (null) by default
    approach_ramp_m_s: Bounded(0.2, 2.0) | None = None


class CalibrationConfig(_Strict):
    """The calibration plan's hold legs, flown by the daemon in governor mode (companion/onboard/calibration_holds.py):
    `calibration-legs.json` of `contract-guard calibrate plan`, or the `.plan` / `.waypoints` it wrote."""

    legs: FilePath  # calibration-legs.json (or the .plan / .waypoints) of `contract-guard calibrate plan`

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
    dir: FilePath = Path("/var/log/contract-guard")  # the event log's directory (events.jsonl, raw.tlog)
    # an event log file is rotated at this size. At least 1 MB: a state record is about 0.8 kB, so a file holds
    # two minutes of flight at 10 Hz or more (smaller, a flight's start would be rotated away while it is flown)
    max_bytes: Annotated[int, Field(ge=1_000_000)] = 50_000_000
    # rotated files kept. At least 1: with none, every rotation deletes the record of the flight just flown
    keep: Annotated[int, Field(ge=1, le=10_000)] = 10
    tlog: bool = False  # also write the raw MAVLink as a .tlog (raw.tlog, as MAVProxy and QGroundControl write it)
    state_hz: Pos = 10.0  # state samples per second in the event log


class Config(_Strict):
    vehicle: VehicleRef | None = None  # shipped name or path to a vehicle file: which aircraft the contract is for
    table: FilePath | None = None  # default: the shipped table of the vehicle
    # the table must carry an ed25519 signature by this public key's private key (PEM; `contract-guard keys
    # --table` makes the pair, `table sign` signs): an edited and re-hashed table is refused at start
    table_public_key: FilePath | None = None
    # where the daemon keeps the serial of the last signed table it accepted (default: table-serial.json beside
    # link.signing_timestamp_file; neither: a rollback is not checked, said in the banner). An older table is
    # refused unless allow_table_rollback (then WEAKENED in the banner and a `table_rollback` event at every start)
    table_state_file: FilePath | None = None
    allow_table_rollback: bool = False
    mode: Literal["shadow", "governor", "offboard"] = "shadow"
    engage: bool = False  # engage only when asked (also the CG_ENGAGE parameter)
    # the daemon's cycle: at least 20 Hz, the offboard setpoint stream's rate (PX4 needs > 2 Hz to stay in
    # offboard; 20 Hz keeps a setpoint's age under the vehicle files' t_react). t_react budgets one 50 Hz cycle,
    # so a slower loop is named in the banner. At most 1000 Hz (a typo would only spin the CPU)
    loop_hz: Bounded(20.0, 1000.0) = 50.0
    # the autopilot's overshoot above the speed limit sent (companion/onboard/overshoot.py): budgeted (the limit
    # sent leaves room for it below V_max) and the only tolerance a limit flown is judged with
    speed_overshoot: SpeedOvershootConfig = SpeedOvershootConfig()
    link: LinkConfig = LinkConfig()
    sensors: list[SensorConfig] = []  # the obstacle sensors as mounted (none: D_od is 0, no speed is safe)
    contract: ContractConfig = ContractConfig()
    thrust: ThrustConfig = ThrustConfig()
    detection: DetectionConfig = DetectionConfig()
    timeouts: Timeouts = Timeouts()
    delivery: DeliveryConfig = DeliveryConfig()
    log: LogConfig = LogConfig()
    route: RouteConfig | None = None  # offboard mode: the route to fly
    offboard_entry_s: Pos = 1.0  # setpoints streamed before asking for OFFBOARD (PX4 needs > 0.5 s)
    calibration: CalibrationConfig | None = None  # governor mode: the daemon flies the calibration plan's hold legs
    governor: GovernorConfig = GovernorConfig()

    @property
    def daemon_mode(self) -> Mode:
        """The daemon's mode as its object (companion/onboard/modes.py)."""
        return mode_of(self.mode)

    @model_validator(mode="after")
    def _sensors_rated(self):
        if self.daemon_mode.commands and not self.sensors:
            raise ValueError(f"sensors: at least one obstacle sensor is required in {self.mode} mode")
        if self.daemon_mode.commands:
            for k, s in enumerate(self.sensors):
                if s.max_range_m is None:
                    raise ValueError(f"sensors[{k}].max_range_m (the sensor's rated range) is required in {self.mode} "
                                     "mode: a message's max_distance is capped by it")
        if self.governor.recovery_brake and not self.daemon_mode.governs:
            raise ValueError(f"governor.recovery_brake: governor mode only (mode is {self.mode})")
        if self.calibration is not None and not self.daemon_mode.governs:
            raise ValueError(f"calibration.legs: the daemon flies the hold legs in governor mode only (mode is "
                             f"{self.mode})")
        return self


def config_from_dict(data: object, source: str = "config") -> Config:
    return model_from_dict(Config, data, source, empty_ok=True)


def load_config(path: str | Path) -> Config:
    """A config file; the relative paths in it (vehicle file, table, log directory, calibration legs,
    signing files) are relative to the file's own directory."""
    return load_model(Config, path, "config", empty_ok=True, context={"config_dir": Path(path).parent})


# The values whose weaker side the start banner names: (section, key, "higher"/"lower" is weaker, what it costs).
WEAKER = (
    ("timeouts", "heartbeat_s", "higher", "a lost autopilot link is noticed later"),
    ("timeouts", "telemetry_s", "higher", "a stale position is believed longer"),
    ("timeouts", "obstacle_s", "higher", "a silent obstacle sensor's last reading is believed longer"),
    ("timeouts", "nav_s", "higher", "a silent estimator is believed healthy longer"),
    ("timeouts", "cycle_jitter_s", "higher", "more of the daemon's lateness goes uncounted (t_react must hold it)"),
    ("timeouts", "cycle_late_s", "higher", "a stalled daemon hands over to Hold later"),
    ("", "loop_hz", "lower", "decisions are further apart than t_react budgets"),
    ("speed_overshoot", "base_m_s", "lower", "less of the autopilot's overshoot is budgeted below V_max"),
    ("speed_overshoot", "fraction", "lower", "less of the autopilot's overshoot is budgeted below V_max"),
    ("contract", "e_tr_floor_m", "lower", "a smaller tracking error is assumed"),
    ("contract", "e_tr_window_s", "lower", "a tracking error is forgotten sooner"),
    ("contract", "dwell_s", "lower", "a higher limit takes effect sooner"),
    ("contract", "late_detection_hold_s", "lower", "a late detection lowers D_od for less time"),
    ("contract", "late_detection_tolerance_m", "higher", "a larger range shortfall passes as on time"),
    ("contract", "late_detection_confirm_frames", "higher",
     "a late detection lowers D_od, and a return within a sensor's clutter is held for, frames later"),
    ("delivery", "t_cmd_s", "lower", "a command lost or delayed for a shorter time is outside the contract"),
    ("delivery", "t_mode_s", "higher", "a mode the autopilot does not show is given up on later"),
    ("thrust", "tau_s", "higher", "a thrust loss shows later"),
    ("detection", "reference_reflectivity", "higher", "a darker obstacle than this is seen later than D_od"),
    ("detection", "backscatter_length_m", "higher", "the same backscatter reads as thinner fog"),
    ("detection", "range_noise_m", "higher", "a larger range shortfall at first sight passes as noise"),
    ("detection", "range_noise_rel", "higher", "a larger range shortfall at first sight passes as noise"),
    ("detection", "range_noise_quad_per_m", "higher", "a larger range shortfall at first sight passes as noise"),
    ("detection", "attitude_error_deg", "lower", "the ground nearer than placed reads as an obstacle"),
)


def weakened(cfg: Config) -> list[str]:
    """What in `cfg` is inside its safe range but weaker than the default, one line each (the start banner).
    Pure: the configuration alone."""
    out = []
    for section, key, worse, cost in WEAKER:
        obj = getattr(cfg, section) if section else cfg
        value, default = getattr(obj, key), type(obj).model_fields[key].default
        if (value > default) if worse == "higher" else (value < default):
            out.append(f"weaker than the default: {section + '.' if section else ''}{key} {value:g} (default "
                       f"{default:g}): {cost}")
    lo = cfg.contract.r_obst_range_m[0]
    if lo < ContractConfig.model_fields["r_obst_range_m"].default[0]:
        out.append(f"weaker than the default: contract.r_obst_range_m from {lo:g} m: a ground station may set "
                   "CG_R_OBST that small")
    if cfg.thrust.source == "configured":
        out.append("weaker than the default: thrust.source configured: thrust_ratio is fixed, a thrust loss is not seen")
    for k, s in enumerate(cfg.sensors):
        if s.min_quality < SensorConfig.model_fields["min_quality"].default:
            out.append(f"weaker than the default: sensors[{k}].min_quality {s.min_quality} (default "
                       f"{SensorConfig.model_fields['min_quality'].default}): poorer readings are trusted")
        if s.spurious_rate > 0.0:
            out.append(f"weaker than the default: sensors[{k}].spurious_rate {s.spurious_rate:g} (default 0): a fog "
                       "whose backscatter its own spurious returns could account for is not seen")
    if cfg.link.clock_rate < 1.0:
        out.append(f"weaker than the default: link.clock_rate {cfg.link.clock_rate:g}: every time-out runs "
                   f"{1 / cfg.link.clock_rate:g} times longer in real time (1 on an aircraft)")
    lk = cfg.link
    if cfg.daemon_mode.commands and lk.signing_key_file is None and lk.accept_unsigned and is_network_link(lk.connect):
        out.append(f"WEAKENED link.accept_unsigned: unsigned on a network link in {cfg.mode} mode: anyone who can "
                   f"reach {lk.connect} can send the daemon sensor data and commands, and forge the autopilot's "
                   "address (sign instead: link.signing_key_file, contract-guard keys)")
    return out


def is_network_link(connect: str) -> bool:
    """A pymavlink URL over the network (udp, udpin, udpout, udpbcast, tcp, tcpin) to or from anything but the
    loopback interface: not a serial port, not a SITL on this host."""
    scheme, _, rest = connect.partition(":")
    host = rest.rpartition(":")[0].strip("[]").lower()
    loopback = host == "localhost" or host.startswith("127.") or host == "::1"
    return scheme.lower() in ("udp", "udpin", "udpout", "udpbcast", "tcp", "tcpin") and not loopback
