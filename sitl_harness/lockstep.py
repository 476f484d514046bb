"""Lock-step link: the vehicle in-process on a simulated clock, real MAVLink bytes both ways.

This is the API the daemon's tests build on::

    from sitl_harness import Sim, LockstepLink
    sim = Sim("column_ahead", "px4")        # scenario name/path/object, personality
    link = LockstepLink(sim)
    link.client_send(packet_bytes)          # one datagram from the client (any bytes, even garbage)
    link.step(0.02)                         # advance simulated time by 20 ms (whole 10 ms ticks)
    data = link.client_recv()               # every byte the vehicle sent since the last call
    sim.time_s                              # the simulated clock [s]; also in the vehicle's
                                            # time_boot_ms / SYSTEM_TIME / TIMESYNC

Delivery is deterministic: bytes sent with `client_send` are delivered, in order, at the start of
the next tick, before the autopilot runs; everything the vehicle emits during `step` is
available from `client_recv` afterwards. The same seed gives the same flight, byte for byte.
`client_recv_packets()` returns the packets one by one. A pymavlink client can parse the bytes
with `mavutil.mavlink.MAVLink(None).parse_buffer(data)` or wrap the link with
`LockstepLink.as_file()` — an object with `write(bytes)` for an encoder's `file` argument.
"""

from __future__ import annotations

from collections import deque

from .sim import Sim


class _Writer:
    def __init__(self, link: "LockstepLink"):
        self._link = link

    def write(self, b) -> None:
        self._link.client_send(bytes(b))


class LockstepLink:
    """In-memory MAVLink link to a `Sim` (see module docstring)."""

    def __init__(self, sim: Sim):
        self.sim = sim
        self._to_vehicle: deque[bytes] = deque()
        self._to_client: list[bytes] = []

    @property
    def time_s(self) -> float:
        return self.sim.time_s

    def client_send(self, data: bytes) -> None:
        """Queue one datagram for the vehicle (delivered at the start of the next tick)."""
        self._to_vehicle.append(bytes(data))

    def as_file(self) -> _Writer:
        return _Writer(self)

    def step(self, dt: float) -> None:
        """Advance the simulation by `dt` seconds (whole ticks), delivering queued datagrams."""
        sim = self.sim
        end = sim.time_s + dt - 1e-9
        while sim.time_s < end:
            self.tick()

    def tick(self) -> None:
        sim = self.sim
        while self._to_vehicle:
            sim.deliver(self._to_vehicle.popleft())
        sim.tick()
        self._to_client.extend(sim.take_output())

    def client_recv_packets(self) -> list[bytes]:
        out, self._to_client = self._to_client, []
        return out

    def client_recv(self) -> bytes:
        return b"".join(self.client_recv_packets())
