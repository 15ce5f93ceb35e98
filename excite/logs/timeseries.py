"""Time-series logs: read a robot's encoder and pose streams, synchronise them and cut them
into the segments the calibrator takes.

Streams, clocks and frames
--------------------------
* Encoder stream: times ``t_enc`` (s, the encoder clock) and cumulative wheel angles
  ``phi_L``, ``phi_R`` (rad, positive when the wheel drives the robot forward). Angles wrapped
  to one turn (continuous joints that some drivers report modulo 2 pi, in [-pi, pi) or
  [0, 2 pi)) are unwrapped and the segmentation report says so; an error when they are
  sampled too slowly to unwrap.
* Pose stream: times ``t_pose`` (s, the pose sensor's clock) and the sensor's pose in the
  world frame: ``x``, ``y`` (m) and ``theta`` (rad, unwrapped; a wrapped input is unwrapped).
* The clocks differ by a constant ``time_offset`` (s): pose time + time_offset = encoder time.
  :func:`estimate_time_offset` finds it from the data; :func:`noticeable_time_offset` tells
  whether it is clearly not zero.

Synchronisation (one choice, everywhere)
----------------------------------------
Segment boundaries are pose samples, and poses are never interpolated: a segment's measured
increment is the difference of two measured poses, so consecutive segments share exactly one
pose sample (``SegmentedLog.shares_endpoints``) and nothing else. The encoder angles are
interpolated at the boundary times (encoders are usually denser and far less noisy than
poses) by a monotone cubic (PCHIP): a straight line errs by up to max|phi''| h^2 / 8 for an
encoder period h (1e-4 rad at 100 Hz and 8 rad/s^2, but 6 standard errors of bias on b with
12.5 Hz encoders), the cubic by O(h^3), and it never overshoots a standstill.

Segmentation
------------
* Fixed windows (``window`` s): a boundary at the first pose sample at or after
  t_0 + k window (k = 0, 1, ...) in each stretch of the log without gaps, so a segment lasts
  the window to within one pose period.
* Keyframes by motion (``min_distance`` m and/or ``min_angle`` rad): a new boundary at the first
  pose sample where the sensor is at least ``min_distance`` from the last keyframe's position,
  or its heading differs from the keyframe's by at least ``min_angle``.

A segment holds dphi_L, dphi_R (encoder increments, rad) and the sensor's pose increment in its
own frame at the segment start: (dx, dy) = R(-theta_start) (p_end - p_start) (m),
dtheta = theta_end - theta_start (rad, continuous).

Detection, never silent averaging (all of it in :class:`SegmentationReport`)
-----------------------------------------------------------------------------
* Gaps: a stream without a sample for longer than the window, or than ``Limits.max_gap``
  (default 3x the stream's median period). With ``on_gap="error"`` (the default) a gap longer
  than the window is an error naming the file and line (or time) where the stream resumes;
  otherwise every gap splits the log and no segment spans it.
* Dropouts: missed samples (an interval over 1.5 median periods but not a gap); bridged and
  counted.
* Jumps: consecutive pose samples implying a speed over ``Limits.max_speed`` (m/s) or a turn
  rate over ``Limits.max_turn_rate`` (rad/s), or consecutive encoder samples implying a wheel
  rate over ``Limits.max_wheel_rate`` (rad/s, e.g. a counter reset); segments containing one
  are dropped.
* Segments in which neither wheel turned more than ``Limits.still_wheel`` are, by how far the
  sensor moved and turned, one of three (see :class:`Limits`):
  - standstills: the sensor stayed within the still limits (``Limits.still_distance``,
    ``Limits.still_heading``) or within the pose noise (``Limits.carry_sigmas``; the noise is
    estimated from the pose stream itself); dropped (they carry noise, no information about
    r_L, r_R, b);
  - carried: the sensor moved or turned beyond both, and beyond what the wheels' small turns
    could have made any plausible robot do: it was carried or pushed, or the pose source
    relocalised; dropped;
  - otherwise a slow motion (a big-wheeled robot spinning slowly), kept.
"""

from __future__ import annotations

import math
import operator
import os
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from itertools import repeat
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.calibration.noise import MEDIAN_ABS_NORMAL
from excite.calibration.wiring import MAX_RADIUS_TO_TRACK
from excite.errors import DataError
from excite.logs.segments import MIN_SEGMENTS, Segments, read_text

