"""Weighted maximum-likelihood fit of a segment model by Levenberg–Marquardt, with the
per-channel noise levels estimated jointly (the engine of :func:`excite.calibrate`).

Steps are taken in relative units (the model's ``column_scale``: log parameters relative to
their value, offsets in units of b, angles in rad), like scipy.optimize's ``x_scale``; the
normal equations are built channel-major (x, y, theta) so that the noise levels can be
re-estimated without re-evaluating the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from excite.calibration.noise import ChainWhitener
from excite.core.information import channel_gram
from excite.core.kinematics import wrap_angle
from excite.core.models import SegmentModel
from excite.logs.segments import Segments
from excite.stats.robust import MEDIAN_ABS_NORMAL

__all__ = ["Loss", "HUBER_K", "STEP_IN_STD", "Problem", "Evaluation", "System", "Fit",
           "solve_psd", "step_in_std", "complement", "damped_step", "damped_step_svd",
           "levenberg_marquardt", "normal_system", "estimate_sigma"]

FloatArray = NDArray[np.float64]
Loss = Literal["linear", "huber"]

#: Huber threshold on whitened residuals (95% efficiency under Gaussian noise).
HUBER_K = 1.345
#: Singular values of the weighted Jacobian below this fraction of the largest are treated as
#: zero in a step (directions the data do not determine do not take steps driven by noise),
#: unless they are above the caller's ``determined`` level (see :func:`damped_step`).
RCOND = 1e-6
#: :func:`damped_step` solves the damped normal equations when their condition number is below
#: this (the Jacobian's below 1e4), and falls back to the SVD of the Jacobian otherwise; above
#: it, :func:`step_in_std` does not end a fit.
GRAM_CONDITION = 1e8
#: A fit has also converged when the Gauss-Newton step would move the estimate by less than
#: this fraction of its std (in the information's metric, the Newton decrement's root): what is
#: left changes nothing the std can see, and large data sets end an evaluation sooner.
STEP_IN_STD = 1e-3
#: The smallest Levenberg-Marquardt damping (relative to the information's diagonal).
MIN_DAMPING = 1e-30
#: Noise levels are floored at this fraction of the measured magnitudes (noise-free data).
SIGMA_FLOOR = 1e-10
#: Most rounds of :func:`settled_sigma` (it settles in a few: the degrees of freedom depend
#: weakly on the levels' ratios).
SETTLE_ROUNDS = 50


class Evaluation:
    """The model at theta: raw residuals (3, N) (predicted - measured, heading wrapped) and
    relative Jacobian rows (3, P, N): d raw[c, k] / d theta_i * column_scale_i. With a
    whitener, raw and jac are whitened (innovations) and ``residual`` keeps the predicted -
    measured values; otherwise ``residual`` is ``raw``."""

    def __init__(self, theta: FloatArray, scale: FloatArray, raw: FloatArray, jac: FloatArray,
                 residual: FloatArray | None = None):
        self.theta, self.scale, self.raw, self.jac = theta, scale, raw, jac
        self.residual = raw if residual is None else residual
        self._unit: tuple[FloatArray, FloatArray, FloatArray] | None = None

    def unit_system(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Per channel: J_c J_c^T (3, P, P), J_c r_c (3, P) and r_c . r_c (3,), for sigma = 1."""
        if self._unit is None:
            info = channel_gram(self.jac)
            gradient = channel_gram(self.jac, self.raw[:, None, :])[:, :, 0]
            self._unit = (info, gradient, channel_gram(self.raw[:, None, :])[:, 0, 0])
        return self._unit


#: How many unwhitened evaluations a whitened problem keeps (the accepted iterate and a
#: rejected trial after it).
PLAIN_KEPT = 2


