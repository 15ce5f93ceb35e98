"""SE(2) poses (x, y, theta) as arrays (..., 3): x, y in m, theta in rad (not wrapped).

``compose(a, b)`` is a (+) b: pose b, given in the frame of pose a, expressed in a's parent
frame; ``between(a, b)`` is (-a) (+) b: pose b in the frame of pose a; ``inverse(a)`` is -a.
Batch-first: every function broadcasts over the leading axes; :func:`between_scalar` is the
fast form of :func:`between` for one pair of poses (the single environment's step).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["compose", "between", "between_scalar", "inverse", "accumulate"]

FloatArray = NDArray[np.float64]


def compose(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """a (+) b for poses (..., 3)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1],
                     a[..., 1] + s * b[..., 0] + c * b[..., 1], a[..., 2] + b[..., 2]], axis=-1)


def between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """(-a) (+) b for poses (..., 3): b in the frame of a (theta difference not wrapped)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    d = b - a
    return np.stack([c * d[..., 0] + s * d[..., 1], c * d[..., 1] - s * d[..., 0], d[..., 2]],
                    axis=-1)


def between_scalar(a: FloatArray, b: FloatArray) -> FloatArray:
    """:func:`between` of two poses (3,), with math's cos and sin: the same bits without
    numpy's per-call overheads."""
    ex, ey = b[0] - a[0], b[1] - a[1]
    th = a[2]
    c, s = math.cos(th), math.sin(th)
    return np.array([c * ex + s * ey, c * ey - s * ex, b[2] - th])


def inverse(a: ArrayLike) -> FloatArray:
    """-a for poses (..., 3): a (+) (-a) = 0."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], -a[..., 2]],
                    axis=-1)


def accumulate(dx: ArrayLike, dy: ArrayLike, dtheta: ArrayLike) -> FloatArray:
    """0 (+) d_1 (+) d_2 (+) ... of increments d_k = (dx, dy, dtheta) (n,), each in the frame
    of the pose before it: the n + 1 poses (n + 1, 3), the first the origin, theta continuous
    (the cumulative heading, not wrapped)."""
    dx, dy, dtheta = (np.asarray(a, dtype=float) for a in (dx, dy, dtheta))
    theta = np.concatenate(([0.0], np.cumsum(dtheta)))
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    x = np.concatenate(([0.0], np.cumsum(c * dx - s * dy)))
    y = np.concatenate(([0.0], np.cumsum(s * dx + c * dy)))
    return np.column_stack([x, y, theta])
