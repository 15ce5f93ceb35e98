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
from excite.kinematics import Params, sinc_family, wrap_angle

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


def _lstsq_from(gram: FloatArray, rhs: FloatArray, ref: FloatArray) -> tuple[FloatArray, int]:
    """Solution of the normal equations gram x = rhs closest to ``ref`` (min-norm correction),
    and the numerical rank of gram."""
    if not np.any(gram):
        return ref.copy(), 0
    lam = np.linalg.eigvalsh(gram)
    rank = int(np.sum(lam > lam[-1] * 1e-12))
    return ref + _solve_psd(gram, rhs - gram @ ref), rank


def initial_estimate(segments: Segments, fallback: Params = DEFAULT_NOMINAL) -> Params:
    """Closed-form first estimate of (r_L, r_R, b), no guess needed.

    With the measured heading change th_k, the translation is linear in the radii:
    (dx, dy)_k = (sinc(th_k), cosc(th_k)) * (r_L dphi_L + r_R dphi_R) / 2; and the heading
    change is linear in r/b: th_k = (r_R/b) dphi_R - (r_L/b) dphi_L. Directions the data do
    not determine are taken from ``fallback`` (keeping its b/r ratio).
    """
    phi_L, phi_R, th = segments.dphi_L, segments.dphi_R, segments.dtheta
    f, g = sinc_family(th, derivatives=False)
    # Translation rows (f, g) * (phi_L, phi_R)/2 . (r_L, r_R): 2x2 normal equations.
    phi = np.stack([phi_L, phi_R])
    w = 0.25 * (f * f + g * g)
    v = 0.5 * (f * segments.dx + g * segments.dy)
    gram = np.einsum("ik,k,jk->ij", phi, w, phi)
    r_ref = np.array([fallback.r_L, fallback.r_R])
    radii, rank_trans = _lstsq_from(gram, np.einsum("ik,k->i", phi, v), r_ref)
    if np.any(radii <= 0):
        radii, rank_trans = r_ref, 0

    b_ref = fallback.b * radii.mean() / r_ref.mean()
    # Heading rows (-phi_L, phi_R) . (r_L/b, r_R/b).
    signed = phi * np.array([[-1.0], [1.0]])
    gram = np.einsum("ik,jk->ij", signed, signed)
    ratios, rank_rot = _lstsq_from(gram, np.einsum("ik,k->i", signed, th), radii / b_ref)
    if rank_trans == 0 and rank_rot > 0 and np.all(ratios > 0):
        # Nothing translates: only r/b is known; the common scale comes from the fallback.
        return Params(*(ratios * fallback.b), fallback.b)
    b = b_ref
    if rank_rot > 0:
        chord = radii[1] * phi_R - radii[0] * phi_L  # = b * dtheta
        denominator = float(np.einsum("k,k->", th, th))
        candidate = float(np.einsum("k,k->", chord, th)) / denominator if denominator else 0.0
        if np.isfinite(candidate) and 0.5 * b_ref < candidate < 2.0 * b_ref:
            b = candidate
    return Params(radii[0], radii[1], b)


