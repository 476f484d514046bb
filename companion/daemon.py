"""The on-board daemon: one loop (default 50 Hz) over one MAVLink connection (DESIGN.md §5). Thin: it
polls, steps and runs; the work is in the pipeline it wires together.

    MAVLink in (mavlink_in.py: samples) → cycle (cycle.py: estimators → supervisor → guidance, pure)
              → MAVLink out (mavlink_out.py: commands, setpoints, STATUSTEXT, parameters); every step → event log

`Daemon.poll()` drains the link, `Daemon.step()` runs one cycle at the injected clock's time. The
real-time runner (`run`) calls both at `loop_hz`; lock-step tests call them between simulator steps.
Nothing here raises on bad input: a malformed message is counted and dropped, a failed log write is
the log's problem, a missing stream leads to the supervisor's safe action.
"""

from __future__ import annotations

import math
import time

from contracts.table import ContractTable

from .autopilot_base import MAV_CMD_DO_CHANGE_SPEED
from .autopilots import adapter_for
from .calibration_holds import CalibrationHolds, read_legs
from .config import Config
from .cycle import CYCLE_SAMPLES, Cycle
from .guidance import InlinePlanning, ThreadedPlanning
from .logschema import NVF, STATE_FIELDS
from .mavlink_in import MavlinkIn, VehicleClock, refusal_text
from .mavlink_out import Counters, MavlinkOut, ParamServer
from .mission import Home, MissionSource, home_request
from .samples import (AutopilotParam, AutopilotRestart, CommandAck, Implausible, MissionMessage, ParamRequest,
                      SourceRefused)
from .startup import StartupChecks
from .supervisor import Decision, Inputs


MAX_MESSAGES_PER_POLL = 2000  # messages taken per cycle at most (a 50 Hz autopilot sends ~400/s)
RESTART_CHECK_S = 10.0  # the start-up checks re-run after an autopilot restart at most this often


