"""The daemon's start-up checks (DESIGN.md §5), pure: the autopilot's parameters against the vehicle file
and the contract, and the configured sensors against the direction of flight."""

from __future__ import annotations

from .config import Config


class StartupChecks:
    """DESIGN.md §5 start-up checks: the autopilot's tilt limit and braking limits must be at least what
    the contract assumes (else its braking or swerving is weaker than the table's), a companion-only
    offboard flight needs Land or Hold as offboard-loss action, and the configured sensors must cover
    the direction of flight. Any mismatch refuses to engage (shadow mode still runs)."""

    def __init__(self, adapter, vehicle, cfg: Config, controller_contract: bool = True):
        """`controller_contract`: the table carries E_tr_pred."""
        self.adapter, self.vehicle, self.cfg = adapter, vehicle, cfg
        self.controller_contract = controller_contract
        self.values: dict[str, float] = {}

    def static(self) -> str | None:
        """What refuses at once, before the autopilot answers: the config and the table alone."""
        if not self.controller_contract and self.cfg.contract.e_tr_assumed_m is None:
            return ("the table carries no controller contract (E_tr_pred): build it (contract-guard table etr) "
                    "or state contract.e_tr_assumed_m")
        if not any(abs(((s.orientation_deg + 180) % 360) - 180) <= s.h_fov_deg / 2 for s in self.cfg.sensors):
            return "no configured sensor looks forward"
        return None

    def wanted(self) -> list[str]:
        """The parameters to ask for: the checked ones, and the cruise speed (not checked, but used)."""
        cruise = [self.adapter.cruise_param[0]] if self.adapter.cruise_param else []
        return [c.name for c in self.adapter.param_checks] + cruise

    def take(self, name: str, value: float) -> bool:
        """Record one parameter; True when all checked ones are in."""
        if name in self.wanted():
            self.values[name] = value
        return set(self.values) >= {c.name for c in self.adapter.param_checks}

    def verdict(self) -> tuple[bool, str]:
        v = self.vehicle
        if (why := self.static()) is not None:
            return False, why
        needs = {"tilt_max_deg": v.tilt_max_deg, "braking.accel_max_m_s2": v.braking.accel_max_m_s2,
                 "braking.jerk_max_m_s3": v.braking.jerk_max_m_s3}
        for c in self.adapter.param_checks:
            if c.name not in self.values:
                return False, f"autopilot did not report {c.name}"
            got = self.values[c.name] * c.scale
            if c.what in needs and got < needs[c.what] * 0.999:
                return False, f"{c.name} = {got:g} below the vehicle file's {c.what} = {needs[c.what]:g}"
            if c.offboard_allowed and self.cfg.mode == "offboard" and int(got) not in c.offboard_allowed:
                return False, f"{c.name} = {int(got)}: a companion-only aircraft needs {c.offboard_need}"
        return True, "ok"
