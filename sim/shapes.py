"""Object shapes: footprints made of rounded convex pieces, extruded to prisms.

Every object stands on the table as a prism: its footprint (in the object's frame, the
origin at the centre of the footprint's bounding box) is a union of pieces, each a convex
polygon grown by a radius (a disc is a point grown, a stadium a segment grown). One
description serves the physics (MJCF geoms: boxes, vertical cylinders, convex meshes), the
geometry the exploration and the planner need (distance to the footprint, support along a
direction, enclosing radius, the turn after which the object looks the same), and the
pictures. Flat-bottomed prisms slide rather than roll, as pushed objects on a table do.

Families (``SHAPES``), generated in code from the scenario's ranges, nothing downloaded:

- ``box``, ``cylinder``: as before;
- ``capsule``: an elongated stadium puck (a box with round ends);
- ``hull``: the convex hull of random points in a rectangle (irregular, no symmetry);
- ``L`` and ``T``: two bars of one width, joined at a corner or at the middle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SHAPES = ("box", "cylinder", "capsule", "hull", "L", "T")
"""shape families, in the order datasets store them (indices must never change)"""
DETAILED_SHAPES = ("hull", "L", "T")
"""shapes that need more than their extents (``ObjectSpec.arm_m``, ``ObjectSpec.outline``)"""
HULL_POINTS = 8
"""random points whose convex hull is a ``hull`` object's footprint"""
MAX_OUTLINE = HULL_POINTS
"""the most outline vertices an object stores"""


@dataclass(frozen=True)
class Piece:
    """A convex polygon (1 vertex: a point, 2: a segment) grown by ``radius``, in the
    object's frame; its vertices run counter-clockwise."""

    vertices: tuple[tuple[float, float], ...]
    radius: float = 0.0

    @property
    def array(self) -> np.ndarray:
        return np.array(self.vertices, dtype=float).reshape(-1, 2)

    def distance(self, p: np.ndarray) -> float:
        """Distance from ``p`` (2,) to the piece (0 inside)."""
        v = self.array
        if len(v) >= 3:
            edges = np.roll(v, -1, 0) - v
            cross = edges[:, 0] * (p[1] - v[:, 1]) - edges[:, 1] * (p[0] - v[:, 0])
            if np.all(cross >= 0):
                return 0.0
        d = min(_segment_distance(p, a, b) for a, b in zip(v, np.roll(v, -1, 0), strict=True))
        return max(0.0, d - self.radius)

    def area(self) -> float:
        v, r = self.array, self.radius
        if len(v) == 1:
            return math.pi * r * r
        if len(v) == 2:
            return 2 * r * float(np.linalg.norm(v[1] - v[0])) + math.pi * r * r
        w = np.roll(v, -1, 0)
        polygon = 0.5 * abs(float(np.sum(v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1])))
        return polygon + r * float(np.linalg.norm(w - v, axis=1).sum()) + math.pi * r * r


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    n = float(ab @ ab)
    s = 0.0 if n == 0 else min(1.0, max(0.0, float((p - a) @ ab) / n))
    return float(np.linalg.norm(p - (a + s * ab)))


def _rect(x0: float, x1: float, y0: float, y1: float) -> Piece:
    return Piece(((x0, y0), (x1, y0), (x1, y1), (x0, y1)))


