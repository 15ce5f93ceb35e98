"""Validation on held-out logs: does a calibration make dead reckoning better?

Each log's encoders are dead-reckoned twice, with the nominal and with the calibrated robot
(wheel parameters and sensor pose), and the predicted sensor poses are compared with the
external ones. Computation only: :mod:`excite.validation.report` writes the results as text
(with the verdict of :mod:`excite.validation.verdict`) and :mod:`excite.validation.plot`
draws them.

Dead reckoning (one choice, everywhere)
---------------------------------------
* Clocks: pose time + ``time_offset`` = encoder time (s), as in :mod:`excite.logs.timeseries`.
  Dead reckoning uses the pose samples inside the encoder time range (a contiguous stretch);
  it starts at the first of them.
* Between consecutive encoder samples the robot moves on the arc of constant wheel-rate ratio
  (:class:`excite.core.kinematics.Arc`) with the calibration model's term for the change of
  curvature from its neighbours (:func:`excite.core.models.curvature_change`: an arc per
  interval alone drifts by O(h^2) of the encoder period on curving paths). At the pose times
  the cumulative wheel angles are interpolated by the segmentation's monotone cubic
  (:func:`excite.logs.wheel_path.wheel_angles`): the integration grid is the union of the
  encoder and pose times. Across a gap in the encoder stream the motion is one arc, like any
  other interval (``excite validate`` cuts a log at gaps longer than a second and follows
  each part from its own first pose: :func:`excite.calibration.logs.validate_logs`).
* Poses are composed in SE(2) (:mod:`excite.core.se2`), vectorised: the heading is the cumulative
  sum of the arcs' dtheta and the position the cumulative sum of their (dx, dy) rotated by the
  heading at each arc's start.
* Start: with the sensor at l = (l_x, l_y, l_theta) in the body frame (l = 0 without a sensor
  pose, the axle model), the body starts at M_0 (+) (-l), M_0 the first external pose, so
  the predicted sensor pose body (+) l starts exactly at M_0. The nominal robot is usually
  given the calibrated sensor pose, so that the comparison measures the wheel calibration
  rather than a mounting offset that a URDF would already hold.

Metrics (per log, for the nominal and the calibrated robot)
-----------------------------------------------------------
* ``end_position_error`` (m): distance between the predicted and the measured sensor position
  at the last pose sample used.
* ``end_heading_error`` (rad): |predicted - measured heading| there, wrapped to [0, pi].
* ``rms_path_error`` (m): root mean square of the position distance over every pose sample used.
* ``ratio``: calibrated / nominal of each metric (None when the nominal one is 0).
Overall: the mean of each metric over the logs and the ratio of those means.

UMBmark (Borenstein & Feng, "Measurement and correction of systematic odometry errors in
mobile robots", IEEE T-RA 1996)
-----------------------------------------------------------------------------------------
A log is a bidirectional square when :func:`find_loops` finds at least one clockwise and one
counter-clockwise loop in its external poses:

1. Sides: the pose samples are split, greedily from the first, into maximal runs whose heading
   stays within ``straight_tolerance`` (rad) of the run's first sample; a run whose end points
   are at least ``min_side`` (m) apart is a side (straight driving), anything else a turn.
2. A loop: four consecutive sides whose three heading changes (between the sides' mean
   headings) are all within ``turn_tolerance`` (rad) of +pi/2 (counter-clockwise) or all of
   -pi/2 (clockwise), and whose end (the last sample of the fourth side) is back at the start
   (the first sample of the first side) within ``closure`` times the loop's perimeter (the sum
   of the sides' lengths). The search continues after a loop's fourth side, otherwise after the
   first side.

For every loop, dead reckoning restarts at the loop's start (as above, from the measured pose
there) and the loop's error is Borenstein's eps = measured - dead-reckoned sensor position at
the loop's end, expressed in the measured sensor frame at the loop's start (m). With c_cw and
c_ccw the centroids of the clockwise and counter-clockwise errors, the measure of systematic
odometry error is E_max,syst = max(|c_cw|, |c_ccw|) (m).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from excite.core import se2
from excite.core.kinematics import Arc, Params, wrap_angle
from excite.core.models import SensorPose, curvature_change
from excite.errors import DataError
from excite.logs.continuity import check_continuity
from excite.logs.segments import read_text
from excite.logs.timeseries import TimeSeries
from excite.logs.wheel_path import wheel_angles
from excite.validation.verdict import METRIC, Verdict, judge

__all__ = [
    "Loop",
    "LogValidation",
    "ParamsFile",
    "PathErrors",
    "Robot",
    "UMBmark",
    "UMBmarkErrors",
    "ValidationResult",
    "dead_reckon",
    "find_loops",
    "read_params_file",
    "sensor_track",
    "summarize",
    "validate_log",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
#: A robot as validation sees it: wheel parameters (m) and the sensor's pose in the body frame
#: (None: the axle model, l = 0).
Robot = tuple[Params, SensorPose | None]
Direction = Literal["cw", "ccw"]

_METRICS = ("end_position_error", "end_heading_error", "rms_path_error")


def _verdict(nominal: PathErrors, calibrated: PathErrors) -> Verdict:
    """The verdict of :mod:`excite.validation.verdict` on its metric."""
    return judge(getattr(nominal, METRIC), getattr(calibrated, METRIC))


def _ratio(calibrated: float, nominal: float) -> float | None:
    """calibrated / nominal, None when the nominal value is 0."""
    return calibrated / nominal if nominal > 0.0 else None


# --------------------------------------------------------------------------- dead reckoning


def _used_samples(series: TimeSeries, time_offset: float, name: str) -> IntArray:
    """Indices of the pose samples inside the encoder time range (contiguous, at least 2)."""
    t_pose = series.t_pose + time_offset
    used = np.flatnonzero((t_pose >= series.t_enc[0]) & (t_pose <= series.t_enc[-1]))
    if used.size < 2:
        raise DataError(f"{name}: {used.size} pose sample(s) within the encoder time range "
                        f"({series.t_enc[0]:.6g} to {series.t_enc[-1]:.6g} s with time offset "
                        f"{time_offset:g} s); at least 2 are needed to validate")
    return used


def dead_reckon(series: TimeSeries, time_offset: float, params: Params,
                used: IntArray | None = None) -> FloatArray:
    """Dead-reckoned body poses (n, 3) at the pose samples ``used`` (default: those inside the
    encoder time range), in the body frame at the first of them (so the first row is 0):
    x, y in m, theta in rad (continuous). See the module docstring for the method.

    time_offset (s): pose time + time_offset = encoder time. params: wheel parameters (m).
    ``used`` must be increasing indices of pose samples inside the encoder time range.
    """
    if used is None:
        used = _used_samples(series, time_offset, series.source[1])
    t_eval = series.t_pose[used] + time_offset
    t_enc = series.t_enc
    inner = t_enc[(t_enc > t_eval[0]) & (t_enc < t_eval[-1])]
    grid = np.union1d(t_eval, inner)
    phi = np.diff(wheel_angles(series)(grid), axis=0)
    arc = Arc(phi[:, 0], phi[:, 1], params.r_L, params.r_R, params.b, derivatives=False)
    steps = np.stack([arc.dx, arc.dy, arc.dtheta])
    curvature_change(arc, params.b, steps, None)
    path = se2.accumulate(*steps)
    return path[np.searchsorted(grid, t_eval)]


def _lever(sensor_pose: SensorPose | None) -> FloatArray:
    return np.zeros(3) if sensor_pose is None else sensor_pose.as_array()


def sensor_track(start: FloatArray, odometry: FloatArray,
                 sensor_pose: SensorPose | None) -> FloatArray:
    """Predicted world poses of the sensor (..., 3) from its measured world pose ``start``
    (..., 3) and the dead-reckoned body motion ``odometry`` (..., 3) since then (body frame
    at the start): body_0 = start (+) (-l), sensor = body_0 (+) odometry (+) l. Broadcasts
    batch-first; m, m, rad."""
    lever = _lever(sensor_pose)
    body_start = se2.compose(start, se2.inverse(lever))
    return se2.compose(se2.compose(body_start, odometry), lever)


# --------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class PathErrors:
    """How far a dead-reckoned sensor path is from the measured one: end_position_error (m),
    end_heading_error (rad, wrapped, >= 0), rms_path_error (m, over all samples)."""

    end_position_error: float
    end_heading_error: float
    rms_path_error: float

    @classmethod
    def of(cls, predicted: FloatArray, measured: FloatArray) -> PathErrors:
        """Errors of predicted against measured world poses (n, 3) at the same times."""
        distance = np.hypot(*(predicted[:, :2] - measured[:, :2]).T)
        return cls(float(distance[-1]),
                   float(abs(wrap_angle(predicted[-1, 2] - measured[-1, 2]))),
                   float(np.sqrt(np.mean(distance**2))))

    @classmethod
    def mean(cls, errors: Sequence[PathErrors]) -> PathErrors:
        """The mean of each metric."""
        return cls(*(float(np.mean([getattr(e, m) for e in errors])) for m in _METRICS))

    def ratio(self, nominal: PathErrors) -> dict[str, float | None]:
        """self / nominal for each metric (None where the nominal one is 0)."""
        return {m: _ratio(getattr(self, m), getattr(nominal, m)) for m in _METRICS}

    def to_dict(self) -> dict[str, float]:
        return {m: getattr(self, m) for m in _METRICS}


# --------------------------------------------------------------------------- UMBmark


@dataclass(frozen=True)
class Loop:
    """One closed square loop of a log: ``start`` and ``end`` index the log's used pose
    samples (:attr:`LogValidation.t`); t_start, t_end (s, encoder clock); direction "cw" or
    "ccw"."""

    start: int
    end: int
    t_start: float
    t_end: float
    direction: Direction


def _run_end(theta: FloatArray, i: int, tolerance: float) -> int:
    """First index after i where |theta - theta[i]| > tolerance (len(theta) if none); the
    search window doubles, so the cost is proportional to the run's length."""
    width = 16
    while True:
        window = theta[i + 1:i + 1 + width]
        outside = np.flatnonzero(np.abs(window - theta[i]) > tolerance)
        if outside.size:
            return i + 1 + int(outside[0])
        if i + 1 + width >= theta.size:
            return theta.size
        width *= 2