class Daemon:
    def __init__(self, cfg: Config, table: ContractTable, conn, log, clock=None, wall=time.time, signing_clock=None,
                 planning: str = "thread", contract: str | None = None):
        """`planning`: "thread" (the avoidance planner beside the loop, so the setpoint stream keeps its
        rate) or "inline" (in the loop: deterministic lock-step tests). `contract`: the one to enforce
        (default: "avoid" in offboard mode, else "stop"; a replay names the one the flight flew under)."""
        if planning not in ("thread", "inline"):
            raise ValueError(f"planning must be 'thread' or 'inline', not {planning!r}")
        self.cfg, self.table, self.conn, self.log, self.wall = cfg, table, conn, log, wall
        self.signing_clock = signing_clock
        self._t_signing_saved = -math.inf
        self.vclock = VehicleClock(rate=cfg.link.clock_rate) if clock is None else None
        self.clock = clock or self.vclock
        self.adapter = adapter_for(cfg.link.autopilot)
        self.counters = Counters()
        self.mav_in = MavlinkIn(cfg, self.adapter, self.clock, self.vclock, self.counters)
        self.out = MavlinkOut(conn, cfg.link, self.adapter, self.counters, self._event)
        self.param_server = ParamServer(
            self.out, cfg.link.component_id,
            {"CG_ENGAGE": float(cfg.engage), "CG_MODE": float(ParamServer.MODES.index(cfg.mode)),
             "CG_R_OBST": cfg.contract.r_obst_m},
            ranges={"CG_ENGAGE": frozenset({0.0, 1.0}), "CG_R_OBST": tuple(cfg.contract.r_obst_range_m)},
            setters=tuple(cfg.link.gcs_system_ids), unsigned_refused=cfg.link.unsigned_param_refusal)
        self.cycle = Cycle(cfg, table, self.adapter, contract or ("avoid" if cfg.mode == "offboard" else "stop"),
                           ThreadedPlanning if planning == "thread" else InlinePlanning)
        self.checks = StartupChecks(self.adapter, table.vehicle, cfg, table.e_pred is not None)
        self.startup_ok: bool | None = None
        self.mission: MissionSource | None = None  # route.source: mission — the route comes from the autopilot
        if cfg.mode == "offboard" and cfg.route.source == "mission":
            lk = cfg.link
            self.mission = MissionSource(self.adapter.mission_item0_is_home, lk.target_system, lk.target_component,
                                         lk.target_system, lk.component_id, cfg.route.level_tolerance_m,
                                         corner_cut_m=cfg.route.corner_cut_m)
        # calibration.legs: the calibration plan's hold legs, flown by the daemon (governor mode only: config.py)
        self.calibration: CalibrationHolds | None = None
        if cfg.calibration is not None:
            self.calibration = CalibrationHolds(read_legs(cfg.calibration.legs), self.adapter.mission_item0_is_home)
            self.cycle.mission_speed = self.calibration.mission_speed
        self._t_home_asked = -math.inf
        self.last: Decision | None = None
        self._link_up = False
        self._t_hb_out = -math.inf
        self._t_state_log = -math.inf
        self._t_nvf = -math.inf
        self._t_checks: float | None = None
        self._implausible_seen: dict[str, tuple[float, int]] = {}  # kind → (last logged, count since)
        self._t_error_hold = -math.inf
        self._t_restart = -math.inf
        self._log_healthy = True
        self._verdict: tuple[bool, str] | None = None  # the start-up checks' last verdict logged
        if (why := self.checks.static()) is not None:  # refused before the autopilot is even heard
            self.startup_ok, self._verdict = False, (False, why)
            self._event(self.clock(), "startup_check", ok=False, reason=why)

    # what tests and the CLI look at
    @property
    def tel(self):
        return self.mav_in.tel

    @property
    def params(self) -> dict[str, float]:
        return self.param_server.values

    @property
    def offboard(self):
        return self.cycle.offboard

    # ------------------------------------------------------------------ input
    def poll(self) -> int:
        """Drain the link, within a budget (MAX_MESSAGES_PER_POLL, and half a loop period of host time), so
        that no flood can stall the cycle; what is left waits for the next cycle (or is dropped by the
        kernel, which the UDP link counts). Returns the number of messages taken."""
        n, t_end = 0, time.monotonic() + 0.5 / self.cfg.loop_hz
        while True:
            if n >= MAX_MESSAGES_PER_POLL or n % 64 == 63 and time.monotonic() > t_end:
                self.counters.poll_budget_hits += 1
                break
            try:
                msg = self.conn.recv_msg()
            except Exception:  # a transport hiccup (e.g. serial unplugged): try again next cycle
                break
            if msg is None:
                break
            n += 1
            self._dispatch(msg)
        for s in self.mav_in.from_link(self.conn):  # the link's counts, and whom it refused
            self.take(s)
        return n

    def feed(self, msg) -> None:
        """One message as `poll` hands it on, from a log that is decoded already (a `.tlog` replay): the same
        routing and checks from here on, without parsing the bytes a second time."""
        self._dispatch(msg)

    def _dispatch(self, msg) -> None:
        kind = msg.get_type()
        if self.cfg.log.tlog and kind != "BAD_DATA":
            self.log.raw(int(self.wall() * 1e6), msg.get_msgbuf())
        if kind == "BAD_DATA":
            self.counters.bad_packets += 1
            if "signature" in str(getattr(msg, "reason", "")).lower():
                self.counters.rejected_signature += 1  # unsigned or wrongly signed
            return
        if kind.startswith("UNKNOWN_"):  # a frame of a message id our dialect does not define
            self.counters.unknown_messages += 1
            return
        self.counters.messages += 1
        try:
            for s in self.mav_in.accept(msg):
                self.take(s)
        except Exception:  # decoded but nonsensical (a decoder's or an estimator's complaint): drop it
            self.counters.bad_packets += 1

    def take(self, s) -> None:
        """A sample to where it belongs: the cycle's estimators, or the daemon's own protocols (MAVLink-in's
        samples, or a flight log reader's)."""
        if type(s) in CYCLE_SAMPLES:  # the most of them (50 Hz streams): straight to the estimators
            self.cycle.take(s)
        elif isinstance(s, ParamRequest):
            self._param_request(s.msg)
        elif isinstance(s, AutopilotRestart):
            self._autopilot_restarted(s)
        elif isinstance(s, CommandAck):
            self._event(s.t, "command_ack", command=s.command, result=s.result)
        elif isinstance(s, SourceRefused):
            self._source_refused(s)
        elif isinstance(s, AutopilotParam):
            self._cruise_param(s)
            if self.checks.take(s.name, s.value):
                self._finish_checks(s.t)
        elif isinstance(s, MissionMessage):
            if self.calibration is not None and s.msg.get_type() == "HOME_POSITION":
                self.calibration.take_home(Home.from_msg(s.msg))
            if self.mission is not None:
                self._mission_actions(s.t, self.mission.take(s.t, s.msg))
        else:
            if isinstance(s, Implausible):
                self._implausible(s)
            self.cycle.take(s)

    def _source_refused(self, s: SourceRefused) -> None:
        """Whom MAVLink-in or the link refused, in the event log; a pinned source's ids from another address (a
        second autopilot, a spoofed sensor) or a move also to the ground station and the console."""
        fields = dict(what=s.what, system=s.ids[0], component=s.ids[1], autopilot=s.autopilot, address=s.address,
                      pinned=s.pinned, count=s.count)
        self._event(s.t, "source_refused", **fields)
        if s.what != "unknown":
            self.out.statustext(2 if s.what == "refused" else 4, "CG: " + refusal_text(fields))

    def _cruise_param(self, s: AutopilotParam) -> None:
        """The autopilot's cruise speed, logged when it changes: a governor's limit is never sent above it."""
        before = self.cycle.v_cruise
        self.cycle.take(s)
        now = self.cycle.v_cruise
        if now != before and not (math.isnan(now) and math.isnan(before)):
            self._event(s.t, "cruise_speed", param=s.name, v=now)

    def _implausible(self, s: Implausible) -> None:
        """Counted always; logged at the first of a kind and then at most once a second per kind."""
        self.counters.implausible += 1
        last, count = self._implausible_seen.get(s.kind, (-math.inf, 0))
        if s.t - last >= 1.0:
            self._event(s.t, "implausible_input", message=s.kind, why=s.why, count=count + 1)
            self._implausible_seen[s.kind] = (s.t, 0)
        else:
            self._implausible_seen[s.kind] = (last, count + 1)

    def _autopilot_restarted(self, s: AutopilotRestart) -> None:
        """A restarted autopilot may come back with other parameters: the start-up checks run again (at
        most every RESTART_CHECK_S: a boot clock that keeps going back is a fault, not a restart a second)."""
        if s.t - self._t_restart < RESTART_CHECK_S:
            self.cycle.take(Implausible(s.t, "time_boot_ms", "the autopilot's boot clock keeps going back"))
            return
        self._t_restart = s.t
        self._event(s.t, "autopilot_restart", boot_s_before=s.from_s, boot_s_now=s.to_s)
        self.out.statustext(4, "CG: autopilot restarted: start-up checks again")
        self.checks.values, self._t_checks, self._verdict = {}, s.t, None
        self.startup_ok = None if self.checks.static() is None else False
        self.out.request_streams(s.t, self.checks.wanted())

    def _param_request(self, msg) -> None:
        ps = self.param_server
        changed = ps.handle(msg)
        for name, value, source, why in ps.refused:
            self._event(self.clock(), "param_refused", param=name, value=value, source=source, why=why)
        ps.refused.clear()
        if changed is None:
            return
        name, old, new = changed
        if name == "CG_ENGAGE" and new >= 0.5 and old < 0.5:
            self.cycle.engage_requested()
            if self.mission is not None:  # fly the mission as it is now (it may have been edited)
                self._mission_actions(self.clock(), self.mission.request(self.clock(), "engage requested"))
        self._event(self.clock(), "param_set", param=name, old=old, new=new)
        self.param_server.send(name)
        if self.signing_clock is not None:  # a set taken is never taken again, even after a kill -9
            self.signing_clock.save(self.conn.mav.signing)

    def _finish_checks(self, t: float) -> None:
        """The verdict, logged and said when it changes (a ground station reading every parameter makes
        the autopilot send them all again)."""
        ok, reason = self.checks.verdict()
        self.startup_ok = ok
        if (ok, reason) == self._verdict:
            return
        self._verdict = (ok, reason)
        self._event(t, "startup_check", ok=ok, reason=reason)
        if not ok:
            self.out.statustext(3, f"CG: refusing to engage: {reason}")

    def _event(self, t: float, name: str, **fields) -> None:
        try:
            self.log.event(t, name, **fields)
        except Exception:
            self.counters.log_errors += 1

    def _mission_actions(self, t: float, acts) -> None:
        for msg in acts.send:
            self.out.send(msg)
        for name, fields in acts.events:
            self._event(t, name, **fields)
        for sev, text in acts.texts:
            self.out.statustext(sev, text)

    # ------------------------------------------------------------------ the cycle
    def step(self) -> Decision | None:
        """One cycle at the clock's time; None when it failed (the safe action was taken and logged)."""
        t = self.clock()
        try:
            d = self._step(t)
        except Exception as err:  # a fault of ours, in any stage, must still end in the safe action
            self._cycle_failed(t, err)
            return None
        self._bad_cycles = 0
        return d

    def _step(self, t: float) -> Decision:
        m = self.mission
        if m is not None:
            self._mission_actions(t, m.poll(t))
        i, d = self.cycle.step(t, self.tel, r_obst=self.params["CG_R_OBST"], engage=self.params["CG_ENGAGE"] >= 0.5,
                               startup_ok=self.startup_ok, mission_route=m.route if m is not None else None,
                               route_ready=m is None or m.route is not None)
        self.last = d
        self._link_events(t, i)
        self._carry_out(t, d)
        if self.calibration is not None:
            self._calibration_holds(t, i, d)
        self._periodic(t, i, d)
        return d

    def _calibration_holds(self, t: float, i: Inputs, d: Decision) -> None:
        """The calibration plan's hold legs (companion/calibration_holds.py): Hold, at rest `rest_s`, the mission.
        A hold or failsafe of the supervisor's own this cycle wins (the leg is abandoned)."""
        cal, tel = self.calibration, self.tel
        if cal.home is None and i.link_ok and t - self._t_home_asked >= 5.0:  # the waypoints are placed from it
            self._t_home_asked = t
            self.out.send(home_request(self.cfg.link.target_system, self.cfg.link.target_component))
        safety = (d.hold_causes[0] if d.hold_causes else "hold") if d.hold else \
            (f"state {d.state}" if d.state in ("holding", "failsafe") else None)
        acts = cal.step(t, mode=i.mode, mission_seq=tel.mission_seq, x=tel.x, y=tel.y, speed=i.ground_speed,
                        telemetry_ok=i.telemetry_ok, active=d.state == "active", safety=safety)
        if acts.command == "hold":
            self.cycle.hold_commanded(t)
            self.out.hold(t)
        elif acts.command == "mission":
            self.cycle.commanded_mode = ("mission", t, False)
            self.out.set_mode(t, "mission", "mission")
        for name, fields in acts.events:
            self._event(t, name, **fields)
        for sev, text in acts.texts:
            self.out.statustext(sev, text)

    _bad_cycles = 0

    def _cycle_failed(self, t: float, err: Exception) -> None:
        """A cycle that raised: Hold (unless in shadow mode or on the ground), at most once a second; the
        heartbeat says CRITICAL; logged at the 1st, 10th, 100th and every 1000th failure in a row."""
        self._bad_cycles += 1
        self.counters.loop_errors += 1
        flying = self.tel.armed and self.tel.in_air
        action = "none (shadow mode)" if self.cfg.mode == "shadow" else "hold" if flying else "none (not flying)"
        if action == "hold" and t - self._t_error_hold >= 1.0:
            self._t_error_hold = t
            self.cycle.hold_commanded(t)
            self.out.hold(t)
        if self._bad_cycles in (1, 10, 100) or self._bad_cycles % 1000 == 0:
            self._event(t, "loop_error", error=f"{type(err).__name__}: {err}"[:200], consecutive=self._bad_cycles,
                        action=action)
            self.out.statustext(2, "CG: internal error: holding" if action == "hold" else "CG: internal error")
        if t - self._t_hb_out >= 1.0 or t < self._t_hb_out:
            self._t_hb_out = t
            self.out.heartbeat("failsafe")

    def _carry_out(self, t: float, d: Decision) -> None:
        """The decision on the link, in order: Hold, the speed limit, offboard, events and texts."""
        if d.hold:
            self.out.hold(t)
        if d.send_speed is not None and self.cfg.mode == "governor":
            self.out.command(t, MAV_CMD_DO_CHANGE_SPEED, self.adapter.speed_params(d.send_speed), "change_speed")
        acts = d.offboard
        if acts is not None:
            for name, fields in acts.events:
                self._event(t, name, **fields)
            if d.stream_ended:
                self.out.end_stream()
            if acts.hold:
                self.out.hold(t)
            if acts.enter:
                self.out.set_mode(t, "offboard", "offboard")
            if acts.setpoint is not None:
                self.out.setpoint(t, acts.setpoint)
        for name, fields in d.events:
            self._event(t, name, **fields)
        for sev, text in d.statustext:
            self.out.statustext(sev, text)

    def _link_events(self, t: float, i: Inputs) -> None:
        if i.link_ok != self._link_up:
            self._link_up = i.link_ok
            self._event(t, "link", status="up" if i.link_ok else "down")
            if i.link_ok:
                self._t_checks = t if self.startup_ok is None else self._t_checks
                if self.startup_ok is False:  # the ground station hears why, now that it can
                    self.out.statustext(3, f"CG: refusing to engage: {self._verdict[1]}")
                if self.mission is not None and self.mission.status in ("idle", "refused"):
                    why = "start-up" if self.mission.status == "idle" else "link up"
                    self._mission_actions(t, self.mission.request(t, why))
                self.out.request_streams(t, self.checks.wanted())

    def _watch_log(self, t: float) -> None:
        """A failing event log is said (STATUSTEXT, the console) when it starts failing and when it recovers."""
        healthy = getattr(self.log, "healthy", True)
        if healthy == self._log_healthy:
            return
        self._log_healthy = healthy
        error = str(getattr(self.log, "last_error", "") or "")[:120]
        self.out.statustext(3 if not healthy else 5, f"CG: event log failing: {error}" if not healthy
                            else "CG: event log writing again")
        self._event(t, "log_failing" if not healthy else "log_writing", error=error)

    def _periodic(self, t: float, i: Inputs, d: Decision) -> None:
        self._watch_log(t)
        if self.signing_clock is not None and abs(t - self._t_signing_saved) >= 10.0:
            self._t_signing_saved = t
            self.signing_clock.save(self.conn.mav.signing)
        if self.startup_ok is None and self._t_checks is not None and t - self._t_checks > 5.0:
            self._finish_checks(t)  # what did not answer in 5 s counts as missing
        if t - self._t_hb_out >= 1.0 or t < self._t_hb_out:
            self._t_hb_out = t
            self.out.heartbeat(d.state)
        nvf_due = t - self._t_nvf >= 0.5 or t < self._t_nvf
        state_due = t - self._t_state_log >= 1.0 / self.cfg.log.state_hz or t < self._t_state_log
        if not (nvf_due or state_due):
            return
        record = self._state_record(i, d)
        if nvf_due:
            self._t_nvf = t
            self.out.named_values(t, {name: record[field] if field else d.omega.gamma
                                      for name, (field, _, _) in NVF.items()})
        if state_due:
            self._t_state_log = t
            try:
                self.log.state(t, **{k: record[k] for k in STATE_FIELDS})
            except Exception:
                self.counters.log_errors += 1

    def _state_record(self, i: Inputs, d: Decision) -> dict:
        """The state sample's values (companion/logschema.py: STATE says what each means)."""
        tel, om = self.tel, d.omega
        return dict(
            state=d.state, mode=i.mode, contract=self.cycle.sup.contract, engaged=i.engaged,
            x=tel.x, y=tel.y, z=tel.z, vx=tel.vx, vy=tel.vy, vz=tel.vz, ground_speed=i.ground_speed,
            d_od=i.dod.d_od, e_tr=om.e_tr, e_tr_measured=i.e_tr_measured, r_obst=i.r_obst,
            thrust_ratio=i.thrust_ratio, v_max=om.v_max, tilt_deg=math.degrees(om.tilt), v_safe=om.v_safe,
            gamma=(d.v_cmd if d.v_cmd is not None else om.v_max) - om.v_safe,
            gamma_flown=i.ground_speed - om.v_safe, v_cmd=d.v_cmd, obstacle_m=i.dod.obstacle_m)

    def shutdown(self) -> None:
        """Leave cleanly: offboard hands over to Hold; persist the signing timestamp; say so."""
        t = self.clock()
        if self.cycle.shutdown(t):
            self.out.hold(t)
        if self.signing_clock is not None:
            self.signing_clock.save(self.conn.mav.signing)
        self.out.statustext(5, "CG: contract-guard stopping")

    # ------------------------------------------------------------------ real time
    def run(self, should_stop, notifier=None) -> None:
        """Poll and step at `loop_hz` until `should_stop()`. An exception inside a cycle is logged and
        counted, never fatal; the systemd watchdog is fed only while cycles complete on time."""
        from .service import WatchdogFeeder

        feeder = WatchdogFeeder(notifier, time.monotonic) if notifier is not None else None
        period = 1.0 / self.cfg.loop_hz
        next_t = time.monotonic()
        while not should_stop():
            started = time.monotonic()
            try:
                self.poll()
                self.step()
            except Exception as err:  # a bug must not take the loop down: the safe action, logged; retried
                self._cycle_failed(self.clock(), err)
            if feeder is not None:
                feeder.tick(self._bad_cycles < 10 and time.monotonic() - started < 5 * period)
            if hasattr(self.log, "tick"):
                self.log.tick()
            # the loop rate is in vehicle time: against a SITL sped up k times, cycle k times as often
            rate = self.vclock.rate if self.vclock is not None else 1.0
            next_t += period / rate
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()
