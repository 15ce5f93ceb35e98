"""Time-series logs as CSV files: one file with both streams, or two files with one stream
each, read into a :class:`~excite.logs.timeseries.TimeSeries` and written back.

Columns (header required, any order): ``t`` (s), the wheel angles ``phi_L,phi_R`` (rad) or
encoder ticks ``ticks_L,ticks_R`` (with ticks_per_rev), and the pose ``x,y`` (m), ``theta``
(rad, may be wrapped), each also under the names of :data:`ALIASES` and with a unit in the
header (``t [ms]``, ``yaw (deg)``: converted to s, m, rad); other columns are not read, with a
note naming them. Instead of ``theta``, an orientation quaternion ``qx,qy,qz,qw`` (``qx,qy``
may be left out: a planar rotation) gives the heading, its yaw
(:mod:`excite.logs.orientation`: free of the quaternion's length; a z-up world frame).
Separated by commas, semicolons, tabs or spaces (:mod:`excite.logs.csv_table`). A file
without a header whose rows are 8 numbers separated by spaces is a TUM trajectory
(:data:`TUM_HEADER`), the pose stream. In one file, a row
leaves a stream's cells empty (or NaN) when that stream has no sample at its time. Blank lines and
``#`` comments are ignored. Every error is one line naming the file and line (docs/formats.md,
"Time-series logs").
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from excite.core.arrays import BoolArray, FloatArray, IntArray
from excite.errors import DataError
from excite.logs.csv_table import (
    Column,
    Header,
    content_lines,
    delimiter_of,
    header_fields,
    is_separator_line,
    label_of,
    parse_header,
    read_columns,
)
from excite.logs.orientation import headings
from excite.logs.segments import read_text
from excite.logs.timeseries import (
    ANGLE_COLUMNS,
    POSE_COLUMNS,
    TICK_COLUMNS,
    TimeSeries,
    tick_angle,
    unwrapped_counter,
)

__all__ = ["ALIASES", "QUATERNION_COLUMNS", "read_timeseries", "write_timeseries",
           "timeseries_streams", "is_timeseries_csv", "header_hint"]

PathArg = str | os.PathLike[str]
OnNote = Callable[[str], None]

#: The header names read as each column (without case; a unit may follow in brackets, or
#: after an underscore: ``t [ms]``, ``yaw_deg``). Only names that say what the column holds:
#: ``left``/``right`` alone could be an angle, ticks, a distance or a speed, and are not read.
ALIASES: dict[str, tuple[str, ...]] = {
    "t": ("t", "time", "timestamp", "stamp"),
    **{f"phi_{s}": (f"phi_{s}", f"phi_{side}", f"angle_{s}", f"angle_{side}", f"{side}_angle",
                    f"{side}_wheel_angle") for s, side in (("L", "left"), ("R", "right"))},
    **{f"ticks_{s}": (f"ticks_{s}", f"ticks_{side}", f"{side}_ticks", f"{side}_wheel_ticks")
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
#: The quantity of each column (the units it may be written in: excite.logs.csv_table.UNITS).
_QUANTITIES = {"t": "time", **dict.fromkeys(ANGLE_COLUMNS, "angle"),
               **dict.fromkeys(TICK_COLUMNS, "count"), "x": "length", "y": "length",
               "theta": "angle", **dict.fromkeys(QUATERNION_COLUMNS, "number")}
_EXPECTED = "t,phi_L,phi_R,x,y,theta in one file, or t,phi_L,phi_R and t,x,y,theta in two"
#: The columns of a TUM trajectory (evo's and the TUM RGB-D benchmark's format: a pose per
#: row, timestamp in s, position in m, orientation quaternion; no header, or a ``#``
#: comment): read as the pose stream of a file whose first row is 8 numbers separated by
#: spaces.
TUM_HEADER = "t x y z qx qy qz qw"
# Header names of columns not read that look like a wheel's or an orientation's.
_WHEEL_LIKE = re.compile(r"left|right|wheel|enc|tick")
_QUATERNION_LIKE = re.compile(r"^(q|quat|orientation)[_ .]?[xyzw]\b|^q[xyzw]$")


def _names(line: str) -> dict[str, str]:
    """The header names read as each column for this header line: :data:`ALIASES`, and RX..RW
    as the quaternion when the line has an RW column."""
    fields = header_fields(line, delimiter_of(line))
    if any(label_of(field, {"rw": "rw"})[0] == "rw" for field in fields):
        return _NAMES | _ROTATION_QUATERNION
    return _NAMES


@dataclass(frozen=True)
class _Table:
    """The data rows of one time-series CSV: values (n, k) of the columns read (base units),
    NaN in empty cells."""

    name: str
    header: Header
    values: FloatArray
    empty: BoolArray
    lines: IntArray
    header_line: int

    @property
    def columns(self) -> tuple[str, ...]:
        return self.header.labels

    def has(self, names: Sequence[str]) -> bool:
        return all(n in self.columns for n in names)

    @property
    def encoder_columns(self) -> tuple[str, ...] | None:
        for names in (ANGLE_COLUMNS, TICK_COLUMNS):
            if self.has(names):
                return names
        return None

    @property
    def has_pose(self) -> bool:
        return self.has(POSE_COLUMNS)

    def stream(self, names: Sequence[str]) -> tuple[list[FloatArray], IntArray]:
        """Columns t and ``names`` over the rows where ``names`` are filled, and those lines."""
        index = [self.columns.index(n) for n in ("t", *names)]
        rows = ~self.empty[:, index[1]]
        return [self.values[rows, i] for i in index], self.lines[rows]


def _hint(header: Header) -> str:
    """What the columns not read may have been meant as, when a wheel group or theta is
    missing ('' when nothing looks so)."""
    labels = set(header.labels)
    wheels = [text for text in header.ignored if _WHEEL_LIKE.search(text.lower())
              and not any(labels >= set(names) for names in (ANGLE_COLUMNS, TICK_COLUMNS))]
    turns = [text for text in header.ignored if _QUATERNION_LIKE.search(text.lower())]
    hints = []
    if wheels:
        hints.append(f"{', '.join(map(repr, wheels))} not read: wheel columns are named "
                     "phi_L, phi_R (rad) or ticks_L, ticks_R (see docs/formats.md)")
    if turns and "theta" not in labels:
        hints.append(f"{', '.join(map(repr, turns))} not read: give the heading as theta "
                     "(rad) or as the quaternion qx, qy, qz, qw")
    return "".join(f"; {hint}" for hint in hints)


def _parse_header(line: str, where: str) -> Header:
    """The layout of a time-series header; DataError for anything else."""
    header = parse_header(line, _names(line), _QUANTITIES, where)
    if "t" not in header.labels:
        raise DataError(f"{where}: no time column t (s); the header names {header.found()} "
                        f"(expected {_EXPECTED}){_hint(header)}")
    header = _orientation(header, where)
    _check_column_set(header, where)
    return header


def _orientation(header: Header, where: str) -> Header:
    """The header with the quaternion columns not read when it has theta; DataError for a
    quaternion without qz or qw, or with one of qx, qy."""
    quaternion = [c for c in header.columns if c.label in QUATERNION_COLUMNS]
    if not quaternion:
        return header
    if "theta" in header.labels:
        return header.without(QUATERNION_COLUMNS)
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
    """A complete encoder group (angles or ticks), a complete pose group, or both."""
    columns = header.labels
    angles, ticks = set(ANGLE_COLUMNS) & set(columns), set(TICK_COLUMNS) & set(columns)
    if angles and ticks:
        raise DataError(f"{where}: both wheel angles (phi_L, phi_R) and ticks "
                        "(ticks_L, ticks_R); give one kind")
    groups = [(present, expected) for present, expected in (
        (angles, ANGLE_COLUMNS), (ticks, TICK_COLUMNS), (_pose_labels(columns),
                                                         POSE_COLUMNS)) if present]
    if not groups:
        raise DataError(f"{where}: neither encoder (phi_L, phi_R) nor pose (x, y, theta) "
                        f"columns (expected {_EXPECTED}); the header names {header.found()}"
                        f"{_hint(header)}")
    for present, expected in groups:
        missing = [c for c in expected if c not in present]
        if missing:
            raise DataError(f"{where}: missing column {missing[0]} (expected {_EXPECTED}); "
                            f"the header names {header.found()}{_hint(header)}")


def _checked_cells(table: _Table, note: OnNote) -> _Table:
    """The table after checking that t is always filled and each stream's cells in a row are
    all filled or all empty; a row that fills no stream is an error, unless the file has
    columns not read (a merged export whose other topics have rows of their own): such rows
    are then left out, and ``note`` told how many."""
    groups = [g for g in (table.encoder_columns, POSE_COLUMNS if table.has_pose else None) if g]
    t_empty = table.empty[:, table.columns.index("t")]
    if t_empty.any():
        raise DataError(f"{table.name}:{table.lines[np.argmax(t_empty)]}: t is empty")
    filled_any = np.zeros(len(table.lines), dtype=bool)
    for group in groups:
        empty = table.empty[:, [table.columns.index(c) for c in group]]
        partial = empty.any(axis=1) & ~empty.all(axis=1)
        if partial.any():
            row = int(np.argmax(partial))
            column = group[int(np.argmax(empty[row]))]
            raise DataError(f"{table.name}:{table.lines[row]}: {column} is empty (or NaN) "
                            f"but other {'/'.join(group)} cells are not")
        filled_any |= ~empty[:, 0]
    if filled_any.all():
        return table
    if not table.header.ignored:
        row = int(np.argmin(filled_any))
        raise DataError(f"{table.name}:{table.lines[row]}: the row has only a time, no values")
    note(f"{table.name}: {int(np.sum(~filled_any))} rows without encoder or pose values left "
         "out (a merged export's other columns)")
    return replace(table, values=table.values[filled_any], empty=table.empty[filled_any],
                   lines=table.lines[filled_any])


def _read_table(path: PathArg, note: OnNote) -> _Table:
    """Read and check one time-series CSV (header required), telling ``note`` the columns not
    read and the units converted."""
    name = os.fspath(path)
    text = read_text(name)
    numbers, lines = content_lines(text)
    if not lines:
        raise DataError(f"{name}: empty file (expected a header {_EXPECTED})")
    if _tum(lines[0]):  # no header: the TUM trajectory's columns
        note(f"{name}: read as a TUM trajectory ({TUM_HEADER}: s, m, the orientation "
             "quaternion)")
        numbers, lines = [numbers[0] - 1, *numbers], [TUM_HEADER, *lines]
    header = _parse_header(lines[0], f"{name}:{numbers[0]}")
    for line in header.notes(name):
        note(line)
    values, empty = read_columns(name, numbers[1:], lines[1:], header, allow_empty=True)
    line_numbers = np.asarray(numbers[1:], dtype=np.int64)
    empty, with_nan, unmeasured = _nan_as_missing(header, values, empty)
    keep = ~unmeasured
    table = _heading_of_quaternion(_Table(name, header, values[keep], empty[keep],
                                          line_numbers[keep], numbers[0]))
    if table.header is not header:
        note(f"{name}: theta is the yaw of the quaternion "
             f"{', '.join(c for c in QUATERNION_COLUMNS if c in header.labels)}")
    table = _checked_cells(table, note)
    if with_nan.any():
        rows = line_numbers[with_nan]
        note(f"{name}: {rows.size} rows with NaN cells (lines {rows[0]}-{rows[-1]}) read as "
             "samples not measured, like empty cells (a motion-capture body not tracked?)")
    return table


def _nan_as_missing(header: Header, values: FloatArray, empty: BoolArray
                    ) -> tuple[BoolArray, BoolArray, BoolArray]:
    """(empty with NaN cells counted as empty, the rows with a NaN cell, the rows whose every
    value but t was NaN): a sample written as NaN was not measured (a motion-capture body not
    tracked, an exporter's missing value), like an empty cell."""
    nan = np.isnan(values) & ~empty
    empty = empty | nan
    others = [j for j, label in enumerate(header.labels) if label != "t"]
    with_nan = nan.any(axis=1)
    return empty, with_nan, with_nan & empty[:, others].all(axis=1)


def _heading_of_quaternion(table: _Table) -> _Table:
    """The table with its quaternion columns replaced by theta, their yaw (rad); unchanged
    without them. DataError naming the line of a row with some of the quaternion's cells
    empty, or of a quaternion that is no rotation or tilted from z-up
    (:func:`excite.logs.orientation.headings`)."""
    labels = table.columns
    if "qw" not in labels:
        return table
    index = [labels.index(c) for c in QUATERNION_COLUMNS if c in labels]
    empty = table.empty[:, index]
    partial = empty.any(axis=1) & ~empty.all(axis=1)
    if partial.any():
        row = int(np.argmax(partial))
        column = labels[index[int(np.argmax(empty[row]))]]
        raise DataError(f"{table.name}:{table.lines[row]}: {column} is empty (or NaN) "
                        "but other quaternion cells are not")
    q = np.zeros((len(table.lines), 4))
    for axis, column in enumerate(QUATERNION_COLUMNS):
        if column in labels:
            q[:, axis] = table.values[:, labels.index(column)]
    filled = np.flatnonzero(~empty[:, 0])
    theta = np.full(len(table.lines), np.nan)
    theta[filled] = headings(q[filled], lambda i: f"{table.name}:{table.lines[filled[i]]}")
    keep = [i for i, label in enumerate(labels) if label not in QUATERNION_COLUMNS]
    derived = Column("theta", -1, "theta")  # computed, at no position in a row
    columns = (*(table.header.columns[i] for i in keep), derived)
    return replace(table, header=replace(table.header, columns=columns),
                   values=np.column_stack([table.values[:, keep], theta]),
                   empty=np.column_stack([table.empty[:, keep], empty[:, 0]]))


def _tum(line: str) -> bool:
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


def _first_line(path: PathArg) -> str | None:
    """A text file's header line: its first line that is neither blank nor a comment nor a
    separator line (stripped), or :data:`TUM_HEADER` when that line is a TUM trajectory's
    row; None when the file cannot be read as text or has no such line."""
    try:
        with open(os.fspath(path), encoding="utf-8-sig") as handle:
            for line in handle:
                stripped = line.strip()
                if stripped and not stripped.startswith("#") and not is_separator_line(
                        stripped):
                    return None if "\x00" in stripped else (
                        TUM_HEADER if _tum(stripped) else stripped)
    except (OSError, UnicodeDecodeError):
        return None
    return None


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
    line = _first_line(path)
    labels = _labels(line) if line is not None else set()
    if not labels:
        return frozenset()
    labels |= _pose_labels(list(labels))
    groups = {"encoder": (ANGLE_COLUMNS, TICK_COLUMNS), "pose": (POSE_COLUMNS,)}
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
    line = _first_line(path)
    try:
        return _hint(parse_header(line, _names(line), _QUANTITIES, "")) if line else ""
    except DataError:
        return ""


def is_timeseries_csv(path: PathArg) -> bool:
    """Whether a file's header names a time-series column (:data:`ALIASES`): a time-series
    CSV, as opposed to a segment CSV (header ``dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt`` or none);
    False when the file cannot be read as text."""
    return bool(timeseries_streams(path))


def _path_list(paths: PathArg | Sequence[PathArg]) -> list[PathArg]:
    if isinstance(paths, str | bytes | os.PathLike):
        return [paths]
    return list(paths)


def _pick_streams(tables: list[_Table]) -> tuple[_Table, _Table]:
    """(encoder table, pose table): one combined file, or one file of each kind."""
    if len(tables) == 1:
        table = tables[0]
        if table.encoder_columns and table.has_pose:
            return table, table
        have, need = (("encoder", "t,x,y,theta") if table.encoder_columns
                      else ("pose", "t,phi_L,phi_R"))
        raise DataError(f"{table.name}: only {have} columns; give the other stream too "
                        f"(a second file with {need}, or all columns in one file)"
                        f"{_hint(table.header)}")
    for table in tables:
        if table.encoder_columns and table.has_pose:
            raise DataError(f"{table.name}: has both encoder and pose columns; "
                            "give it alone, not with a second file")
    encoders = [t for t in tables if t.encoder_columns]
    poses = [t for t in tables if t.has_pose]
    if len(encoders) != 1 or len(poses) != 1:
        kind = "encoder" if encoders else "pose"
        raise DataError(f"{tables[0].name} and {tables[1].name} are both {kind} files; give "
                        "one encoder file (t,phi_L,phi_R) and one pose file (t,x,y,theta)")
    return encoders[0], poses[0]


def _encoder_angles(table: _Table, ticks_per_rev: float | None
                    ) -> tuple[list[FloatArray], IntArray, tuple[str, ...]]:
    """[t, phi_L, phi_R] (s, rad, rad), lines, and the tick columns whose counter wrapped (e.g.
    'ticks_L (16-bit counter)'); ticks become angles."""
    names = table.encoder_columns
    assert names is not None
    (t, left, right), lines = table.stream(names)
    if names == TICK_COLUMNS:
        if ticks_per_rev is None:
            raise DataError(f"{table.name}:{table.header_line}: encoder ticks (ticks_L, "
                            "ticks_R) need the encoder resolution, ticks_per_rev "
                            "(--ticks-per-rev)")
        scale = tick_angle(ticks_per_rev)
        (left, left_bits), (right, right_bits) = map(unwrapped_counter, (left, right))
        wrapped = tuple(f"{name} ({bits}-bit counter)" for name, bits in
                        zip(TICK_COLUMNS, (left_bits, right_bits), strict=True) if bits)
        return [t, left * scale, right * scale], lines, wrapped
    if ticks_per_rev is not None:
        raise DataError(f"{table.name}:{table.header_line}: ticks_per_rev given, but the "
                        "encoder columns are angles in rad (phi_L, phi_R); ticks are columns "
                        "ticks_L, ticks_R")
    return [t, left, right], lines, ()


def read_timeseries(paths: PathArg | Sequence[PathArg],
                    ticks_per_rev: float | None = None, *,
                    on_note: OnNote | None = None) -> TimeSeries:
    """Read a time-series log from one CSV file or two.

    One file: header ``t,phi_L,phi_R,x,y,theta`` (any column order, names as
    :data:`ALIASES`, separated by commas, semicolons or tabs); a row may leave one stream's
    cells empty when that stream has no sample at its time. Two files, in any order:
    ``t,phi_L,phi_R`` and ``t,x,y,theta`` (recognised by their headers). Wheel columns
    ``ticks_L,ticks_R`` instead of ``phi_L,phi_R`` are encoder ticks: angles = ticks * 2 pi /
    ticks_per_rev (ticks without ticks_per_rev are an error). Units: t in s, angles in rad,
    x, y in m, unless the header gives another unit (``t [ms]``, ``x (mm)``, ``theta [deg]``:
    converted); theta may be wrapped. Other columns are not read. Blank lines and ``#``
    comments are ignored. on_note: told, one line each, the columns not read and the units
    converted (each note starts with the file's name).

    Raises DataError (one line naming the file and line) for: a missing, unreadable or
    binary file; a file that is neither kind; a missing or repeated column; a unit that does
    not fit its column; a wrong cell count; text in a number; decimal commas and points
    mixed; NaN or inf; time not strictly increasing in a stream; fewer than 2 samples in a
    stream.
    """
    if ticks_per_rev is not None:
        tick_angle(ticks_per_rev)  # checked before any file is read
    files = _path_list(paths)
    if not 1 <= len(files) <= 2:
        raise DataError(f"a time-series log is one CSV file or two (encoders and poses), "
                        f"got {len(files)} files")
    note = on_note if on_note is not None else (lambda text: None)
    encoders, poses = _pick_streams([_read_table(p, note) for p in files])
    (t_enc, phi_L, phi_R), enc_lines, counters = _encoder_angles(encoders, ticks_per_rev)
    (t_pose, x, y, theta), pose_lines = poses.stream(POSE_COLUMNS)
    return TimeSeries(t_enc, phi_L, phi_R, t_pose, x, y, theta,
                      source=(encoders.name, poses.name), lines=(enc_lines, pose_lines),
                      unwrapped_counters=counters)


# --------------------------------------------------------------------------- CSV writing

#: Angles further than this from a whole number of ticks (in ticks) are not encoder readings.
WHOLE_TICK_TOLERANCE = 1e-6


def _float_cells(values: FloatArray) -> list[str]:
    """The shortest text of each float that reads back the same float."""
    return list(map(repr, values.tolist()))


def _encoder_cells(series: TimeSeries, ticks_per_rev: float | None
                   ) -> tuple[tuple[str, str], list[list[str]]]:
    """The encoder column names and cells: angles (rad) in full precision, or whole ticks."""
    angles = (series.phi_L, series.phi_R)
    if ticks_per_rev is None:
        return ANGLE_COLUMNS, [_float_cells(a) for a in angles]
    scale = tick_angle(ticks_per_rev)
    cells = []
    for name, angle in zip(ANGLE_COLUMNS, angles, strict=True):
        ticks = angle / scale
        whole = np.rint(ticks)
        off = np.flatnonzero(np.abs(ticks - whole) > WHOLE_TICK_TOLERANCE)
        if off.size:
            i = int(off[0])
            raise DataError(f"{series.location('encoder', i)}: {name} = {float(angle[i])!r} rad is "
                            f"not a whole number of ticks of 2 pi / {ticks_per_rev} rad")
        cells.append(list(map(str, whole.astype(np.int64).tolist())))
    return TICK_COLUMNS, cells


def write_timeseries(path: PathArg, series: TimeSeries,
                     ticks_per_rev: float | None = None) -> None:
    """Write a time-series log as one CSV that :func:`read_timeseries` reads back equal.

    Header ``t,phi_L,phi_R,x,y,theta``, or ``t,ticks_L,ticks_R,x,y,theta`` with
    ``ticks_per_rev`` (the angles divided by 2 pi / ticks_per_rev, written as whole numbers:
    read them back with the same ticks_per_rev). One row per time of either stream, in
    ascending order; a stream's cells are empty in the rows where it has no sample. Times as
    held (s, each stream on its own clock, no offset applied), angles in rad, x, y in m, theta
    in rad (unwrapped), all at full float precision (the shortest text that reads back the
    same float).

    Raises DataError when ticks_per_rev is not positive and finite, or an angle is not a whole
    number of ticks (naming the sample).
    """
    names, encoder = _encoder_cells(series, ticks_per_rev)
    t = np.union1d(series.t_enc, series.t_pose)
    enc_rows = np.searchsorted(t, series.t_enc).tolist()
    pose_rows = np.searchsorted(t, series.t_pose).tolist()
    pose = [_float_cells(a) for a in (series.x, series.y, series.theta)]
    columns = [_float_cells(t)]
    for rows, cells in [(enc_rows, c) for c in encoder] + [(pose_rows, c) for c in pose]:
        column = [""] * t.size
        for row, cell in zip(rows, cells, strict=True):
            column[row] = cell
        columns.append(column)
    rows = (",".join(row) for row in zip(*columns, strict=True))
    lines = [",".join(("t", *names, *POSE_COLUMNS)), *rows]
    with open(path, "w", encoding="utf-8", newline="\n") as file:
        file.write("\n".join(lines) + "\n")