__all__ = [
    "Gap",
    "Limits",
    "OffsetHint",
    "OffsetOutOfRange",
    "SegmentationReport",
    "SegmentedLog",
    "TimeSeries",
    "check_continuity",
    "estimate_time_offset",
    "noticeable_time_offset",
    "is_timeseries_csv",
    "tick_angle",
    "unwrapped_words",
    "timeseries_streams",
    "read_timeseries",
    "sample_at",
    "write_timeseries",
    "segment_timeseries",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
PathArg = str | os.PathLike[str]
Stream = Literal["encoder", "pose"]

#: Fewest samples a stream may have.
MIN_SAMPLES = 2
ANGLE_COLUMNS = ("phi_L", "phi_R")
TICK_COLUMNS = ("ticks_L", "ticks_R")
POSE_COLUMNS = ("x", "y", "theta")
_CANONICAL = {c.lower(): c for c in ("t", *ANGLE_COLUMNS, *TICK_COLUMNS, *POSE_COLUMNS)}
_EXPECTED = "t,phi_L,phi_R,x,y,theta in one file, or t,phi_L,phi_R and t,x,y,theta in two"
_SPACE_AROUND_COMMA = re.compile(r"[ \t]*,[ \t]*")

# Drop reasons (SegmentationReport keys).
POSE_JUMP, ENCODER_JUMP, STANDSTILL = "pose jump", "encoder jump", "standstill"
CARRIED = "pose moved while the wheels stood still"
CUT_BY_GAP, END_OF_LOG = "cut by a gap", "end of log"
OUTSIDE_ENCODERS, INSIDE_ENCODER_GAP = "outside the encoder time range", "inside an encoder gap"
#: A stream interval over this many median periods has missed samples (a dropout).
DROPOUT_RATIO = 1.5
#: Default max_gap, in median periods of the stream.
GAP_RATIO = 3.0
#: The most sub-steps per segment (_substeps); sub-steps are one encoder period long up to this.
#: One arc per encoder period is dead reckoning at the encoder rate: coarser sub-steps (50 ms)
#: left a systematic model error of ~1e-5 m per 1 s segment on curving paths, which biased the
#: wheel radii by 1.7 standard deviations at 0.5 mm pose noise (benchmarks/bench_logs.py).
MAX_SUBSTEPS = 256
#: s, the longest sub-step: slower encoders get several sub-steps per period, through the cubic
#: interpolant (:func:`_wheel_angles`). One arc per 40 ms period biased b by 0.65 standard
#: errors, per 80 ms by 2.6 (even with the cubic boundaries; 6 with straight lines); 20 ms
#: sub-steps leave no bias at 12.5 Hz (synthetic logs, 100 Hz poses of 1 mm / 2 mrad).
MAX_SUBSTEP = 0.02


# --------------------------------------------------------------------------- the streams


def sample_at(source: str, t: float) -> str:
    """A sample's place when its line is unknown: 'source at t = ... s' (t in s, to the us);
    errors about time-series samples and bag messages name them so."""
    return f"{source} at t = {float(t):.6f} s"


def _where(source: str, lines: IntArray | None, t: ArrayLike, index: int) -> str:
    """'file:line' of a sample, or 'source at t = ... s' when lines are unknown."""
    if lines is not None:
        return f"{source}:{lines[index]}"
    return sample_at(source, np.asarray(t)[index])


def _checked_stream(kind: Stream, source: str, lines: IntArray | None,
                    columns: dict[str, ArrayLike]) -> list[FloatArray]:
    """Validate one stream (first column the time): equal lengths, enough samples, finite
    values, strictly increasing time. Errors name the file and line (or time)."""
    arrays = []
    for name, values in columns.items():
        try:
            arrays.append(np.array(values, dtype=float).reshape(-1))
        except (TypeError, ValueError):
            raise DataError(f"{source}: {name} is not an array of numbers") from None
    sizes = {a.size for a in arrays} | ({lines.size} if lines is not None else set())
    if len(sizes) != 1:
        raise DataError(f"{source}: the {kind} columns have different lengths {sorted(sizes)}")
    t = arrays[0]
    if t.size < MIN_SAMPLES:
        raise DataError(f"{source}: {t.size} {kind} sample(s); at least {MIN_SAMPLES} are needed")
    finite = np.isfinite(np.vstack(arrays))
    if not finite.all():
        index, column = (int(v[0]) for v in np.nonzero(~finite.T))
        name = list(columns)[column]
        raise DataError(f"{_where(source, lines, t, index)}: {name} is not finite "
                        f"({arrays[column][index]})")
    steps = np.flatnonzero(np.diff(t) <= 0)
    if steps.size:
        i = int(steps[0]) + 1
        raise DataError(f"{_where(source, lines, t, i)}: time does not increase "
                        f"({float(t[i])!r} s after {float(t[i - 1])!r} s)")
    return arrays


#: Wheel angles whose range (max - min) exceeds one turn, 2 pi, by at most this (rad) may be
#: wrapped: continuous joints that some drivers report modulo 2 pi, whether in [-pi, pi) or in
#: [0, 2 pi).
WRAP_TOLERANCE = 1e-3
#: The largest wheel step between encoder samples (rad) that unwrapping trusts. np.unwrap takes
#: the step within +-pi, right while the wheel turns less than pi per sample; a wheel that sped
#: up past pi per sample would pass through steps between pi/2 and pi first (unless its step
#: changed by over pi/2 from one sample to the next), so a step over pi/2 means the stream is
#: sampled too slowly to unwrap reliably.
MAX_UNWRAPPED_STEP = 0.5 * math.pi


def _unwrapped_wheel(source: str, lines: IntArray | None, t: FloatArray, name: str,
                     phi: FloatArray) -> FloatArray | None:
    """The wheel angles unwrapped when they are wrapped (all within one turn, a range of at
    most 2 pi + WRAP_TOLERANCE, and some step between samples over pi); None when they are not
    wrapped.
    DataError naming the sample when a step after unwrapping exceeds MAX_UNWRAPPED_STEP."""
    steps = np.abs(np.diff(phi))
    if np.ptp(phi) > 2.0 * math.pi + WRAP_TOLERANCE or not (steps > math.pi).any():
        return None
    unwrapped = np.unwrap(phi)
    fast = np.abs(np.diff(unwrapped))
    i = int(np.argmax(fast))
    if fast[i] > MAX_UNWRAPPED_STEP:
        raise DataError(f"{_where(source, lines, t, i + 1)}: the wheel angles {name} are "
                        f"wrapped modulo 2 pi and sampled too slowly to unwrap (a step of "
                        f"{fast[i]:.2f} rad after unwrapping, over pi/2): record them "
                        "unwrapped or more often")
    return unwrapped


def unwrapped_words(wheels: tuple[str, ...], counters: tuple[str, ...]) -> str:
    """The wheel columns unwrapped (TimeSeries.unwrapped_wheels, .unwrapped_counters) in
    words, e.g. 'phi_L wrapped modulo 2 pi, unwrapped'; '' when there are none."""
    parts = []
    if wheels:
        parts.append(f"{', '.join(wheels)} wrapped modulo 2 pi, unwrapped")
    if counters:
        parts.append(f"{', '.join(counters)} overflowed, unwrapped")
    return "; ".join(parts)


@dataclass(frozen=True, eq=False)
class TimeSeries:
    """The encoder and pose streams of one recording, validated.

    t_enc: encoder times (s, encoder clock); phi_L, phi_R: cumulative wheel angles (rad).
    t_pose: pose times (s, pose clock); x, y (m), theta (rad): the external sensor's pose in
    the world frame; theta is unwrapped here. Each stream's time strictly increases and has at
    least 2 samples; every value is finite.
    source: (encoder source, pose source) for messages: file names, or bag and topic.
    lines: (encoder lines, pose lines): each sample's line in its file, or None (messages then
    name the sample's time).
    unwrapped_wheels: the wheel columns (of "phi_L", "phi_R") that were wrapped to one turn
    (continuous joints reported modulo 2 pi) and are unwrapped here; DataError when such a
    stream is sampled too slowly to unwrap (see MAX_UNWRAPPED_STEP). unwrapped_counters: the
    tick columns whose fixed-width counter overflowed and was unwrapped when they were read
    (e.g. 'ticks_L (16-bit counter)', :func:`read_timeseries`), for the reports.
    """

    t_enc: FloatArray
    phi_L: FloatArray
    phi_R: FloatArray
    t_pose: FloatArray
    x: FloatArray
    y: FloatArray
    theta: FloatArray
    source: tuple[str, str] = ("encoders", "poses")
    lines: tuple[IntArray | None, IntArray | None] = (None, None)
    unwrapped_counters: tuple[str, ...] = ()
    unwrapped_wheels: tuple[str, ...] = field(default=(), init=False)

    def __post_init__(self) -> None:
        lines = tuple(None if a is None else np.asarray(a, dtype=np.int64).reshape(-1)
                      for a in self.lines)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "source", tuple(str(s) for s in self.source))
        encoder = _checked_stream("encoder", self.source[0], lines[0], {
            "t": self.t_enc, "phi_L": self.phi_L, "phi_R": self.phi_R})
        pose = _checked_stream("pose", self.source[1], lines[1], {
            "t": self.t_pose, "x": self.x, "y": self.y, "theta": self.theta})
        pose[3] = np.unwrap(pose[3])
        unwrapped = []
        for k, name in enumerate(ANGLE_COLUMNS, start=1):
            wheel = _unwrapped_wheel(self.source[0], lines[0], encoder[0], name, encoder[k])
            if wheel is not None:
                encoder[k] = wheel
                unwrapped.append(name)
        object.__setattr__(self, "unwrapped_wheels", tuple(unwrapped))
        names = ("t_enc", "phi_L", "phi_R", "t_pose", "x", "y", "theta")
        for name, array in zip(names, encoder + pose, strict=True):
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    def location(self, stream: Stream, index: int) -> str:
        """Where sample ``index`` of a stream came from: 'file:line', or source and time."""
        k = 0 if stream == "encoder" else 1
        return _where(self.source[k], self.lines[k], (self.t_enc, self.t_pose)[k], index)


# --------------------------------------------------------------------------- CSV reading


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


def tick_angle(ticks_per_rev: float) -> float:
    """The angle of one encoder tick, 2 pi / ticks_per_rev (rad); DataError unless
    ticks_per_rev is positive and finite."""
    if not 0 < ticks_per_rev < math.inf:
        raise DataError(f"ticks_per_rev must be positive and finite, got {ticks_per_rev}")
    return 2.0 * math.pi / ticks_per_rev


#: Widths (bits) of the encoder counters whose overflows are undone (_unwrapped_counter).
COUNTER_BITS = (16, 32)


def _counter_width(ticks: FloatArray) -> int | None:
    """The width (bits, of COUNTER_BITS) of a fixed-width counter that may have wrapped in
    ``ticks``: whole numbers within an unsigned or a signed range of that width, with a step
    between samples over half of it; None otherwise."""
    if ticks.size < 3 or not np.all(ticks == np.round(ticks)):
        return None
    low, high = float(ticks.min()), float(ticks.max())
    step = float(np.abs(np.diff(ticks)).max())
    for bits in COUNTER_BITS:
        span = 2.0**bits
        fits = (low >= 0 and high < span) or (-span / 2 <= low and high < span / 2)
        if fits and step > span / 2:
            return bits
    return None


