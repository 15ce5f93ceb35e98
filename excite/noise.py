"""Correlated measurement noise of segments cut from a log: each pose sample's noise enters
the two segments that share it.

Model (DESIGN.md, "Time-series logs"; frames: the sensor's world poses and its increments in
its own frame at each segment start). A segment's measured increment is
z_k = (-P_k) (+) P_{k+1} of two pose samples P = (p, theta), plus noise of its own:

* pose-sample noise, independent per sample: isotropic std ``sigma_xy`` (m) on p and
  ``sigma_theta`` (rad) on theta;
* segment noise, independent per segment (wheel slip, encoder quantisation, model error):
  std ``sigma`` = (x [m], y [m], theta [rad]).

Linearised at the measured increments d_k = (dx_k, dy_k) (J = rotation by +90 degrees,
R(a) = rotation by a, Delta_k = dtheta_k), the covariance of the stacked increments is
block tridiagonal over chains of segments that share their end and start samples:

    C_kk      = diag(sigma^2) + [[2 sxy^2 I + sth^2 (J d_k)(J d_k)^T,  sth^2 J d_k],
                                 [sth^2 (J d_k)^T,                    2 sth^2   ]]
    C_(k-1)k  = [[-sxy^2 R(Delta_(k-1)),  0     ],
                 [-sth^2 (J d_k)^T,       -sth^2]]          (only when k is chained to k-1)

:class:`ChainWhitener` factors C (banded Cholesky, bandwidth 5, O(N)) and whitens residuals
and Jacobians, so that the weighted least-squares fit is the (linearised) maximum-likelihood
fit under this model. :func:`reml_noise` estimates the five noise levels by restricted maximum
likelihood (REML: the likelihood of the residuals with the fitted parameters integrated out, so
the levels are not biased low by the fit), with the log-determinant of C from the same factor;
:func:`moment_noise` gives its starting point from the residuals' lag-0 and lag-1 moments.

A segment noise that is truly 0 (a log without slip) is visible only at the lowest
frequencies, where the pose noise telescopes away, so its unconstrained REML levels are often
well above 0; a spurious segment level then outweighs the pose noise over long stretches (it
raised the RMSE of r_L, r_R and b by 25-50% on the ideal env's logs, benchmarks/bench_logs.py).
:func:`reml_noise` therefore tests the hypothesis "no segment noise" (all three segment
levels 0, the pose noise alone) by the restricted likelihood ratio; three variance components
on the boundary of their space have a chi-bar-square null distribution, sum_k binom(3, k) / 8
chi2(k) for k = 0..3 (Self & Liang 1987). Unless the data reject it (at the 5% level), the
segment levels are held at their floor. In small samples this null is conservative (fewer
rejections than nominal: about 1% of the ideal env's logs keep their segment levels).
The test is joint, not per channel: slip enters through the wheels, so when any channel shows
it, the others carry it too (and a per-channel test drops real but weak x noise of slipping
logs: coverage 0.77 instead of 0.86 on synthetic slip).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from excite.data import Segments

__all__ = ["NoiseLevels", "ChainWhitener", "moment_noise", "reml_noise", "chi2_quantile",
           "chi2_survival", "chi_bar_square_quantile", "SEGMENT_NOISE_TEST_LEVEL"]

FloatArray = NDArray[np.float64]
_BAND = 5  # lower bandwidth of C in segment-major order (x, y, theta per segment)
#: Level of the test of "no segment noise" (:func:`reml_noise`): the segment levels are held
#: at their floor unless the data reject that hypothesis at this level.
SEGMENT_NOISE_TEST_LEVEL = 0.05


def chi2_quantile(q: float, dof: float) -> float:
    """The q-quantile of the chi-square distribution with ``dof`` degrees of freedom (scipy's
    special function, imported on first use: scipy.stats is too slow to import)."""
    from scipy.special import chdtri

    return float(chdtri(dof, 1.0 - q))


def chi2_survival(x: float, dof: float) -> float:
    """P(X > x) for X chi-square with ``dof`` degrees of freedom (scipy's special function,
    imported on first use)."""
    from scipy.special import chdtrc

    return float(chdtrc(dof, x))


def chi_bar_square_quantile(q: float, components: int) -> float:
    """The q-quantile (2^-n < q < 1) of the chi-bar-square distribution of the likelihood ratio
    for n = ``components`` orthogonal variance components on the boundary: the mixture
    sum_k binom(n, k) / 2^n chi2(k), k = 0..n (chi2(0) a point mass at 0)."""
    from scipy.optimize import brentq

    weights = [math.comb(components, k) / 2**components for k in range(1, components + 1)]

    def excess(x: float) -> float:
        return sum(w * chi2_survival(x, k) for k, w in enumerate(weights, start=1)) - (1.0 - q)

    return float(brentq(excess, 0.0, chi2_quantile(q, components)))


@dataclass(frozen=True)
class NoiseLevels:
    """sigma: segment noise std (x [m], y [m], theta [rad]); pose: pose-sample noise std
    (xy [m], theta [rad])."""

    sigma: FloatArray
    pose: FloatArray

    def close_to(self, other: NoiseLevels, rtol: float) -> bool:
        """Whether every level is within ``rtol`` of ``other``'s, or within 1e-3 of the
        largest level (levels near 0 need not settle relatively)."""
        a = np.concatenate([self.sigma, self.pose])
        b = np.concatenate([other.sigma, other.pose])
        return bool(np.all(np.abs(a - b) <= rtol * np.maximum(np.abs(b), 1e-300)
                           + 1e-3 * np.max(np.abs(b))))


def _perpendicular(segments: Segments) -> tuple[FloatArray, FloatArray]:
    """J d_k = (-dy_k, dx_k) (m)."""
    return -segments.dy, segments.dx


def _chained(segments: Segments) -> NDArray[np.bool_]:
    return (np.zeros(len(segments), dtype=bool) if segments.chained is None
            else segments.chained)


class ChainWhitener:
    """Whitening by the Cholesky factor of the covariance C of the stacked increments (see
    the module doc), for given noise levels."""

    def __init__(self, segments: Segments, levels: NoiseLevels):
        from scipy.linalg import cholesky_banded

        n = len(segments)
        sx2, sy2, st2 = levels.sigma**2
        pxy2, pth2 = levels.pose**2
        jx, jy = _perpendicular(segments)
        # lower band storage: band[i - j, j] = C[i, j] for i >= j, rows/cols 3k + channel
        band = np.zeros((_BAND + 1, 3 * n))
        diag = band[0].reshape(n, 3)
        diag[:, 0] = sx2 + 2 * pxy2 + pth2 * jx * jx
        diag[:, 1] = sy2 + 2 * pxy2 + pth2 * jy * jy
        diag[:, 2] = st2 + 2 * pth2
        band[1].reshape(n, 3)[:, 0] = pth2 * jx * jy  # C[y, x]
        band[1].reshape(n, 3)[:, 1] = pth2 * jy  # C[theta, y]
        band[2].reshape(n, 3)[:, 0] = pth2 * jx  # C[theta, x]
        chained = _chained(segments)
        if chained.any():
            k = np.flatnonzero(chained)  # block (k, k - 1): rows of segment k, cols of k - 1
            c, s = np.cos(segments.dtheta[k - 1]), np.sin(segments.dtheta[k - 1])
            # C[(k-1) rows, k cols] = [[-pxy2 R, 0], [-pth2 (J d_k)^T, -pth2]]; store its
            # transpose C[k rows, (k-1) cols] at offsets i - j = 3 + a - b.
            zero, c_xy, s_xy = np.zeros(k.size), pxy2 * c, pxy2 * s
            # entry (a, b) = C[3k + a, 3(k-1) + b] = block C_(k-1)k at (b, a); stored at
            # band offset i - j = 3 + a - b
            entries = {(0, 0): -c_xy, (0, 1): -s_xy, (1, 0): s_xy, (1, 1): -c_xy,
                       (2, 0): zero, (2, 1): zero,
                       (0, 2): -pth2 * jx[k], (1, 2): -pth2 * jy[k], (2, 2): zero - pth2}
            for (a, b), value in entries.items():
                band[3 + a - b, 3 * (k - 1) + b] = value
        self._factor = cholesky_banded(band, lower=True)
        self.n = n

    @property
    def log_det(self) -> float:
        """log det C (C in the units of the increments: m^2, rad^2)."""
        return 2.0 * float(np.sum(np.log(self._factor[0])))

    def whiten(self, raw: FloatArray, jac: FloatArray | None
               ) -> tuple[FloatArray, FloatArray | None]:
        """L^-1 of residuals (3, N) and Jacobian rows (3, P, N), in the same layouts: the
        innovations of segment k are column k."""
        from scipy.linalg import solve_banded

        n = self.n
        columns = [raw.T.reshape(3 * n, 1)]
        if jac is not None:
            p = jac.shape[1]
            columns.append(jac.transpose(2, 0, 1).reshape(3 * n, p))
        rhs = np.concatenate(columns, axis=1)
        out = solve_banded((_BAND, 0), self._factor, rhs, check_finite=False)
        white = out[:, 0].reshape(n, 3).T
        if jac is None:
            return white, None
        return white, out[:, 1:].reshape(n, 3, -1).transpose(1, 2, 0)


def moment_noise(segments: Segments, residual: FloatArray, n_parameters: int,
                 floor: FloatArray) -> NoiseLevels:
    """The five noise levels from residuals (3, N) of a fit (predicted - measured), by moments:
    lag-1 products over chained pairs give the pose-sample levels (E r_th,k-1 r_th,k =
    -sth^2; E r_xy,k-1^T R(Delta_k-1) r_xy,k = -2 sxy^2), the lag-0 moments the rest; the
    lag-0 moments are scaled by 3N / (3N - P) for the fitted parameters. Levels are >= 0;
    segment levels at least ``floor`` (3,)."""
    n = residual.shape[1]
    inflate = 3 * n / max(3 * n - n_parameters, 1)
    chained = np.flatnonzero(_chained(segments))
    pxy2 = pth2 = 0.0
    if chained.size:
        prev, cur = chained - 1, chained
        pth2 = max(0.0, -float(np.mean(residual[2, prev] * residual[2, cur])))
        c, s = np.cos(segments.dtheta[prev]), np.sin(segments.dtheta[prev])
        ax, ay = residual[0, prev], residual[1, prev]
        bx, by = residual[0, cur], residual[1, cur]
        rotated = ax * (c * bx - s * by) + ay * (s * bx + c * by)  # a^T R(Delta) b
        pxy2 = max(0.0, -0.5 * float(np.mean(rotated)))
    jx, jy = _perpendicular(segments)
    lag0 = inflate * np.mean(residual**2, axis=1)
    seg2 = lag0 - np.array([2 * pxy2 + pth2 * np.mean(jx * jx),
                            2 * pxy2 + pth2 * np.mean(jy * jy), 2 * pth2])
    sigma = np.maximum(np.sqrt(np.maximum(seg2, 0.0)), floor)
    return NoiseLevels(sigma, np.sqrt(np.array([pxy2, pth2])))


def _restricted_deviance(segments: Segments, levels: NoiseLevels, residual: FloatArray,
                         jac: FloatArray) -> float:
    """-2 log restricted likelihood (up to a constant) of residuals (3, N) with Jacobian rows
    (3, P, N) of the linearised model: log det C + log det(J^T C^-1 J) + e^T C^-1 e, with e
    the generalised least-squares residual (the parameters profiled out)."""
    whitener = ChainWhitener(segments, levels)
    white, white_jac = whitener.whiten(residual, jac)
    w = white.T.reshape(-1)
    a = white_jac.transpose(2, 0, 1).reshape(w.size, -1)
    factor = np.linalg.cholesky(a.T @ a)  # J^T C^-1 J = G G^T
    projected = np.linalg.solve(factor, a.T @ w)  # |G^-1 J^T C^-1 r|^2: the fitted part
    return (whitener.log_det + 2.0 * float(np.sum(np.log(np.diag(factor))))
            + float(w @ w - projected @ projected))


def reml_noise(segments: Segments, residual: FloatArray, jac: FloatArray,
               start: NoiseLevels, floor: FloatArray,
               test_level: float = SEGMENT_NOISE_TEST_LEVEL) -> NoiseLevels:
    """The five noise levels maximising the restricted likelihood of the residuals (3, N)
    (predicted - measured) of a fit whose Jacobian rows (3, P, N) span the fitted directions
    (only the directions the data determine). Optimised over the logs of the levels from
    ``start`` (L-BFGS-B); each level at least its floor: ``floor`` (3,) is (position,
    position, heading) and floors the segment levels and (position, heading) the pose levels.

    Then the hypothesis "no segment noise" is tested (see the module doc): the restricted
    deviance with the three segment levels at their floor (the pose levels re-optimised) minus
    the optimum's, against the (1 - ``test_level``)-quantile of the chi-bar-square
    distribution; if the data do not reject it, those levels are returned.
    """
    from scipy.optimize import minimize

    lower = np.log(np.concatenate([floor, floor[[0, 2]]]))
    u0 = np.maximum(np.log(np.maximum(np.concatenate([start.sigma, start.pose]), 1e-300)),
                    lower)
    spread = float(np.max(np.abs(residual))) if residual.size else 1.0
    upper = np.full(5, np.log(max(10.0 * spread, 1e-300)))
    u0 = np.minimum(u0, upper)

    def levels_of(u: FloatArray) -> NoiseLevels:
        sigma = np.exp(u)
        return NoiseLevels(sigma[:3], sigma[3:])

    def deviance(u: FloatArray) -> float:
        try:
            return _restricted_deviance(segments, levels_of(u), residual, jac)
        except np.linalg.LinAlgError:  # C numerically not positive definite at the bounds
            return 1e300  # finite: the optimiser's difference quotients stay numbers

    def optimum(start_u: FloatArray, fixed: NDArray[np.bool_]) -> tuple[FloatArray, float]:
        """The minimum of the deviance over the levels not ``fixed`` (5,) at their floor."""
        u = np.where(fixed, lower, start_u)
        free = np.flatnonzero(~fixed)
        start_value = deviance(u)

        def partial(v: FloatArray) -> float:
            full = u.copy()
            full[free] = v
            return deviance(full)

        result = minimize(partial, u[free], method="L-BFGS-B",
                          bounds=list(zip(lower[free], upper[free], strict=True)))
        if result.fun > start_value:
            return u, start_value
        u[free] = result.x
        return u, float(result.fun)

    u_hat, best = optimum(u0, np.zeros(5, dtype=bool))
    if np.any(u_hat[:3] > lower[:3]):
        u_null, null = optimum(u_hat, np.array([True, True, True, False, False]))
        if null - best < chi_bar_square_quantile(1.0 - test_level, 3):
            u_hat = u_null
    return levels_of(u_hat)
