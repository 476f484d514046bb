"""The paper's demonstration flights (Figures 14–16): the full contract, flown on the SITL.

Paper: "Virtual obstacle envelope" (Figure 13: the obstacle inflated by E_tr) and "Demonstration of
contract implementation" (Figures 14–16). Each scenario file (`scenarios/fig1*_*.yaml`) gives the
vehicle, the real obstacle (one column: its radius is R_obst), the navigation guarantee (the range
sensor's `max_range_m` is D_od) and the actuator state (a `thrust_ratio` fault at t = 0).

One flight: the contract's Ω = (V_max, tilt) and E_tr (`ContractTable.omega`, the E_tr fixed point
included; the tilt capped at `tilt_cap` when given, e.g. the paper's fixed 7.03°/9°/9°); the avoid
planner (`contracts.planner`, eq. (14)–(19)) plans around the virtual obstacle R_obst + E_tr (+ the
body radius) from V_max, after the folded reaction time's straight coast; the SITL cascade flies
the planned reference with position/velocity/acceleration feed-forward (the same loop as the E_tr
sweep, `maneuvers.fly`), thrust limited, design wind. The obstacle is revealed exactly at D_od: on a
cruise at full V_max, the instant the *true* vehicle is D_od from the column's surface, the plan starts
there (as a daemon re-planning from its measured state). The SITL's own collision monitor
(`world.CollisionMonitor`) measures the clearance to the real obstacle.

Negative controls: the same flight planned without the E_tr inflation, and the same manoeuvre entered
at 1.15 × V_max (same ZOH accelerations and sample time; the contract's speed exceeded).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from contracts.contour import contour_errors
from contracts.errors import ContractError

from .maneuvers import DT_NAV, WINDOW_S, fly, wind_for_seed, zoh_reference
from .scenario import Scenario, load_scenario
from .world import Column, CollisionMonitor, World

SCENARIOS = ("fig14_thrust060", "fig15_thrust080", "fig16_thrust100")
# the paper's values (Figures 14–16): fixed tilt, V_max, E_tr
PAPER = {
    "fig14_thrust060": {"figure": 14, "tilt_deg": 7.03, "v_max": 4.09, "e_tr": 0.85},
    "fig15_thrust080": {"figure": 15, "tilt_deg": 9.0, "v_max": 5.29, "e_tr": 0.75},
    "fig16_thrust100": {"figure": 16, "tilt_deg": 9.0, "v_max": 2.93, "e_tr": 0.24},
}
SETTLE_MIN_S = 4.0  # [s] at least this much cruise at V_max before the reveal
COAST_AFTER_S = 3.0  # [s] flown after the planned manoeuvre's last interval
NEG_SPEED_FACTOR = 1.15


@dataclass(frozen=True)
class DemoSetup:
    """What a demonstration scenario file says, in the contract's symbols."""

    name: str
    thrust_ratio: float
    d_od: float
    r_obst: float
    column_xy: tuple[float, float]
    scenario: Scenario

    @classmethod
    def load(cls, name_or_path) -> "DemoSetup":
        sc = load_scenario(name_or_path)
        if len(sc.world.columns) != 1:
            raise ContractError(f"scenario {sc.name}: a demonstration needs exactly one column")
        trs = [f.thrust_ratio for f in sc.faults if f.thrust_ratio is not None and f.at_s == 0.0]
        col = sc.world.columns[0]
        return cls(sc.name, trs[0] if trs else 1.0, sc.sensor.max_range_m, col.radius_m, (col.x_m, col.y_m), sc)


