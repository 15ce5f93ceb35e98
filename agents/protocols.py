"""Calibration protocols: the one interface every policy implements, their declared
parameters, and the scripted maneuvers.

A protocol is reset with a random generator at the start of each episode and then asked for
one action per segment from what the robot knows (:class:`excite.contracts.RobotKnowledge`),
never the hidden truth. Actions are wheel-speed commands in [-1, 1]^2 (fractions of the motor
limit). Every protocol passes its plan through a wall guard: a command predicted (kinematic
model at the current estimate) to bring the chassis near a wall is replaced by a safe one.

Each protocol class declares its settings as :class:`Parameter` s (name, type, default, range,
meaning); ``Protocol(**settings)`` checks them and sets each as an attribute. This module is
light (numpy only): a planner can drive a real robot without the simulator.
"""

from __future__ import annotations

import math
import numbers
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from agents.motion import MARGIN, SPEED_MARGIN, safe_actions, turn_to_center
from excite.contracts import RobotKnowledge
from excite.errors import ExciteError, one_line_repr

#: A parameter's value.
Value = float | int | bool | str
_BOOLS = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False}


class ProtocolError(ExciteError, ValueError):
    """An unknown protocol or parameter, a bad value, or a protocol that cannot be built
    (e.g. a learned policy that cannot be loaded)."""


@dataclass(frozen=True)
class Parameter:
    """One declared setting of a protocol (``NAME:KEY=VALUE`` on the command line).

    kind: float, int, bool or str. default: the value when not set. meaning: one line, with
    units. low, high: the allowed range, inclusive (numbers only). grid: how many values of
    [low, high] ``excite tune`` tries (0: not tuned, the default is kept), evenly spaced, or
    evenly spaced in log (``log``: for a scale such as a speed, where 0.1 to 0.2 matters as
    much as 0.5 to 1).
    """

    name: str
    kind: type
    default: Value
    meaning: str
    low: float | None = None
    high: float | None = None
    grid: int = 0
    log: bool = False

    def check(self, value: object) -> Value:
        """``value`` as this parameter's kind (any real number for a float, any integer for
        an int, numpy's too), or ProtocolError if of another kind or out of range."""
        numeric = {float: numbers.Real, int: numbers.Integral}.get(self.kind)
        if numeric and isinstance(value, numeric) and not isinstance(value, bool | np.bool_):
            value = self.kind(value)
        elif self.kind is bool and isinstance(value, np.bool_):
            value = bool(value)
        if type(value) is not self.kind:
            raise ProtocolError(f"{self.name} must be {self.kind_name}, got {value!r}")
        if numeric and not (math.isfinite(value) and self.low <= value <= self.high):
            raise ProtocolError(f"{self.name} must be in [{self.format(self.low)}, "
                                f"{self.format(self.high)}], got {self.format(value)}")
        return value

    def parse(self, text: str) -> Value:
        """The value written ``text`` on the command line, checked."""
        if self.kind is bool:
            if text.lower() not in _BOOLS:
                raise ProtocolError(f"{self.name} must be true or false, got {text!r}")
            return _BOOLS[text.lower()]
        if self.kind is str:
            return text
        try:
            value = self.kind(text)
        except ValueError:
            raise ProtocolError(f"{self.name} must be {self.kind_name}, got {text!r}") from None
        return self.check(value)

    def format(self, value: Value) -> str:
        """``value`` as written on the command line (the shortest round-trip form)."""
        if isinstance(value, bool):
            return "true" if value else "false"
        if isinstance(value, float):
            return repr(value)
        return str(value)

    @property
    def kind_name(self) -> str:
        return {float: "a number", int: "a whole number", bool: "true or false",
                str: "text"}[self.kind]

    def tuning_values(self) -> tuple[Value, ...]:
        """The values ``excite tune`` tries: ``grid`` spaced over [low, high] (rounded to 2
        significant digits, as short labels), both booleans, or only the default when not
        tuned."""
        if self.grid == 0:
            return (self.default,)
        if self.kind is bool:
            return (False, True)
        spaced = np.geomspace if self.log else np.linspace
        values = (float(f"{v:.2g}") for v in spaced(self.low, self.high, self.grid))
        return tuple(dict.fromkeys(self.kind(round(v) if self.kind is int else v)
                                   for v in values))


#: The wall guard's clearance per unit of commanded speed, a setting of every protocol.
WALL_MARGIN = Parameter(
    "speed_margin", float, SPEED_MARGIN, "wall clearance the guard adds per unit of commanded "
    f"speed (m), beyond a fixed {MARGIN} m", 0.0, 0.7)
#: The commanded speed of a scripted maneuver.
SPEED = Parameter("speed", float, 0.5, "commanded wheel speed, fraction of the motor limit",
                  0.1, 1.0, grid=11, log=True)