class Problem:
    """A data set and a model: evaluates residuals and relative Jacobians at theta. whitener:
    an :class:`excite.calibration.noise.ChainWhitener` for segments whose noise is correlated
    (then fit with sigma = 1; the measured positions divided by its ``position_mean``), or
    None (independent segments, per-channel sigma)."""

    def __init__(self, model: SegmentModel, segments: Segments,
                 whitener: ChainWhitener | None = None):
        self.model = model
        self.whitener = whitener
        self.substeps = segments.sub_dphi_L is not None
        if self.substeps:  # a segment of a log: the composition of its sub-steps
            self.phi_L, self.phi_R = segments.sub_dphi_L, segments.sub_dphi_R
        else:
            self.phi_L, self.phi_R = segments.dphi_L, segments.dphi_R
        self.measured = np.stack([segments.dx, segments.dy, segments.dtheta])
        if whitener is not None:  # the measured positions' mean under the pose heading noise
            self.measured[:2] /= whitener.position_mean
        self.n = len(segments)
        position = float(np.sqrt(np.mean(self.measured[0] ** 2 + self.measured[1] ** 2)))
        heading = float(np.sqrt(np.mean(self.measured[2] ** 2)))
        floor = SIGMA_FLOOR * np.array([position, position, heading])
        self.sigma_floor = np.where(floor > 0, floor, 1e-300)
        # the unwhitened evaluations behind the last whitened ones (theta's bytes: evaluation),
        # for the stages that weigh the residuals their own way after a whitened fit
        self._plain: dict[bytes, Evaluation] = {}

    def evaluate(self, theta: FloatArray, whiten: bool = True) -> Evaluation:
        """The evaluation at ``theta``; whitened by the whitener unless ``whiten`` is False."""
        theta = np.asarray(theta, dtype=float)
        key = theta.tobytes()
        if not whiten and key in self._plain:
            return self._plain[key]
        prediction, jac = self.model.evaluate(self.phi_L, self.phi_R, theta,
                                              substeps=self.substeps)
        raw = prediction - self.measured
        raw[2] = wrap_angle(raw[2])
        scale = self.model.column_scale(theta)
        jac *= scale[None, :, None]
        if self.whitener is None or not whiten:
            return Evaluation(theta, scale, raw, jac)
        white, white_jac = self.whitener.whiten(raw, jac)
        if len(self._plain) >= PLAIN_KEPT:
            del self._plain[next(iter(self._plain))]
        self._plain[key] = Evaluation(theta, scale, raw, jac)
        return Evaluation(theta, scale, white, white_jac, residual=raw)


def huber_cost(z: FloatArray) -> float:
    a = np.abs(z)
    return float(np.sum(np.where(a <= HUBER_K, 0.5 * z * z, HUBER_K * (a - 0.5 * HUBER_K))))


@dataclass(frozen=True)
class System:
    """Whitened, (Huber-)weighted normal equations of an evaluation for given sigma."""

    channel_information: FloatArray  # (3 channels, P, P), relative parameters
    gradient: FloatArray  # (P,)
    cost: float

    @property
    def information(self) -> FloatArray:
        return self.channel_information.sum(axis=0)

    def channel_dof(self) -> FloatArray:
        """h_c = tr(F^-1 F_c) (3,): the degrees of freedom the fit takes from each channel
        (they sum to the parameters the data determine); a channel's residual degrees of
        freedom are its residuals' count less h_c."""
        inverse = np.linalg.pinv(self.information, hermitian=True)
        return np.einsum("ij,cji->c", inverse, self.channel_information)


def _weights(ev: Evaluation, sigma: FloatArray, loss: Loss) -> FloatArray:
    """The weight of each residual (3, N): 1 / sigma_c^2, times Huber's k / max(|z|, k)."""
    inv_var = 1.0 / (sigma * sigma)
    if loss == "linear":
        return np.broadcast_to(inv_var[:, None], ev.raw.shape)
    z = ev.raw / sigma[:, None]
    return (HUBER_K / np.maximum(np.abs(z), HUBER_K)) * inv_var[:, None]


def damped_step(ev: Evaluation, system: System, sigma: FloatArray, loss: Loss, lam: float,
                basis: FloatArray | None = None, determined: float = np.inf) -> FloatArray:
    """The Levenberg–Marquardt step in relative units: the least-squares solution of the
    weighted linearised residuals with damping rows sqrt(lam * diag(information)).

    system: the normal equations of ``ev`` at ``sigma`` (:func:`normal_system`). When their
    damped form is well conditioned (condition number below :data:`GRAM_CONDITION`: every
    direction is determined, and the step keeps at least 8 of its 16 digits, which the
    iteration refines), the step solves them; otherwise it is :func:`damped_step_svd`'s,
    solved on the Jacobian itself. basis: (P, m) orthonormal directions the step is confined
    to (None: all); determined: see :func:`damped_step_svd`.
    """
    p = ev.jac.shape[1]
    diagonal = np.maximum(np.diag(system.information), 0.0)
    gram = system.information + np.diag(lam * diagonal)
    gradient = system.gradient
    if basis is not None:
        gram, gradient = basis.T @ gram @ basis, basis.T @ gradient
    if gram.shape[0] == 0:  # every direction frozen: nothing may move
        return np.zeros(p)
    eigenvalues, vectors = np.linalg.eigh(gram)
    if not eigenvalues[0] > eigenvalues[-1] / GRAM_CONDITION:
        return damped_step_svd(ev, sigma, loss, lam, diagonal, basis, determined)
    step = -(vectors @ ((vectors.T @ gradient) / eigenvalues))
    return step if basis is None else basis @ step


