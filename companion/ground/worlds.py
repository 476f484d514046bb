"""The world families the ground tools fly: a scenario's `world` (sitl_harness/scenario.py `WorldSpec` keys) and the
route through it (local NED waypoints [m], x north, y east), drawn from a seed. Pure; no I/O.

Two sets, built from the same pieces (a column, a facade with a doorway, a stand of poles, a corridor):

- **clear** (`clear_world`, `CLEAR`): everything beside or across the route, nothing on it — the clear air in which
  companion/ground/false_alarms.py counts holds and violations a perfect observer calls unfounded;
- **cluttered** (`cluttered_world`, `CLUTTERED`): the guard has real work — obstacles on the route, one at a time
  along it (`columns`), a doorway 3–6 m wide whose centre is up to 0.5 m off the route (`doorway`), a stand of poles
  beside the route and one pole on it (`cluster`), a corridor 5–7 m wide with a turn and a column inside
  (`corridor`), and a corridor that narrows and is closed at its end, the route's end beyond it (`dead_end`: no
  route exists; the flight succeeds by stopping short without contact, said). Each says whether its route exists.

The sizes are building-scale and the same for every vehicle: a 3 m doorway leaves a 450–500 mm quad (r_body
0.38 m) 1.1 m either side, a 5 m corridor 2.1 m; the columns and poles (radius 0.1–0.5 m) are no wider than the
campaign's R_obst of 1 m. Consecutive columns on the `columns` route stand 11–14 m apart, beyond a 10 m sensor's
range, so one is in view at a time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CLEAR = ("plain", "columns", "doorway", "cluster", "corridor")
CLUTTERED = ("columns", "doorway", "cluster", "corridor", "dead_end")
FACADE_HALF_M = 20.0  # a facade reaches this far either side of the route


@dataclass(frozen=True)
class Drawn:
    """One drawn world: the scenario's `world`, the route's waypoints, and whether a route to its end exists."""

    world: dict
    route: list[list[float]]
    route_exists: bool = True


# ----------------------------------------------------------------------------- the pieces

def column(x: float, y: float, radius: float, name: str) -> dict:
    return {"x_m": float(x), "y_m": float(y), "radius_m": float(radius), "name": name}


def facade(x: float, width: float, off: float) -> dict:
    """A wall across the route (north at `x`), FACADE_HALF_M either side, with a doorway `width` wide centred `off`
    east of the route."""
    return {"points": [[x, -FACADE_HALF_M], [x, FACADE_HALF_M]], "thickness_m": 0.3, "name": "facade",
            "gaps": [{"at_m": FACADE_HALF_M + off, "width_m": width}]}


def pole_stand(rng, x_range: tuple[float, float], edge_off: tuple[float, float]) -> dict:
    """A stand of poles (radius 0.1–0.3 m, 1.5 m apart) in a disc of radius 4–7 m, its centre `x_range` (drawn)
    along the route, on a random side, its edge `edge_off` (drawn) off the route."""
    radius = float(rng.uniform(4.0, 7.0))
    side = 1.0 if rng.random() < 0.5 else -1.0
    count = int(rng.integers(4, int(1.6 * radius) + 1))  # as many as fit 1.5 m apart
    return {"x_m": float(rng.uniform(*x_range)), "y_m": side * (radius + 0.3 + float(rng.uniform(*edge_off))),
            "radius_m": radius, "count": count, "column_radius_m": [0.1, 0.3],
            "min_gap_m": 1.5, "seed": int(rng.integers(0, 2**31 - 1)), "name": "poles"}


def turning_corridor(a: float, b: float, width: float) -> dict:
    """An open corridor `width` wide from behind the start north to `a`, then `b` east (west when negative)."""
    return {"points": [[-3.0, 0.0], [a, 0.0], [a, b + 3.0 * np.sign(b)]], "width_m": width,
            "thickness_m": 0.2, "name": "corridor"}


# ----------------------------------------------------------------------------- clear air

def clear_world(family: str, seed: int) -> tuple[dict, list[list[float]]]:
    """(the scenario's `world`, the route's waypoints) of a clear-air family, drawn from `seed`: everything beside or
    across the route, nothing on it (a route that exists)."""
    if family not in CLEAR:
        raise ValueError(f"unknown world family {family!r}")
    rng = np.random.default_rng([seed, CLEAR.index(family)])
    length = float(rng.uniform(40.0, 55.0))
    if family == "plain":
        return {}, [[0.0, 0.0], [length, 0.0]]
    if family == "columns":  # a route past columns, either side, their surfaces 2.5–5 m off the route
        cols = []
        for k, x in enumerate(np.arange(10.0, length - 5.0, float(rng.uniform(5.0, 8.0)))):
            r = float(rng.uniform(0.1, 0.4))
            side = 1.0 if k % 2 else -1.0
            cols.append(column(x, side * (r + float(rng.uniform(2.5, 5.0))), r, f"column {k}"))
        return {"columns": cols}, [[0.0, 0.0], [length, 0.0]]
    if family == "doorway":  # a facade across the route, flown through a doorway 4–6 m wide
        x = float(rng.uniform(14.0, 22.0))
        width = float(rng.uniform(4.0, 6.0))
        return {"walls": [facade(x, width, float(rng.uniform(-0.5, 0.5)))]}, [[0.0, 0.0], [length, 0.0]]
    if family == "cluster":  # a stand of poles flown beside, its edge 3–5 m off the route
        return {"clusters": [pole_stand(rng, (18.0, 25.0), (3.0, 5.0))]}, [[0.0, 0.0], [length, 0.0]]
    # corridor: an open corridor 5–7 m wide that turns left or right
    width = float(rng.uniform(5.0, 7.0))
    a = float(rng.uniform(14.0, 20.0))
    b = float(rng.uniform(12.0, 18.0)) * (1.0 if rng.random() < 0.5 else -1.0)
    return {"corridors": [turning_corridor(a, b, width)]}, [[0.0, 0.0], [a, 0.0], [a, b]]


# ----------------------------------------------------------------------------- cluttered

def cluttered_world(family: str, seed: int) -> Drawn:
    """A cluttered family's world and route (module docstring), drawn from `seed` (its own stream per family)."""
    if family not in CLUTTERED:
        raise ValueError(f"unknown world family {family!r}")
    rng = np.random.default_rng([seed, 100 + CLUTTERED.index(family)])
    length = float(rng.uniform(45.0, 60.0))
    straight = [[0.0, 0.0], [length, 0.0]]
    if family == "columns":  # columns 11–14 m apart, the first and about half the others within ±1 m of the route
        cols, x, k = [], float(rng.uniform(15.0, 22.0)), 0
        while x < length - 8.0:
            r = float(rng.uniform(0.1, 0.5))
            on = k == 0 or rng.random() < 0.6
            y = float(rng.uniform(-1.0, 1.0)) if on else float(rng.choice([-1.0, 1.0])) * (r + rng.uniform(2.5, 5.0))
            cols.append(column(x, y, r, f"column {k}"))
            x, k = x + float(rng.uniform(11.0, 14.0)), k + 1
        return Drawn({"columns": cols}, straight)
    if family == "doorway":  # a facade across the route, flown through a doorway 3–6 m wide
        x = float(rng.uniform(16.0, 24.0))
        return Drawn({"walls": [facade(x, float(rng.uniform(3.0, 6.0)), float(rng.uniform(-0.5, 0.5)))]}, straight)
    if family == "cluster":  # a stand of poles beside the route (its edge 1–3 m off it), one pole on the route
        stand = pole_stand(rng, (18.0, 25.0), (1.0, 3.0))
        pole = column(stand["x_m"] + float(rng.uniform(-3.0, 3.0)), float(rng.uniform(-0.5, 0.5)), float(rng.uniform(0.1, 0.3)),
                      "pole on the route")
        return Drawn({"clusters": [stand], "columns": [pole]}, straight)
    if family == "corridor":  # a corridor 5–7 m wide with a turn, the route down its middle, a column inside
        width = float(rng.uniform(5.0, 7.0))
        a = float(rng.uniform(18.0, 26.0))
        b = float(rng.uniform(14.0, 20.0)) * (1.0 if rng.random() < 0.5 else -1.0)
        r = float(rng.uniform(0.1, 0.4))
        if rng.random() < 0.5:  # on the first leg, at least 10 m from the start and 5 m before the turn
            pole = column(float(rng.uniform(10.0, a - 5.0)), float(rng.uniform(-1.0, 1.0)), r, "column")
        else:  # on the second leg, 5 m or more past the turn
            along = float(rng.uniform(5.0, abs(b) - 3.0)) * np.sign(b)
            pole = column(a + float(rng.uniform(-1.0, 1.0)), along, r, "column")
        return Drawn({"corridors": [turning_corridor(a, b, width)], "columns": [pole]}, [[0.0, 0.0], [a, 0.0], [a, b]])
    # dead_end: a corridor 5–7 m wide narrowing to 2–3 m and closed at its end; the route's end lies beyond it
    width = float(rng.uniform(5.0, 7.0))
    a = float(rng.uniform(22.0, 32.0))
    corr = {"points": [[-3.0, 0.0], [a, 0.0]], "width_m": width, "end_width_m": float(rng.uniform(2.0, 3.0)),
            "closed_end": True, "thickness_m": 0.2, "name": "dead end"}
    return Drawn({"corridors": [corr]}, [[0.0, 0.0], [a + 10.0, 0.0]], route_exists=False)
