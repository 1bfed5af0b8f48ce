"""Device server configuration: TOML driver blocks in the shape of Player's ``.cfg`` files.

Thesis appendix A.2-A.4 configure Player with ``driver ( name ... provides [...] requires [...]
params )`` blocks. The same thing in TOML::

    [server]
    node = "r0"                       # node of devices written without one ("laser:0")

    [[driver]]
    name = "rangertolaser"
    requires = ["r0:ranger:1"]        # may be on another server: waited for on the fabric
    provides = ["laser:0"]

    [[driver]]
    name = "mapfile"
    provides = ["map:0"]
    filename = "../maps/floor.png"    # relative to this file
    resolution = 0.05
    origin = [-31.475, -7.8]

Every key other than ``name``, ``provides``, ``requires``, ``node`` and ``rate`` is a driver
parameter, with Player's parameter names. Errors name the file, the driver block and a fix.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rsal.errors import RsalError
from rsal.keys import DeviceAddr, check_name, parse_device
from rsal.suggest import did_you_mean

__all__ = ["ConfigError", "DriverConfig", "ServerConfig", "load_config", "parse_config"]


class ConfigError(RsalError, ValueError):
    """A configuration that cannot be used; the text names file, block and fix."""


@dataclass
class DriverConfig:
    name: str
    provides: list[DeviceAddr]
    requires: list[DeviceAddr] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    rate: float | None = None
    where: str = ""  # "file: driver #n (name)" for messages
    base_dir: Path = field(default_factory=Path.cwd)

    def param(self, key: str, default: Any = None) -> Any:
        return self.params.get(key, default)

    def path_param(self, key: str) -> Path | None:
        v = self.params.get(key)
        if v is None:
            return None
        p = Path(str(v))
        return p if p.is_absolute() else (self.base_dir / p)

    def required(self, key: str) -> DeviceAddr:
        """The required device with Player role ``key`` (``odometry``, ``laser``...)."""
        for r in self.requires:
            if r.key == key:
                return r
        raise ConfigError(f"{self.where}: needs a required device with key {key!r} (e.g. '{key}::r0:...:0')")


@dataclass
class ServerConfig:
    node: str = "robot"
    drivers: list[DriverConfig] = field(default_factory=list)
    source: str = ""


def load_config(path: str | Path, *, default_node: str | None = None) -> ServerConfig:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such configuration file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{p}: cannot be read ({e})") from None
    return parse_config(text, source=str(p), base_dir=p.resolve().parent, default_node=default_node)


def parse_config(
    text: str,
    *,
    source: str = "<config>",
    base_dir: Path | None = None,
    default_node: str | None = None,
    known_drivers: list[str] | None = None,
) -> ServerConfig:
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{source}: not valid TOML: {e}") from None
    unknown = set(doc) - {"server", "driver"}
    if unknown:
        raise ConfigError(f"{source}: unknown section(s) {sorted(unknown)}; use [server] and [[driver]] blocks")
    server = doc.get("server", {})
    if not isinstance(server, dict):
        raise ConfigError(f"{source}: [server] must be a table")
    node = default_node or server.get("node", "robot")
    try:
        check_name("node", node)
    except ValueError as e:
        raise ConfigError(f"{source}: [server] {e}") from None
    blocks = doc.get("driver", [])
    if not isinstance(blocks, list) or not all(isinstance(b, dict) for b in blocks):
        raise ConfigError(f"{source}: drivers must be [[driver]] blocks")
    if not blocks:
        raise ConfigError(f"{source}: no [[driver]] blocks; add at least one driver")
    cfg = ServerConfig(node=node, source=source)
    for i, b in enumerate(blocks, start=1):
        name = b.get("name")
        where = f"{source}: driver #{i}" + (f" ({name})" if isinstance(name, str) and name else "")
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{where}: missing 'name' (the driver type, e.g. name = \"sim\")")
        if known_drivers is not None and name not in known_drivers:
            close = did_you_mean(name, known_drivers)
            hint = f"; did you mean {close!r}?" if close else f"; known drivers: {', '.join(sorted(known_drivers))}"
            raise ConfigError(f"{where}: unknown driver {name!r}{hint}")
        dnode = b.get("node", node)
        provides = _devices(b.get("provides", []), dnode, where, "provides")
        requires = _devices(b.get("requires", []), dnode, where, "requires")
        if not provides and name not in ("simulation", "ros2_export"):
            raise ConfigError(f"{where}: 'provides' is empty; list the devices it offers, e.g. [\"laser:0\"]")
        rate = b.get("rate")
        if rate is not None and (isinstance(rate, bool) or not isinstance(rate, (int, float)) or rate <= 0):
            raise ConfigError(f"{where}: 'rate' must be a positive number of Hz, not {rate!r}")
        params = {k: v for k, v in b.items() if k not in ("name", "provides", "requires", "node", "rate")}
        cfg.drivers.append(
            DriverConfig(name, provides, requires, params, float(rate) if rate else None, where, base_dir or Path.cwd())
        )
    seen: dict[DeviceAddr, str] = {}
    for d in cfg.drivers:
        for a in d.provides:
            k = a.without_key()
            if k in seen:
                raise ConfigError(f"{d.where}: device {k} is already provided by {seen[k]}; give it another index")
            seen[k] = d.where
    return cfg


def _devices(value: Any, node: str, where: str, what: str) -> list[DeviceAddr]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list):
        raise ConfigError(f"{where}: '{what}' must be a list of devices like [\"r0:laser:0\"]")
    out = []
    for v in value:
        try:
            out.append(parse_device(v, node))
        except ValueError as e:
            raise ConfigError(f"{where}: {what}: {e}") from None
    return out
