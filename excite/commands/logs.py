"""Inputs of calibrate, segment and validate: segment files, time-series CSVs and ROS bags,
with the options that read and cut the logs (one definition, shared by those commands).

Each command-line input is one of: a segment file (segment CSV or Censi tuple file), a
time-series CSV holding both streams, a pair of adjacent time-series CSVs (one with the
encoder stream ``t,phi_L,phi_R``, the other with the pose stream ``t,x,y,theta``, in either
order), or a ROS bag (``.bag``, ``.db3``, ``.mcap``, or a rosbag2 directory).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from excite.commands.args import UsageError
from excite.errors import DataError
from excite.logs.segments import Segments, check_not_utf16
from excite.logs.timeseries import MAX_TIME_OFFSET, OffsetHint, SegmentedLog, TimeSeries

__all__ = ["Log", "Input", "Part", "add_log_options", "group_inputs", "read_log",
           "segment_log", "segment_inputs"]


@dataclass(frozen=True)
class Input:
    """One data set on the command line: ``kind`` is "segments", "timeseries" or "bag";
    ``paths`` its one or two files; ``name`` how messages call it."""

    kind: str
    paths: tuple[str, ...]

    @property
    def name(self) -> str:
        return "+".join(self.paths)


@dataclass(frozen=True)
class Log:
    """A time-series log read from an input, with the clock offset used for it (s; pose time
    + offset = encoder time) and where that offset came from: "given" (--time-offset S),
    "estimated" (--time-offset estimate) or "default" (none given: 0). With the default,
    hint says what offset the data suggest when it is clearly not zero
    (excite.logs.timeseries.noticeable_time_offset), else None. skipped: for a bag, the messages
    the reader skipped, in one line (None for a CSV log)."""

    name: str
    series: TimeSeries
    time_offset: float
    offset_source: Literal["given", "estimated", "default"]
    hint: OffsetHint | None = None
    skipped: str | None = None

    def offset_text(self) -> str:
        """The offset and its source, e.g. '+0.0000 s (default; the data suggest -0.1502 s:
        --time-offset estimate)'."""
        how = self.offset_source + (f"; {self.hint.text()}" if self.hint is not None else "")
        return f"{self.time_offset:+.4f} s ({how})"


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"must be positive and finite, got {text!r}")
    return value


def _offset(text: str) -> float | str:
    if text == "estimate":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of seconds or 'estimate', "
                                         f"got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def _frame_pair(text: str) -> tuple[str, str]:
    parent, sep, child = text.partition(":")
    if not sep or not parent or not child:
        raise argparse.ArgumentTypeError(f"must be PARENT:CHILD, got {text!r}")
    return parent, child


def add_log_options(parser: argparse.ArgumentParser, segmentation: bool = True) -> None:
    """The time-series and bag options (docs/formats.md, "Time-series logs"); with
    ``segmentation`` also the options that cut logs into segments."""
    group = parser.add_argument_group(
        "time-series logs and ROS bags",
        "a CSV with header t,phi_L,phi_R,x,y,theta (or two CSVs, one per stream, given one "
        "after the other), or a ROS bag (.bag, .db3, .mcap, or a rosbag2 directory)")
    if segmentation:
        group.add_argument("--window", type=_positive, default=1.0, metavar="S",
                           help="segment duration in s (default 1)")
        group.add_argument("--min-distance", type=_positive, metavar="M",
                           help="keyframes instead of windows: a new segment after M meters "
                           "...")
        group.add_argument("--min-angle", type=_positive, metavar="RAD",
                           help="... or after turning RAD radians")
        group.add_argument("--split-at-gaps", action="store_true",
                           help="cut the log at gaps longer than the window instead of "
                           "refusing it")
    group.add_argument("--ticks-per-rev", type=_positive, metavar="N",
                       help="encoder resolution: converts ticks_L,ticks_R columns to rad, "
                       "and calibrate models the encoders' rounding (one tick) in the noise "
                       "of the segments cut from logs")
    group.add_argument("--time-offset", type=_offset, metavar="S|estimate",
                       help="pose time + S = encoder time (s, default 0; a note tells when "
                       "the data suggest otherwise), or 'estimate' it from the data")
    group.add_argument("--max-time-offset", type=_positive, default=MAX_TIME_OFFSET,
                       metavar="S", help="estimated time offsets are searched within +-S s "
                       f"(default {MAX_TIME_OFFSET:g})")
    group.add_argument("--joint-states", default="/joint_states", metavar="TOPIC",
                       help="bag topic of sensor_msgs/msg/JointState (default /joint_states)")
    group.add_argument("--left-wheel", metavar="NAME", help="left wheel joint name (bags)")
    group.add_argument("--right-wheel", metavar="NAME", help="right wheel joint name (bags)")
    group.add_argument("--pose-topic", metavar="TOPIC",
                       help="bag topic of the sensor's pose (PoseStamped, "
                       "PoseWithCovarianceStamped or Odometry)")
    group.add_argument("--tf", type=_frame_pair, metavar="PARENT:CHILD",
                       help="the sensor's pose from /tf instead: CHILD's pose in PARENT")


