"""The clocks of a log's two streams: pose time + time_offset = encoder time (s).

:func:`estimate_time_offset` finds the offset from the data (the lag at which the wheel rates
explain the heading rate best); :func:`noticeable_time_offset` tells, when no offset was given,
whether the data clearly suggest one (a note for the user, :class:`OffsetHint`). Segmentation
takes the offset as given (:func:`excite.logs.segmentation.segment_timeseries`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from excite.errors import DataError
from excite.logs.timeseries import TimeSeries

__all__ = ["MAX_TIME_OFFSET", "OffsetFit", "OffsetHint", "OffsetOutOfRange",
           "estimate_time_offset", "explained", "noticeable_time_offset", "offset_fit",
           "refined_lag", "rejected_offset", "smoothed_change", "untested_offset"]

FloatArray = NDArray[np.float64]


def _rate_signals(ts: TimeSeries, step: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Heading rate of the poses and the two wheel rates (rad/s), on one grid of spacing
    ``step`` (s) over the time both streams cover, each stream on its own clock."""
    start, stop = max(ts.t_enc[0], ts.t_pose[0]), min(ts.t_enc[-1], ts.t_pose[-1])
    grid = start + step * np.arange(int((stop - start) / step) + 1)
    rates = [np.gradient(np.interp(grid, t, angle), step)
             for t, angle in ((ts.t_pose, ts.theta), (ts.t_enc, ts.phi_L), (ts.t_enc, ts.phi_R))]
    return rates[0], rates[1], rates[2]


def _sliding_dot(a: FloatArray, b: FloatArray) -> FloatArray:
    """s[j] = sum_k a[k] b[j + k] for every full placement j = 0..len(b) - len(a) (by FFT)."""
    length = 1 << int(math.ceil(math.log2(a.size + b.size)))
    full = np.fft.irfft(np.conj(np.fft.rfft(a, length)) * np.fft.rfft(b, length), length)
    return full[: b.size - a.size + 1]


def _sliding_sum(x: FloatArray, width: int) -> FloatArray:
    """Sums of x over every window of ``width`` consecutive samples."""
    total = np.concatenate(([0.0], np.cumsum(x)))
    return total[width:] - total[:-width]


def explained(turn: FloatArray, left: FloatArray, right: FloatArray, max_lag: int) -> FloatArray:
    """For each lag m = -max_lag..max_lag, the fraction R^2 of the heading rate's variance
    (over the central samples max_lag..n - max_lag) that a linear fit
    a phi_L'(t + m) + c phi_R'(t + m) (plus a constant) explains."""
    width = turn.size - 2 * max_lag
    y = turn[max_lag: max_lag + width] - turn[max_lag: max_lag + width].mean()
    energy = float(y @ y)
    if not energy > 1e-24 * width * max(1.0, float(np.abs(turn).max())) ** 2:
        raise DataError("cannot estimate the time offset: the heading does not vary "
                        "(the robot must turn at changing rates)")
    wheels = [w - w.mean() for w in (left, right)]
    cross = [_sliding_dot(y, w) for w in wheels]
    sums = [_sliding_sum(w, width) for w in wheels]
    gram = [[_sliding_sum(u * v, width) - su * sv / width for v, sv in zip(wheels, sums,
                                                                           strict=True)]
            for u, su in zip(wheels, sums, strict=True)]
    ridge = 1e-9 * (gram[0][0] + gram[1][1])
    if not np.all(ridge > 1e-30):
        raise DataError("cannot estimate the time offset: the wheel speeds do not vary")
    g00, g11, g01 = gram[0][0] + ridge, gram[1][1] + ridge, gram[0][1]
    c0, c1 = cross
    return (c0 * c0 * g11 - 2.0 * c0 * c1 * g01 + c1 * c1 * g00) / (g00 * g11 - g01**2) / energy


#: A lag outside the search range fits clearly better than every lag inside it when it leaves
#: at most this fraction of the heading rate's variance that the best lag inside leaves
#: unexplained. Robot motions often repeat (a protocol's period of a few seconds), so lags a
#: period apart fit almost equally well (within a few percent in the unexplained variance);
#: halving it is not chance: with ~100 independent samples of the turn rate (a minute of
#: turning that changes every ~0.5 s) a variance ratio of 2 is beyond F(100, 100)'s 99.9 %
#: quantile (1.87); on shorter or smoother logs the test is looser.
CLEARLY_BETTER = 0.5


