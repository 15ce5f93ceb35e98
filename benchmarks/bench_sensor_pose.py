"""Sensor-pose calibration benchmarks (the sensor-pose issue's acceptance 2-5).

1. Efficiency and consistency with an off-axle, rotated sensor: Monte Carlo over data sets
   of 200 segments driven as random arcs (wheel increments ~ N(0, 2^2) rad: turns of about
   0.5 rad, the "ordinary driving" the model needs to see the sensor offset), truth
   (0.050, 0.051, 0.300) m, sensor l = (0.05 m, -0.03 m, 1.8 rad), in the three noise regimes
   of the calibration benchmark, no initial guess. RMSE / CRLB of all six parameters (relative
   units: r and b relative to their value, l_x, l_y in units of b, l_theta in rad) with sigma
   given and estimated; the share of runs whose truth lies inside the 95% ellipse of the
   reported 6x6 covariance; and how often ``auto`` picks the sensor-pose model.
2. Axle data (the lesson's data sets): how often ``auto`` picks the axle model, its RMSE/CRLB
   for r_L, r_R, b, and how often the fit test raises a false alarm.
3. Forcing the axle model on off-axle data (offsets drawn small, so that some are barely
   detectable): the share of runs with exit status 4 (fit.ok false) among those whose offset
   is >= 5 standard deviations of its estimate.
4. Speed: 100k segments with the sensor pose estimated vs the lesson's 3-parameter estimator
   on the same data, same process, median of repeats; the six-parameter online update at 100
   and 100k segments.

Usage: python benchmarks/bench_sensor_pose.py [--datasets 1000] [--workers 2]
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from tqdm import tqdm

sys.path.insert(0, os.path.dirname(__file__))
from bench_calibration import REGIMES, _median_time, update_latency  # noqa: E402
from common import monte_carlo_parser  # noqa: E402
from lesson_baseline import lesson_calibrate  # noqa: E402

from excite import OnlineEstimator, Segments, calibrate  # noqa: E402
from excite.core.information import crlb_relative_std, fisher_information, scaled_jacobian  # noqa: E402
from excite.core.kinematics import wrap_angle  # noqa: E402
from excite.core.models import SENSOR_POSE  # noqa: E402
from excite.logs.synthetic import LESSON_TRUTH, lesson_dataset  # noqa: E402
from excite.stats.chi2 import chi2_quantile  # noqa: E402

POSE = np.array([0.05, -0.03, 1.8])
TRUTH = np.append(LESSON_TRUTH.as_array(), POSE)
SCALE = SENSOR_POSE.column_scale(TRUTH)
WHEEL_STD = 2.0  # rad per segment
INSIDE_95 = chi2_quantile(0.95, 6)


def sensor_dataset(rng: np.random.Generator, n: int, theta: np.ndarray, sigma) -> Segments:
    """Random arcs measured by a sensor at theta[3:] (the sensor-pose model, Gaussian noise)."""
    phi_L, phi_R = rng.normal(0.0, WHEEL_STD, n), rng.normal(0.0, WHEEL_STD, n)
    measured = SENSOR_POSE.predict(phi_L, phi_R, theta) + rng.normal(size=(n, 3)) * sigma
    return Segments(phi_L, phi_R, *measured.T)


def _relative_error(result, truth: np.ndarray) -> np.ndarray:
    theta = np.append(result.params.as_array(), result.sensor_pose.as_array())
    d = theta - truth
    d[5] = wrap_angle(d[5])
    return d, d / SCALE


def _off_axle_run(args) -> np.ndarray:
    """Row: relative errors (sigma given, estimated: 12), NEES (2), auto picked sensor (1),
    CRLB relative std (6)."""
    seed, sigma = args
    seg = sensor_dataset(np.random.default_rng(seed), 200, TRUTH, sigma)
    out = []
    nees = []
    for given in (sigma, None):
        result = calibrate(seg, sigma=given, sensor_pose="estimate")
        d, rel = _relative_error(result, TRUTH)
        out.extend(rel)
        nees.append(float(d @ np.linalg.solve(result.full_covariance, d)))
    picked = calibrate(seg, sensor_pose="auto").model == "sensor_pose"
    crlb = crlb_relative_std(fisher_information(scaled_jacobian(
        seg.dphi_L, seg.dphi_R, TRUTH, sigma, model=SENSOR_POSE)))
    return np.array([*out, *nees, float(picked), *crlb])


def _axle_run(args) -> np.ndarray:
    """Row: auto picked axle (1), relative errors of auto (3), CRLB (3), fit alarm (1)."""
    seed, sigma = args
    seg = lesson_dataset(np.random.default_rng(seed), 200, LESSON_TRUTH, sigma=sigma)
    result = calibrate(seg)
    truth = LESSON_TRUTH.as_array()
    crlb = crlb_relative_std(fisher_information(scaled_jacobian(
        seg.dphi_L, seg.dphi_R, truth, sigma)))
    return np.array([float(result.model == "axle"), *(result.params.as_array() / truth - 1),
                     *crlb, float(not result.fit.ok)])


def _forced_axle_run(args) -> np.ndarray:
    """Row: the largest |offset| / std of the estimated sensor pose, and fit.ok of the forced
    axle model (offsets drawn so that some are barely detectable)."""
    seed, sigma = args
    rng = np.random.default_rng(seed)
    # Random direction, magnitude log-uniform from 0.1 mm (undetectable) to 3 cm (obvious);
    # the angle in rad at 5x the offset in m.
    direction = rng.normal(size=3)
    pose = direction / np.linalg.norm(direction) * 10 ** rng.uniform(-4, -1.5)
    pose[2] *= 5.0
    seg = sensor_dataset(rng, 200, np.append(LESSON_TRUTH.as_array(), pose), sigma)
    estimated = calibrate(seg, sensor_pose="estimate")
    z = np.max(np.abs(estimated.sensor_pose.as_array()) / estimated.sensor_pose_std)
    forced = calibrate(seg, sensor_pose="axle")
    return np.array([z, float(forced.fit.ok)])


def _pool_map(fn, args, workers: int, desc: str) -> np.ndarray:
    with ProcessPoolExecutor(workers) as pool:
        return np.array(list(tqdm(pool.map(fn, args, chunksize=20), total=len(args),
                                  desc=desc, leave=False)))


def off_axle(datasets: int, workers: int, seed_offset: int = 0,
             regimes: tuple[str, ...] = tuple(REGIMES)) -> dict:
    results = {}
    for name in regimes:
        sigma = REGIMES[name]
        seeds = [(2_000_000 + seed_offset + i, sigma) for i in range(datasets)]
        runs = _pool_map(_off_axle_run, seeds,
                         workers, f"off-axle {name}")
        bound = np.sqrt(np.mean(runs[:, 15:21] ** 2, axis=0))
        results[name] = {
            "rmse_crlb_given": (np.sqrt(np.mean(runs[:, 0:6] ** 2, axis=0)) / bound).tolist(),
            "rmse_crlb_estimated": (np.sqrt(np.mean(runs[:, 6:12] ** 2, axis=0))
                                    / bound).tolist(),
            "inside_95_given": float(np.mean(runs[:, 12] <= INSIDE_95)),
            "inside_95_estimated": float(np.mean(runs[:, 13] <= INSIDE_95)),
            "auto_picks_sensor_pose": float(np.mean(runs[:, 14])),
        }
    return results


def on_axle(datasets: int, workers: int) -> dict:
    results = {}
    for name, sigma in REGIMES.items():
        runs = _pool_map(_axle_run, [(3_000_000 + i, sigma) for i in range(datasets)],
                         workers, f"axle {name}")
        bound = np.sqrt(np.mean(runs[:, 4:7] ** 2, axis=0))
        results[name] = {"auto_picks_axle": float(np.mean(runs[:, 0])),
                         "rmse_crlb_auto": (np.sqrt(np.mean(runs[:, 1:4] ** 2, axis=0))
                                            / bound).tolist(),
                         "fit_false_alarms": float(np.mean(runs[:, 7]))}
    return results


def forced_axle(datasets: int, workers: int) -> dict:
    sigma = REGIMES["(2e-3, 1e-3)"]
    runs = _pool_map(_forced_axle_run, [(4_000_000 + i, sigma) for i in range(datasets)],
                     workers, "forced axle")
    detectable = runs[:, 0] >= 5.0
    return {"runs": datasets, "offset_ge_5_std": int(detectable.sum()),
            "exit_4_share_of_those": float(np.mean(runs[detectable, 1] == 0.0)),
            "exit_4_share_below_5_std": float(np.mean(runs[~detectable, 1] == 0.0))}


def speed(n: int = 100_000, repeats: int = 5) -> dict:
    """On the same off-axle data (where the lesson's axle model misfits and iterates long),
    and, for a fair reference, the lesson's time on axle data of the same size."""
    sigma = REGIMES["(2e-3, 1e-3)"]
    seg = sensor_dataset(np.random.default_rng(5), n, TRUTH, sigma)
    axle_seg = sensor_dataset(np.random.default_rng(5), n, np.append(TRUTH[:3], [0, 0, 0]),
                              sigma)
    t_lesson = _median_time(lambda: lesson_calibrate(seg), repeats)
    t_lesson_axle = _median_time(lambda: lesson_calibrate(axle_seg), repeats)
    t_sensor = _median_time(lambda: calibrate(seg, sensor_pose="estimate"), repeats)
    t_auto = _median_time(lambda: calibrate(seg), repeats)
    return {"segments": n, "lesson_s": t_lesson, "lesson_axle_data_s": t_lesson_axle,
            "sensor_pose_s": t_sensor, "auto_s": t_auto,
            "ratio_sensor_pose": t_sensor / t_lesson,
            "ratio_sensor_pose_vs_lesson_on_axle_data": t_sensor / t_lesson_axle,
            "ratio_auto": t_auto / t_lesson}


def online_latency() -> dict:
    seg = sensor_dataset(np.random.default_rng(6), 5000, TRUTH, REGIMES["(2e-3, 1e-3)"])
    rows = [tuple(map(float, r)) for r in seg.as_array()]
    nominal = np.append(LESSON_TRUTH.as_array(), POSE + np.array([0.01, 0.01, 0.1]))
    return update_latency(OnlineEstimator(nominal, model=SENSOR_POSE), rows)


def main(argv=None) -> dict:
    parser = monte_carlo_parser(__doc__, datasets=1000)
    parser.add_argument("--seed-offset", type=int, default=0,
                        help="shift the off-axle data sets' seeds (an independent re-run)")
    parser.add_argument("--off-axle-only", metavar="REGIME", default=None,
                        help="run only the off-axle efficiency part, in this regime")
    args = parser.parse_args(argv)
    names = "r_L r_R b l_x l_y l_theta"

    regimes = (args.off_axle_only,) if args.off_axle_only else tuple(REGIMES)
    off = off_axle(args.datasets, args.workers, args.seed_offset, regimes)
    print(f"\nOff-axle sensor l = {POSE.tolist()}: RMSE / CRLB over {args.datasets} data sets "
          f"of 200 segments ({names})")
    for regime, row in off.items():
        given = " ".join(f"{v:5.3f}" for v in row["rmse_crlb_given"])
        est = " ".join(f"{v:5.3f}" for v in row["rmse_crlb_estimated"])
        print(f"  {regime:<14} sigma given {given} | estimated {est} | inside 95%: "
              f"{100 * row['inside_95_given']:.1f}% / {100 * row['inside_95_estimated']:.1f}% "
              f"| auto picks sensor_pose {100 * row['auto_picks_sensor_pose']:.1f}%")
    if args.off_axle_only:
        return {"off_axle": off}
    axle = on_axle(args.datasets, args.workers)
    print("\nAxle data (lesson's data sets), sensor_pose='auto':")
    for regime, row in axle.items():
        rmse = " ".join(f"{v:5.3f}" for v in row["rmse_crlb_auto"])
        print(f"  {regime:<14} picks axle {100 * row['auto_picks_axle']:.1f}% | RMSE/CRLB "
              f"{rmse} | fit false alarms {100 * row['fit_false_alarms']:.1f}%")
    forced = forced_axle(args.datasets, args.workers)
    print(f"\nAxle model forced on off-axle data: {forced['offset_ge_5_std']} of "
          f"{forced['runs']} runs with the offset >= 5 std; exit 4 in "
          f"{100 * forced['exit_4_share_of_those']:.1f}% of those "
          f"({100 * forced['exit_4_share_below_5_std']:.1f}% of the others)")
    spd = speed()
    print(f"\n100k segments, median of 5: lesson (3 parameters) {spd['lesson_s']:.3f} s on the "
          f"off-axle data ({spd['lesson_axle_data_s']:.3f} s on axle data); sensor pose "
          f"estimated {spd['sensor_pose_s']:.3f} s ({spd['ratio_sensor_pose']:.3f}x; "
          f"{spd['ratio_sensor_pose_vs_lesson_on_axle_data']:.3f}x the lesson on axle data), "
          f"auto {spd['auto_s']:.3f} s ({spd['ratio_auto']:.3f}x)")
    lat = online_latency()
    print("Online six-parameter update median: "
          + ", ".join(f"{k} = {v:.1f} us" for k, v in lat.items()))
    return {"off_axle": off, "axle": axle, "forced_axle": forced, "speed": spd,
            "online": lat}


if __name__ == "__main__":
    main()
