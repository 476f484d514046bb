"""Everything the daemon sends in a cycle leaves in that cycle's one outbox (DESIGN.md §5): `MavlinkOut.apply` is
called once per `Daemon.step` (a failed cycle too) and never while polling, and no datagram leaves outside it — the
protocols' answers, the link coming up, the periodic work and the failed cycle's Hold all ride in the one box.
A lock-step flight with real MAVLink bytes."""

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.onboard.outbox import EMPTY
from tests.lockstep import Rig
from tests.test_daemon_lockstep import column_scenario, fly

AUTOPILOT = mav.MAVLink(None, srcSystem=1, srcComponent=1)


class Watch:
    """Counts the applies in each call of the daemon's `poll`, `step` and `finish`, and the datagrams the daemon
    writes outside an apply."""

    def __init__(self, rig: Rig):
        daemon, self.calls, self.stray = rig.daemon, [], []
        self.applies, self.inside = 0, False
        apply = daemon.out.apply

        def counted_apply(t, box):
            self.applies, self.inside = self.applies + 1, True
            try:
                apply(t, box)
            finally:
                self.inside = False

        daemon.out.apply = counted_apply
        for name in ("poll", "step", "finish"):
            setattr(daemon, name, self._counted(name, getattr(daemon, name), rig))
        watch = self

        class Written(list):
            def append(self, data):
                if not watch.inside:
                    watch.stray.append((rig.sim.time_s, data))
                super().append(data)

        rig.daemon_out = Written(rig.daemon_out)

    def _counted(self, name, call, rig):
        def counted():
            before = self.applies
            out = call()
            self.calls.append((name, rig.sim.time_s, self.applies - before, out))
            return out

        return counted

    def applies_by(self, name):
        return [n for what, _, n, _ in self.calls if what == name]


def test_every_cycle_sends_through_one_apply_and_nothing_leaves_outside_it(monkeypatch):
    rig = Rig(column_scenario(1, x_col=400.0), "px4")
    watch = Watch(rig)
    fly(rig, 4.0)  # the link comes up in the first cycles; the daemon engages and limits the speed
    rig.to_daemon(rig.gcs.param_request_list_encode(1, 191))  # the parameter protocol's answers
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_MODE", 7.0, 9))  # refused: echoed
    rig.to_daemon(AUTOPILOT.system_time_encode(0, 150), AUTOPILOT)  # an autopilot restart: the stream requests again
    rig.run(0.5)
    rig.log.healthy, rig.log.last_error = False, "disk full"  # the periodic work says so (STATUSTEXT)
    rig.run(0.1)
    rig.log.healthy = True
    rig.run(0.1)

    def broken(i):
        raise ZeroDivisionError("a bug")

    with monkeypatch.context() as m:  # failed cycles: the failsafe Hold, the internal-error text, the heartbeat
        m.setattr(rig.daemon.cycle.sup, "step", broken)
        rig.run(1.1)  # (the heartbeat is due once a second)
    rig.run(0.5)
    rig.daemon.finish()

    steps = [(t, n, d) for what, t, n, d in watch.calls if what == "step"]
    assert len(steps) > 200 and all(n == 1 for _, n, _ in steps), [s for s in steps if s[1] != 1][:5]
    assert set(watch.applies_by("poll")) == {0} and watch.applies_by("finish") == [1]
    assert watch.stray == []
    # the cycles this covers: the link coming up, the answers to samples, the periodic work's text, failed cycles
    assert rig.log.named("link")[0]["status"] == "up" and rig.log.named("autopilot_restart")
    assert sum(d is None for _, _, d in steps) >= 50 and rig.log.named("loop_error")
    sent = rig.daemon_messages()
    assert {m.param_id for m in sent if m.get_type() == "PARAM_VALUE"} == {"CG_ENGAGE", "CG_MODE", "CG_R_OBST"}
    assert sum(m.get_type() == "COMMAND_LONG" and m.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL for m in sent) >= 18
    texts = rig.daemon_texts()
    for said in ("CG: event log failing: disk full", "CG: event log writing again", "CG: internal error: holding",
                 "CG: autopilot restarted: start-up checks again", "CG: contract-guard stopping"):
        assert said in texts
    holds = [e for e in rig.log.named("command") if e["cmd"] == "hold"]
    assert holds and [m for m in sent if m.get_type() == "HEARTBEAT" and m.system_status == mav.MAV_STATE_CRITICAL]


def test_the_watch_sees_a_second_apply_and_a_send_beside_the_outbox():
    rig = Rig(column_scenario(1, x_col=400.0), "px4")
    daemon = rig.daemon
    step = daemon.step

    def step_twice():  # what came back: a second apply in the cycle, and a text sent straight out
        out = step()
        daemon.out.apply(daemon.clock(), EMPTY)
        daemon.out.statustext(6, "CG: beside the outbox")
        return out

    daemon.step = step_twice
    watch = Watch(rig)
    rig.run(0.1)
    assert set(watch.applies_by("step")) == {2} and len(watch.stray) == 5
