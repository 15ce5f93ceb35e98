"""Wheel speeds that lag the motion: a driver's velocity estimate, low-pass filtered.

A log whose wheel angles are integrated wheel speeds (a driver that reports velocities only:
:func:`excite.logs.timeseries.integrated_speed`) carries the driver's filter. A first-order
low-pass (an exponential moving average) of time constant tau turns the true speed w into
w_f with w = w_f + tau w_f', so the true angle is the integral of w_f plus tau w_f (a constant
aside)::

    phi = Phi + tau omega        (lag_corrected)

At low frequencies the filter is a delay of tau, so the clock offset's detection
(:func:`excite.logs.time_offset.noticeable_time_offset`) finds an offset near +tau (pose time
+ offset = encoder time). A delay keeps the quick changes of the speeds that the filter
smoothed away, though, and the wheel radii then come out large: by 0.9% (5.7 of their std) on
two minutes of smooth random driving through a 0.2 s filter, with the offset found at 0.195 s.

:func:`speed_lag` tells the two apart on the rate signals the offset was found on: the share
of the heading rate's variance (R^2) that the wheel rates explain at the best delay, and with
the lag undone (w + tau w', w' by :func:`excite.logs.time_offset.smoothed_change`) at the
best tau in [0, max_offset], over the same samples; the lag is taken when it explains more.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from excite.errors import DataError
from excite.logs.time_offset import (
    MAX_TIME_OFFSET,
    MIN_CORRELATION,
    explained,
    offset_fit,
    refined_lag,
    smoothed_change,
)
from excite.logs.timeseries import TimeSeries

__all__ = ["lag_corrected", "speed_lag"]

FloatArray = NDArray[np.float64]


def _rate(t: FloatArray, phi: FloatArray) -> FloatArray:
    """The angle's rate (rad/s) at each sample over the interval before it (the first
    sample: the first interval's): the mean of the two speed samples the trapezoidal rule
    integrated there."""
    rate = np.diff(phi) / np.diff(t)
    return np.concatenate([rate[:1], rate])


def lag_corrected(series: TimeSeries, tau: float) -> TimeSeries:
    """``series`` with its wheel angles corrected for a first-order lag of ``tau`` (s):
    phi + tau omega (rad), omega the rate over the interval before each sample (rad/s). For
    an exponential moving average at the samples' rate, y_k = y_(k-1) + a (w_k - y_(k-1)),
    whose lag is tau = (1 - a) / a times the sample period, this undoes it exactly: the
    trapezoidal integral of w is that of y plus tau (y_k + y_(k-1)) / 2."""
    t = series.t_enc
    phi_L, phi_R = (phi + tau * _rate(t, phi) for phi in (series.phi_L, series.phi_R))
    corrected = TimeSeries(t, phi_L, phi_R, series.t_pose, series.x, series.y, series.theta,
                           source=series.source, lines=series.lines,
                           unwrapped_counters=series.unwrapped_counters, speeds=series.speeds)
    object.__setattr__(corrected, "unwrapped_wheels", series.unwrapped_wheels)
    return corrected


def _lag_r2(turn: FloatArray, left: FloatArray, right: FloatArray, step: float,
            taus: FloatArray) -> FloatArray:
    """R^2 of the heading rate ``turn`` fitted by a (w_L + tau w_L') + c (w_R + tau w_R')
    plus a constant, for each tau (s), the rates on a grid of spacing ``step`` (s)."""
    rates = np.column_stack([left, right])
    changes = np.column_stack([smoothed_change(w, step) for w in (left, right)])
    y = turn - turn.mean()
    a, d = rates - rates.mean(axis=0), changes - changes.mean(axis=0)
    aa, ad, dd = a.T @ a, a.T @ d, d.T @ d
    ay, dy = a.T @ y, d.T @ y
    energy = float(y @ y)
    r2 = np.empty(taus.size)
    for k, tau in enumerate(taus):
        gram = aa + tau * (ad + ad.T) + tau * tau * dd
        cross = ay + tau * dy
        r2[k] = float(cross @ np.linalg.solve(gram, cross)) / energy
    return r2


def speed_lag(series: TimeSeries, max_offset: float = MAX_TIME_OFFSET) -> float | None:
    """The time constant tau (s, in (0, max_offset)) of the first-order lag of the wheel
    speeds when it explains the heading rate better than the best clock offset within
    +-max_offset s (module doc); None when it does not, when tau is 0 or at max_offset, or
    when the rates cannot be compared (see :func:`excite.logs.time_offset.offset_fit`)."""
    try:
        fit = offset_fit(series, max_offset, MIN_CORRELATION)
    except DataError:
        return None
    lag, step = fit.max_lag, fit.step
    by_offset = float(np.max(explained(*fit.signals, lag)))
    central = [signal[lag: signal.size - lag] for signal in fit.signals]
    r2 = _lag_r2(*central, step, step * np.arange(lag + 1))
    tau = refined_lag(r2, 0, step)
    if not tau > 0 or not float(np.max(r2)) > by_offset:
        return None
    return tau
