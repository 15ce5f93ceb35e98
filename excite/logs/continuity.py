"""What is wrong with a log's streams, found before it is cut or followed: gaps, dropouts
and jumps, with the thresholds of all detection in segmentation (:class:`Limits`).

* Gaps: a stream without a sample for longer than the window, or than ``Limits.max_gap``
  (default 3x the stream's median period); no segment spans one.
* Dropouts: missed samples (an interval over 1.5 median periods but not a gap); bridged and
  counted.
* Jumps: consecutive pose samples implying a speed over ``Limits.max_speed`` (m/s) or a turn
  rate over ``Limits.max_turn_rate`` (rad/s), or consecutive encoder samples implying a wheel
  rate over ``Limits.max_wheel_rate`` (rad/s, e.g. a counter reset); segmentation drops the
  segments containing one, and :func:`check_continuity` refuses a log with one for uses that
  follow the whole log (dead reckoning).
* Excursions: a jump out and a jump back within ``Limits.max_excursion`` pose samples, the
  track continuous across them (a marker swap, a scan matcher's bad match, a frame of another
  object): those samples are off the track, and segmentation leaves them out
  (:func:`excursions`) rather than drop the segments around them, which would break the
  chain of segments that share pose samples.

The per-stream checks (:func:`check_encoders`, :func:`check_poses`, :func:`find_gaps`) are the
first stages of :func:`excite.logs.segmentation.segment_timeseries`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from excite.core.kinematics import MAX_RADIUS_TO_TRACK
from excite.core.plausible import RADIUS_RANGE
from excite.errors import DataError
from excite.logs.timeseries import Stream, TimeSeries, without_poses
from excite.stats.robust import MEDIAN_ABS_NORMAL

__all__ = ["Limits", "Gap", "StreamCheck", "check_continuity", "check_encoders", "check_poses",
           "encoder_stretches", "excursions", "left_on_track", "on_track", "find_gaps",
           "refuse_long_gaps", "stale_poses", "flagged_overlaps", "pose_noise"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

#: A stream interval over this many median periods has missed samples (a dropout).
DROPOUT_RATIO = 1.5
#: Default max_gap, in median periods of the stream.
GAP_RATIO = 3.0


@dataclass(frozen=True)
class Limits:
    """Thresholds of the detection in :func:`excite.logs.segmentation.segment_timeseries` and
    :func:`check_continuity`.

    max_gap (s): a stream interval longer than this (or than the window) is a gap; None means
        3x the stream's median sample period.
    max_speed (m/s), max_turn_rate (rad/s): sensor speed and turn rate between consecutive pose
        samples above which the step is a jump. Sized for ground robots below ~3.5 m/s and
        3 revolutions per second (the presets reach 2 m/s and, spinning at full speed, up to
        10.7 rad/s). The pose noise adds to the apparent motion (1 cm at 100 Hz reads as
        ~1.4 m/s), so a step is a jump only beyond these limits plus ``jump_sigmas`` times the
        noise of a difference of two poses (estimated from the pose stream, as for
        carry_sigmas).
    jump_sigmas: at 6, noise alone passes the jump limit once in ~10^8 samples (the Rayleigh
        tail exp(-6^2 / 2) for the position, twice the normal tail for the heading). At low
        pose rates (about 1 Hz) the robust noise estimate also counts the curvature of the
        motion between samples (0.13 m, 0.15 rad turning at 1 m/s and 1 rad/s), which widens
        the limit by about 1 m there.
    max_wheel_rate (rad/s): wheel rate between consecutive encoder samples above which the
        step is a jump (a counter reset or overflow).
    max_excursion: the most consecutive pose samples between a jump out and a jump back that
        are left out as off the track when the step across them is no jump (at 50 Hz, 0.1 s;
        a longer departure is more likely a relocalisation and its return another).
    still_wheel (rad), still_distance (m), still_heading (rad): a segment is a standstill when
        both wheels turned at most still_wheel and the sensor moved at most still_distance and
        turned at most still_heading.
    carry_sigmas: a segment in which both wheels turned at most still_wheel is a standstill
        too when the sensor moved at most carry_sigmas standard deviations of the noise of a
        difference of two poses and turned likewise: at 5, a still robot's noise passes it in
        about 4 of a million segments (the Rayleigh tail exp(-5^2 / 2)). The pose noise is
        estimated from the pose stream (:func:`pose_noise`).
    stale_turn (rad), stale_steps: pose samples that repeat the sample before them exactly
        (x, y and theta) while the wheels turned more than stale_turn in all (|dphi_L| +
        |dphi_R|; 0.1 rad rolls a 5 cm wheel 5 mm), and by so much that even the smallest
        plausible wheel (RADIUS_RANGE[0]) rolled stale_steps of the positions' resolution
        (their smallest change between samples: a source that writes cm repeats its pose
        while the robot creeps), came from a source that froze or held a placeholder while
        it lost the body (:func:`stale_poses`); a robot standing still may repeat its pose.
    max_radius_to_track, max_wheel_radius (m), max_sensor_arm (m): the most the wheels' small
        turns dphi_L, dphi_R (within still_wheel) can move a plausible robot's sensor: a turn of
        max_radius_to_track (|dphi_L| + |dphi_R|) (rad; r / b is 0.3 on a Husky, under 1 on any
        differential drive whose wheels are smaller than its track) and a displacement of
        max_wheel_radius max |dphi| plus max_sensor_arm times that turn (the sensor's lever
        arm). A segment with wheels this still whose sensor moved beyond that plus the
        standstill limit above, or turned likewise, was carried. Floors of a few times the
        still limits would do as well for the presets; this bound instead keeps full
        sensitivity where the wheels stood exactly still.
    """

    max_gap: float | None = None
    max_speed: float = 5.0
    max_turn_rate: float = 6.0 * math.pi
    jump_sigmas: float = 6.0
    max_wheel_rate: float = 200.0
    max_excursion: int = 5
    still_wheel: float = 0.02
    still_distance: float = 0.01
    still_heading: float = 0.01
    carry_sigmas: float = 5.0
    stale_turn: float = 0.1
    stale_steps: float = 3.0
    max_radius_to_track: float = MAX_RADIUS_TO_TRACK
    max_wheel_radius: float = 0.5
    max_sensor_arm: float = 1.0


@dataclass(frozen=True)
class Gap:
    """An interruption of one stream: no sample between t_start and t_end (s, that stream's
    own clock); location: file:line (or source and time) of the sample that resumes it."""

    stream: Stream
    t_start: float
    t_end: float
    location: str

    @property
    def duration(self) -> float:
        return self.t_end - self.t_start


@dataclass(frozen=True)
class StreamCheck:
    """Per-interval flags of one stream (one per interval between consecutive samples): gap
    (no segment spans it), jump; and the number of samples missed in dropouts."""

    gap: BoolArray
    jump: BoolArray
    dropouts: int


def pose_noise(ts: TimeSeries) -> tuple[float, float]:
    """Robust std of the pose samples' noise (m for x and y pooled, rad for theta): each inner
    sample minus the linear interpolation of its neighbours (exact for motion at a constant
    velocity, whatever the spacing) has, with independent noise of std sigma and even
    spacing, std sigma sqrt(3/2); the median absolute value of those residuals over
    MEDIAN_ABS_NORMAL sqrt(3/2) estimates sigma, unmoved by the few samples where the
    motion changes abruptly. (0, 0) with fewer than 3 samples. Correlated noise reads low."""
    if ts.t_pose.size < 3:
        return 0.0, 0.0
    t = ts.t_pose
    weight = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
    residual = [v[1:-1] - ((1.0 - weight) * v[:-2] + weight * v[2:])
                for v in (ts.x, ts.y, ts.theta)]
    scale = MEDIAN_ABS_NORMAL * math.sqrt(1.5)
    xy = float(np.median(np.abs(np.concatenate(residual[:2])))) / scale
    return xy, float(np.median(np.abs(residual[2]))) / scale


def _gap_flags(t: FloatArray, window: float, max_gap: float | None) -> tuple[BoolArray, int]:
    """Intervals that are gaps, and the number of samples missed in shorter dropouts."""
    dt = np.diff(t)
    period = float(np.median(dt))
    limit = min(window, GAP_RATIO * period if max_gap is None else max_gap)
    gap = dt > limit
    short = (dt > DROPOUT_RATIO * period) & ~gap
    missed = int(np.maximum(np.rint(dt[short] / period) - 1, 1).sum())
    return gap, missed


def check_encoders(ts: TimeSeries, window: float, limits: Limits) -> StreamCheck:
    """Gaps (longer than ``window`` s or ``limits.max_gap``), jumps (a wheel rate over
    ``limits.max_wheel_rate``) and dropouts of the encoder stream."""
    gap, missed = _gap_flags(ts.t_enc, window, limits.max_gap)
    dt = np.diff(ts.t_enc)
    step = np.maximum(np.abs(np.diff(ts.phi_L)), np.abs(np.diff(ts.phi_R)))
    return StreamCheck(gap, step > limits.max_wheel_rate * dt, missed)


def check_poses(ts: TimeSeries, window: float, limits: Limits,
                noise: tuple[float, float]) -> StreamCheck:
    """Gaps and jumps of the pose stream; a step is a jump when it exceeds the motion limits
    plus jump_sigmas times the noise of a difference of two poses (``noise``: a sample's std,
    xy and theta)."""
    gap, missed = _gap_flags(ts.t_pose, window, limits.max_gap)
    before, after = np.arange(ts.t_pose.size - 1), np.arange(1, ts.t_pose.size)
    return StreamCheck(gap, _jumps(ts, before, after, limits, noise), missed)


def _jumps(ts: TimeSeries, before: IntArray, after: IntArray, limits: Limits,
           noise: tuple[float, float]) -> BoolArray:
    """Whether the step from pose sample ``before`` to ``after`` is a jump (see
    :func:`check_poses`)."""
    dt = ts.t_pose[after] - ts.t_pose[before]
    moved = np.hypot(ts.x[after] - ts.x[before], ts.y[after] - ts.y[before])
    turned = np.abs(ts.theta[after] - ts.theta[before])
    spread = limits.jump_sigmas * math.sqrt(2.0)
    return ((moved > limits.max_speed * dt + spread * noise[0])
            | (turned > limits.max_turn_rate * dt + spread * noise[1]))


def excursions(ts: TimeSeries, poses: StreamCheck, limits: Limits,
               noise: tuple[float, float]) -> IntArray:
    """The pose samples off the track (indices): each run of at most
    ``limits.max_excursion`` samples from a jump out to the first jump (``poses.jump``) after
    which the pose is back on the track, with no gap among them: the step from the sample
    before the run to the sample after it is no jump (and turns less than pi, so that the
    headings unwrap the same without the run)."""
    jumps = np.flatnonzero(poses.jump)
    gaps = np.concatenate(([0], np.cumsum(poses.gap)))
    off = np.zeros(ts.t_pose.size, dtype=bool)
    k = 0
    while k + 1 < jumps.size:  # from each jump out, the first jump back that returns
        out = int(jumps[k])
        k += 1
        for m in range(k, jumps.size):
            back = int(jumps[m])  # the run: samples out + 1 .. back
            if back - out > limits.max_excursion or gaps[back + 1] != gaps[out]:
                break
            across = np.array([out]), np.array([back + 1])
            # back on the track, and the heading across unambiguous to unwrap
            if (not _jumps(ts, *across, limits, noise)[0]
                    and abs(ts.theta[back + 1] - ts.theta[out]) < math.pi):
                off[out + 1:back + 1] = True
                k = m + 1
                break
    return np.flatnonzero(off).astype(np.int64)


def left_on_track(ts: TimeSeries, poses: StreamCheck, limits: Limits,
                  noise: tuple[float, float]) -> tuple[TimeSeries, StreamCheck, int]:
    """``ts`` without its pose samples off the track (:func:`excursions`), the pose stream's
    check on the samples left, and how many were left out. The jumps are found again; a
    bridged interval is a gap only where an interval it bridges was one (a sample left out is
    no gap: an excursion holds none); the dropouts stay as counted on the stream as
    recorded."""
    off = excursions(ts, poses, limits, noise)
    if not off.size:
        return ts, poses, 0
    kept = np.setdiff1d(np.arange(ts.t_pose.size), off)
    thinned = without_poses(ts, off)
    gaps = np.concatenate(([0], np.cumsum(poses.gap)))
    bridged = gaps[kept[1:]] > gaps[kept[:-1]]
    jump = _jumps(thinned, np.arange(kept.size - 1), np.arange(1, kept.size), limits, noise)
    return thinned, StreamCheck(bridged, jump, poses.dropouts), int(off.size)


def _resolution(ts: TimeSeries) -> float:
    """The positions' resolution (m): their smallest change between consecutive samples (inf
    when they never change)."""
    steps = np.abs(np.concatenate([np.diff(ts.x), np.diff(ts.y)]))
    steps = steps[steps > 0]
    return float(steps.min()) if steps.size else math.inf


def stale_poses(ts: TimeSeries, limits: Limits | None = None) -> IntArray:
    """The pose samples (indices) that repeat the sample before them exactly, in runs over
    which the wheels turned more than :class:`Limits` allows (``stale_turn``, and
    ``stale_steps`` of the positions' resolution): every sample of such a run but its first,
    and the first too when the pose jumped to it (a placeholder, such as the origin, while
    the body was lost; the jump judged with the noise of the samples that do not repeat)."""
    limits = limits or Limits()
    poses = np.column_stack([ts.x, ts.y, ts.theta])
    same = np.all(poses[1:] == poses[:-1], axis=1)
    if not same.any():
        return np.zeros(0, dtype=np.int64)
    edges = np.diff(np.concatenate(([0], same.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # runs of repeats
    turned = sum(np.abs(np.interp(ts.t_pose[ends], ts.t_enc, phi)
                        - np.interp(ts.t_pose[starts], ts.t_enc, phi))
                 for phi in (ts.phi_L, ts.phi_R))
    least = max(limits.stale_turn,
                2.0 * limits.stale_steps * _resolution(ts) / RADIUS_RANGE[0])
    held = turned > least
    if not held.any():
        return np.zeros(0, dtype=np.int64)
    starts, ends = starts[held], ends[held]
    # a run that jumped away from the pose before it is a placeholder from its first sample
    entered = starts > 0
    jumped = np.zeros(starts.size, dtype=bool)
    noise = pose_noise(without_poses(ts, np.flatnonzero(same) + 1))
    jumped[entered] = _jumps(ts, starts[entered] - 1, starts[entered], limits, noise)
    return np.concatenate([np.arange(a + (not j), b + 1)
                           for a, b, j in zip(starts, ends, jumped, strict=True)]).astype(np.int64)


def on_track(ts: TimeSeries, limits: Limits | None = None) -> tuple[TimeSeries, int]:
    """A log followed whole without its pose samples off the track (:func:`left_on_track`,
    with the default ``limits``), and how many were left out."""
    limits = limits or Limits()
    noise = pose_noise(ts)
    thinned, _, count = left_on_track(ts, check_poses(ts, math.inf, limits, noise), limits,
                                      noise)
    return thinned, count


#: What most often makes each stream jump, for the messages about a jump.
ENCODER_JUMP_HINT = ("a counter that overflows or resets, a second publisher of the wheel "
                     "joints, or wheel angles in degrees or encoder counts? (wheel angles "
                     "must be cumulative, in rad: a JointState's positions in rad; a CSV's "
                     "counts as ticks_L,ticks_R columns, with --ticks-per-rev)")
POSE_JUMP_HINT = ("a relocalisation, positions in mm or headings in degrees? (x, y are in m, "
                  "theta in rad)")


def check_continuity(ts: TimeSeries, limits: Limits | None = None) -> None:
    """DataError naming the first jump of either stream (as
    :func:`~excite.logs.segmentation.segment_timeseries` detects them, with its default
    ``limits``), for uses that follow the whole log instead of dropping the segments around a
    jump (dead reckoning in :mod:`excite.validation.dead_reckoning`)."""
    limits = limits or Limits()
    window = math.inf  # gaps are not jumps here
    checks = (("encoder", check_encoders(ts, window, limits), ENCODER_JUMP_HINT,
               "the wheel angles jump"),
              ("pose", check_poses(ts, window, limits, pose_noise(ts)), POSE_JUMP_HINT,
               "the pose jumps"))
    for stream, check, hint, what in checks:
        jumps = np.flatnonzero(check.jump)
        if jumps.size:
            raise DataError(f"{ts.location(stream, int(jumps[0]) + 1)}: {what} ({jumps.size} "
                            f"time(s) in the log; the first here), so dead reckoning across it "
                            f"means nothing: {hint}")


def encoder_stretches(ts: TimeSeries, longer_than: float
                      ) -> tuple[list[tuple[float, float]], list[Gap]]:
    """The encoder stream's stretches between its gaps longer than ``longer_than`` s (first
    and last stamp, s, encoder clock), and those gaps: the wheels' path across such a gap is
    unknown, so dead reckoning (:mod:`excite.validation.dead_reckoning`) restarts after it."""
    cuts = np.flatnonzero(np.diff(ts.t_enc) > longer_than)
    firsts = np.concatenate(([0], cuts + 1))
    lasts = np.concatenate((cuts, [ts.t_enc.size - 1]))
    gaps = [Gap("encoder", float(ts.t_enc[i]), float(ts.t_enc[i + 1]),
                ts.location("encoder", int(i) + 1)) for i in cuts]
    return [(float(ts.t_enc[a]), float(ts.t_enc[b])) for a, b in zip(firsts, lasts,
                                                                     strict=True)], gaps


def find_gaps(ts: TimeSeries, encoders: StreamCheck, poses: StreamCheck) -> list[Gap]:
    """Every gap of both streams, in time order (each on its own clock)."""
    gaps = []
    for stream, t, check in (("encoder", ts.t_enc, encoders), ("pose", ts.t_pose, poses)):
        gaps += [Gap(stream, float(t[i]), float(t[i + 1]), ts.location(stream, int(i) + 1))
                 for i in np.flatnonzero(check.gap)]
    return sorted(gaps, key=lambda g: g.t_start)


def refuse_long_gaps(gaps: list[Gap], window: float) -> None:
    """DataError naming where the stream resumes after the first gap longer than ``window``
    (s)."""
    for gap in gaps:
        if gap.duration > window:
            raise DataError(f"{gap.location}: gap of {gap.duration:.3f} s in the {gap.stream} "
                            f"stream ({gap.t_start:.3f}-{gap.t_end:.3f} s), longer than the "
                            f"window ({window:g} s, --window, which bounds gaps in keyframe "
                            "mode too); --split-at-gaps, the command line's default (on_gap="
                            "'split'), cuts the log there instead")


def flagged_overlaps(t_enc: FloatArray, flags: BoolArray, start: FloatArray,
                     stop: FloatArray) -> IntArray:
    """How many flagged encoder intervals (t_enc[j], t_enc[j+1]) overlap each (start, stop)
    (open intervals; start == stop asks whether the instant lies strictly inside one)."""
    count = np.concatenate(([0], np.cumsum(flags)))
    first = np.clip(np.searchsorted(t_enc, start, side="right") - 1, 0, flags.size)
    last = np.clip(np.searchsorted(t_enc, stop, side="left"), 0, flags.size)
    return np.maximum(count[last] - count[first], 0)
