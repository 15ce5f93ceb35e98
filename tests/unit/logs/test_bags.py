"""ROS bags: real bags written with the library's writer (rosbags' writers: rosbag2 sqlite3 and
mcap, ROS 1) from the simulated log of the time-series tests, read back with read_bag."""

from __future__ import annotations

import itertools
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.typesys import get_types_from_msg  # noqa: E402

from excite import DataError  # noqa: E402
from excite.logs.bag_paths import is_bag_path  # noqa: E402
from excite.logs.bag_reader import MISSING_EXTRA, read_bag, read_bag_log  # noqa: E402
from excite.logs.bag_writer import (  # noqa: E402
    MISSING_WRITE_EXTRA,
    STORAGES,
    BagWriter,
    write_bag,
)
from excite.logs.segmentation import segment_timeseries  # noqa: E402
from excite.logs.timeseries import TimeSeries  # noqa: E402
from tests.conftest import assert_one_line_error, run_cli  # noqa: E402
from tests.unit.logs.test_timeseries import assert_same, make_log, simulate  # noqa: E402

LEFT, RIGHT = "wheel_left_joint", "wheel_right_joint"
BAG_STORAGES = ["sqlite3", "sqlite3-file", "mcap", "mcap-file", "ros1"]
POSE_KINDS = ["pose", "pose_cov", "odom", "tf"]
TF_MSG = "geometry_msgs/TransformStamped[] transforms\n"
Messages = Callable[[BagWriter], list[tuple[str, float, object]]]
#: A pose sample's orientation quaternion (x, y, z, w), from its index and heading (rad).
Orientation = Callable[[int, float], tuple[float, float, float, float]]


def slow_but(fast: set[tuple[str, ...]], *axes: list[str]) -> list:
    """Every combination of the values of ``axes`` (its id: the values joined by "-"), marked
    slow but the ``fast`` ones: a few that between them take every value of every axis."""
    return [pytest.param(*combo, id="-".join(combo),
                         marks=() if combo in fast else pytest.mark.slow)
            for combo in itertools.product(*axes)]


@pytest.fixture(scope="module")
def log() -> TimeSeries:
    """12 s: 100 Hz wheel angles, 50 Hz sensor poses; the heading starts in (-pi, pi] and
    turns past pi, so the bag's wrapped yaw must be unwrapped."""
    ts = make_log(simulate(duration=12.0, step=0.01))
    theta = ts.theta + 1.6
    assert theta[0] < np.pi < theta.max()
    return TimeSeries(ts.t_enc, ts.phi_L, ts.phi_R, ts.t_pose, ts.x, ts.y, theta)


def oriented(bag: BagWriter, x: float, y: float, theta: float,
             q: tuple[float, float, float, float] | None = None):
    """bag.pose(x, y, theta), its orientation replaced by the quaternion ``q`` if given."""
    pose = bag.pose(x, y, theta)
    if q is not None:
        pose.orientation = bag.types["geometry_msgs/msg/Quaternion"](
            x=q[0], y=q[1], z=q[2], w=q[3])
    return pose


def pose_message(bag: BagWriter, kind: str, t: float, x: float, y: float, theta: float,
                 q: tuple[float, float, float, float] | None = None):
    """A pose message of one supported kind (pose, pose_cov, odom) in the map frame, oriented
    by the yaw ``theta`` or by the quaternion ``q``."""
    T, header, pose = bag.types, bag.header(t, "map"), oriented(bag, x, y, theta, q)
    if kind == "pose":
        return T["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)
    covariant = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
    if kind == "pose_cov":
        return T["geometry_msgs/msg/PoseWithCovarianceStamped"](header=header, pose=covariant)
    vector = T["geometry_msgs/msg/Vector3"]
    twist = T["geometry_msgs/msg/Twist"](linear=vector(x=0.0, y=0.0, z=0.0),
                                         angular=vector(x=0.0, y=0.0, z=0.0))
    return T["nav_msgs/msg/Odometry"](
        header=header, child_frame_id="lidar", pose=covariant,
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))


