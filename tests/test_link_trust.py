"""Who is who on the link, over real loopback UDP with the daemon as a process (`contract-guard run`,
`udpin`): the autopilot is its ids and the address it is pinned to, each sensor its configured source, and
only a configured ground station's *signed* message sets the daemon's parameters over a network link. A seat
(the autopilot's, a sensor's with ids of its own) goes to no one while two addresses claim it, which refuses
engaging and is said on the console, in the event log and to the seat's holder and the ground stations; it
never moves while the vehicle is armed (test_link_seats.py: the same rules on the link alone).

Before these checks, a spoofed DISTANCE_SENSOR "free to 6 m" at 200 Hz hid a real obstacle at 3 m (from
another component, another address or the autopilot's own address); an unsigned PARAM_SET CG_ENGAGE 0 from
a new address disengaged the daemon; whoever sent the first autopilot HEARTBEAT became the autopilot, and a
second one was dropped without a word."""

import contextlib
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.onboard.eventlog import read_events

ROOT = Path(__file__).resolve().parents[1]
OBSTACLE_CM = 300  # the real obstacle, 3 m ahead
MAX_CM = 600


def udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


def addr(s: socket.socket) -> str:
    return "%s:%d" % s.getsockname()


class Peer:
    """One sender on the loopback: its socket, its MAVLink encoder, and what the daemon sent it."""

    def __init__(self, system: int, component: int, sock: socket.socket | None = None):
        self.sock = sock or udp_socket()
        self.address = addr(self.sock)
        self.enc = mav.MAVLink(None, srcSystem=system, srcComponent=component)
        self.parser = mav.MAVLink(None)
        self.parser.robust_parsing = True
        self.got: list = []  # (host monotonic time, message) the daemon sent here

    def send(self, msg, target) -> None:
        self.sock.sendto(msg.pack(self.enc), target)

    def drain(self) -> None:
        while True:
            try:
                data = self.sock.recv(65535)
            except (BlockingIOError, ConnectionRefusedError):
                return
            now = time.monotonic()
            self.got.extend((now, m) for m in self.parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA")

    def received(self, kind: str, after: float = 0.0) -> list:
        return [m for t, m in self.got if t >= after and m.get_type() == kind]

    def texts(self) -> list[str]:
        """The STATUSTEXTs heard, chunks (MAVLink 2 id, chunk_seq) joined."""
        out, parts = [], {}
        for m in self.received("STATUSTEXT"):
            parts.setdefault(m.id, []).append(m.text)
            if not m.id or len(m.text) < 50:
                out.append("".join(parts.pop(m.id)))
        return out


class Flight:
    """`contract-guard run` in shadow mode listening on a free loopback port, the autopilot `ap` (1/1) sending
    its HEARTBEAT, ATTITUDE, LOCAL_POSITION_NED (x = 1 m) and a DISTANCE_SENSOR seeing the obstacle 3 m ahead
    at 50 Hz (each `each(t)` call, t: seconds since the daemon first answered)."""

    def __init__(self, tmp_path: Path, link: dict | None = None, engage: bool = False):
        self.tmp = tmp_path
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            self.target = s.getsockname()
        self.ap = Peer(1, 1)
        self.link = {"connect": "udpin:%s:%d" % self.target, **(link or {})}
        self.engage = engage
        self.mode = "shadow"
        self.armed = True  # what the autopilot's HEARTBEAT says
        self.silent = lambda t: False  # the autopilot says nothing while this holds (t: since the daemon answered)
        self.console = ""
        self.t_first: float | None = None

    def fly(self, seconds: float, each=lambda t: None, before=lambda: True, answered=None) -> list:
        """Run the daemon for `seconds` after it first answers (`answered()`, default: the autopilot hears it);
        returns its event log. `before()` is called every cycle from the start, before the autopilot speaks,
        which it does only once `before()` has returned True (e.g. after an impostor who is first)."""
        answered = answered or (lambda: self.ap.got)
        speaking = False
        cfg = self.tmp / "cg.yaml"
        cfg.write_text(yaml.safe_dump({"vehicle": "mambo", "mode": self.mode, "engage": self.engage, "link": self.link,
                                       "sensors": [{"h_fov_deg": 30, "max_range_m": 6}],
                                       "log": {"dir": str(self.tmp / "log")}}))
        d = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg)], cwd=ROOT,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        t_start = time.monotonic()
        try:
            while time.monotonic() - t_start < 90 and (self.t_first is None or
                                                      time.monotonic() - self.t_first < seconds):
                if d.poll() is not None:
                    break
                tick = time.monotonic()
                speaking = before() or speaking
                tb = int((tick - t_start) * 1000)
                if speaking and not (self.t_first is not None and self.silent(time.monotonic() - self.t_first)):
                    e = self.ap.enc
                    for msg in (e.heartbeat_encode(2, 12, 1 | (128 if self.armed else 0), 4 << 16 | 4 << 24, 4),
                                e.attitude_encode(tb, 0, 0, 0, 0, 0, 0),
                                e.local_position_ned_encode(tb, 1.0, 2.0, -2, 0, 0, 0),
                                e.distance_sensor_encode(tb, 20, MAX_CM, OBSTACLE_CM, 0, 0, 0, 255)):
                        self.ap.send(msg, self.target)
                self.ap.drain()
                if self.t_first is None and answered():
                    self.t_first = time.monotonic()
                if self.t_first is not None:
                    each(time.monotonic() - self.t_first)
                time.sleep(max(0.0, 0.02 - (time.monotonic() - tick)))
        finally:
            if d.poll() is None:
                d.send_signal(signal.SIGTERM)
            out, err = d.communicate(timeout=30)
            self.console = out + err
            self.ap.sock.close()
        assert self.t_first is not None, f"the daemon never answered: {self.console[-2000:]}"
        return read_events(self.tmp / "log")


