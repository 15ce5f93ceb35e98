"""``excite sim-robot``: the simulated robot (:class:`envs.sim_robot.SimRobot`) as a ROS 2
node, to rehearse ``excite live`` before the real robot (and for its tests).

It publishes ``/clock`` (rosgraph_msgs/Clock) every physics tick, the wheel joints'
JointState on ``/joint_states`` and the mounted body's PoseStamped on the pose topic, all
stamped with the simulated time, and obeys ``/cmd_vel`` (TwistStamped, or Twist) as
diff_drive_controller does. It runs ``speed`` times faster than real time (1: real time);
nodes that use ``use_sim_time`` follow its clock. Streams can be cut for a while (``cuts``)
to rehearse faults (timed from the first command, so a session meets them however long it
took to start). On exit (``duration`` reached, SIGINT or SIGTERM) it writes its hidden
truth and its own log when asked.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from envs.sim_robot import Cut, SimRobot
from excite.live.ros2 import stop_on_signals

__all__ = ["SimTopics", "run_sim_robot"]


@dataclass(frozen=True)
class SimTopics:
    """The node's topics: joint_states, left_wheel and right_wheel (the joint names it
    publishes, among ``extra_joints`` of 0 rad), pose_topic, cmd_vel, cmd_type
    ("twist_stamped" or "twist"), best_effort (publish the pose best effort, as motion
    capture does), frame_id (of the poses)."""

    joint_states: str = "/joint_states"
    left_wheel: str = "left_wheel_joint"
    right_wheel: str = "right_wheel_joint"
    extra_joints: tuple[str, ...] = ("caster_joint",)
    pose_topic: str = "/pose"
    cmd_vel: str = "/cmd_vel"
    cmd_type: str = "twist_stamped"
    best_effort: bool = True
    frame_id: str = "map"


def _stamp(t: float):
    from builtin_interfaces.msg import Time

    sec = int(t // 1)
    return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)


def run_sim_robot(robot: SimRobot, topics: SimTopics, speed: float = 1.0,
                  duration: float = float("inf"), cuts: tuple[Cut, ...] = (),
                  truth_out: str | None = None, log_out: str | None = None,
                  domain_id: int | None = None,
                  on_ready=None) -> int:
    """Run the node until ``duration`` s of simulated time, SIGINT or SIGTERM; write the
    truth (JSON) and the robot's log (CSV: t, x, y, theta, v, omega, received,
    received_wall; :meth:`envs.sim_robot.SimRobot.log_array`) when asked.
    Returns the number of physics ticks run."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id,
               signal_handler_options=SignalHandlerOptions.NO)
    node = Node("excite_sim_robot", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT
                     if topics.best_effort else ReliabilityPolicy.RELIABLE)
    clock = node.create_publisher(Clock, "/clock", 10)
    joints = node.create_publisher(JointState, topics.joint_states, 50)
    poses = node.create_publisher(PoseStamped, topics.pose_topic, qos)
    stamped = topics.cmd_type == "twist_stamped"

    def on_command(msg) -> None:
        twist = msg.twist if stamped else msg
        robot.command(robot.t, twist.linear.x, twist.angular.z, time.time())

    node.create_subscription(TwistStamped if stamped else Twist, topics.cmd_vel, on_command,
                             10)
    names = [topics.left_wheel, topics.right_wheel, *topics.extra_joints]
    ticks = 0
    with stop_on_signals() as stop:  # from here on, SIGINT and SIGTERM end the loop
        try:
            if on_ready is not None:
                on_ready()
            wall0 = time.monotonic()
            while not stop.is_set() and robot.t < duration:
                readings = robot.advance()
                ticks += 1
                stamp = _stamp(readings.t)
                clock.publish(Clock(clock=stamp))
                silent = {c.stream for c in cuts if c.covers(readings.t,
                                                               robot.first_command)}
                if readings.wheels is not None and "joints" not in silent:
                    msg = JointState(name=names,
                                     position=[*readings.wheels, *[0.0] * len(topics.extra_joints)])
                    msg.header.stamp = stamp
                    joints.publish(msg)
                if readings.pose is not None and "pose" not in silent:
                    msg = PoseStamped()
                    msg.header.stamp, msg.header.frame_id = stamp, topics.frame_id
                    x, y, theta = readings.pose
                    msg.pose.position.x, msg.pose.position.y = x, y
                    msg.pose.orientation.z, msg.pose.orientation.w = np.sin(0.5 * theta), np.cos(
                        0.5 * theta)
                    poses.publish(msg)
                executor.spin_once(timeout_sec=0.0)
                ahead = wall0 + readings.t / speed - time.monotonic()
                if ahead > 0:
                    time.sleep(ahead)
        finally:
            if truth_out:
                Path(truth_out).write_text(json.dumps(robot.truth(), indent=2) + "\n")
            if log_out:
                np.savetxt(log_out, robot.log_array(), delimiter=",", fmt="%.15g",
                           header="t,x,y,theta,v,omega,received,received_wall", comments="")
            executor.remove_node(node)
            node.destroy_node()
            executor.shutdown(timeout_sec=1.0)
            context.try_shutdown()
    return ticks
