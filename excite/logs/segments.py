"""Segment data: the lesson's CSV format and Censi tuple files, read with validation.

A segment CSV has the columns ``dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt`` (radians, radians,
meters, meters, radians; the pose increment in the body frame at the segment's start, dtheta
continuous), one row per segment, and optionally ``t_start,t_end`` (s). The header line is
optional; with one, the columns may come in any order, carry units (``dx_gt [mm]``,
``dtheta_gt (deg)``: converted) and be joined by columns that are not read (a note names
them). Separated by commas, semicolons or tabs (:mod:`excite.logs.csv_table`). Blank lines
and lines starting with ``#`` are ignored. Any other malformed line is an error naming the
file and line.

A Censi tuple file (Censi et al., "Simultaneous calibration of odometry and sensor parameters
for mobile robots", T-RO 2013) is a stream of JSON objects (not a JSON array) separated by any
whitespace, ``{"T": s, "phi_l": rad/s, "phi_r": rad/s, "sm": [x, y, theta], ...}``, one segment
per object, extra keys ignored. The segment is ``dphi_L = phi_l * T``, ``dphi_R = phi_r * T``
and ``(dx, dy, dtheta) = sm`` (m, m, rad): the sensor's own motion in the sensor frame at the
segment's start. Between objects, ``#`` starts a comment that runs to the end of the line. A
file is read as a tuple file when its name ends in ``.tuple`` or its first character that is
not whitespace or in a comment line is ``{``; otherwise it is a segment CSV.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.errors import DataError
from excite.logs.csv_table import (
    Header,
    content_lines,
    delimiter_of,
    header_fields,
    is_header,
    parse_header,
    plain_header,
    read_columns,
)
from excite.logs.segment_bounds import first_impossible

__all__ = [
    "COLUMNS",
    "DataError",
    "MIN_SEGMENTS",
    "Segments",
    "load_segment_files",
    "load_segments",
    "check_not_utf16",
    "form_problem",
    "read_text",
    "save_segments",
]

COLUMNS = ("dphi_L", "dphi_R", "dx_gt", "dy_gt", "dtheta_gt")
#: Optional trailing columns of a segment CSV cut from a log: each segment's time span (s).
TIME_COLUMNS = ("t_start", "t_end")
MIN_SEGMENTS = 3
_NAMES = {c.lower(): c for c in COLUMNS + TIME_COLUMNS}
_QUANTITIES = {"dphi_L": "angle", "dphi_R": "angle", "dx_gt": "length", "dy_gt": "length",
               "dtheta_gt": "angle", "t_start": "time", "t_end": "time"}
FloatArray = NDArray[np.float64]
OnNote = Callable[[str], None]
_FIELDS = ("dphi_L", "dphi_R", "dx", "dy", "dtheta")
TUPLE_SUFFIX = ".tuple"
TUPLE_KEYS = ("T", "phi_l", "phi_r", "sm")
# Whitespace and "#" comments (to the end of the line) between the objects of a tuple file.
_TUPLE_GAP = re.compile(r"(?:\s+|#[^\n]*)*")


@dataclass(frozen=True)
class Segments:
    """N motion segments as float64 arrays of shape (N,).

    dphi_L, dphi_R: encoder increments (rad). dx, dy (m), dtheta (rad): measured pose
    increment in the body frame at the segment's start, dtheta continuous (unwrapped).

    Segments cut from a time-series log also carry (all None otherwise):
    t_start, t_end (N,): each segment's time span (s, encoder clock).
    chained (N,) bool: segment k starts at the very pose sample where segment k - 1 ended, so
    their measured increments share that sample's noise (calibration models the correlation).
    sub_dphi_L, sub_dphi_R (N, K): each segment's consecutive encoder sub-increments (rad,
    zero-padded, summing to dphi_L, dphi_R): the motion is their composition, not one arc.
    sub_count (N,) int: how many of the K sub-steps are the segment's own, equal parts of its
    time span (the rest is padding); None: all K (see :attr:`substep_counts`).
    """

    dphi_L: NDArray[np.float64]
    dphi_R: NDArray[np.float64]
    dx: NDArray[np.float64]
    dy: NDArray[np.float64]
    dtheta: NDArray[np.float64]
    t_start: NDArray[np.float64] | None = None
    t_end: NDArray[np.float64] | None = None
    chained: NDArray[np.bool_] | None = None
    sub_dphi_L: NDArray[np.float64] | None = None
    sub_dphi_R: NDArray[np.float64] | None = None
    sub_count: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        arrays = [np.array(getattr(self, name), dtype=float).reshape(-1) for name in _FIELDS]
        if len({a.size for a in arrays}) != 1:
            raise DataError("segment arrays must all have the same length")
        n = arrays[0].size
        for name, a in zip(_FIELDS, arrays, strict=True):
            if not np.all(np.isfinite(a)):
                raise DataError(f"{name} contains NaN or inf")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        for name, dtype, ndim in _OPTIONAL:
            value = getattr(self, name)
            if value is None:
                continue
            a = np.array(value, dtype=dtype)
            if a.ndim != ndim or a.shape[0] != n or (dtype is float and not np.all(
                    np.isfinite(a))):
                raise DataError(f"{name} must be a finite array with {n} rows, got shape "
                                f"{a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if (self.sub_dphi_L is None) != (self.sub_dphi_R is None) or (
                self.sub_dphi_L is not None and self.sub_dphi_L.shape != self.sub_dphi_R.shape):
            raise DataError("sub_dphi_L and sub_dphi_R must be given together, of one shape")
        if self.sub_count is not None and (self.sub_dphi_L is None or not np.all(
                (self.sub_count >= 1) & (self.sub_count <= self.sub_dphi_L.shape[1]))):
            raise DataError("sub_count needs sub-steps, each count in 1..K")

    @property
    def substep_counts(self) -> NDArray[np.int64] | None:
        """Each segment's own sub-steps (N,) (None without sub-steps)."""
        if self.sub_dphi_L is None:
            return None
        if self.sub_count is None:
            return np.full(len(self), self.sub_dphi_L.shape[1], dtype=np.int64)
        return self.sub_count

    @classmethod
    def from_array(cls, rows: ArrayLike) -> Segments:
        """Build from an (N, 5) array in CSV column order."""
        a = np.asarray(rows, dtype=float)
        if a.ndim != 2 or a.shape[1] != 5:
            raise DataError(f"expected an (N, 5) array of segments, got shape {a.shape}")
        return cls(*a.T)

    @classmethod
    def concatenate(cls, parts: Sequence[Segments]) -> Segments:
        """One data set of several, in order; no segment is chained across parts. Times and
        sub-steps are kept when every part has them (sub-steps zero-padded to one K)."""
        def joined(name: str) -> NDArray | None:
            values = [getattr(p, name) for p in parts]
            return None if any(v is None for v in values) else np.concatenate(values)

        chained = [np.zeros(len(p), dtype=bool) if p.chained is None else p.chained.copy()
                   for p in parts]
        for c in chained:
            c[:1] = False
        subs: list[NDArray | None] = [None, None]
        counts = None
        if all(p.sub_dphi_L is not None for p in parts):
            counts = np.concatenate([p.substep_counts for p in parts])
            width = max(p.sub_dphi_L.shape[1] for p in parts)
            subs = [np.concatenate([np.pad(getattr(p, name), ((0, 0), (0, width - getattr(
                p, name).shape[1]))) for p in parts]) for name in ("sub_dphi_L", "sub_dphi_R")]
        rows = np.concatenate([p.as_array() for p in parts])
        return cls(*rows.T, t_start=joined("t_start"), t_end=joined("t_end"),
                   chained=np.concatenate(chained) if any(p.chained is not None for p in parts)
                   else None, sub_dphi_L=subs[0], sub_dphi_R=subs[1], sub_count=counts)

    def as_array(self) -> NDArray[np.float64]:
        """(N, 5) array in CSV column order."""
        return np.column_stack([self.dphi_L, self.dphi_R, self.dx, self.dy, self.dtheta])

    @property
    def measured(self) -> NDArray[np.float64]:
        """(N, 3) measured increments (dx, dy, dtheta)."""
        return np.column_stack([self.dx, self.dy, self.dtheta])

    def __len__(self) -> int:
        return int(self.dphi_L.size)

    def __getitem__(self, index) -> Segments:
        """The segments at ``index`` (slice, mask or indices), in that order; a segment stays
        chained only to the segment right before it in the original data."""
        positions = np.arange(len(self))[index].reshape(-1)
        optional = {}
        for name, _, _ in _OPTIONAL:
            value = getattr(self, name)
            optional[name] = None if value is None else value[positions]
        if self.chained is not None:
            follows = np.concatenate(([False], np.diff(positions) == 1))
            optional["chained"] = optional["chained"] & follows
        return Segments(*self.as_array()[positions].T, **optional)


