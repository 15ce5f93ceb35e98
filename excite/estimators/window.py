"""A reference baseline: a sliding-window batch estimator (fixed-lag smoother) with a
marginalised prior.

The estimator keeps the last W segments and re-solves, on every update, the maximum a
posteriori problem

    min_q  1/2 sum_{k in window} |z_k - h(theta(q), k)|^2_{R^-1}  +  1/2 q^T L q - eta^T q

by Gauss–Newton from the previous estimate. The quadratic term is the prior: the initial
Gaussian prior plus the information of every segment that has left the window. A segment
leaves (when the (W+1)-th arrives) by first-order marginalisation: its residual is
linearised at the estimate of that moment, e(q) ~ e_0 - J (q - q_0), and its information
J^T R^-1 J and information vector J^T R^-1 (J q_0 + e_0) are added to (L, eta). Nothing is
dropped: with W at least the number of segments this is the batch maximum a posteriori
estimate (the batch :func:`excite.calibrate` plus the prior), and with a shorter window it
differs only by the linearisation of the segments that left.

q is the chart of :class:`excite.OnlineEstimator`, the model's relative step from the
nominal parameters (:meth:`excite.core.models.SegmentModel.step`): log(theta / nominal) for
lengths, (theta - nominal) / nominal b for offsets, theta - nominal in rad for angles; the
prior information of the segments that left stays in the chart where the scale invariance
of the heading is the fixed direction (1, 1, 1) (module doc of :mod:`excite.estimators.online`).

Cost per update: a few evaluations of W segments (bounded, not constant: O(W)).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core.information import DEFAULT_SIGMA
from excite.core.kinematics import Params, wrap_angle
from excite.core.models import AXLE, SegmentModel
from excite.errors import EstimatorError
from excite.estimators.base import MAX_CHART_STEP, SegmentEstimator

__all__ = ["DEFAULT_WINDOW", "DEFAULT_WINDOW_ITERATIONS", "SlidingWindowSmoother"]

FloatArray = NDArray[np.float64]

#: Segments kept in the window: beyond a few tens of well-spread segments the estimate is
#: already within a fraction of its standard deviation of the batch one, so the linearisation
#: of those that leave costs little, while the cost per update grows with W.
DEFAULT_WINDOW = 50
#: Gauss–Newton iterations per update at most (warm-started: two or three usually suffice).
DEFAULT_WINDOW_ITERATIONS = 10
#: Gauss–Newton stops after a step shorter than this many posterior standard deviations
#: (the Newton decrement sqrt(step^T H step)); what remains is of the order of its square.
_TOLERANCE = 1e-3


class SlidingWindowSmoother(SegmentEstimator):
    """Sliding-window maximum a posteriori estimator with a marginalised prior (module doc).

    Arguments as :class:`excite.estimators.base.SegmentEstimator`: ``initial`` (the prior
    mean, Params or P parameters), ``prior_std`` (parameter units; None: 10% of lengths,
    0.1 b for offsets, 0.5 rad for angles), ``sigma`` (sigma_x [m], sigma_y [m],
    sigma_theta [rad]) and ``model``; plus ``size``, the window length W in segments, and
    ``iterations``, the most Gauss–Newton iterations per update. A Gauss–Newton step that
    is not finite or not solvable (absurd segments) ends the update where the estimate is.
    """

    def __init__(
        self,
        initial: Params | ArrayLike,
        prior_std: float | ArrayLike | None = None,
        sigma: ArrayLike = DEFAULT_SIGMA,
        model: SegmentModel = AXLE,
        size: int = DEFAULT_WINDOW,
        iterations: int = DEFAULT_WINDOW_ITERATIONS,
    ):
        super().__init__(initial, prior_std, sigma, model)
        if int(size) != size or size < 1:
            raise EstimatorError(f"window size must be a whole number of segments >= 1, "
                                 f"got {size}")
        if int(iterations) != iterations or iterations < 1:
            raise EstimatorError(f"iterations must be a whole number >= 1, got {iterations}")
        self.size, self.iterations = int(size), int(iterations)
        self._units = model.column_scale(self._nominal_theta)  # d theta / d q at nominal
        self._log = np.array([t == "log" for t in model.transforms])
        self._weights = self.sigma**-2.0
        self._initial_prior = np.diag((self._units / self.prior_std) ** 2)
        self._prior = self._initial_prior.copy()  # L, the prior's information in the chart
        self._prior_vector = np.zeros(model.size)  # eta (the initial prior's mean is q = 0)
        self._q = np.zeros(model.size)
        self._hessian = self._initial_prior.copy()  # of the last solve, at ``_q``
        self._window: deque[tuple[float, float, float, float, float]] = deque()

    def _theta_of(self, q: FloatArray) -> FloatArray:
        return self.model.step(self._nominal_theta, q, self._units)

    def _chart_derivative(self, theta: FloatArray) -> FloatArray:
        """d theta / d q at theta: the value for lengths, the chart's unit otherwise."""
        return np.where(self._log, theta, self._units)

    def _linearise(self, rows: FloatArray, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Residuals z - h (3, N; m, m, rad, heading wrapped) of the segments ``rows``
        (N, 5: dphi_L, dphi_R, dx, dy, dtheta) at q, and the derivatives d h / d q (3, P, N)."""
        theta = self._theta_of(q)
        prediction, jac = self.model.evaluate(rows[:, 0], rows[:, 1], theta)
        residual = rows[:, 2:].T - prediction
        residual[2] = wrap_angle(residual[2])
        jac = jac * self._chart_derivative(theta)[None, :, None]
        return residual, jac

    def _marginalise(self, row: tuple[float, float, float, float, float]) -> None:
        """Fold a segment leaving the window into the prior, linearised at the estimate."""
        residual, jac = self._linearise(np.array([row]), self._q)
        weighted = jac * self._weights[:, None, None]
        information = np.einsum("cin,cjn->ij", weighted, jac)
        vector = information @ self._q + np.einsum("cin,cn->i", weighted, residual)
        if np.all(np.isfinite(information)) and np.all(np.isfinite(vector)):
            self._prior += information
            self._prior_vector += vector

    def _update(self, dphi_L: float, dphi_R: float, dx: float, dy: float,
                dtheta: float) -> None:
        if len(self._window) == self.size:
            self._marginalise(self._window.popleft())
        self._window.append((dphi_L, dphi_R, dx, dy, dtheta))
        rows = np.array(self._window)
        q = self._q
        for _ in range(self.iterations):
            residual, jac = self._linearise(rows, q)
            weighted = jac * self._weights[:, None, None]
            hessian = self._prior + np.einsum("cin,cjn->ij", weighted, jac)
            gradient = (np.einsum("cin,cn->i", weighted, residual)
                        + self._prior_vector - self._prior @ q)  # minus the cost's gradient
            try:
                step = np.linalg.solve(hessian, gradient)
            except np.linalg.LinAlgError:  # numerically singular: absurd segments
                break
            largest = float(np.max(np.abs(step)))
            if not np.isfinite(largest):
                break
            if largest > MAX_CHART_STEP:  # trust region
                step *= MAX_CHART_STEP / largest
            q = q + step
            self._q, self._hessian = q, hessian
            if step @ hessian @ step < _TOLERANCE**2:
                break

    @property
    def theta(self) -> FloatArray:
        return self._theta_of(self._q)

    @property
    def covariance(self) -> FloatArray:
        d = self._chart_derivative(self.theta)
        return np.linalg.inv(self._hessian) * np.outer(d, d)

    @property
    def information(self) -> FloatArray:
        ratio = self._units / self._chart_derivative(self.theta)
        return (self._hessian - self._initial_prior) * np.outer(ratio, ratio)
