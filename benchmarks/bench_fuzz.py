"""Fuzz the daemon with ≥ 1 M well-formed MAVLink messages of every type it decodes, hostile field values
(tests/fuzz_messages.py), through its real link parser and cycle; one JSON object on stdout.

The daemon runs in governor mode, engaged, on an in-memory link: each 50 Hz step a well-behaved PX4
flying a mission (armed, in the air, fresh position, a clear forward sensor at its rated range) sends
its telemetry, and BENCH_FUZZ_PER_STEP (default 2) hostile messages are mixed in — few enough that the
daemon is engaged and commanding much of the time, so an attempt to raise its speed could show. Checked after every step: no cycle failed, the speed it
commanded never exceeded the stop contract's at the sensor's rated range, and every message with a
non-finite vehicle state was counted as implausible.

    python benchmarks/bench_fuzz.py            # BENCH_FUZZ_N (default 1 000 000), BENCH_FUZZ_SEED (1)
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from companion.onboard.config import config_from_dict  # noqa: E402
from companion.onboard.daemon import Daemon  # noqa: E402
from companion.onboard.link import MemoryMavfile  # noqa: E402
from contracts.table import load_for_vehicle  # noqa: E402
from tests.fuzz_messages import DECODED, mav, packed  # noqa: E402

RATED_M = 6.0


def main() -> None:
    n, seed = int(os.environ.get("BENCH_FUZZ_N", "1000000")), int(os.environ.get("BENCH_FUZZ_SEED", "1"))
    per_step = int(os.environ.get("BENCH_FUZZ_PER_STEP", "2"))
    cfg = config_from_dict({"vehicle": "mambo", "mode": "governor", "engage": True,
                            "link": {"connect": "memory"}, "log": {"dir": tempfile.mkdtemp()},
                            "sensors": [{"kind": "distance_sensor", "h_fov_deg": 30, "max_range_m": RATED_M},
                                        {"kind": "obstacle_distance", "h_fov_deg": 60, "max_range_m": RATED_M}]})
    table = load_for_vehicle(cfg.vehicle)
    cap = table.omega(RATED_M, cfg.contract.r_obst_range_m[0], cfg.contract.e_tr_floor_m,
                      table.vehicle.thrust_ratio_range[1], contract="stop").v_max
    pending: list[bytes] = []
    sent: list[bytes] = []  # what the daemon sends (its commands), kept to be inspected
    def take() -> bytes:
        data = b"".join(pending)
        pending.clear()
        return data

    conn = MemoryMavfile(take, sent.append, source_system=1, source_component=191)
    now = {"t": 0.0}

    class Quiet:  # the event log's interface, counting what it is given
        events = 0

        def event(self, t, name, **fields):
            Quiet.events += 1

        def state(self, t, **fields):
            self.v_cmd = fields.get("v_cmd")

        def tick(self):
            pass

    log = Quiet()
    daemon = Daemon(cfg, table, conn, log, clock=lambda: now["t"], planning="inline")
    rng, encoders, names = np.random.default_rng(seed), {}, list(DECODED)
    ap = encoders.setdefault((1, 1), mav.MAVLink(None, srcSystem=1, srcComponent=1))
    params = {"MPC_TILTMAX_AIR": 45.0, "MPC_ACC_HOR": 3.0, "MPC_JERK_AUTO": 4.0, "COM_OBL_RC_ACT": 5.0}

    reader = mav.MAVLink(None)
    mode = {"custom": 4 << 16 | 4 << 24, "resume": None}  # PX4 AUTO.MISSION

    def normal(t: float) -> list[bytes]:
        """The autopilot: obeys the daemon's Hold; its pilot resumes the mission a second later."""
        for m in reader.parse_buffer(b"".join(sent)) or []:
            if m.get_type() == "COMMAND_LONG" and m.command == 176:
                mode["custom"], mode["resume"] = 4 << 16 | 3 << 24, t + 1.0  # AUTO.LOITER (Hold)
        sent.clear()
        if mode["resume"] is not None and t >= mode["resume"]:
            mode["custom"], mode["resume"] = 4 << 16 | 4 << 24, None
        tb = int(t * 1000)
        out = [ap.heartbeat_encode(2, 12, 1 | 128, mode["custom"], 4), ap.extended_sys_state_encode(0, 1 if t < 1.0 else 2),
               ap.local_position_ned_encode(tb, 3.0 * t, 0, -2, 3.0, 0, 0), ap.attitude_encode(tb, 0, 0, 0, 0, 0, 0),
               ap.estimator_status_encode(0, 1 | 2 | 8 | 16 | 32, 0, 0, 0, 0, 0, 0, 0, 0),
               ap.vfr_hud_encode(3.0, 3.0, 0, 50, -2, 0),
               ap.distance_sensor_encode(tb, 10, 600, 601, 0, 0, 0, 255)]
        if int(t * 50) % 50 == 0:  # the parameters the start-up checks ask for, once a second
            out += [ap.param_value_encode(k.encode(), v, 9, len(params), i) for i, (k, v) in enumerate(params.items())]
        return [m.pack(ap) for m in out]
    bad_expected, v_cmd_max, failures, active = 0, 0.0, 0, 0
    t0, c0 = time.monotonic(), time.process_time()
    for k in range(n):
        data, name, bad = packed(rng, encoders, names[k % len(names)])
        pending.append(data)
        bad_expected += bad
        if k % per_step == per_step - 1:
            pending.extend(normal(now["t"]))
            daemon.poll()
            now["t"] += 0.02
            if daemon.step() is None:
                failures += 1
            v = getattr(log, "v_cmd", None)
            v_cmd_max = max(v_cmd_max, v or 0.0)
            active += daemon.cycle.sup.state == "active"
    wall, cpu = time.monotonic() - t0, time.process_time() - c0
    c = daemon.counters
    engaged = daemon.cycle.sup.state
    print(json.dumps({
        "supervisor_state_at_end": engaged, "hostile_per_step": per_step,
        "steps_active_share": round(active / max(1, n // per_step), 3),
        "benchmark": "fuzz", "inputs": n, "seed": seed, "seconds": round(wall, 1), "cpu_s": round(cpu, 1),
        "inputs_per_s": round(n / wall), "failed_cycles": failures, "loop_errors": c.loop_errors,
        "speed_cap_m_s": round(cap, 3), "v_cmd_max_m_s": round(v_cmd_max, 3), "cap_held": v_cmd_max <= cap + 1e-9,
        "implausible_counted": c.implausible, "implausible_expected_at_least": bad_expected,
        "all_counted": c.implausible >= bad_expected, "bad_packets": c.bad_packets, "messages": c.messages,
        "load_average_1min": round(os.getloadavg()[0], 2), "speed_cap_is_finite": math.isfinite(cap),
    }))


if __name__ == "__main__":
    main()
