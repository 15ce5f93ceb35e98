"""The rows the topics of a bag give, message by message: the wheels' angles from JointState
messages (:class:`JointRows`) and the external sensor's poses from pose messages
(:class:`PoseTopicRows`) or TF (:class:`TransformRows`), each with its receive times, the
messages skipped and why, and notes; :mod:`excite.logs.bag_reader` opens the bag and feeds
them. Their columns are put in stamp order by :mod:`excite.logs.bag_stamps`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from excite.errors import DataError
from excite.logs.bag_stamps import stamped_table, wheels_together
from excite.logs.orientation import headings, z_up
from excite.logs.timeseries import SPEED_NOTE, integrated_speed, sample_at

__all__ = ["FEWER_POSITIONS", "NOT_FINITE_WHEELS", "NOT_TRACKED", "NO_POSITIONS", "POSE_2D",
           "POSE_PARTS", "POSE_TYPES", "JointRows", "PoseRows", "PoseTopicRows", "TopicRows",
           "TransformRows", "frame_name", "planar_row", "pose_row", "stamp_ns"]

#: Where each stamped pose message type keeps its position and orientation quaternion
#: (geometry_msgs Point or Vector3, and Quaternion): bags' messages and a live node's alike.
POSE_PARTS: dict[str, Callable[[Any], tuple[Any, Any]]] = {
    "geometry_msgs/msg/PoseStamped": lambda msg: (msg.pose.position, msg.pose.orientation),
    "geometry_msgs/msg/PoseWithCovarianceStamped": lambda msg: (msg.pose.pose.position,
                                                                msg.pose.pose.orientation),
    "nav_msgs/msg/Odometry": lambda msg: (msg.pose.pose.position, msg.pose.pose.orientation),
    "geometry_msgs/msg/TransformStamped": lambda msg: (msg.transform.translation,
                                                       msg.transform.rotation),
}


def planar_row(position: Any, q: Any) -> tuple[float, ...]:
    """What a pose row keeps: x, y, z (m) and the orientation quaternion's x, y, z, w."""
    return position.x, position.y, position.z, q.x, q.y, q.z, q.w


#: A pose message type without a header, as ROS 1's laser_scan_matcher publishes it: timed
#: by the receive times (:mod:`excite.logs.bag_stamps`).
POSE_2D = "geometry_msgs/msg/Pose2D"
#: Supported pose message types (:func:`pose_row`).
POSE_TYPES = (*POSE_PARTS, POSE_2D)


def pose_row(msg: Any) -> tuple[float, ...]:
    """A pose message's row (:func:`planar_row`); a Pose2D's heading as a quaternion about z."""
    if msg.__msgtype__ == POSE_2D:
        half = msg.theta / 2
        return msg.x, msg.y, 0.0, 0.0, 0.0, math.sin(half), math.cos(half)
    return planar_row(*POSE_PARTS[msg.__msgtype__](msg))


#: Why a JointState message naming both wheels is skipped: its position array is empty.
NO_POSITIONS = "without wheel positions"
#: Why a JointState message is skipped: a wheel's position (or, when read, velocity) is NaN or
#: infinite, as ros2_control publishes before the hardware's first reading.
NOT_FINITE_WHEELS = "with a wheel value not finite (NaN before the hardware's first reading?)"
#: Why a JointState message with the wheels' positions is skipped: most messages have their
#: velocities only, which are read instead.
FEWER_POSITIONS = ("with wheel positions, fewer than those with velocities only (a start-up's "
                   "or another publisher's), which are read")
#: Why a pose is skipped: it holds NaN or a quaternion of zeros.
NOT_TRACKED = "not measured (NaN, or a quaternion of zeros: a body not tracked?)"