class _Evaluation:
    """The model at p: raw residuals and relative Jacobian rows, channel-major.

    raw[c, k]: residual (predicted - measured) of channel c (x, y, theta) of segment k.
    jac[c, i, k]: d raw[c, k] / d p_i * p_i, the derivative with respect to the relative
    parameters (Jacobian columns scaled by p).
    """

    def __init__(self, p: FloatArray, raw: FloatArray, jac: FloatArray):
        self.p, self.raw, self.jac = p, raw, jac
        self._unit: tuple[FloatArray, FloatArray, FloatArray] | None = None

    def unit_system(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Per channel: J_c J_c^T (3,3,3), J_c r_c (3,3) and r_c . r_c (3,), for sigma = 1."""
        if self._unit is None:
            # einsum's own loops, not BLAS: threads only contend on these long, thin products.
            info = np.einsum("cik,cjk->cij", self.jac, self.jac)
            gradient = np.einsum("cik,ck->ci", self.jac, self.raw)
            self._unit = (info, gradient, np.einsum("ck,ck->c", self.raw, self.raw))
        return self._unit


class _Model:
    """Residuals and analytic Jacobian of one dataset, in the structure the solver needs."""

    def __init__(self, seg: Segments):
        self.phi_L, self.phi_R = seg.dphi_L, seg.dphi_R
        self.dx, self.dy, self.dtheta = seg.dx, seg.dy, seg.dtheta
        self.n = len(seg)

    def evaluate(self, p: FloatArray) -> _Evaluation:
        r_L, r_R, b = p
        s_L, s_R = r_L * self.phi_L, r_R * self.phi_R
        ds, th = 0.5 * (s_L + s_R), (s_R - s_L) / b
        f, g, fp, gp = sinc_family(th)
        raw = np.empty((3, self.n))
        np.subtract(ds * f, self.dx, out=raw[0])
        np.subtract(ds * g, self.dy, out=raw[1])
        raw[2] = wrap_angle(th - self.dtheta)
        # Relative derivatives of ds: (s_L, s_R, 0)/2; of th: (-s_L/b, s_R/b, -th).
        a0, a1 = 0.5 * s_L, 0.5 * s_R
        c0, c1, c2 = -s_L / b, s_R / b, -th
        ex, ey = ds * fp, ds * gp
        jac = np.empty((3, 3, self.n))
        jac[0, 0], jac[0, 1], jac[0, 2] = f * a0 + ex * c0, f * a1 + ex * c1, ex * c2
        jac[1, 0], jac[1, 1], jac[1, 2] = g * a0 + ey * c0, g * a1 + ey * c1, ey * c2
        jac[2, 0], jac[2, 1], jac[2, 2] = c0, c1, c2
        return _Evaluation(p, raw, jac)


def _huber_cost(z: FloatArray) -> float:
    a = np.abs(z)
    return float(np.sum(np.where(a <= HUBER_K, 0.5 * z * z, HUBER_K * (a - 0.5 * HUBER_K))))


@dataclass(frozen=True)
class _System:
    """Whitened, (Huber-)weighted normal equations of an evaluation for given sigma."""

    channel_information: FloatArray  # (3 channels, 3, 3), relative parameters
    gradient: FloatArray  # (3,)
    cost: float

    @property
    def information(self) -> FloatArray:
        return self.channel_information.sum(axis=0)


def _system(ev: _Evaluation, sigma: FloatArray, loss: Loss) -> _System:
    inv_var = 1.0 / (sigma * sigma)
    if loss == "linear":
        info, gradient, rss = ev.unit_system()
        return _System(info * inv_var[:, None, None], inv_var @ gradient,
                       0.5 * float(inv_var @ rss))
    z = ev.raw / sigma[:, None]
    w = (HUBER_K / np.maximum(np.abs(z), HUBER_K)) * inv_var[:, None]
    weighted = ev.jac * w[:, None, :]
    info = np.einsum("cik,cjk->cij", weighted, ev.jac)
    gradient = np.einsum("cik,ck->i", weighted, ev.raw)
    return _System(info, gradient, _huber_cost(z))


def _solve_psd(a: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve a x = rhs for symmetric PSD a, ignoring numerically null directions."""
    lam, vec = np.linalg.eigh(a)
    keep = lam > max(lam[-1], 0.0) * 1e-12
    coef = (vec.T @ rhs)[keep] / lam[keep]
    return vec[:, keep] @ coef


def _estimate_sigma(ev: _Evaluation, system: _System | None, loss: Loss) -> FloatArray:
    """Per-channel noise std from the residuals at an evaluation.

    linear: sqrt(RSS_c / (N - h_c)), with h_c = tr(F^-1 F_c) the degrees of freedom the fit
    takes from channel c (REML-style); huber: 1.4826 * median |residual| (MAD).
    """
    raw = ev.raw
    if loss == "huber":
        sigma = _MAD_TO_STD * np.median(np.abs(raw), axis=1)
    else:
        dof = np.full(3, float(raw.shape[1]))
        if system is not None:
            inverse = np.linalg.pinv(system.information, hermitian=True)
            dof -= np.einsum("ij,cji->c", inverse, system.channel_information)
        sigma = np.sqrt(ev.unit_system()[2] / np.maximum(dof, 1.0))
    # Floor for noise-free data: 1e-12 of the measured magnitudes (never divide by zero).
    return np.maximum(sigma, 1e-12 * (np.sqrt(ev.unit_system()[2] / raw.shape[1]) + 1e-300))


@dataclass
class _Fit:
    ev: _Evaluation
    system: _System
    sigma: FloatArray
    iterations: int
    converged: bool
    message: str


def _levenberg_marquardt(
    model: _Model,
    p0: FloatArray,
    sigma: FloatArray | None,
    loss: Loss,
    max_iterations: int,
    tol: float,
    frozen: FloatArray | None = None,
) -> _Fit:
    """Minimise the whitened (Huber-)cost; steps are relative: p <- p * (1 + step).

    sigma None: re-estimate the noise levels at every iterate (joint iteration), until both
    the step and the noise levels settle. frozen: (3, k) orthonormal relative directions the
    steps must not move along.
    """
    estimate = sigma is None
    ev = model.evaluate(p0)
    if estimate:
        sigma = _estimate_sigma(ev, None, loss)
    system = _system(ev, sigma, loss)
    lam = 1e-3

    def damped_step() -> FloatArray:
        a = system.information
        step = _solve_psd(a + lam * np.diag(np.diag(a)), -system.gradient)
        return step if frozen is None else step - frozen @ (frozen.T @ step)

    for iteration in range(1, max_iterations + 1):
        settled = True
        if estimate:
            new_sigma = _estimate_sigma(ev, system, loss)
            settled = bool(np.all(np.abs(new_sigma / sigma - 1.0) < 1e-6))
            if not settled:
                sigma = new_sigma
                system = _system(ev, sigma, loss)
        step = damped_step()
        if np.max(np.abs(step)) < tol and settled:
            return _Fit(ev, system, sigma, iteration, True, "relative step below tolerance")
        while True:
            trial = ev.p * (1.0 + step)
            if np.all(trial > 0):
                ev_trial = model.evaluate(trial)
                system_trial = _system(ev_trial, sigma, loss)
                if system_trial.cost <= system.cost:
                    break
            lam *= 10.0
            if lam > 1e12:
                return _Fit(ev, system, sigma, iteration, True, "no further decrease of the cost")
            step = damped_step()
        ev, system = ev_trial, system_trial
        lam = max(lam / 10.0, 1e-12)
    return _Fit(ev, system, sigma, max_iterations, False, "maximum number of iterations reached")


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
    tol: float = 1e-8,
    max_relative_std: float = DEFAULT_MAX_RELATIVE_STD,
) -> CalibrationResult:
    """Estimate p = (r_L, r_R, b) from segments by weighted maximum likelihood.

    segments: Segments or an (N, 5) array in CSV column order (N >= 3).
    initial: starting Params; None finds its own start (:func:`initial_estimate`).
    sigma: measurement noise std (sigma_x [m], sigma_y [m], sigma_theta [rad]) or
        (sigma_xy, sigma_theta); None estimates them from the residuals, re-weighting at
        every iteration until they settle.
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

    model = _Model(seg)
    given = None if sigma is None else as_sigma(sigma)
    fit = _levenberg_marquardt(model, p, given, loss, max_iterations, tol)
    lam, vec = np.linalg.eigh(fit.system.information)
    weak = lam * max_relative_std**2 < 1.0
    if np.any(weak):
        # The data cannot determine these directions: hold them at the start instead of
        # letting the fit wander along them to chase noise.
        refit = _levenberg_marquardt(model, start, fit.sigma, loss, max_iterations, tol,
                                     frozen=vec[:, weak])
        refit.iterations += fit.iterations
        fit = refit
    return _result(seg, fit, sigma is None, loss, max_relative_std)


def _result(seg: Segments, fit: _Fit, sigma_estimated: bool, loss: Loss,
            max_relative_std: float) -> CalibrationResult:
    p, info_rel = fit.ev.p, fit.system.information
    lam, vec = np.linalg.eigh(info_rel)
    singular = np.sqrt(np.maximum(lam[::-1], 0.0))
    s_min = singular[-1]
    condition = singular[0] / s_min if s_min > 0 else float("inf")
    covariance = inverse_information(info_rel) * np.outer(p, p)
    identifiable = bool(s_min > 0 and 1.0 / s_min <= max_relative_std)
    direction = vector = None
    if not identifiable:
        vector = vec[:, 0]
        direction = _describe_direction(vector, seg, fit.sigma)
    raw = fit.ev.raw.T
    z = raw / fit.sigma
    outliers = int(np.sum(np.sum(z * z, axis=1) > chi2.ppf(OUTLIER_QUANTILE, 3)))
    return CalibrationResult(
        params=Params.from_array(p),
        covariance=covariance,
        std=np.sqrt(np.diag(covariance)),
        singular_values=singular,
        condition_number=float(condition),
        identifiable=identifiable,
        unidentifiable_direction=direction,
        unidentifiable_vector=vector,
        n_segments=len(seg),
        n_outliers=outliers,
        rms_residual=np.sqrt(np.mean(raw * raw, axis=0)),
        sigma=fit.sigma,
        sigma_estimated=sigma_estimated,
        loss=loss,
        converged=fit.converged,
        iterations=fit.iterations,
        message=fit.message,
        residuals=raw,
    )
