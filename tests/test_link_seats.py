"""Seats on a listening UDP link (docs/link-trust.md), over real loopback sockets: the autopilot's seat and a
sensor's are never given by arrival order alone. Each case has its negative control: the same datagrams with
the seat rules of before (the first claimant takes a free seat at once, and a seat follows a new address after
its holder's silence whatever the vehicle does) show the old behaviour, so each test can fail."""

import time

import pytest

import companion.onboard.link as lk
from tests.test_link_trust import link_and_peers, read_all

HB_DISARMED = (2, 12, 1, 4 << 16 | 4 << 24, 3)  # HEARTBEAT fields: quadrotor, PX4, standby
HB_ARMED = (2, 12, 1 | 128, 4 << 16 | 4 << 24, 4)


@pytest.fixture
def fast(monkeypatch):
    """Seat times short enough for a test: settle 0.3 s, silence and contest 0.6 s."""
    monkeypatch.setattr(lk, "SEAT_SETTLE_S", 0.3)
    monkeypatch.setattr(lk, "CLIENT_TIMEOUT_S", 0.6)
    monkeypatch.setattr(lk, "CONTEST_S", 0.6)


def old_rules(monkeypatch):
    """The protection switched off: a free seat goes to its first claimant at once, and a held seat follows a
    new address after its holder's silence even when armed or engaged."""
    monkeypatch.setattr(lk, "SEAT_SETTLE_S", 0.0)
    monkeypatch.setattr(lk.UdpLink, "seats_held", property(lambda self: None))


def heartbeat(peer, target, fields=HB_DISARMED):
    peer.send(peer.enc.heartbeat_encode(*fields), target)


def telemetry(peer, target, x):
    peer.send(peer.enc.local_position_ned_encode(0, x, 0.0, -2, 0, 0, 0), target)


def positions(msgs) -> list[float]:
    return [m.x for m in msgs if m.get_type() == "LOCAL_POSITION_NED"]


def speak(link, target, peers, seconds, every=0.05, fields=HB_DISARMED):
    """Each (peer, x) sends HEARTBEAT and a position every `every` s for `seconds`; what the link delivered."""
    got, t_end = [], time.monotonic() + seconds
    while time.monotonic() < t_end:
        for peer, x in peers:
            heartbeat(peer, target, fields)
            telemetry(peer, target, x)
        got += read_all(link, tries=int(every / 0.005))
    return got


# ------------------------------------------------------------------ first speaker
@pytest.mark.parametrize("protection", [True, False], ids=["seats", "negative control: first speaker wins"])
def test_an_impostor_speaking_first_takes_no_seat(fast, monkeypatch, protection):
    """One impostor HEARTBEAT 1/1 just before the real autopilot (x = 1 m), then one every 0.3 s (inside the
    0.6 s contest window, as one every 9 s is inside 10 s): no one takes the seat, the real autopilot's first
    messages are not reported as "a second autopilot … it is None", and the contest names both addresses.
    Before, the impostor took the seat at its first HEARTBEAT and kept it."""
    if not protection:
        old_rules(monkeypatch)
    with link_and_peers(None, impostor=(1, 1), ap=(1, 1)) as (link, target, p):
        heartbeat(p["impostor"], target)
        read_all(link, tries=2)
        got, t0 = [], time.monotonic()
        last = t0
        while time.monotonic() - t0 < 1.5:
            if time.monotonic() - last >= 0.3:
                heartbeat(p["impostor"], target)
                last = time.monotonic()
            got += speak(link, target, [(p["ap"], 1.0)], 0.05)
        reports = link.take_refusals()
        if not protection:  # the old behaviour: the impostor holds the seat, the real autopilot refused
            assert link.autopilot_addr == p["impostor"].sock.getsockname()
            assert positions(got) == []
            return
        assert link.autopilot_addr is None and positions(got) == []
        [c] = link.contested()
        assert c["autopilot"] and c["seat"] is None
        assert set(c["claimants"]) == {p["impostor"].address, p["ap"].address}
        assert [r["what"] for r in reports] == ["contested"]  # no "refused … it is None"
        assert all(r["pinned"] is not None for r in reports if r["what"] == "refused")


