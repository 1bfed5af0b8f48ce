"""Collision outlines of models: Stage's ``block`` polygons scaled to ``size``, offset by ``origin``.

Stage 4 semantics (Stage manual "model": ``size``, ``origin``, ``block``; ``libstage/blockgroup.cc``
read for meaning): a model's blocks, written in any unit, are scaled together so that the bounding
box of all of them is the model's ``size`` (x, y), and that box is centred on the model's
``origin [x y z a]``, an offset of the shape from the model's pose (the centre of rotation). A model
without blocks is one ``size`` box. Outlines may be concave: pymunk's convex decomposition splits
them into the convex pieces its polygons need.
"""

from __future__ import annotations

import math

import pymunk
import pymunk.autogeometry

from .spec import ModelSpec

__all__ = ["convex_pieces", "make_shapes", "outline"]

Point = tuple[float, float]


def outline(spec: ModelSpec) -> list[list[Point]]:
    """The model's block polygons in its body frame, metres: scaled to ``size``, placed at ``origin``."""
    sx, sy = float(spec.size[0]), float(spec.size[1])
    ox, oy, oa = (float(v) for v in spec.origin)
    blocks = [list(b) for b in spec.blocks if len(b) >= 3 and abs(_area(list(b))) > 1e-12]
    if not blocks:
        blocks = [[(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]]
    xs = [p[0] for b in blocks for p in b]
    ys = [p[1] for b in blocks for p in b]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    kx = sx / (x1 - x0) if x1 > x0 else 1.0
    ky = sy / (y1 - y0) if y1 > y0 else 1.0
    cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    c, s = math.cos(oa), math.sin(oa)
    out = []
    for b in blocks:
        poly = []
        for x, y in b:
            u, v = (x - cx) * kx, (y - cy) * ky
            poly.append((ox + c * u - s * v, oy + s * u + c * v))
        out.append(poly)
    return out


def convex_pieces(poly: list[Point]) -> list[list[Point]]:
    """A simple polygon as convex polygons (itself when convex), counter-clockwise."""
    if _area(poly) < 0:
        poly = poly[::-1]
    if _is_convex(poly):
        return [poly]
    closed = [*poly, poly[0]]
    try:
        parts = pymunk.autogeometry.convex_decomposition(closed, 0.0)
    except AssertionError:  # self-intersecting outline: its hull is the best pymunk can do
        return [poly]
    return [[(float(p[0]), float(p[1])) for p in part[:-1]] for part in parts if len(part) >= 4]


def _area(poly: list[Point]) -> float:
    return 0.5 * sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(poly, poly[1:] + poly[:1], strict=True))


def _is_convex(poly: list[Point]) -> bool:
    n = len(poly)
    for i in range(n):
        (x0, y0), (x1, y1), (x2, y2) = poly[i], poly[(i + 1) % n], poly[(i + 2) % n]
        if (x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1) < -1e-12:
            return False
    return True


def make_shapes(body: pymunk.Body, spec: ModelSpec) -> tuple[list[pymunk.Poly], float, float]:
    """The pymunk polygons of ``spec`` on ``body``, the body's moment of inertia for ``spec.mass``
    spread over their area, and the radius of the circle rangers see: half the larger side of
    ``size`` (as for a plain box) plus the ``origin`` offset."""
    pieces = [p for poly in outline(spec) for p in convex_pieces(poly)]
    areas = [max(abs(_area(p)), 1e-12) for p in pieces]
    total = sum(areas)
    mass = max(float(spec.mass), 1e-3)
    moment = sum(pymunk.moment_for_poly(mass * a / total, p) for p, a in zip(pieces, areas, strict=True))
    shapes = [pymunk.Poly(body, p) for p in pieces]
    radius = 0.5 * max(float(spec.size[0]), float(spec.size[1])) + math.hypot(spec.origin[0], spec.origin[1])
    return shapes, moment, radius
