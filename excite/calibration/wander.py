"""A pose source whose heading error wanders: a first-order Gauss-Markov heading error of the
pose samples, estimated with the other noise levels of a log's segments, and the covariance
of the fitted parameters it implies.

Model (frames and linearisation as :mod:`excite.calibration.noise`). Besides each pose sample's
independent noise, the heading of every pose sample errs by g(t), a stationary first-order
Gauss-Markov process (a scan matcher's or visual odometry's slowly wandering error): std
``std`` (rad) and correlation exp(-|t - t'| / ``time``) (s) between samples on one clock;
samples on different clocks (logs whose times do not follow on) are independent. Segment k,
measured between the pose samples at t_s and t_e, errs by

    -g(t_s) J d_k  (x, y; J d_k the measured increment turned by +90 degrees),
    g(t_e) - g(t_s)  (theta).

The heading error does not cancel in x and y: a part of it that is constant over the log
turns every increment by the same angle, exactly as the sensor's mounting angle does, so no
fit of one log can tell them apart, and the mounting angle carries the log's mean heading
error. The model states that uncertainty instead of hiding it: its level and time constant
are identified by how the error varies within the log, and the mean over the log that this
implies enters the parameters' covariance. (A time constant far beyond the log's length
cannot be told from a heading random walk; it is bounded by the longest unbroken stretch of
chained segments, no gap between them, and ``HeadingWander.at_bound`` says when it sits
there; from below by the median segment duration.) The position part of such
an error is not modelled: its differences nearly cancel along the log.

* :func:`estimate_wander`: restricted maximum likelihood (as
  :func:`excite.calibration.reml.reml_noise`) of the chain's noise levels with and without the
  wandering error (with it: the projected Newton search of
  :func:`excite.calibration.reml_search.newton_search` with the analytic gradient and the
  average information, L-BFGS-B on where it does not converge), on the dense covariance of
  chunks of at most CHUNK_SEGMENTS consecutive segments (their restricted likelihood as if
  the chunks were independent; at most MAX_CHUNKS chunks, spread over the log); the
  wandering error is kept when the likelihood ratio exceeds the chi-bar-square quantile of
  one variance component on its boundary at ``test_level`` (as
  :func:`excite.calibration.reml.reml_noise`'s tests; the time constant is not identified
  without the wander, so the level is approximate: ``benchmarks/bench_logs.py`` counts how
  often white pose noise is taken for a wander).
* :func:`wander_covariance`: the covariance of the estimate weighted by the chain's
  covariance B alone (the fit is unchanged) when the increments' covariance is
  C = B' + A Sigma A^T (the sandwich I^-1 J^T B^-1 C B^-1 J I^-1), in O(N).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from excite.calibration.noise import (
    ChainWhitener,
    LevelBands,
    NoiseLevels,
    WheelNoise,
    chain_band,
)
from excite.calibration.reml import level_bounds
from excite.calibration.reml_search import RestrictedDeviance, newton_search
from excite.core.arrays import BoolArray, FloatArray, IntArray
from excite.core.banded import band_inner, band_product, dense
from excite.logs.segments import Segments
from excite.stats.autocorrelation import runs_of
from excite.stats.chi2 import chi_bar_square_quantile

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

__all__ = ["HeadingWander", "estimate_wander", "wander_covariance", "CHUNK_SEGMENTS",
           "MAX_CHUNKS", "MIN_WANDER_SEGMENTS", "WANDER_TEST_LEVEL"]


#: Segments per chunk of the dense restricted likelihood (a 3n x 3n covariance per chunk).
CHUNK_SEGMENTS = 150
#: At most this many chunks enter the estimate (spread evenly over a longer log).
MAX_CHUNKS = 3
#: Logs of fewer segments are not tested for a wandering heading error.
MIN_WANDER_SEGMENTS = 50
#: Time constants (in segment durations) at which the search may start, each with the std
#: at the chain's heading level, 3 times it and the heading residuals' RMS (where the chain
#: found no heading noise its level is the floor, where the deviance is flat in the time
#: constant); it starts at the best.
START_TIMES = (2.0, 6.0, 20.0, 60.0)
#: Relative tolerance of each likelihood search (the deviance is ~ -1e3 per 100 segments).
FTOL = 1e-10
#: An L-BFGS-B search restarts from where it stopped (at most MAX_RESTARTS times) while a
#: restart lowers the deviance by more than RESTART_GAIN.
MAX_RESTARTS = 8
RESTART_GAIN = 1e-2
#: Level of the likelihood-ratio test of "no wandering heading error".
WANDER_TEST_LEVEL = 0.05
#: The deviance where a covariance is not positive definite (finite: L-BFGS-B's difference
#: checks stay numbers).
UNDEFINED = 1e300
#: Relative jitter added to the diagonal of each chunk's dense covariance.
JITTER = 1e-10
#: Most evaluations of one L-BFGS-B search.
MAX_EVALUATIONS = 400


@dataclass(frozen=True)
class HeadingWander:
    """A wandering heading error of the pose samples: ``std`` (rad), ``correlation_time``
    (s), the likelihood ratio against none (``statistic``), the chain's noise levels
    estimated with it (``levels``: sigma m, m, rad; pose m, rad; slip rad / sqrt(s); timing s) and
    whether the time constant sits at its bound, the longest unbroken stretch of the log
    (``at_bound``: a slower wander, indistinguishable from a heading random walk, whose
    mean over the log is then understated)."""

    std: float
    correlation_time: float
    statistic: float
    levels: NoiseLevels
    at_bound: bool = False


@dataclass(frozen=True)
class _Samples:
    """The pose samples segments are measured between: each segment's first and last sample
    (indices into ``times``), the samples' times (s) and clocks (a new clock wherever a
    segment starts before the one before it ended: another log)."""

    start: IntArray
    end: IntArray
    times: FloatArray
    clock: IntArray

    @classmethod
    def of(cls, segments: Segments) -> _Samples:
        if segments.t_start is None or segments.t_end is None:
            raise ValueError("a wandering heading error needs segments with times")
        t0, t1 = segments.t_start, segments.t_end
        clock = np.concatenate(([0], np.cumsum(t0[1:] < t1[:-1])))
        keys = np.stack([np.concatenate([clock, clock]), np.concatenate([t0, t1])], axis=1)
        unique, inverse = np.unique(keys, axis=0, return_inverse=True)
        n = len(segments)
        inverse = inverse.reshape(-1)
        return cls(inverse[:n], inverse[n:], unique[:, 1], unique[:, 0].astype(np.int64))

    def correlation(self, time: float) -> tuple[FloatArray, FloatArray]:
        """R (M, M) for the correlation ``time`` (s): exp(-|t_i - t_j| / time) on one clock,
        0 across clocks; and dR / d log time = R |t_i - t_j| / time."""
        lag = np.abs(self.times[:, None] - self.times[None, :])
        same = self.clock[:, None] == self.clock[None, :]
        r = np.where(same, np.exp(-lag / time), 0.0)
        return r, r * lag / time

    def apply_correlation(self, time: float, h: FloatArray) -> FloatArray:
        """R h for h (M, P) and the correlation ``time`` (s), in O(M P): the forward and
        backward first-order recursions."""
        gap = np.diff(self.times)
        a = np.where(np.diff(self.clock) == 0, np.exp(-np.maximum(gap, 0.0) / time), 0.0)
        forward, backward = h.copy(), h.copy()
        for i in range(1, len(h)):
            forward[i] += a[i - 1] * forward[i - 1]
        for i in range(len(h) - 2, -1, -1):
            backward[i] += a[i] * backward[i + 1]
        return forward + backward - h

    def design(self, segments: Segments) -> csr_matrix:
        """A^T (M, 3N), sparse: segment k's x, y rows are its lever arm -J d_k
        (:func:`_lever`) at its first sample, its theta row -1 there and +1 at its last."""
        from scipy.sparse import csr_matrix

        lever, n = _lever(segments), len(segments)
        rows = 3 * np.arange(n)
        return csr_matrix(
            (np.concatenate([lever[:, 0], lever[:, 1], -np.ones(n), np.ones(n)]),
             (np.concatenate([self.start, self.start, self.start, self.end]),
              np.concatenate([rows, rows + 1, rows + 2, rows + 2]))),
            shape=(len(self.times), 3 * n))

    def transpose_design(self, segments: Segments, rows: FloatArray) -> FloatArray:
        """A^T ``rows`` (M, P) for rows (3N, P) in O(N P)."""
        return self.design(segments) @ rows


def _longest_stretch(segments: Segments) -> float:
    """The longest unbroken stretch of chained segments (s): from the first one's start to
    the last one's end, with no gap or part boundary between (0 without times)."""
    if segments.t_start is None or segments.t_end is None:
        return 0.0
    runs = runs_of(segments.chained, len(segments))
    first = np.flatnonzero(np.diff(runs, prepend=-1) != 0)
    last = np.append(first[1:], len(segments)) - 1
    return float(np.max(segments.t_end[last] - segments.t_start[first]))


