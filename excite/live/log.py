"""The log of a live session: its streams as they arrive (and, when they go silent, for how
long and why), cut into segments as ``excite calibrate`` cuts a log, the stopping rule's
decision on them (run wherever the session says, e.g. in a process of its own), and the noise
a planner weighs a segment with.

Units: s, rad, m.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import replace

import numpy as np

from excite.calibration.result import CalibrationResult
from excite.errors import DataError, ExciteError
from excite.logs.segmentation import segment_timeseries
from excite.logs.segments import Segments
from excite.logs.time_offset import OffsetOutOfRange, estimate_time_offset, untested_offset
from excite.logs.timeseries import TimeSeries
from excite.stopping import StopDecision, StoppingRule

__all__ = ["FROZEN_WHEEL_TURN", "Stream", "better_offset", "clock_offset", "cut",
           "decide_log", "increment_noise", "pose_age", "silence_text"]

#: rad: wheels that turned this much while the poses repeated one value: the pose source is
#: frozen (any robot moves its sensor by a millimetre or more on it, and a real source's noise
#: changes its values even when standing still).
FROZEN_WHEEL_TURN = 0.2


def increment_noise(result: CalibrationResult, duration: float) -> np.ndarray:
    """The std (m, m, rad) of one segment's measured increment under a calibration's noise
    model, for segments of ``duration`` s: its white segment noise; for segments cut from a
    log, the two pose samples the increment is the difference of (sqrt(2) times their std);
    and with wheel slip, each wheel's random walk over the segment (slip^2 * duration per
    wheel, rad^2) carried to the increment by a short segment's first-order wheel Jacobian at
    the estimate: x and y by (r_L^2 + r_R^2) / 4, theta by (r_L^2 + r_R^2) / b^2. What a
    planner weighs the segments with. No term alone will do: the calibration may put the
    heading's noise in the pose samples or in the slip, and the one it leaves out is near
    zero (a near-zero std would make the planner's information matrix singular)."""
    variance = np.asarray(result.sigma, dtype=float)[:3] ** 2
    if result.pose_sigma is not None:
        xy, theta = np.asarray(result.pose_sigma, dtype=float)
        variance = variance + 2.0 * np.array([xy, xy, theta]) ** 2
    if result.slip is not None:
        r_L, r_R, b = result.params.as_array()
        wheels = result.slip**2 * duration * (r_L**2 + r_R**2)
        variance = variance + wheels * np.array([0.25, 0.25, b**-2.0])
    return np.sqrt(variance)


def clock_offset(series: TimeSeries, time_offset: float | str) -> float:
    """The clock offset (s; pose time + offset = wheel time) a session's log is cut with:
    ``time_offset`` itself, or for "estimate" the log's estimate (as ``excite calibrate
    --time-offset estimate``), 0 while the log cannot give one (too short, too little turning,
    or a heading too noisy to compare its rate with the wheels': the data then say nothing
    about the clocks), and :class:`~excite.logs.time_offset.OffsetOutOfRange` (a DataError)
    when the best fit lies beyond the search range."""
    if time_offset != "estimate":
        return float(time_offset)
    try:
        return float(estimate_time_offset(series))
    except OffsetOutOfRange:
        raise
    except DataError:
        return 0.0


def cut(series: TimeSeries, window: float, time_offset: float = 0.0) -> Segments:
    """A session's log cut into segments as ``excite calibrate --window WINDOW
    --time-offset TIME_OFFSET --split-at-gaps`` cuts it (TIME_OFFSET in s, e.g. from
    :func:`clock_offset`; ExciteError when it cannot be, e.g. too few segments)."""
    return segment_timeseries(series, window=window, time_offset=time_offset,
                              on_gap="split").segments


def decide_log(rule: StoppingRule, series: TimeSeries, window: float, nominal,
               previous: StopDecision | None = None, time_offset: float | str = 0.0
               ) -> tuple[StopDecision | None, float | None]:
    """The stopping rule's decision on a session's log so far cut with ``time_offset`` (s,
    or "estimate": :func:`clock_offset`), ``previous`` the decision at an earlier look of it
    (the rule's screen then spares most looks the batch calibration), and the offset (s) the
    log was cut with. The decision is None while the log cannot be cut into segments yet,
    and *not yet* (offset None) while "estimate" finds the offset beyond its search range
    (the reason says so)."""
    try:
        offset = clock_offset(series, time_offset)
    except OffsetOutOfRange as exc:
        return StopDecision.not_yet(0, f"no clock offset: {exc}"), None
    try:
        segments = cut(series, window, offset)
    except ExciteError:
        return None, offset
    return rule.decide(segments, nominal, previous=previous), offset


def better_offset(rule: StoppingRule, series: TimeSeries, window: float, nominal,
                  offset: float) -> float | None:
    """For a session's whole log cut with a given clock ``offset`` (s) that did not reach its
    target: the offset at which its wheel rates explain its heading rate best
    (:func:`~excite.logs.time_offset.untested_offset`) when ``rule`` says *done* on the log
    cut with that one (a pose source's stamp latency kept the session from its target);
    else None."""
    lag = untested_offset(replace(series, t_pose=series.t_pose + offset))
    if lag is None:
        return None
    try:
        done = rule.decide(cut(series, window, lag + offset), nominal).done
    except (ExciteError, np.linalg.LinAlgError):  # a hint only: none
        return None
    return float(lag + offset) if done else None


class Stream:
    """Samples of one stream with strictly increasing stamps (late or repeated ones are
    counted and left out).

    Besides its samples, what a stream that goes silent needs to say why: ``left_out``, why
    its latest messages were not used (set by :meth:`add` for stamps that go back, by a
    transport for messages it could not read; None once a sample is used again), and
    ``lag``, how long after its stamp the latest sample arrived (s; None when not told)."""

    def __init__(self, width: int) -> None:
        self.t: list[float] = []
        self.values: list[tuple[float, ...]] = []
        self.width = width
        self.out_of_order = 0
        #: The stamp of the latest sample whose values differ from the one before (s).
        self.last_change: float | None = None
        self.left_out: str | None = None
        self.lag: float | None = None

    def add(self, t: float, values: tuple[float, ...], received: float | None = None) -> bool:
        """Add a sample stamped ``t`` (s) that arrived at ``received`` (s, the same clock;
        None: not known); False (and counted) when its stamp is not after the last one's."""
        if not (math.isfinite(t) and all(map(math.isfinite, values))):
            raise ValueError(f"a sample must be finite, got t={t!r}, {values!r}")
        if self.t and t <= self.t[-1]:
            self.out_of_order += 1
            self.left_out = (f"stamps at or before {self.t[-1]:.3f} s, the last one used: "
                             "they went back")
            return False
        values = tuple(map(float, values))
        if not self.values or values != self.values[-1]:
            self.last_change = float(t)
        self.t.append(float(t))
        self.values.append(values)
        self.left_out = None
        self.lag = None if received is None else float(received) - float(t)
        return True

    @property
    def last(self) -> float | None:
        return self.t[-1] if self.t else None

    def at(self, t: float) -> np.ndarray | None:
        """The values linearly interpolated at ``t``; None outside the samples."""
        if len(self.t) < 2 or not (self.t[0] <= t <= self.t[-1]):
            return None
        k = bisect.bisect_left(self.t, t)
        if self.t[k] == t:
            return np.array(self.values[k])
        w = (t - self.t[k - 1]) / (self.t[k] - self.t[k - 1])
        return (1 - w) * np.array(self.values[k - 1]) + w * np.array(self.values[k])

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.t), np.array(self.values).reshape(-1, self.width)


