"""Built-in drivers; importing this package registers them with :data:`mrs_bridge.driver.DRIVERS`."""

from ..ros2 import driver as _ros2_driver  # noqa: F401 - the ROS 2 drivers live with the ROS 2 bridge
from ..ros2 import export_driver as _ros2_export_driver  # noqa: F401
from . import amcl, hokuyo, localplanner, mapfile, p2os, rangertolaser, replay, sim, virtual_ranger, wavefront  # noqa: F401
