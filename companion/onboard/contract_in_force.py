"""The contract in force in offboard mode: the avoid contract while what it assumes is there, else the stop contract.

Pure: no I/O; `ContractInForce.judge(inputs, e_tr)` once a cycle, `fallback_omega(...)` the operating point under
the stop contract as offboard flies it.

The avoid contract (the paper's numerical construction, DESIGN.md §1) assumes

(i)  one obstacle no wider than R_obst at a time: the swerve round one keep-out disc of radius
     r_k = R_obst + E_tr + r_body. Among walls the daemon would plan round a wall as one huge disc, which no cell of
     the table covers; among several obstacles in view at once (a stand of poles) the swerve round one may meet
     another, which the table's cell does not know of;
(ii) that the sensors keep the swerve in view. A pass round the keep-out disc whose centre lies c = D_od + R_obst
     ahead leaves along a bearing at least asin(ρ) off the line to the obstacle, ρ = r_k / c (the table's own reduced
     axis, DESIGN.md §2), and the vehicle's heading — the sensors' axis — lags behind its track. The pass is seen
     only where asin(ρ) + lag ≤ the half-width of the forward field of view (on the narrower side: the pass may go
     either way). E_tr is that of the disc the planner goes round: the controller contract's E_tr_pred at the speed
     flown (Figure 13's virtual obstacle), or the measured error if larger; the avoid contract is flown no faster
     than the speed whose E_tr_pred keeps the pass in view at the D_od (the supervisor's `_in_view_speed`).

Where either fails the stop contract is in force: Ω is the table's stop contract with the braking stop offboard
flies (`fallback_omega`), something in the swept corridor within stopping distance is a braking stop then Hold at
rest (the supervisor's OBSTACLE hold cause, as in governor mode), and guidance plans round nothing: it cruises the
route (several things in view as `Apart` counts them: where the frame before told one apart, a run parted from the
run in the bin beside it by a range step alone counts from the next frame that tells them apart too, unless the stop
contract needs it now). A thing wider than R_obst, or several things in view, keep the stop contract in force until
the vehicle has flown the detection range they were seen within (D_od at the last sighting) past the last sighting,
each breach its own: until then they may still be within reach (`within_reach`; the environment violations last as
long). The avoid contract comes back only once its assumptions have held for
`dwell_s` (limits move one way fast).

Where the stop contract is in force because of the world (something wider than R_obst, several obstacles) while the
field-of-view rule (ii) holds, offboard still swerves (`InForce.swerve`): guidance plans round the obstacles no wider
than R_obst (`swerve_discs`: runs of bins within R_obst in width and depth whose sides the bins beside them saw past,
single beams; a wall gets no disc, whose chord would make a disc that blocks its own doorway; the supervisor passes
on a disc once an earlier frame saw it too) and keeps out of every other bin's hit point (`wall_discs`), at
the stop contract's Ω lowered to the speed whose E_tr_pred is E_SWERVE_M (`swerve_omega`). That Ω guarantees the
braking stop started now stops short of anything seen at D_od along the direction of travel; the swerve is flown only
inside that guarantee: the OBSTACLE hold judges every hit, walls included, against the path the vehicle will fly
(`path_obstacle_m`: the plan in force, else the route ahead) instead of the straight line, and stops where anything
lies within r_body + E_tr of it inside the stopping distance — a wall across the route, a closing corridor, is still a
dead end. What guidance is given for the first time — a new obstacle, or more of one come into view past its disc — it
plans round in the same cycle (`unplanned`): the hold judges that plan from the next. Where the field-of-view rule is
broken the swerve would leave the view: guidance plans round nothing and the hold judges the straight line
(`swept_obstacle_m`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from contracts.contour import distance_to_polyline
from contracts.online_planner import Disc
from contracts.table import ContractTable, Omega

from .guidance import ENTER_TOL_M, new_obstacles, obstacle_discs
from .sight import neighbouring

# [deg] the heading's lag behind the track the field-of-view rule budgets: the median measured in the SITL (true heading
# against true track above 1 m/s over 20 offboard flights: median 8°, 17–21° at speed). Not the worst: the rule
# already asks more of the sensors than the evidence needs (no collision in 161 narrow-beam flights with beams of
# 12° and more, half of which is less than asin(ρ) at any D_od), and a 60° sensor keeps the swerve round a column
# in view (R_obst 1 m, E_tr 0.3 m, the Mambo) from D_od ≈ 2.7 m with it, ≈ 8 m with the worst lag
LAG_BUDGET_DEG = 8.0
# an obstacle out of view counts with the one in view once this many cycles, in this many sensor frames, saw it
# (`_not_passed`): a frame lasts at most two cycles of the 50 Hz loop from a sensor at 25 Hz or faster, so there the
# frames add nothing to the cycles; from a slower one (a camera at 10 Hz: five cycles a frame) they keep one frame's
# return from being remembered
SEEN_CYCLES, SEEN_FRAMES = 3, 2
WIDE_TOL_M = 0.05  # an obstacle is wider than R_obst where its measured half-width exceeds R_obst by this
MIN_SPEED_M_S = 0.2  # below this the avoid contract flies nothing (the supervisor's MIN_SPEED_CMD: a Hold instead)
AVOID, STOP = "avoid", "stop"
E_SWERVE_M = 0.5  # [m] the tracking error the swerve under the stop contract is flown at (`swerve_omega`) …
SWERVE_MIN_M_S = 1.0  # [m/s] … but not slower than this for it
DEAD_END = "no path the contract can prove: stopped"
WIDE, SEVERAL = "an obstacle wider than R_obst", "several obstacles"  # the world's breaches of the avoid contract


def pass_bearing(r_k: float, c: float) -> float:
    """[rad] the least bearing off the line to the obstacle along which a pass round the keep-out disc of radius r_k
    centred c ahead leaves: asin(ρ), ρ = r_k / c (π/2 where the disc reaches the vehicle)."""
    return math.asin(min(r_k / c, 1.0)) if c > 0.0 else math.pi / 2


def forward_half_fov(sensors) -> float:
    """[rad] the half-width of the configured sensors' joint field of view about the forward axis: the largest a with
    the bearings [−a, a] inside the union of their fields of view (0 where none looks forward)."""
    arcs = []
    for s in sensors:
        half = math.radians(min(s.h_fov_deg, 360.0)) / 2
        if half >= math.pi:
            return math.pi
        c = (math.radians(s.orientation_deg) + math.pi) % (2 * math.pi) - math.pi
        arcs += [(c - half + k * 2 * math.pi, c + half + k * 2 * math.pi) for k in (-1, 0, 1)]
    lo = hi = None  # the union's interval about 0
    for a, b in sorted(arcs):
        if hi is not None and a <= hi:
            hi = max(hi, b)  # overlaps the interval being grown
        elif hi is not None and hi >= 0.0:
            break  # a gap after the interval round 0
        else:
            lo, hi = a, b
    if lo is None or not lo <= 0.0 <= hi:
        return 0.0
    return min(hi, -lo, math.pi)


def in_view_share(half_fov: float, lag: float) -> float:
    """The field-of-view rule as a share of the distance: a pass round a keep-out disc of radius r_k centred c ahead
    stays in view where r_k ≤ c·sin(half_fov − lag) (asin(r_k / c) + lag ≤ half_fov); 0 where the lag leaves no
    room, 1 from a room of 90° (the disc must still not reach the vehicle)."""
    return math.sin(min(max(half_fov - lag, 0.0), math.pi / 2))


def avoid_d_od_from(half_fov: float, r_k: float, r_obst: float, lag: float) -> float | None:
    """[m] the least D_od at which the field-of-view rule holds (r_k ≤ (D_od + R_obst)·`in_view_share`), None where
    it holds at no range."""
    share = in_view_share(half_fov, lag)
    return max(r_k / share - r_obst, 0.0) if share > 0.0 else None


def banner_line(sensors, r_k: float, r_obst: float, top_m: float) -> str:
    """The start banner's line: the D_od range in which the configured sensors keep the avoid contract's swerve in
    view (at the least E_tr assumed), or that offboard flies the stop contract only."""
    half = forward_half_fov(sensors)
    d = avoid_d_od_from(half, r_k, r_obst, math.radians(LAG_BUDGET_DEG))
    what = (f"the forward field of view ±{math.degrees(half):.1f}° less the heading's lag {LAG_BUDGET_DEG:g}° "
            f"against the pass bearing asin(r_k / (D_od + R_obst)), r_k {r_k:.2f} m")
    if d is None or d >= top_m:
        return f"avoid contract in view: {what}: at no D_od within {top_m:g} m: stop contract only"
    return (f"avoid contract in view: {what}: from D_od {d:.2f} m (to {top_m:g} m), flown no faster than keeps r_k "
            f"with E_tr_pred at its speed in view; below it, or among things wider than R_obst, offboard flies the stop "
            f"contract")


@dataclass(frozen=True, slots=True)
class InForce:
    """The contract in force this cycle, why, and whether it changed this cycle."""

    contract: str
    reason: str
    changed: bool = False
    # the stop contract in force because of the world with the pass in view: guidance still plans round the obstacles
    # no wider than R_obst (`swerve_discs`) and the hold judges the path it flies (`path_obstacle_m`)
    swerve: bool = False


class Sighting(NamedTuple):
    """An obstacle seen under way (`ContractInForce._not_passed`): its disc, in how many cycles and in how many of the
    sensors' frames it was seen, and the last frame's number."""

    disc: Disc
    cycles: int
    frames: int
    last_frame: int


class ContractInForce:
    """Judges, each cycle, which contract offboard flies (the module's docstring: the rule, and how long a sighting
    holds)."""

    def __init__(self, half_fov: float, dwell_s: float, lag: float = math.radians(LAG_BUDGET_DEG)):
        self.half_fov, self.dwell_s, self.lag = half_fov, dwell_s, lag
        self.now = InForce(AVOID, "its assumptions hold")
        self._odo = 0.0  # [m] flown, from the ground speed
        self._t: float | None = None
        self._breach: dict[str, tuple[float, float]] = {}  # WIDE, SEVERAL: (odometer, D_od) at its last sighting
        self._clear_since: float | None = None  # the avoid contract's assumptions have held since
        self._dead_end_said = False  # the dead end of this stretch under the stop contract has been said
        self._seen: list[Sighting] = []  # obstacles seen under way, not yet passed
        self._frames = LastFrame()  # the sensors' frames, numbered

    def judge(self, i, avoid: Omega, r_body: float) -> InForce:
        """This cycle's contract from the supervisor's inputs `i` (time, ground speed, widest obstacle seen, R_obst,
        D_od, the measured E_tr) and the avoid contract's Ω at them (`avoid`: the speed it would fly; `r_body` the
        vehicle's radius). The keep-out disc of the rule is r_k = R_obst + E_tr + r_body with the E_tr of the disc the
        planner goes round: the avoid Ω's (E_tr_pred at its speed), or the measured E_tr if larger. Where the avoid
        contract has no speed to fly there is no swerve to keep in view: the field-of-view rule is not judged (either
        contract holds the vehicle there)."""
        speed = i.ground_speed if math.isfinite(i.ground_speed) else 0.0
        if self._t is not None:
            self._odo += speed * max(i.t - self._t, 0.0)
        self._t = i.t
        e_tr = i.e_tr_measured if math.isfinite(i.e_tr_measured) else math.inf
        e_tr = max(e_tr, avoid.e_tr) if math.isfinite(avoid.e_tr) else e_tr  # the disc the planner goes round
        r_k, swerves = e_tr + r_body + i.r_obst, avoid.v_max >= MIN_SPEED_M_S
        why = self._broken(i, r_k, swerves)
        in_view = self._in_view(i, r_k, swerves) is None
        if why is not None:
            self._clear_since = None
            return self._say(InForce(STOP, why, swerve=in_view))
        if self.now.contract == STOP:
            self._clear_since = i.t if self._clear_since is None else self._clear_since
            if i.t - self._clear_since < self.dwell_s:
                # (the swerve goes on only for a breach of the world: a stretch the view broke stays straight)
                return self._say(InForce(STOP, self.now.reason, swerve=self.now.swerve and in_view))
        return self._say(InForce(AVOID, "its assumptions hold: one obstacle no wider than R_obst, the pass in view"))

    def _broken(self, i, r_k: float, swerves: bool) -> str | None:
        """Which assumption of the avoid contract does not hold now (None: both hold)."""
        d_od = i.dod.d_od if math.isfinite(i.dod.d_od) else 0.0
        if i.obstacle_width > i.r_obst + WIDE_TOL_M:
            self._breach[WIDE] = (self._odo, d_od)
            return f"an obstacle {i.obstacle_width:.2f} m wide (half-width) in view, wider than R_obst {i.r_obst:g} m"
        before = self._not_passed(i, d_od)
        if i.obstacles > 1 or i.obstacles and before:
            self._breach[SEVERAL] = (self._odo, d_od)
            if i.obstacles > 1:
                return f"{i.obstacles} obstacles in view at once: the avoid contract goes round one at a time"
            return (f"an obstacle in view and {before} seen before, not yet passed: the avoid contract goes round one "
                    "at a time")
        self._breach = {what: b for what, b in self._breach.items() if self.within_reach(what)}
        if self._breach:
            what, (odo, reach) = max(self._breach.items(), key=lambda wb: wb[1][0])  # the last sighting
            return f"{what} seen {self._odo - odo:.1f} m ago, within reach until {reach:.1f} m past the sighting"
        return self._in_view(i, r_k, swerves)

    def _not_passed(self, i, d_od: float) -> int:
        """How many obstacles seen before, out of view now, are not yet passed: their centre ahead of the vehicle along
        its direction of travel and within D_od + their radius of it (a pass round the one in view may meet them: a
        stand of poles seen one pole at a time). An obstacle is remembered once SEEN_CYCLES cycles under way (above
        1 m/s), in SEEN_FRAMES of the sensors' frames, saw it at one place (a medium's near returns move with the
        vehicle; a frame's spurious return, or a column the range noise splits, is one frame's)."""
        now = list(i.discs)
        self._frames.see(i.hits, ())
        frame = self._frames.number
        self._seen = [s for s in self._seen if not_passed(i, s.disc, d_od)]
        before = sum(1 for s in self._seen
                     if s.cycles >= SEEN_CYCLES and s.frames >= SEEN_FRAMES and new_obstacles([s.disc], now))
        if i.ground_speed > 1.0:
            for o in now:
                match = [s for s in self._seen if not new_obstacles([s.disc], [o])]
                cycles = 1 + max((s.cycles for s in match), default=0)
                frames = max((s.frames + (s.last_frame != frame) for s in match), default=1)
                self._seen = [s for s in self._seen if all(s is not m for m in match)] + \
                    [Sighting(o, cycles, frames, frame)]
        return before

    def within_reach(self, what: str) -> bool:
        """Whether a breach of the world (WIDE, SEVERAL) is seen now or may still be within reach: the vehicle has not
        yet flown the D_od of its last sighting past it."""
        b = self._breach.get(what)
        return b is not None and self._odo - b[0] < b[1]

    def e_tr_in_view(self, d_od: float, r_obst: float, r_body: float) -> float:
        """[m] the largest E_tr whose keep-out disc r_k = R_obst + E_tr + r_body a pass at this D_od goes round in
        view (rule (ii), `in_view_share`); below 0: none."""
        share = in_view_share(self.half_fov, self.lag)
        if share <= 0.0 or not d_od + r_obst > 0.0:
            return -math.inf
        return (d_od + r_obst) * share - r_obst - r_body

    def _in_view(self, i, r_k: float, swerves: bool) -> str | None:
        """Why the pass round the keep-out disc r_k would leave the field of view at this D_od (None: it stays in
        view, or there is no swerve to judge)."""
        d_od = i.dod.d_od if math.isfinite(i.dod.d_od) else 0.0
        if swerves and r_k > (d_od + i.r_obst) * in_view_share(self.half_fov, self.lag):
            bearing = pass_bearing(r_k, d_od + i.r_obst)
            return (f"the pass at D_od {d_od:.2f} m leaves {math.degrees(bearing):.1f}° off the obstacle, with the "
                    f"heading's lag {math.degrees(self.lag):g}° beyond the field of view ±"
                    f"{math.degrees(self.half_fov):.1f}°")
        return None

    def dead_end(self) -> bool:
        """An obstacle ahead stops the vehicle under the stop contract: True the first time in this stretch under it
        (said once: a stop flickering with what the sensors see is one dead end)."""
        first, self._dead_end_said = not self._dead_end_said, True
        return first

    def _say(self, new: InForce) -> InForce:
        changed = new.contract != self.now.contract
        if changed:
            self._dead_end_said = False
        self.now = replace(new, changed=changed)
        return self.now


class LastFrame:
    """What was seen in the sensors' frame before this one. A frame is told by the fresh hits: a cycle's hits stay
    those of the last frame until a sensor sends its next (with several sensors, any one's next frame is a frame)."""

    def __init__(self) -> None:
        self.number = 0  # the frames seen so far
        self._hits: tuple | None = None  # the frame the things below were seen in
        self._now: tuple = ()
        self._before: tuple = ()

    def see(self, hits: tuple, things) -> tuple:
        """This cycle's `hits` and the `things` (discs, places) seen in them; returns those of the frame before."""
        if hits != self._hits:  # a new frame: the last one's are now the frame before's
            self._hits, self._before = hits, self._now
            self.number += 1
        self._now = tuple(things)
        return self._before


class Apart:
    """How many obstacles in view rule (i) counts: each the beams tell apart (`Inputs.places`), but where the frame
    before told at most one apart, two runs in neighbouring bins (one run parted by a range step alone) count as one
    while the stop contract could stop short of them were it put in force within `tau_s` (a sensor's silence budget
    and a loop period: until the next frame is judged). A stereo camera's range noise splits a column far off into
    two runs now and then (one bin 2.5 σ short: 2.4 m at 9.6 m), in one frame; two obstacles are two in the next
    frame too, and count from then, or from the cycle the stop contract needs them. Meanwhile guidance plans round
    every disc the beams see, and at every cycle an obstacle not counted leaves the stop contract its full guarantee:
    v_ref ≤ V_stop(d − v_ref·τ), d the distance to its nearest disc's edge (no farther than its nearest return),
    v_ref the fastest the vehicle flies until then. Obstacles with a bin between them (a doorway's two sides, a
    stand's poles) and a single beam's hits are no such split: they count at once."""

    def __init__(self) -> None:
        self._frames = LastFrame()
        self._said = 0  # the last frame whose wait was said
        self.split: Split | None = None  # this frame's wait, the first cycle it is judged (said once a frame)

    def count(self, i, v_ref: float, v_stop, tau_s: float) -> int:
        """`i`: the supervisor's inputs (their `places`, `hits`, `pose`); `v_stop(d)`: the stop contract's V_max at an
        obstacle d away (offboard's, `fallback_omega`). Where runs wait, `split` says so the first time in a frame."""
        before = self._frames.see(i.hits, i.places)
        self.split = None
        if len(i.places) < 2 or len(before) >= 2:
            return len(i.places)
        x, y = i.pose[0], i.pose[1]

        def waiting(k: int) -> tuple[float, float] | None:
            """(d, V_stop) of a run that waits: beside another, the stop contract stopping short of it; else None."""
            a = i.places[k].bins
            # next to another run: their nearest bins are neighbours (the run rule of `seen_obstacles`)
            beside = a is not None and any(b is not None and neighbouring(max(b[0] - a[1], a[0] - b[1]), a[2], b[2])
                                           for m, b in enumerate(p.bins for p in i.places) if m != k)
            if not beside:
                return None
            d = min(math.hypot(c.x - x, c.y - y) - c.r for c in i.places[k].discs)
            v = v_stop(d - v_ref * tau_s)
            return (d, v) if v_ref <= v else None

        waits = [w for w in map(waiting, range(len(i.places))) if w is not None]
        n = max(len(i.places) - len(waits), 1)
        if waits and self._said != self._frames.number:
            self._said = self._frames.number
            d, v = min(waits)
            self.split = Split(len(i.places), n, d, v_ref, v)
        return n


class Split(NamedTuple):
    """A frame's runs counted as fewer obstacles than the beams told apart (`Apart`): how many were told apart, how
    many counted, the nearest waiting run's distance [m] and the speeds that let it wait, v_ref ≤ V_stop [m/s]."""

    told: int
    counted: int
    nearest_m: float
    v_ref: float
    v_stop: float


def fallback_omega(table: ContractTable, d_od: float, i, t_cmd: float, loop_dt: float) -> Omega:
    """Ω under the stop contract as offboard flies it: the stop is the daemon's own braking stop from offboard
    (flying.py `OffboardFlight`: the airframe's braking at the tilt flown, never softer than the autopilot's, at the
    stop jerk — `contracts.stop.recovery_brake_stop`, the recovery brake's), so the table's stop slot with the
    recovery brake's stop and its E_tr_pred surface (`recovery_dt` one loop period, `e_brake`); the dead time it
    budgets (reaction, the switch, a loop period, `t_cmd`) is more than offboard's, which needs no switch. The
    vehicle cruises on offboard setpoints, so E_tr is at least the offboard (avoid) surface's at the speed flown:
    E_tr = max(measured, E_tr_pred_avoid(V)), V from the stop contract at the measured E_tr, then again at that E_tr
    (a larger E_tr never gives a higher V_max, so the second answer is safe at its own speed). Never above the avoid
    contract's own Ω at the same inputs. `d_od`: the detection range after any lateness fold (the supervisor's)."""
    r, thr, e = i.r_obst, i.thrust_ratio, i.e_tr_measured
    t_silent = i.dod.silence_s

    def stop(e_tr: float) -> Omega:
        return table.omega(d_od, r, e_tr, thr, contract=STOP, recovery_dt=loop_dt, t_cmd=t_cmd, t_silent=t_silent,
                           e_brake=True)

    first = stop(e)
    e_avoid = table.e_tr_pred(first.v_max, first.tilt, thr, AVOID) if first.v_max > 0.0 else e
    om = stop(max(e, e_avoid)) if math.isfinite(e_avoid) else replace(first, v_max=0.0, v_safe=0.0, gamma=0.0,
                                                                     reason="no E_tr_pred for offboard at this speed")
    avoid = table.omega(d_od, r, e, thr, contract=AVOID, t_silent=t_silent)
    return om if om.v_max <= avoid.v_max else replace(avoid, contract=STOP, reason=f"{avoid.reason} (the avoid "
                                                                                    "contract's, lower)")


def swerve_omega(table: ContractTable, om: Omega, i, e_tr_m: float = E_SWERVE_M) -> Omega:
    """Ω for the swerve under the stop contract: the stop contract's `om`, its speed lowered (never raised: the stop
    contract holds at any lower speed) to the highest at which the controller contract predicts a tracking error of
    at most `e_tr_m` (E_tr_pred, Figure 12, the larger of offboard's and the brake's surfaces at Ω's tilt), never
    below SWERVE_MIN_M_S. The pass between walls needs r_body + E_tr either side of its path: at the stop contract's
    own speed E_tr_pred is up to 1.3 m, which closes a 3 m doorway or a corridor beside a column. Its E_tr: the
    measured error or E_tr_pred at the lowered speed, the larger. `i`: the supervisor's inputs."""
    def e_pred(v: float) -> float:
        e = max(table.e_tr_pred(v, om.tilt, i.thrust_ratio, s) for s in (AVOID, "brake"))
        return e if math.isfinite(e) else math.inf

    if om.v_max <= SWERVE_MIN_M_S or e_pred(om.v_max) <= e_tr_m:
        return om
    lo, hi = SWERVE_MIN_M_S, om.v_max  # E_tr_pred does not decrease with the speed (the table's monotonicity)
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if e_pred(mid) <= e_tr_m else (lo, mid)
    return replace(om, v_max=lo, gamma=lo - om.v_safe, e_tr=max(i.e_tr_measured, e_pred(lo)),
                   reason=f"{om.reason}; swerving: E_tr_pred ≤ {e_tr_m:g} m")


def path_obstacle_m(hits, pose, path, half_width_m: float) -> float:
    """[m] the distance along `path` to where it first comes within `half_width_m` (r_body + E_tr) of a hit — the
    swept corridor of `ahead.swept_obstacle_m` laid along the path the vehicle will fly rather than the line of travel,
    whatever the hit's shape. `pose`: the vehicle's (x, y, yaw) in local NED, where the hits' body bearings are
    measured from; `path`: the points ahead (x, y) it flies through in order, from where it is (the plan in force;
    a path that goes on carries a far point, one that ends at rest ends there). A bin's hit may lie anywhere in its
    sector (± its uncertainty): the sector's arc is sampled and the band widened by the sampling's reach; a single
    beam's hit is taken as on the path at its range (inf: nothing within the band)."""
    x, y, yaw = pose
    pts = np.array([(x, y), *path], float).reshape(-1, 2)
    seg = np.diff(pts, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    keep = length > 1e-9
    if not keep.any():  # at rest where it is: what touches it
        pts, seg, length, keep = pts[:1].repeat(2, 0), np.array([[1e-9, 0.0]]), np.array([1e-9]), np.array([True])
    a, seg, ends = pts[:-1][keep], seg[keep], length[keep]
    u = seg / ends[:, None]
    s0 = np.concatenate([[0.0], np.cumsum(ends)[:-1]])
    nearest = math.inf
    for b, r, h, bins in hits:
        if not bins:
            nearest = min(nearest, r)
            continue
        n = max(2, math.ceil(2 * h * r / 0.1) + 1)
        reach = 2 * r * math.sin(h / (2 * (n - 1)))  # the farthest a point of the arc is from its nearest sample
        w = half_width_m + reach
        if r - w >= nearest:  # the path reaches its band no sooner than r − w along (a path is no shorter than a line)
            continue
        ang = yaw + np.linspace(b - h, b + h, n)
        q = np.column_stack([x + r * np.cos(ang), y + r * np.sin(ang)])  # (n, 2) the sector's possible hit points
        rel = q[:, None, :] - a[None, :, :]  # (n, m)
        along = np.einsum("nmk,mk->nm", rel, u)
        perp2 = np.einsum("nmk,nmk->nm", rel, rel) - along * along
        inside = perp2 <= w * w
        half_chord = np.sqrt(np.maximum(w * w - perp2, 0.0))
        enter, leave = along - half_chord, along + half_chord
        on = inside & (enter <= ends[None, :]) & (leave >= 0.0)
        if on.any():
            nearest = min(nearest, float(np.min((s0[None, :] + np.maximum(enter, 0.0))[on])))
    return nearest


def uncovered(hits, pose, discs) -> tuple:
    """The hits whose point (at the sector's centre bearing) lies in none of `discs`: what a plan round the discs
    does not go round."""
    x, y, yaw = pose
    return tuple(hit for hit in hits if not any(
        math.hypot(x + hit[1] * math.cos(yaw + hit[0]) - d.x, y + hit[1] * math.sin(yaw + hit[0]) - d.y) <= d.r
        for d in discs))


def wall_discs(i, discs) -> tuple[Disc, ...]:
    """What a plan round `discs` keeps out of too: each bin's hit outside them (a wall's, a facade's) as the disc of
    its lateral uncertainty about the point at its sector's centre (range × tan of the half-bin, plus 5 cm, as
    `obstacle_discs` pads a run)."""
    x, y, yaw = i.pose
    return tuple(Disc(x + r * math.cos(yaw + b), y + r * math.sin(yaw + b), r * math.tan(h) + 0.05)
                 for b, r, h, bins in uncovered(i.hits, i.pose, discs) if bins)


def unplanned(i, known: tuple, reach_m: float) -> tuple:
    """The hits the Hold judges this cycle: those inside what guidance was given to plan round or keep out of the cycle
    before (`known`: those (discs, walls)), less those of a swerve disc (`swerve_discs` at `reach_m`) not among them —
    an obstacle planned round once an earlier frame saw it too, its hit points kept out of meanwhile. The rest guidance
    is given for the first time now — a new obstacle, or more of one come into view past the disc it was given (a bin
    more of a column's outline) — and plans round at once (companion/onboard/guidance.py `OffboardGuidance._avoid`):
    its plan is judged against them from the next cycle."""
    old_discs, old_walls = known if known else ((), ())
    unplanned_discs = new_obstacles(swerve_discs(i, reach_m), old_discs)
    unknown = set(uncovered(i.hits, i.pose, (*old_discs, *old_walls)))
    return tuple(hit for hit in uncovered(i.hits, i.pose, unplanned_discs) if hit not in unknown)


def swerve_discs(i, reach_m: float) -> tuple[Disc, ...]:
    """The discs guidance plans round under the stop contract where it still swerves: those of the runs of bins no
    wider than R_obst (`WIDE_TOL_M` as the rule judges) and of single beams (companion/onboard/guidance.py
    `obstacle_discs`). A wider run — a wall, a facade — gets none: its chord's disc would block its own doorway; the
    hold judges the path flown against it (`path_obstacle_m`). A run farther than `reach_m` (how far the hold reaches
    now) gets the disc of what was seen of it, not R_obst's: within that reach a plan round what was seen, on the
    hold's edge, was held for what the next cycles added of the obstacle's outline (a pole passed at speed)."""
    x, y, yaw = i.pose
    discs, _, _ = obstacle_discs(i.hits, (x, y), yaw, i.r_obst, widest=i.r_obst + WIDE_TOL_M, measured_beyond=reach_m,
                                 ends=i.hit_ends)
    return tuple(discs)


def not_passed(i, d: Disc, d_od: float, behind: float = 0.0) -> bool:
    """Whether the vehicle (`i`: the supervisor's inputs, pose and beta) has not yet passed disc d: its centre no more
    than `behind` behind the vehicle along its direction of travel, and within D_od + its radius of it."""
    x, y, yaw = i.pose
    along = (d.x - x) * math.cos(yaw + i.beta) + (d.y - y) * math.sin(yaw + i.beta)
    return along >= -behind and math.hypot(d.x - x, d.y - y) <= d_od + d.r


class OutOfView:
    """What the swerve saw of its discs, out of view now, that the path ahead flies into. A turn of the swerve takes a
    pole out of the sensors' view while the way back to the route still passes it: planned round only while in view,
    it is flown past blind. What was seen of such a disc is planned round again once the path ahead (`Inputs.path`,
    from where the vehicle is) comes within its radius and r_body + E_tr of it (by more than `ENTER_TOL_M`), and stays
    so until it is passed — behind the vehicle along its direction of travel by more than its radius and r_body + E_tr —
    or farther than D_od. One the path keeps clear of is left out. What was seen: the widest disc of its sectors
    (`swerve_discs` measured at any range) that one frame saw, no wider than R_obst — the last frames before a pole
    leaves the view see only its side; not the union of the frames' discs, whose far sightings' centres wander with the
    range noise and grow a pole's disc until it closes a corridor; not R_obst's disc, which off a wall's end seen at a
    doorway fills the doorway."""

    def __init__(self) -> None:
        self._out: list[Disc] = []  # what was seen of the discs seen before, not yet passed
        self._kept: list[Disc] = []  # of them, out of view and planned round again

    def keep(self, i, seen: tuple, measured: tuple, half_width: float) -> tuple[Disc, ...]:
        """The discs to plan round besides this cycle's `seen` (the swerve's discs, seen in two frames). `measured`:
        this cycle's discs of what was seen (`swerve_discs` at reach 0); `i`: the supervisor's inputs (pose, beta,
        path, D_od, R_obst); `half_width`: r_body + E_tr."""
        d_od = i.dod.d_od if math.isfinite(i.dod.d_od) else 0.0
        out = [k for k in self._out if new_obstacles([k], seen) and not_passed(i, k, d_od, k.r + half_width)]
        path = np.array([i.pose[:2], *i.path], float)
        self._kept = [k for k in out if k in self._kept
                      or distance_to_polyline((k.x, k.y), path) < k.r + half_width - ENTER_TOL_M]
        self._out = [*(self._so_far(d, i.r_obst) for d in measured if not new_obstacles([d], seen)), *out]
        return tuple(self._kept)

    def _so_far(self, d: Disc, r_obst: float) -> Disc:
        """What the frames saw of the obstacle `d` is this frame's sight of: the widest of their discs of it no wider
        than R_obst."""
        for k in self._out:
            if not new_obstacles([d], [k]) and d.r < k.r <= r_obst + WIDE_TOL_M:
                d = k
        return d


def fallback_for(cfg, contract: str) -> ContractInForce | None:
    """The daemon's fallback under the avoid contract, from the configured sensors' forward field of view and the
    contract's dwell (None under the stop contract: nothing to fall back from)."""
    return ContractInForce(forward_half_fov(cfg.sensors), cfg.contract.dwell_s) if contract == AVOID else None
