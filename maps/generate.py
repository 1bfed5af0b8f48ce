#!/usr/bin/env python3
"""Draw the project's floorplan bitmaps: ``python maps/generate.py`` rewrites every PNG in place,
with ``maps.yaml`` and, per map, ``NAME.yaml`` in the ROS map_server format (docs/mapping.md).

All three maps are original drawings of this project (nothing is taken from Stage or Player).
Each layout is plain data below: rectangles ``(x0, y0, x1, y1)`` and polygons ``[(x, y), ...]``
in *world metres*, the same coordinates the world files and Player's ``mapfile`` driver use
(``origin`` is the world position of the bitmap's bottom-left corner). The output is an 8-bit
grayscale PNG, 255 = free and 0 = occupied, with an outer wall around the whole bitmap.

Drawing order per map: the outer wall, ``walls``, then ``doors`` are cut free again (a door is a
gap in a wall), then ``blocks`` (furniture, pillars, stairs) and ``polygons`` (irregular solids).

Rectangle edges snap to the nearest pixel boundary (ties round up). For ``testroom`` and
``arena`` every edge used lies exactly on a pixel boundary, so their geometry is exact; the
``floor`` origin (-31.475, -7.8) puts round x values on pixel centres, so its vertical edges land
0.025 m (half a pixel) east of the listed value -- irrelevant for a building plan.

Only numpy and Pillow are needed; the output is deterministic (same bytes every run).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

HERE = Path(__file__).resolve().parent

FREE, OCCUPIED = 255, 0


def _octagon(cx: float, cy: float, w: float, h: float, cut: float) -> list[tuple[float, float]]:
    """An axis-aligned w x h rectangle centred at (cx, cy) with its corners cut by ``cut``."""
    x0, x1, y0, y1 = cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2
    return [
        (x0 + cut, y0),
        (x1 - cut, y0),
        (x1, y0 + cut),
        (x1, y1 - cut),
        (x1 - cut, y1),
        (x0 + cut, y1),
        (x0, y1 - cut),
        (x0, y0 + cut),
    ]


def _circle(cx: float, cy: float, r: float, n: int = 24) -> list[tuple[float, float]]:
    return [(cx + r * math.cos(2 * math.pi * k / n), cy + r * math.sin(2 * math.pi * k / n)) for k in range(n)]


# =====================================================================================================
# floor.png -- "in the spirit of the TAMS floor": 60 m x 20 m, 0.05 m/px, origin (-31.475, -7.8).
# World extent x in [-31.475, 28.525], y in [-7.8, 12.2]. Outer wall 0.3 m, inner walls 0.2 m.
# A 2.5 m corridor (y 0.5 .. 3.0) runs the whole length; rooms on both sides open onto it through
# door gaps of 0.95-1.2 m; the corridor ends east in an open stair hall (x > 20).
#
#   north band (y 3.2 .. 11.9):  N1 seminar [-31.2,-24.2] | LAB [-24.0,-12.0] (12.0 x 8.7 m, two doors)
#     | N3 [-11.8,-7.0] | N4 [-6.8,-3.0] | N5 server room [-2.8,0.2] (NO door) | N6 [0.4,5.0]
#     | N7 [5.2,11.0] | N8 workshop [11.2,19.8] (L-shaped partition) | stair hall [20.0,28.2]
#   south band (y -7.5 .. 0.3): S1 [-31.2,-26.2] | S2 [-26.0,-20.0] | S3 [-19.8,-15.0] | S4 [-14.8,-9.0]
#     | S5 kitchen [-8.8,-5.0] | S6 [-4.8,2.0] | S7 [2.2,8.0] | S8 [8.2,14.0] | S9 [14.2,20.0]
#     | S10 washrooms [20.2,28.2] (L-shaped partition)
# =====================================================================================================
FLOOR = {
    "file": "floor.png",
    "resolution": 0.05,
    "origin": (-31.475, -7.8),
    "size_px": (1200, 400),
    "outer_wall": 0.3,
    "walls": [
        # corridor walls: south wall runs the full length, north wall stops at the stair hall
        (-31.475, 0.3, 28.525, 0.5),
        (-31.475, 3.0, 20.0, 3.2),
        # north partitions (y 3.2 .. outer wall)
        (-24.2, 3.2, -24.0, 12.2),
        (-12.0, 3.2, -11.8, 12.2),
        (-7.0, 3.2, -6.8, 12.2),
        (-3.0, 3.2, -2.8, 12.2),
        (0.2, 3.2, 0.4, 12.2),
        (5.0, 3.2, 5.2, 12.2),
        (11.0, 3.2, 11.2, 12.2),
        (19.8, 3.2, 20.0, 12.2),
        # workshop N8: L-shaped partition leaving a store in its north-east corner
        (15.4, 7.0, 15.6, 12.2),
        (15.4, 7.0, 18.2, 7.2),
        # south partitions (outer wall .. y 0.3)
        (-26.2, -7.8, -26.0, 0.3),
        (-20.0, -7.8, -19.8, 0.3),
        (-15.0, -7.8, -14.8, 0.3),
        (-9.0, -7.8, -8.8, 0.3),
        (-5.0, -7.8, -4.8, 0.3),
        (2.0, -7.8, 2.2, 0.3),
        (8.0, -7.8, 8.2, 0.3),
        (14.0, -7.8, 14.2, 0.3),
        (20.0, -7.8, 20.2, 0.3),
        # washrooms S10: L-shaped partition
        (24.0, -7.8, 24.2, -2.0),
        (24.0, -2.2, 26.6, -2.0),
    ],
    "doors": [
        # north side of the corridor (gap through y 3.0 .. 3.2); N5 has none
        (-26.8, 2.9, -25.8, 3.3),  # N1 seminar, 1.0 m
        (-22.6, 2.9, -21.5, 3.3),  # LAB west door, 1.1 m
        (-14.9, 2.9, -13.9, 3.3),  # LAB east door, 1.0 m
        (-8.4, 2.9, -7.4, 3.3),  # N3, 1.0 m
        (-6.4, 2.9, -5.45, 3.3),  # N4, 0.95 m
        (0.9, 2.9, 1.9, 3.3),  # N6, 1.0 m
        (9.6, 2.9, 10.7, 3.3),  # N7, 1.1 m
        (11.7, 2.9, 12.9, 3.3),  # N8 workshop, 1.2 m
        (17.0, 6.9, 18.0, 7.3),  # N8 inner door to its store, 1.0 m
        # south side of the corridor (gap through y 0.3 .. 0.5)
        (-27.6, 0.2, -26.6, 0.6),  # S1
        (-25.4, 0.2, -24.4, 0.6),  # S2
        (-16.4, 0.2, -15.4, 0.6),  # S3
        (-14.2, 0.2, -13.2, 0.6),  # S4
        (-7.2, 0.2, -6.2, 0.6),  # S5 kitchen
        (-0.5, 0.2, 0.6, 0.6),  # S6, 1.1 m
        (6.6, 0.2, 7.6, 0.6),  # S7
        (8.7, 0.2, 9.7, 0.6),  # S8
        (18.5, 0.2, 19.5, 0.6),  # S9
        (21.0, 0.2, 22.1, 0.6),  # S10 washrooms, 1.1 m
        (24.9, -2.3, 25.9, -1.9),  # S10 inner door, 1.0 m
    ],
    "blocks": [
        # pillars, half let into the corridor walls
        (-24.3, 2.7, -23.9, 3.0),
        (-9.1, 0.5, -8.7, 0.8),
        (4.9, 2.7, 5.3, 3.0),
        # laboratory furniture
        (-23.4, 11.1, -19.4, 11.9),  # work bench along the north wall
        (-24.0, 6.0, -23.4, 9.0),  # cabinets on the west wall
        (-18.5, 6.8, -15.5, 8.2),  # island table
        (-16.0, 10.6, -14.4, 11.9),  # desk
        (-12.6, 8.5, -12.0, 11.9),  # tall cabinet on the east wall
        # kitchen S5: L-shaped counter
        (-8.8, -7.5, -8.2, -3.5),
        (-8.8, -7.5, -6.0, -6.9),
        # stair hall: lift shaft in the north-east corner
        (26.2, 9.4, 28.525, 12.2),
        # a few desks / shelves in offices
        (-11.8, 10.9, -9.8, 11.9),  # N3 desk
        (5.2, 3.2, 5.8, 6.2),  # N7 shelf
        (2.2, -7.5, 4.2, -6.7),  # S7 desk
        (14.2, -3.0, 14.8, 0.3),  # S9 shelf
    ],
    "polygons": [
        _octagon(-27.7, 7.6, 3.0, 1.6, 0.4),  # seminar room N1: conference table
        [(-31.475, 12.2), (-29.5, 12.2), (-31.475, 10.2)],  # chamfered north-west corner of N1
        [(22.0, 12.2), (22.0, 9.5), (23.5, 8.0), (25.2, 8.0), (25.2, 12.2)],  # stairwell, cut corner
        [(25.5, 0.5), (28.525, 0.5), (28.525, 3.5)],  # slanted wall, south-east of the stair hall
        [(-31.475, -7.8), (-29.8, -7.8), (-31.475, -6.0)],  # chamfered south-west corner of S1
        [(12.0, -7.5), (13.9, -7.5), (13.9, -5.8)],  # wedge-shaped cabinet in S8
    ],
}

# =====================================================================================================
# arena.png -- the swarm arena (thesis fig. 4.7: 128 m x 128 m, "derived from simple.world" in
# spirit): 0.1 m/px, origin (-64, -64), world extent [-64, 64] x [-64, 64]. Outer wall 0.5 m.
# A dozen scattered obstacles of varied shape; nothing reaches into the square |x|, |y| < 20 m, so
# the centre (|x|, |y| <= 10 m asked for) is free with margin for 100 robots starting close together.
# =====================================================================================================
ARENA = {
    "file": "arena.png",
    "resolution": 0.1,
    "origin": (-64.0, -64.0),
    "size_px": (1280, 1280),
    "outer_wall": 0.5,
    "walls": [
        (-50.0, 5.0, -49.0, 45.0),  # long wall, west
        (-10.0, 45.0, 40.0, 46.0),  # long wall, north
        (10.0, -55.0, 11.0, -20.0),  # long wall, south
        (30.0, 28.0, 44.0, 29.5),  # T-shape: bar ...
        (36.2, 29.5, 37.8, 38.0),  # ... and stem
        (-58.0, -58.0, -44.0, -56.5),  # U-shape (open to the north): base ...
        (-58.0, -56.5, -56.5, -46.0),  # ... west arm
        (-45.5, -56.5, -44.0, -46.0),  # ... east arm
    ],
    "doors": [],
    "blocks": [
        (20.0, 18.0, 26.0, 24.0),  # square block
        (-30.0, 24.0, -24.0, 27.0),  # flat block
        (-40.0, -40.0, -38.0, -25.0),  # L-shape south-west: upright ...
        (-40.0, -40.0, -25.0, -38.0),  # ... and foot
        (35.0, -45.0, 37.0, -30.0),  # L-shape south-east: upright ...
        (25.0, -45.0, 37.0, -43.0),  # ... and foot
        (45.0, 10.0, 52.0, 14.0),  # block east
        (-17.0, 38.0, -15.0, 40.0),  # three small crates, north-west ...
        (-13.0, 36.0, -11.0, 38.0),
        (-18.0, 33.0, -16.0, 35.0),
    ],
    "polygons": [
        [(-26.0, -26.0), (-16.0, -26.0), (-26.0, -16.0)],  # triangle south-west of centre
        _circle(-35.0, 0.0, 2.5),  # round pillar west
        [(50.0, -14.0), (54.0, -10.0), (50.0, -6.0), (46.0, -10.0)],  # diamond east
        [(20.0, 50.0), (32.0, 54.0), (30.0, 58.0), (18.0, 55.0)],  # skewed slab far north
    ],
}

# =====================================================================================================
# testroom.png -- a 10 m x 8 m test room, 0.05 m/px, origin (-5, -4): world extent [-5, 5] x [-4, 4].
# Every edge lies on a pixel boundary, so the geometry below is exact (tests use it analytically):
#   outer walls 0.2 m thick -> free interior x in [-4.8, 4.8], y in [-3.8, 3.8]
#   one free-standing 1 m x 1 m box: x in [2.0, 3.0], y in [-0.5, 0.5] (centre (2.5, 0.0))
# =====================================================================================================
TESTROOM = {
    "file": "testroom.png",
    "resolution": 0.05,
    "origin": (-5.0, -4.0),
    "size_px": (200, 160),
    "outer_wall": 0.2,
    "walls": [],
    "doors": [],
    "blocks": [
        (2.0, -0.5, 3.0, 0.5),  # the box
    ],
    "polygons": [],
}

# =====================================================================================================
# hall.png -- the arena with a hall in its middle, for the thesis's swarm with sonar localization:
# the crowd of 100 Pioneer 3-AT (|x|, |y| <= 5.4 m) starts inside an 18 m x 18 m room of 0.3 m walls
# with a 2 m door in the middle of each side, so a 5 m sonar ring finds walls within a few metres
# of the crowd (in the open arena it sees only other robots, and AMCL has nothing to localize on).
# =====================================================================================================
_HALL, _DOOR, _T = 9.0, 1.0, 0.15
HALL = dict(
    ARENA,
    file="hall.png",
    walls=ARENA["walls"]
    + [(-_HALL, s * _HALL - _T, -_DOOR, s * _HALL + _T) for s in (-1, 1)]
    + [(_DOOR, s * _HALL - _T, _HALL, s * _HALL + _T) for s in (-1, 1)]
    + [(s * _HALL - _T, -_HALL, s * _HALL + _T, -_DOOR) for s in (-1, 1)]
    + [(s * _HALL - _T, _DOOR, s * _HALL + _T, _HALL) for s in (-1, 1)],
)

# =====================================================================================================
# hunt_energy.png -- Hunt and Prey with energy stations (thesis 4.2.1, "An Advanced Hunt and Prey"):
# a 20 m x 12 m hall, 0.05 m/px, origin (-10, -6): world extent [-10, 10] x [-6, 6], outer wall
# 0.2 m (free interior x in [-9.8, 9.8], y in [-5.8, 5.8]). A long table west of the centre and two
# pillars give AMCL something to hold on to and the prey's wall-following a detour; the energy
# stations (``charger`` models of hunt_energy.world) stand 1 m off the middle of the west and east
# walls, where nothing blocks the way to them.
# =====================================================================================================
HUNT_ENERGY = {
    "file": "hunt_energy.png",
    "resolution": 0.05,
    "origin": (-10.0, -6.0),
    "size_px": (400, 240),
    "outer_wall": 0.2,
    "walls": [],
    "doors": [],
    "blocks": [
        (-4.0, -0.5, -1.0, 0.5),  # the long table
        (3.0, 2.5, 3.8, 3.3),  # north-east pillar
        (3.0, -3.3, 3.8, -2.5),  # south-east pillar
    ],
    "polygons": [],
}

MAPS = {"floor": FLOOR, "arena": ARENA, "hall": HALL, "testroom": TESTROOM, "hunt_energy": HUNT_ENERGY}


# =====================================================================================================
# drawing
# =====================================================================================================
def _edge(v: float) -> int:
    """Index of the pixel boundary nearest to ``v`` pixels (ties round up, robust to float noise)."""
    return int(math.floor(v + 0.5 + 1e-6))


def _fill_rect(img: np.ndarray, m: dict, rect: tuple[float, float, float, float], value: int) -> None:
    res = m["resolution"]
    ox, oy = m["origin"]
    w, h = m["size_px"]
    x0, y0, x1, y1 = rect
    c0, c1 = sorted((_edge((x0 - ox) / res), _edge((x1 - ox) / res)))
    b0, b1 = sorted((_edge((y0 - oy) / res), _edge((y1 - oy) / res)))  # rows counted from the bottom
    c0, c1 = max(c0, 0), min(c1, w)
    b0, b1 = max(b0, 0), min(b1, h)
    if c0 < c1 and b0 < b1:
        img[h - b1 : h - b0, c0:c1] = value  # image row 0 is the top of the map


def _fill_polygon(img: np.ndarray, m: dict, points: list[tuple[float, float]], value: int) -> None:
    res = m["resolution"]
    ox, oy = m["origin"]
    w, h = m["size_px"]
    # Pillow's pixel (c, r) has its centre at (c, r); world point -> continuous pixel coordinates
    pts = [((x - ox) / res - 0.5, h - (y - oy) / res - 0.5) for x, y in points]
    mask = Image.new("L", (w, h), 0)
    ImageDraw.Draw(mask).polygon(pts, fill=1, outline=1)
    img[np.asarray(mask, dtype=bool)] = value


def render(m: dict) -> np.ndarray:
    w, h = m["size_px"]
    img = np.full((h, w), FREE, dtype=np.uint8)
    t = _edge(m["outer_wall"] / m["resolution"])
    img[:t, :] = img[-t:, :] = img[:, :t] = img[:, -t:] = OCCUPIED
    for r in m["walls"]:
        _fill_rect(img, m, r, OCCUPIED)
    for r in m["doors"]:
        _fill_rect(img, m, r, FREE)
    # a door cut may not open the outer wall
    img[:t, :] = img[-t:, :] = img[:, :t] = img[:, -t:] = OCCUPIED
    for r in m["blocks"]:
        _fill_rect(img, m, r, OCCUPIED)
    for p in m["polygons"]:
        _fill_polygon(img, m, p, OCCUPIED)
    return img


def _yaml(maps: dict) -> str:
    lines = [
        "# Map metadata, written by maps/generate.py (do not edit by hand; edit the script).",
        "# origin: world (x, y) of the bitmap's bottom-left corner, as Player's mapfile driver.",
        "# Pixels: 255 = free, 0 = occupied (negate 0; anything darker than mid-grey is occupied).",
        "# Stage placement: floorplan( bitmap <image> size [size_m] pose [centre 0 0] ).",
        "maps:",
    ]
    for name, m in maps.items():
        res = m["resolution"]
        w, h = m["size_px"]
        ox, oy = m["origin"]
        sx, sy = round(w * res, 6), round(h * res, 6)
        lines += [
            f"  {name}:",
            f"    image: {m['file']}",
            f"    resolution: {res}",
            f"    origin: [{ox}, {oy}]",
            f"    size_px: [{w}, {h}]",
            f"    size_m: [{sx}, {sy}]",
            f"    extent: {{x: [{ox}, {round(ox + sx, 6)}], y: [{oy}, {round(oy + sy, 6)}]}}",
            f"    centre: [{round(ox + sx / 2, 6)}, {round(oy + sy / 2, 6)}]",
            f"    outer_wall_m: {m['outer_wall']}",
            "    negate: 0",
            "    occupied_thresh: 0.5",
        ]
    return "\n".join(lines) + "\n"


def _map_server_yaml(m: dict) -> str:
    """``NAME.yaml``: the bitmap as a ROS map_server map, loadable wherever a built map is."""
    ox, oy = m["origin"]
    return (
        "# Written by maps/generate.py (do not edit by hand). ROS map_server format: docs/mapping.md.\n"
        f"image: {m['file']}\n"
        f"resolution: {m['resolution']}\n"
        f"origin: [{ox}, {oy}, 0.0]\n"
        "occupied_thresh: 0.65\n"
        "free_thresh: 0.196\n"
        "negate: 0\n"
        "mode: trinary\n"
    )


def main() -> None:
    for m in MAPS.values():
        img = render(m)
        out = HERE / m["file"]
        Image.fromarray(img).save(out, format="PNG", optimize=True)
        occ = float((img == OCCUPIED).mean())
        print(f"{out.relative_to(HERE.parent)}: {img.shape[1]} x {img.shape[0]} px, {occ:.1%} occupied")
        (HERE / m["file"]).with_suffix(".yaml").write_text(_map_server_yaml(m))
    (HERE / "maps.yaml").write_text(_yaml(MAPS))
    print("maps/maps.yaml")


if __name__ == "__main__":
    main()
