"""The model choice of ``sensor_pose="auto"`` on few segments (noise levels estimated).

Independent segments of the lesson's kind (wheel increments ~ N(0, 2^2) rad, noise 2 mm /
2 mm / 1 mrad, truth (0.050, 0.051, 0.300) m), N segments per data set:

1. on the axle: how often ``auto`` chooses the sensor-pose model (the test's level is 0.1%);
2. with the sensor (0.02 m, 0.01 m, 0.02 rad) off the axle: how often it does (its power);
   and in both, how often the calibration ends as usable (determined, fit ok) with a
   parameter more than 4 of its std from the truth.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_model_choice.py [--runs 2000]
"""

from __future__ import annotations

import argparse

import numpy as np

from excite import Segments, calibrate
from excite.core.models import SENSOR_POSE
from excite.logs.synthetic import LESSON_TRUTH, lesson_dataset

OFF_AXLE = (0.02, 0.01, 0.02)
SIGMA = np.array([2e-3, 2e-3, 1e-3])


def off_axle(rng: np.random.Generator, n: int) -> Segments:
    phi_l, phi_r = rng.normal(0.0, 2.0, (2, n))
    measured = SENSOR_POSE.predict(phi_l, phi_r, np.append(LESSON_TRUTH.as_array(), OFF_AXLE))
    return Segments(phi_l, phi_r, *(measured + rng.normal(size=measured.shape) * SIGMA).T)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2000, help="data sets per row")
    args = parser.parse_args()
    truth = LESSON_TRUTH.as_array()
    for name, make in (("axle", lambda rng, n: lesson_dataset(rng, n, dphi_std=2.0)),
                       ("off axle", off_axle)):
        for n in (7, 8, 10, 12, 16, 24):
            chosen = wrong = 0
            for run in range(args.runs):
                result = calibrate(make(np.random.default_rng([n, run, 9]), n))
                chosen += result.model == "sensor_pose"
                z = np.abs(result.params.as_array() - truth) / result.std
                wrong += bool(result.identifiable and result.fit.ok and np.max(z) > 4)
            print(f"{name}, {n} segments: sensor pose chosen {chosen}/{args.runs}; usable "
                  f"and > 4 std off {wrong}/{args.runs}", flush=True)


if __name__ == "__main__":
    main()
