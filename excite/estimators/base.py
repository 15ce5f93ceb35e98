"""What every segment estimator shares (:class:`excite.OnlineEstimator` and the reference
estimators of :mod:`excite.estimators`): the start and prior checks, the chart's trust region,
and the estimator protocol's attributes around one abstract update (the environment and the
comparison read ``params``, ``covariance`` and, when present, ``theta``)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core.information import as_sigma, as_theta, sigma_min
from excite.core.kinematics import Params
from excite.core.models import SegmentModel, SensorPose
from excite.errors import EstimatorError

__all__ = ["DEFAULT_PRIOR", "MAX_CHART_STEP", "SegmentEstimator", "as_prior_std",
           "initial_theta"]

FloatArray = NDArray[np.float64]

#: Trust region: one segment may change no parameter by more than a factor exp(0.5) (or an
#: offset by 0.5 b, an angle by 0.5 rad).
MAX_CHART_STEP = 0.5
#: Default prior std, relative to the chart (module doc of excite.core.models): 10% of a length,
#: 0.1 b for an offset, 0.5 rad for an angle.
DEFAULT_PRIOR = {"log": 0.1, "identity": 0.1, "angle": 0.5}


def initial_theta(initial: Params | ArrayLike, model: SegmentModel) -> NDArray[np.float64]:
    """An estimator's starting point as the model's P parameters (a flat float array):
    Params gives (r_L, r_R, b) in m, then l_x, l_y [m], l_theta [rad] for the sensor-pose
    model."""
    theta = as_theta(initial).astype(float).reshape(-1)
    if theta.size != model.size:
        raise EstimatorError(f"initial must have the {model.size} parameters "
                             f"{', '.join(model.names)}, got {theta.size} values")
    return theta


def as_prior_std(model: SegmentModel, initial: NDArray[np.float64],
                 std: float | ArrayLike | None = None) -> NDArray[np.float64]:
    """The prior standard deviation (P,) of each parameter in its own units (m, rad) around
    ``initial`` (the P parameters): ``std`` a scalar for all or P values; None means
    :data:`DEFAULT_PRIOR` in the chart's units (10% of each length, 0.1 b for offsets,
    0.5 rad for angles)."""
    if std is None:
        out = np.array([DEFAULT_PRIOR[t] for t in model.transforms]) * model.column_scale(initial)
    else:
        out = np.broadcast_to(np.asarray(std, dtype=float), (model.size,))
    if not np.all(np.isfinite(out)) or np.any(out <= 0):
        raise EstimatorError(f"prior_std must be positive and finite, got {std}")
    return out


class SegmentEstimator(ABC):
    """An estimator of a segment model's P parameters theta, fed one segment at a time.

    initial: the nominal robot, the prior mean: Params or the model's P parameters
        ((r_L, r_R, b) in m, then l_x, l_y [m], l_theta [rad] for the sensor-pose model).
    prior_std: prior standard deviation in the parameters' units (scalar or P values); None:
        10% of each length, 0.1 b for offsets, 0.5 rad for angles (as
        :class:`excite.OnlineEstimator`).
    sigma: measurement noise (sigma_x [m], sigma_y [m], sigma_theta [rad]).
    model: the segment model (default :data:`excite.core.models.AXLE`).

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
        at ``initial``, docs/conventions.md)."""

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
