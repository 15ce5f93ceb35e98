"""ROS bags: real bags written with the library's writer (rosbags' writers: rosbag2 sqlite3 and
mcap, ROS 1) from the simulated log of the time-series tests, read back with read_bag."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.typesys import get_types_from_msg  # noqa: E402

from excite import DataError  # noqa: E402
from excite.bags import (  # noqa: E402
    MISSING_EXTRA,
    MISSING_WRITE_EXTRA,
    STORAGES,
    BagWriter,
    is_bag_path,
    read_bag,
    write_bag,
)
from excite.timeseries import TimeSeries, segment_timeseries  # noqa: E402
from tests.test_timeseries import assert_same, make_log, simulate  # noqa: E402

LEFT, RIGHT = "wheel_left_joint", "wheel_right_joint"
BAG_STORAGES = ["sqlite3", "sqlite3-file", "mcap", "mcap-file", "ros1"]
TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"
Messages = Callable[[BagWriter], list[tuple[str, float, object]]]


@pytest.fixture(scope="module")
def log() -> TimeSeries:
    """12 s: 100 Hz wheel angles, 50 Hz sensor poses; the heading starts in (-pi, pi] and
    turns past pi, so the bag's wrapped yaw must be unwrapped."""
    ts = make_log(simulate(duration=12.0, step=0.01))
    theta = ts.theta + 1.6
    assert theta[0] < np.pi < theta.max()
    return TimeSeries(ts.t_enc, ts.phi_L, ts.phi_R, ts.t_pose, ts.x, ts.y, theta)


def pose_message(bag: BagWriter, kind: str, t: float, x: float, y: float, theta: float):
    """A pose message of one supported kind (pose, pose_cov, odom) in the map frame."""
    if kind == "pose":
        return bag.pose_stamped(t, x, y, theta)
    T, header, pose = bag.types, bag.header(t, "map"), bag.pose(x, y, theta)
    covariant = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
    if kind == "pose_cov":
        return T["geometry_msgs/msg/PoseWithCovarianceStamped"](header=header, pose=covariant)
    vector = T["geometry_msgs/msg/Vector3"]
    twist = T["geometry_msgs/msg/Twist"](linear=vector(x=0.0, y=0.0, z=0.0),
                                         angular=vector(x=0.0, y=0.0, z=0.0))
    return T["nav_msgs/msg/Odometry"](
        header=header, child_frame_id="lidar", pose=covariant,
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))


def transforms(bag: BagWriter, entries: list[tuple[float, str, str, float, float, float]]):
    """A TFMessage of (stamp, parent, child, x, y, yaw) transforms."""
    T = bag.types
    out = []
    for t, parent, child, x, y, theta in entries:
        out.append(T["geometry_msgs/msg/TransformStamped"](
            header=bag.header(t, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.1),
                rotation=bag.pose(x, y, theta).orientation)))
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


def log_messages(bag: BagWriter, ts: TimeSeries,
                 pose_kind: str) -> list[tuple[str, float, object]]:
    """(topic, receive time, message) in receive order: receive times lag the header stamps by
    4-7 ms; joints in varying order, with extra joints and messages lacking a wheel."""
    out: list[tuple[str, float, object]] = []
    for i, (t, left, right) in enumerate(zip(ts.t_enc, ts.phi_L, ts.phi_R, strict=True)):
        names, positions = ([LEFT, "caster", RIGHT], [left, 0.5, right]) if i % 2 else (
            [RIGHT, LEFT], [right, left])
        out.append(("/joint_states", t + 0.004 + 0.003 * (i % 3 == 0),
                    bag.joint_state(t, names, positions)))
        if i % 25 == 0:
            out.append(("/joint_states", t + 0.001, bag.joint_state(t + 0.001, ["arm"], [1.0])))
    frame = "/" if bag.ros1 else ""
    for t, x, y, theta in zip(ts.t_pose, ts.x, ts.y, ts.theta, strict=True):
        if pose_kind == "tf":
            message = transforms(bag, [(t, f"{frame}map", f"{frame}odom", 0.0, 0.0, 0.0),
                                       (t, f"{frame}odom", f"{frame}lidar", x, y, theta)])
            out.append(("/tf", t + 0.006, message))
        else:
            out.append(("/sensor_pose", t + 0.005, pose_message(bag, pose_kind, t, x, y, theta)))
    out.append(("/imu_like", ts.t_enc[0], bag.joint_state(ts.t_enc[0], ["unrelated"], [0.0])))
    return sorted(out, key=lambda item: item[1])


