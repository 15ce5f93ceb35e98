"""A node that advertises topics and never publishes on them (a motion-capture server whose
body is not tracked), until SIGINT or SIGTERM: ``python silent_topic.py TOPIC:pose ...``."""

import signal
import sys

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

TYPES = {"pose": PoseStamped, "joints": JointState}


def main() -> None:
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = Node("silent_topic", context=context)
    for spec in sys.argv[1:]:
        topic, kind = spec.rsplit(":", 1)
        node.create_publisher(TYPES[kind], topic, 10)
    stop: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(1))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    while not stop:
        executor.spin_once(timeout_sec=0.1)
    node.destroy_node()
    context.try_shutdown()


if __name__ == "__main__":
    main()
