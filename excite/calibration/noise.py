"""The noise model of segments cut from a log: each pose sample's noise enters the two
segments that share it, and noise that enters through the wheels follows the segment model.

Model (docs/formats.md, "Time-series logs"; frames: the sensor's world poses and its increments in
its own frame at each segment start). A segment's measured increment is
z_k = (-P_k) (+) P_{k+1} of two pose samples P = (p, theta), plus noise of its own:

* pose-sample noise, independent per sample: isotropic std ``sigma_xy`` (m) on p and
  ``sigma_theta`` (rad) on theta;
* segment noise, independent per segment (wheel slip, encoder quantisation, model error):
  std ``sigma`` = (x [m], y [m], theta [rad]).

Linearised at increments d_k = (dx_k, dy_k) (J = rotation by +90 degrees, R(a) = rotation
by a, Delta_k = dtheta_k; the calibration gives the model's predicted ones, see
:func:`excite.calibration.noise_rounds.predicted`), the covariance of the stacked increments is
block tridiagonal over chains of segments that share their end and start samples:

    C_kk      = diag(sigma^2) + [[2 sxy^2 I + sth^2 (J d_k)(J d_k)^T,  sth^2 J d_k],
                                 [sth^2 (J d_k)^T,                    2 sth^2   ]]
    C_(k-1)k  = [[-sxy^2 R(Delta_(k-1)),  0     ],
                 [-sth^2 (J d_k)^T,       -sth^2]]          (only when k is chained to k-1)

:class:`ChainWhitener` factors C (banded Cholesky, bandwidth 5, O(N)) and whitens residuals
and Jacobians, so that the weighted least-squares fit is the (linearised) maximum-likelihood
fit under this model.

Wheel-space noise (:class:`WheelNoise`, for segments cut from a log: sub-steps of one encoder
period). Noise that enters through the wheels reaches the measured increment through the
segment model's wheel Jacobian G_kj = d(increment k)/d(sub-increment j)
(:meth:`excite.core.models.SegmentModel.wheel_jacobian`):

* wheel slip: each wheel's ground contact drifts from its encoder by a random walk of
  intensity ``slip`` (rad / sqrt(s)), independent between wheels; segment k gets
  slip^2 sum_j dt_j G_kj G_kj^T (3 x 3, full: slip moves x, y and theta together), no
  correlation between segments.
* encoder quantization: each angle sample errs by its rounding, variance q = tick^2 / 12 per
  wheel, known from the resolution (not estimated). A boundary sample is shared by the two
  segments it separates: q (G_start G_start^T + G_end G_end^T) on the diagonal block and
  -q G_start,k G_end,k-1^T between chained segments (inside the band, like the pose samples);
  the samples inside a segment enter through the change of G between sub-steps, bounded for
  correlated rounding (see :class:`WheelNoise`).
* encoder timing: each encoder sample is read ``timing`` (s, std) off its stamp, both wheels
  at once, and errs by the wheels' rate times that error (the sub-step before it when read
  early, the one after when late); shared by chained segments like its rounding, the samples
  inside a segment independent (see :class:`WheelNoise`). Its level is at most
  TIMING_PERIOD_FRACTION of the encoder period.

The levels (:class:`NoiseLevels`) are estimated from a fit's residuals by
:mod:`excite.calibration.reml`. A pose source whose heading error wanders over seconds
(correlated between samples, not independent) is modelled on top of this chain by
:mod:`excite.calibration.wander`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from excite.core.models import SegmentModel
from excite.logs.segments import Segments

__all__ = ["NoiseLevels", "WheelNoise", "ChainWhitener", "LevelBands", "chain_band",
           "chained_mask", "cut_from_log", "perpendicular", "quantization_variance", "stacked",
           "TIMING_PERIOD_FRACTION"]

FloatArray = NDArray[np.float64]
_BAND = 5  # lower bandwidth of C in segment-major order (x, y, theta per segment)

#: The encoder timing level is at most this fraction of the encoder period (s): an error of a
#: few std then stays within half a period, so the samples stay in their stamps' order (a
#: larger level would take up misfit instead, e.g. slip that grows with acceleration).
TIMING_PERIOD_FRACTION = 0.25


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
        the bound of fully correlated errors, not the independent sum (about 1/K of the
        boundaries', which leaves the increments' covariance nearly singular where the inner
        samples matter: 2 wheel angles per boundary, 3 channels per segment).
    quantization: variance of each encoder sample's rounding error (rad^2, 0: not modelled).
        An angle sample at a segment boundary errs by e: the segment ending there by
        G_end e, the one starting there by -G_start e, so chained segments share it (like a
        pose sample). Sub-steps are taken to end at encoder samples (they are one encoder
        period long, :func:`excite.logs.segmentation.segment_timeseries`; encoders slower
        than 50 Hz get several per period, and the inner samples' bound then counts each
        sub-step end as a sample: conservative).
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
        period long (:func:`excite.logs.segmentation.segment_timeseries`: encoders of 50 Hz
        and more, windows of up to 256 periods; else the sub-steps' own length, and the
        timing level is an effective one of their ends). The timing level is at most
        :attr:`timing_bound`.
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
        shared = np.flatnonzero(chained_mask(segments))
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


def perpendicular(segments: Segments) -> tuple[FloatArray, FloatArray]:
    """J d_k = (-dy_k, dx_k) (m)."""
    return -segments.dy, segments.dx


def chained_mask(segments: Segments) -> NDArray[np.bool_]:
    """Per segment, whether it shares its start sample with the previous segment's end."""
    return (np.zeros(len(segments), dtype=bool) if segments.chained is None
            else segments.chained)


