"""Time-series logs written as ROS bags (:func:`write_bag`, :class:`BagWriter`): JointState
and PoseStamped messages, in rosbag2 (sqlite3 or mcap storage) or ROS 1, readable by
:func:`excite.logs.bag_reader.read_bag`. Written through the ``rosbags`` library (the ``ros``
extra), imported only when a bag is written.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from excite.errors import DataError
from excite.logs.bag_reader import JOINT_STATE, JOINT_STATES, POSE_STAMPED
from excite.logs.timeseries import TimeSeries

__all__ = ["STORAGES", "LEFT_WHEEL", "RIGHT_WHEEL", "POSE_TOPIC", "WORLD_FRAME",
           "MISSING_WRITE_EXTRA", "BagWriter", "write_bag"]

#: Bag storages write_bag can write: rosbag2 (a directory) with sqlite3 or mcap files, ROS 1.
STORAGES = ("sqlite3", "mcap", "ros1")
#: Defaults of write_bag: the wheel joints, the pose topic, and the frame of the sensor's poses
#: (the JointState topic: excite.logs.bag_reader.JOINT_STATES).
LEFT_WHEEL, RIGHT_WHEEL = "left_wheel_joint", "right_wheel_joint"
POSE_TOPIC = "/pose"
WORLD_FRAME = "map"
MISSING_WRITE_EXTRA = "writing bags needs the ros extra: pip install 'excite[ros]'"


def _ns(t: float) -> int:
    """A time in s as whole ns (header stamps and receive times)."""
    return int(round(t * 1e9))


class BagWriter:
    """A new ROS bag, written message by message with rosbags' writers.

    storage: "sqlite3" or "mcap" (rosbag2 version 9; ``path`` is the bag's directory, created
    with its parents) or "ros1" (``path`` is the ``.bag`` file; its directory must exist). The
    path must not exist. Messages are built with the storage's typestore (ROS 2, or ROS 1
    Noetic, whose Header has a seq): ``types`` maps type names to message classes, and
    `header`, `joint_state`, `pose`, `pose_stamped` build the common ones. Use it as a context
    manager; the bag is complete once it closes.

    Raises DataError (one line) without rosbags (naming the extra to install), for an unknown
    storage, or when the bag cannot be created.
    """

    def __init__(self, path: str | os.PathLike[str], storage: str = "sqlite3") -> None:
        if storage not in STORAGES:
            raise DataError(f"unknown bag storage {storage!r}; use one of {', '.join(STORAGES)}")
        try:
            from rosbags.rosbag1 import Writer as Writer1
            from rosbags.rosbag1 import WriterError as Writer1Error
            from rosbags.rosbag2 import StoragePlugin
            from rosbags.rosbag2 import Writer as Writer2
            from rosbags.rosbag2 import WriterError as Writer2Error
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise DataError(MISSING_WRITE_EXTRA) from None
        self.path = Path(path)
        self.ros1 = storage == "ros1"
        self.store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.LATEST)
        self.types: dict[str, Any] = self.store.types
        self._errors = (Writer1Error, Writer2Error, OSError)
        self._connections: dict[str, Any] = {}
        #: Messages written so far, by topic.
        self.written: dict[str, int] = {}
        try:
            if self.ros1:
                self._writer: Any = Writer1(self.path)
            else:
                plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
                self._writer = Writer2(self.path, version=9, storage_plugin=plugin)
        except self._errors as exc:
            raise DataError(f"{self.path}: cannot write the bag ({exc})") from None

    def __enter__(self) -> BagWriter:
        try:
            self._writer.open()
        except self._errors as exc:
            raise DataError(f"{self.path}: cannot write the bag ({exc})") from None
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._writer.close()

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Declare a topic and its message type (also when no message follows)."""
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(topic, msgtype,
                                                                   typestore=self.store)

    def write(self, topic: str, received: float, msg: Any) -> None:
        """Write a message on a topic (declared on first use) at receive time ``received``
        (s; the bag's timestamp, apart from the header stamp)."""
        self.add_topic(topic, msg.__msgtype__)
        serialize = self.store.serialize_ros1 if self.ros1 else self.store.serialize_cdr
        self._writer.write(self._connections[topic], _ns(received),
                           serialize(msg, msg.__msgtype__))
        self.written[topic] = self.written.get(topic, 0) + 1

    def header(self, t: float, frame_id: str = "") -> Any:
        """A std_msgs Header stamped ``t`` s (whole ns)."""
        sec, nanosec = divmod(_ns(t), 1_000_000_000)
        stamp = self.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        extra = {"seq": 0} if self.ros1 else {}
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id, **extra)

    def joint_state(self, t: float, names: list[str], positions: list[float]) -> Any:
        """A JointState stamped ``t`` s: joint ``names`` at ``positions`` (rad)."""
        empty = np.zeros(0)
        return self.types[JOINT_STATE](header=self.header(t), name=names,
                                       position=np.array(positions, dtype=float),
                                       velocity=empty, effort=empty)

    def pose(self, x: float, y: float, theta: float,
             quaternion: tuple[float, float, float, float] | None = None) -> Any:
        """A geometry_msgs Pose at (x, y, 0) m, turned by the yaw ``theta`` (rad), or by
        ``quaternion`` (x, y, z, w) as given (a received pose recorded unchanged)."""
        types = self.types
        qx, qy, qz, qw = quaternion or (0.0, 0.0, math.sin(0.5 * theta), math.cos(0.5 * theta))
        return types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))

    def twist_stamped(self, t: float, v: float, omega: float, frame_id: str = "") -> Any:
        """A geometry_msgs TwistStamped stamped ``t`` s: forward speed ``v`` (m/s) and turn
        rate ``omega`` (rad/s)."""
        vector = self.types["geometry_msgs/msg/Vector3"]
        twist = self.types["geometry_msgs/msg/Twist"](linear=vector(x=v, y=0.0, z=0.0),
                                                      angular=vector(x=0.0, y=0.0, z=omega))
        return self.types["geometry_msgs/msg/TwistStamped"](header=self.header(t, frame_id),
                                                            twist=twist)

    def pose_stamped(self, t: float, x: float, y: float, theta: float,
                     frame_id: str = WORLD_FRAME,
                     quaternion: tuple[float, float, float, float] | None = None) -> Any:
        """A PoseStamped stamped ``t`` s: `pose` (x, y, theta, or ``quaternion``) in
        ``frame_id``."""
        return self.types[POSE_STAMPED](header=self.header(t, frame_id),
                                        pose=self.pose(x, y, theta, quaternion))


