"""Environment benchmarks (issue 3 acceptance 4).

- throughput of one env on one core (1-s segments, random actions): segments per second
  (= simulated seconds per wall-clock second);
- the env's overhead over its own bare physics loop (Simulation.run_segment with the same
  commands and the same resets): (t_env - t_sim) / t_sim. Env and bare loop run in alternating
  blocks, and the median over the blocks is reported with its range: a shared 2-core VM moves
  single timings by +-10%;
- memory over 100k steps: Python heap traced by tracemalloc at every 20k steps, as found
  (it includes reference cycles awaiting the garbage collector: every pymunk Space is one, and
  the simulation builds a fresh space per episode) and after gc.collect() (live memory: flat
  means no leak); and the process's peak resident set size.
"""

from __future__ import annotations

import gc
import statistics
import time
import tracemalloc

import gymnasium as gym
import numpy as np
from bench_simulation import peak_rss_mib

import excite  # noqa: F401
from excite.registration import DEFAULT_ENV_ID

ENV_ID = DEFAULT_ENV_ID


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.6, 0.6, size=(n, 2))


def _time_env(env, actions: np.ndarray) -> float:
    env.reset(seed=0)
    start = time.perf_counter()
    for k, a in enumerate(actions):
        env.step(a)
        if (k + 1) % env.budget == 0:
            env.reset()
    return time.perf_counter() - start


def _time_bare_physics(env, actions: np.ndarray) -> float:
    env.reset(seed=0)
    sim, speed = env.sim, env.max_wheel_speed
    start = time.perf_counter()
    for k, a in enumerate(actions):
        sim.run_segment(a[0] * speed, a[1] * speed, 1.0)
        if (k + 1) % env.budget == 0:
            env.reset()
    return time.perf_counter() - start


def throughput(blocks: int = 9, segments_per_block: int = 1500) -> dict:
    env = gym.make(ENV_ID).unwrapped
    actions = _actions(segments_per_block)
    _time_env(env, actions[:300])  # warm up
    t_env, t_sim = [], []
    for _ in range(blocks):
        t_env.append(_time_env(env, actions))
        t_sim.append(_time_bare_physics(env, actions))
    overheads = [(e - s) / s for e, s in zip(t_env, t_sim, strict=True)]
    return {"segments_per_s": segments_per_block / statistics.median(t_env),
            "bare_physics_segments_per_s": segments_per_block / statistics.median(t_sim),
            "overhead": statistics.median(overheads),
            "overhead_range": (min(overheads), max(overheads))}


def memory(steps: int = 100_000, checkpoints: int = 5) -> dict:
    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=1)
    actions = _actions(steps, 1)
    tracemalloc.start()
    found, live = [], []
    for k, a in enumerate(actions):
        env.step(a)
        if (k + 1) % env.budget == 0:
            env.reset()
        if (k + 1) % (steps // checkpoints) == 0:
            found.append(tracemalloc.get_traced_memory()[0] / 2**20)
            gc.collect()
            live.append(tracemalloc.get_traced_memory()[0] / 2**20)
    tracemalloc.stop()
    return {"found_mib": found, "live_mib": live, "peak_rss_mib": peak_rss_mib()}


def main() -> dict:
    tp = throughput()
    low, high = tp["overhead_range"]
    print(f"env: {tp['segments_per_s']:.0f} segments/s (1-s segments = simulated s per wall s); "
          f"bare physics {tp['bare_physics_segments_per_s']:.0f}/s; env overhead "
          f"{100 * tp['overhead']:.1f}% (median of 9 alternating blocks; range "
          f"{100 * low:.1f}-{100 * high:.1f}%)")
    mem = memory()
    print("traced Python heap over 100k steps (MiB at each 20k): as found "
          + ", ".join(f"{m:.2f}" for m in mem["found_mib"]) + "; live (after gc.collect) "
          + ", ".join(f"{m:.3f}" for m in mem["live_mib"])
          + f"; peak RSS {mem['peak_rss_mib']:.0f} MiB")
    return {**tp, **mem}


if __name__ == "__main__":
    main()
