"""A log format of your own: turn it into excite's time-series log, then calibrate.

excite reads segment CSVs, Censi tuple files, time-series CSVs and ROS bags (docs/formats.md).
Any other recording becomes an ``excite.logs.timeseries.TimeSeries`` (the two streams: encoder
times and cumulative wheel angles; pose times and the external sensor's world poses, in the
units and frames of docs/conventions.md) and from there goes through the same
synchronisation, segmentation, checks and calibration as a time-series CSV. The same reader,
added to ``excite.logs.inputs`` (the one place that turns input paths into logs),
would make the format an input of ``excite calibrate``, ``segment`` and ``validate``.

The format here is JSON lines, one message per line, as a robot's own logger might write::

    {"stamp": 1.00, "kind": "wheels", "left": 2878, "right": 2255}
    {"stamp": 1.00, "kind": "pose", "x": 0.912, "y": 0.632, "yaw": 0.900}

(wheel counts in ticks of 4096 per revolution, poses in m and rad). Run this file to write such
a log of a synthetic robot, read it back and calibrate it:
``python examples/custom_input_format.py [FILE.jsonl]``.
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from excite import CalibrationResult, SensorPose, calibrate
from excite.logs.segmentation import segment_timeseries
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries import TimeSeries

TICKS_PER_REV = 4096


def read_jsonl(path: str | Path) -> TimeSeries:
    """The two streams of a JSON-lines log, wheel ticks converted to radians."""
    wheels, poses = [], []
    for line in Path(path).read_text().splitlines():
        if not line.strip():
            continue
        message = json.loads(line)
        if message["kind"] == "wheels":
            wheels.append((message["stamp"], message["left"], message["right"]))
        elif message["kind"] == "pose":
            poses.append((message["stamp"], message["x"], message["y"], message["yaw"]))
    enc, pose = np.array(wheels, dtype=float), np.array(poses, dtype=float)
    tick = 2 * math.pi / TICKS_PER_REV
    # TimeSeries checks both streams (times strictly increasing, finite values, >= 2
    # samples) and names the source in its errors.
    return TimeSeries(enc[:, 0], enc[:, 1] * tick, enc[:, 2] * tick,
                      pose[:, 0], pose[:, 1], pose[:, 2], pose[:, 3],
                      source=(f"{path} (wheels)", f"{path} (poses)"))


def calibrate_jsonl(path: str | Path) -> CalibrationResult:
    """Cut the log into 1 s segments and calibrate them (as ``excite calibrate`` does)."""
    cut = segment_timeseries(read_jsonl(path), window=1.0)
    print(f"{path}: {cut.report.n_segments} segments; dropped: {cut.report.counts_text()}")
    return calibrate(cut.segments, ticks_per_rev=TICKS_PER_REV)


def write_example(path: str | Path, seed: int = 0) -> None:
    """A synthetic robot's one-minute log in the JSON-lines format (a pose sensor 10 cm ahead
    of the axle, turned by 0.5 rad, with 2 mm / 2 mrad of noise), with its truth printed."""
    log = synthetic_log(np.random.default_rng(seed), duration=60.0,
                        sensor_pose=SensorPose(0.10, -0.03, 0.5), pose_noise=(2e-3, 2e-3),
                        ticks_per_rev=TICKS_PER_REV)
    s = log.series
    tick = 2 * math.pi / TICKS_PER_REV
    lines = [json.dumps({"stamp": t, "kind": "wheels", "left": round(left / tick),
                         "right": round(right / tick)})
             for t, left, right in zip(s.t_enc, s.phi_L, s.phi_R, strict=True)]
    lines += [json.dumps({"stamp": t, "kind": "pose", "x": x, "y": y, "yaw": yaw})
              for t, x, y, yaw in zip(s.t_pose, s.x, s.y, s.theta, strict=True)]
    Path(path).write_text("\n".join(lines) + "\n")
    print(f"truth: {log.params}, sensor at {log.sensor_pose}")


def main(path: str) -> int:
    write_example(path)
    result = calibrate_jsonl(path)
    print(result.summary())
    return 0 if result.fit.ok and result.identifiable else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1
                  else str(Path(tempfile.mkdtemp()) / "log.jsonl")))
