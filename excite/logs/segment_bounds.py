"""Segments no robot drives: a corrupt row, a missing-value sentinel (-9999), a value in other
units by orders of magnitude. Such a row is bad input, an error naming its file and line
(:func:`excite.logs.segments.load_segments`), not data for the calibration: one of them
decides a least-squares fit before any test of gross errors can see it.

The bounds are loose by design, far beyond any robot and any pose source's failure (those are
the calibration's gross errors, :mod:`excite.calibration.gross_errors`), from the limits of
:class:`excite.logs.continuity.Limits` and :mod:`excite.core.plausible`:

* turn: |dtheta| <= MAX_RADIUS_TO_TRACK (|dphi_L| + |dphi_R|) + :data:`TURN_SLACK` (rad): r / b
  is below 1 on any differential drive, and the slack covers a heading wrapped twice and any
  noise;
* travel: |(dx, dy)| <= r_max max(|dphi_L|, |dphi_R|) + d min(turn, 2) + :data:`TRAVEL_SLACK`
  (m): the axle's travel, r_max the largest plausible wheel radius (2 m), and the chord of a
  sensor d = MAX_SENSOR_OFFSET (20 m) from the axle midpoint turned by at most the turn bound
  (rad) without its slack;
* wheels: |dphi| <= ``max_wheel_rate`` (t_end - t_start) with the time columns (where
  t_end > t_start), else |dphi| <= :data:`MAX_WHEEL_TURN` (rad).
"""

from __future__ import annotations

import math

import numpy as np

from excite.core.arrays import FloatArray
from excite.core.kinematics import MAX_RADIUS_TO_TRACK
from excite.core.plausible import MAX_SENSOR_OFFSET, RADIUS_RANGE
from excite.logs.continuity import Limits

__all__ = ["MAX_WHEEL_TURN", "TRAVEL_SLACK", "TURN_SLACK", "first_impossible"]

#: rad: the slack of the turn bound (two turns).
TURN_SLACK = 4.0 * math.pi
#: m: the slack of the travel bound.
TRAVEL_SLACK = 1.0
#: rad: without times, no segment turns a wheel further (about 160,000 revolutions).
MAX_WHEEL_TURN = 1e6

_HINT = "a corrupt row or a missing-value sentinel?"


#: How values in other units are read right, as the hint says it for a segment CSV.
SEGMENT_UNITS = "a unit in the header converts, e.g. dx_gt [mm], dphi_L [deg]"


def first_impossible(dphi_L: FloatArray, dphi_R: FloatArray, dx: FloatArray, dy: FloatArray,
                     dtheta: FloatArray, duration: FloatArray | None = None,
                     units: str = SEGMENT_UNITS, rows: str = "rows"
                     ) -> tuple[int, str] | None:
    """The first segment no robot drives, and why in words; None when every one is plausible.
    Its columns as in a segment CSV (rad, rad, m, m, rad), with each segment's ``duration``
    (s) when known; ``units``: how values in other units are read right, in the hint's words
    (for a CSV, its header units as examples); ``rows``: what the hint calls the segments
    ("rows" of a file).
    Usually settled by a few reductions (:func:`_within_the_slacks`; 0.1 ms for 100k
    segments); the bounds per segment only when some value is beyond the slacks."""
    if dphi_L.size == 0:
        return None
    limits = Limits()
    if _within_the_slacks(dphi_L, dphi_R, dx, dy, dtheta, duration, limits):
        return None
    left, right = np.abs(dphi_L), np.abs(dphi_R)
    most = np.maximum(left, right)
    turn = (left + right) * MAX_RADIUS_TO_TRACK  # the most a robot turns on them
    bad = np.abs(dtheta) > turn + TURN_SLACK
    # the axle's travel, and the chord of a sensor on the farthest mounting (at most 2 x arm)
    travel_bound = most * RADIUS_RANGE[1] + MAX_SENSOR_OFFSET * np.minimum(turn, 2.0)
    travel_bound += TRAVEL_SLACK
    with np.errstate(over="ignore"):  # 1e300 squared is inf, beyond any bound all the same
        bad |= dx * dx + dy * dy > travel_bound * travel_bound
    wheel_bound = _wheel_bounds(duration, limits)
    bad |= most > wheel_bound
    if not bad.any():
        return None
    k = int(np.argmax(bad))
    count = int(bad.sum())
    hint = _HINT if count == 1 else (
        f"{count} of {bad.size} {rows} are: values in other units? (excite reads m and rad; "
        f"{units}), or corrupt rows")
    wheels = f"{dphi_L[k]:.6g} and {dphi_R[k]:.6g} rad"
    bound_k = np.broadcast_to(wheel_bound, most.shape)[k]
    if most[k] > bound_k:  # the left wheel named first when both are beyond
        name, value = ("dphi_L", dphi_L[k]) if left[k] > bound_k else ("dphi_R", dphi_R[k])
        if duration is not None and duration[k] > 0:
            return k, (f"{name} {value:.6g} rad in {duration[k]:.6g} s, faster than any wheel "
                       f"turns ({limits.max_wheel_rate:g} rad/s): {hint}")
        return k, (f"{name} {value:.6g} rad, more than any segment turns a wheel "
                   f"({MAX_WHEEL_TURN:g} rad): {hint}")
    if abs(dtheta[k]) > turn[k] + TURN_SLACK:
        return k, (f"dtheta_gt {dtheta[k]:.6g} rad, more than any robot turns on wheel "
                   f"increments of {wheels} (at most {turn[k] + TURN_SLACK:.3g} rad): {hint}")
    return k, (f"the sensor moved {math.hypot(dx[k], dy[k]):.6g} m (dx_gt {dx[k]:.6g}, dy_gt "
               f"{dy[k]:.6g}), more than any robot moves on wheel increments of {wheels} "
               f"(at most {travel_bound[k]:.3g} m): {hint}")


def _largest(*columns: FloatArray) -> float:
    """The largest magnitude in the columns (reductions only, no temporary arrays)."""
    return max(max(float(c.max()), -float(c.min())) for c in columns)


def _within_the_slacks(dphi_L: FloatArray, dphi_R: FloatArray, dx: FloatArray, dy: FloatArray,
                       dtheta: FloatArray, duration: FloatArray | None, limits: Limits
                       ) -> bool:
    """Whether every segment is within the bounds by their slacks alone (no turn and no
    travel beyond them, every wheel within the slowest segment's bound): the common case,
    settled by a few reductions before any per-segment bound is built."""
    wheel_bound = MAX_WHEEL_TURN if duration is None else float(
        np.min(_wheel_bounds(duration, limits)))
    travel_slack = TRAVEL_SLACK / math.sqrt(2.0)  # whatever the turn
    return (_largest(dphi_L, dphi_R) <= wheel_bound and _largest(dtheta) <= TURN_SLACK
            and _largest(dx, dy) <= travel_slack)


def _wheel_bounds(duration: FloatArray | None, limits: Limits) -> FloatArray | float:
    """The most a wheel turns in each segment (rad): ``limits.max_wheel_rate`` times its
    duration (s), or MAX_WHEEL_TURN where the duration is unknown or not positive (times
    rounded to the same stamp say nothing of the rate)."""
    if duration is None:
        return MAX_WHEEL_TURN
    return np.where(duration > 0, limits.max_wheel_rate * duration, MAX_WHEEL_TURN)
