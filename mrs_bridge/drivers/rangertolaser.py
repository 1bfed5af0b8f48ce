"""``rangertolaser`` driver: republish a ranger as a laser (Player's rangertolaser, appendix A.2).

Requires one ranger (``requires = ["r0:ranger:1"]``), provides one laser (``provides =
["r0:laser:0"]``). Every scan of the ranger is republished unchanged in the laser's key: the
message already carries the beam geometry Player's laser interface has (first angle, angular
step, minimum and maximum range).
"""

from __future__ import annotations

from dataclasses import dataclass

from rsal.msgs import MessageError, RangerData

from ..config import ConfigError
from ..driver import Driver, register
from ..params import parse_params

__all__ = ["RangerToLaser"]


@dataclass(frozen=True)
class RangerToLaserParams:
    """``rangertolaser`` has no parameters."""


@register("rangertolaser")
class RangerToLaser(Driver):
    interfaces = ("laser",)
    default_rate = 0.0
    data_types = {"laser": "RangerData"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        rangers = [r for r in cfg.requires if r.interface == "ranger"]
        if len(rangers) != 1 or len(cfg.provides) != 1:
            raise ConfigError(f"{cfg.where}: needs exactly one required ranger and one provided laser")
        parse_params(RangerToLaserParams, cfg)  # no parameters: a stray key is a mistake, named
        self.source = rangers[0].without_key()
        self.last: RangerData | None = None
        self.count = 0

    def on_input(self, addr, channel, msg):
        if channel != "data" or addr.without_key() != self.source:
            return
        try:
            scan = RangerData.from_dict(msg)
        except MessageError as e:
            self.server._warn(f"rangertolaser:{addr}", f"{self.cfg.where}: malformed scan from {addr}: {e}")
            return
        self.last = scan
        self.count += 1
        self.publish(self.cfg.provides[0], scan)

    def publish_rate(self, addr) -> float:
        return 10.0

    def geometry(self, addr):
        s = self.last
        if s is None:
            return {"source": str(self.source)}
        return {
            "source": str(self.source),
            "angle_min": s.angle_min,
            "angle_step": s.angle_step,
            "samples": int(s.ranges.shape[0]),
            "range_min": s.range_min,
            "range_max": s.range_max,
        }
