"""Calibration from time-series logs, by Monte Carlo: coverage of the 95% ellipse of the six
estimated parameters (wheels and sensor pose) and RMSE per parameter against the Cramér–Rao
bound (the segment data's Fisher information at the truth under the true noise model, known
when the only noise is on the pose samples; otherwise RMSE / mean reported std is printed).
For synthetic logs (all of the same robot), also the honesty of the reported uncertainty
between independent logs: for pairs of logs (2i, 2i + 1), the normalised difference of their
estimates d^T (C_a + C_b)^-1 d should fall inside the chi-square 95% bound 95% of the time.

Sources of logs:

* ``synthetic`` (excite.synthetic): smooth random curves, an off-axle sensor, 50 Hz pose
  samples with noise, optional random-walk wheel slip;
* ``env``: the simulator (``excite simulate --format timeseries``): a hidden robot and sensor
  mounting per log, encoder ticks at the physics rate, a 100 Hz pose stream with noise, driven
  by the arcs protocol at ``--speed`` of the motor limit (gently: the slip env slips little).

    python benchmarks/bench_logs.py --logs 200 --slip 0
    python benchmarks/bench_logs.py --logs 200 --slip 0.01
    python benchmarks/bench_logs.py --logs 200 --slip 0.01 --pose-noise 0   # independent noise
    python benchmarks/bench_logs.py --source env --env excite/DiffDriveCalibSensor-v0 --logs 200
    python benchmarks/bench_logs.py --source env --env excite/DiffDriveCalibIdeal-v0 --logs 200
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

from excite.calibration import calibrate
from excite.models import SENSOR_POSE, SensorPose
from excite.noise import ChainWhitener, NoiseLevels
from excite.registration import SENSOR_MOUNTING
from excite.solver import Problem, normal_system
from excite.synthetic import synthetic_log
from excite.timeseries import TimeSeries, segment_timeseries

SENSOR = SensorPose(0.1, -0.03, 0.4)
CHI2_6_95 = 12.5916
NAMES = ("r_L", "r_R", "b", "l_x", "l_y", "l_theta")


def synthetic_source(args: argparse.Namespace, i: int
                     ) -> tuple[TimeSeries, np.ndarray, tuple[float, float] | None]:
    """A synthetic log: its series, the truth (6,) and the pose noise when it is the only
    noise (else None)."""
    log = synthetic_log(np.random.default_rng(args.seed + i), args.duration,
                        sensor_pose=SENSOR, pose_noise=(args.pose_noise, args.pose_noise),
                        slip=args.slip)
    only_pose = (args.pose_noise, args.pose_noise) if args.slip == 0 else None
    return log.series, np.append(log.params.as_array(), SENSOR.as_array()), only_pose


def env_source(args: argparse.Namespace, i: int
               ) -> tuple[TimeSeries, np.ndarray, tuple[float, float] | None]:
    """A log of the simulator driven by the arcs protocol at args.speed."""
    from agents.compare import make_env, run_protocol_episode
    from agents.protocols import Arcs

    env = make_env(args.env, int(args.duration), record=True, sensor_pose=SENSOR_MOUNTING)
    run_protocol_episode(env, Arcs(speed=args.speed), args.seed + i)
    base = env.unwrapped
    truth = np.append(base.true_params.as_array(), base.true_sensor_pose.as_array())
    sigma = base.recording.sigma
    only_pose = (float(sigma[0]), float(sigma[2])) if base.sim.config.ideal else None
    return base.recording.series, truth, only_pose


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=("synthetic", "env"), default="synthetic")
    parser.add_argument("--logs", type=int, default=200)
    parser.add_argument("--duration", type=float, default=120.0, help="s per log")
    parser.add_argument("--pose-noise", type=float, default=0.002, help="m and rad (synthetic)")
    parser.add_argument("--slip", type=float, default=0.0,
                        help="rad / sqrt(s) per wheel (synthetic)")
    parser.add_argument("--env", default="excite/DiffDriveCalibSensor-v0", help="(env)")
    parser.add_argument("--speed", type=float, default=0.2,
                        help="arcs speed, fraction of the motor limit (env)")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    source = synthetic_source if args.source == "synthetic" else env_source
    errors, distances, bounds, reported, covariances = [], [], [], [], []
    for i in tqdm(range(args.logs), desc="logs"):
        series, truth, only_pose = source(args, i)
        segments = segment_timeseries(series).segments
        result = calibrate(segments, sensor_pose="estimate")
        error = np.append(result.params.as_array(), result.sensor_pose.as_array()) - truth
        error[5] = (error[5] + np.pi) % (2 * np.pi) - np.pi
        errors.append(error)
        distances.append(error @ np.linalg.solve(result.full_covariance, error))
        reported.append(np.diag(result.full_covariance))
        covariances.append(result.full_covariance)
        if only_pose is not None:
            levels = NoiseLevels(np.full(3, 1e-9), np.array(only_pose))
            ev = Problem(SENSOR_POSE, segments, ChainWhitener(segments, levels)).evaluate(truth)
            info = normal_system(ev, np.ones(3), "linear").information
            bounds.append(np.linalg.inv(info) * np.outer(ev.scale, ev.scale))
    errors, distances = np.array(errors), np.array(distances)
    rmse = np.sqrt(np.mean(errors**2, axis=0))
    what = (f"{args.env}, arcs at {args.speed:g}" if args.source == "env" else
            f"synthetic, pose noise {args.pose_noise:g}, slip {args.slip:g}")
    print(f"{args.logs} logs of {args.duration:g} s ({what})")
    print(f"truth inside the 95% ellipse (6 parameters): {np.mean(distances < CHI2_6_95):.3f}")
    print("RMSE", " ".join(f"{n} {v:.3g}" for n, v in zip(NAMES, rmse, strict=True)))
    print("RMSE / mean reported std", " ".join(
        f"{n} {v:.3f}" for n, v in zip(NAMES, rmse / np.sqrt(np.mean(reported, axis=0)),
                                        strict=True)))
    if args.source == "synthetic":  # one robot: pairs of independent logs must agree
        a, b = slice(0, args.logs - 1, 2), slice(1, args.logs, 2)
        diff = errors[a] - errors[b]
        diff[:, 5] = (diff[:, 5] + np.pi) % (2 * np.pi) - np.pi
        pair_cov = np.array(covariances[a]) + np.array(covariances[b])
        q = np.einsum("ki,ki->k", diff, np.linalg.solve(pair_cov, diff[:, :, None])[:, :, 0])
        inside = float(np.mean(q < CHI2_6_95))
        print(f"pairs of logs whose difference is inside the 95% bound: {inside:.3f} of {q.size}")
    if bounds:
        ratio = rmse / np.sqrt(np.diag(np.mean(bounds, axis=0)))
        print("RMSE / CRLB", " ".join(f"{n} {v:.3f}" for n, v in zip(NAMES, ratio,
                                                                      strict=True)))


if __name__ == "__main__":
    main()
