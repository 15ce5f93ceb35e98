"""Outlier trimming before the calibration's fits: the segments with the largest whitened
residuals dropped, a few at a time with a refit after each pass (Censi et al.).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from excite.calibration.options import FitOptions
from excite.calibration.solver import Problem, levenberg_marquardt
from excite.calibration.starts import Starts
from excite.logs.segments import Segments

__all__ = ["TRIM_PASS", "trimmed"]

FloatArray = NDArray[np.float64]
#: Each trimming pass drops at most this fraction of the segments (Censi et al. drop 1%).
TRIM_PASS = 0.01


def trimmed(seg: Segments, starts: Starts, sigma: FloatArray | None, trim: float,
            options: FitOptions) -> Segments:
    """The segments kept after dropping the fraction ``trim`` with the largest whitened
    residuals of the primary model (fitted from its start, with the given noise std ``sigma``
    (m, m, rad) or, None, the estimated one), at most TRIM_PASS per pass with a refit after
    each; ``seg`` itself when ``trim`` is 0."""
    if not trim:
        return seg
    keep = np.ones(len(seg), dtype=bool)
    target = int(round(trim * len(seg)))
    theta = starts.start
    while (dropped := int(np.sum(~keep))) < target:
        fit = levenberg_marquardt(Problem(starts.primary, seg[keep]), theta, sigma, options.loss,
                                  options.max_iterations, options.tol,
                                  determined=1.0 / options.max_relative_std)
        theta = fit.theta
        z2 = np.sum((fit.ev.raw / fit.sigma[:, None]) ** 2, axis=0)
        count = min(max(1, int(math.ceil(TRIM_PASS * len(seg)))), target - dropped)
        kept = np.flatnonzero(keep)
        keep[kept[np.argsort(z2)[::-1][:count]]] = False
    return seg[keep]