class OffsetOutOfRange(DataError):
    """The clock offset is not within estimate_time_offset's search range. candidates: the lags
    (s) outside it that fit far better, nearest zero first (several when the motion repeats);
    empty when the best fit is merely at the edge of the range."""

    def __init__(self, message: str, candidates: Sequence[float] = ()) -> None:
        super().__init__(message)
        self.candidates = tuple(candidates)


def _refuse_better_fit_outside(signals: tuple[FloatArray, FloatArray, FloatArray], step: float,
                               max_lag: int, max_offset: float, overlap: float) -> None:
    """DataError when a lag beyond +-max_lag fits clearly better (CLEARLY_BETTER) than every
    lag within it: the offset is then outside the search range, and the best lag inside only a
    lesser local optimum. Lags are scanned as far as the comparison keeps half the overlap
    (+-overlap / 4)."""
    wide_lag = int(overlap / 4.0 / step)
    if wide_lag <= max_lag:
        return
    unexplained = 1.0 - explained(*signals, wide_lag)
    outside = np.ones(unexplained.size, dtype=bool)
    outside[wide_lag - max_lag: wide_lag + max_lag + 1] = False
    best_inside, best_outside = unexplained[~outside].min(), unexplained[outside].min()
    if not best_outside < CLEARLY_BETTER * best_inside:
        return
    # where to look: the runs of lags outside not clearly worse than the best there, nearest
    # zero first; several when the motion repeats (lags a period apart fit about as well)
    near = outside & (CLEARLY_BETTER * unexplained <= best_outside)
    runs = np.flatnonzero(np.diff(np.concatenate(([0], near.astype(np.int8), [0])))).reshape(-1, 2)
    lags = sorted(((int(a) + int(np.argmin(unexplained[a:b])) - wide_lag) * step
                   for a, b in runs), key=abs)
    where = " or ".join(f"{lag:+.2f} s" for lag in lags[:3])
    repeats = "; the motion repeats, so each fits about as well" if len(lags) > 1 else ""
    raise OffsetOutOfRange(f"cannot estimate the time offset: it is not within +-{max_offset} "
                           f"s (the streams agree far better near {where}{repeats}; widen the "
                           "search range: --max-time-offset)", lags)


def refined_lag(r2: FloatArray, max_lag: int, step: float) -> float:
    """The lag (s) of the largest R^2 (index k of lags -max_lag..max_lag, spacing ``step``),
    refined by a parabola through the three values around it; NaN at the edge."""
    k = int(np.argmax(r2))
    if k in (0, r2.size - 1):
        return math.nan
    curvature = r2[k - 1] - 2.0 * r2[k] + r2[k + 1]
    shift = 0.5 * (r2[k - 1] - r2[k + 1]) / curvature if curvature < 0 else 0.0
    return (k - max_lag + shift) * step


#: The offset is estimated on a uniform grid of the finer median sample period over the time
#: both streams cover; a grid of more points than this many per sample means long gaps (a
#: clock that jumps, a pause between sessions), over which the rates cannot be compared, and
#: is refused (a one-year clock jump at 100 Hz asked for 1.3 TiB; a 20 h one for 1 GB).
MAX_GRID_PER_SAMPLE = 4
#: The default search range of estimate_time_offset: +- this (s).
MAX_TIME_OFFSET = 1.0
#: The default least correlation of estimate_time_offset's best fit.
MIN_CORRELATION = 0.5


