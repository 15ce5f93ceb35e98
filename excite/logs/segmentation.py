"""Cutting a time-series log into the segments the calibrator takes
(:func:`segment_timeseries`), with an account of what was kept and dropped and why
(:class:`SegmentationReport`).

Synchronisation (one choice, everywhere)
----------------------------------------
Segment boundaries are pose samples, and poses are never interpolated: a segment's measured
increment is the difference of two measured poses, so consecutive segments share exactly one
pose sample (``SegmentedLog.shares_endpoints``) and nothing else. The encoder angles are
interpolated at the boundary times (encoders are usually denser and far less noisy than
poses) along the wheels' path between samples (:mod:`excite.logs.wheel_path`): a monotone
cubic, or for slow encoders whose log's heading says so, straight lines (one arc per encoder
period).

Segmentation
------------
* Fixed windows (``window`` s): a boundary at the first pose sample at or after
  t_0 + k window (k = 0, 1, ...) in each stretch of the log without gaps, so a segment lasts
  the window to within one pose period. When the encoders are the coarser stream (a median
  period over COARSER times the poses'), at the pose sample nearest the encoder sample
  nearest t_0 + k window instead: the interpolated wheel angles are then read within half a
  pose period of an encoder sample, where the cubic errs least (a robot whose speed changes
  at the boundaries: a protocol's command steps, ``excite live``'s segments).
* Keyframes by motion (``min_distance`` m and/or ``min_angle`` rad): a new boundary at the first
  pose sample where the sensor is at least ``min_distance`` from the last keyframe's position,
  or its heading differs from the keyframe's by at least ``min_angle``.

A segment holds dphi_L, dphi_R (encoder increments, rad) and the sensor's pose increment in its
own frame at the segment start: (dx, dy) = R(-theta_start) (p_end - p_start) (m),
dtheta = theta_end - theta_start (rad, continuous).

Detection, never silent averaging (all of it in :class:`SegmentationReport`)
-----------------------------------------------------------------------------
* Gaps, dropouts and jumps of either stream (:mod:`excite.logs.continuity`). Every gap splits
  the log and no segment spans it (``on_gap="split"``, the default, as the command line's);
  with ``on_gap="error"`` a gap longer than the window is an error naming the file and line
  (or time) where the stream resumes. Segments containing a jump are dropped; a few pose
  samples off the track (a jump out and a jump back, the track continuous across them) are
  left out instead, so that the segments around them stay
  (:func:`~excite.logs.continuity.excursions`).
* Segments in which neither wheel turned more than ``Limits.still_wheel`` are, by how far the
  sensor moved and turned, one of three (see :class:`~excite.logs.continuity.Limits`):
  - standstills: the sensor stayed within the still limits (``Limits.still_distance``,
    ``Limits.still_heading``) or within the pose noise (``Limits.carry_sigmas``; the noise is
    estimated from the pose stream itself); dropped (they carry noise, no information about
    r_L, r_R, b);
  - carried: the sensor moved or turned beyond both, and beyond what the wheels' small turns
    could have made any plausible robot do: it was carried or pushed, or the pose source
    relocalised; dropped;
  - otherwise a slow motion (a big-wheeled robot spinning slowly), kept.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from excite.core import se2
from excite.errors import DataError
from excite.logs.continuity import (
    ENCODER_JUMP_HINT,
    POSE_JUMP_HINT,
    Gap,
    Limits,
    StreamCheck,
    check_encoders,
    check_poses,
    find_gaps,
    flagged_overlaps,
    left_on_track,
    pose_noise,
    refuse_long_gaps,
)
from excite.logs.segments import MIN_SEGMENTS, Segments
from excite.logs.timeseries import TimeSeries, unwrapped_words
from excite.logs.wheel_path import MAX_SUBSTEP, WheelPath, path_between_samples, wheel_angles

__all__ = ["SegmentationReport", "SegmentedLog", "segment_timeseries", "POSE_JUMP",
           "ENCODER_JUMP", "STANDSTILL", "CARRIED", "CUT_BY_GAP", "END_OF_LOG",
           "OUTSIDE_ENCODERS", "INSIDE_ENCODER_GAP", "OFF_TRACK"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

# Drop reasons (SegmentationReport keys).
POSE_JUMP, ENCODER_JUMP, STANDSTILL = "pose jump", "encoder jump", "standstill"
CARRIED = "pose moved while the wheels stood still"
CUT_BY_GAP, END_OF_LOG = "cut by a gap", "end of log"
OUTSIDE_ENCODERS, INSIDE_ENCODER_GAP = "outside the encoder time range", "inside an encoder gap"
OFF_TRACK = ("off the track (out and back beyond the jump limits: a marker swap or a bad "
             "match), left out")
#: The most sub-steps per segment (_substeps); sub-steps are one encoder period long up to this.
#: One arc per encoder period is dead reckoning at the encoder rate: coarser sub-steps (50 ms)
#: left a systematic model error of ~1e-5 m per 1 s segment on curving paths, which biased the
#: wheel radii by 1.7 standard deviations at 0.5 mm pose noise (benchmarks/bench_logs.py).
MAX_SUBSTEPS = 256
#: Fixed windows end near encoder samples when the encoders' median period is over this many
#: times the poses' (module docstring).
COARSER = 1.5


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def _ranges_text(ranges: Sequence[tuple[float, float]], shown: int = 3) -> str:
    text = ", ".join(f"{a:.3f}-{b:.3f} s" for a, b in ranges[:shown])
    return text + (f" and {len(ranges) - shown} more" if len(ranges) > shown else "")


@dataclass(frozen=True)
class SegmentationReport:
    """What segmentation kept and dropped, and why.

    n_segments: segments kept. segments_dropped: count per reason (pose jump, encoder jump,
    standstill, cut by a gap, end of log: the unfinished window or keyframe at the end of a
    stretch). dropped_ranges: the time ranges of those segments per reason (s, encoder clock,
    adjacent ones merged). samples_dropped: pose samples unused, per reason (outside the
    encoder time range, inside an encoder gap, off the track). gaps: every gap, in time
    order. dropouts: missed samples per stream, bridged. unwrapped_wheels: the wheel columns
    that were wrapped modulo 2 pi and were unwrapped (TimeSeries.unwrapped_wheels).
    wheel_path: how the wheels turned between encoder samples, as the segments read them
    (:mod:`excite.logs.wheel_path`: "cubic", or "arcs" for a log of slow encoders whose
    heading follows straight wheel angles clearly better).
    """

    n_segments: int
    segments_dropped: dict[str, int] = field(default_factory=dict)
    dropped_ranges: dict[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)
    samples_dropped: dict[str, int] = field(default_factory=dict)
    gaps: tuple[Gap, ...] = ()
    dropouts: dict[str, int] = field(default_factory=dict)
    unwrapped_wheels: tuple[str, ...] = ()
    unwrapped_counters: tuple[str, ...] = ()
    wheel_path: WheelPath = "cubic"

    def unwrapped_text(self) -> str:
        """'phi_L, phi_R wrapped modulo 2 pi, unwrapped' and/or 'ticks_L (16-bit counter)
        overflowed, unwrapped' ('' when nothing was wrapped)."""
        return unwrapped_words(self.unwrapped_wheels, self.unwrapped_counters)

    def counts_text(self) -> str:
        """What was dropped, in one line, e.g. '3 standstill, 1 pose jump; 25 pose samples
        outside the encoder time range' ('nothing' when nothing was)."""
        segments = ", ".join(f"{n} {reason}" for reason, n in self.segments_dropped.items() if n)
        samples = ", ".join(f"{_plural(n, 'pose sample')} {reason}"
                            for reason, n in self.samples_dropped.items() if n)
        return "; ".join(part for part in (segments, samples) if part) or "nothing"

    def summary(self) -> str:
        """The report in words, one fact per line."""
        lines = [f"{_plural(self.n_segments, 'segment')} kept."]
        if self.wheel_path == "arcs":
            lines.append("Wheel speeds constant between encoder samples (one arc per encoder "
                         "period: the heading follows that clearly better than a smooth "
                         "curve).")
        if self.unwrapped_text():
            lines.append(f"Wheel angles {self.unwrapped_text()}.")
        dropped = sum(self.segments_dropped.values())
        if dropped:
            lines.append(f"{_plural(dropped, 'segment')} dropped:")
            lines += [f"  {n} {reason} (t = {_ranges_text(self.dropped_ranges[reason])})"
                      for reason, n in self.segments_dropped.items() if n]
        lines += [f"{_plural(n, 'pose sample')} unused: {reason}."
                  for reason, n in self.samples_dropped.items() if n]
        for gap in self.gaps:
            lines.append(f"Gap of {gap.duration:.3f} s in the {gap.stream} stream "
                         f"({gap.t_start:.3f}-{gap.t_end:.3f} s; next sample: {gap.location}); "
                         "no segment spans it.")
        lines += [f"{_plural(n, f'{stream} sample')} missed (dropouts, bridged)."
                  for stream, n in self.dropouts.items() if n]
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class SegmentedLog:
    """Segments cut from a time-series log.

    segments: the segments (excite.logs.segments.Segments). t_start, t_end: each segment's time span
    (s, encoder clock). shares_endpoints[k]: segment k starts at the pose sample where segment
    k - 1 ended, so their measured increments share that sample's noise (negatively
    correlated); False for the first segment and after a gap or a dropped segment.
    report: what was dropped and why.
    """

    segments: Segments
    t_start: FloatArray
    t_end: FloatArray
    shares_endpoints: BoolArray
    report: SegmentationReport