def _sides(xy: FloatArray, theta: FloatArray, min_side: float, straight_tolerance: float
           ) -> list[tuple[int, int, float]]:
    """The straight sides (first index, last index, mean heading) of a path (module doc)."""
    sides, i = [], 0
    while i < theta.size:
        j = _run_end(theta, i, straight_tolerance)
        if math.dist(xy[i], xy[j - 1]) >= min_side:
            sides.append((i, j - 1, float(np.mean(theta[i:j]))))
        i = j
    return sides


def find_loops(t: FloatArray, poses: FloatArray, *, min_side: float = 0.5,
               straight_tolerance: float = 0.15, turn_tolerance: float = 0.3,
               closure: float = 0.1) -> list[Loop]:
    """Closed square loops in measured world poses (n, 3) (m, m, rad; theta continuous) at
    times t (s), by the method of the module docstring: sides at least ``min_side`` m long
    with headings within ``straight_tolerance`` rad, turns within ``turn_tolerance`` rad of
    +-pi/2, back at the start within ``closure`` x the perimeter."""
    xy, theta = poses[:, :2], poses[:, 2]
    sides = _sides(xy, theta, min_side, straight_tolerance)
    loops, k = [], 0
    while k + 4 <= len(sides):
        four = sides[k:k + 4]
        turns = np.diff([side[2] for side in four])
        sign = 1.0 if turns[0] > 0 else -1.0
        start, end = four[0][0], four[3][1]
        perimeter = sum(math.dist(xy[a], xy[b]) for a, b, _ in four)
        if (np.all(np.abs(turns - sign * 0.5 * math.pi) <= turn_tolerance)
                and math.dist(xy[start], xy[end]) <= closure * perimeter):
            loops.append(Loop(start, end, float(t[start]), float(t[end]),
                              "ccw" if sign > 0 else "cw"))
            k += 4
        else:
            k += 1
    return loops


