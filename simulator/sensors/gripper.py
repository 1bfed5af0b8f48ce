"""Grippers: two paddles, a lift and two break beams (Stage 4 ``gripper`` model; Player's gripper).

An actuator with sensors, so it lives with the sensors: each step its paddles and lift move
towards the last command (``paddle_time``/``lift_time`` seconds per motion), its beams report
objects with ``gripper_return`` between the paddles (inner: near their back, outer: near their
tips), closing on such an object grabs it (:meth:`World.hold` takes it out of the physics) and
opening drops it (:meth:`World.release`). A held object follows the paddles. Who holds what is
the world's ``carried_by``; a gripper's ``carrying`` is only believed while that agrees, so
moving or removing the object elsewhere (``set_pose``, ``remove_model``) needs no call back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ModelError
from ..spec import GripperSpec
from .base import Model, Sensor, mount

__all__ = ["GripperState", "Grippers"]


@dataclass(frozen=True)
class GripperState:
    """Player's gripper state: paddles, lift, break beams, what is carried."""

    paddles: str  # "open" | "closed" | "opening" | "closing"
    lift: str  # "down" | "up" | "raising" | "lowering"
    inner_beam: bool  # an object is between the paddles, near their back
    outer_beam: bool  # an object is between the paddles, near their tips
    carrying: str | None  # name of the object held
    time: float


@dataclass
class _Gripper:
    spec: GripperSpec
    model: Model
    paddles: str = "open"
    lift: str = "down"
    paddle_progress: float = 0.0  # seconds of the current paddle motion done
    lift_progress: float = 0.0  # seconds of the current lift motion done (the lift moves independently)
    carrying: str | None = None
    inner_beam: bool = False
    outer_beam: bool = False
    stamp: float = 0.0


class Grippers(Sensor):
    kind = "gripper"
    spec_field = "grippers"
    describe_key = "grippers"

    def make(self, model: Model, spec: GripperSpec) -> _Gripper:
        return _Gripper(spec, model)

    def _held(self, g: _Gripper) -> str | None:
        """What ``g`` holds, checked against the world (the object may have been moved away)."""
        o = self.world.models.get(g.carrying or "")
        if o is None or o.carried_by != g.model.spec.name:
            g.carrying = None
        return g.carrying

    def state(self, name: str, index: int) -> GripperState:
        g = self.device(name, index)
        return GripperState(g.paddles, g.lift, g.inner_beam, g.outer_beam, self._held(g), g.stamp)

    def command(self, name: str, command: str, index: int) -> None:
        """``open``, ``close``, ``up``, ``down`` or ``stop`` (Player's gripper/actarray commands)."""
        g = self.device(name, index)
        cmd = str(command).lower()
        if cmd == "open":
            if g.paddles not in ("open", "opening"):
                g.paddles, g.paddle_progress = "opening", 0.0
        elif cmd == "close":
            if g.paddles not in ("closed", "closing"):
                g.paddles, g.paddle_progress = "closing", 0.0
        elif cmd == "up":
            if g.lift not in ("up", "raising"):
                g.lift, g.lift_progress = "raising", 0.0
        elif cmd == "down":
            if g.lift not in ("down", "lowering"):
                g.lift, g.lift_progress = "lowering", 0.0
        elif cmd == "stop":
            g.paddles = {"opening": "open", "closing": "open"}.get(g.paddles, g.paddles)
            g.lift = {"raising": "down", "lowering": "down"}.get(g.lift, g.lift)
        else:
            raise ModelError(f"unknown gripper command {command!r}; use open, close, up, down or stop")

    def rebuild(self) -> None:
        self._grippable = [m for m in self.world.models.values() if m.spec.gripper_return]

    def update(self, dt: float) -> None:
        for gs in self.devices.values():
            for g in gs:
                self._step(g, dt)

    def _step(self, g: _Gripper, dt: float) -> None:
        w, m, spec = self.world, g.model, g.spec
        b = m.body
        gx, gy, ga = mount((b.position.x, b.position.y, b.angle), (spec.pose[0], spec.pose[1], 0.0))
        # Beams: objects with gripper_return whose centre is between the paddles.
        depth, width = spec.size
        inner = outer = False
        between: Model | None = None
        ca, sa = math.cos(ga), math.sin(ga)
        for o in self._grippable:
            if o is m or (o.carried_by and o.carried_by != m.spec.name):
                continue
            dx, dy = o.body.position.x - gx, o.body.position.y - gy
            lx = ca * dx + sa * dy
            ly = -sa * dx + ca * dy
            if abs(ly) <= width / 2 and -depth / 2 - 0.1 <= lx <= depth / 2 + 0.1:
                if lx <= 0.0:
                    inner = True
                else:
                    outer = True
                if between is None:
                    between = o
        g.inner_beam, g.outer_beam = inner, outer
        held = self._held(g)
        if g.paddles in ("opening", "closing"):
            g.paddle_progress += dt
            if g.paddle_progress >= spec.paddle_time - 1e-9:
                if g.paddles == "closing":
                    g.paddles = "closed"
                    if between is not None and between.carried_by is None and held is None:
                        w.hold(between, m.spec.name)
                        g.carrying = held = between.spec.name
                else:
                    g.paddles = "open"
                    if held:
                        w.release(w.models[held])
                        g.carrying = held = None
        if g.lift in ("raising", "lowering"):
            g.lift_progress += dt
            if g.lift_progress >= spec.lift_time - 1e-9:
                g.lift = "up" if g.lift == "raising" else "down"
        if held:
            o = w.models[held]
            o.body.position = (gx, gy)
            o.body.angle = ga
            g.inner_beam = True
        g.stamp = w.time