#: An overflow is undone only where the step it leaves is at most this many times the larger
#: of its neighbouring steps (plus OVERFLOW_SLACK ticks): a wheel turning on as before. A
#: counter reset (a reboot: 65300 -> 0) leaves a step unlike its neighbours and stays a jump.
OVERFLOW_STEP_RATIO = 2.0
OVERFLOW_SLACK = 2.0


def _unwrapped_counter(ticks: FloatArray) -> tuple[FloatArray, int | None]:
    """Encoder ticks with a fixed-width counter's overflows undone, as a cumulative count, and
    the counter's width (None: no overflow undone, ticks unchanged). A step over half the
    counter's range (:func:`_counter_width`) is an overflow when, taken modulo the range, it
    continues the neighbouring steps (OVERFLOW_STEP_RATIO); other big steps are left alone
    (jumps, which segmentation drops and validation refuses)."""
    bits = _counter_width(ticks)
    if bits is None:
        return ticks, None
    span = 2.0**bits
    steps = np.diff(ticks)
    big = np.abs(steps) > span / 2
    wrapped = steps - span * np.round(steps / span)
    small = np.where(big, 0.0, np.abs(steps))
    neighbours = np.maximum(np.concatenate(([0.0], small[:-1])),
                            np.concatenate((small[1:], [0.0])))
    overflow = big & (np.abs(wrapped) <= OVERFLOW_STEP_RATIO * neighbours + OVERFLOW_SLACK)
    if not overflow.any():
        return ticks, None
    fixed = np.where(overflow, wrapped, steps)
    return ticks[0] + np.concatenate(([0.0], np.cumsum(fixed))), bits


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
        (left, left_bits), (right, right_bits) = map(_unwrapped_counter, (left, right))
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


# --------------------------------------------------------------------------- time offset


