"""Flying the SITL cascade directly (no MAVLink): hovering, one flight loop (`fly`), the reference
types it flies, the seeded design wind, and the reference manoeuvres of the controller tests (circles,
steps, sampled references) and of the controller-contract sweep (`etr_sweep`, the paper's Figure 12).

Every flight starts `hovering` (at its entry velocity), then `fly` sends `setpoint(t, pos, vel) ->
(p, v, a)` each navigation tick — position + velocity + acceleration feed-forward (PX4 offboard style;
the acceleration is the flat model's attitude feed-forward, eq. (8)) — and steps the physics. Contour
error (Figure 11) on a circle of radius R centred at the origin is exact in closed form:
√((ρ − R)² + Δz²), ρ the horizontal distance from the centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from contracts.contour import contour_errors
from contracts.online_planner import REPLAN_S, AvoidancePlanner, Disc, Plan, best_stop, keeps_plan
from contracts.stop import stop_path_budget
from contracts.vehicle import G, Vehicle

from .control import C_TILT_MAX, M_POS, S_HOVER, SP_ACC, SP_HTE, SP_MODE, SP_POS, SP_VEL, SP_YAW
from .kernel import VehicleModel
from .physics import X_R
from .wind import Wind

DT_NAV = 0.01  # [s] setpoint rate (100 Hz, the SITL's navigation tick)
SETTLE_S = 4.0  # [s] cruise before the manoeuvre (not measured)
COAST_S = 2.0  # [s] measured after the manoeuvre's last interval
WINDOW_S = 1.0  # [s] contour-error path window (±) around each sample's own time
MEASURE_EVERY = 4  # contour error at every 4th tick (25 Hz; the margin covers the sampling)
Z_REF = -2.0  # [m] NED altitude of horizontal setpoints (level flight, DESIGN.md §2)
DIVERGED_M = 50.0  # a contour error beyond this is a lost vehicle: the cell has no bound (+inf)


# ============================================================================ hovering, one flight loop


def hovering(vehicle, thrust_ratio: float = 1.0, pos=(0.0, 0.0, -5.0), vel=(0.0, 0.0, 0.0),
             tilt_max: float | None = None) -> VehicleModel:
    """A `VehicleModel` in the air at `pos` with rotors at hover speed and a converged hover estimate."""
    m = VehicleModel(vehicle)
    m.thrust_ratio = thrust_ratio
    m.x[0:3] = pos
    m.x[3:6] = vel
    m.x[X_R:X_R + 4] = math.sqrt(vehicle.mass_kg * G / (4 * thrust_ratio * vehicle.rotor.k_thrust))
    m.s[S_HOVER] = vehicle.mass_kg * G / (thrust_ratio * vehicle.t_nom_n)
    if tilt_max is not None:
        m.cp[C_TILT_MAX] = tilt_max
    m.sp[SP_MODE] = M_POS
    m.sp[SP_POS:SP_POS + 3] = pos
    m.sp[SP_YAW] = 0.0
    m.sp[SP_HTE] = 1.0
    m.resting = False
    return m


def wind_for_seed(vehicle: Vehicle, seed: int) -> Wind:
    """The vehicle file's design wind (mean + turbulence), blowing from a direction drawn from `seed`."""
    from_deg = float(np.random.default_rng(seed + 7919).uniform(0.0, 360.0))
    return Wind(vehicle.wind.mean_m_s, from_deg, vehicle.wind.gust_m_s, seed=seed)


@dataclass
class Flight:
    t: np.ndarray  # sample times (the tick's end; manoeuvre start = 0)
    pos: np.ndarray  # (n, 3) true NED positions
    vel: np.ndarray  # (n, 3) true NED velocities
    ok: bool  # never NaN, never on the ground


def _ned(x, z: float):
    return (x[0], x[1], x[2]) if len(x) > 2 else (x[0], x[1], z)


