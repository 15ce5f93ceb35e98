"""Gross errors handled by default (``loss="auto"``): contaminated simulations.

Segment CSVs: data sets of 200 segments of two kinds, the lesson's (axle truth
(0.050, 0.051, 0.300) m, wheel increments ~ N(0, 0.4^2) rad) and random arcs seen by an
off-axle, rotated sensor (benchmarks/bench_sensor_pose.py: l = (0.05 m, -0.03 m, 1.8 rad)),
in the three noise regimes of the calibration benchmark. A fraction (0, 1%, 3%, 5%) of the
segments is made gross: half of them get an error uniform within +-0.1 m on dx, dy and
+-0.3 rad on dtheta, the other half swap their measured increments in pairs (a wrong
correspondence). Default flags (``calibrate(seg)``), no initial guess. Per cell:

* RMSE / CRLB of every parameter of the truth's model (r_L, r_R, b; with the sensor l_x, l_y,
  l_theta), the CRLB being the clean data's bound at the truth (all N segments, true sigma);
* the share of data sets whose truth lies inside the 95% ellipse of the reported covariance
  (of the model the calibration chose);
* the share of the gross segments flagged, of the clean segments flagged, and of the data
  sets with any segment flagged;
* the RMSE over the default's on the same data sets without the gross errors (what the gross
  errors cost), and the RMSE / CRLB with ``loss="linear"`` (plain least squares, the default
  before "auto") on the same data.

Time-series logs: synthetic logs of 120 s (excite.logs.synthetic.synthetic_log: 100 Hz
encoders, 50 Hz poses with white noise in three regimes, the sensor at (0.1 m, -0.03 m,
0.4 rad)), cut into 1 s windows by segment_timeseries. A fraction of the pose samples at the
segments' boundaries is made gross (half an error uniform within +-0.1 m, +-0.1 m, +-0.3 rad,
half the pose of the sample 0.1 s later: a swap), then the log is cut again (the jump
detector drops the segments around the largest jumps) and calibrated with default flags.
Per cell: RMSE / CRLB of the six parameters against the bound of the clean log's pose noise
(benchmarks/bench_logs.py: the segments' Fisher information at the truth and the true
levels), the 95% ellipse's coverage, the share of the bad samples reaching the calibration
that are flagged (a flagged segment starts or ends there), the share the segmentation
dropped, the share of the segments not touching a bad sample that are flagged, and the RMSE
over the default's on the same logs without the gross errors (what the gross errors cost).

Usage: python benchmarks/bench_gross_errors.py [--datasets 500] [--logs 100] [--workers 2]
       [--only segments|logs] [--log-regimes "2 mm / 2 mrad"]
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from bench_calibration import REGIMES  # noqa: E402
from bench_sensor_pose import TRUTH as SENSOR_TRUTH  # noqa: E402
from bench_sensor_pose import sensor_dataset  # noqa: E402
from common import monte_carlo_parser  # noqa: E402

from excite import Segments, calibrate  # noqa: E402
from excite.core.information import crlb_relative_std, fisher_information, scaled_jacobian  # noqa: E402
from excite.core.kinematics import wrap_angle  # noqa: E402
from excite.core.models import AXLE, SENSOR_POSE, SensorPose  # noqa: E402
from excite.logs.segmentation import segment_timeseries  # noqa: E402
from excite.logs.synthetic import LESSON_TRUTH, lesson_dataset, synthetic_log  # noqa: E402
from excite.logs.timeseries import TimeSeries  # noqa: E402
from excite.stats.chi2 import chi2_quantile  # noqa: E402

FRACTIONS = (0.0, 0.01, 0.03, 0.05)
KINDS = ("lesson", "sensor")
N_SEGMENTS = 200
UNIFORM = np.array([0.1, 0.1, 0.3])  # half-widths of the uniform gross error (m, m, rad)


def contaminate(rng: np.random.Generator, seg: Segments, fraction: float
                ) -> tuple[Segments, np.ndarray]:
    """``seg`` with round(fraction N) gross segments (half uniform errors, half swapped in
    pairs; an odd one out gets a uniform error) and their sorted indices."""
    rows = seg.as_array().copy()
    n = len(rows)
    count = int(round(fraction * n))
    bad = rng.choice(n, count, replace=False)
    swapped = bad[: 2 * (count // 4)]
    uniform = bad[2 * (count // 4):]
    rows[uniform, 2:] += rng.uniform(-1.0, 1.0, (uniform.size, 3)) * UNIFORM
    a, b = swapped[0::2], swapped[1::2]
    rows[a, 2:], rows[b, 2:] = rows[b, 2:].copy(), rows[a, 2:].copy()
    return Segments.from_array(rows), np.sort(bad)


def _truth_theta(kind: str) -> np.ndarray:
    return LESSON_TRUTH.as_array() if kind == "lesson" else SENSOR_TRUTH


def _errors(result, truth: np.ndarray) -> tuple[np.ndarray, float]:
    """Relative errors of the truth's parameters (P,) and the NEES of the chosen model's."""
    theta = result.params.as_array()
    if result.sensor_pose is not None and result.sensor_pose_std is not None:
        theta = np.append(theta, result.sensor_pose.as_array())
    p = truth.size
    full = theta if theta.size >= p else np.append(theta, np.zeros(p - theta.size))
    d = full[:p] - truth
    if p == 6:
        d[5] = wrap_angle(d[5])
    model = SENSOR_POSE if p == 6 else AXLE
    relative = d / model.column_scale(truth)
    # NEES in the chosen model's own parameters (the axle model: its 3)
    chosen = theta.size
    truth_chosen = truth[:chosen] if chosen <= p else np.append(truth, np.zeros(chosen - p))
    e = theta - truth_chosen
    if chosen == 6:
        e[5] = wrap_angle(e[5])
    nees = float(e @ np.linalg.solve(result.full_covariance, e))
    return relative, nees / chi2_quantile(0.95, chosen)


def _one(args) -> np.ndarray:
    """Row: relative errors (6, zero-padded), NEES/quantile, gross segments flagged, clean
    segments flagged, gross count, any flagged; with loss linear: relative errors (6); the
    clean CRLB (6); seconds of the default calibration; the default's relative errors on the
    same data set without the gross errors (6)."""
    kind, sigma, fraction, seed, options = args
    rng = np.random.default_rng(seed)
    truth = _truth_theta(kind)
    seg = (lesson_dataset(rng, N_SEGMENTS, LESSON_TRUTH, sigma=sigma) if kind == "lesson"
           else sensor_dataset(rng, N_SEGMENTS, truth, np.asarray(sigma)))
    model = AXLE if kind == "lesson" else SENSOR_POSE
    crlb = crlb_relative_std(fisher_information(scaled_jacobian(
        seg.dphi_L, seg.dphi_R, truth, sigma, model=model)))
    dirty, bad = contaminate(rng, seg, fraction)
    t0 = time.perf_counter()
    result = calibrate(dirty, **options)
    seconds = time.perf_counter() - t0
    rel, nees = _errors(result, truth)
    flagged = (np.zeros(0, dtype=int) if result.gross_errors is None
               else result.gross_errors.segments)
    hit = np.isin(bad, flagged).sum()
    false = np.setdiff1d(flagged, bad).size
    linear, _ = _errors(calibrate(dirty, loss="linear", **options), truth)
    twin = rel if fraction == 0.0 else _errors(calibrate(seg, **options), truth)[0]
    pad = np.zeros(6 - truth.size)
    return np.concatenate([rel, pad, [nees, hit, false, bad.size, float(flagged.size > 0)],
                           linear, pad, crlb, pad, [seconds], twin, pad])


def segments_cells(datasets: int, workers: int, options: dict) -> dict:
    cells = [(kind, name, fraction) for kind in KINDS for name in REGIMES
             for fraction in FRACTIONS]
    jobs = [(kind, REGIMES[name], fraction, 7_000_000 + 10_000 * c + i, options)
            for c, (kind, name, fraction) in enumerate(cells) for i in range(datasets)]
    with ProcessPoolExecutor(workers) as pool:
        rows = np.array(list(pool.map(_one, jobs, chunksize=10)))
    results = {}
    for c, (kind, name, fraction) in enumerate(cells):
        runs = rows[c * datasets:(c + 1) * datasets]
        p = 3 if kind == "lesson" else 6
        bound = np.sqrt(np.mean(runs[:, 17:17 + p] ** 2, axis=0))
        gross = runs[:, 9].sum()
        cell = {
            "datasets": datasets,
            "rmse_crlb": (np.sqrt(np.mean(runs[:, :p] ** 2, axis=0)) / bound).tolist(),
            "inside_95": float(np.mean(runs[:, 6] <= 1.0)),
            "gross_flagged": float(runs[:, 7].sum() / gross) if gross else None,
            "clean_flagged": float(runs[:, 8].sum() / (datasets * N_SEGMENTS - gross)),
            "datasets_flagged": float(np.mean(runs[:, 10])),
            "seconds_median": float(np.median(runs[:, 23])),
            "rmse_crlb_linear": (np.sqrt(np.mean(runs[:, 11:11 + p] ** 2, axis=0))
                                 / bound).tolist(),
            "rmse_over_clean_twin": (np.sqrt(np.mean(runs[:, :p] ** 2, axis=0))
                                     / np.sqrt(np.mean(runs[:, 24:24 + p] ** 2, axis=0))
                                     ).tolist(),
        }
        results[f"{kind} {name} {100 * fraction:g}%"] = cell
    return results


def _print_segments(results: dict) -> None:
    print(f"\nSegment CSVs ({N_SEGMENTS} segments): RMSE/CRLB (clean bound) "
          "r_L r_R b [l_x l_y l_theta] | inside 95% | gross flagged | clean flagged | "
          "data sets with a flag | median time | RMSE over the default's on the same data "
          "sets without the gross errors | RMSE/CRLB of --loss linear")
    for key, cell in results.items():
        rmse = " ".join(f"{v:5.3f}" for v in cell["rmse_crlb"])
        gross = "   -  " if cell["gross_flagged"] is None else (
            f"{100 * cell['gross_flagged']:5.1f}%")
        twin = " ".join(f"{v:5.3f}" for v in cell["rmse_over_clean_twin"])
        linear = " ".join(f"{v:5.3g}" for v in cell["rmse_crlb_linear"])
        print(f"  {key:<26} {rmse} | {100 * cell['inside_95']:5.1f}% | {gross} | "
              f"{100 * cell['clean_flagged']:.3f}% | {100 * cell['datasets_flagged']:5.1f}% | "
              f"{1e3 * cell['seconds_median']:.0f} ms ({cell['datasets']} sets) | over the "
              f"clean twin {twin} | linear {linear}")


# --- time-series logs --------------------------------------------------------------------

TS_SENSOR = SensorPose(0.1, -0.03, 0.4)
#: Pose noise (xy m, theta rad) of the time-series regimes.
TS_REGIMES = {"2 mm / 2 mrad": (2e-3, 2e-3), "0.5 mm / 5 mrad": (5e-4, 5e-3),
              "5 mm / 0.5 mrad": (5e-3, 5e-4)}
SWAP_LAG = 5  # pose periods: a swapped sample takes the pose of the sample this many later


def contaminate_log(rng: np.random.Generator, series: TimeSeries, boundaries: np.ndarray,
                    fraction: float) -> tuple[TimeSeries, np.ndarray]:
    """``series`` with round(fraction B) of its B segment-boundary pose samples made gross
    (half an error uniform within +-0.1 m, +-0.1 m, +-0.3 rad, half the pose of the sample
    SWAP_LAG periods later), and their times (s)."""
    count = int(round(fraction * boundaries.size))
    bad = np.sort(rng.choice(boundaries, count, replace=False))
    index = np.searchsorted(series.t_pose, bad)
    assert np.allclose(series.t_pose[index], bad)
    poses = np.column_stack([series.x, series.y, series.theta])
    swapped, uniform = index[: count // 2], index[count // 2:]
    later = np.minimum(swapped + SWAP_LAG, poses.shape[0] - 1)
    poses[swapped] = poses[later]
    poses[uniform] += rng.uniform(-1.0, 1.0, (uniform.size, 3)) * UNIFORM
    return TimeSeries(series.t_enc, series.phi_L, series.phi_R, series.t_pose, *poses.T,
                      source=series.source), bad


def _one_log(args) -> np.ndarray:
    """Row: relative errors (6), NEES / quantile, bad samples injected, of them flagged (a
    flagged segment starts or ends there), of them dropped by the segmentation, clean
    segments flagged, clean segments, any flagged; the clean bound's relative std (6);
    seconds; the default's relative errors on the same log without the gross errors (6)."""
    from bench_logs import pose_noise_fit

    regime, fraction, seed, options = args
    noise = TS_REGIMES[regime]
    rng = np.random.default_rng(seed)
    log = synthetic_log(rng, 120.0, sensor_pose=TS_SENSOR, pose_noise=noise)
    truth = np.append(log.params.as_array(), TS_SENSOR.as_array())
    clean = segment_timeseries(log.series).segments
    bound, _ = pose_noise_fit(clean, truth, truth, noise)
    boundaries = np.unique(np.concatenate([clean.t_start, clean.t_end]))
    series, bad = contaminate_log(rng, log.series, boundaries, fraction)
    seg = segment_timeseries(series).segments
    t0 = time.perf_counter()
    result = calibrate(seg, **options)
    seconds = time.perf_counter() - t0
    rel, nees = _errors(result, truth)
    gross = result.gross_errors
    on_boundary = np.isin(bad, np.concatenate([seg.t_start, seg.t_end]))
    flagged_times = np.zeros(0)
    flagged_segments = np.zeros(0, dtype=int)
    if gross is not None and gross.segments.size:
        flagged_segments = gross.segments
        flagged_times = np.concatenate([gross.t_start, gross.t_end])
    hit = int(np.sum(on_boundary & np.isin(bad, flagged_times)))
    near_bad = np.isin(seg.t_start, bad) | np.isin(seg.t_end, bad)
    false = int(np.sum(~near_bad[flagged_segments]))
    scale = SENSOR_POSE.column_scale(truth)
    crlb = np.sqrt(np.diag(bound)) / scale
    twin = rel if fraction == 0.0 else _errors(calibrate(clean, **options), truth)[0]
    return np.concatenate([rel, [nees, bad.size, hit, int(np.sum(~on_boundary)), false,
                                 int(np.sum(~near_bad)), float(flagged_segments.size > 0)],
                           crlb, [seconds], twin])


