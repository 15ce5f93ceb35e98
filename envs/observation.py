"""What a robot knows after each segment, and the observation vector built from it.

The sensor's readings through its mounting, the estimator's estimate, the eigen-decomposition
of the information matrix, and the observation (the table in
:class:`envs.env.DiffDriveCalibEnv`'s docstring): for one robot (the single env) and for N
robots batch-first (the vector env), one implementation of the numbers for both envs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from gymnasium import spaces

from envs.sensors import RelativePoseSensor
from excite.core import se2
from excite.core.information import eigen_3x3, information_matrix
from excite.core.kinematics import Params
from excite.core.models import AXLE, SegmentModel, body_to_sensor


def observation_space(model: SegmentModel) -> spaces.Box:
    """The observation space of a model with P parameters: ``Box(float32, (3 P + 7,))``."""
    p = model.size
    low = np.array([-1] * p + [0] * p + [-1] * p + [-1.5] * 2 + [-1] * 4 + [0], np.float32)
    high = np.array([1] * p + [5] * p + [1] * p + [1.5] * 2 + [1] * 4 + [1], np.float32)
    return spaces.Box(low, high, dtype=np.float32)


def read_estimate(estimator, model: SegmentModel,
                  nominal_theta: np.ndarray) -> tuple[Params, np.ndarray]:
    """The estimator's wheel parameters and all model parameters (an estimator without
    ``theta`` leaves the sensor pose at its nominal value)."""
    p = estimator.params
    params = p if isinstance(p, Params) else Params.from_array(p)
    if model is AXLE:
        return params, params.as_array()
    theta = getattr(estimator, "theta", None)
    if theta is None or len(theta) != model.size:
        theta = np.append(params.as_array(), nominal_theta[3:])
    return params, np.asarray(theta, dtype=float)


def sense_increments(sensor: RelativePoseSensor, true_increments: np.ndarray,
                     rngs: Sequence[np.random.Generator], mounts: np.ndarray) -> np.ndarray:
    """N off-axle sensors' noisy increments (N, 3): each sensor's own motion in its own frame
    at the segment's start (docs/conventions.md, "Sensor pose"; x, y in m, theta in rad), robot i
    drawing its noise from ``rngs[i]``. true_increments (N, 3): the bodies' true increments;
    mounts (N, 3): the sensors' mountings in the body frame."""
    return sensor.each(body_to_sensor(true_increments, mounts), rngs)


def measure_poses(sensor: RelativePoseSensor, body_poses: np.ndarray,
                  rngs: Sequence[np.random.Generator], mounts: np.ndarray | None,
                  theta: np.ndarray) -> np.ndarray:
    """N bodies' world poses (N, 3) (x, y, theta) as the robots know them: each sensor's
    noisy world pose (robot i drawing from ``rngs[i]``), taken back to the body with the
    estimated mounting (theta[:, 3:6]). body_poses (N, 3): the true poses; mounts (N, 3): the
    sensors' true mountings (None: on the axle); theta (N, P): the estimates."""
    if mounts is None:
        return sensor.each(body_poses, rngs)
    readings = sensor.each(se2.compose(body_poses, mounts), rngs)
    return se2.compose(readings, se2.inverse(theta[:, 3:6]))