@dataclass(frozen=True)
class _Chunk:
    """One chunk's fixed parts: the covariance's band as a function of the levels, the
    heading-error design (``design``: A^T, :meth:`_Samples.design`) and the residuals and
    Jacobian."""

    bands: LevelBands
    samples: _Samples
    design: csr_matrix
    residual: FloatArray
    jac: FloatArray

    @classmethod
    def of(cls, segments: Segments, wheels: WheelNoise | None, residual: FloatArray,
           jac: FloatArray, n_levels: int) -> _Chunk:
        samples = _Samples.of(segments)
        return cls(LevelBands(segments, wheels, n_levels), samples, samples.design(segments),
                   residual, jac)


def _lever(segments: Segments) -> FloatArray:
    """-J d (N, 2) (m/rad): each segment's x and y error per unit heading error at its first
    sample (its theta row is -1 there and +1 at its last: the design A of the module doc)."""
    return np.stack([segments.dy, -segments.dx], axis=1)


def _sandwiched(design: csr_matrix, r: FloatArray) -> FloatArray:
    """A R A^T (3n, 3n) for the heading-error design ``design`` = A^T (M, 3n)
    (:meth:`_Samples.design`) and R (M, M) symmetric: two sparse products, A (A R)^T."""
    a = design.T
    return a @ (a @ r).T


