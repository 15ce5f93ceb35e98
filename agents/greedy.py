"""The model-based information planner: greedy E-optimal excitation.

At every segment it predicts, with the kinematic model at the current estimate, the
information each candidate command would add, and picks the one that raises sigma_min of all
segments most, among those predicted to stay clear of the walls. With ``lookahead`` it scores
each of the best first moves by the best second move that can follow it. Mirror-image commands
(forward and backward, say) add the same information; such ties go to the move predicted to
end nearest the arena centre, not to the last bit of rounding.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from agents.motion import (
    action_margin,
    is_safe,
    predicted_poses,
    safe_actions,
    turn_to_center,
    wheel_increments,
)
from agents.protocols import MAX_SPEED, WALL_MARGIN, Parameter, Protocol, Value
from excite.contracts import RobotKnowledge
from excite.core.information import segment_information

#: Relative score difference below which two commands count as equally informative.
TIE_TOLERANCE = 1e-9


def square_grid(n: int, limit: float = 1.0) -> np.ndarray:
    """All (left, right) pairs (n^2, 2) of an n x n grid over [-limit, limit]^2, left-major."""
    axis = np.linspace(-limit, limit, n)
    return np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)


def command_grid(n: int, limit: float = 1.0) -> np.ndarray:
    """All (left, right) pairs of an n x n grid over [-limit, limit]^2, without (0, 0)."""
    grid = square_grid(n, limit)
    return grid[np.any(grid != 0.0, axis=1)]


def command_information(actions: np.ndarray, knowledge: RobotKnowledge) -> np.ndarray:
    """Relative Fisher information (n, P, P) each command would add, predicted with the
    knowledge's segment model at the estimate."""
    dphi = wheel_increments(actions, knowledge)
    return segment_information(dphi[:, 0], dphi[:, 1], knowledge.theta, knowledge.sigma,
                               scale=knowledge.nominal_theta, model=knowledge.model)


def smallest_eigenvalue(information: np.ndarray) -> np.ndarray:
    return np.linalg.eigvalsh(information)[..., 0]


def best_index(score: np.ndarray, candidates: np.ndarray, knowledge: RobotKnowledge) -> int:
    """Index of the best (highest) score of the candidate commands (n, 2); ties (within 1e-9)
    go to the command predicted to end nearest the arena centre."""
    top = float(np.max(score))
    tied = np.flatnonzero(score >= top - TIE_TOLERANCE * abs(top))
    if tied.size <= 1:  # one best, or no comparable score (nan)
        return int(tied[0]) if tied.size else int(np.argmax(score))
    dphi = wheel_increments(candidates[tied], knowledge)
    ends = predicted_poses(knowledge.pose, dphi, knowledge.estimate)[:, -1, :2]
    return int(tied[np.argmin(np.hypot(ends[:, 0], ends[:, 1]))])


class GreedyPlanner(Protocol):
    """E-optimal greedy planner over a grid of commands (``grid`` x ``grid`` in
    [-max_speed, max_speed]^2); ``lookahead`` adds a second step for the ``beam`` best."""

    parameters = (
        MAX_SPEED,
        Parameter("grid", int, 21, "candidate commands per wheel (grid x grid in all)", 3, 101),
        Parameter("lookahead", bool, False, "score each of the beam best moves by its best "
                  "second move"),
        Parameter("beam", int, 12, "first moves scored two steps ahead (with lookahead)",
                  1, 1000),
        replace(WALL_MARGIN, grid=3),  # it drives to the walls' limits, unlike the scripts
    )
    max_speed: float
    grid: int
    lookahead: bool
    beam: int

    def __init__(self, **settings: Value) -> None:
        super().__init__(**settings)
        self.candidates = command_grid(self.grid, self.max_speed)

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        gains = command_information(self.candidates, knowledge)
        score = smallest_eigenvalue(knowledge.information + gains)
        ok = safe_actions(self.candidates, knowledge, self.speed_margin)
        if not ok.any():
            return turn_to_center(knowledge)
        score = np.where(ok, score, -np.inf)
        if self.lookahead and knowledge.n_segments + 1 < knowledge.budget:
            score = self._two_step_scores(knowledge, gains, score)
        return self.candidates[best_index(score, self.candidates, knowledge)]

    def _two_step_scores(self, knowledge: RobotKnowledge, gains: np.ndarray,
                         score: np.ndarray) -> np.ndarray:
        """Replace the scores of the ``beam`` best first moves by their best two-step score
        (the second move also wall-checked, from the first move's predicted end pose)."""
        best = np.argsort(score)[::-1][: self.beam]
        best = best[np.isfinite(score[best])]
        dphi = wheel_increments(self.candidates[best], knowledge)
        ends = predicted_poses(knowledge.pose, dphi, knowledge.estimate)[:, -1]
        second_dphi = wheel_increments(self.candidates, knowledge)
        two_step = np.full(score.shape, -np.inf)
        for index, end in zip(best, ends, strict=True):
            safe = is_safe(predicted_poses(end, second_dphi, knowledge.estimate),
                           knowledge.arena,
                           action_margin(self.candidates, self.speed_margin),
                           knowledge.chassis)
            if not safe.any():
                continue
            info = knowledge.information + gains[index] + gains[safe]
            two_step[index] = smallest_eigenvalue(info).max()
        return two_step if np.isfinite(two_step).any() else score