def transforms(bag: BagWriter, entries: list[tuple[float, str, str, float, float, float]],
               q: tuple[float, float, float, float] | None = None):
    """A TFMessage of (stamp, parent, child, x, y, yaw) transforms; the last one oriented by
    the quaternion ``q`` if given."""
    T = bag.types
    out = []
    for k, (t, parent, child, x, y, theta) in enumerate(entries):
        last = k == len(entries) - 1
        out.append(T["geometry_msgs/msg/TransformStamped"](
            header=bag.header(t, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.1),
                rotation=oriented(bag, x, y, theta, q if last else None).orientation)))
    return T["tf2_msgs/msg/TFMessage"](transforms=out)


def log_messages(bag: BagWriter, ts: TimeSeries, pose_kind: str,
                 orientation: Orientation | None = None) -> list[tuple[str, float, object]]:
    """(topic, receive time, message) in receive order: receive times lag the header stamps by
    4-7 ms; joints in varying order, with extra joints and messages lacking a wheel. Poses are
    oriented by their heading, or by ``orientation`` if given."""
    out: list[tuple[str, float, object]] = []
    for i, (t, left, right) in enumerate(zip(ts.t_enc, ts.phi_L, ts.phi_R, strict=True)):
        names, positions = ([LEFT, "caster", RIGHT], [left, 0.5, right]) if i % 2 else (
            [RIGHT, LEFT], [right, left])
        out.append(("/joint_states", t + 0.004 + 0.003 * (i % 3 == 0),
                    bag.joint_state(t, names, positions)))
        if i % 25 == 0:
            out.append(("/joint_states", t + 0.001, bag.joint_state(t + 0.001, ["arm"], [1.0])))
    frame = "/" if bag.ros1 else ""
    for j, (t, x, y, theta) in enumerate(zip(ts.t_pose, ts.x, ts.y, ts.theta, strict=True)):
        q = None if orientation is None else orientation(j, theta)
        if pose_kind == "tf":
            message = transforms(bag, [(t, f"{frame}map", f"{frame}odom", 0.0, 0.0, 0.0),
                                       (t, f"{frame}odom", f"{frame}lidar", x, y, theta)], q)
            out.append(("/tf", t + 0.006, message))
        else:
            out.append(("/sensor_pose", t + 0.005,
                        pose_message(bag, pose_kind, t, x, y, theta, q)))
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


@pytest.mark.parametrize("pose_kind, storage", slow_but(
    {("pose", "sqlite3"), ("pose_cov", "mcap"), ("odom", "ros1"), ("tf", "sqlite3-file"),
     ("tf", "mcap-file")}, POSE_KINDS, BAG_STORAGES))
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

    def no_poses(bag: BagWriter):
        return [item for item in log_messages(bag, log, "pose") if item[0] != "/sensor_pose"]
    with pytest.raises(DataError, match=r"/sensor_pose: 0 pose sample\(s\); at least 2"):
        read_bag(make_bag(tmp_path / "e", "sqlite3", no_poses,
                          topics={"/sensor_pose": "geometry_msgs/msg/PoseStamped"}),
                 LEFT, RIGHT, pose_topic="/sensor_pose")

    def repeated(bag: BagWriter):
        items = log_messages(bag, log, "pose")
        return items + [("/sensor_pose", 9999.0, bag.pose_stamped(log.t_pose[3], 0, 0, 0))]
    with pytest.raises(DataError) as info:
        read_bag(make_bag(tmp_path / "b", "mcap", repeated), LEFT, RIGHT,
                 pose_topic="/sensor_pose")
    assert one_line(info).endswith(f"/sensor_pose at t = {log.t_pose[3]:.6f} s: two messages "
                                   "with this header stamp and different values (two "
                                   "publishers, or two bodies, on one topic?)")

    def unstamped(bag: BagWriter):
        return log_messages(bag, log, "pose") + [
            ("/joint_states", 9999.0, bag.joint_state(0.0, [LEFT, RIGHT], [0.0, 0.0]))]
    with pytest.raises(DataError) as info:
        read_bag(make_bag(tmp_path / "c", "ros1", unstamped), LEFT, RIGHT,
                 pose_topic="/sensor_pose")
    n = log.t_enc.size + 1
    assert one_line(info).endswith(
        f"/joint_states: a header stamp of zero (not set) after stamped messages (message {n} "
        f"of {n}, received after the one stamped {log.t_enc[-1]:.6f} s)")



