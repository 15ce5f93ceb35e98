"""One robot in the arena, driven segment by segment and measured like a calibration log.

Knows nothing of reinforcement learning: it composes a drive (`IdealDrive` or
`PymunkDrive`), wheel encoders and the external pose sensor. Units: meters, radians,
seconds. Poses are world (x, y, theta) of the axle midpoint with theta continuous; segment
increments are in the body frame at the segment's start (x forward, y left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from envs.ideal_drive import IdealBatchDrive, IdealDrive
from envs.physics import PymunkBatchDrive, PymunkDrive
from envs.robot import DEFAULT_CHASSIS_SIZE, RobotSpec
from envs.sensors import RelativePoseSensor, WheelEncoders
from excite.core import se2
from excite.core.arena import Arena

#: m, minimum distance from a random start position to the walls for the default robot's
#: 0.36 m chassis; other robots scale it with their chassis (`spawn_margin`).
SPAWN_MARGIN = 0.6


def spawn_margin(robot: RobotSpec) -> float:
    """Minimum distance (m) from a random start position (the axle midpoint) to the walls:
    SPAWN_MARGIN per 0.36 m of the chassis' longer side (5/3 of it), so any heading keeps the
    footprint (half-diagonal at most 0.71 of the longer side) well clear of the walls."""
    return SPAWN_MARGIN * (max(robot.chassis_length, robot.chassis_width) / DEFAULT_CHASSIS_SIZE)


class Drive(Protocol):
    """Moves one robot in the arena at a fixed tick: what a Simulation needs of its drive
    (:class:`envs.ideal_drive.IdealDrive`, :class:`envs.physics.PymunkDrive`)."""

    dt: float  # s, one physics tick

    def reset(self, robot: RobotSpec, pose: np.ndarray, wheel_angles: np.ndarray) -> None:
        """Place `robot` at rest at world pose (x, y, theta) with absolute wheel angles (rad)."""
        ...

    @property
    def pose(self) -> np.ndarray:
        """Current world pose (x, y, theta) of the axle midpoint, theta continuous."""
        ...

    @property
    def wheel_angles(self) -> np.ndarray:
        """Current absolute wheel angles (phi_L, phi_R) in rad, unquantized."""
        ...

    def run(self, cmd_L: float, cmd_R: float,
            n_ticks: int) -> tuple[np.ndarray, np.ndarray, bool]:
        """Hold wheel-speed commands (rad/s) for `n_ticks` ticks.

        Returns the world poses at every tick, shape (n_ticks + 1, 3) starting with the
        current pose, the absolute wheel angles (phi_L, phi_R) (rad, unquantized) at the same
        ticks, shape (n_ticks + 1, 2), and whether the chassis touched a wall.
        """
        ...


@dataclass(frozen=True)
class SimulationConfig:
    """Settings of the world and its sensors.

    Attributes:
        arena_width, arena_height: arena extent along world x and y (m), centred at the origin.
            Whether a robot fits is checked at `Simulation.reset` (it depends on the robot;
            `RobotDistribution.arena_size()` recommends a size).
        physics_hz: physics tick rate (Hz). 50 Hz resolves the 0.05 s motor lag (exactly
            discretized) and keeps throughput high; the traction solver is stable at any rate.
        ideal: roll without slip or lag (the kinematic model is exact) instead of pymunk.
        ticks_per_rev: encoder resolution (ticks per wheel revolution).
        sigma_xy, sigma_theta: pose sensor noise standard deviations (m, rad).
    """

    arena_width: float = 4.0
    arena_height: float = 4.0
    physics_hz: float = 50.0
    ideal: bool = False
    ticks_per_rev: int = 4096
    sigma_xy: float = 2e-3
    sigma_theta: float = 1e-3

    def __post_init__(self) -> None:
        if not (math.isfinite(self.physics_hz) and self.physics_hz > 0):
            raise ValueError(f"physics_hz must be finite and > 0, got {self.physics_hz}")
        for name in ("arena_width", "arena_height"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0 m, got {value}")
        WheelEncoders(self.ticks_per_rev)  # validate the sensor settings early
        RelativePoseSensor(self.sigma_xy, self.sigma_theta)


@dataclass(frozen=True, eq=False)
class SegmentOutcome:
    """What one segment produced (all arrays read-only).

    Attributes:
        measurement: (5,) the CSV row dphi_L, dphi_R (quantized encoder increments, rad),
            dx, dy (m), dtheta (rad) (noisy relative pose in the start body frame).
        true_increment: (3,) true dx, dy (m), dtheta (rad, continuous).
        true_dphi: (2,) unquantized wheel angle increments (rad).
        collision: whether the chassis touched a wall during the segment.
        pose_start, pose_end: (3,) world poses (x, y, theta), theta continuous.
        path: (M, 3) world poses at every physics tick, pose_start first and pose_end last.
        wheel_path: (M, 2) absolute wheel angles (phi_L, phi_R) (rad, unquantized) at the
            same ticks.
    """

    measurement: np.ndarray
    true_increment: np.ndarray
    true_dphi: np.ndarray
    collision: bool
    pose_start: np.ndarray
    pose_end: np.ndarray
    path: np.ndarray
    wheel_path: np.ndarray


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def start_state(arena: Arena, robot: RobotSpec, rng: np.random.Generator,
                pose: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A robot's start: world pose (x, y, theta) and absolute wheel angles (rad), drawn from
    ``rng`` in a fixed order (see :meth:`Simulation.reset`, whose errors it raises)."""
    if not robot.fits_chassis():
        raise ValueError(
            f"robot does not fit its {robot.chassis_length} x {robot.chassis_width} m "
            f"chassis (length x width): b={robot.b}, com_offset={robot.com_offset}"
        )
    if pose is None:
        margin = spawn_margin(robot)
        half = np.array([arena.width, arena.height]) / 2 - margin
        if not (half > 0).all():
            raise ValueError(
                f"the {arena.width} x {arena.height} m arena is too small for "
                f"this robot's {robot.chassis_length} x {robot.chassis_width} m chassis: a "
                f"random start needs more than {2 * margin:.3g} m (RobotDistribution."
                f"arena_size() recommends a size)"
            )
        pose = np.append(rng.uniform(-half, half), rng.uniform(-math.pi, math.pi))
    else:
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (3,) or not np.isfinite(pose).all():
            raise ValueError(f"pose must be 3 finite numbers (x, y, theta), got {pose}")
        if not arena.contains_footprint(pose[0], pose[1], pose[2], chassis=robot.chassis):
            raise ValueError(f"pose {pose} puts the chassis outside the arena")
    wheel_angles = rng.uniform(0.0, 2.0 * math.pi, 2)
    return pose, wheel_angles


