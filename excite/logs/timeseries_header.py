"""The header of a time-series CSV: the names and units its columns are read under, the
streams a file holds (found from its header alone), and what columns not read may have been
meant as (:mod:`excite.logs.timeseries_csv` reads the rows).

A header names ``t`` (s), the wheel angles ``phi_L,phi_R`` (rad), encoder ticks
``ticks_L,ticks_R`` or wheel speeds ``omega_L,omega_R`` (rad/s, as a JointState's velocity),
and the pose ``x,y`` (m), ``theta`` (rad) or an orientation quaternion
``qx,qy,qz,qw`` (``qx,qy`` may be left out), each also under the names of :data:`ALIASES` and
with a unit (``t [ms]``, ``yaw (deg)``; :mod:`excite.logs.csv_table`). The header of a
tool's export laid out otherwise (a TUM trajectory, PlotJuggler, rostopic, OptiTrack Motive)
comes from :mod:`excite.logs.export_layouts`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence

from excite.errors import DataError
from excite.logs.csv_table import (
    Header,
    delimiter_of,
    header_fields,
    is_separator_line,
    label_of,
    parse_header,
)
from excite.logs.export_layouts import HEADER_LINES, layout
from excite.logs.timeseries import ANGLE_COLUMNS, POSE_COLUMNS, SPEED_COLUMNS, TICK_COLUMNS

__all__ = ["ALIASES", "EXPECTED", "QUATERNION_COLUMNS", "columns_hint", "header_hint",
           "header_problem", "is_time_name", "is_timeseries_csv", "parse_timeseries_header",
           "timeseries_streams"]

PathArg = str | os.PathLike[str]

#: The header names read as each column (without case; a unit may follow in brackets, or
#: after an underscore: ``t [ms]``, ``yaw_deg``). Only names that say what the column holds:
#: ``left``/``right`` alone could be an angle, ticks, a distance or a speed, and are not read.
ALIASES: dict[str, tuple[str, ...]] = {
    "t": ("t", "time", "timestamp", "stamp"),
    **{f"phi_{s}": (f"phi_{s}", f"phi_{side}", f"angle_{s}", f"angle_{side}", f"{side}_angle",
                    f"{side}_wheel_angle") for s, side in (("L", "left"), ("R", "right"))},
    **{f"ticks_{s}": (f"ticks_{s}", f"ticks_{side}", f"{side}_ticks", f"{side}_wheel_ticks")
       for s, side in (("L", "left"), ("R", "right"))},
    **{f"omega_{s}": (f"omega_{s}", f"omega_{side}", f"{side}_omega", f"{side}_wheel_speed",
                      f"{side}_wheel_velocity", f"{side}_wheel_omega")
       for s, side in (("L", "left"), ("R", "right"))},
    **{axis: (axis, f"pos_{axis}", f"position_{axis}", f"pose_{axis}") for axis in "xy"},
    "theta": ("theta", "yaw", "heading"),
    **{f"q{axis}": (f"q{axis}", f"q_{axis}", f"quat_{axis}", f"quaternion_{axis}",
                    f"orientation_{axis}") for axis in "xyzw"},
}
#: The orientation quaternion's columns (x, y, z, w; dimensionless): the heading is its yaw
#: when the header has no theta (qx, qy may be left out: a rotation about z alone).
QUATERNION_COLUMNS = ("qx", "qy", "qz", "qw")
_NAMES = {alias.lower(): column for column, aliases in ALIASES.items() for alias in aliases}
#: A motion-capture export's rotation columns (Motive, Vicon: RX, RY, RZ, RW), read as the
#: quaternion only when RW is there: without it RX, RY, RZ are Euler angles.
_ROTATION_QUATERNION = {f"r{axis}": f"q{axis}" for axis in "xyzw"}
#: The position's z (m), read beside a quaternion: a Y-up stream is turned Z-up with it
#: (:func:`excite.logs.orientation.z_up`).
_Z_NAMES = {name: "z" for name in ("z", "pos_z", "position_z", "pose_z")}
#: The quantity of each column (the units it may be written in: excite.logs.csv_table.UNITS).
_QUANTITIES = {"t": "time", **dict.fromkeys(ANGLE_COLUMNS, "angle"),
               **dict.fromkeys(TICK_COLUMNS, "count"),
               **dict.fromkeys(SPEED_COLUMNS, "angular speed"), "x": "length", "y": "length",
               "theta": "angle", **dict.fromkeys(QUATERNION_COLUMNS, "number"),
               "z": "length"}
EXPECTED = "t,phi_L,phi_R,x,y,theta in one file, or t,phi_L,phi_R and t,x,y,theta in two"
#: The wheel columns' kinds, one of which a log gives.
_WHEEL_GROUPS = (ANGLE_COLUMNS, TICK_COLUMNS, SPEED_COLUMNS)
# Header names of columns not read that look like a wheel's or an orientation's.
_WHEEL_LIKE = re.compile(r"left|right|wheel|enc|tick")
_QUATERNION_LIKE = re.compile(r"^(q|quat|orientation)[_ .]?[xyzw]\b|^q[xyzw]$|\brotation\b")


def _names(line: str) -> dict[str, str]:
    """The header names read as each column for this header line: :data:`ALIASES`, RX..RW
    as the quaternion when the line has an RW column, and the height z (:data:`_Z_NAMES`)
    when it has a quaternion (a Y-up world's ground coordinates are x and z)."""
    fields = header_fields(line, delimiter_of(line))
    names = _NAMES
    if any(label_of(field, {"rw": "rw"})[0] == "rw" for field in fields):
        names = names | _ROTATION_QUATERNION
    if {"qz", "qw"} <= {label_of(field, names)[0] for field in fields}:
        names = names | _Z_NAMES
    return names


def is_time_name(field: str) -> bool:
    """Whether a header field names the time column t (under any of its names, any unit)."""
    return label_of(field, _NAMES)[0] == "t"


def columns_hint(header: Header) -> str:
    """What the columns not read may have been meant as, when a wheel group or theta is
    missing ('' when nothing looks so)."""
    labels = set(header.labels)
    wheels = [text for text in header.ignored if _WHEEL_LIKE.search(text.lower())
              and not any(labels >= set(names) for names in _WHEEL_GROUPS)]
    turns = [text for text in header.ignored if _QUATERNION_LIKE.search(text.lower())]
    hints = []
    if wheels:
        hints.append(f"{', '.join(map(repr, wheels))} not read: wheel columns are named "
                     "phi_L, phi_R (rad), ticks_L, ticks_R or omega_L, omega_R (rad/s; see "
                     "docs/formats.md)")
    if turns and "theta" not in labels:
        hints.append(f"{', '.join(map(repr, turns))} not read: give the heading as theta "
                     "(rad) or as the quaternion qx, qy, qz, qw")
    if "field.position0" in (text.lower() for text in header.ignored):
        hints.append("a JointState of rostopic echo -p: name the wheels' field.position<i> "
                     "columns phi_L and phi_R (their joints are in field.name<i>)")
    return "".join(f"; {hint}" for hint in hints)


def header_problem(path: PathArg) -> DataError | None:
    """What is wrong with a time-series CSV's header (the error reading it would raise); None
    when it is right, or the file is no time-series CSV."""
    try:
        line = _first_line(path)
        if line is None or not _labels(line):
            return None
        parse_timeseries_header(line, f"{os.fspath(path)}")
    except DataError as exc:
        return exc
    return None


def parse_timeseries_header(line: str, where: str) -> Header:
    """The layout of a time-series header; DataError for anything else."""
    header = parse_header(line, _names(line), _QUANTITIES, where)
    if "t" not in header.labels:
        raise DataError(f"{where}: no time column t (s); the header names {header.found()} "
                        f"(expected {EXPECTED}){columns_hint(header)}")
    header = _orientation(header, where)
    _check_column_set(header, where)
    _check_speed_units(header, where)
    return header


def _check_speed_units(header: Header, where: str) -> None:
    """DataError for a wheel speed column named without its unit, unless its name says
    rad/s (omega): a motor controller's speed is as often in rpm, and read as rad/s it would
    scale the wheel radii by 2 pi / 60 without a word."""
    for column in header.columns:
        unit = label_of(column.text, _NAMES)[1]
        if column.label in SPEED_COLUMNS and unit is None and "omega" not in column.text.lower():
            raise DataError(f"{where}: column {column.text!r} has no unit: wheel speeds may be "
                            "in rad/s, deg/s, rpm or rev/s; say which, e.g. "
                            f"'{column.text} [rpm]' or '{column.text} [rad/s]'")


def _orientation(header: Header, where: str) -> Header:
    """The header with the quaternion columns (and z) not read when it has theta; DataError
    for a quaternion without qz or qw, or with one of qx, qy."""
    quaternion = [c for c in header.columns if c.label in QUATERNION_COLUMNS]
    if not quaternion:
        return header
    if "theta" in header.labels:
        return header.without((*QUATERNION_COLUMNS, "z"))
    labels = {c.label for c in quaternion}
    missing = [c for c in ("qz", "qw") if c not in labels]
    if not missing and len(labels & {"qx", "qy"}) == 1:
        missing = sorted({"qx", "qy"} - labels)
    if missing:
        raise DataError(f"{where}: the quaternion has no column {missing[0]} (the heading is "
                        "the yaw of qx, qy, qz, qw; qx and qy may both be left out); the "
                        f"header names {header.found()}")
    return header


def _pose_labels(labels: Sequence[str]) -> set[str]:
    """The pose columns (POSE_COLUMNS) among ``labels``, the quaternion standing for theta."""
    found = set(POSE_COLUMNS) & set(labels)
    return found | {"theta"} if {"qz", "qw"} <= set(labels) else found


def _check_column_set(header: Header, where: str) -> None:
    """A complete encoder group (angles, ticks or speeds), a complete pose group, or both."""
    columns = header.labels
    wheels = [(set(names) & set(columns), names) for names in _WHEEL_GROUPS]
    given = [names for present, names in wheels if present]
    if len(given) > 1:
        raise DataError(f"{where}: wheel columns of two kinds ({', '.join(given[0])} and "
                        f"{', '.join(given[1])}); give one kind")
    groups = [(present, expected) for present, expected in (
        *wheels, (_pose_labels(columns), POSE_COLUMNS)) if present]
    if not groups:
        raise DataError(f"{where}: neither encoder (phi_L, phi_R) nor pose (x, y, theta) "
                        f"columns (expected {EXPECTED}); the header names {header.found()}"
                        f"{columns_hint(header)}")
    for present, expected in groups:
        missing = [c for c in expected if c not in present]
        if missing:
            raise DataError(f"{where}: missing column {missing[0]} (expected {EXPECTED}); "
                            f"the header names {header.found()}{columns_hint(header)}")


def _first_line(path: PathArg) -> str | None:
    """A text file's header line: the header the layout of its first content lines gives
    (:func:`excite.logs.export_layouts.layout`: a tool's export, else the first line that is
    neither blank nor a comment nor a separator line, stripped); None when the file cannot be
    read as text or has no such line; DataError when its layout is refused."""
    lines: list[str] = []
    try:
        with open(os.fspath(path), encoding="utf-8-sig") as handle:
            for line in handle:
                stripped = line.strip()
                if "\x00" in stripped:
                    return None
                if stripped and not stripped.startswith("#") and not (
                        not lines and is_separator_line(stripped)):
                    lines.append(stripped)
                    if len(lines) == HEADER_LINES:
                        break
    except (OSError, UnicodeDecodeError):
        return None
    if not lines:
        return None
    return layout(lines, lambda _: os.fspath(path), is_time_name).header


def _labels(line: str) -> set[str]:
    """The time-series columns (:data:`ALIASES`) a header line names."""
    names = _names(line)
    labels = (label_of(field, names)[0] for field in header_fields(line, delimiter_of(line)))
    return {label for label in labels if label is not None}


def timeseries_streams(path: PathArg) -> frozenset[str]:
    """The streams a time-series CSV holds, from its header: {"encoder"} or {"pose"} for a
    file of one stream (a ``t`` column, one complete group of :data:`ALIASES` columns, none of
    the other), {"encoder", "pose"} for any other header naming a time-series column (both
    streams, or a header with a problem: read alone, the error names it); empty for a segment
    CSV (header ``dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt`` or none) or a file that cannot be read
    as text. Reads only up to the header."""
    groups = {"encoder": _WHEEL_GROUPS, "pose": (POSE_COLUMNS,)}
    try:
        line = _first_line(path)
    except DataError:  # a layout refused: read alone, the error names it
        return frozenset(groups)
    labels = _labels(line) if line is not None else set()
    if not labels:
        return frozenset()
    labels |= _pose_labels(list(labels))
    complete = {kind for kind, options in groups.items()
                if any(labels >= set(names) for names in options)}
    present = {kind for kind, options in groups.items()
               if any(labels & set(names) for names in options)}
    try:
        parse_header(line, _names(line), _QUANTITIES, os.fspath(path))
    except DataError:
        return frozenset(groups)
    if "t" in labels and len(complete) == 1 and present == complete:
        return frozenset(complete)
    return frozenset(groups)


def header_hint(path: PathArg) -> str:
    """What a time-series CSV's columns that are not read may have been meant as: wheel
    columns under names that are not read (``left``, ``enc_right``), a quaternion instead of
    theta; '' when nothing looks so. Starts with '; ' (to end an error message)."""
    try:
        line = _first_line(path)
        return columns_hint(parse_header(line, _names(line), _QUANTITIES, "")) if line else ""
    except DataError:
        return ""


def is_timeseries_csv(path: PathArg) -> bool:
    """Whether a file's header names a time-series column (:data:`ALIASES`): a time-series
    CSV, as opposed to a segment CSV (header ``dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt`` or none);
    False when the file cannot be read as text."""
    return bool(timeseries_streams(path))
