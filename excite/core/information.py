"""Information measures on the whitened, relatively scaled Jacobian (docs/conventions.md).

Rows of the increment Jacobian are divided by the measurement standard deviations
(sigma_x, sigma_y, sigma_theta); columns are multiplied by the nominal parameter values.
The Fisher information F = sum_k J_k^T J_k is then dimensionless and

* ``sigma_min(F)`` = sqrt(lambda_min(F)) = smallest singular value of the stacked J;
  1 / sigma_min is the worst-direction relative standard deviation any unbiased estimator
  can reach (Cramér–Rao bound);
* ``crlb_relative_std(F)`` = sqrt(diag(F^-1)): per-parameter relative CRLB std.

Every estimator, the environment's reward and the planners use these functions.

The reference is ``fisher_information(scaled_jacobian(...))``. For the axle model with
sigma_x == sigma_y, F comes from the Jacobian's rows turned onto the chord of each arc
(:func:`_information_rows`), in two fast forms: :func:`_chord_rows` in array code and
:func:`_chord_information_scalar` in one pure-Python pass over short logs (the single
environment's step); tests/unit/core/test_fast_forms.py holds both equal to the reference.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core.kinematics import Params, _as_params, sinc_family, sinc_family_scalar
from excite.core.models import AXLE, SegmentModel

__all__ = [
    "Sigma",
    "as_sigma",
    "as_theta",
    "scaled_jacobian",
    "segment_information",
    "information_matrix",
    "information_matrices",
    "eigen_3x3",
    "fisher_information",
    "channel_gram",
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
_EPS = float(np.finfo(float).eps)


def as_sigma(sigma: ArrayLike) -> FloatArray:
    """Validate per-channel noise std (sigma_x [m], sigma_y [m], sigma_theta [rad]).

    A pair (sigma_xy, sigma_theta) is accepted and expanded.
    """
    s = np.asarray(sigma, dtype=float).reshape(-1)
    if s.size == 2:
        s = np.array([s[0], s[0], s[1]])
    if s.size != 3 or not all(0.0 < x < math.inf for x in s.tolist()):
        raise ValueError(f"sigma must be three positive finite numbers (sx, sy, sth), got {sigma}")
    return s


def _increments(dphi_L: ArrayLike, dphi_R: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Wheel increments as two flat float arrays of one length (broadcast, then flattened)."""
    phi_L, phi_R = np.asarray(dphi_L, dtype=float), np.asarray(dphi_R, dtype=float)
    if phi_L.shape != phi_R.shape:
        phi_L, phi_R = np.broadcast_arrays(phi_L, phi_R)
    return np.ravel(phi_L), np.ravel(phi_R)


def _chord_coefficients(
    params: tuple[float, float, float], scale: tuple[float, float, float], sigma_xy: float
) -> tuple[float, ...]:
    """Constants that make every chord-frame row linear in (dphi_L, dphi_R, v):

    v = dtheta / 2 = v_L dphi_L + v_R dphi_R; w = ds / (2 sigma_xy) = w_L dphi_L + w_R dphi_R;
    heading gradient d(dtheta)/dp times the column scale = (h_L dphi_L, h_R dphi_R, h_v v);
    d(ds)/dp times the column scale, / sigma_xy = (e_L dphi_L, e_R dphi_R, 0).
    Returns (v_L, v_R, w_L, w_R, h_L, h_R, h_v, e_L, e_R).
    """
    r_L, r_R, b = params
    c_L, c_R, c_b = scale
    return (-0.5 * r_L / b, 0.5 * r_R / b, 0.25 * r_L / sigma_xy, 0.25 * r_R / sigma_xy,
            -c_L / b, c_R / b, -2.0 * c_b / b, 0.5 * c_L / sigma_xy, 0.5 * c_R / sigma_xy)


def as_theta(params: Params | ArrayLike) -> FloatArray:
    """Model parameters as a float array (..., P): Params gives (r_L, r_R, b)."""
    return params.as_array() if isinstance(params, Params) else np.asarray(params, dtype=float)


