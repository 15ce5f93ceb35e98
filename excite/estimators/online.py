"""Online estimation of a segment model's parameters: an iterated extended information filter.

Each segment updates the estimate and its information matrix at constant cost (P x P
arithmetic, independent of how many segments came before). The general update is batch-first
(:func:`update_batch`: N independent filters, each fed its own segment, in one pass of array
code on the segment model's ``evaluate``), run by :class:`BatchOnlineEstimator` on N robots at
once (the vector environment's step). :class:`OnlineEstimator` runs tested specialisations of
it for one robot, where numpy's call overheads would dominate: the model in pure Python with
P x P numpy algebra for any model, and an unrolled pure-Python 3x3 update for the axle model
(r_L, r_R, b; the single environment's hot path).

The filter runs on log-parameters q = log p. The heading change is invariant under a common
scale of (r_L, r_R, b); in q that invariant direction is (1, 1, 1) wherever the estimate is,
so the (often very precise) heading information summarised at early, rough estimates does not
leak into the scale, which is what makes a filter in p drift from the batch solution.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core.information import DEFAULT_SIGMA, inverse_information
from excite.core.kinematics import Params, sinc_cosc_scalar
from excite.core.models import AXLE, SegmentModel
from excite.errors import EstimatorError
from excite.estimators.base import MAX_CHART_STEP, SegmentEstimator

__all__ = ["OnlineEstimator", "BatchOnlineEstimator", "update_batch"]

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
    model: the segment model (default :data:`excite.core.models.AXLE`).

    Attributes after updates: ``params`` (Params), ``sensor_pose`` (SensorPose or None),
    ``theta`` (all P parameters), ``covariance`` (P x P, posterior, in the parameters' units),
    ``information`` (P x P, dimensionless: the data's whitened Fisher information with columns
    scaled at ``initial``, docs/conventions.md), ``sigma_min`` (its smallest singular value),
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
        self._weights = np.array(self._w)  # 1 / sigma^2 of (dx, dy, dtheta)
        # The chart's unit of each parameter for update_batch: NaN marks a log parameter.
        self._units_array = np.where(self._log, np.nan, self._units)

    def _to_theta(self, q: list[float]) -> tuple[float, ...]:
        return tuple(math.exp(x) if log else x * c
                     for x, log, c in zip(q, self._log, self._units, strict=True))

    def _update_general(self, phi_L: float, phi_R: float, zx: float, zy: float,
                        zt: float) -> None:
        """The update for any model on one robot: :func:`update_batch` specialised to a
        batch of one (the model evaluated in pure Python, ``evaluate_scalar``, and P x P
        algebra in numpy: several times faster than the array code on one robot; tested
        against it)."""
        q = np.array(self._q)
        info = np.asarray(self._info)
        x = q
        for iteration in range(self._iterations):
            theta = self._to_theta(x.tolist())
            (px, py, pt), rows = self.model.evaluate_scalar(phi_L, phi_R, theta)
            h = np.array(rows) * self._chart_derivative(theta)
            weighted = h * self._weights[:, None]
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
        """The axle model's update, unrolled in pure Python (a specialisation of
        :func:`update_batch`, microseconds for one robot where numpy's call overheads would
        dominate; tested against it)."""
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
        ``initial``, docs/conventions.md)."""
        ratio = (self.model.column_scale(self._nominal_theta)
                 / self._chart_derivative(self._to_theta(self._q)))
        return (np.array(self._info) - self._prior) * np.outer(ratio, ratio)


def update_batch(model: SegmentModel, q: NDArray[np.float64], info: NDArray[np.float64],
                 rows: NDArray[np.float64], weights: NDArray[np.float64],
                 units: NDArray[np.float64], iterations: int
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One segment folded into each of N independent filters: the iterated update of
    :class:`OnlineEstimator` (Gauss–Newton on the new segment, the past summarised by the
    estimate and its information), batch-first.

    model: the segment model (prediction and Jacobian from its ``evaluate``); q (N, P): the
    estimates in the chart (log of lengths, offsets in units of the nominal b, angles in
    rad); info (N, P, P): their information in the chart; rows (N, 5): each filter's segment
    (dphi_L, dphi_R [rad], dx, dy [m], dtheta [rad]); weights (3,): 1 / sigma^2 of the
    measured (dx, dy, dtheta); units (P,): the chart's unit of each parameter (NaN for a log
    parameter); iterations: the most Gauss–Newton iterations (a filter stops after a step
    below ``_RELINEARIZE``). Returns the new (q, info); a filter whose update is not finite
    keeps its old values.
    """
    x, m = q, info
    live = None  # the filters still iterating (None: all)
    for iteration in range(iterations):
        if live is None:
            q_live, info_live, rows_live, x_live = q, info, rows, x
        else:
            q_live, info_live, rows_live, x_live = q[live], info[live], rows[live], x[live]
        theta = chart_to_theta(x_live, units)
        prediction, jac = model.evaluate(rows_live[:, :1], rows_live[:, 1:2], theta)
        derivative = chart_derivative(theta, units)
        h = jac[..., 0].transpose(2, 0, 1) * derivative[:, None, :]  # (n, 3, P)
        innovation = rows_live[:, 2:] - prediction[..., 0].T
        innovation[:, 2] = _wrap(innovation[:, 2])
        if iteration:  # relinearized around the prior's mean
            innovation += (h @ (x_live - q_live)[..., None])[..., 0]
        weighted_t = h.transpose(0, 2, 1) * weights  # (n, P, 3)
        m_live = info_live + weighted_t @ h
        step = _solve_each(m_live, weighted_t @ innovation[..., None])[..., 0]
        largest = np.abs(step).max(axis=1)
        step *= (MAX_CHART_STEP / np.maximum(largest, MAX_CHART_STEP))[:, None]  # trust region
        x_new = q_live + step
        change = largest if not iteration else np.abs(x_new - x_live).max(axis=1)
        going = ~(change < _RELINEARIZE)
        if live is None:
            x, m = x_new, m_live
            if not going.all():
                live = np.flatnonzero(going)
        else:
            x[live], m[live] = x_new, m_live
            live = live[going]
        if live is not None and not live.size:
            break
    finite = np.isfinite(x.sum(axis=1) + np.trace(m, axis1=1, axis2=2))
    if finite.all():
        return x, m
    return np.where(finite[:, None], x, q), np.where(finite[:, None, None], m, info)


def chart_to_theta(q: NDArray[np.float64], units: NDArray[np.float64]) -> NDArray[np.float64]:
    """The parameters theta (N, P) of chart coordinates q (N, P): exp(q) for a log parameter
    (``units`` NaN), else q times the chart's unit (m or rad)."""
    is_log = np.isnan(units)
    if is_log.all():
        return np.exp(q)
    return np.where(is_log, np.exp(np.where(is_log, q, 0.0)), q * units)


