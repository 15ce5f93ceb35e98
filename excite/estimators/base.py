"""What the reference estimators share: the estimator protocol's attributes around one
abstract update (the environment and the comparison read ``params``, ``covariance`` and,
when present, ``theta``)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.information import as_sigma, sigma_min
from excite.kinematics import Params
from excite.models import SegmentModel, SensorPose
from excite.online import as_prior_std, initial_theta

__all__ = ["SegmentEstimator"]

FloatArray = NDArray[np.float64]


class SegmentEstimator(ABC):
    """An estimator of a segment model's P parameters theta, fed one segment at a time.

    initial: the nominal robot, the prior mean: Params or the model's P parameters
        ((r_L, r_R, b) in m, then l_x, l_y [m], l_theta [rad] for the sensor-pose model).
    prior_std: prior standard deviation in the parameters' units (scalar or P values); None:
        10% of each length, 0.1 b for offsets, 0.5 rad for angles (as
        :class:`excite.OnlineEstimator`).
    sigma: measurement noise (sigma_x [m], sigma_y [m], sigma_theta [rad]).
    model: the segment model (default :data:`excite.models.AXLE`).

    Subclasses implement :meth:`_update`, ``theta``, ``covariance`` and ``information``.
    """

    def __init__(self, initial: Params | ArrayLike, prior_std: float | ArrayLike | None,
                 sigma: ArrayLike, model: SegmentModel):
        self.model = model
        self._nominal_theta = initial_theta(initial, model)
        self.nominal = Params(*self._nominal_theta[:3])
        self.prior_std = as_prior_std(model, self._nominal_theta, prior_std)
        self.sigma = as_sigma(sigma)
        self.n_segments = 0

    def update(self, dphi_L: float, dphi_R: float, dx: float, dy: float, dtheta: float) -> None:
        """Fold in one segment: wheel increments (rad) and the measured increment (the
        sensor's motion in its frame at the segment's start; m, m, rad)."""
        values = (float(dphi_L), float(dphi_R), float(dx), float(dy), float(dtheta))
        if not all(map(math.isfinite, values)):
            raise ValueError("segment values must be finite")
        self._update(*values)
        self.n_segments += 1

    @abstractmethod
    def _update(self, dphi_L: float, dphi_R: float, dx: float, dy: float,
                dtheta: float) -> None:
        """Fold in one validated segment."""

    @property
    @abstractmethod
    def theta(self) -> FloatArray:
        """All P parameters of the model (m, rad; angles wrapped to (-pi, pi])."""

    @property
    @abstractmethod
    def covariance(self) -> FloatArray:
        """Posterior covariance of theta (P x P; m^2, m rad, rad^2)."""

    @property
    @abstractmethod
    def information(self) -> FloatArray:
        """The data's dimensionless Fisher information (P x P, prior excluded, columns scaled
        at ``initial``, DESIGN.md)."""

    @property
    def params(self) -> Params:
        """The wheel parameters (r_L, r_R, b) in m."""
        return Params(*self.theta[:3])

    @property
    def sensor_pose(self) -> SensorPose | None:
        """The sensor pose (None on models without one)."""
        return self.model.split(self.theta)[1]

    @property
    def sigma_min(self) -> float:
        """Smallest singular value of the data's relative Jacobian, sqrt(lambda_min(F))."""
        return sigma_min(self.information)
