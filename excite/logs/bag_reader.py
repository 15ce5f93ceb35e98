"""ROS bags read as time-series logs: wheel angles and the external sensor's poses.

Reads rosbag2 (sqlite3 or mcap storage: a directory with ``metadata.yaml``, or a single
``.db3`` / ``.mcap`` file) and ROS 1 (``.bag``) through the ``rosbags`` library (the ``ros``
extra), imported only when a bag is read.
Messages are decoded with the definitions the bag records for the topics read (types it does
not define: rosbags' ROS 1 Noetic or latest ROS 2 store); other topics' definitions are never
looked at, so a rosserial bridge's empty definition or a stale custom type elsewhere in the bag
does not matter. Parts of a bag that cannot be opened as given (``.bag.active``, a rosbag2
directory without ``metadata.yaml``, its ``metadata.yaml`` or a ``.zstd`` file) are named with
the way out (:func:`excite.logs.bag_paths.bag_path_problem`).

* Wheel angles: ``sensor_msgs/msg/JointState`` messages on one topic; ``position`` (rad,
  cumulative) of the two wheel joints, found by name in each message (any order; a message
  lacking either joint is left out; one naming both with an empty ``position``, as a
  velocity-only publisher sends, is skipped and counted). When no message has the wheels'
  positions (empty, or NaN as joint_state_broadcaster fills a velocity-only interface's),
  their ``velocity`` (rad/s) is integrated into angles (the trapezoidal rule,
  :func:`excite.logs.timeseries.integrated_speed`), with a note. When no message names both (a
  driver per motor), each wheel's messages are put together, the right wheel's angles
  interpolated to the left wheel's stamps (:func:`excite.logs.bag_stamps.wheels_together`),
  with a note.
* Poses of the external sensor in the world frame: a ``geometry_msgs/msg/PoseStamped``,
  ``PoseWithCovarianceStamped``, ``TransformStamped`` (vicon_bridge), ``Pose2D`` (no header:
  ROS 1's laser_scan_matcher) or ``nav_msgs/msg/Odometry`` topic (several of these types on
  one topic are fine: publishers of different types), or TF: the transforms from ``parent``
  to ``child`` in ``tf2_msgs/msg/TFMessage`` (or ROS 1's older ``tf/tfMessage``) messages on
  ``/tf``. Only direct parent -> child transforms are used (no chaining through other frames,
  no inversion, not ``/tf_static``); record the transform you need directly. Leading ``/`` of
  frame ids (ROS 1) are ignored. x, y in m; heading = yaw of the orientation quaternion
  (:mod:`excite.logs.orientation`: free of the quaternion's length; the world frame must be
  z-up, a tilt beyond 45 degrees is an error, most often a Y-up motion capture stream). A
  pose holding NaN or a quaternion of zeros (a motion-capture body not tracked) is skipped
  and counted.
* Times are the messages' header stamps (s), checked against the receive times
  (:mod:`excite.logs.bag_stamps`): a stream without stamps is timed by its receive times,
  a clock step is found and corrected, each with a note; each stream is put in stamp order.
  Messages stamped zero (not set) before the first stamped message of their topic are
  skipped and counted (published before the clock ran), as are exact repeats (same stamp,
  same values); zero stamps after stamped ones, or one stamp with different values, are
  errors. :func:`read_bag_log` returns the counts and notes beside the log.

Writing bags: :mod:`excite.logs.bag_writer`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from excite.errors import DataError
from excite.logs.bag_paths import bag_path_problem
from excite.logs.bag_topics import POSE_TYPES, JointRows, PoseTopicRows, TransformRows
from excite.logs.timeseries import TimeSeries

__all__ = ["JOINT_STATES", "MISSING_EXTRA", "BagLog", "read_bag", "read_bag_log"]

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF_TOPIC = "/tf"
#: The TF message types read from /tf: ROS 2's and ROS 1's, and ROS 1's before tf2.
TF_MESSAGES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
#: The topic of the wheels' JointState messages, unless told otherwise (reading and writing).
JOINT_STATES = "/joint_states"
MISSING_EXTRA = "reading bags needs the ros extra: pip install 'excite[ros]'"


class _Bag:
    """One open bag (rosbags' ROS 1 or rosbag2 reader; the ``ros`` extra): its connections,
    and the messages of chosen connections decoded with the definitions recorded for those
    connections only, so that an unused topic's missing, empty or mismatching definition (a
    rosserial bridge's, a stale custom type) does not matter. Types the bag defines for no
    chosen connection come from rosbags' typestore of ROS 1 Noetic or of the latest ROS 2."""

    def __init__(self, name: str) -> None:
        try:
            from rosbags.rosbag1 import Reader as Reader1
            from rosbags.rosbag2 import Reader as Reader2
        except ImportError:
            raise DataError(MISSING_EXTRA) from None
        self.name = name
        self.ros1 = Path(name).suffix == ".bag"
        try:
            self.reader = (Reader1 if self.ros1 else Reader2)(Path(name))
            self.reader.open()
        except Exception as exc:  # rosbags raises its own errors, and KeyError on odd files
            raise DataError(f"{name}: not a readable ROS bag ({_why(exc)})") from None
        self.connections = list(self.reader.connections)

    def close(self) -> None:
        self.reader.close()

    def messages(self, connections: list[Any]) -> Iterator[tuple[Any, int, Any]]:
        """(connection, receive time in ns, decoded message) of ``connections`` in receive
        order; DataError naming the topic for a message its recorded definition cannot
        decode."""
        decode = self._decoder(connections)
        where = ""
        try:
            for connection, received, raw in self.reader.messages(connections=connections):
                where = connection.topic
                yield connection, received, decode(raw, connection.msgtype)
        except Exception as exc:  # rosbags' errors while reading or decoding
            hint = ""
            if Path(self.name).is_file() and (Path(self.name).parent / "metadata.yaml").exists():
                hint = (f"; if the bag is compressed, give its directory "
                        f"{Path(self.name).parent}")
            place = f"{self.name} {where}" if where else self.name
            raise DataError(f"{place}: a message cannot be read or decoded "
                            f"({_why(exc)}){hint}") from None

    def _decoder(self, connections: list[Any]) -> Callable[[bytes, str], Any]:
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

        default = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.LATEST)
        types = dict(default.fielddefs)
        try:
            for connection in connections:
                definition = connection.msgdef
                if definition.format == MessageDefinitionFormat.MSG and definition.data.strip():
                    types.update(get_types_from_msg(definition.data, connection.msgtype))
                elif definition.format == MessageDefinitionFormat.IDL and definition.data.strip():
                    separator = "=" * 80 + "\n"  # several IDL files, each under "IDL: name"
                    idls = ([part.split("\n", 1)[1]
                             for part in definition.data.split(separator)[1:]]
                            if definition.data.startswith(f"{separator}IDL: ")
                            else [definition.data])
                    for idl in idls:
                        types.update(get_types_from_idl(idl))
        except Exception as exc:  # a definition rosbags cannot parse
            raise DataError(f"{self.name}: the recorded message definition of "
                            f"{connection.topic} ({connection.msgtype}) cannot be read "
                            f"({_why(exc)})") from None
        store = get_typestore(Stores.EMPTY)
        store.register(types)
        return store.deserialize_ros1 if self.ros1 else store.deserialize_cdr


