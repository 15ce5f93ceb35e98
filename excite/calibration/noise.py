"""Correlated measurement noise of segments cut from a log: each pose sample's noise enters
the two segments that share it.

Model (docs/formats.md, "Time-series logs"; frames: the sensor's world poses and its increments in
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

Wheel-space noise (:class:`WheelNoise`, for segments cut from a log: sub-steps of one encoder
period). Noise that enters through the wheels reaches the measured increment through the
segment model's wheel Jacobian G_kj = d(increment k)/d(sub-increment j)
(:meth:`excite.core.models.SegmentModel.wheel_jacobian`):

* wheel slip: each wheel's ground contact drifts from its encoder by a random walk of
  intensity ``slip`` (rad / sqrt(s)), independent between wheels; segment k gets
  slip^2 sum_j dt_j G_kj G_kj^T (3 x 3, full: slip moves x, y and theta together), no
  correlation between segments. Its level is estimated by REML with the others.
* encoder quantization: each angle sample errs by its rounding, variance q = tick^2 / 12 per
  wheel, known from the resolution (not estimated). A boundary sample is shared by the two
  segments it separates: q (G_start G_start^T + G_end G_end^T) on the diagonal block and
  -q G_start,k G_end,k-1^T between chained segments (inside the band, like the pose samples);
  the samples inside a segment enter through the change of G between sub-steps, bounded for
  correlated rounding (see :class:`WheelNoise`).
* encoder timing: each encoder sample is read ``timing`` (s, std) off its stamp, both wheels
  at once, and errs by the wheels' rate times that error (the sub-step before it when read
  early, the one after when late); shared by chained segments like its rounding, the samples
  inside a segment independent (see :class:`WheelNoise`). Its level is estimated by REML and
  tested last (below), at most TIMING_PERIOD_FRACTION of the encoder period.

With wheel-space noise the REML levels are seven (white x, y, theta; pose xy, theta; slip;
timing) and the tests nest, the timing level held at 0: first "no segment noise" against
white segment noise (three components, as above: the pose-only logs keep the behaviour of
the white model), then, if rejected, "slip alone" against slip plus white (three
components): slip through the wheels is kept unless the white levels are needed too; last,
"no timing error" against the chosen levels with a free timing level (one component). The
segment levels are not tested again once a timing level is kept. Every search also starts
the segment levels at fractions of the residuals' RMS, because a level at its floor has no
slope in the deviance and would stay there.

A pose source whose heading error wanders over seconds (correlated between samples, not
independent) is modelled on top of this chain by :mod:`excite.calibration.wander`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from excite.core.models import SegmentModel
from excite.logs.segments import Segments

__all__ = ["NoiseLevels", "WheelNoise", "ChainWhitener", "chain_band", "level_bounds",
           "moment_noise", "reml_noise", "chi2_quantile", "chi2_survival",
           "chi_bar_square_quantile", "quantization_variance", "SEGMENT_NOISE_TEST_LEVEL",
           "MEDIAN_ABS_NORMAL"]

FloatArray = NDArray[np.float64]
_BAND = 5  # lower bandwidth of C in segment-major order (x, y, theta per segment)
#: Level of the test of "no segment noise" (:func:`reml_noise`): the segment levels are held
#: at their floor unless the data reject that hypothesis at this level.
SEGMENT_NOISE_TEST_LEVEL = 0.05
#: Further starts of the REML search (:func:`reml_noise`): the segment levels at these
#: fractions of the residuals' RMS (a level started far below where it matters stays there).
START_FRACTIONS = (0.3, 0.03, 0.003)


#: The encoder timing level is at most this fraction of the encoder period (s): an error of a
#: few std then stays within half a period, so the samples stay in their stamps' order (a
#: larger level would take up misfit instead, e.g. slip that grows with acceleration).
TIMING_PERIOD_FRACTION = 0.25

#: The median of |N(0, 1)|: a robust std is the median absolute value / this (MAD).
MEDIAN_ABS_NORMAL = 0.6744897501960817


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


def quantization_variance(tick: float) -> float:
    """Variance (rad^2) of the rounding error of one encoder sample whose angle is a whole
    number of ticks of ``tick`` rad: uniform over one tick, tick^2 / 12."""
    return tick * tick / 12.0


@dataclass(frozen=True)
class NoiseLevels:
    """sigma: white segment noise std (x [m], y [m], theta [rad]); pose: pose-sample noise
    std (xy [m], theta [rad]); slip: wheel slip intensity (rad / sqrt(s): each wheel's ground
    contact drifts from its encoder by a random walk, variance slip^2 per second of motion);
    timing: std of each encoder sample's time against the pose stream (s: the sample was read
    earlier or later than its stamp says, both wheels at once). slip and timing are used with
    a :class:`WheelNoise`."""

    sigma: FloatArray
    pose: FloatArray
    slip: float = 0.0
    timing: float = 0.0

    def vector(self, with_wheels: bool) -> FloatArray:
        """The levels as one vector: sigma (3), pose (2) and, ``with_wheels``, slip and
        timing."""
        values = np.concatenate([self.sigma, self.pose])
        return np.append(values, [self.slip, self.timing]) if with_wheels else values

    @classmethod
    def from_vector(cls, values: FloatArray) -> NoiseLevels:
        """The inverse of :meth:`vector` (5 or 7 values; slip and timing 0 with 5)."""
        if values.size not in (5, 7):
            raise ValueError(f"noise levels are 5 or 7 values, got {values.size}")
        if values.size == 7:
            return cls(values[:3], values[3:5], float(values[5]), float(values[6]))
        return cls(values[:3], values[3:5])

    def close_to(self, other: NoiseLevels, rtol: float, slip_scale: float = 0.0,
                 timing_scale: float = 0.0) -> bool:
        """Whether every level is within ``rtol`` of ``other``'s, or within 1e-3 of the
        largest level (levels near 0 need not settle relatively); the slip and timing levels
        count in the increments' units, times ``slip_scale`` and ``timing_scale`` (the std
        of an increment per unit of each, :attr:`WheelNoise.scale` and
        :attr:`WheelNoise.timing_scale`)."""
        a = np.concatenate([self.sigma, self.pose,
                            [self.slip * slip_scale, self.timing * timing_scale]])
        b = np.concatenate([other.sigma, other.pose,
                            [other.slip * slip_scale, other.timing * timing_scale]])
        return bool(np.all(np.abs(a - b) <= rtol * np.maximum(np.abs(b), 1e-300)
                           + 1e-3 * np.max(np.abs(b))))


@dataclass(frozen=True)
class WheelNoise:
    """How noise that enters through the wheels reaches each of N segments' measured
    increments (in the sensor's frame at the segment's start), linearised by the segment
    model's wheel Jacobian G_kj = d(increment k)/d(sub-increment j) (3, 2) at some parameters.

    slip (N, 3, 3): sum_j w_j G_kj G_kj^T, w_j the duration of sub-step j (s; 0 for a sub-step
        in which neither wheel turns): the covariance of the increment per unit slip^2 when each
        wheel slips by a random walk in time, independent between wheels and segments
        (m^2 / (rad^2 / s) ... rad^2 / (rad^2 / s)).
    start, end (N, 3, 2): the derivatives by the wheel angles at the segment's first and last
        encoder sample (the first sub-step's G, and the last one's; m/rad, rad/rad).
    inner (N, 3, 3): (K - 1) sum_j sum_w D_jw D_jw^T over the K - 1 samples inside the
        segment, D_j = G_j - G_(j+1) (a sample between sub-steps j and j + 1 moves the first
        by +e and the next by -e; m^2/rad^2 ... ). Consecutive rounding errors of a smoothly
        turning wheel are far from independent (a slow sawtooth at a steady rate), so this is
        the bound of fully correlated errors, not the independent sum (which is ~1/K of the
        boundaries' and left the increments' covariance nearly singular where the inner
        samples matter: 2 wheel angles per boundary, 3 channels per segment).
    quantization: variance of each encoder sample's rounding error (rad^2, 0: not modelled).
        An angle sample at a segment boundary errs by e: the segment ending there by
        G_end e, the one starting there by -G_start e, so chained segments share it (like a
        pose sample). Sub-steps are taken to end at encoder samples (they are one encoder
        period long, :func:`excite.logs.timeseries.segment_timeseries`; encoders slower than 50 Hz
        get several per period, and the inner samples' bound then counts each sub-step end as
        a sample: conservative).
    rate_start, rate_end (N, 2, 3): how the increment errs per second that its first and
        last encoder sample's time errs (m/s, m/s, rad/s). A sample read dt later than its
        stamp errs by w dt in both wheels at once, w the wheels' rates (rad/s) of the
        sub-step after it (before it when dt < 0: the segment model's wheels turn at a
        constant rate per sub-step), so its error's covariance is dt^2 (w_b w_b^T +
        w_a w_a^T) / 2: the two rows are G w_b / sqrt(2) and G w_a / sqrt(2), G the
        sample's wheel Jacobian (G_start, G_end). Chained segments share the sample as they
        share its rounding; a chain's first and last sample use their own sub-step's rate.
    rate_inner (N, 3, 3): sum_j D_j (w_j w_j^T + w_(j+1) w_(j+1)^T) D_j^T / 2 over the
        samples inside the segment (between sub-steps j and j + 1): their timing errors are
        independent, unlike their rounding.
    period: the median sub-step duration (s): the encoder period where the sub-steps are one
        period long (:func:`excite.logs.timeseries.segment_timeseries`: encoders of 50 Hz and more,
        windows of up to 256 periods; else the sub-steps' own length, and the timing level is
        an effective one of their ends). The timing level is at most :attr:`timing_bound`.
    """

    slip: FloatArray
    start: FloatArray
    end: FloatArray
    inner: FloatArray
    quantization: float
    rate_start: FloatArray
    rate_end: FloatArray
    rate_inner: FloatArray
    period: float

    @classmethod
    def of(cls, model: SegmentModel, segments: Segments, theta: FloatArray,
           tick: float | None) -> WheelNoise:
        """At parameters ``theta`` (P,) for segments cut from a log (with sub-steps and times);
        ``tick``: the encoder resolution (rad), None when the angles are not quantised."""
        if segments.sub_dphi_L is None or segments.t_start is None or segments.t_end is None:
            raise ValueError("wheel-space noise needs segments cut from a log (sub-steps, times)")
        sub_L, sub_R = segments.sub_dphi_L, segments.sub_dphi_R
        jac = model.wheel_jacobian(sub_L, sub_R, theta, substeps=True)  # (N, K, 3, 2)
        moving = (sub_L != 0.0) | (sub_R != 0.0)
        k = np.arange(moving.shape[1])
        count = segments.substep_counts  # the segment's own sub-steps, equal parts of it
        duration = (segments.t_end - segments.t_start) / count  # s per sub-step
        weight = np.where(moving, duration[:, None], 0.0)
        slip = np.einsum("nk,nkaw,nkbw->nab", weight, jac, jac)
        step = (jac[:, :-1] - jac[:, 1:]) * (k[1:] < count[:, None])[:, :, None, None]
        # the bound of fully correlated rounding errors (see the class doc):
        # (sum_j D_j e_j)(sum_j D_j e_j)^T <= (K - 1) sum_j e_j^2 D_j D_j^T
        inner = np.maximum(count - 1, 1)[:, None, None] * np.einsum("nkaw,nkbw->nab", step,
                                                                     step)
        rows = np.arange(len(segments))
        end = jac[rows, count - 1]
        per_second = np.divide(1.0, duration, out=np.zeros_like(duration),
                               where=duration > 0)
        rate = np.stack([sub_L, sub_R], axis=-1) * per_second[:, None, None]  # (N, K, 2)
        # a sample read early errs at the rate of the sub-step before it, late at the one
        # after: halves of variance 1/2 each (a chain's first and last sample: its own rate)
        first, last = rate[:, 0], rate[rows, count - 1]  # (N, 2)
        before, after = first.copy(), last.copy()
        shared = np.flatnonzero(_chained(segments))
        before[shared], after[shared - 1] = last[shared - 1], first[shared]
        at_start = math.sqrt(0.5) * np.stack([before, first], axis=1)  # (N, 2 halves, 2)
        at_end = math.sqrt(0.5) * np.stack([last, after], axis=1)
        early = np.einsum("nkaw,nkw->nka", step, rate[:, :-1])
        late = np.einsum("nkaw,nkw->nka", step, rate[:, 1:])
        return cls(slip, jac[:, 0], end, inner,
                   0.0 if tick is None else quantization_variance(tick),
                   np.einsum("naw,nhw->nha", jac[:, 0], at_start),
                   np.einsum("naw,nhw->nha", end, at_end),
                   0.5 * (np.einsum("nka,nkb->nab", early, early)
                          + np.einsum("nka,nkb->nab", late, late)),
                   float(np.median(duration)))

    def take(self, index: NDArray[np.int64]) -> WheelNoise:
        """The wheel-space noise of the segments at ``index`` (consecutive, in order)."""
        return WheelNoise(self.slip[index], self.start[index], self.end[index],
                          self.inner[index], self.quantization, self.rate_start[index],
                          self.rate_end[index], self.rate_inner[index], self.period)

    @property
    def scale(self) -> float:
        """The typical std of an increment per unit slip level: sqrt of the largest channel's
        mean slip covariance (m or rad per rad / sqrt(s))."""
        return _largest_channel_std(self.slip)

    @property
    def timing_bound(self) -> float:
        """The largest timing level (s): TIMING_PERIOD_FRACTION of the period, so that a
        time error of a few std keeps the samples in their stamps' order."""
        return TIMING_PERIOD_FRACTION * self.period

    def at_timing_bound(self, timing: float) -> bool:
        """Whether a timing level (s) sits at :attr:`timing_bound` (larger errors are not
        described: the std are then too narrow)."""
        return timing >= self.timing_bound * (1.0 - 1e-9)

    @property
    def timing_scale(self) -> float:
        """The typical std of an increment per unit timing level: sqrt of the largest
        channel's mean timing covariance (m/s or rad/s)."""
        return _largest_channel_std(self._own_timing)

    @cached_property
    def _own_samples(self) -> FloatArray:
        """G_start G_start^T + G_end G_end^T + inner (N, 3, 3): a segment's own encoder samples
        (fixed for the geometry; the REML search rebuilds whiteners at many levels)."""
        return (np.einsum("naw,nbw->nab", self.start, self.start)
                + np.einsum("naw,nbw->nab", self.end, self.end) + self.inner)

    @cached_property
    def _own_timing(self) -> FloatArray:
        """The covariance of a segment's increment (N, 3, 3) from its own encoder samples'
        timing errors, per unit timing variance (rate_start, rate_end, rate_inner)."""
        return (np.einsum("nha,nhb->nab", self.rate_start, self.rate_start)
                + np.einsum("nha,nhb->nab", self.rate_end, self.rate_end) + self.rate_inner)

    @cached_property
    def _boundaries(self) -> FloatArray:
        """G_start,k G_end,k-1^T (N - 1, 3, 3) of every pair of consecutive segments."""
        return np.einsum("maw,mbw->mab", self.start[1:], self.end[:-1])

    @cached_property
    def _timing_boundaries(self) -> FloatArray:
        """sum over the halves of rate_start,k rate_end,k-1^T (N - 1, 3, 3) of every pair of
        consecutive segments."""
        return np.einsum("mha,mhb->mab", self.rate_start[1:], self.rate_end[:-1])

    def diagonal_blocks(self, slip: float, timing: float) -> FloatArray:
        """Each segment's own covariance (N, 3, 3) from slip, quantization and timing."""
        blocks = slip * slip * self.slip
        if self.quantization:
            blocks = blocks + self.quantization * self._own_samples
        if timing:
            blocks = blocks + timing * timing * self._own_timing
        return blocks

    def shared_blocks(self, k: NDArray[np.int64], timing: float) -> FloatArray:
        """C[rows of segment k, columns of k - 1] (m, 3, 3) for chained segments k: the
        boundary sample's quantization and timing error, -q G_start,k G_end,k-1^T
        - timing^2 sum_h rate_start,k,h rate_end,k-1,h^T."""
        return (-self.quantization * self._boundaries[k - 1]
                - timing * timing * self._timing_boundaries[k - 1])


