"""A live calibration session without ROS: a made-up transport around a kinematic robot.

Replace ``ToyRobot`` by your robot's I/O (a serial port, a websocket, a vendor SDK): the
session only needs the wheel angles and the external poses with their stamps, and gives the
wheel speeds to command.

    python examples/live_session.py
"""

from __future__ import annotations

import numpy as np

from agents.catalog import make_protocol
from excite import Params
from excite.contracts import Traction
from excite.core.kinematics import predict_increment
from excite.core.se2 import compose
from excite.live import LiveResult, LiveSession, LiveSettings


class ToyRobot:
    """A robot whose true wheels differ from the nominal ones: it turns its wheels at the
    commanded speeds (rad/s), its encoders report the angles, a motion-capture system its
    pose (1 mm, 2 mrad noise). With a ``latency`` (s) the poses arrive that long after they
    were taken and are stamped on arrival (a pose source that stamps at receipt: pose time =
    true time + latency; ``excite live --time-offset`` is for that)."""

    def __init__(self, truth: Params, seed: int = 0, latency: float = 0.0) -> None:
        self.truth = truth
        self.rng = np.random.default_rng(seed)
        self.t, self.phi, self.pose = 0.0, np.zeros(2), np.zeros(3)
        self.speeds = np.zeros(2)
        self.latency, self.taken = latency, []

    def step(self, dt: float) -> None:
        dphi = self.speeds * dt
        increment = predict_increment(dphi[0], dphi[1], self.truth)
        self.pose = compose(self.pose, np.array(increment, dtype=float))
        self.phi += dphi
        self.t += dt
        if self.latency:
            self.taken.append(self._pose_now())

    def wheel_angles(self) -> tuple[float, float, float]:
        return self.t, *self.phi

    def measured_pose(self) -> tuple[float, float, float, float]:
        if not self.latency:
            return self._pose_now()
        while len(self.taken) > 1 and self.taken[1][0] <= self.t - self.latency + 1e-9:
            self.taken.pop(0)
        t, *pose = self.taken[0]
        return t + self.latency, *pose

    def _pose_now(self) -> tuple[float, float, float, float]:
        noise = self.rng.normal(0.0, [1e-3, 1e-3, 2e-3])
        return self.t, *(self.pose + noise)


def run(session: LiveSession, robot: ToyRobot, dt: float = 0.02,
        wheels_every: int = 1) -> LiveResult:
    """The transport's loop (every ``dt`` s, here as fast as the computer goes): the robot
    moves, the session gets its wheel angles (every ``wheels_every``-th tick: encoders
    slower than the loop) and its pose and gives the wheel speeds to command, until the
    session ends; then its result."""
    tick = 0
    while not session.ended:
        robot.step(dt)
        tick += 1
        if tick % wheels_every == 0:
            session.add_wheels(*robot.wheel_angles())
        session.add_pose(*robot.measured_pose())
        command = session.command(robot.t)
        robot.speeds = np.array([command.left, command.right])
    return session.finish()


def main() -> None:
    nominal = Params(0.05, 0.05, 0.30)
    robot = ToyRobot(Params(0.0505, 0.0497, 0.306))
    settings = LiveSettings(nominal=nominal, max_wheel_speed=20.0, target=0.005,
                            sensor_pose="axle", max_time=120.0,
                            traction=Traction(motor_tau=0.05, grip=5.0))
    result = run(LiveSession(settings, make_protocol("slip_aware"), seed=0), robot)
    print(f"{result.outcome} after {result.duration:.0f} s: {result.reason}")
    if result.calibration is not None:
        print(result.calibration.summary())
    print(f"truth: {robot.truth}")


if __name__ == "__main__":
    main()
