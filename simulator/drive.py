"""Differential drives and wheel odometry of all robots, as arrays with one row per robot.

The vectorised maths behind :class:`~simulator.world.World`'s step (Stage's ``position`` model,
Player's position2d): velocities approach the command within acceleration limits, motors become
the force and torque that make pymunk's velocity integration land on the commanded ``(v, w)``
(exact unicycle integration: the chord of the step's arc along the mid-step heading), and
odometry integrates each robot's true motion in its own frame with a per-robot scale bias and
white noise (Stage's ``odom_error``), so it drifts the way a wheel encoder does.
"""

from __future__ import annotations

import numpy as np

from .sensors.base import wrap

__all__ = ["Drives"]

_ARRAYS = {  # name: columns (0: a 1-D array)
    "cmd": 2, "vel": 2, "limits": 4, "odom": 3, "bias": 3, "noise": 3, "prev": 3, "stall": 0, "drive": 2,
    "mass": 0, "moment": 0,
}  # fmt: skip


class Drives:
    """The state of every robot's drive, by row: ``cmd`` and ``vel`` ``(v, w)``, ``limits``
    ``(vmax, wmax, amax, alphamax)``, ``odom``, its ``bias`` and ``noise``, ``prev`` (the true
    pose after the last step), ``stall``, ``drive`` (the ``(v, w)`` the motors applied last),
    ``mass`` and ``moment`` of the body."""

    def __init__(self) -> None:
        for name, cols in _ARRAYS.items():
            setattr(self, name, np.zeros((0, cols) if cols else 0, dtype=bool if name == "stall" else float))

    def add(self, pose, limits, bias, noise, mass: float, moment: float) -> None:
        row = {"cmd": (0.0, 0.0), "vel": (0.0, 0.0), "limits": limits, "odom": (0.0, 0.0, 0.0), "bias": bias}
        row.update(noise=noise, prev=pose, stall=False, drive=(0.0, 0.0), mass=mass, moment=moment)
        for name, cols in _ARRAYS.items():
            arr = getattr(self, name)
            setattr(self, name, np.vstack([arr, row[name]]) if cols else np.append(arr, row[name]))

    def remove(self, row: int) -> None:
        keep = np.ones(self.vel.shape[0], dtype=bool)
        keep[row] = False
        for name in _ARRAYS:
            setattr(self, name, getattr(self, name)[keep])

    def accelerate(self, dt: float) -> None:
        """Velocities towards the commands, within the acceleration limits."""
        a = self.limits[:, 2:4] * dt
        self.vel += np.clip(self.cmd - self.vel, -a, a)

    def motors(self, b: np.ndarray, rows: np.ndarray, h: float, damping: float, first: bool) -> np.ndarray:
        """The batch write buffer for one pymunk sub-step of ``h`` s from the batch read ``b``
        (per body ``[angle, vx, vy, w, fx, fy, torque]``, ``rows[i]`` its robot row or -1).

        The velocity is set *before* contacts are solved: walls and other bodies still stop or
        deflect the robot, and the next position update moves it with the corrected velocity. On
        the first sub-step of a step, a robot whose drive changed gets the new velocity at once;
        an unchanged drive leaves the contact corrections of the last step in place."""
        b = b.copy()
        r = rows >= 0
        rr = rows[r]
        v, w = self.vel[rr, 0], self.vel[rr, 1]
        half = 0.5 * h * w
        small = np.abs(half) <= 1e-12
        chord = v * np.where(small, 1.0, np.sin(half) / np.where(small, 1.0, half))
        ang = b[r, 0]
        cur = b[r, 1:4]
        if first:
            changed = (self.vel[rr] != self.drive[rr]).any(axis=1)
            if changed.any():
                a0 = ang[changed] + half[changed]
                cur[changed] = np.stack([chord[changed] * np.cos(a0), chord[changed] * np.sin(a0), w[changed]], 1)
            self.drive[rr] = self.vel[rr]
        # Heading after pymunk's position update (angle + w h), then half the step's turn on.
        a = ang + cur[:, 2] * h + half
        damp = damping**h
        mass = self.mass[rr]
        b[r, 1:4] = cur
        b[r, 4] = mass * (chord * np.cos(a) - cur[:, 0] * damp) / h
        b[r, 5] = mass * (chord * np.sin(a) - cur[:, 1] * damp) / h
        b[r, 6] = self.moment[rr] * (w - cur[:, 2] * damp) / h
        return np.ascontiguousarray(b[:, 1:]).reshape(-1)

    def odometry(self, pose: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        """Integrate odometry from ``prev`` to the true ``pose``; detect stalls; ``prev = pose``."""
        d = pose - self.prev
        dth = wrap(d[:, 2])
        # Displacement in the frame of the mid-step heading (where the chord of an arc points).
        mid_true = self.prev[:, 2] + 0.5 * dth
        c, s = np.cos(mid_true), np.sin(mid_true)
        dx = c * d[:, 0] + s * d[:, 1]
        dy = -s * d[:, 0] + c * d[:, 1]
        # Achieved velocity in the robot frame, and stall detection.
        expect = np.abs(self.vel[:, 0]) * dt
        self.stall = (expect > 1e-3) & (np.hypot(dx, dy) < 0.3 * expect)
        self.vel[:, 0] = np.where(self.stall, dx / dt, self.vel[:, 0])
        nz = rng.standard_normal((len(dx), 3)) * self.noise
        ox = dx * (1.0 + self.bias[:, 0]) + nz[:, 0] * np.abs(dx)
        oy = dy * (1.0 + self.bias[:, 1]) + nz[:, 1] * np.abs(dx)
        ot = dth * (1.0 + self.bias[:, 2]) + nz[:, 2] * np.abs(dth)
        mid = self.odom[:, 2] + 0.5 * ot
        self.odom[:, 0] += np.cos(mid) * ox - np.sin(mid) * oy
        self.odom[:, 1] += np.sin(mid) * ox + np.cos(mid) * oy
        self.odom[:, 2] = wrap(self.odom[:, 2] + ot)
        self.prev = pose