def test_the_autopilots_telemetry_before_its_heartbeat_is_no_second_autopilot(fast):
    """At an ordinary start the autopilot's first messages come before its HEARTBEAT has taken the seat: they
    are waited out quietly (`unseated`), never reported as "a second autopilot … REFUSED … it is None"."""
    with link_and_peers(None, ap=(1, 1)) as (link, target, p):
        telemetry(p["ap"], target, 1.0)
        got = speak(link, target, [(p["ap"], 1.0)], 0.6)
        assert link.autopilot_addr == p["ap"].sock.getsockname()
        assert positions(got) and set(positions(got)) == {1.0}
        assert link.take_refusals() == [] and link.stats["unseated"] > 0 and link.stats["foreign_autopilot"] == 0


# ------------------------------------------------------------------ two claimants
@pytest.mark.parametrize("rules", ["seats", "negative control: old rules"])
def test_two_claimants_contest_a_held_seat_until_one_falls_silent(fast, monkeypatch, rules):
    """The autopilot holds its seat; an impostor claims it too. The holder keeps the seat, and the seat is
    contested (the daemon refuses to engage) until the impostor has been silent for CONTEST_S. With the rules
    of before the impostor was refused quietly and nothing stood in the way of engaging."""
    old = rules != "seats"
    if old:
        old_rules(monkeypatch)
        monkeypatch.setattr(lk.UdpLink, "contested", lambda self, now=None: [])  # a second claimant counts for nothing
    with link_and_peers(None, ap=(1, 1), impostor=(1, 1)) as (link, target, p):
        speak(link, target, [(p["ap"], 1.0)], 0.5)
        assert link.autopilot_addr == p["ap"].sock.getsockname()
        got = speak(link, target, [(p["ap"], 1.0), (p["impostor"], 1000.0)], 0.4)
        if old:
            assert set(positions(got)) == {1.0} and link.contested() == []
            assert [r["what"] for r in link.take_refusals()] == ["refused"]
            return
        assert set(positions(got)) == {1.0}  # the holder keeps its seat
        [c] = link.contested()
        assert c["seat"] == p["ap"].address and c["claimants"] == [p["ap"].address, p["impostor"].address]
        said = link.take_refusals()
        assert {"refused", "contested"} <= {r["what"] for r in said}
        speak(link, target, [(p["ap"], 1.0)], 0.8)  # the impostor silent for longer than CONTEST_S
        assert link.contested() == []
        assert [r["what"] for r in link.take_refusals()] == ["uncontested"]


# ------------------------------------------------------------------ silent, then loud: on the ground and in flight
@pytest.mark.parametrize("case", ["armed", "engaged", "on the ground", "negative control: armed, old rules"])
def test_a_silent_holder_is_replaced_only_on_the_ground(fast, monkeypatch, case):
    """The autopilot holds its seat (armed, or the daemon engaged, or neither) and falls silent for longer than
    CLIENT_TIMEOUT_S; another address then speaks: in flight (armed) or engaged it is refused, the seat held;
    on the ground it takes the seat once heard alone for SEAT_SETTLE_S, and the move is said."""
    if case.startswith("negative"):
        old_rules(monkeypatch)
    fields = HB_ARMED if "armed" in case else HB_DISARMED
    with link_and_peers(None, ap=(1, 1), new=(1, 1)) as (link, target, p):
        speak(link, target, [(p["ap"], 1.0)], 0.5, fields=fields)
        link.hold_seats(case == "engaged")
        assert link.autopilot_addr == p["ap"].sock.getsockname()
        time.sleep(0.7)  # silent
        got = speak(link, target, [(p["new"], 1000.0)], 0.6, fields=fields)
        said = link.take_refusals()
        if case in ("armed", "engaged"):
            assert link.autopilot_addr == p["ap"].sock.getsockname() and positions(got) == []
            assert said[0]["what"] == "refused" and said[0]["held"] == case
        else:
            assert link.autopilot_addr == p["new"].sock.getsockname() and 1000.0 in positions(got)
            assert "moved" in [r["what"] for r in said]


