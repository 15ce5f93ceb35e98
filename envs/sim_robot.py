"""A simulated robot to rehearse a live session on: the pymunk robot (hidden wheel
parameters, motor lag, slip) driven by velocity commands as ROS 2's diff_drive_controller
drives a real one, read by wheel encoders and a motion-capture system.

Transport-agnostic (its ROS 2 node is :mod:`envs.ros2_robot`): :meth:`SimRobot.command`
takes a (v, omega) command at a time, :meth:`SimRobot.advance` runs the physics one tick and
says which readings are due.

- **The controller**: (v, omega) becomes wheel speeds with the NOMINAL geometry (the
  controller's configured radius and separation): omega_L = (v - omega b / 2) / r,
  omega_R = (v + omega b / 2) / r, each clipped to the motor limit; a command older than
  ``command_timeout`` (0.5 s, diff_drive_controller's cmd_vel_timeout) is replaced by zero.
- **Faults to rehearse** (``faults``): "ignore_commands" (the controller is not running),
  "swap_wheels" (the left command drives the right motor), "mirror_left" (the left motor
  turns backwards).
- **The readings**: the wheel angles (rad) at ``joint_hz`` and the pose of a rigid body
  mounted at ``mount`` (x, y, theta in the body frame) at ``pose_hz``, with Gaussian noise
  ``pose_sigma`` (m, rad) per reading.
- **The robot's own log** (:attr:`SimRobot.log`): for every tick the time, the true body
  pose, the last command received and when it arrived (simulated and wall-clock time);
  tests judge a session from it.

Units: m, rad, s; the world frame is the motion-capture frame; the robot starts at the
origin facing +x unless told otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from envs.physics import PymunkDrive
from envs.robot import RobotSpec
from excite.core import se2
from excite.core.arena import Arena

__all__ = ["FAULTS", "STREAMS", "Cut", "Readings", "SimRobot"]

#: The faults SimRobot can rehearse.
FAULTS = ("ignore_commands", "swap_wheels", "mirror_left")
#: The streams a Cut can silence.
STREAMS = ("pose", "joints")
#: m, the side of the simulated floor (its walls are far from any session).
FLOOR = 1000.0


@dataclass(frozen=True)
class Cut:
    """A stream ("pose" or "joints") silent from ``start`` s after the first command reached
    the robot, for ``duration`` s (simulated time)."""

    stream: str
    start: float
    duration: float

    def __post_init__(self) -> None:
        if self.stream not in STREAMS:
            raise ValueError(f"a cut's stream is one of {', '.join(STREAMS)}, got "
                             f"{self.stream!r}")
        if not (self.start >= 0 and self.duration > 0):
            raise ValueError(f"a cut needs START >= 0 and SECONDS > 0, got {self.start:g} and "
                             f"{self.duration:g}")

    def covers(self, t: float, first_command: float | None) -> bool:
        """Whether the cut silences its stream at time ``t`` (s) when the first command
        arrived at ``first_command`` (None: not yet)."""
        if first_command is None:
            return False
        return self.start <= t - first_command < self.start + self.duration


@dataclass(frozen=True)
class Readings:
    """The readings due after a tick: ``wheels`` (phi_L, phi_R in rad) or None, ``pose``
    (x, y, theta of the mounted body in m, rad, with noise) or None, at time ``t`` (s)."""

    t: float
    wheels: tuple[float, float] | None
    pose: tuple[float, float, float] | None


class SimRobot:
    """One simulated robot (see the module docstring).

    robot: the hidden truth (:class:`envs.robot.RobotSpec`); nominal: the controller's
    (r_L, r_R, b) in m; mount: the motion-capture body's pose on the robot (x, y, theta);
    pose_sigma: (xy in m, theta in rad) noise per pose reading; physics_hz, joint_hz, pose_hz
    (Hz); command_timeout (s); faults: a subset of :data:`FAULTS`; seed: the noise's seed;
    start: the body's start pose (x, y, theta).
    """

    def __init__(self, robot: RobotSpec, nominal: tuple[float, float, float],
                 mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 pose_sigma: tuple[float, float] = (1e-3, 2e-3), physics_hz: float = 100.0,
                 joint_hz: float = 50.0, pose_hz: float = 100.0, command_timeout: float = 0.5,
                 faults: tuple[str, ...] = (), seed: int = 0,
                 start: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        unknown = sorted(set(faults) - set(FAULTS))
        if unknown:
            raise ValueError(f"unknown faults {unknown}; known: {', '.join(FAULTS)}")
        for name, hz in (("physics_hz", physics_hz), ("joint_hz", joint_hz),
                         ("pose_hz", pose_hz)):
            if not (math.isfinite(hz) and hz > 0):
                raise ValueError(f"{name} must be finite and > 0, got {hz}")
        self.robot, self.nominal, self.faults = robot, tuple(nominal), frozenset(faults)
        self.mount = np.array(mount, dtype=float)
        self.pose_sigma = pose_sigma
        self.command_timeout = command_timeout
        self.rng = np.random.default_rng(seed)
        self.drive = PymunkDrive(Arena(FLOOR, FLOOR), physics_hz)
        self.drive.reset(robot, np.array(start, dtype=float), np.zeros(2))
        self.dt = self.drive.dt
        self._ticks = 0
        self._joint_every = max(int(round(physics_hz / joint_hz)), 1)
        self._pose_every = max(int(round(physics_hz / pose_hz)), 1)
        self._twist = (0.0, 0.0)
        self._received: float | None = None
        self._wall = math.nan
        #: When the first non-zero command arrived (s; None before).
        self.first_command: float | None = None
        self.log: list[tuple[float, ...]] = []

    @property
    def t(self) -> float:
        """The simulated time (s)."""
        return self._ticks * self.dt

    @property
    def pose(self) -> np.ndarray:
        """The true body (axle midpoint) pose (x, y, theta)."""
        return self.drive.pose

    def command(self, t: float, v: float, omega: float, wall: float = math.nan) -> None:
        """A (v in m/s, omega in rad/s) command arriving at time ``t`` (s; ``wall``: the
        wall-clock time, s since the epoch, for the log)."""
        self._twist, self._received, self._wall = (float(v), float(omega)), float(t), wall
        if self.first_command is None and (v != 0.0 or omega != 0.0):
            self.first_command = float(t)

    def wheel_commands(self) -> tuple[float, float]:
        """The wheel speeds (rad/s) the controller drives now (timeout, faults applied)."""
        if ("ignore_commands" in self.faults or self._received is None
                or self.t - self._received > self.command_timeout):
            return 0.0, 0.0
        r_L, r_R, b = self.nominal
        v, omega = self._twist
        limit = self.robot.max_wheel_speed
        left = float(np.clip((v - 0.5 * omega * b) / r_L, -limit, limit))
        right = float(np.clip((v + 0.5 * omega * b) / r_R, -limit, limit))
        if "swap_wheels" in self.faults:
            left, right = right, left
        if "mirror_left" in self.faults:
            left = -left
        return left, right

    def advance(self) -> Readings:
        """Run one physics tick; the readings due at its end."""
        left, right = self.wheel_commands()
        self.drive.run(left, right, 1)
        self._ticks += 1
        pose = self.drive.pose
        self.log.append((self.t, *pose, *self._twist,
                         math.nan if self._received is None else self._received, self._wall))
        wheels = pose_reading = None
        if self._ticks % self._joint_every == 0:
            phi = self.drive.wheel_angles
            wheels = (float(phi[0]), float(phi[1]))
        if self._ticks % self._pose_every == 0:
            sensor = se2.compose(pose, self.mount)
            sxy, sth = self.pose_sigma
            noisy = sensor + self.rng.normal(0.0, [sxy, sxy, sth])
            pose_reading = (float(noisy[0]), float(noisy[1]), float(noisy[2]))
        return Readings(self.t, wheels, pose_reading)

    def truth(self) -> dict:
        """The hidden truth as JSON: r_L, r_R, b (m) and the mount (m, m, rad)."""
        r = self.robot
        return {"r_L": r.r_L, "r_R": r.r_R, "b": r.b,
                "sensor_pose": dict(zip(("x", "y", "theta"), self.mount.tolist(), strict=True)),
                "nominal": dict(zip(("r_L", "r_R", "b"), self.nominal, strict=True)),
                "faults": sorted(self.faults)}

    def log_array(self) -> np.ndarray:
        """The robot's log (n, 8): t, x, y, theta (true body pose), v, omega (the last
        command received), the time it arrived (nan before any) and its wall-clock time."""
        return np.array(self.log, dtype=float).reshape(-1, 8)
