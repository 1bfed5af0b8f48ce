"""``mapfile`` driver: a grid map from a bitmap, like Player's mapfile (thesis appendix A.2).

Parameters (Player's names): ``filename`` (relative to the config file), ``resolution`` (m/pixel),
``origin`` ``[x, y]`` (world position of the bitmap's bottom-left corner; default: centred on 0,0),
``negate`` (dark = free), ``occupied_thresh`` (fraction of full brightness below which a pixel is
occupied, default 0.5). Provides ``map:N``: ``rpc/get`` returns the whole grid (int8, Player's
-1 free / 0 unknown / +1 occupied, rows from the bottom); ``data`` carries the map's metadata
every few seconds so late subscribers learn of it.
"""

from __future__ import annotations

import numpy as np

from rsal.msgs import MapData

from ..config import ConfigError
from ..driver import Driver, register

__all__ = ["MapfileDriver"]


@register("mapfile")
class MapfileDriver(Driver):
    interfaces = ("map",)
    default_rate = 0.2
    data_types = {"map": "MapInfo"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        from simulator import SimulatorError
        from simulator.gridmap import GridMap

        path = cfg.path_param("filename")
        if path is None:
            raise ConfigError(f"{cfg.where}: needs 'filename', the map bitmap")
        try:
            res = float(cfg.param("resolution", 0.05))
        except (TypeError, ValueError):
            res = -1.0
        if not res > 0:
            raise ConfigError(f"{cfg.where}: resolution {cfg.param('resolution')!r} must be positive metres per pixel")
        thresh = float(cfg.param("occupied_thresh", 0.5))
        try:
            grid = GridMap.from_image(path, res, (0.0, 0.0), threshold=thresh)
        except SimulatorError as e:
            raise ConfigError(f"{cfg.where}: {e}") from None
        origin = cfg.param("origin")
        if origin is None:
            origin = (-grid.width * res / 2, -grid.height * res / 2)
        if not (isinstance(origin, list | tuple) and len(origin) >= 2):
            raise ConfigError(f"{cfg.where}: origin {origin!r} must be [x, y] in metres")
        occ = grid.occupied
        if cfg.param("negate", False):
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


@register("simmap")
class SimMapDriver(MapfileDriver):
    """The floorplan of the in-process simulation served as a map (``rsal sim`` adds it)."""

    def __init__(self, cfg, server):
        Driver.__init__(self, cfg, server)
        world = server.shared.get("simulator.world")
        if world is None or world.grid is None:
            raise ConfigError(f"{cfg.where}: there is no simulated floorplan to serve")
        g = world.grid
        self.map = MapData(g.width, g.height, g.resolution, g.origin, np.where(g.occupied, 1, -1).astype(np.int8))
