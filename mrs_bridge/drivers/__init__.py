"""Built-in drivers; importing this package registers them with :data:`mrs_bridge.driver.DRIVERS`."""

from . import mapfile, rangertolaser, replay, sim  # noqa: F401
