"""Calibration and validation from files: segment files, time-series logs and ROS bags, read
with :class:`~excite.logs.inputs.LogOptions` (what ``excite calibrate`` and ``excite validate``
do, without the command line).

:func:`calibrate_logs` is a recipe of named stages: group the inputs and keep back whole logs
for validation (``holdout``) -> read and segment each input -> check each one's wiring and
pose source -> pool the segments -> calibrate (:func:`excite.calibration.pipeline.calibrate`)
-> with several inputs, test whether they agree (each calibrated alone,
:func:`excite.calibration.heterogeneity.across_logs`) -> fail the fit where the data reject a
given clock offset -> validate on the held-out logs.
:func:`validate_logs` dead-reckons logs with a calibrated and a nominal robot
(:mod:`excite.validation.dead_reckoning`).

Nothing here prints: the notes for the user come back in the results, and are passed as they
arise to an ``on_note`` function when one is given (the command line prints them so).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from numpy.typing import ArrayLike

from excite.calibration.heterogeneity import HeterogeneityOption, across_logs, applied
from excite.calibration.options import SensorPoseOption
from excite.calibration.pipeline import calibrate
from excite.calibration.result import CalibrationResult
from excite.calibration.solver import Loss
from excite.calibration.wiring import check_pose_source, check_wiring
from excite.core.kinematics import Params
from excite.core.plausible import METRE_RADII, metre_radii
from excite.errors import DataError
from excite.logs.continuity import encoder_stretches
from excite.logs.inputs import (
    DEFAULT_LOG_OPTIONS,
    Input,
    Log,
    LogOptions,
    OnNote,
    Part,
    group_inputs,
    note_taker,
    note_unused_options,
    read_log,
    segment_inputs,
    segment_log,
)
from excite.logs.segment_bounds import first_impossible
from excite.logs.segments import MIN_SEGMENTS, Segments
from excite.logs.timeseries import TimeSeries, during
from excite.validation.dead_reckoning import Robot, ValidationResult, summarize, validate_log

__all__ = ["LogCalibration", "ValidatedLogs", "calibrate_logs", "validate_logs"]


@dataclass(frozen=True)
class ValidatedLogs:
    """Logs dead-reckoned with a calibrated and a nominal robot.

    result: the metrics per log and overall
    (:class:`~excite.validation.dead_reckoning.ValidationResult`; its ``summary()`` and
    ``to_dict()`` are ``excite validate``'s report and JSON). notes: what the user should hear
    about the logs, one line each, in order (wheel angles that were unwrapped; a clock offset
    the data suggest when none was given).
    """

    result: ValidationResult
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class LogCalibration:
    """A calibration from segment files, logs and bags.

    result: the :class:`~excite.calibration.result.CalibrationResult`. parts: the inputs
    calibrated on, in order, each as segments (``Part.describe()`` says in one line what was
    read, kept and dropped). notes: what the user should hear, one line each, in order: the
    logs' notes (a clock offset the data suggest when none was given), pose sources whose
    headings follow the wheel angles exactly
    (:func:`~excite.calibration.wiring.check_pose_source`), then the held-out logs' notes.
    holdout: the validation on the held-out logs against the nominal robot, None without a
    hold-out.
    """

    result: CalibrationResult
    parts: tuple[Part, ...]
    notes: tuple[str, ...] = ()
    holdout: ValidatedLogs | None = None


def _split_holdout(inputs: list[Input], fraction: float) -> tuple[list[Input], list[Input]]:
    """(inputs to calibrate on, logs kept back): the last round(fraction * logs) logs, >= 1."""
    if not fraction:
        return inputs, []
    logs = [source for source in inputs if source.kind != "segments"]
    if len(logs) < 2:
        raise DataError("--holdout keeps back whole logs: give at least 2 time-series logs "
                        "or bags")
    count = min(max(1, round(fraction * len(logs))), len(logs) - 1)
    held = logs[-count:]
    return [source for source in inputs if source not in held], held


def _refuse_repeated(parts: Sequence[Part]) -> None:
    """DataError when two inputs hold the same segments (a file given twice, or a copy of
    it): pooled, they would count every segment twice and halve the variances."""
    seen: dict[bytes, str] = {}
    for part in parts:
        key = part.segments.as_array().tobytes()
        if key in seen:
            raise DataError(f"{seen[key]} and {part.source.name} hold the same data: give "
                            "each log once (pooled twice, every std would be 1/sqrt(2) of "
                            "what the data say)")
        seen[key] = part.source.name


def _check_part(part: Part, initial: Params | None, note: OnNote) -> None:
    """DataError when a part's heading changes contradict its wheels (wiring), or its poses
    are the nominal robot's own dead reckoning; a note when a log's headings follow its wheel
    angles exactly (a segment file, most often made rather than recorded, is not noted)."""
    _check_conventions(part)
    if part.log is None:
        return
    start = None if initial is None else tuple(initial.as_array().tolist())
    text = check_pose_source(part.segments, part.source.name, start)
    if text is not None:
        note(text)


#: How a log's values in other units are read right, in a hint: a time-series CSV's header
#: units, and a bag's.
LOG_UNITS = ("a unit in the header converts, e.g. x (mm) for positions in mm, phi_L [deg] "
             "for wheel angles in degrees")
BAG_UNITS = "a bag's poses must be in m, its JointState positions in rad"


def _check_plausible(part: Part) -> None:
    """DataError naming a log and the time of its first segment that no robot drives (values
    in other units, :func:`~excite.logs.segment_bounds.first_impossible`), with the log's
    own columns in the hint."""
    seg = part.segments
    if seg.t_start is None or seg.t_end is None:
        return
    impossible = first_impossible(seg.dphi_L, seg.dphi_R, seg.dx, seg.dy, seg.dtheta,
                                  seg.t_end - seg.t_start,
                                  units=BAG_UNITS if part.source.kind == "bag" else LOG_UNITS,
                                  rows="segments")
    if impossible is not None:
        k, why = impossible
        raise DataError(f"{part.source.name}: the segment from t = {seg.t_start[k]:.6g} s: "
                        f"{why}")


def _check_wired(source: Input, log: Log, options: LogOptions) -> None:
    """DataError when a log to dead-reckon breaks the model's conventions as calibration
    checks them on its segments (a wheel that runs backwards, left and right swapped, values
    in other units): dead reckoning it would compare two meaningless paths. A log too short
    to cut into segments is not checked."""
    try:
        cut = segment_log(log, options)
    except DataError:
        return
    _check_conventions(Part(source, cut.segments, log, cut))


def _check_conventions(part: Part) -> None:
    """DataError when a part's heading changes contradict its wheels (wiring) or, for a log,
    a segment no robot drives (values in other units)."""
    check_wiring(part.segments, part.source.name)
    if part.log is not None:
        _check_plausible(part)


def _pooled(parts: Sequence[Part]) -> Segments:
    """The segments of every part as one set (at least MIN_SEGMENTS)."""
    segments = Segments.concatenate([part.segments for part in parts])
    if len(segments) < MIN_SEGMENTS:
        raise DataError(f"{len(segments)} segment(s) in total; at least {MIN_SEGMENTS} are "
                        "needed")
    return segments


def _validated(inputs: Sequence[Input], options: LogOptions, calibrated: Robot,
               nominal: Robot, on_note: OnNote | None, *,
               note_unused: bool = False) -> ValidatedLogs:
    """Each log read whole and dead-reckoned with both robots, in order; ``note_unused``:
    first note the options none of them reads (the held-out logs of calibrate_logs are
    noted with its other inputs)."""
    notes: list[str] = []
    note = note_taker(notes, on_note)
    if note_unused:
        note_unused_options(inputs, options, note)
    validations = []
    for source in inputs:
        log = read_log(source, options, whole=True, on_note=note)
        _check_wired(source, log, options)
        for name, series in _between_encoder_gaps(log, options.window, note):
            validations.append(validate_log(series, log.time_offset, calibrated, nominal,
                                            name=name))
    return ValidatedLogs(summarize(validations), tuple(notes))


def _between_encoder_gaps(log: Log, window: float, note: OnNote
                          ) -> list[tuple[str, TimeSeries]]:
    """The log whole, or its parts between encoder gaps longer than the window (s, as
    calibrate cuts logs), each named (the wheels' path across a gap is unknown: each part is
    dead-reckoned from its own first pose), with a note; parts with fewer than 2 samples of a
    stream are left out (a DataError when none is left)."""
    stretches, gaps = encoder_stretches(log.series, window)
    if not gaps:
        return [(log.name, log.series)]
    pieces = []
    for start, end in stretches:
        try:
            pieces.append(during(log.series, start, end))
        except DataError:  # too short to follow
            continue
    if not pieces:
        raise DataError(f"{log.name}: no part between its encoder gaps holds 2 samples of "
                        "each stream")
    longest = max(gaps, key=lambda gap: gap.duration)
    note(f"{log.name}: cut at {len(gaps)} encoder gap(s) longer than the window ({window:g} "
         f"s), the longest {longest.duration:.3f} s ({longest.location}): the wheels' path "
         f"across a gap is unknown, so each of its {len(pieces)} parts is dead-reckoned from "
         "its own first pose")
    return [(f"{log.name} (part {k + 1} of {len(pieces)})", piece)
            for k, piece in enumerate(pieces)]


def validate_logs(paths: Sequence[str], calibrated: Robot, nominal: Robot,
                  options: LogOptions = DEFAULT_LOG_OPTIONS, *,
                  on_note: OnNote | None = None) -> ValidatedLogs:
    """Dead-reckon each time-series log or bag of ``paths`` (a pair of stream CSVs is one log)
    with the calibrated and the nominal robot, each (Params, SensorPose or None), and compare
    both with the log's external poses (:func:`excite.validation.dead_reckoning.validate_log`).
    options: how the logs are read (the segmentation options are not used). on_note: told
    each note as it arises.

    Raises DataError for a segment file, a log that cannot be read or whose streams jump, one
    that breaks the model's conventions as calibration checks them on its segments (a wheel
    that runs backwards, values in other units), and as validate_log does.
    """
    return _validated(group_inputs(paths), options, calibrated, nominal, on_note,
                      note_unused=True)


def _with_rejected_offsets(result: CalibrationResult, parts: Sequence[Part]
                           ) -> CalibrationResult:
    """The result with its fit failed when the data reject a clock offset the user gave
    (:attr:`Log.hint` of a "given" offset): a wrong offset bends every segment where the
    wheel speeds change, and estimated noise levels would take that for noise. The reason
    comes first in the fit's message."""
    reasons = [f"the data reject the clock offset given for {part.log.name} "
               f"({part.log.time_offset:+.4f} s): {part.log.hint.text()}"
               for part in parts if part.log is not None and part.log.hint is not None
               and part.log.offset_source == "given"]
    if not reasons:
        return result
    message = "; ".join(reasons) + ("" if result.fit.ok else f"; and {result.fit.message}")
    return replace(result, fit=replace(result.fit, ok=False, message=message))


