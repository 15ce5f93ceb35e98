"""The clock offset's estimate (excite.logs.time_offset.estimate_time_offset) on streams of
different rates: its mean error and scatter.

One-minute synthetic logs (excite.logs.synthetic.synthetic_log: smooth random driving,
4096-tick encoders, 2 mm / 4 mrad pose noise), 16 random paths per pair of rates (seeds
200+), recorded without an offset and with the poses 30 ms late; per pair the mean and the
standard deviation of the estimate's error (ms).

Usage: python benchmarks/bench_time_offset.py [--logs 16]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from excite.logs.synthetic import synthetic_log
from excite.logs.time_offset import estimate_time_offset

#: (encoder rate, pose rate), Hz.
RATES = ((10.0, 100.0), (100.0, 10.0), (100.0, 50.0), (50.0, 50.0), (200.0, 200.0))
LATE = 0.03  # s


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=16)
    args = parser.parse_args(argv)
    out = {}
    for encoder_rate, pose_rate in RATES:
        errors = {0.0: [], LATE: []}
        for seed in range(args.logs):
            series = synthetic_log(np.random.default_rng(200 + seed), 60.0,
                                   encoder_rate=encoder_rate, pose_rate=pose_rate,
                                   pose_noise=(0.002, 0.004), ticks_per_rev=4096).series
            for offset in errors:
                late = dataclasses.replace(series, t_pose=series.t_pose - offset)
                errors[offset].append(estimate_time_offset(late) - offset)
        row = {f"{1e3 * offset:g} ms": (1e3 * float(np.mean(e)), 1e3 * float(np.std(e)))
               for offset, e in errors.items()}
        out[f"{encoder_rate:g}/{pose_rate:g} Hz"] = row
        print(f"encoders {encoder_rate:g} Hz, poses {pose_rate:g} Hz: " + "; ".join(
            f"offset {name}: error {mean:+.2f} ms mean, {sd:.2f} ms std"
            for name, (mean, sd) in row.items()), flush=True)
    return out


if __name__ == "__main__":
    main()