def _largest_channel_std(blocks: FloatArray) -> float:
    """sqrt of the largest channel's mean variance over covariance blocks (N, 3, 3)."""
    return float(np.sqrt(np.max(np.mean(np.diagonal(blocks, axis1=1, axis2=2), axis=0))))


def _perpendicular(segments: Segments) -> tuple[FloatArray, FloatArray]:
    """J d_k = (-dy_k, dx_k) (m)."""
    return -segments.dy, segments.dx


def _chained(segments: Segments) -> NDArray[np.bool_]:
    return (np.zeros(len(segments), dtype=bool) if segments.chained is None
            else segments.chained)


def _add_diagonal_blocks(band: FloatArray, blocks: FloatArray) -> None:
    """Add symmetric blocks (N, 3, 3) to the diagonal blocks of C in lower band storage."""
    for a in range(3):
        for b in range(a + 1):
            band[a - b, b::3] += blocks[:, a, b]


def _add_shared_blocks(band: FloatArray, k: NDArray[np.int64], blocks: FloatArray) -> None:
    """Add blocks C[rows of k, columns of k - 1] (m, 3, 3) in lower band storage: entry
    (a, b) is C[3k + a, 3(k-1) + b], at band offset 3 + a - b."""
    for a in range(3):
        for b in range(3):
            band[3 + a - b, 3 * (k - 1) + b] += blocks[:, a, b]


