"""Monte Carlo safety campaigns (`contract-guard campaign SPEC.yaml`): lock-step flights of the real daemon
against the real SITL over real MAVLink bytes (`companion/ground/flights.py`), over a sampled scenario
distribution, with the autopilots' own laws and negative controls flown over the same scenarios
(`companion/ground/baselines.py`), on a local process pool or a Dask cluster (`contracts/runner.py`).

Determinism: scenario `k` is sampled from `numpy.random.default_rng([seed, k])` alone, and flight `i`
is scenario `i // len(arms)` flown by arm `arms[i % len(arms)]`; a flight's row depends on (spec, i) and
nothing else, so any flight can be re-flown (`--fly i`) and a pool and a Dask cluster give the same rows.
Results: `OUT/results.jsonl`, one JSON object per flight, appended as each flight ends (fsync'd every SYNC_ROWS
rows or SYNC_S s), so an interrupted campaign resumes where it stopped. The report is `companion/ground/campaign_report.py`.

Spec (YAML, validated like every file here; a range is a number or `[low, high]`, sampled uniformly)::

    name: small
    seed: 1
    scenarios: 20                 # each flown by every arm: flights = scenarios × len(arms)
    vehicles: [mambo, x500]       # shipped names or vehicle files (the table: the vehicle's shipped one)
    personalities: [px4, ardupilot]
    arms: [governor, offboard, px4_cp, ac_avoid, no_guard, governor_x1.15, governor_x1.3, offboard_x1.3,
           offboard_no_etr]
    duration_s: 30
    scenario:
      sensor_range_m: [5, 8]      # the sensor's range (its rating: the daemon caps claims at it)
      r_obst_m: 1.0               # the R_obst the daemon is configured with
      r_obst_true_m: [0.3, 1.0]   # the columns' true radius (above r_obst_m: out of assumption)
      lateral_offset_m: [-0.5, 0.5]
      x_obst_m: [25, 35]          # the first column's distance along the route
      obstacles: [1, 2]           # how many columns (integers), each `min_gap_m` or more beyond the last
      min_gap_m: 10
      wind_factor: [0, 1]         # × the vehicle file's design wind (> 1: beyond design)
      gust_factor: [0, 1]
      cruise_m_s: 8               # the mission's cruise speed (governor arms, no guard)
      sensor_latency_s: [0, 0.05]
      noise_sd_m: [0.0, 0.03]
      # optional (unset: not drawn, the scenario as before): the autopilot's braking, set in the SITL and
      # stated in the vehicle file the daemon flies (a vehicle file calibrated to the user's setting)
      accel_hor_m_s2: [1, 5]      # PX4 MPC_ACC_HOR, ArduPilot WPNAV_ACCEL / 100
      jerk_auto_m_s3: [1, 8]      # PX4 MPC_JERK_AUTO, ArduPilot WPNAV_JERK
      reveal_in_speedup: [0.1, 0.9]  # the first column first seen at this fraction of the speed-up to cruise
      wind_from_deg: 270          # the wind's direction (unset: any); the route flies north, +y is east
      # a cluttered world per scenario (companion/ground/worlds.py), the same for every arm; replaces the columns and
      # the straight route (the mission's waypoints for the governor arms, the daemon's route for offboard)
      world_families: [columns, doorway, cluster, corridor, dead_end]
      sensor_models: [sector, depth_camera, single_beam]  # the SITL's sensor model (unset: sector)
    stresses:                     # optional: scenario k flies stress k mod len(stresses), its own dims and faults
      - {name: fog, faults: [{kind: fog_honest, p: 1}]}
      - {name: crosswind, scenario: {wind_from_deg: 270, lateral_offset_m: [1.5, 2.5]}}
    faults:                       # each kind occurs with probability p, at at_s, with its own parameters
      - {kind: fog_hidden, p: 0.2, at_s: [4, 10], visibility_m: [3, 5]}
      - {kind: fog_honest, p: 0.2, at_s: [4, 10], visibility_m: [3, 5]}
      - {kind: thrust_loss, p: 0.2, at_s: [4, 10], thrust_ratio: [0.65, 0.9]}
      - {kind: sensor_dropout, p: 0.1, at_s: [4, 10], duration_s: [0.5, 2]}
      - {kind: link_loss, p: 0.1, at_s: [4, 10], duration_s: [2, 4]}
      - {kind: bad_nav, p: 0.1, at_s: [4, 10], duration_s: [1, 3]}
      # the daemon's outbound link, from at_s (companion/ground/flights.py OutboundFaults): each datagram lost at `rate` to
      # the end of the flight; everything lost for duration_s; each delayed up to max_s to the end of the flight
      - {kind: cmd_loss, p: 1, at_s: 1, rate: [0.01, 0.05]}
      - {kind: cmd_burst, p: 0.5, at_s: [4, 10], duration_s: 0.5}
      - {kind: cmd_jitter, p: 0.5, at_s: 1, max_s: 0.1}

Arms: `governor` and `offboard` (ours), `px4_cp` and `ac_avoid` (the autopilots' laws as governors; `px4_cp` at
the firmware's jerk MPC_JERK_MAX and resuming as the firmware does, `px4_cp_auto_jerk` the same law at the
mission's MPC_JERK_AUTO),
`no_guard` (daemon off), and the negative controls `<mode>_x<k>` (the contract's speed × k) and
`<mode>_no_etr` (the contract without the E_tr inflation); `governor_brake` is the governor with its recovery brake
(`governor.recovery_brake`: the daemon's own stop in offboard, at the airframe's braking); `governor_brake_proven`
the same with its switch taken as shown from take-off (a measurement of what the brake's own limit buys before a
first stop has shown the switch, not a mode the daemon offers); `governor_ramp` the governor with its approach ramp
(`governor.approach_ramp_m_s` RAMP_ARM_M_S). The governor arms read the SITL's sensor as one DISTANCE_SENSOR (the
nearest return of its field, `shots_per_frame` its bins), `governor_sector` as offboard does, its bins in
OBSTACLE_DISTANCE (and so does every arm in a cluttered world).

In a cluttered world the row also says the world (`world_family`, `world_seed`, `world`, `route`), whether its route
exists (`route_exists`; a dead end has none, and its success is `stopped_short`: standing still short of its end
without contact, after a stop the daemon said), what the vehicle touched (`collided_with`: the SITL's collision truth
against every shape), the seconds airborne (`airborne_s`), and every hold, stop and violation the daemon logged judged
by the perfect observer of companion/ground/false_alarms.py (`judged_alarms`; the unfounded ones listed in
`unfounded_alarms`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import time
from itertools import pairwise
from pathlib import Path
from typing import Annotated, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from companion.onboard.modes import mode_of
from contracts.errors import ContractError
from contracts.lidar import REFERENCE_REFLECTIVITY, extinction_from_met_visibility, visibility_for_extinction
from contracts.yamlfile import load_model, model_from_dict

from .worlds import CLUTTERED, cluttered_world

Num = Annotated[float, Field(allow_inf_nan=False)]
Range = Union[Num, tuple[Num, Num]]
IntRange = Union[int, tuple[int, int]]
OURS = ("governor", "offboard")
BASELINES = ("px4_cp", "px4_cp_auto_jerk", "ac_avoid", "no_guard")
ARM_RE = re.compile(r"^(governor|offboard)(_x(\d+(\.\d+)?)|_no_etr|_claim)?$|^governor_(brake|brake_proven|ramp|sector)$")
SENSOR_FOV_DEG, SENSOR_BIN_DEG = 60, 5  # the SITL sensor every campaign flies: its field and its bins
SENSOR_MODELS = ("sector", "depth_camera", "single_beam")  # the SITL's sensor models (sitl_harness/sensor_models.py)
# the scenario keys of the one column route, which a cluttered world replaces
COLUMN_KEYS = ("columns", "x_obst_m", "lateral_offset_m", "r_obst_true_m", "obstacles")
RAMP_ARM_M_S = 0.3  # the approach ramp of the `governor_ramp` arm
LINK_FAULTS = ("cmd_loss", "cmd_burst", "cmd_jitter")  # the daemon's outbound datagrams (flights.OutboundFaults)
FAULT_KINDS = ("fog_hidden", "fog_honest", "thrust_loss", "sensor_dropout", "link_loss", "bad_nav", *LINK_FAULTS)
ARRIVE_M = 1.0  # within this of the last waypoint: the route is complete
ALT_M = 2.0
STILL_S = 5.0  # stood still this long after setting off: the flight is over
FAULT_WINDOW_S = 5.0  # an arrived flight still flies this long after its last fault (≥ the thrust estimate's p95)
SYNC_ROWS, SYNC_S = 32, 10.0  # results.jsonl is fsync'd at least every this many rows or seconds
LATENCY_BUDGET_S = 0.05  # part of the vehicles' t_react (sensor latency + decision + response)


class CampaignError(ContractError):
    """A one-line, user-facing error about a campaign spec or its output directory."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _check_range(v):
    if isinstance(v, tuple) and v[0] > v[1]:
        raise ValueError(f"range low {v[0]} above high {v[1]}")
    return v


