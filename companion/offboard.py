"""Offboard mode's control of the autopilot: entering, flying, leaving. Pure: returns actions.

    off ──engaged, flying──▶ entering (stream setpoints at the current position for `entry_s`,
                                        then ask for OFFBOARD / GUIDED)
        entering ──heartbeat shows it──▶ flying (guidance setpoints every cycle, ≥ 20 Hz)
        flying ──mode changed by someone else──▶ stood_down (stop streaming; never re-enter by itself)
        flying ──route flown──▶ done (Hold)        done / stood_down ──disengaged──▶ off
        any ──hold requested (failsafe, stop, Ctrl-C)──▶ leaving (ask for Hold, stop streaming)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .guidance import OffboardGuidance, Setpoint


@dataclass
class OffboardActions:
    setpoint: Setpoint | None = None
    enter: bool = False  # ask the autopilot for OFFBOARD / GUIDED now
    hold: bool = False  # ask the autopilot for Hold now (the route is complete)
    events: list[tuple[str, dict]] = field(default_factory=list)


@dataclass
class OffboardController:
    guidance: OffboardGuidance
    entry_s: float = 1.0
    state: str = "off"
    _t_state: float = 0.0
    _hold_here: np.ndarray | None = None
    _t_last: float | None = None
    _asked: int = 0
    _braking: bool = False

    def _go(self, t, new, why, acts):
        acts.events.append(("offboard", {"from": self.state, "to": new, "reason": why}))
        self.state, self._t_state = new, t

    def step(self, t, *, engaged: bool, flying: bool, mode: str, by_daemon: bool, p, v, z, yaw,
             v_max: float, a_max: float, discs, stop: bool) -> OffboardActions:
        acts = OffboardActions()
        dt = 0.02 if self._t_last is None else min(max(t - self._t_last, 1e-3), 0.2)
        self._t_last = t
        if stop and self.state in ("entering", "flying"):
            self._go(t, "off", "hold requested", acts)
            return acts
        if self.state in ("done", "stood_down"):  # until asked again (CG_ENGAGE off and on)
            return acts
        if self.state == "off":
            if engaged and flying and not stop:
                self._hold_here = np.asarray(p, float).copy()
                self._hold_z, self._hold_yaw = z, yaw
                self._go(t, "entering", "engaged", acts)
            else:
                return acts
        if self.state == "entering":
            if mode == "offboard" and by_daemon:
                self.guidance.start(p, v)
                self._go(t, "flying", "autopilot in offboard", acts)
            else:
                acts.setpoint = Setpoint(self._hold_here, np.zeros(2), np.zeros(2), self._hold_z, self._hold_yaw,
                                         "hold")
                waited = t - self._t_state
                if waited >= self.entry_s and (self._asked == 0 or waited >= self.entry_s + self._asked * 1.0):
                    acts.enter = True
                    self._asked += 1
                if waited > self.entry_s + 5.0:
                    self._go(t, "off", "autopilot did not enter offboard", acts)
                    acts.setpoint = None
                return acts
        if self.state == "flying":
            if mode != "offboard" or not by_daemon:
                self._go(t, "stood_down", f"{mode} set by someone else", acts)
                return acts
            acts.setpoint = self.guidance.step(t, dt, p, v, v_max, a_max, discs, yaw=yaw)
            if acts.setpoint.mode == "done" and float(np.hypot(*v)) < 0.3:
                acts.hold = True  # the route is flown: hand over to Hold
                self._go(t, "done", "route complete", acts)
                return acts
            if acts.setpoint.mode == "brake" and not self._braking:
                acts.events.append(("no_avoiding_plan", {"notes": self.guidance.last_notes[:3]}))
            self._braking = acts.setpoint.mode == "brake"
        return acts

    @property
    def streaming(self) -> bool:
        return self.state in ("entering", "flying")