def states(log) -> list[dict]:
    return [r for r in log if r.get("kind") == "state" and r.get("x") is not None]


def counters(log) -> dict:
    return next(r["counters"] for r in log if r.get("event") == "stop")


# ------------------------------------------------------------------ a spoofed sensor
FREE_CM = MAX_CM + 1  # "free to 6 m": nothing within the maximum


@pytest.mark.parametrize("via", ["another address, component 200", "the autopilot's address, component 200",
                                 "another address, the autopilot's ids"])
def test_a_spoofed_free_reading_at_200_hz_does_not_hide_the_obstacle(tmp_path, via):
    """The autopilot's DISTANCE_SENSOR sees an obstacle 3 m ahead at 50 Hz; a spoofer says "free to 6 m" at
    200 Hz with the same sensor id and orientation. Without the source checks it was taken (any component, any
    address, the latest sample wins) and the state samples saw no obstacle."""
    flight = Flight(tmp_path)
    spoofer = {"another address, component 200": Peer(1, 200),
               "the autopilot's address, component 200": Peer(1, 200, flight.ap.sock),
               "another address, the autopilot's ids": Peer(1, 1)}[via]
    sent = {"n": 0}

    def spoof(t):
        for _ in range(4):  # 4 per 20 ms cycle: 200 Hz
            spoofer.send(spoofer.enc.distance_sensor_encode(0, 20, MAX_CM, FREE_CM, 0, 0, 0, 255), flight.target)
            sent["n"] += 1

    log = flight.fly(5.0, spoof)
    if spoofer.sock is not flight.ap.sock:
        spoofer.sock.close()
    seen = [s["obstacle_m"] for s in states(log) if s["t"] >= 1.0]
    assert sent["n"] > 500 and len(seen) > 20
    assert all(m == pytest.approx(OBSTACLE_CM / 100) for m in seen), seen  # the obstacle, in every sample
    c = counters(log)
    key = "refused_address" if via == "another address, the autopilot's ids" else "unknown_source"
    in_samples = [s[key] for s in states(log)]  # the state samples carry the count as it grows
    assert in_samples[-1] >= sent["n"] * 0.5 and in_samples == sorted(in_samples) and in_samples[0] < in_samples[-1]
    if via == "another address, the autopilot's ids":  # refused by the link for its address, and said
        assert c["refused_address"] >= sent["n"] * 0.9
        refused = [r for r in log if r.get("event") == "source_refused" and r["what"] == "refused"]
        assert refused and refused[0]["autopilot"] and refused[0]["address"] == spoofer.address
    else:  # a source no sensor is configured at
        assert c["unknown_source"] >= sent["n"] * 0.9
        assert [r for r in log if r.get("event") == "source_refused" and r["what"] == "unknown"
                and (r["system"], r["component"]) == (1, 200)]
    assert "link: " in flight.console and "from unknown sources" in flight.console  # the exit summary


