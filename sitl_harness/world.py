"""The true world: vertical circular columns, (rotated) boxes and solid polygons standing on the ground. Pure maths.

Walls (thick segments and polylines, with gaps and doorways), corridors and clusters of columns are built
from the scenario's keys into these three shapes by `sitl_harness/world_build.py`: a wall piece is a thin
rectangular `Polygon`, a cluster is its `Column`s. Ray casting takes every shape of a kind in one vectorised
pass (columns as circles, polygons as their edges).

Horizontal geometry in local NED (x north, y east). Each obstacle rises from the ground to
`height_m` (infinite by default); a vehicle at altitude h = −z sees/hits it only while h ≤ height.
Each obstacle has a diffuse `reflectivity` (0–1] at the range sensor's wavelength, which decides how far
it is seen through fog (sitl_harness/sensors.py): default 0.5, the reference target; a dark column ≈ 0.1,
a bright (white-painted) wall ≈ 0.8–0.9. In clear air every obstacle of reflectivity ≥ 0.1 is seen to the
sensor's full range, as before reflectivity existed.
Truth stays inside the harness: clients learn about it only through the simulated sensor's MAVLink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from contracts.lidar import REFERENCE_REFLECTIVITY


@dataclass(frozen=True)
class Column:
    x: float
    y: float
    radius: float
    height: float = math.inf
    name: str = ""
    reflectivity: float = REFERENCE_REFLECTIVITY


@dataclass(frozen=True)
class Box:
    x: float  # centre
    y: float
    length: float  # extent along the box's own x axis (north when yaw = 0)
    width: float
    yaw: float = 0.0  # rad, rotation of the box's x axis from north toward east
    height: float = math.inf
    name: str = ""
    reflectivity: float = REFERENCE_REFLECTIVITY


@dataclass(frozen=True)
class Polygon:
    """A solid prism on a simple polygon's outline (`points` in order, either sense, not repeated at the end)."""

    points: tuple[tuple[float, float], ...]
    height: float = math.inf
    name: str = ""
    reflectivity: float = REFERENCE_REFLECTIVITY