def write_bag(
    path: str | os.PathLike[str],
    series: TimeSeries,
    storage: str = "sqlite3",
    joint_states: str = JOINT_STATES,
    left_wheel: str = LEFT_WHEEL,
    right_wheel: str = RIGHT_WHEEL,
    pose_topic: str = POSE_TOPIC,
) -> Path:
    """Write a time-series log as a new ROS bag that
    :func:`~excite.logs.bag_reader.read_bag` reads back.

    The encoder stream becomes JointState messages on ``joint_states`` (joints ``left_wheel``,
    ``right_wheel``, positions in rad), the pose stream PoseStamped messages on ``pose_topic``
    (frame ``WORLD_FRAME``, z = 0, the heading as a yaw quaternion). Header stamps are the
    sample times in whole ns (read back as ns * 1e-9 s), receive times equal the stamps, and
    messages are written in time order. storage: see :class:`BagWriter`. Returns the path to
    read: the bag directory (rosbag2) or file (ros1).

    Raises DataError (one line) for a sample time that is not positive (a zero stamp means
    "not set" in ROS), and as BagWriter does.
    """
    for stream, t in (("encoder", series.t_enc), ("pose", series.t_pose)):
        if t[0] <= 0:
            raise DataError(f"{series.location(stream, 0)}: a ROS header stamp must be "
                            "positive (zero means not set)")
    times = np.concatenate([series.t_enc, series.t_pose])
    order = np.argsort(times, kind="stable").tolist()
    n_enc = series.t_enc.size
    with BagWriter(path, storage) as bag:
        bag.add_topic(joint_states, JOINT_STATE)
        bag.add_topic(pose_topic, POSE_STAMPED)
        for i in order:
            if i < n_enc:
                t = float(series.t_enc[i])
                msg = bag.joint_state(t, [left_wheel, right_wheel],
                                      [series.phi_L[i], series.phi_R[i]])
                bag.write(joint_states, t, msg)
            else:
                k = i - n_enc
                t = float(series.t_pose[k])
                bag.write(pose_topic, t, bag.pose_stamped(t, series.x[k], series.y[k],
                                                          series.theta[k]))
    return bag.path
