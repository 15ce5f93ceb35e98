"""The times of bag streams: clock steps against receive times, streams without stamps, and
poses not measured; the steps found on arrays, then real bags written with rosbags and read
back."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.typesys import get_types_from_msg  # noqa: E402

from excite import DataError  # noqa: E402
from excite.logs.bag_reader import read_bag_log  # noqa: E402
from excite.logs.bag_stamps import receive_time_steps, stamped_table  # noqa: E402
from excite.logs.bag_writer import BagWriter  # noqa: E402
from excite.logs.segmentation import segment_timeseries  # noqa: E402
from tests.unit.logs.test_bags import (  # noqa: E402
    LEFT,
    RIGHT,
    TF_MSG,
    assert_same_log,
    log_messages,
    make_bag,
    part_of,
    unset,
)
from tests.unit.logs.test_bags import log as log  # noqa: E402, F401  (the fixture)

PERIOD = 0.02


def receive_times(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, receive times) of n messages at 50 Hz: the recorder gets each 3-9 ms after
    its stamp (a transport latency with jitter)."""
    stamps = 100.0 + PERIOD * np.arange(n)
    return stamps, stamps + np.random.default_rng(seed).uniform(0.003, 0.009, n)


@pytest.mark.parametrize("step", [0.3, 5.0, -2.0, -2.005, -0.08])
@pytest.mark.parametrize("rate", [1.0, 0.8])
def test_a_clock_step_is_found_with_its_size(step, rate):
    """A publisher's clock set while recording (NTP): the stamps after message 300 jump,
    the receive times do not; also when the stamps are a simulation's clock running at 0.8
    of the recorder's (sim time against wall time: a step was missed or 13 ms off)."""
    stamps, received = receive_times(600)
    received = 100.0 + (received - 100.0) / rate
    stamps[300:] += step
    (index, found), = receive_time_steps(stamps, received)
    assert index == 299 and found == pytest.approx(step, abs=0.003)


def test_what_is_no_clock_step():
    """A late message, a recorder that stalls and then receives a burst, the recorder's own
    clock stepping, a simulation's clock slower than the recorder's (stamps drift against
    receive times), a short stream: none is a step of the stamps."""
    stamps, received = receive_times(600)
    late = received.copy()
    late[200] += 0.4
    stalled = received.copy()
    stalled[300:400] = np.maximum(received[300:400], received[399])  # 2 s stall, then a burst
    recorder = received.copy()
    recorder[300:] -= 3.0
    for times in (late, stalled, recorder, 100.0 + PERIOD / 0.7 * np.arange(600),
                  100.0 + PERIOD / 0.15 * np.arange(600)):
        assert receive_time_steps(stamps, times) == []
    assert receive_time_steps(stamps[:40], received[:40] + np.r_[np.zeros(20), np.ones(20)]) == []


def test_stamped_table_corrects_a_step_and_uses_receive_times_without_stamps():
    stamps, received = receive_times(600)
    values = np.arange(600.0)
    stepped = stamps.copy()
    stepped[300:] -= 2.0  # back: without the correction, later stamps repeat earlier ones
    table = stamped_table("/js", np.column_stack([stepped, values]), received)
    np.testing.assert_allclose(table.rows[:, 0], stamps, atol=0.003)
    np.testing.assert_array_equal(table.rows[:, 1], values)
    step = stepped[300] - table.rows[300, 0]  # as found: -2 s to the latency's jitter
    assert table.notes == [f"/js at t = {stamps[299]:.6f} s: the header stamps step by "
                           f"{step:+.3f} s against the times the recorder received the "
                           "messages (a clock set while recording, e.g. by NTP): the stamps "
                           f"after it are corrected by {-step:+.3f} s"]
    unset_table = stamped_table("/pose2D", np.column_stack([np.zeros(600), values]), received)
    np.testing.assert_array_equal(unset_table.rows[:, 0], received)
    assert unset_table.notes == ["/pose2D: no header stamps (zero, or a message type without "
                                 "a header): the times the recorder received the messages "
                                 "are used"]


# --------------------------------------------------------------------------- real bags


def stepped(bag: BagWriter, log, topic: str, step: float, at: float):
    """The log's messages, the stamps of ``topic`` after ``at`` (s) moved by ``step`` while
    their receive times stay."""
    out = []
    for name, received, msg in log_messages(bag, log, "pose"):
        if name == topic and msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec > at:
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            msg.header = bag.header(t + step, msg.header.frame_id)
        out.append((name, received, msg))
    return out