def fly(vehicle: Vehicle, setpoint: Callable, t_end: float, thrust_ratio: float = 1.0, wind: Wind | None = None,
        start_p=(0.0, 0.0), start_v=(0.0, 0.0), settle_s: float = SETTLE_S, on_sample: Callable | None = None, *,
        z: float = Z_REF, tilt_max: float | None = None, yaw: float = 0.0, dt_nav: float = DT_NAV) -> Flight:
    """Fly `setpoint(t, pos, vel) -> (p, v, a)` (given the true position and velocity; each horizontal
    (2,) at altitude `z`, or NED (3,), NaN where unused) on the SITL cascade from −settle_s to t_end,
    starting `hovering` at `start_p`, `start_v` (horizontal at `z`, or NED), heading `yaw`: position +
    velocity + acceleration feed-forward, thrust limited to `thrust_ratio`, `wind` (stepped each tick)
    or none. `on_sample(t, pos)` sees every true position; a NaN or a landing ends the flight (not ok)."""
    m = hovering(vehicle, thrust_ratio, _ned(start_p, z), _ned(start_v, 0.0), tilt_max)
    n_phys = max(1, round(dt_nav / m.dt))
    ticks = int(round((t_end + settle_s) / dt_nav))
    ts = np.empty(ticks)
    ps = np.empty((ticks, 3))
    vs = np.empty((ticks, 3))
    ok = True
    m.sp[SP_YAW] = yaw
    for k in range(ticks):
        t = -settle_s + k * dt_nav
        p, v, a = setpoint(t, m.pos, m.vel)
        m.sp[SP_POS:SP_POS + 3] = _ned(p, z)
        m.sp[SP_VEL:SP_VEL + 3] = _ned(v, 0.0)
        m.sp[SP_ACC:SP_ACC + 3] = _ned(a, 0.0)
        if wind is not None:
            m.set_wind(wind.step(dt_nav))
        m.step(n_phys)
        ts[k] = t + dt_nav
        ps[k] = m.pos
        vs[k] = m.vel
        if on_sample is not None:
            on_sample(ts[k], ps[k])
        if not np.all(np.isfinite(m.pos)) or m.pos[2] > -0.05:
            ok = False
            ts, ps, vs = ts[: k + 1], ps[: k + 1], vs[: k + 1]
            break
    return Flight(ts, ps, vs, ok)


# ============================================================================ references (pure maths)


@dataclass(frozen=True)
class Reference:
    """A horizontal reference on the DT_NAV grid from the manoeuvre start (t = 0): positions,
    velocities, accelerations (n, 2). Before t = 0 it is the straight line through p[0] at v[0]."""

    name: str
    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray

    def at(self, t: float):
        """(p, v, a) at time t: the settle line before 0, the nearest sample, the ballistic coast after the end."""
        if t < 0.0:
            return self.p[0] + self.v[0] * t, self.v[0], np.zeros(2)
        if t > self.t[-1]:
            return self.p[-1] + self.v[-1] * (t - self.t[-1]), self.v[-1], np.zeros(2)
        i = int(round(t / DT_NAV))
        return self.p[i], self.v[i], self.a[i]

    def path(self, t0: float = -WINDOW_S):
        """Path samples from t0 (the settle line included) to the end: (times, points (m, 2))."""
        pre = np.arange(math.floor(t0 / DT_NAV), 0) * DT_NAV
        pts = np.vstack([self.p[0] + np.outer(pre, self.v[0]), self.p]) if len(pre) else self.p
        return np.concatenate([pre, self.t]), pts

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def flight(self) -> Reference:
        """The setpoint source of one flight: a fixed reference is its own (no state)."""
        return self

    def setpoint(self, t: float, pos, vel):
        return self.at(t)


def _grid(duration: float) -> np.ndarray:
    return np.arange(int(math.ceil(round(duration / DT_NAV, 6))) + 1) * DT_NAV


