"""Online estimation of a segment model's parameters: an iterated extended information filter.

Each segment updates the estimate and its information matrix at constant cost (P x P
arithmetic, independent of how many segments came before).

The filter runs on log-parameters q = log p. The heading change is invariant under a common
scale of (r_L, r_R, b); in q that invariant direction is (1, 1, 1) wherever the estimate is,
so the (often very precise) heading information summarised at early, rough estimates does not
leak into the scale, which is what makes a filter in p drift from the batch solution.

One update in three forms, all on a :class:`FilterChart` (the chart and the filter's fixed
settings): the reference :func:`update_batch` (N independent filters, each fed its own
segment, in one pass of array code on the segment model's ``evaluate``; run by
:class:`BatchOnlineEstimator`, the vector environment's estimator) and two fast forms for one
filter, where numpy's per-call overheads would dominate, run by :class:`OnlineEstimator`:
:func:`update_scalar` (any model, evaluated in pure Python, with P x P numpy algebra) and
:func:`update_axle_scalar` (the axle model unrolled in pure Python: the single environment's
hot path). tests/unit/core/test_fast_forms.py holds both equal to the reference.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core.information import DEFAULT_SIGMA, as_sigma, inverse_information
from excite.core.kinematics import Params, sinc_family_scalar
from excite.core.models import AXLE, SegmentModel
from excite.errors import EstimatorError
from excite.estimators.base import MAX_CHART_STEP, SegmentEstimator, as_prior_std, initial_theta

__all__ = ["BatchOnlineEstimator", "FilterChart", "OnlineEstimator", "update_axle_scalar",
           "update_batch", "update_scalar"]

FloatArray = NDArray[np.float64]
_TWO_PI = 2.0 * math.pi
#: A second Gauss–Newton iteration is taken only after a first step larger than this (in the
#: chart's units): smaller steps change the linearization by far less than the posterior std.
_RELINEARIZE = 1e-3


def _wrap(a: float) -> float:
    """Wrap an angle (rad) to (-pi, pi]."""
    return math.pi - (math.pi - a) % _TWO_PI


class FilterChart:
    """The chart an information filter on a segment model runs in, and its fixed settings
    (shared by :class:`OnlineEstimator` and :class:`BatchOnlineEstimator`).

    The chart: q = log theta for a length (``log`` transform), theta / unit for the others
    (offsets in units of the nominal b, angles in rad).

    model: the segment model; nominal (P,): the prior mean (m, rad); prior_std (P,): the
    prior standard deviation (the parameters' units); sigma (3,): the measurement noise
    (sigma_x [m], sigma_y [m], sigma_theta [rad]); iterations: the most Gauss–Newton
    iterations per update (1 = extended information filter; EstimatorError below 1).

    Attributes: ``model``, ``iterations``; ``units`` (P,): the chart's unit of each parameter
    (m or rad), NaN for a log parameter; ``scale`` (P,): the model's column scale at the
    nominal (docs/conventions.md); ``weights`` (3,): 1 / sigma^2 of the measured (dx, dy,
    dtheta); ``start`` (P,): the prior mean in the chart; ``prior`` (P, P): the prior's
    information in the chart.
    """

    def __init__(self, model: SegmentModel, nominal: FloatArray, prior_std: FloatArray,
                 sigma: FloatArray, iterations: int):
        if iterations < 1:
            raise EstimatorError("iterations must be at least 1")
        self.model = model
        self.iterations = int(iterations)
        self.scale = model.column_scale(nominal)
        self._log = [t == "log" for t in model.transforms]
        self._unit_values = self.scale.tolist()
        self.units = np.where(self._log, np.nan, self.scale)
        self._is_log = np.isnan(self.units)
        self.weights = 1.0 / np.asarray(sigma, dtype=float) ** 2
        self.start = np.array([math.log(x) if log else x / c for x, log, c in
                               zip(nominal.tolist(), self._log, self._unit_values, strict=True)])
        self.prior = np.diag((self.derivative(nominal) / prior_std) ** 2)

    def to_theta(self, q: FloatArray) -> FloatArray:
        """The parameters theta (..., P) of chart coordinates q (..., P): exp(q) for a log
        parameter, else q times the chart's unit (m or rad)."""
        is_log = self._is_log
        if is_log.all():
            return np.exp(q)
        return np.where(is_log, np.exp(np.where(is_log, q, 0.0)), q * self.units)

    def to_theta_scalar(self, q: Sequence[float]) -> tuple[float, ...]:
        """:meth:`to_theta` of one filter's P floats, in pure Python (math's exp): the one-filter
        updates' form."""
        return tuple(math.exp(x) if log else x * c
                     for x, log, c in zip(q, self._log, self._unit_values, strict=True))

    def derivative(self, theta: ArrayLike) -> FloatArray:
        """d theta / d q (..., P) at parameters theta (..., P): the value for a log parameter,
        else the chart's unit."""
        return np.where(self._is_log, theta, self.units)

    def information(self, info: ArrayLike, theta: ArrayLike) -> FloatArray:
        """The data's dimensionless Fisher information (..., P, P) of filters with information
        ``info`` (..., P, P) in the chart at parameters theta (..., P): the prior removed,
        columns scaled at the nominal (docs/conventions.md)."""
        ratio = self.scale / self.derivative(theta)
        return (info - self.prior) * (ratio[..., :, None] * ratio[..., None, :])


def update_batch(chart: FilterChart, q: FloatArray, info: FloatArray,
                 rows: FloatArray) -> tuple[FloatArray, FloatArray]:
    """One segment folded into each of N independent filters, batch-first: the iterated
    update (Gauss–Newton on the new segment, the past summarised by the estimate and its
    information; a trust region of ``MAX_CHART_STEP`` per parameter) of the module doc.

    chart: the filters' chart and settings; q (N, P): the estimates in the chart; info
    (N, P, P): their information in the chart; rows (N, 5): each filter's segment (dphi_L,
    dphi_R [rad], dx, dy [m], dtheta [rad]). At most ``chart.iterations`` iterations (a
    filter stops after a step below ``_RELINEARIZE``). Returns the new (q, info); a filter
    whose update is not finite keeps its old values.
    """
    weights = chart.weights
    x, m = q, info
    live = None  # the filters still iterating (None: all)
    for iteration in range(chart.iterations):
        if live is None:
            q_live, info_live, rows_live, x_live = q, info, rows, x
        else:
            q_live, info_live, rows_live, x_live = q[live], info[live], rows[live], x[live]
        theta = chart.to_theta(x_live)
        prediction, jac = chart.model.evaluate(rows_live[:, :1], rows_live[:, 1:2], theta)
        derivative = chart.derivative(theta)
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


def update_scalar(chart: FilterChart, q: list[float], info: ArrayLike, phi_L: float,
                  phi_R: float, zx: float, zy: float, zt: float
                  ) -> tuple[list[float], ArrayLike]:
    """:func:`update_batch` of one filter, any model: the estimate q (P floats) and its
    information ``info`` (P x P) in the chart, the segment's wheel increments (rad) and
    measured increment (m, m, rad). The model in pure Python (``evaluate_scalar``), the
    P x P algebra in numpy. Returns the new (q, info), or the old where the update is not
    finite or its system singular."""
    weights = chart.weights
    prior_q = np.array(q)
    prior_info = np.asarray(info)
    x = prior_q
    for iteration in range(chart.iterations):
        theta = chart.to_theta_scalar(x.tolist())
        (px, py, pt), rows = chart.model.evaluate_scalar(phi_L, phi_R, theta)
        h = np.array(rows) * chart.derivative(theta)
        weighted = h * weights[:, None]
        innovation = np.array((zx - px, zy - py, _wrap(zt - pt))) + h @ (x - prior_q)
        m = prior_info + weighted.T @ h
        try:
            step = np.linalg.solve(m, weighted.T @ innovation)
        except np.linalg.LinAlgError:
            return q, info
        largest = max(map(abs, step.tolist()))
        if largest > MAX_CHART_STEP:  # trust region
            step *= MAX_CHART_STEP / largest
        previous, x = x, prior_q + step
        change = largest if iteration == 0 else max(map(abs, (x - previous).tolist()))
        if change < _RELINEARIZE:
            break
    new_q = x.tolist()
    if math.isfinite(sum(new_q) + float(np.trace(m))):  # PSD: a finite diagonal bounds m
        return new_q, m
    return q, info


def update_axle_scalar(chart: FilterChart, q: list[float], info: list[list[float]],
                       phi_L: float, phi_R: float, zx: float, zy: float, zt: float
                       ) -> tuple[list[float], list[list[float]]]:
    """:func:`update_batch` of one filter of the axle model (log-parameters of (r_L, r_R,
    b)), unrolled in pure Python: q (3 floats) and ``info`` (3 lists of 3 floats) as
    :func:`update_scalar`, and its returns."""
    wx, wy, wt = chart.weights.tolist()
    q0, q1, q2 = q
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = info
    x0, x1, x2 = q0, q1, q2  # the iterate, in log-parameters
    for iteration in range(chart.iterations):
        b = math.exp(x2)
        s_L, s_R = math.exp(x0) * phi_L, math.exp(x1) * phi_R  # wheel travel (m)
        ds, th = 0.5 * (s_L + s_R), (s_R - s_L) / b
        f, g, fp, gp = sinc_family_scalar(th)
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
        return [x0, x1, x2], [[m00, m01, m02], [m01, m11, m12], [m02, m12, m22]]
    return q, info


def _solve3(m00: float, m01: float, m02: float, m11: float, m12: float, m22: float,
            v0: float, v1: float, v2: float) -> tuple[float, float, float]:
    """Solve the symmetric positive-definite 3x3 system m x = v (Cramer's rule)."""
    c00, c01, c02 = m11 * m22 - m12 * m12, m02 * m12 - m01 * m22, m01 * m12 - m02 * m11
    c11, c12, c22 = m00 * m22 - m02 * m02, m01 * m02 - m00 * m12, m00 * m11 - m01 * m01
    det = m00 * c00 + m01 * c01 + m02 * c02
    return ((c00 * v0 + c01 * v1 + c02 * v2) / det,
            (c01 * v0 + c11 * v1 + c12 * v2) / det,
            (c02 * v0 + c12 * v1 + c22 * v2) / det)


def _solve_each(m: FloatArray, v: FloatArray) -> FloatArray:
    """x with m x = v for stacks m (N, P, P), v (N, P, 1); NaN for a singular m."""
    try:
        return np.linalg.solve(m, v)
    except np.linalg.LinAlgError:  # some m singular: solve one by one
        out = np.full_like(v, np.nan)
        for i in range(len(m)):
            with contextlib.suppress(np.linalg.LinAlgError):
                out[i] = np.linalg.solve(m[i], v[i])
        return out


class OnlineEstimator(SegmentEstimator):
    """Recursive estimate of a segment model's parameters (default: the axle model's
    p = (r_L, r_R, b)) from one segment at a time.

    Information form with an iterated update (Gauss–Newton on each new segment, the past
    summarised by the current estimate and its information matrix) in the model's chart
    (:class:`FilterChart`): log-parameters for lengths (the heading is invariant under a
    common scale of (r_L, r_R, b), and in log-parameters that direction is (1, 1, 1) wherever
    the estimate is, so the precise heading information gathered at rough early estimates
    does not leak into the scale), offsets in units of the nominal b, angles in rad. After
    the last segment it agrees with :func:`excite.calibrate` on the same data to a small
    fraction of a standard deviation. The update is :func:`update_axle_scalar` on the axle
    model, :func:`update_scalar` on the others.

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
    ``n_segments``; ``chart`` (:class:`FilterChart`).
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
        self.chart = FilterChart(model, self._nominal_theta, self.prior_std, self.sigma,
                                 iterations)
        self._q = self.chart.start.tolist()
        self._info = self.chart.prior.tolist()
        self._step = update_axle_scalar if model is AXLE else update_scalar

    def _update(self, phi_L: float, phi_R: float, zx: float, zy: float, zt: float) -> None:
        self._q, self._info = self._step(self.chart, self._q, self._info, phi_L, phi_R, zx,
                                         zy, zt)

    @property
    def theta(self) -> FloatArray:
        """All P parameters of the model (angles wrapped to (-pi, pi])."""
        theta = np.array(self.chart.to_theta_scalar(self._q))
        for i, transform in enumerate(self.model.transforms):
            if transform == "angle":
                theta[i] = _wrap(theta[i])
        return theta

    @property
    def params(self) -> Params:
        return Params(*self.chart.to_theta_scalar(self._q)[:3])

    @property
    def covariance(self) -> FloatArray:
        """Posterior covariance of theta (P x P; m^2, m rad, rad^2; first order from the
        chart)."""
        d = self.chart.derivative(self.chart.to_theta_scalar(self._q))
        return inverse_information(np.array(self._info)) * np.outer(d, d)

    @property
    def information(self) -> FloatArray:
        """The data's dimensionless Fisher information (prior excluded, columns scaled at
        ``initial``, docs/conventions.md)."""
        return self.chart.information(np.array(self._info),
                                      self.chart.to_theta_scalar(self._q))


class BatchOnlineEstimator:
    """N independent :class:`OnlineEstimator` filters with the same settings, each fed its
    own segments, updated together in array code (:func:`update_batch`): the vector
    environment's estimator, one per robot.

    n: the number of filters; initial, prior_std, sigma, iterations, model: as
    :class:`OnlineEstimator` (shared by all). Filter i after the segments given to it is
    OnlineEstimator after the same segments up to rounding (tested): the one-filter forms
    order their arithmetic differently and take math's exp, this numpy's.

    Attributes: ``model``, ``chart`` (:class:`FilterChart`), ``n_segments`` (N,).
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
        nominal = initial_theta(initial, model)
        self.chart = FilterChart(model, nominal, as_prior_std(model, nominal, prior_std),
                                 as_sigma(sigma), iterations)
        self.model = model
        self._q = np.tile(self.chart.start, (n, 1))
        self._info = np.tile(self.chart.prior, (n, 1, 1))
        self.n_segments = np.zeros(n, dtype=int)
        self._angles = [i for i, t in enumerate(model.transforms) if t == "angle"]

    def reset(self, mask: NDArray[np.bool_]) -> None:
        """Start the filters of ``mask`` (N,) anew, at the prior."""
        self._q[mask] = self.chart.start
        self._info[mask] = self.chart.prior
        self.n_segments[mask] = 0

    def update(self, rows: ArrayLike, mask: NDArray[np.bool_]) -> None:
        """Fold segment ``rows[i]`` (dphi_L, dphi_R [rad], dx, dy [m], dtheta [rad]) into
        filter i for each i of ``mask`` (N,) (the other rows are ignored)."""
        rows = np.asarray(rows, dtype=float)
        every = bool(mask.all())
        if not every:
            rows = rows[mask]
        if not np.isfinite(rows).all():
            raise ValueError("segment values must be finite")
        q, info = update_batch(self.chart, self._q if every else self._q[mask],
                               self._info if every else self._info[mask], rows)
        if every:
            self._q, self._info = q, info
        else:
            self._q[mask], self._info[mask] = q, info
        self.n_segments += mask

    @property
    def theta(self) -> FloatArray:
        """Every filter's P parameters (N, P) (m, rad; angles wrapped to (-pi, pi])."""
        theta = self.chart.to_theta(self._q)
        if self._angles:
            theta[:, self._angles] = _wrap(theta[:, self._angles])
        return theta

    @property
    def information(self) -> FloatArray:
        """Every filter's dimensionless Fisher information (N, P, P), as
        :attr:`OnlineEstimator.information`."""
        return self.chart.information(self._info, self.chart.to_theta(self._q))