def chain_band(segments: Segments, levels: NoiseLevels,
               wheels: WheelNoise | None = None) -> FloatArray:
    """The covariance C of the stacked increments (see the module doc) in lower band storage
    (_BAND + 1, 3N): ``band[i - j, j] = C[i, j]`` for i >= j, rows and columns 3k + channel
    (x, y, theta of segment k); ``wheels`` adds the noise that enters through the wheels (slip
    at ``levels.slip``, encoder quantization, encoder timing at ``levels.timing``),
    :class:`WheelNoise`. C is linear in the
    variances (the squared levels)."""
    n = len(segments)
    sx2, sy2, st2 = levels.sigma**2
    pxy2, pth2 = levels.pose**2
    jx, jy = _perpendicular(segments)
    # each segment's own block: its channels' noise and its two pose samples
    own = np.zeros((n, 3, 3))
    own[:, 0, 0] = sx2 + 2 * pxy2 + pth2 * jx * jx
    own[:, 1, 1] = sy2 + 2 * pxy2 + pth2 * jy * jy
    own[:, 2, 2] = st2 + 2 * pth2
    own[:, 1, 0] = pth2 * jx * jy  # C[y, x]
    own[:, 2, 1] = pth2 * jy  # C[theta, y]
    own[:, 2, 0] = pth2 * jx  # C[theta, x]
    if wheels is not None:
        own = own + wheels.diagonal_blocks(levels.slip, levels.timing)
    band = np.zeros((_BAND + 1, 3 * n))
    _add_diagonal_blocks(band, own)
    chained = _chained(segments)
    if chained.any():
        k = np.flatnonzero(chained)  # block (k, k - 1): rows of segment k, cols of k - 1
        c, s = np.cos(segments.dtheta[k - 1]), np.sin(segments.dtheta[k - 1])
        # C[(k-1) rows, k cols] = [[-pxy2 R, 0], [-pth2 (J d_k)^T, -pth2]] (the pose
        # sample they share); its transpose C[k rows, (k-1) cols]:
        shared = np.zeros((k.size, 3, 3))
        shared[:, 0, 0], shared[:, 0, 1] = -pxy2 * c, -pxy2 * s
        shared[:, 1, 0], shared[:, 1, 1] = pxy2 * s, -pxy2 * c
        shared[:, 0, 2], shared[:, 1, 2], shared[:, 2, 2] = -pth2 * jx[k], -pth2 * jy[k], -pth2
        if wheels is not None and (wheels.quantization or levels.timing):
            shared = shared + wheels.shared_blocks(k, levels.timing)
        _add_shared_blocks(band, k, shared)
    return band


