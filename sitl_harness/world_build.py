"""From a scenario's world keys to the shapes of `world.py`: walls (thick polylines with gaps), corridors,
polygons and seeded clusters of columns. Pure maths, no I/O.

A wall is a polyline of a given thickness, centred on its points. Each straight piece becomes a solid
rectangle; at a joint of two pieces both are lengthened by half the thickness, so the corner is closed (for a
turn up to 90°; a sharper one leaves a notch on its outside). A gap (a doorway) removes `width_m` of the wall
centred `at_m` along it, measured from its first point; the pieces either side of a gap end square, exactly
`width_m` apart along the centre line.

A corridor is two walls either side of a centre polyline, their inner faces `width_m` apart at the start and
`end_width_m` apart at the end (the width changes linearly along the centre line: a corridor that narrows, or
closes at 0, which also puts a wall across its end), with mitred corners at each turn of the centre line;
`closed_end` puts a wall across its end (a dead end).
"""

from __future__ import annotations

import math

import numpy as np

from .world import Column, Polygon

Point = tuple[float, float]


def _lengths(points: list[Point]) -> np.ndarray:
    """Cumulative length along a polyline at each of its points (0 at the first)."""
    p = np.asarray(points, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])


def _at(points: list[Point], cum: np.ndarray, s: float) -> Point:
    """The point `s` along a polyline."""
    i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(points) - 2))
    f = 0.0 if cum[i + 1] == cum[i] else (s - cum[i]) / (cum[i + 1] - cum[i])
    (x0, y0), (x1, y1) = points[i], points[i + 1]
    return (x0 + f * (x1 - x0), y0 + f * (y1 - y0))


def sub_polyline(points: list[Point], s0: float, s1: float) -> list[Point]:
    """The part of a polyline from `s0` to `s1` along it (its own points in between kept)."""
    cum = _lengths(points)
    inner = [tuple(map(float, points[i])) for i in range(len(points)) if s0 < cum[i] < s1]
    return [_at(points, cum, s0), *inner, _at(points, cum, s1)]