class _World:
    """The arena and the sensors of a simulation (one robot or N), and segment timing."""

    def __init__(self, config: SimulationConfig | None = None) -> None:
        self.config = config or SimulationConfig()
        self.arena = Arena(self.config.arena_width, self.config.arena_height)
        self.encoders = WheelEncoders(self.config.ticks_per_rev)
        self.pose_sensor = RelativePoseSensor(self.config.sigma_xy, self.config.sigma_theta)
        self.dt = 1.0 / self.config.physics_hz  # s, one physics tick

    def _ticks(self, seconds: float, name: str, minimum: int) -> int:
        ticks = seconds * self.config.physics_hz if math.isfinite(seconds) else -1.0
        n = round(ticks)
        if n < minimum or abs(ticks - n) > 1e-9 * max(n, 1):
            raise ValueError(
                f"{name} must be a {'positive' if minimum else 'non-negative'} multiple of the "
                f"physics tick {self.dt} s, got {seconds}"
            )
        return n


class Simulation(_World):
    """A robot in a walled arena, run in motion segments with fixed wheel-speed commands.

    `reset` must be called before `run_segment`. Noise is drawn from the generator given to
    `reset`, so the same robot, seed and commands give bit-identical outcomes.
    """

    def __init__(self, config: SimulationConfig | None = None) -> None:
        super().__init__(config)
        drive_type = IdealDrive if self.config.ideal else PymunkDrive
        self.drive: Drive = drive_type(self.arena, self.config.physics_hz)
        self._robot: RobotSpec | None = None
        self._rng: np.random.Generator | None = None

    def reset(
        self,
        robot: RobotSpec,
        rng: np.random.Generator,
        pose: np.ndarray | None = None,
    ) -> None:
        """Place `robot` at rest and keep `rng` for all later noise.

        pose: world (x, y, theta); None draws one from `rng`, at least `spawn_margin(robot)`
        from the walls, heading uniform in [-pi, pi). Wheel angles start at random (uniform in
        [0, 2 pi)) so encoder quantization is not aligned with the start.

        Raises ValueError when the robot does not fit its own chassis (b < chassis width,
        |com_offset| < half its length), when a random start needs a wider arena
        (2 spawn margins) or when the given pose puts the chassis outside the arena.
        """
        pose, wheel_angles = start_state(self.arena, robot, rng, pose)
        self.drive.reset(robot, pose, wheel_angles)
        self._robot = robot
        self._rng = rng

    def run_segment(
        self, cmd_L: float, cmd_R: float, duration: float, settle: float = 0.0
    ) -> SegmentOutcome:
        """Hold wheel-speed commands (rad/s, clipped to the motor limit) for `duration` s,
        then command zero for `settle` s (stop-and-go), all measured as one segment.

        Starting and ending at rest, both wheels follow the same lag shape, so their speed
        ratio, and the path's curvature, stay constant: without slip the segment is exactly
        the kinematic model's arc. duration and settle must be whole numbers of physics ticks.
        """
        if self._robot is None:
            raise RuntimeError("Simulation.reset must be called before run_segment")
        if not (math.isfinite(cmd_L) and math.isfinite(cmd_R)):
            raise ValueError(f"wheel commands must be finite, got {(cmd_L, cmd_R)}")
        n_ticks = self._ticks(duration, "duration", minimum=1)
        n_settle = self._ticks(settle, "settle", minimum=0)
        phi_start = self.drive.wheel_angles
        path, wheels, collision = self.drive.run(float(cmd_L), float(cmd_R), n_ticks)
        if n_settle:
            stop_path, stop_wheels, stop_collision = self.drive.run(0.0, 0.0, n_settle)
            path = np.concatenate([path, stop_path[1:]])
            wheels = np.concatenate([wheels, stop_wheels[1:]])
            collision = collision or stop_collision
        phi_end = self.drive.wheel_angles
        true_increment = se2.between_scalar(path[0], path[-1])
        measurement = np.concatenate([self.encoders.increments(phi_start, phi_end),
                                      self.pose_sensor.measure(true_increment, self._rng)])
        return SegmentOutcome(
            measurement=_read_only(measurement),
            true_increment=_read_only(true_increment),
            true_dphi=_read_only(phi_end - phi_start),
            collision=collision,
            pose_start=_read_only(path[0].copy()),
            pose_end=_read_only(path[-1].copy()),
            path=_read_only(path),
            wheel_path=_read_only(wheels),
        )

    @property
    def pose(self) -> np.ndarray:
        """Current world pose (x, y, theta) of the axle midpoint, theta continuous."""
        return self.drive.pose

    @property
    def wheel_angles(self) -> np.ndarray:
        """Current absolute (unquantized) wheel angles (phi_L, phi_R) in rad."""
        return self.drive.wheel_angles

    @property
    def robot(self) -> RobotSpec:
        """The hidden robot set by the last `reset`."""
        if self._robot is None:
            raise RuntimeError("Simulation.reset has not been called")
        return self._robot


