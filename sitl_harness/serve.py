"""Serve one scenario over UDP, in real time or sped up: `serve(scenario_path, personality, listen, speedup)`.

`listen` is `udp:HOST:PORT` (alias `udpin:`): the vehicle binds HOST:PORT and answers whoever
sends to it (every peer heard in the last 10 s gets the telemetry), e.g. MAVSDK's
`udpout://HOST:PORT` or pymavlink's `udpout:HOST:PORT`; or `udpout:HOST:PORT`: the vehicle pushes
to that address from an ephemeral port (for clients that listen, MAVSDK `udpin://`).

Routing: like an autopilot's MAVLink router (mavlink.io/en/guide/routing.html), the vehicle relays
between its clients (`Router`), so a ground station and a companion computer on the same port see
each other: a client's broadcast messages (HEARTBEAT, STATUSTEXT, PARAM_VALUE, …) reach the others,
and a message addressed to a component learnt behind another client (e.g. PARAM_SET to 1/191) is
forwarded to that client only. Messages for the vehicle itself (1/1) are not forwarded.

One simulated tick (10 ms) is paced to `10 ms / speedup` of wall time; the vehicle's clock
(time_boot_ms, SYSTEM_TIME, TIMESYNC) runs `speedup` times faster than the wall clock. The loop
reports its pacing jitter (how late each tick started, in wall-clock ms).
"""

from __future__ import annotations

import math
import selectors
import socket
import time
from dataclasses import dataclass, field

from .mavlink_endpoint import target_of
from .scenario import ScenarioError
from .sim import Sim

PEER_TIMEOUT_S = 10.0


def parse_listen(listen: str) -> tuple[str, str, int]:
    """`udp:HOST:PORT` / `udpin:HOST:PORT` / `udpout:HOST:PORT` → (kind, host, port)."""
    try:
        kind, host, port = listen.split(":")
        port_i = int(port)
    except ValueError:
        raise ScenarioError(f"--listen {listen!r}: expected udp:HOST:PORT or udpout:HOST:PORT") from None
    if kind not in ("udp", "udpin", "udpout") or not 0 <= port_i <= 65535:
        raise ScenarioError(f"--listen {listen!r}: expected udp:HOST:PORT or udpout:HOST:PORT")
    return ("out" if kind == "udpout" else "in"), host, port_i


class Router:
    """MAVLink routing between clients (channels): routes are learnt from each message's source
    (sysid, compid); a message goes to the other live clients if it is broadcast (no target or
    target system 0), to those behind which its target system was seen (target component 0), or to
    the one behind which its (system, component) was seen. Never back to its sender."""

    def __init__(self, sysid: int = 1, compid: int = 1):
        self.own = (sysid, compid)
        self.routes: dict[tuple[int, int], object] = {}

    def learn(self, client, msg) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src[1] != 0 and src != self.own:  # compid 0 is no valid source; never a route to ourselves
            self.routes[src] = client

    def destinations(self, client, msg, clients) -> list:
        sys_, comp = target_of(msg)
        if sys_ == 0:
            wanted = set(clients)
        elif comp == 0:
            wanted = {c for (s, _), c in self.routes.items() if s == sys_}
        else:
            wanted = {self.routes.get((sys_, comp))}
        return [c for c in clients if c in wanted and c != client]


@dataclass
class ServeStats:
    ticks: int = 0
    forwarded: int = 0
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    late_ms: list[float] = field(default_factory=list)

    def summary(self, sim: Sim) -> dict:
        import numpy as np

        lat = np.array(self.late_ms) if self.late_ms else np.zeros(1)
        return {
            "ticks": self.ticks, "sim_time_s": round(self.sim_time_s, 3), "wall_time_s": round(self.wall_time_s, 3),
            "jitter_ms_mean": float(lat.mean()), "jitter_ms_p99": float(np.percentile(lat, 99)),
            "jitter_ms_max": float(lat.max()), "collisions": len(sim.collisions),
            "rx_bad": sim.endpoint.stats["rx_bad"], "rx_messages": sim.endpoint.stats["rx_messages"],
            "forwarded": self.forwarded,
        }


