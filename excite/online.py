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


def _model(p: list[float], phi_L: float, phi_R: float):
    """Predicted increment h(p) and its Jacobian rows H (d/d(r_L, r_R, b)) for one segment."""
    r_L, r_R, b = p
    s_L, s_R = r_L * phi_L, r_R * phi_R
    ds = 0.5 * (s_L + s_R)
    th = (s_R - s_L) / b
    f, g, fp, gp = sinc_cosc_scalar(th)
    dth = (-phi_L / b, phi_R / b, -th / b)
    dds = (0.5 * phi_L, 0.5 * phi_R, 0.0)
    kf, kg = ds * fp, ds * gp
    hx = [dds[i] * f + kf * dth[i] for i in range(3)]
    hy = [dds[i] * g + kg * dth[i] for i in range(3)]
    return (ds * f, ds * g, th), (hx, hy, dth)


def _solve3(m: list[list[float]], v: list[float]) -> list[float]:
    """Solve the symmetric positive-definite 3x3 system m x = v (Cramer's rule)."""
    (a, b, c), (_, d, e), (_, _, f) = m
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    x0, x1, x2 = v
    return [
        (c00 * x0 + c01 * x1 + c02 * x2) / det,
        (c01 * x0 + c11 * x1 + c12 * x2) / det,
        (c02 * x0 + c12 * x1 + c22 * x2) / det,
    ]


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
        z = (float(dx), float(dy), float(dtheta))
        if not all(map(math.isfinite, (phi_L, phi_R, *z))):
            raise ValueError("segment values must be finite")
        wx, wy, wt = self._w
        prior_q, prior_info = self._q, self._info
        q = prior_q
        for _ in range(self._iterations):
            p = [math.exp(qi) for qi in q]
            (px, py, pt), (hx, hy, ht) = _model(p, phi_L, phi_R)
            # Chain rule to log-parameters: d/dq_i = p_i d/dp_i.
            hx = [hx[i] * p[i] for i in range(3)]
            hy = [hy[i] * p[i] for i in range(3)]
            ht = [ht[i] * p[i] for i in range(3)]
            d = [q[i] - prior_q[i] for i in range(3)]
            yx = z[0] - px + hx[0] * d[0] + hx[1] * d[1] + hx[2] * d[2]
            yy = z[1] - py + hy[0] * d[0] + hy[1] * d[1] + hy[2] * d[2]
            yt = _wrap(z[2] - pt) + ht[0] * d[0] + ht[1] * d[1] + ht[2] * d[2]
            info = [
                [prior_info[i][j] + wx * hx[i] * hx[j] + wy * hy[i] * hy[j] + wt * ht[i] * ht[j]
                 for j in range(3)]
                for i in range(3)
            ]
            rhs = [wx * hx[i] * yx + wy * hy[i] * yy + wt * ht[i] * yt for i in range(3)]
            step = _solve3(info, rhs)
            largest = max(abs(x) for x in step)
            if largest > _MAX_LOG_STEP:
                step = [x * (_MAX_LOG_STEP / largest) for x in step]
            q = [prior_q[i] + step[i] for i in range(3)]
        if all(math.isfinite(x) for row in info for x in (*row, *q)):
            self._q, self._info = q, info
        self.n_segments += 1

    @property
    def params(self) -> Params:
        return Params(*(math.exp(qi) for qi in self._q))

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
