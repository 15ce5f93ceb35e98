"""The oracle bound: the sigma_min an E-optimal design of the same budget would reach.

For the true parameters and ideal kinematics, ignoring walls, the best possible allocation of
``budget`` segments over a dense grid of admissible constant commands maximises
lambda_min(sum_i w_i M_i) subject to w >= 0, sum w = budget (the convex relaxation of the
design problem, so its optimum is a ceiling for every protocol using such segments). Solved by
Kelley's cutting planes: lambda_min(F) = min over unit v of v^T F v is concave and piecewise
linear in w through the directions v; each LP adds the current worst direction as a cut. The
LP value is an upper bound, the design it returns a lower bound; we stop when they agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from agents.greedy import command_grid
from excite.core.information import segment_information
from excite.core.kinematics import Params
from excite.core.models import AXLE, SegmentModel


@dataclass(frozen=True)
class OracleDesign:
    """sigma_min: the ceiling (sqrt of the LP upper bound); lower: sqrt of the lambda_min the
    returned design achieves; commands: (n, 2) actions; weights: (n,) segments per command."""

    sigma_min: float
    lower: float
    commands: np.ndarray
    weights: np.ndarray
    iterations: int


def oracle_design(
    params: Params | np.ndarray,
    sigma: np.ndarray,
    nominal: Params | np.ndarray,
    budget: int,
    max_wheel_speed: float,
    segment_duration: float,
    grid: int = 41,
    rtol: float = 1e-4,
    max_iterations: int = 200,
    model: SegmentModel = AXLE,
) -> OracleDesign:
    """E-optimal design over a grid x grid set of commands in [-1, 1]^2, the standstill
    (no information) left out (see module doc). params / nominal: the model's true and
    nominal parameters (Params for the axle model)."""
    commands = command_grid(grid)
    dphi = commands * max_wheel_speed * segment_duration
    info = segment_information(dphi[:, 0], dphi[:, 1], params, sigma, scale=nominal,
                               model=model)
    n = len(commands)
    cuts = list(np.eye(model.size))
    objective = np.zeros(n + 1)
    objective[-1] = -1.0  # maximise t
    a_eq = np.append(np.ones(n), 0.0)[None, :]
    bounds = [(0, None)] * n + [(None, None)]
    upper = lower = 0.0
    weights = np.zeros(n)
    iteration = 0
    while iteration < max_iterations:
        iteration += 1
        v = np.array(cuts)
        quad = np.einsum("ci,nij,cj->cn", v, info, v)  # v_c^T M_n v_c
        a_ub = np.hstack([-quad, np.ones((len(cuts), 1))])  # t - sum_n w_n q_cn <= 0
        lp = linprog(objective, A_ub=a_ub, b_ub=np.zeros(len(cuts)), A_eq=a_eq,
                     b_eq=[budget], bounds=bounds, method="highs")
        if lp.status != 0:
            raise RuntimeError(f"oracle LP failed: {lp.message}")
        weights, upper = lp.x[:n], -lp.fun
        lam, vec = np.linalg.eigh(np.einsum("n,nij->ij", weights, info))
        lower = max(lam[0], 0.0)
        if upper - lower <= rtol * upper:
            break
        cuts.append(vec[:, 0])
    used = weights > 1e-9 * budget
    return OracleDesign(float(np.sqrt(upper)), float(np.sqrt(lower)), commands[used],
                        weights[used], iteration)
