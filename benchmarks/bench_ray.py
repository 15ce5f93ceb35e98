"""Ray backend of compare (issue 12), side by side in one run on this machine: the same
comparison (7 protocols x EPISODES episodes x 30 segments, slip env) on the local backend
(2 worker processes) and on a local Ray (2 CPUs), with Ray's tasks chunked to >= 1 s (the
default) and with one episode per task, then local again (the machine's drift), after an
untimed warm-up. Prints the wall times, the ratio to local, the chunk size chosen and
whether the result files are byte-identical."""

from __future__ import annotations

import argparse
import logging
import shutil
import tempfile
import time
from pathlib import Path

import ray

from agents import backends
from agents.compare import (
    CompareSettings,
    as_estimator_specs,
    as_specs,
    run_comparison,
    run_episodes,
)
from excite.estimators import DEFAULT_ESTIMATOR

PROTOCOLS = ["straight", "spin", "straight_spin", "umbmark", "random", "arcs", "greedy"]


def timed(out: Path, episodes: int, **backend) -> float:
    start = time.perf_counter()
    run_comparison(out, PROTOCOLS, episodes, CompareSettings(), progress=False, **backend)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=60)
    args = parser.parse_args(argv)
    tmp = Path(tempfile.mkdtemp())
    timed(tmp / "warm-up", 2, workers=2)  # first-use costs (imports, file cache) not timed
    walls = {"local (2 processes)": timed(tmp / "local", args.episodes, workers=2)}
    start = time.perf_counter()
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.ERROR)
    startup = time.perf_counter() - start
    walls["ray, tasks >= 1 s"] = timed(tmp / "ray", args.episodes, backend="ray")
    default = backends._RayExecutor.task_seconds
    backends._RayExecutor.task_seconds = 1e-9  # one episode per task, for comparison
    try:
        walls["ray, 1 episode per task"] = timed(tmp / "ray1", args.episodes, backend="ray")
    finally:
        backends._RayExecutor.task_seconds = default
    ray.shutdown()
    # Local again: the drift of this shared machine between the first and the last run.
    walls["local again"] = timed(tmp / "local2", args.episodes, workers=2)
    episode = CompareSettings()
    start = time.perf_counter()
    (estimator,) = as_estimator_specs([DEFAULT_ESTIMATOR])
    run_episodes(episode, [(0, [(protocol, estimator) for protocol in as_specs(PROTOCOLS)])])
    cost = time.perf_counter() - start
    first = (tmp / "local" / "segments.csv").read_bytes()
    same = all((tmp / name / "segments.csv").read_bytes() == first
               for name in ("ray", "ray1", "local2"))
    print(f"7 protocols x {args.episodes} episodes x 30 segments, slip env, 2 cores")
    print(f"one episode (7 protocols), timed again here: {cost:.2f} s -> Ray tasks of about "
          f"{backends.chunk_size(default, cost)} episodes (each run times its own first)")
    print(f"Ray start-up (ray.init, num_cpus=2): {startup:.1f} s (not in the times below)")
    for name, wall in walls.items():
        print(f"{name:<26} {wall:6.1f} s   {wall / walls['local (2 processes)']:.2f} x local")
    print(f"segments.csv of every run byte-identical to the first: {same}")
    shutil.rmtree(tmp)
    return walls


if __name__ == "__main__":
    main()
