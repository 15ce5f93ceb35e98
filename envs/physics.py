"""The slipping drive: a pymunk rigid body pushed by two wheels through a traction model.

`PymunkDrive` moves one robot: motor lag and a friction circle per wheel, so it slips under
hard accelerations; `PymunkBatchDrive` steps N robots together in one pymunk space on the same
compiled kernel (:func:`envs.traction_kernel.traction_tick` on N robots instead of one) and
gives each robot the single drive's numbers bit for bit. The drive of the default
configuration; :mod:`envs.ideal_drive` is the other, without slip or lag.

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
from typing import NamedTuple

import numpy as np
import pymunk
import pymunk.batch

from envs.robot import GRAVITY, RobotSpec
from envs.traction_kernel import PATH_FIELDS, STATE_FIELDS, TRACTION_FIELDS, traction_tick
from excite.core.arena import Arena

WALL_RADIUS = 0.05  # m, half-thickness of the arena's wall segments
_CHASSIS_TYPE, _WALL_TYPE = 1, 2  # pymunk collision types
_PHI = slice(STATE_FIELDS.index("phi_L"), STATE_FIELDS.index("phi_R") + 1)  # state columns
_POSE = slice(STATE_FIELDS.index("x"), STATE_FIELDS.index("theta") + 1)


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


class _Buffers(NamedTuple):
    """pymunk.batch buffers kept for the life of a drive and reused by every :class:`_TickLoop`
    on it: pymunk never frees a Buffer's C arrays (a new Buffer per rebuild leaked ~6 KB)."""

    listing: pymunk.batch.Buffer
    put: pymunk.batch.Buffer
    get: pymunk.batch.Buffer

    @classmethod
    def new(cls) -> _Buffers:
        return cls(pymunk.batch.Buffer(), pymunk.batch.Buffer(), pymunk.batch.Buffer())


class _TickLoop:
    """The tick loop of both pymunk drives on a space: the compiled kernel, then pymunk.batch's
    bulk set of the velocities, the space's step and the bulk get of the bodies. Robot i's body
    is row ``slots[i]`` of the space's body list (pymunk's order: the dynamic bodies, then the
    walls' static body); rebuild this after adding or removing a body. ``body_ids``: the robots'
    ``pymunk.Body.id`` (kept by the drives: reading 64 of them costs more than this whole
    setup); ``buffers``: the drive's."""

    _GET = (pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.ANGLE
            | pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY)
    _SET = pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY

    def __init__(self, space: pymunk.Space, body_ids: list[int], buffers: _Buffers) -> None:
        self._space = space
        listing = buffers.listing
        listing.clear()
        pymunk.batch.get_space_bodies(space, pymunk.batch.BodyFields.BODY_ID, listing)
        ids = list(memoryview(listing.int_buf()).cast("P"))
        row = {body_id: k for k, body_id in enumerate(ids)}
        self.slots = np.array([row[body_id] for body_id in body_ids], dtype=np.int64)
        # (M, 3) vx, vy (m/s), w (rad/s) per listed body: the buffer pymunk's velocities are
        # set from (the kernel writes the robots' rows)
        self._velocities = np.zeros((len(ids), 3))
        self._set = buffers.put
        self._set.set_float_buf(self._velocities)
        # pymunk.batch's get buffer grows only when a reading does not fit, so after a first
        # reading of these bodies every later one rewrites the same memory: one numpy view of
        # it serves every tick (a new view per tick costs percents at N = 1); run() checks it.
        self._get = buffers.get
        self._get.clear()
        pymunk.batch.get_space_bodies(space, self._GET, self._get)
        self._bodies = np.frombuffer(self._get.float_buf(), dtype=float)

    def read(self) -> np.ndarray:
        """(M * 6,): each listed body's COM x, y (m), yaw (rad), velocity x, y (m/s), yaw rate
        (rad/s), flat (a view that the next reading overwrites)."""
        self._get.clear()
        pymunk.batch.get_space_bodies(self._space, self._GET, self._get)
        return self._bodies

    def _check_view(self) -> None:
        """Raise if pymunk.batch moved its get buffer away from the view."""
        now = np.frombuffer(self._get.float_buf(), dtype=float)
        if now.ctypes.data != self._bodies.ctypes.data or len(now) != len(self._bodies):
            raise RuntimeError("pymunk.batch moved its body buffer during a run")

    def run(self, dt: float, k: np.ndarray, state: np.ndarray, commands: np.ndarray,
            contacts: np.ndarray, began: np.ndarray, n_ticks: int,
            path: np.ndarray | None = None) -> np.ndarray:
        """Hold ``commands`` (N, 2) (rad/s) for ``n_ticks`` ticks of ``dt`` s: each tick one
        call of the compiled kernel (:func:`envs.traction_kernel.traction_tick`, which first
        takes in the step before it), then pymunk's bulk set, step and get; a last kernel call
        takes in the last step. k (N, F) the robots' constants, ``state`` (N, S) updated in
        place; ``contacts``, ``began`` (N,): the robots' wall contacts kept by the collision
        callbacks; ``path`` (n_ticks + 1, N, 5) records every tick when given. Returns whether
        each robot touched a wall (N,)."""
        collided = np.zeros(len(state), dtype=bool)
        path = _NO_PATH if path is None else path
        space, put, get, fields_set, fields_get = (self._space, self._set, self._get,
                                                   self._SET, self._GET)
        set_bodies, get_bodies = pymunk.batch.set_space_bodies, pymunk.batch.get_space_bodies
        slots, velocities = self.slots, self._velocities
        bodies = self.read()
        for tick in range(n_ticks):  # (inlined: a method call per tick costs percents at N = 1)
            traction_tick(k, state, commands, dt, bodies, slots, contacts, began, collided,
                          velocities, path, tick, n_ticks)
            set_bodies(space, fields_set, put)
            space.step(dt)
            get.clear()
            get_bodies(space, fields_get, get)
        self._check_view()
        traction_tick(k, state, commands, dt, bodies, slots, contacts, began, collided,
                      velocities, path, n_ticks, n_ticks)
        return collided

    def poses(self, k: np.ndarray, state: np.ndarray) -> None:
        """The kernel's axle poses in ``state`` (N, S) from the bodies now (nothing else
        changes)."""
        n = len(state)
        traction_tick(k, state, np.zeros((n, 2)), 0.0, self.read(), self.slots,
                      np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool),
                      np.zeros(n, dtype=bool), self._velocities, _NO_PATH, 0, 0)