class ChainWhitener:
    """Whitening by the Cholesky factor of the covariance C of the stacked increments
    (:func:`chain_band`), for given noise levels; ``wheels`` adds the noise that enters
    through the wheels (slip at ``levels.slip``, encoder quantization, encoder timing at
    ``levels.timing``), :class:`WheelNoise`."""

    def __init__(self, segments: Segments, levels: NoiseLevels,
                 wheels: WheelNoise | None = None):
        from scipy.linalg import cholesky_banded

        self._factor = cholesky_banded(chain_band(segments, levels, wheels), lower=True)
        self.n = len(segments)
        self.wheels = wheels

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

    def solve(self, rows: FloatArray) -> FloatArray:
        """C^-1 ``rows`` for (3N, m) rows in the stacked order (3k + channel)."""
        from scipy.linalg import cho_solve_banded

        return cho_solve_banded((self._factor, True), rows, check_finite=False)


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
                         jac: FloatArray, wheels: WheelNoise | None = None) -> float:
    """-2 log restricted likelihood (up to a constant) of residuals (3, N) with Jacobian rows
    (3, P, N) of the linearised model: log det C + log det(J^T C^-1 J) + e^T C^-1 e, with e
    the generalised least-squares residual (the parameters profiled out)."""
    whitener = ChainWhitener(segments, levels, wheels)
    white, white_jac = whitener.whiten(residual, jac)
    w = white.T.reshape(-1)
    a = white_jac.transpose(2, 0, 1).reshape(w.size, -1)
    factor = np.linalg.cholesky(a.T @ a)  # J^T C^-1 J = G G^T
    projected = np.linalg.solve(factor, a.T @ w)  # |G^-1 J^T C^-1 r|^2: the fitted part
    return (whitener.log_det + 2.0 * float(np.sum(np.log(np.diag(factor))))
            + float(w @ w - projected @ projected))


