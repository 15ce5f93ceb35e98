"""Clock steps in a log's stamps, found where one stream resumes after a gap: a publisher's
clock set while recording (NTP or chrony stepping it).

A forward step of one stream's clock shows in its stamps as a gap that the other stream
does not have; the samples after it are then offset from the other stream's by the step,
so every segment after it pairs wheel angles and poses of different times (a 0.3 s step of
the encoders' clock half-way through a log moved the wheel radii by 6%, with a clean fit).
A bag's receive times show a step directly (:mod:`excite.logs.bag_stamps`); a CSV log has
only its stamps, so here the step is found from the motion:

1. the gaps of each stream (an interval over :data:`~excite.logs.continuity.GAP_RATIO` median
   periods and over :data:`~excite.logs.timeseries.MIN_CLOCK_STEP`) that the other stream does
   not share;
2. around each, the stretches of the log between it and the gaps next to it, each at least
   :data:`STRETCH` long, their clock offsets estimated apart within the larger of the given
   range and the gap's length (:data:`SEARCH_SHARE`)
   (:func:`excite.logs.time_offset.estimate_time_offset`: the lag at which the wheel rates
   explain the heading rate, precise to a few ms);
3. offsets that differ by more than :data:`~excite.logs.timeseries.MIN_CLOCK_STEP` are a step of
   the stream that has the gap when they differ the way a forward step does, by at most the gap
   less half a period (a step forward opens the gap it is found at): its later stamps are moved
   back by the difference, and a note says where and by how much. Two clocks that drift apart
   step so at every such gap, and are corrected alike.

A stretch whose offset cannot be estimated (too little turning, too short) leaves its gap
unchecked; an offset beyond the search range there is noted, not corrected.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from excite.errors import DataError
from excite.logs.continuity import GAP_RATIO
from excite.logs.time_offset import MAX_TIME_OFFSET, OffsetOutOfRange, estimate_time_offset
from excite.logs.timeseries import MIN_CLOCK_STEP, TimeSeries, during

__all__ = ["SEARCH_SHARE", "STRETCH", "corrected_clock_steps"]

FloatArray = NDArray[np.float64]

#: The shortest stretch (s) whose clock offset is estimated on its own.
STRETCH = 20.0
#: The offsets are searched within the larger of the given range and the gap, at most this
#: share of the shorter stretch (the estimate needs an overlap of 4 times its range).
SEARCH_SHARE = 0.22


def _gaps(t: FloatArray) -> list[int]:
    """Indices i of the intervals t[i] -> t[i + 1] that are gaps (module docstring)."""
    if t.size < 3:
        return []
    d = np.diff(t)
    limit = max(MIN_CLOCK_STEP, GAP_RATIO * float(np.median(d)))
    return [int(i) for i in np.flatnonzero(d > limit)]


def _shared(t_other: FloatArray, start: float, end: float) -> bool:
    """Whether the other stream has no sample within (start, end) either: a pause of the
    recording, not one stream's clock."""
    inside = np.searchsorted(t_other, end, side="left") - np.searchsorted(t_other, start,
                                                                          side="right")
    return inside == 0


def _offset(series: TimeSeries, start: float, end: float, max_offset: float) -> float | None:
    """The clock offset of the log's samples stamped within [start, end] (encoder clock), or
    None when they cannot determine it."""
    try:
        return estimate_time_offset(during(series, start, end), max_offset)
    except OffsetOutOfRange:
        raise
    except DataError:
        return None


def corrected_clock_steps(series: TimeSeries, max_offset: float = MAX_TIME_OFFSET
                          ) -> tuple[TimeSeries, list[str]]:
    """The log with the clock steps found at its gaps corrected, and a note for each step
    (and for a stretch whose offset lies beyond +-``max_offset`` s); see the module
    docstring."""
    notes: list[str] = []
    candidates = sorted(
        [(float(series.t_enc[i]), "encoder", i) for i in _gaps(series.t_enc)
         if not _shared(series.t_pose, series.t_enc[i], series.t_enc[i + 1])]
        + [(float(series.t_pose[i]), "pose", i) for i in _gaps(series.t_pose)
           if not _shared(series.t_enc, series.t_pose[i], series.t_pose[i + 1])])
    if not candidates:
        return series, notes
    bounds = [series.t_enc[0]] + [t for t, _, _ in candidates] + [series.t_enc[-1]]
    for k, (t_gap, stream, i) in enumerate(candidates):
        before, after = (bounds[k], t_gap), (t_gap, bounds[k + 2])
        shortest = min(before[1] - before[0], after[1] - after[0])
        if shortest < STRETCH:
            continue
        t = series.t_enc if stream == "encoder" else series.t_pose
        # a forward step is at most the gap it opens: search that far, as the stretches allow
        search = min(max(max_offset, float(t[i + 1] - t[i]) + MIN_CLOCK_STEP),
                     SEARCH_SHARE * shortest)
        try:
            first = _offset(series, *before, search)
            second = _offset(series, *after, search)
        except OffsetOutOfRange:
            notes.append(f"{series.location(stream, i + 1)}: the clock offset of the log "
                         f"before this gap and after it differ beyond +-{search:.3g} s (a "
                         "clock set while recording?): calibrate each side alone (--end, "
                         "--start)")
            continue
        if first is None or second is None or abs(second - first) <= MIN_CLOCK_STEP:
            continue
        series, note = _corrected(series, stream, i, second - first)
        if note:
            notes.append(note)
    return series, notes


def _corrected(series: TimeSeries, stream: str, i: int, change: float
               ) -> tuple[TimeSeries, str | None]:
    """The log with the stamps of ``stream`` after index i moved so that the clock offset
    (pose time + offset = encoder time) after the gap is what it was before (``change``:
    how much it grew there, s), and the note; unchanged (None) when that would move them
    past the gap's start."""
    t = (series.t_enc if stream == "encoder" else series.t_pose).copy()
    shift = -change if stream == "encoder" else change
    period = float(np.median(np.diff(t)))
    if shift >= 0 or t[i + 1] + shift < t[i] + 0.5 * period:
        return series, None  # a forward step opens the gap it closes, no more
    where = series.location(stream, i + 1)
    t[i + 1:] += shift
    field = "t_enc" if stream == "encoder" else "t_pose"
    moved = dataclasses.replace(series, **{field: t})
    object.__setattr__(moved, "unwrapped_wheels", series.unwrapped_wheels)
    return moved, (f"{where}: the {stream} stamps step by {-shift:+.3f} s at this gap (the "
                   "clock offset of the log after it differs from before it: a clock set "
                   "while recording, e.g. by NTP, or two clocks drifting apart): the later "
                   f"{stream} stamps are corrected by {shift:+.3f} s")