def cut_from_log(segments: Segments) -> bool:
    """Whether segments were cut from a log (sub-steps and times): their noise enters through
    the wheels too (:class:`WheelNoise`, the slip level)."""
    return segments.sub_dphi_L is not None and segments.t_start is not None


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
    jx, jy = perpendicular(segments)
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
    chained = chained_mask(segments)
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


class LevelBands:
    """The covariance band of the stacked increments (:func:`chain_band`) as a linear function
    of the squared levels: C = C_0 + sum_i level_i^2 U_i, C_0 the part of no level (the
    encoder quantization), U_i each level's band at 1. Built once for a data set, evaluated
    at many levels (the searches of the noise levels).

    Attributes
    ----------
    zero : ndarray, shape (_BAND + 1, 3N)
        C_0 in lower band storage.
    units : list of ndarray, each (_BAND + 1, 3N)
        U_i, for the levels in the order of :meth:`NoiseLevels.vector` (5, or 7 with wheels).
    """

    def __init__(self, segments: Segments, wheels: WheelNoise | None, size: int):
        zero = np.zeros(size)
        self.zero = chain_band(segments, NoiseLevels.from_vector(zero), wheels)
        self.units = []
        for i in range(size):
            one = zero.copy()
            one[i] = 1.0
            self.units.append(chain_band(segments, NoiseLevels.from_vector(one), wheels)
                              - self.zero)

    @classmethod
    def side_by_side(cls, parts: list[LevelBands]) -> LevelBands:
        """The bands of parts that share no noise (chunks of a log, apart) as one, block
        diagonal: :func:`chain_band` leaves the band's last columns beyond each part zero."""
        joined = cls.__new__(cls)
        joined.zero = np.concatenate([part.zero for part in parts], axis=1)
        joined.units = [np.concatenate(units, axis=1)
                        for units in zip(*(part.units for part in parts), strict=True)]
        return joined

    def at(self, levels: FloatArray) -> FloatArray:
        """The band at ``levels`` (5 or 7, the order of :meth:`NoiseLevels.vector`)."""
        band = self.zero.copy()
        for value, unit in zip(levels, self.units, strict=True):
            if value:
                band += value * value * unit
        return band


def stacked(raw: FloatArray, jac: FloatArray | None = None) -> FloatArray:
    """Residuals (3, N) and Jacobian rows (3, P, N) in the stacked order (3k + channel), as
    the columns of one (3N, 1 [+ P]) array."""
    n = raw.shape[1]
    columns = [raw.T.reshape(3 * n, 1)]
    if jac is not None:
        columns.append(jac.transpose(2, 0, 1).reshape(3 * n, jac.shape[1]))
    return np.concatenate(columns, axis=1)


