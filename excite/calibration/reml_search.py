"""The search of the restricted-likelihood noise levels (:func:`excite.calibration.reml.
reml_noise`): a projected Newton method over the squared levels within their bounds, with
the average information as its Hessian.

The restricted deviance D(v) = log det C + log det(J^T C^-1 J) + y^T P y of the residuals y
and Jacobian rows J, C = C_0 + sum_i v_i U_i linear in the squared levels v_i
(:class:`excite.calibration.noise.LevelBands`) and P = C^-1 - C^-1 J (J^T C^-1 J)^-1 J^T C^-1,
has the second derivatives 2 y^T P U_i P U_j P y - tr(P U_i P U_j), whose mean is
tr(P U_i P U_j): both are matched by the *average information* (Gilmour, Thompson & Cullis,
Biometrics 1995)

    H_ij = y^T P U_i P U_j P y = r_i^T r_j,   r_i = (I - a (a^T a)^-1 a^T) L^-1 U_i P y,

with L the Cholesky factor of C and a = L^-1 J: one more whitening of as many columns as
levels, the cost of about one evaluation of D. The search also serves a deviance that is not
linear in its parameters (the wandering heading's time constant,
:mod:`excite.calibration.wander`), given its gradient and average information. The gradient
of the banded deviance is taken by forward differences of D, a hundredth of each level's
standard error (1 / sqrt(H_ii)) long (D changes by about 1e-4 over it near the minimum: well
above its rounding, about 1e-5 on noise-free data, where C is ill-conditioned) and corrected
by half a step of its curvature: the trace terms of the exact gradient would need the band
of C^-1.

The search runs in the squared levels, not in their logs (where the callers' bounds are
given): a level whose best value is 0 has a deviance that flattens out as its log falls,
and a Newton step in the logs chases it down that plateau, while in v it reaches the floor
in one projected step. Each iteration: the levels at a bound whose gradient pushes them out
are held there; the others take the Newton step (the information scaled to unit diagonal,
its eigenvalues floored at EIGEN_FLOOR of the largest), projected onto the bounds and halved
until D falls by at least ARMIJO of the gradient's prediction. It ends when the Newton step
would gain less than DEVIANCE_TOLERANCE: D within about that of its minimum, far below one
unit of D (what moves a level by about its standard error). The caller falls back to
L-BFGS-B from where it stopped when it did not converge (far from the minimum, where D is
far from quadratic in v, within MAX_ITERATIONS). L-BFGS-B alone, with difference gradients
in the logs, took 30-40 iterations of as many evaluations per gradient and sometimes stopped
on such a plateau.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from excite.calibration.noise import ChainWhitener, LevelBands
from excite.core.arrays import BoolArray, FloatArray
from excite.core.banded import band_product

__all__ = ["DEVIANCE_TOLERANCE", "RestrictedDeviance", "newton_search", "restricted_deviance"]

#: The search ends when the Newton step's predicted gain in D is below this (deviance units).
DEVIANCE_TOLERANCE = 1e-4
#: Forward-difference step of the gradient, in standard errors of the squared level.
DIFFERENCE_STEP = 1e-2
#: The most Newton iterations before the search gives up (:func:`newton_search` returns
#: ``converged`` False and its caller falls back to a quasi-Newton search).
MAX_ITERATIONS = 40
#: Sufficient decrease of a step: D falls by at least this fraction of the gradient's
#: prediction for it.
ARMIJO = 1e-4
#: The smallest eigenvalue of the Newton system, as a fraction of the largest.
EIGEN_FLOOR = 1e-10
#: A value of D that stands for "not defined here" (C not positive definite).
UNDEFINED = 1e300


def restricted_deviance(band: FloatArray, rows: FloatArray) -> float:
    """-2 log restricted likelihood (up to a constant) of residuals with Jacobian rows of the
    linearised model, given as ``rows`` (3N, 1 + P) in the stacked order
    (:func:`excite.calibration.noise.stacked`), under the covariance ``band``
    (:func:`excite.calibration.noise.chain_band`): log det C + log det(J^T C^-1 J)
    + e^T C^-1 e, with e the generalised least-squares residual (the parameters profiled
    out). LinAlgError when C or J^T C^-1 J is not positive definite."""
    whitener = ChainWhitener.from_band(band)
    return _deviance_of(whitener, whitener.whiten_stacked(rows))


def _deviance_of(whitener: ChainWhitener, out: FloatArray) -> float:
    """:func:`restricted_deviance` from the whitener and the whitened rows."""
    w, a = out[:, 0], out[:, 1:]
    factor = np.linalg.cholesky(a.T @ a)  # J^T C^-1 J = G G^T
    projected = np.linalg.solve(factor, a.T @ w)  # |G^-1 J^T C^-1 r|^2: the fitted part
    return (whitener.log_det + 2.0 * float(np.sum(np.log(np.diag(factor))))
            + float(w @ w - projected @ projected))


class RestrictedDeviance:
    """D as a function of the logs of the levels u (in the order of the bands' units), and
    its average information (module docstring). The whitening of the last u evaluated is
    kept: the search asks the information where its line search has just evaluated D.

    Attributes
    ----------
    bands : LevelBands
        C as a function of the levels.
    rows : ndarray, shape (3N, 1 + P)
        The residuals and the Jacobian rows of the directions the data determine, stacked
        (:func:`excite.calibration.noise.stacked`).
    """

    def __init__(self, bands: LevelBands, rows: FloatArray):
        self.bands = bands
        self.rows = rows
        self._last: tuple[bytes, ChainWhitener, FloatArray] | None = None

    def _whitened(self, u: FloatArray) -> tuple[ChainWhitener, FloatArray]:
        """The whitener of C at log-levels u and the whitened rows (LinAlgError when C is
        not positive definite)."""
        key = np.asarray(u, dtype=float).tobytes()
        if self._last is None or self._last[0] != key:
            whitener = ChainWhitener.from_band(self.bands.at(np.exp(u)))
            self._last = (key, whitener, whitener.whiten_stacked(self.rows))
        return self._last[1], self._last[2]

    def __call__(self, u: FloatArray) -> float:
        """D at log-levels u; UNDEFINED where C is numerically not positive definite (at the
        bounds)."""
        try:
            return _deviance_of(*self._whitened(u))
        except np.linalg.LinAlgError:
            return UNDEFINED

    def information(self, u: FloatArray) -> FloatArray:
        """The average information of D in the squared levels v = exp(2 u) at log-levels u
        (len(u), len(u)). LinAlgError when C is not positive definite there."""
        whitener, out = self._whitened(u)
        w, a = out[:, 0], out[:, 1:]
        gram = a.T @ a
        beta = np.linalg.solve(gram, a.T @ w)
        py = whitener.solve(self.rows[:, :1] - self.rows[:, 1:] @ beta[:, None])  # P y
        moved = np.column_stack([band_product(unit, py) for unit in self.bands.units])
        white = whitener.whiten_stacked(moved)
        rest = white - a @ np.linalg.solve(gram, a.T @ white)
        return rest.T @ rest

    def estimated_levels_term(self, u: FloatArray, free: BoolArray) -> FloatArray:
        """Lambda (P, P), in the rows' units: how much the generalised least-squares
        estimate's covariance grows because the ``free`` levels (at log-levels u) were
        estimated from the same residuals (Kackar & Harville, JASA 1984; Kenward & Roger,
        Biometrics 1997):

            Lambda = Phi (sum_ij W_ij R_i^T R_j) Phi,   R_i = M L^-1 U_i C^-1 J,

        Phi = (J^T C^-1 J)^-1, M = I - a Phi a^T the projection off a = L^-1 J (so that
        R_i^T R_j = Q_ij - P_i Phi P_j in Kenward and Roger's notation) and W = 2 H^-1 the
        covariance of the free squared levels (H their average information, :meth:`information`:
        the restricted log-likelihood's information is H / 2). The estimate's covariance is
        about Phi + Lambda, and Phi at the estimated levels is low by about Lambda on average,
        so Kenward and Roger report Phi + 2 Lambda (their R_ij term is 0: C is linear in the
        squared levels). LinAlgError when C is not positive definite at u."""
        index = np.flatnonzero(free)
        whitener, out = self._whitened(u)
        a = out[:, 1:]
        gram = a.T @ a
        phi = np.linalg.inv(gram)
        c_inv_j = whitener.solve(self.rows[:, 1:])
        rest = []
        for i in index:
            white = whitener.whiten_stacked(band_product(self.bands.units[i], c_inv_j))
            rest.append(white - a @ (phi @ (a.T @ white)))
        weights = 2.0 * np.linalg.pinv(self.information(u)[np.ix_(index, index)])
        middle = sum(weights[i, j] * rest[i].T @ rest[j]
                     for i in range(index.size) for j in range(index.size))
        out = phi @ middle @ phi
        return 0.5 * (out + out.T)


def newton_search(deviance: Callable[[FloatArray], float],
                  information: Callable[[FloatArray], FloatArray], u0: FloatArray,
                  value0: float, free: BoolArray, lower: FloatArray, upper: FloatArray,
                  gradient: Callable[[FloatArray], FloatArray] | None = None
                  ) -> tuple[FloatArray, float, bool]:
    """The minimum of ``deviance`` (a function of the log-levels u) over the levels ``free``
    within [lower, upper] (log-levels), from u0 (inside the bounds; ``value0`` the deviance
    there), the others held: the log-levels, the deviance there and whether the search
    converged (module docstring). ``information``: the average information in the squared
    levels v = exp(2 u) at u (LinAlgError where it is not defined); ``gradient``: dD / dv at
    u, every level (None: by differences, module docstring)."""
    u, value = u0.copy(), float(value0)
    index = np.flatnonzero(free)
    if index.size == 0 or not value < UNDEFINED:
        return u, value, index.size == 0
    low, high = np.exp(2.0 * lower[index]), np.exp(2.0 * upper[index])

    def at(v: FloatArray) -> FloatArray:  # the log-levels of squared levels v of ``index``
        out = u.copy()
        out[index] = np.clip(0.5 * np.log(np.maximum(v, 1e-300)), lower[index], upper[index])
        return out

    for _ in range(MAX_ITERATIONS):
        v = np.exp(2.0 * u[index])
        try:
            hessian = information(u)[np.ix_(index, index)]
        except np.linalg.LinAlgError:
            return u, value, False
        slope = (_gradient(deviance, at, v, value, high, np.diag(hessian)) if gradient is None
                 else gradient(u)[index])
        if not np.all(np.isfinite(slope)):
            return u, value, False
        held = (((v <= low) & (slope > 0.0)) | ((v >= high) & (slope < 0.0))
                | (np.diag(hessian) <= 0.0))
        moving = ~held
        if not moving.any():
            return u, value, True
        g, h = slope[moving], hessian[np.ix_(moving, moving)]
        root = np.sqrt(np.diag(h))  # scaled to unit diagonal: the levels differ by decades
        lam, vectors = np.linalg.eigh(h / np.outer(root, root))
        lam = np.maximum(lam, max(EIGEN_FLOOR * float(lam[-1]), 1e-300))
        step = -(vectors @ ((vectors.T @ (g / root)) / lam)) / root
        with np.errstate(over="ignore", invalid="ignore"):
            predicted = 0.5 * float(-(g @ step))
        if not math.isfinite(predicted):  # steps beyond what the numbers hold
            return u, value, False
        if predicted < DEVIANCE_TOLERANCE:
            return u, value, True
        t = 1.0
        while True:
            trial_v = v.copy()
            trial_v[moving] = np.clip(v[moving] + t * step, low[moving], high[moving])
            trial = at(trial_v)
            trial_value = deviance(trial)
            if trial_value <= value + ARMIJO * float(g @ (trial_v - v)[moving]):
                break
            t *= 0.5
            if t < 1e-8:  # no descent along the step: the gradient's differences are noise
                return u, value, predicted < 10 * DEVIANCE_TOLERANCE
        u, value = trial, float(trial_value)
    return u, value, False


def _gradient(deviance: Callable[[FloatArray], float], at: Callable[[FloatArray], FloatArray],
              v: FloatArray, value: float, high: FloatArray, curvature: FloatArray
              ) -> FloatArray:
    """Forward (at the upper bound backward) differences of D in the squared levels v, each
    by a step of DIFFERENCE_STEP of the level's standard error (1 / sqrt(curvature), the
    information's diagonal) and corrected by half a step of its curvature: the error of the
    difference quotient to first order; inf where D is not defined at the step's end.
    ``at``: the log-levels of squared levels."""
    out = np.empty(v.size)
    for i in range(v.size):
        h = DIFFERENCE_STEP / math.sqrt(curvature[i]) if curvature[i] > 0 else DIFFERENCE_STEP
        if v[i] + h > high[i]:
            h = -h
        shifted = v.copy()
        shifted[i] += h
        shifted_value = deviance(at(shifted))
        out[i] = (math.inf if not shifted_value < UNDEFINED
                  else (shifted_value - value) / h - 0.5 * h * curvature[i])
    return out
