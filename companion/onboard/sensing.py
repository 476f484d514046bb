"""What the cycle measures (DESIGN.md §5): the estimators the samples feed — E_tr (eq. 29), D_od from the sensors'
claim and from evidence, the thrust ratio, the navigation's health, the loop's own timeliness, the acceleration
flown — and the autopilot's cruise speed as it reported it. Pure: samples in (`take`), values out."""

from __future__ import annotations

import math

from contracts.table import ContractTable

from .ahead import Creep
from .assumptions import e_tr_floor, start_thrust
from .config import Config
from .detection_range import DetectionRange, DetectionRangeParams, RangeNoise
from .estimators import (AccelEstimator, DodEstimator, EtrEstimator, NavHealth, SilenceBudget, ThrustEstimator,
                         Timeliness)
from .mavlink_in import SENSOR_MSGS
from .samples import AutopilotParam, Heading, Implausible, NavStatus, PathTarget, Position, Scan, Throttle
from .supervisor import RAMP_WINDOW_S

A0_S = 0.1  # [s] the recovery brake's stop starts from the acceleration measured over this long (Δv/Δt)

# the samples only the estimators take (by type: `Daemon.take` sends them here first, the others by isinstance)
CYCLE_SAMPLES = frozenset((Position, Heading, PathTarget, Throttle, NavStatus, Scan))


def silence_budget(cfg: Config) -> SilenceBudget:
    """Each obstacle sensor's silence budget as configured (`timeouts.obstacle_periods`, `obstacle_min_s`, capped by
    `obstacle_s`)."""
    t = cfg.timeouts
    return SilenceBudget(t.obstacle_periods, min(t.obstacle_min_s, t.obstacle_s), t.obstacle_s)


class Sensing:
    def __init__(self, cfg: Config, table: ContractTable, adapter, contract: str):
        veh = table.vehicle
        self.adapter = adapter
        self.dod = DodEstimator(cfg.sensors, cfg.contract, cfg.timeouts.obstacle_s, silence_budget(cfg),
                                cover=contract == "stop",
                                range_noise=RangeNoise.of(cfg.detection))
        # D_od from evidence: what the sensors' claim cannot say
        self.truth = DetectionRange(cfg.sensors, params=DetectionRangeParams.of(cfg.detection,
                                                                        cfg.contract.late_detection_confirm_frames))
        self.etr = EtrEstimator(cfg.contract, e_tr_floor(cfg, table))
        self.creep = Creep()  # the direction of travel below walking pace (companion/onboard/ahead.py)
        hover = cfg.thrust.hover_throttle_nominal or veh.controller.thr_hover
        start, self.thrust_start = start_thrust(table, contract)
        self.thrust = ThrustEstimator(cfg.thrust, hover, start, veh.thrust_ratio_range[1])
        self.nav = NavHealth(cfg.timeouts.nav_s)
        self.timing = Timeliness(1.0 / cfg.loop_hz, cfg.timeouts.cycle_jitter_s)
        # the acceleration flown: the speed limit's check (its slow-down starts from it), the approach ramp's, and the
        # recovery brake's start
        self.accel = AccelEstimator(max(RAMP_WINDOW_S, A0_S))
        self.v_cruise = math.nan  # the autopilot's cruise-speed parameter [m/s] (Adapter.cruise_param)
        self._takers = {Position: self._position, Heading: self._heading, Throttle: self._throttle,
                        NavStatus: self._nav_status, Scan: self._scan}

    def take(self, s, ours: bool) -> bool:
        """One sample to the estimators that take it (the 50 Hz kinds by their type); False: none took it. `ours`:
        the autopilot flies the daemon's own setpoints (offboard, or the recovery brake, shown): they, not the
        autopilot's targets, are the commanded path E_tr is measured against."""
        if type(s) is PathTarget:
            if not ours:
                self.etr.command(s.t, s.x, s.y)
            return True
        own = self._takers.get(type(s))
        if own is not None:
            own(s)
            return True
        return self._take_other(s)

    def _position(self, s: Position) -> None:
        self.etr.measure(s.t, s.x, s.y)
        self.dod.add_position(s.t, s.x, s.y)
        self.truth.add_position(s.t, s.x, s.y)

    def _heading(self, s: Heading) -> None:
        self.dod.add_heading(s.t, s.yaw)
        self.truth.add_heading(s.t, s.yaw)
        self.dod.set_speed(s.ground_speed)

    def _throttle(self, s: Throttle) -> None:
        self.thrust.add(s.t, s.throttle, s.roll, s.pitch, s.vz_down, s.in_air)

    def _nav_status(self, s: NavStatus) -> None:
        self.nav.update(s.t, s.source, s.flags)

    def _scan(self, s: Scan) -> None:  # every return to the obstacle logic; the medium's are D_od's evidence as well
        self.truth.add_scan(s)
        self.dod.add_scan(s)

    def _take_other(self, s) -> bool:
        if isinstance(s, AutopilotParam) and self.adapter.cruise_param and s.name == self.adapter.cruise_param[0]:
            v = s.value * self.adapter.cruise_param[1]
            self.v_cruise = v if 0 < v < 100 else math.nan  # nonsense is not a cruise speed
        elif isinstance(s, Implausible) and s.kind not in SENSOR_MSGS:  # a sensor's: its scan covers nothing
            self.nav.fault(s.t, f"{s.kind}: {s.why}")
        else:
            return False
        return True