def test_without_rosbags_the_error_names_the_extra(monkeypatch, good_bag):
    monkeypatch.setitem(sys.modules, "rosbags.rosbag1", None)
    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)
    with pytest.raises(DataError) as info:
        read_bag(good_bag, LEFT, RIGHT, tf=("odom", "lidar"))
    assert one_line(info) == MISSING_EXTRA == (
        "reading bags needs the ros extra: pip install 'excite[ros]'")


@pytest.mark.parametrize("storage", slow_but({("sqlite3",), ("ros1",)},
                                              ["sqlite3", "mcap", "ros1"]))
def test_unused_topics_with_unreadable_definitions_do_not_matter(tmp_path, log, storage):
    """A bag whose unused topics carry definitions rosbags cannot use (a rosserial bridge's
    empty one, a stale custom type's wrong hash) reads like the clean bag: only the
    definitions of the topics read are used (rosbags' AnyReader refused the whole bag)."""
    def messages(bag: BagWriter):
        ros1 = bag.ros1
        for topic, msgtype, definition, digest in [
                ("/arduino/status", "std_msgs/msg/Int8", "", "27ffa0c9c4b8fb8492252bcad9e5c57b"),
                ("/custom", "my_msgs/msg/Foo", "float64 a\n", "0" * 32)]:
            key = {"md5sum": digest} if ros1 else {"rihs01": "RIHS01_" + "0" * 64}
            connection = bag._writer.add_connection(topic, msgtype, msgdef=definition, **key)
            bag._writer.write(connection, 1, bytes(8) if ros1 else bytes([0, 1, 0, 0]) + bytes(8))
        return log_messages(bag, log, "pose")
    clean = read_bag(make_bag(tmp_path / "clean", storage, lambda bag: log_messages(bag, log,
                                                                                   "pose")),
                     LEFT, RIGHT, pose_topic="/sensor_pose")
    assert_same_log(read_bag(make_bag(tmp_path / "odd", storage, messages), LEFT, RIGHT,
                             pose_topic="/sensor_pose"), clean)


def test_one_pose_topic_may_carry_two_supported_types(tmp_path, log):
    """Two publishers of /sensor_pose, one PoseStamped and one PoseWithCovarianceStamped (a
    relay), alternating: every sample is read."""
    def messages(bag: BagWriter):
        kinds = {}
        for kind, msgtype in (("pose", "geometry_msgs/msg/PoseStamped"),
                              ("pose_cov", "geometry_msgs/msg/PoseWithCovarianceStamped")):
            kinds[kind] = bag._writer.add_connection("/sensor_pose", msgtype,
                                                     typestore=bag.store, callerid=f"/{kind}")
        items = [item for item in log_messages(bag, log, "pose") if item[0] != "/sensor_pose"]
        for j, (t, x, y, theta) in enumerate(zip(log.t_pose, log.x, log.y, log.theta,
                                                 strict=True)):
            kind = "pose" if j % 2 else "pose_cov"
            msg = pose_message(bag, kind, t, x, y, theta)
            bag._writer.write(kinds[kind], int(t * 1e9) + 5_000_000,
                              bag.store.serialize_ros1(msg, msg.__msgtype__))
        return items
    assert_same_log(read_bag(make_bag(tmp_path, "ros1", messages), LEFT, RIGHT,
                             pose_topic="/sensor_pose"), log)


def test_parts_of_bags_are_named_with_the_way_out(tmp_path, capsys, good_bag):
    """Paths a user hands over from a bag that excite cannot open as given: one line saying
    what it is and what to do."""
    active = tmp_path / "run.bag.active"
    active.write_bytes(b"#ROSBAG V2.0\n\x00")
    killed = tmp_path / "killed"
    killed.mkdir()
    (killed / "killed_0.mcap").write_bytes(b"\x89MCAP0\r\n")
    compressed = tmp_path / "zipped" / "zipped_0.db3.zstd"
    compressed.parent.mkdir()
    compressed.write_bytes(b"\x28\xb5\x2f\xfd")
    cases = [(active, "an unfinished ROS 1 recording (.bag.active); `rosbag reindex"),
             (killed, "a rosbag2 directory without metadata.yaml (a recording stopped "
                      f"without closing it?); `ros2 bag reindex {killed}` writes it"),
             (good_bag / "metadata.yaml", f"the metadata of a rosbag2 bag; give the bag's "
                                          f"directory {good_bag}"),
             (compressed, f"a compressed file of a rosbag2 bag; give the bag's directory "
                          f"{compressed.parent}")]
    for path, fragment in cases:
        assert is_bag_path(path)
        with pytest.raises(DataError) as info:
            read_bag(path, LEFT, RIGHT, pose_topic="/pose")
        assert one_line(info).startswith(f"{path}: {fragment}")
        assert_one_line_error(*run_cli(capsys, "calibrate", path)[::2], f"{path}: {fragment}")


