"""Lock-step calibration flights for the issue-15 tests: a "real aircraft" (a vehicle that differs from its
vehicle file) flies `contract-guard calibrate plan`'s mission in the real SITL, the daemon on the link, and the
ground station's side of the link is written as a MAVLink `.tlog` (the autopilot's stream, the ground station's
commands and the daemon's messages as a router forwards them, each packet stamped, as MAVProxy writes it).

The plan's hold legs are flown as the plan says: at `hold_before_m` before the leg's waypoint Hold (PX4 Hold /
ArduPilot Brake), `rest_s` at rest, the mission again. `holds="daemon"` (the default): the daemon commands them,
in governor mode with `calibration.legs` (companion/onboard/calibration_holds.py), its sensor rated at `SENSOR_RANGE_M`
(open space: the stop contract's limit is then the plan's top speed, and the governor flies the plan's own speeds).
The ground station plays the operator: after a safety Hold of the daemon's own (at the plan's top speed a tail
wind carries the ground speed past the contract's top, 8 m/s for the X500: "speed limit not in force") it resumes
the mission once the vehicle has been at rest 2 s (`resumed_after_daemon_holds`: when, why). `holds="none"`: the
daemon in governor mode without `calibration.legs` (a negative control: nothing commands the holds).
`holds="gcs"`: the daemon in shadow mode and the ground station commands them (the way before the daemon could).
A plan without hold legs (the held-out flights) is flown with the daemon in shadow mode.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.onboard.autopilots import adapter_for
from companion.ground.flights import Rig, fly_mission
from contracts.missionfile import read_mission

EPOCH_US = 1_790_000_000_000_000
# each flight its own day (calibrate counts logs whose time spans overlap as one flight): the epoch of flight
# (personality, seed) is EPOCH_US + FLIGHT_STEP_US × (2·seed + [ardupilot]); the SITL's own logs share it
FLIGHT_STEP_US = 86_400_000_000


def flight_epoch_us(personality: str, seed: int) -> int:
    return EPOCH_US + FLIGHT_STEP_US * (2 * seed + (personality == "ardupilot"))


def sitl_time_s(stamp_us: int) -> float:
    """A .tlog stamp of these flights as the SITL's time [s] (the stamp less its flight's epoch)."""
    return ((stamp_us - EPOCH_US) % FLIGHT_STEP_US) / 1e6
TRUTH_GAIN = 0.6  # the "real aircraft": position- and velocity-loop gains −40 % …
TRUTH_DELAY_S = 0.06  # … and a 60 ms larger actuator delay than its vehicle file's SITL (which has none),
# with its inner loops tuned for it: the file's attitude/rate gains at 60 ms more delay diverge (checked: rolls
# past 45° within 3 s of hover in 5 m/s wind); att_p × 0.6, rate_p × 0.5 fly (stable to about 80 ms)
TRUTH_INNER = {"att_p": 0.6, "rate_p": 0.5}
SENSOR_RANGE_M = 40.0  # the calibration flight's forward sensor (a lidar's range): V_stop covers 8 m/s at E_tr 3 m


def split_frames(data: bytes) -> list[bytes] | None:
    """The MAVLink frames `data` is made of, whole (MAVLink 1: 8 bytes + payload; 2: 12 + payload, + 13 signed),
    without decoding them; None when it is not a sequence of whole frames."""
    out, pos = [], 0
    while pos < len(data):
        if len(data) - pos < 3 or data[pos] not in (0xFD, 0xFE):
            return None
        n = 8 + data[pos + 1] if data[pos] == 0xFE else 12 + data[pos + 1] + (13 if data[pos + 2] & 1 else 0)
        if pos + n > len(data):
            return None
        out.append(bytes(data[pos:pos + n]))
        pos += n
    return out


class TlogTee:
    """Stamps every packet crossing the ground station's side of a lock-step link into a `.tlog`."""

    def __init__(self, rig: Rig, path: Path, epoch_us: int = EPOCH_US):
        self.rig, self.fh, self.epoch_us = rig, open(path, "wb"), epoch_us  # noqa: SIM115 — closed by close()
        self.parser = mav.MAVLink(None)
        self.parser.robust_parsing = True
        link = rig.link
        recv, send = link.client_recv, link.client_send

        def tee_recv():
            data = recv()
            self._write(data)
            return data

        def tee_send(data):
            self._write(data)
            return send(data)

        link.client_recv = tee_recv
        rig.gcs.file.write = tee_send  # the ground station's own commands
        daemon_write = rig.conn._write

        def tee_daemon(data):  # the daemon's, as a router forwards them to the ground station
            self._write(data)
            return daemon_write(data)

        rig.conn._write = tee_daemon
        self._send = send

    def _write(self, data: bytes) -> None:
        if not data:
            return
        stamp = struct.pack(">Q", self.epoch_us + int(self.rig.sim.time_s * 1e6))
        frames = split_frames(data)
        if frames is None:  # not whole frames: what the parser makes of it
            frames = [bytes(m.get_msgbuf()) for m in self.parser.parse_buffer(data) or []]
        for f in frames:
            self.fh.write(stamp + f)

    def close(self) -> None:
        self.fh.close()