def estimate_time_offset(ts: TimeSeries, max_offset: float = MAX_TIME_OFFSET,
                         min_correlation: float = MIN_CORRELATION) -> float:
    """The clock offset (s) with pose time + offset = encoder time.

    The heading rate of the poses is a fixed linear combination of the wheel rates,
    theta' = (r_R phi_R' - r_L phi_L') / b, so the offset is the lag at which the wheel rates
    explain the heading rate best: the largest R^2 of a linear fit of theta' on the shifted
    phi_L', phi_R' (the normalised cross-correlation of theta' with phi_R' - phi_L' when
    r_L = r_R, without that one's bias from the forward speed when r_L != r_R). The rates are
    computed on one grid (spacing h: the smaller median sample period) over the time both
    streams cover; the heading rate's central part (all but max_offset at each end) is
    compared with the wheel rates at every lag within +-max_offset (s), each lag's fit
    normalised over its own samples (no edge bias); the best lag is refined by a parabola
    through the three grid values around it.

    Precision: on smooth motion (turn rates changing over ~1 s) the parabolic refinement's
    bias is below 1e-3 h (noise-free simulated logs: errors ~1e-4 h), and noise averages down
    over the log: from a noisy 2-minute log (100 Hz encoders, 50 Hz poses with 2 mm / 2 mrad
    noise) the error is at most 0.015 h over five noise draws; the tests require 0.05 h.

    An offset outside the search range shows as a best lag at its edge or, as often (the fit
    has local optima), as a lesser optimum inside it: so lags up to +-overlap/4 are scanned as
    well, and a lag there that fits clearly better (CLEARLY_BETTER) than every lag inside
    makes it an error.

    Raises DataError when max_offset is not positive and finite, when the heading or the wheel
    speeds do not vary, when the streams overlap for less than 4 max_offset, when the best
    fit's correlation sqrt(R^2) is below ``min_correlation`` (no clear agreement), when the
    best lag is at the edge of the search range, or when a lag outside it fits clearly better.
    """
    return offset_fit(ts, max_offset, min_correlation).offset


@dataclass(frozen=True)
class OffsetFit:
    """An estimated offset (s) and what it came from: the rate signals (the heading's, the
    left and right wheels', rad/s) on their grid of spacing ``step`` (s) and the search
    range in grid steps."""

    offset: float
    signals: tuple[FloatArray, FloatArray, FloatArray]
    step: float
    max_lag: int


def offset_fit(ts: TimeSeries, max_offset: float, min_correlation: float) -> OffsetFit:
    """:func:`estimate_time_offset`, keeping the signals it fitted (same errors)."""
    if not 0 < max_offset < math.inf:
        raise DataError(f"max_offset must be positive and finite (s), got {max_offset}")
    step = float(min(np.median(np.diff(ts.t_enc)), np.median(np.diff(ts.t_pose))))
    overlap = min(ts.t_enc[-1], ts.t_pose[-1]) - max(ts.t_enc[0], ts.t_pose[0])
    if not overlap > 4 * max_offset:
        raise DataError(f"cannot estimate the time offset: the streams overlap for "
                        f"{max(overlap, 0.0):.3g} s, less than 4 x max_offset ({max_offset} s)")
    samples = ts.t_enc.size + ts.t_pose.size
    if overlap / step > MAX_GRID_PER_SAMPLE * samples:
        raise DataError(f"cannot estimate the time offset: the streams' {samples} samples "
                        f"span {overlap:.6g} s, {overlap / step:.3g} sample periods "
                        f"({step:.3g} s): long gaps (or a clock that jumps); give "
                        "--time-offset, or estimate it on each part of the log")
    max_lag = max(1, int(math.ceil(max_offset / step)))
    signals = _rate_signals(ts, step)
    r2 = explained(*signals, max_lag)
    _refuse_better_fit_outside(signals, step, max_lag, max_offset, overlap)
    k = int(np.argmax(r2))
    correlation = math.sqrt(max(float(r2[k]), 0.0))
    if correlation < min_correlation:
        raise DataError(f"cannot estimate the time offset: heading rate and wheel speeds "
                        f"agree poorly (correlation {correlation:.2f} < {min_correlation})")
    offset = refined_lag(r2, max_lag, step)
    if math.isnan(offset):
        raise OffsetOutOfRange(f"cannot estimate the time offset: it is not within "
                               f"+-{max_offset} s (the best fit is at the edge of the search "
                               "range: --max-time-offset)")
    return OffsetFit(offset, signals, step, max_lag)


