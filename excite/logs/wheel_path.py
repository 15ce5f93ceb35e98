"""How the wheels turned between encoder samples: the wheel angles at any time, which the
segments' boundaries and sub-steps are read from (:mod:`excite.logs.segmentation`).

Two readings of the path between samples:

* ``"cubic"``: a monotone cubic (PCHIP, Fritsch-Carlson) through the samples. On a smoothly
  accelerating wheel it errs by O(h^3) of the encoder period h, where a straight line errs by
  max|phi''| h^2 / 8; it never leaves the range of the two samples around (no overshoot at a
  standstill or a command step) and is exact at the samples.
* ``"arcs"``: the angles straight between samples, the wheel speeds constant within each
  encoder period (each period one arc): a robot driven by commands held over intervals, whose
  speeds settle within a period. Through the cubic, such a log's speed steps bend the path
  within the period after each step the same way every time, a bias of the wheels that the
  fit does not see (BENCHMARKS.md, "Logs as real exports differ").

With encoders at least 1 / MAX_SUBSTEP fast (50 Hz) the two differ by less than the noise and
the cubic is used. With slower ones the log decides (:func:`path_between_samples`): the
reading whose wheel rates explain the heading rate of the poses better (the share of its
variance a fit a phi_L' + c phi_R' leaves, as the clock offset's estimate does,
:func:`excite.logs.time_offset.explained`), arcs only when they leave at most ARCS_SHARE of
what the cubic leaves.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from excite.errors import DataError
from excite.logs.time_offset import explained
from excite.logs.timeseries import TimeSeries

__all__ = ["ARCS_SHARE", "MAX_SUBSTEP", "WheelPath", "path_between_samples", "wheel_angles"]

FloatArray = NDArray[np.float64]
WheelPath = Literal["cubic", "arcs"]

#: s, the longest sub-step of a segment (:mod:`excite.logs.segmentation`): slower encoders get
#: several sub-steps per period along the cubic (one arc per 40 ms period biased b by 0.65
#: standard errors on smooth driving, per 80 ms by 2.6; 20 ms sub-steps left no bias at
#: 12.5 Hz, synthetic logs of 100 Hz poses of 1 mm / 2 mrad), unless the log reads "arcs".
MAX_SUBSTEP = 0.02
#: Arcs are read when the straight angles' wheel rates leave at most this share of the heading
#: rate's unexplained variance that the cubic's leave: clear of smooth driving, where the
#: share is about 1 or more at every encoder rate, and of held commands, where it is a few
#: tenths (the ranges measured: BENCHMARKS.md, "Logs as real exports differ").
ARCS_SHARE = 0.9


def wheel_angles(ts: TimeSeries, path: WheelPath = "cubic"
                 ) -> Callable[[FloatArray], FloatArray]:
    """The wheels' cumulative angles (rad) at any times (s, encoder clock, within the stream;
    NaN outside), (..., 2) for (phi_L, phi_R), along ``path`` (module docstring)."""
    if path == "arcs":
        def straight(t: FloatArray) -> FloatArray:
            return np.stack([np.interp(t, ts.t_enc, phi, left=np.nan, right=np.nan)
                             for phi in (ts.phi_L, ts.phi_R)], axis=-1)
        return straight
    from scipy.interpolate import PchipInterpolator

    return PchipInterpolator(ts.t_enc, np.column_stack([ts.phi_L, ts.phi_R]),
                             extrapolate=False)


def path_between_samples(ts: TimeSeries, time_offset: float = 0.0) -> WheelPath:
    """"cubic" or "arcs" for the log ``ts`` (pose time + time_offset = encoder time), as the
    module docstring says: "cubic" for encoders at least 1 / MAX_SUBSTEP fast, or when the
    heading or the wheel speeds do not vary."""
    if float(np.median(np.diff(ts.t_enc))) <= MAX_SUBSTEP:
        return "cubic"
    t_pose = ts.t_pose + time_offset
    step = float(np.median(np.diff(t_pose)))
    start, stop = max(ts.t_enc[0], t_pose[0]), min(ts.t_enc[-1], t_pose[-1])
    if not stop - start > 4 * step:
        return "cubic"
    grid = start + step * np.arange(int((stop - start) / step) + 1)
    turn = np.gradient(np.interp(grid, t_pose, ts.theta), step)
    unexplained = {}
    for path in ("cubic", "arcs"):
        angles = wheel_angles(ts, path)(grid)
        left, right = (np.gradient(angles[:, k], step) for k in (0, 1))
        try:
            unexplained[path] = 1.0 - float(explained(turn, left, right, 0)[0])
        except DataError:  # the heading or the wheel speeds do not vary
            return "cubic"
    return "arcs" if unexplained["arcs"] <= ARCS_SHARE * unexplained["cubic"] else "cubic"
