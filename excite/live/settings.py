"""What a live session is told before it starts: the nominal robot, its limits, the area,
the target and the watchdogs' times. Strict: every value is checked when it is built.

Units: m, rad, s; wheel speeds in rad/s, wheel accelerations in rad/s^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from excite.calibration.options import SensorPoseOption
from excite.contracts import Traction
from excite.core.arena import DEFAULT_CHASSIS
from excite.core.kinematics import Params
from excite.live.area import Area
from excite.stopping import DEFAULT_CONFIDENCE, DEFAULT_TARGET

__all__ = ["DEFAULT_SIGMA", "LiveSettings", "LiveTopics"]

#: The pose noise (m, m, rad) the planner assumes until the calibration has estimated it.
DEFAULT_SIGMA = (2e-3, 2e-3, 1e-3)
#: s, the shortest maneuver: a robot follows a command within a tenth of a second or more.
MIN_SEGMENT_DURATION = 0.1


def _positive(name: str, value: float, allow_inf: bool = False) -> None:
    ok = isinstance(value, (int, float)) and value > 0 and (
        math.isfinite(value) or (allow_inf and value == math.inf))
    if not ok:
        raise ValueError(f"{name} must be {'> 0' if allow_inf else 'finite and > 0'}, "
                         f"got {value!r}")


@dataclass(frozen=True)
class LiveSettings:
    """The settings of a :class:`excite.live.session.LiveSession`.

    Attributes
    ----------
    nominal : Params
        The nominal wheel radii r_L, r_R and separation b (m): the planner's start, and how
        wheel speeds become (v, omega) on ``/cmd_vel``.
    max_wheel_speed : float
        The wheels' speed limit (rad/s).
    speed_fraction : float
        The share of ``max_wheel_speed`` the protocol may command, in (0, 1].
    segment_duration : float
        How long each of the protocol's commands is held (s); also the window the session's
        log is cut into, as ``excite calibrate --window``.
    area : Area or None
        Where the robot may go (pose frame); None: ``area_size`` (or ``radius``) around the
        start pose.
    radius : float or None
        Without ``area``: the robot stays within this distance (m) of its start (the largest
        square inside that circle). None: a square of side ``area_size``.
    area_size : float
        Without ``area`` or ``radius``: the side (m) of the square centred on the start.
    chassis : (float, float)
        The nominal footprint (length along body x, width along body y) in m.
    traction : Traction or None
        The nominal motor lag and grip, for a planner that plans around slip.
    max_wheel_acceleration : float
        The largest change of a wheel's commanded speed (rad/s^2); inf: step commands.
    target, confidence : float
        The stopping rule's target (relative error of r_L, r_R, b) and confidence.
    max_time : float
        The session ends *out of time* after this long (s) of driving.
    sensor_pose : "auto", "axle", "estimate" or SensorPose
        Where the pose sensor sits on the robot (:func:`excite.calibrate`).
    sigma : (float, float, float)
        The pose noise (m, m, rad) the planner assumes until the calibration estimates it.
    silence_timeout : float
        Stop the robot when the pose or the wheel angles have been silent this long (s).
    abort_timeout : float
        Abort when a silence lasts this long (s).
    motion_window : float
        The wheels' mean speeds over this long (s) are compared with the mean command: the
        session aborts when they do not turn at all (no controller), or turn as if swapped or
        mirrored (:mod:`excite.live.watch`).
    response_time : float
        How long (s) the controller and motors take to follow a command.
    time_offset : float or "estimate"
        The clock offset of the pose stamps (s; pose time + time_offset = wheel time), as
        ``excite calibrate --time-offset``: the session's log is cut with it; "estimate"
        (default) estimates it from the log so far at every look
        (:func:`excite.logs.time_offset.estimate_time_offset`, as ``excite calibrate
        --time-offset estimate``; 0 while the log cannot give one, *not yet* while it lies
        beyond the search range: :func:`excite.live.log.clock_offset`). A pose source that
        stamps at receipt lags the wheels, and a lag cut with 0 makes false stops.
    """

    nominal: Params
    max_wheel_speed: float
    speed_fraction: float = 1.0
    segment_duration: float = 1.0
    area: Area | None = None
    radius: float | None = None
    area_size: float = 4.0
    chassis: tuple[float, float] = DEFAULT_CHASSIS
    traction: Traction | None = None
    max_wheel_acceleration: float = math.inf
    target: float = DEFAULT_TARGET
    confidence: float = DEFAULT_CONFIDENCE
    max_time: float = 600.0
    sensor_pose: SensorPoseOption = "auto"
    sigma: tuple[float, float, float] = DEFAULT_SIGMA
    silence_timeout: float = 0.5
    abort_timeout: float = 10.0
    motion_window: float = 0.5
    response_time: float = 0.2
    time_offset: float | Literal["estimate"] = "estimate"

    def __post_init__(self) -> None:
        if not isinstance(self.nominal, Params):
            raise ValueError(f"nominal must be Params (r_L, r_R, b in m), got {self.nominal!r}")
        if not all(math.isfinite(v) and v > 0 for v in self.nominal.as_array()):
            raise ValueError(f"the nominal r_L, r_R, b must be finite and > 0 (m), got "
                             f"{tuple(self.nominal.as_array())}")
        for name in ("max_wheel_speed", "segment_duration", "area_size", "silence_timeout",
                     "abort_timeout", "motion_window", "response_time"):
            _positive(name, getattr(self, name))
        for name in ("max_wheel_acceleration", "max_time"):
            _positive(name, getattr(self, name), allow_inf=True)
        if self.segment_duration > self.max_time:
            raise ValueError(f"segment_duration ({self.segment_duration:g} s) must be at most "
                             f"max_time ({self.max_time:g} s): a session of one unfinished "
                             "maneuver never decides")
        if not (isinstance(self.speed_fraction, (int, float)) and 0 < self.speed_fraction <= 1):
            raise ValueError(f"speed_fraction must be in (0, 1], got {self.speed_fraction!r}")
        if self.time_offset != "estimate" and not (
                isinstance(self.time_offset, (int, float)) and math.isfinite(self.time_offset)):
            raise ValueError(f"time_offset must be finite (s) or 'estimate', got "
                             f"{self.time_offset!r}")
        if self.radius is not None:
            _positive("radius", self.radius)
        if self.area is not None and self.radius is not None:
            raise ValueError("give the area or a radius around the start, not both")
        if not (0 < self.target < 1):
            raise ValueError(f"target must be a relative error in (0, 1), got {self.target!r}")
        if not (0 < self.confidence < 1):
            raise ValueError(f"confidence must be in (0, 1), got {self.confidence!r}")
        sigma = np.asarray(self.sigma, dtype=float)
        if sigma.shape != (3,) or not np.all(np.isfinite(sigma) & (sigma > 0)):
            raise ValueError(f"sigma must be three positive numbers (m, m, rad), got "
                             f"{self.sigma!r}")
        if self.abort_timeout < self.silence_timeout:
            raise ValueError("abort_timeout must be at least silence_timeout")
        if self.response_time >= self.abort_timeout:
            raise ValueError(f"response_time ({self.response_time:g} s) must be shorter than "
                             f"abort_timeout ({self.abort_timeout:g} s): a controller that "
                             "slow cannot be watched")
        if self.segment_duration < MIN_SEGMENT_DURATION:
            raise ValueError(f"segment_duration must be at least {MIN_SEGMENT_DURATION:g} s "
                             f"(a maneuver the robot can follow), got {self.segment_duration:g}")

    @property
    def command_speed(self) -> float:
        """The largest wheel speed the protocol commands (rad/s)."""
        return self.max_wheel_speed * self.speed_fraction

    def area_at(self, start: np.ndarray) -> Area:
        """The safe area for a session whose body starts at pose ``start`` (x, y, theta)."""
        if self.area is not None:
            return self.area
        center = (float(start[0]), float(start[1]))
        if self.radius is not None:
            return Area.around(center, self.radius)
        return Area.square(center, self.area_size)

    def twist(self, left: float, right: float) -> tuple[float, float]:
        """Wheel speeds (rad/s) as (v in m/s, omega in rad/s) with the nominal geometry, the
        inverse of what diff_drive_controller does with the same radii and separation."""
        r_L, r_R, b = self.nominal.as_array()
        return 0.5 * (r_R * right + r_L * left), (r_R * right - r_L * left) / b


@dataclass(frozen=True)
class LiveTopics:
    """The node's topics and names: joint_states (JointState), left_wheel and right_wheel (joint
    names in it), pose_topic, cmd_vel, cmd_type ("twist_stamped" or "twist"), rate (Hz of the
    command), use_sim_time, wait (s of wall time to wait for the topics at the start),
    frame_id (of the TwistStamped commands)."""

    joint_states: str = "/joint_states"
    left_wheel: str = "left_wheel_joint"
    right_wheel: str = "right_wheel_joint"
    pose_topic: str = "/pose"
    cmd_vel: str = "/cmd_vel"
    cmd_type: str = "twist_stamped"
    rate: float = 30.0
    use_sim_time: bool = False
    wait: float = 10.0
    frame_id: str = "base_link"
