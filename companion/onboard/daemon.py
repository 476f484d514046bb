"""The on-board daemon: one loop (default 50 Hz) over one MAVLink connection (DESIGN.md §5). Thin: it polls, steps
and runs the pipeline it wires — MAVLink in (samples) → cycle (pure: sensing → mode authority → supervisor →
actors → one Outbox) → MAVLink out (`apply(outbox)`) — its protocols and its periodic work (`PERIODIC`). Everything sent in a cycle leaves in that cycle's one outbox: what the protocols
and the link's events want sent since the last cycle (their events logged at once) is joined to it, and so is
what the periodic work adds. `poll()` drains the link, `step()` runs one cycle at the injected clock's time;
`run` calls both at `loop_hz`, lock-step tests between simulator steps. `stop()` begins the shutdown (engaged in
flight, a Hold first), `stopped` says when it is over. Nothing here raises on bad input: a malformed message is
counted and dropped, a failed log write is the log's problem, a missing stream leads to the safe action.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

from contracts.table import ContractTable

from .autopilots import adapter_for
from .config import Config
from .cycle import Cycle, Given
from .eventlog import sparse
from .guidance import InlinePlanning, ProcessPlanning, ThreadedPlanning
from .logschema import LINK_COUNTERS, NVF, STATE_FIELDS
from .mavlink_in import MavlinkIn, VehicleClock
from .mavlink_out import Counters, MavlinkOut
from .mission import home_request
from .outbox import EMPTY, Outbox
from .protocols import Protocols
from .sensing import CYCLE_SAMPLES
from .states import CYCLE_COMPLETES, Subsystem
from .supervisor import Decision

MAX_MESSAGES_PER_POLL = 2000  # messages taken per cycle at most (a 50 Hz autopilot sends ~400/s)

# the daemon's periodic work, as ArduPilot's scheduler_tasks[] lists its loops: (period [s], method); a period of
# None is the state-sample rate (log.state_hz). Each runs when its period has passed since its last run (or the
# clock went back), in this order, at the end of a cycle: what it returns joins the cycle's outbox (None: nothing
# to send); a task that returns False had nothing to do yet and is tried again at the next cycle. The state sample
# is written after the outbox is applied (after the cycle's events, as the log orders them).
PERIODIC = ((0.0, "_watch_log"), (10.0, "_save_signing"), (0.0, "_checks_deadline"), (5.0, "_request_home"),
            (1.0, "_heartbeat"), (0.5, "_named_values"))
AFTER_OUTBOX = ((None, "_state_sample"),)


class Daemon:
    def __init__(self, cfg: Config, table: ContractTable, conn, log, clock=None, wall=time.time, signing_clock=None,
                 planning: str = "process", contract: str | None = None, policy=None):
        """`planning`: "process" (the avoidance planner in a worker process: no planning holds the loop's
        interpreter lock), "thread" or "inline" (in the loop: lock-step tests), or a factory of a runner.
        `contract`: the one to enforce (default: "avoid" in offboard mode, else "stop"; a replay names the one the
        flight flew under). `policy`: the speed policy (the contract's Ω by default; a campaign's baselines:
        companion/ground/baselines.py)."""
        runners = {"process": ProcessPlanning, "thread": ThreadedPlanning, "inline": InlinePlanning}
        if isinstance(planning, str) and planning not in runners:
            raise ValueError(f"planning must be one of {', '.join(runners)}, not {planning!r}")
        self.cfg, self.table, self.conn, self.log, self.wall = cfg, table, conn, log, wall
        table.warm()  # the compiled lookup now, not in the first cycle
        self.signing_clock = signing_clock
        self.vclock = VehicleClock(rate=cfg.link.clock_rate) if clock is None else None
        self.clock = clock or self.vclock
        self.adapter = adapter_for(cfg.link.autopilot)
        self.counters = Counters()
        self.mav_in = MavlinkIn(cfg, self.adapter, self.clock, self.vclock, self.counters)
        self.out = MavlinkOut(conn, cfg.link, self.adapter, self.counters, self.event)
        self.cycle = Cycle(cfg, table, self.adapter, contract or cfg.daemon_mode.contract,
                           runners.get(planning, planning), policy)
        self.checks = self.cycle.checks
        self.protocols = Protocols(cfg, self.adapter, self.cycle, self.checks, self.out, self.counters,
                                   lambda: self._save_signing(None))
        self.param_server, self.mission = self.protocols.params, self.protocols.mission
        self.last: Decision | None = None
        self._last_in = None  # the last cycle's Inputs (the periodic tasks' state)
        self._record: dict | None = None  # this cycle's state record, made once for NVF and the state sample
        self._heartbeat_state = "standby"
        period = {None: 1.0 / cfg.log.state_hz}
        self._periodic, self._after_outbox = ([(period.get(p, p), getattr(self, name), [-math.inf]) for p, name in rows]
                                              for rows in (PERIODIC, AFTER_OUTBOX))
        self._later = EMPTY  # what samples and the link's events want sent with the next cycle's outbox
        self._link_up = False
        self._log_healthy = True
        self._bad_cycles = 0
        if self.checks.ok is False:  # refused before the autopilot is even heard
            self.event(self.clock(), "startup_check", ok=False, reason=self.checks.reason)

    # what tests and the CLI look at
    tel = property(lambda self: self.mav_in.tel)
    params = property(lambda self: self.param_server.values)
    startup_ok = property(lambda self: self.checks.ok)
    offboard = property(lambda self: self.cycle.offboard)
    calibration = property(lambda self: self.cycle.calibration)

    @property
    def healthy(self) -> bool:
        """Cycles complete (fewer than 10 failed in a row): the systemd watchdog is fed."""
        return self._bad_cycles < 10

    @property
    def stopped(self) -> bool:
        """The shutdown begun by `stop()` is over (its Hold, if one was needed, confirmed or given up)."""
        return self.cycle.shutdown is not None and self.cycle.shutdown.done

    # ------------------------------------------------------------------ input
    def poll(self) -> int:
        """Drain the link within a budget (MAX_MESSAGES_PER_POLL, half a loop period of host time): no flood stalls
        the cycle; the rest waits (or the kernel drops it, counted by the UDP link). The number of messages taken."""
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
            self.feed(msg)
        for s in self.mav_in.from_link(self.conn):  # the link's counts, and whom it refused
            self.take(s)
        return n

    def feed(self, msg) -> None:
        """One message to its samples and where they belong (`poll`'s, or a decoded log's: a `.tlog` replay)."""
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
        except Exception as err:  # decoded but nonsensical (a decoder's or an estimator's complaint): dropped, said
            self.counters.bad_packets += 1
            if sparse(self.counters.bad_packets):
                self.event(self.clock(), "sample_dropped", kind=kind, error=f"{type(err).__name__}: {err}"[:200],
                           count=self.counters.bad_packets)

    def take(self, s) -> None:
        """A sample to where it belongs: the cycle's estimators, or the daemon's own protocols (MAVLink-in's
        samples, or a flight log reader's)."""
        if type(s) in CYCLE_SAMPLES:  # the most of them (50 Hz streams): straight to the estimators
            self.cycle.take(s)
        else:
            t = getattr(s, "t", None)  # (a PARAM_SET carries no time: the daemon's)
            self._send_later(self.clock() if t is None else t, self.protocols.take(s, self.clock()))

    def _send_later(self, t: float, box: Outbox) -> None:
        """An outbox made outside the cycle (a protocol's answer, what the link coming up asks for): its events
        logged now, the rest sent with the next cycle's outbox (a poll and its cycle follow each other at once)."""
        for name, fields in box.events:
            self.event(t, name, **fields)
        self._later = self._later.then(replace(box, events=()))

    def event(self, t: float, name: str, **fields) -> None:
        try:
            self.log.event(t, name, **fields)
        except Exception:
            self.counters.log_errors += 1

    # ------------------------------------------------------------------ the cycle
    def step(self) -> Decision | None:
        """One cycle at the clock's time; None when it failed (the safe action was taken and logged)."""
        t = self.clock()
        self._record = None
        try:
            m = self.mission
            i, d, box = self.cycle.step(Given(
                t, self.tel, r_obst=self.params["CG_R_OBST"], engage=self.params["CG_ENGAGE"] >= 0.5,
                startup_ok=self.startup_ok, mission_route=m.route if m is not None else None,
                route_ready=m is None or m.route is not None, protocol=m.poll(t) if m is not None else None))
            self.last, self._last_in, self._heartbeat_state = d, i, d.state
            self._link_events(t, i)
            self._apply(t, box.then(self._run_periodic(t, self._periodic)))
            self._run_periodic(t, self._after_outbox)
        except Exception as err:  # a fault of ours, in any stage, must still end in the safe action
            self.cycle_failed(t, err)
            return None
        if self._bad_cycles:
            self.event(t, "violation_end", subsystem=Subsystem.GUIDANCE, guarantee=CYCLE_COMPLETES,
                       observed=self._bad_cycles)
        self._bad_cycles = 0
        return d

    def cycle_failed(self, t: float, err: Exception) -> None:
        """A cycle that raised: Hold (unless in shadow mode or on the ground), delivered by the mode authority; the
        heartbeat says CRITICAL; logged at the 1st, 10th, 100th and every 1000th failure in a row. It breaks the
        daemon's own guarantee, guidance's: a violation from the first failed cycle to the next that completes (what
        the contracts fly assumes a decision every cycle; the avoid contract's speed, its swerves)."""
        self._bad_cycles += 1
        self.counters.loop_errors += 1
        flying = self.tel.armed and self.tel.in_air
        action = (f"none ({self.cfg.mode} mode)" if not self.cfg.daemon_mode.commands else "hold" if flying
                  else "none (not flying)")
        # the Hold asked every failed cycle: the mode authority delivers it (re-sent until answered)
        box = self.cycle.failed_hold(t) if action == "hold" else EMPTY
        if self._bad_cycles == 1:
            box = box.then(Outbox(events=(("violation_start", {
                "subsystem": Subsystem.GUIDANCE, "guarantee": CYCLE_COMPLETES, "assumed": 0, "observed": 1,
                "action": action}),)))
        if sparse(self._bad_cycles):
            box = box.then(Outbox(
                events=(("loop_error", {"error": f"{type(err).__name__}: {err}"[:200],
                                        "consecutive": self._bad_cycles, "action": action}),),
                texts=((2, "CG: internal error: holding" if action == "hold" else "CG: internal error"),)))
        self._heartbeat_state = "failsafe"
        self._apply(t, box.then(self._run_periodic(t, self._periodic, only=self._heartbeat)))

    def _apply(self, t: float, box: Outbox) -> None:
        """The cycle's one outbox, after what was left to send with it."""
        box, self._later = self._later.then(box), EMPTY
        self.out.apply(t, box)

    def _link_events(self, t: float, i) -> None:
        if i.link_ok != self._link_up:
            self._link_up = i.link_ok
            self.event(t, "link", status="up" if i.link_ok else "down")
            if i.link_ok:
                box = self.checks.asked(t)
                if self.mission is not None and self.mission.status in ("idle", "refused"):
                    why = "start-up" if self.mission.status == "idle" else "link up"
                    box = box.then(self.protocols.mission_request(t, why))
                self._send_later(t, box.then(self.out.stream_requests(self.checks.wanted())))

    # ------------------------------------------------------------------ the periodic work (PERIODIC)
    def _run_periodic(self, t: float, tasks, only=None) -> Outbox:
        """The tasks that are due (or `only` that one, if due); what they want sent, as one outbox."""
        box = EMPTY
        for period, task, last in tasks:
            if (only is None or task == only) and (t - last[0] >= period or t < last[0]):
                said = task(t)
                if said is not False:
                    last[0] = t
                    box = box if said is None else box.then(said)
        return box

    def _watch_log(self, t: float) -> Outbox | None:
        """A failing event log is said (STATUSTEXT, the console) when it starts failing and when it recovers."""
        healthy = getattr(self.log, "healthy", True)
        if healthy == self._log_healthy:
            return None
        self._log_healthy = healthy
        error = str(getattr(self.log, "last_error", "") or "")[:120]
        return Outbox(events=(("log_failing" if not healthy else "log_writing", {"error": error}),),
                      texts=((3, f"CG: event log failing: {error}") if not healthy
                             else (5, "CG: event log writing again"),))

    def _save_signing(self, t: float | None) -> None:
        if self.signing_clock is not None:
            self.signing_clock.save(self.conn.mav.signing)

    def _checks_deadline(self, t: float) -> Outbox:
        return self.checks.deadline(t)

    def _request_home(self, t: float) -> Outbox | bool:
        """The calibration legs' waypoints are placed from HOME_POSITION: asked for until heard (once the link
        is up, every 5 s)."""
        cal = self.cycle.calibration
        if cal is None or cal.home is not None or self._last_in is None or not self._last_in.link_ok:
            return False
        return Outbox(messages=(home_request(self.cfg.link.target_system, self.cfg.link.target_component),))

    def _heartbeat(self, t: float) -> Outbox:
        return Outbox(heartbeat=self._heartbeat_state)

    def _named_values(self, t: float) -> Outbox:
        record, gamma = self._state_record(), self.last.omega.gamma
        return Outbox(values=tuple((name, record[field] if field else gamma) for name, (field, _, _) in NVF.items()))

    def _state_sample(self, t: float) -> None:
        record = self._state_record()
        try:
            self.log.state(t, **{k: record[k] for k in STATE_FIELDS})
        except Exception:
            self.counters.log_errors += 1

    def _state_record(self) -> dict:
        if self._record is None:  # made once a cycle, for NAMED_VALUE_FLOAT and the state sample
            self._record = self.cycle.state_record(self._last_in, self.last, self.tel)
            self._record.update({k: getattr(self.counters, k) for k in LINK_COUNTERS})
        return self._record

    # ------------------------------------------------------------------ stopping and real time
    def stop(self) -> None:
        """Begin the shutdown: engaged in flight, the next cycles command Hold until the autopilot shows it
        (at most a second; `stopped` then); on the ground, or not engaged, it is over at the next cycle."""
        self.cycle.stop(self.clock())

    def finish(self) -> None:
        """After the shutdown: persist the signing timestamp; say so (the last outbox, after the last cycle's);
        the planning worker ends."""
        self._save_signing(None)
        self.cycle.close()
        self._apply(self.clock(), Outbox(texts=((5, "CG: contract-guard stopping"),)))

    def run(self, should_stop, notifier=None) -> None:
        """Poll and step at `loop_hz` until `should_stop()` and then until the shutdown is over (companion/onboard/
        realtime.py)."""
        from .realtime import run

        run(self, should_stop, notifier)