def logs_cells(datasets: int, workers: int, regimes: tuple[str, ...], options: dict) -> dict:
    cells = [(regime, fraction) for regime in regimes for fraction in FRACTIONS]
    jobs = [(regime, fraction, 8_000_000 + 10_000 * c + i, options)
            for c, (regime, fraction) in enumerate(cells) for i in range(datasets)]
    with ProcessPoolExecutor(workers) as pool:
        rows = np.array(list(pool.map(_one_log, jobs, chunksize=2)))
    np.save(os.path.join(os.environ.get("TMPDIR", "/tmp"), "bench_gross_errors_logs.npy"), rows)
    results = {}
    for c, (regime, fraction) in enumerate(cells):
        runs = rows[c * datasets:(c + 1) * datasets]
        bound = np.sqrt(np.mean(runs[:, 13:19] ** 2, axis=0))
        injected = runs[:, 7].sum()
        reaching = injected - runs[:, 9].sum()
        results[f"{regime} {100 * fraction:g}%"] = {
            "datasets": datasets,
            "rmse_crlb": (np.sqrt(np.mean(runs[:, :6] ** 2, axis=0)) / bound).tolist(),
            "inside_95": float(np.mean(runs[:, 6] <= 1.0)),
            "gross_flagged": float(runs[:, 8].sum() / reaching) if reaching else None,
            "gross_dropped_by_segmentation": (float(runs[:, 9].sum() / injected) if injected
                                              else None),
            "clean_flagged": float(runs[:, 10].sum() / runs[:, 11].sum()),
            "datasets_flagged": float(np.mean(runs[:, 12])),
            "seconds_median": float(np.median(runs[:, 19])),
            "rmse_over_clean_twin": (np.sqrt(np.mean(runs[:, :6] ** 2, axis=0))
                                     / np.sqrt(np.mean(runs[:, 20:26] ** 2, axis=0))).tolist(),
        }
    return results