@dataclass(frozen=True, eq=False)
class BatchOutcome:
    """What one segment produced on each of N robots (the fields of :class:`SegmentOutcome`
    stacked on a first axis of N, without the per-tick paths)."""

    measurement: np.ndarray  # (N, 5)
    true_increment: np.ndarray  # (N, 3)
    collision: np.ndarray  # (N,) bool
    pose_start: np.ndarray  # (N, 3)
    pose_end: np.ndarray  # (N, 3)
    wheel_path: np.ndarray | None = None  # (M, N, 2) wheel angles at every tick, when asked


class BatchSimulation(_World):
    """N robots in one arena (they never touch each other), run segment by segment together.

    Robot i reset with a robot, a generator and a pose draws and measures exactly as a
    :class:`Simulation` reset with the same arguments (same start draws, same noise draws);
    the physics is the same kernel on arrays (:class:`envs.physics.PymunkBatchDrive`,
    :class:`envs.ideal_drive.IdealBatchDrive`).
    """

    def __init__(self, config: SimulationConfig | None = None, n: int = 1) -> None:
        super().__init__(config)
        if not isinstance(n, int | np.integer) or n < 1:
            raise ValueError(f"the number of robots must be a positive integer, got {n!r}")
        self.n = int(n)
        drive_type = IdealBatchDrive if self.config.ideal else PymunkBatchDrive
        self.drive = drive_type(self.arena, self.config.physics_hz, self.n)
        self._robots: list[RobotSpec | None] = [None] * self.n
        self._rngs: list[np.random.Generator | None] = [None] * self.n

    def reset(self, i: int, robot: RobotSpec, rng: np.random.Generator,
              pose: np.ndarray | None = None) -> None:
        """Place robot ``i`` at rest and keep ``rng`` for its noise (as Simulation.reset)."""
        pose, wheel_angles = start_state(self.arena, robot, rng, pose)
        self.drive.reset(i, robot, pose, wheel_angles)
        self._robots[i] = robot
        self._rngs[i] = rng

    def run_segment(self, commands: np.ndarray, duration: float,
                    settle: float = 0.0, wheels: bool = False) -> BatchOutcome:
        """Hold wheel-speed commands (N, 2) (rad/s, clipped to each motor's limit) for
        ``duration`` s, then zero for ``settle`` s, on every robot (as Simulation.run_segment);
        with ``wheels``, the outcome holds the wheel angles at every tick (as
        SegmentOutcome.wheel_path, on a second axis of N)."""
        if any(robot is None for robot in self._robots):
            raise RuntimeError("BatchSimulation.reset must be called for every robot first")
        commands = np.asarray(commands, dtype=float)
        if commands.shape != (self.n, 2) or not np.isfinite(commands).all():
            raise ValueError(f"wheel commands must be finite, shape ({self.n}, 2)")
        n_ticks = self._ticks(duration, "duration", minimum=1)
        n_settle = self._ticks(settle, "settle", minimum=0)
        phi_start = self.drive.wheel_angles
        pose_start = self.drive.poses()
        pose_end, collision, path = self.drive.run(commands, n_ticks, wheels)
        if n_settle:
            pose_end, stopped, stop_path = self.drive.run(np.zeros_like(commands), n_settle,
                                                          wheels)
            collision = collision | stopped
            if path is not None and stop_path is not None:
                path = np.concatenate([path, stop_path[1:]])
        phi_end = self.drive.wheel_angles
        true_increment = se2.between(pose_start, pose_end)
        measurement = self._measure(phi_start, phi_end, true_increment, self._rngs)
        return BatchOutcome(measurement, true_increment, collision, pose_start, pose_end, path)

    def _measure(self, phi_start: np.ndarray, phi_end: np.ndarray, true_increment: np.ndarray,
                 rngs: list[np.random.Generator]) -> np.ndarray:
        """The calibration rows (N, 5) (dphi_L, dphi_R, dx, dy, dtheta) of N segments, as
        Simulation.run_segment measures one: wheel angles (N, 2) at the start and end, true
        increments (N, 3), one generator per robot."""
        rows = np.empty((len(rngs), 5))
        rows[:, :2] = self.encoders.increments(phi_start, phi_end)
        rows[:, 2:] = self.pose_sensor.each(true_increment, rngs)
        return rows

    @property
    def poses(self) -> np.ndarray:
        """Current world poses (N, 3) of the axle midpoints."""
        return self.drive.poses()