def calibrate_logs(
    paths: Sequence[str],
    options: LogOptions = DEFAULT_LOG_OPTIONS,
    *,
    initial: Params | None = None,
    sigma: ArrayLike | None = None,
    loss: Loss = "linear",
    sensor_pose: SensorPoseOption = "auto",
    trim: float = 0.0,
    holdout: float = 0.0,
    on_note: OnNote | None = None,
    heterogeneity: HeterogeneityOption = "random",
) -> LogCalibration:
    """Calibrate r_L, r_R, b (and the sensor pose) on the segment files, time-series logs and
    bags of ``paths``, one data set (a pair of stream CSVs is one log); the stages are listed
    in the module docstring.

    options: how the logs are read and cut. initial (m): the nominal robot and starting point
    (None: found from the data). sigma, loss, sensor_pose, trim: as
    :func:`excite.calibration.pipeline.calibrate`, which also gets options.ticks_per_rev.
    holdout: the fraction of the logs (whole logs, the last ones, at least one; segment files
    are never kept back) not calibrated on but validated on, against ``initial`` with the
    calibrated sensor pose; it needs ``initial`` and at least 2 logs. on_note: told each note
    as it arises (they are in the result too). heterogeneity: as
    :func:`~excite.calibration.pipeline.calibrate` for one input (kinds of motion); with
    several inputs the test is between them instead, each calibrated alone
    (:func:`excite.calibration.heterogeneity.across_logs`).

    Raises DataError for bad inputs or settings: as the readers, segmentation and
    :func:`~excite.calibration.pipeline.calibrate` do, for miswired wheels or poses that are
    the nominal robot's own dead reckoning (:mod:`excite.calibration.wiring`), and for fewer
    than MIN_SEGMENTS segments in all.
    """
    if holdout and initial is None:
        raise DataError("--holdout compares with the nominal robot: give --init RL,RR,B (m)")
    inputs = group_inputs(paths)
    used, held = _split_holdout(inputs, holdout)
    notes: list[str] = []
    note = note_taker(notes, on_note)
    note_unused_options(inputs, options, note)
    parts = segment_inputs(used, options, on_note=note)
    _refuse_repeated(parts)
    for part in parts:
        _check_part(part, initial, note)
    several = len(parts) > 1

    def fit(segments: Segments, pose: SensorPoseOption, test: HeterogeneityOption
            ) -> CalibrationResult:
        return calibrate(segments, initial=initial, sigma=sigma, loss=loss, sensor_pose=pose,
                         trim=trim, ticks_per_rev=options.ticks_per_rev, heterogeneity=test)

    result = fit(_pooled(parts), sensor_pose, "off" if several else heterogeneity)
    if several and heterogeneity != "off":
        test = across_logs([(part.source.name, part.segments) for part in parts], result,
                           lambda segments, pose: fit(segments, pose, "off"), note,
                           sensor_pose)
        result = applied(result, test, heterogeneity)
    result = _with_rejected_offsets(result, parts)
    if initial is None and metre_radii(result.params.r_L, result.params.r_R):
        note(f"{', '.join(paths)}: both wheel radii come out 1 m ({result.params.r_L:.4g} and "
             f"{result.params.r_R:.4g} m), what {METRE_RADII}: if the wheel columns hold "
             "those, these radii scale them (give the robot's nominal values, --init, to "
             "check)")
    validation = None
    if held:
        assert initial is not None  # checked above
        validation = _validated(held, options, (result.params, result.sensor_pose),
                                (initial, result.sensor_pose), note)
    return LogCalibration(result, tuple(parts), tuple(notes), validation)
