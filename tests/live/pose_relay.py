"""A node that republishes the simulated robot's ``/pose`` (PoseStamped) as
``geometry_msgs/TransformStamped`` on ``/relay_pose``, as a motion-capture bridge such as
vicon_bridge publishes a body's pose, until SIGINT or SIGTERM: ``python pose_relay.py``."""

from companion import node, spin_until_signalled
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.qos import qos_profile_sensor_data


def main() -> None:
    relay_node = node("pose_relay")
    out = relay_node.create_publisher(TransformStamped, "/relay_pose", 50)

    def relay(msg: PoseStamped) -> None:
        transform = TransformStamped()
        transform.header, transform.child_frame_id = msg.header, "robot"
        p, t = msg.pose.position, transform.transform.translation
        t.x, t.y, t.z = p.x, p.y, p.z
        transform.transform.rotation = msg.pose.orientation
        out.publish(transform)

    relay_node.create_subscription(PoseStamped, "/pose", relay, qos_profile_sensor_data)
    spin_until_signalled(relay_node)


if __name__ == "__main__":
    main()
