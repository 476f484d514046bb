"""The report of a campaign (`companion/ground/campaign.py`): `summarize(rows)` (pure) and `write_report` (JSON, HTML,
PNG; matplotlib is imported here only — offline, never on the daemon's path).

Per arm and per group of scenarios (all, in assumption, nominal = in assumption without faults, and each
stress: hidden fog, thrust loss, wind beyond design, a link fault, a command delivered late; and each named stress
of a spec's `stresses`, `stress_markdown`): the flights in assumption, the collision rate with its exact
Clopper–Pearson 95 % interval (two-sided, `cp95_low` … `cp95_high`) and the one-sided 95 % upper bound
(`upper95_one_sided`: the rate that k or fewer collisions in n would show with 5 % probability; for 0 in n it is
1 − 0.05^(1/n), lower than the two-sided interval's upper end 1 − 0.025^(1/n)), the distribution of the minimum
clearance to the true surface, the mean speed while moving and the time to destination, and the route completion. Ratios:
each arm against each baseline over the same scenarios (paired: the mean speed over the scenarios both
flew; the time to destination over those both completed). Two counts of the flights within the contract: lenient
(`in_assumption`: the sampled conditions alone, `campaign.classify`) and strict (`in_contract`: also no violation
logged and ground speed never above V_safe beyond the review's tolerance, `campaign.strict`), each with its
collisions and bounds; rows flown before Γ_flown was kept are judged strictly by their violations alone (said). The fault matrix: fault kind × subsystem
attributed × action → occurrences, detections, latency. The worst flights, with the command that re-flies
each. In cluttered worlds (the spec's `world_families`), per world family and arm (`world_family_stats`,
`world_family_markdown`): collisions in assumption, route completion where a route exists, stops short without contact
where none does, the mean speed and its ratio to the PX4 law's over the same scenarios, and the alarms the perfect
observer called unfounded per flight-hour, with the hours flown.
"""

from __future__ import annotations

import html
import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from .campaign import BASELINES, refly_command, strict