def level_bounds(residual: FloatArray, floor: FloatArray, wheels: WheelNoise | None = None
                 ) -> tuple[FloatArray, FloatArray]:
    """The bounds of the logs of the noise levels a REML search moves in: each level at
    least its floor (``floor`` (3,) = (position, position, heading) floors the segment
    levels, (position, heading) the pose levels; the slip and timing floors are the heading
    floor over their scales, :attr:`WheelNoise.scale` and :attr:`WheelNoise.timing_scale`)
    and at most 10 times the largest residual (3, N) (over their scales for slip and
    timing; the timing level also at most :attr:`WheelNoise.timing_bound`).
    Five levels, seven with ``wheels``."""
    spread = float(np.max(np.abs(residual))) if residual.size else 1.0
    lower = np.log(np.concatenate([floor, floor[[0, 2]]]))
    upper = np.full(5, np.log(max(10.0 * spread, 1e-300)))
    if wheels is not None:
        units = np.maximum([wheels.scale, wheels.timing_scale], 1e-300)
        lower = np.append(lower, np.log(floor[2] / units))
        upper = np.append(upper, np.log(np.maximum(10.0 * spread / units, 1e-300)))
        upper[6] = min(upper[6], math.log(max(wheels.timing_bound, 1e-300)))
        lower[6] = min(lower[6], upper[6])
    return lower, upper


