"""Sensors: quantizing wheel encoders and an external (motion-capture-like) pose sensor.

Poses are (x, y, theta) of the axle midpoint in the world frame (m, m, rad; x right, y up,
theta counter-clockwise and continuous, i.e. never wrapped). Sensors hold no random state:
every noisy reading takes the np.random.Generator to draw from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


class WheelEncoders:
    """Incremental encoders reading the absolute wheel angles floored to whole ticks.

    Increments are differences of quantized absolute readings, so quantization errors stay
    within one tick per segment and never accumulate along a run.
    """

    def __init__(self, ticks_per_rev: int = 4096) -> None:
        if int(ticks_per_rev) != ticks_per_rev or ticks_per_rev < 1:
            raise ValueError(f"ticks_per_rev must be a positive integer, got {ticks_per_rev!r}")
        self.ticks_per_rev = int(ticks_per_rev)
        self.resolution = 2.0 * math.pi / self.ticks_per_rev  # rad per tick

    def count(self, angles: np.ndarray) -> np.ndarray:
        """Tick counts (floats holding integers) for absolute wheel angles (rad)."""
        return np.floor(np.asarray(angles, dtype=float) / self.resolution)

    def increments(self, angles_start: np.ndarray, angles_end: np.ndarray) -> np.ndarray:
        """Measured wheel angle increments (rad) between two absolute angle readings."""
        return (self.count(angles_end) - self.count(angles_start)) * self.resolution

    def sub_increments(self, wheel_path: np.ndarray, count: int) -> np.ndarray:
        """The increments (rad) between ``count + 1`` readings evenly spaced over a segment's
        ticks, its first and last included: wheel_path (M, ..., 2) absolute wheel angles at
        every tick (rad) -> (count, ..., 2), fewer when the segment has fewer than ``count``
        ticks. Their whole ticks sum to those of :meth:`increments` of the first and last tick."""
        ticks = len(wheel_path) - 1
        at = np.linspace(0, ticks, min(count, ticks) + 1).round().astype(np.int64)
        return np.diff(self.count(wheel_path[at]), axis=0) * self.resolution


@dataclass(frozen=True)
class RelativePoseSensor:
    """External pose sensor with independent Gaussian noise per reading.

    Attributes:
        sigma_xy: standard deviation of the x and y errors (m).
        sigma_theta: standard deviation of the heading error (rad).
    """

    sigma_xy: float = 2e-3
    sigma_theta: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("sigma_xy", "sigma_theta"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"RelativePoseSensor.{name} must be finite and >= 0, got {value}")
        sigma = np.array([self.sigma_xy, self.sigma_xy, self.sigma_theta])
        sigma.flags.writeable = False
        object.__setattr__(self, "_sigma", sigma)

    @property
    def sigma(self) -> np.ndarray:
        """Per-channel standard deviations (sigma_x, sigma_y, sigma_theta) in (m, m, rad)."""
        return self._sigma.copy()

    def measure(self, true_increment: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy body-frame increment (dx, dy, dtheta); one fresh noise draw per segment."""
        return _add_noise(true_increment, self._sigma, rng)

    def each(self, values: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        """Noisy readings (N, 3) of N robots' increments or poses (N, 3), robot i drawing from
        ``rngs[i]`` exactly as :meth:`measure` / :meth:`absolute` would."""
        noise = np.empty((len(rngs), 3))
        for rng, row in zip(rngs, noise, strict=True):  # drawn in place: no array per robot
            rng.standard_normal(out=row)
        noise *= self._sigma
        return values + noise

    def absolute(self, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy world pose(s) (..., 3) (x, y, theta), an independent draw per reading; theta
        stays continuous (not wrapped)."""
        return _add_noise(pose, self._sigma, rng)


def _add_noise(values: np.ndarray, sigma: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """values (..., 3) + sigma * standard normal draws (3 per reading, in order)."""
    values = np.asarray(values, dtype=float)
    return values + sigma * rng.standard_normal(values.shape)
