"""Time-series logs as CSV files: one file with both streams, or two files with one stream
each, read into a :class:`~excite.logs.timeseries.TimeSeries` and written back.

Columns (header required, any order; the names and units read, and the header a TUM
trajectory implies: :mod:`excite.logs.timeseries_header`): ``t`` (s), the wheel angles
``phi_L,phi_R`` (rad) or encoder ticks ``ticks_L,ticks_R`` (with ticks_per_rev), and the
pose ``x,y`` (m), ``theta`` (rad, may be wrapped) or an orientation quaternion whose yaw is
the heading (:mod:`excite.logs.orientation`: free of the quaternion's length; a z-up world
frame); other columns are not read, with a note naming them. Separated by commas,
semicolons, tabs or spaces (:mod:`excite.logs.csv_table`). In one file, a row leaves a
stream's cells empty (or NaN) when that stream has no sample at its time. Blank lines and
``#`` comments are ignored. Every error is one line naming the file and line
(docs/formats.md, "Time-series logs").
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from excite.core.arrays import BoolArray, FloatArray, IntArray
from excite.errors import DataError
from excite.logs.csv_table import (
    Column,
    Header,
    content_lines,
    read_columns,
)
from excite.logs.export_layouts import HEADER_LINES, Layout, layout
from excite.logs.orientation import headings, z_up
from excite.logs.segments import read_text
from excite.logs.timeseries import (
    ANGLE_COLUMNS,
    POSE_COLUMNS,
    SPEED_COLUMNS,
    SPEED_NOTE,
    TICK_COLUMNS,
    TimeSeries,
    integrated_speed,
    tick_angle,
    unwrapped_counter,
)
from excite.logs.timeseries_header import (
    EXPECTED,
    QUATERNION_COLUMNS,
    columns_hint,
    is_time_name,
    parse_timeseries_header,
)

__all__ = ["read_timeseries", "write_timeseries"]

PathArg = str | os.PathLike[str]
OnNote = Callable[[str], None]

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
        for names in (ANGLE_COLUMNS, TICK_COLUMNS, SPEED_COLUMNS):
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
        raise DataError(f"{name}: empty file (expected a header {EXPECTED})")
    found = layout(lines[:HEADER_LINES], lambda i: f"{name}:{numbers[i]}", is_time_name)
    if found.speeds is None:
        return _table_of(name, numbers, lines, found, note)
    notes: list[str] = []
    table = _table_of(name, numbers, lines, found, notes.append)
    if table.encoder_columns == ANGLE_COLUMNS and not _changing(table, ANGLE_COLUMNS):
        note(f"{name}: the wheel joints' position columns are never filled or never change "
             "(a driver that reports velocities only): their velocity columns read instead")
        return _table_of(name, numbers, lines, found.speeds, note)
    for line in notes:
        note(line)
    return table


def _changing(table: _Table, names: Sequence[str]) -> bool:
    """Whether the columns ``names`` are filled in some row and take more than one value."""
    _, *columns = table.stream(names)[0]
    return any(np.ptp(column) > 0 for column in columns if column.size)


def _table_of(name: str, numbers: list[int], lines: list[str], found: Layout, note: OnNote
              ) -> _Table:
    """The table of a file's content ``lines`` (their line ``numbers``) read with the layout
    ``found``."""
    if found.note is not None:
        note(f"{name}: {found.note}")
    header_number = numbers[found.data - 1] if found.data else numbers[0] - 1
    numbers, lines = [header_number, *numbers[found.data:]], [found.header,
                                                             *lines[found.data:]]
    header = parse_timeseries_header(lines[0], f"{name}:{numbers[0]}")
    for line in header.notes(name):
        note(line)
    values, empty = read_columns(name, numbers[1:], lines[1:], header, allow_empty=True)
    line_numbers = np.asarray(numbers[1:], dtype=np.int64)
    empty, with_nan, unmeasured = _nan_as_missing(header, values, empty)
    keep = ~unmeasured
    table = _heading_of_quaternion(_Table(name, header, values[keep], empty[keep],
                                          line_numbers[keep], numbers[0]), note)
    if table.header is not header:
        note(f"{name}: theta is the yaw of the quaternion "
             f"{', '.join(c for c in QUATERNION_COLUMNS if c in header.labels)}")
    table = _held_as_missing(_checked_cells(table, note), note)
    if with_nan.any():
        rows = line_numbers[with_nan]
        note(f"{name}: {rows.size} rows with NaN cells (lines {rows[0]}-{rows[-1]}) read as "
             "samples not measured, like empty cells (a motion-capture body not tracked?)")
    return table


#: A stream of a one-file table whose value usually changes only every this many rows or
#: more, repeating in between, was filled with held values (:func:`_held_as_missing`).
HELD_ROWS = 1.5
#: A run of repeats up to this many times the stream's usual interval between changes is a
#: held value; a longer one is the robot standing still (kept: its value is the same).
HELD_RUN = 3.0
#: The fewest values a stream must take before its repeats are judged.
MIN_HELD_VALUES = 10
#: A filled export's stream changes at its own rate: at least this share of the intervals
#: between its changes lie within HELD_JITTER of their median (a coarse value that holds
#: while the robot creeps changes at times that follow the motion instead).
HELD_REGULAR = 0.8
HELD_JITTER = 0.25


def _held_as_missing(table: _Table, note: OnNote) -> _Table:
    """The table with a stream's held values as empty cells: an export that writes every row
    full (PlotJuggler's "fill with previous value") repeats a stream's last sample in the
    rows of the other stream's samples, so its values change only every few rows, at its own
    rate. Where a stream's value usually changes only every :data:`HELD_ROWS` rows or more,
    at regular times (:data:`HELD_REGULAR`), each repeat
    of the value before it, in a run of repeats lasting up to :data:`HELD_RUN` times the
    usual interval between changes, is no sample (read at a later time, it would shift the
    stream's clock by up to a sample period); longer runs (standing still) are kept. A stream
    with an empty cell after its first sample is no filled export's, and is left as it is.
    Rows left with no value are dropped; ``note`` is told per stream."""
    groups = [g for g in (table.encoder_columns, POSE_COLUMNS if table.has_pose else None)
              if g]
    if len(groups) < 2:
        return table
    empty = table.empty.copy()
    for group in groups:
        index = [table.columns.index(c) for c in group]
        rows = np.flatnonzero(~empty[:, index[0]])
        if rows.size and rows[-1] - rows[0] + 1 != rows.size:
            continue  # empty cells between its samples: not a filled export
        t = table.values[rows, table.columns.index("t")]
        values = table.values[np.ix_(rows, index)]
        changed = np.concatenate(([True], np.any(values[1:] != values[:-1], axis=1)))
        starts = np.flatnonzero(changed)
        if (starts.size < MIN_HELD_VALUES or rows.size < HELD_ROWS * starts.size
                or np.any(np.diff(t) <= 0)):  # a clock that does not increase: an error later
            continue
        intervals = np.diff(t[starts])
        usual = float(np.median(intervals))
        if np.mean(np.abs(intervals - usual) <= HELD_JITTER * usual) < HELD_REGULAR:
            continue  # changes at irregular times: a coarse value that holds, not a rate
        run = np.diff(np.append(starts, rows.size))  # rows per value
        ends = t[np.minimum(starts + run, rows.size - 1)]
        held = np.repeat(ends - t[starts] <= HELD_RUN * usual, run) & ~changed
        empty[np.ix_(rows[held], index)] = True
        note(f"{table.name}: the {'/'.join(group)} cells repeat the row before them in "
             f"{int(held.sum())} rows (an export that fills every cell with the last value, "
             "e.g. PlotJuggler's, or values that change only every few rows): read as no "
             "sample")
    keep = ~np.all(empty[:, [table.columns.index(c) for g in groups for c in g]], axis=1)
    return replace(table, values=table.values[keep], empty=empty[keep],
                   lines=table.lines[keep])


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


def _heading_of_quaternion(table: _Table, note: OnNote) -> _Table:
    """The table with its quaternion columns (and z) replaced by theta, their yaw (rad), a
    Y-up stream turned Z-up first (:func:`excite.logs.orientation.z_up`, with z; ``note`` is
    told); unchanged without them. DataError naming the line of a row with some of the
    quaternion's cells empty, or of a quaternion that is no rotation or tilted from z-up
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
    values = table.values
    if "z" in labels:
        xyz = values[np.ix_(filled, [labels.index(c) for c in ("x", "y", "z")])]
        q_up, xyz, turned = z_up(q[filled], xyz)
        if turned is not None:
            if np.isnan(xyz).any():
                row = filled[int(np.argmax(np.isnan(xyz).any(axis=1)))]
                raise DataError(f"{table.name}:{table.lines[row]}: z is empty but the poses "
                                "are Y-up (their ground coordinates are x and z)")
            values = values.copy()
            values[filled, labels.index("x")], values[filled, labels.index("y")] = xyz[:, :2].T
            q[filled] = q_up
            note(f"{table.name}: {turned}")
    theta = np.full(len(table.lines), np.nan)
    theta[filled] = headings(q[filled], lambda i: f"{table.name}:{table.lines[filled[i]]}")
    keep = [i for i, label in enumerate(labels) if label not in (*QUATERNION_COLUMNS, "z")]
    derived = Column("theta", -1, "theta")  # computed, at no position in a row
    columns = (*(table.header.columns[i] for i in keep), derived)
    return replace(table, header=replace(table.header, columns=columns),
                   values=np.column_stack([values[:, keep], theta]),
                   empty=np.column_stack([table.empty[:, keep], empty[:, 0]]))


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
                        f"{columns_hint(table.header)}")
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


def _encoder_angles(table: _Table, ticks_per_rev: float | None, note: OnNote
                    ) -> tuple[list[FloatArray], IntArray, tuple[str, ...]]:
    """[t, phi_L, phi_R] (s, rad, rad), lines, and the tick columns whose counter wrapped (e.g.
    'ticks_L (16-bit counter)'); ticks become angles, speeds are integrated (``note`` told)."""
    names = table.encoder_columns
    assert names is not None
    (t, left, right), lines = table.stream(names)
    if names == SPEED_COLUMNS and ticks_per_rev is None:
        note(f"{table.name}: {SPEED_NOTE}")
        return [t, integrated_speed(t, left), integrated_speed(t, right)], lines, ()
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
                        f"encoder columns are {', '.join(names)}, not ticks; ticks are columns "
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
    ticks_per_rev (ticks without ticks_per_rev are an error); ``omega_L,omega_R`` are wheel
    speeds (rad/s, or the unit the header gives: deg/s, rpm), integrated into angles
    (:func:`excite.logs.timeseries.integrated_speed`, with a note). Units: t in s, angles in rad,
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
    (t_enc, phi_L, phi_R), enc_lines, counters = _encoder_angles(encoders, ticks_per_rev, note)
    (t_pose, x, y, theta), pose_lines = poses.stream(POSE_COLUMNS)
    return TimeSeries(t_enc, phi_L, phi_R, t_pose, x, y, theta,
                      source=(encoders.name, poses.name), lines=(enc_lines, pose_lines),
                      unwrapped_counters=counters,
                      speeds=encoders.encoder_columns == SPEED_COLUMNS)


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
