"""Simulation layer benchmarks.

1. Throughput: simulated seconds per wall-clock second on one core, for the pymunk (slip)
   variant and the ideal variant, running 1-s segments with random wheel commands in the
   default 4 m arena (walls included), a fresh random robot every 50 segments.
2. Memory: tracemalloc peak per window and traced memory after each window over 20k
   physics segments (0.2 s each, so the traced run stays under a minute), with the
   process's peak resident set size, to show they stay flat.

Usage: python benchmarks/bench_simulation.py [--segments 6000] [--memory-segments 20000]
"""

from __future__ import annotations

import argparse
import gc
import resource
import time
import tracemalloc

import numpy as np

from envs.robot import RobotDistribution
from envs.simulation import Simulation, SimulationConfig

EPISODE = 50  # segments per robot
SEGMENT = 1.0  # s, timing runs
MEMORY_SEGMENT = 0.2  # s, memory runs (tracemalloc slows every allocation down)


def _drive(sim: Simulation, n_segments: int, seed: int, duration: float = SEGMENT) -> None:
    """Run `n_segments` random segments, resetting to a new robot every EPISODE."""
    dist = RobotDistribution()
    rng = np.random.default_rng(seed)
    limit = dist.max_wheel_speed
    for start in range(0, n_segments, EPISODE):
        sim.reset(dist.sample(rng), rng)
        commands = rng.uniform(-limit, limit, (min(EPISODE, n_segments - start), 2))
        for cmd_L, cmd_R in commands.tolist():
            sim.run_segment(cmd_L, cmd_R, duration)


def throughput(ideal: bool, n_segments: int, seed: int = 0) -> float:
    """Simulated seconds per wall-clock second (best of three runs)."""
    sim = Simulation(SimulationConfig(ideal=ideal))
    _drive(sim, min(n_segments, 200), seed)  # warm-up
    best = np.inf
    for repeat in range(3):
        start = time.perf_counter()
        _drive(sim, n_segments, seed + 1 + repeat)
        best = min(best, time.perf_counter() - start)
    return n_segments * SEGMENT / best


def peak_rss_mib() -> float:
    """Peak resident set size of this process (MiB, Linux ru_maxrss is in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def memory(n_segments: int, windows: int = 5, seed: int = 0) -> list[dict]:
    """tracemalloc peak / current (KiB) and peak RSS after each of `windows` equal windows."""
    sim = Simulation(SimulationConfig(ideal=False))
    per_window = n_segments // windows
    rows = []
    tracemalloc.start()
    try:
        for w in range(windows):
            tracemalloc.reset_peak()
            _drive(sim, per_window, seed + w, MEMORY_SEGMENT)
            gc.collect()
            current, peak = tracemalloc.get_traced_memory()
            rows.append(
                {
                    "segments": (w + 1) * per_window,
                    "traced_kib": current / 1024,
                    "peak_kib": peak / 1024,
                    "rss_mib": peak_rss_mib(),
                }
            )
    finally:
        tracemalloc.stop()
    return rows


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmarks, print a table and return the numbers."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, default=6000, help="segments per timing run")
    parser.add_argument("--memory-segments", type=int, default=20000)
    args = parser.parse_args(argv)

    physics = throughput(ideal=False, n_segments=args.segments)
    ideal = throughput(ideal=True, n_segments=args.segments)
    hz = SimulationConfig().physics_hz
    print(f"\nThroughput, 1-s segments, random commands, {hz:g} Hz physics (best of 3)")
    print(f"{'variant':<10}{'sim s / wall s':>16}{'physics ticks / s':>20}")
    print(f"{'physics':<10}{physics:>16.0f}{physics * hz:>20.0f}")
    print(f"{'ideal':<10}{ideal:>16.0f}{ideal * hz:>20.0f}")
    print(f"target: physics >= 1500 sim s / wall s -> {'met' if physics >= 1500 else 'NOT met'}")

    rows = memory(args.memory_segments)
    print(f"\nMemory over {args.memory_segments} physics segments of {MEMORY_SEGMENT} s")
    print(f"{'segments':>10}{'traced KiB':>14}{'window peak KiB':>18}{'peak RSS MiB':>15}")
    for row in rows:
        print(
            f"{row['segments']:>10}{row['traced_kib']:>14.1f}"
            f"{row['peak_kib']:>18.1f}{row['rss_mib']:>15.1f}"
        )
    growth = rows[-1]["traced_kib"] - rows[0]["traced_kib"]
    print(f"traced growth from first to last window: {growth:+.1f} KiB")
    return {
        "physics_sim_s_per_wall_s": physics,
        "ideal_sim_s_per_wall_s": ideal,
        "physics_hz": hz,
        "memory": rows,
        "memory_traced_growth_kib": growth,
    }


if __name__ == "__main__":
    main()
