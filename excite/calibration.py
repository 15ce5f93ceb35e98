"""Batch calibration of (r_L, r_R, b): weighted maximum likelihood by Levenberg–Marquardt.

``calibrate(segments)`` needs no initial guess (a linear first estimate starts it) and no
noise levels (per-channel sigmas are estimated from the residuals, iterating estimate /
re-weight), returns a :class:`CalibrationResult` with the covariance (inverse Fisher
information at the solution) and an identifiability verdict on the whitened, relatively
scaled Jacobian (DESIGN.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2

from excite.data import DataError, Segments
from excite.information import as_sigma, inverse_information
from excite.kinematics import Params, increment_jacobian, predict_increment, sinc_family, wrap_angle

__all__ = ["CalibrationResult", "calibrate", "initial_estimate", "DEFAULT_NOMINAL"]

FloatArray = NDArray[np.float64]
Loss = Literal["linear", "huber"]

#: Used only for directions the data cannot determine when no initial guess is given.
DEFAULT_NOMINAL = Params(0.05, 0.05, 0.30)
#: Huber threshold on whitened residuals (95% efficiency under Gaussian noise).
HUBER_K = 1.345
#: A segment is an outlier when its whitened squared residual exceeds this chi2(3) quantile.
OUTLIER_QUANTILE = 0.999
#: Data determine p when the worst-direction relative std 1/sigma_min is at most this.
DEFAULT_MAX_RELATIVE_STD = 0.1
_MAD_TO_STD = 1.482602218505602
_PARAM_NAMES = ("r_L", "r_R", "b")


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`calibrate` (modelled on scipy's OptimizeResult).

    params: estimate (m). covariance: 3x3 (m^2), inverse Fisher information at the estimate,
    inf along directions the data do not determine. std: sqrt(diag(covariance)) (m).
    singular_values, condition_number: of the whitened, relatively scaled Jacobian (DESIGN.md),
    descending. identifiable: whether 1/sigma_min <= max_relative_std. unidentifiable_direction:
    None, or what is not determined, in words. sigma: noise std per channel (m, m, rad), given or
    estimated. rms_residual: raw residual RMS per channel. n_outliers: segments whose whitened
    squared residual exceeds the 99.9% chi2(3) quantile.
    """

    params: Params
    covariance: FloatArray
    std: FloatArray
    singular_values: FloatArray
    condition_number: float
    identifiable: bool
    unidentifiable_direction: str | None
    unidentifiable_vector: FloatArray | None
    n_segments: int
    n_outliers: int
    rms_residual: FloatArray
    sigma: FloatArray
    sigma_estimated: bool
    loss: str
    converged: bool
    iterations: int
    message: str
    residuals: FloatArray = field(repr=False)

    @property
    def sigma_min(self) -> float:
        return float(self.singular_values[-1])

    def to_dict(self) -> dict:
        """JSON-ready dict (the ``excite calibrate --json`` object); inf becomes None."""

        def finite(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            "params": dict(zip(_PARAM_NAMES, map(float, self.params.as_array()), strict=True)),
            "std": {n: finite(s) for n, s in zip(_PARAM_NAMES, self.std, strict=True)},
            "covariance": [[finite(v) for v in row] for row in self.covariance],
            "singular_values": [float(s) for s in self.singular_values],
            "condition_number": finite(self.condition_number),
            "identifiable": bool(self.identifiable),
            "unidentifiable_direction": self.unidentifiable_direction,
            "n_segments": self.n_segments,
            "n_outliers": self.n_outliers,
            "rms_residual": dict(zip(("x", "y", "theta"), map(float, self.rms_residual),
                                     strict=True)),
            "sigma": dict(zip(("x", "y", "theta"), map(float, self.sigma), strict=True)),
            "sigma_estimated": self.sigma_estimated,
            "loss": self.loss,
            "converged": bool(self.converged),
            "iterations": self.iterations,
        }

    def summary(self) -> str:
        """Human-readable report."""
        p = self.params.as_array()
        lines = [f"excite calibration: {self.n_segments} segments, loss={self.loss}"]
        for name, value, s in zip(_PARAM_NAMES, p, self.std, strict=True):
            rel = f"({100 * s / value:.3f}%)" if np.isfinite(s) else "(undetermined)"
            lines.append(f"  {name:<4}= {value:.6f} m  ± {s:.2e} m {rel}")
        sv = ", ".join(f"{s:.4g}" for s in self.singular_values)
        lines += [
            f"  sigma_min       = {self.sigma_min:.4g}  (worst-direction relative std "
            f"{_inverse_or_inf(self.sigma_min):.3g})",
            f"  singular values = {sv};  condition number = {self.condition_number:.4g}",
            f"  identifiable    = {'yes' if self.identifiable else 'NO'}"
            + (f": {self.unidentifiable_direction}" if self.unidentifiable_direction else ""),
            "  residual RMS    = x {:.3e} m, y {:.3e} m, theta {:.3e} rad".format(
                *self.rms_residual),
            "  noise sigma     = x {:.3e} m, y {:.3e} m, theta {:.3e} rad ({})".format(
                *self.sigma, "estimated" if self.sigma_estimated else "given"),
            f"  outliers        = {self.n_outliers}",
            f"  converged       = {self.converged} after {self.iterations} iterations"
            f" ({self.message})",
        ]
        return "\n".join(lines)