def open_spans(length: float, gaps: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The spans of [0, length] left once each gap (centre along the line, width) is taken out."""
    cuts = sorted((max(0.0, c - 0.5 * w), min(length, c + 0.5 * w)) for c, w in gaps)
    spans, start = [], 0.0
    for a, b in cuts:
        if a > start:
            spans.append((start, a))
        start = max(start, b)
    if start < length:
        spans.append((start, length))
    return [(a, b) for a, b in spans if b - a > 1e-9]


def thick_pieces(points: list[Point], thickness: float) -> list[tuple[Point, ...]]:
    """The solid rectangles of a polyline wall of `thickness` (module docstring: joints closed, free ends
    square)."""
    out = []
    n = len(points) - 1
    for i in range(n):
        (x0, y0), (x1, y1) = points[i], points[i + 1]
        length = math.hypot(x1 - x0, y1 - y0)
        if length < 1e-9:
            continue
        ux, uy = (x1 - x0) / length, (y1 - y0) / length
        back = 0.5 * thickness if i > 0 else 0.0  # lengthened into a joint, not at a free end
        ahead = 0.5 * thickness if i < n - 1 else 0.0
        ax, ay = x0 - back * ux, y0 - back * uy
        bx, by = x1 + ahead * ux, y1 + ahead * uy
        nx, ny = -uy * 0.5 * thickness, ux * 0.5 * thickness
        out.append(((ax + nx, ay + ny), (bx + nx, by + ny), (bx - nx, by - ny), (ax - nx, ay - ny)))
    return out


def wall_polygons(points: list[Point], thickness: float, gaps: list[tuple[float, float]] = (), *,
                  height: float = math.inf, name: str = "", reflectivity: float) -> list[Polygon]:
    """A wall along `points` with its gaps (centre along it, width) as solid rectangles."""
    cum = _lengths(points)
    out = []
    for a, b in open_spans(float(cum[-1]), list(gaps)):
        for quad in thick_pieces(sub_polyline(points, a, b), thickness):
            out.append(Polygon(quad, height, name, reflectivity))
    return out


def offset_polyline(points: list[Point], offsets: list[float]) -> list[Point]:
    """`points` moved `offsets[i]` to the left of the direction of travel (a negative offset: to the right),
    corners mitred."""
    p = np.asarray(points, dtype=float)
    d = np.diff(p, axis=0)
    u = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    left = np.column_stack([u[:, 1], -u[:, 0]])  # x north, y east: left of travel is (uy, −ux)
    out = []
    for i in range(len(p)):
        if i == 0:
            n, scale = left[0], 1.0
        elif i == len(p) - 1:
            n, scale = left[-1], 1.0
        else:
            m = left[i - 1] + left[i]
            n = m / np.hypot(*m)
            scale = 1.0 / max(float(n @ left[i]), 0.2)  # mitre; a hairpin is capped at 5× the offset
        q = p[i] + n * offsets[i] * scale
        out.append((float(q[0]), float(q[1])))
    return out


def corridor_walls(points: list[Point], width: float, end_width: float, thickness: float,
                   closed_end: bool) -> list[list[Point]]:
    """The centre lines of a corridor's walls: left, right (and, closed, the end wall)."""
    cum = _lengths(points)
    half = [0.5 * (width + (end_width - width) * s / cum[-1]) + 0.5 * thickness for s in cum]
    left = offset_polyline(points, half)
    right = offset_polyline(points, [-h for h in half])
    walls = [left, right]
    if closed_end or end_width <= 0.0:  # closing to nothing: the walls' ends would only touch at a point
        walls.append([left[-1], right[-1]])
    return walls


def cluster_columns(x: float, y: float, radius: float, count: int, r_min: float, r_max: float, min_gap: float,
                    seed: int, tries: int = 200) -> list[tuple[float, float, float]]:
    """`count` columns (x, y, radius) with centres uniform in the disc of `radius` about (x, y), radii uniform
    in [r_min, r_max], every two surfaces at least `min_gap` apart; the same seed gives the same cluster.
    Raises ValueError when they do not fit (`tries` draws per column)."""
    rng = np.random.default_rng(seed)
    placed: list[tuple[float, float, float]] = []
    for k in range(count):
        for _ in range(tries):
            rr = radius * math.sqrt(rng.random())
            a = 2.0 * math.pi * rng.random()
            r = r_min + (r_max - r_min) * rng.random()
            cx, cy = x + rr * math.cos(a), y + rr * math.sin(a)
            if all(math.hypot(cx - px, cy - py) - r - pr >= min_gap for px, py, pr in placed):
                placed.append((cx, cy, r))
                break
        else:
            raise ValueError(f"only {k} of {count} columns fit a disc of radius {radius:g} m {min_gap:g} m apart")
    return placed


def cluster(spec, prefix: str, reflectivity: float, height: float = math.inf) -> list[Column]:
    """A cluster spec's columns (named `prefix`.k)."""
    cols = cluster_columns(spec.x_m, spec.y_m, spec.radius_m, spec.count, spec.column_radius_m[0],
                           spec.column_radius_m[1], spec.min_gap_m, spec.seed)
    return [Column(cx, cy, r, height, f"{prefix}.{k}", reflectivity) for k, (cx, cy, r) in enumerate(cols)]


def built(world_spec) -> tuple[list[Column], list[Polygon]]:
    """The columns of the clusters and the polygons of the walls, corridors and polygons of a `WorldSpec`."""
    inf = math.inf
    columns = []
    for i, c in enumerate(world_spec.clusters):
        columns += cluster(c, c.name or f"cluster{i}", c.reflectivity, c.height_m or inf)
    polys: list[Polygon] = []
    for i, w in enumerate(world_spec.walls):
        polys += wall_polygons([tuple(p) for p in w.points], w.thickness_m, [(g.at_m, g.width_m) for g in w.gaps],
                               height=w.height_m or inf, name=w.name or f"wall{i}", reflectivity=w.reflectivity)
    for i, c in enumerate(world_spec.corridors):
        name = c.name or f"corridor{i}"
        end = c.width_m if c.end_width_m is None else c.end_width_m
        for side, line in zip(("left", "right", "end"), corridor_walls([tuple(p) for p in c.points], c.width_m, end,
                                                                      c.thickness_m, c.closed_end)):
            polys += wall_polygons(line, c.thickness_m, height=c.height_m or inf, name=f"{name}.{side}",
                                   reflectivity=c.reflectivity)
    for i, p in enumerate(world_spec.polygons):
        polys.append(Polygon(tuple(tuple(q) for q in p.points), p.height_m or inf, p.name or f"polygon{i}",
                             p.reflectivity))
    return columns, polys


def outline(world_spec) -> dict:
    """The world drawn from above, as plain data: {"columns": [[x, y, r, name]], "polygons": [[[x, y], …]]}
    (boxes as their four corners); what a plan view draws."""
    cols, polys = built(world_spec)
    columns = [[c.x_m, c.y_m, c.radius_m, c.name] for c in world_spec.columns]
    columns += [[float(c.x), float(c.y), float(c.radius), c.name] for c in cols]
    shapes = [[[float(x), float(y)] for x, y in poly.points] for poly in polys]
    for b in world_spec.boxes:
        cy, sy = math.cos(math.radians(b.yaw_deg)), math.sin(math.radians(b.yaw_deg))
        hx, hy = 0.5 * b.length_m, 0.5 * b.width_m
        shapes.append([[b.x_m + cy * lx - sy * ly, b.y_m + sy * lx + cy * ly]
                       for lx, ly in ((hx, hy), (hx, -hy), (-hx, -hy), (-hx, hy))])
    return {"columns": columns, "polygons": shapes}
