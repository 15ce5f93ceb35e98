"""ROS bags: real bags written with rosbags' writers (rosbag2 sqlite3 and mcap, ROS 1) from the
simulated log of the time-series tests, read back with read_bag."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from excite import DataError  # noqa: E402
from excite.bags import MISSING_EXTRA, is_bag_path, read_bag  # noqa: E402
from excite.timeseries import TimeSeries, segment_timeseries  # noqa: E402
from tests.test_timeseries import assert_same, make_log, simulate  # noqa: E402

LEFT, RIGHT = "wheel_left_joint", "wheel_right_joint"
POSE_TYPE = {
    "pose": "geometry_msgs/msg/PoseStamped",
    "pose_cov": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "odom": "nav_msgs/msg/Odometry",
}
STORAGES = ["sqlite3", "sqlite3-file", "mcap", "mcap-file", "ros1"]
TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"


@pytest.fixture(scope="module")
def log() -> TimeSeries:
    """12 s: 100 Hz wheel angles, 50 Hz sensor poses; the heading starts in (-pi, pi] and
    turns past pi, so the bag's wrapped yaw must be unwrapped."""
    ts = make_log(simulate(duration=12.0, step=0.01))
    theta = ts.theta + 1.6
    assert theta[0] < np.pi < theta.max()
    return TimeSeries(ts.t_enc, ts.phi_L, ts.phi_R, ts.t_pose, ts.x, ts.y, theta)


class Messages:
    """Builds messages of one typestore (ROS 2 or ROS 1: the ROS 1 Header has a seq)."""

    def __init__(self, ros1: bool) -> None:
        self.store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
        if ros1:  # the noetic store lacks tf2_msgs: register its definition
            self.store.register(get_types_from_msg(TF_MSG, "tf2_msgs/msg/TFMessage"))
        self.ros1 = ros1
        self.types = self.store.types

    def serialize(self, msg) -> bytes:
        if self.ros1:
            return self.store.serialize_ros1(msg, msg.__msgtype__)
        return self.store.serialize_cdr(msg, msg.__msgtype__)

    def header(self, t: float, frame: str):
        ns = int(round(t * 1e9))
        stamp = self.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        extra = {"seq": 0} if self.ros1 else {}
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)

    def joints(self, t: float, names: list[str], positions: list[float]):
        empty = np.zeros(0)
        return self.types["sensor_msgs/msg/JointState"](
            header=self.header(t, ""), name=names, position=np.array(positions),
            velocity=empty, effort=empty)

    def pose(self, x: float, y: float, theta: float):
        T = self.types
        return T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.1),
            orientation=T["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2)))

    def pose_message(self, kind: str, t: float, x: float, y: float, theta: float):
        T, header, pose = self.types, self.header(t, "map"), self.pose(x, y, theta)
        covariant = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose,
                                                              covariance=np.zeros(36))
        if kind == "pose":
            return T["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)
        if kind == "pose_cov":
            return T["geometry_msgs/msg/PoseWithCovarianceStamped"](header=header,
                                                                    pose=covariant)
        vector = T["geometry_msgs/msg/Vector3"]
        twist = T["geometry_msgs/msg/Twist"](linear=vector(x=0.0, y=0.0, z=0.0),
                                             angular=vector(x=0.0, y=0.0, z=0.0))
        return T["nav_msgs/msg/Odometry"](
            header=header, child_frame_id="lidar", pose=covariant,
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist,
                                                             covariance=np.zeros(36)))

    def transforms(self, entries: list[tuple[float, str, str, float, float, float]]):
        T = self.types
        out = []
        for t, parent, child, x, y, theta in entries:
            q = self.pose(x, y, theta).orientation
            out.append(T["geometry_msgs/msg/TransformStamped"](
                header=self.header(t, parent), child_frame_id=child,
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.1), rotation=q)))
        return T["tf2_msgs/msg/TFMessage"](transforms=out)


def log_messages(m: Messages, ts: TimeSeries, pose_kind: str) -> list[tuple[str, float, object]]:
    """(topic, receive time, message) in receive order: receive times lag the header stamps by
    4-7 ms; joints in varying order, with extra joints and messages lacking a wheel."""
    out: list[tuple[str, float, object]] = []
    for i, (t, left, right) in enumerate(zip(ts.t_enc, ts.phi_L, ts.phi_R, strict=True)):
        names, positions = ([LEFT, "caster", RIGHT], [left, 0.5, right]) if i % 2 else (
            [RIGHT, LEFT], [right, left])
        out.append(("/joint_states", t + 0.004 + 0.003 * (i % 3 == 0), m.joints(t, names,
                                                                                  positions)))
        if i % 25 == 0:
            out.append(("/joint_states", t + 0.001, m.joints(t + 0.001, ["arm"], [1.0])))
    frame = "/" if m.ros1 else ""
    for t, x, y, theta in zip(ts.t_pose, ts.x, ts.y, ts.theta, strict=True):
        if pose_kind == "tf":
            message = m.transforms([(t, f"{frame}map", f"{frame}odom", 0.0, 0.0, 0.0),
                                    (t, f"{frame}odom", f"{frame}lidar", x, y, theta)])
            out.append(("/tf", t + 0.006, message))
        else:
            out.append(("/sensor_pose", t + 0.005, m.pose_message(pose_kind, t, x, y, theta)))
    out.append(("/imu_like", ts.t_enc[0], m.joints(ts.t_enc[0], ["unrelated"], [0.0])))
    return sorted(out, key=lambda item: item[1])


