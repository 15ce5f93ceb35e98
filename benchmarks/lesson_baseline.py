"""The lesson's estimator exactly as written (Chapter2_Lesson5.py): unweighted residuals,
scipy least_squares(method="trf", loss="huber", f_scale=0.01) from (0.05, 0.05, 0.30).

Kept only as the reference the benchmarks compare excite against."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from excite.logs.segments import Segments


def _sinc1(x):
    y = np.empty_like(x)
    small = np.abs(x) < 1e-6
    xs = x[small]
    y[small] = 1.0 - (xs * xs) / 6.0 + (xs**4) / 120.0
    xb = x[~small]
    y[~small] = np.sin(xb) / xb
    return y


def _cosc1(x):
    y = np.empty_like(x)
    small = np.abs(x) < 1e-6
    xs = x[small]
    y[small] = xs / 2.0 - (xs**3) / 24.0 + (xs**5) / 720.0
    xb = x[~small]
    y[~small] = (1.0 - np.cos(xb)) / xb
    return y


def _dsinc1(x):
    y = np.empty_like(x)
    small = np.abs(x) < 1e-5
    xs = x[small]
    y[small] = -(xs) / 3.0 + (xs**3) / 30.0 - (xs**5) / 840.0
    xb = x[~small]
    y[~small] = (xb * np.cos(xb) - np.sin(xb)) / (xb * xb)
    return y


def _dcosc1(x):
    y = np.empty_like(x)
    small = np.abs(x) < 1e-5
    xs = x[small]
    y[small] = 0.5 - (xs * xs) / 8.0 + (xs**4) / 144.0
    xb = x[~small]
    y[~small] = (xb * np.sin(xb) - (1.0 - np.cos(xb))) / (xb * xb)
    return y


def _residuals_and_jacobian(p, seg: Segments):
    rL, rR, b = float(p[0]), float(p[1]), float(p[2])
    sL, sR = rL * seg.dphi_L, rR * seg.dphi_R
    A, B = sR + sL, sR - sL
    ds, dtheta = 0.5 * A, B / b
    f, g, fp, gp = _sinc1(dtheta), _cosc1(dtheta), _dsinc1(dtheta), _dcosc1(dtheta)
    ex = ds * f - seg.dx
    ey = ds * g - seg.dy
    eth = (dtheta - seg.dtheta + np.pi) % (2.0 * np.pi) - np.pi
    ddth = (-seg.dphi_L / b, seg.dphi_R / b, -B / (b * b))
    dds = (0.5 * seg.dphi_L, 0.5 * seg.dphi_R, 0.0)
    n = seg.dphi_L.size
    r = np.empty(3 * n)
    J = np.empty((3 * n, 3))
    r[0::3], r[1::3], r[2::3] = ex, ey, eth
    for i in range(3):
        J[0::3, i] = dds[i] * f + ds * fp * ddth[i]
        J[1::3, i] = dds[i] * g + ds * gp * ddth[i]
        J[2::3, i] = ddth[i]
    return r, J


def lesson_calibrate(seg: Segments, p0=(0.05, 0.05, 0.30)) -> np.ndarray:
    res = least_squares(
        lambda p: _residuals_and_jacobian(p, seg)[0],
        x0=np.asarray(p0, dtype=float),
        jac=lambda p: _residuals_and_jacobian(p, seg)[1],
        method="trf",
        loss="huber",
        f_scale=0.01,
    )
    return res.x.astype(float)
