"""A robot's recording as two streams: encoder angles and the external sensor's poses, each on
its own clock, validated and ready for synchronisation and segmentation.

Streams, clocks and frames
--------------------------
* Encoder stream: times ``t_enc`` (s, the encoder clock) and cumulative wheel angles
  ``phi_L``, ``phi_R`` (rad, positive when the wheel drives the robot forward). Angles wrapped
  to one turn (continuous joints that some drivers report modulo 2 pi, in [-pi, pi) or
  [0, 2 pi)) are unwrapped and the segmentation report says so; an error when they are
  sampled too slowly to unwrap. Encoder ticks become angles through :func:`tick_angle`; a
  fixed-width tick counter that overflowed is unwrapped by :func:`unwrapped_counter`.
* Pose stream: times ``t_pose`` (s, the pose sensor's clock) and the sensor's pose in the
  world frame: ``x``, ``y`` (m) and ``theta`` (rad, unwrapped; a wrapped input is unwrapped).
* The clocks differ by a constant ``time_offset`` (s): pose time + time_offset = encoder time
  (:mod:`excite.logs.time_offset` estimates it).

Where the streams come from and go: :mod:`excite.logs.timeseries_csv` (CSV files),
:mod:`excite.logs.bag_reader` and :mod:`excite.logs.bag_writer` (ROS bags); how they become
segments: :mod:`excite.logs.segmentation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.errors import DataError

__all__ = ["SpeedIntegral", "TimeSeries", "integrated_speed", "sample_at", "tick_angle",
           "unwrapped_counter", "unwrapped_words", "ANGLE_COLUMNS", "POSE_COLUMNS",
           "SPEED_COLUMNS", "SPEED_NOTE", "TICK_COLUMNS"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Stream = Literal["encoder", "pose"]

#: Fewest samples a stream may have.
MIN_SAMPLES = 2
#: The wheel columns: angles (rad), encoder ticks or angular speeds (rad/s, integrated:
#: :func:`integrated_speed`); and the pose columns (m, m, rad).
ANGLE_COLUMNS = ("phi_L", "phi_R")
TICK_COLUMNS = ("ticks_L", "ticks_R")
SPEED_COLUMNS = ("omega_L", "omega_R")
POSE_COLUMNS = ("x", "y", "theta")


#: The smallest clock step (s) excite finds (:mod:`excite.logs.clock_steps`,
#: :mod:`excite.logs.bag_stamps`) or names (a stream's time stepping back by more, and
#: increasing after): smaller ones are within a stamp latency's spread, or a sample out of
#: order.
MIN_CLOCK_STEP = 0.05


def sample_at(source: str, t: float) -> str:
    """A sample's place when its line is unknown: 'source at t = ... s' (t in s, to the us);
    errors about time-series samples and bag messages name them so."""
    return f"{source} at t = {float(t):.6f} s"


def _where(source: str, lines: IntArray | None, t: ArrayLike, index: int) -> str:
    """'file:line' of a sample, or 'source at t = ... s' when lines are unknown."""
    if lines is not None:
        return f"{source}:{lines[index]}"
    return sample_at(source, np.asarray(t)[index])


def _checked_stream(kind: Stream, source: str, lines: IntArray | None,
                    columns: dict[str, ArrayLike]) -> list[FloatArray]:
    """Validate one stream (first column the time): equal lengths, enough samples, finite
    values, strictly increasing time. Errors name the file and line (or time)."""
    arrays = []
    for name, values in columns.items():
        try:
            arrays.append(np.array(values, dtype=float).reshape(-1))
        except (TypeError, ValueError):
            raise DataError(f"{source}: {name} is not an array of numbers") from None
    sizes = {a.size for a in arrays} | ({lines.size} if lines is not None else set())
    if len(sizes) != 1:
        raise DataError(f"{source}: the {kind} columns have different lengths {sorted(sizes)}")
    t = arrays[0]
    if t.size < MIN_SAMPLES:
        raise DataError(f"{source}: {t.size} {kind} sample(s); at least {MIN_SAMPLES} are needed")
    finite = np.isfinite(np.vstack(arrays))
    if not finite.all():
        index, column = (int(v[0]) for v in np.nonzero(~finite.T))
        name = list(columns)[column]
        raise DataError(f"{_where(source, lines, t, index)}: {name} is not finite "
                        f"({arrays[column][index]})")
    steps = np.flatnonzero(np.diff(t) <= 0)
    if steps.size:
        i = int(steps[0]) + 1
        back = float(t[i - 1] - t[i])
        hint = (f"; a clock set back by {back:.3g} s while recording (NTP)? split the file "
                "at this line and calibrate the two parts as two logs"
                if back > MIN_CLOCK_STEP and np.all(np.diff(t[i:]) > 0) else "")
        raise DataError(f"{_where(source, lines, t, i)}: time does not increase "
                        f"({float(t[i])!r} s after {float(t[i - 1])!r} s){hint}")
    return arrays


#: Wheel angles whose range (max - min) exceeds one turn, 2 pi, by at most this (rad) may be
#: wrapped: continuous joints that some drivers report modulo 2 pi, whether in [-pi, pi) or in
#: [0, 2 pi).
WRAP_TOLERANCE = 1e-3
#: The largest wheel step between encoder samples (rad) that unwrapping trusts. np.unwrap takes
#: the step within +-pi, right while the wheel turns less than pi per sample; a wheel that sped
#: up past pi per sample would pass through steps between pi/2 and pi first (unless its step
#: changed by over pi/2 from one sample to the next), so a step over pi/2 means the stream is
#: sampled too slowly to unwrap reliably.
MAX_UNWRAPPED_STEP = 0.5 * math.pi


def _unwrapped_wheel(source: str, lines: IntArray | None, t: FloatArray, name: str,
                     phi: FloatArray) -> FloatArray | None:
    """The wheel angles unwrapped when they are wrapped (all within one turn, a range of at
    most 2 pi + WRAP_TOLERANCE, and some step between samples over pi); None when they are not
    wrapped.
    DataError naming the sample when a step after unwrapping exceeds MAX_UNWRAPPED_STEP."""
    steps = np.abs(np.diff(phi))
    if np.ptp(phi) > 2.0 * math.pi + WRAP_TOLERANCE or not (steps > math.pi).any():
        return None
    unwrapped = np.unwrap(phi)
    fast = np.abs(np.diff(unwrapped))
    i = int(np.argmax(fast))
    if fast[i] > MAX_UNWRAPPED_STEP:
        raise DataError(f"{_where(source, lines, t, i + 1)}: the wheel angles {name} are "
                        f"wrapped modulo 2 pi and sampled too slowly to unwrap (a step of "
                        f"{fast[i]:.2f} rad after unwrapping, over pi/2): record them "
                        "unwrapped or more often")
    return unwrapped


def unwrapped_words(wheels: tuple[str, ...], counters: tuple[str, ...]) -> str:
    """The wheel columns unwrapped (TimeSeries.unwrapped_wheels, .unwrapped_counters) in
    words, e.g. 'phi_L wrapped modulo 2 pi, unwrapped'; '' when there are none."""
    parts = []
    if wheels:
        parts.append(f"{', '.join(wheels)} wrapped modulo 2 pi, unwrapped")
    if counters:
        parts.append(f"{', '.join(counters)} overflowed, unwrapped")
    return "; ".join(parts)


@dataclass(frozen=True, eq=False)
class TimeSeries:
    """The encoder and pose streams of one recording, validated.

    t_enc: encoder times (s, encoder clock); phi_L, phi_R: cumulative wheel angles (rad).
    t_pose: pose times (s, pose clock); x, y (m), theta (rad): the external sensor's pose in
    the world frame; theta is unwrapped here. Each stream's time strictly increases and has at
    least 2 samples; every value is finite.
    source: (encoder source, pose source) for messages: file names, or bag and topic.
    lines: (encoder lines, pose lines): each sample's line in its file, or None (messages then
    name the sample's time).
    unwrapped_wheels: the wheel columns (of "phi_L", "phi_R") that were wrapped to one turn
    (continuous joints reported modulo 2 pi) and are unwrapped here; DataError when such a
    stream is sampled too slowly to unwrap (see MAX_UNWRAPPED_STEP). unwrapped_counters: the
    tick columns whose fixed-width counter overflowed and was unwrapped when they were read
    (e.g. 'ticks_L (16-bit counter)', :func:`unwrapped_counter`), for the reports. speeds:
    the wheel angles are wheel speeds integrated (:func:`integrated_speed`), which may lag
    the motion (:mod:`excite.logs.speed_lag`).
    """

    t_enc: FloatArray
    phi_L: FloatArray
    phi_R: FloatArray
    t_pose: FloatArray
    x: FloatArray
    y: FloatArray
    theta: FloatArray
    source: tuple[str, str] = ("encoders", "poses")
    lines: tuple[IntArray | None, IntArray | None] = (None, None)
    unwrapped_counters: tuple[str, ...] = ()
    speeds: bool = False
    unwrapped_wheels: tuple[str, ...] = field(default=(), init=False)

    def __post_init__(self) -> None:
        lines = tuple(None if a is None else np.asarray(a, dtype=np.int64).reshape(-1)
                      for a in self.lines)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "source", tuple(str(s) for s in self.source))
        encoder = _checked_stream("encoder", self.source[0], lines[0], {
            "t": self.t_enc, "phi_L": self.phi_L, "phi_R": self.phi_R})
        pose = _checked_stream("pose", self.source[1], lines[1], {
            "t": self.t_pose, "x": self.x, "y": self.y, "theta": self.theta})
        pose[3] = np.unwrap(pose[3])
        unwrapped = []
        for k, name in enumerate(ANGLE_COLUMNS, start=1):
            wheel = _unwrapped_wheel(self.source[0], lines[0], encoder[0], name, encoder[k])
            if wheel is not None:
                encoder[k] = wheel
                unwrapped.append(name)
        object.__setattr__(self, "unwrapped_wheels", tuple(unwrapped))
        names = ("t_enc", "phi_L", "phi_R", "t_pose", "x", "y", "theta")
        for name, array in zip(names, encoder + pose, strict=True):
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    def location(self, stream: Stream, index: int) -> str:
        """Where sample ``index`` of a stream came from: 'file:line', or source and time."""
        k = 0 if stream == "encoder" else 1
        return _where(self.source[k], self.lines[k], (self.t_enc, self.t_pose)[k], index)


def during(series: TimeSeries, start: float | None = None, end: float | None = None
           ) -> TimeSeries:
    """The samples of both streams stamped within [start, end] (s, each stream's own stamps;
    None: unbounded). Raises DataError naming the source when a stream keeps fewer than 2."""
    if start is None and end is None:
        return series
    lo = -math.inf if start is None else start
    hi = math.inf if end is None else end
    stamps = (series.t_enc, series.t_pose)
    keep = [(t >= lo) & (t <= hi) for t in stamps]
    for k, (name, mask) in enumerate(zip(("encoder", "pose"), keep, strict=True)):
        if mask.sum() < 2:
            raise DataError(f"{series.source[k]}: fewer than 2 {name} samples between "
                            f"{lo:.3f} and {hi:.3f} s (its stamps run from {stamps[k][0]:.3f} "
                            f"to {stamps[k][-1]:.3f} s; --start and --end are in the log's own "
                            "stamps)")
    return _subset(series, *keep)


def without_poses(series: TimeSeries, index: IntArray) -> TimeSeries:
    """``series`` without the pose samples ``index`` (each sample keeps its line for
    messages)."""
    keep = np.ones(series.t_pose.size, dtype=bool)
    keep[index] = False
    return _subset(series, np.ones(series.t_enc.size, dtype=bool), keep)


def _subset(series: TimeSeries, enc: NDArray[np.bool_], pose: NDArray[np.bool_]
            ) -> TimeSeries:
    """The samples of ``series`` where ``enc`` and ``pose`` (one per sample) are true (the
    wheels it unwrapped still named as such)."""
    lines = tuple(None if a is None else a[m]
                  for a, m in zip(series.lines, (enc, pose), strict=True))
    subset = TimeSeries(series.t_enc[enc], series.phi_L[enc], series.phi_R[enc],
                        series.t_pose[pose], series.x[pose], series.y[pose],
                        series.theta[pose], source=series.source, lines=lines,
                        unwrapped_counters=series.unwrapped_counters, speeds=series.speeds)
    object.__setattr__(subset, "unwrapped_wheels", series.unwrapped_wheels)
    return subset


#: What a log whose wheels were given as speeds says (after its source's name).
SPEED_NOTE = ("wheel speeds (rad/s) integrated into angles by the trapezoidal rule; their "
              "errors add up over time, which the noise model's slip level takes")


def integrated_speed(t: FloatArray, omega: FloatArray) -> FloatArray:
    """The cumulative angle (rad, 0 at the first sample) of a wheel whose angular speed
    ``omega`` (rad/s) is sampled at the strictly increasing times ``t`` (s): the trapezoidal
    rule, exact for a speed that changes linearly between samples (for a driver's speed that
    is the mean over the last sample period, the difference is half a sample's change of
    speed times its period, which does not add up over a segment)."""
    steps = 0.5 * (omega[1:] + omega[:-1]) * np.diff(t)
    return np.concatenate(([0.0], np.cumsum(steps)))


class SpeedIntegral:
    """:func:`integrated_speed` of two wheels one sample at a time, as a live stream gives
    them: :meth:`add` returns the angles (rad) at the sample (0 at the first)."""

    def __init__(self) -> None:
        self.t: float | None = None
        self.omega = (0.0, 0.0)
        self.angles = (0.0, 0.0)

    def add(self, t: float, omega_L: float, omega_R: float) -> tuple[float, float] | None:
        """The angles at time ``t`` (s) of wheels turning at ``omega_L``, ``omega_R``
        (rad/s); None for a sample not after the last one (left out)."""
        if self.t is not None:
            if not t > self.t:
                return None
            step = t - self.t
            self.angles = tuple(angle + 0.5 * (before + now) * step for angle, before, now
                                in zip(self.angles, self.omega, (omega_L, omega_R),
                                       strict=True))
        self.t, self.omega = t, (omega_L, omega_R)
        return self.angles


def tick_angle(ticks_per_rev: float) -> float:
    """The angle of one encoder tick, 2 pi / ticks_per_rev (rad); DataError unless
    ticks_per_rev is positive and finite."""
    if not 0 < ticks_per_rev < math.inf:
        raise DataError(f"ticks_per_rev must be positive and finite, got {ticks_per_rev}")
    return 2.0 * math.pi / ticks_per_rev


#: Widths (bits) of the encoder counters whose overflows are undone (unwrapped_counter).
COUNTER_BITS = (16, 32)


def _counter_width(ticks: FloatArray) -> int | None:
    """The width (bits, of COUNTER_BITS) of a fixed-width counter that may have wrapped in
    ``ticks``: whole numbers within an unsigned or a signed range of that width, with a step
    between samples over half of it; None otherwise."""
    if ticks.size < 3 or not np.all(ticks == np.round(ticks)):
        return None
    low, high = float(ticks.min()), float(ticks.max())
    step = float(np.abs(np.diff(ticks)).max())
    for bits in COUNTER_BITS:
        span = 2.0**bits
        fits = (low >= 0 and high < span) or (-span / 2 <= low and high < span / 2)
        if fits and step > span / 2:
            return bits
    return None


#: An overflow is undone only where the step it leaves is at most this many times the larger
#: of its neighbouring steps (plus OVERFLOW_SLACK ticks): a wheel turning on as before. A
#: counter reset (a reboot: 65300 -> 0) leaves a step unlike its neighbours and stays a jump.
OVERFLOW_STEP_RATIO = 2.0
OVERFLOW_SLACK = 2.0


def unwrapped_counter(ticks: FloatArray) -> tuple[FloatArray, int | None]:
    """Encoder ticks with a fixed-width counter's overflows undone, as a cumulative count, and
    the counter's width (None: no overflow undone, ticks unchanged). A step over half the
    counter's range (:func:`_counter_width`) is an overflow when, taken modulo the range, it
    continues the neighbouring steps (OVERFLOW_STEP_RATIO); other big steps are left alone
    (jumps, which segmentation drops and validation refuses)."""
    bits = _counter_width(ticks)
    if bits is None:
        return ticks, None
    span = 2.0**bits
    steps = np.diff(ticks)
    big = np.abs(steps) > span / 2
    wrapped = steps - span * np.round(steps / span)
    small = np.where(big, 0.0, np.abs(steps))
    neighbours = np.maximum(np.concatenate(([0.0], small[:-1])),
                            np.concatenate((small[1:], [0.0])))
    overflow = big & (np.abs(wrapped) <= OVERFLOW_STEP_RATIO * neighbours + OVERFLOW_SLACK)
    if not overflow.any():
        return ticks, None
    fixed = np.where(overflow, wrapped, steps)
    return ticks[0] + np.concatenate(([0.0], np.cumsum(fixed))), bits
