"""Vehicle files: the constants of one airframe and its autopilot, validated on load.

A vehicle file is YAML (`contracts/data/<name>.yaml`). Every key is declared here; an unknown key
or a bad value ends with one `ContractError` line naming the field. SI units and radians inside
the code; the file uses the unit its key names (`tilt_max_deg`, `tilt_rate_max_deg_s`).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from .errors import ContractError
from .yamlfile import load_model, model_from_dict, resolve_named

G = 9.80665  # standard gravity [m/s²]
DATA_DIR = Path(__file__).resolve().parent / "data"
# keys only the SITL and the avoid sweep need: a stop-only table (`table build --stop-only`) does without them
SITL_KEYS = ("inertia_kg_m2", "yaw_moment_max_nm", "rotor")

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Frac = Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Rotor(_Strict):
    """ω² rotor model: thrust k_thrust·ω², drag torque k_torque·ω² (quad X layout)."""

    arm_m: Pos  # centre to rotor axis
    radius_m: Pos  # propeller radius
    k_thrust: Pos  # [N/(rad/s)²]
    k_torque: Pos  # [N·m/(rad/s)²]
    omega_max_rad_s: Pos
    motor_tau_s: Pos  # first-order motor lag
    spin: tuple[int, int, int, int] = (1, -1, 1, -1)  # +1: CCW seen from above (reaction torque +z_body)


class Braking(_Strict):
    """The autopilot's own braking in its auto modes (stop contract)."""

    accel_max_m_s2: Pos  # PX4 MPC_ACC_HOR, ArduPilot WPNAV_ACCEL
    jerk_max_m_s3: Pos  # PX4 MPC_JERK_AUTO, ArduPilot WPNAV_JERK
    hold_switch_s: NonNeg  # command → autopilot in Hold/Brake and braking


class Controller(_Strict):
    """Gains of the SITL's PX4-like cascade (scale-free: accelerations per error)."""

    rate_hz: Pos = 250.0
    pos_p: Pos = 0.95  # [1/s] PX4 MPC_XY_P
    vel_p: Pos = 1.8  # [1/s] PX4 MPC_XY_VEL_P_ACC
    vel_i: NonNeg = 0.4  # [1/s²] MPC_XY_VEL_I_ACC
    vel_d: NonNeg = 0.2  # [-] MPC_XY_VEL_D_ACC
    z_pos_p: Pos = 1.0  # MPC_Z_P
    z_vel_p: Pos = 4.0  # MPC_Z_VEL_P_ACC
    z_vel_i: NonNeg = 2.0  # MPC_Z_VEL_I_ACC
    att_p: Pos = 6.5  # [1/s] MC_ROLL_P / MC_PITCH_P
    yaw_p: Pos = 2.8  # MC_YAW_P
    rate_p: Pos = 20.0  # [1/s] angular-acceleration per rate error
    rate_i: NonNeg = 5.0
    rate_d: NonNeg = 0.0
    thr_hover: Frac = 0.5  # seed of the hover-thrust estimate (MPC_THR_HOVER)
    thr_xy_margin: Frac = 0.3  # MPC_THR_XY_MARG


class Wind(_Strict):
    """Design wind for the controller contract and end-to-end tests."""

    mean_m_s: NonNeg = 0.0
    gust_m_s: NonNeg = 0.0  # Dryden-type turbulence intensity (1 σ)