_OPTIONAL = (("t_start", float, 1), ("t_end", float, 1), ("chained", bool, 1),
             ("sub_dphi_L", float, 2), ("sub_dphi_R", float, 2), ("sub_count", np.int64, 1))


def _segment_header(line: str, where: str) -> Header:
    """The layout a segment CSV's header gives: the five columns (and optionally the two time
    columns), any order, units allowed; DataError for a header without them."""
    header = parse_header(line, _NAMES, _QUANTITIES, where)
    present = set(header.labels)
    if not present & set(COLUMNS):
        raise DataError(f"{where}: the header names {header.found()}: neither a segment CSV "
                        f"({','.join(COLUMNS)}) nor a time-series CSV (t with phi_L,phi_R or "
                        "ticks_L,ticks_R, and x,y,theta; names and units: docs/formats.md)")
    missing = [c for c in COLUMNS if c not in present]
    if missing:
        raise DataError(f"{where}: missing column {missing[0]} (a segment CSV's columns: "
                        f"{','.join(COLUMNS)}); the header names {header.found()}")
    if len(present & set(TIME_COLUMNS)) == 1:
        raise DataError(f"{where}: the time columns {' and '.join(TIME_COLUMNS)} go together")
    return header


def check_not_utf16(name: str, start: bytes) -> None:
    """DataError when a file's first bytes ``start`` are a UTF-16 byte-order mark (text as
    Windows PowerShell writes it), which excite does not read."""
    if start[:2] in (b"\xff\xfe", b"\xfe\xff"):
        raise DataError(f"{name}: UTF-16 text (as Windows PowerShell writes it); save it as "
                        "UTF-8")


