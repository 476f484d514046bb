"""Python SITL quadrotor speaking MAVLink like PX4 or ArduPilot Copter (DESIGN.md §6).

Public API: `Sim` (one vehicle + world on a simulated clock), `LockstepLink` (in-process link
carrying real MAVLink bytes, for deterministic tests), `serve.serve` (UDP, real time or sped up),
`load_scenario`. Imports `contracts` only, never `companion`.
"""

from .lockstep import LockstepLink
from .scenario import Scenario, ScenarioError, load_scenario
from .sim import Sim

__all__ = ["Sim", "LockstepLink", "Scenario", "ScenarioError", "load_scenario"]
