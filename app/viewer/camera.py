"""First-person camera: position and heading (yaw, pitch) -> camera-to-world (OpenGL frame)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class FlyCamera:
    """Yaw turns about world +y, pitch about the camera's x; moves are in the heading's frame."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0  # radians, 0 looks down world -z
    pitch: float = 0.0  # radians, positive looks up
    speed: float = 1.0  # metres per second
    fov: float = 75.0  # vertical field of view of the perspective display (degrees)

    @classmethod
    def from_c2w(cls, c2w: np.ndarray, **kw) -> FlyCamera:
        """The camera at a pose; roll is dropped (a walking viewer stays level)."""
        c2w = np.asarray(c2w, np.float64)
        forward = -c2w[:3, 2]
        yaw = math.atan2(-forward[0], -forward[2])
        pitch = math.asin(float(np.clip(forward[1], -1.0, 1.0)))
        return cls(position=c2w[:3, 3].copy(), yaw=yaw, pitch=pitch, **kw)

    @property
    def c2w(self) -> np.ndarray:
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        r_yaw = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        r_pitch = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
        m = np.eye(4)
        m[:3, :3] = r_yaw @ r_pitch
        m[:3, 3] = self.position
        return m

    @property
    def level_c2w(self) -> np.ndarray:
        """The pose with the pitch dropped: the heading's frame, horizon level."""
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        m = np.eye(4)
        m[:3, :3] = [[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]
        m[:3, 3] = self.position
        return m

    def look(self, d_yaw: float, d_pitch: float) -> None:
        self.yaw = (self.yaw + d_yaw + math.pi) % (2 * math.pi) - math.pi
        self.pitch = float(np.clip(self.pitch + d_pitch, -1.5, 1.5))

    def move(self, forward: float, right: float, up: float, seconds: float) -> None:
        """Walk by (forward, right, up) in [-1, 1] each, for ``seconds`` at ``speed``."""
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        fwd = np.array([-sy, 0.0, -cy])
        rgt = np.array([cy, 0.0, -sy])
        step = forward * fwd + right * rgt + up * np.array([0.0, 1.0, 0.0])
        self.position = self.position + self.speed * seconds * step


def walk_speed(c2w: np.ndarray) -> float:
    """A first walking speed (metres per second) for a scene whose sources are ``c2w`` [V, 4,
    4]: half the largest distance from a source to its nearest other source, so that W takes
    about two seconds from one source to the next (within 0.1-1 m/s; 0.5 for one view). A fixed
    1 m/s walked a user out of a small scene in a second."""
    centres = np.asarray(c2w, np.float64)[:, :3, 3]
    if len(centres) < 2:
        return 0.5
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(np.clip(0.5 * d.min(1).max(), 0.1, 1.0))