@dataclass(frozen=True)
class _Stretches:
    """Stretches of consecutive usable pose samples: [first[k], last[k]] (inclusive)."""

    first: IntArray
    last: IntArray
    outside: int
    in_gap: int


def _stretches(t_enc: FloatArray, t_pose: FloatArray, encoders: StreamCheck,
               poses: StreamCheck) -> _Stretches:
    """Split the pose samples (t_pose on the encoder clock) where no segment may span: pose
    gaps, encoder gaps, samples outside the encoder time range or inside an encoder gap."""
    inside = (t_pose >= t_enc[0]) & (t_pose <= t_enc[-1])
    in_gap = inside & (flagged_overlaps(t_enc, encoders.gap, t_pose, t_pose) > 0)
    usable = inside & ~in_gap
    link = (usable[:-1] & usable[1:] & ~poses.gap
            & (flagged_overlaps(t_enc, encoders.gap, t_pose[:-1], t_pose[1:]) == 0))
    edges = np.diff(np.concatenate(([0], link.astype(np.int8), [0])))
    return _Stretches(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1),
                      int((~inside).sum()), int(in_gap.sum()))


def _window_boundaries(t: FloatArray, first: int, last: int, window: float,
                       t_enc: FloatArray | None = None) -> IntArray:
    """Boundary samples of one stretch: the first sample at or after t[first] + k window;
    with ``t_enc`` (the encoder times, when they are the coarser stream), the sample nearest
    the encoder sample nearest that time (module docstring)."""
    tolerance = 1e-6 * window
    n = int(math.floor((t[last] - t[first] + tolerance) / window))
    grid = t[first] + window * np.arange(n + 1)
    part = t[first:last + 1]
    if t_enc is None:
        index = first + np.searchsorted(part, grid - tolerance, side="left")
    else:
        index = first + _nearest(part, t_enc[_nearest(t_enc, grid)])
        index[0] = first  # the stretch starts where it starts
    return index[np.concatenate(([True], np.diff(index) > 0))]