def _print_logs(results: dict) -> None:
    print("\nTime-series logs (120 s, 1 s windows, sensor (0.1, -0.03, 0.4)): "
          "RMSE/CRLB (the clean pose-noise bound) r_L r_R b l_x l_y l_theta | inside 95% | "
          "bad samples flagged (of those reaching the calibration; dropped by the "
          "segmentation) | clean segments flagged | data sets with a flag | median time | "
          "RMSE over the default's on the same logs without the gross errors")
    for key, cell in results.items():
        rmse = " ".join(f"{v:5.3f}" for v in cell["rmse_crlb"])
        dropped = cell["gross_dropped_by_segmentation"]
        gross = "   -  " if cell["gross_flagged"] is None else (
            f"{100 * cell['gross_flagged']:5.1f}% ({100 * dropped:.1f}%)")
        twin = " ".join(f"{v:5.3f}" for v in cell["rmse_over_clean_twin"])
        print(f"  {key:<20} {rmse} | {100 * cell['inside_95']:5.1f}% | {gross} | "
              f"{100 * cell['clean_flagged']:.3f}% | {100 * cell['datasets_flagged']:5.1f}% | "
              f"{cell['seconds_median']:.2f} s ({cell['datasets']} logs) | over the clean "
              f"twin {twin}")