def test_an_mcap_of_ros1_messages_is_named():
    from excite.logs.bag_reader import _why

    assert "ROS 1 messages" in _why(KeyError("ros1msg"))
    assert _why(KeyError("")) == "KeyError ''"


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


# --------------------------------------------------------------------------- real publishers


def pose_source(pose_kind: str) -> dict[str, object]:
    """read_bag's pose source for the messages of log_messages(..., pose_kind)."""
    return dict(tf=("odom", "lidar")) if pose_kind == "tf" else dict(pose_topic="/sensor_pose")


def zyx(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll) (rad)."""
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    return (cy * cp * sr - sy * sp * cr, cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr, cy * cp * cr + sy * sp * sr)


def unset(bag: BagWriter, msg):
    """The message with its header stamp zero (not set)."""
    msg.header = bag.header(0.0, msg.header.frame_id)
    return msg


def velocity_only(bag: BagWriter, t: float):
    """A JointState naming both wheels with velocities only (an empty position array)."""
    msg = bag.joint_state(t, [LEFT, RIGHT], [])
    msg.velocity = np.array([1.0, -1.0])
    return msg


def wheel_indices(items: list[tuple[str, float, object]]) -> dict[int, int]:
    """{position in items: index of the encoder sample} of the messages carrying both
    wheels."""
    wheels = [k for k, (topic, _, msg) in enumerate(items)
              if topic == "/joint_states" and LEFT in msg.name and RIGHT in msg.name]
    return {k: i for i, k in enumerate(wheels)}


def part_of(ts: TimeSeries, encoders: np.ndarray | slice = slice(None),
            poses: np.ndarray | slice = slice(None)) -> TimeSeries:
    """The log with only some samples of each stream."""
    return TimeSeries(ts.t_enc[encoders], ts.phi_L[encoders], ts.phi_R[encoders],
                      ts.t_pose[poses], ts.x[poses], ts.y[poses], ts.theta[poses])


@pytest.mark.parametrize("pose_kind", slow_but({("pose",), ("tf",)}, POSE_KINDS))
def test_the_heading_does_not_depend_on_the_quaternion_length(tmp_path, log, pose_kind):
    """Publishers that do not normalise: |q| from 0.5 to 3 and either sign give the heading
    to float precision (1 - 2(y^2 + z^2) would read |q| = 1.02 as another angle)."""
    scales = [1.02, -0.5, 3.0, -1.0, 0.97]

    def scaled(j: int, theta: float) -> tuple[float, float, float, float]:
        return tuple(scales[j % len(scales)] * c for c in zyx(theta))
    path = make_bag(tmp_path, "sqlite3", lambda bag: log_messages(bag, log, pose_kind, scaled))
    assert_same_log(read_bag(path, LEFT, RIGHT, **pose_source(pose_kind)), log)


@pytest.mark.parametrize("tilt, pose_kind", slow_but(
    {("ramp", "pose_cov"), ("43 degrees", "tf")}, ["ramp", "43 degrees"], POSE_KINDS))
def test_roll_and_pitch_below_the_limit_keep_the_heading(tmp_path, log, pose_kind, tilt):
    """A ramp (roll and pitch up to 0.05 rad, varying) or a constant 43 degree roll: the
    heading read is the ZYX yaw, exactly."""
    def tilted(j: int, theta: float) -> tuple[float, float, float, float]:
        if tilt == "ramp":
            return zyx(theta, 0.05 * np.cos(0.02 * j), 0.05 * np.sin(0.03 * j))
        return zyx(theta, 0.0, np.radians(43.0))
    path = make_bag(tmp_path, "mcap", lambda bag: log_messages(bag, log, pose_kind, tilted))
    assert_same_log(read_bag(path, LEFT, RIGHT, **pose_source(pose_kind)), log)


def rolled(j: int, theta: float) -> tuple[float, float, float, float]:
    """47 degrees of roll in the 101st sample, 40 in the 201st to 300th (one message over the
    limit is enough)."""
    degrees = 47.0 if j == 100 else 40.0 if 200 <= j < 300 else 0.0
    return zyx(theta, 0.0, np.radians(degrees))


@pytest.mark.parametrize("pose_kind", slow_but({("tf",)}, ["pose", "pose_cov", "odom", "tf"]))
def test_a_tilted_pose_is_refused_naming_the_largest_tilt(tmp_path, log, pose_kind):
    """The body z axis more than 45 degrees from the world z axis: a roll of 47 degrees in
    one message (a Y-up world is turned Z-up: test_bag_stamps.py)."""
    path = make_bag(tmp_path, "ros1" if pose_kind == "tf" else "sqlite3",
                    lambda bag: log_messages(bag, log, pose_kind, rolled))
    with pytest.raises(DataError) as info:
        read_bag(path, LEFT, RIGHT, **pose_source(pose_kind))
    message = one_line(info)
    tilts = np.zeros(log.t_pose.size)
    tilts[100] = 47.0
    j = int(np.argmax(tilts))
    topic = "/tf" if pose_kind == "tf" else "/sensor_pose"
    assert message.startswith(f"{path} {topic} at t = {log.t_pose[j]:.6f} s: the pose's z axis "
                              f"is tilted {tilts[j]:.1f} degrees from the world z axis")
    assert "a Y-up frame? Motion capture systems often stream Y-up; convert the poses to Z-up" \
        in message


@pytest.mark.parametrize("bad", [
    pytest.param((1e-4, 0.0, 0.0, 0.0), id="short"),
    pytest.param((0.0, 0.0, np.inf, 1.0), id="infinite", marks=pytest.mark.slow)])
def test_an_orientation_that_is_no_rotation_is_named(tmp_path, log, bad):
    """Almost zero, or infinite (NaN and all zeros are poses not measured: skipped)."""
    def broken(j: int, theta: float) -> tuple[float, float, float, float]:
        return bad if j == 7 else zyx(theta)
    path = make_bag(tmp_path, "mcap", lambda bag: log_messages(bag, log, "odom", broken))
    with pytest.raises(DataError) as info:
        read_bag(path, LEFT, RIGHT, pose_topic="/sensor_pose")
    assert one_line(info) == (
        f"{path} /sensor_pose at t = {log.t_pose[7]:.6f} s: the orientation quaternion "
        f"(x, y, z, w) = {tuple(float(c) for c in bad)} is not a rotation (zero length or not "
        "finite)")


def test_joint_states_without_positions_are_skipped_and_counted(tmp_path, log):
    """A velocity-only publisher on the topic (extra messages), and some messages of the
    wheels' own publisher without positions: the samples with positions are read, the rest
    counted."""
    def mixed(bag: BagWriter):
        items = log_messages(bag, log, "pose")
        sample = wheel_indices(items)
        out = []
        for k, (topic, received, msg) in enumerate(items):
            i = sample.get(k)
            if i is not None and i % 7 == 3:
                msg = velocity_only(bag, log.t_enc[i])
            out.append((topic, received, msg))
            if i is not None and i % 10 == 0:
                out.append((topic, received + 0.002, velocity_only(bag, log.t_enc[i] + 0.002)))
        return out
    bag = read_bag_log(make_bag(tmp_path, "sqlite3", mixed), LEFT, RIGHT,
                       pose_topic="/sensor_pose")
    index = np.arange(log.t_enc.size)
    assert_same_log(bag.series, part_of(log, encoders=index % 7 != 3))
    n = np.sum(index % 7 == 3) + np.sum(index % 10 == 0)
    assert bag.skipped == {"/joint_states without wheel positions": n}
    assert bag.skipped_text() == f"{n} /joint_states without wheel positions"


def with_velocities(bag: BagWriter, log: TimeSeries, change) -> list:
    """The log's messages, each JointState of the wheels carrying the log's wheel speeds
    (central differences of its angles, rad/s) as its velocity; ``change(i, msg, order)``
    then sets the i-th one's positions (and may spoil its velocity; order: the wheels'
    indices in it)."""
    speeds = (np.gradient(log.phi_L, log.t_enc), np.gradient(log.phi_R, log.t_enc))
    out, i = [], 0
    for topic, received, msg in log_messages(bag, log, "pose"):
        if topic == "/joint_states" and LEFT in msg.name:
            order = [msg.name.index(LEFT), msg.name.index(RIGHT)]
            msg.velocity = np.zeros(len(msg.name))
            msg.velocity[order] = speeds[0][i], speeds[1][i]
            change(i, msg, order)
            i += 1
        out.append((topic, received, msg))
    return out


@pytest.mark.parametrize("positions", ["empty", "nan"])
def test_joint_states_with_velocities_only_are_integrated(tmp_path, log, positions):
    """A driver with velocity state interfaces only: JointState messages with the wheels'
    velocities (rad/s) and no positions (an empty array, or NaN as joint_state_broadcaster
    fills them). Their trapezoidal integral is read as the wheel angles, with a note, and
    segments like the angles it was differentiated from."""
    def no_positions(i, msg, order):
        msg.position = (np.zeros(0) if positions == "empty"
                        else np.full(len(msg.name), np.nan))

    bag = read_bag_log(make_bag(tmp_path, "mcap",
                                lambda bag: with_velocities(bag, log, no_positions)),
                       LEFT, RIGHT, pose_topic="/sensor_pose")
    assert bag.skipped == {}
    assert any("wheel speeds (rad/s) integrated into angles by the trapezoidal rule" in note
               for note in bag.notes)
    assert bag.series.speeds  # integrated speeds (excite.logs.speed_lag)
    read, angles = segment_timeseries(bag.series).segments, segment_timeseries(log).segments
    assert len(read) == len(angles)
    # the integral of central differences: within a small part of each increment
    np.testing.assert_allclose(read.dphi_L, angles.dphi_L, rtol=0, atol=2e-3)
    np.testing.assert_allclose(read.dphi_R, angles.dphi_R, rtol=0, atol=2e-3)
    np.testing.assert_allclose(read.dx, angles.dx, rtol=0, atol=1e-12)


def test_a_start_up_s_positions_and_values_not_finite_beside_velocities(tmp_path, log):
    """A velocity-only driver whose first messages carry zero positions (a start-up's, or
    joint_state_publisher's beside it) and NaN velocities before its first reading, and a
    NaN now and then: the velocities are read, integrated, and every message left out is
    counted (both refused the bag, or left no encoder sample)."""
    def start_up(i, msg, order):
        if i < 5 or i % 97 == 50:
            msg.velocity[order[0]] = np.nan
        msg.position = np.zeros(len(msg.name) if i < 3 else 0)

    bag = read_bag_log(make_bag(tmp_path, "sqlite3",
                                lambda bag: with_velocities(bag, log, start_up)),
                       LEFT, RIGHT, pose_topic="/sensor_pose")
    nan = sum(1 for i in range(3, log.t_enc.size) if i < 5 or i % 97 == 50)  # 0-2: positions
    assert bag.skipped == {
        "/joint_states with a wheel value not finite (NaN before the hardware's first "
        "reading?)": nan,
        "/joint_states with wheel positions, fewer than those with velocities only (a "
        "start-up's or another publisher's), which are read": 3}
    read, angles = segment_timeseries(bag.series).segments, segment_timeseries(log).segments
    assert abs(len(read) - len(angles)) <= 1  # the first 5 samples are not read
    assert np.all(np.isfinite(bag.series.phi_L))


def test_joint_states_never_with_positions_or_malformed(tmp_path, log):
    def no_state(bag: BagWriter):
        return [(topic, received, bag.joint_state(msg.header.stamp.sec
                                                  + 1e-9 * msg.header.stamp.nanosec,
                                                  [LEFT, RIGHT], []))
                if topic == "/joint_states" and LEFT in msg.name else (topic, received, msg)
                for topic, received, msg in log_messages(bag, log, "pose")]
    with pytest.raises(DataError) as info:
        read_bag(make_bag(tmp_path / "a", "mcap", no_state), LEFT, RIGHT,
                 pose_topic="/sensor_pose")
    assert one_line(info).endswith(
        f"/joint_states: no message has positions for the joints {LEFT!r} and {RIGHT!r} "
        f"({log.t_enc.size} name them with an empty position array: velocity or effort only)")

    def short(bag: BagWriter):
        items = log_messages(bag, log, "pose")
        k = next(k for k, i in wheel_indices(items).items() if i == 5)
        items[k] = ("/joint_states", items[k][1], bag.joint_state(log.t_enc[5], [LEFT, RIGHT],
                                                                 [1.0]))
        return items
    with pytest.raises(DataError) as info:
        read_bag(make_bag(tmp_path / "b", "sqlite3", short), LEFT, RIGHT,
                 pose_topic="/sensor_pose")
    assert one_line(info).endswith(f"/joint_states at t = {log.t_enc[5]:.6f} s: 1 positions "
                                   "for 2 joint names")


@pytest.mark.parametrize("topic, storage", slow_but(
    {("/joint_states", "sqlite3"), ("/sensor_pose", "ros1")}, ["/joint_states", "/sensor_pose"],
    ["sqlite3", "ros1"]))
def test_leading_unstamped_messages_are_skipped_and_counted(tmp_path, log, storage, topic):
    """The first 3 messages of a topic stamped zero (published before the clock ran, e.g.
    before /clock in simulation)."""
    def early(bag: BagWriter):
        items = log_messages(bag, log, "pose")
        first = ([k for k in wheel_indices(items)] if topic == "/joint_states" else
                 [k for k, item in enumerate(items) if item[0] == topic])[:3]
        return [(t, received, unset(bag, msg) if k in first else msg)
                for k, (t, received, msg) in enumerate(items)]
    bag = read_bag_log(make_bag(tmp_path, storage, early), LEFT, RIGHT,
                       pose_topic="/sensor_pose")
    rest = slice(3, None)
    expected = (part_of(log, encoders=rest) if topic == "/joint_states" else
                part_of(log, poses=rest))
    assert_same_log(bag.series, expected)
    assert bag.skipped == {f"{topic} stamped 0 before the first stamped message": 3}


@pytest.mark.parametrize("pose_kind", ["odom", "tf"])
def test_repeated_messages_are_skipped_and_counted(tmp_path, log, pose_kind):
    """A republished message (same stamp, same values, received later) is read once."""
    repeats: dict[str, int] = {}

    def republished(bag: BagWriter):
        items = log_messages(bag, log, pose_kind)
        again = []
        for k, (topic, received, msg) in enumerate(items):
            if k % 40 == 9 and topic != "/imu_like":
                again.append((topic, received + 0.0021, msg))
                if topic != "/joint_states" or (LEFT in msg.name and RIGHT in msg.name):
                    repeats[topic] = repeats.get(topic, 0) + 1
        return sorted(items + again, key=lambda item: item[1])
    bag = read_bag_log(make_bag(tmp_path, "mcap", republished), LEFT, RIGHT,
                       **pose_source(pose_kind))
    assert_same_log(bag.series, log)
    assert bag.skipped == {f"{topic} repeated (same stamp, same values)": n
                           for topic, n in repeats.items()}
    assert all(repeats.values())


def test_the_cli_reports_skipped_messages_and_refuses_a_tilted_pose(tmp_path, log, capsys):
    def early(bag: BagWriter):
        items = log_messages(bag, log, "pose")
        first = list(wheel_indices(items))[:2]
        return [(t, received, unset(bag, msg) if k in first else msg)
                for k, (t, received, msg) in enumerate(items)]
    options = ["--left-wheel", LEFT, "--right-wheel", RIGHT, "--pose-topic", "/sensor_pose"]
    path = make_bag(tmp_path / "a", "sqlite3", early)
    code, out, _ = run_cli(capsys, "segment", path, *options, "--out", tmp_path / "s.csv")
    assert code == 0
    assert "; messages skipped: 2 /joint_states stamped 0 before the first stamped message; " \
        "time offset" in out
    path = make_bag(tmp_path / "b", "sqlite3",
                    lambda bag: log_messages(bag, log, "pose", rolled))
    code, _, err = run_cli(capsys, "calibrate", path, *options)
    assert_one_line_error(code, err, f"{path} /sensor_pose at t = ", "Y-up")
