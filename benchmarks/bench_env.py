"""Environment benchmarks (issue 3 acceptance 4).

- throughput of one env on one core (1-s segments, random actions): segments per second
  (= simulated seconds per wall-clock second);
- the env's overhead over its own bare physics loop (Simulation.run_segment with the same
  commands): (t_env - t_sim) / t_sim;
- memory over 100k steps (tracemalloc current size at intervals: flat means no leak).
"""

from __future__ import annotations

import time
import tracemalloc

import gymnasium as gym
import numpy as np

import excite  # noqa: F401

ENV_ID = "excite/DiffDriveCalib-v0"


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.6, 0.6, size=(n, 2))


def throughput(n: int = 6000) -> dict:
    env = gym.make(ENV_ID).unwrapped
    actions = _actions(n)
    env.reset(seed=0)
    start = time.perf_counter()
    for k, a in enumerate(actions):
        *_, terminated, truncated, _ = env.step(a)
        if (k + 1) % env.budget == 0:
            env.reset()
    t_env = time.perf_counter() - start

    sim = env.sim
    env.reset(seed=0)
    start = time.perf_counter()
    for k, a in enumerate(actions):
        sim.run_segment(a[0] * env.max_wheel_speed, a[1] * env.max_wheel_speed, 1.0)
        if (k + 1) % env.budget == 0:
            env.reset()
    t_sim = time.perf_counter() - start
    return {"segments_per_s": n / t_env, "bare_physics_segments_per_s": n / t_sim,
            "overhead": (t_env - t_sim) / t_sim}


def memory(steps: int = 100_000, checkpoints: int = 5) -> list[float]:
    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=1)
    actions = _actions(steps, 1)
    tracemalloc.start()
    sizes = []
    for k, a in enumerate(actions):
        env.step(a)
        if (k + 1) % env.budget == 0:
            env.reset()
        if (k + 1) % (steps // checkpoints) == 0:
            sizes.append(tracemalloc.get_traced_memory()[0] / 2**20)
    tracemalloc.stop()
    return sizes


def main() -> dict:
    tp = throughput()
    print(f"env: {tp['segments_per_s']:.0f} segments/s (1-s segments = simulated s per wall s); "
          f"bare physics {tp['bare_physics_segments_per_s']:.0f}/s; env overhead "
          f"{100 * tp['overhead']:.1f}%")
    mem = memory()
    print("traced memory over 100k steps (MiB at each 20k): "
          + ", ".join(f"{m:.2f}" for m in mem))
    return {**tp, "memory_mib": mem}


if __name__ == "__main__":
    main()
