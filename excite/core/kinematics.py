"""Differential-drive kinematics of one motion segment, and its analytic Jacobian.

Frames and units (docs/conventions.md): parameters p = (r_L, r_R, b) in meters, wheel increments
dphi in radians. The increment (dx, dy, dtheta) is expressed in the body frame at the start
of the segment (x forward, y left, theta counter-clockwise); the left wheel sits at +b/2 on y.

For a constant-curvature segment (lesson, section 2)::

    ds     = (r_L dphi_L + r_R dphi_R) / 2
    dtheta = (r_R dphi_R - r_L dphi_L) / b
    dx     = ds * sinc(dtheta),  sinc(u) = sin(u) / u
    dy     = ds * cosc(dtheta),  cosc(u) = (1 - cos(u)) / u

sinc, cosc and their derivatives are evaluated by cancellation-free closed forms where those
are accurate and by their Taylor series where not (see :func:`sinc_family`; its fast form for
one float is :func:`sinc_family_scalar`); both branches agree to a few ulps at each seam, and
nothing is NaN or inf for u = 0, tiny u, or many turns.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from math import factorial

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "MAX_RADIUS_TO_TRACK",
    "Arc",
    "Params",
    "predict_increment",
    "sinc_family",
    "sinc_family_scalar",
    "wrap_angle",
]

FloatArray = NDArray[np.float64]
_TWO_PI = 2.0 * math.pi
#: r / b of any differential drive is below this (its wheels are smaller than its track; 0.3
#: on a Husky): heading changes faster than this per wheel radian are in other units.
MAX_RADIUS_TO_TRACK = 1.0

#: Below this |u| sinc' uses its series (12 terms: truncation error < 1e-20 there).
SERIES_THRESHOLD = 1.0
#: Below this |u| sinc, cosc, cosc' use their first 3 series terms (truncation < 1e-25).
TINY_THRESHOLD = 1e-4
_N_TERMS = 12


def _coefficients(term) -> tuple[float, ...]:
    """Coefficients c_k of a series sum_k c_k * (u^2)^k, highest power first (for Horner)."""
    return tuple(term(k) for k in reversed(range(_N_TERMS)))


# sinc(u)  = sum_k (-1)^k u^2k / (2k+1)!
_SINC = _coefficients(lambda k: (-1) ** k / factorial(2 * k + 1))
# cosc(u)  = u * sum_k (-1)^k u^2k / (2k+2)!
_COSC = _coefficients(lambda k: (-1) ** k / factorial(2 * k + 2))
# sinc'(u) = u * sum_k (-1)^(k+1) (2k+2) u^2k / (2k+3)!
_DSINC = _coefficients(lambda k: (-1) ** (k + 1) * (2 * k + 2) / factorial(2 * k + 3))
# cosc'(u) = sum_k (-1)^k (2k+1) u^2k / (2k+2)!
_DCOSC = _coefficients(lambda k: (-1) ** k * (2 * k + 1) / factorial(2 * k + 2))


def _series(coeffs: tuple[float, ...], u2):
    """Horner evaluation in u^2; works on Python floats and numpy arrays alike."""
    acc = 0.0
    for c in coeffs:
        acc = acc * u2 + c
    return acc


def _dsinc_series(u: FloatArray) -> FloatArray:
    """sinc'(u) of an array by its series (|u| <= 1), Horner in place, with only the terms
    that matter: those that can exceed 1e-18 of the leading one for the largest u^2 present."""
    u2 = u * u
    used = _dsinc_terms(float(u2.max()) if u2.size else 0.0)
    acc = np.full_like(u2, used[0])
    for c in used[1:]:
        acc *= u2
        acc += c
    acc *= u
    return acc


# The series term of power k (in u^2) matters once u^2 reaches this (increasing in k).
_DSINC_THRESHOLDS = tuple(
    (1e-18 * abs(_DSINC[-1]) / abs(_DSINC[-1 - k])) ** (1.0 / k) for k in range(1, _N_TERMS))
_DSINC_TRUNCATED = tuple(_DSINC[_N_TERMS - 1 - k:] for k in range(_N_TERMS))  # k + 1 terms
# The first three terms: exact (truncation < 1e-25) below TINY_THRESHOLD.
_SINC3, _COSC3, _DSINC3, _DCOSC3 = _SINC[-3:], _COSC[-3:], _DSINC[-3:], _DCOSC[-3:]


def _dsinc_terms(largest_u2: float) -> tuple[float, ...]:
    """The series coefficients of sinc' that matter up to u^2 = largest_u2 (Horner order)."""
    return _DSINC_TRUNCATED[bisect_right(_DSINC_THRESHOLDS, largest_u2)]


