"""``rsal rehearse WORLD ROBOT``: a "real" Pioneer with a Hokuyo laser, without the hardware.

One process holds "the real world": a simulator world stepped in real time (the ``rehearsal``
driver, :class:`~mrs_bridge.rehearse.coupling.RehearsalDriver`, on node ``world``), an emulated
Pioneer on one pseudo-terminal whose body is robot ROBOT of that world and an emulated URG-04LX
(or UTM-30LX) on another whose ranges are cast in it (:mod:`mrs_bridge.rehearse.coupling`,
:mod:`mrs_bridge.emulators`). Then it starts the real drivers on those ptys: ``rsal serve`` with a
generated configuration -- the shape of ``deploy/pioneer2dx-urg.toml``, or the user's own file
(``--config``) with its ``p2os`` and ``hokuyo`` ports pointed at the ptys -- as a child process
connected to this one's endpoint; ``--no-serve`` prints the ptys, the file and the command
instead. The ground truth stays readable on the fabric: ``world:simulation:0`` (``get_pose``) and
``ROBOT:position2d:3`` (frame ``gps``, as ``rsal sim --truth``). SIGTERM or Ctrl-C stops the child
by its PID, then the world.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import tomllib
from pathlib import Path

from rsal.cliutil import brief, positive
from rsal.errors import RsalError
from rsal.keys import DeviceAddr, parse_device
from rsal.suggest import did_you_mean
from rsal.transport import DEFAULT_ENDPOINT, add_transport_args, free_port, port_free

from ..cli import TRUTH_INDEX, run_server
from ..config import ConfigError, DriverConfig, ServerConfig, load_config

__all__ = ["register", "rehearsal_config", "driver_config", "write_toml"]

PROG = "rsal rehearse"
HOKUYO_NAMES = ("hokuyo", "hokuyo_aist", "urglaser")


def say(msg: str) -> None:
    print(f"[rehearse] {msg}", flush=True)


class RehearseError(RsalError):
    """A user error: one line, exit 1."""


# ---------------------------------------------------------------------------- configurations
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str | Path):
        s = str(v).replace("\\", "\\\\").replace('"', '\\"')
        return f'"{s}"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def write_toml(doc: dict, header: str = "") -> str:
    """A device-server configuration as TOML: ``[server]`` and ``[[driver]]`` tables of scalars
    and lists (the only shapes :mod:`mrs_bridge.config` reads)."""
    out = [header] if header else []
    for key, val in doc.items():
        if isinstance(val, dict):
            out.append(f"[{key}]")
            out += [f"{k} = {_toml_value(v)}" for k, v in val.items()]
            out.append("")
        elif isinstance(val, list) and val and all(isinstance(x, dict) for x in val):
            for table in val:
                out.append(f"[[{key}]]")
                out += [f"{k} = {_toml_value(v)}" for k, v in table.items()]
                out.append("")
        else:
            out.insert(1 if header else 0, f"{key} = {_toml_value(val)}")
    return "\n".join(out)


def driver_config(
    world, robot: str, pioneer_pty: str, laser_pty: str, laser: str, laser_pose, nav: str | None = None
) -> dict:
    """The configuration ``deploy/pioneer2dx-urg.toml`` would be for this robot: ``p2os`` with
    the devices the robot's body has, the laser as ``ranger:1`` and ``laser:0``, and the world's
    floorplan as ``map:0`` (the building's map a real robot would be given); with ``nav`` also the
    navigation stack (:func:`nav_drivers`)."""
    spec = world.model_spec(robot)
    provides = ["odometry::position2d:0"]
    if any(r.kind == "sonar" for r in spec.rangers):
        provides.append("sonar:0")
    provides.append("power:0")
    if spec.grippers:
        provides += ["gripper::gripper:0", "lift::actarray:0", "dio:0"]
    drivers = [
        {"name": "p2os", "provides": provides, "port": pioneer_pty, "pulse": 0.5, "timeout": 1.0, "reconnect": 0.5},
        {
            "name": "hokuyo",
            "provides": ["ranger:1", "laser:0"],
            "port": laser_pty,
            "model": laser,
            "pose": [round(float(x), 4) for x in laser_pose],
        },
    ]
    fp = world.spec.floorplan
    if fp is not None and world.grid is not None:
        x0, _, y0, _ = world.grid.extent
        drivers.append(
            {
                "name": "mapfile",
                "provides": ["map:0"],
                "filename": str(Path(fp.bitmap).resolve()),
                "resolution": float(world.grid.resolution),
                "origin": [float(x0), float(y0)],
            }
        )
    if nav:
        if fp is None:
            raise RehearseError(f"{world.spec.source or 'the world'}: --nav needs a floorplan, the map to navigate on")
        x, y, a = world.get_pose(robot)
        drivers += nav_drivers(nav, (x, y, math.degrees(a)))
    return {"server": {"node": robot}, "driver": drivers}


def nav_drivers(nav: str, start) -> list[dict]:
    """The navigation stack of ``deploy/r0-nav.toml`` (thesis A.3) on the robot's own devices:
    ``amcl`` started at ``start`` (x, y m, yaw deg), the local planner ``nav`` and ``wavefront``,
    with the parameters ``rsal sim --nav`` uses (:mod:`mrs_bridge.nav.profile`)."""
    from ..nav import profile

    return [
        {
            "name": "amcl",
            "provides": ["localize:0", "position2d:2"],
            "requires": ["odometry::position2d:0", "laser:0", "laser::map:0"],
            "init_pose": [round(float(v), 4) for v in start],
            "init_pose_var": [0.05, 0.05, math.degrees(math.radians(5) ** 2)],
            **profile.AMCL,
        },
        {"name": nav, "provides": ["position2d:1"], "requires": ["position2d:0", "laser:0"], **profile.LOCAL[nav]},
        {
            "name": "wavefront",
            "provides": ["planner:0"],
            "requires": ["output::position2d:1", "input::position2d:2", "map:0"],
            **profile.WAVEFRONT,
        },
    ]


def user_config(path: Path, robot: str, pioneer_pty: str, laser_pty: str) -> dict:
    """The user's configuration with the ``p2os`` and ``hokuyo`` ports on the ptys and relative
    paths made absolute (the generated file lives elsewhere)."""
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as e:
        raise RehearseError(f"{path}: cannot read it ({e.strerror}); give an existing TOML file") from None
    except tomllib.TOMLDecodeError as e:
        raise RehearseError(f"{path}: not valid TOML ({e}); fix the file") from None
    drivers = doc.get("driver", [])
    names = [d.get("name") for d in drivers if isinstance(d, dict)]
    if "p2os" not in names or not any(n in HOKUYO_NAMES for n in names):
        raise RehearseError(
            f"{path}: needs a p2os and a hokuyo driver block to rehearse; start from deploy/pioneer2dx-urg.toml"
        )
    for d in drivers:
        if d.get("name") == "p2os":
            d["port"] = pioneer_pty
        elif d.get("name") in HOKUYO_NAMES:
            d["port"] = laser_pty
        for k in ("filename", "worldfile", "file"):
            if isinstance(d.get(k), str) and not Path(d[k]).is_absolute():
                d[k] = str((path.parent / d[k]).resolve())
    doc.setdefault("server", {}).setdefault("node", robot)
    return doc


def rehearsal_config(world, robot: str, node: str, source: str) -> ServerConfig:
    """This process's server: the world stepped in real time and the robot's ground truth."""

    def block(name, provides, **params):
        return DriverConfig(name, provides, [], params, None, f"{source}: {name}")

    return ServerConfig(
        node=node,
        drivers=[
            block("rehearsal", [DeviceAddr(node, "simulation", 0)]),
            block("sim", [DeviceAddr(robot, "position2d", TRUTH_INDEX)], model=robot, localization="gps"),
        ],
        source=source,
    )


# ---------------------------------------------------------------------------- the command
def _laser_of(world, robot: str):
    """The mount pose (x, y, yaw) of the robot's first laser in the world, else the URG's on a P2DX."""
    for r in world.rangers(robot):
        if r.kind != "sonar":
            return r.pose[:3] if len(r.pose) >= 3 else (*r.pose, 0.0)
    return (0.13, 0.0, 0.0)


def _endpoints(args) -> list[str]:
    """The child's transport flags: listen on a free loopback port, connect to this process."""
    own = ["--listen", f"tcp/127.0.0.1:{free_port()}"]
    if args.config_zenoh:
        return ["--config", args.config_zenoh]
    if args.listen:
        return [*own, "--connect", args.listen[0]]
    if args.connect:
        return [*own, *(x for c in args.connect for x in ("--connect", c))]
    return [*own, "--connect", DEFAULT_ENDPOINT]


def _rehearse(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except RehearseError as e:
        print(f"{PROG}: {e}", file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    from simulator import SimulatorError
    from simulator.loader import load_world
    from simulator.world import World

    from ..emulators.p2os import PioneerEmulator
    from ..emulators.urg import SENSORS, HokuyoEmulator
    from .coupling import COUPLINGS_KEY, WorldLaser, WorldRobot

    args.config_zenoh = getattr(args, "config", None)  # the transport's --config (Zenoh)
    try:
        spec = load_world(args.world, seed=args.seed)
        for w in spec.warnings:
            print(f"{PROG}: warning: {w}", file=sys.stderr)
        spec.speedup = 1.0  # the real world runs in real time
        world = World(spec)
    except SimulatorError as e:
        raise RehearseError(str(e)) from None
    robot = args.robot
    if robot not in world.robot_names:
        near = did_you_mean(robot, world.robot_names)
        hint = f"did you mean {near!r}? " if near else ""
        raise RehearseError(
            f"{args.world}: no robot named {robot!r}; {hint}robots: {brief(world.robot_names) or 'none'}"
        )
    if not all(c.isalnum() or c in "_-" for c in robot):
        raise RehearseError(f"{args.world}: robot name {robot!r} is no node name; rename it (letters, digits, _ -)")
    x, y, a = world.get_pose(robot)
    say(f"{args.world}: the real world, {robot} at ({x:.2f}, {y:.2f}) heading {math.degrees(a):.0f} deg")

    body = WorldRobot(world, robot)
    n_sonars = len(body.sense().sonars or ()) or 8
    pose = _laser_of(world, robot)
    scene = WorldLaser(world, robot, SENSORS[args.laser], pose)
    pioneer = PioneerEmulator(args.pioneer, name=robot, sonars=min(16, n_sonars), body=body)
    urg = HokuyoEmulator(args.laser, scene=scene)
    tmp = Path(tempfile.mkdtemp(prefix="rsal-rehearse-"))
    child: subprocess.Popen | None = None
    ending = threading.Event()  # set once this process stops the child itself
    failed: list[int] = []  # the child's exit code when it ended by itself
    try:
        say(f"Pioneer {args.pioneer} emulated on {pioneer.path} (body: {robot} in the world)")
        say(f"{args.laser} emulated on {urg.path} at ({pose[0]:g}, {pose[1]:g}, {math.degrees(pose[2]):g} deg)")
        if args.robot_config is not None and args.nav:
            raise RehearseError(f"--nav adds to the generated configuration; add the stack to {args.robot_config}")
        if args.robot_config is not None:
            doc = user_config(Path(args.robot_config), robot, pioneer.path, urg.path)
        else:
            doc = driver_config(world, robot, pioneer.path, urg.path, args.laser, pose, args.nav)
        cfg_path = tmp / f"{robot}-rehearsal.toml"
        cfg_path.write_text(
            write_toml(doc, f"# rsal rehearse {args.world} {robot}: the robot's drivers on emulated hardware\n")
        )
        try:
            load_config(cfg_path)  # the user's mistakes as one line now, not in the child
        except ConfigError as e:
            raise RehearseError(f"{args.robot_config or cfg_path}: {e}") from None
        if not (args.listen or args.connect or args.config_zenoh):  # this process is the fabric's entry
            args.listen = [DEFAULT_ENDPOINT] if port_free(DEFAULT_ENDPOINT) else [f"tcp/127.0.0.1:{free_port()}"]
            if args.listen[0] != DEFAULT_ENDPOINT:
                args.connect = [DEFAULT_ENDPOINT]
        serve = [sys.executable, "-m", "rsal.cli", "serve", str(cfg_path), *_endpoints(args)]
        say(f"configuration written to {cfg_path}")
        say(f"ground truth: {args.node}:simulation:0 (get_pose {robot}) and {robot}:position2d:{TRUTH_INDEX}")
        if args.no_serve:
            say("run the robot's drivers yourself with: rsal " + " ".join(serve[3:]))
        else:
            child = subprocess.Popen(serve)
            say(f"started the drivers: rsal serve (pid {child.pid})")
            watch = threading.Thread(target=_watch_child, args=(child, ending, failed), name="rehearse-child")
            watch.daemon = True
            watch.start()
        cfg = rehearsal_config(world, robot, args.node, str(args.world))
        args.command = "rehearse"
        rc = run_server(cfg, args, shared={"simulator.world": world, COUPLINGS_KEY: [body, scene]})
        return rc or (1 if failed else 0)
    finally:
        ending.set()
        if child is not None and child.poll() is None:
            child.send_signal(signal.SIGTERM)
            try:
                child.wait(10)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait(5)
        pioneer.close()
        urg.close()
        for f in tmp.iterdir():
            f.unlink()
        tmp.rmdir()


def _watch_child(child: subprocess.Popen, ending: threading.Event, failed: list[int]) -> None:
    """When the drivers' server ends by itself, the rehearsal ends too (it has no robot to serve)."""
    rc = child.wait()
    if ending.is_set():
        return
    failed.append(rc)
    if rc != 0:
        print(f"{PROG}: the drivers' server (rsal serve) exited with code {rc}; see its message above", file=sys.stderr)
    os.kill(os.getpid(), signal.SIGTERM)


def register(sub) -> None:
    from ..emulators.p2os import DIST_CONV
    from ..emulators.urg import SENSORS

    p = sub.add_parser(
        "rehearse",
        help="rehearse a real Pioneer with a Hokuyo laser: emulated hardware in a simulated world, real drivers",
    )
    p.add_argument("world", metavar="WORLD", help="the 'real world': a Stage .world or YAML world file")
    p.add_argument("robot", metavar="ROBOT", help="the robot of that world the emulated Pioneer drives")
    p.add_argument(
        "--robot-config",
        metavar="FILE",
        help="the robot's server configuration (e.g. deploy/pioneer2dx-urg.toml); its p2os and hokuyo ports "
        "are pointed at the emulators (default: one generated in that shape)",
    )
    p.add_argument("--pioneer", choices=tuple(DIST_CONV), default="P2DX", help="the Pioneer model (default P2DX)")
    p.add_argument("--laser", choices=tuple(SENSORS), default="URG-04LX", help="the laser (default URG-04LX)")
    p.add_argument(
        "--nav",
        choices=("vfh", "nd", "snd"),  # mrs_bridge.nav.profile.LOCAL_PLANNERS
        help="add the navigation stack to the generated configuration: amcl, this local planner, wavefront",
    )
    p.add_argument("--seed", type=int, help="random seed of the world (default: the world's)")
    p.add_argument(
        "--node", type=_check_node, default="world", help="node of the world's simulation device (default world)"
    )
    p.add_argument(
        "--no-serve",
        action="store_true",
        help="do not start the drivers; print the ptys, the configuration and the rsal serve command",
    )
    p.add_argument("--require-timeout", type=positive, default=30.0, help=argparse.SUPPRESS)
    add_transport_args(p)
    p.set_defaults(func=_rehearse)


def _check_node(text: str) -> str:
    try:
        parse_device(f"{text}:simulation:0")
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not a node name ({e})") from None
    return text
