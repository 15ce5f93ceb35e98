"""``excite live`` as a ROS 2 node (rclpy; the ``ros2`` extra): the transport of a
:class:`excite.live.session.LiveSession`.

It subscribes the wheel joints' JointState messages and the external pose (PoseStamped,
PoseWithCovarianceStamped, TransformStamped or Odometry; best-effort publishers such as motion
capture included: the subscriptions are best effort, which matches both kinds), publishes the
session's command on the command topic (``geometry_msgs/TwistStamped``, or ``Twist``) at
``rate`` Hz on the node's clock (``/clock`` with ``use_sim_time``), and records every message
it receives or sends in a bag (rosbags' writer) when asked.

Safety: a zero command is published on every way out (done, out of time, a fault, Ctrl-C,
SIGTERM, an exception); the session stops the robot while a stream is silent. A clock that
stops (the simulator's ``/clock`` gone) stops the ticks of the command timer: watched on wall
time between them, it has the robot commanded to zero after ``silence_timeout`` seconds and
the session aborted after ``abort_timeout``. A topic that is advertised but sends nothing for
``wait`` seconds after the node subscribed is an error before the robot moves. The stopping
rule's process ignores SIGINT (a terminal's Ctrl-C reaches it too; the node ends the session)
and is terminated when the session ends.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import (
    PoseStamped,
    PoseWithCovarianceStamped,
    TransformStamped,
    Twist,
    TwistStamped,
)
from nav_msgs.msg import Odometry
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

from excite.errors import DataError, ExciteError
from excite.live.result import STOP, Command, LiveResult
from excite.live.session import LiveSession
from excite.live.settings import LiveTopics
from excite.logs.bag_topics import POSE_PARTS
from excite.logs.orientation import headings, z_up
from excite.logs.timeseries import SPEED_NOTE, SpeedIntegral, sample_at
from excite.processes import deaf_to_sigint, shut_down_now, sigint_blocked
from excite.signals import handled

__all__ = ["INTERRUPTED", "POSE_TYPES", "SessionFailed", "run_live", "stop_on_signals"]

#: How much lower the decisions' process runs than the node (os.nice): on a busy computer
#: the node must keep up with the streams and the commands; a decision may wait.
DECISION_NICENESS = 10
#: The reason of a session ended by SIGINT or SIGTERM.
INTERRUPTED = "interrupted (SIGINT or SIGTERM)"

#: The pose message types the node reads, by ROS type name, with how to get the position
#: and the orientation quaternion (:data:`excite.logs.bag_topics.POSE_PARTS`).
POSE_TYPES: dict[str, tuple[type, Callable[[Any], tuple[Any, Any]]]] = {
    name: (kind, POSE_PARTS[name]) for name, kind in (
        ("geometry_msgs/msg/PoseStamped", PoseStamped),
        ("geometry_msgs/msg/PoseWithCovarianceStamped", PoseWithCovarianceStamped),
        ("nav_msgs/msg/Odometry", Odometry),
        ("geometry_msgs/msg/TransformStamped", TransformStamped))}
JOINT_STATE = "sensor_msgs/msg/JointState"
#: Best effort matches best-effort and reliable publishers alike; deep enough for 1 kHz.
SENSOR_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT,
                        history=HistoryPolicy.KEEP_LAST)


class SessionFailed(Exception):
    """A session ended by an exception while it drove (a bug, or a user's protocol that
    failed): the robot was stopped and the session aborted with the exception as its reason;
    ``result`` is what it recorded (:meth:`LiveSession.finish`), the exception its
    ``__cause__``."""

    def __init__(self, result: LiveResult) -> None:
        super().__init__(result.reason)
        self.result = result


#: s of wall time between two checks for other nodes publishing on the command topic.
COMMANDERS_CHECK = 0.5


def _typed_as(types: list[str] | None) -> str:
    """Words for a topic that exists with other types than the one expected; '' for none."""
    return f"; it is there as {', '.join(types)}" if types else ""


def _node_name(namespace: str, name: str) -> str:
    """A node's full name, or words for one whose name is not discovered yet (DDS finds a
    publisher before its node's name)."""
    if name.startswith("_NODE_NAME_UNKNOWN"):
        return "a node whose name is not known yet"
    return f"{namespace.rstrip('/')}/{name}"