def _rate_signals(ts: TimeSeries, step: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Heading rate of the poses and the two wheel rates (rad/s), on one grid of spacing
    ``step`` (s) over the time both streams cover, each stream on its own clock."""
    start, stop = max(ts.t_enc[0], ts.t_pose[0]), min(ts.t_enc[-1], ts.t_pose[-1])
    grid = start + step * np.arange(int((stop - start) / step) + 1)
    rates = [np.gradient(np.interp(grid, t, angle), step)
             for t, angle in ((ts.t_pose, ts.theta), (ts.t_enc, ts.phi_L), (ts.t_enc, ts.phi_R))]
    return rates[0], rates[1], rates[2]


def _sliding_dot(a: FloatArray, b: FloatArray) -> FloatArray:
    """s[j] = sum_k a[k] b[j + k] for every full placement j = 0..len(b) - len(a) (by FFT)."""
    length = 1 << int(math.ceil(math.log2(a.size + b.size)))
    full = np.fft.irfft(np.conj(np.fft.rfft(a, length)) * np.fft.rfft(b, length), length)
    return full[: b.size - a.size + 1]


def _sliding_sum(x: FloatArray, width: int) -> FloatArray:
    """Sums of x over every window of ``width`` consecutive samples."""
    total = np.concatenate(([0.0], np.cumsum(x)))
    return total[width:] - total[:-width]


def _explained(turn: FloatArray, left: FloatArray, right: FloatArray, max_lag: int) -> FloatArray:
    """For each lag m = -max_lag..max_lag, the fraction R^2 of the heading rate's variance
    (over the central samples max_lag..n - max_lag) that a linear fit
    a phi_L'(t + m) + c phi_R'(t + m) (plus a constant) explains."""
    width = turn.size - 2 * max_lag
    y = turn[max_lag: max_lag + width] - turn[max_lag: max_lag + width].mean()
    energy = float(y @ y)
    if not energy > 1e-24 * width * max(1.0, float(np.abs(turn).max())) ** 2:
        raise DataError("cannot estimate the time offset: the heading does not vary "
                        "(the robot must turn at changing rates)")
    wheels = [w - w.mean() for w in (left, right)]
    cross = [_sliding_dot(y, w) for w in wheels]
    sums = [_sliding_sum(w, width) for w in wheels]
    gram = [[_sliding_sum(u * v, width) - su * sv / width for v, sv in zip(wheels, sums,
                                                                           strict=True)]
            for u, su in zip(wheels, sums, strict=True)]
    ridge = 1e-9 * (gram[0][0] + gram[1][1])
    if not np.all(ridge > 1e-30):
        raise DataError("cannot estimate the time offset: the wheel speeds do not vary")
    g00, g11, g01 = gram[0][0] + ridge, gram[1][1] + ridge, gram[0][1]
    c0, c1 = cross
    return (c0 * c0 * g11 - 2.0 * c0 * c1 * g01 + c1 * c1 * g00) / (g00 * g11 - g01**2) / energy


#: A lag outside the search range fits clearly better than every lag inside it when it leaves
#: at most this fraction of the heading rate's variance that the best lag inside leaves
#: unexplained. Robot motions often repeat (a protocol's period of a few seconds), so lags a
#: period apart fit almost equally well (within a few percent in the unexplained variance);
#: halving it is not chance: with ~100 independent samples of the turn rate (a minute of
#: turning that changes every ~0.5 s) a variance ratio of 2 is beyond F(100, 100)'s 99.9 %
#: quantile (1.87); on shorter or smoother logs the test is looser.
CLEARLY_BETTER = 0.5


class OffsetOutOfRange(DataError):
    """The clock offset is not within estimate_time_offset's search range. candidates: the lags
    (s) outside it that fit far better, nearest zero first (several when the motion repeats);
    empty when the best fit is merely at the edge of the range."""

    def __init__(self, message: str, candidates: Sequence[float] = ()) -> None:
        super().__init__(message)
        self.candidates = tuple(candidates)


def _refuse_better_fit_outside(signals: tuple[FloatArray, FloatArray, FloatArray], step: float,
                               max_lag: int, max_offset: float, overlap: float) -> None:
    """DataError when a lag beyond +-max_lag fits clearly better (CLEARLY_BETTER) than every
    lag within it: the offset is then outside the search range, and the best lag inside only a
    lesser local optimum. Lags are scanned as far as the comparison keeps half the overlap
    (+-overlap / 4)."""
    wide_lag = int(overlap / 4.0 / step)
    if wide_lag <= max_lag:
        return
    unexplained = 1.0 - _explained(*signals, wide_lag)
    outside = np.ones(unexplained.size, dtype=bool)
    outside[wide_lag - max_lag: wide_lag + max_lag + 1] = False
    best_inside, best_outside = unexplained[~outside].min(), unexplained[outside].min()
    if not best_outside < CLEARLY_BETTER * best_inside:
        return
    # where to look: the runs of lags outside not clearly worse than the best there, nearest
    # zero first; several when the motion repeats (lags a period apart fit about as well)
    near = outside & (CLEARLY_BETTER * unexplained <= best_outside)
    runs = np.flatnonzero(np.diff(np.concatenate(([0], near.astype(np.int8), [0])))).reshape(-1, 2)
    lags = sorted(((int(a) + int(np.argmin(unexplained[a:b])) - wide_lag) * step
                   for a, b in runs), key=abs)
    where = " or ".join(f"{lag:+.2f} s" for lag in lags[:3])
    repeats = "; the motion repeats, so each fits about as well" if len(lags) > 1 else ""
    raise OffsetOutOfRange(f"cannot estimate the time offset: it is not within +-{max_offset} "
                           f"s (the streams agree far better near {where}{repeats}; widen the "
                           "search range: --max-time-offset)", lags)


def _refined_lag(r2: FloatArray, max_lag: int, step: float) -> float:
    """The lag (s) of the largest R^2 (index k of lags -max_lag..max_lag, spacing ``step``),
    refined by a parabola through the three values around it; NaN at the edge."""
    k = int(np.argmax(r2))
    if k in (0, r2.size - 1):
        return math.nan
    curvature = r2[k - 1] - 2.0 * r2[k] + r2[k + 1]
    shift = 0.5 * (r2[k - 1] - r2[k + 1]) / curvature if curvature < 0 else 0.0
    return (k - max_lag + shift) * step


#: The offset is estimated on a uniform grid of the finer median sample period over the time
#: both streams cover; a grid of more points than this many per sample means long gaps (a
#: clock that jumps, a pause between sessions), over which the rates cannot be compared, and
#: is refused (a one-year clock jump at 100 Hz asked for 1.3 TiB; a 20 h one for 1 GB).
MAX_GRID_PER_SAMPLE = 4
#: The default search range of estimate_time_offset: +- this (s).
MAX_TIME_OFFSET = 1.0
#: The default least correlation of estimate_time_offset's best fit.
MIN_CORRELATION = 0.5


def estimate_time_offset(ts: TimeSeries, max_offset: float = MAX_TIME_OFFSET,
                         min_correlation: float = MIN_CORRELATION) -> float:
    """The clock offset (s) with pose time + offset = encoder time.

    The heading rate of the poses is a fixed linear combination of the wheel rates,
    theta' = (r_R phi_R' - r_L phi_L') / b, so the offset is the lag at which the wheel rates
    explain the heading rate best: the largest R^2 of a linear fit of theta' on the shifted
    phi_L', phi_R' (the normalised cross-correlation of theta' with phi_R' - phi_L' when
    r_L = r_R, without that one's bias from the forward speed when r_L != r_R). The rates are
    computed on one grid (spacing h: the smaller median sample period) over the time both
    streams cover; the heading rate's central part (all but max_offset at each end) is
    compared with the wheel rates at every lag within +-max_offset (s), each lag's fit
    normalised over its own samples (no edge bias); the best lag is refined by a parabola
    through the three grid values around it.

    Precision: on smooth motion (turn rates changing over ~1 s) the parabolic refinement's
    bias is below 1e-3 h (noise-free simulated logs: errors ~1e-4 h), and noise averages down
    over the log: from a noisy 2-minute log (100 Hz encoders, 50 Hz poses with 2 mm / 2 mrad
    noise) the error is at most 0.015 h over five noise draws; the tests require 0.05 h.

    An offset outside the search range shows as a best lag at its edge or, as often (the fit
    has local optima), as a lesser optimum inside it: so lags up to +-overlap/4 are scanned as
    well, and a lag there that fits clearly better (CLEARLY_BETTER) than every lag inside
    makes it an error.

    Raises DataError when max_offset is not positive and finite, when the heading or the wheel
    speeds do not vary, when the streams overlap for less than 4 max_offset, when the best
    fit's correlation sqrt(R^2) is below ``min_correlation`` (no clear agreement), when the
    best lag is at the edge of the search range, or when a lag outside it fits clearly better.
    """
    return _estimate(ts, max_offset, min_correlation).offset


@dataclass(frozen=True)
class _OffsetFit:
    """An estimated offset (s) and what it came from: the rate signals on their grid of
    spacing ``step`` (s) and the search range in grid steps."""

    offset: float
    signals: tuple[FloatArray, FloatArray, FloatArray]
    step: float
    max_lag: int


def _estimate(ts: TimeSeries, max_offset: float, min_correlation: float) -> _OffsetFit:
    """estimate_time_offset, keeping the signals it fitted."""
    if not 0 < max_offset < math.inf:
        raise DataError(f"max_offset must be positive and finite (s), got {max_offset}")
    step = float(min(np.median(np.diff(ts.t_enc)), np.median(np.diff(ts.t_pose))))
    overlap = min(ts.t_enc[-1], ts.t_pose[-1]) - max(ts.t_enc[0], ts.t_pose[0])
    if not overlap > 4 * max_offset:
        raise DataError(f"cannot estimate the time offset: the streams overlap for "
                        f"{max(overlap, 0.0):.3g} s, less than 4 x max_offset ({max_offset} s)")
    samples = ts.t_enc.size + ts.t_pose.size
    if overlap / step > MAX_GRID_PER_SAMPLE * samples:
        raise DataError(f"cannot estimate the time offset: the streams' {samples} samples "
                        f"span {overlap:.6g} s, {overlap / step:.3g} sample periods "
                        f"({step:.3g} s): long gaps (or a clock that jumps); give "
                        "--time-offset, or estimate it on each part of the log")
    max_lag = max(1, int(math.ceil(max_offset / step)))
    signals = _rate_signals(ts, step)
    r2 = _explained(*signals, max_lag)
    _refuse_better_fit_outside(signals, step, max_lag, max_offset, overlap)
    k = int(np.argmax(r2))
    correlation = math.sqrt(max(float(r2[k]), 0.0))
    if correlation < min_correlation:
        raise DataError(f"cannot estimate the time offset: heading rate and wheel speeds "
                        f"agree poorly (correlation {correlation:.2f} < {min_correlation})")
    offset = _refined_lag(r2, max_lag, step)
    if math.isnan(offset):
        raise OffsetOutOfRange(f"cannot estimate the time offset: it is not within "
                               f"+-{max_offset} s (the best fit is at the edge of the search "
                               "range: --max-time-offset)")
    return _OffsetFit(offset, signals, step, max_lag)


#: s, the blocks of the heading rate whose sums make the batch-means standard error of the lag
#: zero score (_lag_zero_score): four times the time over which the turn rate changes
#: (~0.5 s), so consecutive block sums are nearly independent.
OFFSET_TEST_BLOCK = 2.0
#: The fewest blocks the test needs (a t quantile of fewer degrees of freedom is too wide).
MIN_OFFSET_TEST_BLOCKS = 8
#: s, the moving average over which the lag direction (the fitted heading rate's derivative) is
#: smoothed: it needs only the motion's time scale, and differentiating the wheel rates again
#: amplifies the encoder noise (with 4096-tick encoders at 200 Hz it hid a 150 ms offset).
LAG_DIRECTION_SMOOTHING = 0.1
#: Two-sided level of the test that lag zero fits as well as a small shift (noticeable_time_offset).
NOTICEABLE_OFFSET_LEVEL = 1e-3
#: An offset the test finds is noted only beyond this fraction of the coarser stream's median
#: sample period: comparing rates of a coarse stream interpolated on a fine grid leaves a lag
#: of its own (up to 0.08 of a period on logs recorded without an offset: -7.3 ms with 10 Hz
#: encoders under 100 Hz poses, which the test, being about noise, calls significant; a 30 ms
#: offset there is estimated at ~15 ms, so the floor stays near that bias).
NOTICEABLE_OFFSET_PERIODS = 0.1


def _lag_zero_score(fit: _OffsetFit) -> tuple[float, int]:
    """A score test that the clock offset is zero: (t statistic, number of blocks).

    At lag zero the heading rate is fitted by the wheel rates (a phi_L' + c phi_R' + const,
    least squares over the compared central samples); a small lag d changes that fit by
    d f'(t) (f the fitted heading rate), so the residual's correlation with f' (smoothed over
    LAG_DIRECTION_SMOOTHING and made orthogonal to the regressors) is the slope of the
    unexplained variance in the lag. It is zero on average when the offset is zero. Its sum
    over blocks of OFFSET_TEST_BLOCK s, mean over the blocks' standard error, is t-distributed
    with blocks - 1 degrees of freedom (batch means: honest for noise correlated over less than
    a block). (0, 0) when there are fewer than MIN_OFFSET_TEST_BLOCKS blocks or a block would
    hold fewer than two samples.
    """
    lag, step = fit.max_lag, fit.step
    turn, left, right = (signal[lag: signal.size - lag] for signal in fit.signals)
    blocks = int(turn.size * step / OFFSET_TEST_BLOCK)
    if blocks < MIN_OFFSET_TEST_BLOCKS or 2 * step > OFFSET_TEST_BLOCK:
        return 0.0, 0  # too short a log, or a block would not hold two samples
    regressors = np.column_stack([left, right, np.ones(turn.size)])
    coefficients = np.linalg.lstsq(regressors, turn, rcond=None)[0]
    residual = turn - regressors @ coefficients
    width = max(1, round(LAG_DIRECTION_SMOOTHING / step))
    direction = np.convolve(np.gradient(regressors[:, :2] @ coefficients[:2], step),
                            np.full(width, 1.0 / width), "same")
    direction -= regressors @ np.linalg.lstsq(regressors, direction, rcond=None)[0]
    size = turn.size // blocks
    sums = (residual * direction)[: size * blocks].reshape(blocks, size).sum(axis=1)
    spread = float(np.std(sums, ddof=1))
    if not spread > 0:
        return 0.0, blocks
    return float(np.mean(sums)) / spread * math.sqrt(blocks), blocks


@dataclass(frozen=True)
class OffsetHint:
    """A clock offset the data suggest although none was given (s; pose time + offset =
    encoder time): ``offset``, the estimate, clearly not zero and within the search range
    +-``max_offset``; or, when the offset lies beyond that range, ``offset`` None and
    ``beyond`` the lags there that fit far better, nearest zero first (empty when the best
    fit is merely at the range's edge)."""

    offset: float | None
    max_offset: float
    beyond: tuple[float, ...] = ()

    def text(self) -> str:
        """The hint in words, e.g. 'the data suggest -0.1502 s: --time-offset estimate'."""
        if self.offset is not None:
            return f"the data suggest {self.offset:+.4f} s: --time-offset estimate"
        near = f" (near {' or '.join(f'{lag:+.2f} s' for lag in self.beyond[:3])})"
        return (f"the data suggest an offset beyond +-{self.max_offset:g} s"
                f"{near if self.beyond else ''}: --time-offset estimate --max-time-offset S")


def noticeable_time_offset(ts: TimeSeries, max_offset: float = MAX_TIME_OFFSET
                           ) -> OffsetHint | None:
    """What the data say about the clock offset when none was given: a hint when the data
    reject a zero offset (:func:`_lag_zero_score` beyond the two-sided NOTICEABLE_OFFSET_LEVEL
    quantile of Student's t) or the estimate lies beyond +-max_offset s; None when zero fits
    about as well, the estimate is within NOTICEABLE_OFFSET_PERIODS of the coarser stream's
    period, the log is too short for the test (under 8 blocks of 2 s), or the offset cannot be
    estimated (too little turning, too short an overlap: see :func:`estimate_time_offset`).

    On one-minute simulated logs (12 random paths each; 4096-tick encoders and poses at 10 to
    200 Hz, 2 mm / 4 mrad pose noise) no zero offset was noted (largest |t| 2.5, the quantile
    is 3.7); 5 ms offsets were noted in 0-12 of 12 (by rates), 10 ms in 5-12, 20 ms and more in
    all. The old rule (3 batch-means standard errors of the estimate, or a quarter period)
    noted zero offsets in up to 1 of 12; an F test of the unexplained variance (lag zero
    against the best lag) missed 150 ms at 200 Hz, where the heading rate is mostly noise.
    """
    from scipy.special import stdtrit

    try:
        fit = _estimate(ts, max_offset, MIN_CORRELATION)
    except OffsetOutOfRange as exc:
        return OffsetHint(None, max_offset, exc.candidates)
    except DataError:
        return None
    score, blocks = _lag_zero_score(fit)
    if blocks == 0 or abs(score) <= stdtrit(blocks - 1, 1.0 - 0.5 * NOTICEABLE_OFFSET_LEVEL):
        return None
    coarser = max(float(np.median(np.diff(ts.t_enc))), float(np.median(np.diff(ts.t_pose))))
    if abs(fit.offset) <= NOTICEABLE_OFFSET_PERIODS * coarser:
        return None  # within the interpolation's own lag (module constant)
    return OffsetHint(fit.offset, max_offset)


# --------------------------------------------------------------------------- segmentation


@dataclass(frozen=True)
class Limits:
    """Thresholds of the detection in :func:`segment_timeseries`.

    max_gap (s): a stream interval longer than this (or than the window) is a gap; None means
        3x the stream's median sample period.
    max_speed (m/s), max_turn_rate (rad/s): sensor speed and turn rate between consecutive pose
        samples above which the step is a jump. Sized for ground robots below ~3.5 m/s and
        3 revolutions per second (the presets reach 2 m/s and, spinning at full speed, up to
        10.7 rad/s). The pose noise adds to the apparent motion (1 cm at 100 Hz reads as
        ~1.4 m/s), so a step is a jump only beyond these limits plus ``jump_sigmas`` times the
        noise of a difference of two poses (estimated from the pose stream, as for
        carry_sigmas).
    jump_sigmas: at 6, noise alone passes the jump limit once in ~10^8 samples (the Rayleigh
        tail exp(-6^2 / 2) for the position, twice the normal tail for the heading). At low
        pose rates (about 1 Hz) the robust noise estimate also counts the curvature of the
        motion between samples (0.13 m, 0.15 rad turning at 1 m/s and 1 rad/s), which widens
        the limit by about 1 m there.
    max_wheel_rate (rad/s): wheel rate between consecutive encoder samples above which the
        step is a jump (a counter reset or overflow).
    still_wheel (rad), still_distance (m), still_heading (rad): a segment is a standstill when
        both wheels turned at most still_wheel and the sensor moved at most still_distance and
        turned at most still_heading.
    carry_sigmas: a segment in which both wheels turned at most still_wheel is a standstill
        too when the sensor moved at most carry_sigmas standard deviations of the noise of a
        difference of two poses and turned likewise: at 5, a still robot's noise passes it in
        about 4 of a million segments (the Rayleigh tail exp(-5^2 / 2)). The pose noise is
        estimated from the pose stream (:func:`_pose_noise`).
    max_radius_to_track, max_wheel_radius (m), max_sensor_arm (m): the most the wheels' small
        turns dphi_L, dphi_R (within still_wheel) can move a plausible robot's sensor: a turn of
        max_radius_to_track (|dphi_L| + |dphi_R|) (rad; r / b is 0.3 on a Husky, under 1 on any
        differential drive whose wheels are smaller than its track) and a displacement of
        max_wheel_radius max |dphi| plus max_sensor_arm times that turn (the sensor's lever
        arm). A segment with wheels this still whose sensor moved beyond that plus the
        standstill limit above, or turned likewise, was carried. Floors of a few times the
        still limits would do as well for the presets; this bound instead keeps full
        sensitivity where the wheels stood exactly still.
    """

    max_gap: float | None = None
    max_speed: float = 5.0
    max_turn_rate: float = 6.0 * math.pi
    jump_sigmas: float = 6.0
    max_wheel_rate: float = 200.0
    still_wheel: float = 0.02
    still_distance: float = 0.01
    still_heading: float = 0.01
    carry_sigmas: float = 5.0
    max_radius_to_track: float = MAX_RADIUS_TO_TRACK
    max_wheel_radius: float = 0.5
    max_sensor_arm: float = 1.0


@dataclass(frozen=True)
class Gap:
    """An interruption of one stream: no sample between t_start and t_end (s, that stream's
    own clock); location: file:line (or source and time) of the sample that resumes it."""

    stream: Stream
    t_start: float
    t_end: float
    location: str

    @property
    def duration(self) -> float:
        return self.t_end - self.t_start


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def _ranges_text(ranges: Sequence[tuple[float, float]], shown: int = 3) -> str:
    text = ", ".join(f"{a:.3f}-{b:.3f} s" for a, b in ranges[:shown])
    return text + (f" and {len(ranges) - shown} more" if len(ranges) > shown else "")


@dataclass(frozen=True)
class SegmentationReport:
    """What segmentation kept and dropped, and why.

    n_segments: segments kept. segments_dropped: count per reason (pose jump, encoder jump,
    standstill, cut by a gap, end of log: the unfinished window or keyframe at the end of a
    stretch). dropped_ranges: the time ranges of those segments per reason (s, encoder clock,
    adjacent ones merged). samples_dropped: pose samples unused, per reason (outside the
    encoder time range, inside an encoder gap). gaps: every gap, in time order. dropouts:
    missed samples per stream, bridged. unwrapped_wheels: the wheel columns that were wrapped
    modulo 2 pi and were unwrapped (TimeSeries.unwrapped_wheels).
    """

    n_segments: int
    segments_dropped: dict[str, int] = field(default_factory=dict)
    dropped_ranges: dict[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)
    samples_dropped: dict[str, int] = field(default_factory=dict)
    gaps: tuple[Gap, ...] = ()
    dropouts: dict[str, int] = field(default_factory=dict)
    unwrapped_wheels: tuple[str, ...] = ()
    unwrapped_counters: tuple[str, ...] = ()

    def unwrapped_text(self) -> str:
        """'phi_L, phi_R wrapped modulo 2 pi, unwrapped' and/or 'ticks_L (16-bit counter)
        overflowed, unwrapped' ('' when nothing was wrapped)."""
        return unwrapped_words(self.unwrapped_wheels, self.unwrapped_counters)

    def counts_text(self) -> str:
        """What was dropped, in one line, e.g. '3 standstill, 1 pose jump; 25 pose samples
        outside the encoder time range' ('nothing' when nothing was)."""
        segments = ", ".join(f"{n} {reason}" for reason, n in self.segments_dropped.items() if n)
        samples = ", ".join(f"{_plural(n, 'pose sample')} {reason}"
                            for reason, n in self.samples_dropped.items() if n)
        return "; ".join(part for part in (segments, samples) if part) or "nothing"

    def summary(self) -> str:
        """The report in words, one fact per line."""
        lines = [f"{_plural(self.n_segments, 'segment')} kept."]
        if self.unwrapped_text():
            lines.append(f"Wheel angles {self.unwrapped_text()}.")
        dropped = sum(self.segments_dropped.values())
        if dropped:
            lines.append(f"{_plural(dropped, 'segment')} dropped:")
            lines += [f"  {n} {reason} (t = {_ranges_text(self.dropped_ranges[reason])})"
                      for reason, n in self.segments_dropped.items() if n]
        lines += [f"{_plural(n, 'pose sample')} unused: {reason}."
                  for reason, n in self.samples_dropped.items() if n]
        for gap in self.gaps:
            lines.append(f"Gap of {gap.duration:.3f} s in the {gap.stream} stream "
                         f"({gap.t_start:.3f}-{gap.t_end:.3f} s; next sample: {gap.location}); "
                         "no segment spans it.")
        lines += [f"{_plural(n, f'{stream} sample')} missed (dropouts, bridged)."
                  for stream, n in self.dropouts.items() if n]
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class SegmentedLog:
    """Segments cut from a time-series log.

    segments: the segments (excite.logs.segments.Segments). t_start, t_end: each segment's time span
    (s, encoder clock). shares_endpoints[k]: segment k starts at the pose sample where segment
    k - 1 ended, so their measured increments share that sample's noise (negatively
    correlated); False for the first segment and after a gap or a dropped segment.
    report: what was dropped and why.
    """

    segments: Segments
    t_start: FloatArray
    t_end: FloatArray
    shares_endpoints: BoolArray
    report: SegmentationReport


@dataclass(frozen=True)
class _StreamCheck:
    """Per-interval flags of one stream: gap (split there), jump; its dropouts."""

    gap: BoolArray
    jump: BoolArray
    dropouts: int


def _pose_noise(ts: TimeSeries) -> tuple[float, float]:
    """Robust std of the pose samples' noise (m for x and y pooled, rad for theta): each inner
    sample minus the linear interpolation of its neighbours (exact for motion at a constant
    velocity, whatever the spacing) has, with independent noise of std sigma and even
    spacing, std sigma sqrt(3/2); the median absolute value of those residuals over
    MEDIAN_ABS_NORMAL sqrt(3/2) estimates sigma, unmoved by the few samples where the
    motion changes abruptly. (0, 0) with fewer than 3 samples. Correlated noise reads low."""
    if ts.t_pose.size < 3:
        return 0.0, 0.0
    t = ts.t_pose
    weight = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
    residual = [v[1:-1] - ((1.0 - weight) * v[:-2] + weight * v[2:])
                for v in (ts.x, ts.y, ts.theta)]
    scale = MEDIAN_ABS_NORMAL * math.sqrt(1.5)
    xy = float(np.median(np.abs(np.concatenate(residual[:2])))) / scale
    return xy, float(np.median(np.abs(residual[2]))) / scale


def _gap_flags(t: FloatArray, window: float, max_gap: float | None) -> tuple[BoolArray, int]:
    """Intervals that are gaps, and the number of samples missed in shorter dropouts."""
    dt = np.diff(t)
    period = float(np.median(dt))
    limit = min(window, GAP_RATIO * period if max_gap is None else max_gap)
    gap = dt > limit
    short = (dt > DROPOUT_RATIO * period) & ~gap
    missed = int(np.maximum(np.rint(dt[short] / period) - 1, 1).sum())
    return gap, missed


def _check_encoders(ts: TimeSeries, window: float, limits: Limits) -> _StreamCheck:
    gap, missed = _gap_flags(ts.t_enc, window, limits.max_gap)
    dt = np.diff(ts.t_enc)
    step = np.maximum(np.abs(np.diff(ts.phi_L)), np.abs(np.diff(ts.phi_R)))
    return _StreamCheck(gap, step > limits.max_wheel_rate * dt, missed)


def _check_poses(ts: TimeSeries, window: float, limits: Limits,
                 noise: tuple[float, float]) -> _StreamCheck:
    """Gaps and jumps of the pose stream; a step is a jump when it exceeds the motion limits
    plus jump_sigmas times the noise of a difference of two poses (``noise``: a sample's std,
    xy and theta)."""
    gap, missed = _gap_flags(ts.t_pose, window, limits.max_gap)
    dt = np.diff(ts.t_pose)
    moved = np.hypot(np.diff(ts.x), np.diff(ts.y))
    turned = np.abs(np.diff(ts.theta))
    spread = limits.jump_sigmas * math.sqrt(2.0)
    jump = ((moved > limits.max_speed * dt + spread * noise[0])
            | (turned > limits.max_turn_rate * dt + spread * noise[1]))
    return _StreamCheck(gap, jump, missed)


_ENCODER_JUMP_HINT = ("a counter that overflows or resets, or a second publisher of the wheel "
                      "joints? (wheel angles must be cumulative; ticks as counted, with "
                      "--ticks-per-rev)")
_POSE_JUMP_HINT = "a relocalisation, or headings in degrees? (theta is in rad)"


def check_continuity(ts: TimeSeries, limits: Limits | None = None) -> None:
    """DataError naming the first jump of either stream (as :func:`segment_timeseries`
    detects them, with its default ``limits``), for uses that follow the whole log instead of
    dropping the segments around a jump (dead reckoning in
    :mod:`excite.validation.dead_reckoning`)."""
    limits = limits or Limits()
    window = math.inf  # gaps are not jumps here
    checks = (("encoder", _check_encoders(ts, window, limits), _ENCODER_JUMP_HINT,
               "the wheel angles jump"),
              ("pose", _check_poses(ts, window, limits, _pose_noise(ts)), _POSE_JUMP_HINT,
               "the pose jumps"))
    for stream, check, hint, what in checks:
        jumps = np.flatnonzero(check.jump)
        if jumps.size:
            raise DataError(f"{ts.location(stream, int(jumps[0]) + 1)}: {what} ({jumps.size} "
                            f"time(s) in the log; the first here), so dead reckoning across it "
                            f"means nothing: {hint}")


def _gaps(ts: TimeSeries, encoders: _StreamCheck, poses: _StreamCheck) -> list[Gap]:
    """Every gap of both streams, in time order (each on its own clock)."""
    gaps = []
    for stream, t, check in (("encoder", ts.t_enc, encoders), ("pose", ts.t_pose, poses)):
        gaps += [Gap(stream, float(t[i]), float(t[i + 1]), ts.location(stream, int(i) + 1))
                 for i in np.flatnonzero(check.gap)]
    return sorted(gaps, key=lambda g: g.t_start)


def _refuse_long_gaps(gaps: list[Gap], window: float) -> None:
    for gap in gaps:
        if gap.duration > window:
            raise DataError(f"{gap.location}: gap of {gap.duration:.3f} s in the {gap.stream} "
                            f"stream ({gap.t_start:.3f}-{gap.t_end:.3f} s), longer than the "
                            f"window ({window:g} s); --split-at-gaps (on_gap='split') cuts "
                            "the log there instead")


def _flagged_overlaps(t_enc: FloatArray, flags: BoolArray, start: FloatArray,
                      stop: FloatArray) -> IntArray:
    """How many flagged encoder intervals (t_enc[j], t_enc[j+1]) overlap each (start, stop)
    (open intervals; start == stop asks whether the instant lies strictly inside one)."""
    count = np.concatenate(([0], np.cumsum(flags)))
    first = np.clip(np.searchsorted(t_enc, start, side="right") - 1, 0, flags.size)
    last = np.clip(np.searchsorted(t_enc, stop, side="left"), 0, flags.size)
    return np.maximum(count[last] - count[first], 0)


@dataclass(frozen=True)
class _Stretches:
    """Stretches of consecutive usable pose samples: [first[k], last[k]] (inclusive)."""

    first: IntArray
    last: IntArray
    outside: int
    in_gap: int


def _stretches(t_enc: FloatArray, t_pose: FloatArray, encoders: _StreamCheck,
               poses: _StreamCheck) -> _Stretches:
    """Split the pose samples (t_pose on the encoder clock) where no segment may span: pose
    gaps, encoder gaps, samples outside the encoder time range or inside an encoder gap."""
    inside = (t_pose >= t_enc[0]) & (t_pose <= t_enc[-1])
    in_gap = inside & (_flagged_overlaps(t_enc, encoders.gap, t_pose, t_pose) > 0)
    usable = inside & ~in_gap
    link = (usable[:-1] & usable[1:] & ~poses.gap
            & (_flagged_overlaps(t_enc, encoders.gap, t_pose[:-1], t_pose[1:]) == 0))
    edges = np.diff(np.concatenate(([0], link.astype(np.int8), [0])))
    return _Stretches(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1),
                      int((~inside).sum()), int(in_gap.sum()))


def _window_boundaries(t: FloatArray, first: int, last: int, window: float) -> IntArray:
    """Boundary samples of one stretch: the first sample at or after t[first] + k window."""
    tolerance = 1e-6 * window
    n = int(math.floor((t[last] - t[first] + tolerance) / window))
    grid = t[first] + window * np.arange(n + 1)
    index = first + np.searchsorted(t[first:last + 1], grid - tolerance, side="left")
    return index[np.concatenate(([True], np.diff(index) > 0))]


def _next_keyframe(x: FloatArray, y: FloatArray, theta: FloatArray, key: int, last: int,
                   min_distance: float, min_angle: float, block: int) -> int | None:
    """First sample after ``key`` (up to ``last``) at least min_distance (m) from it or
    turned at least min_angle (rad) from it; searched in growing blocks."""
    start = key + 1
    while start <= last:
        stop = min(last + 1, start + block)
        far = np.hypot(x[start:stop] - x[key], y[start:stop] - y[key]) >= min_distance
        turned = np.abs(theta[start:stop] - theta[key]) >= min_angle
        hit = np.flatnonzero(far | turned)
        if hit.size:
            return start + int(hit[0])
        start, block = stop, 2 * block
    return None


def _keyframe_boundaries(ts: TimeSeries, first: int, last: int, min_distance: float,
                         min_angle: float) -> IntArray:
    """Keyframe samples of one stretch (see the module docstring)."""
    keys, block = [first], 16
    while (key := _next_keyframe(ts.x, ts.y, ts.theta, keys[-1], last, min_distance,
                                 min_angle, block)) is not None:
        block = max(16, 2 * (key - keys[-1]))
        keys.append(key)
    return np.asarray(keys, dtype=np.int64)


@dataclass(frozen=True)
class _Cut:
    """Candidate segments (pose sample indices) and the unfinished tails of the stretches."""

    start: IntArray
    end: IntArray
    tails: dict[str, list[tuple[int, int]]]


def _cut(ts: TimeSeries, t_pose: FloatArray, stretches: _Stretches, window: float,
         min_distance: float | None, min_angle: float | None) -> _Cut:
    """Boundaries in every stretch, by fixed windows or by keyframes."""
    starts, ends = [], []
    tails: dict[str, list[tuple[int, int]]] = {CUT_BY_GAP: [], END_OF_LOG: []}
    keyframes = min_distance is not None or min_angle is not None
    for k, (first, last) in enumerate(zip(stretches.first, stretches.last, strict=True)):
        if keyframes:
            bounds = _keyframe_boundaries(ts, int(first), int(last), min_distance or math.inf,
                                          min_angle or math.inf)
        else:
            bounds = _window_boundaries(t_pose, int(first), int(last), window)
        starts.append(bounds[:-1])
        ends.append(bounds[1:])
        if bounds[-1] < last:
            reason = END_OF_LOG if k == stretches.first.size - 1 else CUT_BY_GAP
            tails[reason].append((int(bounds[-1]), int(last)))
    empty = np.zeros(0, dtype=np.int64)
    return _Cut(np.concatenate([empty, *starts]), np.concatenate([empty, *ends]), tails)


def _wheel_angles(ts: TimeSeries) -> Callable[[FloatArray], FloatArray]:
    """The wheels' cumulative angles (rad) at any times (s, encoder clock, within the stream),
    (..., 2) for (phi_L, phi_R): a monotone cubic (PCHIP, Fritsch-Carlson) between the
    samples. On a smoothly accelerating wheel it errs by O(h^3) of the encoder period h, where
    a straight line errs by max|phi''| h^2 / 8 (a bias of 6 standard errors on b with 12.5 Hz
    encoders and 100 Hz poses); it never leaves the range of the two samples around (no
    overshoot at a standstill or a command step) and is exact at the samples."""
    from scipy.interpolate import PchipInterpolator

    return PchipInterpolator(ts.t_enc, np.column_stack([ts.phi_L, ts.phi_R]),
                             extrapolate=False)


def _increments(ts: TimeSeries, wheels: Callable[[FloatArray], FloatArray],
                t_pose: FloatArray, start: IntArray, end: IntArray) -> FloatArray:
    """(N, 5) segments: encoder increments interpolated at the boundary times (rad) and the
    sensor's pose increment in its frame at the start (m, m, rad)."""
    dphi = wheels(t_pose[end]) - wheels(t_pose[start])
    c, s = np.cos(ts.theta[start]), np.sin(ts.theta[start])
    px, py = ts.x[end] - ts.x[start], ts.y[end] - ts.y[start]
    return np.column_stack([*dphi.T, c * px + s * py, c * py - s * px,
                            ts.theta[end] - ts.theta[start]])


def _substeps(ts: TimeSeries, wheels: Callable[[FloatArray], FloatArray], t_a: FloatArray,
              t_b: FloatArray) -> tuple[FloatArray, FloatArray, IntArray]:
    """Each segment's encoder sub-increments (N, K) over its own count (N,) of equal
    sub-intervals of [t_a, t_b] (s, encoder clock), zero-padded to the largest: sub-intervals
    of about the (median) encoder period, or MAX_SUBSTEP when the encoders are slower (the
    angles between samples from the cubic interpolant), at most MAX_SUBSTEPS. They sum to the
    segment's increments exactly."""
    period = min(float(np.median(np.diff(ts.t_enc))), MAX_SUBSTEP)
    duration = t_b - t_a
    count = np.clip(np.ceil(duration / period - 1e-9), 1, MAX_SUBSTEPS)
    count = count.astype(np.int64)
    j = np.arange(int(count.max()) + 1)
    times = t_a[:, None] + duration[:, None] * np.minimum(j / count[:, None], 1.0)
    times[j[None, :] >= count[:, None]] = np.repeat(t_b, j.size - count)  # exactly t_b
    sub = np.diff(wheels(times), axis=1)
    return sub[..., 0], sub[..., 1], count


def _drop_reasons(ts: TimeSeries, t_pose: FloatArray, cut: _Cut, rows: FloatArray,
                  encoders: _StreamCheck, poses: _StreamCheck, limits: Limits,
                  noise: tuple[float, float]) -> dict[str, BoolArray]:
    """Per reason, which candidate segments to drop (a segment counts under its first
    reason only)."""
    pose_jumps = np.concatenate(([0], np.cumsum(poses.jump)))
    wheel = np.abs(rows[:, :2])
    wheels_still = wheel.max(axis=1, initial=0.0) <= limits.still_wheel
    moved, turned = np.hypot(rows[:, 2], rows[:, 3]), np.abs(rows[:, 4])
    # still: within the still limits or the noise (a difference of two poses has sqrt(2) times
    # a sample's noise)
    near = max(limits.still_distance, limits.carry_sigmas * math.sqrt(2.0) * noise[0])
    near_heading = max(limits.still_heading, limits.carry_sigmas * math.sqrt(2.0) * noise[1])
    # carried: beyond that plus what the wheels' small turns could do to any plausible robot
    could_turn = limits.max_radius_to_track * wheel.sum(axis=1)
    could_move = limits.max_wheel_radius * wheel.max(axis=1, initial=0.0) + (
        limits.max_sensor_arm * could_turn)
    reasons = {
        POSE_JUMP: pose_jumps[cut.end] > pose_jumps[cut.start],
        ENCODER_JUMP: _flagged_overlaps(ts.t_enc, encoders.jump, t_pose[cut.start],
                                        t_pose[cut.end]) > 0,
        STANDSTILL: wheels_still & (moved <= near) & (turned <= near_heading),
        CARRIED: wheels_still & ((moved > near + could_move)
                                 | (turned > near_heading + could_turn)),
    }
    taken = np.zeros(cut.start.size, dtype=bool)
    for reason, mask in reasons.items():
        reasons[reason] = mask & ~taken
        taken |= mask
    return reasons


def _merged(ranges: list[tuple[float, float]]) -> tuple[tuple[float, float], ...]:
    """Sorted ranges with touching ones joined."""
    merged: list[tuple[float, float]] = []
    for a, b in sorted(ranges):
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(b, merged[-1][1]))
        else:
            merged.append((a, b))
    return tuple(merged)


