"""Drives: how wheel-speed commands move the chassis in the walled arena.

Two implementations of one `Drive` interface:

- `PymunkDrive`: a pymunk rigid body pushed by two wheels through a traction model with
  motor lag and a friction circle per wheel (it slips under hard accelerations).
- `IdealDrive`: rolls without slip and without lag, so the kinematic model is exact.

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
from typing import Protocol

import numpy as np
import pymunk

from envs.robot import RobotSpec
from excite.arena import Arena
from excite.kinematics import sinc_cosc_scalar, sinc_family

GRAVITY = 9.81  # m/s^2
WALL_RADIUS = 0.05  # m, half-thickness of the arena's wall segments
SLIP_ITERATIONS = 6  # Gauss-Seidel sweeps over the two wheels when a friction cap binds
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
    collision is reported.
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
        limit = robot.max_wheel_speed
        omega = np.clip([cmd_L, cmd_R], -limit, limit)
        t = np.arange(1, n_ticks + 1) * self.dt
        v_L, v_R = robot.r_L * omega[0], robot.r_R * omega[1]
        ds = 0.5 * (v_L + v_R) * t
        dth = (v_R - v_L) / robot.b * t
        sinc, cosc = sinc_family(dth, derivatives=False)
        bx, by = ds * sinc, ds * cosc
        x0, y0, th0 = self._pose
        c, s = math.cos(th0), math.sin(th0)
        path = np.empty((n_ticks + 1, 3))
        path[0] = self._pose
        path[1:, 0] = x0 + c * bx - s * by
        path[1:, 1] = y0 + s * bx + c * by
        path[1:, 2] = th0 + dth
        inside = self.arena.contains_footprint(path[1:, 0], path[1:, 1], path[1:, 2],
                                               chassis=robot.chassis)
        ticks_done = int(np.argmin(inside)) if not inside.all() else n_ticks
        path[ticks_done + 1 :] = path[ticks_done]
        self._pose = path[ticks_done].copy()
        turned = np.minimum(np.arange(n_ticks + 1), ticks_done) * self.dt  # s of rolling
        wheels = self._phi + omega * turned[:, None]
        self._phi = wheels[-1].copy()
        return path, wheels, ticks_done < n_ticks


class _ContactFlag:
    """Set by the pymunk collision callback when the chassis touches a wall."""

    def __init__(self) -> None:
        self.hit = False


def _mark_contact(arbiter: pymunk.Arbiter, space: pymunk.Space, flag: _ContactFlag) -> None:
    flag.hit = True


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
        x, y, theta = (float(v) for v in pose)
        d = robot.com_offset
        self._build_space((x + d * math.cos(theta), y + d * math.sin(theta)), theta)
        self._touched = False
        self._velocity = (0.0, 0.0)
        self._omega_body = 0.0
        self._omega = [0.0, 0.0]
        self._phi = [float(wheel_angles[0]), float(wheel_angles[1])]
        self._contact.hit = False
        self._prepare_traction(robot)

    def _build_space(self, com: tuple[float, float], angle: float) -> None:
        """A fresh space: the walls and the chassis at rest, COM at `com` (m), yaw `angle` (rad).

        The body origin is the COM (pymunk's pickling loses a non-zero center_of_gravity);
        the axle midpoint, the pose reference, sits at body (-com_offset, 0).
        """
        robot = self._robot
        space = pymunk.Space()
        space.collision_slop = 1e-3  # m; pymunk's default (0.1) is sized for pixels
        space.collision_bias = 0.5 ** (1.0 / self.dt)  # push half of any overlap out per tick
        hx = 0.5 * self.arena.width + WALL_RADIUS
        hy = 0.5 * self.arena.height + WALL_RADIUS
        corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
        for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
            wall = pymunk.Segment(space.static_body, a, b, WALL_RADIUS)
            wall.collision_type = _WALL_TYPE
            wall.friction = 0.5
            space.add(wall)
        d, hl, hw = robot.com_offset, 0.5 * robot.chassis_length, 0.5 * robot.chassis_width
        body = pymunk.Body(robot.mass, robot.inertia)
        body.angle = angle
        body.position = com
        footprint = [(-d - hl, -hw), (-d + hl, -hw), (-d + hl, hw), (-d - hl, hw)]
        chassis = pymunk.Poly(body, footprint)
        chassis.collision_type = _CHASSIS_TYPE
        chassis.friction = 0.5
        space.add(body, chassis)
        space.on_collision(_CHASSIS_TYPE, _WALL_TYPE, pre_solve=_mark_contact, data=self._contact)
        self._space, self._body = space, body

    def _prepare_traction(self, robot: RobotSpec) -> None:
        """Per-robot constants of the traction solver (body frame, relative to the COM)."""
        m, inertia, d, hb = robot.mass, robot.inertia, robot.com_offset, 0.5 * robot.b
        cap = robot.mu * 0.5 * robot.mass * GRAVITY * robot.wheel_load_fraction * self.dt
        self._cap = cap  # N s, friction-circle radius of one wheel's impulse per tick
        self._alpha = 1.0 - math.exp(-self.dt / robot.motor_tau)
        # Effective-mass inverses at the contacts r = (-d, s*hb), s = +1 left, -1 right.
        self._k_inv = []
        for side in (1.0, -1.0):
            k00 = 1.0 / m + hb * hb / inertia
            k01 = side * hb * d / inertia
            k11 = 1.0 / m + d * d / inertia
            det = k00 * k11 - k01 * k01
            self._k_inv.append((side, k11 / det, -k01 / det, k00 / det))

    @property
    def pose(self) -> np.ndarray:
        x, y = self._body.position
        th = self._body.angle
        d = self._robot.com_offset
        return np.array([x - d * math.cos(th), y - d * math.sin(th), th])

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
        robot, body, space, contact = self._robot, self._body, self._space, self._contact
        limit = robot.max_wheel_speed
        cmd_L = min(max(cmd_L, -limit), limit)
        cmd_R = min(max(cmd_R, -limit), limit)
        dt, alpha, cap = self.dt, self._alpha, self._cap
        cap2 = cap * cap
        m, inertia, d, r_L, r_R = robot.mass, robot.inertia, robot.com_offset, robot.r_L, robot.r_R
        inv_b, two_over_b = 1.0 / robot.b, 2.0 / robot.b
        w_L, w_R = self._omega
        phi_L, phi_R = self._phi
        vel_x, vel_y = self._velocity
        w = self._omega_body
        x, y = body.position
        th = body.angle
        c, s = math.cos(th), math.sin(th)
        path = [(x - d * c, y - d * s, th)]
        wheels = [(phi_L, phi_R)]
        collided = False
        step = space.step
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
            if q_L >= 0.0 and q_R >= 0.0 and abs(py) <= math.sqrt(q_L) + math.sqrt(q_R):
                vx, vy, w = tx, ty, tw
            else:
                vx, vy, w = self._slip(vx, vy, w, t_L, t_R)
            vel_x, vel_y = c * vx - s * vy, s * vx + c * vy
            sinc, cosc = sinc_cosc_scalar(w * dt, derivatives=False)
            chord_x = sinc * vel_x - cosc * vel_y
            chord_y = cosc * vel_x + sinc * vel_y
            body.velocity = (chord_x, chord_y)
            body.angular_velocity = w
            step(dt)
            if contact.hit:
                contact.hit = False
                collided = True
                after_x, after_y = body.velocity
                vel_x += after_x - chord_x
                vel_y += after_y - chord_y
                w = body.angular_velocity
            x, y = body.position
            th = body.angle
            c, s = math.cos(th), math.sin(th)
            path.append((x - d * c, y - d * s, th))
            wheels.append((phi_L, phi_R))
        self._omega = [w_L, w_R]
        self._phi = [phi_L, phi_R]
        self._velocity = (vel_x, vel_y)
        self._omega_body = w
        self._touched = collided
        return np.array(path), np.array(wheels), collided

    def _slip(
        self, vx: float, vy: float, w: float, t_L: float, t_R: float
    ) -> tuple[float, float, float]:
        """Friction-capped traction by projected Gauss-Seidel over the two wheels.

        Works on the body-frame COM velocity (vx, vy) (m/s) and yaw rate w (rad/s); t_L, t_R
        are the wheel surface speeds (m/s). Accumulated impulses per wheel stay inside the
        friction circle of radius self._cap (N s). Returns the new (vx, vy, w).
        """
        robot = self._robot
        inv_m, inv_i = 1.0 / robot.mass, 1.0 / robot.inertia
        d, hb, cap = robot.com_offset, 0.5 * robot.b, self._cap
        acc = [[0.0, 0.0], [0.0, 0.0]]
        targets = (t_L, t_R)
        for _ in range(SLIP_ITERATIONS):
            for i in (0, 1):
                side, k00, k01, k11 = self._k_inv[i]
                ex = targets[i] - (vx - w * side * hb)  # wanted minus contact velocity
                ey = w * d - vy
                old_x, old_y = acc[i]
                new_x = old_x + k00 * ex + k01 * ey
                new_y = old_y + k01 * ex + k11 * ey
                norm = math.hypot(new_x, new_y)
                if norm > cap:
                    new_x, new_y = new_x * cap / norm, new_y * cap / norm
                acc[i] = [new_x, new_y]
                dx, dy = new_x - old_x, new_y - old_y
                vx += dx * inv_m
                vy += dy * inv_m
                w -= (side * hb * dx + d * dy) * inv_i
        return vx, vy, w
