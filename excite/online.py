"""Online estimation of a segment model's parameters: an iterated extended information filter.

Each segment updates the estimate and its information matrix at constant cost (pure-Python
P x P arithmetic: microseconds, independent of how many segments came before). The axle model
(r_L, r_R, b) has an unrolled 3x3 update (the environment's hot path), a tested
specialisation of the general update that serves every other model (the sensor-pose model).

The filter runs on log-parameters q = log p. The heading change is invariant under a common
scale of (r_L, r_R, b); in q that invariant direction is (1, 1, 1) wherever the estimate is,
so the (often very precise) heading information summarised at early, rough estimates does not
leak into the scale, which is what makes a filter in p drift from the batch solution.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.errors import EstimatorError
from excite.information import DEFAULT_SIGMA, inverse_information
from excite.kinematics import Params, sinc_cosc_scalar
from excite.models import AXLE, SegmentModel
from excite.segment_estimator import MAX_CHART_STEP, SegmentEstimator

__all__ = ["OnlineEstimator"]

_TWO_PI = 2.0 * math.pi
#: A second Gauss–Newton iteration is taken only after a first step larger than this (in the
#: chart's units): smaller steps change the linearization by far less than the posterior std.
_RELINEARIZE = 1e-3


def _wrap(a: float) -> float:
    """Wrap an angle (rad) to (-pi, pi]."""
    return math.pi - (math.pi - a) % _TWO_PI


def _solve3(m00: float, m01: float, m02: float, m11: float, m12: float, m22: float,
            v0: float, v1: float, v2: float) -> tuple[float, float, float]:
    """Solve the symmetric positive-definite 3x3 system m x = v (Cramer's rule)."""
    c00, c01, c02 = m11 * m22 - m12 * m12, m02 * m12 - m01 * m22, m01 * m12 - m02 * m11
    c11, c12, c22 = m00 * m22 - m02 * m02, m01 * m02 - m00 * m12, m00 * m11 - m01 * m01
    det = m00 * c00 + m01 * c01 + m02 * c02
    return ((c00 * v0 + c01 * v1 + c02 * v2) / det,
            (c01 * v0 + c11 * v1 + c12 * v2) / det,
            (c02 * v0 + c12 * v1 + c22 * v2) / det)


class OnlineEstimator(SegmentEstimator):
    """Recursive estimate of a segment model's parameters (default: the axle model's
    p = (r_L, r_R, b)) from one segment at a time.

    Information form with an iterated update (Gauss–Newton on each new segment, the past
    summarised by the current estimate and its information matrix) in the model's chart:
    log-parameters for lengths (the heading is invariant under a common scale of (r_L, r_R,
    b), and in log-parameters that direction is (1, 1, 1) wherever the estimate is, so the
    precise heading information gathered at rough early estimates does not leak into the
    scale), offsets in units of the nominal b, angles in rad. After the last segment it agrees
    with :func:`excite.calibrate` on the same data to a small fraction of a standard deviation.

    initial: the nominal robot, the prior mean: Params or the model's P parameters
        ((r_L, r_R, b) in m, then l_x, l_y [m], l_theta [rad] for the sensor-pose model).
    prior_std: prior standard deviation in the parameters' units: a scalar for all or P
        values; None means 10% of each length, 0.1 b for offsets and 0.5 rad for angles.
    sigma: measurement noise (sigma_x [m], sigma_y [m], sigma_theta [rad]).
    iterations: Gauss–Newton iterations per update (1 = extended information filter).
    model: the segment model (default :data:`excite.models.AXLE`).

    Attributes after updates: ``params`` (Params), ``sensor_pose`` (SensorPose or None),
    ``theta`` (all P parameters), ``covariance`` (P x P, posterior, in the parameters' units),
    ``information`` (P x P, dimensionless: the data's whitened Fisher information with columns
    scaled at ``initial``, DESIGN.md), ``sigma_min`` (its smallest singular value),
    ``n_segments``.
    """

    def __init__(
        self,
        initial: Params | ArrayLike,
        prior_std: float | ArrayLike | None = None,
        sigma: ArrayLike = DEFAULT_SIGMA,
        iterations: int = 2,
        model: SegmentModel = AXLE,
    ):
        super().__init__(initial, prior_std, sigma, model)
        if iterations < 1:
            raise EstimatorError("iterations must be at least 1")
        theta = self._nominal_theta
        # The chart's unit of each non-log parameter (offsets: the nominal b; angles: 1 rad).
        self._units = model.column_scale(theta).tolist()
        self._log = [t == "log" for t in model.transforms]
        chart_units = self._chart_derivative(theta.tolist())
        self._w = [float(x) for x in 1.0 / self.sigma**2]
        self._iterations = int(iterations)
        self._prior = np.diag((chart_units / self.prior_std) ** 2)  # information in the chart
        self._q = [math.log(x) if log else x / c
                   for x, log, c in zip(theta.tolist(), self._log, self._units, strict=True)]
        self._info = [[float(x) for x in row] for row in self._prior]
        if model is AXLE:  # the unrolled specialisation of _update_general
            self._update = self._update_axle
        self._w_array = np.array(self._w)[:, None]

    def _to_theta(self, q: list[float]) -> tuple[float, ...]:
        return tuple(math.exp(x) if log else x * c
                     for x, log, c in zip(q, self._log, self._units, strict=True))

    def _update_general(self, phi_L: float, phi_R: float, zx: float, zy: float,
                        zt: float) -> None:
        """The update for any model (P x P algebra in numpy; the model in pure Python)."""
        q = np.array(self._q)
        info = np.asarray(self._info)
        x = q
        for iteration in range(self._iterations):
            theta = self._to_theta(x.tolist())
            (px, py, pt), rows = self.model.evaluate_scalar(phi_L, phi_R, theta)
            h = np.array(rows) * self._chart_derivative(theta)
            weighted = h * self._w_array
            innovation = np.array((zx - px, zy - py, _wrap(zt - pt))) + h @ (x - q)
            m = info + weighted.T @ h
            try:
                step = np.linalg.solve(m, weighted.T @ innovation)
            except np.linalg.LinAlgError:
                return
            largest = max(map(abs, step.tolist()))
            if largest > MAX_CHART_STEP:  # trust region
                step *= MAX_CHART_STEP / largest
            previous, x = x, q + step
            change = largest if iteration == 0 else max(map(abs, (x - previous).tolist()))
            if change < _RELINEARIZE:
                break
        new_q = x.tolist()
        if math.isfinite(sum(new_q) + float(np.trace(m))):  # PSD: a finite diagonal bounds m
            self._q, self._info = new_q, m

    def _update_axle(self, phi_L: float, phi_R: float, zx: float, zy: float,
                     zt: float) -> None:
        """The axle model's update, unrolled (a specialisation of :meth:`_update_general`)."""
        wx, wy, wt = self._w
        q0, q1, q2 = self._q
        (a00, a01, a02), (_, a11, a12), (_, _, a22) = self._info
        x0, x1, x2 = q0, q1, q2  # the iterate, in log-parameters
        for iteration in range(self._iterations):
            b = math.exp(x2)
            s_L, s_R = math.exp(x0) * phi_L, math.exp(x1) * phi_R  # wheel travel (m)
            ds, th = 0.5 * (s_L + s_R), (s_R - s_L) / b
            f, g, fp, gp = sinc_cosc_scalar(th)
            # Model rows (dx, dy, dtheta) differentiated by log-parameters: d/dq = p d/dp.
            t0, t1, t2 = -s_L / b, s_R / b, -th
            e0, e1 = 0.5 * s_L, 0.5 * s_R
            kf, kg = ds * fp, ds * gp
            x_0, x_1, x_2 = e0 * f + kf * t0, e1 * f + kf * t1, kf * t2
            y_0, y_1, y_2 = e0 * g + kg * t0, e1 * g + kg * t1, kg * t2
            d0, d1, d2 = x0 - q0, x1 - q1, x2 - q2
            # Whitened innovations of the relinearized model around the prior.
            rx = wx * (zx - ds * f + x_0 * d0 + x_1 * d1 + x_2 * d2)
            ry = wy * (zy - ds * g + y_0 * d0 + y_1 * d1 + y_2 * d2)
            rt = wt * (_wrap(zt - th) + t0 * d0 + t1 * d1 + t2 * d2)
            m00 = a00 + wx * x_0 * x_0 + wy * y_0 * y_0 + wt * t0 * t0
            m01 = a01 + wx * x_0 * x_1 + wy * y_0 * y_1 + wt * t0 * t1
            m02 = a02 + wx * x_0 * x_2 + wy * y_0 * y_2 + wt * t0 * t2
            m11 = a11 + wx * x_1 * x_1 + wy * y_1 * y_1 + wt * t1 * t1
            m12 = a12 + wx * x_1 * x_2 + wy * y_1 * y_2 + wt * t1 * t2
            m22 = a22 + wx * x_2 * x_2 + wy * y_2 * y_2 + wt * t2 * t2
            s0, s1, s2 = _solve3(m00, m01, m02, m11, m12, m22,
                                 x_0 * rx + y_0 * ry + t0 * rt,
                                 x_1 * rx + y_1 * ry + t1 * rt,
                                 x_2 * rx + y_2 * ry + t2 * rt)
            largest = max(abs(s0), abs(s1), abs(s2))
            if largest > MAX_CHART_STEP:  # trust region
                shrink = MAX_CHART_STEP / largest
                s0, s1, s2 = s0 * shrink, s1 * shrink, s2 * shrink
            previous = (x0, x1, x2)
            x0, x1, x2 = q0 + s0, q1 + s1, q2 + s2
            change = largest if iteration == 0 else max(
                abs(x0 - previous[0]), abs(x1 - previous[1]), abs(x2 - previous[2]))
            if change < _RELINEARIZE:
                break
        if math.isfinite(x0 + x1 + x2 + m00 + m01 + m02 + m11 + m12 + m22):
            self._q = [x0, x1, x2]
            self._info = [[m00, m01, m02], [m01, m11, m12], [m02, m12, m22]]

    _update = _update_general  # any model; the axle model's instances use _update_axle

    @property
    def theta(self) -> NDArray[np.float64]:
        """All P parameters of the model (angles wrapped to (-pi, pi])."""
        theta = np.array(self._to_theta(self._q))
        for i, transform in enumerate(self.model.transforms):
            if transform == "angle":
                theta[i] = _wrap(theta[i])
        return theta

    @property
    def params(self) -> Params:
        return Params(*self._to_theta(self._q)[:3])

    def _chart_derivative(self, theta: Sequence[float]) -> NDArray[np.float64]:
        """d theta / d q at theta: the value for log parameters, else the chart's unit."""
        return np.array([t if log else c
                         for t, log, c in zip(theta, self._log, self._units, strict=True)])

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Posterior covariance of theta (P x P; m^2, m rad, rad^2; first order from the
        chart)."""
        d = self._chart_derivative(self._to_theta(self._q))
        return inverse_information(np.array(self._info)) * np.outer(d, d)

    @property
    def information(self) -> NDArray[np.float64]:
        """The data's dimensionless Fisher information (prior excluded, columns scaled at
        ``initial``, DESIGN.md)."""
        ratio = (self.model.column_scale(self._nominal_theta)
                 / self._chart_derivative(self._to_theta(self._q)))
        return (np.array(self._info) - self._prior) * np.outer(ratio, ratio)