class ChainWhitener:
    """Whitening by the Cholesky factor of the covariance C of the stacked increments
    (:func:`chain_band`), for given noise levels; ``wheels`` adds the noise that enters
    through the wheels (slip at ``levels.slip``, encoder quantization, encoder timing at
    ``levels.timing``), :class:`WheelNoise`. LinAlgError when C is not positive definite.

    Attributes
    ----------
    levels : NoiseLevels or None
        The levels C was built at; None when built from a band.
    geometry : Segments or None
        The segments C was linearised at (:func:`chain_band`: their increments give the
        heading's lever arms and the turns between chained segments); None when built from a
        band.
    position_mean : float
        E[cos e] = exp(-sigma_theta^2 / 2) of the pose heading noise e: a segment's measured
        position increment is the true one turned by its start sample's heading error, so its
        mean is this fraction of the true one (1 without pose heading noise);
        :class:`excite.calibration.solver.Problem` divides the measured positions by it.
    """

    def __init__(self, segments: Segments, levels: NoiseLevels,
                 wheels: WheelNoise | None = None):
        self._factor = _rounded_cholesky(chain_band(segments, levels, wheels))
        self.n = len(segments)
        self.wheels = wheels
        self.levels: NoiseLevels | None = levels
        self.geometry: Segments | None = segments
        self.position_mean = math.exp(-0.5 * float(levels.pose[1]) ** 2)

    @classmethod
    def from_band(cls, band: FloatArray, wheels: WheelNoise | None = None) -> ChainWhitener:
        """The whitener of a covariance band already built (:func:`chain_band`,
        :meth:`LevelBands.at`); ``wheels``: the wheel noise it includes, if any."""
        whitener = cls.__new__(cls)
        whitener._factor = _banded_cholesky(band)
        whitener.n = band.shape[1] // 3
        whitener.wheels = wheels
        whitener.levels, whitener.geometry, whitener.position_mean = None, None, 1.0
        return whitener

    @property
    def log_det(self) -> float:
        """log det C (C in the units of the increments: m^2, rad^2)."""
        return 2.0 * float(np.sum(np.log(self._factor[0])))

    def whiten(self, raw: FloatArray, jac: FloatArray | None
               ) -> tuple[FloatArray, FloatArray | None]:
        """L^-1 of residuals (3, N) and Jacobian rows (3, P, N), in the same layouts: the
        innovations of segment k are column k."""
        n = self.n
        out = self.whiten_stacked(stacked(raw, jac))
        white = out[:, 0].reshape(n, 3).T
        if jac is None:
            return white, None
        return white, out[:, 1:].reshape(n, 3, -1).transpose(1, 2, 0)

    def whiten_stacked(self, rows: FloatArray) -> FloatArray:
        """L^-1 ``rows`` for (3N, m) rows in the stacked order (:func:`stacked`)."""
        from scipy.linalg.lapack import dtbtrs

        out, info = dtbtrs(self._factor, rows, uplo="L")
        if info != 0:
            raise np.linalg.LinAlgError("the covariance's factor is singular")
        return out

    def solve(self, rows: FloatArray) -> FloatArray:
        """C^-1 ``rows`` for (3N, m) rows in the stacked order (3k + channel)."""
        from scipy.linalg import cho_solve_banded

        return cho_solve_banded((self._factor, True), rows, check_finite=False)


#: The relative raises of a covariance band's diagonal tried, in turn, when its factorization
#: fails by rounding (:func:`_rounded_cholesky`).
ROUNDING_JITTER = (1e-14, 1e-12, 1e-10)


def _rounded_cholesky(band: FloatArray) -> FloatArray:
    """:func:`_banded_cholesky` of a covariance built from noise levels (:func:`chain_band`),
    which is positive semi-definite by construction (a sum of squared levels times positive
    semi-definite units): where its factorization fails, it fails by rounding (a level at its
    floor beside a level many decades larger, e.g. pose positions far more precise than the
    heading's lever arm, or a variance of exactly zero), and the diagonal raised by
    ROUNDING_JITTER, relative to each entry and to the largest, in turn factorizes it.
    LinAlgError when none does."""
    try:
        return _banded_cholesky(band)
    except np.linalg.LinAlgError:
        for jitter in ROUNDING_JITTER:
            raised = band.copy()
            raised[0] += jitter * (np.abs(band[0]) + float(np.max(np.abs(band[0]))))
            try:
                return _banded_cholesky(raised)
            except np.linalg.LinAlgError:
                continue
        raise


def _banded_cholesky(band: FloatArray) -> FloatArray:
    """The lower Cholesky factor of a symmetric band (lower storage), by LAPACK's dpbtrf;
    LinAlgError when not positive definite."""
    from scipy.linalg.lapack import dpbtrf

    lower, info = dpbtrf(band, lower=1)
    if info != 0:
        raise np.linalg.LinAlgError("the covariance is not positive definite")
    return lower
