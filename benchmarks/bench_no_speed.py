"""Time of one "no safe speed" diagnosis (`companion.onboard.no_speed.diagnose`: the input that caused it, by looking Ω up
again), per kind of cause and contract, on the shipped Mambo table (one JSON object on stdout).

It runs only in the cycle that says a `no safe speed` Hold (or a shadow flight's change of would-be causes), so
its time is added to that one cycle: it must stay well inside the loop's period (20 ms at 50 Hz). Records the
1-minute load average before and after: on a shared machine the figures move with it.

    python benchmarks/bench_no_speed.py [--repeat 50]

On a 2-core AMD EPYC virtual machine at load 7.5: medians 1.1–1.6 ms (D_od and E_tr causes), max 9.6 ms; a
thrust cause 0.01 ms.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.onboard.estimators import DodEstimate  # noqa: E402
from companion.onboard.no_speed import diagnose  # noqa: E402
from companion.onboard.supervisor import Inputs  # noqa: E402
from contracts.table import load_for_vehicle  # noqa: E402

CASES = {  # (D_od, E_tr, thrust_ratio): each a different cause
    "d_od": (0.0, 0.3, 1.0),
    "e_tr": (1.0, 1.2, 1.0),
    "thrust_ratio": (6.0, 0.3, 0.55),
}


def inputs(d_od: float, e_tr: float, thrust_ratio: float) -> Inputs:
    return Inputs(t=0.0, link_ok=True, telemetry_ok=True, nav_ok=True, armed=True, in_air=True, mode="mission",
                  limit_applies=True, mode_by_daemon=False, ground_speed=1.0,
                  dod=DodEstimate(d_od, (), math.inf, None, "bench"), e_tr_measured=e_tr, thrust_ratio=thrust_ratio,
                  r_obst=0.5, engaged=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=50)
    a = ap.parse_args()
    table = load_for_vehicle("mambo")
    out = {"table": "mambo (shipped)", "repeat": a.repeat, "load_before": os.getloadavg()[0]}
    for contract in ("stop", "avoid"):
        for name, case in CASES.items():
            i = inputs(*case)
            diagnose(table, contract, i, e_tr_floor=0.3, thrust_basis="hover")  # warm-up (compiled kernels)
            ms = []
            for _ in range(a.repeat):
                t0 = time.perf_counter()
                diagnose(table, contract, i, e_tr_floor=0.3, thrust_basis="hover")
                ms.append((time.perf_counter() - t0) * 1e3)
            out[f"{contract}_{name}_ms"] = {"median": statistics.median(ms), "max": max(ms)}
    out["load_after"] = os.getloadavg()[0]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
