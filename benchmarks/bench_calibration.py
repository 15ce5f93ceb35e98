"""Calibration core benchmarks (issue 2 acceptance 2 and 3).

1. Efficiency: Monte Carlo over datasets of the lesson's kind (200 segments, wheel increments
   ~ N(0, 0.4^2) rad, truth (0.050, 0.051, 0.300) m) in three noise regimes; RMSE of each
   parameter divided by the Cramér–Rao bound at the truth, for excite's axle model with sigma
   given, with sigma estimated, and for the lesson's unweighted estimator (the default
   sensor_pose="auto" on these data: benchmarks/bench_sensor_pose.py).
2. Speed: 100k segments, excite (the axle model, as the lesson's; and the default
   sensor_pose="auto") vs the lesson's estimator on the same data, same process, median of
   repeats.
3. Online update latency: median per update at 100 and at 100k segments processed.

Usage: python benchmarks/bench_calibration.py [--datasets 1000] [--workers 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from tqdm import tqdm

sys.path.insert(0, os.path.dirname(__file__))
from lesson_baseline import lesson_calibrate  # noqa: E402

from excite import OnlineEstimator, calibrate  # noqa: E402
from excite.core.information import crlb_relative_std, fisher_information, scaled_jacobian  # noqa: E402
from excite.logs.synthetic import LESSON_TRUTH, lesson_dataset  # noqa: E402

REGIMES = {"(2e-3, 1e-3)": (2e-3, 2e-3, 1e-3), "(5e-4, 1e-2)": (5e-4, 5e-4, 1e-2),
           "(5e-3, 2e-4)": (5e-3, 5e-3, 2e-4)}
ESTIMATORS = ("excite, sigma given", "excite, sigma estimated", "lesson (unweighted)")


def _one_dataset(args) -> np.ndarray:
    """Relative errors of the three estimators and the CRLB for one dataset, (4, 3)."""
    seed, sigma = args
    seg = lesson_dataset(np.random.default_rng(seed), 200, LESSON_TRUTH, sigma=sigma)
    truth = LESSON_TRUTH.as_array()
    rows = [
        calibrate(seg, sigma=sigma, sensor_pose="axle").params.as_array() / truth - 1,
        calibrate(seg, sensor_pose="axle").params.as_array() / truth - 1,
        lesson_calibrate(seg) / truth - 1,
        crlb_relative_std(fisher_information(
            scaled_jacobian(seg.dphi_L, seg.dphi_R, LESSON_TRUTH, sigma))),
    ]
    return np.array(rows)


def efficiency(datasets: int, workers: int) -> dict:
    results = {}
    with ProcessPoolExecutor(workers) as pool:
        for name, sigma in REGIMES.items():
            seeds = [(1_000_000 + i, sigma) for i in range(datasets)]
            runs = np.array(list(tqdm(pool.map(_one_dataset, seeds, chunksize=20),
                                      total=datasets, desc=f"regime {name}", leave=False)))
            rmse = np.sqrt(np.mean(runs[:, :3] ** 2, axis=0))  # (3 estimators, 3 params)
            bound = np.sqrt(np.mean(runs[:, 3] ** 2, axis=0))
            results[name] = {est: (rmse[i] / bound).tolist() for i, est in enumerate(ESTIMATORS)}
    return results


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def speed(n: int = 100_000, repeats: int = 5) -> dict:
    seg = lesson_dataset(np.random.default_rng(1), n, LESSON_TRUTH)
    sigma = (2e-3, 2e-3, 1e-3)
    t_lesson = _median_time(lambda: lesson_calibrate(seg), repeats)
    t_given = _median_time(lambda: calibrate(seg, sigma=sigma, sensor_pose="axle"), repeats)
    t_est = _median_time(lambda: calibrate(seg, sensor_pose="axle"), repeats)
    t_auto = _median_time(lambda: calibrate(seg), repeats)
    return {"segments": n, "lesson_s": t_lesson, "excite_sigma_given_s": t_given,
            "excite_sigma_estimated_s": t_est, "ratio_given": t_given / t_lesson,
            "ratio_estimated": t_est / t_lesson, "excite_auto_s": t_auto,
            "ratio_auto": t_auto / t_lesson}


def update_latency(est, rows: list[tuple[float, ...]]) -> dict:
    """Median time (us) of ``est.update`` after 100 and after 100k segments (rows cycled)."""
    out = {}
    for mark in (100, 100_000):
        while est.n_segments < mark - 2000:
            est.update(*rows[est.n_segments % len(rows)])
        times = []
        for _ in range(2000):
            row = rows[est.n_segments % len(rows)]
            t0 = time.perf_counter_ns()
            est.update(*row)
            times.append(time.perf_counter_ns() - t0)
        out[f"median_us_at_{mark}"] = float(np.median(times)) / 1e3
    return out


def online_latency() -> dict:
    rows = [tuple(map(float, r)) for r in
            lesson_dataset(np.random.default_rng(2), 5000, LESSON_TRUTH).as_array()]
    return update_latency(OnlineEstimator(LESSON_TRUTH), rows)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args(argv)

    eff = efficiency(args.datasets, args.workers)
    print(f"\nRMSE / CRLB over {args.datasets} datasets of 200 segments (r_L, r_R, b)")
    print(f"{'(sigma_xy, sigma_th)':<22}" + "".join(f"{e:>27}" for e in ESTIMATORS))
    for regime, row in eff.items():
        cells = ["  ".join(f"{v:5.3f}" for v in row[e]) for e in ESTIMATORS]
        print(f"{regime:<22}" + "".join(f"{c:>27}" for c in cells))

    spd = speed()
    print(f"\n100k segments, median of 5: lesson {spd['lesson_s']:.3f} s, "
          f"excite sigma given {spd['excite_sigma_given_s']:.3f} s "
          f"({spd['ratio_given']:.3f}x), sigma estimated {spd['excite_sigma_estimated_s']:.3f} s "
          f"({spd['ratio_estimated']:.3f}x); sensor_pose='auto' (both models fitted and "
          f"tested) {spd['excite_auto_s']:.3f} s ({spd['ratio_auto']:.3f}x)")
    lat = online_latency()
    print("Online update median: " + ", ".join(f"{k} = {v:.1f} us" for k, v in lat.items()))
    return {"efficiency": eff, "speed": spd, "online": lat}


if __name__ == "__main__":
    main()
