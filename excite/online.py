"""Online estimation of (r_L, r_R, b): an iterated extended information filter.

Each segment updates the estimate and its information matrix at constant cost (pure-Python
3x3 arithmetic: microseconds, independent of how many segments came before).

The filter runs on log-parameters q = log p. The heading change is invariant under a common
scale of (r_L, r_R, b); in q that invariant direction is (1, 1, 1) wherever the estimate is,
so the (often very precise) heading information summarised at early, rough estimates does not
leak into the scale, which is what makes a filter in p drift from the batch solution.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.information import DEFAULT_SIGMA, as_sigma, inverse_information, sigma_min
from excite.kinematics import Params, sinc_cosc_scalar

__all__ = ["OnlineEstimator"]

_TWO_PI = 2.0 * math.pi
#: Trust region: one segment may change no parameter by more than a factor exp(0.5).
_MAX_LOG_STEP = 0.5


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


class OnlineEstimator:
    """Recursive estimate of p = (r_L, r_R, b) from one segment at a time.

    Information form with an iterated update (Gauss–Newton on each new segment, the past
    summarised by the current estimate and its information matrix) in log-parameters: after
    the last segment it agrees with :func:`excite.calibrate` on the same data to a small
    fraction of a standard deviation.

    initial: the nominal robot, the prior mean (Params or (r_L, r_R, b) in m).
    prior_std: prior standard deviation (m): a scalar for all three parameters or three
        values; None means 10% of ``initial``.
    sigma: measurement noise (sigma_x [m], sigma_y [m], sigma_theta [rad]).
    iterations: Gauss–Newton iterations per update (1 = extended information filter).

    Attributes after updates: ``params`` (Params), ``covariance`` (3x3, m^2, posterior),
    ``information`` (3x3, dimensionless: the data's whitened Fisher information with columns
    scaled by ``initial``, DESIGN.md), ``sigma_min`` (its smallest singular value),
    ``n_segments``.
    """

    def __init__(
        self,
        initial: Params | ArrayLike,
        prior_std: float | ArrayLike | None = None,
        sigma: ArrayLike = DEFAULT_SIGMA,
        iterations: int = 2,
    ):
        nominal = initial if isinstance(initial, Params) else Params.from_array(initial)
        self.nominal = nominal
        scale = nominal.as_array()
        std = 0.1 * scale if prior_std is None else np.broadcast_to(
            np.asarray(prior_std, dtype=float), (3,))
        if not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise ValueError(f"prior_std must be positive and finite, got {prior_std}")
        if iterations < 1:
            raise ValueError("iterations must be at least 1")
        self.sigma = as_sigma(sigma)
        self._w = [float(x) for x in 1.0 / self.sigma**2]
        self._iterations = int(iterations)
        self._prior = np.diag((scale / std) ** 2)  # information of log p
        self._q = [math.log(x) for x in scale]
        self._info = [[float(x) for x in row] for row in self._prior]
        self.n_segments = 0

    def update(self, dphi_L: float, dphi_R: float, dx: float, dy: float, dtheta: float) -> None:
        """Fold in one segment: wheel increments (rad) and measured body-frame increment."""
        phi_L, phi_R = float(dphi_L), float(dphi_R)
        zx, zy, zt = float(dx), float(dy), float(dtheta)
        if not all(map(math.isfinite, (phi_L, phi_R, zx, zy, zt))):
            raise ValueError("segment values must be finite")
        wx, wy, wt = self._w
        q0, q1, q2 = self._q
        (a00, a01, a02), (_, a11, a12), (_, _, a22) = self._info
        x0, x1, x2 = q0, q1, q2  # the iterate, in log-parameters
        for _ in range(self._iterations):
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
            if largest > _MAX_LOG_STEP:  # trust region
                shrink = _MAX_LOG_STEP / largest
                s0, s1, s2 = s0 * shrink, s1 * shrink, s2 * shrink
            x0, x1, x2 = q0 + s0, q1 + s1, q2 + s2
        if math.isfinite(x0 + x1 + x2 + m00 + m01 + m02 + m11 + m12 + m22):
            self._q = [x0, x1, x2]
            self._info = [[m00, m01, m02], [m01, m11, m12], [m02, m12, m22]]
        self.n_segments += 1

    @property
    def params(self) -> Params:
        q0, q1, q2 = self._q
        return Params(math.exp(q0), math.exp(q1), math.exp(q2))

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Posterior covariance of (r_L, r_R, b) in m^2 (first order from log-parameters)."""
        p = self.params.as_array()
        return inverse_information(np.array(self._info)) * np.outer(p, p)

    @property
    def information(self) -> NDArray[np.float64]:
        """The data's dimensionless Fisher information (prior excluded, columns scaled by
        ``initial``)."""
        ratio = self.nominal.as_array() / self.params.as_array()
        return (np.array(self._info) - self._prior) * np.outer(ratio, ratio)

    @property
    def sigma_min(self) -> float:
        return sigma_min(self.information)