GROUPS = ("all", "in_assumption", "in_contract", "nominal", "hidden_fog", "thrust_loss", "thrust_below_range", "wind_beyond_design",
          "obstacle_wider_than_r_obst", "link_loss", "sensor_dropout", "bad_nav", "cmd_loss", "cmd_burst", "cmd_jitter",
          "delivery")


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper–Pearson) two-sided interval of a binomial rate, k successes in n."""
    from scipy.stats import beta

    if n == 0:
        return (0.0, 1.0)
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def one_sided_upper(k: int, n: int, confidence: float = 0.95) -> float:
    """The exact one-sided upper bound of a binomial rate, k successes in n: the rate at which k or fewer occur
    with probability 1 − confidence (Clopper–Pearson's upper end at level 1 − confidence, not split in two)."""
    from scipy.stats import beta

    if n == 0 or k == n:
        return 1.0
    return float(beta.ppf(confidence, k + 1, n - k))


def in_group(r: dict, g: str) -> bool:
    if g == "all":
        return True
    if g == "in_assumption":
        return r["in_assumption"]
    if g == "in_contract":
        return strict(r)[0]
    if g == "nominal":
        return r["in_assumption"] and not r["faults"]
    return g in r["stresses"]


def _pct(xs, q):
    return float(np.percentile(xs, q)) if xs else None


def arm_stats(rows: list[dict]) -> dict:
    n = len(rows)
    k = sum(r["collided"] for r in rows)
    clear = [(-1.0 if r["collided"] and r["min_clearance_m"] is None else r["min_clearance_m"])
             for r in rows if r["min_clearance_m"] is not None]
    times = [r["time_to_destination_s"] for r in rows if r["time_to_destination_s"] is not None]
    lo, hi = clopper_pearson(k, n)
    judged = [strict(r) for r in rows]
    why: dict[str, int] = defaultdict(int)
    for (ok, reasons, _), r in zip(judged, rows):
        if r["in_assumption"] and not ok:
            for x in reasons:
                why[x] += 1
    return {"flights": n, "in_assumption": sum(r["in_assumption"] for r in rows),
            "in_contract": sum(ok for ok, _, _ in judged),
            "in_assumption_outside_contract": sum(r["in_assumption"] and not ok for (ok, _, _), r in zip(judged, rows)),
            "outside_contract_why": dict(sorted(why.items())),
            "strict_judged_in_full": all(full for _, _, full in judged),
            "collisions": k, "rate": k / n if n else None, "cp95_low": lo, "cp95_high": hi,
            "upper95_one_sided": one_sided_upper(k, n),
            "clearance_m": {"min": min(clear) if clear else None, "p5": _pct(clear, 5), "p50": _pct(clear, 50),
                            "p95": _pct(clear, 95)},
            "mean_speed_m_s": float(np.mean([r["mean_speed_m_s"] for r in rows])) if rows else None,
            "time_to_destination_s": float(np.mean(times)) if times else None,
            "route_completion": sum(r["route_completed"] for r in rows) / n if n else None,
            "contact_speed_m_s_max": max((r["contact_speed_m_s"] for r in rows if r["contact_speed_m_s"] is not None),
                                         default=None)}


def ratios(rows: list[dict], arms: list[str]) -> dict:
    """arm → baseline → paired mean-speed and time ratios (arm / baseline) over the same scenarios."""
    by = defaultdict(dict)
    for r in rows:
        by[r["arm"]][r["scenario"]] = r
    out = {}
    for a in arms:
        for b in [x for x in arms if x in BASELINES and x != a]:
            common = sorted(set(by[a]) & set(by[b]))
            if not common:
                continue
            va = np.mean([by[a][s]["mean_speed_m_s"] for s in common])
            vb = np.mean([by[b][s]["mean_speed_m_s"] for s in common])
            both = [s for s in common if by[a][s]["time_to_destination_s"] is not None
                    and by[b][s]["time_to_destination_s"] is not None]
            ta = np.mean([by[a][s]["time_to_destination_s"] for s in both]) if both else None
            tb = np.mean([by[b][s]["time_to_destination_s"] for s in both]) if both else None
            out.setdefault(a, {})[b] = {
                "scenarios": len(common), "speed_ratio": float(va / vb) if vb > 0 else None,
                "time_ratio": float(ta / tb) if both and tb > 0 else None, "both_completed": len(both)}
    return out


def fault_matrix(rows: list[dict]) -> list[dict]:
    cells = defaultdict(list)
    for r in rows:
        if r["arm"] in BASELINES:
            continue
        for f in r["fault_outcomes"]:
            if f["occurs"]:
                cells[(r["mode"], f["kind"], f["subsystem"] or "not detected", f["action"] or "-")].append(f)
    out = []
    per_kind = defaultdict(int)
    for (mode, kind, _, _), fs in cells.items():
        per_kind[(mode, kind)] += len(fs)
    for (mode, kind, sub, act), fs in sorted(cells.items()):
        lat = [f["latency_s"] for f in fs if f["latency_s"] is not None]
        out.append({"mode": mode, "fault": kind, "subsystem": sub, "action": act, "flights": len(fs),
                    "of_kind": per_kind[(mode, kind)],
                    "latency_s": {"p50": _pct(lat, 50), "p95": _pct(lat, 95), "max": max(lat) if lat else None}})
    return out


def worst(rows: list[dict], spec_path: str, n: int = 5) -> list[dict]:
    out = []
    for a in sorted({r["arm"] for r in rows}):
        mine = sorted((r for r in rows if r["arm"] == a),
                      key=lambda r: (not r["collided"], math.inf if r["min_clearance_m"] is None else r["min_clearance_m"],
                                     r["index"]))
        for r in mine[:n]:
            out.append({"arm": a, "index": r["index"], "collided": r["collided"], "min_clearance_m": r["min_clearance_m"],
                        "vehicle": r["vehicle"], "personality": r["personality"], "stresses": r["stresses"],
                        "refly": refly_command(spec_path, r["index"])})
    return out


PEER = "px4_cp"  # the law each arm's speed is compared with per world family


def family_arm_stats(rows: list[dict], peer: list[dict]) -> dict:
    """One arm's flights in one world family; `peer`: the PX4 law's flights of the same family."""
    ia = [r for r in rows if r["in_assumption"]]
    route = [r for r in rows if r["route_exists"]]
    dead = [r for r in rows if not r["route_exists"]]
    pv = {r["scenario"]: r["mean_speed_m_s"] for r in peer}
    common = [r for r in rows if r["scenario"] in pv]
    peer_v = float(np.mean([pv[r["scenario"]] for r in common])) if common else 0.0
    hours = sum(r["airborne_s"] for r in rows) / 3600.0
    unfounded = sum(len(r["unfounded_alarms"]) for r in rows)
    k_ia = sum(r["collided"] for r in ia)
    return {"flights": len(rows), "in_assumption": len(ia), "collisions": sum(r["collided"] for r in rows),
            "collisions_in_assumption": k_ia, "cp95_high_in_assumption": clopper_pearson(k_ia, len(ia))[1],
            "with_route": len(route), "routes_completed": sum(r["route_completed"] for r in route),
            "dead_ends": len(dead), "stopped_short": sum(r["stopped_short"] for r in dead),
            "mean_speed_m_s": float(np.mean([r["mean_speed_m_s"] for r in rows])) if rows else None,
            "speed_x_peer": float(np.mean([r["mean_speed_m_s"] for r in common])) / peer_v if peer_v > 0 else None,
            "hours": hours, "unfounded_alarms": unfounded,
            "unfounded_per_hour": unfounded / hours if hours > 0 else None}


def world_family_stats(rows: list[dict]) -> dict:
    """family → arm → `family_arm_stats`, over the rows flown in a cluttered world (empty without any)."""
    rows = [r for r in rows if "world_family" in r]
    out: dict = {}
    for fam in sorted({r["world_family"] for r in rows}):
        mine = [r for r in rows if r["world_family"] == fam]
        peer = [r for r in mine if r["arm"] == PEER]
        for a in dict.fromkeys(r["arm"] for r in mine):
            out.setdefault(fam, {})[a] = family_arm_stats([r for r in mine if r["arm"] == a], peer)
    return out


def _of(k: int, n: int) -> str:
    return f"{k}/{n}" if n else "–"


def world_family_markdown(s: dict) -> str:
    """Per world family and arm: flights, collisions in assumption (of the flights in assumption) and the upper end of
    their two-sided 95 % interval, routes completed where a route exists, stops short without contact where none
    does, mean speed, × the PX4 law's over the same scenarios, unfounded alarms per flight-hour (hours flown)."""
    lines = ["| world | arm | flights | collisions in assumption | CP 95 % upper | routes completed | dead ends: "
             "stopped short | mean speed [m/s] | × px4_cp speed | unfounded alarms / h (hours flown) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for fam, arms in s["per_world_family"].items():
        for a, x in arms.items():
            lines.append(f"| {fam} | {a} | {x['flights']} | {_of(x['collisions_in_assumption'], x['in_assumption'])} "
                         f"| {_f(x['cp95_high_in_assumption'], '{:.2f}')} | "
                         f"{_of(x['routes_completed'], x['with_route'])} | {_of(x['stopped_short'], x['dead_ends'])} | "
                         f"{_f(x['mean_speed_m_s'], '{:.2f}')} | {_f(x['speed_x_peer'], '{:.2f}')} | "
                         f"{_f(x['unfounded_per_hour'], '{:.1f}')} ({x['hours']:.3f}) |")
    return "\n".join(lines)


def summarize(rows: list[dict], spec_path: str = "SPEC.yaml") -> dict:
    rows = sorted(rows, key=lambda r: r["index"])  # the same figures whatever order the rows came in
    arms = list(dict.fromkeys(r["arm"] for r in rows))
    per = {a: {g: arm_stats([r for r in rows if r["arm"] == a and in_group(r, g)]) for g in GROUPS} for a in arms}
    by_vp = {a: {f"{v}/{p}": arm_stats([r for r in rows if r["arm"] == a and r["in_assumption"]
                                       and r["vehicle"] == v and r["personality"] == p])
                 for v in sorted({r["vehicle"] for r in rows}) for p in sorted({r["personality"] for r in rows})}
             for a in arms}
    stresses = list(dict.fromkeys(r["stress"] for r in rows if "stress" in r))
    per_stress = {a: {st: arm_stats([r for r in rows if r["arm"] == a and r.get("stress") == st]) for st in stresses}
                  for a in arms}
    return {"flights": len(rows), "arms": arms, "per_arm": per, "per_stress": per_stress, "in_assumption_by_vehicle_personality": by_vp, "ratios": ratios(rows, arms),
            "ratios_in_assumption": ratios([r for r in rows if r["in_assumption"]], arms),
            "fault_matrix": fault_matrix(rows), "worst": worst(rows, spec_path),
            "per_world_family": world_family_stats(rows)}


def _f(x, fmt="{:.3g}"):
    return "–" if x is None else fmt.format(x)


def format_summary(s: dict) -> str:
    lines = [f"campaign: {s['flights']} flights (95 % upper bounds of the collision rate: exact, one-sided / the "
             "upper end of the two-sided Clopper–Pearson interval; in assumption: the conditions sampled; in contract: "
             "also no violation and ground speed never above V_safe + tolerance)"]
    for a in s["arms"]:
        for g in ("all", "in_assumption", "in_contract"):
            st = s["per_arm"][a][g]
            if st["flights"]:
                lines.append(f"  {a:16s} {g:14s} {st['flights']:5d} flights, {st['collisions']:4d} collisions "
                             f"(95 % upper {_f(st['upper95_one_sided'], '{:.4%}')} one-sided / "
                             f"{_f(st['cp95_high'], '{:.4%}')} two-sided), mean speed {_f(st['mean_speed_m_s'])} m/s, "
                             f"completion {_f(st['route_completion'], '{:.0%}')}, min clearance "
                             f"{_f(st['clearance_m']['min'], '{:.2f}')} m")
        ia = s["per_arm"][a]["in_assumption"]
        if ia["in_assumption_outside_contract"]:
            why = ", ".join(f"{k} {v}" for k, v in ia["outside_contract_why"].items())
            lines.append(f"  {a:16s} in assumption but outside the contract: {ia['in_assumption_outside_contract']} "
                         f"({why})" + ("" if ia["strict_judged_in_full"] else
                                        "; rows without Γ_flown: judged by their violations only"))
    if any(s["per_stress"].values()):
        lines.append(stress_markdown(s))
    if s["per_world_family"]:
        lines.append(world_family_markdown(s))
    for a, rs in s["ratios"].items():
        if a in BASELINES:
            continue
        for b, q in rs.items():
            lines.append(f"  {a} / {b}: speed ×{_f(q['speed_ratio'])}, time ×{_f(q['time_ratio'])} "
                         f"({q['scenarios']} scenarios, {q['both_completed']} both completed)")
    return "\n".join(lines)


def stress_markdown(s: dict) -> str:
    """Per named stress and arm (a spec's `stresses`): flights in assumption, collisions, their 95 % upper bound,
    speed, time, routes."""
    lines = ["| stress | arm | flights | in assumption | collisions | 95 % upper (two-sided CP) | mean speed [m/s] "
             "| time to destination [s] | routes completed |", "|---|---|---|---|---|---|---|---|---|"]
    for st in dict.fromkeys(k for d in s["per_stress"].values() for k in d):
        for a in s["arms"]:
            x = s["per_stress"][a][st]
            done = round(x["route_completion"] * x["flights"]) if x["flights"] else 0
            lines.append(f"| {st} | {a} | {x['flights']} | {x['in_assumption']} | {x['collisions']} | "
                         f"{_f(x['cp95_high'], '{:.2f}')} | "
                         f"{_f(x['mean_speed_m_s'], '{:.2f}')} | {_f(x['time_to_destination_s'], '{:.1f}')} | "
                         f"{done}/{x['flights']} |")
    return "\n".join(lines)


def _table(rows: list[list], head: list[str]) -> str:
    h = "".join(f"<th>{html.escape(str(x))}</th>" for x in head)
    b = "".join("<tr>" + "".join(f"<td>{html.escape(str(x))}</td>" for x in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{b}</table>"


def write_report(rows: list[dict], out, spec_path: str = "SPEC.yaml") -> dict:
    """report.json, report.html, clearance.png, speed.png under `out`; returns the summary."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = summarize(rows, spec_path)
    (out / "report.json").write_text(json.dumps(s, indent=1, sort_keys=True))
    arms = s["arms"]
    fig, ax = plt.subplots(figsize=(8, 4))
    data = [[r["min_clearance_m"] if r["min_clearance_m"] is not None else -1.0 for r in rows if r["arm"] == a]
            for a in arms]
    ax.boxplot(data, tick_labels=arms)
    ax.axhline(0.0, color="r", lw=0.8)
    ax.set_ylabel("minimum clearance to the true surface [m]")
    ax.tick_params(axis="x", rotation=30)
    fig.tight_layout()
    fig.savefig(out / "clearance.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(8, 4))
    for g, off in (("all", -0.2), ("in_assumption", 0.2)):
        ax.bar(np.arange(len(arms)) + off, [s["per_arm"][a][g]["mean_speed_m_s"] or 0 for a in arms], 0.4, label=g)
    ax.set_xticks(range(len(arms)), arms, rotation=30)
    ax.set_ylabel("mean speed while moving [m/s]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "speed.png", dpi=110)
    plt.close(fig)
    per = [[a, g, st["flights"], st["collisions"], _f(st["upper95_one_sided"], "{:.4f}"), _f(st["cp95_high"], "{:.4f}"),
            _f(st["clearance_m"]["min"]),
            _f(st["clearance_m"]["p50"]), _f(st["mean_speed_m_s"]), _f(st["time_to_destination_s"]),
            _f(st["route_completion"], "{:.0%}")]
           for a in arms for g, st in s["per_arm"][a].items() if st["flights"]]
    out_of_contract = [[a, s["per_arm"][a]["in_assumption"]["flights"],
                        s["per_arm"][a]["in_assumption"]["in_assumption_outside_contract"],
                        ", ".join(f"{k} {v}" for k, v in s["per_arm"][a]["in_assumption"]["outside_contract_why"].items())
                        + ("" if s["per_arm"][a]["in_assumption"]["strict_judged_in_full"] else
                           " (rows without Γ_flown: violations only)")] for a in arms]
    rat = [[a, b, q["scenarios"], _f(q["speed_ratio"]), _f(q["time_ratio"]), q["both_completed"]]
           for a, rs in s["ratios"].items() for b, q in rs.items()]
    fm = [[c["mode"], c["fault"], c["subsystem"], c["action"], f"{c['flights']}/{c['of_kind']}",
           _f(c["latency_s"]["p50"]), _f(c["latency_s"]["p95"]), _f(c["latency_s"]["max"])] for c in s["fault_matrix"]]
    vp = [[a, k, st["flights"], st["collisions"], _f(st["cp95_high"], "{:.4f}"), _f(st["mean_speed_m_s"])]
          for a, d in s["in_assumption_by_vehicle_personality"].items() for k, st in d.items() if st["flights"]]
    ps = [[st, a, x["flights"], x["in_assumption"], x["collisions"], _f(x["cp95_high"], "{:.4f}"),
           _f(x["mean_speed_m_s"]), _f(x["time_to_destination_s"]), _f(x["route_completion"], "{:.0%}")]
          for a, d in s["per_stress"].items() for st, x in d.items()]
    cw = [[fam, a, x["flights"], _of(x["collisions_in_assumption"], x["in_assumption"]),
           _f(x["cp95_high_in_assumption"], "{:.4f}"), _of(x["routes_completed"], x["with_route"]),
           _of(x["stopped_short"], x["dead_ends"]), _f(x["mean_speed_m_s"]), _f(x["speed_x_peer"]),
           _f(x["unfounded_per_hour"]), f"{x['hours']:.3f}"]
          for fam, arms in s["per_world_family"].items() for a, x in arms.items()]
    wf = [[w["arm"], w["index"], w["collided"], _f(w["min_clearance_m"]), w["vehicle"], w["personality"],
           ",".join(w["stresses"]), w["refly"]] for w in s["worst"]]
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>contract-guard campaign</title>
<style>body{{font-family:sans-serif}} table{{border-collapse:collapse}} td,th{{border:1px solid #999;padding:2px 6px}}</style>
</head><body><h1>Campaign: {s['flights']} flights</h1>
<h2>Per arm and group</h2>
<p>In assumption: the sampled conditions; in contract: also no violation and ground speed never above V_safe by
more than the review's tolerance. Upper bounds of the collision rate: exact one-sided 95 %, and the upper end of the
two-sided 95 % Clopper–Pearson interval.</p>{_table(out_of_contract, ["arm", "in assumption", "of them outside the contract", "why"])}
{_table(per, ["arm", "group", "flights", "collisions", "95 % upper (one-sided)", "CP 95 % upper (two-sided)",
                                          "min clearance",
                                          "median clearance", "mean speed", "time to destination", "completion"])}
<h2>Per named stress</h2>{_table(ps, ["stress", "arm", "flights", "in assumption", "collisions", "CP 95 % upper",
                                     "mean speed", "time to destination", "completion"])}
<h2>Per world family</h2>{_table(cw, ["world", "arm", "flights", "collisions in assumption", "CP 95 % upper",
                                        "routes completed", "dead ends: stopped short", "mean speed", "× px4_cp speed",
                                        "unfounded alarms / h", "hours flown"])}
<h2>In assumption, by vehicle and personality</h2>{_table(vp, ["arm", "vehicle/personality", "flights",
                                                                  "collisions", "CP 95 % upper", "mean speed"])}
<img src="clearance.png"><img src="speed.png">
<h2>Against each baseline (paired by scenario)</h2>{_table(rat, ["arm", "baseline", "scenarios", "speed ratio",
                                                                  "time ratio", "both completed"])}
<h2>Fault matrix</h2>{_table(fm, ["mode", "fault", "subsystem attributed", "action", "flights / occurrences",
                                  "latency p50 [s]", "p95", "max"])}
<h2>Worst flights</h2>{_table(wf, ["arm", "flight", "collided", "min clearance", "vehicle", "personality",
                                   "stresses", "re-fly"])}
</body></html>"""
    (out / "report.html").write_text(page)
    return s
