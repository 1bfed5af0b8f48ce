"""Navigation algorithms as plain numpy libraries (thesis 3.3, 3.4.1, appendix A.3).

No Zenoh here: the ``amcl``, ``wavefront``, ``vfh``, ``nd`` and ``snd`` drivers in
:mod:`mrs_bridge.drivers` bind these to the device server. Everything works on a :class:`NavGrid`,
the occupancy grid of a ``map`` device.
"""

from .grid import NavGrid

__all__ = ["NavGrid"]
