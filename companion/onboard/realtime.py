"""The daemon's real-time loop (DESIGN.md §2): poll and step at `loop_hz` in vehicle time, the event log's group
commit after each cycle, the systemd watchdog fed while cycles complete on time, and how the loop kept its
schedule (`loop_timing`, at its end)."""

from __future__ import annotations

import gc
import time

from .service import WatchdogFeeder

STOP_LIMIT_S = 3.0  # [s, host time] the real-time loop ends this long after a stop was asked, whatever the cycle does


def freeze_startup() -> None:
    """What start-up made (the table's lookup lists, the modules: ~150 000 objects) leaves the cyclic collector's
    view (`gc.freeze`), so a full collection in the loop walks only what the loop made: over all of them it took
    61 ms on the 2-core VM, three 50 Hz cycles; in the loop 0.14 ms (`full_gc_ms` of `benchmarks/bench_daemon.py`)."""
    gc.collect()
    gc.freeze()


class LoopTiming:
    """How the real-time loop kept its schedule, for the `loop_timing` event at its end: per cycle the wake-up's
    lateness (the host's: it woke the loop late) and the cycle's own work (poll, step, and the commit of its events
    to the disk: wall time), their largest, how many cycles took over 10 / 20 / 40 ms in all, and the WORST cycles by
    that sum (at vehicle time)."""

    WORST = 5

    def __init__(self):
        self.cycles, self.over = 0, {10: 0, 20: 0, 40: 0}
        self.work_max = self.wake_max = 0.0
        self.worst: list[tuple] = []  # (wake + poll + step + commit, t, wake, poll, step, commit), the largest sums

    def add(self, t: float, wake_s: float, poll_s: float, step_s: float, commit_s: float = 0.0) -> None:
        self.cycles += 1
        work = poll_s + step_s + commit_s
        total = wake_s + work
        self.work_max, self.wake_max = max(self.work_max, work), max(self.wake_max, wake_s)
        for ms in self.over:
            if total * 1e3 > ms:
                self.over[ms] += 1
        if len(self.worst) < self.WORST or total > self.worst[-1][0]:
            self.worst = sorted([*self.worst, (total, t, wake_s, poll_s, step_s, commit_s)],
                                reverse=True)[:self.WORST]

    def summary(self) -> dict:
        ms = lambda x: round(1e3 * x, 2)  # noqa: E731
        return {"cycles": self.cycles, "work_ms_max": ms(self.work_max), "wake_late_ms_max": ms(self.wake_max),
                "cycles_over_ms": {str(k): v for k, v in self.over.items()},
                "worst": [{"t": t, "wake_late_ms": ms(w), "poll_ms": ms(p), "step_ms": ms(k), "commit_ms": ms(c)}
                          for _, t, w, p, k, c in self.worst]}



def run(daemon, should_stop, notifier=None) -> None:
    """Poll and step the daemon at `loop_hz` until `should_stop()` and then until its shutdown is over (`stop`). An
    exception inside a cycle is logged and counted, never fatal; the systemd watchdog is fed only while cycles
    complete on time."""
    feeder = WatchdogFeeder(notifier, time.monotonic) if notifier is not None else None
    period = 1.0 / daemon.cfg.loop_hz
    freeze_startup()
    timing = LoopTiming()
    next_t, t_stop = time.monotonic(), None
    while not daemon.stopped and (t_stop is None or time.monotonic() - t_stop < STOP_LIMIT_S):
        if t_stop is None and should_stop():
            t_stop = time.monotonic()
            daemon.stop()
        started = polled = time.monotonic()
        try:
            daemon.poll()
            polled = time.monotonic()
            daemon.step()
        except Exception as err:  # a bug must not take the loop down: the safe action, logged; retried
            daemon.cycle_failed(daemon.clock(), err)
        stepped = time.monotonic()
        daemon.log.tick()  # the cycle's events to the disk: one fsync for all of them (group commit)
        timing.add(daemon.clock(), started - next_t, polled - started, stepped - polled, time.monotonic() - stepped)
        if feeder is not None:
            feeder.tick(daemon.healthy and time.monotonic() - started < 5 * period)
        # the loop rate is in vehicle time: against a SITL sped up k times, cycle k times as often
        rate = daemon.vclock.rate if daemon.vclock is not None else 1.0
        next_t += period / rate
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            next_t = time.monotonic()
    fsync = getattr(daemon.log, "max_fsync_s", None)  # the event log's slowest fsync (a commit, or a rotation)
    daemon.event(daemon.clock(), "loop_timing", **timing.summary(),
                 event_log_max_fsync_ms=None if fsync is None else round(1e3 * fsync, 2))
    offboard = getattr(daemon.cycle, "offboard", None)
    if offboard is not None and offboard.guidance is not None:
        daemon.event(daemon.clock(), "planning", **offboard.guidance.planning_summary())
