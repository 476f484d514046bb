"""MAVSDK (the native `mavsdk` 4.x binding, a test dependency) against the PX4 personality over
real loopback UDP: connect, health, arm, take off, fly offboard, land (auto-disarm)."""

import asyncio
import math

import pytest

pytest.importorskip("mavsdk.asyncio", reason="needs the native MAVSDK binding, mavsdk>=4")
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync  # noqa: E402

from sitl_process import sitl_process  # noqa: E402

SPEEDUP = 2.0


async def until(pred, timeout_s: float, every: float = 0.1):
    end = asyncio.get_running_loop().time() + timeout_s
    while asyncio.get_running_loop().time() < end:
        if await pred():
            return True
        await asyncio.sleep(every)
    return False


async def fly(port: int) -> dict:
    seen = {}
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as m:
        await m.add_any_connection(f"udpout://127.0.0.1:{port}")
        system = await m.first_autopilot(timeout_s=20.0)
        assert system is not None, "no autopilot discovered"
        tel, act, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)

        async def healthy():
            h = await tel.health()
            return h.is_armable and h.is_local_position_ok and h.is_global_position_ok and h.is_home_position_ok
        seen["health"] = await until(healthy, 15.0)
        await act.set_takeoff_altitude(2.0)  # MIS_TAKEOFF_ALT through the parameter protocol
        await act.arm()
        seen["armed"] = await until(tel.armed, 5.0)
        await act.takeoff()
        seen["in_air"] = await until(tel.in_air, 10.0)

        async def at_altitude():
            return abs((await tel.position_velocity_ned()).position.down_m + 2.0) < 0.2
        seen["takeoff_alt"] = await until(at_altitude, 15.0)
        await off.set_position_ned(PositionNedYaw(0.0, 0.0, -2.0, 0.0))
        await off.start()

        async def offboard_mode():
            return await tel.flight_mode() == FlightMode.OFFBOARD
        seen["offboard"] = await until(offboard_mode, 5.0)
        await off.set_position_ned(PositionNedYaw(3.0, 1.0, -2.5, 90.0))

        async def at_target():
            p = (await tel.position_velocity_ned()).position
            return math.dist((p.north_m, p.east_m, p.down_m), (3.0, 1.0, -2.5)) < 0.2
        seen["offboard_target"] = await until(at_target, 15.0)
        await off.stop()
        await act.land()

        async def disarmed():
            return not await tel.armed()
        seen["landed_disarmed"] = await until(disarmed, 30.0)
        seen["final_down_m"] = (await tel.position_velocity_ned()).position.down_m
    return seen


def test_mavsdk_flies_px4_personality():
    with sitl_process("empty", "px4", SPEEDUP) as port:
        seen = asyncio.run(asyncio.wait_for(fly(port), 120))
    assert all(seen[k] for k in ("health", "armed", "in_air", "takeoff_alt", "offboard", "offboard_target",
                                 "landed_disarmed")), seen
    assert abs(seen["final_down_m"]) < 0.05
