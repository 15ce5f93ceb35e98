"""Delimited tables of numbers as real exports write them: the separator, the header's names
and units, and the numbers of the columns a format reads (the segment CSV of
:mod:`excite.logs.segments` and the time-series CSV of :mod:`excite.logs.timeseries_csv`).

Separator. Found from a table's first line that is neither blank nor a ``#`` comment (nor
the line ``sep=;`` that spreadsheets may write first: skipped): a semicolon when the line has
one; else a tab when the line's comma-separated fields still hold tabs (so a comma padded
with tabs is a comma); else a comma when the line has one; else spaces (runs of them: a
whitespace-separated table, as a TUM trajectory or a ``printf`` log is) when the line has
more than one field. Every line of the table uses it.
With semicolons, tabs or spaces, numbers may use a decimal comma (``0,25``), decided per
table: a table whose columns read hold decimal commas and decimal points both is an error.

Header fields. A name with an optional unit, ``t [s]``, ``x (m)``, ``theta[rad]``, or a unit
after an underscore when the name before it is a known column (``t_ms``, ``yaw_deg``). Names
are matched without case, surrounding spaces or double quotes; spaces, hyphens and dots inside
a name count as underscores (``pos x`` is ``pos_x``). A format gives its names (aliases
included) and each column's quantity; a unit is converted to the quantity's base unit (s, m,
rad, rad/s; ticks stay ticks, see :data:`UNITS`), and a unit of another quantity, or one not in the
table, is an error naming the column. Columns a format does not know are not read (not even
as numbers) and are reported in a note.

Every error is one line naming the file and line.
"""

from __future__ import annotations

import csv
import math
import operator
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from itertools import repeat

import numpy as np
from numpy.typing import NDArray

from excite.errors import DataError

