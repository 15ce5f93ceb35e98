"""The times of a bag stream: its messages' header stamps, checked against the times the
recorder received them.

A bag records two times per message: the header stamp (when the publisher measured it, on
the publisher's clock) and the receive time (when the recorder got it, on the recorder's
clock). excite uses the stamps; the receive times are what it checks them against:

* **Stamps never set.** A stream whose stamps are all zero (the publisher does not set them,
  or a type without a header such as ``geometry_msgs/Pose2D``) is timed by its receive times,
  with a note: they lag the measurement by the transport's latency, a constant part of which
  the clock-offset test finds (:mod:`excite.logs.time_offset`). Zero stamps before the first
  stamped message are skipped (published before the clock ran); a zero stamp after stamped
  ones is an error.
* **Clock steps.** A publisher's clock set while recording (NTP or chrony stepping it, a clock
  that starts wrong and is corrected) makes its stamps jump forward or back while the receive
  times go on as before. The differences of the stamp and receive increments are taken less
  their median (the drift of two clocks that run at different rates, a simulation's against the
  recorder's wall clock). An interval between consecutive messages (receive order) is a step
  when that difference exceeds :data:`~excite.logs.timeseries.MIN_CLOCK_STEP` and 8 robust
  standard deviations of it, the receive increment is an ordinary one (within half that of the
  stream's median: a recorder that stalled, or whose own clock stepped, changes the receive
  increment instead), and the detrended offset stamp - receive time stays shifted after it (the
  medians of :data:`PERSISTENCE` messages each side differ by the step, to half the threshold:
  one late message is no step). Its size is where lines through the offsets on each side (up to
  :data:`SIZE_WINDOW` messages) meet, precise to a fraction of a ms. The stamps after a step are
  shifted back by it, so the stream keeps one clock, and a note says where and by how much.
  Without receive times (CSV logs) steps are found from the motion instead
  (:mod:`excite.logs.clock_steps`).
* **Repeats.** After sorting by stamp, a message repeating the previous one (same stamp, same
  values: recorded twice) is skipped; one stamp with different values is an error.
* **Wheels in separate messages** (a driver per motor): :func:`wheels_together` puts the
  right wheel's angles at the left wheel's stamps, linearly interpolated (exact when both
  are stamped alike; an angle's interpolation error is an eighth of its acceleration times
  the period squared, a thousandth of a radian at 50 Hz), leaving out the stamps where the
  right wheel's stream has a gap (:data:`~excite.logs.continuity.GAP_RATIO` median periods).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from excite.errors import DataError
from excite.logs.continuity import GAP_RATIO
from excite.logs.timeseries import MIN_CLOCK_STEP, sample_at
from excite.stats.robust import MEDIAN_ABS_NORMAL

__all__ = ["PERSISTENCE", "StampedTable", "receive_time_steps", "stamped_table",
           "wheels_together"]

FloatArray = NDArray[np.float64]

#: Messages on each side of a step whose stamp - receive offsets must differ by the step.
PERSISTENCE = 25
#: Messages on each side of a step whose offsets give its size (fewer up to another step).
SIZE_WINDOW = 200
#: A step is this many robust standard deviations of the stamp - receive increments at least.
STEP_SIGMAS = 8.0


@dataclass
class StampedTable:
    """A stream's rows (n, width) in stamp order, the stamp (s) first; the messages skipped
    per reason; and what the user should know (one line each)."""

    rows: FloatArray
    skipped: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def receive_time_steps(stamps: FloatArray, received: FloatArray) -> list[tuple[int, float]]:
    """The steps of ``stamps`` against ``received`` (both s, in receive order, the stamps all
    set): (index of the interval, so between messages i and i + 1; the step, s), in order
    (see the module docstring). Clocks that run at different rates (a simulation's against
    the recorder's wall clock) drift apart by about the same amount at every interval: that
    drift, the median change, is taken out before steps are looked for."""
    n = stamps.size
    if n < 2 * PERSISTENCE:
        return []
    d_stamp, d_received = np.diff(stamps), np.diff(received)
    drift = float(np.median(d_stamp - d_received))
    change = d_stamp - d_received - drift
    spread = MEDIAN_ABS_NORMAL * float(np.median(np.abs(change)))
    threshold = max(MIN_CLOCK_STEP, STEP_SIGMAS * spread)
    usual = float(np.median(d_received))
    offset = stamps - received - drift * np.arange(n)  # detrended
    steps = []
    for i in np.flatnonzero(np.abs(change) > threshold):
        if abs(d_received[i] - usual) > threshold / 2:
            continue  # the receive times moved: a stall, or the recorder's clock
        before = float(np.median(offset[max(0, i + 1 - PERSISTENCE): i + 1]))
        after = float(np.median(offset[i + 1: i + 1 + PERSISTENCE]))
        if abs(after - before - change[i]) <= threshold / 2:
            steps.append(int(i))
    # each step's size: lines through the raw offsets on each side (up to the steps beside
    # it, at most SIZE_WINDOW messages), met at the step
    raw = stamps - received
    bounds = [0, *(i + 1 for i in steps), n]
    sizes = []
    for k, i in enumerate(steps):
        sides = [np.arange(max(bounds[k], i + 1 - SIZE_WINDOW), i + 1),
                 np.arange(i + 1, min(bounds[k + 2], i + 1 + SIZE_WINDOW))]
        at = [np.polyval(np.polyfit(side - i, raw[side], 1), 0.5) if side.size > 2
              else float(np.median(raw[side])) for side in sides]
        sizes.append((i, float(at[1] - at[0])))
    return sizes


def _without_unset(where: str, stamps: FloatArray, received: FloatArray | None
                   ) -> tuple[FloatArray, int, str | None]:
    """(the stamps to use, the leading messages to skip, a note): receive times when no stamp
    is set; DataError for a zero stamp after stamped messages."""
    unset = stamps == 0
    if unset.all():
        if received is None:
            raise DataError(f"{where}: header stamps of zero (the publisher does not set "
                            "them)")
        return received, 0, (f"{where}: no header stamps (zero, or a message type without a "
                             "header): the times the recorder received the messages are used")
    first = int(np.argmax(~unset))
    if unset[first:].any():
        later = first + int(np.argmax(unset[first:]))
        raise DataError(f"{where}: a header stamp of zero (not set) after stamped "
                        f"messages (message {later + 1} of {unset.size}, received after "
                        f"the one stamped {stamps[later - 1]:.6f} s)")
    return stamps, first, None


def stamped_table(where: str, rows: FloatArray, received: FloatArray | None = None
                  ) -> StampedTable:
    """The rows (n, width: the header stamp in s, then the values) of one stream in receive
    order, with its receive times (s; None when there are none), made a table in stamp order
    as the module docstring says; ``where`` names the stream in notes and errors."""
    if rows.size == 0:
        return StampedTable(rows)  # TimeSeries names the stream with too few samples
    table = rows.copy()
    stamps, first, note = _without_unset(where, table[:, 0], received)
    result = StampedTable(table)
    if note is not None:
        result.notes.append(note)
    if first:
        result.skipped["stamped 0 before the first stamped message"] = first
    table = table[first:]
    table[:, 0] = stamps[first:]
    if note is None and received is not None:
        for i, step in receive_time_steps(table[:, 0], received[first:]):
            result.notes.append(
                f"{sample_at(where, table[i, 0])}: the header stamps step by {step:+.3f} s "
                "against the times the recorder received the messages (a clock set while "
                "recording, e.g. by NTP): the stamps after it are corrected by "
                f"{-step:+.3f} s")
            table[i + 1:, 0] -= step
    table = table[np.argsort(table[:, 0], kind="stable")]
    same_stamp = np.flatnonzero(table[1:, 0] == table[:-1, 0])
    equal = np.all((table[same_stamp] == table[same_stamp + 1])
                   | (np.isnan(table[same_stamp]) & np.isnan(table[same_stamp + 1])), axis=1)
    if not equal.all():
        stamp = table[same_stamp[np.argmin(equal)], 0]
        raise DataError(f"{sample_at(where, stamp)}: two messages with this header stamp and "
                        "different values (two publishers, or two bodies, on one topic?)")
    if same_stamp.size:
        result.skipped["repeated (same stamp, same values)"] = int(same_stamp.size)
    result.rows = np.delete(table, same_stamp + 1, axis=0)
    return result


def wheels_together(left: FloatArray, right: FloatArray) -> tuple[FloatArray, int]:
    """The rows (t, phi_L, phi_R) of two wheels' streams (rows (t, angle) each, in stamp
    order) at the left wheel's stamps, the right's angles interpolated (see the module
    docstring), and how many left stamps were left out (outside the right's stream, or in a
    gap of it)."""
    t, t_right = left[:, 0], right[:, 0]
    if t_right.size < 2:
        return np.empty((0, 3)), t.size
    j = np.searchsorted(t_right, t, side="right")
    inside = (j > 0) & (j < t_right.size) | (t == t_right[-1])
    j = np.clip(j, 1, t_right.size - 1)
    period = float(np.median(np.diff(t_right)))
    inside &= t_right[j] - t_right[j - 1] <= GAP_RATIO * period
    angle = np.interp(t[inside], t_right, right[:, 1])
    return np.column_stack([t[inside], left[inside, 1], angle]), int(np.sum(~inside))
