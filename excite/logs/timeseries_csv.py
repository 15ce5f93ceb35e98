"""Time-series logs as CSV files: one file with both streams, or two files with one stream
each, read into a :class:`~excite.logs.timeseries.TimeSeries` and written back.

Columns (header required, any order, names case-insensitive): ``t`` (s), the wheel angles
``phi_L,phi_R`` (rad) or encoder ticks ``ticks_L,ticks_R`` (with ticks_per_rev), and the pose
``x,y`` (m), ``theta`` (rad, may be wrapped). In one file, a row leaves a stream's cells empty
when that stream has no sample at its time. Blank lines and ``#`` comments are ignored. Every
error is one line naming the file and line (docs/formats.md, "Time-series logs").
"""

from __future__ import annotations

import operator
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from itertools import repeat

import numpy as np
from numpy.typing import NDArray

from excite.errors import DataError
from excite.logs.segments import read_text
from excite.logs.timeseries import (
    ANGLE_COLUMNS,
    POSE_COLUMNS,
    TICK_COLUMNS,
    TimeSeries,
    tick_angle,
    unwrapped_counter,
)

__all__ = ["read_timeseries", "write_timeseries", "timeseries_streams", "is_timeseries_csv"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
PathArg = str | os.PathLike[str]

_CANONICAL = {c.lower(): c for c in ("t", *ANGLE_COLUMNS, *TICK_COLUMNS, *POSE_COLUMNS)}
_EXPECTED = "t,phi_L,phi_R,x,y,theta in one file, or t,phi_L,phi_R and t,x,y,theta in two"
_SPACE_AROUND_COMMA = re.compile(r"[ \t]*,[ \t]*")


@dataclass(frozen=True)
class _Table:
    """The data rows of one time-series CSV: values (n, k) with NaN in empty cells."""

    name: str
    columns: tuple[str, ...]
    values: FloatArray
    empty: BoolArray
    lines: IntArray
    header_line: int

    def has(self, names: Iterable[str]) -> bool:
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


def _content_lines(text: str) -> tuple[list[int], list[str]]:
    """Line numbers and stripped text of the lines that are neither blank nor comments."""
    stripped = [line.strip() for line in text.splitlines()]
    numbers = [i for i, line in enumerate(stripped, start=1) if line and line[0] != "#"]
    return numbers, [stripped[i - 1] for i in numbers]


def _header_names(line: str) -> list[str]:
    """A header's names, lower case, without spaces or the double quotes of a quoted header."""
    return [field.strip().strip('"').strip().lower() for field in line.split(",")]


def _names_timeseries(names: set[str]) -> bool:
    """Whether a header's names are a time-series CSV's: a ``t`` column, or any wheel or pose
    column (a time column under another name is then an error naming it, not a segment CSV)."""
    known = {n.lower() for n in ANGLE_COLUMNS + TICK_COLUMNS + POSE_COLUMNS}
    return "t" in names or bool(names & known)


def _parse_header(line: str, where: str) -> tuple[str, ...]:
    """Canonical column names of a time-series header; DataError for anything else."""
    names = _header_names(line)
    if "t" not in names:
        raise DataError(f"{where}: no time column t (s); the header names "
                        f"{', '.join(repr(n) for n in names)} (expected {_EXPECTED})")
    for name in names:
        if name not in _CANONICAL:
            raise DataError(f"{where}: unknown column {name!r} (time-series columns: t, "
                            "phi_L, phi_R or ticks_L, ticks_R, x, y, theta)")
        if names.count(name) > 1:
            raise DataError(f"{where}: column {_CANONICAL[name]} appears twice")
    columns = tuple(_CANONICAL[n] for n in names)
    _check_column_set(columns, where)
    return columns


def _check_column_set(columns: tuple[str, ...], where: str) -> None:
    """A complete encoder group (angles or ticks), a complete pose group, or both."""
    angles, ticks = set(ANGLE_COLUMNS) & set(columns), set(TICK_COLUMNS) & set(columns)
    if angles and ticks:
        raise DataError(f"{where}: both wheel angles (phi_L, phi_R) and ticks "
                        "(ticks_L, ticks_R); give one kind")
    groups = [(present, expected) for present, expected in (
        (angles, ANGLE_COLUMNS), (ticks, TICK_COLUMNS), (set(POSE_COLUMNS) & set(columns),
                                                         POSE_COLUMNS)) if present]
    if not groups:
        raise DataError(f"{where}: neither encoder (phi_L, phi_R) nor pose (x, y, theta) "
                        f"columns (expected {_EXPECTED})")
    for present, expected in groups:
        missing = [c for c in expected if c not in present]
        if missing:
            raise DataError(f"{where}: missing column {missing[0]} (expected {_EXPECTED})")


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _parse_cells(name: str, columns: tuple[str, ...], numbers: list[int],
                 lines: list[str]) -> tuple[FloatArray, BoolArray]:
    """(values, empty) arrays (n, k) of the (stripped) data lines, NaN in empty cells;
    DataError at the first bad line."""
    k = len(columns)
    if not lines:
        return np.zeros((0, k)), np.zeros((0, k), dtype=bool)
    counts = np.fromiter(map(str.count, lines, repeat(",")), dtype=np.int64,
                         count=len(lines)) + 1
    wrong = np.flatnonzero(counts != k)
    if wrong.size:
        i = int(wrong[0])
        raise DataError(f"{name}:{numbers[i]}: expected {k} columns, found {counts[i]}")
    joined = ",".join(lines)
    if " " in joined or "\t" in joined:
        joined = _SPACE_AROUND_COMMA.sub(",", joined)
    cells = joined.split(",")
    empty = np.fromiter(map(operator.not_, cells), dtype=bool, count=len(cells))
    try:
        values = np.fromiter(map(float, [c or "nan" for c in cells]), dtype=float,
                             count=len(cells))
    except ValueError:
        index = next(i for i, cell in enumerate(cells) if cell and not _is_number(cell))
        row, column = divmod(index, k)
        raise DataError(f"{name}:{numbers[row]}: {columns[column]} is not a number: "
                        f"{cells[index]!r}") from None
    return values.reshape(-1, k), empty.reshape(-1, k)


def _check_empty_cells(table: _Table) -> None:
    """t is always filled; each stream's cells in a row are all filled or all empty; a row
    fills at least one stream."""
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
            raise DataError(f"{table.name}:{table.lines[row]}: {column} is empty but other "
                            f"{'/'.join(group)} cells are not")
        filled_any |= ~empty[:, 0]
    if not filled_any.all():
        row = int(np.argmin(filled_any))
        raise DataError(f"{table.name}:{table.lines[row]}: the row has only a time, no values")


def _read_table(path: PathArg) -> _Table:
    """Read and check one time-series CSV (header required)."""
    name = os.fspath(path)
    text = read_text(name)
    numbers, lines = _content_lines(text)
    if not lines:
        raise DataError(f"{name}: empty file (expected a header {_EXPECTED})")
    columns = _parse_header(lines[0], f"{name}:{numbers[0]}")
    values, empty = _parse_cells(name, columns, numbers[1:], lines[1:])
    table = _Table(name, columns, values, empty, np.asarray(numbers[1:], dtype=np.int64),
                   numbers[0])
    _check_empty_cells(table)
    return table


def _header_of(path: PathArg) -> set[str] | None:
    """The lower-case names of a text file's first line that is neither blank nor a comment;
    None when the file cannot be read as text or has no such line."""
    try:
        with open(os.fspath(path), encoding="utf-8-sig") as handle:
            for line in handle:
                stripped = line.strip()
                if stripped and not stripped.startswith("#"):
                    return None if "\x00" in stripped else set(_header_names(stripped))
    except (OSError, UnicodeDecodeError):
        return None
    return None


def timeseries_streams(path: PathArg) -> frozenset[str]:
    """The streams a time-series CSV holds, from its header: a subset of {"encoder", "pose"};
    empty when the header names neither a ``t`` column nor a wheel or pose column (a segment
    CSV, header
    ``dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt`` or none) or the file cannot be read as text.
    Reads only up to the header."""
    names = _header_of(path)
    if not names or not _names_timeseries(names):
        return frozenset()
    wheels = {n.lower() for n in ANGLE_COLUMNS + TICK_COLUMNS}
    return frozenset(kind for kind, columns in (("encoder", wheels), ("pose", set(POSE_COLUMNS)))
                     if names & columns)


def is_timeseries_csv(path: PathArg) -> bool:
    """Whether a file's header names a ``t`` column or a wheel or pose column: a time-series
    CSV, as opposed to a segment CSV (header ``dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt`` or none);
    False when the file cannot be read as text."""
    names = _header_of(path)
    return bool(names) and _names_timeseries(names)


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
                        f"(a second file with {need}, or all columns in one file)")
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
                    ticks_per_rev: float | None = None) -> TimeSeries:
    """Read a time-series log from one CSV file or two.

    One file: header ``t,phi_L,phi_R,x,y,theta`` (any column order); a row may leave one
    stream's cells empty when that stream has no sample at its time. Two files, in any order:
    ``t,phi_L,phi_R`` and ``t,x,y,theta`` (recognised by their headers). Wheel columns
    ``ticks_L,ticks_R`` instead of ``phi_L,phi_R`` are encoder ticks: angles = ticks * 2 pi /
    ticks_per_rev (ticks without ticks_per_rev are an error). Units: t in s, angles in rad,
    x, y in m; theta may be wrapped. Blank lines and ``#`` comments are ignored.

    Raises DataError (one line naming the file and line) for: a missing, unreadable or
    binary file; a file that is neither kind; a missing, unknown or repeated column; a wrong
    cell count; text in a number; NaN or inf; time not strictly increasing in a stream; fewer
    than 2 samples in a stream.
    """
    if ticks_per_rev is not None:
        tick_angle(ticks_per_rev)  # checked before any file is read
    files = _path_list(paths)
    if not 1 <= len(files) <= 2:
        raise DataError(f"a time-series log is one CSV file or two (encoders and poses), "
                        f"got {len(files)} files")
    encoders, poses = _pick_streams([_read_table(p) for p in files])
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
