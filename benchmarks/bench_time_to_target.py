"""Time to target (``excite compare --target``): how long each protocol drives until the
stopping rule says done, how often it stops while the truth is outside the target, and the
error at the stop, on the ideal and the slip env.

Each env runs ``excite compare --target T --protocols slip_aware,arcs,umbmark,spin`` on the
same evaluation episodes (budget 150 segments, the declared protocol settings); the table is
``agents.tables.format_table`` of the summary with ``slip_aware`` as the reference of the
paired ratio of time to target, and the wall time of the run.

    OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_time_to_target.py \
        [--episodes 40] [--target 0.005] [--workers 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from agents.compare import CompareSettings, columns_of, run_comparison
from agents.summary import summarize
from agents.tables import format_table
from agents.target_summary import add_target

ENVS = ("excite/DiffDriveCalibIdeal-v0", "excite/DiffDriveCalib-v0")
PROTOCOLS = ("slip_aware", "arcs", "umbmark", "spin")
REFERENCE = "slip_aware"
BUDGET = 150


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=40, help="episodes per env")
    parser.add_argument("--target", type=float, default=0.005, help="relative error")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    parser.add_argument("--out", default=None, help="results folder (default: a temporary one)")
    args = parser.parse_args()
    root = Path(args.out or tempfile.mkdtemp())
    for env in ENVS:
        settings = CompareSettings(env, BUDGET, 0, target=args.target)
        start = time.perf_counter()
        rows = run_comparison(root / env.split("/")[1], PROTOCOLS, args.episodes, settings,
                              args.workers, progress=False)
        wall = time.perf_counter() - start
        columns = columns_of(rows)
        summary = add_target(summarize(columns, reference=REFERENCE), columns, args.target,
                             settings.target_confidence, BUDGET)
        print(f"\n{env}: {len(PROTOCOLS)} protocols x {args.episodes} episodes, target "
              f"{args.target:g}, budget {BUDGET}: {wall:.0f} s ({args.workers} workers)\n")
        print(format_table(summary))


if __name__ == "__main__":
    main()