def _nearest(t: FloatArray, times: FloatArray) -> IntArray:
    """Index of the sample of the increasing ``t`` nearest each of ``times``."""
    right = np.clip(np.searchsorted(t, times), 1, t.size - 1)
    return right - (times - t[right - 1] < t[right] - times)


def _next_keyframe(x: FloatArray, y: FloatArray, theta: FloatArray, key: int, last: int,
                   min_distance: float, min_angle: float, block: int) -> int | None:
    """First sample after ``key`` (up to ``last``) at least min_distance (m) from it or
    turned at least min_angle (rad) from it; searched in growing blocks."""
    start = key + 1
    while start <= last:
        stop = min(last + 1, start + block)
        far = np.hypot(x[start:stop] - x[key], y[start:stop] - y[key]) >= min_distance
        turned = np.abs(theta[start:stop] - theta[key]) >= min_angle
        hit = np.flatnonzero(far | turned)
        if hit.size:
            return start + int(hit[0])
        start, block = stop, 2 * block
    return None


def _keyframe_boundaries(ts: TimeSeries, first: int, last: int, min_distance: float,
                         min_angle: float) -> IntArray:
    """Keyframe samples of one stretch (see the module docstring)."""
    keys, block = [first], 16
    while (key := _next_keyframe(ts.x, ts.y, ts.theta, keys[-1], last, min_distance,
                                 min_angle, block)) is not None:
        block = max(16, 2 * (key - keys[-1]))
        keys.append(key)
    return np.asarray(keys, dtype=np.int64)


