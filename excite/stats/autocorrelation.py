"""Serial correlation left in a fit's whitened residuals, and a covariance that allows for it.

Under the noise model of a log's segments (:mod:`excite.calibration.noise`) the whitened residuals
of a
fit are independent standard normal, segment after segment. Errors the model does not
describe that persist over several segments (a pose source whose error wanders, as a scan
matcher's or visual odometry's does; wheel rounding of a perfectly steady wheel; slip that
depends on the maneuver) leave them correlated over time, and the parameters' covariance
from the model's information is then too narrow.

* :func:`ljung_box`: the portmanteau test of "no serial correlation" (Ljung & Box 1978),
  over lags 1..H segments of each of the three whitened channels, counting only segments h
  apart with no gap or part boundary between them;
* :func:`long_run_covariance`: the covariance of the fitted parameters that holds under
  serial correlation (Newey & West 1987: the scores' long-run covariance with the Bartlett
  kernel, between the inverse information on both sides), over as many lags as the test
  looked at. (Andrews' (1991) AR(1) plug-in bandwidth was tried: it picks 1-3 segments for
  a pose error wandering over 20 s, whose lag-1 correlation is small, and widened too little;
  ``benchmarks/bench_logs.py --pose-noise-time``.)

Arrays are one fit's: residuals (N, 3) in time order, scores (N, P) in the same relative
units as the information (P, P), runs (N,) the index of the unbroken stretch of segments each
belongs to (:func:`runs_of`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from excite.stats.chi2 import chi2_survival

__all__ = ["LJUNG_BOX_LAGS", "LjungBox", "ljung_box", "long_run_covariance", "at_least",
           "runs_of"]

FloatArray = NDArray[np.float64]

#: Lags (segments) of the Ljung-Box test; logs shorter than 5 times this are not tested.
LJUNG_BOX_LAGS = 10


@dataclass(frozen=True)
class LjungBox:
    """Q = sum_h sum_c (n + 2) n_h / n rho_ch^2 over lags h = 1..lags and the channels c, rho_ch
    the lag-h autocorrelation of channel c over the n_h pairs of segments h apart in one run
    (Ljung and Box's statistic when the log is one run: n_h = n - h); chi-square with ``dof``
    = channels times the lags that have pairs when the residuals are white. p_value: P(chi2 >
    Q). The P fitted parameters are not subtracted from the dof (that correction is for
    residuals of a fitted ARMA model, not of a regression)."""

    statistic: float
    lags: int
    dof: int
    p_value: float


def runs_of(chained: NDArray[np.bool_] | None, n: int) -> NDArray[np.int64]:
    """The run index (n,) of segments from their ``chained`` flags (segment k starts where
    k - 1 ended; :class:`excite.logs.segments.Segments`): a new run at every segment not chained."""
    if chained is None:
        return np.arange(n, dtype=np.int64)
    return np.cumsum(~chained).astype(np.int64)


def _lag_pairs(runs: NDArray[np.int64], h: int) -> NDArray[np.bool_]:
    """Which pairs (k, k + h) lie in one run (no gap or part boundary between them)."""
    return runs[h:] == runs[:-h]


def ljung_box(white: FloatArray, runs: NDArray[np.int64] | None = None,
              lags: int = LJUNG_BOX_LAGS) -> LjungBox | None:
    """The Ljung-Box test of whitened residuals ``white`` (N, C) in time order, each channel's
    autocorrelations at lags 1..``lags`` within ``runs`` (N,) (the run of consecutive segments
    each belongs to: pairs across a gap are not neighbours; None: one run); None when N < 5
    lags (too short to test) or a channel is constant."""
    n, channels = white.shape
    if n < 5 * lags:
        return None
    runs = np.zeros(n, dtype=np.int64) if runs is None else runs
    centred = white - white.mean(axis=0)
    variance = np.mean(centred * centred, axis=0)
    if np.any(variance <= 0.0):
        return None
    q, tested = 0.0, 0
    for h in range(1, lags + 1):
        pairs = _lag_pairs(runs, h)
        count = int(np.count_nonzero(pairs))
        if count == 0:
            continue
        rho = np.sum((centred[h:] * centred[:-h])[pairs], axis=0) / count / variance
        q += (n + 2.0) * count / n * float(np.sum(rho * rho))
        tested += 1
    if tested == 0:
        return None
    dof = channels * tested
    return LjungBox(q, lags, dof, chi2_survival(q, dof))


def long_run_covariance(scores: FloatArray, inverse_information: FloatArray,
                        runs: NDArray[np.int64] | None = None,
                        bandwidth: int = LJUNG_BOX_LAGS) -> FloatArray:
    """Newey-West covariance of the fitted parameters, I^-1 S I^-1, from the per-segment scores
    (N, P) (J_k^T r_k: each segment's whitened Jacobian rows times its whitened residuals, at
    the fit) and the inverse information I^-1 (P, P, finite): S = sum over lags |h| <= L of
    (1 - |h| / (L + 1)) times the cross products of the scores h apart in one of ``runs``
    (as :func:`ljung_box`), L = ``bandwidth`` (segments). Same units as
    ``inverse_information``. It allows for correlation over at most L segments; errors that
    persist longer are under-covered."""
    runs = np.zeros(len(scores), dtype=np.int64) if runs is None else runs
    s = scores.T @ scores
    for h in range(1, min(bandwidth, len(scores) - 1) + 1):
        pairs = _lag_pairs(runs, h)
        lagged = scores[h:][pairs].T @ scores[:-h][pairs]
        s += (1.0 - h / (bandwidth + 1.0)) * (lagged + lagged.T)
    covariance = inverse_information @ s @ inverse_information
    return 0.5 * (covariance + covariance.T)


def at_least(covariance: FloatArray, other: FloatArray) -> FloatArray:
    """``covariance`` plus the positive part of ``other`` - ``covariance``: at least both (in
    the Loewner order), and ``covariance`` itself wherever ``other`` is not larger."""
    difference = other - covariance
    lam, vectors = np.linalg.eigh(0.5 * (difference + difference.T))
    return covariance + (vectors * np.maximum(lam, 0.0)) @ vectors.T

