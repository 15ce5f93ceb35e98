"""The safe area of a live session: an axis-aligned rectangle in the pose frame.

A light module (numpy only). The planners' wall guard works in a frame centred on the area
(:class:`excite.contracts.RobotKnowledge`: the arena centred at the origin), so the session
hands them the robot's pose relative to the area's centre and the area's extent.

Frames and units: the pose frame of the external sensor (x, y in m, theta in rad,
counter-clockwise); the robot's body pose is its axle midpoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from excite.core.arena import DEFAULT_CHASSIS, footprint_clearance

__all__ = ["Area"]


@dataclass(frozen=True)
class Area:
    """The rectangle [x0, x1] x [y0, y1] (m, pose frame) the robot's footprint never leaves.

    Build it from corners, :meth:`square` (a side around a centre) or :meth:`around`
    (within a radius of a centre).
    """

    x0: float
    y0: float
    x1: float
    y1: float

    def __post_init__(self) -> None:
        values = (self.x0, self.y0, self.x1, self.y1)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f"the area's corners must be finite numbers (m), got {values}")
        if not (self.x0 < self.x1 and self.y0 < self.y1):
            raise ValueError(f"the area X0,Y0,X1,Y1 needs X0 < X1 and Y0 < Y1 (m), got "
                             f"{','.join(f'{v:g}' for v in values)}")

    @classmethod
    def square(cls, center: tuple[float, float], side: float) -> Area:
        """The square of ``side`` (m) centred on ``center`` (x, y in m)."""
        if not (math.isfinite(side) and side > 0):
            raise ValueError(f"the area's side must be finite and > 0 (m), got {side}")
        h = 0.5 * side
        return cls(center[0] - h, center[1] - h, center[0] + h, center[1] + h)

    @classmethod
    def around(cls, center: tuple[float, float], radius: float) -> Area:
        """The largest square within ``radius`` (m) of ``center``: every point of it is at
        most ``radius`` from the centre (side radius * sqrt(2))."""
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"the radius must be finite and > 0 (m), got {radius}")
        return cls.square(center, radius * math.sqrt(2.0))

    @property
    def center(self) -> np.ndarray:
        """The centre (x, y) in m, pose frame."""
        return np.array([0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1)])

    @property
    def extent(self) -> tuple[float, float]:
        """(width along x, height along y) in m."""
        return (self.x1 - self.x0, self.y1 - self.y0)

    def to_local(self, pose: np.ndarray) -> np.ndarray:
        """A pose (x, y, theta) of the pose frame in the area's frame (its centre the origin,
        the axes unchanged)."""
        out = np.array(pose, dtype=float)
        out[:2] -= self.center
        return out

    def clearance(self, pose: np.ndarray, chassis: tuple[float, float] = DEFAULT_CHASSIS
                  ) -> float:
        """The smallest distance (m) from the footprint of a robot at body pose (x, y,
        theta) (pose frame) to the area's edges; negative when it reaches outside."""
        x, y, theta = self.to_local(pose)
        return float(footprint_clearance(x, y, theta, self.extent, chassis))

    def to_text(self) -> str:
        """'X0,Y0,X1,Y1' in m, as ``--area`` takes it."""
        return ",".join(f"{v:.3f}" for v in (self.x0, self.y0, self.x1, self.y1))
