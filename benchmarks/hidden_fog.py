"""Hidden fog: the collision rate and mean speed of the contract (D_od from evidence), of the same contract
believing the sensor's stated range (`_claim`), and of PX4's Collision Prevention law, on the same worlds.

Flies examples/campaign-hidden-fog.yaml (the campaign machinery, companion/ground/campaign.py) once per visibility
fraction (the fog lets the sensor see that fraction of the range it keeps stating; 1: clear air) and prints one
JSON object: per arm and fraction the flights, collisions, route completions, Holds and mean speed, and the
ratios the navigation guarantee is judged by (ours against the PX4 law; clear air: evidence against claim).
Results under OUT/frac<f>/ (resumable).

    nice -n 10 python -m benchmarks.hidden_fog OUT [--scenarios N] [--fracs 1 0.8 0.6 0.4 0.2] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from companion.ground import campaign as cg

SPEC = Path(__file__).resolve().parent.parent / "examples" / "campaign-hidden-fog.yaml"
ARMS = ("governor", "offboard", "px4_cp", "governor_claim", "offboard_claim")


def spec_for(frac: float, scenarios: int, arms=ARMS) -> cg.CampaignSpec:
    d = cg.load_spec(SPEC).model_dump(mode="json")
    d.update(scenarios=scenarios, name=f"fog{frac:g}", arms=list(arms))
    fault = d["faults"][0]
    fault.update(visibility_frac=frac, p=1.0 if frac < 1.0 else 0.0)
    return cg.spec_from_dict(d)


def cell(rows: list[dict]) -> dict:
    n = len(rows)
    hits = sum(r["collided"] for r in rows)
    return {"flights": n, "collisions": hits, "completed": sum(r["route_completed"] for r in rows),
            "flights_with_hold": sum(r["holds"] > 0 for r in rows),
            "mean_speed_m_s": round(float(np.mean([r["mean_speed_m_s"] for r in rows])), 3) if n else None,
            "min_clearance_m": round(min(r["min_clearance_m"] for r in rows), 3) if n else None}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--scenarios", type=int, default=30)
    ap.add_argument("--fracs", type=float, nargs="+", default=[1.0, 0.8, 0.6, 0.4, 0.2])
    ap.add_argument("--workers", type=int, default=1)
    a = ap.parse_args(argv)
    cells, fogged = [], {arm: [] for arm in ARMS}
    for frac in a.fracs:
        rows = cg.run(spec_for(frac, a.scenarios), a.out / f"frac{frac:g}", workers=a.workers, progress=False,
                      spec_path=str(SPEC))
        for arm in ARMS:
            mine = [r for r in rows if r["arm"] == arm]
            cells.append({"arm": arm, "visibility_frac": frac, **cell(mine)})
            if frac < 1.0:
                fogged[arm] += mine
    by = {(c["arm"], c["visibility_frac"]): c for c in cells}
    fog = {arm: cell(rows) for arm, rows in fogged.items()}
    judged = {}
    for mode in ("governor", "offboard"):
        judged[mode] = {
            "fog_collisions": fog[mode]["collisions"], "px4_cp_fog_collisions": fog["px4_cp"]["collisions"],
            "at_most_half_of_px4_cp": fog[mode]["collisions"] * 2 <= fog["px4_cp"]["collisions"],
            "fog_mean_speed_vs_px4_cp": round(fog[mode]["mean_speed_m_s"] / fog["px4_cp"]["mean_speed_m_s"], 3)
            if fog["px4_cp"]["mean_speed_m_s"] else None,
            "claim_fog_collisions": fog[f"{mode}_claim"]["collisions"]}
        if (mode, 1.0) in by:
            clear, claim = by[(mode, 1.0)], by[(f"{mode}_claim", 1.0)]
            judged[mode]["clear_air_speed_cost"] = round(1.0 - clear["mean_speed_m_s"] / claim["mean_speed_m_s"], 4)
            judged[mode]["clear_air_flights_with_hold"] = clear["flights_with_hold"]
            judged[mode]["clear_air_flights_with_hold_claim"] = claim["flights_with_hold"]
    print(json.dumps({"spec": str(SPEC), "scenarios": a.scenarios, "fogged": fog, "judged": judged, "cells": cells},
                     indent=1))


if __name__ == "__main__":
    main()