def main(argv=None) -> dict:
    parser = monte_carlo_parser(__doc__, datasets=500)
    parser.add_argument("--logs", type=int, default=100,
                        help="time-series logs per cell (0: none)")
    parser.add_argument("--log-regimes", default=",".join(TS_REGIMES),
                        help="the time-series regimes, comma-separated (of: "
                        f"{', '.join(TS_REGIMES)})")
    parser.add_argument("--only", choices=("segments", "logs"), default=None)
    parser.add_argument("--heterogeneity", default=None,
                        help="passed to every calibrate() (e.g. off: the motion-heterogeneity "
                        "stage left out, to isolate the gross errors' effect); default: the "
                        "default flags")
    args = parser.parse_args(argv)
    options = {} if args.heterogeneity is None else {"heterogeneity": args.heterogeneity}
    results = {}
    print(f"calibrate() options: {options or 'the defaults'}")
    if args.only != "logs":
        results["segments"] = segments_cells(args.datasets, args.workers, options)
        _print_segments(results["segments"])
    if args.only != "segments" and args.logs:
        regimes = tuple(r.strip() for r in args.log_regimes.split(","))
        results["logs"] = logs_cells(args.logs, args.workers, regimes, options)
        _print_logs(results["logs"])
    return results


if __name__ == "__main__":
    main()
