"""Information measures on the whitened, relatively scaled Jacobian (DESIGN.md).

Rows of the increment Jacobian are divided by the measurement standard deviations
(sigma_x, sigma_y, sigma_theta); columns are multiplied by the nominal parameter values.
The Fisher information F = sum_k J_k^T J_k is then dimensionless and

* ``sigma_min(F)`` = sqrt(lambda_min(F)) = smallest singular value of the stacked J;
  1 / sigma_min is the worst-direction relative standard deviation any unbiased estimator
  can reach (Cramér–Rao bound);
* ``crlb_relative_std(F)`` = sqrt(diag(F^-1)): per-parameter relative CRLB std.

Every estimator, the environment's reward and the planners use these functions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.kinematics import Params, increment_jacobian

__all__ = [
    "Sigma",
    "as_sigma",
    "scaled_jacobian",
    "segment_information",
    "fisher_information",
    "sigma_min",
    "log_det",
    "inverse_information",
    "crlb_relative_std",
    "DEFAULT_SIGMA",
]

FloatArray = NDArray[np.float64]
Sigma = tuple[float, float, float]

#: Default external-sensor noise (sigma_x [m], sigma_y [m], sigma_theta [rad]).
DEFAULT_SIGMA: Sigma = (2e-3, 2e-3, 1e-3)


def as_sigma(sigma: ArrayLike) -> FloatArray:
    """Validate per-channel noise std (sigma_x [m], sigma_y [m], sigma_theta [rad]).

    A pair (sigma_xy, sigma_theta) is accepted and expanded.
    """
    s = np.asarray(sigma, dtype=float).reshape(-1)
    if s.size == 2:
        s = np.array([s[0], s[0], s[1]])
    if s.size != 3 or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"sigma must be three positive finite numbers (sx, sy, sth), got {sigma}")
    return s


def scaled_jacobian(
    dphi_L: ArrayLike,
    dphi_R: ArrayLike,
    params: Params | ArrayLike,
    sigma: ArrayLike,
    scale: Params | ArrayLike | None = None,
) -> FloatArray:
    """Whitened, relatively scaled Jacobian of each segment, shape (N, 3, 3).

    params: where the Jacobian is evaluated. scale: the nominal values that multiply the
    columns (default: params itself).
    """
    p = params.as_array() if isinstance(params, Params) else np.asarray(params, dtype=float)
    scale_arr = p if scale is None else (
        scale.as_array() if isinstance(scale, Params) else np.asarray(scale, dtype=float)
    )
    jac = increment_jacobian(dphi_L, dphi_R, p)
    return jac / as_sigma(sigma)[:, None] * scale_arr[None, :]


def segment_information(
    dphi_L: ArrayLike,
    dphi_R: ArrayLike,
    params: Params | ArrayLike,
    sigma: ArrayLike,
    scale: Params | ArrayLike | None = None,
) -> FloatArray:
    """Relative Fisher information J_k^T J_k of each segment on its own, shape (N, 3, 3)."""
    jac = scaled_jacobian(dphi_L, dphi_R, params, sigma, scale)
    return np.einsum("nki,nkj->nij", jac, jac)


def fisher_information(scaled_jac: ArrayLike) -> FloatArray:
    """F = sum_k J_k^T J_k of scaled Jacobians shaped (..., N, 3, 3) -> (..., 3, 3)."""
    j = np.asarray(scaled_jac, dtype=float)
    return np.einsum("...nki,...nkj->...ij", j, j)


def sigma_min(information: ArrayLike) -> FloatArray | float:
    """sqrt of the smallest eigenvalue of F (clipped at 0); works on stacks (..., 3, 3)."""
    lam = np.linalg.eigvalsh(np.asarray(information, dtype=float))[..., 0]
    out = np.sqrt(np.maximum(lam, 0.0))
    return float(out) if out.ndim == 0 else out


def log_det(information: ArrayLike) -> FloatArray | float:
    """log det F (D-optimality); -inf when F is singular."""
    sign, value = np.linalg.slogdet(np.asarray(information, dtype=float))
    out = np.where(sign > 0, value, -np.inf)
    return float(out) if out.ndim == 0 else out


def inverse_information(information: ArrayLike) -> FloatArray:
    """F^-1 for symmetric PSD F (pseudo-inverse), with inf entries for the parameters that
    take part (|v_i| > 0.1) in a numerically null direction v."""
    f = np.asarray(information, dtype=float)
    lam, vec = np.linalg.eigh(f)
    null = lam <= max(lam[-1], 0.0) * 1e-12
    inv = (vec[:, ~null] / lam[~null]) @ vec[:, ~null].T
    if np.any(null):
        involved = (vec[:, null] ** 2).sum(axis=1) > 1e-2
        inv = np.where(np.outer(involved, involved), np.inf, inv)
    return inv


def crlb_relative_std(information: ArrayLike) -> FloatArray:
    """Per-parameter relative Cramér–Rao std sqrt(diag(F^-1)); inf where F is singular."""
    return np.sqrt(np.diag(inverse_information(information)))