@dataclass(frozen=True)
class _Cut:
    """Candidate segments (pose sample indices) and the unfinished tails of the stretches."""

    start: IntArray
    end: IntArray
    tails: dict[str, list[tuple[int, int]]]


def _cut(ts: TimeSeries, t_pose: FloatArray, stretches: _Stretches, window: float,
         min_distance: float | None, min_angle: float | None) -> _Cut:
    """Boundaries in every stretch, by fixed windows or by keyframes."""
    starts, ends = [], []
    tails: dict[str, list[tuple[int, int]]] = {CUT_BY_GAP: [], END_OF_LOG: []}
    keyframes = min_distance is not None or min_angle is not None
    coarse = (ts.t_enc if np.median(np.diff(ts.t_enc)) > COARSER * np.median(np.diff(t_pose))
              else None)
    for k, (first, last) in enumerate(zip(stretches.first, stretches.last, strict=True)):
        if keyframes:
            bounds = _keyframe_boundaries(ts, int(first), int(last), min_distance or math.inf,
                                          min_angle or math.inf)
        else:
            bounds = _window_boundaries(t_pose, int(first), int(last), window, coarse)
        starts.append(bounds[:-1])
        ends.append(bounds[1:])
        if bounds[-1] < last:
            reason = END_OF_LOG if k == stretches.first.size - 1 else CUT_BY_GAP
            tails[reason].append((int(bounds[-1]), int(last)))
    empty = np.zeros(0, dtype=np.int64)
    return _Cut(np.concatenate([empty, *starts]), np.concatenate([empty, *ends]), tails)


def _increments(ts: TimeSeries, wheels: Callable[[FloatArray], FloatArray],
                t_pose: FloatArray, start: IntArray, end: IntArray) -> FloatArray:
    """(N, 5) segments: encoder increments interpolated at the boundary times (rad) and the
    sensor's pose increment in its frame at the start (m, m, rad)."""
    dphi = wheels(t_pose[end]) - wheels(t_pose[start])
    poses = np.column_stack([ts.x, ts.y, ts.theta])
    return np.column_stack([dphi, se2.between(poses[start], poses[end])])


def _substeps(ts: TimeSeries, wheels: Callable[[FloatArray], FloatArray], t_a: FloatArray,
              t_b: FloatArray, path: WheelPath) -> tuple[FloatArray, FloatArray, IntArray]:
    """Each segment's encoder sub-increments (N, K) over its own count (N,) of equal
    sub-intervals of [t_a, t_b] (s, encoder clock), zero-padded to the largest: sub-intervals
    of about the (median) encoder period, or MAX_SUBSTEP when the encoders are slower and
    ``path`` is "cubic" (the angles between samples from the cubic interpolant;
    :mod:`excite.logs.wheel_path`), at most MAX_SUBSTEPS. They sum to the
    segment's increments exactly."""
    period = float(np.median(np.diff(ts.t_enc)))
    if path == "cubic":
        period = min(period, MAX_SUBSTEP)
    duration = t_b - t_a
    count = np.clip(np.ceil(duration / period - 1e-9), 1, MAX_SUBSTEPS)
    count = count.astype(np.int64)
    j = np.arange(int(count.max()) + 1)
    times = t_a[:, None] + duration[:, None] * np.minimum(j / count[:, None], 1.0)
    times[j[None, :] >= count[:, None]] = np.repeat(t_b, j.size - count)  # exactly t_b
    sub = np.diff(wheels(times), axis=1)
    return sub[..., 0], sub[..., 1], count


def _drop_reasons(ts: TimeSeries, t_pose: FloatArray, cut: _Cut, rows: FloatArray,
                  encoders: StreamCheck, poses: StreamCheck, limits: Limits,
                  noise: tuple[float, float]) -> dict[str, BoolArray]:
    """Per reason, which candidate segments to drop (a segment counts under its first
    reason only)."""
    pose_jumps = np.concatenate(([0], np.cumsum(poses.jump)))
    wheel = np.abs(rows[:, :2])
    wheels_still = wheel.max(axis=1, initial=0.0) <= limits.still_wheel
    moved, turned = np.hypot(rows[:, 2], rows[:, 3]), np.abs(rows[:, 4])
    # still: within the still limits or the noise (a difference of two poses has sqrt(2) times
    # a sample's noise)
    near = max(limits.still_distance, limits.carry_sigmas * math.sqrt(2.0) * noise[0])
    near_heading = max(limits.still_heading, limits.carry_sigmas * math.sqrt(2.0) * noise[1])
    # carried: beyond that plus what the wheels' small turns could do to any plausible robot
    could_turn = limits.max_radius_to_track * wheel.sum(axis=1)
    could_move = limits.max_wheel_radius * wheel.max(axis=1, initial=0.0) + (
        limits.max_sensor_arm * could_turn)
    reasons = {
        POSE_JUMP: pose_jumps[cut.end] > pose_jumps[cut.start],
        ENCODER_JUMP: flagged_overlaps(ts.t_enc, encoders.jump, t_pose[cut.start],
                                       t_pose[cut.end]) > 0,
        STANDSTILL: wheels_still & (moved <= near) & (turned <= near_heading),
        CARRIED: wheels_still & ((moved > near + could_move)
                                 | (turned > near_heading + could_turn)),
    }
    taken = np.zeros(cut.start.size, dtype=bool)
    for reason, mask in reasons.items():
        reasons[reason] = mask & ~taken
        taken |= mask
    return reasons