# ------------------------------------------------------------------ a spoofed ground station
def test_an_unsigned_parameter_set_from_a_new_address_is_refused_and_echoed(tmp_path):
    """System 255 from an address never heard before, unsigned: CG_ENGAGE 0 and CG_R_OBST 0.1 are refused
    (over a network link the daemon's parameters take signed sets only), each answered with PARAM_VALUE of
    the value kept. Without the signing check both were taken."""
    flight = Flight(tmp_path, engage=True)
    gcs = Peer(255, 190)
    asked = {"n": 0}

    def attack(t):
        gcs.drain()
        if t > 1.0 and asked["n"] < 2:
            name, value = (b"CG_ENGAGE", 0.0) if asked["n"] == 0 else (b"CG_R_OBST", 0.1)
            gcs.send(gcs.enc.param_set_encode(1, 191, name, value, 9), flight.target)
            asked["n"] += 1

    log = flight.fly(3.0, attack)
    gcs.drain()
    gcs.sock.close()
    assert asked["n"] == 2
    assert not [r for r in log if r.get("event") == "param_set"]
    refused = {r["param"]: r for r in log if r.get("event") == "param_refused"}
    assert set(refused) == {"CG_ENGAGE", "CG_R_OBST"} and all("unsigned" in r["why"] for r in refused.values())
    echo = {m.param_id: m.param_value for m in gcs.received("PARAM_VALUE")}
    assert echo == {"CG_ENGAGE": 1.0, "CG_R_OBST": pytest.approx(1.0)}  # the values kept
    assert "parameter CG_ENGAGE = 0 from system 255 refused: unsigned" in flight.console
    assert "signed sets only" in flight.console  # the banner says who may set them


def test_unsigned_parameter_sets_allowed_by_config_are_taken_and_the_banner_says_weakened(tmp_path):
    flight = Flight(tmp_path, link={"unsigned_params": True})
    gcs = Peer(255, 190)

    def set_once(t):
        if t > 1.0 and not gcs.got:
            gcs.send(gcs.enc.param_set_encode(1, 191, b"CG_R_OBST", 0.6, 9), flight.target)
        gcs.drain()

    log = flight.fly(2.5, set_once)
    gcs.sock.close()
    assert [r for r in log if r.get("event") == "param_set" and r["param"] == "CG_R_OBST"]
    assert "WEAKENED link.unsigned_params" in flight.console


# ------------------------------------------------------------------ a second autopilot
def impostor_flight(tmp_path, configured: bool, first: bool):
    """The real autopilot (x = 1 m) and an impostor claiming its ids (x = 1000 m) from another address; the
    impostor speaks first (`first`) or from 1 s after the daemon answered; `configured`: the real one's
    address is in the config (link.autopilot_address)."""
    impostor = Peer(1, 1)
    flight = Flight(tmp_path)
    if configured:
        flight.link["autopilot_address"] = flight.ap.address
    state = {"t0": None}

    def speak():
        e = impostor.enc
        impostor.send(e.heartbeat_encode(2, 12, 1 | 128, 4 << 16 | 4 << 24, 4), flight.target)
        impostor.send(e.local_position_ned_encode(0, 1000.0, 1000.0, -2, 0, 0, 0), flight.target)
        impostor.drain()

    def early():  # first: the real autopilot waits until the daemon has answered the impostor (or for 1 s)
        if not first:
            return True
        speak()
        state["t_speak"] = state.get("t_speak") or time.monotonic()
        return bool(impostor.got) or configured and time.monotonic() - state["t_speak"] > 1.0

    def later(t):
        if not first and t > 1.0:
            state["t0"] = state["t0"] or time.monotonic()
            speak()

    log = flight.fly(5.0, later, before=early, answered=lambda: flight.ap.got or impostor.got)
    impostor.sock.close()
    return flight, impostor, log, state["t0"]