@dataclass(frozen=True)
class Params:
    """Kinematic parameters of a differential-drive robot (meters).

    r_L, r_R: effective left / right wheel radius; b: effective wheel separation.
    """

    r_L: float
    r_R: float
    b: float

    def __post_init__(self) -> None:
        values = float(self.r_L), float(self.r_R), float(self.b)
        for name, value in zip(("r_L", "r_R", "b"), values, strict=True):
            if not 0.0 < value < math.inf:
                raise ValueError(f"{name} must be a positive finite length in meters, got {value}")
        object.__setattr__(self, "r_L", values[0])
        object.__setattr__(self, "r_R", values[1])
        object.__setattr__(self, "b", values[2])

    @classmethod
    def from_array(cls, values: ArrayLike) -> Params:
        r_L, r_R, b = np.asarray(values, dtype=float).reshape(3)
        return cls(float(r_L), float(r_R), float(b))

    def as_array(self) -> FloatArray:
        """(r_L, r_R, b) as a float64 array of shape (3,)."""
        return np.array([self.r_L, self.r_R, self.b])


def sinc_family(u: ArrayLike, derivatives: bool = True) -> tuple[FloatArray, ...]:
    """(sinc, cosc[, sinc', cosc']) of an array, sharing one tan(u/2) evaluation.

    sinc, cosc and cosc' use cancellation-free closed forms in tan(u/2) (accurate
    to a few ulps for every u != 0) and exact short series for |u| < 1e-4. sinc' has a
    cancellation of order 1/u^2 in closed form, so it uses the series for |u| < 1.
    """
    u = np.asarray(u, dtype=float)
    if u.ndim == 0:
        return tuple(x.reshape(()) for x in sinc_family(u.reshape(1), derivatives))
    tiny = np.abs(u) < TINY_THRESHOLD
    any_tiny = bool(tiny.any())
    safe = np.where(tiny, 1.0, u) if any_tiny else u
    sin_u, one_minus_cos = _turn_by_half_tangent(safe)
    f = sin_u / safe
    g = one_minus_cos / safe
    if derivatives:
        safe2 = safe * safe
        gp = (safe * sin_u - one_minus_cos) / safe2
        small = np.abs(u) < SERIES_THRESHOLD
        if small.all():
            fp = _dsinc_series(u)
        else:
            fp = (safe * (1.0 - one_minus_cos) - sin_u) / safe2
            if small.any():
                fp[small] = _dsinc_series(u[small])
    if any_tiny:
        ut = u[tiny]
        u2 = ut * ut
        f[tiny] = _series(_SINC3, u2)
        g[tiny] = ut * _series(_COSC3, u2)
        if derivatives:
            gp[tiny] = _series(_DCOSC3, u2)
    return (f, g, fp, gp) if derivatives else (f, g)