def _failure_reason(exc: Exception) -> str:
    """An exception as a session's reason to end."""
    if isinstance(exc, ExciteError):
        return str(exc)
    return f"internal error: {type(exc).__name__}: {exc}"


def _seconds(stamp: Any) -> float:
    """A header stamp in s, computed as the bag reader computes it (whole ns times 1e-9), so
    that a recorded session reads back to the same numbers."""
    return (stamp.sec * 1_000_000_000 + stamp.nanosec) * 1e-9


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """While inside: SIGINT and SIGTERM set the event yielded (a node's loop then stops the
    robot and ends); the previous handlers are restored on the way out. In a thread other
    than the main one (where Python cannot install handlers) the event is only yielded."""
    event = threading.Event()
    with handled((signal.SIGINT, signal.SIGTERM), lambda *_: event.set()):
        yield event


class LiveNode:
    """The node around a session (see the module docstring), in the rclpy ``context``.
    ``recorder``: a
    :class:`excite.logs.bag_writer.BagWriter` already open, or None. ``on_status``: told
    every status the session adds (one per segment)."""

    def __init__(self, session: LiveSession, topics: LiveTopics, context: rclpy.Context,
                 recorder=None, on_status: Callable[[Any], None] | None = None) -> None:
        self.session, self.topics, self.recorder = session, topics, recorder
        self.on_status = on_status or (lambda status: None)
        overrides = [Parameter("use_sim_time", Parameter.Type.BOOL, topics.use_sim_time)]
        self.node = Node("excite_live", context=context, parameter_overrides=overrides)
        stamped = topics.cmd_type == "twist_stamped"
        self._cmd_class = TwistStamped if stamped else Twist
        self.publisher = self.node.create_publisher(self._cmd_class, topics.cmd_vel, 10)
        self._wheels_read = False  # a JointState of both wheels was read
        self._speeds: SpeedIntegral | None = None  # wheels given as velocities: their integral
        self._joints_seen: set[str] = set()
        self._first_joint_state: float | None = None
        self._first_pose: float | None = None  # monotonic s of the first pose message
        self._connected: float | None = None  # monotonic s when the topics were subscribed
        self._last_stamp: dict[str, float] = {}  # the latest finite stamp of each topic (s)
        self._noted: set[tuple[str, str]] = set()  # (topic, kind) of bad messages noted
        self._left_out: dict[str, str] = {}  # why each topic's latest message was left out
        self._pose_type: str | None = None
        self._statuses = 0
        self._last_clock = (None, time.monotonic())
        self._commanders_checked = -math.inf  # monotonic s of the last check
        self.error: str | None = None

    # -- start --------------------------------------------------------------------------------
    def _topics(self) -> dict[str, list[str]]:
        return dict(self.node.get_topic_names_and_types())

    def _topic_list(self, seen: dict[str, list[str]]) -> str:
        shown = [f"{name} [{', '.join(types)}]" for name, types in sorted(seen.items())
                 if not name.startswith(("/rosout", "/parameter_events"))]
        return ", ".join(shown) or "none"

    def connect(self, executor: SingleThreadedExecutor, interrupted: threading.Event) -> bool:
        """Wait (``topics.wait`` s of wall time) for the topics, then subscribe; DataError
        naming the topics and types seen when one is missing or of another type; False when
        ``interrupted`` first (Ctrl-C, SIGTERM)."""
        t = self.topics
        deadline = time.monotonic() + t.wait
        while True:
            if interrupted.is_set():
                return False
            seen = self._topics()
            joint_ok = JOINT_STATE in seen.get(t.joint_states, [])
            pose_types = [k for k in seen.get(t.pose_topic, []) if k in POSE_TYPES]
            if joint_ok and pose_types:
                break
            if time.monotonic() > deadline:
                missing = [f"{name} ({kind}{_typed_as(seen.get(name))})" for name, kind, ok in (
                    (t.joint_states, "sensor_msgs/msg/JointState", joint_ok),
                    (t.pose_topic, "PoseStamped, PoseWithCovarianceStamped, TransformStamped "
                     "or Odometry",
                     bool(pose_types))) if not ok]
                raise DataError(f"no {' nor '.join(missing)} after {t.wait:g} s; topics "
                                f"seen: {self._topic_list(seen)}")
            executor.spin_once(timeout_sec=0.1)
        self._pose_type = pose_types[0]
        pose_class, _ = POSE_TYPES[self._pose_type]
        self.node.create_subscription(JointState, t.joint_states, self._on_joints, SENSOR_QOS)
        self.node.create_subscription(pose_class, t.pose_topic, self._on_pose, SENSOR_QOS)
        if self.recorder is not None:
            self.recorder.add_topic(t.joint_states, JOINT_STATE)
            self.recorder.add_topic(t.pose_topic, "geometry_msgs/msg/PoseStamped")
        self._connected = time.monotonic()
        return True

    def check_streams(self) -> None:
        """Before the session starts: DataError naming each topic that is advertised but
        has sent nothing for ``topics.wait`` s since the node subscribed (a motion-capture
        body not tracked, a driver not running), or whose latest messages all had to be left
        out (and why): the session would wait for it forever."""
        if self.session.state != "waiting" or self._connected is None:
            return
        self._check_stamps()
        t = self.topics
        if time.monotonic() - self._connected <= t.wait:
            return
        silent = [topic for topic, first in ((t.joint_states, self._first_joint_state),
                                             (t.pose_topic, self._first_pose))
                  if first is None]
        if silent:
            raise DataError(f"nothing on {' nor '.join(silent)} for {t.wait:g} s after "
                            "subscribing (the topic is advertised, but no message arrives: "
                            "is its publisher sending, the body tracked?)")
        if self._left_out:  # messages arrive, and none of a topic's latest can be used
            topic, why = next(iter(self._left_out.items()))
            raise DataError(f"no usable message on {topic} for {t.wait:g} s after "
                            f"subscribing: {why}")
        if t.use_sim_time and self._now() == 0.0:
            raise DataError(f"no /clock for {t.wait:g} s with --use-sim-time (is the "
                            "simulator publishing it?)")

    def _check_stamps(self) -> None:
        """Before the session starts: DataError when the messages are stamped on another
        clock than the node's (more than ``abort_timeout`` s apart): every stream would look
        silent."""
        if self.session.state != "waiting" or (self.topics.use_sim_time and self._now() == 0):
            return
        now = self._now()
        far = {topic: stamp - now for topic, stamp in self._last_stamp.items()
               if abs(stamp - now) > self.session.settings.abort_timeout}
        if far:
            offsets = ", ".join(f"{topic} {offset:+.3g} s" for topic, offset in far.items())
            clock = "/clock" if self.topics.use_sim_time else "the system clock"
            fix = "without" if self.topics.use_sim_time else "with"
            raise DataError(f"the messages are stamped on another clock than the node's "
                            f"({clock}): {offsets} from it; {fix} --use-sim-time, or the "
                            "computers' clocks synchronised?")

    def watch_clock(self) -> None:
        """Between the ticks, on wall time: the node's clock (``/clock`` with use_sim_time)
        drives the command timer, so a clock that stops stops the ticks too. While it has
        not moved for ``silence_timeout`` s the robot is commanded to zero; after
        ``abort_timeout`` s the session is aborted (:meth:`_check_clock`)."""
        if self.session.ended or self.session.state == "waiting":
            return
        now = self._now()
        self._check_clock(now)
        since = self._last_clock[1]
        if (not self.session.ended
                and time.monotonic() - since > self.session.settings.silence_timeout):
            self.publish(STOP)

    # -- input --------------------------------------------------------------------------------
    def _now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def _usable(self, topic: str, stream: str, t: float, now: float, values: Any) -> bool:
        """Whether a message stamped ``t`` that arrived at ``now`` (s, the node's clock) can
        be used: a stamp >= 0, not ahead of the node's clock by more than the silence
        timeout (a clock ahead would hide a silence: the robot would drive on blind), and
        finite values. A message that cannot is left out (a robot's bad message is no bug
        here; a stream of them goes silent, which stops the robot, and the session says
        why), and the first of each kind on each topic noted on stderr."""
        if math.isfinite(t):
            self._last_stamp[topic] = t
        ahead = t - now if now > 0 else 0.0  # no clock yet (use_sim_time): nothing to judge
        if not (t >= 0 and np.all(np.isfinite(np.asarray(values, dtype=float)))):
            self._leave_out(topic, stream, "not finite",
                            "a stamp before 0 or a value that is not finite")
            return False
        if ahead > self.session.settings.silence_timeout:
            self._leave_out(topic, stream, "ahead",
                            f"stamped {ahead:.3g} s ahead of the node's clock")
            return False
        self._left_out.pop(topic, None)
        return True

    def _leave_out(self, topic: str, stream: str, kind: str, why: str) -> None:
        """A message of ``topic`` (the session's ``stream``) left out for ``why``: told to
        the session, kept for the start's checks, and the first of each ``kind`` on each
        topic noted on stderr."""
        self._left_out[topic] = why
        self.session.left_out(stream, f"messages on {topic} left out: {why}")
        if (topic, kind) not in self._noted:
            self._noted.add((topic, kind))
            print(f"excite: note: {topic}: a message left out ({why}), and any more like it",
                  file=sys.stderr, flush=True)

    def _on_joints(self, msg: JointState) -> None:
        now = self._now()
        t = _seconds(msg.header.stamp) or now
        names = list(msg.name)
        self._joints_seen.update(names)
        if self._first_joint_state is None:
            self._first_joint_state = time.monotonic()
        wheels = (self.topics.left_wheel, self.topics.right_wheel)
        topic = self.topics.joint_states
        missing = [w for w in wheels if w not in names]
        if len(missing) == 2:  # another publisher's joints (an arm, a gripper): not ours
            return
        angles = None if missing else self._wheel_angles(msg, names, wheels, t)
        if angles is None:
            if self._wheels_read:  # a change after the wheels were read
                self._leave_out(topic, "wheels", "names", (
                    f"no joint {missing[0]!r} in them (joints: {', '.join(names)})"
                    if missing else
                    f"{len(msg.position)} positions for {len(names)} joint names"))
            return
        self._wheels_read = True
        if not self._usable(topic, "wheels", t, now, angles):
            return
        self.session.add_wheels(t, *angles, now)
        if self.recorder is not None:  # integrated speeds are recorded as the wheels' angles
            self.recorder.write(topic, t, self.recorder.joint_state(
                t, *((names, [float(p) for p in msg.position]) if self._speeds is None
                     else (list(wheels), list(angles)))))

    def _wheel_angles(self, msg: JointState, names: list[str], wheels: tuple[str, str],
                      t: float) -> tuple[float, float] | None:
        """The wheels' angles (rad) in a JointState naming both: their positions, or when it
        has none (empty, or NaN: a velocity interface) but their velocities (rad/s), those
        integrated (:class:`excite.logs.timeseries.SpeedIntegral`, noted once; NaN for
        velocities not finite, which the integral leaves out); None when it has neither (or
        a message out of order of the integral's)."""
        index = [names.index(wheel) for wheel in wheels]
        if len(msg.position) == len(names) and not all(
                math.isnan(msg.position[k]) for k in index):
            return float(msg.position[index[0]]), float(msg.position[index[1]])
        if len(msg.velocity) != len(names):
            return None
        speeds = (float(msg.velocity[index[0]]), float(msg.velocity[index[1]]))
        if not all(map(math.isfinite, speeds)):  # left out (not finite), the integral kept
            return math.nan, math.nan
        if self._speeds is None:
            self._speeds = SpeedIntegral()
            print(f"excite: note: {self.topics.joint_states}: {SPEED_NOTE}", file=sys.stderr,
                  flush=True)
        return self._speeds.add(t, *speeds)

    def _on_pose(self, msg: Any) -> None:
        if self._first_pose is None:
            self._first_pose = time.monotonic()
        now = self._now()
        t = _seconds(msg.header.stamp) or now
        position, q = POSE_TYPES[self._pose_type][1](msg)
        if not self._usable(self.topics.pose_topic, "poses", t, now,
                            (position.x, position.y, q.x, q.y, q.z, q.w)):
            return
        if q.x == q.y == q.z == q.w == 0.0:  # a bridge's placeholder while the body is lost
            self._leave_out(self.topics.pose_topic, "poses", "not measured",
                            "a quaternion of zeros: a body not tracked?")
            return
        quaternion, xyz, turned = z_up(np.array([[q.x, q.y, q.z, q.w]]),
                                       np.array([[position.x, position.y, position.z]]))
        if turned is not None and (self.topics.pose_topic, "y-up") not in self._noted:
            self._noted.add((self.topics.pose_topic, "y-up"))
            print(f"excite: note: {self.topics.pose_topic}: {turned}", file=sys.stderr,
                  flush=True)
        try:
            theta = float(headings(quaternion,
                                   lambda _: sample_at(self.topics.pose_topic, t))[0])
        except DataError as exc:
            self.session.abort(str(exc))
            return
        x, y = float(xyz[0, 0]), float(xyz[0, 1])
        self.session.add_pose(t, x, y, theta, now)
        if self.recorder is not None:  # as PoseStamped (Z-up), whatever the topic's type
            self.recorder.write(self.topics.pose_topic, t, self.recorder.pose_stamped(
                t, x, y, theta, msg.header.frame_id or "map",
                tuple(float(c) for c in quaternion[0])))

    # -- output -------------------------------------------------------------------------------
    def publish(self, command: Command) -> None:
        twist = Twist()
        twist.linear.x, twist.angular.z = command.v, command.omega
        if self._cmd_class is TwistStamped:
            msg = TwistStamped()
            msg.header.stamp = self.node.get_clock().now().to_msg()
            msg.header.frame_id = self.topics.frame_id
            msg.twist = twist
        else:
            msg = twist
        self.publisher.publish(msg)
        if self.recorder is not None:  # as TwistStamped, whatever the topic's type
            t = self._now()
            self.recorder.write(self.topics.cmd_vel, t, self.recorder.twist_stamped(
                t, command.v, command.omega, self.topics.frame_id))

    def tick(self) -> None:
        """One command: the session's at the node's time."""
        now = self._now()
        self._check_wheel_names()
        self._check_commanders()
        self._check_clock(now)
        try:
            self.publish(self.session.command(now))
        finally:  # the segment's status even when its next maneuver failed
            statuses = self.session.statuses
            for status in statuses[self._statuses:]:
                self.on_status(status)
            self._statuses = len(statuses)

    def _check_wheel_names(self) -> None:
        """JointState messages for 2 s, none of them naming both wheels: a wrong name
        (DataError before the session started)."""
        if self._wheels_read or self._first_joint_state is None:
            return
        if time.monotonic() - self._first_joint_state > 2.0:
            missing = [w for w in (self.topics.left_wheel, self.topics.right_wheel)
                       if w not in self._joints_seen]
            joints = ", ".join(sorted(self._joints_seen)) or "none"
            what = (f"no joint {' nor '.join(map(repr, missing))}" if missing
                    else "no positions for the wheel joints")
            self._refuse(f"the JointState messages on {self.topics.joint_states} have "
                         f"{what} (joints: {joints}); check --left-wheel, --right-wheel")

    def _check_commanders(self) -> None:
        """Another node publishing on the command topic (a teleop or a navigation stack left
        running), checked every COMMANDERS_CHECK s: the robot would follow both. DataError
        before the session started (the robot never commanded); the session aborted after."""
        wall = time.monotonic()
        if self.session.ended or wall - self._commanders_checked < COMMANDERS_CHECK:
            return
        self._commanders_checked = wall
        own = (self.node.get_namespace(), self.node.get_name())
        others = sorted({_node_name(info.node_namespace, info.node_name)
                         for info in self.node.get_publishers_info_by_topic(self.topics.cmd_vel)
                         if (info.node_namespace, info.node_name) != own})
        if not others:
            return
        self._refuse(f"another node publishes on {self.topics.cmd_vel} ({', '.join(others)}): "
                     "the robot would follow both (a teleop or navigation left running?); stop "
                     "it, or give excite a command topic of its own (--cmd-vel)")

    def _refuse(self, text: str) -> None:
        """A fault of the robot's set-up: bad input (DataError) before the session started,
        the robot never commanded; the session aborted after."""
        if self.session.state == "waiting":
            raise DataError(text)
        self.session.abort(text)

    def _check_clock(self, now: float) -> None:
        """The node's clock stopped (no /clock with use_sim_time) for abort_timeout s."""
        last, since = self._last_clock
        wall = time.monotonic()
        if now != last:
            self._last_clock = (now, wall)
        elif wall - since > self.session.settings.abort_timeout:
            self.session.abort(f"the clock stopped for {wall - since:.1f} s (is /clock "
                               "published? use_sim_time is "
                               f"{'on' if self.topics.use_sim_time else 'off'})")

    def stop(self, repeats: int = 3, timeout: float = 1.0) -> None:
        """Publish a zero command (a few times), and wait up to ``timeout`` s for the
        subscribers to acknowledge it: a node destroyed right after publishing may take its
        last messages with it."""
        for _ in range(repeats):
            self.publish(STOP)
        self.publisher.wait_for_all_acked(Duration(nanoseconds=int(timeout * 1e9)))