class ScenarioDims(_Strict):
    sensor_range_m: Range = (5.0, 8.0)
    r_obst_m: Annotated[float, Field(gt=0, le=10)] = 1.0
    r_obst_true_m: Range = (0.3, 1.0)
    lateral_offset_m: Range = (-0.5, 0.5)
    x_obst_m: Range = (25.0, 35.0)
    obstacles: IntRange = 1
    min_gap_m: Annotated[float, Field(gt=0)] = 10.0
    wind_factor: Range = (0.0, 1.0)
    gust_factor: Range = (0.0, 1.0)
    cruise_m_s: Range = 8.0
    sensor_latency_s: Range = (0.0, 0.05)
    noise_sd_m: Range = (0.0, 0.03)
    # drawn only when set, from their own stream (`_extra`): an existing spec's scenarios stay as they were
    accel_hor_m_s2: Range | None = None  # the autopilot's MPC_ACC_HOR (WPNAV_ACCEL / 100), the vehicle's braking
    jerk_auto_m_s3: Range | None = None  # MPC_JERK_AUTO (WPNAV_JERK)
    reveal_in_speedup: Range | None = None  # the first column seen at this fraction of the speed-up (not x_obst_m)
    wind_from_deg: Range | None = None  # the wind's direction (unset: uniform)
    # the forward sensor's field of view [°], one bin per SENSOR_BIN_DEG or one bin when narrower (unset: SENSOR_FOV_DEG)
    sensor_fov_deg: Range | None = None
    # a cluttered world per scenario, one of these families drawn uniformly (companion/ground/worlds.py; unset: the
    # columns above), the same world for every arm; it replaces the columns and the straight route
    world_families: Annotated[list[Literal[CLUTTERED]], Field(min_length=1)] | None = None
    # the SITL's sensor model, one drawn uniformly (unset: sector): sector flies the dimensions above, depth_camera
    # and single_beam their datasheets' ranges and faults (sitl_harness/sensor_models.py) with the drawn latency
    sensor_models: Annotated[list[Literal[SENSOR_MODELS]], Field(min_length=1)] | None = None
    # [m] the daemon's `clutter_m` for the sector sensor: the reach of the returns that are no surface, as a user
    # measures it (the SITL's fog returns within 1.5 × OVERLAP_M = 1.5 m); unset: none. Not drawn
    sensor_clutter_m: Annotated[float, Field(ge=0, le=2)] | None = None

    @model_validator(mode="after")
    def _clutter_alone(self):
        if self.world_families is not None and self.reveal_in_speedup is not None:
            raise ValueError("reveal_in_speedup places the first column: not with world_families")
        return self

    @field_validator("*")
    @classmethod
    def _ranges(cls, v):
        return _check_range(v)


class FaultDist(_Strict):
    kind: Literal[FAULT_KINDS]
    p: Annotated[float, Field(ge=0, le=1)]
    at_s: Range = (4.0, 10.0)
    visibility_m: Range = (3.0, 5.0)  # fog
    visibility_frac: Range | None = None  # fog: the visibility as a fraction of the sensor's range (instead of _m)
    # fog: the medium's meteorological visibility [m] (Koschmieder, α = 3.912 / V_met) instead of the two above; the
    # default target is then seen as far as α lets it, past the sensor's range in haze
    met_visibility_m: Range | None = None
    thrust_ratio: Range = (0.65, 0.9)  # thrust_loss
    duration_s: Range = (0.5, 2.0)  # sensor_dropout, link_loss, bad_nav, cmd_burst
    rate: Range = 0.01  # cmd_loss: each datagram's probability of loss
    max_s: Range = 0.1  # cmd_jitter: each datagram's delay, uniform up to this

    @field_validator("at_s", "visibility_m", "visibility_frac", "thrust_ratio", "duration_s", "rate", "max_s")
    @classmethod
    def _ranges(cls, v):
        return _check_range(v)

    @field_validator("rate", "max_s")
    @classmethod
    def _link(cls, v, info):
        hi = 1.0 if info.field_name == "rate" else 10.0
        if not all(0.0 <= x <= hi for x in (v if isinstance(v, tuple) else (v,))):
            raise ValueError(f"must lie in [0, {hi:g}]")
        return v


class Stress(_Strict):
    """A named condition: its overrides of the spec's scenario dimensions, and its faults (None: the spec's)."""

    name: Annotated[str, Field(min_length=1)]
    scenario: dict[str, object] = {}
    faults: list[FaultDist] | None = None