def _deviance(chunks: list[_Chunk], u: FloatArray, n_levels: int, wander: bool,
              with_gradient: bool = True, with_information: bool = False
              ) -> tuple[float, FloatArray | None, FloatArray | None]:
    """-2 log restricted likelihood (up to a constant) of the chunks taken as independent;
    (``with_gradient``) its gradient by u = log of (levels..., [std, time]); and
    (``with_information``, with the gradient) its average information in v = exp(2 u) (the
    squared levels, std^2 and time^2), y^T P dC_i P dC_j P y (as
    :class:`excite.calibration.reml_search.RestrictedDeviance`'s). Each chunk's
    covariance gets JITTER of its diagonal added: the wander's rank-one x, y blocks with the
    position levels at their floor are otherwise singular to rounding."""
    from scipy.linalg import cho_factor, cho_solve
    from scipy.linalg.lapack import dpotri

    levels = np.exp(u[:n_levels])
    variances = levels * levels
    std2, time = (math.exp(2.0 * u[-2]), math.exp(u[-1])) if wander else (0.0, 1.0)
    total = 0.0
    parts = []
    p = chunks[0].jac.shape[1]
    info, gradient = np.zeros((p, p)), np.zeros(p)
    for c in chunks:
        band = c.bands.at(levels)
        cov = dense(band)
        r = dr = None
        if wander:
            r, dr = c.samples.correlation(time)
            cov += std2 * _sandwiched(c.design, r)
        cov[np.diag_indices_from(cov)] *= 1.0 + JITTER
        factor, _ = cho_factor(cov, lower=True, check_finite=False)
        total += 2.0 * float(np.sum(np.log(np.diag(factor))))
        if with_gradient:  # the gradient needs C^-1 itself
            inverse, status = dpotri(factor, lower=1)
            if status:
                raise np.linalg.LinAlgError("covariance not positive definite")
            np.copyto(inverse, inverse.T, where=_upper(inverse.shape[0]))  # from its lower
            ci_j, ci_e = inverse @ c.jac, inverse @ c.residual
        else:
            inverse = None
            solved = cho_solve((factor, True), np.column_stack([c.jac, c.residual]),
                               check_finite=False)
            ci_j, ci_e = solved[:, :-1], solved[:, -1]
        info += c.jac.T @ ci_j
        gradient += c.jac.T @ ci_e
        total += float(c.residual @ ci_e)
        parts.append((inverse, ci_j, ci_e, r, dr))
    g_factor = cho_factor(info, lower=True, check_finite=False)
    beta = cho_solve(g_factor, gradient, check_finite=False)
    total += 2.0 * float(np.sum(np.log(np.diag(g_factor[0])))) - float(gradient @ beta)
    if not with_gradient:
        return total, None, None
    grad = np.zeros(u.size)
    info_inverse = cho_solve(g_factor, np.eye(p), check_finite=False)
    average = _AverageInformation(u.size, std2, time, p) if with_information else None
    for c, (inverse, ci_j, ci_e, r, dr) in zip(chunks, parts, strict=True):
        # d deviance / d theta_i = tr(M dC_i), M = P - P e e^T P, P = C^-1 - C^-1 J I^-1 J^T
        # C^-1: only M's band (the levels' units) and A^T M A (the wander's) are needed
        y = ci_e - ci_j @ beta  # P e
        low = ci_j @ info_inverse
        width = c.bands.units[0].shape[0]
        n = y.size
        m_band = np.zeros((width, n))
        for d in range(width):
            m_band[d, : n - d] = (np.diagonal(inverse, offset=-d)
                                  - np.einsum("ip,ip->i", low[d:], ci_j[: n - d])
                                  - y[d:] * y[: n - d])
        for i, (v, unit) in enumerate(zip(variances, c.bands.units, strict=True)):
            grad[i] += 2.0 * v * band_inner(unit, m_band)
        if wander:
            a_low, a_j, a_y = c.design @ low, c.design @ ci_j, c.design @ y
            projected = (c.design @ (c.design @ inverse).T
                         - a_low @ a_j.T - np.outer(a_y, a_y))  # A^T M A
            grad[-2] += 2.0 * std2 * float(np.sum(projected * r))
            grad[-1] += std2 * float(np.sum(projected * dr))
        if average is not None:
            average.add(c, inverse, ci_j, y, r, dr)
    return total, grad, None if average is None else average.matrix(info_inverse)