def pose_age(poses: Stream, wheels: Stream, now: float) -> float:
    """How long the poses have said nothing new at ``now`` (s): since their last sample, or,
    while the wheels turned more than FROZEN_WHEEL_TURN since the poses last changed, since
    that change (a source that repeats its last pose, a motion-capture body lost, is as blind
    as a silent one, and the safe area is watched on the poses)."""
    age = now - poses.last
    changed = poses.last_change
    if changed is None or now - changed <= age:
        return age
    then, latest = wheels.at(changed), wheels.at(wheels.last)
    if then is None or latest is None or np.max(np.abs(latest - then)) <= FROZEN_WHEEL_TURN:
        return age
    return now - changed


def silence_text(wheels: Stream, poses: Stream, now: float, timeout: float,
                 lasting: str = "") -> str:
    """Which streams are silent at ``now`` (for longer than ``timeout`` s; ``lasting``: for
    how long, in words), each with why when it is known: messages left out (and why),
    messages that arrive later than the timeout after their stamps, or poses that repeat one
    value while the wheels turn."""
    age_of_poses = pose_age(poses, wheels, now)
    frozen = now - poses.last <= timeout < age_of_poses
    parts = []
    for name, stream, age in (("the wheel angles", wheels, now - wheels.last),
                              ("the poses", poses, age_of_poses)):
        if age <= timeout:
            continue
        why = stream.left_out
        if why is None and stream.lag is not None and stream.lag > timeout:
            why = (f"they arrive {stream.lag:.3g} s after their stamps: stamped on "
                   "another clock, or held up on the way")
        if why is None and stream is poses and frozen:
            why = "they repeat one pose while the wheels turn"
        parts.append(f"{name} silent{lasting}" + (f" ({why})" if why else ""))
    return f"{' and '.join(parts)}; robot stopped"