@dataclass(frozen=True, eq=False)
class UMBmarkErrors:
    """UMBmark errors of one robot (nominal or calibrated) over a log's loops: ``errors``
    (k, 2), per loop eps = measured - dead-reckoned sensor position at the loop's end, in the
    measured sensor frame at its start (m); the centroids (2,) of the clockwise and
    counter-clockwise errors (m); e_max_syst = max(|c_cw|, |c_ccw|) (m)."""

    errors: FloatArray
    centroid_cw: FloatArray
    centroid_ccw: FloatArray
    e_max_syst: float

    @classmethod
    def of(cls, loops: Sequence[Loop], measured: FloatArray, odometry: FloatArray,
           sensor_pose: SensorPose | None) -> UMBmarkErrors:
        """Errors with dead reckoning restarted at each loop's start; ``odometry`` (n, 3) is
        the log's dead-reckoned body motion at the used pose samples, ``measured`` (n, 3) the
        external poses there. Needs at least one loop in each direction."""
        start = np.array([loop.start for loop in loops])
        end = np.array([loop.end for loop in loops])
        motion = se2.between(odometry[start], odometry[end])
        predicted = sensor_track(measured[start], motion, sensor_pose)
        errors = (se2.between(measured[start], measured[end])
                  - se2.between(measured[start], predicted))[:, :2]
        cw = np.array([loop.direction == "cw" for loop in loops])
        c_cw, c_ccw = errors[cw].mean(axis=0), errors[~cw].mean(axis=0)
        return cls(errors, c_cw, c_ccw, float(max(np.hypot(*c_cw), np.hypot(*c_ccw))))

    def to_dict(self) -> dict:
        return {"centroid_cw": self.centroid_cw.tolist(),
                "centroid_ccw": self.centroid_ccw.tolist(),
                "e_max_syst": self.e_max_syst,
                "errors": self.errors.tolist()}


