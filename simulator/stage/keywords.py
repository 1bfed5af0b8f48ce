"""The Stage world-file vocabulary this loader knows: built-in model types and their keywords.

Stage 4's model types and the keywords each reads (Stage manual, ``libstage/model.cc``,
``model_position.cc``, ``model_ranger.cc``, ``model_bumper.cc``, ``model_fiducial.cc``,
``world.cc``) are listed here once; the mapping
(:mod:`simulator.stage.mapping`) reads them to check a model's keywords ("did you mean") and to
report what is recognised but not simulated. Adding a simulated model type or keyword starts here.
"""

from __future__ import annotations

__all__ = [
    "BUILTIN_TYPES", "MODEL_TYPES", "NOT_SIMULATED", "SKIPPED", "DEVICE_TYPES", "KEYS_BY_TYPE", "MODEL_KEYS",
    "NOT_SIMULATED_KEYS", "BLOCK_KEYS", "POSITION_KEYS", "RANGER_KEYS", "LASER_KEYS", "SENSOR_KEYS",
    "BLOBFINDER_KEYS", "GRIPPER_KEYS", "BUMPER_KEYS", "FIDUCIAL_KEYS", "WORLD_KEYS", "BATTERY_KEYS",
    "CHARGER_KEYS",
]  # fmt: skip

MODEL_TYPES = frozenset(
    {"model", "position", "ranger", "sensor", "laser", "blobfinder", "gripper", "bumper", "fiducial", "charger"}
)
NOT_SIMULATED = frozenset({"camera", "actuator", "ptz"})
SKIPPED = frozenset({"window", "block"})  # the GUI window; block outlines are read by the mapping
BUILTIN_TYPES = MODEL_TYPES | NOT_SIMULATED | SKIPPED

MODEL_KEYS = frozenset(
    {
        "name", "pose", "size", "origin", "color", "color_rgba", "mass", "bitmap", "map_resolution",
        "obstacle_return", "laser_return", "ranger_return", "blob_return", "gripper_return",
        "fiducial_return", "fiducial_key", "boundary", "watts", "stack_children", "ctrl",
        "update_interval", "polygons", "polygon.points", "polygon.point", "polygon.filled",
        "velocity", "say", "friction", "alwayson", "joules", "joules_capacity", "kjoules",
        "give_watts", "take_watts", "line_count", "line.points", "line.point", "debug",
    }
)  # fmt: skip
# Our battery extension of a position model (Stage's joules/kjoules/joules_capacity/watts/take_watts
# are read too; simulator.energy).
BATTERY_KEYS = frozenset({"battery_capacity", "battery_charge", "battery_drain"})
POSITION_KEYS = MODEL_KEYS | BATTERY_KEYS | {
    "drive", "velocity_bounds", "acceleration_bounds", "odom_error", "odom_noise", "localization",
    "localization_origin", "wheelbase", "velocity_enable",
}  # fmt: skip
RANGER_KEYS = MODEL_KEYS | {"scount", "spose", "ssize", "sview"}
LASER_KEYS = MODEL_KEYS | {
    "range_min", "range_max", "fov", "samples", "noise", "laser_sample_skip", "resolution",
}  # fmt: skip
SENSOR_KEYS = frozenset(
    {"pose", "size", "range", "fov", "samples", "noise", "color", "color_rgba", "watts", "ranger_return"}
)
BLOBFINDER_KEYS = MODEL_KEYS | {
    "colors_count", "colors", "channel_count", "channels", "fov", "range", "range_max", "image", "pan", "ptz",
}  # fmt: skip
GRIPPER_KEYS = MODEL_KEYS | {
    "paddle_time", "lift_time", "paddle_size", "paddle_state", "lift_state", "autosnatch",
}  # fmt: skip
BUMPER_KEYS = MODEL_KEYS | {"bcount", "bpose", "blength"}
FIDUCIAL_KEYS = MODEL_KEYS | {"range_min", "range_max", "range_max_id", "fov"}
# Our charging station (simulator.spec.ChargerSpec): a top-level model that is not a body.
CHARGER_KEYS = frozenset({"name", "pose", "size", "color", "color_rgba", "charge_rate", "dock_distance", "dock_angle"})
WORLD_KEYS = frozenset(
    {
        "name", "resolution", "interval_sim", "interval_real", "speedup", "quit_time", "threads",
        "paused", "show_clock", "show_clock_interval", "seed", "size", "log",
    }
)  # fmt: skip
KEYS_BY_TYPE = {
    "model": MODEL_KEYS,
    "position": POSITION_KEYS,
    "ranger": RANGER_KEYS,
    "laser": LASER_KEYS,
    "sensor": SENSOR_KEYS,
    "blobfinder": BLOBFINDER_KEYS,
    "gripper": GRIPPER_KEYS,
    "bumper": BUMPER_KEYS,
    "fiducial": FIDUCIAL_KEYS,
    "charger": CHARGER_KEYS,
}
DEVICE_TYPES = frozenset({"ranger", "laser", "blobfinder", "gripper", "bumper", "fiducial"})
BLOCK_KEYS = frozenset({"points", "point", "z", "color", "color_rgba"})

# Keywords that are known (no "unknown keyword" warning) but not simulated: each occurrence is
# listed, with its file:line, in the one "not simulated (ignored)" warning of a load. By scope:
# "world", a model's built-in type, or "floorplan". A model's fiducial_return / fiducial_key are
# simulated on top-level models (robots and objects) and on fiducial finders (the key); on other
# devices and the floorplan they are listed here.
_DEVICE_FIDUCIAL = frozenset({"fiducial_return", "fiducial_key"})
_MODEL_NOT_SIMULATED = frozenset(
    {
        "watts", "stack_children", "update_interval", "polygons",
        "polygon.points", "polygon.point", "polygon.filled", "velocity", "friction", "alwayson", "joules",
        "joules_capacity", "kjoules", "give_watts", "take_watts", "line_count", "line.points", "line.point",
        "boundary", "ctrl",
    }
)  # fmt: skip
NOT_SIMULATED_KEYS: dict[str, frozenset[str]] = {
    "world": frozenset({"paused", "size", "log"}),
    "model": _MODEL_NOT_SIMULATED,
    "floorplan": (_MODEL_NOT_SIMULATED - {"boundary"}) | _DEVICE_FIDUCIAL,
    "position": (_MODEL_NOT_SIMULATED - {"ctrl", "update_interval", "joules", "kjoules", "joules_capacity", "watts",
                                         "take_watts"})
    | {"localization_origin", "wheelbase", "velocity_enable"},
    "ranger": frozenset({"fiducial_return", "fiducial_key", "watts"}),
    "laser": frozenset({"fiducial_return", "fiducial_key", "watts", "laser_sample_skip", "resolution"}),
    "sensor": frozenset({"watts"}),
    "blobfinder": frozenset({"fiducial_return", "fiducial_key", "watts", "pan"}),
    "gripper": frozenset({"fiducial_return", "fiducial_key", "watts", "paddle_size", "paddle_state", "lift_state",
                          "autosnatch"}),
    "bumper": _DEVICE_FIDUCIAL | {"watts"},
    "fiducial": frozenset({"fiducial_return", "watts"}),
}  # fmt: skip
"""Known keywords without a simulated meaning yet, by scope. Keywords that only change the GUI
(``gui_*``, ``say``, ``debug``, ``show_clock``, a device's ``size``/``color``) are accepted silently.
``threads`` sets the ray caster's threads (:attr:`~simulator.spec.WorldSpec.threads`)."""
