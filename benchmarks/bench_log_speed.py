"""Speed of the default ``calibrate`` (issue 26's rows), side by side with another checkout of
excite (ratios, since absolute times drift on a shared machine).

1. A 1-hour 100 Hz log: ``excite.logs.synthetic.synthetic_log`` of 3600 s, encoders and poses
   at 100 Hz, pose noise 2 mm / 2 mrad, the sensor off the axle, with and without wheel slip
   (0.01 rad/sqrt(s)), cut into 1 s windows (3600 segments).
2. 100k segments of the lesson's kind: the default ``calibrate`` over the lesson's estimator
   (``benchmarks/lesson_baseline.py``) on the same data, the two alternating in one process
   (median of 9 each), so that the ratio is of one moment of the machine.

Each is timed in fresh subprocesses, alternating this tree and the baseline, ``--repeats``
times; the medians are printed.

    git archive OLD excite | tar -x -C /tmp/old
    python benchmarks/bench_log_speed.py --baseline /tmp/old
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
#: Run in a subprocess with the tree to time on sys.path: build the log, time calibrate.
CHILD = """
import sys, time
import numpy as np
import os
import excite
from excite.calibration import calibrate
# the layout of the tree on sys.path (an editable install would resolve missing modules
# from another tree): a checkout from before the subpackages has flat modules
if not os.path.exists(os.path.join(os.path.dirname(excite.__file__), "timeseries.py")):
    from excite.core.models import SensorPose
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log
else:
    from excite.models import SensorPose
    from excite.synthetic import synthetic_log
    from excite.timeseries import segment_timeseries

slip, mode = float(sys.argv[1]), sys.argv[2]
log = synthetic_log(np.random.default_rng(7), 3600.0, sensor_pose=SensorPose(0.1, -0.03, 0.4),
                    encoder_rate=100.0, pose_rate=100.0, pose_noise=(2e-3, 2e-3), slip=slip,
                    step=1e-2 / 4)
segments = segment_timeseries(log.series).segments
start = time.perf_counter()
result = calibrate(segments, sensor_pose=mode)
print(time.perf_counter() - start, len(segments))
"""


#: Run in a subprocess with the tree to time on sys.path: the lesson's estimator and the
#: default calibrate alternating on 100k lesson segments; prints both medians (s).
LESSON_CHILD = """
import sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from lesson_baseline import lesson_calibrate
from excite.calibration import calibrate
from excite.logs.synthetic import LESSON_TRUTH, lesson_dataset
seg = lesson_dataset(np.random.default_rng(1), 100_000, LESSON_TRUTH)
calibrate(seg)
lesson_calibrate(seg)
times = {"lesson": [], "excite": []}
for _ in range(9):
    for name, fn in (("lesson", lesson_calibrate), ("excite", calibrate)):
        start = time.perf_counter()
        fn(seg)
        times[name].append(time.perf_counter() - start)
print(np.median(times["lesson"]), np.median(times["excite"]))
"""


def lesson_ratio(tree: str) -> tuple[float, float]:
    """The lesson's and the default calibrate's median seconds on 100k segments, ``tree``."""
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-P", "-c", LESSON_CHILD, str(HERE / "benchmarks")],
                         env=env, check=True, capture_output=True, text=True).stdout.split()
    return float(out[0]), float(out[1])


def timed(tree: str, slip: float, mode: str) -> tuple[float, int]:
    env = dict(os.environ, PYTHONPATH=tree)
    # -P: not the working directory first on sys.path (from a checkout it would shadow tree)
    out = subprocess.run([sys.executable, "-P", "-c", CHILD, str(slip), mode], env=env,
                         check=True, capture_output=True, text=True).stdout.split()
    return float(out[0]), int(out[1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, help="directory holding the other excite/")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    for slip in (0.0, 0.01):
        for mode in ("estimate", "auto"):
            ours, theirs = [], []
            for _ in range(args.repeats):
                seconds, n = timed(str(HERE), slip, mode)
                ours.append(seconds)
                theirs.append(timed(args.baseline, slip, mode)[0])
            a, b = statistics.median(ours), statistics.median(theirs)
            print(f"slip {slip:g}, sensor_pose={mode}: {n} segments; this tree {a:.2f} s, "
                  f"baseline {b:.2f} s, ratio {a / b:.2f}", flush=True)
    ours, theirs = [], []
    for _ in range(args.repeats):
        ours.append(lesson_ratio(str(HERE)))
        theirs.append(lesson_ratio(args.baseline))
    for name, runs in (("this tree", ours), ("baseline", theirs)):
        ratios = [e / lesson for lesson, e in runs]
        print(f"100k lesson segments, default calibrate over the lesson's estimator, {name}: "
              f"{min(ratios):.2f}-{max(ratios):.2f} (calibrate "
              f"{statistics.median(e for _, e in runs):.3f} s, lesson "
              f"{statistics.median(lesson for lesson, _ in runs):.3f} s)", flush=True)


if __name__ == "__main__":
    main()