@dataclass
class DemoFlight:
    name: str
    variant: str  # "contract", "no_inflation", "speed_x1.15"
    tilt_cap_deg: float | None
    tilt_deg: float
    v_max: float  # the contract's V_max (the flight's entry speed is v_flown)
    v_flown: float
    e_tr: float  # the contract's E_tr (the virtual obstacle's inflation)
    e_tr_planned: float  # inflation used by this flight's plan (0 for the no-inflation control)
    d_od: float
    r_obst: float
    thrust_ratio: float
    min_clearance: float  # [m] smallest distance from the body to the real obstacle's surface
    touched: bool
    contour_max: float  # [m] worst contour error against the planned path, from the reveal on
    plan_ok: bool
    seed: int
    r_body: float  # [m] the vehicle's radius (touching = centre within R_obst + r_body)
    reveal_lag_m: float  # true − cruise-reference along-track position at the reveal (< 0: vehicle behind)
    planned: np.ndarray = field(repr=False, default=None)  # (m, 2) in the scenario's frame
    flown: np.ndarray = field(repr=False, default=None)  # (n, 2)
    obstacle: tuple = ()

    def summary(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("planned", "flown")}


def plan_avoidance(vehicle, v: float, d_od: float, r_obst: float, e_tr: float, tilt: float, thrust_ratio: float,
                   tilt_model: str, n: int = 40, cpu_time: float = 3.0):
    """The avoid planner's verified trajectory at speed `v` around the keep-out disc r_obst + e_tr +
    r_body centred at c = d_od + r_obst, after a straight coast of v·t_react(tilt) (the folded
    reaction time the table's lookup assumes). Returns (PlanResult or None, t_react)."""
    from dataclasses import replace

    from contracts.avoid_limit import policy_guess
    from contracts.planner import Limits, head_on_problem, plan

    t_r = vehicle.reaction_time(tilt)
    c, r_k = d_od + r_obst, r_obst + e_tr + vehicle.r_body_m
    lim = Limits.from_vehicle(vehicle, tilt, thrust_ratio, tilt_model=tilt_model)
    pr = head_on_problem(lim, v, c, r_k, n=n)
    q0 = list(pr.q0)
    q0[0] = v * t_r
    pr = replace(pr, q0=tuple(q0))
    best = None
    for beta in (1.35, 0.6, 1.0, 0.3, 0.0):
        w, ts = policy_guess(beta, v, lim.accel_bound(), c - v * t_r, r_k, n)
        r = plan(pr, (w, ts), cpu_time=cpu_time, verify_tol=0.0)
        if r.ok and (best is None or r.t_f < best.t_f):
            best = r
    return best, t_r


