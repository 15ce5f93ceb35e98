"""Drives: how wheel-speed commands move the chassis in the walled arena.

Two implementations of one `Drive` interface:

- `PymunkDrive`: a pymunk rigid body pushed by two wheels through a traction model with
  motor lag and a friction circle per wheel (it slips under hard accelerations).
- `IdealDrive`: rolls without slip and without lag, so the kinematic model is exact.

and their batches of N robots stepped together (`PymunkBatchDrive`, `IdealBatchDrive`), which
run the same kernels (`traction_ticks` on arrays instead of floats, `ideal_arcs`) and give
each robot the single drive's numbers bit for bit.

Frames and units: world frame x right, y up, theta counter-clockwise (rad, continuous);
body frame x forward, y left, origin at the axle midpoint (the reference point of every
pose). The left wheel is at +b/2 on body y, the right at -b/2. Meters, radians, seconds.

Nothing here is sized for one robot: the chassis footprint, mass, inertia, friction and motor
lag all come from the RobotSpec. The fixed lengths are the walls' half-thickness (0.05 m:
a chassis moves at most a few cm per tick at the presets' speeds, far less than its own size,
so it cannot cross a wall within one tick) and pymunk's contact slop (1 mm of tolerated
overlap, small against any chassis).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import numpy as np
import pymunk
import pymunk.batch

from envs.robot import RobotSpec
from excite.arena import Arena
from excite.kinematics import sinc_cosc_scalar, sinc_family

GRAVITY = 9.81  # m/s^2
WALL_RADIUS = 0.05  # m, half-thickness of the arena's wall segments
SLIP_ITERATIONS = 6  # Gauss-Seidel sweeps over the two wheels when a friction cap binds
#: Slipping robots of a batch solved one by one on Python floats up to this many (each takes a
#: few microseconds; numpy's per-call overhead makes arrays faster only beyond).
SCALAR_SLIP_MAX = 12
_CHASSIS_TYPE, _WALL_TYPE = 1, 2  # pymunk collision types


class Drive(Protocol):
    """Moves one robot in the arena at a fixed tick; both implementations share this API."""

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


def traction_constants(robot: RobotSpec, dt: float) -> tuple[float, ...]:
    """Per-robot constants of the traction solver, in the order of :data:`TRACTION_FIELDS`.

    alpha: the motor lag's per-tick factor 1 - exp(-dt/tau); cap: friction-circle radius of one
    wheel's impulse per tick (N s); inv_b, two_over_b (1/m); hb: b/2 (m); the effective-mass
    inverses (k00, k01, k11) at the wheel contacts r = (-d, s*hb), s = +1 left, -1 right,
    relative to the COM in the body frame.
    """
    m, inertia, d, hb = robot.mass, robot.inertia, robot.com_offset, 0.5 * robot.b
    cap = robot.mu * 0.5 * robot.mass * GRAVITY * robot.wheel_load_fraction * dt
    k_inv = []
    for side in (1.0, -1.0):
        k00 = 1.0 / m + hb * hb / inertia
        k01 = side * hb * d / inertia
        k11 = 1.0 / m + d * d / inertia
        det = k00 * k11 - k01 * k01
        k_inv += [k11 / det, -k01 / det, k00 / det]
    return (m, inertia, d, robot.r_L, robot.r_R, 1.0 / robot.b, 2.0 / robot.b, hb,
            1.0 - math.exp(-dt / robot.motor_tau), cap, cap * cap, 1.0 / m, 1.0 / inertia,
            robot.max_wheel_speed, *k_inv)


#: Names of :func:`traction_constants`' values (a float each per robot, or an array over N).
TRACTION_FIELDS = ("m", "inertia", "d", "r_L", "r_R", "inv_b", "two_over_b", "hb", "alpha",
                   "cap", "cap2", "inv_m", "inv_i", "limit",
                   "k00_L", "k01_L", "k11_L", "k00_R", "k01_R", "k11_R")


class _FloatOps:
    """The traction kernel's operations on one robot's Python floats (the single env)."""

    cos, sin = math.cos, math.sin
    sinc_cosc = staticmethod(sinc_cosc_scalar)  # called with derivatives=False (positional)

    @staticmethod
    def clip(value, limit):
        return min(max(value, -limit), limit)

    @staticmethod
    def slip(rolling, k, vx, vy, w, t_L, t_R, rolled):
        return _slip(_FloatOps, k, vx, vy, w, t_L, t_R)

    @staticmethod
    def capped(x, y, cap):
        norm = math.hypot(x, y)
        if norm > cap:
            return x * cap / norm, y * cap / norm
        return x, y


class _ArrayOps:
    """The same operations elementwise on arrays over N robots (the vector env)."""

    cos, sin = np.cos, np.sin
    sinc_cosc = staticmethod(sinc_family)

    @staticmethod
    def clip(value, limit):
        return np.clip(value, -limit, limit)

    @staticmethod
    def rolls(q_L, q_R, py):
        # sqrt of a negative q is nan (the caller silences the warning) and fails the test,
        # as the floats' q >= 0 checks do
        return np.abs(py) <= np.sqrt(q_L) + np.sqrt(q_R)

    @staticmethod
    def slip(rolling, k, vx, vy, w, t_L, t_R, rolled):
        """The rolling robots take ``rolled``; the slipping ones run :func:`_slip`, one by one
        on Python floats (exactly the single robot's arithmetic) when they are few, else on
        arrays of the slipping robots."""
        out = tuple(value.copy() for value in rolled)
        slipping = np.flatnonzero(~rolling)
        inputs = (vx, vy, w, t_L, t_R)
        if len(slipping) > SCALAR_SLIP_MAX:
            result = _slip(_ArrayOps, k.subset(slipping), *(a[slipping] for a in inputs))
            for target, value in zip(out, result, strict=True):
                target[slipping] = value
            return out
        columns = [a[slipping].tolist() for a in inputs]
        for j, i in enumerate(slipping.tolist()):
            result = _slip(_FloatOps, k.robots[i], *(column[j] for column in columns))
            out[0][i], out[1][i], out[2][i] = result
        return out

    @staticmethod
    def capped(x, y, cap):
        # Python's hypot (numpy's differs from it in the last bit now and then)
        norm = np.array([math.hypot(a, b) for a, b in zip(x.tolist(), y.tolist(), strict=True)])
        over = norm > cap
        norm = np.where(over, norm, cap)
        return np.where(over, x * cap / norm, x), np.where(over, y * cap / norm, y)


class OneBody(NamedTuple):
    """One robot's pymunk I/O for :func:`traction_ticks` on floats: its body, the space's step
    and a flag with ``hit`` set (and cleared by the kernel) when the chassis touches a wall."""

    body: pymunk.Body
    step: Callable[[float], None]
    contact: Any


class BodyBatch(NamedTuple):
    """N robots' pymunk I/O for :func:`traction_ticks` on arrays: advance(chord_x, chord_y, w)
    sets the bodies' velocities, steps pymunk one tick and returns the COM poses (x, y, th) and
    which bodies touched a wall; velocity() reads the velocities after that step."""

    advance: Callable
    velocity: Callable


def traction_ticks(ops, k, state: tuple, cmd_L, cmd_R, n_ticks: int,
                   world: OneBody | BodyBatch, record: bool = False):
    """The motors, the traction and the tick loop of :class:`PymunkDrive`, written once for one
    robot on Python floats (``ops=_FloatOps``, ``world`` a :class:`OneBody`) or N robots on
    arrays (``ops=_ArrayOps``, ``world`` a :class:`BodyBatch`).

    k: the traction constants (:data:`TRACTION_FIELDS` attributes, floats or (N,) arrays).
    state: (w_L, w_R, phi_L, phi_R, vel_x, vel_y, w, x, y, th): motor speeds (rad/s), wheel
    angles (rad), world inertial COM velocity (m/s), yaw rate (rad/s), COM position (m) and yaw
    (rad). Returns the new state, whether each robot touched a wall, and (with ``record``) the
    axle poses and wheel angles at every tick, the current ones first (lists of tuples).

    Two small pieces are written per backend, in place (the single robot's hot path, where a
    function call per tick costs percents): the rolling test (``_ArrayOps.rolls`` on arrays)
    and the pymunk I/O (a :class:`BodyBatch` on arrays).
    """
    w_L, w_R, phi_L, phi_R, vel_x, vel_y, w, x, y, th = state
    cmd_L, cmd_R = ops.clip(cmd_L, k.limit), ops.clip(cmd_R, k.limit)
    dt, alpha, cap2 = k.dt, k.alpha, k.cap2
    m, inertia, d, r_L, r_R = k.m, k.inertia, k.d, k.r_L, k.r_R
    inv_b, two_over_b = k.inv_b, k.two_over_b
    cos, sin, sinc_cosc = ops.cos, ops.sin, ops.sinc_cosc
    scalar, sqrt = ops is _FloatOps, math.sqrt
    if scalar:
        body, step, contact = world
    else:
        advance, velocity = world
        rolls = ops.rolls
    c, s = cos(th), sin(th)
    path = [(x - d * c, y - d * s, th)] if record else None
    wheels = [(phi_L, phi_R)] if record else None
    collided = False
    for _ in range(n_ticks):
        w_L += (cmd_L - w_L) * alpha
        w_R += (cmd_R - w_R) * alpha
        phi_L += w_L * dt
        phi_R += w_R * dt
        vx = c * vel_x + s * vel_y  # body-frame COM velocity
        vy = c * vel_y - s * vel_x
        # Rolling target: contact velocities (r*omega, 0) fix the whole twist.
        t_L, t_R = r_L * w_L, r_R * w_R
        tx, tw = 0.5 * (t_L + t_R), (t_R - t_L) * inv_b
        ty = tw * d
        # Impulses of the exact rolling solution; the lateral split is free.
        px, py = m * (tx - vx), m * (ty - vy)
        diff = -(inertia * (tw - w) + d * py) * two_over_b  # P_Lx - P_Rx
        q_L = cap2 - 0.25 * (px + diff) ** 2
        q_R = cap2 - 0.25 * (px - diff) ** 2
        if scalar:  # _ArrayOps.rolls on floats
            rolling = q_L >= 0.0 and q_R >= 0.0 and abs(py) <= sqrt(q_L) + sqrt(q_R)
        else:
            rolling = rolls(q_L, q_R, py)
        if rolling is True or (rolling is not False and rolling.all()):
            vx, vy, w = tx, ty, tw
        else:
            vx, vy, w = ops.slip(rolling, k, vx, vy, w, t_L, t_R, (tx, ty, tw))
        vel_x, vel_y = c * vx - s * vy, s * vx + c * vy
        sinc, cosc = sinc_cosc(w * dt, False)
        chord_x = sinc * vel_x - cosc * vel_y
        chord_y = cosc * vel_x + sinc * vel_y
        if scalar:
            body.velocity = (chord_x, chord_y)
            body.angular_velocity = w
            step(dt)
            if contact.hit:  # add pymunk's contact impulses
                contact.hit = False
                collided = True
                after_x, after_y = body.velocity
                vel_x += after_x - chord_x
                vel_y += after_y - chord_y
                w = body.angular_velocity
            x, y = body.position
            th = body.angle
        else:
            x, y, th, hit = advance(chord_x, chord_y, w)
            if hit.any():  # add pymunk's contact impulses (0 on the bodies without contact)
                collided = collided | hit
                after_x, after_y, w = velocity()
                vel_x += after_x - chord_x
                vel_y += after_y - chord_y
        c, s = cos(th), sin(th)
        if record:
            path.append((x - d * c, y - d * s, th))
            wheels.append((phi_L, phi_R))
    return (w_L, w_R, phi_L, phi_R, vel_x, vel_y, w, x, y, th), collided, path, wheels


def _slip(ops, k, vx, vy, w, t_L, t_R):
    """Friction-capped traction by projected Gauss-Seidel over the two wheels.

    Works on the body-frame COM velocity (vx, vy) (m/s) and yaw rate w (rad/s); t_L, t_R
    are the wheel surface speeds (m/s). Accumulated impulses per wheel stay inside the
    friction circle of radius k.cap (N s). Returns the new (vx, vy, w).
    """
    inv_m, inv_i, d, hb, cap = k.inv_m, k.inv_i, k.d, k.hb, k.cap
    capped = ops.capped
    contacts = ((1.0, k.k00_L, k.k01_L, k.k11_L, t_L), (-1.0, k.k00_R, k.k01_R, k.k11_R, t_R))
    acc = [(0.0, 0.0), (0.0, 0.0)]
    for _ in range(SLIP_ITERATIONS):
        for i in (0, 1):
            side, k00, k01, k11, target = contacts[i]
            ex = target - (vx - w * side * hb)  # wanted minus contact velocity
            ey = w * d - vy
            old_x, old_y = acc[i]
            new_x, new_y = capped(old_x + k00 * ex + k01 * ey, old_y + k01 * ex + k11 * ey, cap)
            acc[i] = (new_x, new_y)
            dx, dy = new_x - old_x, new_y - old_y
            vx += dx * inv_m
            vy += dy * inv_m
            w -= (side * hb * dx + d * dy) * inv_i
    return vx, vy, w


class _Traction:
    """Traction constants as attributes (floats for one robot, arrays over N robots, then
    with ``robots``: each robot's float constants)."""

    def __init__(self, dt: float, values, robots: list[_Traction] | None = None) -> None:
        self.dt = dt
        self.robots = robots
        self._values = values
        for name, value in zip(TRACTION_FIELDS, values, strict=True):
            setattr(self, name, value)

    def subset(self, rows: np.ndarray) -> _Traction:
        """The constants of some of the robots (arrays)."""
        return _Traction(self.dt, self._values[:, rows])


class _ContactFlag:
    """Set by the pymunk collision callback when the chassis touches a wall."""

    def __init__(self) -> None:
        self.hit = False


def _mark_contact(arbiter: pymunk.Arbiter, space: pymunk.Space, flag: _ContactFlag) -> None:
    flag.hit = True


def _new_space(arena: Arena, dt: float) -> pymunk.Space:
    """An empty space with the arena's walls; contact settings sized for meters."""
    space = pymunk.Space()
    space.collision_slop = 1e-3  # m; pymunk's default (0.1) is sized for pixels
    space.collision_bias = 0.5 ** (1.0 / dt)  # push half of any overlap out per tick
    hx = 0.5 * arena.width + WALL_RADIUS
    hy = 0.5 * arena.height + WALL_RADIUS
    corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
    for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
        wall = pymunk.Segment(space.static_body, a, b, WALL_RADIUS)
        wall.collision_type = _WALL_TYPE
        wall.friction = 0.5
        space.add(wall)
    return space


def _chassis(body: pymunk.Body, robot: RobotSpec) -> pymunk.Poly:
    """The robot's footprint on ``body`` (whose origin is the COM; the axle midpoint sits at
    body (-com_offset, 0))."""
    d, hl, hw = robot.com_offset, 0.5 * robot.chassis_length, 0.5 * robot.chassis_width
    footprint = [(-d - hl, -hw), (-d + hl, -hw), (-d + hl, hw), (-d - hl, hw)]
    chassis = pymunk.Poly(body, footprint)
    chassis.collision_type = _CHASSIS_TYPE
    chassis.friction = 0.5
    return chassis


def _robot_body(robot: RobotSpec, com: tuple[float, float], angle: float) -> pymunk.Body:
    """A body of the robot at rest, its origin (the COM) at ``com`` (m), yaw ``angle`` (rad)."""
    body = pymunk.Body(robot.mass, robot.inertia)
    body.angle = angle
    body.position = com
    return body


def _com(robot: RobotSpec, pose: np.ndarray) -> tuple[tuple[float, float], float]:
    """The COM (m) and yaw (rad) of the robot at world pose (x, y, theta) of its axle
    midpoint (the COM is com_offset ahead of the axle)."""
    x, y, theta = (float(v) for v in pose)
    d = robot.com_offset
    return (x + d * math.cos(theta), y + d * math.sin(theta)), theta


def _axle_pose(body: pymunk.Body, robot: RobotSpec) -> np.ndarray:
    """World pose (x, y, theta) of the axle midpoint of the robot's ``body``."""
    x, y = body.position
    th = body.angle
    d = robot.com_offset
    return np.array([x - d * math.cos(th), y - d * math.sin(th), th])


class PymunkDrive:
    """pymunk chassis driven by two lagging motors through friction-limited traction.

    Each tick (dt = 1/physics_hz):

    1. Motors: omega += (cmd - omega) * (1 - exp(-dt/tau)) (exact first-order lag), and
       the wheel angles integrate omega (the encoders see the motor, slip or not).
    2. Traction: impulses at the two wheel contacts (body (0, +-b/2)) drive each contact's
       ground velocity toward the wheel surface velocity (r*omega forward, 0 laterally),
       each capped by its friction circle mu * N * dt with N = mass*g*load_fraction/2.
       If an exact rolling solution fits inside both circles it is applied exactly
       (rolling without slip); otherwise projected Gauss-Seidel sweeps over the two wheels
       find the capped impulses and the wheels slip.
    3. pymunk integrates the pose and resolves wall contacts. The velocity handed to pymunk
       is the chord of the exact constant-twist arc over the tick, so without contacts the
       pose follows the kinematic arc exactly rather than Euler's tangent.

    pymunk detects wall contacts after moving the chassis, so on impact the footprint may
    overlap a wall by up to one tick's travel (2 cm at 1 m/s and 50 Hz) before being pushed out.

    The velocity state carried between ticks is the inertial one (the body's velocity after
    traction), so the traction supplies centripetal forces, e.g. m*w^2*com_offset in a spin.

    Steps 1-2 and the tick loop are :func:`traction_ticks`, the kernel
    :class:`PymunkBatchDrive` runs on N robots at once; here it runs on Python floats.
    """

    def __init__(self, arena: Arena, physics_hz: float) -> None:
        self.arena = arena
        self.dt = 1.0 / physics_hz
        self._robot: RobotSpec | None = None
        self._space: pymunk.Space | None = None
        self._body: pymunk.Body | None = None
        self._contact = _ContactFlag()
        self._touched = False  # the last run touched a wall (pymunk holds contact state)
        self._velocity = (0.0, 0.0)  # m/s, world-frame inertial COM velocity
        self._omega_body = 0.0  # rad/s, chassis yaw rate
        self._omega = [0.0, 0.0]  # rad/s, motor speeds (L, R)
        self._phi = [0.0, 0.0]  # rad, absolute wheel angles (L, R)

    def reset(self, robot: RobotSpec, pose: np.ndarray, wheel_angles: np.ndarray) -> None:
        self._robot = robot
        self._build_space(*_com(robot, pose))
        self._touched = False
        self._velocity = (0.0, 0.0)
        self._omega_body = 0.0
        self._omega = [0.0, 0.0]
        self._phi = [float(wheel_angles[0]), float(wheel_angles[1])]
        self._contact.hit = False
        self._traction = _Traction(self.dt, traction_constants(robot, self.dt))

    def _build_space(self, com: tuple[float, float], angle: float) -> None:
        """A fresh space: the walls and the chassis at rest, COM at `com` (m), yaw `angle` (rad).

        The body origin is the COM (pymunk's pickling loses a non-zero center_of_gravity);
        the axle midpoint, the pose reference, sits at body (-com_offset, 0).
        """
        space = _new_space(self.arena, self.dt)
        body = _robot_body(self._robot, com, angle)
        space.add(body, _chassis(body, self._robot))
        space.on_collision(_CHASSIS_TYPE, _WALL_TYPE, pre_solve=_mark_contact, data=self._contact)
        self._space, self._body = space, body

    @property
    def pose(self) -> np.ndarray:
        return _axle_pose(self._body, self._robot)

    @property
    def wheel_angles(self) -> np.ndarray:
        return np.array(self._phi)

    def run(self, cmd_L: float, cmd_R: float,
            n_ticks: int) -> tuple[np.ndarray, np.ndarray, bool]:
        if self._touched:
            # pymunk keeps contact state that it does not pickle (warm-start impulses, the
            # position-correction velocity), so a run after a wall contact starts in a fresh
            # space: pickling between runs then continues bit-identically.
            self._build_space(tuple(self._body.position), self._body.angle)
        body = self._body
        x, y = body.position
        state = (*self._omega, *self._phi, *self._velocity, self._omega_body, x, y, body.angle)
        state, collided, path, wheels = traction_ticks(
            _FloatOps, self._traction, state, cmd_L, cmd_R, n_ticks,
            OneBody(body, self._space.step, self._contact), record=True)
        w_L, w_R, phi_L, phi_R, vel_x, vel_y, w = state[:7]
        self._omega = [w_L, w_R]
        self._phi = [phi_L, phi_R]
        self._velocity = (vel_x, vel_y)
        self._omega_body = w
        self._touched = collided
        return np.array(path), np.array(wheels), collided


class PymunkBatchDrive:
    """N robots of :class:`PymunkDrive`'s physics in one pymunk space, stepped together.

    Every chassis is in the same arena at its own world pose; the chassis share one pymunk
    shape-filter group, so robots never touch each other, only the walls. The motors and
    traction of all robots are one :func:`traction_ticks` call on (N,) arrays (on floats for
    N = 1); body velocities go into pymunk and poses come out in bulk (``pymunk.batch``); wall
    contacts are counted per robot by the collision callbacks (begin / separate: they run only
    when a contact starts or ends). As PymunkDrive builds a fresh space, a robot gets a fresh
    pymunk body at its reset and after a run that touched a wall (a pymunk body keeps contact
    state that a fresh one does not).

    Robot i driven alone by a :class:`PymunkDrive` gives the same numbers bit for bit, wall
    contacts included (tested; pymunk resolves each chassis' wall contacts on their own).
    """

    _GET = (pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.ANGLE
            | pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY)
    _SET = pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY

    def __init__(self, arena: Arena, physics_hz: float, n: int) -> None:
        self.arena = arena
        self.dt = 1.0 / physics_hz
        self.n = n
        self._space = _new_space(arena, self.dt)
        self._bodies: list[pymunk.Body | None] = [None] * n
        self._shapes: list[pymunk.Poly | None] = [None] * n
        self._robots: list[RobotSpec | None] = [None] * n
        self._shape_index: dict[pymunk.Shape, int] = {}
        self._contacts = np.zeros(n, dtype=int)  # wall contacts each chassis is in now
        self._began = np.zeros(n, dtype=bool)  # a contact began during this tick
        self._space.on_collision(_CHASSIS_TYPE, _WALL_TYPE, begin=self._begin,
                                 separate=self._separate)
        self._robot_traction: list[_Traction | None] = [None] * n
        self._filter = pymunk.ShapeFilter(group=1)  # chassis never collide with each other
        self._touched = np.zeros(n, dtype=bool)
        self._state = np.zeros((7, n))  # w_L, w_R, phi_L, phi_R, vel_x, vel_y, w
        self._constants = np.ones((len(TRACTION_FIELDS), n))
        self._slots: np.ndarray | None = None  # robot i's row in pymunk.batch's body list
        self._set = pymunk.batch.Buffer()
        self._get = pymunk.batch.Buffer()

    def _robot_of(self, arbiter: pymunk.Arbiter) -> int:
        a, b = arbiter.shapes  # (bodies are gone when a removed shape separates)
        return self._shape_index[a] if a in self._shape_index else self._shape_index[b]

    def _begin(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data) -> None:
        i = self._robot_of(arbiter)
        self._contacts[i] += 1
        self._began[i] = True

    def _separate(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data) -> None:
        self._contacts[self._robot_of(arbiter)] -= 1

    def reset(self, i: int, robot: RobotSpec, pose: np.ndarray,
              wheel_angles: np.ndarray) -> None:
        """Place robot ``i`` at rest at world pose (x, y, theta) with wheel angles (rad)."""
        self._robots[i] = robot
        self._new_body(i, *_com(robot, pose))
        self._state[:, i] = (0.0, 0.0, float(wheel_angles[0]), float(wheel_angles[1]),
                             0.0, 0.0, 0.0)
        constants = traction_constants(robot, self.dt)
        self._constants[:, i] = constants
        self._robot_traction[i] = _Traction(self.dt, constants)
        self._touched[i] = False

    def _new_body(self, i: int, com: tuple[float, float], angle: float) -> None:
        """A fresh body and chassis for robot i at rest, COM at ``com`` (m), yaw ``angle``."""
        if self._bodies[i] is not None:
            self._space.remove(self._bodies[i], self._shapes[i])
            del self._shape_index[self._shapes[i]]
        robot = self._robots[i]
        body = _robot_body(robot, com, angle)
        shape = _chassis(body, robot)
        shape.filter = self._filter
        self._shape_index[shape] = i
        self._space.add(body, shape)
        self._bodies[i], self._shapes[i] = body, shape
        self._slots = None  # pymunk's body order changed

    def _order(self) -> np.ndarray:
        """Each robot's row in pymunk.batch's body list (the dynamic bodies, then the walls'
        static body), and the float buffer the velocities are set from."""
        if self._slots is None:
            listing = pymunk.batch.Buffer()
            pymunk.batch.get_space_bodies(self._space, pymunk.batch.BodyFields.BODY_ID, listing)
            ids = list(memoryview(listing.int_buf()).cast("P"))
            row = {body_id: k for k, body_id in enumerate(ids)}
            self._slots = np.array([row[body.id] for body in self._bodies])
            self._velocities = np.zeros((len(ids), 3))  # vx, vy, w per listed body
            self._set = pymunk.batch.Buffer()
            self._set.set_float_buf(self._velocities)
        return self._slots

    def _read(self) -> np.ndarray:
        """(6, N): COM x, y (m), yaw (rad), velocity x, y (m/s), yaw rate (rad/s)."""
        self._get.clear()
        pymunk.batch.get_space_bodies(self._space, self._GET, self._get)
        bodies = np.frombuffer(self._get.float_buf(), dtype=float).reshape(-1, 6)
        return bodies[self._slots].T

    def _advance(self, chord_x: np.ndarray, chord_y: np.ndarray, w: np.ndarray):
        velocities, slots = self._velocities, self._slots
        velocities[slots, 0] = chord_x
        velocities[slots, 1] = chord_y
        velocities[slots, 2] = w
        pymunk.batch.set_space_bodies(self._space, self._SET, self._set)
        self._space.step(self.dt)
        self._last = self._read()
        # In contact during this tick: pymunk's pre-solve would have run (a contact that began
        # and ended within the tick counts too).
        hit = self._contacts > 0
        if self._began.any():
            hit |= self._began
            self._began[:] = False
        return self._last[0], self._last[1], self._last[2], hit

    def _body_velocity(self):
        return self._last[3], self._last[4], self._last[5]

    def poses(self, com: np.ndarray | None = None) -> np.ndarray:
        """World poses (N, 3) of the axle midpoints (x, y, theta)."""
        if com is None:
            self._order()
            com = self._read()
        d = self._constants[TRACTION_FIELDS.index("d")]
        th = com[2]
        return np.stack([com[0] - d * np.cos(th), com[1] - d * np.sin(th), th], axis=1)

    def pose(self, i: int) -> np.ndarray:
        """Robot i's world pose (x, y, theta) of the axle midpoint."""
        return _axle_pose(self._bodies[i], self._robots[i])

    @property
    def wheel_angles(self) -> np.ndarray:
        """Absolute wheel angles (N, 2) (phi_L, phi_R) in rad, unquantized."""
        return self._state[2:4].T.copy()

    def run(self, commands: np.ndarray, n_ticks: int) -> tuple[np.ndarray, np.ndarray]:
        """Hold wheel-speed commands (N, 2) (rad/s) for ``n_ticks`` ticks on every robot.
        Returns the end poses (N, 3) and whether each robot touched a wall (N,)."""
        for i in np.flatnonzero(self._touched):  # as PymunkDrive's fresh space after a contact
            body = self._bodies[i]
            self._new_body(i, tuple(body.position), body.angle)
        self._order()
        com = self._read()
        state = (*self._state, com[0], com[1], com[2])
        if self.n == 1:  # one robot: the kernel on Python floats, as PymunkDrive runs it
            state, collided = self._run_one(tuple(float(v[0]) for v in state),
                                            commands[0].tolist(), n_ticks)
        else:
            k = _Traction(self.dt, self._constants, self._robot_traction)
            with np.errstate(invalid="ignore"):  # sqrt of negative q in _ArrayOps.rolls
                state, collided, _, _ = traction_ticks(
                    _ArrayOps, k, state, commands[:, 0], commands[:, 1], n_ticks,
                    BodyBatch(self._advance, self._body_velocity))
        self._state = np.array(state[:7]).reshape(7, self.n)
        collided = np.broadcast_to(collided, (self.n,)).copy()
        self._touched = collided
        return self.poses(np.array(state[7:]).reshape(3, self.n)), collided

    def _run_one(self, state: tuple[float, ...], command: list[float],
                 n_ticks: int) -> tuple[tuple[float, ...], bool]:
        """:func:`traction_ticks` on floats for a batch of one robot."""
        world = OneBody(self._bodies[0], self._space.step, _CountedContact(self))
        state, collided, _, _ = traction_ticks(_FloatOps, self._robot_traction[0], state,
                                               *command, n_ticks, world)
        return state, collided


class _CountedContact:
    """PymunkBatchDrive's wall contacts of robot 0 as a :class:`_ContactFlag`: ``hit`` while
    in contact or when a contact began during the last tick; clearing it forgets the latter."""

    def __init__(self, drive: PymunkBatchDrive) -> None:
        self._contacts, self._began = drive._contacts, drive._began

    @property
    def hit(self) -> bool:
        return bool(self._contacts[0] > 0 or self._began[0])

    @hit.setter
    def hit(self, value: bool) -> None:
        self._began[0] = value


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

    def pose(self, i: int) -> np.ndarray:
        return self._poses[i].copy()

    @property
    def wheel_angles(self) -> np.ndarray:
        return self._phi.copy()

    def run(self, commands: np.ndarray, n_ticks: int) -> tuple[np.ndarray, np.ndarray]:
        paths, wheels, collided = ideal_arcs(self.arena, self.dt, self._poses, self._phi,
                                             commands, self._limits, self._params,
                                             self._chassis, n_ticks)
        self._poses = paths[:, -1].copy()
        self._phi = wheels[:, -1].copy()
        return self._poses.copy(), collided