class Vehicle(_Strict):
    """One airframe and its autopilot (DESIGN.md §4.1)."""

    name: str
    description: str = ""
    mass_kg: Pos
    # the SITL's physics and the avoid sweep (yaw authority, eq. 7); not needed for a stop-only table
    inertia_kg_m2: tuple[Pos, Pos, Pos] | None = None
    t_nom_n: Pos  # nominal maximum total thrust, all rotors at ω_max
    collective_max_fraction: Frac = 1.0  # share of T_max usable for translation (rest: attitude authority)
    r_body_m: Pos  # radius of the disc that holds the whole vehicle
    t_react_s: NonNeg  # sensor latency + decision + autopilot response
    tilt_max_deg: Annotated[float, Field(gt=0, lt=89)]  # the autopilot's total-tilt limit
    tilt_rate_max_deg_s: Pos
    yaw_rate_max_deg_s: Pos
    yaw_moment_max_nm: Pos | None = None  # the avoid sweep's yaw authority u_ψ,max (eq. 7)
    drag_coeff_n_s2_m2: NonNeg = 0.0  # quadratic body drag, F = c·|v|·v
    thrust_ratio_range: tuple[Frac, Frac]
    braking: Braking
    rotor: Rotor | None = None  # the SITL's rotor model
    controller: Controller = Controller()
    wind: Wind = Wind()
    tilt_model: Literal["cone", "box"] = "cone"

    @model_validator(mode="after")
    def _consistent(self) -> "Vehicle":
        lo, hi = self.thrust_ratio_range
        if not lo < hi:
            raise ValueError(f"thrust_ratio_range: lower end {lo} must be below upper end {hi}")
        rotor_thrust = 4.0 * self.rotor.k_thrust * self.rotor.omega_max_rad_s**2 if self.rotor else self.t_nom_n
        if abs(rotor_thrust - self.t_nom_n) > 0.02 * self.t_nom_n:
            raise ValueError(
                f"t_nom_n: {self.t_nom_n} N disagrees with 4·k_thrust·omega_max² = {rotor_thrust:.4g} N"
            )
        if self.t_max(lo) <= 1.02 * self.mass_kg * G:
            raise ValueError(
                f"thrust_ratio_range: at {lo} the usable thrust {self.t_max(lo):.3g} N cannot hold the "
                f"weight {self.mass_kg * G:.3g} N with a 2 % margin"
            )
        return self

    def require(self, keys: tuple[str, ...], for_what: str) -> "Vehicle":
        """Itself, or one `ContractError` line naming the optional keys `for_what` needs and the file lacks."""
        missing = [k for k in keys if getattr(self, k) is None]
        if missing:
            raise ContractError(f"vehicle {self.name}: {', '.join(missing)} required for {for_what} "
                                "(docs/vehicle-file.md)")
        return self

    # ----- derived quantities (SI, radians) -----
    @property
    def tilt_max(self) -> float:
        return math.radians(self.tilt_max_deg)

    @property
    def tilt_rate_max(self) -> float:
        return math.radians(self.tilt_rate_max_deg_s)

    @property
    def k_psi(self) -> float:
        """K of eq. (7): ψ̈ = K·u_ψ, K = 1/I_zz."""
        return 1.0 / self.inertia_kg_m2[2]

    def t_max(self, thrust_ratio: float) -> float:
        """Total thrust available for translation at `thrust_ratio` = T_max/T_nom [N]."""
        return thrust_ratio * self.collective_max_fraction * self.t_nom_n

    def hover_fraction(self, thrust_ratio: float = 1.0) -> float:
        """Hover thrust as a fraction of the (degraded) maximum thrust."""
        return self.mass_kg * G / (thrust_ratio * self.t_nom_n)

    def reaction_time(self, tilt: float) -> float:
        """Folded reaction time of the avoid contract (DESIGN.md §2): latency plus the time to
        reach `tilt` at the autopilot's attitude-rate limit (treated as no manoeuvre at all)."""
        return self.t_react_s + tilt / self.tilt_rate_max

    def metadata(self) -> dict:
        return self.model_dump(mode="json")

    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON of every parameter (tables record it)."""
        blob = json.dumps(self.metadata(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()


def vehicle_from_dict(data: object, source: str = "vehicle") -> Vehicle:
    return model_from_dict(Vehicle, data, source)


def resolve_vehicle_path(name_or_path: str | Path) -> Path:
    """A path as given, or a shipped vehicle by name (`mambo` → contracts/data/mambo.yaml)."""
    return resolve_named(name_or_path, DATA_DIR)


def load_vehicle(name_or_path: str | Path) -> Vehicle:
    return load_model(Vehicle, resolve_vehicle_path(name_or_path), "vehicle file")
