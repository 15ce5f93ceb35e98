"""Exports whose header is not one row of excite's column names, read by their layout: a TUM
trajectory (no header), a ROS export (PlotJuggler's CSV, ``rostopic echo -p``: topic paths
and field names), an OptiTrack Motive CSV (a block of take data and several header rows).
:func:`layout` gives the header line a time-series CSV is read with, where its data start,
and what was read so, for a note; :mod:`excite.logs.timeseries_header` reads that header.

OptiTrack Motive: the first line starts ``Format Version`` (the take's settings as name,
value pairs, among them ``Length Units`` and ``Rotation Type``), rows ``Type``, ``Name``,
``ID`` and the kind of each column (``Rotation``, ``Position``, ...) above the row of
``Frame,Time (Seconds),X,Y,Z,...``. The one rigid body's rotation is read as the quaternion
(``Rotation Type`` Quaternion: X, Y, Z, W) and its position as x, y, z in the take's length
unit; markers and other columns are not read. Motive exports Y-up by default: such poses are
turned Z-up (:func:`excite.logs.orientation.z_up`). Several rigid bodies are an error naming
them.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from excite.errors import DataError
from excite.logs.csv_table import delimiter_of, header_fields

__all__ = ["HEADER_LINES", "TUM_HEADER", "Layout", "layout"]

#: The most content lines a layout's header takes (Motive's block is 7).
HEADER_LINES = 12
#: The columns of a TUM trajectory (evo's and the TUM RGB-D benchmark's format: a pose per
#: row, timestamp in s, position in m, orientation quaternion; no header, or a ``#``
#: comment): read as the pose stream of a file whose first row is 8 numbers separated by
#: spaces.
TUM_HEADER = "t x y z qx qy qz qw"


def _is_tum_row(line: str) -> bool:
    """Whether a first content line is a TUM trajectory's row: 8 numbers separated by spaces
    (:data:`TUM_HEADER`)."""
    fields = line.split()
    if len(fields) != 8 or delimiter_of(line) != " ":
        return False
    try:
        [float(field) for field in fields]
    except ValueError:
        return False
    return True


#: Column names of ROS exports read as time-series columns: PlotJuggler's (``__time``,
#: topic paths such as ``/mocap/pose/pose/position/x``, ``/joint_states/<joint>/position``
#: with ``left`` or ``right`` in the joint's name, or its ``velocity`` when no joint has a
#: position column or no position is filled) and ``rostopic echo -p``'s
#: (``field.header.stamp`` in ns, ``field.pose.position.x``).
_ROS_TIME = {"__time": "t", "field.header.stamp": "t [ns]"}
_ROS_POSITION = re.compile(r"(?:^|[/.])(?:position|translation)[/.]([xy])$")
_ROS_ORIENTATION = re.compile(r"(?:^|[/.])(?:orientation|rotation)[/.]([xyzw]|yaw)$")
_ROS_JOINT = re.compile(r"/([^/]+)/(position|velocity)$")
_ROS_NOTE = "the column names of a ROS export (PlotJuggler, rostopic) read: "


def _ros_name(field: str, fields: Sequence[str], is_time: Callable[[str], bool],
              speeds: bool = False) -> str | None:
    """The time-series name of a ROS export's column name; None when it names none.
    ``speeds``: the joints' velocities are read even where they have position columns
    (which are then not read)."""
    name = field.strip().lower()
    if name in _ROS_TIME:
        return _ROS_TIME[name]
    if name == "%time":  # rostopic's receive time (ns): only without another time column
        others = [other for other in fields if other != "%time"]
        return None if "field.header.stamp" in fields or any(map(is_time, others)) else "t [ns]"
    if match := _ROS_POSITION.search(name):
        return match[1]
    if match := _ROS_ORIENTATION.search(name):
        return "theta" if match[1] == "yaw" else f"q{match[1]}"
    if (match := _ROS_JOINT.search(name)) and ("left" in match[1]) != ("right" in match[1]):
        side = "L" if "left" in match[1] else "R"
        if match[2] == "position":
            return None if speeds else f"phi_{side}"
        return f"omega_{side}" if speeds or not _joint_kinds(fields) & {"position"} else None
    return None


def _joint_kinds(fields: Sequence[str]) -> set[str]:
    """Which of a wheel joint's columns (position, velocity) a ROS export's header has."""
    return {joint[2] for joint in map(_ROS_JOINT.search, fields)
            if joint and ("left" in joint[1]) != ("right" in joint[1])}


def _ros_header(line: str, is_time: Callable[[str], bool], where: str, speeds: bool = False
                ) -> tuple[str, list[str]] | None:
    """A header line of a ROS export (PlotJuggler's CSV, ``rostopic echo -p``'s) with its
    columns renamed to the time-series names they hold (the others kept, so not read), and
    the renamings in words ('__time as t'); None for any other header. ``is_time``: whether
    a header field names the time column; ``speeds``: the joints' velocities are read, not
    their positions; ``where`` names the line in errors (two columns of one kind: several
    topics)."""
    delimiter = delimiter_of(line)
    fields = header_fields(line, delimiter)
    lowered = [field.lower() for field in fields]
    if not any(name in _ROS_TIME or name == "%time" for name in lowered):
        return None
    names = [_ros_name(field, lowered, is_time, speeds) or field for field in fields]
    renamed = [f"{field} as {name}" for field, name in zip(fields, names, strict=True)
               if name != field]
    for name in dict.fromkeys(names):
        columns = [field for field, mapped in zip(fields, names, strict=True)
                   if mapped == name and mapped != field]
        if len(columns) > 1 and all(_ROS_JOINT.search(c.lower()) for c in columns):
            raise DataError(f"{where}: columns {', '.join(map(repr, columns))} are all "
                            f"{name}: joints of one side (a skid-steer robot's?); export one "
                            "joint per side, or delete the other joints' columns")
        if len(columns) > 1:
            raise DataError(f"{where}: columns {', '.join(map(repr, columns))} are all "
                            f"{name}: an export of several topics of one kind; export one")
    return delimiter.join(names), renamed


@dataclass(frozen=True)
class Layout:
    """How a time-series CSV is read: ``header``, the header line (excite's names); ``data``,
    the index of its first data line among the file's content lines; ``note``, what was read
    so in words (None for a plain header); ``speeds``, for a ROS export with both position
    and velocity columns of the wheel joints (read as positions), the layout that reads the
    velocities instead (for a driver whose positions are NaN or never filled), else None."""

    header: str
    data: int
    note: str | None = None
    speeds: Layout | None = None


#: Motive's length units, by the take's ``Length Units``.
_MOTIVE_UNITS = {"meters": "m", "centimeters": "cm", "millimeters": "mm"}


def _motive(lines: Sequence[str], where: Callable[[int], str]) -> Layout | None:
    """The layout of an OptiTrack Motive CSV (module docstring); None for another file."""
    if not lines[0].lower().startswith("format version"):
        return None
    rows = [header_fields(line, ",") for line in lines]
    frame = next((k for k, row in enumerate(rows) if row[0].lower() == "frame"), None)
    if frame is None or frame < 2:
        return None
    take = dict(zip(rows[0][0::2], rows[0][1::2], strict=False))
    unit = _MOTIVE_UNITS.get(take.get("Length Units", "Meters").lower(), "m")
    quaternion = take.get("Rotation Type", "Quaternion").lower() == "quaternion"
    table = {row[1].lower(): row for row in rows[1:frame] if len(row) > 1}
    types, names, kinds = table.get("type", []), table.get("name", []), rows[frame - 1]

    def cell(row: Sequence[str], j: int) -> str:
        return row[j] if j < len(row) else ""

    header, bodies = ["frame", "t"], set()
    for j, axis in enumerate(rows[frame][2:], start=2):
        kind, body = cell(kinds, j).lower(), cell(types, j).lower() == "rigid body"
        if body and kind in ("rotation", "position"):
            bodies.add(cell(names, j))
        if body and kind == "rotation" and quaternion:
            header.append(f"q{axis.lower()}")
        elif body and kind == "position":
            header.append(f"{axis.lower()} [{unit}]")
        else:
            header.append(" ".join(x for x in (cell(types, j), cell(names, j), kind, axis) if x)
                          or f"column {j + 1}")
    if len(bodies) > 1:
        raise DataError(f"{where(frame)}: an OptiTrack Motive export of several rigid bodies "
                        f"({', '.join(sorted(bodies))}); export the robot's alone")
    return Layout(",".join(header), frame + 1,
                  f"read as an OptiTrack Motive export (rigid body {next(iter(bodies), '?')!r}"
                  f", lengths in {unit}{'' if quaternion else ', rotation as Euler angles'})")


def layout(lines: Sequence[str], where: Callable[[int], str],
           is_time: Callable[[str], bool] = lambda _: False) -> Layout:
    """The layout of a time-series CSV whose first content lines (stripped; up to
    :data:`HEADER_LINES`) are ``lines``: a TUM trajectory's, a ROS export's, a Motive
    export's, else the first line as the header. ``where(i)`` names content line i in
    errors; ``is_time``: whether a header field names the time column."""
    if _is_tum_row(lines[0]):
        return Layout(TUM_HEADER, 0, f"read as a TUM trajectory ({TUM_HEADER}: s, m, the "
                      "orientation quaternion)")
    motive = _motive(lines, where)
    if motive is not None:
        return motive
    ros = _ros_header(lines[0], is_time, where(0))
    if ros is None:
        return Layout(lines[0], 1)
    speeds = None
    fields = header_fields(lines[0].lower(), delimiter_of(lines[0]))
    if _joint_kinds(fields) == {"position", "velocity"}:
        header, renamed = _ros_header(lines[0], is_time, where(0), speeds=True)
        speeds = Layout(header, 1, f"{_ROS_NOTE}{', '.join(renamed)}")
    return Layout(ros[0], 1, f"{_ROS_NOTE}{', '.join(ros[1])}", speeds)
