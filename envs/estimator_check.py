"""Test an online estimator in the environment loop: accuracy (RMSE) and consistency (NEES).

Runs an estimator factory through N episodes of an environment under a policy and reports,
per segment, the RMSE of each parameter against the hidden truth and the average normalized
estimation error squared (ANEES) with its two-sided 95% chi-square bounds. A consistent
estimator's ANEES lies inside the bounds; one that is overconfident lies above them. The
parameters judged are those the estimator reports a covariance for (see
:func:`excite.stats.consistency.estimate_error`): the wheels (r_L, r_R, b) on the axle model, and
the sensor pose too on ``excite/DiffDriveCalibSensor-v0`` with a sensor-pose estimator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from envs.env import default_estimator
from excite.contracts import EstimatorFactory
from excite.core.models import SENSOR_POSE
from excite.stats.chi2 import chi2_quantile
from excite.stats.consistency import CONFIDENCE, anees, anees_bounds, estimate_error, nees, verdict

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class EstimatorReport:
    """Per-segment accuracy and consistency of an estimator over ``episodes`` episodes.

    rmse: (K, P) RMSE of the P judged parameters (r_L, r_R, b in m, then l_x, l_y in m and
    l_theta in rad when the sensor pose is estimated) after each of K segments.
    anees: (K,) average NEES; anees_bounds: (low, high) two-sided 95% chi-square bounds of the
    ANEES of consistent estimates (P parameters, ``episodes`` samples).
    nees_final: (episodes,) NEES after the last segment of each episode.
    """

    env_id: str
    episodes: int
    rmse: np.ndarray
    anees: np.ndarray
    anees_bounds: tuple[float, float]
    nees_final: np.ndarray

    @property
    def parameters(self) -> int:
        """P, the number of parameters judged."""
        return int(self.rmse.shape[-1])

    @property
    def verdict(self) -> str:
        """The final ANEES against its bounds (:func:`excite.stats.consistency.verdict`)."""
        return verdict(float(self.anees[-1]), self.anees_bounds)

    @property
    def consistent(self) -> bool:
        """ANEES after the last segment inside its 95% bounds."""
        return self.verdict == "consistent"

    @property
    def fraction_inside_95(self) -> float:
        """Share of episodes whose final estimate lies inside its 95% ellipse."""
        return float(np.mean(self.nees_final <= chi2_quantile(CONFIDENCE, self.parameters)))

    def summary(self) -> str:
        low, high = self.anees_bounds
        # The judged parameters lead the sensor-pose model's (the wheels first).
        rmse = ", ".join(f"{n} {v:.2e} {u}" for n, v, u in zip(
            SENSOR_POSE.names, self.rmse[-1], SENSOR_POSE.units, strict=False))
        return (f"{self.env_id}: {self.episodes} episodes x {len(self.anees)} segments; "
                f"final RMSE {rmse}; "
                f"ANEES {self.anees[-1]:.2f} (95% bounds {low:.2f}-{high:.2f}, "
                f"{'consistent' if self.consistent else 'INCONSISTENT: ' + self.verdict}); "
                f"{100 * self.fraction_inside_95:.0f}% of final estimates inside their 95% "
                "ellipse")


def check_estimator(
    env: str | gym.Env,
    estimator_factory: EstimatorFactory = default_estimator,
    policy: Policy | None = None,
    episodes: int = 100,
    seed: int = 0,
    **env_kwargs,
) -> EstimatorReport:
    """Run ``estimator_factory`` in ``env`` (an id or an instance) for ``episodes`` episodes.

    policy: observation -> action; None draws uniform random actions (seeded).
    env_kwargs: passed to ``gymnasium.make`` when ``env`` is an id (e.g. budget=150).
    """
    if isinstance(env, str):
        env_id = env
        env = gym.make(env, estimator_factory=estimator_factory, **env_kwargs)
    else:
        env_id = env.spec.id if env.spec else type(env.unwrapped).__name__
        env.unwrapped.estimator_factory = estimator_factory
    env.action_space.seed(seed)
    errors, covariances = [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        truth = env.unwrapped.true_theta
        ep_err, ep_cov = [], []
        done = False
        while not done:
            action = env.action_space.sample() if policy is None else policy(obs)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
            error, covariance = estimate_error(env.unwrapped.estimator, truth)
            ep_err.append(error)
            ep_cov.append(covariance)
        errors.append(ep_err)
        covariances.append(ep_cov)
    length = min(len(e) for e in errors)
    err = np.array([e[:length] for e in errors])
    cov = np.array([c[:length] for c in covariances])
    return EstimatorReport(
        env_id=env_id,
        episodes=episodes,
        rmse=np.sqrt(np.mean(err**2, axis=0)),
        anees=anees(err, cov),
        anees_bounds=anees_bounds(episodes, err.shape[-1]),
        nees_final=nees(err[:, -1], cov[:, -1]),
    )


def assert_consistent(report: EstimatorReport) -> None:
    """pytest-friendly: raise AssertionError with the summary unless ANEES is in bounds."""
    if not report.consistent:
        raise AssertionError(report.summary())
