"""The lock-step flight of the real daemon against the real SITL: one rig for the tests and the campaign.

`Rig(scenario, personality, config)` puts the daemon (`companion.daemon.Daemon`) and a ground station on
one in-process SITL link (`sitl_harness.LockstepLink`) that carries real MAVLink bytes both ways;
`Rig.run(seconds)` advances the simulator and the daemon in turn at the daemon's loop rate. Truth
(collisions, clearance) comes from the simulator's own API and is only read by assertions and by the
campaign's results, never by the daemon.

This is one of the two wiring modules that may import `sitl_harness/` (the other is `companion/cli.py`,
which wires `sitl` and `demo`; `tests/test_import_graph.py` allows exactly these two): a flight needs both
the daemon and the SITL. Nothing on board imports it. `tests/lockstep.py` re-exports it.

`log_dir`: the SITL writes the autopilot's own flight log there (a ULog for PX4, a DataFlash `.bin` for
ArduPilot; `Rig.close_log()` finishes it and gives its path).

`policy`: the speed policy flown in place of the contract's own Ω (a baseline flown as a governor, or a negative
control: `companion/baselines.py`), or a function of the daemon's `Config` that makes one (a baseline law needs
the sensors' mounts: it builds its own obstacle map from every sample the daemon's cycle takes);
`table_wrapper`: a wrapper of the contract table. Neither is an on-board default.
"""

from __future__ import annotations

import math
import os
from collections import deque

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from contracts.table import load_for_vehicle  # noqa: E402
from sitl_harness import LockstepLink, Sim  # noqa: E402
from sitl_harness.scenario import scenario_from_dict  # noqa: E402

from .config import config_from_dict  # noqa: E402
from .daemon import Daemon  # noqa: E402
from .guidance import PLAN_BUDGET_S, InlinePlanning  # noqa: E402
from .link import MemoryMavfile  # noqa: E402


class DelayedPlanning(InlinePlanning):
    """Plans at once but answers `delay_s` of vehicle time later, with a planner's time budget, as a worker on a
    busy host does (deterministic: lock-step flights of the planning's latency, benchmarks/bench_plan_latency.py)."""

    budget_s = PLAN_BUDGET_S

    def __init__(self, delay_s: float, clock):
        super().__init__()
        self.delay_s, self.clock, self._due = delay_s, clock, math.inf

    @property
    def busy(self) -> bool:
        return self._out is not None

    def submit(self, planner, *args, **kw) -> None:
        super().submit(planner, *args, **{**kw, "budget_s": None})  # the delay is the latency, not the host
        self._due = self.clock() + self.delay_s

    def poll(self):
        return super().poll() if self.clock() >= self._due - 1e-9 else None


class Recorder:
    """Keeps what the daemon logs, for assertions (the real event log is tested on its own)."""

    def __init__(self):
        self.events: list[dict] = []
        self.states: list[dict] = []

    def event(self, t, name, **fields):
        self.events.append({"t": t, "event": name, **fields})

    def state(self, t, **fields):
        self.states.append({"t": t, **fields})

    def named(self, name):
        return [e for e in self.events if e["event"] == name]


class Rig:
    def __init__(self, scenario: dict, personality: str = "px4", config: dict | None = None, log=None,
                 table_wrapper=None, seed: int | None = None, sim_kwargs: dict | None = None, policy=None,
                 log_dir=None, planning_delay_s: float | None = None):
        sc = scenario_from_dict(scenario)
        self.sim = Sim(sc, personality, seed=seed, **(sim_kwargs or {}))
        if log_dir is not None:  # the autopilot's own flight log (.ulg / .bin); `close_log()` finishes it
            self.sim.start_log(log_dir)
        self.link = LockstepLink(self.sim)
        self._queues: list[deque] = []
        table = load_for_vehicle(sc.vehicle)
        if table_wrapper is not None:
            table = table_wrapper(table)
        cfg = {"vehicle": sc.vehicle, "mode": "governor", "engage": True,
               "link": {"autopilot": personality, "connect": "memory"},
               "sensors": [{"kind": "distance_sensor", "h_fov_deg": sc.sensor.fov_deg}]}
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
            write(data)

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
            self.link.step(dt)
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