_NO_PATH = np.empty((0, 0, len(PATH_FIELDS)))


def _mark_contact(arbiter: pymunk.Arbiter, space: pymunk.Space, began: np.ndarray) -> None:
    began[0] = True

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

    Steps 1-2 are the compiled kernel :func:`envs.traction_kernel.traction_tick`, run here on
    a batch of one robot in the tick loop of :class:`PymunkBatchDrive` (:class:`_TickLoop`).
    """

    def __init__(self, arena: Arena, physics_hz: float) -> None:
        self.arena = arena
        self.dt = 1.0 / physics_hz
        self._robot: RobotSpec | None = None
        self._space: pymunk.Space | None = None
        self._body: pymunk.Body | None = None
        self._io: _TickLoop | None = None  # per space
        self._buffers: _Buffers | None = None  # (pymunk buffers do not pickle: made again)
        self._began = np.zeros(1, dtype=bool)  # set by pymunk's pre-solve on a wall contact
        self._no_contacts = np.zeros(1, dtype=np.int64)  # (pre-solve runs every tick in contact)
        self._touched = False  # the last run touched a wall (pymunk holds contact state)
        self._state = np.zeros((1, len(STATE_FIELDS)))  # the kernel's state of the robot
        self._constants = np.ones((1, len(TRACTION_FIELDS)))

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_io": None, "_buffers": None}

    def reset(self, robot: RobotSpec, pose: np.ndarray, wheel_angles: np.ndarray) -> None:
        self._robot = robot
        self._build_space(*_com(robot, pose))
        self._touched = False
        self._state[:] = 0.0
        self._state[0, _PHI] = (float(wheel_angles[0]), float(wheel_angles[1]))
        self._began[0] = False
        self._constants[0] = traction_constants(robot, self.dt)

    def _build_space(self, com: tuple[float, float], angle: float) -> None:
        """A fresh space: the walls and the chassis at rest, COM at `com` (m), yaw `angle` (rad).

        The body origin is the COM (pymunk's pickling loses a non-zero center_of_gravity);
        the axle midpoint, the pose reference, sits at body (-com_offset, 0).
        """
        space = _new_space(self.arena, self.dt)
        body = _robot_body(self._robot, com, angle)
        space.add(body, _chassis(body, self._robot))
        space.on_collision(_CHASSIS_TYPE, _WALL_TYPE, pre_solve=_mark_contact, data=self._began)
        self._space, self._body, self._io = space, body, None

    @property
    def pose(self) -> np.ndarray:
        return _axle_pose(self._body, self._robot)

    @property
    def wheel_angles(self) -> np.ndarray:
        return self._state[0, _PHI].copy()

    def run(self, cmd_L: float, cmd_R: float,
            n_ticks: int) -> tuple[np.ndarray, np.ndarray, bool]:
        if self._touched:
            # pymunk keeps contact state that it does not pickle (warm-start impulses, the
            # position-correction velocity), so a run after a wall contact starts in a fresh
            # space: pickling between runs then continues bit-identically.
            self._build_space(tuple(self._body.position), self._body.angle)
        if self._io is None:
            self._buffers = self._buffers or _Buffers.new()
            self._io = _TickLoop(self._space, [self._body.id], self._buffers)
        path = np.empty((n_ticks + 1, 1, len(PATH_FIELDS)))
        collided = self._io.run(self.dt, self._constants, self._state,
                                np.array([[cmd_L, cmd_R]], dtype=float), self._no_contacts,
                                self._began, n_ticks, path)
        self._touched = bool(collided[0])
        return path[:, 0, :3].copy(), path[:, 0, 3:].copy(), self._touched


class PymunkBatchDrive:
    """N robots of :class:`PymunkDrive`'s physics in one pymunk space, stepped together.

    Every chassis is in the same arena at its own world pose; the chassis share one pymunk
    shape-filter group, so robots never touch each other, only the walls. Each tick is one call
    of the compiled kernel over all robots (:func:`envs.traction_kernel.traction_tick`, the one
    PymunkDrive runs on its robot), then the body velocities go into pymunk and poses come out
    in bulk (``pymunk.batch``); wall contacts are counted per robot by the collision callbacks
    (begin / separate: they run only when a contact starts or ends). As PymunkDrive builds a
    fresh space, a robot gets a fresh pymunk body at its reset and after a run that touched a
    wall (a pymunk body keeps contact state that a fresh one does not).

    Robot i driven alone by a :class:`PymunkDrive` gives the same numbers bit for bit, wall
    contacts included (tested; pymunk resolves each chassis' wall contacts on their own).
    """

    def __init__(self, arena: Arena, physics_hz: float, n: int) -> None:
        self.arena = arena
        self.dt = 1.0 / physics_hz
        self.n = n
        self._space = _new_space(arena, self.dt)
        self._bodies: list[pymunk.Body | None] = [None] * n
        self._shapes: list[pymunk.Poly | None] = [None] * n
        self._body_ids = [0] * n  # pymunk.Body.id of each robot's body
        self._robots: list[RobotSpec | None] = [None] * n
        self._shape_index: dict[pymunk.Shape, int] = {}
        self._contacts = np.zeros(n, dtype=np.int64)  # wall contacts each chassis is in now
        self._began = np.zeros(n, dtype=bool)  # a contact began since the kernel's last look
        self._space.on_collision(_CHASSIS_TYPE, _WALL_TYPE, begin=self._begin,
                                 separate=self._separate)
        self._filter = pymunk.ShapeFilter(group=1)  # chassis never collide with each other
        self._touched = np.zeros(n, dtype=bool)
        self._state = np.zeros((n, len(STATE_FIELDS)))  # the kernel's state of each robot
        self._constants = np.ones((n, len(TRACTION_FIELDS)))
        self._io: _TickLoop | None = None  # rebuilt when pymunk's body order changes
        self._buffers = _Buffers.new()

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
        self._state[i] = 0.0
        self._state[i, _PHI] = (float(wheel_angles[0]), float(wheel_angles[1]))
        self._constants[i] = traction_constants(robot, self.dt)
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
        self._bodies[i], self._shapes[i], self._body_ids[i] = body, shape, body.id
        self._io = None  # pymunk's body order changed

    def _ticks(self) -> _TickLoop:
        if self._io is None:
            self._io = _TickLoop(self._space, self._body_ids, self._buffers)
        return self._io

    def poses(self) -> np.ndarray:
        """World poses (N, 3) of the axle midpoints (x, y, theta)."""
        self._ticks().poses(self._constants, self._state)
        return self._state[:, _POSE].copy()

    @property
    def wheel_angles(self) -> np.ndarray:
        """Absolute wheel angles (N, 2) (phi_L, phi_R) in rad, unquantized."""
        return self._state[:, _PHI].copy()

    def run(self, commands: np.ndarray, n_ticks: int, wheels: bool = False
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Hold wheel-speed commands (N, 2) (rad/s) for ``n_ticks`` ticks on every robot.
        Returns the end poses (N, 3), whether each robot touched a wall (N,) and, with
        ``wheels``, the wheel angles at every tick (n_ticks + 1, N, 2) (rad; else None)."""
        for i in np.flatnonzero(self._touched):  # as PymunkDrive's fresh space after a contact
            body = self._bodies[i]
            self._new_body(i, tuple(body.position), body.angle)
        path = np.empty((n_ticks + 1, len(self._state), len(PATH_FIELDS))) if wheels else None
        self._touched = self._ticks().run(self.dt, self._constants, self._state,
                                             np.ascontiguousarray(commands, dtype=float),
                                             self._contacts, self._began, n_ticks, path)
        return (self._state[:, _POSE].copy(), self._touched.copy(),
                None if path is None else path[:, :, 3:].copy())
