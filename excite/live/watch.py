"""Does the robot do what it is told? The live session's check of the wheels against the
commands.

A robot whose controller is not running does not move when commanded; one with wrong or
swapped wheel names, or a mirrored motor, moves against the command. Either way a planner
that believes its commands drives the robot blind, so the session stops it. The wheels'
measured speeds (from the wheel angles) are compared with the commanded ones once the
command has been held for a while (the motors' lag and the controller's ramps settle in the
``response_time``, so a command is judged once it has been held steady for
``response_time`` plus a ``window`` over which the wheels' mean speed is measured):

- *not turning*: both wheels turn at less than 20% of the command;
- *faster than the command*: the wheels turn more than FASTER times the fastest command
  held over the window (a ramp of commands within STEADY may end above their mean), at a
  settled speed (the window's two halves within STEADY of the limit of each other: a
  robot still slowing down after a lower command turns faster than it for a while), which is
  a controller whose wheel radii or separation differ from the nominal ones, or that scales
  the commands: the robot would drive faster than the planner and the stopping guard
  believe;
- *against the command*: the measured speeds fit a swapped, mirrored or swapped-and-mirrored
  command far better (half the residual or less) than the command itself, which they miss
  by more than half its size.

A straight command cannot tell swapped wheels from the right ones, and then need not: the
robot does what it is told.

Units: s, rad, rad/s.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable

import numpy as np

__all__ = ["MotionFault", "MotionWatch"]

#: The smallest commanded wheel speed (share of the command limit) the check judges.
MIN_COMMAND = 0.1
#: Commands count as one steady command while they stay within this share of the limit.
STEADY = 0.1
#: Below this share of the command the wheels count as not turning.
STALLED = 0.2
#: Above this multiple of the command the wheels turn too fast (a calibration moves the wheel
#: geometry by a few percent; a controller of another robot's by far more: the Husky's radius
#: is 1.68 times the Jackal's, the default robot's 1.5 times the TurtleBot3's).
FASTER = 1.4
#: The wirings the measured speeds are compared with, as (name, matrix on (left, right)).
WIRINGS = (
    ("the left and right wheels are swapped", np.array([[0.0, 1.0], [1.0, 0.0]])),
    ("the left wheel turns backwards (mirrored motor or joint)", np.diag([-1.0, 1.0])),
    ("the right wheel turns backwards (mirrored motor or joint)", np.diag([1.0, -1.0])),
    ("both wheels turn backwards", np.diag([-1.0, -1.0])),
    ("the wheels are swapped and turn backwards", np.array([[0.0, -1.0], [-1.0, 0.0]])),
)


class MotionFault(str):
    """A one-line description of how the wheels fail to follow the command."""


class MotionWatch:
    """Compares the measured wheel speeds with the commanded ones (see the module docstring).

    window: how long (s) the wheels are watched for one judgement; response_time: how long
    (s) the controller and the motors take to follow a command (the commands are compared
    that much earlier than the wheels); command_speed: the largest commanded wheel speed
    (rad/s).
    """

    def __init__(self, window: float, response_time: float, command_speed: float) -> None:
        self.window = window
        self.response_time = response_time
        self.command_speed = command_speed
        self._t: list[float] = []
        self._commands: list[tuple[float, float]] = []

    def commanded(self, t: float, left: float, right: float) -> None:
        """The wheel speeds (rad/s) commanded from time ``t`` (s) on."""
        if self._commands and self._commands[-1] == (left, right):
            return
        self._t.append(t)
        self._commands.append((left, right))

    def _steady_commands(self, start: float, end: float) -> np.ndarray | None:
        """The commands (k, 2) (rad/s) in force over [start, end], when each is within
        STEADY of the limit of the others; None before the first command or while it
        changes (the wheels' response is then not known well enough to judge)."""
        if not self._t or start < self._t[0]:
            return None
        first = bisect.bisect_right(self._t, start) - 1
        last = bisect.bisect_right(self._t, end)
        held = np.array(self._commands[first:last])
        if np.ptp(held, axis=0).max() > STEADY * self.command_speed:
            return None
        return held

    def check(self, t: float, wheel_angles: Callable[[float], np.ndarray | None]
              ) -> MotionFault | None:
        """The fault at time ``t`` (s), if any, judged up to ``t`` (the latest wheel sample,
        as the readings arrive later than they are stamped). wheel_angles(t): the wheels'
        angles (rad) at a time, or None where not measured."""
        lag, window = self.response_time, self.window
        held = self._steady_commands(t - window - lag, t)
        if held is None:
            return None
        command = held.mean(axis=0)
        if float(np.abs(command).max()) < MIN_COMMAND * self.command_speed:
            return None
        start, middle, end = (wheel_angles(t - window), wheel_angles(t - 0.5 * window),
                              wheel_angles(t))
        if start is None or end is None:
            return None
        settled = middle is not None and float(np.max(np.abs(
            (end - middle) - (middle - start)))) / (0.5 * window) <= STEADY * self.command_speed
        fastest = held[int(np.argmax(np.linalg.norm(held, axis=1)))]
        return judge(command, (end - start) / window, settled, fastest)


def judge(command: np.ndarray, measured: np.ndarray, settled: bool = True,
          fastest: np.ndarray | None = None) -> MotionFault | None:
    """The fault of wheels turning at ``measured`` (rad/s, left and right) under
    ``command`` (rad/s, the mean of the commands held over the window), or None when they
    follow it; ``settled``: the wheels' speed held over the window (only then is a speed
    above the command a fault); ``fastest``: the fastest of the commands held (rad/s; by
    default ``command``), the speed the wheels may have reached."""
    size = float(np.linalg.norm(command))
    if np.linalg.norm(measured) < STALLED * size:
        return MotionFault(
            f"the wheels do not turn (commanded {command[0]:.2f}, {command[1]:.2f} rad/s, "
            f"measured {measured[0]:.2f}, {measured[1]:.2f}): is the controller running and "
            "listening on the command topic?")
    top = command if fastest is None else fastest
    ratio = float(np.linalg.norm(measured)) / float(np.linalg.norm(top))
    if settled and ratio > FASTER:
        return MotionFault(
            f"the wheels turn {ratio:.2f} times the commanded speed (commanded {top[0]:.2f}, "
            f"{top[1]:.2f} rad/s, measured {measured[0]:.2f}, {measured[1]:.2f}): the "
            "controller's wheel radii or separation are not the nominal ones (--robot, "
            "--nominal), or it scales the commands; the robot would drive faster than planned")
    miss = float(np.linalg.norm(measured - command))
    if miss <= 0.5 * size:
        return None
    fits = [(float(np.linalg.norm(measured - m @ command)), name) for name, m in WIRINGS]
    best, name = min(fits)
    if best <= 0.5 * miss:
        return MotionFault(
            f"the robot moves against the command: {name} (commanded {command[0]:.2f}, "
            f"{command[1]:.2f} rad/s, measured {measured[0]:.2f}, {measured[1]:.2f}); check "
            "--left-wheel, --right-wheel and the controller's wheel names")
    return None