def _merged(ranges: list[tuple[float, float]]) -> tuple[tuple[float, float], ...]:
    """Sorted ranges with touching ones joined."""
    merged: list[tuple[float, float]] = []
    for a, b in sorted(ranges):
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(b, merged[-1][1]))
        else:
            merged.append((a, b))
    return tuple(merged)


def _report(t_pose: FloatArray, cut: _Cut, reasons: dict[str, BoolArray], kept: int,
            stretches: _Stretches, gaps: list[Gap], encoders: StreamCheck,
            poses: StreamCheck, ts: TimeSeries, off_track: int, path: WheelPath
            ) -> SegmentationReport:
    """What was kept and dropped, and why (dropped ranges on the encoder clock;
    ``off_track``: the pose samples left out as off the track; ``path``: the wheels' path
    between encoder samples)."""
    ranges = {reason: [(t_pose[a], t_pose[b]) for a, b in zip(cut.start[mask], cut.end[mask],
                                                              strict=True)]
              for reason, mask in reasons.items()}
    ranges |= {reason: [(t_pose[a], t_pose[b]) for a, b in tails]
               for reason, tails in cut.tails.items()}
    return SegmentationReport(
        n_segments=kept,
        segments_dropped={reason: len(r) for reason, r in ranges.items()},
        dropped_ranges={reason: _merged([(float(a), float(b)) for a, b in r])
                        for reason, r in ranges.items()},
        samples_dropped={OUTSIDE_ENCODERS: stretches.outside,
                         INSIDE_ENCODER_GAP: stretches.in_gap, OFF_TRACK: off_track},
        gaps=tuple(gaps),
        dropouts={"encoder": encoders.dropouts, "pose": poses.dropouts},
        unwrapped_wheels=ts.unwrapped_wheels,
        unwrapped_counters=ts.unwrapped_counters,
        wheel_path=path,
    )


#: s: a median sample period this long suggests times in other units than seconds (no pose
#: source for calibration is that slow).
SLOWEST_PERIOD = 5.0


def _check_settings(ts: TimeSeries, window: float, min_distance: float | None,
                    min_angle: float | None, time_offset: float, on_gap: str) -> None:
    """DataError for a setting of :func:`segment_timeseries` that is out of range, or a window
    shorter than the pose sample period."""
    if not 0 < window < math.inf:
        raise DataError(f"window must be positive and finite (s), got {window}")
    for name, value in (("min_distance", min_distance), ("min_angle", min_angle)):
        if value is not None and not 0 < value < math.inf:
            raise DataError(f"{name} must be positive and finite, got {value}")
    if not math.isfinite(time_offset):
        raise DataError(f"time_offset must be finite (s), got {time_offset}")
    if on_gap not in ("error", "split"):
        raise DataError(f"on_gap must be 'error' or 'split', got {on_gap!r}")
    period = float(np.median(np.diff(ts.t_pose)))
    if window < period:
        units = (" (times are in s: are these ms, us or ns?)" if period >= SLOWEST_PERIOD
                 else "")
        raise DataError(f"{ts.source[1]}: the window ({window:g} s) is shorter than the pose "
                        f"sample period ({period:.3g} s){units}")