def bag_path(directory: Path, storage: str) -> Path:
    """Where a storage's bag lives once written (file storages: the file in the directory)."""
    if storage == "ros1":
        return directory / "log.bag"
    bag = directory / f"log_{storage.split('-')[0]}"
    if storage.endswith("-file"):
        return bag / f"{bag.name}.{'db3' if storage.startswith('sqlite3') else 'mcap'}"
    return bag


def make_bag(directory: Path, storage: str, messages: Messages,
             topics: dict[str, str] | None = None) -> Path:
    """A real bag of ``storage`` holding ``messages`` (and connections for ``topics``, topic:
    type, even without messages); returns the path to read."""
    ros1 = storage == "ros1"
    if ros1:
        directory.mkdir(parents=True, exist_ok=True)
    with BagWriter(directory / ("log.bag" if ros1 else f"log_{storage.split('-')[0]}"),
                   storage.split("-")[0]) as bag:
        if ros1:  # the noetic store lacks tf2_msgs: register its definition
            bag.store.register(get_types_from_msg(TF_MSG, "tf2_msgs/msg/TFMessage"))
        for topic, msgtype in (topics or {}).items():
            bag.add_topic(topic, msgtype)
        for topic, received, msg in messages(bag):
            bag.write(topic, received, msg)
    return bag_path(directory, storage)


def assert_same_log(ts: TimeSeries, expected: TimeSeries) -> None:
    """Equal to float precision: stamps to the ns they were written with."""
    np.testing.assert_allclose(ts.t_enc, expected.t_enc, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ts.t_pose, expected.t_pose, rtol=0, atol=1e-9)
    for name in ("phi_L", "phi_R", "x", "y"):
        np.testing.assert_array_equal(getattr(ts, name), getattr(expected, name), name)
    np.testing.assert_allclose(ts.theta, expected.theta, rtol=0, atol=1e-13)


@pytest.mark.parametrize("storage", BAG_STORAGES)
@pytest.mark.parametrize("pose_kind", ["pose", "pose_cov", "odom", "tf"])
def test_bags_read_back_the_simulated_log(tmp_path, log, storage, pose_kind):
    path = make_bag(tmp_path, storage, lambda bag: log_messages(bag, log, pose_kind))
    if pose_kind == "tf":
        ts = read_bag(path, LEFT, RIGHT, tf=("odom", "lidar"))
        assert ts.source == (f"{path} /joint_states", f"{path} /tf odom->lidar")
    else:
        ts = read_bag(path, LEFT, RIGHT, pose_topic="/sensor_pose")
        assert ts.source == (f"{path} /joint_states", f"{path} /sensor_pose")
    assert_same_log(ts, log)
    assert is_bag_path(path)


def test_a_bag_segments_like_its_csv(tmp_path, log):
    path = make_bag(tmp_path, "mcap", lambda bag: log_messages(bag, log, "odom"))
    from_bag = segment_timeseries(read_bag(path, LEFT, RIGHT, pose_topic="/sensor_pose"))
    from_memory = segment_timeseries(log)
    np.testing.assert_allclose(from_bag.segments.as_array(), from_memory.segments.as_array(),
                               rtol=0, atol=1e-12)


def test_stamps_not_receive_times_order_the_streams(tmp_path, log):
    """Messages received out of stamp order are put in stamp order."""
    def shuffled(bag: BagWriter):
        items = log_messages(bag, log, "pose")
        return [(topic, 5000.0 - received, msg) for topic, received, msg in items]
    ts = read_bag(make_bag(tmp_path, "sqlite3", shuffled), LEFT, RIGHT,
                  pose_topic="/sensor_pose")
    assert_same(ts, log, atol=1e-9)