def read_text(name: str, kind: str = "CSV") -> str:
    """The file's text (UTF-8, BOM removed); DataError naming the file (a ``kind`` file) if
    it cannot be read or is not text."""
    try:
        with open(name, "rb") as handle:
            raw = handle.read()
    except FileNotFoundError:
        raise DataError(f"{name}: no such file") from None
    except IsADirectoryError:
        raise DataError(f"{name}: is a directory, not a {kind} file") from None
    except OSError as exc:
        raise DataError(f"{name}: cannot read: {exc.strerror}") from None
    check_not_utf16(name, raw[:2])
    if b"\x00" in raw:
        raise DataError(f"{name}: binary data, not a {kind} text file")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise DataError(f"{name}:{line}: not UTF-8 text") from None


def _looks_like_tuples(text: str) -> bool:
    """True when the first character outside blank and ``#`` comment lines is ``{`` (or
    ``[``: a JSON array, which the tuple reader refuses with a hint; no CSV starts so)."""
    for line in text.splitlines():
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            return stripped.startswith(("{", "["))
    return False


def _csv_rows(name: str, text: str, on_note: OnNote | None = None
              ) -> tuple[FloatArray, list[int]]:
    """Rows (n, 5) of a segment CSV in column order, or (n, 7) with the time columns the
    header names, in base units, and each row's line; on_note told the columns not read and
    the units converted. DataError naming file and line if malformed."""
    numbers, lines = content_lines(text)
    if not lines:
        return np.zeros((0, len(COLUMNS))), []
    delimiter = delimiter_of(lines[0])
    header = _header_of(name, numbers, lines)
    if header is not None:
        for note in header.notes(name) if on_note is not None else ():
            on_note(note)
        numbers, lines = numbers[1:], lines[1:]
    else:
        header = plain_header(COLUMNS, delimiter)
        width = len(header_fields(lines[0], delimiter))
        if width != len(COLUMNS):
            raise DataError(f"{name}:{numbers[0]}: {width} columns and no header: a segment "
                            f"CSV has {len(COLUMNS)} ({','.join(COLUMNS)}; a header names "
                            "any others), a time-series CSV needs its header "
                            "(t,phi_L,phi_R,x,y,theta)")
    values, _ = read_columns(name, numbers, lines, header)
    order = [header.labels.index(c) for c in COLUMNS + TIME_COLUMNS if c in header.labels]
    return values[:, order], list(numbers)