#: s, the blocks of the heading rate whose sums make the batch-means standard error of the lag
#: zero score (_lag_zero_score): four times the time over which the turn rate changes
#: (~0.5 s), so consecutive block sums are nearly independent.
OFFSET_TEST_BLOCK = 2.0
#: The fewest blocks the test needs (a t quantile of fewer degrees of freedom is too wide).
MIN_OFFSET_TEST_BLOCKS = 8
#: s, the moving average over which the lag direction (the fitted heading rate's derivative) is
#: smoothed: it needs only the motion's time scale, and differentiating the wheel rates again
#: amplifies the encoder noise (with 4096-tick encoders at 200 Hz it hid a 150 ms offset).
LAG_DIRECTION_SMOOTHING = 0.1
#: Two-sided level of the test that lag zero fits as well as a small shift (noticeable_time_offset).
NOTICEABLE_OFFSET_LEVEL = 1e-3
#: An offset the test finds is noted only beyond this fraction of the coarser stream's median
#: sample period: comparing rates of a coarse stream interpolated on a fine grid leaves a lag
#: of its own (up to 0.08 of a period on logs recorded without an offset: -7.3 ms with 10 Hz
#: encoders under 100 Hz poses, which the test, being about noise, calls significant; a 30 ms
#: offset there is estimated at ~15 ms, so the floor stays near that bias).
NOTICEABLE_OFFSET_PERIODS = 0.1


def smoothed_change(signal: FloatArray, step: float) -> FloatArray:
    """The rate of change of a rate signal on a grid of spacing ``step`` (s), smoothed over
    LAG_DIRECTION_SMOOTHING (differentiating the wheel rates again amplifies the encoder
    noise)."""
    width = max(1, round(LAG_DIRECTION_SMOOTHING / step))
    return np.convolve(np.gradient(signal, step), np.full(width, 1.0 / width), "same")


def _lag_zero_score(fit: OffsetFit) -> tuple[float, int]:
    """A score test that the clock offset is zero: (t statistic, number of blocks).

    At lag zero the heading rate is fitted by the wheel rates (a phi_L' + c phi_R' + const,
    least squares over the compared central samples); a small lag d changes that fit by
    d f'(t) (f the fitted heading rate), so the residual's correlation with f' (smoothed over
    LAG_DIRECTION_SMOOTHING and made orthogonal to the regressors) is the slope of the
    unexplained variance in the lag. It is zero on average when the offset is zero. Its sum
    over blocks of OFFSET_TEST_BLOCK s, mean over the blocks' standard error, is t-distributed
    with blocks - 1 degrees of freedom (batch means: honest for noise correlated over less than
    a block). (0, 0) when there are fewer than MIN_OFFSET_TEST_BLOCKS blocks or a block would
    hold fewer than two samples.
    """
    lag, step = fit.max_lag, fit.step
    turn, left, right = (signal[lag: signal.size - lag] for signal in fit.signals)
    blocks = int(turn.size * step / OFFSET_TEST_BLOCK)
    if blocks < MIN_OFFSET_TEST_BLOCKS or 2 * step > OFFSET_TEST_BLOCK:
        return 0.0, 0  # too short a log, or a block would not hold two samples
    regressors = np.column_stack([left, right, np.ones(turn.size)])
    coefficients = np.linalg.lstsq(regressors, turn, rcond=None)[0]
    residual = turn - regressors @ coefficients
    direction = smoothed_change(regressors[:, :2] @ coefficients[:2], step)
    direction -= regressors @ np.linalg.lstsq(regressors, direction, rcond=None)[0]
    size = turn.size // blocks
    sums = (residual * direction)[: size * blocks].reshape(blocks, size).sum(axis=1)
    spread = float(np.std(sums, ddof=1))
    if not spread > 0:
        return 0.0, blocks
    return float(np.mean(sums)) / spread * math.sqrt(blocks), blocks


@dataclass(frozen=True)
class OffsetHint:
    """A clock offset the data suggest although none was given (s; pose time + offset =
    encoder time): ``offset``, the estimate, clearly not zero and within the search range
    +-``max_offset``; or, when the offset lies beyond that range, ``offset`` None and
    ``beyond`` the lags there that fit far better, nearest zero first (empty when the best
    fit is merely at the range's edge)."""

    offset: float | None
    max_offset: float
    beyond: tuple[float, ...] = ()

    def text(self) -> str:
        """The hint in words, e.g. 'the data suggest -0.1502 s: --time-offset estimate'."""
        if self.offset is not None:
            return f"the data suggest {self.offset:+.4f} s: --time-offset estimate"
        near = f" (near {' or '.join(f'{lag:+.2f} s' for lag in self.beyond[:3])})"
        return (f"the data suggest an offset beyond +-{self.max_offset:g} s"
                f"{near if self.beyond else ''}: --time-offset estimate --max-time-offset S")


