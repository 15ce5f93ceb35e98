"""The ideal drive: rolling without slip and without lag, so the kinematic model is exact.

`IdealDrive` moves one robot and `IdealBatchDrive` N robots, both on one kernel
(:func:`ideal_arcs`), so each robot of a batch gets the single drive's numbers bit for bit.
Each physics tick is an exact constant-curvature arc; a robot whose footprint would enter a
wall stops there. The drive of the ``ideal`` configuration (the id
``excite/DiffDriveCalibIdeal-v0``); :mod:`envs.physics` is the other, with slip and lag.

Frames and units: world frame x right, y up, theta counter-clockwise (rad, continuous);
body frame x forward, y left, origin at the axle midpoint (the reference point of every
pose). Meters, radians, seconds.
"""

from __future__ import annotations

import numpy as np

from envs.robot import RobotSpec
from excite.core.arena import Arena
from excite.core.kinematics import sinc_family


class IdealDrive:
    """Exact kinematics: no motor lag, no slip; each tick is an exact constant-curvature arc.

    When a tick would put the footprint into a wall, the robot stops for the rest of the
    call (both wheels stop, so the wheel increments still match the arc travelled) and a
    collision is reported. One robot; :func:`ideal_arcs` is the batch-first kernel it runs.
    """

    def __init__(self, arena: Arena, physics_hz: float) -> None:
        self.arena = arena
        self.dt = 1.0 / physics_hz
        self._robot: RobotSpec | None = None
        self._pose = np.zeros(3)
        self._phi = np.zeros(2)

    def reset(self, robot: RobotSpec, pose: np.ndarray, wheel_angles: np.ndarray) -> None:
        self._robot = robot
        self._pose = np.array(pose, dtype=float)
        self._phi = np.array(wheel_angles, dtype=float)

    @property
    def pose(self) -> np.ndarray:
        return self._pose.copy()

    @property
    def wheel_angles(self) -> np.ndarray:
        return self._phi.copy()

    def run(self, cmd_L: float, cmd_R: float,
            n_ticks: int) -> tuple[np.ndarray, np.ndarray, bool]:
        robot = self._robot
        paths, wheels, collided = ideal_arcs(
            self.arena, self.dt, self._pose[None], self._phi[None], np.array([[cmd_L, cmd_R]]),
            np.array([robot.max_wheel_speed]), np.array([robot.kinematic_params()]),
            [robot.chassis], n_ticks)
        self._pose = paths[0, -1].copy()
        self._phi = wheels[0, -1].copy()
        return paths[0], wheels[0], bool(collided[0])


def ideal_arcs(arena: Arena, dt: float, poses: np.ndarray, wheel_angles: np.ndarray,
               commands: np.ndarray, limits: np.ndarray, params: np.ndarray,
               chassis: list[tuple[float, float]], n_ticks: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """N robots rolling exactly along constant-curvature arcs for ``n_ticks`` ticks of ``dt`` s.

    poses (N, 3) world (x, y, theta); wheel_angles (N, 2) rad; commands (N, 2) wheel speeds
    (rad/s), clipped to +-limits (N,); params (N, 3) true (r_L, r_R, b) in m; chassis: each
    robot's (length, width) in m. A robot whose footprint would enter a wall stops there for
    the rest of the call. Returns the poses (N, n_ticks + 1, 3) and wheel angles
    (N, n_ticks + 1, 2) at every tick, the current ones first, and whether each robot hit a
    wall (N,).
    """
    limit = limits[:, None]
    omega = np.clip(commands, -limit, limit)
    t = np.arange(1, n_ticks + 1) * dt
    r_L, r_R, b = params[:, 0], params[:, 1], params[:, 2]
    v_L, v_R = r_L * omega[:, 0], r_R * omega[:, 1]
    ds = (0.5 * (v_L + v_R))[:, None] * t
    dth = ((v_R - v_L) / b)[:, None] * t
    sinc, cosc = sinc_family(dth, derivatives=False)
    bx, by = ds * sinc, ds * cosc
    x0, y0, th0 = (poses[:, i, None] for i in range(3))
    c, s = np.cos(th0), np.sin(th0)
    path = np.empty((len(poses), n_ticks + 1, 3))
    path[:, 0] = poses
    path[:, 1:, 0] = x0 + c * bx - s * by
    path[:, 1:, 1] = y0 + s * bx + c * by
    path[:, 1:, 2] = th0 + dth
    inside = np.empty((len(poses), n_ticks), dtype=bool)
    for footprint in set(chassis):
        rows = [i for i, c in enumerate(chassis) if c == footprint]
        ahead = path[rows, 1:]
        inside[rows] = arena.contains_footprint(ahead[..., 0], ahead[..., 1], ahead[..., 2],
                                                chassis=footprint)
    clear = inside.all(axis=1)
    ticks_done = np.where(clear, n_ticks, np.argmin(inside, axis=1))  # (N,)
    held = np.minimum(np.arange(n_ticks + 1), ticks_done[:, None])  # (N, n_ticks + 1)
    path = np.take_along_axis(path, held[:, :, None], axis=1)
    wheels = wheel_angles[:, None, :] + omega[:, None, :] * (held * dt)[:, :, None]
    return path, wheels, ~clear


class IdealBatchDrive:
    """N robots of :class:`IdealDrive` (the same kernel, :func:`ideal_arcs`), bit for bit."""

    def __init__(self, arena: Arena, physics_hz: float, n: int) -> None:
        self.arena = arena
        self.dt = 1.0 / physics_hz
        self.n = n
        self._poses = np.zeros((n, 3))
        self._phi = np.zeros((n, 2))
        self._limits = np.ones(n)
        self._params = np.ones((n, 3))
        self._chassis: list[tuple[float, float]] = [(1.0, 1.0)] * n

    def reset(self, i: int, robot: RobotSpec, pose: np.ndarray,
              wheel_angles: np.ndarray) -> None:
        """Place robot ``i`` at rest at world pose (x, y, theta) with wheel angles (rad)."""
        self._poses[i] = pose
        self._phi[i] = wheel_angles
        self._limits[i] = robot.max_wheel_speed
        self._params[i] = robot.kinematic_params()
        self._chassis[i] = robot.chassis

    def poses(self) -> np.ndarray:
        return self._poses.copy()

    @property
    def wheel_angles(self) -> np.ndarray:
        return self._phi.copy()

    def run(self, commands: np.ndarray, n_ticks: int, wheels: bool = False
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        paths, angles, collided = ideal_arcs(self.arena, self.dt, self._poses, self._phi,
                                             commands, self._limits, self._params,
                                             self._chassis, n_ticks)
        self._poses = paths[:, -1].copy()
        self._phi = angles[:, -1].copy()
        return self._poses.copy(), collided, angles.transpose(1, 0, 2).copy() if wheels else None