def zoh_reference(name: str, q0, w, ts: float, coast_s: float = COAST_S, p0=(0.0, 0.0)) -> Reference:
    """The flat model's ZOH trajectory, eq. (12)–(13) (nodes by `contracts.planner.propagate`), evaluated
    in closed form on the DT_NAV grid (x, y chains of q0 = [X, Ẋ, Y, Ẏ, …] and w (N, ≥2)), then the
    ballistic coast (a = 0). `p0` shifts the positions."""
    from contracts.planner import propagate  # offline side (CasADi) like the rest of the sweep

    w = np.asarray(w, dtype=float)[:, :2]
    n = len(w)
    q = np.zeros(8)
    q[:4] = (q0[0] + p0[0], q0[1], q0[2] + p0[1], q0[3])
    w4 = np.zeros((n, 4))
    w4[:, :2] = w
    qn = propagate(q, w4, ts)
    pn, vn = qn[:, [0, 2]], qn[:, [1, 3]]
    t = _grid(n * ts + coast_s)
    k = np.minimum((t / ts).astype(int), n)
    tau = (t - k * ts)[:, None]
    a = np.where((k < n)[:, None], w[np.minimum(k, n - 1)], 0.0)
    return Reference(name, t, pn[k] + vn[k] * tau + 0.5 * a * tau * tau, vn[k] + a * tau, a)


def cruise_reference(v: float, duration: float = 4.0) -> Reference:
    """Straight, level cruise along +x at `v`."""
    t = _grid(duration)
    z = np.zeros_like(t)
    return Reference("cruise", t, np.column_stack([v * t, z]), np.column_stack([v + z, z]), np.zeros((len(t), 2)))


def speed_step_reference(name: str, v_from: float, v_to: float, a_max: float, coast_s: float = COAST_S) -> Reference:
    """A speed step along +x from `v_from` to `v_to` at constant |acceleration| `a_max` (ZOH, as the
    planner's bang-bang inputs), then `coast_s` at `v_to`."""
    t_acc = abs(v_to - v_from) / a_max
    a = math.copysign(a_max, v_to - v_from)
    return zoh_reference(name, (0.0, v_from, 0.0, 0.0), np.array([[a, 0.0]]), t_acc, coast_s)


def smooth_step_reference(name: str, v_from: float, v_to: float, a: float, j: float,
                          coast_s: float = COAST_S) -> Reference:
    """A speed change along +x as the autopilot's velocity smoothing flies it: the jerk-limited S-curve of
    `contracts.stop.braking_distance` (|acceleration| ≤ a, jerk ≤ j), as ZOH accelerations on DT_NAV that meet its
    speed at every node and end at `v_to`, then `coast_s` at `v_to`. ``hold`` is the one to rest (its Hold)."""
    dv = abs(v_to - v_from)
    a_p = min(a, math.sqrt(j * dv))  # the peak acceleration (a, or where the ramps meet)
    t_end = dv / a_p + a_p / j if dv > 0 else 0.0
    n = max(int(math.ceil(t_end / DT_NAV)), 1)
    fine = np.linspace(0.0, n * DT_NAV, 64 * n + 1)
    acc = np.clip(np.minimum(j * fine, j * (t_end - fine)), 0.0, a_p)
    gain = np.concatenate([[0.0], np.cumsum(0.5 * (acc[1:] + acc[:-1]) * np.diff(fine))])
    nodes = v_from + math.copysign(1.0, v_to - v_from) * np.minimum(gain[::64], dv)
    nodes[-1] = v_to
    w = np.column_stack([np.diff(nodes) / DT_NAV, np.zeros(n)])
    return zoh_reference(name, (0.0, v_from, 0.0, 0.0), w, DT_NAV, coast_s)


@dataclass(frozen=True)
class OnlineReference:
    """``online@ρ`` (Figure 12 over what offboard mode flies): the online planner's first plan around
    `disc` from the entry state (origin, +x at the plan's v[0]) and its limits; each `flight()`
    replans it as the guidance would."""

    name: str
    plan: Plan
    disc: Disc
    v_max: float
    a_max: float  # the replans' (and the fail-safe stop's) acceleration limit: the cell's a_h
    replans: int  # replans modelled per flight
    failsafe_frac: float | None = None  # at this fraction of the first plan, the daemon's fail-safe stop
    stop_decel: float = 0.0  # the stop contract's braking deceleration and jerk (the swerve's path budget)
    brake_jerk: float = math.inf
    stop_jerk: float = math.inf  # the fail-safe stop's jerk (`contracts.stop.stop_jerk`)

    def stop_budget(self, speed: float) -> float:
        """The fail-safe stop's path budget from `speed` (`contracts.stop.stop_path_budget`; none: ∞)."""
        return stop_path_budget(speed, self.stop_decel, self.brake_jerk) if self.stop_decel > 0 else math.inf

    @property
    def t_end(self) -> float:
        extra = 0.0 if self.failsafe_frac is None else 2.0 * self.v_max / max(self.a_max, 1e-3)
        return float(self.plan.t[-1]) + COAST_S + extra

    @property
    def p(self) -> np.ndarray:  # entry state, as `Reference.p[0]`, `Reference.v[0]`
        return self.plan.p[:1]

    @property
    def v(self) -> np.ndarray:
        return self.plan.v[:1]

    def flight(self) -> OnlineFlight:
        return OnlineFlight(self)


