"""The metrics a comparison is decided by, as pure functions over arrays (no I/O).

Inputs are per-segment records: index k along the last axis is the state after segment
k + 1 of an episode (K segments); episodes, when there are several, run along the first axis.
Consistency (NEES, ANEES and its chi-square bounds) is in :mod:`excite.stats.consistency`, shared
with the environment's estimator check.

* :func:`time_to_accuracy`: segments, seconds and metres of driving until the max relative
  error stays below a threshold, censored (inf, flagged) when it never does;
* :func:`error_time_area`: the area under the max relative error over time;
* :func:`paired_ratio`: one policy's median over another's on the same episodes, with a
  paired percentile bootstrap 95% interval;
* :func:`rate_interval`: a rate of events (e.g. false stops) with its Wilson 95% interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import trapezoid
from scipy.stats import binomtest

from excite.errors import MetricError
from excite.stats.consistency import CONFIDENCE, check_confidence

__all__ = [
    "CONFIDENCE",
    "N_BOOT",
    "MetricError",
    "PairedRatio",
    "TimeToAccuracy",
    "error_time_area",
    "paired_ratio",
    "rate_interval",
    "time_to_accuracy",
]

FloatArray = NDArray[np.float64]

#: Bootstrap resamples of the episodes.
N_BOOT = 2000


@dataclass(frozen=True)
class TimeToAccuracy:
    """How long until the error stays below a threshold, per episode (arrays shaped like the
    inputs without their last axis).

    segments: segments driven (k + 1 for the first index k after which the error stays
        below), float; seconds, metres: the cumulative time (s) and distance (m) at that
        segment's end (None when not asked for); censored: True where the error is not below
        the threshold at the last segment (then every value is inf: not reached within the
        record, which says nothing about later).
    """

    segments: FloatArray
    seconds: FloatArray | None
    metres: FloatArray | None
    censored: NDArray[np.bool_]


def _per_segment(name: str, values: ArrayLike | None, shape: tuple[int, ...]
                 ) -> FloatArray | None:
    if values is None:
        return None
    out = np.asarray(values, dtype=float)
    if out.shape != shape:
        raise MetricError(f"{name} must be shaped like the errors {shape}, got {out.shape}")
    return out


def time_to_accuracy(max_error: ArrayLike, threshold: float, time: ArrayLike | None = None,
                     distance: ArrayLike | None = None) -> TimeToAccuracy:
    """The first segment after which ``max_error`` stays strictly below ``threshold``.

    max_error: (..., K) the max relative error over the parameters after each segment
    (dimensionless; nan counts as not below); threshold: relative (0.005 for 0.5%); time,
    distance: (..., K) cumulative seconds and metres driven at each segment's end.
    Episodes whose last error is not below are censored: inf, flagged.

    "Stays below" is judged on the record: an episode that ends below the threshold is
    counted as reached. With one horizon for all episodes, every censored time exceeds
    every reached one, so medians over episodes with inf for censored are exact as long as
    fewer than half are censored (and inf otherwise: "not reached").
    """
    error = np.asarray(max_error, dtype=float)
    if error.ndim < 1 or error.shape[-1] < 1:
        raise MetricError("max_error needs at least one segment on its last axis")
    if not threshold > 0.0:
        raise MetricError(f"threshold must be positive, got {threshold}")
    time_ = _per_segment("time", time, error.shape)
    distance_ = _per_segment("distance", distance, error.shape)
    below = error < threshold
    # stays[..., k]: below at k and at every later segment.
    stays = np.flip(np.logical_and.accumulate(np.flip(below, axis=-1), axis=-1), axis=-1)
    censored = ~stays[..., -1]
    first = np.argmax(stays, axis=-1)[..., None]

    def at_first(values: FloatArray) -> FloatArray:
        return np.where(censored, np.inf, np.take_along_axis(values, first, axis=-1)[..., 0])

    return TimeToAccuracy(
        segments=np.where(censored, np.inf, first[..., 0] + 1.0),
        seconds=None if time_ is None else at_first(time_),
        metres=None if distance_ is None else at_first(distance_),
        censored=censored,
    )


def error_time_area(max_error: ArrayLike, time: ArrayLike) -> FloatArray:
    """The area under the max relative error over time, by the trapezoid rule over the
    samples given (relative error x s): (..., K) errors and cumulative times -> (...).

    Prepend the start (time 0, the nominal robot's error) to count the first segment; compare
    areas over one common horizon only (same segment budget and duration)."""
    error = np.asarray(max_error, dtype=float)
    t = _per_segment("time", time, error.shape)
    return np.asarray(trapezoid(error, t, axis=-1), dtype=float)


@dataclass(frozen=True)
class PairedRatio:
    """ratio = median(numerator) / median(denominator) over the same episodes, with its
    percentile bootstrap interval ci = (low, high) at ``confidence``."""

    ratio: float
    ci: tuple[float, float]
    confidence: float
    n_boot: int


def _ratio_of_medians(numerator: FloatArray, denominator: FloatArray) -> FloatArray:
    """median / median along the last axis; inf / inf (both mostly censored) is nan."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.median(numerator, axis=-1) / np.median(denominator, axis=-1)


def paired_ratio(numerator: ArrayLike, denominator: ArrayLike, rng: np.random.Generator,
                 n_boot: int = N_BOOT, confidence: float = CONFIDENCE) -> PairedRatio:
    """How one policy (numerator, e.g. learned) compares with a baseline (denominator) on the
    same M episodes: the ratio of their medians, with a percentile bootstrap interval that
    resamples the episodes in pairs (one index draw for both, so the robots they share cancel).

    numerator, denominator: (M,) per-episode values of one metric (final error, time to
    accuracy with inf for censored, error-time area, ...), episode i of both on the same
    robot. rng: draws the resamples.

    The ratio of medians rather than the median of per-episode ratios: a per-episode ratio
    explodes when one baseline episode happens to land near zero error, is undefined for an
    episode censored in both (inf / inf), and its median answers "how much better on a
    typical robot" only for near-proportional metrics; the medians are robust, use censored
    episodes correctly (an inf median means "not reached for most robots": ratio 0 or inf),
    and the pairing is kept by the joint resampling. inf / inf is nan (undefined), and so
    is an interval when any resample is undefined.
    """
    num = np.asarray(numerator, dtype=float)
    den = np.asarray(denominator, dtype=float)
    if num.ndim != 1 or num.shape != den.shape or num.size < 1:
        raise MetricError(f"numerator and denominator must be two equal-length 1-D arrays of "
                          f"paired episodes, got shapes {num.shape} and {den.shape}")
    if int(n_boot) != n_boot or n_boot < 1:
        raise MetricError(f"n_boot must be a whole number >= 1, got {n_boot}")
    alpha = 1.0 - check_confidence(confidence)
    draws = rng.integers(0, num.size, size=(int(n_boot), num.size))
    boot = _ratio_of_medians(num[draws], den[draws])
    # Order statistics (no interpolation: between two inf resamples it would give nan).
    low, high = np.quantile(boot, [0.5 * alpha, 1.0 - 0.5 * alpha], method="inverted_cdf")
    return PairedRatio(float(_ratio_of_medians(num, den)), (float(low), float(high)),
                       confidence, int(n_boot))


def rate_interval(events: int, trials: int, confidence: float = CONFIDENCE
                  ) -> tuple[float | None, tuple[float, float]]:
    """The rate events / trials (None without trials) and its Wilson score interval at
    ``confidence`` ((0, 1) without trials: nothing is known)."""
    if int(events) != events or int(trials) != trials or not 0 <= events <= trials:
        raise MetricError(f"need whole numbers 0 <= events <= trials, got {events}, {trials}")
    if trials == 0:
        return None, (0.0, 1.0)
    ci = binomtest(int(events), int(trials)).proportion_ci(check_confidence(confidence),
                                                            "wilson")
    return events / trials, (float(ci.low), float(ci.high))
