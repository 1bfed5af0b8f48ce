"""Loader for the YAML world format: an easier front end than Stage's ``.world`` syntax.

Produces the same :class:`~simulator.spec.WorldSpec` as :mod:`simulator.stageworld` (the Stage
world file format of thesis appendix A.1, A.5, A.6), with robots, devices and objects taken from
the presets of :mod:`simulator.presets`. Units are SI, except yaw and field-of-view angles, which
are degrees as in Stage files::

    world: {interval_sim: 0.1, speedup: 1.0, seed: 1}   # s per step; speedup: a number or "max"
    floorplan: {bitmap: testroom.png, resolution: 0.05, origin: [-5.0, -4.0]}
    #      or: {bitmap: testroom.png, size: [10.0, 8.0], pose: [0.0, 0.0]}   (Stage placement)
    robots:
      - name: r0
        type: pioneer2dx            # pioneer2dx | pioneer3at (default pioneer2dx)
        pose: [-3.0, 0.0, 90]       # x m, y m, yaw degrees
        color: red
        sonar: true                 # keep the preset's sonar ring (default true)
        devices:
          - {type: laser, model: urg04lx, pose: [0.13, 0, 0]}   # or fov/samples/range/noise
          - {type: sonar, model: pioneer2dx_sonar}              # or sensors: [{pose, fov, range}]
          - {type: blobfinder, colors: [green], fov: 90, range: 3, image: [80, 60]}
          - {type: gripper}
          - {type: bumper, model: pioneer}      # or segments: [{pose: [x, y, yaw], length: 0.1}]
          - {type: fiducial, range: [0, 8], range_id: 5, fov: 180, key: 0}
        fiducial_return: 1          # id fiducial finders read (0: not seen); fiducial_key: 0
    objects:
      - {name: blob0, type: blob, pose: [1.0, 2.0, 0], color: green}   # blob | box

Robots may also override ``size``, ``mass``, ``max_speed [m/s, deg/s]``, ``max_accel``,
``odom_error``, ``odom_noise``, the ``*_return`` flags and ``fiducial_return``/``fiducial_key``;
objects ``size``, ``mass``, the flags, ``fiducial_return`` and ``fiducial_key``.
The bitmap path is relative to the YAML file. Unknown keys are skipped with a warning (with a
"did you mean"); wrong types, missing required keys (robot and object ``name``, object ``type``,
floorplan ``bitmap``) and duplicate model names raise :class:`~simulator.errors.WorldFileError`
naming file:line and a fix.

Three stages, one module each, as :mod:`simulator.stage` is split: :mod:`~.reader` (YAML with
lines), :mod:`~.values` (typed values with file:line errors), :mod:`~.devices` and :mod:`~.mapping`
(the ``devices[]`` items and the file's sections to specs). This package keeps the public name
other code imports: :func:`load_yaml_world`.
"""

from __future__ import annotations

import os

from ..errors import as_world_file_errors
from ..spec import WorldSpec
from .mapping import Mapper
from .reader import read

__all__ = ["load_yaml_world"]


def load_yaml_world(path: str | os.PathLike[str], *, seed: int | None = None) -> WorldSpec:
    """Read a YAML world file into a WorldSpec (``seed`` overrides ``world.seed``).

    Raises :class:`WorldFileError` naming file:line and a fix for a malformed file; warnings
    (unknown keys, duplicate keys) are in ``WorldSpec.warnings``.
    """
    display = os.fspath(path)
    doc, duplicates = read(display)
    world = Mapper(display)
    for key, line in duplicates:
        world.warn(line, f"duplicate key '{key}': the last one wins")
    with as_world_file_errors(display, "YAML nested too deeply"):
        return world.build(doc, seed)
