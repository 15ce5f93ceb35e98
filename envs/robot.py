"""The hidden truth of a differential-drive robot, and the distribution it is drawn from.

Units: meters, radians, seconds, kilograms. Body frame: x forward, y left; the left wheel
sits at +b/2 on body y, the right wheel at -b/2, both on the axle (body x = 0). The body
frame's origin is the axle midpoint, the reference point of every pose in this package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


@dataclass(frozen=True)
class RobotSpec:
    """One robot's physical parameters (the truth the calibration tries to recover).

    Attributes:
        r_L, r_R: effective wheel radii (m).
        b: wheel separation (m).
        mass: chassis mass (kg).
        inertia: yaw moment of inertia about the center of mass (kg m^2).
        com_offset: center of mass ahead of the axle midpoint along body x (m). A spin about
            the axle midpoint needs the centripetal force mass * w^2 * com_offset from the
            wheels' lateral friction, so fast spins can slip.
        mu: wheel-floor friction coefficient (dimensionless).
        motor_tau: time constant of the first-order motor lag (s).
        max_wheel_speed: wheel angular speed limit (rad/s).
        wheel_load_fraction: share of the weight carried by the two drive wheels (the rest
            rests on a frictionless caster), in (0, 1].
    """

    r_L: float
    r_R: float
    b: float
    mass: float
    inertia: float
    com_offset: float
    mu: float
    motor_tau: float
    max_wheel_speed: float
    wheel_load_fraction: float

    def __post_init__(self) -> None:
        values = [getattr(self, f.name) for f in fields(self)]
        _require(_finite(*values), f"RobotSpec values must be finite, got {self}")
        for name in ("r_L", "r_R", "b", "mass", "inertia", "mu", "motor_tau", "max_wheel_speed"):
            _require(getattr(self, name) > 0, f"RobotSpec.{name} must be > 0")
        _require(
            0 < self.wheel_load_fraction <= 1,
            f"RobotSpec.wheel_load_fraction must be in (0, 1], got {self.wheel_load_fraction}",
        )

    def kinematic_params(self) -> tuple[float, float, float]:
        """The calibrated quantities (r_L, r_R, b), in meters."""
        return (self.r_L, self.r_R, self.b)


@dataclass(frozen=True)
class RobotDistribution:
    """Nominal robot and the ranges hidden robots are drawn from.

    Relative ranges are half-widths: r_L, r_R and b are each drawn uniformly and independently
    in nominal * [1 - rel, 1 + rel]; mass likewise with `mass_rel`. The inertia scales with the
    drawn mass (same mass distribution). mu and com_offset are drawn uniformly in absolute
    ranges. Motor lag, speed limit and load fraction are not randomized.
    """

    radius: float = 0.05
    separation: float = 0.30
    mass: float = 4.0
    inertia: float = 0.05
    com_offset: float = 0.04
    mu: float = 0.8
    motor_tau: float = 0.05
    max_wheel_speed: float = 20.0
    wheel_load_fraction: float = 0.8
    radius_rel: float = 0.05
    separation_rel: float = 0.05
    mass_rel: float = 0.20
    mu_range: tuple[float, float] = (0.5, 1.0)
    com_offset_range: tuple[float, float] = (0.0, 0.06)

    def __post_init__(self) -> None:
        self.nominal()  # validates the nominal values through RobotSpec
        for name in ("radius_rel", "separation_rel", "mass_rel"):
            rel = getattr(self, name)
            _require(
                _finite(rel) and 0 <= rel < 1,
                f"RobotDistribution.{name} must be in [0, 1), got {rel}",
            )
        for name in ("mu_range", "com_offset_range"):
            lo, hi = getattr(self, name)
            _require(
                _finite(lo, hi) and lo <= hi,
                f"RobotDistribution.{name} must be finite with low <= high, got {(lo, hi)}",
            )
        _require(self.mu_range[0] > 0, f"RobotDistribution.mu_range must be > 0: {self.mu_range}")

    def nominal(self) -> RobotSpec:
        """The nominal robot (what the engineer believes before calibration)."""
        return RobotSpec(
            r_L=self.radius,
            r_R=self.radius,
            b=self.separation,
            mass=self.mass,
            inertia=self.inertia,
            com_offset=self.com_offset,
            mu=self.mu,
            motor_tau=self.motor_tau,
            max_wheel_speed=self.max_wheel_speed,
            wheel_load_fraction=self.wheel_load_fraction,
        )

    def sample(self, rng: np.random.Generator) -> RobotSpec:
        """Draw one hidden robot. Draw order is fixed, so a seeded rng gives the same robot."""
        r_L, r_R = self.radius * rng.uniform(1 - self.radius_rel, 1 + self.radius_rel, 2)
        b = self.separation * rng.uniform(1 - self.separation_rel, 1 + self.separation_rel)
        mass = self.mass * rng.uniform(1 - self.mass_rel, 1 + self.mass_rel)
        mu = rng.uniform(*self.mu_range)
        com_offset = rng.uniform(*self.com_offset_range)
        return RobotSpec(
            r_L=float(r_L),
            r_R=float(r_R),
            b=float(b),
            mass=float(mass),
            inertia=self.inertia * float(mass) / self.mass,
            com_offset=float(com_offset),
            mu=float(mu),
            motor_tau=self.motor_tau,
            max_wheel_speed=self.max_wheel_speed,
            wheel_load_fraction=self.wheel_load_fraction,
        )
