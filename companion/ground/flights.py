"""The lock-step flight of the real daemon against the real SITL: one rig for the tests and the campaign.

`Rig(scenario, personality, config)` puts the daemon (`companion.onboard.daemon.Daemon`) and a ground station on
one in-process SITL link (`sitl_harness.LockstepLink`) that carries real MAVLink bytes both ways;
`Rig.run(seconds)` advances the simulator and the daemon in turn at the daemon's loop rate. Truth
(collisions, clearance) comes from the simulator's own API and is only read by assertions and by the
campaign's results, never by the daemon.

This is one of the two wiring modules that may import `sitl_harness/` (the other is `companion/cli.py`,
which wires `sitl` and `demo`; `tests/test_import_graph.py` allows exactly these two): a flight needs both
the daemon and the SITL. Nothing on board imports it. `tests/lockstep.py` re-exports it.

`log_dir`: the SITL writes the autopilot's own flight log there (a ULog for PX4, a DataFlash `.bin` for
ArduPilot; `Rig.close_log()` finishes it and gives its path).

`outbound`: faults of the daemon's outbound link (`OutboundFaults`' keywords; its seed the flight's): every datagram
the daemon sends passes `daemon_write`, where the faults drop or delay it, and `rig.outbound` keeps the ground truth of
what reached the autopilot when. The inbound direction (autopilot → daemon) is not faulted.

`policy`: the speed policy flown in place of the contract's own Ω (a baseline flown as a governor, or a negative
control: `companion/ground/baselines.py`), or a function of the daemon's `Config` that makes one (a baseline law needs
the sensors' mounts: it builds its own obstacle map from every sample the daemon's cycle takes);
`table_wrapper`: a wrapper of the contract table. Neither is an on-board default.
"""

from __future__ import annotations

import heapq
import math
import os
import random
import struct
from collections import deque
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from companion.onboard.config import config_from_dict  # noqa: E402
from companion.onboard.daemon import Daemon  # noqa: E402
from companion.onboard.guidance import InlinePlanning  # noqa: E402
from companion.onboard.link import MemoryMavfile  # noqa: E402
from contracts.table import load_for_vehicle  # noqa: E402
from sitl_harness import LockstepLink, Sim  # noqa: E402
from sitl_harness.scenario import scenario_from_dict  # noqa: E402


class DelayedPlanning(InlinePlanning):
    """Plans at once but answers `delay_s` of vehicle time later, as a worker on a busy host does (deterministic:
    lock-step flights of the planning's latency, benchmarks/bench_plan_latency.py). The planner has no wall-clock
    budget (`budget_s` None, as inline): the delay is the latency, not the host."""

    deferred = True  # the answer comes `delay_s` after it was asked for

    def __init__(self, delay_s: float, clock):
        super().__init__()
        self.delay_s, self.clock, self._due = delay_s, clock, math.inf

    @property
    def busy(self) -> bool:
        return self._out is not None

    def submit(self, planner, *args, **kw) -> None:
        super().submit(planner, *args, **kw)
        self._due = self.clock() + self.delay_s

    def poll(self):
        return super().poll() if self.clock() >= self._due - 1e-9 else None


# the delivery contract's commands: mode requests, speed limits, offboard setpoints (DESIGN.md §1, link and autopilot)
CONTRACTED = ("DO_SET_MODE", "DO_CHANGE_SPEED", "SET_POSITION_TARGET_LOCAL_NED")
STREAMS = ("SET_POSITION_TARGET_LOCAL_NED",)  # each message a new request, none a re-send of another
RESEND_GAP_S = 0.25  # copies of a command this close are re-sends of one request; after a longer silence, a new one
_COMMAND_PARAMS = {mav.MAVLINK_MSG_ID_COMMAND_LONG: tuple(f"param{k}" for k in range(1, 8)),
                   mav.MAVLINK_MSG_ID_COMMAND_INT: ("param1", "param2", "param3", "param4", "x", "y", "z")}


def asks_for_hold(personality: str, p2: float, p3: float) -> bool:
    """A DO_SET_MODE's custom mode (param2, param3) is the personality's Hold: PX4 AUTO.LOITER (main 4, sub 3),
    ArduPilot BRAKE (17) or LOITER (5)."""
    return (p2, p3) == (4.0, 3.0) if personality == "px4" else p2 in (5.0, 17.0)


