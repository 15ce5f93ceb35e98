"""How far a robot goes before it stops: the live session's stopping guard, which keeps the
footprint in the safe area whatever the protocol commands.

A protocol's wall guard plans with the simulator's model of the robot; a real robot may
answer later (its controller's response time), slow down more gently (``--max-wheel-accel``,
or a floor that grips less) or have no guard at all (a user's protocol). The session
therefore scales each command down to what the robot can stop from :data:`STOP_MARGIN`
inside the area, from the footprint's clearance at the latest pose (:func:`within_reach`).

Units: m, s, rad/s (wheel speeds).
"""

from __future__ import annotations

import math

import numpy as np

from excite.live.settings import LiveSettings

__all__ = ["STOP_MARGIN", "reach", "within_reach"]

#: m: the guard stops the footprint this far inside the area's edge, so that the pose noise
#: of a robot standing there does not read as the footprint outside (which aborts the
#: session).
STOP_MARGIN = 0.02


def reach(settings: LiveSettings, wheels: np.ndarray) -> tuple[float, float]:
    """(a, c) of how far (m) a point of the footprint may still travel when the wheels turn
    at ``wheels`` x f (rad/s) and the command goes to zero now: a f + c f^2. Every point moves
    at most s = |v| + |omega| R (R the footprint's corner from the axle midpoint) through the
    response time and the motors' lag (response_time + motor_tau), then while the wheels
    stop, which takes their surface speed over the deceleration max_wheel_acceleration
    allows, or the floor's grip, whichever is less (s over half that time)."""
    s = settings
    v, omega = s.twist(float(wheels[0]), float(wheels[1]))
    speed = abs(v) + abs(omega) * 0.5 * math.hypot(*s.chassis)
    delay = s.response_time + (s.traction.motor_tau if s.traction is not None else 0.0)
    radius = float(max(s.nominal.r_L, s.nominal.r_R))
    deceleration = min(s.max_wheel_acceleration * radius,
                       s.traction.grip if s.traction is not None else math.inf)
    stopping = float(np.max(np.abs(wheels))) * radius / deceleration
    return speed * delay, 0.5 * speed * stopping


def within_reach(settings: LiveSettings, wheels: np.ndarray, clearance: float) -> float:
    """The largest share (at most 1) of the wheel speeds ``wheels`` (rad/s) from which the
    robot stops :data:`STOP_MARGIN` inside the area, its footprint ``clearance`` (m) from the
    edge now (:func:`reach`); 0 at or beyond the margin."""
    room = clearance - STOP_MARGIN
    if room <= 0:
        return 0.0
    a, c = reach(settings, wheels)
    if a + c <= room:
        return 1.0
    if c <= 0:
        return room / a
    return (math.sqrt(a * a + 4.0 * c * room) - a) / (2.0 * c)