class _SentPath:
    """The setpoints a flight sent from −WINDOW_S on (its commanded path, Figure 11)."""

    def __init__(self):
        self._t: list[float] = []
        self._p: list[np.ndarray] = []

    def _sent(self, t: float, p) -> None:
        if t >= -WINDOW_S - 1e-9:
            self._t.append(t)
            self._p.append(np.asarray(p, dtype=float))

    def path(self):
        """The setpoints sent from −WINDOW_S on: (times, points (m, 2))."""
        return np.array(self._t), np.array(self._p)


class OnlineFlight(_SentPath):
    """One flight of an `OnlineReference`: the setpoints sent (its commanded path for the contour
    error, Figure 11, as the on-board estimator sees it) and the replans — from the measured state,
    every REPLAN_S while the disc is still ahead, warm-started from the plan in progress, which a
    failed replan does not replace. With `failsafe_frac` the flight ends as the daemon's offboard
    fail-safe does: at that fraction of the plan, a braking stop from the measured
    state at the cell's a_h (`contracts.online_planner.best_stop`, straight or swerving ≤ 45°, off the
    disc), then rest."""

    def __init__(self, ref: OnlineReference):
        self.ref = ref
        self.plan, self.plan_t = ref.plan, 0.0
        self.left = ref.replans
        self.planner = AvoidancePlanner()  # per flight: the replans do not depend on other flights
        self.adopted = self.kept = 0
        self.stop: Plan | None = None
        self.stop_t = 0.0
        self._a_last = np.zeros(2)  # the last setpoint's acceleration (the fail-safe stop starts from it)
        super().__init__()

    def setpoint(self, t: float, pos, vel):
        ref, d = self.ref, self.ref.disc
        if t < 0.0:
            p, v, a = ref.plan.p[0] + ref.plan.v[0] * t, ref.plan.v[0], np.zeros(2)
        elif self.stop is None and ref.failsafe_frac is not None and t >= ref.failsafe_frac * float(ref.plan.t[-1]):
            # as the daemon (companion/onboard/offboard.py): from the last setpoint's acceleration at the stop's jerk,
            # a swerve no longer than the stop contract's budget
            sp_, sv, sa, sts, _ = best_stop(np.asarray(pos[:2], float), np.asarray(vel[:2], float), ref.a_max, [d],
                                            max_path_m=ref.stop_budget(float(np.hypot(*vel[:2]))),
                                            a0=self._a_last, jerk=ref.stop_jerk)
            self.stop = Plan("brake", np.arange(len(sp_)) * sts, sp_, sv, sa, True, 0.0)
            self.stop_t = t
            p, v, a = self.stop.sample(0.0)
        elif self.stop is not None:
            p, v, a = self.stop.sample(t - self.stop_t)  # held at rest after its end
        else:
            if self.left and t - self.plan_t >= REPLAN_S - 1e-9 and pos[0] < d.x + d.r:
                self.left -= 1
                new = self.planner.plan(pos[:2], vel[:2], (1.0, 0.0), [d], v_max=ref.v_max, a_max=ref.a_max,
                                        warm=self.plan, elapsed=t - self.plan_t)
                if keeps_plan(self.plan, t - self.plan_t, new):
                    self.kept += 1
                else:
                    self.plan, self.plan_t = new, t
                    self.adopted += 1
            tau = t - self.plan_t
            # after the last interval, as the guidance: a pass rejoins the route at its end velocity (the
            # coast); a stop is at rest (as `Plan.sample` holds)
            if tau >= self.plan.t[-1]:
                p, v, a = self.plan.p[-1] + self.plan.v[-1] * (tau - self.plan.t[-1]), self.plan.v[-1], np.zeros(2)
            else:
                p, v, a = self.plan.sample(tau)
        self._a_last = np.asarray(a, dtype=float)
        self._sent(t, p)
        return p, v, a



