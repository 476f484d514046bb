"""`python -m sitl_harness --scenario FILE --personality px4|ardupilot --listen udp:HOST:PORT [--speedup K]`

The same flags as `contract-guard sitl` (which calls `sitl_harness.serve.serve`). Errors a person
can cause end with one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys

from contracts.errors import ContractError

from .scenario import ScenarioError
from .serve import serve


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sitl_harness", description="SITL quadrotor speaking MAVLink")
    ap.add_argument("--scenario", required=True, help="scenario YAML file or shipped scenario name")
    ap.add_argument("--personality", choices=("px4", "ardupilot"), default="px4")
    ap.add_argument("--listen", default="udp:127.0.0.1:14540", help="udp:HOST:PORT (answer senders) or udpout:HOST:PORT")
    ap.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall-clock second")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    ap.add_argument("--signing-key-hex", default=None, help="MAVLink 2 signing key, 64 hex digits")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    args = ap.parse_args(argv)
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
                        signing_key=key, on_ready=ready)
    except (ScenarioError, ContractError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0
    print(json.dumps(summary) if args.json else summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