def reml_noise(segments: Segments, residual: FloatArray, jac: FloatArray,
               start: NoiseLevels, floor: FloatArray,
               test_level: float = SEGMENT_NOISE_TEST_LEVEL,
               wheels: WheelNoise | None = None) -> NoiseLevels:
    """The noise levels maximising the restricted likelihood of the residuals (3, N)
    (predicted - measured) of a fit whose Jacobian rows (3, P, N) span the fitted directions
    (only the directions the data determine): the five of the module doc and, with
    ``wheels``, the slip and encoder timing levels (its quantization is known, not
    estimated). Optimised over the logs of the levels from ``start`` (L-BFGS-B); each level
    at least its floor: ``floor`` (3,) is (position, position, heading) and floors the
    segment levels and (position, heading) the pose levels; the slip and timing floors are
    the heading floor over their scales.

    Then the hypothesis "no segment noise" is tested (see the module doc): the restricted
    deviance with the segment levels (and slip) at their floor (the pose levels
    re-optimised) minus that of white segment noise (slip at its floor), against the
    (1 - ``test_level``)-quantile of the chi-bar-square distribution of three boundary
    components; if the data do not reject it, those levels are returned. With ``wheels``, if
    it is rejected, "slip alone, no white segment noise" is tested against the full optimum
    the same way (three components), and slip alone is kept unless rejected. All of this
    holds the timing level at 0; last, "no timing error" is tested against the
    chosen levels with a free timing level (one boundary component), and the timing level
    kept only if rejected (else it is 0).
    """
    from scipy.optimize import minimize

    lower, upper = level_bounds(residual, floor, wheels)
    first = start.vector(with_wheels=wheels is not None)
    segment = [0, 1, 2]  # the levels of segment noise (tested together)
    if wheels is not None:
        units = np.maximum([wheels.scale, wheels.timing_scale], 1e-300)
        segment.append(5)
    u0 = np.minimum(np.maximum(np.log(np.maximum(first, 1e-300)), lower), upper)
    # where a level is held: the segment levels and slip at their floor, the timing level at
    # 0 (not its floor: where every level sits at its floor, as in noise-free simulated logs,
    # one more floor-sized term would change the fit)
    held_at = lower.copy()
    held_at[6:] = -np.inf

    def levels_of(u: FloatArray) -> NoiseLevels:
        return NoiseLevels.from_vector(np.exp(u))

    def deviance(u: FloatArray) -> float:
        try:
            return _restricted_deviance(segments, levels_of(u), residual, jac, wheels)
        except np.linalg.LinAlgError:  # C numerically not positive definite at the bounds
            return 1e300  # finite: the optimiser's difference quotients stay numbers

    def optimum(start_u: FloatArray, fixed: NDArray[np.bool_],
                start_value: float | None = None) -> tuple[FloatArray, float]:
        """The minimum of the deviance over the levels not ``fixed`` at their floor
        (``start_value``: the deviance at the start, when known)."""
        u = np.where(fixed, held_at, start_u)
        free = np.flatnonzero(~fixed)
        if start_value is None:
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

    # A level far below where it matters has no slope in the deviance: each search also
    # starts the free segment levels at fractions of the residuals' size (the best start is
    # kept), so that a level held at its floor in one model can rise in the next.
    rms = np.sqrt(np.mean(residual**2, axis=1)) if residual.size else np.ones(3)

    def search(start_u: FloatArray, fixed: NDArray[np.bool_]) -> tuple[FloatArray, float]:
        candidates = [np.minimum(np.maximum(start_u, lower), upper)]
        for fraction in START_FRACTIONS:
            u = start_u.copy()
            u[:3] = np.maximum(np.log(np.maximum(fraction * rms, 1e-300)), start_u[:3])
            if wheels is not None:
                u[5:] = np.maximum(np.log(max(fraction * float(np.max(rms)), 1e-300) / units),
                                   start_u[5:])
            candidates.append(np.minimum(np.maximum(u, lower), upper))
        values = [deviance(np.where(fixed, held_at, u)) for u in candidates]
        best = int(np.argmin(values))
        return optimum(candidates[best], fixed, values[best])

    timing = np.zeros(u0.size, dtype=bool)  # the timing level (tested last)
    timing[6:] = True
    u, fixed, value = _segment_noise(search, optimum, u0, timing, lower, segment,
                                     chi_bar_square_quantile(1.0 - test_level, 3))
    if wheels is None:
        return levels_of(u)
    u_timing, with_timing = search(u, fixed & ~timing)
    kept = value - with_timing > chi_bar_square_quantile(1.0 - test_level, 1)
    return levels_of(u_timing if kept else u)


