"""Faults of the daemon's outbound link in the lock-step rig (companion/ground/flights.py `OutboundFaults`): what the
autopilot received, decoded from the bytes it was handed, against the rig's record; and the campaign's
classification of a flight by its commands' delivery."""

import pytest

from companion.ground import campaign as cg
from companion.ground.flights import asks_for_hold
from tests.lockstep import Rig, fly_mission, mav
from tests.test_daemon_lockstep import column_scenario


def received(rig: Rig) -> list:
    """Every message the autopilot will receive from the daemon, with the simulator's time it was handed over:
    `Sim.deliver` wrapped (the link calls it for each datagram at the start of a tick)."""
    got, deliver, parser = [], rig.sim.deliver, mav.MAVLink(None)

    def wrapped(data):
        for m in parser.parse_buffer(data) or []:
            if m.get_srcComponent() == rig.cfg.link.component_id:
                got.append((rig.sim.time_s, data, m))
        return deliver(data)

    rig.sim.deliver = wrapped
    return got


def stamped(got) -> list[tuple[float, float]]:
    """(received, sent) of the messages that carry the daemon's send time (NAMED_VALUE_FLOAT: time_boot_ms)."""
    return [(t, m.time_boot_ms / 1000.0) for t, _, m in got if m.get_type() == "NAMED_VALUE_FLOAT"]


def test_losses_and_a_burst_drop_what_the_record_says():
    rig = Rig(column_scenario(1), "px4", outbound={"losses": [(2.0, 8.0, 0.3), (4.0, 4.5, 1.0)]})
    got = received(rig)
    fly_mission(rig, 8.0)
    # what arrived is what the daemon sent, in order, less the datagrams the record says were dropped
    arrived, j, missing = [d for _, d, _ in got], 0, []
    for d in rig.daemon_out:
        if j < len(arrived) and arrived[j] == d:
            j += 1
        else:
            missing.append(d)
    assert j == len(arrived) and len(missing) == len(rig.outbound.dropped) > 0
    parser = mav.MAVLink(None)
    assert [parser.parse_buffer(d)[0].get_type() for d in missing] == [n for _, n in rig.outbound.dropped]
    assert all(2.0 - 1e-6 <= t < 8.0 for t, _ in rig.outbound.dropped)
    # nothing sent during the burst arrived, nothing late; about 30 % of the rest of the window did not arrive
    sent = stamped(got)
    assert not any(4.0 <= s < 4.5 for _, s in sent) and any(3.5 <= s < 4.0 for _, s in sent)
    assert all(t == pytest.approx(s, abs=0.0015) for t, s in sent) and not rig.outbound.delayed

    def window(t):
        return 2.0 - 1e-6 <= t < 8.0 - 1e-6 and not 4.0 - 1e-6 <= t < 4.5 - 1e-6

    lost = sum(window(t) for t, _ in rig.outbound.dropped)
    kept = sum(window(t) for t, _, _ in got)
    assert 0.15 < lost / (lost + kept) < 0.45


