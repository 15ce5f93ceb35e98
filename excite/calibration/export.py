"""Export a calibration to ROS 2 ``diff_drive_controller`` parameters."""

from __future__ import annotations

import os

from excite.core.kinematics import Params
from excite.core.models import SensorPose

__all__ = ["ros2_diff_drive_parameters", "static_transform_command", "write_ros2_yaml"]


def ros2_diff_drive_parameters(estimate: Params, nominal: Params | None = None) -> dict:
    """The ``diff_drive_controller`` parameters that make odometry use ``estimate``.

    ``wheel_radius`` and ``wheel_separation`` keep the nominal values (what the robot's
    description says; the controller has a single nominal radius, the mean of the nominal
    r_L and r_R); the multipliers carry the calibration: estimate / nominal. Without a nominal
    robot, the nominal radius is the mean calibrated radius and the nominal separation the
    calibrated one.
    """
    nominal = nominal or estimate
    radius = 0.5 * (nominal.r_L + nominal.r_R)
    return {
        "wheel_separation": nominal.b,
        "wheel_radius": radius,
        "left_wheel_radius_multiplier": estimate.r_L / radius,
        "right_wheel_radius_multiplier": estimate.r_R / radius,
        "wheel_separation_multiplier": estimate.b / nominal.b,
    }


def static_transform_command(pose: SensorPose, parent: str = "base_link",
                             child: str = "sensor") -> str:
    """The ROS 2 ``static_transform_publisher`` command that publishes the sensor's pose in
    the body frame (base_link -> sensor: x, y in m, yaw in rad; z, roll, pitch 0)."""
    return (f"ros2 run tf2_ros static_transform_publisher --x {pose.x:.9g} --y {pose.y:.9g} "
            f"--z 0 --yaw {pose.theta:.9g} --pitch 0 --roll 0 --frame-id {parent} "
            f"--child-frame-id {child}")


def write_ros2_yaml(
    path: str | os.PathLike[str],
    estimate: Params,
    nominal: Params | None = None,
    controller: str = "diff_drive_controller",
    sensor_pose: SensorPose | None = None,
    unsafe: str | None = None,
) -> None:
    """Write the parameters as a ROS 2 parameter file (``controller: ros__parameters: ...``).
    With an estimated ``sensor_pose``, the file starts with the static transform of the
    sensor as a ready-to-run ``static_transform_publisher`` command (a YAML comment, so the
    file stays a valid parameter file). ``unsafe``: why the values must not be loaded into a
    controller (a failed calibration written anyway); the file then starts with a comment
    ``# UNSAFE: ...`` saying so."""
    parameters = ros2_diff_drive_parameters(estimate, nominal)
    lines = []
    if unsafe is not None:
        lines += ["# UNSAFE: do not load these parameters into a controller: the calibration "
                  "failed.", f"# Why: {' '.join(unsafe.split())}"]
    if sensor_pose is not None:
        lines += ["# The external sensor's pose in base_link (estimated by excite):",
                  f"# {static_transform_command(sensor_pose)}"]
    lines += [f"{controller}:", "  ros__parameters:"]
    lines += [f"    {key}: {value:.9g}" for key, value in parameters.items()]
    with open(os.fspath(path), "w") as handle:
        handle.write("\n".join(lines) + "\n")
