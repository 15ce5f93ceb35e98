"""The contracts between a robot (simulated or real) and the planners that drive it.

A light module (numpy only), so a planner can drive a real robot without the simulator:

- :class:`RobotKnowledge`: everything a planner may use after n segments, never the truth;
- :class:`Estimator`: what an online estimator offers (``OnlineEstimator`` implements it);
- :data:`EstimatorFactory`: how a fresh estimator is made at the start of an episode;
- :class:`Traction`: the nominal robot's limits that decide when its wheels slip.

The arena's geometry is in :mod:`excite.core.arena`, the kinematic prediction in
:mod:`excite.core.kinematics` and :mod:`excite.core.models`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from excite.core.arena import DEFAULT_CHASSIS
from excite.core.kinematics import Params
from excite.core.models import AXLE, SegmentModel

__all__ = ["Estimator", "EstimatorFactory", "RobotKnowledge", "Traction"]


class Estimator(Protocol):
    """What the environment needs of an online estimator (OnlineEstimator implements it).

    ``update(dphi_L, dphi_R, dx, dy, dtheta)``: fold in one segment, called once per segment
    with five positional floats: the wheel increments dphi_L, dphi_R (rad) and the measured
    increment dx, dy (m), dtheta (rad), the sensor's motion in its own frame at the segment's
    start (docs/conventions.md); returns nothing.

    ``params``: the current estimate of the wheel parameters, :class:`excite.Params` or three
    finite values (r_L, r_R, b) in m.

    ``covariance``: its covariance, a finite (P, P) array in the parameters' units (m^2
    between lengths, m rad and rad^2 with an angle), P >= 3: (r_L, r_R, b) first, then, for
    an estimator of the sensor pose (P = 6), l_x, l_y [m] and l_theta [rad]. Such an
    estimator also gives ``theta``, all P parameters (P,) in that order.

    The smallest estimator, which keeps the nominal robot (the factory's arguments are those
    of :data:`EstimatorFactory`)::

        >>> import numpy as np
        >>> from excite import Params
        >>> class Nominal:
        ...     def __init__(self, nominal, sigma):
        ...         self.params = nominal
        ...         self.covariance = np.diag((0.1 * nominal.as_array()) ** 2)
        ...     def update(self, dphi_L, dphi_R, dx, dy, dtheta):
        ...         pass
        >>> estimator = Nominal(Params(0.05, 0.05, 0.3), np.array([2e-3, 2e-3, 1e-3]))
        >>> estimator.update(10.0, 10.0, 0.5, 0.0, 0.0)
        >>> estimator.params
        Params(r_L=0.05, r_R=0.05, b=0.3)
        >>> estimator.covariance.shape
        (3, 3)

    A class like ``Nominal`` is itself a factory: ``excite compare --estimators
    module:Nominal``, or ``estimator_factory=Nominal`` for the environment.
    """

    def update(self, dphi_L: float, dphi_R: float, dx: float, dy: float,
               dtheta: float) -> None: ...

    @property
    def params(self) -> Params: ...

    @property
    def covariance(self) -> np.ndarray: ...


#: estimator_factory(nominal, sensor sigma (sx, sy, sth)) -> a fresh estimator. nominal is
#: the nominal robot's Params on the axle model, and the nominal parameter array
#: (r_L, r_R, b, l_x, l_y, l_theta) when the env estimates the sensor pose.
EstimatorFactory = Callable[[Params | np.ndarray, np.ndarray], Estimator]


@dataclass(frozen=True)
class Traction:
    """What the nominal robot's spec says about slip (a real robot's user can give it).

    motor_tau: time constant (s) of the wheel motors' first-order lag (the wheel speed
    approaches a new command as 1 - exp(-t / motor_tau)). grip: the largest acceleration (m/s^2)
    the floor can give a wheel's contact before it slides, mu * g * (share of the weight on the
    two drive wheels); a wheel whose command asks for more slips. spin_inertia: the chassis'
    yaw inertia over mass * (b / 2)^2 (dimensionless): below 1 the grip turns the chassis
    more easily than it pushes it (a spin's contacts may accelerate grip / spin_inertia).
    """

    motor_tau: float
    grip: float
    spin_inertia: float = 1.0

    def __post_init__(self) -> None:
        for name in ("motor_tau", "grip", "spin_inertia"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"Traction.{name} must be finite and > 0, got {value}")


@dataclass(frozen=True)
class RobotKnowledge:
    """What the robot knows after n segments: everything a planner may use, never the truth.

    observation: the env's observation vector. estimate: current estimate (m). information:
    relative Fisher information of the log at the estimate (P x P). log: (n, 5) calibration
    rows. pose: the body's measured world pose (x, y, theta). nominal: the nominal robot.
    sigma: sensor noise (m, m, rad). max_wheel_speed: motor limit (rad/s); segment_duration
    (s); arena_size (m): the side of the square arena centred at the world origin (the
    observation's unit of position); budget (segments); chassis: the nominal footprint
    (length, width, m). arena_extent: the arena's (width along x, height along y) in m when it
    is a rectangle other than the square of arena_size (a live session's area); None: that
    square.
    model: the segment model; theta / nominal_theta:
    the current estimate and the nominal values of all its P parameters. traction: the
    nominal robot's motor lag and grip (None when unknown; the simulator always gives it).
    """

    observation: np.ndarray
    estimate: Params
    information: np.ndarray
    log: np.ndarray
    pose: np.ndarray
    nominal: Params
    sigma: np.ndarray
    max_wheel_speed: float
    segment_duration: float
    arena_size: float
    budget: int
    model: SegmentModel = AXLE
    chassis: tuple[float, float] = DEFAULT_CHASSIS
    theta: np.ndarray | None = None
    nominal_theta: np.ndarray | None = None
    traction: Traction | None = None
    arena_extent: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.theta is None:
            object.__setattr__(self, "theta", self.estimate.as_array())
        if self.nominal_theta is None:
            object.__setattr__(self, "nominal_theta", self.nominal.as_array())

    @property
    def arena(self) -> tuple[float, float]:
        """The arena's (width along x, height along y) in m, centred at the world origin."""
        if self.arena_extent is not None:
            return self.arena_extent
        return (self.arena_size, self.arena_size)

    @property
    def n_segments(self) -> int:
        return int(self.log.shape[0])