# --------------------------------------------------------------------------- errors


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory, log) -> Path:
    directory = tmp_path_factory.mktemp("bags")
    return make_bag(directory, "sqlite3", lambda bag: log_messages(bag, log, "tf"))


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
    def nothing(bag: BagWriter):
        return []
    path = make_bag(tmp_path, storage, nothing,
                     topics={"/joint_states": "sensor_msgs/msg/JointState"} if with_topic else {})
    with pytest.raises(DataError) as info:
        read_bag(path, LEFT, RIGHT, pose_topic="/pose")
    assert one_line(info) == f"{path}: empty bag (no messages)"


def test_stream_errors(tmp_path, log):
    def short(bag: BagWriter):
        return [item for item in log_messages(bag, log, "pose")
                if item[0] != "/sensor_pose" or item[1] < log.t_pose[0] + 0.01]
    with pytest.raises(DataError, match=r"/sensor_pose: 1 pose sample\(s\); at least 2"):
        read_bag(make_bag(tmp_path / "a", "mcap", short), LEFT, RIGHT,
                 pose_topic="/sensor_pose")

    def repeated(bag: BagWriter):
        items = log_messages(bag, log, "pose")
        return items + [("/sensor_pose", 9999.0, bag.pose_stamped(log.t_pose[3], 0, 0, 0))]
    with pytest.raises(DataError, match=r"/sensor_pose at t = .* time does not increase"):
        read_bag(make_bag(tmp_path / "b", "mcap", repeated), LEFT, RIGHT,
                 pose_topic="/sensor_pose")

    def unstamped(bag: BagWriter):
        return log_messages(bag, log, "pose") + [
            ("/joint_states", 9999.0, bag.joint_state(0.0, [LEFT, RIGHT], [0.0, 0.0]))]
    with pytest.raises(DataError, match="/joint_states: header stamps of zero"):
        read_bag(make_bag(tmp_path / "c", "ros1", unstamped), LEFT, RIGHT,
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


# --------------------------------------------------------------------------- write_bag


@pytest.mark.parametrize("storage", STORAGES)
def test_write_bag_reads_back(tmp_path, log, storage):
    """JointState and PoseStamped with header stamps: the same log, theta to float precision
    (it goes through a quaternion)."""
    path = write_bag(tmp_path / ("log.bag" if storage == "ros1" else "log"), log,
                     storage=storage, joint_states="/wheels", left_wheel=LEFT,
                     right_wheel=RIGHT, pose_topic="/mocap")
    assert is_bag_path(path)
    assert_same_log(read_bag(path, LEFT, RIGHT, pose_topic="/mocap", joint_states="/wheels"),
                    log)


def test_write_bag_errors_are_one_line(tmp_path, log, monkeypatch):
    with pytest.raises(DataError, match="unknown bag storage 'zip'; use one of sqlite3, mcap"):
        write_bag(tmp_path / "a", log, storage="zip")
    (tmp_path / "b").mkdir()
    with pytest.raises(DataError) as info:
        write_bag(tmp_path / "b", log)
    assert one_line(info).startswith(f"{tmp_path / 'b'}: cannot write the bag (")
    early = TimeSeries(log.t_enc - log.t_enc[0], log.phi_L, log.phi_R, log.t_pose, log.x,
                       log.y, log.theta)
    with pytest.raises(DataError, match="a ROS header stamp must be positive"):
        write_bag(tmp_path / "c", early)
    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)
    with pytest.raises(DataError) as info:
        write_bag(tmp_path / "d", log)
    assert one_line(info) == MISSING_WRITE_EXTRA == (
        "writing bags needs the ros extra: pip install 'excite[ros]'")
    assert not (tmp_path / "c").exists() and not (tmp_path / "d").exists()