@pytest.mark.parametrize("configured", [True, False], ids=["address configured", "first heard"])
def test_a_second_autopilot_is_refused_and_said_the_real_one_keeps_the_link(tmp_path, configured):
    """The impostor speaks after the real autopilot: refused (its position never taken), said in the event
    log, a STATUSTEXT and the console, and the real autopilot keeps hearing the daemon (it used to be dropped
    without a word)."""
    flight, impostor, log, t0 = impostor_flight(tmp_path, configured, first=False)
    assert t0 is not None
    assert states(log) and all(s["x"] == 1.0 for s in states(log))
    refused = [r for r in log if r.get("event") == "source_refused" and r["what"] == "refused"]
    assert refused and refused[0]["autopilot"] and refused[0]["address"] == impostor.address
    assert refused[0]["pinned"] == flight.ap.address
    assert any("second autopilot 1/1" in t and "REFUSED" in t for t in flight.ap.texts())  # the ground station hears it
    assert f"a second autopilot 1/1 from {impostor.address} REFUSED" in flight.console
    assert len(flight.ap.received("HEARTBEAT", after=t0)) >= 2  # the daemon still talks to the real one
    contest = [" ".join(t.split()) for t in flight.ap.texts() if "claim the autopilot 1/1" in t]
    assert contest and f"said to the seat {flight.ap.address}" in contest[0]  # the seat hears it, and whom it is
    assert "refusing to engage" in contest[0]
    assert not impostor.received("HEARTBEAT") and not impostor.received("COMMAND_LONG")
    assert counters(log)["refused_address"] > 50


def test_an_impostor_heard_first_is_refused_where_the_autopilot_address_is_configured(tmp_path):
    """Whoever sends the first autopilot HEARTBEAT is pinned unless the address is configured (the real
    autopilot then got no command at all). With link.autopilot_address, the real one gets the link-up commands
    and the impostor nothing."""
    flight, impostor, log, _ = impostor_flight(tmp_path, configured=True, first=True)
    assert states(log) and all(s["x"] == 1.0 for s in states(log))
    asked = flight.ap.received("COMMAND_LONG")
    assert [m for m in asked if m.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL]  # the daemon's link-up requests
    assert not impostor.received("COMMAND_LONG") and not impostor.received("HEARTBEAT")
    assert [r for r in log if r.get("event") == "source_refused" and r["address"] == impostor.address]
    assert f"from {flight.ap.address}" in flight.console  # the banner names the configured address


def test_an_impostor_heard_alone_first_without_a_configured_address_is_never_silent(tmp_path):
    """Without link.autopilot_address an impostor heard alone before the real autopilot speaks at all takes the
    seat (nothing else tells them apart): then the real autopilot is refused — loudly, naming both addresses, so
    that a person can configure the right one — and the seat is contested: no engaging."""
    flight, impostor, log, _ = impostor_flight(tmp_path, configured=False, first=True)
    refused = [r for r in log if r.get("event") == "source_refused" and r["what"] == "refused"]
    assert refused and refused[0]["address"] == flight.ap.address and refused[0]["pinned"] == impostor.address
    assert f"a second autopilot 1/1 from {flight.ap.address} REFUSED" in flight.console
    assert [r for r in log if r.get("event") == "source_refused" and r["what"] == "contested"]
    assert "2 addresses claim the autopilot 1/1" in flight.console


