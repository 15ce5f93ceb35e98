"""A node between the simulated robot and live that spoils the joint states after a while (a
driver that changes its joint names, a clock that jumps, a bad stamp), until SIGINT or SIGTERM:
``python relay.py FAULT AFTER FILE`` republishes ``/joint_states`` on ``/relay_joints``; from
AFTER s (the messages' own stamps) past the first one on, each message has FAULT:
"drop_left" (no left wheel in it), "ahead" (stamped 100 s later) or "negative" (stamped at
-1 s); or, "gripper", each is followed by a message of another joint (an arm's or a gripper's
publisher on the same topic); or, "velocities", each has the wheels' velocities (rad/s, the
mean over the period since the message before, as a driver measures them) and NaN positions,
as joint_state_broadcaster publishes joints with a velocity interface only (the first five
velocities NaN, as before the hardware's first reading). The stamp of the first spoilt message
(s) is written to FILE."""

import math
import sys
from pathlib import Path

from builtin_interfaces.msg import Time
from companion import node, spin_until_signalled
from sensor_msgs.msg import JointState

FAULTS = ("drop_left", "ahead", "negative", "gripper", "velocities")


def spoilt(msg: JointState, fault: str) -> JointState:
    out = JointState()
    out.header = msg.header
    out.name, out.position = list(msg.name), list(msg.position)
    if fault == "drop_left":
        keep = [i for i, name in enumerate(out.name) if name != "left_wheel_joint"]
        out.name = [out.name[i] for i in keep]
        out.position = [out.position[i] for i in keep]
    elif fault == "ahead":
        out.header.stamp = Time(sec=msg.header.stamp.sec + 100,
                                nanosec=msg.header.stamp.nanosec)
    else:
        out.header.stamp = Time(sec=-1, nanosec=0)
    return out


def main() -> None:
    fault, after, file = sys.argv[1], float(sys.argv[2]), Path(sys.argv[3])
    if fault not in FAULTS:
        raise SystemExit(f"FAULT must be one of {', '.join(FAULTS)}, got {fault!r}")
    relay_node = node("relay")
    out = relay_node.create_publisher(JointState, "/relay_joints", 50)
    first: list[float] = []
    before: list[tuple[float, list[float]]] = []  # the last message's stamp and positions
    relayed: list[float] = []  # the stamps relayed as velocities

    def relay(msg: JointState) -> None:
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        if not first:
            first.append(t)
        if fault == "velocities":
            last = before[-1] if before else (t - 0.01, list(msg.position))
            before[:] = [(t, list(msg.position))]
            relayed.append(t)
            velocity = [(a - b) / max(t - last[0], 1e-9)
                        for a, b in zip(msg.position, last[1], strict=True)]
            if len(relayed) <= 5:  # NaN before the hardware's first reading (ros2_control)
                velocity = [math.nan] * len(velocity)
            out.publish(JointState(header=msg.header, name=list(msg.name),
                                   position=[math.nan] * len(msg.name), velocity=velocity))
            return
        if t - first[0] >= after and not file.exists():
            file.write_text(f"{t}\n")
        if t - first[0] >= after and fault == "gripper":
            out.publish(msg)
            other = JointState()
            other.header, other.name, other.position = msg.header, ["gripper_joint"], [0.01]
            out.publish(other)
            return
        if t - first[0] >= after:
            msg = spoilt(msg, fault)
        out.publish(msg)

    relay_node.create_subscription(JointState, "/joint_states", relay, 50)
    spin_until_signalled(relay_node)


if __name__ == "__main__":
    main()