class _AverageInformation:
    """The average information y^T P dC_i P dC_j P y of :func:`_deviance` in v = exp(2 u),
    summed over the chunks: with w_i = dC_i P y per chunk, sum w_i^T C^-1 w_j less
    t_i^T (J^T C^-1 J)^-1 t_j, t_i = sum J^T C^-1 w_i (P couples the chunks through the common
    parameters). dC_i: the level's unit band; for std^2, A R A^T; for time^2, std^2 A (dR / d
    time) A^T / (2 time)."""

    def __init__(self, size: int, std2: float, time: float, p: int):
        self.size, self.std2, self.time = size, std2, time
        self.inner = np.zeros((size, size))
        self.shares = np.zeros((p, size))

    def add(self, c: _Chunk, inverse: FloatArray, ci_j: FloatArray, y: FloatArray,
            r: FloatArray | None, dr: FloatArray | None) -> None:
        """One chunk's share (its C^-1, C^-1 J, P y and R, dR / d log time)."""
        w = np.empty((y.size, self.size))
        for i, unit in enumerate(c.bands.units):
            w[:, i] = band_product(unit, y[:, None])[:, 0]
        if r is not None and dr is not None:
            a_y = c.design @ y
            w[:, -2] = c.design.T @ (r @ a_y)
            w[:, -1] = (self.std2 / (2.0 * self.time**2)) * (c.design.T @ (dr @ a_y))
        self.inner += w.T @ (inverse @ w)
        self.shares += ci_j.T @ w

    def matrix(self, info_inverse: FloatArray) -> FloatArray:
        """The sum over the chunks, given (J^T C^-1 J)^-1 of all of them."""
        out = self.inner - self.shares.T @ info_inverse @ self.shares
        return 0.5 * (out + out.T)


@functools.lru_cache(maxsize=8)
def _upper(n: int) -> BoolArray:
    """The mask (n, n) of the strict upper triangle."""
    return np.triu(np.ones((n, n), dtype=bool), 1)