# ------------------------------------------------------------------ the pieces: the link and MAVLink-in
@contextlib.contextmanager
def link_and_peers(pins=None, **peers):
    """A listening UdpLink on a free loopback port and named `Peer`s ((system, component) each); closed after."""
    from companion.onboard.link import open_connection

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    link = open_connection(f"udpin:127.0.0.1:{port}", 0, 1, 191, (1, 1), pins)
    made = {k: Peer(*ids) for k, ids in peers.items()}
    try:
        yield link, ("127.0.0.1", port), made
    finally:
        link.close()
        for peer in made.values():
            peer.sock.close()


def read_all(link, tries=20) -> list:
    got = []
    for _ in range(tries):
        m = link.recv_msg()
        while m is not None:
            got.append(m)
            m = link.recv_msg()
        time.sleep(0.005)
    return got


def test_a_sensor_with_ids_of_its_own_is_taken_from_the_address_that_claimed_it_alone(monkeypatch):
    import companion.onboard.link as lk

    monkeypatch.setattr(lk, "SEAT_SETTLE_S", 0.2)
    with link_and_peers({(1, 1): None, (1, 158): None}, ap=(1, 1), lidar=(1, 158), spoof=(1, 158)) as (link, target, p):
        p["ap"].send(p["ap"].enc.heartbeat_encode(2, 12, 0, 0, 4), target)
        for _ in range(3):  # heard alone for the settle time: the seat is the lidar's
            p["lidar"].send(p["lidar"].enc.distance_sensor_encode(0, 20, 600, 300, 0, 0, 0, 255), target)
            read_all(link)
            time.sleep(0.1)
        assert link.pinned[(1, 158)] == p["lidar"].sock.getsockname()
        for _ in range(20):
            p["spoof"].send(p["spoof"].enc.distance_sensor_encode(0, 20, 600, 601, 0, 0, 0, 255), target)
        p["lidar"].send(p["lidar"].enc.distance_sensor_encode(0, 20, 600, 300, 0, 0, 0, 255), target)
        got = [m for m in read_all(link) if m.get_type() == "DISTANCE_SENSOR"]
        assert [m.current_distance for m in got] == [300]
        assert link.stats["foreign_source"] == 20
        r, contest = link.take_refusals()  # reported once, with the first of them; and the contest
        assert (r["what"], r["ids"], r["address"], r["pinned"]) == ("refused", (1, 158), p["spoof"].address,
                                                                    p["lidar"].address)
        assert (contest["what"], contest["ids"], contest["pinned"]) == ("contested", (1, 158), p["lidar"].address)


def test_an_autopilot_on_its_first_address_moves_only_after_silence_and_says_so(monkeypatch):
    import companion.onboard.link as lk

    monkeypatch.setattr(lk, "CLIENT_TIMEOUT_S", 0.3)
    monkeypatch.setattr(lk, "CONTEST_S", 0.3)
    monkeypatch.setattr(lk, "SEAT_SETTLE_S", 0.0)
    with link_and_peers(None, old=(1, 1), new=(1, 1)) as (link, target, p):
        hb = p["old"].enc.heartbeat_encode(2, 12, 0, 0, 4)  # disarmed: the seat may move once silent
        p["old"].send(hb, target)
        read_all(link)
        p["new"].send(hb, target)
        read_all(link)
        assert link.autopilot_addr == p["old"].sock.getsockname()
        assert [r["what"] for r in link.take_refusals()] == ["refused", "contested"]
        time.sleep(0.4)  # the old address falls silent
        p["new"].send(hb, target)
        read_all(link)
        assert link.autopilot_addr == p["new"].sock.getsockname()
        [r] = [r for r in link.take_refusals() if r["what"] != "uncontested"]
        assert (r["what"], r["address"], r["pinned"]) == ("moved", p["new"].address, p["old"].address)