@dataclass(frozen=True)
class UMBmark:
    """Borenstein & Feng's measure on a bidirectional square log: the loops found and the
    errors of the nominal and the calibrated robot."""

    loops: tuple[Loop, ...]
    nominal: UMBmarkErrors
    calibrated: UMBmarkErrors

    @property
    def ratio(self) -> float | None:
        """calibrated / nominal E_max,syst (None when the nominal one is 0)."""
        return _ratio(self.calibrated.e_max_syst, self.nominal.e_max_syst)

    def count(self, direction: Direction) -> int:
        return sum(loop.direction == direction for loop in self.loops)

    def to_dict(self) -> dict:
        return {"loops": [{"direction": loop.direction, "t_start": loop.t_start,
                           "t_end": loop.t_end} for loop in self.loops],
                "nominal": self.nominal.to_dict(), "calibrated": self.calibrated.to_dict(),
                "ratio": self.ratio}


# --------------------------------------------------------------------------- per log, overall


@dataclass(frozen=True, eq=False)
class LogValidation:
    """One log's validation. file: its name. t (n,): the pose samples used (s, encoder clock);
    measured, nominal_path, calibrated_path (n, 3): the measured and the two dead-reckoned
    sensor world poses there (m, m, rad); nominal, calibrated: their :class:`PathErrors`;
    umbmark: :class:`UMBmark` when the log is a bidirectional square, else None."""

    file: str
    t: FloatArray
    measured: FloatArray
    nominal_path: FloatArray
    calibrated_path: FloatArray
    nominal: PathErrors
    calibrated: PathErrors
    umbmark: UMBmark | None

    @property
    def ratio(self) -> dict[str, float | None]:
        """calibrated / nominal of each metric."""
        return self.calibrated.ratio(self.nominal)

    @property
    def verdict(self) -> Verdict:
        """better, no better or worse than nominal (:mod:`excite.validation.verdict`)."""
        return _verdict(self.nominal, self.calibrated)

    def to_dict(self) -> dict:
        return {"file": self.file, "nominal": self.nominal.to_dict(),
                "calibrated": self.calibrated.to_dict(), "ratio": self.ratio,
                "verdict": self.verdict,
                "umbmark": None if self.umbmark is None else self.umbmark.to_dict()}


def validate_log(series: TimeSeries, time_offset: float, calibrated: Robot, nominal: Robot,
                 name: str | None = None) -> LogValidation:
    """Dead-reckon one log with the calibrated and the nominal robot (each (Params,
    SensorPose or None)) and compare both with the external poses (module docstring).

    time_offset (s): pose time + time_offset = encoder time. name: the log's name in messages
    and results (default: the pose stream's source). Raises DataError when fewer than 2 pose
    samples fall within the encoder time range, and
    (:func:`excite.logs.continuity.check_continuity`)
    when either stream jumps.
    """
    name = series.source[1] if name is None else name
    check_continuity(series)
    used = _used_samples(series, time_offset, name)
    measured = np.column_stack([series.x[used], series.y[used], series.theta[used]])
    t = series.t_pose[used] + time_offset
    loops = find_loops(t, measured)
    bidirectional = {loop.direction for loop in loops} == {"cw", "ccw"}
    paths, errors, umbmark = [], [], []
    for params, sensor_pose in (nominal, calibrated):
        odometry = dead_reckon(series, time_offset, params, used)
        path = sensor_track(measured[0], odometry, sensor_pose)
        paths.append(path)
        errors.append(PathErrors.of(path, measured))
        if bidirectional:
            umbmark.append(UMBmarkErrors.of(loops, measured, odometry, sensor_pose))
    return LogValidation(name, t, measured, paths[0], paths[1], errors[0], errors[1],
                         UMBmark(tuple(loops), *umbmark) if bidirectional else None)