__all__ = ["UNITS", "Column", "Header", "content_lines", "delimiter_of", "header_fields",
           "is_header", "is_separator_line", "parse_header", "plain_header", "label_of",
           "read_columns"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_DEGREE = (math.pi, 180.0)
#: The units of each quantity a column may carry, as (numerator, denominator) of the factor
#: to the quantity's base unit, the first one listed (s, m, rad, ticks, rad/s).
UNITS: dict[str, dict[str, tuple[float, float]]] = {
    "time": {"s": (1.0, 1.0), "sec": (1.0, 1.0), "secs": (1.0, 1.0), "second": (1.0, 1.0),
             "seconds": (1.0, 1.0), "ms": (1.0, 1e3), "us": (1.0, 1e6), "µs": (1.0, 1e6),
             "μs": (1.0, 1e6), "ns": (1.0, 1e9)},
    "length": {"m": (1.0, 1.0), "cm": (1.0, 1e2), "mm": (1.0, 1e3)},
    "angle": {"rad": (1.0, 1.0), "radian": (1.0, 1.0), "radians": (1.0, 1.0), "deg": _DEGREE,
              "degree": _DEGREE, "degrees": _DEGREE, "°": _DEGREE},
    "count": {"ticks": (1.0, 1.0), "tick": (1.0, 1.0), "counts": (1.0, 1.0),
              "count": (1.0, 1.0)},
    "angular speed": {"rad/s": (1.0, 1.0), "rad/sec": (1.0, 1.0), "deg/s": _DEGREE,
                      "°/s": _DEGREE, "rpm": (2.0 * math.pi, 60.0), "rev/s": (2.0 * math.pi, 1.0)},
    "number": {},  # dimensionless (a quaternion's components): no unit
}
_ALL_UNITS = {unit for units in UNITS.values() for unit in units}
_DELIMITER_NAMES = {",": "commas", ";": "semicolons", "\t": "tabs", " ": "spaces"}
_UNIT = re.compile(r"^(?P<name>.*?)\s*(?:\[(?P<square>[^\]]*)\]|\((?P<round>[^)]*)\))$")
_INNER = re.compile(r"[\s\-.]+")
#: A cell that is a date or a time of day (2024-05-12T13:20:01, 13:20:01.5), not a number.
_CLOCK_TEXT = re.compile(r"\d:\d\d|\d{4}-\d\d-\d\d")
# Whitespace a line may be stripped of: all of it, except tabs in a tab-separated table.
_NOT_TAB = " \r\n\x0b\x0c\xa0"


@dataclass(frozen=True)
class Column:
    """A column a format reads: its name in the format (``label``), its position in a row
    (``index``), the header's text for it (``text``, '' without a header) and the unit it was
    written in (``unit``, None for the base unit or no unit) with that unit's factor."""

    label: str
    index: int
    text: str = ""
    unit: str | None = None
    factor: tuple[float, float] = (1.0, 1.0)

    def converted(self, values: FloatArray) -> FloatArray:
        """Values in this column's unit converted to the base unit."""
        numerator, denominator = self.factor
        if numerator == 1.0:
            return values if denominator == 1.0 else values / denominator
        return values * (numerator / denominator)


@dataclass(frozen=True)
class Header:
    """A table's layout: separator, number of fields per row, the columns read (in the order
    they appear) and the header's texts of those not read."""

    delimiter: str
    width: int
    columns: tuple[Column, ...]
    ignored: tuple[str, ...] = ()
    texts: tuple[str, ...] = ()

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(c.label for c in self.columns)

    def found(self) -> str:
        """The header's fields as written, for messages: "'t', 'x', 'yaw [deg]'"."""
        return ", ".join(repr(text) for text in self.texts)

    def without(self, labels: Sequence[str]) -> Header:
        """This layout with the columns ``labels`` not read (named among the ignored, in the
        header's order)."""
        read = tuple(c for c in self.columns if c.label not in labels)
        positions = {c.index for c in read}
        return replace(self, columns=read, ignored=tuple(
            _unread_name(text, i) for i, text in enumerate(self.texts) if i not in positions))

    def notes(self, name: str) -> list[str]:
        """One-line notes for the user: the columns not read, the units converted."""
        notes = []
        if self.ignored:
            notes.append(f"{name}: columns not read: {', '.join(self.ignored)}")
        converted = [f"{c.label} from {c.unit} to {_base_unit(c.unit)}" for c in self.columns
                     if c.factor != (1.0, 1.0)]
        if converted:
            notes.append(f"{name}: units converted: {', '.join(converted)}")
        return notes


def _unread_name(text: str, index: int) -> str:
    """How a note names a column not read: its header text, or its place when unnamed."""
    return text or f"(unnamed column {index + 1})"


def _base_unit(unit: str | None) -> str:
    """The base unit of the quantity ``unit`` measures (s, m, rad, ticks, rad/s)."""
    return next(next(iter(units)) for units in UNITS.values() if unit in units)


def is_separator_line(line: str) -> bool:
    """Whether a first line (stripped) is a spreadsheet's separator line, ``sep=;``: skipped
    (the header shows the separator)."""
    return line[:4].lower() == "sep=" and line[4:] in ("", *_DELIMITER_NAMES)  # "" a tab


def content_lines(text: str) -> tuple[list[int], list[str]]:
    """Line numbers and text (stripped) of the lines that are neither blank nor comments (nor
    a separator line ``sep=;`` first); in a tab-separated table, tabs at either end of a line
    are kept (they are empty cells)."""
    raw = text.splitlines()
    stripped = [line.strip() for line in raw]
    numbers = [i for i, line in enumerate(stripped, start=1) if line and line[0] != "#"]
    if numbers and is_separator_line(stripped[numbers[0] - 1]):
        numbers = numbers[1:]
    if numbers and delimiter_of(stripped[numbers[0] - 1]) == "\t":
        return numbers, [raw[i - 1].strip(_NOT_TAB) for i in numbers]
    return numbers, [stripped[i - 1] for i in numbers]


def delimiter_of(line: str) -> str:
    """The separator of a table whose first line (stripped) is ``line``: ';', '\\t', ',' or
    ' ' (runs of spaces)."""
    if ";" in line:
        return ";"
    if "\t" in line and any("\t" in field.strip() for field in line.split(",")):
        return "\t"
    if "," not in line and len(line.split()) > 1:
        return " "
    return ","


def header_fields(line: str, delimiter: str) -> list[str]:
    """A line's fields, stripped of spaces and double quotes (a quoted header reads so); with
    spaces, a unit in brackets or parentheses stays with the name before it (``t [s]``)."""
    (fields,) = csv.reader([line], delimiter=delimiter, skipinitialspace=True)
    if delimiter == " ":
        joined: list[str] = []
        for field in fields:
            if joined and field[:1] in "[(" and field:
                joined[-1] += " " + field
            elif field:
                joined.append(field)
        fields = joined
    return [field.strip().strip('"').strip() for field in fields] or [""]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def is_header(fields: Sequence[str], delimiter: str) -> bool:
    """Whether a first line's fields are a header: none of them is a number (with semicolons
    or tabs, a decimal comma counts as a number)."""
    if delimiter != ",":
        fields = [field.replace(",", ".") for field in fields]
    return any(fields) and not any(_is_number(field) for field in fields if field)


def _name_and_unit(text: str) -> tuple[str, str | None]:
    """A header field's name (lower case, inner spaces as underscores) and its bracketed unit
    (lower case; None without one)."""
    match = _UNIT.match(text)
    name, unit = (match["name"], match["square"] if match["square"] is not None
                  else match["round"]) if match else (text, None)
    unit = unit.strip().lower() if unit is not None else None
    return _INNER.sub("_", name.strip().lower()), unit or None


def label_of(text: str, aliases: Mapping[str, str]) -> tuple[str | None, str | None]:
    """The format's name (``aliases`` maps lower-case names to it) of a header field, and the
    unit it is written in (lower case, None without one); (None, None) for an unknown name."""
    name, unit = _name_and_unit(text)
    if name in aliases:
        return aliases[name], unit
    base, _, suffix = name.rpartition("_")
    if unit is None and base in aliases and suffix in _ALL_UNITS:
        return aliases[base], suffix
    return None, None


def _factor(text: str, unit: str | None, quantity: str, where: str) -> tuple[float, float]:
    if unit is None:
        return (1.0, 1.0)
    units = UNITS[quantity]
    if unit not in units:
        raise DataError(f"{where}: column {text!r}: unit {unit!r} is not a unit of "
                        f"{quantity} ({', '.join(units) or 'it has none'})")
    return units[unit]


def parse_header(line: str, aliases: Mapping[str, str], quantities: Mapping[str, str],
                 where: str) -> Header:
    """The layout a header line gives: ``aliases`` maps each accepted lower-case name to the
    format's name, ``quantities`` each format name to its quantity (a key of :data:`UNITS`).
    DataError (at ``where``) for a column given twice or a unit that does not fit."""
    delimiter = delimiter_of(line)
    texts = header_fields(line, delimiter)
    columns: dict[str, Column] = {}
    ignored = []
    for index, text in enumerate(texts):
        label, unit = label_of(text, aliases)
        if label is None:
            ignored.append(_unread_name(text, index))
            continue
        if label in columns:
            first = columns[label].text
            if _name_and_unit(first)[0] == _name_and_unit(text)[0]:
                raise DataError(f"{where}: column {label} appears twice")
            raise DataError(f"{where}: columns {first!r} and {text!r} are both {label}; "
                            "keep one")
        factor = _factor(text, unit, quantities[label], where)
        base = factor == (1.0, 1.0)
        columns[label] = Column(label, index, text, None if base else unit, factor)
    return Header(delimiter, len(texts), tuple(columns.values()), tuple(ignored), tuple(texts))


def plain_header(labels: Sequence[str], delimiter: str) -> Header:
    """The layout of a table without a header: ``labels`` in this order, base units."""
    return Header(delimiter, len(labels), tuple(Column(label, i) for i, label in
                                                enumerate(labels)))


def _split(lines: list[str], delimiter: str, width: int) -> tuple[list[str], int | None]:
    """The cells of the rows before the first with a wrong number of fields, row after row,
    stripped; and that row's index (None when every row has ``width`` fields). Quoted cells
    (a text column holding the separator) are read as CSV quoting has them; with spaces,
    each run of them separates two cells. When the first row has one field too many, the last
    empty (a separator ending the rows), such rows have no such cell."""
    if delimiter == " ":
        lines = [" ".join(line.split()) for line in lines]
    if lines and lines[0].endswith(delimiter) and lines[0].count(delimiter) == width:
        lines = [line[:-1] if line.endswith(delimiter) and line.count(delimiter) == width
                 else line for line in lines]  # a separator ending the rows: no cell
    joined = delimiter.join(lines)
    if '"' in joined:
        rows = list(csv.reader(lines, delimiter=delimiter, skipinitialspace=True))
        counts = np.array([len(row) for row in rows], dtype=np.int64)
        wrong = np.flatnonzero(counts != width)
        good = rows[: wrong[0]] if wrong.size else rows
        cells = [cell.strip() for row in good for cell in row]
        return cells, (int(wrong[0]) if wrong.size else None)
    counts = np.fromiter(map(str.count, lines, repeat(delimiter)), dtype=np.int64,
                         count=len(lines)) + 1
    wrong = np.flatnonzero(counts != width)
    if wrong.size:
        joined = delimiter.join(lines[: wrong[0]])
    if " " in joined or "\t" in joined:
        pad = "[ ]" if delimiter == "\t" else "[ \t]"
        joined = re.sub(f"{pad}*{re.escape(delimiter)}{pad}*", delimiter, joined)
    cells = joined.split(delimiter) if joined else []
    return cells, (int(wrong[0]) if wrong.size else None)


def _cells_read(cells: list[str], header: Header) -> list[str]:
    """The cells (row after row) with those of the columns not read set to '0': they are
    never parsed, and the numbers are parsed in one pass."""
    read = {column.index for column in header.columns}
    rows = len(cells) // header.width
    for j in range(header.width):
        if j not in read:
            cells[j::header.width] = ["0"] * rows
    return cells


def _column_at(header: Header, index: int) -> Column:
    return next(c for c in header.columns if c.index == index % header.width)


def _points(name: str, numbers: list[int], header: Header, cells: list[str]) -> list[str]:
    """The cells with decimal commas as points when the table has them (only with semicolons
    or tabs); DataError at the first decimal point when commas and points are mixed."""
    if header.delimiter == ",":
        return cells
    joined = "\n".join(cells)
    if "," not in joined:
        return cells
    if "." in joined:
        i = next(i for i, cell in enumerate(cells) if "." in cell)
        raise DataError(f"{name}:{numbers[i // header.width]}: {_column_at(header, i).label} "
                        f"has a decimal point ({cells[i]!r}) but other numbers have decimal "
                        "commas")
    return joined.replace(",", ".").split("\n")


def _numbers(name: str, numbers: list[int], header: Header, cells: list[str],
             allow_empty: bool) -> tuple[FloatArray, BoolArray]:
    """(values, empty) (n, m) of the columns read from the cells (row after row, width
    fields each); DataError at the first cell read (row after row) that is not a number, or
    not finite (with ``allow_empty``, NaN is read as NaN: only an infinity is an error)."""
    count = len(cells)
    empty = (np.fromiter(map(operator.not_, cells), dtype=bool, count=count) if allow_empty
             else np.zeros(count, dtype=bool))
    texts = [cell or "nan" for cell in cells] if empty.any() else cells
    try:
        values = np.fromiter(map(float, texts), dtype=float, count=count)
        bad, what = count, ""
    except ValueError:
        bad, what = next(i for i, text in enumerate(texts) if not _is_number(text)), "a number"
        values = np.fromiter(map(float, texts[:bad]), dtype=float, count=bad)
    not_finite = np.isinf(values) if allow_empty else ~np.isfinite(values)
    infinite = np.flatnonzero(not_finite & ~empty[: values.size])
    if infinite.size:
        bad, what = int(infinite[0]), "finite"
    if what:
        column = _column_at(header, bad)
        clock = (" (a date or a time of day: write times as numbers of s, e.g. seconds since "
                 "the epoch)" if column.label in ("t", "t_start", "t_end")
                 and _CLOCK_TEXT.search(cells[bad]) else "")
        raise DataError(f"{name}:{numbers[bad // header.width]}: "
                        f"{column.label} is not {what}: {cells[bad]!r}{clock}")
    index = [column.index for column in header.columns]
    return (values.reshape(-1, header.width)[:, index],
            empty.reshape(-1, header.width)[:, index])


def read_columns(name: str, numbers: list[int], lines: list[str], header: Header, *,
                 allow_empty: bool = False) -> tuple[FloatArray, BoolArray]:
    """The numbers of the columns ``header`` reads from data ``lines`` (stripped, numbered
    ``numbers`` in file ``name``), converted to base units: (values, empty), each (n, m) for
    the m columns in header order; empty cells are NaN in values and True in empty when
    ``allow_empty`` (otherwise an empty cell is not a number), and NaN cells are then NaN in
    values and False in empty (the caller decides what a NaN means).

    DataError naming the file and line of the first problem, row after row: a row with
    another number of fields than ``header.width``, a cell read that is not a number or not
    finite (only infinite with ``allow_empty``), decimal commas and points mixed.
    """
    cells, wrong = _split(lines, header.delimiter, header.width)
    cells = _points(name, numbers, header, _cells_read(cells, header))
    values, empty = _numbers(name, numbers, header, cells, allow_empty)
    if wrong is not None:
        count = (len(next(csv.reader([lines[wrong]], delimiter=header.delimiter)))
                 if '"' in lines[wrong] else lines[wrong].count(header.delimiter) + 1)
        by = ("" if header.delimiter == "," else
              f" separated by {_DELIMITER_NAMES[header.delimiter]}")
        raise DataError(f"{name}:{numbers[wrong]}: expected {header.width} columns{by}, "
                        f"found {count}")
    converted = [c.converted(values[:, j]) for j, c in enumerate(header.columns)]
    return (np.column_stack(converted) if converted else values), empty