def test_a_configured_autopilot_address_is_never_left(monkeypatch):
    import companion.onboard.link as lk

    monkeypatch.setattr(lk, "CLIENT_TIMEOUT_S", 0.1)
    ap = Peer(1, 1)
    with link_and_peers({(1, 1): ap.sock.getsockname()}, impostor=(1, 1)) as (link, target, p):
        ap.sock.close()
        time.sleep(0.2)  # the autopilot silent for longer than the time-out
        p["impostor"].send(p["impostor"].enc.heartbeat_encode(2, 12, 0, 0, 4), target)
        assert not read_all(link)
        assert "%s:%d" % link.autopilot_addr == ap.address
        assert link.stats["foreign_autopilot"] == 1 and link.take_refusals()[0]["pinned"] == ap.address


def test_mavlink_in_takes_each_sensor_from_its_configured_source_only():
    from companion.onboard.config import config_from_dict
    from companion.onboard.mavlink_in import MavlinkIn
    from companion.onboard.mavlink_out import Counters
    from companion.onboard.samples import Scan, SourceRefused

    cfg = config_from_dict({"mode": "shadow", "sensors": [
        {"h_fov_deg": 30, "max_range_m": 6},  # the autopilot's forward sensor (1/1)
        {"h_fov_deg": 30, "orientation_deg": 90, "component_id": 158, "max_range_m": 6}]})  # a peripheral, right
    c = Counters()
    inp = MavlinkIn(cfg, None, lambda: 0.0, None, c)

    def msg(ids, orientation=0, id_=0):
        enc = mav.MAVLink(None, srcSystem=ids[0], srcComponent=ids[1])
        return enc.decode(bytearray(enc.distance_sensor_encode(0, 20, 600, 300, 0, id_, orientation, 255).pack(enc)))

    right = 6  # MAV_SENSOR_ROTATION_YAW_270: facing right
    [fwd] = inp.accept(msg((1, 1)))
    [side] = inp.accept(msg((1, 158), right))
    assert (fwd.sensor, fwd.source, side.sensor, side.source) == (0, (1, 1, 0), 1, (1, 158, 0))
    assert isinstance(fwd, Scan) and inp.accept(msg((1, 158))) == []  # the peripheral has no forward sensor
    first = inp.accept(msg((1, 200)))
    assert [type(s) for s in first] == [SourceRefused] and first[0].ids == (1, 200)
    assert inp.accept(msg((1, 200))) == []  # reported once; counted always
    assert [s.ids for s in inp.accept(msg((2, 1)))] == [(2, 1)]  # another system's autopilot ids
    assert c.unknown_source == 3
    gcs = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    assert inp.accept(gcs.decode(bytearray(gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs)))) == []
    assert c.unknown_source == 3  # a ground station's other messages are not an unknown source


