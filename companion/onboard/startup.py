"""The daemon's start-up checks (DESIGN.md §5), pure: the autopilot's parameters against the vehicle file
and the contract, and the configured sensors against the direction of flight."""

from __future__ import annotations

import math

from .assumptions import least_e_tr
from .config import Config, is_network_link
from .coverage import refusal as coverage_refusal
from .outbox import EMPTY, Outbox

WAIT_S = 5.0  # a parameter asked for and not answered in this long counts as missing
RESTART_CHECK_S = 10.0  # the checks re-run after an autopilot restart at most this often
# ArduPilot's GUIDED follows a velocity (or acceleration) target for GUID_TIMEOUT seconds after the last one
# arrives, then stops; position targets never time out (ArduCopter/Parameters.cpp `guided_timeout`, default 3 s,
# range 0.1-5 s; ardupilot wiki, Copter commands in Guided mode: "re-send every second"). The daemon streams
# velocity setpoints every cycle, so:
# - longer than SETPOINT_TIMEOUT_MAX_S, a daemon that stops leaves the vehicle flying its last velocity blind for
#   longer than ArduPilot's own default (3 s: 15 m at 5 m/s), the worst case the README's failure table states;
# - shorter than one setpoint period plus the lateness the daemon itself tolerates before handing over
#   (timeouts.cycle_late_s), the vehicle would stop between two setpoints of a running daemon: offboard useless.
SETPOINT_TIMEOUT_MAX_S = 3.0


def setpoint_timeout_problem(name: str, value: float | None, cfg: Config) -> str | None:
    """Why the autopilot's offboard setpoint time-out `name` = `value` [s] is refused for this config, or None."""
    lo = 1.0 / cfg.loop_hz + cfg.timeouts.cycle_late_s
    if value is None or not math.isfinite(value) or value <= 0:
        return f"{name} is unset ({value}): offboard needs the autopilot to stop when setpoints stop"
    if value > SETPOINT_TIMEOUT_MAX_S:
        return (f"{name} = {value:g} s: the vehicle would fly its last setpoint blind that long if the daemon "
                f"stopped (at most {SETPOINT_TIMEOUT_MAX_S:g} s; 0.5-1 s recommended)")
    if value < lo:
        return (f"{name} = {value:g} s: shorter than one setpoint period plus timeouts.cycle_late_s ({lo:g} s), "
                "the vehicle would stop between setpoints (0.5-1 s recommended)")
    return None


NOT_FORWARD = "no configured sensor looks forward"


def looks_forward(sensors) -> bool:
    """Some configured sensor's field of view holds the direction of flight (the body's forward axis)."""
    return any(abs(((s.orientation_deg + 180) % 360) - 180) <= s.h_fov_deg / 2 for s in sensors)


def unsigned_refusal(cfg: Config) -> str | None:
    """Why a commanding mode refuses to engage on this link, or None: over a network link (not loopback, not
    serial) the daemon engages only with signing on, or with unsigned operation accepted by name
    (`link.accept_unsigned`, WEAKENED in the banner). Anyone who can reach an unsigned network link can send
    the daemon sensor data and forge the autopilot's address."""
    lk = cfg.link
    if not cfg.daemon_mode.commands or lk.signing_key_file is not None or lk.accept_unsigned \
            or not is_network_link(lk.connect):
        return None
    return (f"unsigned on the network link {lk.connect}: {cfg.mode} mode engages only with signing "
            "(link.signing_key_file) or with link.accept_unsigned: true (weaker)")