def noticeable_time_offset(ts: TimeSeries, max_offset: float = MAX_TIME_OFFSET
                           ) -> OffsetHint | None:
    """What the data say about the clock offset when none was given: a hint when the data
    reject a zero offset (:func:`_lag_zero_score` beyond the two-sided NOTICEABLE_OFFSET_LEVEL
    quantile of Student's t) or the estimate lies beyond +-max_offset s; None when zero fits
    about as well, the estimate is within NOTICEABLE_OFFSET_PERIODS of the coarser stream's
    period, the log is too short for the test (under 8 blocks of 2 s), or the offset cannot be
    estimated (too little turning, too short an overlap: see :func:`estimate_time_offset`).

    On one-minute simulated logs (12 random paths each; 4096-tick encoders and poses at 10 to
    200 Hz, 2 mm / 4 mrad pose noise) no zero offset was noted (largest |t| 2.5, the quantile
    is 3.7); 5 ms offsets were noted in 0-12 of 12 (by rates), 10 ms in 5-12, 20 ms and more in
    all. The old rule (3 batch-means standard errors of the estimate, or a quarter period)
    noted zero offsets in up to 1 of 12; an F test of the unexplained variance (lag zero
    against the best lag) missed 150 ms at 200 Hz, where the heading rate is mostly noise.
    """
    from scipy.special import stdtrit

    try:
        fit = offset_fit(ts, max_offset, MIN_CORRELATION)
    except OffsetOutOfRange as exc:
        return OffsetHint(None, max_offset, exc.candidates)
    except DataError:
        return None
    score, blocks = _lag_zero_score(fit)
    if blocks == 0 or abs(score) <= stdtrit(blocks - 1, 1.0 - 0.5 * NOTICEABLE_OFFSET_LEVEL):
        return None
    if not _beyond_the_floor(ts, fit.offset):
        return None  # within the interpolation's own lag (module constant)
    return OffsetHint(fit.offset, max_offset)


def _beyond_the_floor(ts: TimeSeries, offset: float) -> bool:
    """Whether ``offset`` (s) lies beyond NOTICEABLE_OFFSET_PERIODS of the coarser stream's
    median sample period (within it, the interpolation's own lag)."""
    coarser = max(float(np.median(np.diff(ts.t_enc))), float(np.median(np.diff(ts.t_pose))))
    return abs(offset) > NOTICEABLE_OFFSET_PERIODS * coarser


def rejected_offset(ts: TimeSeries, offset: float, max_offset: float = MAX_TIME_OFFSET
                    ) -> OffsetHint | None:
    """What the data say about a given clock offset ``offset`` (s; pose time + offset =
    encoder time): :func:`noticeable_time_offset`'s hint on the log with that offset applied,
    in offsets of the log itself (the offset the data show instead, or the lags beyond the
    search range around ``offset`` that fit far better); None when the data do not reject
    it."""
    hint = noticeable_time_offset(replace(ts, t_pose=ts.t_pose + offset), max_offset)
    if hint is None:
        return None
    return OffsetHint(None if hint.offset is None else hint.offset + offset, max_offset,
                      tuple(lag + offset for lag in hint.beyond))


def untested_offset(ts: TimeSeries, max_offset: float = MAX_TIME_OFFSET) -> float | None:
    """The lag (s; pose time + offset = encoder time) at which the wheel rates explain the
    heading rate best, when it lies beyond NOTICEABLE_OFFSET_PERIODS of the coarser stream's
    period, whether or not the test of a zero offset rejects zero
    (:func:`noticeable_time_offset`; on some driving, long holds between smooth ramps, that
    test has little power where the estimate is still close to the truth); None when it lies
    within that floor or cannot be estimated. For a calibration that failed: a clock offset
    alone can make it fail."""
    try:
        offset = offset_fit(ts, max_offset, MIN_CORRELATION).offset
    except DataError:
        return None
    return offset if _beyond_the_floor(ts, offset) else None
