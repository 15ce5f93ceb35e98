"""Where would a command take the robot? Kinematic prediction and the wall check.

Planners predict a segment with the kinematic model at the current estimate, assuming the
wheels turn at the commanded speed for the whole segment (no lag, no slip), and reject
commands whose predicted footprint leaves the arena (with a safety margin).
"""

from __future__ import annotations

import numpy as np

from excite.contracts import RobotKnowledge
from excite.core.arena import DEFAULT_CHASSIS, Arena
from excite.core.kinematics import Params, predict_increment

#: Fractions of the segment at which the predicted footprint is checked.
CHECK_POINTS = np.array([0.25, 0.5, 0.75, 1.0])
#: Clearance (m) kept between the predicted footprint and the walls: a fixed part, plus a part
#: per unit of commanded speed (fraction of the motor limit) for what the model does not
#: predict: the motors' lag carrying the previous speed on, and slip.
MARGIN = 0.10
SPEED_MARGIN = 0.35


def wheel_increments(actions: np.ndarray, knowledge: RobotKnowledge) -> np.ndarray:
    """Commanded wheel increments (rad), shape (..., 2), for actions in [-1, 1]^2."""
    return np.asarray(actions, dtype=float) * knowledge.max_wheel_speed * knowledge.segment_duration


def predicted_poses(pose: np.ndarray, dphi: np.ndarray, params: Params,
                    fractions: np.ndarray = CHECK_POINTS) -> np.ndarray:
    """World poses (n, len(fractions), 3) after each fraction of each candidate segment.

    pose: start world pose (x, y, theta), or one per candidate (n, 3); dphi: (n, 2) wheel
    increments (rad).
    """
    dphi = np.atleast_2d(dphi)
    frac = fractions[None, :]
    dx, dy, dth = predict_increment(dphi[:, :1] * frac, dphi[:, 1:] * frac, params)
    x, y, th = np.moveaxis(np.asarray(pose, dtype=float), -1, 0)[..., None]
    c, s = np.cos(th), np.sin(th)
    return np.stack([x + c * dx - s * dy, y + s * dx + c * dy, th + dth], axis=-1)


def is_safe(poses: np.ndarray, arena: tuple[float, float],
            margin: float | np.ndarray = MARGIN,
            chassis: tuple[float, float] = DEFAULT_CHASSIS) -> np.ndarray:
    """Whether the footprint at every pose (n, m, 3) stays inside the arena centred at the
    origin, ``margin`` (m, a scalar or one per candidate) from the walls. arena: (width
    along x, height along y) (m; ``RobotKnowledge.arena``)."""
    margin = np.reshape(margin, (-1,) + (1,) * (poses.ndim - 2))
    inside = Arena(*arena).contains_footprint(
        poses[..., 0], poses[..., 1], poses[..., 2], margin, chassis)
    return inside.all(axis=-1)


def action_margin(actions: np.ndarray, speed_margin: float = SPEED_MARGIN) -> np.ndarray:
    """Wall clearance (m) demanded of each candidate action (n, 2)."""
    return MARGIN + speed_margin * np.abs(np.atleast_2d(actions)).max(axis=1)


def safe_actions(actions: np.ndarray, knowledge: RobotKnowledge,
                 speed_margin: float = SPEED_MARGIN) -> np.ndarray:
    """Boolean mask over candidate actions (n, 2): predicted to stay clear of the walls with
    both the current estimate and the nominal robot (a slip-biased estimate alone can be far
    off)."""
    dphi = wheel_increments(actions, knowledge)
    margin = action_margin(actions, speed_margin)
    return np.logical_and.reduce([
        is_safe(predicted_poses(knowledge.pose, dphi, params), knowledge.arena, margin,
                knowledge.chassis)
        for params in (knowledge.estimate, knowledge.nominal)])


def turn_to_center(knowledge: RobotKnowledge, speed: float = 0.3) -> np.ndarray:
    """An in-place turn towards the arena centre (the fallback when nothing else is safe)."""
    x, y, th = knowledge.pose
    bearing = np.arctan2(-y, -x) - th
    direction = np.sign(np.sin(bearing)) or 1.0
    return np.array([-direction * speed, direction * speed])