@dataclass
class Request:
    """One command as the daemon meant it on its channel (a MAV_CMD, or a stream's message): the times its copies
    were sent, and when the first copy reached the autopilot (None: none did)."""

    channel: str
    key: bytes | None  # what makes a copy the same command (None: every message is its own, a stream's)
    hold: bool
    sends: list[float] = field(default_factory=list)
    delivered_s: float | None = None


class OutboundFaults:
    """Seeded faults on the datagrams the daemon sends, in the lock-step rig (whose clock is the simulator's).

    `losses`: windows (start_s, end_s, p) in which each datagram is dropped with probability p (p = 1: a burst);
    `jitter`: windows (start_s, end_s, max_s) in which each is held back U(0, max_s) and delivered in order of due
    time at the rig's next ticks; `drop_holds`: the first k DO_SET_MODE copies that ask for the personality's Hold
    are dropped. Overlapping windows: the largest p, the largest max_s.

    Ground truth, from the bytes (decoded with pymavlink): `dropped` (time sent, message), `delayed` (sent,
    delivered, message), and `requests`, one `Request` per command the daemon meant; `latencies` measures them."""

    def __init__(self, personality: str, losses=(), jitter=(), drop_holds: int = 0, seed: int = 0, shown=None):
        """`shown(msg)`: whether the autopilot already flies the mode a DO_SET_MODE asks for (its effect is then in
        place whether or not the command arrives); None: never taken as shown."""
        self.personality = personality
        self.shown = shown
        self.losses = [tuple(map(float, w)) for w in losses]
        self.jitter = [tuple(map(float, w)) for w in jitter]
        self.holds_to_drop = int(drop_holds)
        self._rng = random.Random(seed)
        self._parser = mav.MAVLink(None)
        self._parser.robust_parsing = True
        self._queue: list = []  # heap of (due, n, sent, data, message, request)
        self._n = 0
        self._latest: dict[str, Request] = {}  # channel → its latest request
        self.requests: list[Request] = []
        self.dropped: list[tuple[float, str]] = []
        self.delayed: list[tuple[float, float, str]] = []

    def send(self, t: float, data: bytes, deliver) -> None:
        """The daemon sent `data` at `t`: drop it, hold it back, or hand it to `deliver` now."""
        msgs = self._parser.parse_buffer(data) or []
        name = msgs[0].get_type() if msgs else "?"
        req = self._request(t, msgs[0]) if msgs else None
        if req is not None and req.delivered_s is None and self.shown is not None and \
                req.channel == "DO_SET_MODE" and self.shown(msgs[0]):
            req.delivered_s = t  # the autopilot already flies that mode: nothing left to deliver
        u, v = self._rng.random(), self._rng.random()  # two draws a datagram: the stream does not depend on the faults
        drop_hold = req is not None and req.hold and self.holds_to_drop > 0
        self.holds_to_drop -= drop_hold
        if drop_hold or u < _active(self.losses, t):
            self.dropped.append((t, name))
            return
        delay = v * _active(self.jitter, t)
        if delay > 0.0:
            heapq.heappush(self._queue, (t + delay, self._n, t, data, name, req))
            self._n += 1
            return
        self._deliver(t, t, data, name, req, deliver)

    def release(self, t: float, deliver) -> None:
        """Hand every held-back datagram due by `t` to `deliver`, in order of due time."""
        while self._queue and self._queue[0][0] <= t + 1e-9:
            _, _, sent, data, name, req = heapq.heappop(self._queue)
            self._deliver(sent, t, data, name, req, deliver)

    def _deliver(self, sent: float, t: float, data: bytes, name: str, req: Request | None, deliver) -> None:
        deliver(data)
        if t > sent:
            self.delayed.append((sent, t, name))
        if req is not None and req.delivered_s is None:
            req.delivered_s = t

    def _request(self, t: float, msg) -> Request | None:
        mid = msg.get_msgId()
        if mid in _COMMAND_PARAMS:
            cmd = msg.command
            entry = mav.enums["MAV_CMD"].get(cmd)
            channel = entry.name.removeprefix("MAV_CMD_") if entry is not None else f"COMMAND_{cmd}"
            params = [float(getattr(msg, f)) for f in _COMMAND_PARAMS[mid]]
            key = struct.pack("<I7d", cmd, *params)  # bytes: a NaN parameter equals itself
            hold = cmd == mav.MAV_CMD_DO_SET_MODE and asks_for_hold(self.personality, params[1], params[2])
        elif msg.get_type() in STREAMS:
            channel, key, hold = msg.get_type(), None, False
        else:
            return None
        last = self._latest.get(channel)
        if key is not None and last is not None and last.key == key and t - last.sends[-1] <= RESEND_GAP_S:
            last.sends.append(t)
            return last
        req = Request(channel, key, hold, [t])
        self.requests.append(req)
        self._latest[channel] = req
        return req

    def latencies(self, t_end: float, channels=CONTRACTED) -> list[tuple[Request, float]]:
        """Per request on `channels`: the time from its first send until it, or a later request of its channel,
        first reached the autopilot (a newer command replaces it); `t_end` where none did. A stream's message is
        also covered by the end of its stream (its last send before a silence of RESEND_GAP_S)."""
        out = []
        for channel in dict.fromkeys(r.channel for r in self.requests if r.channel in channels):
            rs = [r for r in self.requests if r.channel == channel]
            cover = stream_end = math.inf
            for k in range(len(rs) - 1, -1, -1):
                r = rs[k]
                if channel in STREAMS and (k == len(rs) - 1 or rs[k + 1].sends[0] - r.sends[-1] > RESEND_GAP_S):
                    stream_end = r.sends[-1]
                if r.delivered_s is not None:
                    cover = min(cover, r.delivered_s)
                out.append((r, max(0.0, min(cover, stream_end, t_end) - r.sends[0])))
        return sorted(out, key=lambda x: x[0].sends[0])