# ------------------------------------------------------------------ the first speaker, as a hostile reviewer tried it
def test_an_impostor_heartbeat_before_the_autopilot_and_every_9_s_takes_no_seat_and_engaging_is_refused(tmp_path):
    """Governor mode listening on the loopback with no link.autopilot_address: one impostor HEARTBEAT 1/1
    just before the real autopilot's, then one every 9 s. It used to take the seat (the daemon's HEARTBEAT and
    commands went to it; the real autopilot got none, its first messages said to be "a second autopilot …
    REFUSED … it is None", and engaging was refused for a wrong reason: "autopilot did not report
    MPC_TILTMAX_AIR"). Now no one holds the seat while both claim it, engaging is refused for that reason, and
    it is said on the console, in the event log and to the ground station (no seat: not to either claimant)."""
    flight = Flight(tmp_path, link={"unsigned_params": True})
    impostor, gcs = Peer(1, 1), Peer(255, 190)
    state = {"last": None, "asked": 0}

    def first():  # once the daemon listens (it answers the ground station): one impostor HEARTBEAT, then the real
        gcs.send(gcs.enc.heartbeat_encode(6, 8, 0, 0, 4), flight.target)
        gcs.drain()
        if state["last"] is None and gcs.got:
            impostor.send(impostor.enc.heartbeat_encode(2, 12, 1 | 128, 4 << 16 | 4 << 24, 4), flight.target)
            state["last"] = time.monotonic()
        return state["last"] is not None

    def each(t):
        if time.monotonic() - state["last"] > 9.0:
            impostor.send(impostor.enc.heartbeat_encode(2, 12, 1 | 128, 4 << 16 | 4 << 24, 4), flight.target)
            state["last"] = time.monotonic()
        if int(t * 50) % 50 == 0:
            gcs.send(gcs.enc.heartbeat_encode(6, 8, 0, 0, 4), flight.target)
        if t > 3.0 and state["asked"] < 1:
            gcs.send(gcs.enc.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9), flight.target)
            state["asked"] += 1
        gcs.drain()
        impostor.drain()

    flight.mode = "governor"
    log = flight.fly(11.0, each, before=first, answered=lambda: gcs.got)
    impostor.sock.close()
    gcs.sock.close()
    assert not impostor.received("HEARTBEAT") and not impostor.received("COMMAND_LONG")  # it holds no seat
    assert not flight.ap.received("COMMAND_LONG")  # nor does the real one: two claim it
    contest = [r for r in log if r.get("event") == "source_refused" and r["what"] == "contested"]
    assert contest and set(contest[0]["address"].split(", ")) == {impostor.address, flight.ap.address}
    assert contest[0]["pinned"] is None
    assert "2 addresses claim the autopilot 1/1" in flight.console
    assert "it is None" not in flight.console  # the false report at every ordinary start
    said = [" ".join(t.split()) for t in gcs.texts() if "claim the autopilot 1/1" in t]  # (chunks padded)
    assert said and "no seat held: said to the ground stations only" in said[0]
    [refused] = [r for r in log if r.get("event") == "engage_refused"]
    assert "claim the autopilot 1/1" in refused["reason"] and "MPC_TILTMAX_AIR" not in refused["reason"]
    assert not [s for s in states(log) if s["x"] == 1000.0]
    assert "link: loopback only" in flight.console  # the banner says how seats are given


@pytest.mark.parametrize("armed", [True, False], ids=["in flight: the seat is held", "on the ground: it moves"])
def test_a_silent_autopilot_loses_its_seat_to_a_new_address_only_on_the_ground(tmp_path, armed):
    """The autopilot (x = 1 m) holds its seat, then falls silent for good; from 1 s later another address claims
    its ids (x = 1000 m). Armed (in flight), the seat is never moved: the newcomer is refused, said with why
    ("seat held: armed"), and never answered. Disarmed (on the ground), it takes the seat once the holder has
    been silent for 10 s and it has been the only claimant for 2 s, and the move is said. Before, the seat
    followed the new address after 10 s of silence in flight too."""
    flight = Flight(tmp_path)
    flight.armed = armed
    flight.silent = lambda t: t > 1.0
    newcomer = Peer(1, 1)

    def each(t):
        if t > 2.0:
            e = newcomer.enc
            newcomer.send(e.heartbeat_encode(2, 12, 1 | (128 if armed else 0), 4 << 16 | 4 << 24, 4), flight.target)
            newcomer.send(e.local_position_ned_encode(0, 1000.0, 1000.0, -2, 0, 0, 0), flight.target)
            newcomer.drain()

    log = flight.fly(16.0, each)
    newcomer.sock.close()
    xs = {s["x"] for s in states(log)}
    said = [r for r in log if r.get("event") == "source_refused" and r["address"] == newcomer.address]
    if armed:
        assert xs == {1.0} and not newcomer.received("HEARTBEAT")
        assert said and said[0]["what"] == "refused" and said[0]["held"] == "armed"
        assert "(seat held: armed)" in flight.console
    else:
        assert 1000.0 in xs and newcomer.received("HEARTBEAT")
        moved = [r for r in log if r.get("event") == "source_refused" and r["what"] == "moved"]
        assert moved and moved[0]["address"] == newcomer.address and moved[0]["pinned"] == flight.ap.address