def scaled_jacobian(
    dphi_L: ArrayLike,
    dphi_R: ArrayLike,
    params: Params | ArrayLike,
    sigma: ArrayLike,
    scale: Params | ArrayLike | None = None,
    model: SegmentModel = AXLE,
) -> FloatArray:
    """Whitened, relatively scaled Jacobian of each segment, shape (N, 3, P), batch-first:
    (..., N, 3, P) for logs of wheel increments shaped (..., N), each at its own parameters.

    params: where the Jacobian is evaluated (Params, or the model's P parameters, (..., P)).
    scale: the nominal parameters whose ``model.column_scale`` multiplies the columns
    (default: params itself; (P,) or (..., P)). model: the segment model (default the axle
    model).
    """
    theta = as_theta(params)
    nominal = theta if scale is None else as_theta(scale)
    phi_L, phi_R = np.broadcast_arrays(np.atleast_1d(np.asarray(dphi_L, dtype=float)),
                                       np.atleast_1d(np.asarray(dphi_R, dtype=float)))
    jac = model.jacobian(phi_L, phi_R, theta)
    return jac / as_sigma(sigma)[:, None] * model.column_scale(nominal)[..., None, None, :]


def fisher_information(scaled_jac: ArrayLike) -> FloatArray:
    """F = sum_k J_k^T J_k of scaled Jacobians shaped (..., N, 3, P) -> (..., P, P)."""
    j = np.asarray(scaled_jac, dtype=float)
    return np.einsum("...nki,...nkj->...ij", j, j)


#: Rows at least this long are multiplied by dot products, one pair of rows at a time:
#: BLAS's matrix product of a few long rows is several times slower (memory-bound on a
#: 100k-segment Jacobian, it reads them in the wrong order); for shorter rows numpy's
#: per-call overhead makes the one product faster.
LONG_ROWS = 4096


def channel_gram(a: FloatArray, b: FloatArray | None = None) -> FloatArray:
    """Per channel c, the products of the rows of a (C, P, N) with those of b (C, Q, N)
    (default a): G[c, p, q] = sum_n a[c, p, n] b[c, q, n], shape (C, P, Q); with b omitted,
    J_c J_c^T of Jacobian rows (the information per channel at unit noise)."""
    same = b is None
    b = a if b is None else b
    if a.shape[-1] < LONG_ROWS:
        return np.matmul(a, b.transpose(0, 2, 1))
    out = np.empty((a.shape[0], a.shape[1], b.shape[1]))
    for c in range(a.shape[0]):
        for p in range(a.shape[1]):
            for q in range(p if same else 0, b.shape[1]):
                out[c, p, q] = a[c, p] @ b[c, q]
                if same:
                    out[c, q, p] = out[c, p, q]
    return out


def _information_rows(
    dphi_L: ArrayLike,
    dphi_R: ArrayLike,
    params: Params | ArrayLike,
    sigma: ArrayLike,
    scale: Params | ArrayLike | None,
    model: SegmentModel = AXLE,
) -> FloatArray:
    """Rows R (P parameters, 3 rows, N segments) with R[:, :, k] R[:, :, k]^T = J_k^T J_k,
    J_k the whitened, relatively scaled Jacobian of segment k (:func:`scaled_jacobian`).

    For the axle model with sigma_x == sigma_y the chord rows (:func:`_chord_rows`, below)
    halve the work; every other case takes the model's Jacobian.

    With sigma_x == sigma_y the two position rows may be turned by any angle without changing
    J^T J; turned by -dtheta/2 (onto the chord of the arc) they need only sinc and sinc' of
    v = dtheta/2: dx + i dy = ds sinc(v) e^{iv}, so the turned rows are
    sinc(v) d(ds)/dp + ds sinc'(v)/2 d(dtheta)/dp  and  ds sinc(v)/2 d(dtheta)/dp.
    That is half the work of the Jacobian itself (the environment's hot path).
    """
    s = as_sigma(sigma)
    phi_L, phi_R = _increments(dphi_L, dphi_R)
    sigma_xy, sigma_y, sigma_theta = s.tolist()
    if sigma_y != sigma_xy or model is not AXLE:
        return scaled_jacobian(phi_L, phi_R, params, s, scale, model).transpose(2, 1, 0)
    p = _as_params(params)
    coefficients = _chord_coefficients(p, p if scale is None else _as_params(scale), sigma_xy)
    return _chord_rows(phi_L, phi_R, coefficients, sigma_theta)