A0_S = 0.1  # [s] the brake's start acceleration is measured over this (companion/onboard/sensing.py, A0_S)


@dataclass(frozen=True)
class BrakeReference:
    """``brake``: governor mode's recovery brake as the daemon flies it (companion/onboard/offboard.py `recover`):
    cruise along +x at `v`, then at t = 0 — the moment the autopilot shows it flies the daemon's stream — the
    straight jerk-limited stop from the measured state (`best_stop` at `a_stop`, its acceleration turned from
    the one measured over `A0_S` at `jerk`), then rest at its end."""

    name: str
    v0: float
    a_stop: float
    jerk: float

    @property
    def t_end(self) -> float:
        return self.v0 / self.a_stop + 2.0 * self.a_stop / self.jerk + COAST_S

    @property
    def p(self) -> np.ndarray:
        return np.zeros((1, 2))

    @property
    def v(self) -> np.ndarray:
        return np.array([[self.v0, 0.0]])

    def flight(self) -> BrakeFlight:
        return BrakeFlight(self)


class BrakeFlight(_SentPath):
    """One flight of a `BrakeReference`: the setpoints sent (its commanded path, Figure 11)."""

    def __init__(self, ref: BrakeReference):
        super().__init__()
        self.ref = ref
        self.stop: Plan | None = None
        self._seen: list[tuple[float, np.ndarray]] = []  # (t, velocity) over the last A0_S

    def setpoint(self, t: float, pos, vel):
        ref = self.ref
        vh = np.asarray(vel[:2], float)
        self._seen = [(tk, vk) for tk, vk in self._seen if t - tk <= A0_S + 1e-9] + [(t, vh)]
        if t < 0.0:
            p, v, a = np.array([ref.v0 * t, 0.0]), np.array([ref.v0, 0.0]), np.zeros(2)
        else:
            if self.stop is None:
                (t1, v1) = self._seen[0]
                a0 = (vh - v1) / (t - t1) if t - t1 > 0.5 * A0_S else np.zeros(2)
                sp_, sv, sa, sts, _ = best_stop(np.asarray(pos[:2], float), vh, ref.a_stop, [], 40, a0=a0,
                                                jerk=ref.jerk)
                self.stop = Plan("brake", np.arange(len(sp_)) * sts, sp_, sv, sa, True, -np.inf)
                self.stop_t = t
            p, v, a = self.stop.sample(t - self.stop_t)
        self._sent(t, p)
        return p, v, a


def worst_contour_error(vehicle: Vehicle, ref: Reference | OnlineReference | BrakeReference, thrust_ratio: float,
                        seed: int) -> float:
    """Fly `ref` (after SETTLE_S on its entry line) and return the worst horizontal contour error
    from t = 0 to its end against the path commanded in that flight (Figure 11); +inf if the vehicle
    was lost."""
    run = ref.flight()
    fl = fly(vehicle, run.setpoint, ref.t_end, thrust_ratio, wind_for_seed(vehicle, seed),
             ref.p[0] - ref.v[0] * SETTLE_S, ref.v[0])
    if not fl.ok:
        return math.inf
    sel = np.flatnonzero(fl.t >= 0.0)[::MEASURE_EVERY]
    path_t, path_p = run.path()
    e = contour_errors(fl.pos[sel, :2], fl.t[sel], path_t, path_p, WINDOW_S)
    worst = float(np.max(e)) if e.size else 0.0
    return worst if worst < DIVERGED_M else math.inf



# ============================================================================ reference manoeuvres


@dataclass
class CircleResult:
    thrust_ratio: float
    radius_m: float
    speed_m_s: float
    lateral_acc_m_s2: float
    contour_max_m: float
    contour_mean_m: float