def form_problem(path: str | os.PathLike[str]) -> DataError | None:
    """What keeps ``path`` from being a segment file by its form (no such file, a folder,
    binary or empty text, a header of neither format), without reading its rows; None when
    it is one (its rows may still be bad)."""
    name = os.fspath(path)
    try:
        text, tuples = _text(name)
        if tuples:
            return None
        numbers, lines = content_lines(text)
        if not lines:
            return DataError(f"{name}: empty (no segments and no header)")
        _header_of(name, numbers, lines)
    except DataError as exc:
        return exc
    return None


def _text(name: str) -> tuple[str, bool]:
    """The file's text and whether it is a tuple file (by its name, else its content)."""
    is_tuple_name = name.lower().endswith(TUPLE_SUFFIX)
    text = read_text(name, "tuple" if is_tuple_name else "CSV")
    return text, is_tuple_name or _looks_like_tuples(text)


def _header_of(name: str, numbers: Sequence[int], lines: Sequence[str]) -> Header | None:
    """The segment header of a CSV's first content line; None when that line is numbers;
    DataError for a header of another format."""
    delimiter = delimiter_of(lines[0])
    if not is_header(header_fields(lines[0], delimiter), delimiter):
        return None
    return _segment_header(lines[0], f"{name}:{numbers[0]}")


def _segments(rows: ArrayLike) -> Segments:
    """Segments from parsed rows; with time columns, segment k is chained to k - 1 when it
    starts exactly when k - 1 ends (the files excite segment writes: one pose sample)."""
    a = np.array(rows, dtype=float)
    if a.shape[1] == len(COLUMNS):
        return Segments.from_array(a)
    t_start, t_end = a[:, 5], a[:, 6]
    chained = np.concatenate(([False], t_start[1:] == t_end[:-1]))
    return Segments(*a[:, :5].T, t_start=t_start, t_end=t_end, chained=chained)


def _show(value: object, limit: int = 40) -> str:
    """A short one-line JSON rendering of a value for an error message."""
    text = json.dumps(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _json_type(value: object) -> str:
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, bool):
        return "a boolean"
    if value is None:
        return "null"
    return "a number"


