"""``mapfile`` driver: a grid map from a bitmap, like Player's mapfile (thesis appendix A.2).

Parameters (Player's names): ``filename`` (relative to the config file), ``resolution`` (m/pixel),
``origin`` ``[x, y]`` (world position of the bitmap's bottom-left corner; default: centred on 0,0),
``negate`` (dark = free), ``occupied_thresh`` (fraction of full brightness below which a pixel is
occupied, default 0.5). A ``filename`` ending in ``.yaml``/``.yml`` is a ROS map_server map
(:mod:`rsal.mapping.mapyaml`, what ``rsal map`` writes): the YAML sets resolution, origin,
thresholds and negate, so those parameters must not be given, and its unknown cells are served as
unknown (0). Provides ``map:N``: ``rpc/get`` returns the whole grid (int8, Player's
-1 free / 0 unknown / +1 occupied, rows from the bottom); ``data`` carries the map's metadata
every few seconds so late subscribers learn of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rsal.mapping.mapyaml import MapFileError, is_map_yaml, read_map
from rsal.msgs import MapData

from ..config import ConfigError
from ..driver import Driver, register
from ..params import param, parse_params

__all__ = ["MapfileDriver"]


@dataclass(frozen=True)
class MapfileParams:
    """The ``mapfile`` driver's parameters (module docstring)."""

    filename: Path = param(doc="the map bitmap or map_server YAML", example="../maps/floor.png")
    resolution: float = param(0.05, gt=0.0, expect="positive metres per pixel")
    origin: tuple[float, ...] | None = param(None, expect="[x, y] in metres")
    negate: bool = param(False)
    occupied_thresh: float = param(0.5, min=0.0, max=1.0)

    def __post_init__(self) -> None:
        if self.origin is not None and len(self.origin) < 2:
            raise ValueError(f"origin = {list(self.origin)!r} must be [x, y] in metres")


YAML_SETS = ("resolution", "origin", "negate", "occupied_thresh")
"""Parameters a map_server YAML sets itself."""


def _map_from_yaml(path: Path, cfg) -> MapData:
    """The map of a map_server YAML, in Player's convention; ConfigError (one line) if it is wrong."""
    if given := [k for k in YAML_SETS if k in cfg.params]:
        raise ConfigError(
            f"{cfg.where}: {', '.join(given)}: the map_server YAML {path.name!r} sets "
            f"{'this' if len(given) == 1 else 'these'} itself; remove {' and '.join(given)} from the block"
        )
    try:
        m = read_map(path)
    except MapFileError as e:
        raise ConfigError(f"{cfg.where}: {e}") from None
    if abs(m.origin[2]) > 1e-9:
        raise ConfigError(
            f"{cfg.where}: {path.name}: origin yaw {m.origin[2]!r} rad is not supported (maps are "
            "axis-aligned); re-sample the map, e.g. with 'rsal map align ... -o'"
        )
    return MapData(m.width, m.height, m.resolution, (m.origin[0], m.origin[1]), m.cells())


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
        if is_map_yaml(p.filename):
            self.map = _map_from_yaml(p.filename, cfg)
            return
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