#: The speed limit of a protocol that chooses its own commands.
MAX_SPEED = Parameter("max_speed", float, 1.0, "largest commanded wheel speed, fraction of "
                      "the motor limit", 0.1, 1.0, grid=11, log=True)


class Protocol(ABC):
    """One calibration protocol. Subclasses declare ``parameters`` and implement ``plan``;
    ``Protocol(**settings)`` sets every declared parameter as an attribute (settings not given
    take their defaults)."""

    parameters: ClassVar[tuple[Parameter, ...]] = (WALL_MARGIN,)
    #: The guard's clearance per unit of speed (m); a protocol that does not declare
    #: WALL_MARGIN keeps this default.
    speed_margin: float = SPEED_MARGIN

    def __init__(self, **settings: Value) -> None:
        self.settings = resolve_settings(type(self), settings)
        for name, value in self.settings.items():
            setattr(self, name, value)

    @classmethod
    def unavailable(cls, settings: Mapping[str, Value]) -> str | None:
        """Why this protocol cannot be built here with these (resolved) settings, in words,
        without building it; None when it can (e.g. a policy file is missing)."""
        return None

    @classmethod
    def fingerprint(cls, settings: Mapping[str, Value]) -> str | None:
        """A digest of the content of the files these (resolved) settings name, or None when
        they name none: a comparison resumed with the same settings but another file content
        (e.g. a policy retrained at the same path) must not reuse the old results."""
        return None

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode (``rng``: the episode's generator for any randomness)."""
        self.rng = rng
        self.step_index = 0

    def incompatibility(self, observation_shape: tuple[int, ...]) -> str | None:
        """Why this protocol cannot run on an environment with this observation shape, or
        None (every protocol that plans from the knowledge itself runs anywhere)."""
        return None

    def act(self, knowledge: RobotKnowledge) -> np.ndarray:
        """The action for the next segment (ProtocolError if ``plan`` returns no action)."""
        action = np.clip(check_action(self.plan(knowledge), "plan"), -1.0, 1.0)
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


def check_action(action: object, what: str = "act") -> np.ndarray:
    """``action`` as an array of two finite numbers, else ProtocolError saying what ``what``
    (the method that made it) returned: a NaN or a wrong shape must not reach the wall guard,
    which would silently replace it by a turn."""
    try:
        array = np.asarray(action, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (2,) or not np.isfinite(array).all():
        raise ProtocolError(f"{what} returned {one_line_repr(action)}, not an action (two "
                            "finite wheel-speed fractions, left and right)")
    return array


def resolve_settings(cls: type[Protocol], settings: Mapping[str, object]) -> dict[str, Value]:
    """Every declared parameter of ``cls`` with its value: the checked setting if given, else
    the default. ProtocolError names an undeclared key."""
    declared = {p.name: p for p in cls.parameters}
    for key in settings:
        if key not in declared:
            known = ", ".join(declared) or "none"
            raise ProtocolError(f"{cls.__name__} has no parameter {key!r} (its parameters: "
                                f"{known})")
    return {name: p.check(settings[name]) if name in settings else p.default
            for name, p in declared.items()}


class _AtSpeed(Protocol):
    """A scripted maneuver at one commanded speed (``speed``, fraction of the motor limit)."""

    parameters = (SPEED, WALL_MARGIN)
    speed: float


class Straight(_AtSpeed):
    """Back-and-forth straight runs (identifies r_L/r_R and the scale, never b)."""

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        direction = 1.0 if self.step_index % 2 == 0 else -1.0
        return np.array([direction * self.speed, direction * self.speed])


class Spin(_AtSpeed):
    """In-place rotations alternating direction (identifies r/b, never the scale)."""

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        direction = 1.0 if self.step_index % 2 == 0 else -1.0
        return np.array([-direction * self.speed, direction * self.speed])


class StraightSpin(_AtSpeed):
    """The lesson's minimal pair alternated: straight run, spin, back, spin back, ..."""

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

    parameters = (MAX_SPEED, WALL_MARGIN)
    max_speed: float

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        candidates = self.rng.uniform(-self.max_speed, self.max_speed, size=(20, 2))
        ok = safe_actions(candidates, knowledge, self.speed_margin)
        return candidates[int(np.argmax(ok))] if ok.any() else candidates[0]


class Arcs(_AtSpeed):
    """Arcs of varying curvature, alternating turn direction (figure-eights), both ways."""
    CURVATURES = (0.3, -0.3, 0.7, -0.7, 1.0, -1.0, 0.5, -0.5)

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        k = self.CURVATURES[self.step_index % len(self.CURVATURES)]
        direction = 1.0 if (self.step_index // len(self.CURVATURES)) % 2 == 0 else -1.0
        return direction * self.speed * np.array([1.0 - k, 1.0 + k])