def _turn_by_half_tangent(u: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(sin u, 1 - cos u) of an array from t = tan(u/2): 2t / (1 + t^2) and 2t^2 / (1 + t^2),
    free of cancellation like 2 sin(u/2) cos(u/2) and 2 sin(u/2)^2, with one transcendental
    call instead of two (numpy vectorises tan, not sin and cos, of float64)."""
    t = np.tan(0.5 * u)
    w = 2.0 / (1.0 + t * t)
    sin_u = t * w
    return sin_u, t * sin_u


def sinc_family_scalar(u: float, derivatives: bool = True) -> tuple[float, ...]:
    """:func:`sinc_family` of one Python float, with its branches: the one-segment hot paths
    (the online filter's update, the chord information's loop) where numpy's per-call
    overhead would dominate."""
    if abs(u) < TINY_THRESHOLD:
        u2 = u * u
        f, g = _series(_SINC3, u2), u * _series(_COSC3, u2)
        if not derivatives:
            return f, g
        return f, g, u * _series(_DSINC3, u2), _series(_DCOSC3, u2)
    half_sin, half_cos = math.sin(0.5 * u), math.cos(0.5 * u)
    one_minus_cos = 2.0 * half_sin * half_sin
    sin_u = 2.0 * half_sin * half_cos
    f, g = sin_u / u, one_minus_cos / u
    if not derivatives:
        return f, g
    u2 = u * u
    if abs(u) < SERIES_THRESHOLD:
        fp = u * _series(_dsinc_terms(u2), u2)
    else:
        fp = (u * (1.0 - one_minus_cos) - sin_u) / u2
    return f, g, fp, (u * sin_u - one_minus_cos) / u2


def wrap_angle(a: ArrayLike) -> FloatArray:
    """Wrap angles (rad) to (-pi, pi]."""
    a = np.asarray(a, dtype=float)
    wrapped = a - _TWO_PI * np.round(a / _TWO_PI)  # in [-pi, pi]
    return np.where(wrapped <= -np.pi, wrapped + _TWO_PI, wrapped)


def _as_params(params: Params | ArrayLike) -> tuple[float, float, float]:
    if isinstance(params, Params):
        return params.r_L, params.r_R, params.b
    r_L, r_R, b = np.asarray(params, dtype=float).reshape(3).tolist()  # floats in one call
    return r_L, r_R, b


class Arc:
    """The constant-curvature arc of a batch of segments and, on request, its derivatives by
    (r_L, r_R, b): the one derivation of the lesson's model (section 5) that every other
    model builds on.

    Arrays broadcast over the leading axes of the wheel increments and parameters:
    ds, dtheta, f = sinc(dtheta), g = cosc(dtheta) (and fp, gp their derivatives);
    dx = ds * f, dy = ds * g. ``d_ds`` and ``d_dtheta`` are the gradients of ds (m per m) and
    dtheta (rad per m) by (r_L, r_R, b), as tuples of three arrays.
    """

    __slots__ = ("ds", "dtheta", "f", "g", "fp", "gp", "dx", "dy", "d_ds", "d_dtheta")

    def __init__(self, phi_L: FloatArray, phi_R: FloatArray, r_L, r_R, b,
                 derivatives: bool = True):
        s_L, s_R = r_L * phi_L, r_R * phi_R
        self.ds = 0.5 * (s_L + s_R)
        self.dtheta = (s_R - s_L) / b
        if derivatives:
            self.f, self.g, self.fp, self.gp = sinc_family(self.dtheta)
            inv_b = 1.0 / b
            self.d_ds = (0.5 * phi_L, 0.5 * phi_R, 0.0)
            self.d_dtheta = (-phi_L * inv_b, phi_R * inv_b, -self.dtheta * inv_b)
        else:
            self.f, self.g = sinc_family(self.dtheta, derivatives=False)
        self.dx, self.dy = self.ds * self.f, self.ds * self.g

    def fill_jacobian(self, out: FloatArray) -> FloatArray:
        """Write d(dx, dy, dtheta)/d(r_L, r_R, b) into ``out`` (3 rows, 3 parameters, ...)
        (m per m, rad per m), by the chain rule through ds and dtheta, without temporaries."""
        ex, ey = self.ds * self.fp, self.ds * self.gp
        for k in range(3):
            out[2, k] = self.d_dtheta[k]
            np.multiply(ex, out[2, k], out=out[0, k])
            np.multiply(ey, out[2, k], out=out[1, k])
            if k < 2:  # ds does not depend on b
                out[0, k] += self.d_ds[k] * self.f
                out[1, k] += self.d_ds[k] * self.g
        return out


def predict_increment(
    dphi_L: ArrayLike, dphi_R: ArrayLike, params: Params | ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Predicted body-frame increment (dx [m], dy [m], dtheta [rad]) of each segment.

    dphi_L, dphi_R: wheel increments (rad), any broadcastable shapes.
    params: Params or array-like (r_L, r_R, b) in meters.
    """
    r_L, r_R, b = _as_params(params)
    arc = Arc(np.asarray(dphi_L, dtype=float), np.asarray(dphi_R, dtype=float), r_L, r_R, b,
              derivatives=False)
    return arc.dx, arc.dy, arc.dtheta