def _report(t_pose: FloatArray, cut: _Cut, reasons: dict[str, BoolArray], kept: int,
            stretches: _Stretches, gaps: list[Gap], encoders: _StreamCheck,
            poses: _StreamCheck, ts: TimeSeries) -> SegmentationReport:
    ranges = {reason: [(t_pose[a], t_pose[b]) for a, b in zip(cut.start[mask], cut.end[mask],
                                                              strict=True)]
              for reason, mask in reasons.items()}
    ranges |= {reason: [(t_pose[a], t_pose[b]) for a, b in tails]
               for reason, tails in cut.tails.items()}
    return SegmentationReport(
        n_segments=kept,
        segments_dropped={reason: len(r) for reason, r in ranges.items()},
        dropped_ranges={reason: _merged([(float(a), float(b)) for a, b in r])
                        for reason, r in ranges.items()},
        samples_dropped={OUTSIDE_ENCODERS: stretches.outside,
                         INSIDE_ENCODER_GAP: stretches.in_gap},
        gaps=tuple(gaps),
        dropouts={"encoder": encoders.dropouts, "pose": poses.dropouts},
        unwrapped_wheels=ts.unwrapped_wheels,
        unwrapped_counters=ts.unwrapped_counters,
    )


#: s: a median sample period this long suggests times in other units than seconds (no pose
#: source for calibration is that slow).
SLOWEST_PERIOD = 5.0


