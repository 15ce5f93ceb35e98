"""Symmetric matrices in LAPACK's lower band storage: row d of a band (b + 1, n) holds the
d-th subdiagonal, band[d, j] = X[j + d, j] (the layout of ``dpbtrf``, :func:`scipy.linalg.
cholesky_banded` with ``lower=True``). The covariance of a log's stacked increments is such
a band (:func:`excite.calibration.noise.chain_band`)."""

from __future__ import annotations

import numpy as np

from excite.core.arrays import FloatArray

__all__ = ["band_inner", "band_product", "dense"]


def dense(band: FloatArray) -> FloatArray:
    """The symmetric matrix (n, n) of lower band storage ``band`` (b + 1, n)."""
    n = band.shape[1]
    out = np.zeros((n, n))
    for d in range(band.shape[0]):
        j = np.arange(n - d)
        out[j + d, j] = band[d, : n - d]
        out[j, j + d] = band[d, : n - d]
    return out


def band_inner(band: FloatArray, m_band: FloatArray) -> float:
    """sum(X * M) for X and M symmetric, given by their lower band storage ``band`` and
    ``m_band`` (M's band at least as wide as X's)."""
    n = band.shape[1]
    total = float(band[0] @ m_band[0])
    for d in range(1, band.shape[0]):
        total += 2.0 * float(band[d, : n - d] @ m_band[d, : n - d])
    return total


def band_product(band: FloatArray, x: FloatArray) -> FloatArray:
    """X x for X the symmetric matrix of lower band storage ``band`` (b + 1, n) and x (n, P)."""
    n = band.shape[1]
    out = band[0][:, None] * x
    for d in range(1, band.shape[0]):
        b = band[d, : n - d][:, None]
        out[d:] += b * x[: n - d]
        out[: n - d] += b * x[d:]
    return out