def _tuple_number(value: object, label: str, where: str) -> float:
    """A finite float from a JSON number (booleans are not numbers)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DataError(f"{where}: {label} must be a number, found {_show(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond float range
        number = math.inf
    if not math.isfinite(number):
        raise DataError(f"{where}: {label} is not finite: {_show(value)}")
    return number


def _tuple_row(obj: object, where: str) -> list[float]:
    """[dphi_L, dphi_R, dx, dy, dtheta] from one decoded tuple object."""
    if not isinstance(obj, dict):
        hint = " (a tuple file is a stream of objects, not a JSON array)" if isinstance(
            obj, list
        ) else ""
        raise DataError(f"{where}: expected a JSON object, found {_json_type(obj)}{hint}")
    for key in TUPLE_KEYS:
        if key not in obj:
            raise DataError(f'{where}: missing key "{key}"')
    duration = _tuple_number(obj["T"], '"T"', where)
    if duration <= 0.0:
        raise DataError(f'{where}: "T" must be > 0 s, found {_show(obj["T"])}')
    phi_l = _tuple_number(obj["phi_l"], '"phi_l"', where)
    phi_r = _tuple_number(obj["phi_r"], '"phi_r"', where)
    sm = obj["sm"]
    if not isinstance(sm, list) or len(sm) != 3:
        raise DataError(f'{where}: "sm" must be a list of 3 numbers, found {_show(sm)}')
    motion = [_tuple_number(v, f'"sm"[{i}]', where) for i, v in enumerate(sm)]
    dphi_L, dphi_R = phi_l * duration, phi_r * duration
    for key, value in (("phi_l", dphi_L), ("phi_r", dphi_R)):
        if not math.isfinite(value):
            raise DataError(f'{where}: "{key}" * "T" overflows')
    return [dphi_L, dphi_R, *motion]


def _tuple_rows(name: str, text: str) -> list[list[float]]:
    """Rows of a Censi tuple file; DataError naming file, object number and line if malformed.

    The objects are decoded one after the other with ``json.JSONDecoder().raw_decode``;
    whitespace and ``#`` comments between them are skipped.
    """
    decoder = json.JSONDecoder()
    rows: list[list[float]] = []
    index, line, counted = 0, 1, 0
    while True:
        index = _TUPLE_GAP.match(text, index).end()
        if index >= len(text):
            return rows
        line += text.count("\n", counted, index)
        counted = index
        where = f"{name}: object {len(rows) + 1} (line {line})"
        try:
            obj, index = decoder.raw_decode(text, index)
        except json.JSONDecodeError as exc:
            raise DataError(
                f"{where}: invalid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
            ) from None
        except RecursionError:
            raise DataError(f"{where}: invalid JSON: nested too deeply") from None
        rows.append(_tuple_row(obj, where))


def _load_rows(path: str | os.PathLike[str], on_note: OnNote | None = None
               ) -> tuple[str, ArrayLike]:
    """The file's name and its segment rows (CSV column order), in whichever format it is;
    on_note told a CSV's columns not read and units converted.

    Raises DataError for an unreadable or malformed file or one without segments, but does
    not check the minimum number of segments.
    """
    name = os.fspath(path)
    text, tuples = _text(name)
    if tuples:
        rows = _tuple_rows(name, text)
        if not rows:
            raise DataError(f"{name}: no segments (the tuple file has no JSON objects)")
        where = [f"{name}: object {k + 1}" for k in range(len(rows))]
    else:
        rows, numbers = _csv_rows(name, text, on_note)
        if not len(rows):
            raise DataError(f"{name}: no segments (the file is empty or has only a header)")
        where = [f"{name}:{line}" for line in numbers]
    a = np.asarray(rows, dtype=float)
    impossible = first_impossible(*a[:, :5].T, a[:, 6] - a[:, 5] if a.shape[1] >= 7 else None)
    if impossible is not None:
        raise DataError(f"{where[impossible[0]]}: {impossible[1]}")
    return name, rows


def _too_few(what: str, count: int, total: str = "") -> DataError:
    return DataError(
        f"{what}: {count} segment(s){total}; at least {MIN_SEGMENTS} are needed "
        "to determine r_L, r_R and b"
    )


def load_segments(path: str | os.PathLike[str], *, on_note: OnNote | None = None
                  ) -> Segments:
    """Read a segment CSV or a Censi tuple file (see the module docstring), validating all.

    The format is chosen by the name (``*.tuple``) or else by the content (a first ``{``).
    For a tuple file dx, dy, dtheta are the sensor's motion in the sensor frame (m, m, rad).
    on_note: told, one line each, a CSV's columns not read and units converted (each note
    starts with the file's name).
    Raises DataError naming the file (and line, and for a tuple file the object number) for:
    a missing or unreadable file, binary content, a header that is not a segment CSV's, a
    unit that does not fit its column, a wrong column count, text or NaN/inf in a number,
    decimal commas and points mixed, invalid JSON, a missing or bad key, T <= 0, a segment
    no robot drives (:mod:`excite.logs.segment_bounds`), fewer than 3 segments.
    """
    name, rows = _load_rows(path, on_note)
    if len(rows) < MIN_SEGMENTS:
        raise _too_few(name, len(rows))
    return _segments(rows)


def load_segment_files(paths: Sequence[str | os.PathLike[str]], *,
                       on_note: OnNote | None = None) -> Segments:
    """Read several files, each a segment CSV or a tuple file, as one data set, in order
    (on_note: as :func:`load_segments`).

    Every file must parse and hold at least one segment (DataError naming it otherwise); the
    minimum of 3 segments applies to the total. Units and frames are those of each format.
    """
    if isinstance(paths, str | bytes | os.PathLike):
        raise TypeError("load_segment_files expects a sequence of paths, not a single path")
    if not paths:
        raise DataError("no segment files given")
    names: list[str] = []
    parts: list[Segments] = []
    for path in paths:
        name, file_rows = _load_rows(path, on_note)
        names.append(name)
        parts.append(_segments(file_rows))
    total = sum(len(p) for p in parts)
    if total < MIN_SEGMENTS:
        raise _too_few(", ".join(names), total, " in total" if len(names) > 1 else "")
    return Segments.concatenate(parts)


def save_segments(path: str | os.PathLike[str], segments: Segments) -> None:
    """Write segments as CSV with a header, at full float64 precision; with the time columns
    t_start, t_end when the segments have times (sub-steps are not written: each row is the
    segment's totals)."""
    timed = segments.t_start is not None and segments.t_end is not None
    rows = segments.as_array()
    if timed:
        rows = np.column_stack([rows, segments.t_start, segments.t_end])
    np.savetxt(
        os.fspath(path),
        rows,
        delimiter=",",
        header=",".join(COLUMNS + (TIME_COLUMNS if timed else ())),
        comments="",
        fmt="%.17g",
    )
