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
* travel: |(dx, dy)| <= r_max max(|dphi_L|, |dphi_R|) + 2 ``max_sensor_arm`` +
  :data:`TRAVEL_SLACK` (m), r_max the largest plausible wheel radius (2 m);
* wheels: |dphi| <= ``max_wheel_rate`` (t_end - t_start) with the time columns, else
  |dphi| <= :data:`MAX_WHEEL_TURN` (rad).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from excite.core.kinematics import MAX_RADIUS_TO_TRACK
from excite.core.plausible import RADIUS_RANGE
from excite.logs.continuity import Limits

__all__ = ["MAX_WHEEL_TURN", "TRAVEL_SLACK", "TURN_SLACK", "UNITS_SHARE", "first_impossible"]

#: rad: the slack of the turn bound (two turns).
TURN_SLACK = 4.0 * math.pi
#: m: the slack of the travel bound.
TRAVEL_SLACK = 1.0
#: rad: without times, no segment turns a wheel further (about 160,000 revolutions).
MAX_WHEEL_TURN = 1e6

_HINT = "a corrupt row or a missing-value sentinel?"
#: More than this share of the rows beyond the bounds is no corrupt row: other units.
UNITS_SHARE = 0.5


def first_impossible(rows: NDArray[np.float64]) -> tuple[int, str] | None:
    """The first of the segment rows (N, 5) in CSV column order, or (N, 7) with t_start, t_end
    (s), that no robot drives, and why in words; None when every row is plausible."""
    if rows.shape[0] == 0:
        return None
    limits = Limits()
    dphi = np.abs(rows[:, :2])
    turn_bound = MAX_RADIUS_TO_TRACK * dphi.sum(axis=1) + TURN_SLACK
    travel = np.hypot(rows[:, 2], rows[:, 3])
    travel_bound = (RADIUS_RANGE[1] * dphi.max(axis=1) + 2.0 * limits.max_sensor_arm
                    + TRAVEL_SLACK)
    timed = rows.shape[1] >= 7
    duration = rows[:, 6] - rows[:, 5] if timed else None
    wheel_bound = (limits.max_wheel_rate * np.abs(duration) if timed
                   else np.full(rows.shape[0], MAX_WHEEL_TURN))
    bad = ((dphi > wheel_bound[:, None]).any(axis=1) | (np.abs(rows[:, 4]) > turn_bound)
           | (travel > travel_bound))
    if not bad.any():
        return None
    k = int(np.argmax(bad))
    if bad.mean() > UNITS_SHARE:
        hint = (f"{int(bad.sum())} of {bad.size} rows are: values in other units? (excite "
                "reads m and rad; a unit in the header converts, e.g. dx_gt [mm], dphi_L "
                "[deg])")
    else:
        hint = _HINT
    wheels = f"{rows[k, 0]:.6g} and {rows[k, 1]:.6g} rad"
    for i, name in enumerate(("dphi_L", "dphi_R")):
        if dphi[k, i] > wheel_bound[k]:
            if timed:
                return k, (f"{name} {rows[k, i]:.6g} rad in {duration[k]:.6g} s, faster than "
                           f"any wheel turns ({limits.max_wheel_rate:g} rad/s): {hint}")
            return k, (f"{name} {rows[k, i]:.6g} rad, more than any segment turns a wheel "
                       f"({MAX_WHEEL_TURN:g} rad): {hint}")
    if abs(rows[k, 4]) > turn_bound[k]:
        return k, (f"dtheta_gt {rows[k, 4]:.6g} rad, more than any robot turns on wheel "
                   f"increments of {wheels} (at most {turn_bound[k]:.3g} rad): {hint}")
    return k, (f"the sensor moved {travel[k]:.6g} m (dx_gt {rows[k, 2]:.6g}, dy_gt "
               f"{rows[k, 3]:.6g}), more than any robot moves on wheel increments of {wheels} "
               f"(at most {travel_bound[k]:.3g} m): {hint}")