def _kind(path: str) -> tuple[str, frozenset[str]]:
    from excite.logs.bags import bag_path_problem, is_bag_path
    from excite.logs.timeseries import timeseries_streams

    problem = bag_path_problem(path)
    if problem is not None:
        raise DataError(problem)
    if is_bag_path(path):
        return "bag", frozenset()
    if not os.path.exists(path):
        raise UsageError(f"{path}: no such file")
    try:
        with open(path, "rb") as handle:
            start = handle.read(2)
    except OSError:
        start = b""  # a directory or an unreadable file: reading it says what is wrong
    check_not_utf16(path, start)
    streams = timeseries_streams(path)
    return ("timeseries" if streams else "segments"), streams


def _lone_stream(path: str, streams: frozenset[str]) -> UsageError:
    (only,) = streams
    return UsageError(f"{path}: has only the {only} stream; give the file with the other "
                      "stream right after it")


def group_inputs(paths: Sequence[str]) -> list[Input]:
    """The data sets of the command line, in order (see the module docstring)."""
    inputs: list[Input] = []
    pending: tuple[str, frozenset[str]] | None = None
    for path in paths:
        kind, streams = _kind(path)
        if pending is not None:
            first, first_streams = pending
            if kind != "timeseries" or len(streams) != 1 or streams == first_streams:
                raise _lone_stream(first, first_streams)
            inputs.append(Input("timeseries", (first, path)))
            pending = None
        elif kind == "timeseries" and len(streams) == 1:
            pending = (path, streams)
        else:
            inputs.append(Input(kind, (path,)))
    if pending is not None:
        raise _lone_stream(*pending)
    return inputs


def read_log(args: argparse.Namespace, source: Input, whole: bool = False) -> Log:
    """Read one time-series or bag input and settle its clock offset. whole: the log will be
    followed whole (dead reckoning, not segments): a jump in either stream is an error, before
    anything is said about the clocks."""
    from excite.logs.timeseries import (
        check_continuity,
        estimate_time_offset,
        noticeable_time_offset,
        read_timeseries,
        unwrapped_words,
    )

    skipped = None
    if source.kind == "bag":
        from excite.logs.bags import read_bag_log

        if not args.left_wheel or not args.right_wheel:
            raise UsageError(f"{source.name}: a bag needs --left-wheel and --right-wheel "
                             "(joint names in the JointState messages)")
        if (args.pose_topic is None) == (args.tf is None):
            raise UsageError(f"{source.name}: a bag needs exactly one pose source: "
                             "--pose-topic TOPIC or --tf PARENT:CHILD")
        bag = read_bag_log(source.paths[0], args.left_wheel, args.right_wheel,
                           pose_topic=args.pose_topic, tf=args.tf,
                           joint_states=args.joint_states)
        series, skipped = bag.series, bag.skipped_text()
    elif source.kind == "timeseries":
        series = read_timeseries(source.paths, ticks_per_rev=args.ticks_per_rev)
    else:
        raise UsageError(f"{source.name}: a segment file, not a time-series log or bag")
    if whole:
        check_continuity(series)
        unwrapped = unwrapped_words(series.unwrapped_wheels, series.unwrapped_counters)
        if unwrapped:  # segmenting commands say so in their report of the segments
            print(f"excite: note: {source.name}: {unwrapped}", file=sys.stderr)
    if args.time_offset == "estimate":
        return Log(source.name, series,
                   estimate_time_offset(series, max_offset=args.max_time_offset), "estimated",
                   skipped=skipped)
    if args.time_offset is not None:
        return Log(source.name, series, float(args.time_offset), "given", skipped=skipped)
    hint = noticeable_time_offset(series, max_offset=args.max_time_offset)
    if hint is not None:
        print(f"excite: note: {source.name}: the clocks of the encoder and pose streams seem "
              f"offset (pose time + offset = encoder time), but none was given and 0 is used; "
              f"{hint.text()}", file=sys.stderr)
    return Log(source.name, series, 0.0, "default", hint, skipped)


def segment_log(args: argparse.Namespace, log: Log) -> SegmentedLog:
    """Cut a log into segments with the command line's settings."""
    from excite.logs.timeseries import segment_timeseries

    return segment_timeseries(log.series, window=args.window, min_distance=args.min_distance,
                              min_angle=args.min_angle, time_offset=log.time_offset,
                              on_gap="split" if args.split_at_gaps else "error")


@dataclass(frozen=True)
class Part:
    """One command-line input as segments: the input, its segments, and for a log the log
    and its segmentation (None for a segment file)."""

    source: Input
    segments: Segments
    log: Log | None = None
    cut: SegmentedLog | None = None

    def describe(self) -> str:
        """What was read, in one line (a log: segments kept, dropped and why, time offset; a
        bag also the messages skipped)."""
        if self.cut is None or self.log is None:
            return f"{self.source.name}: {len(self.segments)} segments"
        report = self.cut.report
        offset = f"; time offset {self.log.offset_text()}"
        unwrapped = f"; {report.unwrapped_text()}" if report.unwrapped_text() else ""
        skipped = "" if self.log.skipped is None else f"; messages skipped: {self.log.skipped}"
        return (f"{self.source.name}: {report.n_segments} segments; dropped: "
                f"{report.counts_text()}{unwrapped}{skipped}{offset}")


def segment_inputs(args: argparse.Namespace, inputs: Sequence[Input]) -> list[Part]:
    """Every input as segments: segment files are read, logs read and cut."""
    from excite.logs.segments import load_segments

    parts = []
    for source in inputs:
        if source.kind == "segments":
            parts.append(Part(source, load_segments(source.paths[0])))
        else:
            log = read_log(args, source)
            cut = segment_log(args, log)
            parts.append(Part(source, cut.segments, log, cut))
    return parts