def bag_path(directory: Path, storage: str) -> Path:
    """Where a storage's bag lives once written (file storages: the file in the directory)."""
    if storage == "ros1":
        return directory / "log.bag"
    bag = directory / f"log_{storage.split('-')[0]}"
    if storage.endswith("-file"):
        return bag / f"{bag.name}.{'db3' if storage.startswith('sqlite3') else 'mcap'}"
    return bag


def write_bag(directory: Path, storage: str,
              messages: Callable[[Messages], list[tuple[str, float, object]]],
              topics: dict[str, str] | None = None) -> Path:
    """A real bag of ``storage`` holding ``messages`` (and connections for ``topics``, topic:
    type, even without messages); returns the path to read."""
    ros1 = storage == "ros1"
    m = Messages(ros1)
    items = messages(m)
    if ros1:
        directory.mkdir(parents=True, exist_ok=True)
        writer = Writer1(bag_path(directory, storage))
    else:
        plugin = StoragePlugin.MCAP if storage.startswith("mcap") else StoragePlugin.SQLITE3
        writer = Writer2(directory / f"log_{storage.split('-')[0]}", version=9,
                         storage_plugin=plugin)
    with writer:
        connections = {topic: writer.add_connection(topic, msgtype, typestore=m.store)
                       for topic, msgtype in (topics or {}).items()}
        for topic, _, msg in items:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__,
                                                           typestore=m.store)
        for topic, received, msg in items:
            writer.write(connections[topic], int(round(received * 1e9)), m.serialize(msg))
    return bag_path(directory, storage)


def assert_same_log(ts: TimeSeries, expected: TimeSeries) -> None:
    """Equal to float precision: stamps to the ns they were written with."""
    np.testing.assert_allclose(ts.t_enc, expected.t_enc, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ts.t_pose, expected.t_pose, rtol=0, atol=1e-9)
    for name in ("phi_L", "phi_R", "x", "y"):
        np.testing.assert_array_equal(getattr(ts, name), getattr(expected, name), name)
    np.testing.assert_allclose(ts.theta, expected.theta, rtol=0, atol=1e-13)


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("pose_kind", ["pose", "pose_cov", "odom", "tf"])
def test_bags_read_back_the_simulated_log(tmp_path, log, storage, pose_kind):
    path = write_bag(tmp_path, storage, lambda m: log_messages(m, log, pose_kind))
    if pose_kind == "tf":
        ts = read_bag(path, LEFT, RIGHT, tf=("odom", "lidar"))
        assert ts.source == (f"{path} /joint_states", f"{path} /tf odom->lidar")
    else:
        ts = read_bag(path, LEFT, RIGHT, pose_topic="/sensor_pose")
        assert ts.source == (f"{path} /joint_states", f"{path} /sensor_pose")
    assert_same_log(ts, log)
    assert is_bag_path(path)


def test_a_bag_segments_like_its_csv(tmp_path, log):
    path = write_bag(tmp_path, "mcap", lambda m: log_messages(m, log, "odom"))
    from_bag = segment_timeseries(read_bag(path, LEFT, RIGHT, pose_topic="/sensor_pose"))
    from_memory = segment_timeseries(log)
    np.testing.assert_allclose(from_bag.segments.as_array(), from_memory.segments.as_array(),
                               rtol=0, atol=1e-12)


def test_stamps_not_receive_times_order_the_streams(tmp_path, log):
    """Messages received out of stamp order are put in stamp order."""
    def shuffled(m: Messages):
        items = log_messages(m, log, "pose")
        return [(topic, 5000.0 - received, msg) for topic, received, msg in items]
    ts = read_bag(write_bag(tmp_path, "sqlite3", shuffled), LEFT, RIGHT,
                  pose_topic="/sensor_pose")
    assert_same(ts, log, atol=1e-9)


# --------------------------------------------------------------------------- errors


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory, log) -> Path:
    directory = tmp_path_factory.mktemp("bags")
    return write_bag(directory, "sqlite3", lambda m: log_messages(m, log, "tf"))


