"""A reference baseline: the textbook extended Kalman filter on the parameters themselves.

State theta = (r_L, r_R, b) in m (and l_x, l_y [m], l_theta [rad] on the sensor-pose
model), constant (no process noise); covariance P in the same units. One update per
segment, linearised once at the estimate before the segment (the segment model's prediction
and Jacobian, :mod:`excite.core.models`):

    y = z - h(theta) (heading wrapped),  S = H P H^T + R,  K = P H^T S^-1,
    theta <- theta + K y (angles wrapped),  P <- (I - K H) P (I - K H)^T + K R K^T (Joseph).

How it differs from :class:`excite.OnlineEstimator` (the iterated information filter on
log-parameters): the heading change dtheta = (r_R dphi_R - r_L dphi_L) / b is invariant
under a common scale of (r_L, r_R, b) and is measured very precisely. Here each heading
Jacobian is taken at the estimate of its time, so while the scale is still wrong the
precise heading information lands on directions that are not the invariant direction at
the truth: it leaks into the scale, which becomes over-confident (the filter under-reports
its error and drifts from the batch solution). The log-parameter filter keeps the invariant
direction fixed at (1, 1, 1) wherever the estimate is and re-linearises within each update;
this filter has neither protection (and no trust region), which is what makes it a
baseline: the comparison shows what they buy.

Tested (tests/unit/estimators/test_estimators.py): with the truth drawn from the default
10% prior its ANEES stays above the 95% chi-square bound for tens of segments, and where it
ends far from the batch estimate the offset lies along the common scale of (r_L, r_R, b);
with a 1% prior (Jacobians taken near the truth) it is consistent.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core.information import DEFAULT_SIGMA
from excite.core.kinematics import Params, wrap_angle
from excite.core.models import AXLE, SegmentModel
from excite.estimators.base import SegmentEstimator

__all__ = ["ExtendedKalmanFilter"]

FloatArray = NDArray[np.float64]


class ExtendedKalmanFilter(SegmentEstimator):
    """Extended Kalman filter in theta (module doc): constant cost per update (P x P algebra).

    Arguments as :class:`excite.estimators.base.SegmentEstimator`: ``initial`` (the prior
    mean, Params or P parameters), ``prior_std`` (parameter units; None: 10% of lengths,
    0.1 b for offsets, 0.5 rad for angles), ``sigma`` (sigma_x [m], sigma_y [m],
    sigma_theta [rad]) and ``model``. The filter itself knows no constraint: an update that
    would make r_L, r_R or b non-positive, or anything non-finite (absurd segments), is
    skipped.
    """

    def __init__(
        self,
        initial: Params | ArrayLike,
        prior_std: float | ArrayLike | None = None,
        sigma: ArrayLike = DEFAULT_SIGMA,
        model: SegmentModel = AXLE,
    ):
        super().__init__(initial, prior_std, sigma, model)
        self._theta = self._nominal_theta.copy()
        self._covariance = np.diag(self.prior_std**2)
        self._noise = np.diag(self.sigma**2)
        self._angles = np.array([t == "angle" for t in model.transforms])
        self._lengths = np.array([t == "log" for t in model.transforms])
        self._eye = np.eye(model.size)

    def _update(self, dphi_L: float, dphi_R: float, dx: float, dy: float,
                dtheta: float) -> None:
        (px, py, pt), rows = self.model.evaluate_scalar(dphi_L, dphi_R,
                                                        tuple(self._theta.tolist()))
        h = np.array(rows)
        innovation = np.array([dx - px, dy - py, float(wrap_angle(dtheta - pt))])
        ph = self._covariance @ h.T
        gain = np.linalg.solve(h @ ph + self._noise, ph.T).T  # P H^T S^-1 (S symmetric)
        theta = self._theta + gain @ innovation
        theta[self._angles] = wrap_angle(theta[self._angles])
        shrink = self._eye - gain @ h
        covariance = shrink @ self._covariance @ shrink.T + gain @ self._noise @ gain.T
        if math.isfinite(float(theta.sum() + covariance.sum())) and np.all(
                theta[self._lengths] > 0.0):
            self._theta, self._covariance = theta, 0.5 * (covariance + covariance.T)

    @property
    def theta(self) -> FloatArray:
        return self._theta.copy()

    @property
    def covariance(self) -> FloatArray:
        return self._covariance.copy()

    @property
    def information(self) -> FloatArray:
        data = np.linalg.inv(self._covariance) - np.diag(self.prior_std**-2.0)
        scale = self.model.column_scale(self._nominal_theta)
        return data * np.outer(scale, scale)