@dataclass(frozen=True, eq=False)
class ValidationResult:
    """Validation over several logs: ``logs`` (per log) and, overall, ``nominal`` and
    ``calibrated``, the mean of each metric over the logs (m, rad)."""

    logs: tuple[LogValidation, ...]
    nominal: PathErrors
    calibrated: PathErrors

    @property
    def ratio(self) -> dict[str, float | None]:
        """Overall calibrated / nominal: the ratio of the means."""
        return self.calibrated.ratio(self.nominal)

    @property
    def verdict(self) -> Verdict:
        """Overall: better, no better or worse than nominal, on the means over the logs
        (:mod:`excite.validation.verdict`)."""
        return _verdict(self.nominal, self.calibrated)

    def to_dict(self) -> dict:
        """The ``excite validate --json`` object."""
        return {"logs": [log.to_dict() for log in self.logs],
                "overall": {"nominal": self.nominal.to_dict(),
                            "calibrated": self.calibrated.to_dict(), "ratio": self.ratio,
                            "verdict": self.verdict}}

    def summary(self) -> str:
        """A table per log and overall, and the verdict (text,
        :func:`excite.validation.report.summary`)."""
        from excite.validation.report import summary

        return summary(self)


def summarize(validations: Sequence[LogValidation]) -> ValidationResult:
    """Combine per-log validations: overall means of each metric (at least one log)."""
    if not validations:
        raise ValueError("summarize needs at least one log validation")
    return ValidationResult(tuple(validations),
                            PathErrors.mean([v.nominal for v in validations]),
                            PathErrors.mean([v.calibrated for v in validations]))


# --------------------------------------------------------------------------- params file


@dataclass(frozen=True)
class ParamsFile:
    """A calibration result file (``excite calibrate --json``): params (m), sensor_pose (in
    the body frame, None for the axle model) and, when the file holds a "nominal" key,
    the nominal wheel parameters (m)."""

    params: Params
    sensor_pose: SensorPose | None
    nominal: Params | None


def _numbers(path: str, value: object, key: str, names: tuple[str, ...], positive: bool
             ) -> list[float]:
    """The numbers ``names`` of the JSON object ``value`` (the file's ``key``): finite, and
    positive when asked; DataError naming the file and key otherwise."""
    what = "a positive length in meters" if positive else "a finite number"
    if not isinstance(value, Mapping):
        raise DataError(f"{path}: {key} must be an object with {', '.join(names)}")
    numbers = []
    for name in names:
        number = value.get(name)
        if isinstance(number, int) and not isinstance(number, bool):
            number = float(number) if abs(number) < 2**1023 else math.inf  # no OverflowError
        if (isinstance(number, bool) or not isinstance(number, int | float)
                or not math.isfinite(number) or (positive and number <= 0)):
            raise DataError(f"{path}: {key}.{name} must be {what}, got {json.dumps(number)}")
        numbers.append(float(number))
    return numbers


def read_params_file(path: str) -> ParamsFile:
    """Read the JSON printed by ``excite calibrate --json``: "params" {r_L, r_R, b} (m,
    positive), "sensor_pose" {x, y, theta} (m, m, rad) or null/absent, and optionally
    "nominal" {r_L, r_R, b} (m). Raises DataError naming the file for a missing or unreadable
    file, invalid JSON, or missing / invalid values."""
    text = read_text(path, kind="JSON")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    except RecursionError:
        raise DataError(f"{path}: not valid JSON: nested too deeply") from None
    if not isinstance(data, dict):
        raise DataError(f"{path}: expected a JSON object (the output of excite calibrate "
                        "--json)")
    if "params" not in data:
        raise DataError(f"{path}: no \"params\" key (expected the output of excite calibrate "
                        "--json)")
    lengths, pose, nominal = data["params"], data.get("sensor_pose"), data.get("nominal")
    return ParamsFile(
        Params(*_numbers(path, lengths, "params", ("r_L", "r_R", "b"), positive=True)),
        None if pose is None else SensorPose(
            *_numbers(path, pose, "sensor_pose", ("x", "y", "theta"), positive=False)),
        None if nominal is None else Params(
            *_numbers(path, nominal, "nominal", ("r_L", "r_R", "b"), positive=True)))
