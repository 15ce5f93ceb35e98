"""Calibration from time-series logs, by Monte Carlo: coverage of the 95% ellipse of the six
estimated parameters (wheels and sensor pose) and RMSE per parameter against the Cramér–Rao
bound of the pose noise (the segment data's Fisher information at the truth under the
correlated pose-noise model at the true levels). When the pose noise is the only noise
(synthetic logs without slip, the ideal env) this is the bound; with slip it is a lower bound
of it (slip only removes information), so RMSE / this bound over-states the true ratio. Also
printed: RMSE / mean reported std, and the same logs fitted by the GLS at the true pose-noise
levels with no segment noise (without slip: what the estimator would reach if it knew the
noise, a diagnostic of the noise-level estimation; with slip: the fit that ignores the slip).

Honesty of the reported uncertainty between independent logs of one robot (acceptance 3): for
pairs of logs (2i, 2i + 1), the normalised difference of their estimates d^T (C_a + C_b)^-1 d
should fall inside the chi-square 95% bound 95% of the time. Synthetic logs are all of one
robot; env logs are with ``--same-robot`` (the nominal robot without spread and the sensor at
the synthetic logs' mounting; otherwise each log draws its own hidden robot and sensor).

Sources of logs:

* ``synthetic`` (excite.logs.synthetic): smooth random curves, an off-axle sensor, 50 Hz pose
  samples with noise (white, or wandering with ``--pose-noise-time``: first-order
  Gauss-Markov, as a scan matcher's or visual odometry's error), optional random-walk wheel
  slip;
* ``env``: the simulator (``excite simulate --format timeseries``): a hidden robot and sensor
  mounting per log, encoder ticks at the physics rate, a 100 Hz pose stream with noise, driven
  by the arcs protocol at ``--speed`` of the motor limit (gently: the slip env slips little).

    python benchmarks/bench_logs.py --logs 200 --slip 0
    python benchmarks/bench_logs.py --logs 200 --slip 0.01
    python benchmarks/bench_logs.py --logs 200 --slip 0.01 --pose-noise 0   # independent noise
    python benchmarks/bench_logs.py --logs 200 --pose-noise-time 20          # wandering poses
    python benchmarks/bench_logs.py --logs 200 --pose-noise 0.0001 --ticks-per-rev 4096 \
        --encoder-jitter 0.002                                 # encoder timing errors
    python benchmarks/bench_logs.py --source env --env excite/DiffDriveCalibIdeal-v0 --logs 200
    python benchmarks/bench_logs.py --source env --speed 0.1 --logs 200       # slip env, gently
    python benchmarks/bench_logs.py --source env --speed 0.1 --logs 200 --same-robot
    python benchmarks/bench_logs.py --source env --speed 0.1 --logs 200 --same-robot \
        --record-noise 0,0 [--encoders dithered]     # quantization the only noise
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

from excite.calibration.noise import ChainWhitener, NoiseLevels
from excite.calibration.pipeline import calibrate
from excite.calibration.solver import Problem, levenberg_marquardt, normal_system
from excite.commands.args import pose_noise_arg
from excite.core.models import SENSOR_POSE, SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.segments import Segments
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries import TimeSeries, tick_angle
from excite.registration import SENSOR_MOUNTING
from excite.stats.chi2 import chi2_quantile

SENSOR = SensorPose(0.1, -0.03, 0.4)
CHI2_6_95 = chi2_quantile(0.95, SENSOR_POSE.size)
NAMES = SENSOR_POSE.names
#: The nominal robot without spread (--same-robot): every hidden value fixed at the nominal.
SAME_ROBOT = {"radius_rel": 0.0, "separation_rel": 0.0, "mass_rel": 0.0, "mu_range": (0.8, 0.8),
              "com_offset_range": (0.04, 0.04)}


def synthetic_source(args: argparse.Namespace, i: int
                     ) -> tuple[TimeSeries, np.ndarray, tuple[float, float], float | None]:
    """A synthetic log: its series, the truth (6,), the pose noise (xy m, theta rad) and the
    encoder resolution (None: not quantised)."""
    log = synthetic_log(np.random.default_rng(args.seed + i), args.duration,
                        sensor_pose=SENSOR, pose_noise=(args.pose_noise, args.pose_noise),
                        slip=args.slip, ticks_per_rev=args.ticks_per_rev,
                        pose_noise_time=args.pose_noise_time,
                        encoder_jitter=args.encoder_jitter, pose_jitter=args.pose_jitter,
                        encoder_rate=args.encoder_rate, pose_rate=args.pose_rate,
                        **{key: value for key, value in (("speed", args.forward_speed),
                                                         ("turn_rate", args.turn_rate))
                           if value is not None})
    return (log.series, np.append(log.params.as_array(), SENSOR.as_array()),
            (args.pose_noise, args.pose_noise), args.ticks_per_rev)


def env_source(args: argparse.Namespace, i: int
               ) -> tuple[TimeSeries, np.ndarray, tuple[float, float], float | None]:
    """A log of the simulator driven by the arcs protocol at args.speed (as
    :func:`synthetic_source`; the encoders count whole ticks)."""
    from agents.catalog import make_protocol
    from agents.compare import make_env, run_protocol_episode
    from agents.protocols import Arcs

    robot, mounting = "default", SENSOR_MOUNTING
    if args.same_robot:
        robot = SAME_ROBOT
        mounting = {k: (v, v) for k, v in zip(("x", "y", "theta"), SENSOR.as_array(),
                                               strict=True)}
    noise = {} if args.record_noise is None else {
        "record_sigma_xy": args.record_noise[0], "record_sigma_theta": args.record_noise[1]}
    env = make_env(args.env, int(args.duration), robot=robot, record=True,
                   sensor_pose=mounting, **noise)
    protocol = Arcs(speed=args.speed) if args.protocol is None else make_protocol(args.protocol)
    run_protocol_episode(env, protocol, args.seed + i)
    base = env.unwrapped
    truth = np.append(base.true_params.as_array(), base.true_sensor_pose.as_array())
    sigma = base.recording.sigma
    recording = base.recording
    series = recording.series
    if args.encoders == "dithered" or args.encoder_jitter:
        tick = tick_angle(recording.ticks_per_rev)
        rng = np.random.default_rng(args.seed + i)
        angles = recording.true_wheel_angles
        if args.encoder_jitter:
            # read off a smooth path through the simulator's samples, as a real wheel turns
            # (its path is linear between physics steps: a kink at every sample, where a late
            # read errs with a mean that no zero-mean timing error describes)
            from scipy.interpolate import CubicSpline

            t = series.t_enc
            read = np.clip(t + args.encoder_jitter * rng.normal(size=t.size), t[0], t[-1])
            angles = CubicSpline(t, angles, axis=0)(read)
        if args.encoders == "dithered":  # plus independent rounding errors
            angles = angles + tick * rng.uniform(-0.5, 0.5, angles.shape)
        else:
            angles = np.floor(angles / tick) * tick
        series = TimeSeries(series.t_enc, *angles.T, series.t_pose, series.x, series.y,
                            series.theta, source=series.source)
    return series, truth, (float(sigma[0]), float(sigma[2])), recording.ticks_per_rev


def pose_noise_fit(segments: Segments, truth: np.ndarray, start: np.ndarray,
                   pose_noise: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The bound of the pose noise alone (6, 6) (inverse Fisher information at the truth) and
    the GLS estimate (6,) at those true noise levels, from ``start``."""
    levels = NoiseLevels(np.full(3, 1e-9), np.array(pose_noise))
    problem = Problem(SENSOR_POSE, segments, ChainWhitener(segments, levels))
    ev = problem.evaluate(truth)
    info = normal_system(ev, np.ones(3), "linear").information
    fit = levenberg_marquardt(problem, start, np.ones(3), "linear")
    return np.linalg.inv(info) * np.outer(ev.scale, ev.scale), fit.theta


