"""Issue 19 item 8: collision rate against a hidden shortfall, with and without a navigation margin.

Flies examples/campaign-hidden-fog.yaml (the campaign machinery, companion/campaign.py) once per
(visibility fraction, nav_margin) over the same scenarios; prints one JSON object: per mode and cell the
flights, collisions, route completions and mean speed. Results under OUT/frac<f>_margin<m>/ (resumable).

    nice -n 10 python -m benchmarks.hidden_fog OUT [--scenarios N] [--margins 0 0.3] [--fracs 1 0.9 0.8 0.7 0.5]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from companion import campaign as cg

SPEC = Path(__file__).resolve().parent.parent / "examples" / "campaign-hidden-fog.yaml"


def spec_for(frac: float, margin: float, scenarios: int) -> cg.CampaignSpec:
    d = cg.load_spec(SPEC).model_dump(mode="json")
    d.update(scenarios=scenarios, nav_margin=margin, name=f"fog{frac:g}_m{margin:g}")
    fault = d["faults"][0]
    fault.update(visibility_frac=frac, p=1.0 if frac < 1.0 else 0.0)
    return cg.spec_from_dict(d)


def cell(rows: list[dict]) -> dict:
    n = len(rows)
    hits = sum(r["collided"] for r in rows)
    return {"flights": n, "collisions": hits, "collision_rate": round(hits / n, 3) if n else None,
            "completed": sum(r["route_completed"] for r in rows),
            "mean_speed_m_s": round(float(np.mean([r["mean_speed_m_s"] for r in rows])), 3) if n else None,
            "min_clearance_m": round(min(r["min_clearance_m"] for r in rows), 3) if n else None}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--scenarios", type=int, default=30)
    ap.add_argument("--margins", type=float, nargs="+", default=[0.0, 0.3])
    ap.add_argument("--fracs", type=float, nargs="+", default=[1.0, 0.9, 0.8, 0.7, 0.5])
    a = ap.parse_args(argv)
    table = []
    for margin in a.margins:
        for frac in a.fracs:
            spec = spec_for(frac, margin, a.scenarios)
            rows = cg.run(spec, a.out / f"frac{frac:g}_margin{margin:g}", workers=1, progress=False,
                          spec_path=str(SPEC))
            for mode in cg.OURS:
                table.append({"mode": mode, "visibility_frac": frac, "nav_margin": margin,
                              **cell([r for r in rows if r["mode"] == mode])})
    print(json.dumps({"spec": str(SPEC), "scenarios": a.scenarios, "cells": table}, indent=1))


if __name__ == "__main__":
    main()