def _why(exc: Exception) -> str:
    """An exception from rosbags in a few words (its message, else its type)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, KeyError) and text == "'ros1msg'":
        return "an mcap file of ROS 1 messages; convert it to a ROS 1 .bag"
    return text if text and not isinstance(exc, KeyError) else f"{type(exc).__name__} {text}"


@contextmanager
def _opened(name: str) -> Iterator[_Bag]:
    """An open bag; DataError (one line) for anything that is not a bag or cannot be read, or
    an empty bag."""
    if not os.path.exists(name):
        raise DataError(f"{name}: no such file or directory")
    problem = bag_path_problem(name)
    if problem is not None:
        raise DataError(problem)
    bag = _Bag(name)
    try:
        if bag.reader.message_count == 0:
            raise DataError(f"{name}: empty bag (no messages)")
        yield bag
    finally:
        bag.close()


def _topic_list(topics: dict[str, set[str]]) -> str:
    return ", ".join(f"{topic} ({', '.join(sorted(msgtypes))})"
                     for topic, msgtypes in sorted(topics.items()))


def _require(name: str, topics: dict[str, set[str]], topic: str, kinds: tuple[str, ...],
             role: str) -> None:
    """DataError unless the topic exists and all its message types are among ``kinds``."""
    if topic not in topics:
        raise DataError(f"{name}: no topic {topic} ({role}); the bag has: {_topic_list(topics)}")
    unsupported = sorted(topics[topic] - set(kinds))
    if unsupported:
        raise DataError(f"{name}: topic {topic} has type {', '.join(unsupported)}, not "
                        f"supported for {role}; supported: {', '.join(kinds)}")


def _pose_collector(name: str, topics: dict[str, set[str]], pose_topic: str | None,
                    tf: tuple[str, str] | None) -> tuple[str, PoseTopicRows | TransformRows, str]:
    """(topic to read, its collector, the pose stream's source label)."""
    if tf is not None:
        _require(name, topics, TF_TOPIC, TF_MESSAGES, "transforms")
        transforms = TransformRows(f"{name} {TF_TOPIC}", *tf)
        parent, child = transforms.pair
        return TF_TOPIC, transforms, f"{name} {TF_TOPIC} {parent}->{child}"
    assert pose_topic is not None  # read_bag checked that exactly one source is given
    _require(name, topics, pose_topic, POSE_TYPES, "poses")
    poses = PoseTopicRows(f"{name} {pose_topic}")
    return pose_topic, poses, poses.where


@dataclass(frozen=True)
class BagLog:
    """A bag read as a time-series log.

    series: the log (see :func:`read_bag`). skipped: the messages left out and why, as
    {"topic reason": count} in reading order, e.g. {"/joint_states without wheel
    positions": 12}; empty when every message of the two streams was used. notes: what the
    user should know of the stamps, one line each (receive times used for stamps never set,
    a clock step corrected: :mod:`excite.logs.bag_stamps`).
    """

    series: TimeSeries
    skipped: dict[str, int] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def skipped_text(self) -> str:
        """The skipped messages in one line, e.g. '12 /joint_states without wheel
        positions, 3 /pose stamped 0 before the first stamped message', or 'none'."""
        return ", ".join(f"{n} {what}" for what, n in self.skipped.items()) or "none"


def read_bag_log(
    path: str | os.PathLike[str],
    left_wheel: str,
    right_wheel: str,
    pose_topic: str | None = None,
    tf: tuple[str, str] | None = None,
    joint_states: str = JOINT_STATES,
) -> BagLog:
    """Read wheel angles and sensor poses from a ROS bag (see the module docstring), with
    what was skipped.

    left_wheel, right_wheel: joint names in the JointState messages on ``joint_states``.
    Exactly one pose source: ``pose_topic`` (one of :data:`POSE_TYPES`) or ``tf=(parent,
    child)`` (the child frame's pose in the parent, world, frame, from /tf). The series is
    on the header-stamp clocks (s; receive times for a stream without stamps, clock steps
    corrected: :mod:`excite.logs.bag_stamps`), theta unwrapped; its source names the bag and
    topics.

    Skipped, and counted in ``skipped``: JointState messages that name both wheels with an
    empty position array (velocity or effort only); messages stamped zero (not set) before
    the first stamped message of their topic, in receive order (published before the clock
    ran); a message repeating another (same stamp, same values); poses not measured (NaN, or
    a quaternion of zeros).

    Raises DataError (one line) when rosbags is missing, the path is missing or not a bag, the
    bag is empty, a topic is missing (listing the topics and types present) or of an
    unsupported type (listing the supported ones), a joint is unknown (listing the joints
    present) or never has a position, no transform parent -> child exists (listing the frame
    pairs present), an orientation is tilted over 45 degrees (a Y-up frame), or a stream is
    invalid (a zero stamp after stamped messages, two messages with one stamp and different
    values, too few samples).
    """
    name = os.fspath(path)
    if (pose_topic is None) == (tf is None):
        raise DataError("give exactly one pose source: pose_topic or tf=(parent, child)")
    with _opened(name) as bag:
        topics: dict[str, set[str]] = {}
        for connection in bag.connections:
            topics.setdefault(connection.topic, set()).add(connection.msgtype)
        _require(name, topics, joint_states, (JOINT_STATE,), "wheel joint states")
        joints = JointRows(f"{name} {joint_states}", left_wheel, right_wheel)
        pose_key, poses, pose_source = _pose_collector(name, topics, pose_topic, tf)
        collectors: dict[str, JointRows | PoseTopicRows | TransformRows] = {joint_states: joints,
                                                                 pose_key: poses}
        wanted = [c for c in bag.connections if c.topic in collectors]
        for connection, received, msg in bag.messages(wanted):
            collectors[connection.topic].add(msg, received)
    t_enc, phi_L, phi_R = joints.columns()
    t_pose, x, y, theta = poses.columns()
    series = TimeSeries(t_enc, phi_L, phi_R, t_pose, x, y, theta,
                        source=(joints.where, pose_source), speeds=joints.integrated)
    skipped = {f"{topic} {reason}": n for topic, stream in ((joint_states, joints),
                                                             (pose_key, poses))
               for reason, n in stream.skipped.items()}
    return BagLog(series, skipped, tuple(joints.notes + poses.notes))


def read_bag(
    path: str | os.PathLike[str],
    left_wheel: str,
    right_wheel: str,
    pose_topic: str | None = None,
    tf: tuple[str, str] | None = None,
    joint_states: str = JOINT_STATES,
) -> TimeSeries:
    """The time-series log of a ROS bag: :func:`read_bag_log` without the account of the
    skipped messages (same arguments and errors)."""
    return read_bag_log(path, left_wheel, right_wheel, pose_topic, tf, joint_states).series