def fly_circle(vehicle, thrust_ratio: float, radius: float, lateral_acc: float, tilt_max: float,
               laps: float = 2.0, wind: Wind | None = None, dt_nav: float = 0.01) -> CircleResult:
    """Track a horizontal circle (position + velocity + acceleration feed-forward, PX4 offboard
    style) at speed √(a·R); one lap to settle, then the contour error over `laps` laps."""
    spd = math.sqrt(lateral_acc * radius)
    w = spd / radius
    z = -5.0
    period = 2 * math.pi / w

    def setpoint(t, pos, vel):
        c, s = math.cos(w * t), math.sin(w * t)
        return (radius * c, radius * s), (-spd * s, spd * c), (-lateral_acc * c, -lateral_acc * s)

    fl = fly(vehicle, setpoint, (1.0 + laps) * period, thrust_ratio, wind, (radius, 0.0), (0.0, spd), 0.0,
             z=z, tilt_max=tilt_max, dt_nav=dt_nav)
    lap = np.arange(len(fl.t)) * dt_nav >= period  # the tick's start time
    e = np.array([math.hypot(math.hypot(x, y) - radius, h - z) for x, y, h in fl.pos[lap]])
    return CircleResult(thrust_ratio, radius, spd, lateral_acc, float(e.max()), float(e.mean()))


def step_response(vehicle, axis: int, size: float, seconds: float = 8.0, kind: str = "pos") -> dict:
    """Position (`kind='pos'`) or velocity (`'vel'`) step on one NED axis after 1 s of hover; overshoot
    as a fraction of the step and the 90 % rise time."""
    hover = np.array([0.0, 0.0, -5.0])
    nan3 = np.full(3, math.nan)
    step = {}

    def setpoint(t, pos, vel):
        if t < 0.0:
            return hover, nan3, nan3
        if not step:  # from where the hover left it
            step["start"] = (pos if kind == "pos" else vel)[axis]
            p, v = hover.copy(), nan3.copy()
            if kind == "pos":
                p[axis] = pos[axis] + size
            else:
                p[axis], v[axis] = math.nan, size
            step["sp"] = p, v, nan3
        return step["sp"]

    n = int(seconds / 0.01)
    fl = fly(vehicle, setpoint, n * 0.01, settle_s=1.0, start_p=hover, start_v=(0.0, 0.0, 0.0), dt_nav=0.01)
    x = (fl.pos if kind == "pos" else fl.vel)[-n:, axis]
    tr = (x - step["start"]) * math.copysign(1.0, size)
    rise = int(np.argmax(tr >= 0.9 * abs(size))) * 0.01 if np.any(tr >= 0.9 * abs(size)) else math.inf
    return {"overshoot": float((tr.max() - abs(size)) / abs(size)), "rise_90_s": rise,
            "final_error": float(abs(size) - tr[-1])}


def track_reference(vehicle, t, p, v, a, thrust_ratio: float = 1.0, tilt_max: float | None = None,
                    yaw: float = 0.0, wind: Wind | None = None, dt_nav: float = 0.01) -> np.ndarray:
    """Fly a sampled reference (times `t` (n,), NED positions/velocities/accelerations (n, 3)) with
    position + velocity + acceleration feed-forward, starting on it; returns the flown positions at
    the reference times (n, 3). Pair with `contracts.contour.contour_errors` for E_tr."""
    t = np.asarray(t, float)
    p, v, a = (np.asarray(x, float) for x in (p, v, a))

    def setpoint(tk, pos, vel):
        return tuple(np.array([np.interp(tk, t, arr[:, i]) for i in range(3)]) for arr in (p, v, a))

    ticks = math.ceil(round((t[-1] - t[0]) / dt_nav, 6))
    fl = fly(vehicle, setpoint, t[0] + ticks * dt_nav, thrust_ratio, wind, p[0], v[0], -t[0], tilt_max=tilt_max,
             yaw=yaw, dt_nav=dt_nav)
    out = np.empty_like(p)
    out[0] = p[0]
    idx = np.searchsorted(fl.t + 1e-9, t[1:], side="left")
    out[1:] = fl.pos[np.minimum(idx, len(fl.t) - 1)]
    return out
