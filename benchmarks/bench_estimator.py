"""Estimator consistency on the ideal env (issue 3 acceptance 2): random actions, 150
segments, 100 seeds: share of batch estimates inside their 95% ellipse, and the harness's
ANEES of the default online estimator against its bounds; plus the slip env's ANEES."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import excite  # noqa: F401
from envs.estimator_check import check_estimator
from excite import calibrate
from excite.stats.chi2 import chi2_quantile
from excite.stats.consistency import nees as nees_of


def batch_nees(seeds: int = 100, segments: int = 150) -> np.ndarray:
    env = gym.make("excite/DiffDriveCalibIdeal-v0", budget=segments).unwrapped
    nees = []
    for seed in range(seeds):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        for _ in range(segments):
            env.step(env.action_space.sample())
        result = calibrate(env.segments, sigma=env.sigma)
        nees.append(nees_of(result.params.as_array() - env.true_params.as_array(),
                            result.covariance))
    return np.array(nees)


def main() -> dict:
    nees = batch_nees()
    inside = float(np.mean(nees <= chi2_quantile(0.95, 3)))
    print(f"ideal env, batch calibrate, 100 seeds x 150 random segments: {100 * inside:.0f}% "
          f"inside the 95% ellipse; mean NEES {nees.mean():.2f} (3 expected)")
    ideal = check_estimator("excite/DiffDriveCalibIdeal-v0", episodes=100, budget=150)
    print("harness, online estimator: " + ideal.summary())
    slip = check_estimator("excite/DiffDriveCalib-v0", episodes=100, budget=150)
    print("harness, online estimator: " + slip.summary())
    return {"batch_inside_95": inside, "batch_mean_nees": float(nees.mean()),
            "ideal_anees": float(ideal.anees[-1]), "ideal_bounds": ideal.anees_bounds,
            "slip_anees": float(slip.anees[-1])}


if __name__ == "__main__":
    main()