class CampaignSpec(_Strict):
    name: str = "campaign"
    seed: int = 0
    scenarios: Annotated[int, Field(ge=1, le=10_000_000)]
    vehicles: list[str] = ["mambo"]
    personalities: list[Literal["px4", "ardupilot"]] = ["px4", "ardupilot"]
    arms: list[str] = ["governor", "offboard"]
    duration_s: Annotated[float, Field(gt=5, le=600)] = 30.0
    scenario: ScenarioDims = ScenarioDims()
    faults: list[FaultDist] = []
    px4_cp_dist_m: Annotated[float, Field(ge=0)] = 1.0  # CP_DIST for the PX4 baseline (PX4's −1 disables it)
    nav_margin: Annotated[float, Field(ge=0, le=0.9)] = 0.0  # our arms' contract.nav_margin
    stresses: list[Stress] = []  # scenario k flies stresses[k mod len]; none: every scenario the spec's own

    @model_validator(mode="after")
    def _stress_dims(self):
        for j, st in enumerate(self.stresses):
            try:
                ScenarioDims(**{**self.scenario.model_dump(), **st.scenario})
            except ValueError as e:
                raise ValueError(f"stresses.{j}.scenario: {e.errors()[0]['loc'][0]}: {e.errors()[0]['msg']}") from None
        if len({st.name for st in self.stresses}) != len(self.stresses):
            raise ValueError("stresses: names must be distinct")
        return self

    def conditions(self, k: int) -> tuple[str | None, ScenarioDims, list[FaultDist]]:
        """Scenario `k`'s stress name (None without stresses), its scenario dimensions and its faults."""
        if not self.stresses:
            return None, self.scenario, self.faults
        st = self.stresses[k % len(self.stresses)]
        dims = ScenarioDims(**{**self.scenario.model_dump(), **st.scenario})
        return st.name, dims, self.faults if st.faults is None else st.faults

    @field_validator("arms")
    @classmethod
    def _arms(cls, v):
        for a in v:
            if a not in BASELINES and not ARM_RE.match(a):
                raise ValueError(f"unknown arm {a!r}: governor, offboard, {', '.join(BASELINES)}, "
                                 "<mode>_x<k>, <mode>_no_etr, <mode>_claim, governor_brake, governor_brake_proven, "
                                 "governor_ramp or governor_sector")
        if len(set(v)) != len(v) or not v:
            raise ValueError("arms must be distinct and at least one")
        return v

    @field_validator("vehicles", "personalities")
    @classmethod
    def _nonempty(cls, v):
        if not v:
            raise ValueError("at least one")
        return v

    @property
    def flights(self) -> int:
        return self.scenarios * len(self.arms)


def load_spec(path) -> CampaignSpec:
    return load_model(CampaignSpec, path, "campaign spec", CampaignError)


def spec_from_dict(data) -> CampaignSpec:
    return model_from_dict(CampaignSpec, data, "campaign spec", CampaignError)