def run_live(session: LiveSession, topics: LiveTopics, recorder=None,
             on_status: Callable[[Any], None] | None = None,
             domain_id: int | None = None) -> LiveResult:
    """Run ``session`` over ROS 2 until it ends, Ctrl-C or SIGTERM (the session then ends
    *aborted*, "interrupted"); the robot is commanded to zero on every way out. Returns the
    session's result (:meth:`LiveSession.finish`). Raises DataError when a topic is missing at
    the start (the robot was never commanded), and SessionFailed, with the session's result,
    when an exception ends it while it drives (after the robot was stopped)."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id,
               signal_handler_options=SignalHandlerOptions.NO)
    # The stopping rule's batch calibration runs in a process of its own: in a thread it
    # would hold the interpreter while the callbacks fall behind the streams.
    pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_decision_worker)
    with sigint_blocked():  # the worker starts now, deaf to Ctrl-C from its first instruction
        pool.submit(os.getpid)
    session.executor = pool
    executor = SingleThreadedExecutor(context=context)
    node: LiveNode | None = None
    stopped = False  # the zero command went out and was acknowledged
    try:
        with stop_on_signals() as interrupted:
            node = LiveNode(session, topics, context, recorder, on_status)
            executor.add_node(node.node)
            if not node.connect(executor, interrupted):  # never started: nothing to stop
                session.abort(INTERRUPTED)
                return session.finish()
            period = 1.0 / topics.rate
            node.node.create_timer(period, node.tick)
            try:
                while not session.ended and not interrupted.is_set():
                    executor.spin_once(timeout_sec=min(period, 0.05))
                    node.check_streams()
                    node.watch_clock()
            except Exception as exc:  # stop, keep what was recorded, then report it
                if session.state == "waiting":  # never started: nothing to keep
                    raise
                session.abort(_failure_reason(exc))
                node.stop()
                stopped = True
                raise SessionFailed(session.finish()) from exc
            if interrupted.is_set():
                session.abort(INTERRUPTED)
            node.stop()  # before the final calibration, which takes a while
            stopped = True
            return session.finish()
    finally:
        if node is not None:
            if not stopped:
                node.stop()
            executor.remove_node(node.node)
            node.node.destroy_node()
        # a decision still running is of no use once the session ended, and waiting for it
        # at the interpreter's exit left a second Ctrl-C or SIGTERM with the default handlers
        shut_down_now(pool)
        executor.shutdown(timeout_sec=1.0)
        context.try_shutdown()


def _decision_worker() -> None:
    """The decisions' process: lower priority (DECISION_NICENESS), and deaf to SIGINT: a
    terminal's Ctrl-C reaches every process of the job, and the node, not the worker, ends
    the session (a worker interrupted mid-decision lost the session's report)."""
    os.nice(DECISION_NICENESS)
    deaf_to_sigint()
