"""The compiled physics kernel of the pymunk drives: motors, traction and slip of N robots.

:func:`traction_tick` is called once per physics tick, between pymunk's steps, by both
:class:`envs.physics.PymunkDrive` (N = 1) and :class:`envs.physics.PymunkBatchDrive`; it loops
over the robots in compiled code (numba, no fastmath: IEEE arithmetic in the written order and
libm's sin, cos, hypot; LLVM fuses a sin and cos of one angle into glibc's sincos, which gives
the same bits, tested against Python's math). Its arithmetic per robot does not depend on N or
on the other robots, so robot i of a batch gives the numbers of the same robot alone bit for bit
(tested, and the loop is checked not to be vectorised, which would swap libm's sin/cos for
vector versions).

Frames and units: world frame x right, y up, yaw counter-clockwise; body frame x forward, y
left, origin at the axle midpoint; the pymunk body's origin is the COM, ``d`` ahead of the axle.
Meters, radians, seconds, kilograms.

numba caches the compiled kernel on disk (``cache=True``: compiled once per machine, about 2 s;
a later process loads it in under 1 s) and keys the cache on this file alone: code or
constants of other modules compiled into the kernel would not invalidate it. So
:func:`sinc_cosc`, the compiled fast form of :func:`excite.core.kinematics.sinc_family_scalar`,
is written here (equal to it bit for bit: tests/unit/core/test_fast_forms.py), and the one
constant taken from there, TINY_THRESHOLD, is checked by the same test (after changing it,
delete envs/__pycache__/traction_kernel.*.nbi and .nbc).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from excite.core.kinematics import TINY_THRESHOLD

SLIP_ITERATIONS = 6  # Gauss-Seidel sweeps over the two wheels when a friction cap binds

#: Columns of the kernel's constants (N, F) array, one row per robot
#: (:func:`envs.physics.traction_constants`).
TRACTION_FIELDS = ("m", "inertia", "d", "r_L", "r_R", "inv_b", "two_over_b", "hb", "alpha",
                   "cap", "cap2", "inv_m", "inv_i", "limit",
                   "k00_L", "k01_L", "k11_L", "k00_R", "k01_R", "k11_R")
(_M, _INERTIA, _D, _R_L, _R_R, _INV_B, _TWO_OVER_B, _HB, _ALPHA, _CAP, _CAP2, _INV_M, _INV_I,
 _LIMIT, _K00_L, _K01_L, _K11_L, _K00_R, _K01_R, _K11_R) = range(len(TRACTION_FIELDS))

#: Columns of the kernel's state (N, S) array, one row per robot: motor speeds (rad/s), wheel
#: angles (rad), world inertial COM velocity (m/s) and yaw rate (rad/s) carried between ticks,
#: the chord velocity handed to pymunk in the last tick (m/s), and the axle pose (x, y, theta)
#: (m, m, rad) read after the last step.
STATE_FIELDS = ("w_L", "w_R", "phi_L", "phi_R", "vel_x", "vel_y", "w", "chord_x", "chord_y",
                "x", "y", "theta")
(_W_L, _W_R, _PHI_L, _PHI_R, _VEL_X, _VEL_Y, _W, _CHORD_X, _CHORD_Y, _X, _Y, _TH
 ) = range(len(STATE_FIELDS))
#: Columns of the recorded path (ticks + 1, N, 5): axle pose x, y, theta and wheel angles.
PATH_FIELDS = ("x", "y", "theta", "phi_L", "phi_R")


@numba.njit(cache=True)
def sinc_cosc(u: float) -> tuple[float, float]:
    """(sin(u)/u, (1 - cos(u))/u) of a float, compiled: the branches, closed forms and series
    coefficients of :func:`excite.core.kinematics.sinc_family_scalar` (derivatives=False), bit
    for bit: for |u| < TINY_THRESHOLD the first three Taylor terms, else the closed forms in
    sin(u/2), cos(u/2), which have no cancellation."""
    if abs(u) < TINY_THRESHOLD:
        u2 = u * u
        f = (1.0 / 120.0 * u2 + -1.0 / 6.0) * u2 + 1.0
        g = u * ((1.0 / 720.0 * u2 + -1.0 / 24.0) * u2 + 0.5)
        return f, g
    half_sin, half_cos = math.sin(0.5 * u), math.cos(0.5 * u)
    return 2.0 * half_sin * half_cos / u, 2.0 * half_sin * half_sin / u


@numba.njit(cache=True)
def _capped(x: float, y: float, cap: float) -> tuple[float, float]:
    """(x, y) scaled onto the circle of radius ``cap`` when outside it."""
    norm = math.hypot(x, y)
    if norm > cap:
        return x * cap / norm, y * cap / norm
    return x, y


@numba.njit(cache=True)
def _wheel(side: float, k00: float, k01: float, k11: float, target: float, hb: float, d: float,
           inv_m: float, inv_i: float, cap: float, vx: float, vy: float, w: float,
           acc_x: float, acc_y: float) -> tuple[float, float, float, float, float]:
    """One Gauss-Seidel update of one wheel (side +1 left, -1 right) in :func:`_slip`: its
    accumulated impulse (acc_x, acc_y) (N s) moves toward the contact's target velocity within
    the friction circle; returns the new (vx, vy, w, acc_x, acc_y)."""
    ex = target - (vx - w * side * hb)  # wanted minus contact velocity
    ey = w * d - vy
    new_x, new_y = _capped(acc_x + k00 * ex + k01 * ey, acc_y + k01 * ex + k11 * ey, cap)
    dx, dy = new_x - acc_x, new_y - acc_y
    vx += dx * inv_m
    vy += dy * inv_m
    w -= (side * hb * dx + d * dy) * inv_i
    return vx, vy, w, new_x, new_y


@numba.njit(cache=True)
def _slip(k: np.ndarray, vx: float, vy: float, w: float, t_L: float,
          t_R: float) -> tuple[float, float, float]:
    """Friction-capped traction by projected Gauss-Seidel over the two wheels.

    k: one robot's constants (:data:`TRACTION_FIELDS`). Works on the body-frame COM velocity
    (vx, vy) (m/s) and yaw rate w (rad/s); t_L, t_R are the wheel surface speeds (m/s).
    Accumulated impulses per wheel stay inside the friction circle of radius cap (N s).
    Returns the new (vx, vy, w).
    """
    hb, d, inv_m, inv_i, cap = k[_HB], k[_D], k[_INV_M], k[_INV_I], k[_CAP]
    left_x = left_y = right_x = right_y = 0.0
    for _ in range(SLIP_ITERATIONS):
        vx, vy, w, left_x, left_y = _wheel(1.0, k[_K00_L], k[_K01_L], k[_K11_L], t_L, hb, d,
                                           inv_m, inv_i, cap, vx, vy, w, left_x, left_y)
        vx, vy, w, right_x, right_y = _wheel(-1.0, k[_K00_R], k[_K01_R], k[_K11_R], t_R, hb,
                                             d, inv_m, inv_i, cap, vx, vy, w, right_x, right_y)
    return vx, vy, w


@numba.njit(cache=True)
def traction_tick(k: np.ndarray, state: np.ndarray, commands: np.ndarray, dt: float,
                  bodies: np.ndarray, slots: np.ndarray, contacts: np.ndarray,
                  began: np.ndarray, collided: np.ndarray, velocities: np.ndarray,
                  path: np.ndarray, tick: int, n_ticks: int) -> None:
    """One physics tick of N robots between two pymunk steps, in place.

    k (N, F): constants (:data:`TRACTION_FIELDS`); state (N, S): :data:`STATE_FIELDS`;
    commands (N, 2): wheel-speed commands (rad/s), clipped here to +-limit; dt (s): the tick.
    bodies (M * 6,): pymunk.batch's reading of the space's M bodies, flat (COM x, y (m), yaw
    (rad), velocity x, y (m/s), yaw rate (rad/s) of each), robot i's in row slots[i].
    contacts (N,) int: wall contacts robot i is in now; began (N,) bool: a contact began since
    the last call (cleared here). collided (N,) bool: set for the robots that touched a wall.
    velocities (M, 3): written for pymunk.batch's set (chord x, y (m/s), yaw rate (rad/s)).
    path (T, N, 5): the axle pose and wheel angles are recorded at row ``tick`` when T > 0
    (:data:`PATH_FIELDS`).

    Call ``tick`` (0 to n_ticks) of a run first takes in pymunk's last step (when tick > 0: a
    robot in wall contact adds pymunk's contact impulses to its inertial velocity and takes
    pymunk's yaw rate), reads the pose, then (when tick < n_ticks) runs the next tick's motors
    and traction:

    1. Motors: omega += (cmd - omega) * alpha (exact first-order lag); the wheel angles
       integrate omega (the encoders see the motor, slip or not).
    2. Traction: the exact rolling solution (contact velocities (r*omega, 0)) when its impulses
       fit inside both wheels' friction circles, else :func:`_slip`.
    3. The velocity handed to pymunk is the chord of the exact constant-twist arc over the tick.
    """
    absorb, advance = tick > 0, tick < n_ticks
    for i in range(state.shape[0]):
        ki = k[i]
        si = state[i]
        row = 6 * slots[i]
        d = ki[_D]
        if absorb:
            hit = contacts[i] > 0 or began[i]
            if hit:  # add pymunk's contact impulses
                began[i] = False
                collided[i] = True
                si[_VEL_X] += bodies[row + 3] - si[_CHORD_X]
                si[_VEL_Y] += bodies[row + 4] - si[_CHORD_Y]
                si[_W] = bodies[row + 5]
        x, y, th = bodies[row], bodies[row + 1], bodies[row + 2]
        c, s = math.cos(th), math.sin(th)
        si[_X], si[_Y], si[_TH] = x - d * c, y - d * s, th
        if path.shape[0] > 0:
            record = path[tick, i]
            record[0], record[1], record[2] = si[_X], si[_Y], th
            record[3], record[4] = si[_PHI_L], si[_PHI_R]
        if not advance:
            continue
        limit, alpha = ki[_LIMIT], ki[_ALPHA]
        cmd_L = min(max(commands[i, 0], -limit), limit)
        cmd_R = min(max(commands[i, 1], -limit), limit)
        w_L = si[_W_L] + (cmd_L - si[_W_L]) * alpha
        w_R = si[_W_R] + (cmd_R - si[_W_R]) * alpha
        si[_W_L], si[_W_R] = w_L, w_R
        si[_PHI_L] += w_L * dt
        si[_PHI_R] += w_R * dt
        vel_x, vel_y, w = si[_VEL_X], si[_VEL_Y], si[_W]
        vx = c * vel_x + s * vel_y  # body-frame COM velocity
        vy = c * vel_y - s * vel_x
        # Rolling target: contact velocities (r*omega, 0) fix the whole twist.
        t_L, t_R = ki[_R_L] * w_L, ki[_R_R] * w_R
        tx, tw = 0.5 * (t_L + t_R), (t_R - t_L) * ki[_INV_B]
        ty = tw * d
        # Impulses of the exact rolling solution; the lateral split is free.
        m = ki[_M]
        px, py = m * (tx - vx), m * (ty - vy)
        diff = -(ki[_INERTIA] * (tw - w) + d * py) * ki[_TWO_OVER_B]  # P_Lx - P_Rx
        q_L = ki[_CAP2] - 0.25 * (px + diff) ** 2
        q_R = ki[_CAP2] - 0.25 * (px - diff) ** 2
        if q_L >= 0.0 and q_R >= 0.0 and abs(py) <= math.sqrt(q_L) + math.sqrt(q_R):
            vx, vy, w = tx, ty, tw
        else:
            vx, vy, w = _slip(ki, vx, vy, w, t_L, t_R)
        vel_x, vel_y = c * vx - s * vy, s * vx + c * vy
        sinc, cosc = sinc_cosc(w * dt)
        chord_x = sinc * vel_x - cosc * vel_y
        chord_y = cosc * vel_x + sinc * vel_y
        si[_VEL_X], si[_VEL_Y], si[_W] = vel_x, vel_y, w
        si[_CHORD_X], si[_CHORD_Y] = chord_x, chord_y
        out = velocities[slots[i]]
        out[0], out[1], out[2] = chord_x, chord_y, w
