"""The heading of a pose given as an orientation quaternion: ROS bags and live topics
(geometry_msgs/Pose), and CSV exports with quaternion columns (motion capture, odometry).

The heading is the rotation about the world z axis of the quaternion's ZYX Euler angles: the
direction of the body x axis projected on the world xy plane (rad, counter-clockwise from
the world x axis, in (-pi, pi]). Quaternions are (x, y, z, w) and need not have unit length:
the heading and the tilt are computed free of it. The world frame must be z-up: a body z
axis tilted more than MAX_TILT (45 degrees) from the world z axis is an error (most often a
Y-up motion capture frame); roll and pitch below that (a ramp) are fine.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from excite.errors import DataError

__all__ = ["MAX_TILT", "MIN_QUATERNION_NORM", "headings"]

#: Quaternions shorter than this are no rotation (an orientation never set is all zeros).
MIN_QUATERNION_NORM = 1e-3
#: The largest tilt (rad) of the pose's z axis from the world z axis: a ground robot's sensor
#: stays near z-up (a ramp tilts it a few degrees); more means another frame convention.
MAX_TILT = math.radians(45.0)


def headings(q: np.ndarray, where: Callable[[int], str]) -> np.ndarray:
    """Headings (rad, in (-pi, pi]) of orientation quaternions ``q`` (n, 4: x, y, z, w), see
    the module docstring; ``where(i)`` names sample i in errors (a file and line, or a topic
    and stamp).

    Raises DataError naming the sample for a quaternion that is not finite or shorter than
    MIN_QUATERNION_NORM (an orientation never set is all zeros), and for a body z axis tilted
    more than MAX_TILT from the world z axis (a ground robot's pose is near z-up; more tilt
    means another frame convention, most often Y-up from motion capture).
    """
    x, y, z, w = np.asarray(q, dtype=float).T
    norm2 = x * x + y * y + z * z + w * w
    bad = ~(np.isfinite(norm2) & (norm2 >= MIN_QUATERNION_NORM**2))
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(f"{where(i)}: the orientation quaternion (x, y, z, w) = "
                        f"({x[i]}, {y[i]}, {z[i]}, {w[i]}) is not a rotation (zero length "
                        "or not finite)")
    tilt = np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y) / norm2, -1.0, 1.0))
    if np.any(tilt > MAX_TILT):
        i = int(np.argmax(tilt))
        raise DataError(f"{where(i)}: the pose's z axis is tilted "
                        f"{math.degrees(tilt[i]):.1f} degrees from the world z axis (the "
                        f"largest tilt; a ground robot stays within "
                        f"{math.degrees(MAX_TILT):.0f}): a Y-up frame? Motion capture systems "
                        "often stream Y-up; convert the poses to Z-up")
    return np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)