def spec_hash(spec: CampaignSpec) -> str:
    return hashlib.sha256(json.dumps(spec.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------- sampling

def _u(rng, r) -> float:
    return _u_at(rng.random(), r)  # always one draw: the stream does not depend on the spec's ranges


def _u_at(u: float, r) -> float:
    lo, hi = r if isinstance(r, tuple) else (r, r)
    return float(lo + (hi - lo) * u)


def _i(rng, r) -> int:
    lo, hi = r if isinstance(r, tuple) else (r, r)
    return int(lo + min(int(rng.random() * (hi - lo + 1)), hi - lo))


def sample_scenario(spec: CampaignSpec, k: int) -> dict:
    """Scenario `k`'s parameters, from (seed, k) alone (the same for every arm)."""
    rng = np.random.default_rng([spec.seed & 0xFFFFFFFF, k])
    stress, d, fault_dists = spec.conditions(k)
    s = {"scenario": k,
         "vehicle": spec.vehicles[int(rng.random() * len(spec.vehicles))],
         "personality": spec.personalities[int(rng.random() * len(spec.personalities))],
         "sensor_range_m": _u(rng, d.sensor_range_m), "r_obst_m": d.r_obst_m,
         "r_obst_true_m": _u(rng, d.r_obst_true_m), "lateral_offset_m": _u(rng, d.lateral_offset_m),
         "x_obst_m": _u(rng, d.x_obst_m), "obstacles": _i(rng, d.obstacles),
         "wind_factor": _u(rng, d.wind_factor), "gust_factor": _u(rng, d.gust_factor),
         "wind_from_deg": 360.0 * rng.random(), "cruise_m_s": _u(rng, d.cruise_m_s),
         "sensor_latency_s": _u(rng, d.sensor_latency_s), "noise_sd_m": _u(rng, d.noise_sd_m),
         "sim_seed": int(rng.integers(1, 2**31 - 1))}
    gaps = [d.min_gap_m * (1.0 + 0.5 * rng.random()) for _ in range(max(s["obstacles"] - 1, 0))]
    offs = [_u(rng, d.lateral_offset_m) for _ in gaps]
    s["columns"] = [[s["x_obst_m"], s["lateral_offset_m"]]]
    for g, o in zip(gaps, offs):
        s["columns"].append([s["columns"][-1][0] + g, o])
    _sample_extra(spec.seed, k, d, s)
    if d.sensor_clutter_m:
        s["sensor_clutter_m"] = d.sensor_clutter_m
    if stress is not None:
        s["stress"] = stress
    faults = []
    for f in fault_dists:
        u, at = rng.random(), _u(rng, f.at_s)
        vis, tr, dur = _u(rng, f.met_visibility_m or (f.visibility_m if f.visibility_frac is None else
                                                       f.visibility_frac)), _u(rng, f.thrust_ratio), _u(rng, f.duration_s)
        if f.met_visibility_m is not None:  # the default target's range through the medium (not capped: haze)
            vis = visibility_for_extinction(extinction_from_met_visibility(vis), REFERENCE_REFLECTIVITY,
                                            s["sensor_range_m"])
        elif f.visibility_frac is not None:
            vis *= s["sensor_range_m"]
        # a link fault's size is one more draw, for those kinds only (the other kinds' streams stay as they were)
        size = _u(rng, f.rate if f.kind == "cmd_loss" else f.max_s) if f.kind in ("cmd_loss", "cmd_jitter") else None
        if u < f.p:
            fault = {"kind": f.kind, "at_s": at}
            if f.kind.startswith("fog"):
                fault["visibility_m"] = vis if f.met_visibility_m is not None else min(vis, 0.95 * s["sensor_range_m"])
            elif f.kind == "thrust_loss":
                fault["thrust_ratio"] = tr
            elif f.kind == "cmd_loss":
                fault["rate"] = size
            elif f.kind == "cmd_jitter":
                fault["max_s"] = size
            else:
                fault["duration_s"] = dur
            faults.append(fault)
    s["faults"] = faults
    if "world_family" not in s:
        s["route_end_m"] = s["columns"][-1][0] + 15.0
    s["in_assumption"], s["stresses"] = classify(s)
    return s


def speedup_distance(v: float, a: float, j: float) -> float:
    """The distance a jerk-limited speed-up from rest to `v` takes (acceleration limit `a`, jerk `j`): its mean
    speed is v/2 over v/a + a/j (or 2·√(v/j) when `a` is never reached)."""
    return 0.5 * v * (v / a + a / j if v >= a * a / j else 2.0 * math.sqrt(v / j))


def _sample_extra(seed: int, k: int, d: ScenarioDims, s: dict) -> None:
    """The optional dimensions, from their own stream (seed, k, 1): eight draws whichever are set (the first five are
    what five draws were: a spec without the later dimensions draws as before) — the braking, the reveal, the wind's
    direction, the field of view, then the world family, the world's seed and the sensor model."""
    dims = (d.accel_hor_m_s2, d.jerk_auto_m_s3, d.reveal_in_speedup, d.wind_from_deg, d.sensor_fov_deg)
    if all(r is None for r in dims) and d.world_families is None and d.sensor_models is None:
        return
    u = np.random.default_rng([seed & 0xFFFFFFFF, k, 1]).random(8)
    a, j, frac, wind, fov = (None if r is None else _u_at(x, r) for x, r in zip(u, dims))
    if d.sensor_models is not None:
        s["sensor_model"] = d.sensor_models[min(int(u[7] * len(d.sensor_models)), len(d.sensor_models) - 1)]
    if d.world_families is not None:
        family = d.world_families[min(int(u[5] * len(d.world_families)), len(d.world_families) - 1)]
        with_world(s, family, int(u[6] * (2**31 - 1)))
    if fov is not None:
        s["sensor_fov_deg"] = fov
    if a is not None or j is not None:
        s["braking"] = {"accel_max_m_s2": a, "jerk_max_m_s3": j}
        brk = _braking(s)
        s["braking"] = {"accel_max_m_s2": brk.accel_max_m_s2, "jerk_max_m_s3": brk.jerk_max_m_s3}
    if frac is not None:  # the first column's surface reaches the sensor's range `frac` into the speed-up
        brk = _braking(s)
        x = s["sensor_range_m"] + s["r_obst_true_m"] + frac * speedup_distance(
            s["cruise_m_s"], brk.accel_max_m_s2, brk.jerk_max_m_s3)
        s["columns"] = [[c[0] - s["x_obst_m"] + x, c[1]] for c in s["columns"]]
        s["x_obst_m"] = x
    if wind is not None:
        s["wind_from_deg"] = wind % 360.0


def with_world(s: dict, family: str, seed: int) -> None:
    """Scenario `s` flown in a cluttered world of `family` drawn from `seed` (companion/ground/worlds.py): its world,
    its route, whether the route exists; the one column route's keys go."""
    drawn = cluttered_world(family, seed)
    for key in COLUMN_KEYS:
        s.pop(key, None)
    s.update(world_family=family, world_seed=seed, world=drawn.world, route=drawn.route,
             route_exists=drawn.route_exists)


def route_of(s: dict) -> list[list[float]]:
    """The waypoints scenario `s` flies: its world's route, or straight north past the columns."""
    return s["route"] if "route" in s else [[0.0, 0.0], [s["route_end_m"], 0.0]]


def widest_column_m(s: dict) -> float:
    """The true radius of scenario `s`'s widest column (its world's; 0 without one)."""
    if "r_obst_true_m" in s:
        return s["r_obst_true_m"]
    world = s.get("world", {})
    radii = [c["radius_m"] for c in world.get("columns", [])]
    radii += [c["column_radius_m"][1] for c in world.get("clusters", [])]
    return max(radii, default=0.0)


def _braking(s: dict):
    """The autopilot's braking in scenario `s`: the vehicle file's, with what the scenario drew."""
    from contracts.vehicle import load_vehicle

    brk = load_vehicle(s["vehicle"]).braking
    drawn = {k: v for k, v in (s.get("braking") or {}).items() if v is not None}
    return brk.model_copy(update=drawn)


# faults whose only answer is a Hold: the daemon cannot command the autopilot (link), loses its obstacle sensor (the
# silence before it counts as dead is budgeted as dead time, but the sensor's guarantee is gone), or flies on until
# the estimator is flagged — each breaks a guarantee the contract rests on; they are stresses, flown and reported,
# not in assumption
HOLD_ONLY_FAULTS = ("link_loss", "sensor_dropout", "bad_nav")


def classify(s: dict) -> tuple[bool, list[str]]:
    """(in assumption, stresses) of a sampled scenario. In assumption: obstacles no wider than R_obst,
    wind and gusts within the vehicle's design, sensor latency within its budget, one obstacle at a time in
    the sensed corridor (gaps at least the sensor's range), only faults the contract answers: honest fog,
    thrust losses within the vehicle's range — and every command delivered within its budget. In a cluttered world
    the walls, the stand of poles and the dead end are what the campaign tests, not a breach: the conditions are
    judged as above and its columns by their width (the guard must meet the rest by what it can prove). Link faults are
    judged by the flight's own delivery (`s["delivery"]`, `delivery_of`: the rig's ground truth); before the
    flight it is unknown, and unknown is not in assumption (stress `delivery`)."""
    from contracts.vehicle import load_vehicle

    lo = load_vehicle(s["vehicle"]).thrust_ratio_range[0]
    cols = s.get("columns", [])
    gaps = [b[0] - a[0] for a, b in pairwise(cols)]
    stresses = set()
    for f in s["faults"]:
        if f["kind"] == "fog_hidden":
            stresses.add("hidden_fog")
        elif f["kind"] == "thrust_loss":
            stresses.add("thrust_loss" if f["thrust_ratio"] >= lo else "thrust_below_range")
        elif f["kind"] in HOLD_ONLY_FAULTS or f["kind"] in LINK_FAULTS:
            stresses.add(f["kind"])
    delivery = s.get("delivery")
    if any(f["kind"] in LINK_FAULTS for f in s["faults"]) if delivery is None else delivery["late"] > 0:
        stresses.add("delivery")
    if s["wind_factor"] > 1.0 or s["gust_factor"] > 1.0:
        stresses.add("wind_beyond_design")
    if widest_column_m(s) > s["r_obst_m"]:
        stresses.add("obstacle_wider_than_r_obst")
    breaks = stresses - {"thrust_loss", *LINK_FAULTS}  # a link fault breaks the assumption only through `delivery`
    ok = not breaks and s["sensor_latency_s"] <= LATENCY_BUDGET_S and all(g >= s["sensor_range_m"] for g in gaps)
    return bool(ok), sorted(stresses)


def flown_speed(states) -> tuple[float | None, float]:
    """(the largest Γ_flown = ground speed − V_safe, the time it exceeded `SPEED_TOLERANCE_M_S`) over a flight's
    state samples while the daemon was engaged: the contract evaluated on the flight itself (the review's rule).
    (None, 0) when no engaged sample carries it."""
    from .review_checks import SPEED_TOLERANCE_M_S

    worst, over_s, prev = None, 0.0, None
    for x in states:
        g = x.get("gamma_flown")
        if not x.get("engaged") or g is None or not math.isfinite(g):
            prev = None
            continue
        worst = g if worst is None else max(worst, g)
        if prev is not None and prev[1] > SPEED_TOLERANCE_M_S:
            over_s += x["t"] - prev[0]
        prev = (x["t"], g)
    return worst, over_s


def strict(row: dict) -> tuple[bool, list[str], bool]:
    """The strict classifier: (in contract, why not, judged in full). In contract only where every subsystem's
    guarantee held as stated: in assumption (`classify`), no violation the daemon logged, and ground speed never
    above V_safe by more than the review's tolerance (Γ_flown, `flown_speed`), however the flight came there —
    honest fog that cuts D_od faster than the vehicle can slow is outside the contract while Γ_flown > 0. A row
    flown before Γ_flown was kept is judged by the rest (`judged in full` False)."""
    from .review_checks import SPEED_TOLERANCE_M_S

    why = [] if row["in_assumption"] else ["outside assumption"]
    why += [f"{sub} violation" for sub in dict.fromkeys(v["subsystem"] for v in row.get("violations", []))]
    full = "gamma_flown_max" in row
    g = row.get("gamma_flown_max")
    if g is not None and g > SPEED_TOLERANCE_M_S:
        why.append("ground speed above V_safe")
    if row.get("refused"):
        why.append("refused at start-up")
    return not why, why, full


def flight_of(spec: CampaignSpec, i: int) -> tuple[dict, str]:
    if not 0 <= i < spec.flights:
        raise CampaignError(f"flight {i}: the campaign has flights 0..{spec.flights - 1}")
    return sample_scenario(spec, i // len(spec.arms)), spec.arms[i % len(spec.arms)]


def arm_mode(arm: str) -> str:
    return "offboard" if arm.startswith("offboard") else "governor"


def scenario_dict(s: dict, arm: str) -> dict:
    """The SITL scenario (sitl_harness/scenario.py) of sampled scenario `s` for `arm`."""
    from contracts.vehicle import load_vehicle

    veh = load_vehicle(s["vehicle"])
    off = mode_of(arm_mode(arm)).flies_route
    faults = []
    for f in s["faults"]:
        if f["kind"].startswith("fog"):
            faults.append({"at_s": f["at_s"], "fog": {"visibility_m": f["visibility_m"],
                                                      "report": f["kind"].removeprefix("fog_")}})
        elif f["kind"] == "thrust_loss":
            faults.append({"at_s": f["at_s"], "thrust_ratio": f["thrust_ratio"]})
        elif f["kind"] in LINK_FAULTS:
            continue  # the rig's, not the SITL's (`outbound_faults`)
        else:
            key = {"sensor_dropout": "sensor_dropout_s", "link_loss": "link_dropout_s", "bad_nav": "nav_fault_s"}
            faults.append({"at_s": f["at_s"], key[f["kind"]]: f["duration_s"]})
    world = s["world"] if "world" in s else \
        {"columns": [{"x_m": x, "y_m": y, "radius_m": s["r_obst_true_m"], "name": f"column{j}"}
                     for j, (x, y) in enumerate(s["columns"])]}
    sensor = {"model": s["sensor_model"], "latency_s": s["sensor_latency_s"]} \
        if s.get("sensor_model", "sector") != "sector" else \
        {"fov_deg": fov_of(s), "increment_deg": min(SENSOR_BIN_DEG, fov_of(s)), "max_range_m": s["sensor_range_m"],
         "rate_hz": 20, "latency_s": s["sensor_latency_s"], "noise_sd_m": s["noise_sd_m"]}
    sc = {"name": f"campaign_{s['scenario']}", "vehicle": s["vehicle"], "seed": s["sim_seed"],
          "world": world, "sensor": sensor,
          "wind": {"mean_m_s": veh.wind.mean_m_s * s["wind_factor"], "from_deg": s["wind_from_deg"],
                   "gust_m_s": veh.wind.gust_m_s * s["gust_factor"]},
          "faults": faults}
    # a companion-only aircraft's offboard-loss action: Hold (the start-up check)
    if off or arm.startswith("governor_brake"):
        sc["params"] = {"COM_OBL_RC_ACT": 5} if s["personality"] == "px4" else {}
    if off:
        sc["start"] = {"alt_m": ALT_M}
    else:
        sc["route"] = {"altitude_m": ALT_M, "cruise_speed_m_s": s["cruise_m_s"], "waypoints": route_of(s)}
    if "braking" in s:  # the autopilot's own settings (wire units)
        a, j = s["braking"]["accel_max_m_s2"], s["braking"]["jerk_max_m_s3"]
        sc["params"] = {**sc.get("params", {}), **({"MPC_ACC_HOR": a, "MPC_JERK_AUTO": j} if s["personality"] == "px4"
                                                   else {"WPNAV_ACCEL": 100.0 * a, "WPNAV_JERK": j})}
    return sc


def outbound_faults(s: dict) -> dict | None:
    """The rig's faults of the daemon's outbound link (`flights.OutboundFaults`) in scenario `s` (None: none): a loss
    and a jitter last from their time to the end of the flight, a burst its duration."""
    losses = [(f["at_s"], math.inf, f["rate"]) for f in s["faults"] if f["kind"] == "cmd_loss"] + \
        [(f["at_s"], f["at_s"] + f["duration_s"], 1.0) for f in s["faults"] if f["kind"] == "cmd_burst"]
    jitter = [(f["at_s"], math.inf, f["max_s"]) for f in s["faults"] if f["kind"] == "cmd_jitter"]
    return {"losses": losses, "jitter": jitter} if losses or jitter else None


def delivery_of(rig) -> dict:
    """The flight's command delivery, from the rig's ground truth (not the daemon's view): the budget (the daemon
    config's `t_cmd_s`), the contracted requests, how many reached the autopilot later than it, the worst latency,
    the requests whose own copies never arrived, and how many datagrams the faults dropped and delayed."""

    budget, out = rig.cfg.delivery.t_cmd_s, rig.outbound
    lat = out.latencies(rig.sim.time_s)
    return {"t_cmd_s": budget, "requests": len(lat), "late": sum(x > budget + 1e-9 for _, x in lat),
            "worst_s": round(max((x for _, x in lat), default=0.0), 6),
            "undelivered": sum(r.delivered_s is None for r, _ in lat),
            "dropped": len(out.dropped), "delayed": len(out.delayed)}


def fov_of(s: dict) -> float:
    """The forward sensor's field of view in scenario `s` [°]."""
    return s.get("sensor_fov_deg", SENSOR_FOV_DEG)


def daemon_config(s: dict, arm: str, nav_margin: float = 0.0) -> dict:
    """The daemon's config for scenario `s` and `arm`. The sector sensor is read as its bins (OBSTACLE_DISTANCE) by
    offboard, by `governor_sector` and by every arm in a cluttered world (one nearest return over the field would
    put every wall beside the route ahead); the other governor arms read it as one DISTANCE_SENSOR. Another sensor
    model is read as the rig reads it (flights.Rig: its own message and field)."""
    cfg = {"vehicle": s["vehicle"], "contract": {"r_obst_m": s["r_obst_m"], "nav_margin": nav_margin}}
    bins = [{"kind": "obstacle_distance", "h_fov_deg": fov_of(s)}]
    if mode_of(arm_mode(arm)).flies_route:
        cfg.update({"mode": "offboard", "sensors": bins, "route": {"waypoints": route_of(s), "altitude_m": ALT_M}})
    else:
        cfg["mode"] = "governor"
        beams = max(round(fov_of(s) / SENSOR_BIN_DEG), 1)
        cfg["sensors"] = bins if arm == "governor_sector" or "world_family" in s else \
            [{"kind": "distance_sensor", "h_fov_deg": fov_of(s), "shots_per_frame": beams}]
        if arm.startswith("governor_brake"):
            cfg["governor"] = {"recovery_brake": True}
        elif arm == "governor_ramp":
            cfg["governor"] = {"approach_ramp_m_s": RAMP_ARM_M_S}
    if s.get("sensor_model", "sector") != "sector":
        del cfg["sensors"]
    elif s.get("sensor_clutter_m"):
        for sensor in cfg["sensors"]:
            sensor["clutter_m"] = s["sensor_clutter_m"]
    return cfg


# ----------------------------------------------------------------------------- one flight

class _Trace:
    """Truth at every daemon cycle (for the row only; the daemon never sees it), and the early stop."""

    def __init__(self, end, hold_on_until: float = 0.0):
        """`hold_on_until`: an arrived or held flight is not ended before this time (a fault's detection
        window: a fault that arrives while the daemon holds is to be seen too)."""
        self.end = end
        self.hold_on_until = hold_on_until
        self.rows: list[tuple[float, float, float, float]] = []
        self.t0: float | None = None
        self.t_arrive: float | None = None
        self._still_since: float | None = None

    def __call__(self, rig) -> bool:
        sim = rig.sim
        x, y = float(sim.model.pos[0]), float(sim.model.pos[1])
        v = math.hypot(float(sim.model.vel[0]), float(sim.model.vel[1]))
        t = sim.time_s
        self.rows.append((t, x, y, v))
        if self.t0 is None and math.hypot(x, y) > 0.5:
            self.t0 = t
        if self.t_arrive is None and math.hypot(x - self.end[0], y - self.end[1]) < ARRIVE_M:
            self.t_arrive = t
        # the flight is over when it has arrived, or stood still for STILL_S since it set off (held: a Hold is
        # kept until the pilot decides, which no campaign flight does)
        if self.t0 is None or v >= 0.1:
            self._still_since = None
        elif self._still_since is None:
            self._still_since = t
        over = (self.t_arrive is not None and v < 0.3) or (self._still_since is not None
                                                             and t - self._still_since > STILL_S)
        return over and t >= self.hold_on_until


RESUME_AFTER_S = 0.2  # [s] the law's limit back at MIN_SPEED or above this long before the mission is resumed
RESUME_EVERY_S = 1.0  # [s] a resume asked at most this often (the autopilot's answer takes a moment)


class FirmwareResume:
    """The PX4 law flown as the firmware flies it: Collision Prevention only bounds the velocity, so a limit that
    dips below what the governor can command and rises again lets the vehicle go on. The daemon answers such a
    limit with its "no safe speed" Hold, which a governor keeps until someone changes the mode; here the ground
    station switches the autopilot back to its mission mode (MAV_CMD_DO_SET_MODE: the mission goes on from its
    current item) once the law's own limit (the state samples' `v_max`) has been at the least commandable speed or
    above for `RESUME_AFTER_S`. Wraps the flight's `_Trace` (called every cycle)."""

    def __init__(self, trace: "_Trace"):
        self.trace = trace
        self.resumed: list[float] = []  # when the mission was resumed
        self._ok_since: float | None = None
        self._asked = -math.inf

    def __call__(self, rig) -> bool:
        from .baselines import MIN_SPEED

        st = rig.log.states[-1] if rig.log.states else None
        t = rig.sim.time_s
        held = st is not None and st.get("state") == "holding" and any(
            e["cause"] == "no safe speed" for e in rig.log.named("failsafe")[-1:])
        if held and (st.get("v_max") or 0.0) >= MIN_SPEED:
            self._ok_since = t if self._ok_since is None else self._ok_since
            if t - self._ok_since >= RESUME_AFTER_S and t - self._asked >= RESUME_EVERY_S:
                from .flights import mav

                rig.command(mav.MAV_CMD_DO_SET_MODE, *rig.daemon.adapter.set_mode_params("mission", True))
                self._asked = t
                self.resumed.append(t)
        else:
            self._ok_since = None
        return self.trace(rig)


def _policy(arm: str, s: dict, spec: CampaignSpec):
    """The speed policy an arm flies (None: the contract's own): a baseline law, as a function of the daemon's
    Config (its sensors' mounts), or a negative control. The PX4 law brakes at the autopilot's MPC_ACC_HOR (the
    scenario's) and the firmware's MPC_JERK_MAX (`px4_cp`), or the mission's MPC_JERK_AUTO (`px4_cp_auto_jerk`);
    AC_Avoid is not limited above the mission's cruise speed."""
    from .baselines import ArduPilotAcAvoid, Px4CollisionPrevention, Scaled, WithoutEtr, mounts

    if arm in ("px4_cp", "px4_cp_auto_jerk"):
        brk = _braking(s)
        # the firmware's jerk (MPC_JERK_MAX, its default); the variant the mission's (MPC_JERK_AUTO, drawn)
        jerk = dict(jerk=brk.jerk_max_m_s3, jerk_param="MPC_JERK_AUTO", name=arm) if arm == "px4_cp_auto_jerk" else {}
        return lambda cfg: Px4CollisionPrevention(sensors=mounts(cfg.sensors), cp_dist_m=spec.px4_cp_dist_m,
                                                  acc_hor=brk.accel_max_m_s2, cruise_m_s=s["cruise_m_s"], **jerk)
    if arm == "ac_avoid":
        return lambda cfg: ArduPilotAcAvoid(cruise_m_s=s["cruise_m_s"], sensors=mounts(cfg.sensors))
    m = ARM_RE.match(arm)
    if m is None or m.group(2) is None:
        return None
    if m.group(2) == "_claim":  # the contract's own speed; its D_od the sensor's claim (`fly`)
        return None
    return WithoutEtr() if m.group(2) == "_no_etr" else Scaled(float(m.group(3)))


def _with_braking(s: dict):
    """The table's vehicle with the scenario's drawn braking (None: none drawn) — the vehicle file a user
    calibrates to their autopilot's settings; the stop contract is computed from it in closed form."""
    if "braking" not in s:
        return None
    from contracts.table import ContractTable

    def wrap(t):
        veh = t.vehicle.model_copy(update={"braking": _braking(s)})
        out = ContractTable(t.meta, veh, t.avoid, t.e_pred, t.path, t.e_pred_stop, t.e_pred_brake)
        out.signature = t.signature
        return out
    return wrap


def fly(spec: CampaignSpec, i: int, keep_rig: bool = False):
    """Fly flight `i`; its result row (and the rig, when asked)."""
    from .baselines import TrustTheClaim
    from .flights import Rig, engage_and_fly, fly_mission

    s, arm = flight_of(spec, i)
    mode = arm_mode(arm)
    rig = Rig(scenario_dict(s, arm), s["personality"], config=daemon_config(s, arm, spec.nav_margin),
              policy=_policy(arm, s, spec), table_wrapper=_with_braking(s), outbound=outbound_faults(s))
    # a fault shortly before or after the arrival is still given FAULT_WINDOW_S to be detected (the flight
    # hovers at the end): ending at arrival counted 0.1–2 s-old faults as missed
    trace = _Trace(tuple(route_of(s)[-1]), max((f["at_s"] for f in s["faults"]), default=0.0) + FAULT_WINDOW_S)
    if arm == "no_guard":
        rig.daemon_on = False
    if arm == "governor_brake_proven":  # the brake's switch taken as shown from the start (a measurement)
        rig.daemon.cycle.brake.shown()
    if arm.endswith("_claim"):  # negative control: no detection range from evidence
        rig.daemon.cycle.sensing.truth = TrustTheClaim(rig.daemon.cfg.sensors)
    seconds = spec.duration_s
    until = FirmwareResume(trace) if arm in ("px4_cp", "px4_cp_auto_jerk") else trace
    obs = None
    if "world_family" in s:  # a cluttered world: a perfect observer judges every alarm (false_alarms.py)
        from .false_alarms import Observer

        obs = Observer(rig)
    flown = until if obs is None else _Observed(obs, until)
    if mode_of(mode).flies_route:
        engage_and_fly(rig, seconds, flown)
    else:
        fly_mission(rig, seconds, flown)
    if rig.outbound is not None:  # classified by its own delivery
        s = {**s, "delivery": delivery_of(rig)}
        s["in_assumption"], s["stresses"] = classify(s)
    row = result_row(spec, i, s, arm, rig, trace)
    if isinstance(until, FirmwareResume):
        row["resumed_s"] = until.resumed
    if obs is not None:
        row.update(clutter_outcome(rig, obs, row))
    return (row, rig) if keep_rig else row


def keep_flight(rig, s: dict, arm: str, out: Path, i: int) -> tuple[Path, Path]:
    """A re-flown flight kept for its review: the daemon's records as an event log (`out/flight-i/`, what `contract-guard
    review` reads, opened by the `start` record a daemon's run writes) and the SITL scenario it flew
    (`out/scenario-i.json`, whose world `review --scenario` draws beneath the track). Returns both paths."""
    from companion.onboard.eventlog import EventLog

    log_dir, scenario = out / f"flight-{i}", out / f"scenario-{i}.json"
    scenario.write_text(json.dumps(_plain(scenario_dict(s, arm)), indent=1))
    table = rig.daemon.table
    log = EventLog(log_dir, clock=lambda: 0.0, commit="none", max_bytes=1 << 62)
    log.event(0.0, "start", mode=rig.cfg.mode, vehicle=table.vehicle.name, table=str(table.path), connect="lock-step")
    for rec in sorted(rig.log.states + rig.log.events, key=lambda r: r["t"]):
        fields = {k: v for k, v in rec.items() if k not in ("t", "event")}
        if "event" in rec:
            log.event(rec["t"], rec["event"], **fields)
        else:
            log.state(rec["t"], **fields)
    log.close()
    return log_dir, scenario


class _Observed:
    """A flight's stop rule with the perfect observer's look at the truth before it, once a cycle."""

    def __init__(self, obs, until):
        self.obs, self.until = obs, until

    def __call__(self, rig) -> bool:
        self.obs.watch()
        return self.until(rig)


def clutter_outcome(rig, obs, row: dict) -> dict:
    """What a cluttered flight adds to its row: the seconds airborne, every hold, stop and violation the daemon logged
    judged by the perfect observer (false_alarms.judge: unfounded ones listed), what it touched, and whether it ended
    stopped short without contact with a stop it said (where no route exists, that is the success)."""
    from .false_alarms import STOPS, judged_events

    events = judged_events(rig, obs)
    unfounded = [{k: e[k] for k in ("t", "kind", "cause") if k in e} for e in events if not e["founded"]]
    v = rig.sim.model.vel
    still = math.hypot(float(v[0]), float(v[1])) < 0.3
    said = any(e["event"] in STOPS for e in rig.log.events)  # a Hold, a "no safe speed" stop or "no avoiding plan"
    return {"airborne_s": obs.airborne_s(), "judged_alarms": len(events), "unfounded_alarms": unfounded,
            "collided_with": sorted({c.obstacle_name for c in rig.truth["collisions"]}),
            "stopped_short": bool(still and said and not row["collided"] and not row["route_completed"])}


def _surface_distance(rig, x: float, y: float) -> float:
    """The true distance from (x, y) to the nearest surface of the flight's world, whatever its shape."""
    return rig.sim.world.clearance(x, y, ALT_M)[0]


def _first(items, pred):
    return next((e for e in items if pred(e)), None)


def masked_by_link_loss(f: dict, faults: list[dict], observe_s: float = 0.5) -> bool:
    """A fault the daemon cannot observe (so an undetected one is no miss): another kind's, of which less than
    `observe_s` lies outside the link losses (nothing of the autopilot is heard during one, and its first messages
    after it take a moment: evidence flight 941's bad navigation estimate came and went inside a loss, flight 2440's
    outlasted one by 0.12 s)."""
    if f["kind"] == "link_loss" or "duration_s" not in f:
        return False
    t0, t1 = f["at_s"], f["at_s"] + f["duration_s"]
    hidden = sum(max(0.0, min(t1, g["at_s"] + g["duration_s"]) - max(t0, g["at_s"]))
                 for g in faults if g["kind"] == "link_loss")
    return hidden > 0.0 and f["duration_s"] - hidden < observe_s


def fault_outcomes(s: dict, arm: str, rig, trace: _Trace) -> list[dict]:
    """Per fault of the flight: the subsystem it was attributed to, the detection latency, the action."""
    if arm == "no_guard":
        return []
    log, out = rig.log, []
    lo = rig.daemon.table.vehicle.thrust_ratio_range[0]
    for f in s["faults"]:
        t0, kind = f["at_s"], f["kind"]
        after = [e for e in log.events if e["t"] >= t0 - 1e-9]
        states = [x for x in log.states if x["t"] >= t0 - 1e-9]
        # a fault occurs in the flight when it starts before the route is flown (after the arrival the daemon
        # has handed over to Hold and is done; the flight then goes on FAULT_WINDOW_S only for detection)
        det, subsystem = None, None
        occurs = rig.sim.time_s > t0 and (trace.t_arrive is None or t0 <= trace.t_arrive)
        if kind == "fog_hidden":
            # detectable only once an obstacle came inside the claimed range after the fault
            occurs = occurs and any(_surface_distance(rig, x, y) < s["sensor_range_m"] for t, x, y, _ in trace.rows
                                    if t >= t0)
            e = _first(after, lambda e: e["event"] == "violation_start" and e["subsystem"] == "navigation")
            det, subsystem = (e["t"], "navigation") if e else (None, None)
        elif kind == "fog_honest":
            x = _first(states, lambda x: x["d_od"] <= f["visibility_m"] + 0.05)
            det, subsystem = (x["t"], "navigation (reported)") if x else (None, None)
        elif kind == "thrust_loss":
            if f["thrust_ratio"] < lo:
                e = _first(after, lambda e: e["event"] == "violation_start" and e["subsystem"] == "actuators")
                det = e["t"] if e else None
            else:
                x = _first(states, lambda x: x["thrust_ratio"] <= f["thrust_ratio"] + 0.05)
                det = x["t"] if x else None
            subsystem = "actuators" if det is not None else None
        elif kind == "sensor_dropout":
            # D_od = 0 in a state sample, or the Hold it causes: a drop-out just over the obstacle time-out makes
            # D_od 0 for a cycle or two, between 10 Hz state samples (evidence flights 200, 2832)
            x = _first(states, lambda x: x["d_od"] == 0.0)
            stale_by = t0 + f["duration_s"] + rig.cfg.timeouts.obstacle_s
            e = _first(after, lambda e: e["event"] == "failsafe" and e["cause"] == "no safe speed" and e["t"] <= stale_by)
            t_det = min([y["t"] for y in (x, e) if y is not None], default=None)
            det, subsystem = (t_det, "navigation (stale obstacle data)") if t_det is not None else (None, None)
        elif kind == "link_loss":
            e = _first(after, lambda e: e["event"] == "link" and e.get("status") == "down")
            det, subsystem = (e["t"], "link") if e else (None, None)
        elif kind == "bad_nav":
            e = _first(after, lambda e: e["event"] == "failsafe" and e["cause"] == "bad navigation estimate")
            det, subsystem = (e["t"], "navigation (estimator)") if e else (None, None)
        elif kind in LINK_FAULTS:  # it occurs where a command came late (the ground truth); the daemon's word on it
            occurs = occurs and s["delivery"]["late"] > 0
            e = _first(after, lambda e: e["event"] == "violation_start" and e["subsystem"] == "delivery")
            det, subsystem = (e["t"], "delivery") if e else (None, None)
        occurs = occurs and (det is not None or not masked_by_link_loss(f, s["faults"]))  # unseen: not a miss
        action = None
        if det is not None:
            acts = [e for e in after if e["t"] >= det - 1e-9 and e["t"] <= det + 1.0 and
                    e["event"] in ("failsafe", "hold_trigger", "limit_change", "no_avoiding_plan")]
            action = acts[0]["event"] + (f": {acts[0]['cause']}" if "cause" in acts[0] else "") if acts else "logged"
        out.append({"kind": kind, "at_s": t0, "occurs": bool(occurs), "detected": det is not None,
                    "subsystem": subsystem, "latency_s": None if det is None else round(det - t0, 6),
                    "action": action})
    return out


def result_row(spec: CampaignSpec, i: int, s: dict, arm: str, rig, trace: _Trace) -> dict:
    truth = rig.truth
    cols = truth["collisions"]
    t_hit = cols[0].time_s if cols else None
    contact = None
    if t_hit is not None:
        contact = _first(trace.rows, lambda r: r[0] >= t_hit - 1e-9)
    t0 = trace.t0
    t_end = trace.t_arrive if trace.t_arrive is not None else (trace.rows[-1][0] if trace.rows else 0.0)
    moving = [r[3] for r in trace.rows if t0 is not None and t0 <= r[0] <= t_end and r[3] > 0.3]
    log = rig.log
    viol = [{"subsystem": e["subsystem"], "t": e["t"]} for e in log.named("violation_start")]
    g_max, g_over_s = flown_speed(log.states)
    row = {
        "index": i, "arm": arm, "mode": arm_mode(arm), **s,
        "collided": bool(cols), "contact_speed_m_s": None if contact is None else contact[3],
        "min_clearance_m": _finite(truth["min_clearance_m"]),
        "mean_speed_m_s": float(np.mean(moving)) if moving else 0.0,
        "max_speed_m_s": max((r[3] for r in trace.rows), default=0.0),
        "route_completed": trace.t_arrive is not None,
        "time_to_destination_s": None if trace.t_arrive is None or t0 is None else trace.t_arrive - t0,
        "violations": viol,
        "fault_outcomes": fault_outcomes(s, arm, rig, trace),
        "failsafes": [e["cause"] for e in log.named("failsafe")],
        # Holds commanded (one per cycle that commanded one, whatever its number of causes; a cause that
        # arrives while already holding is logged with its own action and is not another Hold)
        "holds": len({e["t"] for e in log.events if e["event"] in ("failsafe", "hold_trigger")
                      and e.get("action") == "hold"}),
        "sim_time_s": rig.sim.time_s,
        "gamma_flown_max": g_max, "gamma_flown_over_s": g_over_s,
        # the daemon's start-up checks refused to engage (None: they passed, or were never judged): said, and its
        # flight is the autopilot's alone
        "refused": next((e["reason"] for e in log.named("startup_check") if not e["ok"]), None),
    }
    row["in_contract"], row["outside_contract"], _ = strict(row)
    return row


def _finite(x):
    return float(x) if x is not None and math.isfinite(x) else None


def row_json(row: dict) -> str:
    return json.dumps(_plain(row), sort_keys=True, separators=(",", ":"), allow_nan=False)


def _plain(v):
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    return v


# ----------------------------------------------------------------------------- the campaign

def _task(task) -> list[str]:
    """One flight on a worker (module level: picklable): the row as its JSON line."""
    spec_data, i = task
    return [row_json(fly(spec_from_dict(spec_data), i))]


def refly_command(spec_path, i: int) -> str:
    return f"contract-guard campaign {spec_path} --fly {i}"


def read_rows(out: Path) -> list[dict]:
    """The rows written so far, by index (a torn last line — an interrupted write — is ignored)."""
    rows = {}
    p = Path(out) / "results.jsonl"
    if p.exists():
        for line in p.read_text().splitlines():
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue
            rows[r["index"]] = r
    return [rows[k] for k in sorted(rows)]


def same_campaign(old: dict, spec: CampaignSpec) -> bool:
    """Whether the spec stored in an output directory is this one but for `scenarios` and its unset fields: a campaign
    may be extended (or cut short) by its number of scenarios — flight i depends on (spec, i) only."""
    new = spec.model_dump(mode="json")
    return _set({k: v for k, v in old.items() if k != "scenarios"}) == \
        _set({k: v for k, v in new.items() if k != "scenarios"})


def _set(v):
    """A spec's data without its unset (None) fields, at every depth: a dimension added since a campaign was begun
    and left unset there is the same campaign."""
    if isinstance(v, dict):
        return {k: _set(x) for k, x in v.items() if x is not None}
    return [_set(x) for x in v] if isinstance(v, list) else v


def _drop_torn_line(p: Path) -> None:
    """An interrupted write leaves a last line without its newline: cut it (its flight is flown again)."""
    if not p.exists():
        return
    data = p.read_bytes()
    if data and not data.endswith(b"\n"):
        with open(p, "r+b") as f:
            f.truncate(data.rfind(b"\n") + 1)


def run(spec: CampaignSpec, out, *, workers: int = 1, scheduler: str | None = None, progress: bool = True,
        spec_path: str = "SPEC.yaml", limit: int | None = None) -> list[dict]:
    """Fly every flight not yet in `OUT/results.jsonl` (resume); returns all rows by index.
    `limit`: stop after that many new flights (benchmarks, tests of resuming)."""
    from tqdm import tqdm

    from contracts.runner import BuildInterrupted, run_tasks

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = out / "campaign.json"
    h = spec_hash(spec)
    if meta.exists():  # the same campaign, its number of scenarios aside (flight i does not depend on it)
        old = json.loads(meta.read_text())
        if not same_campaign(old.get("spec") or {}, spec):
            raise CampaignError(f"{out}: holds another campaign (spec hash {old.get('spec_hash')}, this one {h}); "
                                "use another --out")
    meta.write_text(json.dumps({"spec_hash": h, "spec": spec.model_dump(mode="json"),
                                "spec_path": str(spec_path)}, indent=1, sort_keys=True))
    _drop_torn_line(out / "results.jsonl")
    done = {r["index"] for r in read_rows(out)}
    todo = [i for i in range(spec.flights) if i not in done]
    if limit is not None:
        todo = todo[:limit]
    data = spec.model_dump(mode="json")
    # one pool (or the in-process loop, or the cluster) for the whole run: a row is written as its flight ends, in
    # any order, and fsync'd every SYNC_ROWS rows or SYNC_S seconds (a kill loses at most those: flown again)
    bar = tqdm(total=spec.flights, initial=len(done), desc=spec.name, unit="flight", disable=not progress)
    flown, synced = [len(done)], [len(done), time.monotonic()]
    try:
        with open(out / "results.jsonl", "a") as f:
            def row(_, lines) -> None:
                f.write(lines[0] + "\n")
                flown[0] += 1
                bar.update(1)
                if flown[0] - synced[0] >= SYNC_ROWS or time.monotonic() - synced[1] >= SYNC_S:
                    f.flush()
                    os.fsync(f.fileno())
                    synced[:] = [flown[0], time.monotonic()]

            try:
                run_tasks([(data, i) for i in todo], workers, scheduler, False, len(todo), _task, on_result=row)
            finally:  # also when interrupted: every row handed over is on disk
                f.flush()
                os.fsync(f.fileno())
    except (BuildInterrupted, KeyboardInterrupt):  # Ctrl-C, or SIGTERM through the CLI: the rows written stay
        bar.close()
        raise BuildInterrupted(f"interrupted after {flown[0]} of {spec.flights} flights, kept in "
                               f"{out / 'results.jsonl'}: run the same command to continue") from None
    bar.close()
    return [r for r in read_rows(out) if r["index"] < spec.flights]