def damped_step_svd(ev: Evaluation, sigma: FloatArray, loss: Loss, lam: float,
                    diagonal: FloatArray, basis: FloatArray | None = None,
                    determined: float = np.inf) -> FloatArray:
    """:func:`damped_step`'s reference form, solved on the Jacobian itself (SVD) rather than
    the normal equations. A direction is left out when its singular value is below RCOND of
    the largest (numerically undetermined, next to the others) and below ``determined``
    (relative, whitened: the data determine it to a relative std of 1 / ``determined``; inf:
    the relative rule alone): a direction known far less well than the others but well enough
    still steps (exact data: headings to 1e-11, lengths to 1e-5). diagonal: the damping's
    (P,) information diagonal."""
    root = np.sqrt(_weights(ev, sigma, loss))
    p = ev.jac.shape[1]
    rows = (ev.jac * root[:, None, :]).transpose(0, 2, 1).reshape(-1, p)
    damping = np.diag(np.sqrt(lam * np.maximum(diagonal, 0.0)))
    lhs = np.vstack([rows, damping])
    if basis is not None:
        lhs = lhs @ basis
    rhs = np.concatenate([-(ev.raw * root).reshape(-1), np.zeros(p)])
    if lhs.shape[1] == 0:  # every direction frozen: nothing may move
        return np.zeros(p)
    u, singular, vt = np.linalg.svd(lhs, full_matrices=False)
    keep = singular > min(RCOND * singular[0], determined)
    step = vt[keep].T @ ((u[:, keep].T @ rhs) / singular[keep])
    return step if basis is None else basis @ step


def normal_system(ev: Evaluation, sigma: FloatArray, loss: Loss) -> System:
    if loss == "linear":
        inv_var = 1.0 / (sigma * sigma)
        info, gradient, rss = ev.unit_system()
        return System(info * inv_var[:, None, None], inv_var @ gradient,
                      0.5 * float(inv_var @ rss))
    z = ev.raw / sigma[:, None]
    w = _weights(ev, sigma, loss)
    weighted = ev.jac * w[:, None, :]
    info = np.matmul(weighted, ev.jac.transpose(0, 2, 1))
    gradient = np.einsum("cik,ck->i", weighted, ev.raw)
    return System(info, gradient, huber_cost(z))


def complement(directions: FloatArray) -> FloatArray:
    """An orthonormal basis (P, P - k) of the complement of orthonormal directions (P, k)."""
    p, k = directions.shape
    if k == 0:
        return np.eye(p)
    return np.linalg.svd(np.eye(p) - directions @ directions.T)[0][:, :p - k]


def step_in_std(system: System, basis: FloatArray | None = None) -> float:
    """The length of the Gauss-Newton step in units of the estimate's std (the root of the
    Newton decrement g' F^-1 g), within ``basis`` (P, m) when given; inf when the information
    is not well conditioned (condition number above :data:`GRAM_CONDITION`: a direction known
    far less well than the others, as in noise-free data, is not measured reliably from it,
    and the relative step tolerance decides alone)."""
    gradient, information = system.gradient, system.information
    if basis is not None:
        gradient, information = basis.T @ gradient, basis.T @ information @ basis
    if gradient.size == 0:
        return 0.0
    lam, vectors = np.linalg.eigh(information)
    if not lam[0] > lam[-1] / GRAM_CONDITION:
        return np.inf
    return float(np.sqrt(np.sum((vectors.T @ gradient) ** 2 / lam)))


