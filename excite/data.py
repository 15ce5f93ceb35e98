"""Segment data: the lesson's CSV format, read with validation of every row.

A segment CSV has the columns ``dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt`` (radians, radians,
meters, meters, radians; the pose increment in the body frame at the segment's start, dtheta
continuous), one row per segment. The header line is optional; blank lines and lines starting
with ``#`` are ignored. Any other malformed line is an error naming the file and line.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.errors import DataError

__all__ = ["COLUMNS", "DataError", "Segments", "load_segments", "save_segments"]

COLUMNS = ("dphi_L", "dphi_R", "dx_gt", "dy_gt", "dtheta_gt")
MIN_SEGMENTS = 3
_FIELDS = ("dphi_L", "dphi_R", "dx", "dy", "dtheta")


@dataclass(frozen=True)
class Segments:
    """N motion segments as float64 arrays of shape (N,).

    dphi_L, dphi_R: encoder increments (rad). dx, dy (m), dtheta (rad): measured pose
    increment in the body frame at the segment's start, dtheta continuous (unwrapped).
    """

    dphi_L: NDArray[np.float64]
    dphi_R: NDArray[np.float64]
    dx: NDArray[np.float64]
    dy: NDArray[np.float64]
    dtheta: NDArray[np.float64]

    def __post_init__(self) -> None:
        arrays = [np.array(getattr(self, name), dtype=float).reshape(-1) for name in _FIELDS]
        if len({a.size for a in arrays}) != 1:
            raise DataError("segment arrays must all have the same length")
        for name, a in zip(_FIELDS, arrays, strict=True):
            if not np.all(np.isfinite(a)):
                raise DataError(f"{name} contains NaN or inf")
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @classmethod
    def from_array(cls, rows: ArrayLike) -> Segments:
        """Build from an (N, 5) array in CSV column order."""
        a = np.asarray(rows, dtype=float)
        if a.ndim != 2 or a.shape[1] != 5:
            raise DataError(f"expected an (N, 5) array of segments, got shape {a.shape}")
        return cls(*a.T)

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
        return Segments.from_array(self.as_array()[index].reshape(-1, 5))


def _is_header(fields: list[str]) -> bool:
    return [f.strip().lower() for f in fields] == [c.lower() for c in COLUMNS]


def _parse_line(fields: list[str], where: str) -> list[float]:
    if len(fields) != len(COLUMNS):
        raise DataError(f"{where}: expected {len(COLUMNS)} columns, found {len(fields)}")
    values = []
    for column, text in zip(COLUMNS, fields, strict=True):
        try:
            value = float(text)
        except ValueError:
            raise DataError(f"{where}: {column} is not a number: {text.strip()!r}") from None
        if not math.isfinite(value):
            raise DataError(f"{where}: {column} is not finite: {text.strip()!r}")
        values.append(value)
    return values


def load_segments(path: str | os.PathLike[str]) -> Segments:
    """Read a segment CSV, validating every row.

    Raises DataError naming the file (and line) for: a missing or unreadable file, binary
    content, a wrong column count, text or NaN/inf in a number, fewer than 3 segments.
    """
    name = os.fspath(path)
    try:
        with open(name, "rb") as handle:
            raw = handle.read()
    except FileNotFoundError:
        raise DataError(f"{name}: no such file") from None
    except IsADirectoryError:
        raise DataError(f"{name}: is a directory, not a CSV file") from None
    except OSError as exc:
        raise DataError(f"{name}: cannot read: {exc.strerror}") from None
    if b"\x00" in raw:
        raise DataError(f"{name}: binary data, not a CSV text file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise DataError(f"{name}:{line}: not UTF-8 text") from None

    rows: list[list[float]] = []
    seen_content = False
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = stripped.split(",")
        if not seen_content and _is_header(fields):
            seen_content = True
            continue
        seen_content = True
        rows.append(_parse_line(fields, f"{name}:{number}"))
    if not rows:
        raise DataError(f"{name}: no segments (the file is empty or has only a header)")
    if len(rows) < MIN_SEGMENTS:
        raise DataError(
            f"{name}: {len(rows)} segment(s); at least {MIN_SEGMENTS} are needed "
            "to determine r_L, r_R and b"
        )
    return Segments.from_array(np.array(rows))


def save_segments(path: str | os.PathLike[str], segments: Segments) -> None:
    """Write segments as CSV with a header, at full float64 precision."""
    np.savetxt(
        os.fspath(path),
        segments.as_array(),
        delimiter=",",
        header=",".join(COLUMNS),
        comments="",
        fmt="%.17g",
    )