def _inverse_or_inf(x: float) -> float:
    return 1.0 / x if x > 0 else float("inf")


def _as_segments(segments: Segments | ArrayLike) -> Segments:
    if isinstance(segments, Segments):
        return segments
    return Segments.from_array(segments)


def _residuals(p: FloatArray, seg: Segments) -> FloatArray:
    """Raw residuals predicted - measured, shape (N, 3), theta wrapped to (-pi, pi]."""
    dx, dy, dth = predict_increment(seg.dphi_L, seg.dphi_R, p)
    return np.column_stack([dx - seg.dx, dy - seg.dy, wrap_angle(dth - seg.dtheta)])


def _lstsq_from(a: FloatArray, y: FloatArray, ref: FloatArray) -> tuple[FloatArray, int]:
    """Least-squares solution closest to ``ref`` (min-norm correction) and the rank of a."""
    if a.size == 0 or not np.any(a):
        return ref.copy(), 0
    delta, _, rank, _ = np.linalg.lstsq(a, y - a @ ref, rcond=1e-6)
    return ref + delta, int(rank)


def initial_estimate(segments: Segments, fallback: Params = DEFAULT_NOMINAL) -> Params:
    """Closed-form first estimate of (r_L, r_R, b), no guess needed.

    With the measured heading change th_k, the translation is linear in the radii:
    (dx, dy)_k = (sinc(th_k), cosc(th_k)) * (r_L dphi_L + r_R dphi_R) / 2; and the heading
    change is linear in r/b: th_k = (r_R/b) dphi_R - (r_L/b) dphi_L. Directions the data do
    not determine are taken from ``fallback`` (keeping its b/r ratio).
    """
    f, g = sinc_family(segments.dtheta, derivatives=False)
    half = 0.5 * np.column_stack([segments.dphi_L, segments.dphi_R])
    a_trans = np.vstack([half * f[:, None], half * g[:, None]])
    y_trans = np.concatenate([segments.dx, segments.dy])
    r_ref = np.array([fallback.r_L, fallback.r_R])
    radii, rank_trans = _lstsq_from(a_trans, y_trans, r_ref)
    if np.any(radii <= 0):
        radii, rank_trans = r_ref, 0

    b_ref = fallback.b * radii.mean() / r_ref.mean()
    a_rot = np.column_stack([-segments.dphi_L, segments.dphi_R])
    ratios, rank_rot = _lstsq_from(a_rot, segments.dtheta, radii / b_ref)
    if rank_trans == 0 and rank_rot > 0 and np.all(ratios > 0):
        # Nothing translates: only r/b is known; the common scale comes from the fallback.
        return Params(*(ratios * fallback.b), fallback.b)
    b = b_ref
    if rank_rot > 0:
        chord = radii[1] * segments.dphi_R - radii[0] * segments.dphi_L  # = b * dtheta
        denominator = float(segments.dtheta @ segments.dtheta)
        candidate = float(chord @ segments.dtheta) / denominator if denominator > 0 else 0.0
        if np.isfinite(candidate) and 0.5 * b_ref < candidate < 2.0 * b_ref:
            b = candidate
    return Params(radii[0], radii[1], b)


class _Objective:
    """Whitened (optionally Huber-weighted) residuals of one dataset for fixed sigma."""

    def __init__(self, seg: Segments, sigma: FloatArray, loss: Loss):
        self.seg, self.inv_sigma, self.loss = seg, 1.0 / sigma, loss

    def whitened(self, p: FloatArray) -> FloatArray:
        return _residuals(p, self.seg) * self.inv_sigma

    def weights(self, z: FloatArray) -> FloatArray:
        if self.loss == "linear":
            return np.ones_like(z)
        a = np.abs(z)
        return np.where(a <= HUBER_K, 1.0, HUBER_K / np.maximum(a, HUBER_K))

    def cost(self, z: FloatArray) -> float:
        if self.loss == "linear":
            return 0.5 * float(np.sum(z * z))
        a = np.abs(z)
        return float(np.sum(np.where(a <= HUBER_K, 0.5 * z * z, HUBER_K * (a - 0.5 * HUBER_K))))

    def jacobian(self, p: FloatArray) -> FloatArray:
        """Whitened Jacobian, (N, 3, 3)."""
        return increment_jacobian(self.seg.dphi_L, self.seg.dphi_R, p) * self.inv_sigma[:, None]