def pairs_inside(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """For pairs of logs (2i, 2i + 1): whether d^T (C_a + C_b)^-1 d < the chi2(6) 95% bound,
    d the difference of their estimates."""
    a, b = slice(0, len(errors) - 1, 2), slice(1, len(errors), 2)
    diff = errors[a] - errors[b]
    diff[:, 5] = (diff[:, 5] + np.pi) % (2 * np.pi) - np.pi
    pair_cov = covariances[a] + covariances[b]
    q = np.einsum("ki,ki->k", diff, np.linalg.solve(pair_cov, diff[:, :, None])[:, :, 0])
    return q < CHI2_6_95


def _row(label: str, values: np.ndarray) -> str:
    return label + " " + " ".join(f"{n} {v:.3f}" for n, v in zip(NAMES, values, strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=("synthetic", "env"), default="synthetic")
    parser.add_argument("--logs", type=int, default=200)
    parser.add_argument("--duration", type=float, default=120.0, help="s per log")
    parser.add_argument("--pose-noise", type=float, default=0.002, help="m and rad (synthetic)")
    parser.add_argument("--pose-noise-time", type=float, default=0.0,
                        help="s: correlation time of the pose noise (synthetic; 0: white)")
    parser.add_argument("--slip", type=float, default=0.0,
                        help="rad / sqrt(s) per wheel (synthetic)")
    parser.add_argument("--encoder-rate", type=float, default=100.0, help="Hz (synthetic)")
    parser.add_argument("--pose-rate", type=float, default=50.0, help="Hz (synthetic)")
    parser.add_argument("--forward-speed", type=float, default=None,
                        help="m/s, the middle of the forward speed's range (synthetic; "
                        "default synthetic_log's)")
    parser.add_argument("--turn-rate", type=float, default=None,
                        help="rad/s, the turn rate's amplitude (synthetic; default "
                        "synthetic_log's)")
    parser.add_argument("--ticks-per-rev", type=int, default=None,
                        help="(synthetic) encoders count whole ticks of this resolution "
                             "(default: exact angles)")
    parser.add_argument("--env", default="excite/DiffDriveCalibSensor-v0", help="(env)")
    parser.add_argument("--speed", type=float, default=0.2,
                        help="arcs speed, fraction of the motor limit (env)")
    parser.add_argument("--protocol", default=None, metavar="SPEC",
                        help="(env) drive with this protocol (e.g. random) instead of arcs at "
                             "--speed")
    parser.add_argument("--same-robot", action="store_true",
                        help="(env) every log of the nominal robot, the sensor at one mounting")
    parser.add_argument("--record-noise", type=pose_noise_arg, default=None, metavar="SXY,STH",
                        help="(env) noise of each recorded pose, m and rad (default: the "
                             "env's; 0,0: no pose noise, the physics' slip alone)")
    parser.add_argument("--encoders", choices=("ticks", "dithered"), default="ticks",
                        help="(env) the recorded whole-tick angles, or the true angles plus "
                             "independent uniform errors of one tick (dithered encoders: "
                             "what the quantization model assumes)")
    parser.add_argument("--encoder-jitter", type=float, default=0.0, metavar="SECONDS",
                        help="each encoder sample read at its stamp plus a Gaussian time "
                             "error of this std (s; both wheels at once)")
    parser.add_argument("--pose-jitter", type=float, default=0.0, metavar="SECONDS",
                        help="(synthetic) each pose sample taken at its stamp plus a Gaussian "
                             "time error of this std (s)")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    source = synthetic_source if args.source == "synthetic" else env_source
    errors, known, distances, reported, covariances, bounds = [], [], [], [], [], []
    widened = driving = wandering = late = 0
    for i in tqdm(range(args.logs), desc="logs"):
        series, truth, pose_noise, ticks = source(args, i)
        segments = segment_timeseries(series).segments
        result = calibrate(segments, sensor_pose="estimate", ticks_per_rev=ticks)
        estimate = np.append(result.params.as_array(), result.sensor_pose.as_array())
        error = estimate - truth
        error[5] = (error[5] + np.pi) % (2 * np.pi) - np.pi
        errors.append(error)
        distances.append(error @ np.linalg.solve(result.full_covariance, error))
        reported.append(np.diag(result.full_covariance))
        covariances.append(result.full_covariance)
        widened += result.fit.long_run_bandwidth is not None
        driving += result.fit.driving_statistic is not None and not result.fit.ok
        wandering += result.fit.heading_wander is not None
        late += bool(result.timing)
        if min(pose_noise) > 0:  # without pose noise there is no pose-noise bound
            bound, theta = pose_noise_fit(segments, truth, estimate, pose_noise)
            bounds.append(bound)
            known.append(theta - truth)
    errors, known, distances = np.array(errors), np.array(known), np.array(distances)
    rmse = np.sqrt(np.mean(errors**2, axis=0))
    driven = f"arcs at {args.speed:g}" if args.protocol is None else args.protocol
    what = (f"{args.env}, {driven}" if args.source == "env" else
            f"synthetic, pose noise {args.pose_noise:g} (correlation time "
            f"{args.pose_noise_time:g} s), slip {args.slip:g}")
    print(f"{args.logs} logs of {args.duration:g} s ({what})")
    print(f"truth inside the 95% ellipse (6 parameters): {np.mean(distances < CHI2_6_95):.3f}")
    print(f"covariance widened for serially correlated residuals: {widened} of {args.logs} logs")
    print(f"pose heading error found to wander: {wandering} of {args.logs} logs")
    print(f"encoder timing error found: {late} of {args.logs} logs")
    print(f"fit failed by the driving test (slip growing with acceleration): {driving} of "
          f"{args.logs} logs")
    print("RMSE", " ".join(f"{n} {v:.3g}" for n, v in zip(NAMES, rmse, strict=True)))
    print(_row("RMSE / mean reported std", rmse / np.sqrt(np.mean(reported, axis=0))))
    print(_row("RMS of error / reported std (z; 1 when honest)",
               np.sqrt(np.mean(errors**2 / np.array(reported), axis=0))))
    if bounds:
        crlb = np.sqrt(np.diag(np.mean(bounds, axis=0)))
        print(_row("RMSE / CRLB of the pose noise", rmse / crlb))
        print(_row("GLS at the pose-noise levels alone (slip ignored): RMSE / CRLB",
                   np.sqrt(np.mean(known**2, axis=0)) / crlb))
    if args.source == "synthetic" or args.same_robot:  # one robot: pairs must agree
        inside = pairs_inside(errors, np.array(covariances))
        print(f"pairs of logs whose difference is inside the 95% bound: {inside.mean():.3f} "
              f"of {inside.size}")


if __name__ == "__main__":
    main()
