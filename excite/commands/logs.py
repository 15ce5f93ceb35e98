"""The options of calibrate, segment and validate that read and cut time-series logs and ROS
bags: their command-line side (:data:`LOG_FILES`, :func:`add_log_options`, :func:`log_options`),
with the defaults of :class:`excite.logs.inputs.LogOptions`; and the library's notes for the
user, printed on stderr as they arise (:func:`print_note`).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from typing import Any

from excite.commands.args import finite_number, positive_number, time_offset_arg
from excite.logs.inputs import DEFAULT_LOG_OPTIONS, LogOptions

__all__ = ["LOG_FILES", "add_log_options", "log_options", "print_note"]

#: What a log given to calibrate, segment or validate is (part of their arguments' help).
LOG_FILES = "time-series CSV (or a pair of stream CSVs) or ROS bag"


def _frame_pair(text: str) -> tuple[str, str]:
    parent, sep, child = text.partition(":")
    if not sep or not parent or not child:
        raise argparse.ArgumentTypeError(f"must be PARENT:CHILD, got {text!r}")
    return parent, child


def _wheel_joint(side: str) -> dict[str, Any]:
    """The keywords of the option naming the ``side`` (left or right) wheel's joint."""
    return {"metavar": "NAME", "help": f"the {side} wheel's joint name in the JointState "
            "messages (bags: required, no default)"}


def _time_bound(text: str) -> dict[str, Any]:
    """The keywords of --start or --end: read only the samples stamped ``text``."""
    return {"type": finite_number, "metavar": "S", "help": f"read only the samples stamped {text}"}


#: The options that cut logs into segments: a field of LogOptions and add_argument's keywords
#: but the flag (--FIELD-NAME) and the default (the field's).
_SEGMENTATION: dict[str, dict[str, Any]] = {
    "window": {"type": positive_number, "metavar": "S",
               "help": "segment duration in s (default %(default)g)"},
    "min_distance": {"type": positive_number, "metavar": "M",
                     "help": "keyframes instead of fixed windows: a new segment once the sensor "
                     "has moved M meters from the last keyframe (or turned --min-angle; "
                     "default: fixed windows)"},
    "min_angle": {"type": positive_number, "metavar": "RAD",
                  "help": "keyframes instead of fixed windows: a new segment once the sensor has "
                  "turned RAD radians from the last keyframe (or moved --min-distance; default: "
                  "fixed windows)"},
    "split_at_gaps": {"action": argparse.BooleanOptionalAction,
                      "help": "cut a log at gaps (a stream without samples for longer than the "
                      "window, in s: a motion-capture body out of view, a driver's pause; no "
                      "segment spans one, a note names them) or, with --no-split-at-gaps, "
                      "refuse it, naming where the stream resumes (default: cut)"},
}
#: The options that read logs and bags, written as those that cut them.
_READING: dict[str, dict[str, Any]] = {
    "ticks_per_rev": {"type": positive_number, "metavar": "N",
                      "help": "encoder resolution in ticks per wheel revolution: converts "
                      "ticks_L,ticks_R columns to rad, and calibrate models the encoders' "
                      "rounding (one tick) in the noise of the segments cut from logs (default: "
                      "none; the wheel columns are phi_L,phi_R in rad)"},
    "time_offset": {"type": time_offset_arg, "metavar": "S|estimate",
                    "help": "pose time + S = encoder time (s; default: 0 unless the data "
                    "reject a zero offset, then the offset they show, with a note), or "
                    "'estimate' it from the data"},
    "max_time_offset": {"type": positive_number, "metavar": "S",
                        "help": "estimated time offsets are searched within +-S s (default "
                        "%(default)g)"},
    "joint_states": {"metavar": "TOPIC",
                     "help": "bag topic of the wheels' sensor_msgs/msg/JointState messages "
                     "(default %(default)s)"},
    "left_wheel": _wheel_joint("left"),
    "right_wheel": _wheel_joint("right"),
    "pose_topic": {"metavar": "TOPIC",
                   "help": "bag topic of the sensor's pose in the world frame, x, y in m "
                   "(PoseStamped, PoseWithCovarianceStamped, TransformStamped, Pose2D or "
                   "Odometry); a bag needs this or --tf (no default)"},
    "start": _time_bound("from S on (s, the log's own stamps; default: from the first)"),
    "end": _time_bound("up to S (s; default: to the last)"),
    "tf": {"type": _frame_pair, "metavar": "PARENT:CHILD",
           "help": "the sensor's pose from /tf instead: CHILD's pose in PARENT (m, rad), direct "
           "transforms only (bags; no default)"},
}


def add_log_options(parser: argparse.ArgumentParser, segmentation: bool = True) -> None:
    """The time-series and bag options (docs/formats.md, "Time-series logs"); with
    ``segmentation`` also the options that cut logs into segments. Their destinations are the
    fields of :class:`~excite.logs.inputs.LogOptions`, their defaults its defaults."""
    group = parser.add_argument_group(
        "time-series logs and ROS bags",
        "a CSV with header t,phi_L,phi_R,x,y,theta (s, rad, rad, m, m, rad; or two CSVs, one "
        "per stream, given one after the other), or a ROS bag (.bag, .db3, .mcap, or a "
        "rosbag2 directory)")
    options = {**_SEGMENTATION, **_READING} if segmentation else _READING
    for field, keywords in options.items():
        group.add_argument("--" + field.replace("_", "-"),
                           default=getattr(DEFAULT_LOG_OPTIONS, field), **keywords)


def log_options(args: argparse.Namespace) -> LogOptions:
    """The :class:`~excite.logs.inputs.LogOptions` of parsed arguments (the options a command
    does not have keep their defaults)."""
    given = vars(args)
    return LogOptions(**{f.name: given[f.name] for f in fields(LogOptions) if f.name in given})


def print_note(note: str) -> None:
    """A note of the library (its ``on_note``) on stderr, one line ``excite: note: ...``."""
    print(f"excite: note: {note}", file=sys.stderr)