def _active(windows, t: float) -> float:
    """The largest value of the windows (start, end, value) that contain `t` (0: none; the rig's clock is a sum of
    ticks, so a time is taken 1 ns late)."""
    return max((v for a, b, v in windows if a <= t + 1e-9 < b), default=0.0)


class Recorder:
    """Keeps what the daemon logs, for assertions (the real event log is tested on its own)."""

    def __init__(self):
        self.events: list[dict] = []
        self.states: list[dict] = []

    def event(self, t, name, **fields):
        self.events.append({"t": t, "event": name, **fields})

    def state(self, t, **fields):
        self.states.append({"t": t, **fields})

    def tick(self) -> None:
        """Once a cycle (as the event log commits its events): nothing to commit, the records are in memory."""

    def named(self, name):
        return [e for e in self.events if e["event"] == name]


class Rig:
    def __init__(self, scenario: dict, personality: str = "px4", config: dict | None = None, log=None,
                 table_wrapper=None, seed: int | None = None, sim_kwargs: dict | None = None, policy=None,
                 log_dir=None, planning_delay_s: float | None = None, outbound: dict | None = None):
        sc = scenario_from_dict(scenario)
        self.sim = Sim(sc, personality, seed=seed, **(sim_kwargs or {}))
        ap = self.sim.autopilot
        self.outbound = None if outbound is None else OutboundFaults(
            personality, **{"seed": self.sim.seed, **outbound},
            shown=lambda m: (ap.pers.mode_from_request(m.param1, m.param2, m.param3) or (None, None))[1] == ap.custom)
        if log_dir is not None:  # the autopilot's own flight log (.ulg / .bin); `close_log()` finishes it
            self.sim.start_log(log_dir)
        self.link = LockstepLink(self.sim)
        self._queues: list[deque] = []
        table = load_for_vehicle(sc.vehicle)
        if table_wrapper is not None:
            table = table_wrapper(table)
        cfg = {"vehicle": sc.vehicle, "mode": "governor", "engage": True,
               "link": {"autopilot": personality, "connect": "memory"},
               "sensors": [self._scenario_sensor(sc)]}
        if getattr(self.sim.sensor.cfg, "noise_quad_per_m", 0.0):  # a stereo camera's noise, as its datasheet says
            cfg["detection"] = {"range_noise_quad_per_m": self.sim.sensor.cfg.noise_quad_per_m}
        for k, v in (config or {}).items():
            cfg[k] = {**cfg[k], **v} if isinstance(v, dict) and isinstance(cfg.get(k), dict) else v
        # the sensors are the scenario's: rated at its range unless a test says otherwise
        cfg["sensors"] = [{"max_range_m": sc.sensor.max_range_m, **s} for s in cfg["sensors"]]
        self.cfg = config_from_dict(cfg)
        read, write = self._endpoint()
        self.daemon_out: list[bytes] = []  # every datagram the daemon sent (what a router would forward)
        self._daemon_in: deque = deque()  # datagrams for the daemon only (a ground station via a router)

        def daemon_read():
            extra = b"".join(self._daemon_in)
            self._daemon_in.clear()
            return extra + read()

        def daemon_write(data):
            self.daemon_out.append(data)
            if self.outbound is None:
                write(data)
            else:
                self.outbound.send(self.sim.time_s, data, write)

        self.conn = MemoryMavfile(daemon_read, daemon_write, source_system=1,
                                  source_component=self.cfg.link.component_id)
        self.log = log if log is not None else Recorder()
        if policy is not None and not hasattr(policy, "omega"):  # a factory of the daemon's Config
            policy = policy(self.cfg)
        clock = lambda: self.sim.time_s  # noqa: E731
        self.daemon = Daemon(self.cfg, table, self.conn, self.log, clock=clock, policy=policy,
                             planning="inline" if planning_delay_s is None else
                             lambda: DelayedPlanning(planning_delay_s, clock))
        gread, gwrite = self._endpoint()
        self._gcs_read = gread
        self.gcs = mav.MAVLink(_W(gwrite), srcSystem=255, srcComponent=190)
        self.gcs_msgs: list = []
        self.daemon_on = True

    def _scenario_sensor(self, sc) -> dict:
        """The daemon's sensor entry for the SITL's sensor: its message and the field of view its bins cover (the
        sector sensor: DISTANCE_SENSOR over the scenario's field of view; a depth camera: OBSTACLE_DISTANCE, its
        bins' depth along its axis); a body-fixed model's vertical field of view and mount, where the ground
        comes into its view, and the reach of its spurious returns (its clutter)."""
        s = self.sim.sensor
        if sc.sensor.model == "sector":
            return {"kind": "distance_sensor", "h_fov_deg": sc.sensor.fov_deg}
        kind = "distance_sensor" if "DISTANCE_SENSOR" in s.MESSAGES else "obstacle_distance"
        depth = {"depth": "axis_depth"} if kind == "obstacle_distance" and s.cfg.reports == "z_depth" else {}
        # its spurious returns' reach, as a range (a depth along the axis is up to 1 / cos(half its field) farther)
        reach = s.cfg.spurious_max_m / (math.cos(s.n_used * s.inc / 2) if depth else 1.0)
        clutter = {"clutter_m": round(reach, 3), "spurious_rate": s.cfg.spurious_rate} \
            if s.cfg.spurious_rate > 0 else {}
        return {"kind": kind, "h_fov_deg": round(math.degrees(s.n_used * s.inc), 6), **depth, **clutter,
                "v_fov_deg": s.cfg.v_fov_deg, "mount_pitch_deg": s.cfg.mount_pitch_deg}

    def _endpoint(self):
        q: deque = deque()
        self._queues.append(q)

        def read():
            out = b"".join(q)
            q.clear()
            return out

        return read, self.link.client_send

    def _pump(self):
        data = self.link.client_recv()
        for q in self._queues:
            q.append(data)
        for m in self.gcs.parse_buffer(self._gcs_read()) or []:
            self.gcs_msgs.append(m)

    def run(self, seconds: float, until=None) -> None:
        dt = 1.0 / self.cfg.loop_hz
        end = self.sim.time_s + seconds
        while self.sim.time_s < end - 1e-9:
            step_end = self.sim.time_s + dt - 1e-9
            while self.sim.time_s < step_end:  # the link's ticks; held-back datagrams are delivered between them
                if self.outbound is not None:
                    self.outbound.release(self.sim.time_s, self.link.client_send)
                self.link.tick()
            self._pump()
            if self.daemon_on:
                self.daemon.poll()
                self.daemon.step()
            if until is not None and until(self):
                return

    # ---- ground station
    def to_daemon(self, msg, mav_obj=None) -> None:
        """A ground-station message routed to the daemon (as mavlink-router would)."""
        self._daemon_in.append(msg.pack(mav_obj or self.gcs))

    def daemon_messages(self):
        parser = mav.MAVLink(None)
        parser.robust_parsing = True
        return [m for d in self.daemon_out for m in (parser.parse_buffer(d) or [])]

    def daemon_texts(self) -> list[str]:
        """The daemon's STATUSTEXTs, chunks joined (MAVLink 2 id / chunk_seq)."""
        out, parts = [], {}
        for m in self.daemon_messages():
            if m.get_type() != "STATUSTEXT":
                continue
            text = m.text if isinstance(m.text, str) else m.text.decode()
            if not m.id:
                out.append(text)
                continue
            parts.setdefault(m.id, []).append(text)
            if len(text) < 50:  # the last chunk (the others end at a word, padded with spaces)
                out.append(" ".join("".join(parts.pop(m.id)).split()))
        return out

    def command(self, cmd, *params):
        p = list(params) + [0.0] * (7 - len(params))
        self.gcs.send(self.gcs.command_long_encode(1, 1, cmd, 0, *p))

    def arm(self):
        self.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def start_mission(self):
        self.command(mav.MAV_CMD_MISSION_START, 0, 0)

    @property
    def truth(self):
        return self.sim.truth()

    def close_log(self):
        """Finish the SITL's own flight log (asked for with `log_dir`); its path, or None."""
        return self.sim.close_log()


