"""Mixed reality: the ViewAgent mirrors real robots into a virtual world (thesis 4.3, 3.6.2.3).

"This is made possible by a *ViewAgent*, which subscribes to the *SendPositionService* and listens
to robot position broadcasts. Knowing robot identifiers and positions, the *ViewAgent* can update a
simulation in order to position a proxy robot for each existing physical robot. This use-case can
be configured to filter certain robots, as a simulation environment can host both proxy and
simulated robots simultaneously." (thesis 4.2.1)

:class:`ViewAgent` listens to ``send_position`` and, for each robot in ``robots`` (the real ones;
the filter), moves that robot's proxy in the virtual world to its broadcast pose with the
simulation interface's ``set_pose`` (the thesis's ``setPositionOf``) at most ``rate`` times a
second. Only ``map`` frame positions are mirrored: both worlds share the map's coordinates. A proxy
is a plain model of the virtual world (a Stage ``model`` with a body that rangers and blob cameras
see, see ``maps/mixed_virtual_*.world``), named like its robot unless ``proxies`` maps robot ids to
other model names. Virtual robots' lasers and blobfinders then see the real robots, and the agents
of the virtual robots cannot tell which is which. The reverse direction, real robots sensing virtual
ones, is the ``virtual_ranger`` driver (:mod:`mrs_bridge.drivers.virtual_ranger`).

The real robots' agents should broadcast often (``report_every: 0.1``) so that the proxies follow
smoothly. ``set_pose`` calls never block the loop (:meth:`rsal.client.Fabric.rpc_async`); a proxy
with a call under way is updated again after the answer, to its latest pose.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Future

from agents.registry import agent_class
from agents.runtime import Agent
from agents.services import Message, SendPosition
from rsal.client import Fabric
from rsal.keys import DeviceAddr, parse_device
from rsal.msgs import RpcError

__all__ = ["ViewAgent"]

log = logging.getLogger(__name__)


@agent_class("ViewAgent")
class ViewAgent(Agent):
    """Mirrors the poses of the real ``robots`` onto their proxies in the virtual ``simulation``
    (a device address, default ``sim:simulation:0``) at up to ``rate`` Hz (thesis 4.2.1, 4.3)."""

    capabilities = ("view",)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        robots: Sequence[str] = (),
        proxies: Mapping[str, str] | None = None,
        simulation: str = "sim:simulation:0",
        rate: float = 10.0,
        startup_timeout: float = 30.0,
    ):
        if isinstance(rate, bool) or not isinstance(rate, int | float) or not 0 < rate <= 100:
            raise ValueError(f"agent {agent_id}: rate {rate!r} must be a number in (0, 100] Hz")
        super().__init__(agent_id, period=1.0 / float(rate), robot=robot)
        if isinstance(robots, str):
            robots = [robots]
        if not isinstance(robots, Sequence) or not robots or not all(isinstance(r, str) and r for r in robots):
            raise ValueError(f"agent {agent_id}: robots {robots!r} must be a non-empty list of real robot ids")
        proxies = dict(proxies or {})
        if not all(isinstance(k, str) and isinstance(v, str) and v for k, v in proxies.items()):
            raise ValueError(f"agent {agent_id}: proxies {proxies!r} must map robot ids to model names")
        unknown = sorted(set(proxies) - set(robots))
        if unknown:
            raise ValueError(f"agent {agent_id}: proxies names robot(s) {', '.join(unknown)} that are not in robots")
        try:
            self.sim_addr: DeviceAddr = parse_device(simulation)
        except (TypeError, ValueError) as e:
            raise ValueError(
                f"agent {agent_id}: simulation {simulation!r} is not a device address like sim:simulation:0 ({e})"
            ) from None
        if self.sim_addr.interface != "simulation":
            raise ValueError(f"agent {agent_id}: simulation {simulation!r} must be a simulation device")
        if isinstance(startup_timeout, bool) or not isinstance(startup_timeout, int | float) or startup_timeout <= 0:
            raise ValueError(f"agent {agent_id}: startup_timeout {startup_timeout!r} must be a positive number")
        self.robots = list(dict.fromkeys(robots))
        self.proxies = {r: proxies.get(r, r) for r in self.robots}  # robot id -> proxy model name
        self.rate = float(rate)
        self.startup_timeout = float(startup_timeout)
        self.fabric: Fabric | None = None
        self.latest: dict[str, tuple[float, float, float]] = {}  # robot -> latest map pose heard
        self.placed: dict[str, tuple[float, float, float]] = {}  # robot -> pose last set on its proxy
        self.updates: dict[str, int] = {r: 0 for r in self.robots}  # set_pose calls answered ok
        self.errors = 0
        self._inflight: dict[str, Future] = {}
        self._last_error = ""

    # ------------------------------------------------------------------ the simulation
    def rpc(self, op: str, args: dict | None = None, timeout: float = 2.0) -> Future:
        """Call ``op`` on the virtual simulation without blocking (a future of the reply map)."""
        assert self.fabric is not None
        return self.fabric.rpc_async(self.sim_addr, op, args, timeout=timeout)

    def _check_world(self) -> None:  # a worker thread
        """Wait for the simulation device and check that every proxy is a model of its world."""
        deadline = time.monotonic() + self.startup_timeout
        node = self.fabric.node(str(self.sim_addr))
        try:
            node.wait_for(str(self.sim_addr), 1, self.startup_timeout)
        except TimeoutError:
            raise TimeoutError(
                f"agent {self.id}: the virtual simulation {self.sim_addr} did not appear within "
                f"{self.startup_timeout:g} s (start it with 'rsal sim WORLD', node {self.sim_addr.node})"
            ) from None
        while True:
            try:
                models = self.rpc("models").result(3.0)
                break
            except (RpcError, TimeoutError) as e:
                if time.monotonic() >= deadline:
                    raise TimeoutError(f"agent {self.id}: {self.sim_addr} does not answer 'models': {e}") from None
                time.sleep(0.2)  # a worker thread, not the loop
        objects = set(models.get("objects", []))
        robots = set(models.get("robots", []))
        missing = [m for m in self.proxies.values() if m not in objects | robots]
        if missing:
            raise ValueError(
                f"agent {self.id}: the virtual world of {self.sim_addr} has no model {', '.join(missing)} to mirror "
                "a real robot into; add a plain model of that name (a Stage 'model' with a size, see "
                "maps/mixed_virtual_prey.world) or map the robot to another model with proxies"
            )
        for r, m in self.proxies.items():
            if m in robots:
                log.warning("%s: proxy %s of %s is a simulated robot; its own driver also moves it", self.id, m, r)

    # ------------------------------------------------------------------ lifecycle
    async def created(self) -> None:
        if self.fabric is None:
            self.fabric = Fabric(self._require_host().session, own_session=False)
            await asyncio.to_thread(self._check_world)
        self.subscribe(SendPosition.SERVICE, self._on_position)

    def _on_position(self, msg: Message) -> None:
        p: SendPosition = msg.body
        if p.robot in self.proxies and p.frame == "map":
            self.latest[p.robot] = (p.x, p.y, p.yaw)

    async def step(self) -> None:
        for robot, pose in self.latest.items():
            fut = self._inflight.get(robot)
            if fut is not None:
                if not fut.done():
                    continue
                self._finish(robot, fut)
            if self.placed.get(robot) == pose:
                continue
            self.placed[robot] = pose
            self._inflight[robot] = self.rpc("set_pose", {"name": self.proxies[robot], "pose": list(pose)})

    def _finish(self, robot: str, fut: Future) -> None:
        del self._inflight[robot]
        try:
            fut.result()
            self.updates[robot] += 1
        except Exception as e:  # the simulation answered with an error or not at all: try again
            self.errors += 1
            self.placed.pop(robot, None)
            text = f"set_pose of {self.proxies[robot]} ({robot}) on {self.sim_addr}: {e}"
            if text != self._last_error:
                log.warning("%s: %s", self.id, text)
                self._last_error = text

    async def killed(self) -> None:
        if self.fabric is not None:
            self.fabric.close()  # the proxies only; the host owns the session

    def status(self) -> str:
        """One progress line: each real robot's mirrored pose and how many updates it had."""
        parts = []
        for r in self.robots:
            p = self.placed.get(r)
            where = f"({p[0]:.2f}, {p[1]:.2f}, {math.degrees(p[2]):.0f} deg)" if p is not None else "not heard yet"
            parts.append(f"{r}->{self.proxies[r]} {where} x{self.updates[r]}")
        err = f"  {self.errors} failed update(s)" if self.errors else ""
        return "mirroring " + ", ".join(parts) + err
