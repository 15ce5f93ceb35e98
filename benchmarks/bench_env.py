"""Environment benchmarks (issue 3 acceptance 4, issue 12 acceptance 1).

- throughput of the single env (1-s segments, random actions within 60% of the motor limit):
  segments per second (= simulated seconds per second), per wall-clock second and per second
  of the process's CPU time (the ratios below use both; CPU time is far less disturbed by
  other processes on a shared machine), and its overhead over its own bare physics loop
  (Simulation.run_segment with the same commands and resets): (t_env - t_sim) / t_sim;
- the native vector env (``gymnasium.make_vec(id, num_envs=N)``) at N = 1, 8, 64 beside the
  single env, in alternating blocks of one run (a shared 2-core VM moves single timings by
  +-10% or more): median segments/s over the blocks and the ratio to the single env's median;
- with ``--reference DIR`` (another checkout, e.g. main's code extracted with git archive):
  that tree's single env and this one's, each block in a fresh subprocess, alternating;
- memory over ``--memory-steps`` (100k) steps of the single env: Python heap traced by
  tracemalloc at checkpoints, as found (including reference cycles awaiting the garbage
  collector: every pymunk Space is one) and after gc.collect() (live memory: flat means no
  leak), and the process's peak resident set size; over ``--vector-memory-segments`` (1M)
  segments of the vector env at N = 64: the resident set size and the objects tracked by the
  garbage collector at checkpoints (flat means no leak).

Usage: python benchmarks/bench_env.py [--env ID] [--blocks 7] [--reference DIR]
       [--memory-steps 100000] [--vector-memory-segments 1000000] [--skip-memory]
"""

from __future__ import annotations

import argparse
import gc
import os
import statistics
import subprocess
import sys
import time
import tracemalloc

import gymnasium as gym
import numpy as np
from bench_simulation import peak_rss_mib
from tqdm import tqdm

import excite  # noqa: F401
from excite.registration import DEFAULT_ENV_ID

ENV_ID = DEFAULT_ENV_ID
VECTOR_SIZES = (1, 8, 64)


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.6, 0.6, size=(n, 2))


def _clocks() -> tuple[float, float]:
    """(wall-clock, this process's CPU) seconds."""
    return time.perf_counter(), time.process_time()


def _since(start: tuple[float, float]) -> tuple[float, float]:
    wall, cpu = _clocks()
    return wall - start[0], cpu - start[1]


def _time_env(env, actions: np.ndarray) -> tuple[float, float]:
    env.reset(seed=0)
    start = _clocks()
    for k, a in enumerate(actions):
        env.step(a)
        if (k + 1) % env.budget == 0:
            env.reset()
    return _since(start)


def _time_bare_physics(env, actions: np.ndarray) -> tuple[float, float]:
    env.reset(seed=0)
    sim, speed = env.sim, env.max_wheel_speed
    start = _clocks()
    for k, a in enumerate(actions):
        sim.run_segment(a[0] * speed, a[1] * speed, 1.0)
        if (k + 1) % env.budget == 0:
            env.reset()
    return _since(start)


def _time_vector(venv, steps: int, seed: int = 0) -> tuple[float, float]:
    """(wall, CPU) seconds for ``steps`` steps of all robots (autoreset at the budget)."""
    actions = np.random.default_rng(seed).uniform(-0.6, 0.6, (steps, venv.num_envs, 2))
    venv.reset(seed=seed)
    start = _clocks()
    for a in actions:
        venv.step(a)
    return _since(start)


