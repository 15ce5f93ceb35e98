"""The arena's geometry: a walled rectangle, and whether a robot's footprint fits inside.

A light module (numpy only): the simulator builds its walls from it, and planners check
their predicted footprints against it, on a simulated robot or a real one.

Frames and units: world frame x right, y up, theta counter-clockwise (rad); meters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Arena", "DEFAULT_CHASSIS", "DEFAULT_CHASSIS_SIZE", "footprint_clearance"]

#: m, side of the default robot's square chassis footprint.
DEFAULT_CHASSIS_SIZE = 0.36
#: m, (length, width) of the default robot's footprint: contains_footprint's default chassis.
DEFAULT_CHASSIS = (DEFAULT_CHASSIS_SIZE, DEFAULT_CHASSIS_SIZE)


@dataclass(frozen=True)
class Arena:
    """Rectangular arena centred at the world origin; walls on its boundary.

    The arena knows nothing of the robot: whether a robot fits is checked against its own
    chassis (`contains_footprint`, `envs.simulation.Simulation.reset`).

    Attributes:
        width: extent along world x (m).
        height: extent along world y (m).
    """

    width: float = 4.0
    height: float = 4.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"Arena.{name} must be finite and > 0, got {value}")

    def contains_footprint(self, x: np.ndarray, y: np.ndarray, theta: np.ndarray,
                           margin: float | np.ndarray = 0.0,
                           chassis: tuple[float, float] = DEFAULT_CHASSIS) -> np.ndarray:
        """Whether the chassis footprint at poses (x, y, theta) is inside the walls, at least
        ``margin`` (m, broadcast with the poses) away from them.

        chassis: (length along body x, width along body y) of the rectangular footprint (m),
        centred on the axle midpoint; the default robot's 0.36 m square by default (use
        ``RobotSpec.chassis`` for another robot).
        """
        return footprint_clearance(x, y, theta, (self.width, self.height), chassis) >= margin


def footprint_clearance(x, y, theta, extent: tuple[float, float],
                        chassis: tuple[float, float] = DEFAULT_CHASSIS) -> np.ndarray:
    """The smallest distance (m) from the chassis footprint (length along body x, width along
    body y, m, centred on the axle midpoint) at poses (x, y, theta) to the edges of an
    ``extent`` (width along x, height along y, m) rectangle centred on the origin, in that
    rectangle's frame; negative where the footprint reaches outside."""
    length, width = chassis
    c, s = np.abs(np.cos(theta)), np.abs(np.sin(theta))
    # Corner extent of the rectangle rotated by theta, along each axis.
    if length == width:  # a square: one product, as before presets existed
        reach_x = reach_y = 0.5 * length * (c + s)
    else:
        reach_x = 0.5 * (length * c + width * s)
        reach_y = 0.5 * (length * s + width * c)
    return np.minimum(0.5 * extent[0] - np.abs(x) - reach_x,
                      0.5 * extent[1] - np.abs(y) - reach_y)
