"""Export a calibration to ROS 2 ``diff_drive_controller`` parameters."""

from __future__ import annotations

import os

from excite.kinematics import Params

__all__ = ["ros2_diff_drive_parameters", "write_ros2_yaml"]


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


def write_ros2_yaml(
    path: str | os.PathLike[str],
    estimate: Params,
    nominal: Params | None = None,
    controller: str = "diff_drive_controller",
) -> None:
    """Write the parameters as a ROS 2 parameter file (``controller: ros__parameters: ...``)."""
    parameters = ros2_diff_drive_parameters(estimate, nominal)
    lines = [f"{controller}:", "  ros__parameters:"]
    lines += [f"    {key}: {value:.9g}" for key, value in parameters.items()]
    with open(os.fspath(path), "w") as handle:
        handle.write("\n".join(lines) + "\n")