def _chunk_ranges(n: int) -> list[range]:
    """Up to MAX_CHUNKS ranges of CHUNK_SEGMENTS consecutive segments (a shorter log: one or
    more chunks of about equal length), spread evenly over the n segments."""
    count = math.ceil(n / CHUNK_SEGMENTS)
    size = math.ceil(n / count)
    starts = [i * size for i in range(count)]
    if count > MAX_CHUNKS:
        starts = [starts[i] for i in np.linspace(0, count - 1, MAX_CHUNKS).round().astype(int)]
    return [range(s, min(s + size, n)) for s in starts]


def estimate_wander(segments: Segments, residual: FloatArray, jac: FloatArray,
                    levels: NoiseLevels, floor: FloatArray, wheels: WheelNoise | None = None,
                    test_level: float = WANDER_TEST_LEVEL) -> HeadingWander | None:
    """The wandering heading error of the pose samples (module doc), or None when the data do
    not show one (or the log is shorter than MIN_WANDER_SEGMENTS, has no times, or no
    unbroken stretch longer than two segment durations). residual (3, N) (predicted
    - measured) and jac (3, P, N) (the directions the data determine) of the fit at the
    chain's noise ``levels`` (the start of the search; ``wheels``: its wheel-space noise);
    ``floor`` (3,): the (position, position, heading) floor of the levels, as reml_noise."""
    from scipy.optimize import minimize

    n = len(segments)
    if n < MIN_WANDER_SEGMENTS or segments.t_start is None or segments.t_end is None:
        return None
    step = float(np.median(segments.t_end - segments.t_start))  # s
    longest = _longest_stretch(segments)  # s
    if not step > 0.0 or not longest > 2.0 * step:  # nothing long enough to see a wander
        return None
    n_levels = levels.vector(wheels is not None).size
    e = residual.T.reshape(-1)
    j = jac.transpose(2, 0, 1).reshape(e.size, -1)
    chunks = []
    for part in _chunk_ranges(n):
        rows = np.arange(3 * part.start, 3 * part.stop)
        chunk_wheels = None if wheels is None else wheels.take(np.asarray(part))
        chunks.append(_Chunk.of(segments[part.start:part.stop], chunk_wheels, e[rows],
                                j[rows], n_levels))
    lower, upper = level_bounds(residual, floor, wheels)
    start = np.clip(np.log(np.maximum(levels.vector(wheels is not None), 1e-300)), lower,
                    upper)

    last: dict[tuple[bytes, bool], tuple[float, FloatArray]] = {}

    def deviance(u: FloatArray, wander: bool) -> tuple[float, FloatArray]:
        key = (u.tobytes(), wander)
        if key in last:  # a restart begins where the search before it ended
            value, gradient = last[key]
            return value, gradient.copy()
        try:
            value, gradient, _ = _deviance(chunks, u, n_levels, wander)
        except np.linalg.LinAlgError:  # not positive definite at the bounds
            return UNDEFINED, np.zeros(u.size)
        assert gradient is not None
        last.clear()
        last[key] = (value, gradient)
        return value, gradient.copy()

    def fitted(u0: FloatArray, lo: FloatArray, hi: FloatArray, wander: bool
               ) -> tuple[FloatArray, float]:
        # L-BFGS-B stops early in the deviance's curved valleys (its line search gives up):
        # it restarts from where it stopped until a restart gains less than RESTART_GAIN
        u, value = u0, math.inf
        for _ in range(MAX_RESTARTS):
            result = minimize(deviance, u, args=(wander,), jac=True, method="L-BFGS-B",
                              bounds=list(zip(lo, hi, strict=True)),
                              options={"ftol": FTOL, "maxfun": MAX_EVALUATIONS})
            gain = value - float(result.fun)
            if gain > 0:
                u, value = result.x, float(result.fun)
            if not gain > RESTART_GAIN:
                break
        return u, value

    # without the wander the chunks' covariance is banded: the REML search of the chain's
    # levels (the same deviance, the dense one's L-BFGS-B where it does not converge)
    banded = RestrictedDeviance(LevelBands.side_by_side([c.bands for c in chunks]),
                                np.column_stack([np.concatenate([c.residual for c in chunks]),
                                                 np.concatenate([c.jac for c in chunks])]))
    _, null, converged = newton_search(banded, banded.information, start, banded(start),
                                       np.ones(start.size, dtype=bool), lower, upper)
    if not converged:
        _, null = fitted(start, lower, upper, wander=False)
    if null >= UNDEFINED:
        return None
    largest_heading = max(float(np.max(np.abs(residual[2]))), floor[2])  # rad
    w_lower = np.append(lower, [math.log(floor[2]), math.log(step)])
    w_upper = np.append(upper, [math.log(10.0 * largest_heading), math.log(longest)])
    # start the search at the best of a few time constants (the deviance can have a local
    # minimum at a short one, mimicking white noise, and one at a long one)
    first_std = max(levels.pose[1], levels.sigma[2], floor[2])  # rad: the chain's heading level
    heading_rms = max(float(np.sqrt(np.mean(residual[2] ** 2))), floor[2])  # rad
    starts = [np.clip(np.append(start, [math.log(std), math.log(tau)]), w_lower, w_upper)
              for tau in step * np.array(START_TIMES)
              for std in (first_std, 3.0 * first_std, heading_rms)]
    search = _Search(chunks, n_levels)
    values = [search(u0) for u0 in starts]
    first = int(np.argmin(values))
    # the projected Newton search with the average information (reml_search), L-BFGS-B on
    # from where it stopped when it does not converge
    best_u, best, converged = newton_search(
        search, search.information, starts[first], values[first],
        np.ones(w_lower.size, dtype=bool), w_lower, w_upper, gradient=search.gradient)
    if not converged:
        best_u, best = fitted(best_u, w_lower, w_upper, wander=True)
    statistic = null - best
    if statistic <= chi_bar_square_quantile(1.0 - test_level, 1):
        return None
    return HeadingWander(float(np.exp(best_u[-2])), float(np.exp(best_u[-1])), statistic,
                         NoiseLevels.from_vector(np.exp(best_u[:n_levels])),
                         at_bound=bool(best_u[-1] >= w_upper[-1] - 1e-6))