def eigen(information: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """One robot's eigenvalues (ascending) and weakest eigenvector of its information matrix
    (P x P); closed form for 3 x 3."""
    if information.shape == (3, 3):
        return eigen_3x3(information)
    lam, vec = np.linalg.eigh(information)
    return tuple(lam.tolist()), tuple(vec[:, 0].tolist())


def observation(model: SegmentModel, theta: Sequence[float], nominal_theta: Sequence[float],
                eigenvalues: Sequence[float], weakest: Sequence[float], pose: Sequence[float],
                last_action: Sequence[float], used: float, arena_size: float,
                space: spaces.Box) -> np.ndarray:
    """One robot's observation (3 P + 7,) float32 (the table in DiffDriveCalibEnv's doc), from
    Python floats: the single env's step (a few microseconds, where :func:`observations` of a
    batch of one spends several times that on numpy's call overheads); a tested
    specialisation of :func:`observations`, the same numbers.

    theta: the estimate (P values), nominal_theta: the nominal ones; eigenvalues (ascending)
    and weakest, the eigenvector of the smallest (given a unique sign here: its largest
    entry is positive); pose: the measured world pose (x, y in m, theta in rad); last_action
    (2 values); used: the fraction of the budget used; arena_size (m). Clipped to ``space``.
    """
    sign = 1.0 if max(weakest, key=abs) >= 0 else -1.0  # a unique sign for the direction
    relative = [theta[0] / nominal_theta[0] - 1.0, theta[1] / nominal_theta[1] - 1.0,
                theta[2] / nominal_theta[2] - 1.0]
    if model is not AXLE:
        b = nominal_theta[2]
        relative += [(theta[3] - nominal_theta[3]) / b, (theta[4] - nominal_theta[4]) / b,
                     theta[5] - nominal_theta[5]]
    x, y, heading = pose
    to_unit = 2.0 / arena_size
    obs = np.array([
        *relative,
        *[0.1 * math.log1p(max(lam, 0.0)) for lam in eigenvalues],
        *[sign * v for v in weakest],
        x * to_unit, y * to_unit, math.cos(heading), math.sin(heading),
        *last_action,
        used,
    ], dtype=np.float32)
    return np.minimum(np.maximum(obs, space.low, out=obs), space.high, out=obs)


def observations(model: SegmentModel, theta: np.ndarray, nominal_theta: np.ndarray,
                 eigenvalues: np.ndarray, weakest: np.ndarray, pose: np.ndarray,
                 last_action: np.ndarray, used: np.ndarray, arena_size: float,
                 space: spaces.Box) -> np.ndarray:
    """N robots' observations (N, 3 P + 7) float32 (the table in DiffDriveCalibEnv's doc),
    batch-first.

    theta (N, P): the estimates; nominal_theta (P,): the nominal parameters; eigenvalues
    (N, P), ascending, and weakest (N, P), the eigenvector of the smallest (given a unique
    sign here: its first entry of largest magnitude is positive); pose (N, 3): the measured
    world poses (x, y in m, theta in rad); last_action (N, 2); used (N,): the fraction of the
    budget used; arena_size (m). Clipped to ``space``. The vector env's step; the single
    env's is :func:`observation`.
    """
    n, p = theta.shape
    obs = np.empty((n, 3 * p + 7))
    np.divide(theta[:, :3], nominal_theta[:3], out=obs[:, :3])
    obs[:, :3] -= 1.0
    if model is not AXLE:  # offsets in units of the nominal b, the angle in rad
        obs[:, 3:5] = (theta[:, 3:5] - nominal_theta[3:5]) / nominal_theta[2]
        obs[:, 5] = theta[:, 5] - nominal_theta[5]
    obs[:, p:2 * p] = 0.1 * np.log1p(np.maximum(eigenvalues, 0.0))
    largest = weakest[np.arange(n), np.abs(weakest).argmax(axis=1)]
    np.multiply(weakest, np.where(largest >= 0, 1.0, -1.0)[:, None], out=obs[:, 2 * p:3 * p])
    obs[:, 3 * p:3 * p + 2] = pose[:, :2] * (2.0 / arena_size)
    obs[:, 3 * p + 2] = np.cos(pose[:, 2])
    obs[:, 3 * p + 3] = np.sin(pose[:, 2])
    obs[:, 3 * p + 4:3 * p + 6] = last_action
    obs[:, 3 * p + 6] = used
    out = obs.astype(np.float32)
    return np.minimum(np.maximum(out, space.low, out=out), space.high, out=out)


def observation_of(knowledge, last_action) -> np.ndarray:
    """The observation (the table in DiffDriveCalibEnv's doc) of what a robot knows, as
    :class:`excite.contracts.RobotKnowledge` (a live session's), after ``last_action``
    ([-1, 1]^2): what a learned policy reads off the simulator."""
    eigenvalues, weakest = eigen(knowledge.information)
    return observation(knowledge.model, knowledge.theta.tolist(),
                       knowledge.nominal_theta.tolist(), eigenvalues, weakest,
                       knowledge.pose.tolist(), [float(a) for a in last_action],
                       min(knowledge.n_segments / knowledge.budget, 1.0), knowledge.arena_size,
                       observation_space(knowledge.model))


def on_axle(knowledge):
    """The same knowledge on the axle model (the wheels' three parameters, the information
    of the log on them): what a policy trained on the wheels-only env reads while a live
    session plans for the sensor-pose model."""
    log = knowledge.log
    information = (information_matrix(log[:, 0], log[:, 1], knowledge.estimate,
                                      knowledge.sigma, scale=knowledge.nominal)
                   if len(log) else np.zeros((3, 3)))
    return replace(knowledge, model=AXLE, theta=knowledge.estimate.as_array(),
                   nominal_theta=knowledge.nominal.as_array(), information=information)


def observer_for(shape: tuple[int, ...]):
    """The observation a policy trained for observations of ``shape`` reads from a live
    session's knowledge: :func:`observation_of` the knowledge's own model, or of
    :func:`on_axle` when only that has the policy's shape (the policy refuses any other)."""
    axle = observation_space(AXLE).shape

    def observe(knowledge, last_action) -> np.ndarray:
        if (knowledge.model is not AXLE and tuple(shape) == axle
                and observation_space(knowledge.model).shape != axle):
            knowledge = on_axle(knowledge)
        return observation_of(knowledge, last_action)

    return observe