def test_jitter_delays_each_datagram_up_to_its_bound_in_order_of_due_time():
    rig = Rig(column_scenario(1), "px4", outbound={"jitter": [(2.0, 8.0, 0.1)]})
    got = received(rig)
    fly_mission(rig, 8.0)
    assert sorted(d for _, d, _ in got) == sorted(rig.daemon_out) and not rig.outbound.dropped  # all arrive
    delays = [(s, t - s) for t, s in stamped(got)]
    inside = [d for s, d in delays if 2.0 + 0.002 <= s < 8.0 - 0.002]
    assert all(d == pytest.approx(0.0, abs=0.0015) for s, d in delays if not 2.0 - 0.002 <= s < 8.0 + 0.002)
    assert inside and all(0.0 < d <= 0.1 + 0.0015 for d in inside)
    assert 0.03 < sum(inside) / len(inside) < 0.08  # uniform up to 0.1 s, released at the next 10 ms tick
    # the record: the same delays, and datagrams overtaking each other (delivered in order of due time)
    assert all(0.0 < t - s <= 0.1 + 1e-9 and 2.0 - 1e-6 <= s < 8.0 for s, t, _ in rig.outbound.delayed)
    seqs = [m.get_seq() for t, _, m in got if 2.5 < t < 7.5]
    assert any(b < a for a, b in zip(seqs, seqs[1:]) if a - b < 128)  # a later datagram arrived first


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_the_first_hold_dropped_is_delivered_with_its_next_copy(personality):
    """The daemon's first Hold is lost: the record says that command reached the autopilot when its next copy did,
    and the autopilot received no Hold before that."""
    rig = Rig(column_scenario(1), personality, outbound={"drop_holds": 1})
    got = received(rig)
    fly_mission(rig, 20.0)
    holds = [r for r in rig.outbound.requests if r.hold]
    t1, t2 = sorted(t for r in holds for t in r.sends)[:2]
    assert rig.outbound.dropped == [(t1, "COMMAND_LONG")]
    latency = next(x for r, x in rig.outbound.latencies(rig.sim.time_s) if r is holds[0])
    assert latency == pytest.approx(t2 - t1, abs=1e-9) and latency > 0.0
    arrived = [t for t, _, m in got if m.get_type() == "COMMAND_LONG" and m.command == mav.MAV_CMD_DO_SET_MODE
               and asks_for_hold(personality, m.param2, m.param3)]
    assert arrived[0] == pytest.approx(t2, abs=1e-9)
    # the campaign's view of the same record: late exactly when the gap is beyond the budget
    d = cg.delivery_of(rig)
    assert d["worst_s"] == pytest.approx(t2 - t1, abs=1e-6) and (d["late"] > 0) == (t2 - t1 > d["t_cmd_s"])


def spec(faults_a, faults_b):
    return cg.spec_from_dict({"name": "link", "seed": 3, "scenarios": 2, "vehicles": ["mambo"],
                              "personalities": ["px4"], "arms": ["offboard"], "duration_s": 30,
                              "stresses": [{"name": "a", "faults": faults_a}, {"name": "b", "faults": faults_b}]})


def test_a_half_second_burst_is_outside_the_assumption_and_one_percent_loss_inside():
    """In offboard the daemon streams setpoints at 50 Hz: a 0.5 s burst leaves the autopilot without one for
    0.5 s, beyond the 0.1 s budget; 1 % loss drops some, each covered by the next 20 ms later."""
    sp = spec([{"kind": "cmd_burst", "p": 1, "at_s": 5, "duration_s": 0.5}],
              [{"kind": "cmd_loss", "p": 1, "at_s": 1, "rate": 0.01}])
    burst, rig_b = cg.fly(sp, 0, keep_rig=True)
    loss, rig_l = cg.fly(sp, 1, keep_rig=True)
    assert not burst["in_assumption"] and "delivery" in burst["stresses"]
    assert burst["delivery"]["late"] > 0 and burst["delivery"]["worst_s"] == pytest.approx(0.5, abs=0.03)
    assert [f["occurs"] for f in burst["fault_outcomes"]] == [True]
    assert loss["in_assumption"] and loss["stresses"] == ["cmd_loss"]
    lost = [n for _, n in rig_l.outbound.dropped]
    assert "SET_POSITION_TARGET_LOCAL_NED" in lost and loss["delivery"]["worst_s"] == pytest.approx(0.02, abs=1e-6)
    # before the flight the delivery is unknown: not in assumption
    assert not cg.sample_scenario(sp, 1)["in_assumption"]


def test_the_spec_refuses_a_loss_rate_above_one():
    with pytest.raises(cg.CampaignError, match="rate"):
        spec([{"kind": "cmd_loss", "p": 1, "rate": 1.5}], [])