Search = Callable[[FloatArray, NDArray[np.bool_]], tuple[FloatArray, float]]


def _segment_noise(search: Search, optimum: Search, u0: FloatArray, held: NDArray[np.bool_],
                   lower: FloatArray, segment: list[int], quantile: float
                   ) -> tuple[FloatArray, NDArray[np.bool_], float]:
    """:func:`reml_noise`'s tests of segment noise (its doc) with the levels ``held`` held
    throughout (where ``search`` and ``optimum`` hold levels: the timing level at 0): the
    chosen log-levels, the levels its model holds and its deviance."""
    u_hat, best = search(u0, held)
    if not np.any(u_hat[segment] > lower[segment]):
        return u_hat, held, best
    white = held.copy()
    white[:3] = True
    no_slip = held.copy()
    no_slip[segment[3:]] = True
    with_wheels = len(segment) > 3
    # 1. Is there segment noise at all? "None" against white segment noise (slip held at its
    # floor): three boundary components.
    _, best_white = search(u_hat, no_slip) if with_wheels else (u_hat, best)
    u_null, null = optimum(u_hat, white | no_slip)
    if null - best_white < quantile:
        return u_null, white | no_slip, null
    if not with_wheels:
        return u_hat, held, best
    # 2. There is: does slip through the wheels explain it, without white segment noise?
    u_slip, only_slip = search(u_hat, white)
    if only_slip - best < quantile:
        return u_slip, white, only_slip
    return u_hat, held, best