def stamp_ns(header: Any) -> int:
    """A header stamp in ns."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def frame_name(frame_id: str) -> str:
    return frame_id.lstrip("/")


class TopicRows:
    """Rows (header stamp in ns first, then the values read) of one topic in receive order,
    their receive times (ns), the messages skipped per reason, and notes for the user."""

    def __init__(self, where: str) -> None:
        self.where = where
        self.rows: list[tuple[float, ...]] = []
        self.received: list[int] = []
        self.skipped: dict[str, int] = {}
        self.notes: list[str] = []

    def skip(self, reason: str, count: int = 1) -> None:
        if count:
            self.skipped[reason] = self.skipped.get(reason, 0) + count

    def append(self, row: tuple[float, ...], received: int) -> None:
        self.rows.append(row)
        self.received.append(received)

    def table(self, width: int) -> np.ndarray:
        """The rows (n, width) in stamp order, the stamp in s, as
        :func:`excite.logs.bag_stamps.stamped_table` makes them (stamps not set, clock
        steps, repeats)."""
        rows = np.array(self.rows, dtype=float).reshape(-1, width)
        rows[:, 0] *= 1e-9
        stamped = stamped_table(self.where, rows, np.array(self.received, dtype=float) * 1e-9)
        for reason, count in stamped.skipped.items():
            self.skip(reason, count)
        self.notes += stamped.notes
        return stamped.rows


class JointRows(TopicRows):
    """Collects (stamp, left angle, right angle) from JointState messages; each wheel's
    (stamp, angle) apart from messages that name one wheel only (a driver per motor); and
    (stamp, left speed, right speed) from messages naming both wheels without their positions
    (empty or NaN) but with their velocities (rad/s), integrated when no message has the
    positions."""

    def __init__(self, where: str, left: str, right: str) -> None:
        super().__init__(where)
        self.left, self.right = left, right
        self.names: set[str] = set()
        self.apart = {joint: TopicRows(f"{where} {joint}") for joint in (left, right)}
        self.speeds = TopicRows(where)
        #: Whether :meth:`columns` integrated the wheels' velocities.
        self.integrated = False
        self.apart_speeds = {joint: TopicRows(f"{where} {joint}") for joint in (left, right)}

    def add(self, msg: Any, received: int) -> None:
        names = list(msg.name)
        self.names.update(names)
        wheels = [joint for joint in (self.left, self.right) if joint in names]
        if not wheels:
            return
        index = [names.index(joint) for joint in wheels]
        stamp = stamp_ns(msg.header)
        if len(msg.velocity) == len(names) and (
                len(msg.position) != len(names)
                or any(math.isnan(msg.position[k]) for k in index)):
            self._rows_of(wheels, self.speeds, self.apart_speeds).append(
                (stamp, *(msg.velocity[k] for k in index)), received)
        if len(msg.position) == 0:  # velocity or effort only: allowed by JointState
            if len(wheels) == 2:
                self.skip(NO_POSITIONS)
            return
        if len(msg.position) != len(names):
            raise DataError(f"{sample_at(self.where, stamp * 1e-9)}: "
                            f"{len(msg.position)} positions for {len(names)} joint names")
        self._rows_of(wheels, self, self.apart).append(
            (stamp, *(msg.position[k] for k in index)), received)

    @staticmethod
    def _rows_of(wheels: list[str], both: TopicRows, apart: dict[str, TopicRows]
                 ) -> TopicRows:
        """Where a message's row goes: ``both`` when it names both wheels, else its wheel's
        own rows in ``apart``."""
        return both if len(wheels) == 2 else apart[wheels[0]]

    def columns(self) -> list[np.ndarray]:
        """[t (s), phi_L, phi_R (rad)]: from the messages with both wheels, or when there
        are none, from the wheels' separate messages put together, or when no message has
        their positions, their velocities integrated (a note says so)."""
        for joint in (self.left, self.right):
            if joint not in self.names:
                present = ", ".join(sorted(self.names)) or "none"
                raise DataError(f"{self.where}: no joint {joint!r}; joints present: {present}")
        table = self.table(3) if self.rows else None
        measured = None if table is None else table[np.isfinite(table[:, 1:]).all(axis=1)]
        if self.speeds.rows and (measured is None or len(measured) < len(self.speeds.rows)):
            return self._from_speeds(0 if measured is None else len(measured))
        if table is not None and measured is not None:
            if not len(measured):
                raise DataError(f"{self.where}: the positions of {self.left!r} and "
                                f"{self.right!r} are all NaN (joints with a velocity state "
                                "interface only?); excite needs the wheels' positions")
            self.skip(NOT_FINITE_WHEELS, len(table) - len(measured))
            return list(measured.T)
        if all(stream.rows for stream in self.apart.values()):
            return self._together(self.apart)
        if all(stream.rows for stream in self.apart_speeds.values()):
            return self._together(self.apart_speeds, speeds=True)
        if self.skipped.get(NO_POSITIONS):
            raise DataError(f"{self.where}: no message has positions for the joints "
                            f"{self.left!r} and {self.right!r} "
                            f"({self.skipped[NO_POSITIONS]} name them with an empty "
                            "position array: velocity or effort only)")
        missing = next(joint for joint, stream in self.apart.items() if not stream.rows)
        raise DataError(f"{self.where}: no message has a position of the joint {missing!r}")

    def _from_speeds(self, with_positions: int) -> list[np.ndarray]:
        """The wheels' velocities integrated into angles (:func:`integrated_speed`), those
        not finite left out and counted; the messages without positions are then read, not
        skipped, and the ``with_positions`` messages that had them (fewer: a start-up's, or
        another publisher's) are counted as left out."""
        angles = _integrated(self.speeds, self.speeds.table(3))
        self.integrated = True
        self.skipped = dict(self.speeds.skipped)
        self.skip(FEWER_POSITIONS, with_positions)
        self.notes = [*self.speeds.notes, f"{self.where}: {SPEED_NOTE}"]
        return list(angles.T)

    def _together(self, apart: dict[str, TopicRows], speeds: bool = False
                  ) -> list[np.ndarray]:
        """Each wheel's own messages put together (their angles, or with ``speeds`` their
        velocities integrated, those not finite left out and counted): the right wheel's
        angles interpolated to the left wheel's stamps."""
        left, right = (apart[joint] for joint in (self.left, self.right))
        tables = [stream.table(2) for stream in (left, right)]
        if speeds:
            tables = [_integrated(stream, table)
                      for stream, table in zip((left, right), tables, strict=True)]
            self.integrated = True
            self.notes.append(f"{self.where}: {SPEED_NOTE}")
        rows, left_out = wheels_together(*tables)
        for stream in (left, right):
            self.notes += stream.notes
            for reason, count in stream.skipped.items():
                self.skip(f"{reason} ({stream.where.rsplit(' ', 1)[1]})", count)
        self.skip(f"{self.left} outside the {self.right} messages' time range or gaps",
                  left_out)
        self.notes.append(f"{self.where}: the wheels come in separate messages: the "
                          f"{self.right} angles are interpolated to the {self.left} stamps")
        return list(rows.T)


def _integrated(rows: TopicRows, table: np.ndarray) -> np.ndarray:
    """A table of (t, wheel speeds...) (s, rad/s) as (t, angles...) (rad, from 0): each
    speed integrated (:func:`integrated_speed`) over the rows whose speeds are all finite,
    the others left out and counted in ``rows``."""
    finite = np.isfinite(table[:, 1:]).all(axis=1)
    rows.skip(NOT_FINITE_WHEELS, int(np.sum(~finite)))
    t = table[finite, 0]
    return np.column_stack([t, *(integrated_speed(t, speed) for speed in table[finite, 1:].T)])


class PoseRows(TopicRows):
    """Rows of (stamp, x, y, z, quaternion x, y, z, w)."""

    def columns(self) -> list[np.ndarray]:
        """[t (s), x, y (m), theta (rad, wrapped)], without the poses not measured (a NaN,
        or a quaternion of zeros: a motion-capture body not tracked), skipped and counted."""
        table = self.table(8)
        lost = np.isnan(table).any(axis=1) | (table[:, 4:] == 0).all(axis=1)
        self.skip(NOT_TRACKED, int(lost.sum()))
        table = table[~lost]
        t = table[:, 0]
        q, position, turned = z_up(table[:, 4:], table[:, 1:4])
        if turned is not None:
            self.notes.append(f"{self.where}: {turned}")
        return [t, position[:, 0], position[:, 1],
                headings(q, lambda i: sample_at(self.where, t[i]))]


class PoseTopicRows(PoseRows):
    """Collects the poses of messages of the supported types (one topic may carry several,
    from publishers of different types)."""

    def add(self, msg: Any, received: int) -> None:
        stamp = stamp_ns(msg.header) if hasattr(msg, "header") else 0
        self.append((stamp, *pose_row(msg)), received)


class TransformRows(PoseRows):
    """Collects the direct parent -> child transforms in TF messages."""

    def __init__(self, where: str, parent: str, child: str) -> None:
        super().__init__(where)
        self.pair = (frame_name(parent), frame_name(child))
        self.pairs: set[tuple[str, str]] = set()

    def add(self, msg: Any, received: int) -> None:
        for transform in msg.transforms:
            pair = (frame_name(transform.header.frame_id), frame_name(transform.child_frame_id))
            self.pairs.add(pair)
            if pair == self.pair:
                self.append((stamp_ns(transform.header),
                             *planar_row(transform.transform.translation,
                                      transform.transform.rotation)), received)

    def columns(self) -> list[np.ndarray]:
        """[t (s), x, y (m), theta (rad, wrapped)]."""
        if not self.rows:
            present = ", ".join(f"{a} -> {b}" for a, b in sorted(self.pairs)) or "none"
            raise DataError(f"{self.where}: no transform {self.pair[0]} -> {self.pair[1]}; "
                            f"frame pairs present: {present}")
        return super().columns()
