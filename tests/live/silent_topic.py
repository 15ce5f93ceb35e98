"""A node that advertises topics and never publishes on them (a motion-capture server whose
body is not tracked, a teleop that sends nothing), until SIGINT or SIGTERM: ``python
silent_topic.py TOPIC:pose ...`` (kinds pose, joints, twist)."""

import sys

from companion import node, spin_until_signalled
from geometry_msgs.msg import PoseStamped, TwistStamped
from sensor_msgs.msg import JointState

TYPES = {"pose": PoseStamped, "joints": JointState, "twist": TwistStamped}


def main() -> None:
    silent = node("silent_topic")
    for spec in sys.argv[1:]:
        topic, kind = spec.rsplit(":", 1)
        silent.create_publisher(TYPES[kind], topic, 10)
    spin_until_signalled(silent)


if __name__ == "__main__":
    main()