def _check_settings(ts: TimeSeries, window: float, min_distance: float | None,
                    min_angle: float | None, time_offset: float, on_gap: str) -> None:
    if not 0 < window < math.inf:
        raise DataError(f"window must be positive and finite (s), got {window}")
    for name, value in (("min_distance", min_distance), ("min_angle", min_angle)):
        if value is not None and not 0 < value < math.inf:
            raise DataError(f"{name} must be positive and finite, got {value}")
    if not math.isfinite(time_offset):
        raise DataError(f"time_offset must be finite (s), got {time_offset}")
    if on_gap not in ("error", "split"):
        raise DataError(f"on_gap must be 'error' or 'split', got {on_gap!r}")
    period = float(np.median(np.diff(ts.t_pose)))
    if window < period:
        units = (" (times are in s: are these ms, us or ns?)" if period >= SLOWEST_PERIOD
                 else "")
        raise DataError(f"{ts.source[1]}: the window ({window:g} s) is shorter than the pose "
                        f"sample period ({period:.3g} s){units}")


def segment_timeseries(
    ts: TimeSeries,
    window: float = 1.0,
    min_distance: float | None = None,
    min_angle: float | None = None,
    time_offset: float = 0.0,
    *,
    on_gap: Literal["error", "split"] = "error",
    limits: Limits | None = None,
) -> SegmentedLog:
    """Cut a time-series log into segments (see the module docstring for the method).

    window (s): segment duration in fixed-window mode; in both modes a gap longer than it is
    an error when on_gap="error". min_distance (m), min_angle (rad): keyframe mode when either
    is given. time_offset (s): pose time + time_offset = encoder time. on_gap: "error" raises
    for a gap longer than the window, naming the file and line (or time) where the stream
    resumes; "split" cuts the log there. limits: the detection thresholds (default Limits()).

    Raises DataError for bad settings, a gap (with on_gap="error"), or fewer than 3 segments
    left.
    """
    _check_settings(ts, window, min_distance, min_angle, time_offset, on_gap)
    limits = limits or Limits()
    noise = _pose_noise(ts)
    encoders, poses = (_check_encoders(ts, window, limits),
                       _check_poses(ts, window, limits, noise))
    gaps = _gaps(ts, encoders, poses)
    if on_gap == "error":
        _refuse_long_gaps(gaps, window)
    t_pose = ts.t_pose + time_offset
    stretches = _stretches(ts.t_enc, t_pose, encoders, poses)
    cut = _cut(ts, t_pose, stretches, window, min_distance, min_angle)
    wheels = _wheel_angles(ts)
    rows = _increments(ts, wheels, t_pose, cut.start, cut.end)
    reasons = _drop_reasons(ts, t_pose, cut, rows, encoders, poses, limits, noise)
    keep = ~np.logical_or.reduce(list(reasons.values()))
    start, end = cut.start[keep], cut.end[keep]
    report = _report(t_pose, cut, reasons, int(keep.sum()), stretches, gaps, encoders, poses,
                     ts)
    if report.n_segments < MIN_SEGMENTS:
        # name the stream behind most of the drops (encoder jumps and standstills: the wheels)
        worst = max(report.segments_dropped, key=report.segments_dropped.get, default=None)
        stream = ts.source[0] if worst in (ENCODER_JUMP, STANDSTILL) else ts.source[1]
        hint = {ENCODER_JUMP: f"; {_ENCODER_JUMP_HINT}",
                POSE_JUMP: f"; {_POSE_JUMP_HINT}"}.get(worst, "")
        raise DataError(f"{stream}: {report.n_segments} segment(s) after segmentation; "
                        f"at least {MIN_SEGMENTS} are needed (dropped: {report.counts_text()})"
                        f"{hint}")
    t_start, t_end = t_pose[start], t_pose[end]
    shares = np.concatenate(([False], start[1:] == end[:-1]))
    sub_L, sub_R, count = _substeps(ts, wheels, t_start, t_end)
    segments = Segments(*rows[keep].T, t_start=t_start, t_end=t_end, chained=shares,
                        sub_dphi_L=sub_L, sub_dphi_R=sub_R, sub_count=count)
    return SegmentedLog(segments=segments, t_start=t_start, t_end=t_end,
                        shares_endpoints=shares, report=report)