def throughput(env_id: str = ENV_ID, blocks: int = 7, segments_per_block: int = 1500,
               sizes: tuple[int, ...] = VECTOR_SIZES) -> dict:
    """Single env, its bare physics and the vector env at each size, in alternating blocks
    of about ``segments_per_block`` segments each: segments per wall-clock second and per
    second of this process's CPU time (which a loaded shared machine disturbs far less), the
    medians over the blocks, and the vector env's ratios to the single env."""
    env = gym.make(env_id).unwrapped
    vectors = {n: gym.make_vec(env_id, num_envs=n) for n in sizes}
    actions = _actions(segments_per_block)
    _time_env(env, actions[:300])  # warm up
    for n, venv in vectors.items():
        _time_vector(venv, max(300 // n, 3))
    t_env, t_sim = [], []
    rates: dict[int, list[tuple[float, float]]] = {n: [] for n in sizes}
    for _ in tqdm(range(blocks), desc="throughput blocks", leave=False):
        t_env.append(_time_env(env, actions))
        t_sim.append(_time_bare_physics(env, actions))
        for n, venv in vectors.items():
            steps = max(segments_per_block // n, 10)
            wall, cpu = _time_vector(venv, steps)
            rates[n].append((steps * n / wall, steps * n / cpu))
    overheads = [(e[1] - s[1]) / s[1] for e, s in zip(t_env, t_sim, strict=True)]
    single = [segments_per_block / statistics.median(t[c] for t in t_env) for c in (0, 1)]
    out = {"segments_per_s": single[0], "cpu_segments_per_s": single[1],
           "bare_physics_segments_per_s": segments_per_block / statistics.median(
               t[1] for t in t_sim),
           "overhead": statistics.median(overheads),
           "overhead_range": (min(overheads), max(overheads))}
    for c, clock in enumerate(("wall", "cpu")):
        medians = {n: statistics.median(r[c] for r in rs) for n, rs in rates.items()}
        out[f"vector_{clock}_segments_per_s"] = medians
        out[f"vector_{clock}_range"] = {n: (min(r[c] for r in rs), max(r[c] for r in rs))
                                        for n, rs in rates.items()}
        out[f"vector_{clock}_ratio"] = {n: m / single[c] for n, m in medians.items()}
    return out


_SINGLE_BLOCK = """
import time, numpy as np, gymnasium as gym, excite
env = gym.make({env_id!r}).unwrapped
actions = np.random.default_rng(0).uniform(-0.6, 0.6, ({segments}, 2))
def run(acts):
    env.reset(seed=0)
    start = time.perf_counter(), time.process_time()
    for k, a in enumerate(acts):
        env.step(a)
        if (k + 1) % env.budget == 0:
            env.reset()
    return time.perf_counter() - start[0], time.process_time() - start[1]
run(actions[:300])
wall, cpu = run(actions)
print({segments} / wall, {segments} / cpu)
"""


def reference_comparison(reference: str, env_id: str = ENV_ID, blocks: int = 7,
                         segments: int = 1500) -> dict:
    """The single env of ``reference`` (a source tree) and of this tree, each block in a fresh
    subprocess (PYTHONPATH set to the tree), alternating; medians (segments per wall-clock
    second and per CPU second) and the ratios."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    code = _SINGLE_BLOCK.format(env_id=env_id, segments=segments)
    rates: dict[str, list[list[float]]] = {"reference": [], "this": []}
    for _ in tqdm(range(blocks), desc="reference blocks", leave=False):
        for name, tree in (("reference", reference), ("this", here)):
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 env={**os.environ, "PYTHONPATH": tree}, check=True,
                                 cwd="/")
            rates[name].append([float(v) for v in out.stdout.split()[-2:]])
    result = {}
    for c, clock in enumerate(("wall", "cpu")):
        ref = [r[c] for r in rates["reference"]]
        this = [r[c] for r in rates["this"]]
        result[clock] = {"reference": statistics.median(ref), "this": statistics.median(this),
                         "ratio": statistics.median(this) / statistics.median(ref),
                         "reference_range": (min(ref), max(ref)),
                         "this_range": (min(this), max(this))}
    return result


def memory(steps: int = 100_000, checkpoints: int = 5, env_id: str = ENV_ID) -> dict:
    env = gym.make(env_id).unwrapped
    env.reset(seed=1)
    actions = _actions(steps, 1)
    tracemalloc.start()
    found, live = [], []
    for k, a in enumerate(tqdm(actions, desc="single env memory", leave=False)):
        env.step(a)
        if (k + 1) % env.budget == 0:
            env.reset()
        if (k + 1) % (steps // checkpoints) == 0:
            found.append(tracemalloc.get_traced_memory()[0] / 2**20)
            gc.collect()
            live.append(tracemalloc.get_traced_memory()[0] / 2**20)
    tracemalloc.stop()
    return {"found_mib": found, "live_mib": live, "peak_rss_mib": peak_rss_mib()}


def _rss_mib() -> float:
    """The process's current resident set size (MiB), from /proc (Linux)."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def vector_memory(segments: int = 1_000_000, n: int = 64, checkpoints: int = 5,
                  env_id: str = ENV_ID) -> dict:
    """Resident set size (after gc.collect) of the vector env at ``checkpoints`` points over
    ``segments`` segments (segments / n steps; tracemalloc would slow this run several fold),
    with the number of objects the garbage collector tracks."""
    venv = gym.make_vec(env_id, num_envs=n)
    venv.reset(seed=2)
    steps = segments // n
    rng = np.random.default_rng(2)
    rss, objects = [], []
    for k in tqdm(range(steps), desc=f"vector env memory (N={n})", leave=False):
        venv.step(rng.uniform(-0.6, 0.6, (n, 2)))
        if (k + 1) % (steps // checkpoints) == 0:
            gc.collect()
            rss.append(_rss_mib())
            objects.append(len(gc.get_objects()))
    return {"vector_rss_mib": rss, "vector_gc_objects": objects, "vector_segments": steps * n}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default=ENV_ID)
    parser.add_argument("--blocks", type=int, default=7)
    parser.add_argument("--reference", help="another source tree to time the single env of")
    parser.add_argument("--memory-steps", type=int, default=100_000,
                        help="single env steps traced by tracemalloc")
    parser.add_argument("--vector-memory-segments", type=int, default=1_000_000)
    parser.add_argument("--skip-memory", action="store_true")
    args = parser.parse_args(argv)
    results: dict = {}
    if args.reference:
        ref = reference_comparison(args.reference, args.env, args.blocks)
        for clock, r in ref.items():
            print(f"single env, {args.blocks} alternating subprocess blocks of 1500 segments, "
                  f"segments per {clock} second: reference {r['reference']:.0f} (range "
                  f"{r['reference_range'][0]:.0f}-{r['reference_range'][1]:.0f}), this tree "
                  f"{r['this']:.0f} (range {r['this_range'][0]:.0f}-{r['this_range'][1]:.0f}):"
                  f" ratio {r['ratio']:.3f}", flush=True)
        results["reference"] = ref
    tp = throughput(args.env, args.blocks)
    low, high = tp["overhead_range"]
    print(f"{args.env}: single env {tp['segments_per_s']:.0f} segments/s wall clock, "
          f"{tp['cpu_segments_per_s']:.0f} per CPU second (1-s segments = simulated s per s); "
          f"bare physics {tp['bare_physics_segments_per_s']:.0f} per CPU s; env overhead "
          f"{100 * tp['overhead']:.1f}% (CPU; median of {args.blocks} alternating blocks; "
          f"range {100 * low:.1f}-{100 * high:.1f}%)")
    for n in tp["vector_cpu_segments_per_s"]:
        parts = []
        for clock in ("cpu", "wall"):
            lo, hi = tp[f"vector_{clock}_range"][n]
            parts.append(f"{tp[f'vector_{clock}_segments_per_s'][n]:.0f} per {clock} s "
                         f"(range {lo:.0f}-{hi:.0f}), {tp[f'vector_{clock}_ratio'][n]:.2f}x")
        print(f"  vector env N={n}: " + "; ".join(parts) + " the single env", flush=True)
    results.update(tp)
    if args.skip_memory:
        return results
    mem = memory(args.memory_steps, env_id=args.env)
    print(f"single env, traced Python heap over {args.memory_steps:,} steps (MiB at each "
          "fifth): as found "
          + ", ".join(f"{m:.2f}" for m in mem["found_mib"]) + "; live (after gc.collect) "
          + ", ".join(f"{m:.3f}" for m in mem["live_mib"])
          + f"; peak RSS {mem['peak_rss_mib']:.0f} MiB", flush=True)
    results.update(mem)
    if args.vector_memory_segments:
        vm = vector_memory(args.vector_memory_segments, env_id=args.env)
        print(f"vector env N=64 over {vm['vector_segments']:,} segments, at each fifth: RSS "
              "(MiB, after gc.collect) " + ", ".join(f"{m:.1f}" for m in vm["vector_rss_mib"])
              + "; objects tracked by gc "
              + ", ".join(str(k) for k in vm["vector_gc_objects"]))
        results.update(vm)
    return results


if __name__ == "__main__":
    main()
