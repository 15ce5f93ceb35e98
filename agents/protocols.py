"""Calibration protocols: scripted maneuvers, and the one interface every policy implements.

A protocol is reset with a random generator at the start of each episode and then asked for
one action per segment from what the robot knows (:class:`envs.env.RobotKnowledge`), never the
hidden truth. Actions are wheel-speed commands in [-1, 1]^2 (fractions of the motor limit).
Every scripted protocol passes its plan through a wall guard: a command predicted (kinematic
model at the current estimate) to bring the chassis near a wall is replaced by a safe one.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from agents.motion import SPEED_MARGIN, safe_actions, turn_to_center
from excite.contracts import RobotKnowledge


class Protocol(ABC):
    """One calibration protocol. Subclasses set ``name`` and implement ``plan``."""

    name: ClassVar[str]
    #: Wall clearance per unit of commanded speed (m) the guard demands (agents.motion).
    speed_margin: ClassVar[float] = SPEED_MARGIN

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode (``rng``: the episode's generator for any randomness)."""
        self.rng = rng
        self.step_index = 0

    def incompatibility(self, observation_shape: tuple[int, ...]) -> str | None:
        """Why this protocol cannot run on an environment with this observation shape, or
        None (every protocol that plans from the knowledge itself runs anywhere)."""
        return None

    def act(self, knowledge: RobotKnowledge) -> np.ndarray:
        """The action for the next segment."""
        action = np.clip(np.asarray(self.plan(knowledge), dtype=float), -1.0, 1.0)
        self.step_index += 1
        return self.guard(action, knowledge)

    @abstractmethod
    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        """The protocol's intended action, before the wall guard."""

    def guard(self, action: np.ndarray, knowledge: RobotKnowledge) -> np.ndarray:
        """Keep the robot off the walls: the action if safe, else a safe variant of it (the
        same maneuver reversed, then shortened), else a turn towards the centre."""
        variants = np.array([action, -action, 0.5 * action, -0.5 * action, 0.25 * action])
        ok = safe_actions(variants, knowledge, self.speed_margin)
        return variants[int(np.argmax(ok))] if ok.any() else turn_to_center(knowledge)


class _AtSpeed(Protocol):
    """A scripted maneuver at one commanded speed (fraction of the motor limit)."""

    def __init__(self, speed: float = 0.5):
        self.speed = speed


class Straight(_AtSpeed):
    """Back-and-forth straight runs (identifies r_L/r_R and the scale, never b)."""

    name = "straight"

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        direction = 1.0 if self.step_index % 2 == 0 else -1.0
        return np.array([direction * self.speed, direction * self.speed])


class Spin(_AtSpeed):
    """In-place rotations alternating direction (identifies r/b, never the scale)."""

    name = "spin"

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        direction = 1.0 if self.step_index % 2 == 0 else -1.0
        return np.array([-direction * self.speed, direction * self.speed])


class StraightSpin(_AtSpeed):
    """The lesson's minimal pair alternated: straight run, spin, back, spin back, ..."""

    name = "straight_spin"

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        phase = self.step_index % 4
        direction = 1.0 if phase < 2 else -1.0
        if phase % 2 == 0:
            return np.array([direction * self.speed, direction * self.speed])
        return np.array([-direction * self.speed, direction * self.speed])


class UMBmark(_AtSpeed):
    """Borenstein & Feng's bidirectional square: one straight segment per side, one 90-degree
    in-place turn per corner; a clockwise square, then a counter-clockwise one, repeated.

    The side length is the distance one segment covers at ``speed`` (0.5 m at the defaults),
    the square fitting the 4 m arena; the turn speed gives 90 degrees per segment at the
    nominal robot.
    """

    name = "umbmark"

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        phase = self.step_index % 16  # 8 segments a square: 4 sides, 4 corners
        turn_sign = -1.0 if phase < 8 else 1.0  # clockwise first
        if phase % 2 == 0:
            return np.array([self.speed, self.speed])
        nominal = knowledge.nominal
        wheel = (math.pi / 2) * (nominal.b / 2) / nominal.r_L / knowledge.segment_duration
        turn = wheel / knowledge.max_wheel_speed
        return np.array([-turn_sign * turn, turn_sign * turn])


class RandomCommands(Protocol):
    """Uniform random commands, redrawn (up to 20 times) until predicted clear of the walls."""

    name = "random"

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        candidates = self.rng.uniform(-1.0, 1.0, size=(20, 2))
        ok = safe_actions(candidates, knowledge)
        return candidates[int(np.argmax(ok))] if ok.any() else candidates[0]


class Arcs(_AtSpeed):
    """Arcs of varying curvature, alternating turn direction (figure-eights), both ways."""

    name = "arcs"
    CURVATURES = (0.3, -0.3, 0.7, -0.7, 1.0, -1.0, 0.5, -0.5)

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        k = self.CURVATURES[self.step_index % len(self.CURVATURES)]
        direction = 1.0 if (self.step_index // len(self.CURVATURES)) % 2 == 0 else -1.0
        return direction * self.speed * np.array([1.0 - k, 1.0 + k])


SCRIPTED: dict[str, type[Protocol]] = {
    cls.name: cls for cls in (Straight, Spin, StraightSpin, UMBmark, RandomCommands, Arcs)
}
