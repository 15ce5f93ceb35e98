"""Test an online estimator in the environment loop: accuracy (RMSE) and consistency (NEES).

Runs an estimator factory through N episodes of an environment under a policy and reports,
per segment, the RMSE of each parameter against the hidden truth and the average normalized
estimation error squared (ANEES) with its two-sided 95% chi-square bounds. A consistent
estimator's ANEES lies inside the bounds; one that is overconfident lies above them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from scipy.stats import chi2

from envs.env import EstimatorFactory, default_estimator

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class EstimatorReport:
    """Per-segment accuracy and consistency of an estimator over ``episodes`` episodes.

    rmse: (K, 3) RMSE of (r_L, r_R, b) in meters after each of K segments.
    anees: (K,) average NEES; anees_bounds: (low, high) two-sided 95% chi-square bounds of the
    ANEES of consistent estimates (3 parameters, ``episodes`` samples).
    nees_final: (episodes,) NEES after the last segment of each episode.
    """

    env_id: str
    episodes: int
    rmse: np.ndarray
    anees: np.ndarray
    anees_bounds: tuple[float, float]
    nees_final: np.ndarray

    @property
    def consistent(self) -> bool:
        """ANEES after the last segment inside its 95% bounds."""
        low, high = self.anees_bounds
        return bool(low <= self.anees[-1] <= high)

    @property
    def fraction_inside_95(self) -> float:
        """Share of episodes whose final estimate lies inside its 95% ellipse."""
        return float(np.mean(self.nees_final <= chi2.ppf(0.95, 3)))

    def summary(self) -> str:
        low, high = self.anees_bounds
        rel = self.rmse[-1]
        return (f"{self.env_id}: {self.episodes} episodes x {len(self.anees)} segments; "
                f"final RMSE r_L {rel[0]:.2e} m, r_R {rel[1]:.2e} m, b {rel[2]:.2e} m; "
                f"ANEES {self.anees[-1]:.2f} (95% bounds {low:.2f}-{high:.2f}, "
                f"{'consistent' if self.consistent else 'INCONSISTENT'}); "
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
    errors, nees = [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        truth = env.unwrapped.true_params.as_array()
        ep_err, ep_nees = [], []
        done = False
        while not done:
            action = env.action_space.sample() if policy is None else policy(obs)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
            est = env.unwrapped.estimator
            error = np.asarray(est.params.as_array()) - truth
            ep_err.append(error)
            ep_nees.append(float(error @ np.linalg.solve(est.covariance, error)))
        errors.append(ep_err)
        nees.append(ep_nees)
    length = min(len(e) for e in errors)
    err = np.array([e[:length] for e in errors])
    nees_arr = np.array([n[:length] for n in nees])
    bounds = (chi2.ppf(0.025, 3 * episodes) / episodes, chi2.ppf(0.975, 3 * episodes) / episodes)
    return EstimatorReport(
        env_id=env_id,
        episodes=episodes,
        rmse=np.sqrt(np.mean(err**2, axis=0)),
        anees=nees_arr.mean(axis=0),
        anees_bounds=(float(bounds[0]), float(bounds[1])),
        nees_final=nees_arr[:, -1],
    )


def assert_consistent(report: EstimatorReport) -> None:
    """pytest-friendly: raise AssertionError with the summary unless ANEES is in bounds."""
    if not report.consistent:
        raise AssertionError(report.summary())
