"""A node that republishes the simulated robot's ``/pose`` (PoseStamped, Z-up) on
``/relay_pose`` until SIGINT or SIGTERM, as a motion-capture bridge would:
``python pose_relay.py MODE`` with MODE "transform" (as ``geometry_msgs/TransformStamped``,
vicon_bridge's type), "y_up" (as a PoseStamped in a Y-up world, motion capture's default:
positions (x, y, z) -> (x, z, -y), the world turned -90 degrees about x) or "untracked" (as it
is, but for 1.5 s of its stamps from when the robot is first 0.2 m from where it started, at
the origin with a quaternion of zeros: a bridge's placeholder while the body is lost)."""

import math
import sys

from companion import node, spin_until_signalled
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.qos import qos_profile_sensor_data

MODES = ("transform", "y_up", "untracked")
#: -90 degrees about x (x, y, z, w): a Z-up world's vectors in the Y-up world.
BACK = (-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))


def product(a, b):
    """The Hamilton product a b of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def main() -> None:
    mode = sys.argv[1]
    if mode not in MODES:
        raise SystemExit(f"MODE must be one of {', '.join(MODES)}, got {mode!r}")
    relay_node = node("pose_relay")
    kind = TransformStamped if mode == "transform" else PoseStamped
    out = relay_node.create_publisher(kind, "/relay_pose", 50)

    start: list[tuple[float, float]] = []  # where the robot started
    lost: list[float] = []  # when the body was lost (the stamp, s)

    def relay(msg: PoseStamped) -> None:
        p, q = msg.pose.position, msg.pose.orientation
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        if mode == "untracked":
            if not start:
                start.append((p.x, p.y))
            if not lost and math.hypot(p.x - start[0][0], p.y - start[0][1]) > 0.2:
                lost.append(t)
            if lost and t - lost[0] <= 1.5:
                p.x = p.y = p.z = 0.0
                q.x = q.y = q.z = q.w = 0.0
            out.publish(msg)
            return
        if mode == "transform":
            transform = TransformStamped()
            transform.header, transform.child_frame_id = msg.header, "robot"
            t = transform.transform.translation
            t.x, t.y, t.z = p.x, p.y, p.z
            transform.transform.rotation = q
            out.publish(transform)
            return
        p.x, p.y, p.z = p.x, p.z, -p.y
        q.x, q.y, q.z, q.w = product(BACK, (q.x, q.y, q.z, q.w))
        out.publish(msg)

    relay_node.create_subscription(PoseStamped, "/pose", relay, qos_profile_sensor_data)
    spin_until_signalled(relay_node)


if __name__ == "__main__":
    main()
