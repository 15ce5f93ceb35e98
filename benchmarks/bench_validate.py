"""Does the calibration help on a log it did not see? For robots drawn from the simulator's
default spread (+-5% wheel radii and separation, a hidden off-axle sensor, slip env), one
episode per robot: the first half (arcs, gently) is the calibration log, the second half (a
different protocol at the same gentle speed) the held-out log. The held-out log is
dead-reckoned with the nominal and with the calibrated robot (``excite validate``'s
computation; the nominal robot uses the calibrated sensor pose, as the command does by
default), and their end-point errors compared.

    python benchmarks/bench_validate.py --robots 100
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

from agents.compare import make_env
from agents.protocols import Arcs, StraightSpin, UMBmark
from excite.calibration.pipeline import calibrate
from excite.logs.segmentation import segment_timeseries
from excite.logs.timeseries import TimeSeries
from excite.registration import SENSOR_MOUNTING
from excite.validation.dead_reckoning import summarize, validate_log

HELD_OUT = {"umbmark": UMBmark, "straight_spin": StraightSpin}


def split(series: TimeSeries, at: float) -> tuple[TimeSeries, TimeSeries]:
    """The series before and after time ``at`` (s)."""
    def part(enc: np.ndarray, pose: np.ndarray) -> TimeSeries:
        return TimeSeries(series.t_enc[enc], series.phi_L[enc], series.phi_R[enc],
                          series.t_pose[pose], series.x[pose], series.y[pose],
                          series.theta[pose], series.source)
    return (part(series.t_enc <= at, series.t_pose <= at),
            part(series.t_enc >= at, series.t_pose >= at))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--segments", type=int, default=120, help="per half (1 s each)")
    parser.add_argument("--speed", type=float, default=0.1, help="arcs speed (calibration)")
    parser.add_argument("--held-out", choices=sorted(HELD_OUT), default="umbmark")
    parser.add_argument("--env", default="excite/DiffDriveCalibSensor-v0")
    parser.add_argument("--seed", type=int, default=5000)
    args = parser.parse_args()
    validations = []
    for i in tqdm(range(args.robots), desc="robots"):
        env = make_env(args.env, 2 * args.segments, record=True, sensor_pose=SENSOR_MOUNTING)
        seed = args.seed + i
        env.reset(seed=seed)
        base = env.unwrapped
        held_out = HELD_OUT[args.held_out](speed=args.speed)
        for k, protocol in enumerate((Arcs(speed=args.speed), held_out)):
            protocol.reset(np.random.default_rng([seed, k]))
            for _ in range(args.segments):
                env.step(protocol.act(base.knowledge()))
        series = base.recording.series
        middle = float(series.t_pose[0] + args.segments * base.segment_duration)
        calibration_log, validation_log = split(series, middle)
        result = calibrate(segment_timeseries(calibration_log).segments,
                           sensor_pose="estimate")
        validations.append(validate_log(
            validation_log, 0.0, (result.params, result.sensor_pose),
            (base.knowledge().nominal, result.sensor_pose), name=f"robot {i}"))
    overall = summarize(validations)
    ratios = np.array([v.ratio["end_position_error"] for v in validations], dtype=float)
    print(f"{args.robots} robots ({args.env}); calibration: arcs at {args.speed:g}, "
          f"{args.segments} s; held out: {args.held_out}, {args.segments} s")
    print(f"end-point error, mean over logs: nominal {overall.nominal.end_position_error:.4g} m,"
          f" calibrated {overall.calibrated.end_position_error:.4g} m, ratio "
          f"{overall.ratio['end_position_error']:.3f}")
    print(f"per log ratio calibrated / nominal: median {np.nanmedian(ratios):.3f}, "
          f"90th percentile {np.nanpercentile(ratios, 90):.3f}, "
          f"<= 0.3 in {np.mean(ratios <= 0.3):.2f} of the logs")


if __name__ == "__main__":
    main()