def truth_sim_kwargs(truth=None, actuator_delay_s: float = TRUTH_DELAY_S) -> dict:
    """The `Sim` keywords of the "real aircraft": its vehicle (`truth_vehicle`) and its actuator delay."""
    return {**({"vehicle": truth} if truth is not None else {}), "actuator_delay_s": actuator_delay_s}


def fly_calibration(plan_path: Path, tlog: Path, *, truth=None, personality: str = "px4", seed: int = 0,
                    wind_m_s: float | None = None, vehicle: str = "x500", max_s: float = 900.0,
                    log_dir: Path | None = None, actuator_delay_s: float = TRUTH_DELAY_S, holds: str = "daemon",
                    pilot=None) -> dict:
    """Fly the plan; returns the holds commanded (t, speed, seq; by the daemon: from its `calibration_hold`
    events), when each mission item became current (t, seq), the flight time, whether the plan was flown to its
    end, the daemon's events (`events`, holds="daemon"), and, with `log_dir`, the path of the autopilot's own log
    the SITL wrote (PX4 ULog / ArduPilot DataFlash). Times are the SITL's (`sitl_time_s` of the `.tlog`'s stamps).
    `pilot(rig) -> bool`: called every cycle (a test's pilot: its own mode changes); True ends the flight."""
    if holds not in ("daemon", "gcs", "none"):
        raise ValueError(f"holds must be 'daemon', 'gcs' or 'none', not {holds!r}")
    mp = read_mission(plan_path)
    legs = {leg["mission_seq_plan"] if personality == "px4" else leg["mission_seq_waypoints"]: leg
            for leg in mp.extra.get("legs", []) if leg["kind"] == "hold"}
    by_daemon = holds == "daemon" and bool(legs)
    governor = by_daemon or holds == "none"
    sc = {"name": "calibration", "vehicle": vehicle, "seed": seed, "route": {"mission": str(plan_path)},
          "wind": {} if wind_m_s is None else {"mean_m_s": wind_m_s, "from_deg": 90.0},
          **({"sensor": {"max_range_m": SENSOR_RANGE_M}} if governor else {})}
    config = {"mode": "governor", "engage": True} if governor else {"mode": "shadow", "engage": False}
    if by_daemon:
        config["calibration"] = {"legs": str(plan_path)}
    epoch_us = flight_epoch_us(personality, seed)
    rig = Rig(sc, personality, config=config, seed=seed, log_dir=log_dir,
              sim_kwargs={**truth_sim_kwargs(truth, actuator_delay_s), "unix_epoch_s": epoch_us / 1e6})
    tee = TlogTee(rig, tlog, epoch_us)
    ad = adapter_for(personality)
    ap = rig.sim.autopilot
    done, log, items = set(), [], []
    n_items = len(ap.mission)
    cal = rig.daemon.calibration
    resumed, rest = [], {"since": None}

    def flown() -> bool:
        return (len(cal.done) == len(cal.by_seq)) if by_daemon else holds == "none" or done == set(legs)

    def watch(r: Rig) -> bool:
        seq = ap.mission_seq
        if not items or items[-1]["seq"] != seq:
            items.append({"t": r.sim.time_s, "seq": seq})
        if pilot is not None and pilot(r):
            return True
        sup = r.daemon.cycle.sup
        if governor and sup.state == "holding":  # the operator decides: on with the plan
            if ap.traj.speed_xy < 0.1:
                rest["since"] = r.sim.time_s if rest["since"] is None else rest["since"]
                if r.sim.time_s - rest["since"] >= 2.0:
                    resumed.append({"t": r.sim.time_s, "after": list(sup._held_for)})
                    r.command(mav.MAV_CMD_DO_SET_MODE, *ad.set_mode_params("mission", True))
                    rest["since"] = None
            else:
                rest["since"] = None
        leg = legs.get(seq)
        if holds == "gcs" and leg is not None and seq not in done and ap.mode == "mission":  # the ground station's
            it = ap.mission[seq]
            d = math.hypot(*(ap.pos[:2] - it.local[:2]))
            if d <= leg["hold_before_m"]:
                done.add(seq)
                r.command(mav.MAV_CMD_DO_SET_MODE, *ad.set_mode_params(ad.hold_mode(), True))
                log.append({"t": r.sim.time_s, "speed_m_s": leg["speed_m_s"], "seq": seq})
                r.run(leg["rest_s"] + 3.0 * leg["speed_m_s"] / 3.0 + 1.0)
                r.command(mav.MAV_CMD_DO_SET_MODE, *ad.set_mode_params("mission", True))
        return seq >= n_items - 1 and ap.mode in ("hold", "mission") and ap.traj.speed_xy < 0.05 and flown()

    fly_mission(rig, max_s, until=watch)
    finished = ap.mission_seq >= n_items - 1 and flown()
    rig.run(2.0)
    tee.close()
    own = rig.close_log() if log_dir is not None else None
    events = rig.log.events if governor else []
    if by_daemon:
        log = [{"t": e["t"], "speed_m_s": e["leg_speed_m_s"], "seq": e["seq"], "ground_speed_m_s": e["speed_m_s"],
                "distance_m": e["distance_m"]} for e in events if e["event"] == "calibration_hold"
               and e["status"] == "commanded"]
    return {"holds": log, "items": items, "finished": finished, "flight_s": rig.sim.time_s,
            "autopilot_log": None if own is None else str(own), "holds_by": "daemon" if by_daemon else holds if legs else None,
            "events": events, "resumed_after_daemon_holds": resumed,
            # the autopilot's own waypoints (truth: where the SITL resolved each item), by its sequence number
            "waypoints_local": {k: [float(it.local[0]), float(it.local[1])] for k, it in enumerate(ap.mission)
                                if it.local is not None and all(map(math.isfinite, it.local[:2]))},
            "collisions": len(rig.truth.get("collisions", [])) if isinstance(rig.truth, dict) else None}