@dataclass(frozen=True)
class ObjectSpec:
    """One free object drawn for an episode."""

    shape: str
    """one of ``SHAPES``"""
    size_m: tuple[float, float, float]
    """extents of the footprint's bounding box along the object's x and y, and the height (a
    cylinder: 2r, 2r, height; a capsule: its length, its width, height)"""
    mass_kg: float
    friction: float
    arm_m: float = 0.0
    """``L``, ``T``: the width of their bars"""
    outline: tuple[tuple[float, float], ...] = ()
    """``hull``: the footprint polygon's vertices, counter-clockwise, object frame"""

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"unknown shape {self.shape!r}; known: {', '.join(SHAPES)}")

    def pieces(self) -> list[Piece]:
        """The footprint as convex pieces (see the module doc)."""
        sx, sy, _ = self.size_m
        hx, hy, w = sx / 2, sy / 2, self.arm_m
        if self.shape == "box":
            return [_rect(-hx, hx, -hy, hy)]
        if self.shape == "cylinder":
            return [Piece(((0.0, 0.0),), hx)]
        if self.shape == "capsule":
            r = min(hx, hy)
            return [Piece(((-(hx - r), 0.0), (hx - r, 0.0)), r)]
        if self.shape == "hull":
            return [Piece(self.outline)]
        # two bars that do not overlap (the mass is shared out by area)
        if self.shape == "L":  # a bar along x at the bottom, one along y at the left
            return [_rect(-hx, hx, -hy, -hy + w), _rect(-hx, -hx + w, -hy + w, hy)]
        return [_rect(-hx, hx, hy - w, hy), _rect(-w / 2, w / 2, -hy, hy - w)]  # T

    def distance_to_footprint_m(self, xy_obj: np.ndarray) -> float:
        """Distance from a point ``(2,)`` in the object's frame to its footprint (0 inside)."""
        p = np.asarray(xy_obj, dtype=float)
        return min(piece.distance(p) for piece in self.pieces())

    def support_m(self, u_obj: np.ndarray) -> float:
        """How far the footprint reaches along the unit direction ``u_obj`` (object frame):
        the largest ``p . u`` over its points."""
        ux, uy = (float(c) for c in u_obj)
        return max(  # elementwise, not a matrix product: the same rounding on every machine
            float((piece.array[:, 0] * ux + piece.array[:, 1] * uy).max()) + piece.radius
            for piece in self.pieces()
        )

    @property
    def footprint_radius_m(self) -> float:
        """Radius of the circle about the origin that holds the footprint in any yaw."""
        return max(
            max(math.hypot(x, y) for x, y in piece.vertices) + piece.radius
            for piece in self.pieces()
        )

    @property
    def yaw_period_rad(self) -> float | None:
        """The turn after which the object looks the same: π for a box or a capsule, π/2 for
        a box with a square footprint, None for a cylinder (any turn), 2π for the rest."""
        if self.shape == "cylinder":
            return None
        if self.shape == "box":
            sx, sy, _ = self.size_m
            return math.pi / 2 if abs(sx - sy) < 1e-3 else math.pi
        return math.pi if self.shape == "capsule" else 2 * math.pi

    def mjcf(self, name: str, attributes: str) -> tuple[str, str]:
        """(assets, geoms): MJCF for the object's prisms, centred on the body's origin in
        height; the mass is shared out by footprint area. ``attributes`` go on every geom."""
        hz = self.size_m[2] / 2
        parts: list[tuple[str, float]] = []  # (geom attributes, area)
        assets = []
        for j, piece in enumerate(self.pieces()):
            v, r = piece.array, piece.radius
            if len(v) == 1:
                parts.append((_cylinder(v[0], r, hz), piece.area()))
            elif len(v) == 2 and np.allclose(v[0], v[1]):  # a stadium as wide as it is long
                parts.append((_cylinder(v[0], r, hz), piece.area()))
            elif len(v) == 2:  # a stadium: a box and a cylinder at each end
                d = v[1] - v[0]
                length, angle = float(np.linalg.norm(d)), math.atan2(d[1], d[0])
                centre, size = mjcf_numbers(*(v[0] + v[1]) / 2, 0), mjcf_numbers(length / 2, r, hz)
                box = f'type="box" pos="{centre}" euler="0 0 {angle:.6g}" size="{size}"'
                parts.append((box, 2 * r * length))
                parts += [(_cylinder(end, r, hz), math.pi * r * r / 2) for end in v]
            elif self.shape != "hull":  # an axis-aligned rectangle
                lo, hi = v.min(0), v.max(0)
                centre, size = mjcf_numbers(*(lo + hi) / 2, 0), mjcf_numbers(*(hi - lo) / 2, hz)
                box = f'type="box" pos="{centre}" size="{size}"'
                parts.append((box, piece.area()))
            else:
                mesh = f"{name}_mesh{j}"
                prism = mjcf_numbers(*np.ravel([(x, y, z) for z in (-hz, hz) for x, y in v]))
                assets.append(f'<mesh name="{mesh}" vertex="{prism}"/>')
                parts.append((f'type="mesh" mesh="{mesh}"', piece.area()))
        total = sum(area for _, area in parts)
        geoms = [
            f'<geom name="{name}{"" if k == 0 else f"_{k}"}" {geom} '
            f'mass="{self.mass_kg * area / total:.6g}" {attributes}/>'
            for k, (geom, area) in enumerate(parts)
        ]
        return "".join(assets), "".join(geoms)

    def outline_array(self) -> np.ndarray:
        """(MAX_OUTLINE, 2) the outline, NaN-padded (as datasets store it)."""
        out = np.full((MAX_OUTLINE, 2), np.nan)
        out[: len(self.outline)] = np.array(self.outline, dtype=float).reshape(-1, 2)
        return out


def mjcf_numbers(*xs: float) -> str:
    """Numbers as an MJCF attribute value."""
    return " ".join(f"{x:.6g}" for x in xs)


def _cylinder(centre: np.ndarray, r: float, hz: float) -> str:
    return f'type="cylinder" pos="{mjcf_numbers(*centre, 0)}" size="{mjcf_numbers(r, hz)}"'


def hull_outline(points: np.ndarray) -> np.ndarray:
    """Vertices (counter-clockwise) of the convex hull of 2-D ``points`` (monotone chain)."""
    pts = sorted(map(tuple, np.asarray(points, dtype=float)))

    def half(seq: list) -> list:
        out: list = []
        for p in seq:
            while len(out) >= 2 and _cross(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _cross(o: tuple, a: tuple, b: tuple) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def outside_ranges(spec: ObjectSpec, objects) -> list[str]:
    """Why an object lies outside the ranges a scenario's ``objects`` (an ``ObjectsConfig``)
    draws from: a shape family it never draws, a size, mass or friction beyond its ranges.
    Empty: the scenario could have drawn it (what a held-out scenario must never be)."""
    if spec.shape not in objects.shapes:
        return [f"a {spec.shape}, a shape the scenario does not draw"]
    sx, sy, sz = spec.size_m
    if spec.shape == "cylinder":
        r_lo, r_hi = objects.cylinder_radius_m
        sizes = [(sx / 2, (r_lo, r_hi), "radius"), (sz, objects.cylinder_height_m, "height")]
    else:
        ranges = {"box": objects.box_size_m, "capsule": objects.capsule_size_m,
                  "hull": objects.hull_size_m}.get(spec.shape, objects.bar_size_m)  # fmt: skip
        if spec.shape == "hull":  # the hull of points drawn in the rectangle is smaller
            ranges = ((0.0, ranges[0][1]), (0.0, ranges[1][1]), ranges[2])
        sizes = list(zip((sx, sy, sz), ranges, ("x extent", "y extent", "height"), strict=True))
        if spec.shape in ("L", "T"):
            sizes.append((spec.arm_m, objects.bar_width_m, "bar width"))
    sizes.append((spec.mass_kg, objects.mass_kg, "mass"))
    sizes.append((spec.friction, objects.friction, "friction"))
    return [
        f"{what} {value:.3g} outside [{lo:.3g}, {hi:.3g}]"
        for value, (lo, hi), what in sizes
        if not lo - 1e-9 <= value <= hi + 1e-9
    ]
