"""slip_aware's ``lookahead`` (segments over which a maneuver is valued), chosen on the tuning
stream: time to target of each value on the sensor env and the slip env.

Each cell is ``agents.compare.run_comparison`` in target mode on tuning robots (the stream
``excite tune`` uses, never compare's evaluation robots), budget 150 segments; printed: the
robots done within the budget and the median segments to the stopping rule's *done* (robots
not done count as beyond the budget), with its bootstrap 95% interval. Last, the planning time
per action of each lookahead, side by side on one slip-env episode of 60 segments.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_lookahead.py [--episodes 20] [--workers 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from agents.compare import TUNING_STREAM, CompareSettings, columns_of, make_env, run_comparison
from agents.slip_aware import SlipAwarePlanner
from agents.summary import summarize
from agents.target_summary import add_target

#: (env, target): the sensor env at 0.5% (where lookahead 1 held a spin), the slip env at 0.2%.
CELLS = (("excite/DiffDriveCalibSensor-v0", 0.005), ("excite/DiffDriveCalib-v0", 0.002))
LOOKAHEADS = (1, 3, 6, 10)
BUDGET = 150


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=20, help="tuning robots per cell")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    parser.add_argument("--out", default=None, help="results folder (default: a temporary one)")
    args = parser.parse_args()
    root = Path(args.out or tempfile.mkdtemp())
    protocols = [f"slip_aware:lookahead={k}" for k in LOOKAHEADS]
    for env, target in CELLS:
        settings = CompareSettings(env, BUDGET, 0, stream=TUNING_STREAM, target=target)
        start = time.perf_counter()
        rows = run_comparison(root / f"{env.split('/')[1]}_{target:g}", protocols,
                              args.episodes, settings, args.workers, progress=False)
        columns = columns_of(rows)
        summary = add_target(summarize(columns), columns, target, settings.target_confidence,
                             BUDGET)
        print(f"\n{env}, target {target:g}, {args.episodes} tuning robots, budget {BUDGET}: "
              f"{time.perf_counter() - start:.0f} s")
        for label in protocols:
            entry = next(iter(summary["protocols"][label].values()))["target"]
            segments = entry["time_to_target"]["segments"]
            done = entry["false_stop_rate"]["stops"]
            print(f"  {label:26s} done {done}/{args.episodes}, median segments "
                  f"{_text(segments['median'])} [{', '.join(map(_text, segments['ci95']))}]")
    print("\nplanning time per action, slip env, 60 segments:")
    for lookahead in LOOKAHEADS:
        print(f"  lookahead {lookahead:2d}: {1e3 * _planning_seconds(lookahead):.1f} ms")


def _planning_seconds(lookahead: int, segments: int = 60) -> float:
    """Mean seconds per action of slip_aware on one slip-env episode (tuning seed 3)."""
    env = make_env("excite/DiffDriveCalib-v0", segments)
    env.reset(seed=3)
    planner = SlipAwarePlanner(lookahead=lookahead)
    planner.reset(np.random.default_rng(3))
    spent = 0.0
    for _ in range(segments):
        knowledge = env.unwrapped.knowledge()
        start = time.perf_counter()
        action = planner.act(knowledge)
        spent += time.perf_counter() - start
        env.step(action)
    return spent / segments


def _text(value: float | None) -> str:
    """A number of segments, or beyond the budget (None)."""
    return f">{BUDGET}" if value is None else f"{value:g}"


if __name__ == "__main__":
    main()
