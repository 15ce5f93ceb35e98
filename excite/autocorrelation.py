"""Serial correlation left in a fit's whitened residuals, and a covariance that allows for it.

Under the noise model of a log's segments (:mod:`excite.noise`) the whitened residuals of a
fit are independent standard normal, segment after segment. Errors the model does not
describe that persist over several segments (a pose source whose error wanders, as a scan
matcher's or visual odometry's does; wheel rounding of a perfectly steady wheel; slip that
depends on the maneuver) leave them correlated over time, and the parameters' covariance
from the model's information is then too narrow.

* :func:`ljung_box`: the portmanteau test of "no serial correlation" (Ljung & Box 1978),
  over lags 1..H segments of each of the three whitened channels;
* :func:`long_run_covariance`: the covariance of the fitted parameters that holds under
  serial correlation (Newey & West 1987: the scores' long-run covariance with the Bartlett
  kernel, between the inverse information on both sides), over as many lags as the test
  looked at. (Andrews' (1991) AR(1) plug-in bandwidth was tried: it picks 1-3 segments for
  a pose error wandering over 20 s, whose lag-1 correlation is small, and widened too little;
  ``benchmarks/bench_logs.py --pose-noise-time``.)

Arrays are batch-free: residuals (N, 3) in time order, scores (N, P) in the same relative
units as the information (P, P).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from excite.noise import chi2_survival

__all__ = ["LJUNG_BOX_LAGS", "LjungBox", "ljung_box", "long_run_covariance", "at_least"]

FloatArray = NDArray[np.float64]

#: Lags (segments) of the Ljung-Box test; logs shorter than 5 times this are not tested.
LJUNG_BOX_LAGS = 10


@dataclass(frozen=True)
class LjungBox:
    """Q = n (n + 2) sum_h sum_c rho_ch^2 / (n - h), h = 1..lags, c = the three channels;
    chi-square with 3 lags degrees of freedom when the residuals are white. p_value: P(chi2 >
    Q)."""

    statistic: float
    lags: int
    dof: int
    p_value: float


def ljung_box(white: FloatArray, lags: int = LJUNG_BOX_LAGS) -> LjungBox | None:
    """The Ljung-Box test of whitened residuals ``white`` (N, C) in time order, each channel's
    autocorrelations at lags 1..``lags``; None when N < 5 lags (too short to test)."""
    n, channels = white.shape
    if n < 5 * lags:
        return None
    centred = white - white.mean(axis=0)
    variance = np.sum(centred * centred, axis=0)
    if np.any(variance <= 0.0):
        return None
    q = 0.0
    for h in range(1, lags + 1):
        rho = np.sum(centred[h:] * centred[:-h], axis=0) / variance
        q += float(np.sum(rho * rho)) / (n - h)
    q *= n * (n + 2)
    dof = channels * lags
    return LjungBox(q, lags, dof, chi2_survival(q, dof))


def long_run_covariance(scores: FloatArray, inverse_information: FloatArray,
                        bandwidth: int = LJUNG_BOX_LAGS) -> FloatArray:
    """Newey-West covariance of the fitted parameters, I^-1 S I^-1, from the per-segment scores
    (N, P) (J_k^T r_k: each segment's whitened Jacobian rows times its whitened residuals, at
    the fit) and the inverse information I^-1 (P, P, finite): S = sum over lags |h| <= L of
    (1 - |h| / (L + 1)) times the lag-h cross products of the scores, L = ``bandwidth``
    (segments). Same units as ``inverse_information``."""
    s = scores.T @ scores
    for h in range(1, min(bandwidth, len(scores) - 1) + 1):
        lagged = scores[h:].T @ scores[:-h]
        s += (1.0 - h / (bandwidth + 1.0)) * (lagged + lagged.T)
    covariance = inverse_information @ s @ inverse_information
    return 0.5 * (covariance + covariance.T)


def at_least(covariance: FloatArray, other: FloatArray) -> FloatArray:
    """``covariance`` plus the positive part of ``other`` - ``covariance``: at least both (in
    the Loewner order), and ``covariance`` itself wherever ``other`` is not larger."""
    difference = other - covariance
    lam, vectors = np.linalg.eigh(0.5 * (difference + difference.T))
    return covariance + (vectors * np.maximum(lam, 0.0)) @ vectors.T