class _Search:
    """The deviance with the wander as :func:`excite.calibration.reml_search.newton_search`
    asks for it, by u = log of (levels..., std, time): its value (:meth:`__call__`), and its
    gradient and average information in v = exp(2 u), the two from one evaluation per
    point."""

    def __init__(self, chunks: list[_Chunk], n_levels: int):
        self.chunks, self.n_levels = chunks, n_levels
        self.key: bytes | None = None
        self.full: tuple[FloatArray, FloatArray] | None = None

    def __call__(self, u: FloatArray) -> float:
        try:
            return _deviance(self.chunks, u, self.n_levels, True, with_gradient=False)[0]
        except np.linalg.LinAlgError:  # not positive definite at the bounds
            return UNDEFINED

    def _evaluated(self, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The gradient in u and the average information in v at u (LinAlgError where the
        covariance is not positive definite)."""
        if self.key != u.tobytes() or self.full is None:
            _, gradient, information = _deviance(self.chunks, u, self.n_levels, True,
                                                 with_information=True)
            assert gradient is not None and information is not None
            self.key, self.full = u.tobytes(), (gradient, information)
        return self.full

    def information(self, u: FloatArray) -> FloatArray:
        return self._evaluated(u)[1]

    def gradient(self, u: FloatArray) -> FloatArray:
        """dD / dv = (dD / du) / (2 v)."""
        return self._evaluated(u)[0] / (2.0 * np.exp(2.0 * u))


def wander_covariance(segments: Segments, whitener: ChainWhitener, jac: FloatArray,
                      covariance: FloatArray, wander: HeadingWander) -> FloatArray:
    """The covariance (P, P) of the parameters fitted with the chain's whitener (covariance B;
    ``covariance`` = I^-1 = (J^T B^-1 J)^-1, relative units) when the increments' covariance
    is C = B' + A Sigma A^T: B' the chain's at ``wander.levels`` and Sigma the wandering
    heading error's. jac (3, P, N): the unwhitened relative Jacobian rows of the fit."""
    samples = _Samples.of(segments)
    j = jac.transpose(2, 0, 1).reshape(3 * len(segments), -1)
    g = whitener.solve(j)  # B^-1 J
    band = chain_band(segments, wander.levels, whitener.wheels)
    h = samples.transpose_design(segments, g)  # A^T B^-1 J
    middle = g.T @ band_product(band, g) + wander.std**2 * (
        h.T @ samples.apply_correlation(wander.correlation_time, h))
    out = covariance @ middle @ covariance
    return 0.5 * (out + out.T)
