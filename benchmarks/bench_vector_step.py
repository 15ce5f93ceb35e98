"""Where the vector env's step spends its time (issue 12 acceptance 1): per robot-step, the
physics (``BatchSimulation.run_segment``: motors, traction, pymunk, encoders and the rows'
noise) and everything after it (sensor rows, estimator updates, information matrices and
their eigenvalues, rewards, observations, autoresets).

CPU seconds of this process (a shared machine disturbs them far less than wall-clock time),
the median over alternating rounds of ``--steps`` steps each; with ``--reference DIR`` the
same measurement of another source tree (e.g. main's code extracted with git archive) runs
in a fresh subprocess beside this tree's, alternating.

Usage: python benchmarks/bench_vector_step.py [--env ID ...] [--num-envs 64] [--steps 120]
       [--rounds 5] [--reference DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

from tqdm import tqdm

_ROUND = """
import json, sys, time
import gymnasium as gym
import numpy as np
import excite  # noqa: F401

env_id, n, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
venv = gym.make_vec(env_id, num_envs=n).unwrapped
physics = [0.0]
run_segment = venv.sim.run_segment

def timed(*args, **kwargs):
    start = time.process_time()
    out = run_segment(*args, **kwargs)
    physics[0] += time.process_time() - start
    return out

venv.sim.run_segment = timed
actions = np.random.default_rng(0).uniform(-0.6, 0.6, (steps, n, 2))
venv.reset(seed=0)
for a in actions[:30]:  # warm up (caches, lazily compiled kernels)
    venv.step(a)
venv.reset(seed=1)
physics[0] = 0.0
start = time.process_time()
for a in actions:
    venv.step(a)
total = time.process_time() - start
print(json.dumps({"total": total, "physics": physics[0]}))
"""


def one_round(tree: str, env_id: str, n: int, steps: int) -> tuple[float, float]:
    """(total, physics) CPU microseconds per robot-step of ``steps`` steps of the vector env
    of the source tree ``tree``, in a fresh process."""
    out = subprocess.run([sys.executable, "-c", _ROUND, env_id, str(n), str(steps)],
                         capture_output=True, text=True, check=True, cwd="/",
                         env={**os.environ, "PYTHONPATH": tree})
    result = json.loads(out.stdout.splitlines()[-1])
    scale = 1e6 / (steps * n)
    return result["total"] * scale, result["physics"] * scale


def measure(trees: dict[str, str], env_id: str, n: int, steps: int, rounds: int) -> dict:
    """Median (total, physics, rest) us per robot-step of each tree, rounds alternating."""
    samples: dict[str, list[tuple[float, float]]] = {name: [] for name in trees}
    for _ in tqdm(range(rounds), desc=f"{env_id} N={n}", leave=False):
        for name, tree in trees.items():
            samples[name].append(one_round(tree, env_id, n, steps))
    out = {}
    for name, values in samples.items():
        total = statistics.median(v[0] for v in values)
        physics = statistics.median(v[1] for v in values)
        rest = statistics.median(v[0] - v[1] for v in values)
        out[name] = {"total": total, "physics": physics, "rest": rest,
                     "rest_range": (min(v[0] - v[1] for v in values),
                                    max(v[0] - v[1] for v in values))}
    return out


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", nargs="+", default=["excite/DiffDriveCalibIdeal-v0",
                                                     "excite/DiffDriveCalib-v0"])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[64])
    parser.add_argument("--steps", type=int, default=120)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--reference", help="another source tree to measure beside this one")
    args = parser.parse_args(argv)
    trees = {"this": os.path.dirname(os.path.dirname(os.path.abspath(__file__)))}
    if args.reference:
        trees = {"reference": os.path.abspath(args.reference), **trees}
    results = []
    for env_id in args.env:
        for n in args.num_envs:
            r = measure(trees, env_id, n, args.steps, args.rounds)
            for name, m in r.items():
                low, high = m["rest_range"]
                print(f"{env_id} N={n} {name}: {m['total']:.1f} CPU us per robot-step: physics "
                      f"{m['physics']:.1f}, the rest {m['rest']:.1f} (range {low:.1f}-"
                      f"{high:.1f}; median of {args.rounds} alternating rounds of "
                      f"{args.steps} steps)", flush=True)
            results.append({"env": env_id, "num_envs": n, **r})
    return results


if __name__ == "__main__":
    main()
