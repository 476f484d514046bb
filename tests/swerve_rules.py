"""The swerve's rules turned off one by one, for negative controls: the swerve under the stop contract as it was flown
before each."""

import math

import numpy as np

from contracts import online_planner

from companion.onboard import supervisor
from companion.onboard.contract_in_force import swerve_discs, uncovered, wall_discs
from companion.onboard.estimators import DodEstimator
from companion.onboard.guidance import OffboardGuidance, Route, new_obstacles
from companion.onboard.supervisor import Supervisor


def seen_once(monkeypatch) -> None:
    """A disc planned round from the frame it is first seen in (not only once an earlier frame saw it too)."""
    monkeypatch.setattr(Supervisor, "_seen_again", lambda self, hits, discs: tuple(discs))


def outline_unread(monkeypatch) -> None:
    """Every run of bins a disc, whatever the bins beside it saw."""
    monkeypatch.setattr(DodEstimator, "hit_ends", lambda self, t: [])


def threats_on_the_leg_line(monkeypatch) -> None:
    """A disc is in the way where it is near the line from the vehicle along the leg it is on, however far on (past
    the route's turn too)."""
    monkeypatch.setattr(Route, "straight_left", lambda self, s: math.inf)


def others_passed_through(monkeypatch) -> None:
    """A plan round the discs in the way keeps out of the walls' points only, not of the other discs (a pole beside the
    route)."""
    monkeypatch.setattr(OffboardGuidance, "_others", staticmethod(lambda discs, ahead: ()))


def grown_judged_at_once(monkeypatch) -> None:
    """More of an obstacle come into view past its disc is no reason to plan again, and the Hold judges it at once
    against the plan in force (only the hits of new discs and walls are spared for a cycle)."""
    def only_new_spared(i, known, reach_m):
        discs = swerve_discs(i, reach_m)
        old_discs, old_walls = known if known else ((), ())
        new = [*new_obstacles(discs, old_discs), *new_obstacles(wall_discs(i, discs), old_walls)]
        return uncovered(i.hits, i.pose, new) if new else i.hits
    monkeypatch.setattr(supervisor, "unplanned", only_new_spared)
    monkeypatch.setattr(OffboardGuidance, "_entered", lambda self, t, p, keep_out: [])


def far_side_passed(monkeypatch) -> None:
    """Among walls, a pass goes round every disc on one side, round a wall's hit points beside the route line on their
    far side too (through the wall between the points seen, or behind it), and one the optimiser let drift round such
    a point is flown."""
    monkeypatch.setattr(online_planner, "side_attempts",
                        lambda local, v0, a_max, along: list(online_planner.pass_sides(local, v0, a_max)))
    monkeypatch.setattr(online_planner, "round_far_side", lambda p, local, sides: False)


def horizon_over_speed_now(monkeypatch) -> None:
    """A pass's horizon twice the way over the speed now where that is below the cruise speed (tens of seconds when
    slow)."""
    monkeypatch.setattr(online_planner, "pass_horizon",
                        lambda far, v0, v_c, a: max(1.5, 2.0 * far / max(min(v_c, v0) if v0 > 0.1 else v_c, 0.3)))


def guessed_at_speed_now(monkeypatch) -> None:
    """A pass's first linearisation the path straight on at the speed now (from rest: every point where the vehicle
    is)."""
    def at_speed_now(kind, p0, v0, v_cruise, a_max, ts, n):
        tk = np.arange(n + 1) * ts
        return p0[None, :] + v0[None, :] * tk[:, None]
    monkeypatch.setattr(online_planner, "_cold_guess", at_speed_now)


def threats_past_the_route_end(monkeypatch) -> None:
    """On the route's last leg a disc is in the way near the leg's line as on any other, beyond the route's end too."""
    monkeypatch.setattr(Route, "end_ahead", lambda self, s: None)


def stops_bounded_by_v_max(monkeypatch) -> None:
    """A stop's speed bounded as a pass's (V_max, or the braking profile above it), not by the speed it starts at."""
    caps = online_planner.AvoidancePlanner._speed_caps
    monkeypatch.setattr(online_planner.AvoidancePlanner, "_speed_caps",
                        lambda self, kind, v0, v_max, a_max, ts: caps(self, "pass", v0, v_max, a_max, ts))


def stops_flown_unturned(monkeypatch) -> None:
    """A stop's reference flown as planned whatever the heading (a back-off out of a keep-out disc too)."""
    def unturned(self, vel, acc, speed, turning, a_max, dt):
        self._rate = 1.0
        return vel, acc

    monkeypatch.setattr(OffboardGuidance, "_stop_turning_first", unturned)


def passed_obstacles_forgotten(monkeypatch) -> None:
    """Only the obstacles in view in one frame count for the avoid contract's one at a time (a pole seen before, out
    of view and not yet passed, does not)."""
    from companion.onboard.contract_in_force import ContractInForce

    monkeypatch.setattr(ContractInForce, "_not_passed", lambda self, i, d_od: 0)


def pass_left_beside_its_obstacle(monkeypatch) -> None:
    """A pass flying faster than the route's profile is left for the rejoin wherever its obstacle is, beside the vehicle
    too."""
    past = OffboardGuidance._past_the_profile

    def regardless(self, t, p, v_max, a_max):
        asked, self._asked_discs = self._asked_discs, ()
        try:
            return past(self, t, p, v_max, a_max)
        finally:
            self._asked_discs = asked
    monkeypatch.setattr(OffboardGuidance, "_past_the_profile", regardless)


def pass_at_its_own_speed(monkeypatch) -> None:
    """A pass kept in force flies at the speed it was planned at, whatever V_max has fallen to since (the stop contract
    come in mid-pass); the controller contract's E_tr_pred taken at the limit, not at a faster speed flown, over E_tr's
    window alone."""
    monkeypatch.setattr("companion.onboard.guidance.PASS_OVER_VMAX_M_S", math.inf)
    monkeypatch.setattr(supervisor, "_speed_flown", lambda v_cmd, i: v_cmd)
    monkeypatch.setattr(supervisor, "PRED_WINDOWS", 1.0)


def out_of_view_forgotten(monkeypatch) -> None:
    """The swerve plans round what is in view and was seen a frame before only: what it saw of a disc now out of view
    is not planned round again, whatever the path ahead flies into."""
    from companion.onboard.contract_in_force import OutOfView

    monkeypatch.setattr(OutOfView, "keep", lambda self, i, seen, measured, half_width: ())



def out_of_view_as_union(monkeypatch) -> None:
    """What the swerve saw of a disc now out of view held as the smallest disc holding every frame's sight of it (no
    wider than R_obst), not its widest single sight."""
    from companion.onboard.contract_in_force import WIDE_TOL_M, OutOfView

    Disc = online_planner.Disc

    def enclosing(a, b):
        d = math.hypot(b.x - a.x, b.y - a.y)
        if d + b.r <= a.r or d + a.r <= b.r:
            return a if a.r >= b.r else b
        r = 0.5 * (d + a.r + b.r)
        f = (r - a.r) / d
        return Disc(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y), r)

    def so_far(self, d, r_obst):
        for k in self._out:
            if not new_obstacles([d], [k]) and (grown := enclosing(k, d)).r <= r_obst + WIDE_TOL_M:
                d = grown
        return d

    monkeypatch.setattr(OutOfView, "_so_far", so_far)
