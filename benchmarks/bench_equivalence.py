"""Equivalence of the native vector env and the single env (issue 12 acceptance 2).

For each id, 200 episodes of random actions (uniform in [-1, 1], the same sequence for robot
i of the vector env and the single env run i):

- paired: robot i of ``gymnasium.make_vec(id, num_envs=N)`` reset with seed s, and the single
  env reset with seed s + i: how many episodes have bit-identical segments (all rows of the
  calibration log), and the largest difference of the final max relative error and sigma_min;
- independent: the same vector episodes against single-env episodes of other seeds:
  two-sample Kolmogorov-Smirnov and Mann-Whitney tests on the final max relative error and the
  final sigma_min (p-values; equal distributions give p uniform on [0, 1]).

Usage: python benchmarks/bench_equivalence.py [--episodes 200] [--num-envs 50] [--seed 0]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
from scipy import stats
from tqdm import tqdm

import excite  # noqa: F401
from excite.registration import ENV_IDS


def vector_episodes(env_id: str, episodes: int, num_envs: int, seed: int,
                    actions: np.ndarray) -> dict:
    """Final errors, sigma_min and segment logs of ``episodes`` vector-env episodes (robot i
    of batch b has seed seed + b * num_envs + i and actions[b * num_envs + i])."""
    venv = gym.make_vec(env_id, num_envs=num_envs).unwrapped
    errors, sigmas, logs = [], [], []
    for start in tqdm(range(0, episodes, num_envs), desc=f"{env_id} vector", leave=False):
        venv.reset(seed=seed + start)
        batch = actions[start:start + num_envs]
        for k in range(batch.shape[1]):
            *_, truncated, info = venv.step(batch[:, k])
        assert truncated.all()
        errors += venv.max_relative_errors.tolist()
        sigmas += info["sigma_min"].tolist()
        logs += venv.segments_logged
    return {"error": np.array(errors), "sigma_min": np.array(sigmas), "logs": logs}


def single_episodes(env_id: str, episodes: int, seed: int, actions: np.ndarray,
                    desc: str) -> dict:
    env = gym.make(env_id).unwrapped
    errors, sigmas, logs = [], [], []
    for e in tqdm(range(episodes), desc=f"{env_id} {desc}", leave=False):
        env.reset(seed=seed + e)
        for a in actions[e]:
            *_, info = env.step(a)
        errors.append(env.max_relative_error)
        sigmas.append(info["sigma_min"])
        logs.append(env.segments.as_array())
    return {"error": np.array(errors), "sigma_min": np.array(sigmas), "logs": logs}


def compare(env_id: str, episodes: int = 200, num_envs: int = 50, seed: int = 0) -> dict:
    budget = gym.make(env_id).unwrapped.budget
    actions = np.random.default_rng(seed).uniform(-1, 1, (episodes, budget, 2))
    vector = vector_episodes(env_id, episodes, num_envs, seed, actions)
    paired = single_episodes(env_id, episodes, seed, actions, "single (paired seeds)")
    other = single_episodes(env_id, episodes, seed + 1_000_000, actions,
                            "single (other seeds)")
    identical = sum(np.array_equal(a, b) for a, b in zip(vector["logs"], paired["logs"],
                                                         strict=True))
    out = {"id": env_id, "episodes": episodes, "identical_episodes": identical}
    for key in ("error", "sigma_min"):
        out[f"paired_max_diff_{key}"] = float(np.max(np.abs(vector[key] - paired[key])))
        out[f"ks_p_{key}"] = float(stats.ks_2samp(vector[key], other[key]).pvalue)
        out[f"mannwhitney_p_{key}"] = float(
            stats.mannwhitneyu(vector[key], other[key]).pvalue)
        out[f"median_{key}"] = (float(np.median(vector[key])), float(np.median(other[key])))
    return out


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--num-envs", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    results = []
    for env_id in ENV_IDS:
        r = compare(env_id, args.episodes, args.num_envs, args.seed)
        print(f"{env_id}: {r['identical_episodes']}/{r['episodes']} episodes with bit-identical "
              f"segments (paired seeds); paired max |diff| final error "
              f"{r['paired_max_diff_error']:.2e}, sigma_min {r['paired_max_diff_sigma_min']:.2e}"
              f"; vs other seeds: final error KS p={r['ks_p_error']:.3f}, Mann-Whitney "
              f"p={r['mannwhitney_p_error']:.3f} (medians {r['median_error'][0]:.4f} vs "
              f"{r['median_error'][1]:.4f}); sigma_min KS p={r['ks_p_sigma_min']:.3f}, "
              f"Mann-Whitney p={r['mannwhitney_p_sigma_min']:.3f} (medians "
              f"{r['median_sigma_min'][0]:.1f} vs {r['median_sigma_min'][1]:.1f})", flush=True)
        results.append(r)
    return results


if __name__ == "__main__":
    main()
