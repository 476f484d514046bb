"""`python -m sitl_harness --scenario FILE --personality px4|ardupilot --listen udp:HOST:PORT [--speedup K]`

The same flags as `contract-guard sitl` (which calls `sitl_harness.serve.serve`). Errors a person
can cause end with one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys

from contracts.errors import ContractError

from .scenario import SCENARIO_DIR, ScenarioError
from .serve import serve


def scenario_names() -> list[str]:
    """The shipped scenarios (`sitl_harness/scenarios/*.yaml`), by the name `--scenario` takes."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def build_parser(prog: str = "python -m sitl_harness") -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog=prog, description="SITL quadrotor speaking MAVLink like a PX4 or ArduPilot Copter autopilot "
        "(system 1, component 1); it routes MAVLink between its clients like an autopilot, so a daemon and a "
        "ground station can both connect to it. A scenario with a route loads it as the autopilot's mission "
        "(start it with MAV_CMD_MISSION_START or the ground station's Mission mode).",
        epilog="shipped scenarios: " + ", ".join(scenario_names()) + ". The scenario schema: docs/sitl.md. "
        "On SIGINT/SIGTERM it stops and prints its summary.")
    ap.add_argument("--scenario", default="empty",
                    help="scenario YAML file or shipped scenario name (default: empty, no obstacles, no route)")
    ap.add_argument("--personality", choices=("px4", "ardupilot"), default="px4",
                    help="which autopilot it behaves like: modes, parameters, mission and offboard rules (default px4)")
    ap.add_argument("--listen", default="udp:127.0.0.1:14540", help="udp:HOST:PORT (answer senders) or udpout:HOST:PORT")
    ap.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall-clock second")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    ap.add_argument("--signing-key-hex", default=None, help="MAVLink 2 signing key, 64 hex digits")
    ap.add_argument("--log-dir", default=None, metavar="DIR",
                    help="write the autopilot's own flight log into DIR (flight-NNN.ulg for px4, flight-NNN.bin "
                    "for ardupilot), as the real autopilot writes to its SD card; `contract-guard review` reads it")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m sitl_harness") -> int:
    args = build_parser(prog).parse_args(argv)
    stopping = []

    def _stop(signum, frame):  # stop at the next tick and print the summary (a supervisor's SIGTERM too)
        stopping.append(signum)

    old = {s: signal.signal(s, _stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        key = None
        if args.signing_key_hex is not None:
            try:
                key = bytes.fromhex(args.signing_key_hex)
            except ValueError:
                raise ScenarioError("--signing-key-hex: not hexadecimal") from None
            if len(key) != 32:
                raise ScenarioError("--signing-key-hex: expected 64 hex digits (32 bytes)")
        ready = (lambda a: print(f"SITL {args.personality} listening on {a[0]}:{a[1]}", file=sys.stderr, flush=True))
        summary = serve(args.scenario, args.personality, args.listen, args.speedup, duration_s=args.duration,
                        signing_key=key, on_ready=ready, stop=lambda: bool(stopping),
                        log_dir=args.log_dir)
    except (ScenarioError, ContractError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    print(json.dumps(summary) if args.json else summary_text(summary))
    return 0


def summary_text(s: dict) -> str:
    """The end-of-run summary for a person (``--json`` gives the same fields for a machine)."""
    return (f"SITL stopped: {s['sim_time_s']:.1f} s simulated in {s['wall_time_s']:.1f} s wall ({s['ticks']} ticks)\n"
            f"  collisions: {s['collisions']}\n"
            f"  tick jitter: mean {s['jitter_ms_mean']:.2f} ms, p99 {s['jitter_ms_p99']:.2f} ms, "
            f"max {s['jitter_ms_max']:.2f} ms\n"
            f"  MAVLink in: {s['rx_messages']} messages, {s['rx_bad']} malformed (dropped); "
            f"{s['forwarded']} forwarded")


if __name__ == "__main__":
    sys.exit(main())
