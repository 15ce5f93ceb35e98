"""The heading of a pose given as an orientation quaternion: ROS bags and live topics
(geometry_msgs/Pose), and CSV exports with quaternion columns (motion capture, odometry).

The heading is the rotation about the world z axis of the quaternion's ZYX Euler angles: the
direction of the body x axis projected on the world xy plane (rad, counter-clockwise from
the world x axis, in (-pi, pi]). Quaternions are (x, y, z, w) and need not have unit length:
the heading and the tilt are computed free of it. The world frame must be z-up: a body z
axis tilted more than MAX_TILT (45 degrees) from the world z axis is an error (most often a
Y-up motion capture frame); roll and pitch below that (a ramp) are fine.

Poses with their positions (a bag's, a live topic's) in a Y-up world, as motion capture
streams by default, are turned Z-up first (:func:`z_up`): when every sample's body z or body
y axis lies within MAX_TILT of the world y axis, the world is turned +90 degrees about its x
axis (x, y, z -> x, -z, y), and a Y-up body with it, so that its z axis is up.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from excite.errors import DataError

__all__ = ["MAX_TILT", "MIN_QUATERNION_NORM", "headings", "z_up"]

#: Quaternions shorter than this are no rotation (an orientation never set is all zeros).
MIN_QUATERNION_NORM = 1e-3
#: The largest tilt (rad) of the pose's z axis from the world z axis: a ground robot's sensor
#: stays near z-up (a ramp tilts it a few degrees); more means another frame convention.
MAX_TILT = math.radians(45.0)
#: A z axis tilted more than this from up points down: upside down rather than Y-up (90).
UPSIDE_DOWN = math.radians(135.0)


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
    tilt = np.arccos(np.clip(_cos_tilt(q), -1.0, 1.0))
    if np.any(tilt > MAX_TILT):
        i = int(np.argmax(tilt))
        why = (": upside down, a sensor mounted rolled by 180 degrees or a world frame with "
               "z down? Give the poses of a frame whose z axis points up"
               if tilt[i] > UPSIDE_DOWN else
               ": a Y-up frame? Motion capture systems often stream Y-up; convert the poses "
               "to Z-up")
        raise DataError(f"{where(i)}: the pose's z axis is tilted "
                        f"{math.degrees(tilt[i]):.1f} degrees from the world z axis (the "
                        f"largest tilt; a ground robot stays within "
                        f"{math.degrees(MAX_TILT):.0f}){why}")
    return np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


#: The unit quaternion (x, y, z, w) of a rotation of +90 degrees about the x axis.
_QUARTER_X = np.array([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])


def _product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a b of quaternions (x, y, z, w), row by row (either may be one)."""
    ax, ay, az, aw = np.moveaxis(np.atleast_2d(a), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.atleast_2d(b), -1, 0)
    return np.column_stack([aw * bx + ax * bw + ay * bz - az * by,
                            aw * by - ax * bz + ay * bw + az * bx,
                            aw * bz + ax * by - ay * bx + az * bw,
                            aw * bw - ax * bx - ay * by - az * bz])


def _world_y(q: np.ndarray, axis: int) -> np.ndarray:
    """The world y component of the body's unit ``axis`` (1: y, 2: z) for each quaternion,
    free of the quaternion's length."""
    x, y, z, w = q.T
    norm2 = x * x + y * y + z * z + w * w
    if axis == 1:
        return (w * w - x * x + y * y - z * z) / norm2
    return 2.0 * (y * z - w * x) / norm2


def z_up(q: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray, str | None]:
    """Quaternions ``q`` (n, 4: x, y, z, w) and positions (n, 3: x, y, z; m) turned Z-up when
    every sample is Y-up (the module docstring), with the conversion in words for a note;
    unchanged, with None, otherwise (:func:`headings` then refuses a tilted pose)."""
    q = np.asarray(q, dtype=float)
    if q.size == 0 or not _tilted(q).any():
        return q, position, None
    cos_tilt = math.cos(MAX_TILT)
    with np.errstate(invalid="ignore", divide="ignore"):
        body_z, body_y = _world_y(q, 2), _world_y(q, 1)
    if np.all(body_z > cos_tilt):
        turned, body = _product(_QUARTER_X, q), "its z axis up"
    elif np.all(body_y > cos_tilt):
        back = _QUARTER_X * np.array([-1.0, 1.0, 1.0, 1.0])  # -90 degrees about x
        turned, body = _product(_product(_QUARTER_X, q), back), "its y axis up, turned z-up"
    else:
        return q, position, None
    x, y, z = np.asarray(position, dtype=float).T
    return turned, np.column_stack([x, -z, y]), (
        "the poses are Y-up (the world's y axis up, as motion capture streams by default; the "
        f"body {body}): turned Z-up, positions (x, y, z) read as (x, -z, y)")


def _cos_tilt(q: np.ndarray) -> np.ndarray:
    """The cosine of each quaternion's body z axis' tilt from the world z axis (free of the
    quaternion's length; NaN for one that is no rotation)."""
    x, y, z, w = np.asarray(q, dtype=float).T
    with np.errstate(invalid="ignore", divide="ignore"):
        return 1.0 - 2.0 * (x * x + y * y) / (x * x + y * y + z * z + w * w)


def _tilted(q: np.ndarray) -> np.ndarray:
    """Whether each quaternion's body z axis is tilted more than MAX_TILT from the world z
    axis (False for one that is no rotation)."""
    return np.nan_to_num(_cos_tilt(q), nan=1.0) < math.cos(MAX_TILT)