def fly_demo(table, setup: DemoSetup, tilt_cap: float | None = None, variant: str = "contract", seed: int = 0,
             plan_cache: dict | None = None) -> DemoFlight:
    """One demonstration flight (module docstring). `variant`: "contract", "no_inflation" or
    "speed_x1.15". `plan_cache` (dict) reuses plans between variants."""
    veh = table.vehicle
    om = table.omega(setup.d_od, setup.r_obst, 0.0, setup.thrust_ratio, contract="avoid", tilt=tilt_cap)
    if om.v_max <= 0:
        raise ContractError(f"{setup.name}: the contract gives no safe speed ({om.reason})")
    v, tilt, e_tr = om.v_max, om.tilt, om.e_tr
    e_plan = 0.0 if variant == "no_inflation" else e_tr
    key = (round(v, 9), round(tilt, 9), round(e_plan, 9), setup.d_od, setup.r_obst, setup.thrust_ratio)
    cache = plan_cache if plan_cache is not None else {}
    if key not in cache:
        cache[key] = plan_avoidance(veh, v, setup.d_od, setup.r_obst, e_plan, tilt, setup.thrust_ratio,
                                    table.tilt_model)
    res, t_r = cache[key]
    plan_ok = res is not None
    if plan_ok:
        w, ts = res.w, res.ts
    else:  # no verified pass: brake straight at the cell's full deceleration (the stop branch)
        from contracts.planner import Limits
        from contracts.sweep import brake_accel, stop_trajectory

        lim = Limits.from_vehicle(veh, tilt, setup.thrust_ratio, tilt_model=table.tilt_model)
        w, ts = stop_trajectory(brake_accel(lim), v, 40)
    v_fly = v * (NEG_SPEED_FACTOR if variant.startswith("speed") else 1.0)
    # contract frame: the reveal point (D_od before the surface, on the line) is the origin at t = 0
    cx, cy = setup.column_xy
    c = setup.d_od + setup.r_obst
    origin = np.array([cx - c, cy])
    ref = zoh_reference("plan", (v_fly * t_r, v_fly, 0.0, 0.0), w, ts, COAST_AFTER_S, p0=origin)

    # the reveal: the first instant the *true* vehicle is D_od from the surface; the plan starts there
    # (from the reveal point on the line, time-aligned to the interpolated crossing), as a daemon
    # re-planning from its measured state would; before it, the cruise line at full speed.
    reveal = {}

    def setpoint(t, pos, vel):
        if "t" not in reveal:
            gap = math.hypot(cx - pos[0], cy - pos[1]) - setup.r_obst - setup.d_od
            if gap > 0.0:
                return origin + np.array([v_fly * t, 0.0]), np.array([v_fly, 0.0]), np.zeros(2)
            reveal["t"] = t + gap / v_fly  # interpolated crossing time (gap ≤ 0)
            reveal["lag"] = float(pos[0] - (origin[0] + v_fly * t))  # true − cruise reference, along track
        tau = t - reveal["t"]
        if tau < t_r:
            return origin + np.array([v_fly * tau, 0.0]), np.array([v_fly, 0.0]), np.zeros(2)
        return ref.at(tau - t_r)

    settle = max(SETTLE_MIN_S, 0.0)
    mon = CollisionMonitor(World([Column(cx, cy, setup.r_obst, math.inf, "obstacle")], []), veh.r_body_m)
    fl = fly(veh, setpoint, float(ref.t[-1]) + t_r + 1.5, setup.thrust_ratio, wind_for_seed(veh, seed),
             origin - np.array([v_fly * settle, 0.0]), (v_fly, 0.0), settle_s=settle,
             on_sample=lambda t, pos: mon.update(t, pos))
    t0 = reveal.get("t", 0.0)
    # planned path in flight time: the entry line, the coast from the reveal, then the plan
    tc = np.arange(0.0, t_r, DT_NAV)
    pre = np.arange(-WINDOW_S, 0.0, DT_NAV)
    path_t = t0 + np.concatenate([pre, tc, t_r + ref.t])
    path_p = np.vstack([origin + np.outer(pre, [v_fly, 0.0]), origin + np.outer(tc, [v_fly, 0.0]), ref.p])
    sel = (fl.t >= t0) & (fl.t <= path_t[-1])
    e = contour_errors(fl.pos[sel, :2], fl.t[sel], path_t, path_p, WINDOW_S) if np.any(sel) else np.array([math.inf])
    return DemoFlight(
        name=setup.name, variant=variant, tilt_cap_deg=None if tilt_cap is None else math.degrees(tilt_cap),
        tilt_deg=math.degrees(tilt), v_max=v, v_flown=v_fly, e_tr=e_tr, e_tr_planned=e_plan, d_od=setup.d_od,
        r_obst=setup.r_obst, thrust_ratio=setup.thrust_ratio, min_clearance=float(mon.min_clearance),
        touched=bool(mon.collisions) or mon.min_clearance <= 0.0 or not fl.ok, contour_max=float(np.max(e)),
        plan_ok=plan_ok, seed=seed, r_body=veh.r_body_m, reveal_lag_m=reveal.get("lag", math.nan), planned=path_p,
        flown=fl.pos[:, :2], obstacle=(cx, cy, setup.r_obst))


def demo_set(table, seeds=(0, 1, 2), variants=("contract", "no_inflation", "speed_x1.15"),
             tilt_modes=("paper", "chosen"), names=SCENARIOS) -> list[DemoFlight]:
    """Every scenario × tilt mode (the paper's fixed tilt as a cap, or the contract's choice) ×
    variant × seed."""
    out = []
    for name in names:
        setup = DemoSetup.load(name)
        cache: dict = {}
        for mode in tilt_modes:
            cap = math.radians(PAPER[name]["tilt_deg"]) if mode == "paper" else None
            for variant in variants:
                for seed in seeds:
                    out.append(fly_demo(table, setup, cap, variant, seed, cache))
    return out