@pytest.mark.parametrize("topic, step, storage", [
    ("/joint_states", 0.3, "mcap"), ("/sensor_pose", -2.0, "ros1"),
    ("/joint_states", -2.005, "sqlite3")])
def test_a_bag_whose_clock_steps_reads_as_the_clean_log(tmp_path, log, topic, step, storage):
    """Without the correction: a +0.3 s step cut the log and misaligned its second half
    (r_L 6% off, exit 0), a -2 s one made two messages share a stamp, a -2.005 s one read as
    200 encoder jumps."""
    path = make_bag(tmp_path, storage, lambda bag: stepped(bag, log, topic, step,
                                                                 log.t_enc[0] + 6.0))
    bag = read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose")
    for name in ("t_enc", "t_pose"):
        np.testing.assert_allclose(getattr(bag.series, name), getattr(log, name), atol=0.002)
    for name in ("phi_L", "phi_R", "x", "y"):
        np.testing.assert_array_equal(getattr(bag.series, name), getattr(log, name))
    (note,) = bag.notes
    assert f"{path} {topic} at t = {log.t_enc[0] + 6:.6f} s: the header stamps step by " \
        f"{step:+.3f} s against" in note
    assert note.endswith(f"the stamps after it are corrected by {-step:+.3f} s")


def test_a_clean_bag_has_no_note(tmp_path, log):
    path = make_bag(tmp_path, "mcap", lambda bag: log_messages(bag, log, "pose"))
    assert read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose").notes == ()


def test_poses_never_stamped_are_timed_by_their_receive_times(tmp_path, log):
    """log_messages receives each pose 5 ms after its stamp."""
    def never_stamped(bag: BagWriter):
        return [(topic, received, unset(bag, msg)) if topic == "/sensor_pose" else
                (topic, received, msg) for topic, received, msg in log_messages(bag, log, "pose")]
    path = make_bag(tmp_path, "sqlite3", never_stamped)
    bag = read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose")
    np.testing.assert_allclose(bag.series.t_pose, log.t_pose + 0.005, atol=1e-9)
    assert bag.notes == (f"{path} /sensor_pose: no header stamps (zero, or a message type "
                         "without a header): the times the recorder received the messages "
                         "are used",)


@pytest.mark.parametrize("lost", [(np.nan,) * 4, (0.0,) * 4])
def test_poses_not_measured_are_skipped_and_counted(tmp_path, log, lost):
    """A motion-capture body out of view: its bridge publishes NaN, or a quaternion of
    zeros, for poses 40-59 (before, one such pose refused the whole bag)."""
    def untracked(bag: BagWriter):
        out = []
        for topic, received, msg in log_messages(bag, log, "pose"):
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            if topic == "/sensor_pose" and log.t_pose[40] <= stamp <= log.t_pose[59]:
                msg.pose.position.x = lost[0]
                q = msg.pose.orientation
                q.x, q.y, q.z, q.w = lost
            out.append((topic, received, msg))
        return out
    bag = read_bag_log(make_bag(tmp_path, "mcap", untracked), LEFT, RIGHT,
                       pose_topic="/sensor_pose")
    keep = np.r_[0:40, 60:log.t_pose.size]
    assert_same_log(bag.series, part_of(log, poses=keep))
    assert bag.skipped == {"/sensor_pose not measured (NaN, or a quaternion of zeros: a body "
                           "not tracked?)": 20}


def transform_stamped(bag: BagWriter, msg):
    """A PoseStamped as a TransformStamped (as vicon_bridge publishes poses)."""
    T = bag.types
    p, q = msg.pose.position, msg.pose.orientation
    return T["geometry_msgs/msg/TransformStamped"](
        header=msg.header, child_frame_id="robot",
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=p.x, y=p.y, z=p.z), rotation=q))


def pose_2d(bag: BagWriter, msg):
    """A PoseStamped as a Pose2D, which has no header (ROS 1's laser_scan_matcher)."""
    q = msg.pose.orientation
    return bag.types["geometry_msgs/msg/Pose2D"](
        x=msg.pose.position.x, y=msg.pose.position.y,
        theta=2 * np.arctan2(q.z, q.w))


@pytest.mark.parametrize("convert, storage", [(transform_stamped, "mcap"),
                                              (pose_2d, "ros1")])