class UdpVehicle:
    """A `Sim` behind a UDP socket (see module docstring)."""

    def __init__(self, sim: Sim, listen: str):
        self.sim = sim
        kind, host, port = parse_listen(listen)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        if kind == "in":
            self.sock.bind((host, port))
            self.fixed_peer = None
        else:
            self.sock.bind((host, 0))
            self.fixed_peer = (host, port)
        self.address = self.sock.getsockname()
        self.peers: dict[tuple, float] = {}
        self.router = Router(sim.endpoint.sysid, sim.endpoint.compid)
        self.forwarded = 0
        self.sel = selectors.DefaultSelector()
        self.sel.register(self.sock, selectors.EVENT_READ)

    def poll(self, timeout: float) -> None:
        """Wait up to `timeout` s for datagrams; deliver every one that is waiting."""
        if timeout > 0:
            self.sel.select(timeout)
        now = time.monotonic()
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionResetError:
                continue
            self.peers[addr] = now
            for m in self.sim.deliver(data):
                self.router.learn(addr, m)
                for dest in self.router.destinations(addr, m, self.live_peers(now)):
                    self._send(m.get_msgbuf(), dest)
                    self.forwarded += 1

    def live_peers(self, now: float) -> list:
        if self.fixed_peer:
            return [self.fixed_peer]
        return [a for a, t in self.peers.items() if now - t < PEER_TIMEOUT_S]

    def _send(self, pkt: bytes, addr) -> None:
        try:
            self.sock.sendto(pkt, addr)
        except (BlockingIOError, OSError):
            pass

    def flush(self) -> None:
        out = self.sim.take_output()
        if not out:
            return
        for addr in self.live_peers(time.monotonic()):
            for pkt in out:
                self._send(pkt, addr)

    def close(self) -> None:
        self.sel.close()
        self.sock.close()


def run(vehicle: UdpVehicle, speedup: float = 1.0, duration_s: float | None = None, stop=None) -> ServeStats:
    """Pace the simulation against the wall clock until `duration_s` of simulated time or `stop()`."""
    sim = vehicle.sim
    period = sim.tick_dt / speedup
    st = ServeStats()
    t0 = time.monotonic()
    next_t = t0
    while (duration_s is None or sim.time_s < duration_s - 1e-9) and not (stop is not None and stop()):
        now = time.monotonic()
        if now < next_t:
            vehicle.poll(next_t - now)
            now = time.monotonic()
        late = now - next_t
        if late > 1.0:  # far behind (suspended, overloaded): re-anchor instead of bursting
            next_t = now
            late = 0.0
        st.late_ms.append(late * 1e3)
        vehicle.poll(0.0)
        sim.tick()
        vehicle.flush()
        st.ticks += 1
        next_t += period
    st.forwarded = vehicle.forwarded
    st.sim_time_s = sim.time_s
    st.wall_time_s = time.monotonic() - t0
    return st


def serve(scenario_path, personality: str = "px4", listen: str = "udp:127.0.0.1:14540", speedup: float = 1.0,
          *, duration_s: float | None = None, signing_key: bytes | None = None, stop=None, on_ready=None,
          log_dir=None) -> dict:
    """Serve `scenario_path` (a path or a shipped scenario name) until `duration_s` of simulated time
    (forever if None) or until `stop()` returns True. `on_ready(address)` is called once the socket
    is bound. `log_dir`: write the autopilot's own flight log there (`flightlog.py`: a ULog for PX4, a
    DataFlash `.bin` for ArduPilot). Returns a summary dict (ticks, pacing jitter, collisions, dropped packets).
    Raises `ScenarioError` (one line, a `contracts.errors.ContractError`) for a bad scenario,
    personality, address or speed-up, and `ContractError` for a bad vehicle file."""
    if not (isinstance(speedup, (int, float)) and math.isfinite(speedup) and speedup > 0):
        raise ScenarioError(f"--speedup {speedup!r}: expected a positive number")
    parse_listen(listen)
    sim = Sim(scenario_path, personality, signing_key=signing_key, unix_epoch_s=time.time())
    if log_dir is not None:
        try:
            sim.start_log(log_dir)
        except OSError as err:
            raise ScenarioError(f"--log-dir {log_dir}: cannot write ({err.strerror or err})") from None
    try:
        vehicle = UdpVehicle(sim, listen)
    except OSError as err:
        raise ScenarioError(f"--listen {listen}: cannot bind ({err.strerror or err})") from None
    try:
        if on_ready is not None:
            on_ready(vehicle.address)
        st = run(vehicle, speedup, duration_s, stop)
    finally:
        vehicle.close()
        log = sim.close_log()
    summary = st.summary(sim)
    if log is not None:
        summary["flight_log"] = str(log)
    return summary