def chart_derivative(theta: NDArray[np.float64], units: NDArray[np.float64]
                     ) -> NDArray[np.float64]:
    """d theta / d q (N, P) at parameters theta (N, P): the value for a log parameter
    (``units`` NaN), else the chart's unit (the batch form of
    ``OnlineEstimator._chart_derivative``)."""
    return np.where(np.isnan(units), theta, units)


def _solve_each(m: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """x with m x = v for stacks m (N, P, P), v (N, P, 1); NaN for a singular m."""
    try:
        return np.linalg.solve(m, v)
    except np.linalg.LinAlgError:  # some m singular: solve one by one
        out = np.full_like(v, np.nan)
        for i in range(len(m)):
            with contextlib.suppress(np.linalg.LinAlgError):
                out[i] = np.linalg.solve(m[i], v[i])
        return out


class BatchOnlineEstimator:
    """N independent :class:`OnlineEstimator` filters with the same settings, each fed its
    own segments, updated together in array code (:func:`update_batch`): the vector
    environment's estimator, one per robot.

    n: the number of filters; initial, prior_std, sigma, iterations, model: as
    :class:`OnlineEstimator` (shared by all). Filter i after the segments given to it is
    OnlineEstimator after the same segments (tested): the same kernel on models other than
    the axle; on the axle model OnlineEstimator's unrolled update orders its arithmetic
    differently and takes Python's exp, so the estimates differ in the last bits (~1e-12
    relative after 30 segments; up to ~1e-9 where the normal equations are ill-conditioned:
    the slip id's final estimates, benchmarks/bench_equivalence.py).
    """

    def __init__(
        self,
        n: int,
        initial: Params | ArrayLike,
        prior_std: float | ArrayLike | None = None,
        sigma: ArrayLike = DEFAULT_SIGMA,
        iterations: int = 2,
        model: SegmentModel = AXLE,
    ):
        self._one = OnlineEstimator(initial, prior_std, sigma, iterations, model)
        self.model = model
        self._q = np.tile(self._one._q, (n, 1))
        self._info = np.tile(self._one._prior, (n, 1, 1))
        self.n_segments = np.zeros(n, dtype=int)
        self._angles = [i for i, t in enumerate(model.transforms) if t == "angle"]

    def reset(self, mask: NDArray[np.bool_]) -> None:
        """Start the filters of ``mask`` (N,) anew, at the prior."""
        self._q[mask] = self._one._q
        self._info[mask] = self._one._prior
        self.n_segments[mask] = 0

    def update(self, rows: ArrayLike, mask: NDArray[np.bool_]) -> None:
        """Fold segment ``rows[i]`` (dphi_L, dphi_R [rad], dx, dy [m], dtheta [rad]) into
        filter i for each i of ``mask`` (N,) (the other rows are ignored)."""
        rows = np.asarray(rows, dtype=float)
        one, every = self._one, bool(mask.all())
        if not every:
            rows = rows[mask]
        if not np.isfinite(rows).all():
            raise ValueError("segment values must be finite")
        q, info = update_batch(self.model, self._q if every else self._q[mask],
                               self._info if every else self._info[mask], rows,
                               one._weights, one._units_array, one._iterations)
        if every:
            self._q, self._info = q, info
        else:
            self._q[mask], self._info[mask] = q, info
        self.n_segments += mask

    @property
    def theta(self) -> NDArray[np.float64]:
        """Every filter's P parameters (N, P) (m, rad; angles wrapped to (-pi, pi])."""
        theta = chart_to_theta(self._q, self._one._units_array)
        if self._angles:
            theta[:, self._angles] = _wrap(theta[:, self._angles])
        return theta

    @property
    def information(self) -> NDArray[np.float64]:
        """Every filter's dimensionless Fisher information (N, P, P), as
        :attr:`OnlineEstimator.information`."""
        one = self._one
        theta = chart_to_theta(self._q, one._units_array)
        ratio = one.model.column_scale(one._nominal_theta) / chart_derivative(
            theta, one._units_array)
        return (self._info - one._prior) * ratio[:, :, None] * ratio[:, None, :]