def _chord_rows(phi_L: FloatArray, phi_R: FloatArray, coefficients: tuple[Any, ...],
                sigma_theta: float) -> FloatArray:
    """The rows of :func:`_information_rows` (3 parameters, 3 rows, ...) of wheel increments
    (...) (rad), batch-first: ``coefficients`` (:func:`_chord_coefficients`) are floats or
    arrays broadcasting with the increments (one robot's parameters per leading index)."""
    v_L, v_R, w_L, w_R, h_L, h_R, h_v, e_L, e_R = coefficients
    v = v_L * phi_L + v_R * phi_R
    w = w_L * phi_L + w_R * phi_R
    sinc, _, dsinc, _ = sinc_family(v)
    rows = np.empty((3, 3) + v.shape)
    heading = rows[:, 2]  # the heading gradient, whitened at the end
    np.multiply(h_L, phi_L, out=heading[0])
    np.multiply(h_R, phi_R, out=heading[1])
    np.multiply(h_v, v, out=heading[2])
    np.multiply(heading, w * dsinc, out=rows[:, 0])
    np.multiply(heading, w * sinc, out=rows[:, 1])
    rows[0, 0] += e_L * phi_L * sinc
    rows[1, 0] += e_R * phi_R * sinc
    heading *= 1.0 / sigma_theta
    return rows


#: Segment count up to which the pure-Python pass beats numpy's per-call overhead (inside the
#: environment's step, where numpy calls run with cold caches).
_LOOP_MAX = 32


def _chord_information_scalar(
    phi_L: list[float], phi_R: list[float], coefficients: tuple[float, ...], sigma_theta: float
) -> FloatArray:
    """F from the chord rows (:func:`_chord_rows`) of short logs, in one pure-Python pass:
    the fast scalar form of ``rows @ rows.T`` where numpy's per-call overheads would dominate.

    With t = (h_L dphi_L, h_R dphi_R, h_v v) the heading gradient and e = (e_L dphi_L,
    e_R dphi_R, 0) that of the whitened travel (:func:`_chord_coefficients`), the rows are
    t / sigma_theta, w dsinc t + sinc e and w sinc t, so
    F = sum a t t^T + m (t e^T + e t^T) + sinc^2 e e^T with the per-segment weights
    a = w^2 (sinc^2 + dsinc^2) + 1 / sigma_theta^2 and m = w sinc dsinc: weighted moments of
    (dphi_L, dphi_R, v), v summed as itself (not expanded), so F's b entries stay >= 0.
    """
    v_L, v_R, w_L, w_R, h_L, h_R, h_v, e_L, e_R = coefficients
    heading_weight = 1.0 / (sigma_theta * sigma_theta)
    a_ll = a_lr = a_rr = a_lv = a_rv = a_vv = 0.0
    m_ll = m_lr = m_rr = m_lv = m_rv = s_ll = s_lr = s_rr = 0.0
    for left, right in zip(phi_L, phi_R, strict=True):
        v = v_L * left + v_R * right
        w = w_L * left + w_R * right
        sinc, _, dsinc, _ = sinc_family_scalar(v)
        sinc2 = sinc * sinc
        a = w * w * (sinc2 + dsinc * dsinc) + heading_weight
        m = w * sinc * dsinc
        ll, lr, rr, lv, rv = left * left, left * right, right * right, left * v, right * v
        a_ll += a * ll
        a_lr += a * lr
        a_rr += a * rr
        a_lv += a * lv
        a_rv += a * rv
        a_vv += a * v * v
        m_ll += m * ll
        m_lr += m * lr
        m_rr += m * rr
        m_lv += m * lv
        m_rv += m * rv
        s_ll += sinc2 * ll
        s_lr += sinc2 * lr
        s_rr += sinc2 * rr
    f00 = h_L * h_L * a_ll + 2.0 * h_L * e_L * m_ll + e_L * e_L * s_ll
    f01 = h_L * h_R * a_lr + (h_L * e_R + h_R * e_L) * m_lr + e_L * e_R * s_lr
    f11 = h_R * h_R * a_rr + 2.0 * h_R * e_R * m_rr + e_R * e_R * s_rr
    f02 = h_v * (h_L * a_lv + e_L * m_lv)
    f12 = h_v * (h_R * a_rv + e_R * m_rv)
    f22 = h_v * h_v * a_vv
    return np.array([[f00, f01, f02], [f01, f11, f12], [f02, f12, f22]])


