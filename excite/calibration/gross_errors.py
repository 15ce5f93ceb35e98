"""Gross errors (``loss="auto"``): found by a contaminated-normal noise model, tested for, and
left out of the fits. This module holds the model, the test, the result
(:class:`GrossErrors`) and the case of independent segments;
:mod:`excite.calibration.gross_samples` the case of segments that share pose samples, whose
gross errors are bad samples.

**The model.** Segment k's residual r_k (predicted - measured: dx, dy in m, dtheta in rad, in
the sensor's frame at the segment's start) is N(0, S) with probability 1 - eps, S =
diag(sigma^2) the noise levels, or a gross error (a scan matcher's bad match, a marker swap, a
pose jump) with probability eps, N(0, k^2 S) with a spread k >= MIN_SPREAD; independently
between segments. Its whitened squared size is z_k^2 = r_k^T S^-1 r_k.

**The test** (eps = 0, at GROSS_TEST_LEVEL). At the plain least-squares fit of the model asked
for (the one the calibration fits anyway), the largest z_k^2 against the chi-square quantile
with 3 degrees of freedom at 1 - GROSS_TEST_LEVEL / N (Bonferroni over the N segments): the
test of the largest studentised residual. Its level is at most GROSS_TEST_LEVEL whatever N
(the residuals' leverage only lowers it), so clean data are left alone in at least 99% of data
sets, and fitted exactly as with ``loss="linear"``. A few percent of gross errors inflate the
least-squares levels (they mask each other) but still stand out far above the quantile; much
more contamination than that can hide them from this test.

**The estimate** (when the test rejects). EM from a Huber fit (robust to the gross errors,
levels from the median absolute residual): the E-step gives each segment's posterior
probability of being gross, p_k = eps g(r_k) / (eps g(r_k) + (1 - eps) f(r_k)), f and g the
two normal densities; the M-step refits the parameters by least squares with weights
1 - p_k, the levels from the weighted residuals (their degrees of freedom the sum of the
weights less the fit's share), eps as the mean of p_k and k^2 as the p-weighted mean of
z^2 / 3. A segment whose posterior exceeds 1/2 is a gross error: the calibration then runs
again on the other segments (weight 0 for the flagged ones, 1 for the rest), so that every
later stage (model choice, fit tests, covariance) sees only the clean segments and the
covariance is their information. The gross component is broad, so the posterior moves from
0.01 to 0.99 within a few units of z^2 and hardly any segment lies in between: weights of 0
and 1 lose nothing against the soft posterior weights.

**Not gross errors.** Gross errors are rare and strike at random: candidates are kept when
they are more than MAX_SHARE of the segments, or when they turn or travel more than the other
segments (:func:`follows_driving`): residuals that grow with the turning or the speed are a
misfit (slip in turns) for the fit tests to judge, not errors to drop.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from excite.calibration.model_choice import Candidates
from excite.calibration.model_fit import Fitter, ModelFit
from excite.calibration.noise_rounds import EstimatedNoise
from excite.calibration.options import FitOptions
from excite.calibration.solver import Problem, levenberg_marquardt
from excite.calibration.starts import Starts
from excite.core.arrays import BoolArray, FloatArray, IntArray
from excite.logs.segments import Segments
from excite.stats.chi2 import chi2_quantile
from excite.stats.robust import MEDIAN_ABS_NORMAL

__all__ = ["DRIVING_TEST_LEVEL", "EM_ROUNDS", "EM_TOL", "GROSS_TEST_LEVEL", "MAX_SHARE",
           "MIN_SPREAD", "Fits", "GrossErrors", "declined_reason", "follows_driving",
           "mixture", "screen", "size_range", "test_threshold", "too_many",
           "without_gross_errors"]

#: Level of the test of "no gross error" (eps = 0): the largest whitened squared residual
#: against the chi-square(3) quantile at 1 - GROSS_TEST_LEVEL / N.
GROSS_TEST_LEVEL = 0.01
#: The gross component's spread k (its std over the noise level) is at least this, so that
#: the two components of the mixture stay apart.
MIN_SPREAD = 3.0
#: Most EM rounds; they stop earlier when no posterior moves by more than EM_TOL.
EM_ROUNDS = 50
EM_TOL = 1e-4
#: Gross errors are rare: more candidates than this share of the segments are kept (the
#: noise model or the segment model is wrong, which the fit tests judge).
MAX_SHARE = 0.2
#: Gross errors strike at random: candidates that turn or travel more than the other segments
#: at this level (two rank-sum tests, one-sided) are kept. (Half the level of the two-sided
#: tests it replaced: the same threshold on the side that slip takes.)
DRIVING_TEST_LEVEL = 0.0005


class Fits(NamedTuple):
    """The fits of one data set (stages 2, 4 and 5 of the pipeline): the starts, the noise
    levels of segments that share pose samples (None otherwise), the fits' noise model and
    the candidate models fitted under it."""

    starts: Starts
    noise: EstimatedNoise | None
    fitter: Fitter
    candidates: Candidates


@dataclass(frozen=True)
class GrossErrors:
    """What the gross-error screen found (:func:`screen`).

    Attributes
    ----------
    segments : ndarray of int, shape (m,)
        The segments left out of the fits as gross errors: their indices (0-based, in the
        order of the segments given to :func:`excite.calibrate`); empty when none.
    n_segments : int
        The segments screened.
    statistic : float
        The largest whitened squared residual z^2 at the plain least-squares fit
        (dimensionless; chi-square with 3 degrees of freedom per segment without gross
        errors).
    threshold : float
        The chi-square(3) quantile at 1 - GROSS_TEST_LEVEL / n_segments it is compared with.
    candidates : ndarray of int, shape (c,)
        The segments whose posterior probability of being gross exceeds 1/2 (``segments``
        unless ``declined``); empty when the test does not reject.
    declined : str or None
        Why the candidates were kept after all, in words (too many of them for gross errors,
        or they follow the driving: a misfit such as slip in turns, which the fit tests
        judge); None when they were left out or there are none.
    fraction : float
        The estimated share eps of gross errors (0 when the test does not reject).
    spread : float or None
        The estimated std of the gross component over the noise level, k; None when the
        test does not reject.
    ratio : tuple of float or None
        The smallest and largest candidate's residual over the noise level, sqrt(z^2 / 3)
        at the EM's levels; None without candidates.
    t_start, t_end : ndarray, shape (m,), or None
        The time spans (s, encoder clock) of ``segments`` for segments with times; else
        None.
    samples : ndarray, shape (s,), or None
        For segments that share pose samples, the times (s, encoder clock) of the pose
        samples taken for gross errors: each shared by two flagged segments, which were made
        one (:mod:`excite.calibration.gross_samples`); None for independent segments.
    dropped : int
        For segments that share pose samples, how many flagged segments were left out (their
        neighbours not flagged, or still gross once merged); the others were merged around
        ``samples``.
    """

    segments: IntArray
    n_segments: int
    statistic: float
    threshold: float
    candidates: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    declined: str | None = None
    fraction: float = 0.0
    spread: float | None = None
    ratio: tuple[float, float] | None = None
    t_start: FloatArray | None = None
    t_end: FloatArray | None = None
    samples: FloatArray | None = None
    dropped: int = 0

    @property
    def detected(self) -> bool:
        """Whether any segment was left out as a gross error."""
        return self.segments.size > 0

    @property
    def message(self) -> str:
        """What was found and done, in words (the report's ``gross errors`` line)."""
        if self.candidates.size == 0:
            if self.statistic <= self.threshold:
                return (f"none found (largest residual {self.statistic:.3g} <= "
                        f"{self.threshold:.3g}, the chi-square(3) quantile at 1 - "
                        f"{GROSS_TEST_LEVEL:g}/N)")
            return (f"none found (largest residual {self.statistic:.3g} > "
                    f"{self.threshold:.3g}, but no segment is more likely a gross error "
                    "than not)")
        m, n = self.candidates.size, self.n_segments
        assert self.ratio is not None
        size = _times(*self.ratio)
        count = f"{m} of {n} segment{'' if n == 1 else 's'} ({100 * m / n:.2g}%)"
        if self.declined is not None:
            return (f"{count} {'has' if m == 1 else 'have'} residuals {size} the noise level, "
                    f"{self.declined}: kept as they are")
        if self.samples is None:
            return (f"{count} {'is a gross error' if m == 1 else 'are gross errors'} "
                    f"(residuals {size} the noise level): left out of the fit; --loss linear "
                    "to keep them")
        return (f"{count} spoilt by gross errors (residuals {size} the noise level): "
                f"{_samples_words(self.samples, self.dropped)}; --loss linear to keep them")

    def to_dict(self) -> dict:
        """JSON-ready dict (the ``gross_errors`` object of ``excite calibrate --json``)."""
        return {"detected": self.detected, "message": self.message,
                "statistic": self.statistic, "threshold": self.threshold,
                "candidates": [int(i) for i in self.candidates], "declined": self.declined,
                "fraction": self.fraction, "spread": self.spread,
                "ratio": None if self.ratio is None else list(self.ratio),
                "samples": None if self.samples is None else [float(t) for t in self.samples],
                "dropped": self.dropped}

    def kept(self) -> BoolArray:
        """Which of the screened segments are kept (n_segments,)."""
        keep = np.ones(self.n_segments, dtype=bool)
        keep[self.segments] = False
        return keep


def _samples_words(samples: FloatArray, dropped: int) -> str:
    """What was done about the gross errors of segments that share pose samples."""
    shown = ", ".join(f"{t:.6g}" for t in samples[:5]) + (", ..." if samples.size > 5 else "")
    words = []
    if samples.size:
        one = samples.size == 1
        words.append(f"{samples.size} pose sample{'' if one else 's'} (at t = {shown} s) "
                     f"{'is a gross error' if one else 'are gross errors'}, the segments that "
                     f"share {'it' if one else 'each'} made one")
    if dropped:
        words.append(f"{dropped} {'other ' if samples.size else ''}segment"
                     f"{'' if dropped == 1 else 's'} left out")
    return "; ".join(words)


def _times(lo: float, hi: float) -> str:
    """A range of ratios in words: "12-80x", "7.9x"."""
    def one(x: float) -> str:
        return f"{x:.0f}" if x >= 10 else f"{x:.2g}"

    return f"{one(lo)}x" if one(lo) == one(hi) else f"{one(lo)}-{one(hi)}x"


class _Weights:
    """Scales each segment's residual and Jacobian rows by the square root of its weight (a
    whitener of :class:`excite.calibration.solver.Problem`: weighted least squares)."""

    wheels = None
    position_mean = 1.0  # the measured positions as they are

    def __init__(self, weights: FloatArray):
        self.root = np.sqrt(weights)

    def whiten(self, raw: FloatArray, jac: FloatArray | None
               ) -> tuple[FloatArray, FloatArray | None]:
        return raw * self.root, None if jac is None else jac * self.root


def _z2(residual: FloatArray, sigma: FloatArray) -> FloatArray:
    """Whitened squared size of each segment's residual (N,): sum_c (r_c / sigma_c)^2."""
    z = residual / sigma[:, None]
    return np.einsum("cn,cn->n", z, z)


def _posterior(z2: FloatArray, fraction: float, spread: float) -> FloatArray:
    """Each segment's posterior probability of being gross under the contaminated normal."""
    # log f - log g of the 3-variate normals N(0, S) and N(0, k^2 S) (S cancels)
    log_ratio = -0.5 * z2 * (1.0 - 1.0 / spread**2) + 3.0 * math.log(spread)
    log_odds = math.log(fraction / (1.0 - fraction)) - log_ratio
    return 1.0 / (1.0 + np.exp(-np.clip(log_odds, -700.0, 700.0)))


def _weighted_sigma(problem: Problem, weights: FloatArray, fit) -> FloatArray:
    """Per-channel noise std from the weighted residuals of a fit: sqrt(sum w r_c^2 /
    (sum w - h_c)), h_c = tr(F^-1 F_c) the degrees of freedom the fit takes from channel c."""
    dof = float(np.sum(weights)) - fit.system.channel_dof()
    rss = fit.ev.unit_system()[2]  # of the weighted rows: sum w r_c^2
    return np.maximum(np.sqrt(rss / np.maximum(dof, 1.0)), problem.sigma_floor)


def test_threshold(n: int) -> float:
    """The chi-square(3) quantile at 1 - GROSS_TEST_LEVEL / n the largest of n whitened
    squared residuals is compared with."""
    return chi2_quantile(1.0 - GROSS_TEST_LEVEL / n, 3)


def size_range(size: FloatArray) -> tuple[float, float]:
    """The smallest and largest of the candidates' sizes sqrt(z^2 / 3)."""
    return float(size.min()), float(size.max())


def declined_reason(data: Segments, candidates: IntArray) -> str | None:
    """Why the candidates (indices into ``data``) are not gross errors, in words: more than
    MAX_SHARE of the segments (:func:`too_many`), or following the driving
    (:func:`follows_driving`); None when they are."""
    return too_many(data, candidates) or follows_driving(data, candidates)


def too_many(data: Segments, candidates: IntArray) -> str | None:
    """"too many for gross errors" when the candidates are more than MAX_SHARE of ``data``;
    else None."""
    if candidates.size > MAX_SHARE * len(data):
        return f"too many for gross errors (more than {100 * MAX_SHARE:g}%)"
    return None


def screen(plain: ModelFit, data: Segments, sigma_given: FloatArray | None,
           options: FitOptions) -> GrossErrors:
    """The gross errors of independent segments ``data`` (see the module doc) from the plain
    least-squares fit ``plain`` of the model asked for (per-channel sigma, given as
    ``sigma_given`` (m, m, rad) or estimated)."""
    n = len(data)
    z2 = _z2(plain.fit.ev.residual, plain.fit.sigma)
    nothing = GrossErrors(np.zeros(0, dtype=np.int64), n, float(np.max(z2)), test_threshold(n))
    if nothing.statistic <= nothing.threshold:
        return nothing
    theta, sigma, posterior, fraction, spread = _em(plain, data, sigma_given, options)
    candidates = np.flatnonzero(posterior > 0.5).astype(np.int64)
    if candidates.size == 0:
        return nothing
    size = np.sqrt(_z2(plain.problem.evaluate(theta, whiten=False).raw[:, candidates], sigma)
                   / 3.0)
    found = replace(nothing, segments=candidates, candidates=candidates, fraction=fraction,
                    spread=spread, ratio=size_range(size))
    declined = declined_reason(data, candidates)
    if declined is not None:
        return replace(found, segments=np.zeros(0, dtype=np.int64), declined=declined)
    if data.t_start is None or data.t_end is None:
        return found
    return replace(found, t_start=data.t_start[candidates], t_end=data.t_end[candidates])


def without_gross_errors(fits: Fits, refit: Callable[[Segments], Fits],
                         sigma_given: FloatArray | None, options: FitOptions
                         ) -> tuple[Segments, Fits, GrossErrors]:
    """The calibration's data and fits without their gross errors, and what was found:
    independent segments by :func:`screen` (the fits made again without the flagged ones),
    segments that share pose samples (noise levels estimated) by
    :func:`excite.calibration.gross_samples.screen_chain`. ``refit`` makes the fits of
    another data set (stages 2, 4 and 5 of the pipeline)."""
    data = fits.fitter.data
    if fits.noise is not None:
        from excite.calibration.gross_samples import screen_chain

        return screen_chain(fits, refit)
    found = screen(fits.candidates.primary, data, sigma_given, options)
    if not found.detected:
        return data, fits, found
    kept = data[found.kept()]
    return kept, refit(kept), found


def _rank_sum_z(values: FloatArray, chosen: BoolArray) -> float:
    """The z value of Wilcoxon's rank-sum statistic of ``values[chosen]`` against the rest
    (midranks for ties, the variance corrected for them); 0 when every value ties."""
    n, m = values.size, int(chosen.sum())
    order = np.argsort(values, kind="mergesort")
    _, first, counts = np.unique(values[order], return_index=True, return_counts=True)
    ranks = np.empty(n)
    ranks[order] = np.repeat(first + 0.5 * (counts + 1), counts)
    ties = float(np.sum(counts**3 - counts)) / (n * (n - 1)) if n > 1 else 0.0
    variance = m * (n - m) / 12.0 * ((n + 1) - ties)
    if variance <= 0:
        return 0.0
    return float((ranks[chosen].sum() - m * (n + 1) / 2.0) / math.sqrt(variance))


def follows_driving(data: Segments, candidates: IntArray) -> str | None:
    """Why the candidates are not gross errors, in words, when they follow the driving: the
    rank-sum tests of their turn |dphi_R - dphi_L| and of their travel |dphi_L + dphi_R|
    (rad) against the other segments', one-sided (more than the others: slip grows with the
    turn and the speed), at DRIVING_TEST_LEVEL over both; None when neither rejects (gross
    errors strike at random). Not the other side: where the noise grows with the driving
    (slip through the wheels, encoder timing), a gross error of a given size stands out more
    on the segments that move least, so random gross errors are found mostly there."""
    from scipy.special import ndtri  # scipy on first use (import excite stays light)

    chosen = np.zeros(len(data), dtype=bool)
    chosen[candidates] = True
    limit = float(ndtri(1.0 - DRIVING_TEST_LEVEL / 2.0))
    for values, what in ((np.abs(data.dphi_R - data.dphi_L), "turn the most"),
                         (np.abs(data.dphi_L + data.dphi_R), "travel the farthest")):
        z = _rank_sum_z(values, chosen)
        if z > limit:
            return (f"mostly the segments that {what} (rank-sum z {z:+.1f}), a misfit that "
                    "follows the driving (slip in turns?)")
    return None


def _initial_mixture(z2: FloatArray) -> tuple[float, float]:
    """eps and k to start EM from: the share of z^2 beyond the chi-square(3) 99.9% quantile
    (at least 1 / N) and their mean z^2 / 3 (k at least MIN_SPREAD)."""
    wide = z2 > chi2_quantile(0.999, 3)
    fraction = min(max(float(np.mean(wide)), 1.0 / z2.size), 0.5)
    spread = max(math.sqrt(float(np.mean(z2[wide])) / 3.0) if wide.any() else MIN_SPREAD,
                 MIN_SPREAD)
    return fraction, spread


def _mixture_step(z2: FloatArray, posterior: FloatArray) -> tuple[float, float]:
    """The M-step of eps and k: the mean posterior (within [0.5 / N, 0.5]) and the
    posterior-weighted mean of z^2 / 3 (k at least MIN_SPREAD)."""
    fraction = min(max(float(np.mean(posterior)), 0.5 / z2.size), 0.5)
    spread = max(math.sqrt(float(posterior @ z2) / (3.0 * max(posterior.sum(), 1e-300))),
                 MIN_SPREAD)
    return fraction, spread


def mixture(z2: FloatArray) -> tuple[FloatArray, float, float]:
    """EM of the contaminated normal on whitened squared sizes z^2 (N,) held fixed: each
    segment's posterior probability of being gross, eps and k."""
    fraction, spread = _initial_mixture(z2)
    posterior = np.zeros(z2.size)
    for _ in range(EM_ROUNDS):
        new = _posterior(z2, fraction, spread)
        moved = float(np.max(np.abs(new - posterior)))
        posterior = new
        fraction, spread = _mixture_step(z2, posterior)
        if moved < EM_TOL:
            break
    return _posterior(z2, fraction, spread), fraction, spread


def _em(plain: ModelFit, data: Segments, sigma_given: FloatArray | None,
        options: FitOptions) -> tuple[FloatArray, FloatArray, FloatArray, float, float]:
    """EM of the contaminated normal from a Huber fit, the parameters refitted at each round:
    the parameters, the noise levels (m, m, rad), each segment's posterior probability of
    being gross, eps and k."""
    problem = plain.problem
    model, n = plain.model, problem.n
    frozen = plain.weak if plain.weak.shape[1] else None
    determined = 1.0 / options.max_relative_std
    robust = levenberg_marquardt(problem, plain.theta, sigma_given, "huber",
                                 options.max_iterations, options.tol, frozen=frozen,
                                 determined=determined)
    theta = robust.theta
    raw = robust.ev.residual
    sigma = (sigma_given if sigma_given is not None else np.maximum(
        np.median(np.abs(raw), axis=1) / MEDIAN_ABS_NORMAL, problem.sigma_floor))
    z2 = _z2(raw, sigma)
    fraction, spread = _initial_mixture(z2)
    posterior = np.zeros(n)
    for _ in range(EM_ROUNDS):
        new = _posterior(z2, fraction, spread)
        moved = float(np.max(np.abs(new - posterior)))
        posterior = new
        fraction, spread = _mixture_step(z2, posterior)
        weights = 1.0 - posterior
        weighted = Problem(model, data, _Weights(weights))
        fit = levenberg_marquardt(weighted, theta, sigma, "linear", options.max_iterations,
                                  options.tol, frozen=frozen, determined=determined)
        theta = fit.theta
        if sigma_given is None:
            sigma = _weighted_sigma(problem, weights, fit)
        z2 = _z2(fit.ev.residual, sigma)
        if moved < EM_TOL:
            break
    return theta, sigma, _posterior(z2, fraction, spread), fraction, spread