class StartupChecks:
    """DESIGN.md §5 start-up checks: the autopilot's tilt limit and braking limits must be at least what
    the contract assumes (else its braking or swerving is weaker than the table's), a companion-only
    offboard flight needs Land or Hold as offboard-loss action, and the configured sensors must cover
    the direction of flight and cover its swept corridor at some range (`companion.onboard.coverage`). Any
    mismatch refuses to engage (shadow mode still runs).

    Over time (`ok`: True, False, or None while pending): asked at link-up and after an autopilot restart
    (`asked`, `restarted`), decided when every checked parameter is in or `WAIT_S` after asking (`finish`,
    `deadline`), the verdict logged and said when it changes — each an `Outbox` for MAVLink-out."""

    def __init__(self, adapter, vehicle, cfg: Config, controller_contract: bool = True):
        """`controller_contract`: the table carries E_tr_pred."""
        self.adapter, self.vehicle, self.cfg = adapter, vehicle, cfg
        self.controller_contract = controller_contract
        self.values: dict[str, float] = {}
        # the recovery brake's own checks (governor.recovery_brake): (ok, why), None while pending or not asked for
        self.brake: tuple[bool, str] | None = None
        self.said: tuple[bool, str] | None = None  # the verdict last logged
        self.t_asked: float | None = None
        self._t_restart = -math.inf
        # the link's seats two or more addresses claim: (system, component) → why (`contest`); refuses while any
        self.contests: dict[tuple[int, int], str] = {}
        why = self.static()
        self.ok: bool | None = None if why is None else False  # refused before the autopilot is even heard
        if why is not None:
            self.said = (False, why)

    @property
    def ok(self) -> bool | None:
        """True, False, or None while pending; False too while a seat on the link is contested."""
        return False if self.contests else self._ok

    @ok.setter
    def ok(self, value: bool | None) -> None:
        self._ok = value

    @property
    def reason(self) -> str:
        if self.contests:
            return next(iter(self.contests.values()))
        return self.said[1] if self.said is not None else "the start-up checks are pending"

    def contest(self, ids: tuple[int, int], why: str | None) -> None:
        """The link says two or more addresses claim the source `ids` (`why`), or no longer (None): no engaging
        while any source is claimed twice (an engaged flight then holds, as for any failed check in flight)."""
        if why is None:
            self.contests.pop(ids, None)
        else:
            self.contests[ids] = why

    def asked(self, t: float) -> Outbox:
        """The link is up (the parameters are asked for now): the deadline starts; a refusal is said again, now
        that the ground station can hear it."""
        if self.ok is None:
            self.t_asked = t
        return Outbox(texts=((3, f"CG: refusing to engage: {self.reason}"),)) if self.ok is False else EMPTY

    def restarted(self, t: float) -> bool:
        """The autopilot restarted: True when the checks run again (at most every RESTART_CHECK_S: a boot clock
        that keeps going back is a fault, not a restart a second)."""
        if t - self._t_restart < RESTART_CHECK_S:
            return False
        self._t_restart = t
        self.values, self.t_asked, self.said, self.brake = {}, t, None, None
        self.ok = None if self.static() is None else False
        return True

    def deadline(self, t: float) -> Outbox:
        """What did not answer within WAIT_S counts as missing."""
        if self.ok is None and self.t_asked is not None and t - self.t_asked > WAIT_S:
            return self.finish(t)
        return EMPTY

    def finish(self, t: float) -> Outbox:
        """The verdict, logged and said when it changes (a ground station reading every parameter makes the
        autopilot send them all again)."""
        ok, reason = self.verdict()
        self.ok = ok
        if self.cfg.governor.recovery_brake:
            self.brake = self.brake_verdict(ok, reason)
        if (ok, reason) == self.said:
            return EMPTY
        self.said = (ok, reason)
        return Outbox(events=(("startup_check", {"ok": ok, "reason": reason}),),
                      texts=() if ok else ((3, f"CG: refusing to engage: {reason}"),))

    def static(self) -> str | None:
        """What refuses at once, before the autopilot answers: the config and the table alone."""
        if not self.controller_contract and self.cfg.contract.e_tr_assumed_m is None:
            return ("the table carries no controller contract (E_tr_pred): build it (contract-guard table etr) "
                    "or state contract.e_tr_assumed_m")
        if not looks_forward(self.cfg.sensors):
            return NOT_FORWARD
        e_tr = least_e_tr(self.cfg, self.controller_contract)
        return coverage_refusal(self.cfg.sensors, self.vehicle.r_body_m, e_tr) or \
            unsigned_refusal(self.cfg)

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
        return (True, "ok") if not self.cfg.daemon_mode.flies_route else self._offboard_checks()

    def _offboard_checks(self) -> tuple[bool, str]:
        """What flying in offboard needs: the autopilot has an offboard mode (PX4 OFFBOARD, ArduPilot GUIDED) and,
        for a companion-only aircraft, Land or Hold as its offboard-loss action (the parameters reported)."""
        try:
            self.adapter.set_mode_params("offboard", True)
        except (KeyError, NotImplementedError):  # no such mode in the adapter's table; the generic adapter has none
            return False, "the autopilot reports no offboard mode"
        for c in self.adapter.param_checks:
            if not c.offboard_allowed:
                continue
            if c.name not in self.values:
                return False, f"autopilot did not report {c.name}"
            got = int(self.values[c.name] * c.scale)
            if got not in c.offboard_allowed:
                return False, f"{c.name} = {got}: a companion-only aircraft needs {c.offboard_need}"
        for c in self.adapter.param_checks:
            if c.setpoint_timeout:
                got = self.values.get(c.name)
                why = setpoint_timeout_problem(c.name, None if got is None else got * c.scale, self.cfg)
                if why:
                    return False, why
        return True, "ok"

    def brake_verdict(self, ok: bool, reason: str) -> tuple[bool, str]:
        """The recovery brake's own start-up checks: the daemon's checks pass, and offboard's
        (`_offboard_checks`); failing, the governor flies the autopilot's Hold's stop contract."""
        if not ok:
            return False, f"the start-up checks refuse: {reason}"
        ok, why = self._offboard_checks()
        return (True, "ok: offboard allowed and the offboard-loss action is Hold or Land") if ok else (False, why)