def segment_information(
    dphi_L: ArrayLike,
    dphi_R: ArrayLike,
    params: Params | ArrayLike,
    sigma: ArrayLike,
    scale: Params | ArrayLike | None = None,
    model: SegmentModel = AXLE,
) -> FloatArray:
    """Relative Fisher information J_k^T J_k of each segment on its own, shape (N, P, P).

    dphi_L, dphi_R: wheel increments (rad), flattened to N segments. params: where J is
    evaluated (the model's parameters); scale: the nominal parameters of the column scale
    (default params); model: the segment model (default the axle model).
    """
    rows = _information_rows(dphi_L, dphi_R, params, sigma, scale, model)
    return np.einsum("irn,jrn->nij", rows, rows)


def information_matrix(
    dphi_L: ArrayLike,
    dphi_R: ArrayLike,
    params: Params | ArrayLike,
    sigma: ArrayLike,
    scale: Params | ArrayLike | None = None,
    model: SegmentModel = AXLE,
) -> FloatArray:
    """F = sum_k J_k^T J_k of all segments, (P, P): ``fisher_information(scaled_jacobian(...))``
    without forming the Jacobians (see :func:`segment_information` for the arguments).

    Up to ``_LOOP_MAX`` segments with sigma_x == sigma_y (the environment's step) F comes from
    nine weighted wheel-increment moments summed in one pure-Python pass (see
    :func:`_chord_information_scalar`); beyond, from the vectorized rows.
    """
    s = as_sigma(sigma)
    sigma_x, sigma_y, sigma_theta = s.tolist()
    phi_L, phi_R = _increments(dphi_L, dphi_R)
    if phi_L.size <= _LOOP_MAX and sigma_x == sigma_y and model is AXLE:
        left, right = phi_L.tolist(), phi_R.tolist()
        if math.isfinite(sum(left) + sum(right)):  # else as the rows: nan
            p = _as_params(params)
            coefficients = _chord_coefficients(p, p if scale is None else _as_params(scale),
                                               sigma_x)
            return _chord_information_scalar(left, right, coefficients, sigma_theta)
    rows = _information_rows(phi_L, phi_R, params, s, scale, model)
    rows = rows.reshape(rows.shape[0], -1)
    return rows @ rows.T


