"""Statistical consistency of an estimator: NEES, ANEES and the chi-square bounds of a
consistent one (numpy/scipy only, so the environment's estimator check and the comparison's
reports share one implementation).

* :func:`estimate_error`: an estimator's error against the truth, with the covariance it
  reports for the same parameters (wheels only, or wheels and sensor pose);
* :func:`nees`: the normalised estimation error squared e^T C^-1 e of each estimate;
* :func:`anees`: its average over episodes, per segment;
* :func:`anees_bounds`: the two-sided chi-square interval a consistent estimator's ANEES lies
  in; :func:`verdict` says on which side an ANEES falls.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.contracts import Estimator
from excite.core.kinematics import Params
from excite.errors import MetricError
from excite.stats.chi2 import chi2_quantile

__all__ = [
    "CONFIDENCE",
    "anees",
    "anees_bounds",
    "check_confidence",
    "estimate_error",
    "nees",
    "verdict",
]

FloatArray = NDArray[np.float64]

#: Two-sided confidence of the ANEES bounds (and of the comparison's bootstrap intervals).
CONFIDENCE = 0.95


def check_confidence(confidence: float) -> float:
    """``confidence`` if it lies strictly between 0 and 1, else MetricError."""
    if not 0.0 < confidence < 1.0:
        raise MetricError(f"confidence must lie strictly between 0 and 1, got {confidence}")
    return confidence


def estimate_error(estimator: Estimator, truth: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The estimator's error (estimate minus truth) and its reported covariance, over the same
    P parameters.

    truth: the hidden model parameters (r_L, r_R, b [m], then the sensor pose l_x, l_y [m],
    l_theta [rad] when it is estimated). The estimate is the estimator's ``theta`` when it has
    one (sensor-pose estimators), else its ``params``; P is the least of the covariance's
    size, the estimate's and the truth's, and the covariance is cut to its leading P x P
    block (the marginal covariance: every model orders the wheels first). So a
    wheels-only estimator on a sensor-pose env is judged on the wheels, and a sensor-pose
    estimator on all six.
    """
    covariance = np.asarray(estimator.covariance, dtype=float)
    theta = getattr(estimator, "theta", None)
    if theta is None:
        params = estimator.params
        theta = params.as_array() if isinstance(params, Params) else params
    estimate = np.asarray(theta, dtype=float).reshape(-1)
    true = np.asarray(truth, dtype=float).reshape(-1)
    p = min(covariance.shape[-1], estimate.size, true.size)
    return estimate[:p] - true[:p], covariance[:p, :p]


def nees(errors: ArrayLike, covariances: ArrayLike) -> FloatArray:
    """Normalised estimation error squared e^T C^-1 e of each estimate.

    errors: (..., P) estimate minus truth, in the parameters' units (m, rad);
    covariances: (..., P, P) the estimator's reported covariance of the same estimates.
    Returns (...). A singular or non-finite covariance gives nan there (never a guess).
    """
    e = np.asarray(errors, dtype=float)
    c = np.asarray(covariances, dtype=float)
    if c.shape != e.shape + e.shape[-1:]:
        raise MetricError(f"covariances must be shaped {e.shape + e.shape[-1:]} for errors "
                          f"shaped {e.shape}, got {c.shape}")
    out = np.full(e.shape[:-1], np.nan)
    finite = np.all(np.isfinite(c), axis=(-2, -1)) & np.all(np.isfinite(e), axis=-1)
    if np.any(finite):
        ok_c, ok_e = c[finite], e[finite]
        with np.errstate(invalid="ignore", divide="ignore"):
            full_rank = np.linalg.matrix_rank(ok_c, hermitian=True) == e.shape[-1]
        values = np.full(ok_e.shape[0], np.nan)
        if np.any(full_rank):
            solved = np.linalg.solve(ok_c[full_rank], ok_e[full_rank][..., None])[..., 0]
            values[full_rank] = np.einsum("np,np->n", ok_e[full_rank], solved)
        out[finite] = values
    return out


def anees(errors: ArrayLike, covariances: ArrayLike) -> FloatArray:
    """Average NEES over episodes, per segment.

    errors: (M, K, P) estimate minus truth of M episodes after each of K segments;
    covariances: (M, K, P, P). Returns (K,): nan where any episode's NEES is nan. A
    consistent estimator's ANEES lies inside :func:`anees_bounds` (M, P); above means
    over-confident, below under-confident.
    """
    values = nees(errors, covariances)
    if values.ndim != 2:
        raise MetricError(f"errors must be shaped (episodes, segments, parameters), got "
                          f"{np.shape(errors)}")
    return values.mean(axis=0)


def anees_bounds(episodes: int, parameters: int,
                 confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Two-sided chi-square interval of the ANEES of a consistent estimator: M times the
    ANEES of M independent episodes is chi-square with M P degrees of freedom, so with
    alpha = 1 - confidence the bounds are chi2.ppf(alpha / 2, M P) / M and
    chi2.ppf(1 - alpha / 2, M P) / M (dimensionless)."""
    if episodes < 1 or parameters < 1:
        raise MetricError(f"need at least one episode and one parameter, got {episodes} "
                          f"and {parameters}")
    alpha = 1.0 - check_confidence(confidence)
    dof = episodes * parameters
    return (chi2_quantile(0.5 * alpha, dof) / episodes,
            chi2_quantile(1.0 - 0.5 * alpha, dof) / episodes)


def verdict(value: float, bounds: tuple[float, float]) -> str:
    """"consistent" inside the bounds (inclusive), "over-confident" above (the reported
    covariance is too small for the errors), "under-confident" below, "undefined" for nan
    (a covariance that says nothing)."""
    low, high = bounds
    if np.isnan(value):
        return "undefined"
    if value > high:
        return "over-confident"
    return "under-confident" if value < low else "consistent"
