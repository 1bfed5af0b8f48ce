"""Built-in drivers; importing this package registers them with :data:`mrs_bridge.driver.DRIVERS`."""

from . import amcl, hokuyo, localplanner, mapfile, p2os, rangertolaser, replay, sim, virtual_ranger, wavefront  # noqa: F401