def information_matrices(
    dphi_L: ArrayLike,
    dphi_R: ArrayLike,
    theta: ArrayLike,
    sigma: ArrayLike,
    scale: ArrayLike,
    model: SegmentModel = AXLE,
) -> FloatArray:
    """F of each of N logs at its own parameters, batch-first: (N, P, P).

    dphi_L, dphi_R (N, K): each log's wheel increments (rad), padded with zeros (a segment
    without motion adds no information); theta (N, P): where each log's F is evaluated;
    scale: the nominal parameters of the column scale ((P,) or (N, P)). The same F as
    :func:`information_matrix` of each log (tested): on the axle model with sigma_x ==
    sigma_y from the chord rows of :func:`_information_rows` (half the work), each robot's
    coefficients broadcast over its segments; else from the batched :func:`scaled_jacobian`.
    """
    s = as_sigma(sigma)
    if model is not AXLE or s[0] != s[1]:
        return fisher_information(scaled_jacobian(dphi_L, dphi_R, theta, s, scale, model))
    theta = np.asarray(theta, dtype=float)
    nominal = np.broadcast_to(np.asarray(scale, dtype=float), theta.shape)
    # the chord rows (_information_rows), each robot's coefficients (N, 1) over its K segments
    coefficients = _chord_coefficients(theta.T[..., None], nominal.T[..., None], float(s[0]))
    rows = _chord_rows(np.asarray(dphi_L, dtype=float), np.asarray(dphi_R, dtype=float),
                       coefficients, float(s[2]))  # (3, 3, N, K)
    flat = rows.transpose(2, 0, 1, 3).reshape(theta.shape[0], 3, -1)
    return flat @ flat.transpose(0, 2, 1)


def eigen_3x3(information: ArrayLike) -> tuple[tuple[float, float, float],
                                               tuple[float, float, float]]:
    """Eigenvalues (ascending) of a symmetric 3x3 matrix (its upper triangle is read) and the
    unit eigenvector of the smallest, in a few microseconds of pure Python (numpy.linalg.eigh
    spends more than that on call overhead), with errors of order eps * ||F|| like LAPACK's.

    After scaling F by its largest entry, the closed form (Smith 1961) locates the eigenvalue
    farther from the middle one (the other extreme is ill-conditioned when it nearly coincides
    with the middle); its eigenvector is the longest cross product of two rows of F - lambda I;
    the 2x2 problem on the plane orthogonal to it gives the other two eigenvalues exactly, and
    the trace the isolated one. NaN entries give NaN results.
    """
    entries = np.asarray(information, dtype=float).tolist()
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = entries
    values = (a00, a01, a02, a11, a12, a22)
    if not all(map(math.isfinite, values)):
        nan = math.nan
        return (nan, nan, nan), (nan, nan, nan)
    size = max(map(abs, values))
    if size == 0.0:
        return (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)
    (low, middle, high), weakest = _unit_eigen_3x3(
        a00 / size, a01 / size, a02 / size, a11 / size, a12 / size, a22 / size)
    return (low * size, middle * size, high * size), weakest