class _Edges:
    """Every polygon's edges as arrays (start, direction, owner polygon), rebuilt when a polygon is added."""

    def __init__(self, polygons: list[Polygon]):
        a = [p for poly in polygons for p in poly.points]
        b = [p for poly in polygons for p in (*poly.points[1:], poly.points[0])]
        self.owner = np.array([i for i, poly in enumerate(polygons) for _ in poly.points], dtype=int)
        self.ax, self.ay = (np.array([p[k] for p in a], dtype=float) for k in (0, 1))
        self.ex, self.ey = (np.array([q[k] - p[k] for p, q in zip(a, b)], dtype=float) for k in (0, 1))
        self.height = np.array([p.height for p in polygons], dtype=float)
        self.rho = np.array([p.reflectivity for p in polygons], dtype=float)
        self.n = len(polygons)

    def inside(self, px: float, py: float) -> np.ndarray:
        """Per polygon: whether (px, py) is inside it (crossing number of a ray towards +x)."""
        ay, by = self.ay, self.ay + self.ey
        straddle = (ay > py) != (by > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = self.ax + (py - ay) / self.ey * self.ex
        cross = straddle & (xc > px)
        return np.bincount(self.owner, weights=cross, minlength=self.n).astype(int) % 2 == 1

    def distance(self, px: float, py: float) -> np.ndarray:
        """Per polygon: distance from (px, py) to its outline."""
        wx, wy = px - self.ax, py - self.ay
        ll = self.ex * self.ex + self.ey * self.ey
        s = np.clip((wx * self.ex + wy * self.ey) / ll, 0.0, 1.0)
        d = np.hypot(wx - s * self.ex, wy - s * self.ey)
        out = np.full(self.n, np.inf)
        np.minimum.at(out, self.owner, d)
        return out


@dataclass
class World:
    columns: list[Column] = field(default_factory=list)
    boxes: list[Box] = field(default_factory=list)
    polygons: list[Polygon] = field(default_factory=list)

    def __post_init__(self):
        self.obstacles = [*self.columns, *self.boxes, *self.polygons]
        self._edges = _Edges(self.polygons) if self.polygons else None
        self._poly_index = [len(self.columns) + len(self.boxes) + i for i in range(len(self.polygons))]

    def add(self, obstacle: Column | Box | Polygon) -> None:
        """An obstacle that appears now; appended last to `obstacles`, so earlier indices keep their meaning."""
        if isinstance(obstacle, Polygon):
            self.polygons.append(obstacle)
            self._edges = _Edges(self.polygons)
            self._poly_index.append(len(self.obstacles))
        else:
            (self.columns if isinstance(obstacle, Column) else self.boxes).append(obstacle)
        self.obstacles.append(obstacle)

    def ray_cast(self, px: float, py: float, alt: float, angles: np.ndarray,
                 max_range: float, reflectivity: bool = False):
        """Distance along horizontal rays from (px, py) at compass `angles` (rad) to the first
        obstacle surface, `inf` if none within `max_range`. A ray starting inside an obstacle: 0.
        With `reflectivity`, also the reflectivity of the surface each ray hits (0 where none)."""
        dx = np.cos(angles)
        dy = np.sin(angles)
        best = np.full(angles.shape, np.inf)
        rho = np.zeros(angles.shape)
        cx, cy, cr, ch, crho = self._column_arrays()
        tall = ch >= alt
        if tall.any():  # every column against every ray at once: (columns × rays)
            if not tall.all():
                cx, cy, cr, crho = cx[tall], cy[tall], cr[tall], crho[tall]
            ox = px - cx[:, None]
            oy = py - cy[:, None]
            r = cr[:, None]
            b = dx * ox + dy * oy
            cc = ox * ox + oy * oy - r * r
            disc = b * b - cc
            with np.errstate(invalid="ignore"):
                t = np.where(cc <= 0.0, 0.0, -b - np.sqrt(np.maximum(disc, 0.0)))
            t = np.where((disc >= 0.0) & (t >= 0.0), t, np.inf)
            k = t.argmin(axis=0)  # the first column of the nearest surface, as a loop over columns would keep
            tk = t[k, np.arange(angles.size)].reshape(angles.shape)
            hit = tk < best
            best = np.where(hit, tk, best)
            rho = np.where(hit, crho[k].reshape(angles.shape), rho)
        for bx in self.boxes:
            if alt > bx.height:
                continue
            cy, sy = math.cos(bx.yaw), math.sin(bx.yaw)
            ox, oy = px - bx.x, py - bx.y
            lx, ly = cy * ox + sy * oy, -sy * ox + cy * oy  # origin in the box frame
            ux, uy = cy * dx + sy * dy, -sy * dx + cy * dy  # directions in the box frame
            hx, hy = 0.5 * bx.length, 0.5 * bx.width
            tmin = np.zeros(angles.shape)
            tmax = np.full(angles.shape, np.inf)
            ok = np.ones(angles.shape, dtype=bool)
            for o, u, h in ((lx, ux, hx), (ly, uy, hy)):
                par = np.abs(u) < 1e-12
                ok &= ~(par & (abs(o) > h))
                with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # par: masked below
                    t1 = (-h - o) / u
                    t2 = (h - o) / u
                lo = np.where(par, -np.inf, np.minimum(t1, t2))
                hi = np.where(par, np.inf, np.maximum(t1, t2))
                tmin = np.maximum(tmin, lo)
                tmax = np.minimum(tmax, hi)
            hit = ok & (tmin <= tmax) & (tmin < best)
            best = np.where(hit, tmin, best)
            rho = np.where(hit, bx.reflectivity, rho)
        if self._edges is not None:
            best, rho = self._cast_edges(px, py, alt, dx, dy, best, rho)
        d = np.where(best <= max_range, best, np.inf)
        return (d, np.where(np.isfinite(d), rho, 0.0)) if reflectivity else d

    def _column_arrays(self):
        """The columns' x, y, radius, height and reflectivity as arrays, rebuilt when the list changes."""
        key = (id(self.columns), len(self.columns))
        if getattr(self, "_col_key", None) != key:
            self._col_key = key
            self._cols = tuple(np.array([getattr(c, a) for c in self.columns], dtype=float)
                               for a in ("x", "y", "radius", "height", "reflectivity"))
        return self._cols

    def _cast_edges(self, px, py, alt, dx, dy, best, rho):
        """`best`, `rho` with every polygon's edges taken in (edges × rays); a ray from inside a polygon: 0."""
        e = self._edges
        tall = e.height >= alt
        inside = e.inside(px, py) & tall
        if inside.any():
            i = int(np.flatnonzero(inside)[0])
            return np.zeros_like(best), np.full(best.shape, e.rho[i])
        keep = tall[e.owner]
        ax, ay, ex, ey = (v[keep][:, None] for v in (e.ax, e.ay, e.ex, e.ey))
        wx, wy = ax - px, ay - py
        u, v = dx.reshape(1, -1), dy.reshape(1, -1)
        den = u * ey - v * ex  # (direction × edge): 0 for a ray along the edge
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (wx * ey - wy * ex) / den
            s = (wx * v - wy * u) / den
        t = np.where((den != 0.0) & (t >= 0.0) & (s >= 0.0) & (s <= 1.0), t, np.inf)
        if t.size == 0:
            return best, rho
        k = t.argmin(axis=0)
        tk = t[k, np.arange(t.shape[1])].reshape(best.shape)
        hit = tk < best
        owner_rho = e.rho[e.owner[keep]][k].reshape(best.shape)
        return np.where(hit, tk, best), np.where(hit, owner_rho, rho)

    def distances(self, px: float, py: float, alt: float = -math.inf) -> np.ndarray:
        """Per obstacle (in `obstacles` order): the horizontal distance from a point to its surface (negative
        inside), inf for one lower than `alt`."""
        out = np.full(len(self.obstacles), np.inf)
        for k, o in enumerate(self.obstacles):
            if alt > o.height or isinstance(o, Polygon):
                continue
            if isinstance(o, Column):
                out[k] = math.hypot(px - o.x, py - o.y) - o.radius
            else:
                cy, sy = math.cos(o.yaw), math.sin(o.yaw)
                ox, oy = px - o.x, py - o.y
                lx, ly = abs(cy * ox + sy * oy) - 0.5 * o.length, abs(-sy * ox + cy * oy) - 0.5 * o.width
                out[k] = math.hypot(max(lx, 0.0), max(ly, 0.0)) if (lx > 0 or ly > 0) else max(lx, ly)
        if self._edges is not None:
            e = self._edges
            d = np.where(e.inside(px, py), -1.0, 1.0) * e.distance(px, py)
            out[self._poly_index] = np.where(e.height >= alt, d, np.inf)
        return out

    def clearance(self, px: float, py: float, alt: float) -> tuple[float, int]:
        """Horizontal distance from a point to the nearest obstacle surface (negative inside) and
        that obstacle's index in `obstacles` (−1 if none)."""
        d = self.distances(px, py, alt)
        if not d.size or not np.isfinite(d).any():
            return math.inf, -1
        k = int(d.argmin())
        return float(d[k]), k


@dataclass(frozen=True)
class Collision:
    """The body disc (radius r_body) touched an obstacle: when, where (NED) and which."""

    time_s: float
    position: tuple[float, float, float]
    obstacle: int
    obstacle_name: str
    clearance_m: float  # surface distance of the vehicle centre at detection


class CollisionMonitor:
    """Swept check of the body disc against the true geometry; one record per contact."""

    def __init__(self, world: World, r_body: float):
        self.world = world
        self.r_body = r_body
        self.collisions: list[Collision] = []
        self.min_clearance = math.inf  # smallest surface distance minus r_body seen so far
        self._touching = False
        self._prev: tuple[float, float, float] | None = None

    def update(self, t: float, pos: np.ndarray) -> Collision | None:
        if not self.world.obstacles:
            return None
        x1, y1, z1 = float(pos[0]), float(pos[1]), float(pos[2])
        x0, y0, z0 = (x1, y1, z1) if self._prev is None else self._prev
        self._prev = (x1, y1, z1)
        n = max(1, math.ceil(math.hypot(x1 - x0, y1 - y0) / (0.25 * self.r_body)))
        worst = math.inf
        first = None  # first sample along the step where the body disc touches
        for k in range(1, n + 1):
            f = k / n
            px, py, pz = x0 + (x1 - x0) * f, y0 + (y1 - y0) * f, z0 + (z1 - z0) * f
            d, i = self.world.clearance(px, py, -pz)
            worst = min(worst, d)
            if first is None and d < self.r_body:
                first = (d, i, (px, py, pz))
        self.min_clearance = min(self.min_clearance, worst - self.r_body)
        touching = first is not None
        new = None
        if touching and not self._touching:
            d, widx, wpos = first
            o = self.world.obstacles[widx]
            new = Collision(t, wpos, widx, o.name or f"#{widx}", d)
            self.collisions.append(new)
        self._touching = touching
        return new
