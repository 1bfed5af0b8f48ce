"""The Swarm scenario's world (thesis 4.2.3): a crowd of Pioneers on a grid in the 128 m arena.

:func:`crowd_world` writes the Stage world text of such a crowd (``maps/swarm.world`` is its output
for 100 robots, checked by a test); :func:`write_crowd_world` writes it to a file for the tests and
benchmarks that run other crowd sizes.
"""

from __future__ import annotations

import math
import random
from pathlib import Path

__all__ = ["crowd_world", "write_crowd_world"]

_MODELS = {"pioneer2dx": "Pioneer 2DX with its 8-sonar ring", "pioneer3at": "Pioneer 3-AT with its 16-sonar ring"}


def crowd_world(
    n: int,
    *,
    spacing: float = 1.2,
    seed: int = 0,
    bitmap: str = "arena.png",
    model: str = "pioneer2dx",
    name: str = "r",
    localization: str = "odom",
) -> str:
    """The Stage world text of ``n`` robots (``<name>0`` ..) on a square grid ``spacing`` m apart,
    centred on the 128 m arena's free middle, each facing a random direction (``seed``).
    ``bitmap`` is the arena's floorplan, relative to where the world file is written.
    ``localization "gps"`` makes each robot's position2d report its true pose (Stage's keyword; a
    stand-in for a localizer, for the neighbourhood form whose cells come from the robots' poses)."""
    if localization not in ("odom", "gps"):
        raise ValueError(f"localization {localization!r} must be 'odom' or 'gps'")
    if n < 1:
        raise ValueError(f"a crowd needs at least one robot, got {n}")
    side = math.ceil(math.sqrt(n))
    half = (side - 1) * spacing / 2.0
    if half > 19.0:
        raise ValueError(f"{n} robots {spacing:g} m apart do not fit the arena's free square (|x|, |y| < 20 m)")
    rng = random.Random(seed)
    colors = ("red", "blue", "yellow", "green", "orange", "cyan", "magenta", "gray")
    lines = [
        f"# RSAL fabric -- a crowd of {n} Pioneers for the Swarm scenario (thesis 4.2.3), written by",
        "# agents.scenarios.swarm.crowd_world: the 128 m arena, robots on a square grid around its centre,",
        f"# {spacing:g} m apart, random headings (seed {seed}). Each is a {_MODELS.get(model, model)}",
        "# (the light sensor model: no laser). Stage 4 syntax; original to this project.",
        *(
            ['# localization "gps": each position2d reports its true pose (the neighbourhood form\'s cells).']
            if localization == "gps"
            else []
        ),
        "",
        'include "pioneer.inc"',
        'include "map.inc"',
        "",
        "resolution 0.02",
        "interval_sim 100",
        "speedup 1.000",
        "paused 0",
        "",
        "floorplan",
        "(",
        '  name "arena"',
        f'  bitmap "{bitmap}"',
        "  size [ 128.0 128.0 0.8 ]",
        "  pose [ 0 0 0 0 ]",
        ")",
        "",
    ]
    for i in range(n):
        row, col = divmod(i, side)
        x, y = -half + col * spacing, -half + row * spacing
        yaw = rng.uniform(-180.0, 180.0)
        loc = ' localization "gps"' if localization == "gps" else ""
        lines.append(
            f'{model}( name "{name}{i}" pose [ {x:.2f} {y:.2f} 0 {yaw:.0f} ] color "{colors[row % len(colors)]}"{loc} )'
        )
    return "\n".join(lines) + "\n"


def write_crowd_world(path: str | Path, n: int, *, bitmap: str = "arena.png", **kw) -> Path:
    """Write :func:`crowd_world` to ``path`` with the bitmap (a file of ``maps/``, the arena by
    default) referenced by absolute path."""
    p = Path(path)
    arena = Path(__file__).resolve().parents[3] / "maps" / bitmap
    p.write_text(crowd_world(n, bitmap=str(arena), **kw))
    return p
