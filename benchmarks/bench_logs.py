"""Calibration from time-series logs, by Monte Carlo over synthetic logs (excite.synthetic:
smooth random curves, an off-axle sensor, 50 Hz pose samples with noise, optional slip):
coverage of the 95% ellipse of the six estimated parameters and RMSE / CRLB per parameter
(the bound: the segment data's Fisher information at the truth under the true noise model,
available when the only noise is on the pose samples).

    python benchmarks/bench_logs.py --logs 200 --slip 0
    python benchmarks/bench_logs.py --logs 200 --slip 0.01
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

from excite.calibration import calibrate
from excite.models import SENSOR_POSE, SensorPose
from excite.noise import ChainWhitener, NoiseLevels
from excite.solver import Problem, normal_system
from excite.synthetic import synthetic_log
from excite.timeseries import segment_timeseries

SENSOR = SensorPose(0.1, -0.03, 0.4)
CHI2_6_95 = 12.5916


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=200)
    parser.add_argument("--duration", type=float, default=120.0, help="s per log")
    parser.add_argument("--pose-noise", type=float, default=0.002, help="m and rad")
    parser.add_argument("--slip", type=float, default=0.0, help="rad / sqrt(s) per wheel")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    errors, distances, bounds = [], [], []
    for i in tqdm(range(args.logs), desc="logs"):
        log = synthetic_log(np.random.default_rng(args.seed + i), args.duration,
                            sensor_pose=SENSOR, pose_noise=(args.pose_noise, args.pose_noise),
                            slip=args.slip)
        segments = segment_timeseries(log.series).segments
        result = calibrate(segments, sensor_pose="estimate")
        truth = np.append(log.params.as_array(), SENSOR.as_array())
        error = np.append(result.params.as_array(), result.sensor_pose.as_array()) - truth
        error[5] = (error[5] + np.pi) % (2 * np.pi) - np.pi
        errors.append(error)
        distances.append(error @ np.linalg.solve(result.full_covariance, error))
        if args.slip == 0:
            levels = NoiseLevels(np.full(3, 1e-9), np.array([args.pose_noise] * 2))
            ev = Problem(SENSOR_POSE, segments, ChainWhitener(segments, levels)).evaluate(truth)
            info = normal_system(ev, np.ones(3), "linear").information
            bounds.append(np.linalg.inv(info) * np.outer(ev.scale, ev.scale))
    errors, distances = np.array(errors), np.array(distances)
    rmse = np.sqrt(np.mean(errors**2, axis=0))
    print(f"{args.logs} logs of {args.duration:g} s, pose noise {args.pose_noise:g}, "
          f"slip {args.slip:g}")
    print(f"truth inside the 95% ellipse (6 parameters): {np.mean(distances < CHI2_6_95):.3f}")
    print("RMSE (r_L, r_R, b, l_x, l_y, l_theta):", " ".join(f"{v:.3g}" for v in rmse))
    if bounds:
        ratio = rmse / np.sqrt(np.diag(np.mean(bounds, axis=0)))
        print("RMSE / CRLB:", " ".join(f"{v:.3f}" for v in ratio))


if __name__ == "__main__":
    main()
