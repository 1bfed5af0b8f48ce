"""``mapfile`` driver: a grid map from a bitmap, like Player's mapfile (thesis appendix A.2).

Parameters (Player's names): ``filename`` (relative to the config file), ``resolution`` (m/pixel),
``origin`` ``[x, y]`` (world position of the bitmap's bottom-left corner; default: centred on 0,0),
``negate`` (dark = free), ``occupied_thresh`` (fraction of full brightness below which a pixel is
occupied, default 0.5). Provides ``map:N``: ``rpc/get`` returns the whole grid (int8, Player's
-1 free / 0 unknown / +1 occupied, rows from the bottom); ``data`` carries the map's metadata
every few seconds so late subscribers learn of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rsal.msgs import MapData

from ..config import ConfigError
from ..driver import Driver, register
from ..params import param, parse_params

__all__ = ["MapfileDriver"]


@dataclass(frozen=True)
class MapfileParams:
    """The ``mapfile`` driver's parameters (module docstring)."""

    filename: Path = param(doc="the map bitmap", example="../maps/floor.png")
    resolution: float = param(0.05, gt=0.0, expect="positive metres per pixel")
    origin: tuple[float, ...] | None = param(None, expect="[x, y] in metres")
    negate: bool = param(False)
    occupied_thresh: float = param(0.5, min=0.0, max=1.0)

    def __post_init__(self) -> None:
        if self.origin is not None and len(self.origin) < 2:
            raise ValueError(f"origin = {list(self.origin)!r} must be [x, y] in metres")


@register("mapfile")
class MapfileDriver(Driver):
    interfaces = ("map",)
    default_rate = 0.2
    data_types = {"map": "MapInfo"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        from simulator import SimulatorError
        from simulator.gridmap import GridMap

        p = self.settings = parse_params(MapfileParams, cfg)
        res = p.resolution
        try:
            grid = GridMap.from_image(p.filename, res, (0.0, 0.0), threshold=p.occupied_thresh)
        except SimulatorError as e:
            raise ConfigError(f"{cfg.where}: {e}") from None
        origin = p.origin
        if origin is None:
            origin = (-grid.width * res / 2, -grid.height * res / 2)
        occ = grid.occupied
        if p.negate:
            occ = ~occ
        self.map = MapData(
            grid.width, grid.height, res, (float(origin[0]), float(origin[1])), np.where(occ, 1, -1).astype(np.int8)
        )

    def info(self) -> dict:
        m = self.map
        return {"width": m.width, "height": m.height, "resolution": m.resolution, "origin": list(m.origin)}

    def update(self, now: float) -> None:
        for a in self.cfg.provides:
            self.publish(a, self.info())

    def ops(self, addr):
        return ["get"]

    def on_rpc(self, addr, op, args):
        if op == "get":
            return self.map.to_dict()
        return super().on_rpc(addr, op, args)

    def geometry(self, addr):
        return self.info()


@dataclass(frozen=True)
class SimMapParams:
    """``simmap`` has no parameters (the map is the simulation's floorplan)."""


@register("simmap")
class SimMapDriver(MapfileDriver):
    """The floorplan of the in-process simulation served as a map (``rsal sim`` adds it)."""

    def __init__(self, cfg, server):
        Driver.__init__(self, cfg, server)
        parse_params(SimMapParams, cfg)  # no parameters: a stray key is a mistake, named
        world = server.shared.get("simulator.world")
        if world is None or world.grid is None:
            raise ConfigError(f"{cfg.where}: there is no simulated floorplan to serve")
        g = world.grid
        self.map = MapData(g.width, g.height, g.resolution, g.origin, np.where(g.occupied, 1, -1).astype(np.int8))