def truth_vehicle(name: str = "x500", gain: float = TRUTH_GAIN, inner: dict | None = None):
    """A "real aircraft" that differs from its vehicle file: position- and velocity-loop gains × `gain`, and the
    inner loops scaled by `inner` (default `TRUTH_INNER`, the tuning that flies with `TRUTH_DELAY_S`)."""
    from contracts.vehicle import load_vehicle, vehicle_from_dict

    v = load_vehicle(name)
    d = v.metadata()
    c = d["controller"]
    inner = TRUTH_INNER if inner is None else inner
    d["controller"] = {**c, "pos_p": c["pos_p"] * gain, "vel_p": c["vel_p"] * gain, "vel_i": c["vel_i"] * gain,
                       **{k: c[k] * f for k, f in inner.items()}}
    return vehicle_from_dict(d, f"{name} with gains x{gain}, inner loops {inner}")


def heldout_plan(path: Path, speeds=(3.0, 5.0, 7.0), home=(47.397742, 8.545594, 488.0), alt=5.0) -> Path:
    """Held-out manoeuvres (not in the calibration plan): a zig-zag of 45° turns at each speed."""
    from contracts.geodesy import geo_from_ne
    from contracts.missionfile import (
        MAV_FRAME_GLOBAL_RELATIVE_ALT,
        Item,
        MissionPlan,
        write_plan,
    )

    items, n, e = [], 0.0, 0.0
    for v in speeds:
        items.append(Item(178, MAV_FRAME_GLOBAL_RELATIVE_ALT, (1.0, v, -1.0, 0.0), 0.0, 0.0, 0.0))
        for k in range(4):
            n += 6.0 * v
            e += 6.0 * v * (1 if k % 2 == 0 else -1)
            lat, lon = geo_from_ne(n, e, home[0], home[1])
            items.append(Item(16, MAV_FRAME_GLOBAL_RELATIVE_ALT, (0.0, 0.0, 0.0, math.nan), lat, lon, alt))
    write_plan(path, MissionPlan(home, items, {"legs": []}))
    return path
