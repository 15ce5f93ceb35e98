"""Data sets given as paths: what each one is, reading a log with its clock offset settled,
and cutting logs into segments, with the options that govern it (:class:`LogOptions`, the
settings of ``excite calibrate``, ``segment`` and ``validate``, defined here once).

Each input is one of: a segment file (segment CSV or Censi tuple file), a time-series CSV
holding both streams, a pair of adjacent time-series CSVs (one with the encoder stream
``t,phi_L,phi_R``, the other with the pose stream ``t,x,y,theta``, in either order), or a ROS
bag (``.bag``, ``.db3``, ``.mcap``, or a rosbag2 directory).

Nothing here prints. What a user should hear about a log (a CSV's columns not read and units
converted; the clock offset its data suggest when none was given; wheel angles that were
unwrapped, for a log followed whole) comes back as notes, one line each (:attr:`Log.notes`),
and is passed as it arises to an ``on_note`` function when one is given (the command line
prints them so, in order with everything else, also when a later step fails).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from excite.errors import DataError
from excite.logs.bag_paths import bag_path_problem, is_bag_path
from excite.logs.bag_reader import JOINT_STATES, read_bag_log
from excite.logs.clock_steps import corrected_clock_steps
from excite.logs.continuity import Gap, check_continuity, on_track, stale_poses
from excite.logs.segmentation import (
    OFF_TRACK,
    SLOWEST_PERIOD,
    SegmentedLog,
    segment_timeseries,
)
from excite.logs.segments import Segments, check_not_utf16, form_problem, load_segments
from excite.logs.speed_lag import lag_corrected, speed_lag
from excite.logs.time_offset import (
    MAX_TIME_OFFSET,
    OffsetHint,
    estimate_time_offset,
    noticeable_time_offset,
    rejected_offset,
)
from excite.logs.timeseries import TimeSeries, during, unwrapped_words, without_poses
from excite.logs.timeseries_csv import read_timeseries
from excite.logs.timeseries_header import header_hint, header_problem, timeseries_streams

__all__ = ["LogOptions", "DEFAULT_LOG_OPTIONS", "Input", "Log", "Part", "OnNote",
           "note_taker", "note_unused_options", "group_inputs", "read_log", "segment_log",
           "segment_inputs", "segment_logs"]

#: What is told each note for the user as it arises (the command line prints it).
OnNote = Callable[[str], None]


@dataclass(frozen=True)
class LogOptions:
    """How time-series logs and bags are read and cut into segments (docs/formats.md,
    "Time-series logs"); the defaults are the command line's.

    window (s): segment duration (fixed windows). min_distance (m), min_angle (rad): keyframes
    instead of windows, a new segment once the sensor has moved min_distance or turned
    min_angle from the last keyframe (either or both; None: not used). split_at_gaps: cut a log
    at gaps longer than the window (a motion-capture body out of view, a driver's pause; no
    segment spans one, and a note names them) instead of refusing it. ticks_per_rev: encoder
    ticks per wheel revolution, converting ticks_L, ticks_R columns to rad (None: the wheel
    columns are angles in rad). time_offset: pose time + time_offset = encoder time (s);
    "estimate" finds it from the data; None uses 0 unless the data reject a zero offset, and
    then the offset they show (with a note).
    max_time_offset (s): estimated offsets are searched within +- this. Bags only:
    joint_states, the topic of the JointState messages; left_wheel, right_wheel, the wheel
    joint names in them (required); the sensor's poses from exactly one of pose_topic (a
    PoseStamped, PoseWithCovarianceStamped or Odometry topic) and tf, (parent, child): the
    child frame's pose in the parent frame from /tf. start, end (s): read only the samples
    stamped within [start, end] (each stream's own stamps; None: from the first, to the last).
    """

    window: float = 1.0
    min_distance: float | None = None
    min_angle: float | None = None
    split_at_gaps: bool = True
    ticks_per_rev: float | None = None
    time_offset: float | Literal["estimate"] | None = None
    max_time_offset: float = MAX_TIME_OFFSET
    joint_states: str = JOINT_STATES
    left_wheel: str | None = None
    right_wheel: str | None = None
    pose_topic: str | None = None
    tf: tuple[str, str] | None = None
    start: float | None = None
    end: float | None = None


#: The options the command line starts from (its defaults are read from here).
DEFAULT_LOG_OPTIONS = LogOptions()

#: The options only bags read, and those only logs (time-series and bags) read.
BAG_ONLY = ("joint_states", "left_wheel", "right_wheel", "pose_topic", "tf")
LOG_ONLY = ("window", "min_distance", "min_angle", "split_at_gaps", "ticks_per_rev",
            "time_offset", "max_time_offset", "start", "end")


def _flag(name: str, value: object) -> str:
    """The command-line flag that sets option ``name`` to ``value`` (--no-X for a switch
    turned off)."""
    return ("--no-" if value is False else "--") + name.replace("_", "-")


def note_unused_options(inputs: Sequence[Input], options: LogOptions, note: OnNote) -> None:
    """Tell ``note`` of the options set away from their defaults that none of ``inputs``
    reads (bag options without a bag, log options with segment files only), by their
    command-line flags: a user who gives them expects them to do something."""
    kinds = {source.kind for source in inputs}
    for only, readers, wanted, missing in (
            (BAG_ONLY, {"bag"}, "bags", "no input is a bag"),
            (LOG_ONLY, {"bag", "timeseries"}, "time-series logs and bags",
             "every input is a segment file")):
        if kinds & readers:
            continue
        unused = [name for name in only
                  if getattr(options, name) != getattr(DEFAULT_LOG_OPTIONS, name)]
        if unused:
            flags = ", ".join(_flag(name, getattr(options, name)) for name in unused)
            note(f"{flags} ignored: read from {wanted} only, and {missing}")


@dataclass(frozen=True)
class Input:
    """One data set: ``kind`` is "segments", "timeseries" or "bag"; ``paths`` its one or two
    files; ``name`` how messages call it."""

    kind: str
    paths: tuple[str, ...]

    @property
    def name(self) -> str:
        return "+".join(self.paths)


#: Where a log's clock offset came from (:class:`Log`).
OffsetSource = Literal["given", "estimated", "detected", "default"]
#: How to overrule a detected clock offset.
OVERRULE = "--time-offset 0 for none, --time-offset S to give one"


@dataclass(frozen=True)
class Log:
    """A time-series log read from an input, with the clock offset used for it (s; pose time
    + offset = encoder time) and where that offset came from: "given" (a number in
    LogOptions.time_offset), "estimated" ("estimate"), "detected" (none given, and the data
    reject a zero offset: their estimate, ``hint.offset``) or "default" (none given: 0).
    Without a given offset, hint says what the data suggest when it is clearly not zero
    (:func:`excite.logs.time_offset.noticeable_time_offset`); with a given one (wheel angles,
    not integrated speeds), what they suggest when they reject it
    (:func:`excite.logs.time_offset.rejected_offset`: the calibration's fit then fails);
    else None. skipped: for a bag,
    the messages the reader skipped, in one line (None for a CSV log). notes: what the user
    should hear about the log, one line each, in order (each starts with the log's name).
    speed_lag: the time constant (s) of the wheel speeds' lag the series was corrected for
    (:mod:`excite.logs.speed_lag`), None when it was not."""

    name: str
    series: TimeSeries
    time_offset: float
    offset_source: OffsetSource
    hint: OffsetHint | None = None
    skipped: str | None = None
    notes: tuple[str, ...] = ()
    speed_lag: float | None = None

    def offset_text(self) -> str:
        """The offset and its source, e.g. '-0.0098 s (detected: the data reject a zero offset;
        --time-offset 0 for none, --time-offset S to give one)' or '+0.0000 s (default; the
        data suggest an offset beyond +-1 s: --time-offset estimate --max-time-offset S)'."""
        if self.offset_source == "detected":
            how = f"detected: the data reject a zero offset; {OVERRULE}"
        else:
            how = self.offset_source + (f"; {self.hint.text()}" if self.hint is not None else "")
        return f"{self.time_offset:+.4f} s ({how})"


@dataclass(frozen=True)
class Part:
    """One input as segments: the input, its segments, and for a log the log and its
    segmentation (None for a segment file)."""

    source: Input
    segments: Segments
    log: Log | None = None
    cut: SegmentedLog | None = None

    @property
    def notes(self) -> tuple[str, ...]:
        """The log's notes (none for a segment file)."""
        return () if self.log is None else self.log.notes

    def describe(self) -> str:
        """What was read, in one line (a log: segments kept, dropped and why, time offset; a
        bag also the messages skipped)."""
        if self.cut is None or self.log is None:
            return f"{self.source.name}: {len(self.segments)} segments"
        report = self.cut.report
        offset = f"; time offset {self.log.offset_text()}"
        if self.log.speed_lag is not None:
            offset += f"; wheel speeds' lag {self.log.speed_lag:.4f} s (corrected)"
        unwrapped = f"; {report.unwrapped_text()}" if report.unwrapped_text() else ""
        skipped = "" if self.log.skipped is None else f"; messages skipped: {self.log.skipped}"
        return (f"{self.source.name}: {report.n_segments} segments; dropped: "
                f"{report.counts_text()}{unwrapped}{skipped}{offset}")


def note_taker(notes: list[str], on_note: OnNote | None) -> OnNote:
    """A function that keeps each note it is given in ``notes`` and passes it on to
    ``on_note`` (when given) at once."""

    def note(text: str) -> None:
        notes.append(text)
        if on_note is not None:
            on_note(text)

    return note


def _kind(path: str) -> tuple[str, frozenset[str]]:
    """The kind of input a path is, and for a time-series CSV the streams it holds."""
    problem = bag_path_problem(path)
    if problem is not None:
        raise DataError(problem)
    if is_bag_path(path):
        return "bag", frozenset()
    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    try:
        with open(path, "rb") as handle:
            start = handle.read(2)
    except OSError:
        start = b""  # a directory or an unreadable file: reading it says what is wrong
    check_not_utf16(path, start)
    streams = timeseries_streams(path)
    return ("timeseries" if streams else "segments"), streams


def _lone_stream(path: str, streams: frozenset[str]) -> DataError:
    (only,) = streams
    return DataError(f"{path}: has only the {only} stream; give the file with the other "
                     f"stream right after it{header_hint(path)}")


def _before(inputs: list[Input]) -> DataError | None:
    """The header problem of the input before a lone stream's file, when it is a time-series
    CSV that cannot be read (most often that stream's partner, under names not read)."""
    if inputs and inputs[-1].kind == "timeseries" and len(inputs[-1].paths) == 1:
        return header_problem(inputs[-1].paths[0])
    return None


def _unpaired(first: str, streams: frozenset[str], path: str, kind: str) -> DataError:
    """The error for a one-stream CSV whose next path is not the other stream's file: when
    that path is not a time-series CSV at all (a header of neither format, or none, as a
    motion-capture export's header block reads), or one whose header cannot be read (a
    stream without its heading), its own problem; else :func:`_lone_stream`."""
    if kind == "segments":
        problem = form_problem(path) or DataError(
            f"{path}: no header of a time-series stream (t with x,y,theta or phi_L,phi_R; "
            "names and units: docs/formats.md)")
    elif kind == "timeseries" and (unread := header_problem(path)) is not None:
        problem = unread
    else:
        return _lone_stream(first, streams)
    (only,) = streams
    other = "pose" if only == "encoder" else "encoder"
    return DataError(f"{problem} (given after {first}, which has only the {only} stream: "
                     f"this file should hold the {other} stream)")


def _not_a_log(source: Input) -> DataError:
    """The error for an input that is no log: what keeps it from being a segment file by its
    form (an empty file, a folder, binary data, a header of neither format), or that it is
    one."""
    return form_problem(source.name) or DataError(
        f"{source.name}: a segment file, not a time-series log or bag")


def group_inputs(paths: Sequence[str]) -> list[Input]:
    """The data sets of a list of paths, in order (see the module docstring)."""
    inputs: list[Input] = []
    pending: tuple[str, frozenset[str]] | None = None
    for path in paths:
        kind, streams = _kind(path)
        if pending is not None:
            first, first_streams = pending
            if kind != "timeseries" or len(streams) != 1 or streams == first_streams:
                raise _before(inputs) or _unpaired(first, first_streams, path, kind)
            inputs.append(Input("timeseries", (first, path)))
            pending = None
        elif kind == "timeseries" and len(streams) == 1:
            pending = (path, streams)
        else:
            inputs.append(Input(kind, (path,)))
    if pending is not None:
        raise _before(inputs) or _lone_stream(*pending)
    return inputs


def _read_series(source: Input, options: LogOptions, note: OnNote
                 ) -> tuple[TimeSeries, str | None]:
    """The log of a time-series or bag input, and for a bag the messages skipped; the
    reader's notes (a CSV's columns not read and units converted, a bag's stamps) told to
    ``note``."""
    if source.kind == "bag":
        if not options.left_wheel or not options.right_wheel:
            raise DataError(f"{source.name}: a bag needs --left-wheel and --right-wheel "
                            "(joint names in the JointState messages)")
        if options.left_wheel == options.right_wheel:
            raise DataError(f"{source.name}: --left-wheel and --right-wheel name the same "
                            f"joint {options.left_wheel!r}")
        if (options.pose_topic is None) == (options.tf is None):
            raise DataError(f"{source.name}: a bag needs exactly one pose source: "
                            "--pose-topic TOPIC or --tf PARENT:CHILD")
        bag = read_bag_log(source.paths[0], options.left_wheel, options.right_wheel,
                           pose_topic=options.pose_topic, tf=options.tf,
                           joint_states=options.joint_states)
        for line in bag.notes:
            note(line)
        return bag.series, bag.skipped_text()
    if source.kind == "timeseries":
        return read_timeseries(source.paths, ticks_per_rev=options.ticks_per_rev,
                               on_note=note), None
    raise _not_a_log(source)


def _clock_offset(series: TimeSeries, options: LogOptions
                  ) -> tuple[float, OffsetSource, OffsetHint | None]:
    """The log's clock offset (s), where it came from, and what the data suggest instead:
    without a given offset when it is clearly not zero, their estimate then used when it lies
    within the search range ("detected"; a stamp latency of a few ms shifts a fitted sensor
    mounting by many of its std), else 0 ("default"); with a given one (of wheel angles, not
    integrated speeds) when the data reject it (:func:`rejected_offset`)."""
    if options.time_offset == "estimate":
        offset = estimate_time_offset(series, max_offset=options.max_time_offset)
        return offset, "estimated", None
    if options.time_offset is not None:  # tested, unless the wheel angles are integrated
        given = float(options.time_offset)  # speeds (their own lag: the user's to settle)
        return given, "given", (None if series.speeds else
                                rejected_offset(series, given, options.max_time_offset))
    hint = noticeable_time_offset(series, max_offset=options.max_time_offset)
    if hint is not None and hint.offset is not None:
        return hint.offset, "detected", hint
    return 0.0, "default", hint


def _check_time_unit(source: Input, series: TimeSeries) -> None:
    """DataError when a stream's samples are more than SLOWEST_PERIOD apart (median): times
    in ms, us or ns read as s, before anything is said about the clocks."""
    for name, t, where in (("encoder", series.t_enc, series.source[0]),
                           ("pose", series.t_pose, series.source[1])):
        period = float(np.median(np.diff(t)))
        if period >= SLOWEST_PERIOD:
            way = ("a unit in the header converts them, e.g. t [ms]" if source.kind ==
                   "timeseries" else "a bag's stamps are in s")
            raise DataError(f"{where}: {name} samples every {period:.6g} s (median): times "
                            f"are in s, are these ms, us or ns? ({way})")


def read_log(source: Input, options: LogOptions, *, whole: bool = False,
             on_note: OnNote | None = None) -> Log:
    """Read one time-series or bag input, correct the clock steps at its gaps
    (:mod:`excite.logs.clock_steps`) and settle its clock offset. whole: the log will be
    followed whole (dead reckoning, not segments): a jump in either stream is an error, before
    anything is said about the clocks, and unwrapped wheel angles are noted (segmentation
    reports them instead). on_note: told each of the log's notes as it arises."""
    notes: list[str] = []
    note = note_taker(notes, on_note)
    series, skipped = _read_series(source, options, note)
    series = during(series, options.start, options.end)
    _check_time_unit(source, series)
    stale = stale_poses(series)
    if stale.size:
        series = without_poses(series, stale)
        note(f"{source.name}: {stale.size} pose samples repeat the one before them exactly "
             "while the wheels turned (a pose source that froze, or held a placeholder while "
             "it lost the body): left out")
    series, steps = corrected_clock_steps(series, options.max_time_offset)
    for line in steps:
        note(line)
    if whole:
        series, off = on_track(series)
        if off:
            note(f"{source.name}: {off} pose sample(s) {OFF_TRACK}")
        check_continuity(series)
        unwrapped = unwrapped_words(series.unwrapped_wheels, series.unwrapped_counters)
        if unwrapped:
            note(f"{source.name}: {unwrapped}")
    offset, offset_source, hint = _clock_offset(series, options)
    lag = None
    if series.speeds and offset_source == "detected" and offset > 0:
        lag = speed_lag(series, options.max_time_offset)
        if lag is not None:
            note(f"{source.name}: the wheel speeds lag the motion as a low-pass filter of "
                 f"time constant {lag:.4f} s would (a driver's filtered velocity), which "
                 f"explains the poses better than a clock offset of {offset:+.4f} s: the "
                 f"wheel angles are corrected for it (phi + {lag:.4g} s x omega); "
                 "--time-offset 0 for neither, --time-offset S for an offset instead")
            series = lag_corrected(series, lag)
            offset, offset_source, hint = _clock_offset(series, options)
    if offset_source == "detected":
        note(f"{source.name}: the pose stamps are offset from the encoder stamps by "
             f"{offset:+.4f} s (pose time + offset = encoder time): the data reject a zero "
             f"offset (a stamp latency), so it is used; {OVERRULE}")
    elif hint is not None and offset_source == "given":
        note(f"{source.name}: the data reject the given clock offset {offset:+.4f} s (pose "
             f"time + offset = encoder time): {hint.text()}")
    elif hint is not None:
        note(f"{source.name}: the clocks of the encoder and pose streams seem offset (pose "
             "time + offset = encoder time), but none was given and 0 is used; "
             f"{hint.text()}")
    return Log(source.name, series, offset, offset_source, hint, skipped, tuple(notes), lag)


def segment_log(log: Log, options: LogOptions) -> SegmentedLog:
    """Cut a log into segments with the options' settings and the log's clock offset."""
    return segment_timeseries(log.series, window=options.window,
                              min_distance=options.min_distance, min_angle=options.min_angle,
                              time_offset=log.time_offset,
                              on_gap="split" if options.split_at_gaps else "error")


def _note_long_gaps(source: Input, gaps: Sequence[Gap], window: float,
                    on_note: OnNote | None) -> None:
    """Tell ``on_note`` where a log was cut at gaps longer than the window (s)."""
    long = [gap for gap in gaps if gap.duration > window]
    if long and on_note is not None:
        worst = max(long, key=lambda gap: gap.duration)
        on_note(f"{source.name}: cut at {len(long)} gap(s) longer than the window ({window:g} "
                f"s), the longest {worst.duration:.3f} s in the {worst.stream} stream "
                f"({worst.t_start:.3f}-{worst.t_end:.3f} s): no segment spans one; "
                "--no-split-at-gaps refuses such a log")


def segment_inputs(inputs: Sequence[Input], options: LogOptions, *,
                   on_note: OnNote | None = None) -> list[Part]:
    """Every input as segments, in order: segment files are read, logs read and cut (their
    notes on the parts, and told to on_note as they arise)."""
    parts = []
    for source in inputs:
        if source.kind == "segments":
            parts.append(Part(source, load_segments(source.paths[0], on_note=on_note)))
        else:
            log = read_log(source, options, on_note=on_note)
            cut = segment_log(log, options)
            _note_long_gaps(source, cut.report.gaps, options.window, on_note)
            parts.append(Part(source, cut.segments, log, cut))
    return parts


def segment_logs(paths: Sequence[str], options: LogOptions = DEFAULT_LOG_OPTIONS, *,
                 on_note: OnNote | None = None) -> list[Part]:
    """The time-series logs and bags of ``paths`` (a pair of stream CSVs is one log; no
    segment files) read and cut into segments, one part per log, as
    :func:`segment_inputs` does."""
    inputs = group_inputs(paths)
    segment_files = [source for source in inputs if source.kind == "segments"]
    if segment_files:
        raise _not_a_log(segment_files[0])
    if on_note is not None:
        note_unused_options(inputs, options, on_note)
    return segment_inputs(inputs, options, on_note=on_note)
