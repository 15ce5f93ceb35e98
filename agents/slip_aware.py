"""The slip-aware information planner: E-optimal excitation that plans around slip.

The greedy planner (:mod:`agents.greedy`) picks the most informative command as if the wheels
rolled without slip and reached every command at once. On a real floor (and the slip env) a
command change is followed by the motors' lag (the arc bends while the wheels catch up) and,
when it asks a wheel's contact for more acceleration than the floor can give, by slip: the
encoders then count rotation that never became motion. Both bias the calibration, and the
bias does not average out with more segments.

Each segment this planner scores candidate maneuvers (below), reached from the previous
command by at most ``max_step`` per wheel and segment (a smoothness limit), with a model of
the NOMINAL robot (:class:`excite.contracts.Traction`: motor lag and grip, never the hidden
truth):

1. the nominal wheel dynamics, integrated at ``SUBSTEP_HZ``: each motor approaches the command
   with its lag, and the wheels' contacts follow their surface speeds only as fast as the grip
   allows (less the lateral acceleration of the turn; turning needs spin_inertia times the
   push of a straight acceleration); the encoders see the motor.
   The segment's motion is the composition of the contacts' sub-arcs (excite.core.models'
   sub-steps), so the model predicts the measured increment's error against the single arc
   the estimator fits: from the lag bending the arc and from slip;
2. that error, whitened, enters the estimate as a bias: after segments k the least-squares
   estimate moves by F^-1 sum_k J_k^T e_k (relative units, J_k the whitened, relatively scaled
   Jacobian of excite.core.information, F including the estimator's prior);
3. the cost of a candidate is the predicted squared worst error after it: the worst-direction
   variance 1 / lambda_min(F) (the Cramer-Rao bound, as greedy maximises lambda_min) plus
   ``bias_weight`` times the largest squared relative bias; the cheapest safe one is chosen.

A candidate is a maneuver to aim at, anywhere in the command box (a ``grid`` x ``grid`` grid
over it, and the same grid within ``max_step`` of the last command), valued over
``lookahead`` segments: ramping towards it by at most ``max_step`` per wheel and segment, then
holding it; the first step of the ramp is the command. Where ``max_step`` crosses the box in
fewer steps, over that many (one when a step reaches anywhere: nothing is out of reach).
Valued over the next segment alone (``lookahead=1``), a planner whose neighbourhood holds no
information in the weakest direction (a spin's, on the overall scale of the wheels and the
track) holds its command for ever: the maneuver that would inform that direction is several
steps away.

Safe means: the candidate clears the walls (the guard's check, so the guard never has to undo
a plan), and so does a continuation from its end pose that honours the smoothness limit for up
to ``horizon`` more segments (ramping down to a stop, or into a spin either way): the robot is
never planned into a corner that only a sudden (slipping) command could leave.

Light: numpy and excite's contracts only, no simulator (a planner can drive a real robot).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from agents.greedy import best_index, square_grid
from agents.motion import (
    action_margin,
    is_safe,
    predicted_poses,
    safe_actions,
    wheel_increments,
)
from agents.protocols import MAX_SPEED, WALL_MARGIN, Parameter, Protocol, ProtocolError, Value
from excite.contracts import RobotKnowledge
from excite.core.information import scaled_jacobian
from excite.core.kinematics import Params
from excite.core.models import SegmentModel
from excite.estimators.base import DEFAULT_PRIOR

#: Hz, the rate at which the nominal wheel dynamics are integrated (the simulator's tick).
SUBSTEP_HZ = 50.0
#: Gauss-Seidel sweeps over the two wheels when a wheel slips (as the simulator).
SLIP_SWEEPS = 6
#: Fraction of the speed limit the continuation's spins turn at.
SPIN_FRACTION = 0.5

MAX_STEP = Parameter("max_step", float, 0.2, "largest change of a wheel command from one "
                     "segment to the next, fraction of the motor limit", 0.02, 2.0, grid=3,
                     log=True)
BIAS_WEIGHT = Parameter("bias_weight", float, 1.0, "weight of the predicted squared slip/lag "
                        "bias against the variance (1: mean squared error)", 0.1, 10.0)
HORIZON = Parameter("horizon", int, 6, "segments of smooth continuation (stop, or spin) that "
                    "must stay clear of the walls after a candidate", 1, 20)
GRID = Parameter("grid", int, 9, "candidate commands per wheel (grid x grid over the command "
                 "box, and as many within max_step of the previous command)", 3, 41)
LOOKAHEAD = Parameter("lookahead", int, 6, "segments over which a candidate is valued: ramping "
                      "towards it by max_step per segment, then holding it (at most the steps "
                      "that cross the command box)", 1, 20)


def nominal_segment(previous: np.ndarray, actions: np.ndarray, knowledge: RobotKnowledge,
                    substep_hz: float = SUBSTEP_HZ) -> tuple[np.ndarray, np.ndarray]:
    """The nominal robot's segment under each command after ``previous`` (both fractions of the
    motor limit; actions (n, 2)), started in steady rolling at ``previous``.

    Returns the encoder increments (n, 2) (rad: the motors' rotation, lag included) and the
    contacts' sub-increments (n, K, 2) (rad of wheel rotation that became motion, one per
    substep; their composition is the body's motion). Geometry: the current estimate;
    lag and grip: ``knowledge.traction``.
    """
    traction = knowledge.traction
    if traction is None:
        raise ProtocolError("slip_aware needs the nominal robot's motor lag and grip "
                            "(RobotKnowledge.traction)")
    actions = np.atleast_2d(np.asarray(actions, dtype=float))
    n_sub = max(1, round(knowledge.segment_duration * substep_hz))
    dt = knowledge.segment_duration / n_sub
    alpha = 1.0 - np.exp(-dt / traction.motor_tau)
    radius = np.array([knowledge.estimate.r_L, knowledge.estimate.r_R])
    inv_b = 1.0 / knowledge.estimate.b
    command = actions * knowledge.max_wheel_speed  # rad/s
    motor = np.broadcast_to(np.asarray(previous, dtype=float) * knowledge.max_wheel_speed,
                            command.shape).copy()
    contact = motor * radius  # m/s, rolling at the previous command
    encoder = np.zeros_like(command)
    ground = np.empty((n_sub,) + command.shape)
    grip_dt = traction.grip * dt
    # A wheel's push f (its force over half the mass, m/s per tick) changes its own contact's
    # speed by own * f and the other's by cross * f.
    own = 0.5 * (1.0 + 1.0 / traction.spin_inertia)
    cross = 0.5 * (1.0 - 1.0 / traction.spin_inertia)
    for k in range(n_sub):
        motor += (command - motor) * alpha
        encoder += motor * dt
        speed = contact.mean(axis=1)
        turn = (contact[:, 1] - contact[:, 0]) * inv_b
        lateral = speed * turn
        room = np.sqrt(np.maximum(grip_dt**2 - (lateral * dt) ** 2, 0.0))
        contact += _traction_step(motor * radius - contact, room, own, cross)
        ground[k] = contact * dt / radius
    return encoder, np.moveaxis(ground, 0, 1)


def _traction_step(want: np.ndarray, room: np.ndarray, own: float, cross: float
                   ) -> np.ndarray:
    """The contacts' speed changes (n, 2) (m/s) in one tick: ``want`` (n, 2), the change that
    would make them roll, when both wheels' pushes fit in ``room`` (n,); else the pushes
    capped at ``room`` by projected Gauss-Seidel sweeps over the two wheels, as the
    simulator's solver does."""
    determinant = own * own - cross * cross
    push = (want * own - want[:, ::-1] * cross) / determinant
    slipping = np.abs(push).max(axis=1) > room
    if slipping.any():
        wanted, cap = want[slipping], room[slipping]
        capped = np.zeros_like(wanted)
        for _ in range(SLIP_SWEEPS):
            for i in (0, 1):
                moved = own * capped[:, i] + cross * capped[:, 1 - i]
                capped[:, i] = np.clip(capped[:, i] + (wanted[:, i] - moved) / own, -cap, cap)
        push[slipping] = capped
    return push * own + push[:, ::-1] * cross


def predicted_bias(previous: np.ndarray, actions: np.ndarray, knowledge: RobotKnowledge
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Per command after ``previous``: the whitened, relatively scaled Jacobian (n, 3, P) at
    the predicted encoder increments, and the whitened error (n, 3) of the single arc the
    estimator fits against the motion the nominal robot makes (lag and slip)."""
    encoder, ground = nominal_segment(previous, actions, knowledge)
    model, theta = knowledge.model, knowledge.theta
    single, _ = model.evaluate(encoder[:, 0], encoder[:, 1], theta, jacobian=False)
    moved, _ = model.evaluate(ground[..., 0], ground[..., 1], theta, jacobian=False,
                              substeps=True)
    error = (moved - single).T / knowledge.sigma
    jac = scaled_jacobian(encoder[:, 0], encoder[:, 1], theta, knowledge.sigma,
                          scale=knowledge.nominal_theta, model=model)
    return jac, error


def prior_information(knowledge: RobotKnowledge) -> np.ndarray:
    """The default estimator's prior as relative information (P x P, diagonal)."""
    return np.diag([DEFAULT_PRIOR[t] ** -2.0 for t in knowledge.model.transforms])


class SlipAwarePlanner(Protocol):
    """E-optimal planner with a nominal slip/lag model: minimises the predicted worst variance
    plus ``bias_weight`` x squared bias over maneuvers ramped to by ``max_step`` per segment
    (valued over :attr:`steps` segments), keeping a smooth way out of every wall for
    ``horizon`` segments."""

    parameters = (
        replace(MAX_SPEED, grid=2),  # 0.1 or 1 (2 x 3 candidates: a few minutes to tune)
        MAX_STEP, BIAS_WEIGHT, HORIZON, GRID, LOOKAHEAD, WALL_MARGIN,
    )
    max_speed: float
    max_step: float
    bias_weight: float
    horizon: int
    grid: int
    lookahead: int

    def __init__(self, **settings: Value) -> None:
        super().__init__(**settings)
        self.offsets = square_grid(self.grid, self.max_step)
        self.box = square_grid(self.grid, self.max_speed)

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.previous = np.zeros(2)
        self.bias_gradient: np.ndarray | None = None  # sum_k J_k^T e_k of the segments so far
        self.bias_model: SegmentModel | None = None  # the model it is of

    def act(self, knowledge: RobotKnowledge) -> np.ndarray:
        action = super().act(knowledge)
        jac, error = predicted_bias(self.previous, action[None, :], knowledge)
        self.bias_gradient = self._gradient(knowledge) + np.einsum("nrp,nr->p", jac, error)
        self.bias_model = knowledge.model
        self.previous = action
        return action

    def _gradient(self, knowledge: RobotKnowledge) -> np.ndarray:
        """The predicted bias gradient of the segments so far, in the knowledge's model: zero
        at the start, and again when the model changes (a live session's ``auto`` choosing
        the axle model once the mounting is found on the axle)."""
        if self.bias_gradient is None or self.bias_model is not knowledge.model:
            return np.zeros(knowledge.model.size)
        return self.bias_gradient

    def candidates(self) -> np.ndarray:
        """The maneuvers aimed at: the grid over the command box and the grid within
        ``max_step`` of the previous command (per wheel), within ``max_speed``, each once."""
        moved = np.clip(self.previous + self.offsets, -self.max_speed, self.max_speed)
        return np.unique(np.concatenate([moved, self.box]), axis=0)

    @property
    def steps(self) -> int:
        """The segments a candidate is valued over: ``lookahead``, or fewer where
        ``max_step`` crosses the command box in fewer (2 max_speed / max_step; 1 when one
        step reaches anywhere, and there is no ramp to value)."""
        return max(1, min(self.lookahead, math.ceil(2.0 * self.max_speed / self.max_step
                                                    - 1e-9)))

    def ramps(self, targets: np.ndarray) -> np.ndarray:
        """The commands (n, steps, 2) of the next :attr:`steps` segments towards each
        target (n, 2): each at most ``max_step`` per wheel from the one before, the first
        from the previous command, then the target held."""
        paths = np.empty((len(targets), self.steps, 2))
        command = np.broadcast_to(self.previous, targets.shape)
        for k in range(self.steps):
            command = command + np.clip(targets - command, -self.max_step, self.max_step)
            paths[:, k] = command
        return paths

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        paths = self.ramps(self.candidates())
        first = paths[:, 0]
        clear = safe_actions(first, knowledge, self.speed_margin)
        safe = clear & self.escapes(first, knowledge)
        if not safe.any():  # cornered: any candidate clear now, else slow down (the guard
            safe = clear    # does the rest)
        if not safe.any():
            return self.previous - np.clip(self.previous, -self.max_step, self.max_step)
        score = -self.cost(paths[safe], knowledge)
        return first[safe][best_index(score, first[safe], knowledge)]

    def cost(self, paths: np.ndarray, knowledge: RobotKnowledge) -> np.ndarray:
        """Predicted squared worst relative error after each path of commands (n, k, 2):
        worst-direction variance plus ``bias_weight`` x the largest squared relative bias."""
        information = knowledge.information + prior_information(knowledge)
        gradient = self._gradient(knowledge)
        previous = np.broadcast_to(self.previous, paths[:, 0].shape)
        for k in range(paths.shape[1]):
            jac, error = predicted_bias(previous, paths[:, k], knowledge)
            information = information + np.einsum("nrp,nrq->npq", jac, jac)
            gradient = gradient + np.einsum("nrp,nr->np", jac, error)
            previous = paths[:, k]
        bias = np.linalg.solve(information, gradient[..., None])[..., 0]
        variance = 1.0 / np.linalg.eigvalsh(information)[:, 0]
        return variance + self.bias_weight * np.max(bias**2, axis=1)

    def escapes(self, candidates: np.ndarray, knowledge: RobotKnowledge) -> np.ndarray:
        """Whether each candidate leaves a smooth continuation (stop, spin left or spin right)
        that clears the walls for ``horizon`` segments, predicted (like the guard) with both
        the estimate and the nominal robot."""
        spin = SPIN_FRACTION * self.max_speed
        targets = np.repeat([[0.0, 0.0], [-spin, spin], [spin, -spin]], len(candidates), axis=0)
        commands = np.tile(candidates, (3, 1))
        dphi = wheel_increments(candidates, knowledge)
        clear = np.logical_and.reduce([
            self._continuation_clear(
                commands, np.tile(predicted_poses(knowledge.pose, dphi, params)[:, -1], (3, 1)),
                targets, params, knowledge)
            for params in (knowledge.estimate, knowledge.nominal)])
        return clear.reshape(3, -1).any(axis=0)

    def _continuation_clear(self, commands: np.ndarray, poses: np.ndarray, targets: np.ndarray,
                            params: Params, knowledge: RobotKnowledge) -> np.ndarray:
        """Whether ramping each command (n, 2) towards its target (n, 2) by at most
        ``max_step`` per segment, from its pose (n, 3), stays clear of the walls for up to
        ``horizon`` segments (kinematic prediction with ``params``)."""
        clear = np.ones(len(commands), dtype=bool)
        for _ in range(self.horizon):
            if np.array_equal(commands, targets):
                break
            commands = commands + np.clip(targets - commands, -self.max_step, self.max_step)
            path = predicted_poses(poses, wheel_increments(commands, knowledge), params)
            clear &= is_safe(path, knowledge.arena,
                             action_margin(commands, self.speed_margin), knowledge.chassis)
            poses = path[:, -1]
        return clear
