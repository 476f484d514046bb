"""Hidden fog: the collision rate and mean speed of the contract (D_od from evidence), of the same contract
believing the sensor's stated range (`_claim`), and of PX4's Collision Prevention law, on the same worlds.

Flies examples/campaign-hidden-fog.yaml (the campaign machinery, companion/ground/campaign.py) once per visibility
fraction (the fog lets the sensor see that fraction of the range it keeps stating; 1: clear air) and once per haze
(`--haze`: a medium of that meteorological visibility, α = 3.912 / V_met, whatever the sensor's range) and prints
one JSON object: per arm and fraction the flights, collisions, route completions, Holds and mean speed, each fog's
mean speed as a fraction of the same arm's in clear air, and the ratios the navigation guarantee is judged by
(ours against the PX4 law; clear air: evidence against claim). `governor` reads the SITL's sensor as one
DISTANCE_SENSOR (the nearest of its 12 bins), `governor_sector` as its 12 bins. Results under OUT/frac<f>/ and
OUT/haze<m>/ (resumable).

    nice -n 10 python -m benchmarks.hidden_fog OUT [--scenarios N] [--fracs 1 0.8 0.6 0.4 0.2] [--haze 200]
                                                   [--arms governor offboard ...] [--workers 2]
                                                   [--withhold-the-medium] [--per-frame]

Two negative-control settings the daemon never flies (in-process, one worker): `--withhold-the-medium` keeps the returns
the estimator counts as the medium's from the obstacle logic (tests/test_detection_range.py `hide_the_medium`: what
D_od's evidence does on its own), `--per-frame` counts the governor's DISTANCE_SENSOR as one shot per frame.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from companion.ground import campaign as cg

SPEC = Path(__file__).resolve().parent.parent / "examples" / "campaign-hidden-fog.yaml"
ARMS = ("governor", "governor_sector", "offboard", "px4_cp", "governor_claim", "offboard_claim")


def spec_for(frac: float, scenarios: int, arms=ARMS, haze_m: float | None = None) -> cg.CampaignSpec:
    """The spec at visibility fraction `frac` (1: clear air), or in haze of meteorological visibility `haze_m`."""
    d = cg.load_spec(SPEC).model_dump(mode="json")
    d.update(scenarios=scenarios, name=f"fog{frac:g}" if haze_m is None else f"haze{haze_m:g}", arms=list(arms))
    fault = d["faults"][0]
    if haze_m is None:
        fault.update(visibility_frac=frac, p=1.0 if frac < 1.0 else 0.0)
    else:
        fault.update(met_visibility_m=haze_m, p=1.0)
    return cg.spec_from_dict(d)


def negative_controls(withhold: bool, per_frame: bool) -> None:
    """Patch the campaign's flights in this process for the negative-control settings (module docstring)."""
    if per_frame:
        config = cg.daemon_config

        def per_frame_config(s, arm, nav_margin=0.0):
            cfg = config(s, arm, nav_margin)
            for sensor in cfg.get("sensors", []):
                sensor.pop("shots_per_frame", None)
            return cfg
        cg.daemon_config = per_frame_config
    if withhold:
        from companion.ground import flights
        from tests.test_detection_range import hide_the_medium

        class Withheld(flights.Rig):
            def __init__(self, *a, **k):
                super().__init__(*a, **k)
                hide_the_medium(self.daemon.cycle)
        flights.Rig = Withheld


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
    ap.add_argument("--haze", type=float, nargs="*", default=[], help="meteorological visibilities [m] to fly")
    ap.add_argument("--arms", nargs="+", default=list(ARMS))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--withhold-the-medium", action="store_true", help="negative-control setting (docstring)")
    ap.add_argument("--per-frame", action="store_true", help="negative control: one shot per DISTANCE_SENSOR frame")
    a = ap.parse_args(argv)
    if (a.withhold_the_medium or a.per_frame) and a.workers != 1:
        ap.error("the negative-control settings fly in this process: --workers 1")
    negative_controls(a.withhold_the_medium, a.per_frame)
    arms = a.arms
    cells, fogged = [], {arm: [] for arm in arms}
    media = [(frac, None, f"frac{frac:g}") for frac in a.fracs] + [(1.0, m, f"haze{m:g}") for m in a.haze]
    for frac, haze, sub in media:
        rows = cg.run(spec_for(frac, a.scenarios, arms, haze), a.out / sub, workers=a.workers, progress=False,
                      spec_path=str(SPEC))
        for arm in arms:
            mine = [r for r in rows if r["arm"] == arm]
            medium = {"visibility_frac": frac} if haze is None else {"met_visibility_m": haze}
            cells.append({"arm": arm, **medium, **cell(mine)})
            if frac < 1.0:
                fogged[arm] += mine
    by = {(c["arm"], c.get("visibility_frac")): c for c in cells if "visibility_frac" in c}
    for c in cells:  # each medium's mean speed against the same arm's in clear air
        clear = by.get((c["arm"], 1.0))
        if clear and clear["mean_speed_m_s"] and c["mean_speed_m_s"] is not None:
            c["of_clear_air"] = round(c["mean_speed_m_s"] / clear["mean_speed_m_s"], 3)
    fog = {arm: cell(rows) for arm, rows in fogged.items()}
    judged = {}
    for mode in ("governor", "offboard"):
        if mode not in arms or "px4_cp" not in arms or f"{mode}_claim" not in arms or not fog[mode]["flights"]:
            continue
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
