"""The stopping rule's cost and false-stop rate.

Cost: one decision (excite.stopping.StoppingRule.decide) on a 60-segment session, as segments
of the lesson's kind (independent noise) and as segments cut from a time-series log (shared
pose samples, the GLS with estimated noise levels), median of repeated calls.

False stops: sequences of segments of the lesson's kind, the rule asked after every segment
from the 6th; the share of sequences where it stopped while the truth was outside the target,
with its Wilson 95% interval, and the median segments to the stop.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_stopping.py [--runs N]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from excite.logs.segmentation import segment_timeseries
from excite.logs.synthetic import LESSON_TRUTH, lesson_dataset, synthetic_log
from excite.stopping import StoppingRule


def _median_ms(rule: StoppingRule, segments, repeats: int = 15) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        rule.decide(segments)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def _wilson(k: int, n: int) -> tuple[float, float]:
    if n == 0:
        return (0.0, 1.0)
    z, p = 1.959964, k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=200, help="sequences for the false stops")
    parser.add_argument("--target", type=float, default=0.01)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    lesson = lesson_dataset(rng, 60, dphi_std=2.0)
    log = synthetic_log(np.random.default_rng(1), 70, LESSON_TRUTH)
    cut = segment_timeseries(log.series).segments[:60]
    for name, segments, pose in (("lesson segments, axle", lesson, "axle"),
                                 ("lesson segments, auto", lesson, "auto"),
                                 ("time-series segments, auto", cut, "auto")):
        ms = _median_ms(StoppingRule(target=args.target, sensor_pose=pose), segments)
        print(f"one decision, {len(segments)} {name}: {ms:.1f} ms")
    rule = StoppingRule(target=args.target, sensor_pose="axle")
    truth = LESSON_TRUTH.as_array()
    false = stops = 0
    when = []
    for run in range(args.runs):
        seg = lesson_dataset(np.random.default_rng(10_000 + run), 300, dphi_std=2.0)
        for n in range(6, 301):
            decision = rule.decide(seg[:n])
            if decision.done:
                stops += 1
                when.append(n)
                error = np.abs(decision.result.params.as_array() - truth) / truth
                false += bool(np.max(error) > args.target)
                break
    low, high = _wilson(false, stops)
    print(f"false stops at target {args.target:g}, asked after every segment: {false}/{stops} "
          f"= {false / max(stops, 1):.3f} [{low:.3f}, {high:.3f}]; stopped in {stops}/"
          f"{args.runs}, median {np.median(when) if when else float('nan'):.0f} segments")


if __name__ == "__main__":
    main()