class _W:
    def __init__(self, write):
        self.write = write


# ----------------------------------------------------------------------------- the flights the tests and campaigns fly

def fly_mission(rig: Rig, seconds: float = 20.0, until=None) -> None:
    """Governor/shadow: a second on the ground, arm, start the autopilot's mission, fly `seconds`."""
    rig.run(1.0, until)
    rig.arm()
    rig.run(0.5, until)
    rig.start_mission()
    rig.run(seconds, until)


def engage_and_fly(rig: Rig, seconds: float, until=None) -> None:
    """Offboard, from a hover: engage asked anew from the ground station (it may engage in flight), fly."""
    rig.run(1.0, until)
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 0.0, 9))
    rig.run(0.2, until)
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9))
    rig.run(seconds, until)


def fly_offboard_scenario(scenario, seconds: float = 62.0, setup=None, **rig_kw) -> Rig:
    """Fly an in-flight scenario (Figures 17, 18) in offboard mode at 2 m; the ground station performs its `gcs`
    actions at their times (through the rig's router to the daemon, as over UDP through the SITL). `setup(rig)`
    runs before the flight; `rig_kw` go to the `Rig`."""
    sc = scenario.model_dump(mode="json")
    sc["start"]["alt_m"] = 2.0
    cfg = {"mode": "offboard", "engage": True, "sensors": [{"kind": "obstacle_distance", "h_fov_deg": 60}],
           "route": {"waypoints": sc["route"]["waypoints"], "altitude_m": 2.0}, "contract": {"r_obst_m": 1.0}}
    rig = Rig(sc, "px4", config=cfg, **rig_kw)
    if setup is not None:
        setup(rig)
    rig.run(1.0)
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 0.0, 9))
    rig.run(0.2)
    rig.to_daemon(rig.gcs.param_set_encode(1, 191, b"CG_ENGAGE", 1.0, 9))
    for a in sorted(scenario.gcs, key=lambda a: a.at_s):
        rig.run(max(0.0, a.at_s - rig.sim.time_s))
        p = a.param_set
        msg = rig.gcs.param_set_encode(1, p.component_id, p.name.encode(), p.value, 9)
        if p.component == "daemon":
            rig.to_daemon(msg)
        else:
            rig.gcs.send(msg)
    rig.run(seconds - rig.sim.time_s)
    return rig