def test_transform_stamped_and_pose2d_topics(tmp_path, log, convert, storage):
    def converted(bag: BagWriter):
        return [(topic, received, convert(bag, msg)) if topic == "/sensor_pose" else
                (topic, received, msg) for topic, received, msg in log_messages(bag, log, "pose")]
    bag = read_bag_log(make_bag(tmp_path, storage, converted), LEFT, RIGHT,
                       pose_topic="/sensor_pose")
    if convert is pose_2d:  # timed by receive times, 5 ms after the stamps
        np.testing.assert_allclose(bag.series.t_pose, log.t_pose + 0.005, atol=1e-9)
        np.testing.assert_allclose(bag.series.theta, log.theta, atol=1e-12)
    else:
        assert_same_log(bag.series, log)


def test_a_ros1_tf_topic_of_the_older_tf_type(tmp_path, log):
    """ROS 1 bags from before tf2 record /tf as tf/tfMessage, laid out as tf2's."""
    def old_tf(bag: BagWriter):
        bag.store.register(get_types_from_msg(TF_MSG, "tf/msg/tfMessage"))
        return [(topic, received, bag.types["tf/msg/tfMessage"](transforms=msg.transforms))
                if topic == "/tf" else (topic, received, msg)
                for topic, received, msg in log_messages(bag, log, "tf")]
    bag = read_bag_log(make_bag(tmp_path, "ros1", old_tf), LEFT, RIGHT, tf=("odom", "lidar"))
    assert_same_log(bag.series, log)