def solve_psd(a: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve a x = rhs (a vector or columns) for symmetric PSD a, ignoring numerically null
    directions."""
    lam, vec = np.linalg.eigh(a)
    keep = lam > max(lam[-1], 0.0) * 1e-12
    coef = (vec.T @ rhs)[keep] / lam[keep].reshape((-1,) + (1,) * (np.ndim(rhs) - 1))
    return vec[:, keep] @ coef


def estimate_sigma(problem: Problem, ev: Evaluation, system: System | None,
                   loss: Loss) -> FloatArray:
    """Per-channel noise std from the residuals at an evaluation.

    linear: sqrt(RSS_c / (N - h_c)), with h_c = tr(F^-1 F_c) the degrees of freedom the fit
    takes from channel c (REML-style); huber: 1.4826 * median |residual| (MAD). Floored at
    1e-10 of the measured magnitudes, so exact data give exact parameters.
    """
    raw = ev.raw
    if loss == "huber":
        sigma = np.median(np.abs(raw), axis=1) / MEDIAN_ABS_NORMAL
    else:
        dof = np.full(3, float(raw.shape[1]))
        if system is not None:
            dof -= system.channel_dof()
        sigma = np.sqrt(ev.unit_system()[2] / np.maximum(dof, 1.0))
    return np.maximum(sigma, problem.sigma_floor)


def settled_sigma(problem: Problem, ev: Evaluation, loss: Loss) -> tuple[FloatArray, System]:
    """The noise levels (3,) at an evaluation, iterated with their normal system until they
    settle (relative change below 1e-6; :func:`estimate_sigma`'s degrees of freedom depend on
    the levels' ratios), and that system."""
    sigma = estimate_sigma(problem, ev, None, loss)
    system = normal_system(ev, sigma, loss)
    for _ in range(SETTLE_ROUNDS):
        new_sigma = estimate_sigma(problem, ev, system, loss)
        if np.all(np.abs(new_sigma / sigma - 1.0) < 1e-6):
            break
        sigma, system = new_sigma, normal_system(ev, new_sigma, loss)
    return sigma, system


@dataclass
class Fit:
    """Outcome of :func:`levenberg_marquardt` (the last accepted evaluation and its system)."""

    ev: Evaluation
    system: System
    sigma: FloatArray
    iterations: int
    converged: bool
    message: str

    @property
    def theta(self) -> FloatArray:
        return self.ev.theta


def levenberg_marquardt(
    problem: Problem,
    theta0: FloatArray,
    sigma: FloatArray | None,
    loss: Loss,
    max_iterations: int = 100,
    tol: float = 1e-8,
    frozen: FloatArray | None = None,
    determined: float = np.inf,
) -> Fit:
    """Minimise the whitened (Huber-)cost from theta0.

    sigma None: the noise levels estimated with the parameters (joint iteration): settled
    at the start (:func:`settled_sigma`), re-estimated at every iterate, until both the
    relative step and the noise levels settle. frozen: (P, k) orthonormal relative
    directions the steps must not move along. determined: the singular value (relative,
    whitened) above which a direction always steps (:func:`damped_step`; the caller's
    identifiability level, 1 / max_relative_std).
    """
    model = problem.model
    estimate = sigma is None
    ev = problem.evaluate(np.asarray(theta0, dtype=float))
    if estimate:
        sigma, system = settled_sigma(problem, ev, loss)
    else:
        system = normal_system(ev, sigma, loss)
    lam = 1e-3

    positive = np.array([transform == "log" for transform in model.transforms])
    # the directions the steps may take: the complement of ``frozen``
    free = None if frozen is None else complement(frozen)

    def step_now(damping: float) -> FloatArray:
        return damped_step(ev, system, sigma, loss, damping, free, determined)


    for iteration in range(1, max_iterations + 1):
        settled = True
        if estimate:
            new_sigma = estimate_sigma(problem, ev, system, loss)
            settled = bool(np.all(np.abs(new_sigma / sigma - 1.0) < 1e-6))
            if not settled:
                sigma = new_sigma
                system = normal_system(ev, sigma, loss)
        step = step_now(lam)
        gauss_newton = False
        if settled and np.max(np.abs(step)) < tol:
            # the damping can hide a direction the data determine far less well than the
            # others (a small step is no optimum): the Gauss-Newton step decides
            undamped = step_now(0.0)
            if np.max(np.abs(undamped)) < tol:
                return Fit(ev, system, sigma, iteration, True, "relative step below tolerance")
            step, gauss_newton = undamped, True
        if settled and step_in_std(system, free) < STEP_IN_STD:
            return Fit(ev, system, sigma, iteration, True, "step below 0.001 std")
        while True:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
                trial = model.step(ev.theta, step, ev.scale)  # a wild trial is rejected below
            # a wild step overflows, or underflows a length to 0: damp it more
            if np.all(np.isfinite(trial)) and np.all(trial[positive] > 0):
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    ev_trial = problem.evaluate(trial)
                    system_trial = normal_system(ev_trial, sigma, loss)
                if (system_trial.cost <= system.cost
                        and np.all(np.isfinite(system_trial.information))):
                    break
            if gauss_newton or np.max(np.abs(step)) < tol:
                # a step below the tolerance that does not lower the cost: at the optimum, to
                # rounding (more damping gives only smaller steps)
                return Fit(ev, system, sigma, iteration, True, "relative step below tolerance")
            lam *= 10.0
            if lam > 1e12:
                return Fit(ev, system, sigma, iteration, True, "no further decrease of the cost")
            step = step_now(lam)
        ev, system = ev_trial, system_trial
        lam = max(lam / 10.0, MIN_DAMPING)
    return Fit(ev, system, sigma, max_iterations, False, "maximum number of iterations reached")