@pytest.mark.parametrize("protection", [True, False], ids=["seats", "negative control: first speaker wins"])
def test_a_sensor_seat_goes_to_no_one_while_two_claim_it(fast, monkeypatch, protection):
    """A sensor with ids of its own and no configured address: a spoofer's "free" reading sent just before the
    real sensor's obstacle at 3 m. Before, the spoofer took the seat and the real sensor was refused."""
    if not protection:
        old_rules(monkeypatch)
    with link_and_peers({(1, 1): None, (1, 158): None}, lidar=(1, 158), spoof=(1, 158)) as (link, target, p):
        got, t_end = [], time.monotonic() + 1.0
        while time.monotonic() < t_end:
            p["spoof"].send(p["spoof"].enc.distance_sensor_encode(0, 20, 600, 601, 0, 0, 0, 255), target)
            p["lidar"].send(p["lidar"].enc.distance_sensor_encode(0, 20, 600, 300, 0, 0, 0, 255), target)
            got += read_all(link, tries=10)
        readings = [m.current_distance for m in got if m.get_type() == "DISTANCE_SENSOR"]
        if not protection:
            assert set(readings) == {601}  # the spoofer's "free" reading, and only it
            return
        assert readings == [] and link.pinned[(1, 158)] is None
        assert [c["ids"] for c in link.contested()] == [(1, 158)]


# ------------------------------------------------------------------ what the daemon does with a contest
class ContestedLink:
    """What a listening UDP link reports after a poll (`stats`, `take_refusals`), on the lock-step rig's link: the
    daemon's own path from a contest to its engage decision, with no edit to the cycle (the start-up checks'
    verdict, which the cycle already obeys)."""

    def __init__(self, conn):
        self.conn, self.reports = conn, []
        conn.stats, conn.take_refusals = {}, self.take

    def take(self):
        out, self.reports = self.reports, []
        return out

    def contest(self, on: bool):
        self.reports.append({"what": "contested" if on else "uncontested", "autopilot": True, "ids": (1, 1),
                             "address": "127.0.0.1:40001, 127.0.0.1:40002" if on else None,
                             "pinned": "127.0.0.1:40001", "count": 2 if on else 0, "held": None})


def engage(rig):
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9))
    rig.run(0.5)
    return rig.daemon.params["CG_ENGAGE"]


def test_engaging_is_refused_while_a_seat_is_contested_and_taken_once_it_is_not():
    from tests.lockstep import Rig
    from tests.test_daemon_lockstep import column_scenario

    rig = Rig(column_scenario(1, x_col=400.0), "px4", config={"engage": False})
    link = ContestedLink(rig.conn)
    rig.run(7.0)  # the start-up checks have answered
    assert rig.daemon.startup_ok is True
    link.contest(True)
    rig.run(0.2)
    assert rig.daemon.startup_ok is False and engage(rig) == 0.0
    [refused] = rig.log.named("engage_refused")
    assert "2 addresses claim the autopilot 1/1" in refused["reason"]
    assert any("2 addresses claim the autopilot 1/1" in x for x in rig.daemon_texts())  # STATUSTEXT
    link.contest(False)
    rig.run(0.2)
    assert rig.daemon.startup_ok is True and engage(rig) == 1.0  # the same request, once the contest ended


def test_a_contest_in_flight_holds_the_engaged_vehicle():
    from tests.lockstep import Rig, fly_mission
    from tests.test_daemon_lockstep import column_scenario

    rig = Rig(column_scenario(1, x_col=400.0), "px4")
    link = ContestedLink(rig.conn)
    fly_mission(rig, 6.0)
    assert rig.daemon.last.state == "active"
    t0 = rig.sim.time_s
    link.contest(True)
    rig.run(6.0)
    fs = [e for e in rig.log.named("failsafe") if e["t"] >= t0 - 0.1]
    assert fs and fs[0]["cause"] == "start-up checks failed in flight"
    assert [e for e in rig.log.named("command") if e["cmd"] == "hold" and e["t"] >= fs[0]["t"]]
    assert rig.daemon.tel.ground_speed < 0.5