def _refuse_too_few_segments(ts: TimeSeries, t_pose: FloatArray, report: SegmentationReport
                             ) -> None:
    """DataError when fewer than MIN_SEGMENTS segments are kept, naming the stream behind most
    of the drops (encoder jumps and standstills: the wheels) and what may cause them, or
    that the streams' stamps (the poses' ``t_pose`` with the clock offset) do not overlap."""
    if report.n_segments >= MIN_SEGMENTS:
        return
    dropped = {reason: n for reason, n in report.segments_dropped.items() if n}
    worst = max(dropped, key=dropped.get, default=None)
    stream = ts.source[0] if worst in (ENCODER_JUMP, STANDSTILL) else ts.source[1]
    hint = {ENCODER_JUMP: f"; {ENCODER_JUMP_HINT}",
            POSE_JUMP: f"; {POSE_JUMP_HINT}"}.get(worst, "")
    if t_pose[0] > ts.t_enc[-1] or t_pose[-1] < ts.t_enc[0]:
        hint = (f"; the streams' stamps do not overlap (encoders {ts.t_enc[0]:.9g} to "
                f"{ts.t_enc[-1]:.9g} s, poses {t_pose[0]:.9g} to {t_pose[-1]:.9g} s with the "
                "clock offset): stamps on different clocks, e.g. time since start and epoch "
                "time? --time-offset S")
    raise DataError(f"{stream}: {report.n_segments} segment(s) after segmentation; "
                    f"at least {MIN_SEGMENTS} are needed (dropped: {report.counts_text()})"
                    f"{hint}")


def _segmented_log(ts: TimeSeries, wheels: Callable[[FloatArray], FloatArray],
                   path: WheelPath, t_pose: FloatArray, start: IntArray, end: IntArray,
                   rows: FloatArray, report: SegmentationReport) -> SegmentedLog:
    """The kept segments (boundary samples ``start``, ``end``; their ``rows`` of
    :func:`_increments`) with their time spans, chaining and sub-steps along ``path``."""
    t_start, t_end = t_pose[start], t_pose[end]
    shares = np.concatenate(([False], start[1:] == end[:-1]))
    sub_L, sub_R, count = _substeps(ts, wheels, t_start, t_end, path)
    segments = Segments(*rows.T, t_start=t_start, t_end=t_end, chained=shares,
                        sub_dphi_L=sub_L, sub_dphi_R=sub_R, sub_count=count)
    return SegmentedLog(segments=segments, t_start=t_start, t_end=t_end,
                        shares_endpoints=shares, report=report)


def segment_timeseries(
    ts: TimeSeries,
    window: float = 1.0,
    min_distance: float | None = None,
    min_angle: float | None = None,
    time_offset: float = 0.0,
    *,
    on_gap: Literal["error", "split"] = "split",
    limits: Limits | None = None,
) -> SegmentedLog:
    """Cut a time-series log into segments (see the module docstring for the method).

    window (s): segment duration in fixed-window mode; in both modes a gap longer than it is
    an error when on_gap="error". min_distance (m), min_angle (rad): keyframe mode when either
    is given. time_offset (s): pose time + time_offset = encoder time. on_gap: "error" raises
    for a gap longer than the window, naming the file and line (or time) where the stream
    resumes; "split" cuts the log there. limits: the detection thresholds (default Limits()).

    Raises DataError for bad settings, a gap (with on_gap="error"), or fewer than 3 segments
    left.
    """
    _check_settings(ts, window, min_distance, min_angle, time_offset, on_gap)
    limits = limits or Limits()
    noise = pose_noise(ts)
    encoders, poses = (check_encoders(ts, window, limits),
                       check_poses(ts, window, limits, noise))
    ts, poses, off_track = left_on_track(ts, poses, limits, noise)
    gaps = find_gaps(ts, encoders, poses)
    if on_gap == "error":
        refuse_long_gaps(gaps, window)
    t_pose = ts.t_pose + time_offset
    stretches = _stretches(ts.t_enc, t_pose, encoders, poses)
    cut = _cut(ts, t_pose, stretches, window, min_distance, min_angle)
    path = path_between_samples(ts, time_offset)
    wheels = wheel_angles(ts, path)
    rows = _increments(ts, wheels, t_pose, cut.start, cut.end)
    reasons = _drop_reasons(ts, t_pose, cut, rows, encoders, poses, limits, noise)
    keep = ~np.logical_or.reduce(list(reasons.values()))
    report = _report(t_pose, cut, reasons, int(keep.sum()), stretches, gaps, encoders, poses,
                     ts, off_track, path)
    _refuse_too_few_segments(ts, t_pose, report)
    return _segmented_log(ts, wheels, path, t_pose, cut.start[keep], cut.end[keep], rows[keep],
                          report)