def one_line(error: pytest.ExceptionInfo) -> str:
    message = str(error.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(
    "kwargs, fragments",
    [
        (dict(pose_topic="/nope"),
         ["no topic /nope (poses); the bag has: /imu_like (sensor_msgs/msg/JointState), "
          "/joint_states (sensor_msgs/msg/JointState), /tf (tf2_msgs/msg/TFMessage)"]),
        (dict(tf=("odom", "lidar"), joint_states="/wheels"), ["no topic /wheels"]),
        (dict(pose_topic="/imu_like"),
         ["topic /imu_like has type sensor_msgs/msg/JointState, not supported for poses; "
          "supported: geometry_msgs/msg/PoseStamped, geometry_msgs/msg/"
          "PoseWithCovarianceStamped, nav_msgs/msg/Odometry"]),
        (dict(tf=("odom", "lidar"), joint_states="/tf"),
         ["topic /tf has type tf2_msgs/msg/TFMessage, not supported for wheel joint states"]),
        (dict(tf=("odom", "base_link")),
         ["/tf: no transform odom -> base_link; frame pairs present: map -> odom, "
          "odom -> lidar"]),
        (dict(tf=("odom", "lidar"), left_wheel="front_left"),
         ["/joint_states: no joint 'front_left'; joints present: arm, caster, "
          "wheel_left_joint, wheel_right_joint"]),
        (dict(tf=("odom", "lidar"), left_wheel="caster", right_wheel="arm"),
         ["no message has both joints 'caster' and 'arm'"]),
        (dict(), ["give exactly one pose source"]),
        (dict(pose_topic="/tf", tf=("odom", "lidar")), ["give exactly one pose source"]),
    ],
)
def test_bag_errors_are_one_line_and_list_what_is_there(good_bag, kwargs, fragments):
    arguments = dict(left_wheel=LEFT, right_wheel=RIGHT) | kwargs
    with pytest.raises(DataError) as info:
        read_bag(good_bag, **arguments)
    message = one_line(info)
    for fragment in fragments:
        assert fragment in message


@pytest.mark.parametrize("name", ["junk.bag", "junk.db3", "junk.mcap", "junk.txt", "folder"])
def test_not_a_bag(tmp_path, name):
    path = tmp_path / name
    if name == "folder":
        path.mkdir()
    else:
        path.write_text("t,phi_L,phi_R\n")
    with pytest.raises(DataError) as info:
        read_bag(path, LEFT, RIGHT, pose_topic="/pose")
    assert one_line(info).startswith(f"{path}: not a readable ROS bag (")


def test_missing_path(tmp_path):
    with pytest.raises(DataError, match="missing.bag: no such file or directory"):
        read_bag(tmp_path / "missing.bag", LEFT, RIGHT, pose_topic="/pose")


@pytest.mark.parametrize("storage", ["sqlite3", "mcap", "ros1"])
@pytest.mark.parametrize("with_topic", [False, True])
def test_empty_bag(tmp_path, storage, with_topic):
    def nothing(m: Messages):
        return []
    path = write_bag(tmp_path, storage, nothing,
                     topics={"/joint_states": "sensor_msgs/msg/JointState"} if with_topic else {})
    with pytest.raises(DataError) as info:
        read_bag(path, LEFT, RIGHT, pose_topic="/pose")
    assert one_line(info) == f"{path}: empty bag (no messages)"


def test_stream_errors(tmp_path, log):
    def short(m: Messages):
        return [item for item in log_messages(m, log, "pose")
                if item[0] != "/sensor_pose" or item[1] < log.t_pose[0] + 0.01]
    with pytest.raises(DataError, match=r"/sensor_pose: 1 pose sample\(s\); at least 2"):
        read_bag(write_bag(tmp_path / "a", "mcap", short), LEFT, RIGHT,
                 pose_topic="/sensor_pose")

    def repeated(m: Messages):
        items = log_messages(m, log, "pose")
        return items + [("/sensor_pose", 9999.0, m.pose_message("pose", log.t_pose[3], 0, 0, 0))]
    with pytest.raises(DataError, match=r"/sensor_pose at t = .* time does not increase"):
        read_bag(write_bag(tmp_path / "b", "mcap", repeated), LEFT, RIGHT,
                 pose_topic="/sensor_pose")

    def unstamped(m: Messages):
        return log_messages(m, log, "pose") + [
            ("/joint_states", 9999.0, m.joints(0.0, [LEFT, RIGHT], [0.0, 0.0]))]
    with pytest.raises(DataError, match="/joint_states: header stamps of zero"):
        read_bag(write_bag(tmp_path / "c", "ros1", unstamped), LEFT, RIGHT,
                 pose_topic="/sensor_pose")


def test_without_rosbags_the_error_names_the_extra(monkeypatch, good_bag):
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(DataError) as info:
        read_bag(good_bag, LEFT, RIGHT, tf=("odom", "lidar"))
    assert one_line(info) == MISSING_EXTRA == (
        "reading bags needs the ros extra: pip install 'excite[ros]'")


def test_is_bag_path(tmp_path, good_bag):
    assert is_bag_path(good_bag) and is_bag_path(tmp_path / "x.bag")
    assert is_bag_path(tmp_path / "x.MCAP") and is_bag_path(tmp_path / "x.db3")
    assert not is_bag_path(tmp_path / "log.csv") and not is_bag_path(tmp_path)
