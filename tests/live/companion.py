"""What the companion nodes of the live tests share (``silent_topic.py``, ``relay.py``, run as
scripts beside ``excite live``): their rclpy context, and spinning a node until SIGINT or
SIGTERM."""

import signal

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


def node(name: str) -> Node:
    """A node of its own rclpy context, the signals left to :func:`spin_until_signalled`."""
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    return Node(name, context=context)


def spin_until_signalled(companion: Node) -> None:
    """Spin ``companion`` until SIGINT or SIGTERM, then destroy it and its context."""
    stop: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(1))
    executor = SingleThreadedExecutor(context=companion.context)
    executor.add_node(companion)
    while not stop:
        executor.spin_once(timeout_sec=0.1)
    context = companion.context
    companion.destroy_node()
    context.try_shutdown()