@pytest.mark.parametrize("lag", [0.0, 0.004])
def test_wheels_in_separate_messages_are_put_together(tmp_path, log, lag):
    """A driver per motor: each JointState names one wheel, the right one stamped ``lag``
    after the left (before, "no message has both joints"). Stamped alike, the log is read
    exactly; 4 ms apart, the right angles are interpolated to the left stamps."""
    def apart(bag: BagWriter):
        out = []
        for topic, received, msg in log_messages(bag, log, "pose"):
            if topic == "/joint_states" and LEFT in msg.name and RIGHT in msg.name:
                t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                k = list(msg.name)
                out.append((topic, received, bag.joint_state(
                    t, [LEFT], [msg.position[k.index(LEFT)]])))
                out.append((topic, received + lag, bag.joint_state(
                    t + lag, [RIGHT], [msg.position[k.index(RIGHT)]])))
            else:
                out.append((topic, received, msg))
        return sorted(out, key=lambda item: item[1])
    path = make_bag(tmp_path, "mcap", apart)
    bag = read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose")
    assert bag.notes == (f"{path} /joint_states: the wheels come in separate messages: the "
                         f"{RIGHT} angles are interpolated to the {LEFT} stamps",)
    if lag == 0.0:
        assert_same_log(bag.series, log)
        assert bag.skipped == {}
    else:  # the first left stamp precedes every right one
        expected = part_of(log, encoders=slice(1, None))
        np.testing.assert_allclose(bag.series.t_enc, expected.t_enc, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(bag.series.phi_L, expected.phi_L)
        right = np.interp(bag.series.t_enc, log.t_enc + lag, log.phi_R)
        np.testing.assert_allclose(bag.series.phi_R, right, rtol=0, atol=1e-9)
        assert np.max(np.abs(bag.series.phi_R - expected.phi_R)) < 0.05
        assert bag.skipped == {f"/joint_states {LEFT} outside the {RIGHT} messages' time "
                               "range or gaps": 1}


def test_wheels_in_separate_messages_with_velocities_only(tmp_path, log):
    """A driver per motor with velocity interfaces only: each wheel's velocities integrated
    on its own stamps, then put together as the angles of separate messages are."""
    speeds = {LEFT: np.gradient(log.phi_L, log.t_enc), RIGHT: np.gradient(log.phi_R, log.t_enc)}

    def apart(bag: BagWriter):
        out, i = [], 0
        for topic, received, msg in log_messages(bag, log, "pose"):
            if topic == "/joint_states" and LEFT in msg.name and RIGHT in msg.name:
                t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                for wheel in (LEFT, RIGHT):
                    one = bag.joint_state(t, [wheel], [])
                    one.velocity = np.array([speeds[wheel][i]])
                    out.append((topic, received, one))
                i += 1
            else:
                out.append((topic, received, msg))
        return out
    path = make_bag(tmp_path, "mcap", apart)
    bag = read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose")
    assert len(bag.notes) == 2 and "integrated into angles" in bag.notes[0]
    read, angles = segment_timeseries(bag.series).segments, segment_timeseries(log).segments
    np.testing.assert_allclose(read.dphi_L, angles.dphi_L, rtol=0, atol=2e-3)
    np.testing.assert_allclose(read.dphi_R, angles.dphi_R, rtol=0, atol=2e-3)


def test_one_wheel_never_with_a_position(tmp_path, log):
    def lonely(bag: BagWriter):
        return [(topic, received, bag.joint_state(msg.header.stamp.sec
                                                  + 1e-9 * msg.header.stamp.nanosec, [LEFT],
                                                  [0.0]))
                if topic == "/joint_states" else (topic, received, msg)
                for topic, received, msg in log_messages(bag, log, "pose")] + [
            ("/joint_states", 0.5, bag.joint_state(0.5, [RIGHT], []))]
    path = make_bag(tmp_path, "mcap", lonely)
    with pytest.raises(DataError, match=f"/joint_states: no message has a position of the "
                                        f"joint '{RIGHT}'$"):
        read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose")


def test_wheel_positions_all_nan_are_named(tmp_path, log):
    """joint_state_broadcaster fills the positions of joints that have no position state
    interface with NaN: the error says so (it read "phi_L is not finite")."""
    def velocity_interfaces(bag: BagWriter):
        out = []
        for topic, received, msg in log_messages(bag, log, "pose"):
            if topic == "/joint_states":
                msg.position = np.full(len(msg.name), np.nan)
            out.append((topic, received, msg))
        return out
    path = make_bag(tmp_path, "mcap", velocity_interfaces)
    with pytest.raises(DataError, match="are all NaN \\(joints with a velocity state "
                                        "interface only\\?\\); excite needs the wheels' "
                                        "positions$"):
        read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose")


@pytest.mark.parametrize("body", ["z up", "y up"])
def test_a_y_up_world_is_turned_z_up(tmp_path, log, body):
    """Motion capture streaming Y-up (its default): the ground is the world's x-z plane, the
    heading a turn about y; the body's z axis up, or its y axis (a rigid body defined in
    that world). Read as the Z-up log, with a note (it was refused: "tilted 90 degrees")."""
    from excite.logs.orientation import _QUARTER_X, _product

    back = _QUARTER_X * np.array([-1.0, 1.0, 1.0, 1.0])  # -90 degrees about x

    def y_up(bag: BagWriter):
        out = []
        for topic, received, msg in log_messages(bag, log, "pose"):
            if topic == "/sensor_pose":
                p, q = msg.pose.position, msg.pose.orientation
                turned = _product(back, np.array([q.x, q.y, q.z, q.w]))
                if body == "y up":
                    turned = _product(turned, _QUARTER_X)
                p.x, p.y, p.z = p.x, 0.25, -p.y  # the height is y
                q.x, q.y, q.z, q.w = map(float, turned[0])
            out.append((topic, received, msg))
        return out
    path = make_bag(tmp_path, "mcap", y_up)
    bag = read_bag_log(path, LEFT, RIGHT, pose_topic="/sensor_pose")
    np.testing.assert_allclose(bag.series.x, log.x, atol=1e-12)
    np.testing.assert_allclose(bag.series.y, log.y, atol=1e-12)
    np.testing.assert_allclose(bag.series.theta, log.theta, atol=1e-9)
    axis = "z axis up" if body == "z up" else "y axis up, turned z-up"
    assert bag.notes == (f"{path} /sensor_pose: the poses are Y-up (the world's y axis up, as "
                         "motion capture streams by default; the body its "
                         f"{axis}): turned Z-up, positions (x, y, z) read as (x, -z, y)",)


def test_an_upside_down_pose_is_not_called_y_up():
    """A pose rolled by 180 degrees (a sensor mounted upside down, a world frame with z down)
    is refused with those words; one tilted 90 degrees is the Y-up case."""
    from excite.logs.orientation import headings

    where = lambda i: f"sample {i}"  # noqa: E731
    rolled = np.array([[1.0, 0.0, 0.0, 0.0]] * 3)  # (x, y, z, w): 180 degrees about x
    with pytest.raises(DataError, match=r"sample 0: the pose's z axis is tilted 180\.0 degrees "
                                        r".*: upside down, a sensor mounted rolled by 180"):
        headings(rolled, where)
    half = np.sqrt(0.5)
    y_up = np.array([[half, 0.0, 0.0, half]] * 3)  # 90 degrees about x
    with pytest.raises(DataError, match=r"tilted 90\.0 degrees .*: a Y-up frame\?"):
        headings(y_up, where)