def _normal_equations(jac: FloatArray, z: FloatArray, w: FloatArray, scale: FloatArray):
    """(J_s^T W J_s, J_s^T W z) with J_s = J diag(scale): the relative-parameter system."""
    js = jac * scale
    wj = js * w[:, :, None]
    return np.einsum("nki,nkj->ij", wj, js), np.einsum("nki,nk->i", wj, z)


def _solve_psd(a: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve a x = rhs for symmetric PSD a, ignoring numerically null directions."""
    lam, vec = np.linalg.eigh(a)
    keep = lam > max(lam[-1], 0.0) * 1e-12
    coef = (vec.T @ rhs)[keep] / lam[keep]
    return vec[:, keep] @ coef


def _levenberg_marquardt(
    obj: _Objective,
    p0: FloatArray,
    max_iterations: int,
    tol: float,
    frozen: FloatArray | None = None,
) -> tuple[FloatArray, int, bool, str]:
    """Minimise the (Huber-)weighted whitened cost; steps are relative: p <- p * (1 + step).

    frozen: (3, k) orthonormal relative directions the steps must not move along.
    """
    p = p0.copy()
    z = obj.whitened(p)
    cost = obj.cost(z)
    lam = 1e-3
    for iteration in range(1, max_iterations + 1):
        a, g = _normal_equations(obj.jacobian(p), z, obj.weights(z), p)
        while True:
            step = _solve_psd(a + lam * np.diag(np.diag(a)), -g)
            if frozen is not None:
                step = step - frozen @ (frozen.T @ step)
            trial = p * (1.0 + step)
            if np.all(trial > 0):
                z_trial = obj.whitened(trial)
                cost_trial = obj.cost(z_trial)
                if cost_trial <= cost:
                    break
            lam *= 10.0
            if lam > 1e12:
                return p, iteration, True, "no further decrease of the cost"
        p, z, improvement = trial, z_trial, cost - cost_trial
        cost = cost_trial
        lam = max(lam / 10.0, 1e-9)
        if np.max(np.abs(step)) < tol or improvement <= tol * max(cost, 1e-300):
            return p, iteration, True, "relative step below tolerance"
    return p, max_iterations, False, "maximum number of iterations reached"


def _leverage(jac: FloatArray, w: FloatArray) -> FloatArray:
    """Per-channel sum of hat-matrix diagonals (degrees of freedom the fit takes), (3,)."""
    wj = jac * np.sqrt(w)[:, :, None]
    info = np.einsum("nki,nkj->ij", wj, wj)
    inv = np.linalg.pinv(info, hermitian=True)
    return np.einsum("nki,ij,nkj->k", wj, inv, wj)


def _estimate_sigma(raw: FloatArray, jac_raw: FloatArray, loss: Loss) -> FloatArray:
    """Per-channel noise std from raw residuals (REML-style dof correction; MAD for Huber)."""
    n = raw.shape[0]
    if loss == "huber":
        sigma = _MAD_TO_STD * np.median(np.abs(raw), axis=0)
    else:
        dof = n - _leverage(jac_raw, np.ones_like(raw))
        sigma = np.sqrt(np.sum(raw * raw, axis=0) / np.maximum(dof, 1.0))
    scale = np.maximum(np.max(np.abs(raw), axis=0), 1.0)
    return np.maximum(sigma, 1e-12 * scale)


def _describe_direction(v: FloatArray, seg: Segments, sigma: FloatArray) -> str:
    """Words for a relative-parameter null direction v (unit vector over r_L, r_R, b)."""
    v = v if v[np.argmax(np.abs(v))] > 0 else -v
    if abs(v[2]) > 0.9:
        turning = np.abs(seg.dtheta) > 3.0 * sigma[2]
        why = "no segment turns" if not np.any(turning) else "the turns do not separate it"
        return f"b: {why}"
    if float(v @ np.ones(3)) / np.sqrt(3.0) > 0.95:
        return "the common scale of r_L, r_R and b: no segment translates"
    if abs(v[2]) < 0.1 and v[0] * v[1] < 0 and abs(abs(v[0]) - abs(v[1])) < 0.2:
        return "the ratio r_L/r_R: every segment has the same wheel-speed ratio"
    terms = " ".join(f"{c:+.2f}*{n}" for c, n in zip(v, _PARAM_NAMES, strict=True))
    return f"the relative combination {terms}"


def calibrate(
    segments: Segments | ArrayLike,
    initial: Params | ArrayLike | None = None,
    sigma: ArrayLike | None = None,
    loss: Loss = "linear",
    *,
    max_iterations: int = 100,
    tol: float = 1e-12,
    max_relative_std: float = DEFAULT_MAX_RELATIVE_STD,
    max_sigma_rounds: int = 20,
) -> CalibrationResult:
    """Estimate p = (r_L, r_R, b) from segments by weighted maximum likelihood.

    segments: Segments or an (N, 5) array in CSV column order (N >= 3).
    initial: starting Params; None finds its own start (:func:`initial_estimate`).
    sigma: measurement noise std (sigma_x [m], sigma_y [m], sigma_theta [rad]) or
        (sigma_xy, sigma_theta); None estimates them from the residuals (re-weighting until
        they settle to 0.01%).
    loss: "linear" (Gaussian maximum likelihood) or "huber" (robust to slip outliers; the
        threshold is 1.345 whitened standard deviations).
    max_relative_std: identifiability threshold on 1/sigma_min.
    """
    seg = _as_segments(segments)
    if len(seg) < 3:
        raise DataError(f"{len(seg)} segment(s); at least 3 are needed")
    if loss not in ("linear", "huber"):
        raise ValueError(f"loss must be 'linear' or 'huber', got {loss!r}")
    if initial is None:
        p = initial_estimate(seg).as_array()
    else:
        p = (initial if isinstance(initial, Params) else Params.from_array(initial)).as_array()
    start = p

    estimate_sigma = sigma is None
    if estimate_sigma:
        s = _estimate_sigma(_residuals(p, seg), increment_jacobian(seg.dphi_L, seg.dphi_R, p),
                            loss)
    else:
        s = as_sigma(sigma)

    total_iterations, converged, message = 0, False, ""
    for _ in range(max_sigma_rounds if estimate_sigma else 1):
        obj = _Objective(seg, s, loss)
        p, iterations, converged, message = _levenberg_marquardt(obj, p, max_iterations, tol)
        total_iterations += iterations
        if not estimate_sigma:
            break
        new_s = _estimate_sigma(_residuals(p, seg), obj.jacobian(p) / obj.inv_sigma[:, None],
                                loss)
        settled = np.all(np.abs(new_s / s - 1.0) < 1e-4)
        s = new_s
        if settled:
            break
    weak = _weak_directions(_Objective(seg, s, loss), p, max_relative_std)
    if weak is not None:
        # The data cannot determine these directions: hold them at the start instead of
        # letting the fit wander along them to chase noise.
        p, iterations, converged, message = _levenberg_marquardt(
            _Objective(seg, s, loss), start, max_iterations, tol, frozen=weak)
        total_iterations += iterations
    return _result(seg, p, s, estimate_sigma, loss, converged, total_iterations, message,
                   max_relative_std)


def _relative_information(obj: _Objective, p: FloatArray) -> FloatArray:
    """Whitened (Huber-weighted), relatively scaled Fisher information at p."""
    z = obj.whitened(p)
    return _normal_equations(obj.jacobian(p), z, obj.weights(z), p)[0]


def _weak_directions(obj: _Objective, p: FloatArray, max_relative_std: float):
    """Relative directions whose CRLB std exceeds max_relative_std, as (3, k), or None."""
    lam, vec = np.linalg.eigh(_relative_information(obj, p))
    weak = lam * max_relative_std**2 < 1.0
    return vec[:, weak] if np.any(weak) else None


def _result(seg, p, s, estimate_sigma, loss, converged, iterations, message,
            max_relative_std) -> CalibrationResult:
    obj = _Objective(seg, s, loss)
    z = obj.whitened(p)
    info_rel = _relative_information(obj, p)
    lam, vec = np.linalg.eigh(info_rel)
    singular = np.sqrt(np.maximum(lam[::-1], 0.0))
    s_min = singular[-1]
    condition = singular[0] / s_min if s_min > 0 else float("inf")
    covariance = inverse_information(info_rel) * np.outer(p, p)
    std = np.sqrt(np.diag(covariance))
    identifiable = bool(s_min > 0 and 1.0 / s_min <= max_relative_std)
    direction = vector = None
    if not identifiable:
        vector = vec[:, 0]
        direction = _describe_direction(vector, seg, s)
    raw = z / obj.inv_sigma
    outliers = int(np.sum(np.sum(z * z, axis=1) > chi2.ppf(OUTLIER_QUANTILE, 3)))
    return CalibrationResult(
        params=Params.from_array(p),
        covariance=covariance,
        std=std,
        singular_values=singular,
        condition_number=float(condition),
        identifiable=identifiable,
        unidentifiable_direction=direction,
        unidentifiable_vector=vector,
        n_segments=len(seg),
        n_outliers=outliers,
        rms_residual=np.sqrt(np.mean(raw * raw, axis=0)),
        sigma=s,
        sigma_estimated=estimate_sigma,
        loss=loss,
        converged=converged,
        iterations=iterations,
        message=message,
        residuals=raw,
    )