def _unit_eigen_3x3(a00: float, a01: float, a02: float, a11: float, a12: float,
                    a22: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """:func:`eigen_3x3` of a matrix whose largest entry has magnitude 1."""
    trace = a00 + a11 + a22
    q = trace / 3.0
    d0, d1, d2 = a00 - q, a11 - q, a22 - q
    p2 = (d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0
    p = math.sqrt(p2)
    if p <= 4.0 * _EPS * abs(q):  # a multiple of the identity to working precision
        return (q, q, q), (1.0, 0.0, 0.0)
    det = d0 * (d1 * d2 - a12 * a12) - a01 * (a01 * d2 - a12 * a02) + a02 * (a01 * a12 - d1 * a02)
    r = min(max(det / (2.0 * p * p2), -1.0), 1.0)
    top_is_isolated = r >= 0.0  # then top - middle >= sqrt(3) p, else middle - bottom is
    angle = math.acos(r) / 3.0 + (0.0 if top_is_isolated else 2.0 * math.pi / 3.0)
    isolated = q + 2.0 * p * math.cos(angle)
    # Cross products of the rows of F - isolated I: each is parallel to the eigenvector.
    c0, c1, c2 = a00 - isolated, a11 - isolated, a22 - isolated
    x01 = (a01 * a12 - a02 * c1, a02 * a01 - c0 * a12, c0 * c1 - a01 * a01)
    x02 = (a01 * c2 - a02 * a12, a02 * a02 - c0 * c2, c0 * a12 - a01 * a02)
    x12 = (c1 * c2 - a12 * a12, a12 * a02 - a01 * c2, a01 * a12 - c1 * a02)
    u = _unit(max(x01, x02, x12, key=_norm2))
    # An orthonormal basis (e1, e2) of the plane orthogonal to u.
    ux, uy, uz = abs(u[0]), abs(u[1]), abs(u[2])
    if ux <= uy and ux <= uz:
        e1 = _unit((0.0, u[2], -u[1]))  # u x (1, 0, 0)
    elif uy <= uz:
        e1 = _unit((-u[2], 0.0, u[0]))  # u x (0, 1, 0)
    else:
        e1 = _unit((u[1], -u[0], 0.0))  # u x (0, 0, 1)
    e2 = (u[1] * e1[2] - u[2] * e1[1], u[2] * e1[0] - u[0] * e1[2], u[0] * e1[1] - u[1] * e1[0])
    f1 = (a00 * e1[0] + a01 * e1[1] + a02 * e1[2], a01 * e1[0] + a11 * e1[1] + a12 * e1[2],
          a02 * e1[0] + a12 * e1[1] + a22 * e1[2])  # F e1
    b11 = f1[0] * e1[0] + f1[1] * e1[1] + f1[2] * e1[2]
    b12 = f1[0] * e2[0] + f1[1] * e2[1] + f1[2] * e2[2]
    b22 = (e2[0] * (a00 * e2[0] + a01 * e2[1] + a02 * e2[2])
           + e2[1] * (a01 * e2[0] + a11 * e2[1] + a12 * e2[2])
           + e2[2] * (a02 * e2[0] + a12 * e2[1] + a22 * e2[2]))
    mean, half = 0.5 * (b11 + b22), math.hypot(0.5 * (b11 - b22), b12)
    low, high = mean - half, mean + half
    if not top_is_isolated:
        return (trace - low - high, low, high), u
    turn = 0.5 * math.atan2(2.0 * b12, b11 - b22)  # of the eigenvector of `high` in (e1, e2)
    c, s = math.cos(turn), math.sin(turn)
    return (low, high, trace - low - high), (c * e2[0] - s * e1[0], c * e2[1] - s * e1[1],
                                             c * e2[2] - s * e1[2])


def _norm2(a: tuple[float, float, float]) -> float:
    return a[0] * a[0] + a[1] * a[1] + a[2] * a[2]


def _unit(a: tuple[float, float, float]) -> tuple[float, float, float]:
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return (a[0] / n, a[1] / n, a[2] / n)


def sigma_min(information: ArrayLike) -> FloatArray | float:
    """sqrt of the smallest eigenvalue of F (clipped at 0); works on stacks (..., P, P)."""
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
    take part (|v_i| > 0.1) in a numerically null direction v: an eigenvalue within the
    eigen-solver's rounding of zero (10 P eps times the largest). A direction far weaker than
    the others but above that (exact data: a heading known to 1e-11 rad beside lengths known
    to 1e-5) is determined, and its variance is reported, not inf."""
    f = np.asarray(information, dtype=float)
    lam, vec = np.linalg.eigh(f)
    null = lam <= max(lam[-1], 0.0) * 10 * len(lam) * np.finfo(float).eps
    inv = (vec[:, ~null] / lam[~null]) @ vec[:, ~null].T
    if np.any(null):
        involved = (vec[:, null] ** 2).sum(axis=1) > 1e-2
        inv = np.where(np.outer(involved, involved), np.inf, inv)
    return inv


def crlb_relative_std(information: ArrayLike) -> FloatArray:
    """Per-parameter relative Cramér–Rao std sqrt(diag(F^-1)); inf where F is singular."""
    return np.sqrt(np.diag(inverse_information(information)))
