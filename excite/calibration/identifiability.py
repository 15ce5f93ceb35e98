"""Words for what the data do not determine: the relative directions of the parameters whose
std exceeds the identifiability threshold, named by parameter group and with the reason.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from excite.core.models import AXLE, SENSOR_POSE
from excite.logs.segments import Segments

__all__ = ["describe_weak"]

FloatArray = NDArray[np.float64]


def _moving_segments(seg: Segments, sigma: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Masks of the segments that turn (|dtheta| > 3 sigma_theta) and whose body translates
    (the wheels move together: |dphi_L + dphi_R| > |dphi_R - dphi_L| / 10)."""
    turning = np.abs(seg.dtheta) > 3.0 * sigma[2]
    together = np.abs(seg.dphi_L + seg.dphi_R)
    translating = together > 0.1 * np.abs(seg.dphi_R - seg.dphi_L) + 1e-12
    return turning, translating


def describe_weak(weak: FloatArray, theta: FloatArray, seg: Segments,
                  sigma: FloatArray) -> str:
    """Words for the relative-parameter directions the data do not determine (the columns of
    ``weak`` (P, k), orthonormal) at the estimate ``theta`` (P,), with per-channel noise std
    ``sigma`` (m, m, rad): every named group of parameters that lies in them, with why; else
    the first direction as a relative combination of the parameters."""
    p = weak.shape[0]
    turning, translating = _moving_segments(seg, sigma)
    no_turn = "no segment turns" if not turning.any() else "the turns do not separate it"
    no_move = ("no segment translates" if not translating.any()
               else "the translations do not separate it")
    scale = np.zeros(p)
    scale[:3] = 1.0
    if p == 6:  # a common scale of every length leaves the measurements unchanged
        scale[3:5] = theta[3:5] / theta[2]
    groups = [("b", [np.eye(p)[2]], no_turn),
              ("the common scale of r_L, r_R and b", [scale], "no segment translates"),
              ("the ratio r_L/r_R", [np.eye(p)[0] - np.eye(p)[1]],
               "every segment has the same wheel-speed ratio")]
    if p == 6:
        groups = [("sensor x, y", [np.eye(p)[3], np.eye(p)[4]], no_turn),
                  ("sensor theta", [np.eye(p)[5]], no_move)] + groups
    words = []
    for name, directions, why in groups:
        inside = [float(np.sum((weak.T @ (d / np.linalg.norm(d))) ** 2)) for d in directions]
        if min(inside) > 0.9:
            words.append(f"{name}: {why}")
    if words:
        return "; ".join(words)
    v = weak[:, 0] if weak[np.argmax(np.abs(weak[:, 0])), 0] > 0 else -weak[:, 0]
    names = SENSOR_POSE.names if p == 6 else AXLE.names
    terms = " ".join(f"{c:+.2f}*{n}" for c, n in zip(v, names, strict=True))
    return f"the relative combination {terms}"
