"""Record a simulated run as a time-series log: the encoder and pose streams a real robot would
log, with the truth beside them. Knows nothing of reinforcement learning.

Clock: the recording clock reads ``START_TIME_NS`` at the start of the run and advances with
the physics. Every sample time is a whole number of nanoseconds, given in s as ns * 1e-9 (how
a ROS header stamp reads back), so the log written to a bag reads back with the same times.

Encoders: the quantizing encoders' counts (`WheelEncoders.count`) at every physics tick, as
cumulative wheel angles count * resolution (rad, whole ticks).

Poses: the external sensor's world pose, i.e. the body pose (x, y, theta of the axle midpoint
in the world frame; m, m, rad, theta continuous) composed with the sensor's mounting in the
body frame, sampled at ``pose_hz`` on the same clock, each sample with independent Gaussian
noise. Both drives move the body with a constant twist within a physics tick (an exact arc),
so a sample between two ticks lies on that arc: it is interpolated along the SE(2) geodesic
between the two tick poses (exact for the ideal drive, and for pymunk away from walls).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from envs.sensors import RelativePoseSensor, WheelEncoders
from excite.core import se2
from excite.core.kinematics import sinc_family
from excite.logs.timeseries import TimeSeries

__all__ = ["START_TIME_NS", "RecordingConfig", "Recording", "Recorder", "along_arc"]

FloatArray = NDArray[np.float64]

#: ns, the recording clock at the start of a run: 1 s, since a ROS header stamp of zero means
#: "not set".
START_TIME_NS = 1_000_000_000
#: A sample position (in ticks or samples) this close to a whole number is on it: absorbs the
#: float rounding of rate ratios.
_SNAP = 1e-9


@dataclass(frozen=True)
class RecordingConfig:
    """What to record; no defaults here (the environment's keys ``record_*`` hold them,
    :mod:`envs.config`).

    Attributes:
        pose_hz: rate of the pose stream (Hz).
        sigma_xy: standard deviation of the x and y noise of each pose sample (m).
        sigma_theta: standard deviation of the heading noise of each pose sample (rad).
    """

    pose_hz: float
    sigma_xy: float
    sigma_theta: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pose_hz) and self.pose_hz > 0):
            raise ValueError(f"pose_hz must be finite and > 0, got {self.pose_hz}")
        RelativePoseSensor(self.sigma_xy, self.sigma_theta)  # validates the noise levels


@dataclass(frozen=True, eq=False)
class Recording:
    """One recorded run and its truth.

    Attributes:
        series: the log as the sensors stream it: encoder angles (rad, whole ticks) at every
            physics tick and noisy sensor world poses at ``pose_hz`` (times in s, one clock).
        ticks_per_rev: encoder resolution; the angles are whole multiples of
            2 pi / ticks_per_rev.
        sensor_pose: (3,) the sensor's mounting in the body frame (x, y in m, theta in rad).
        sigma: (3,) standard deviations of the pose noise (m, m, rad).
        true_poses: (M, 3) the sensor's true world poses at ``series.t_pose``.
        true_wheel_angles: (N, 2) the unquantized wheel angles (rad) at ``series.t_enc``.
    """

    series: TimeSeries
    ticks_per_rev: int
    sensor_pose: FloatArray
    sigma: FloatArray
    true_poses: FloatArray
    true_wheel_angles: FloatArray


def along_arc(start: ArrayLike, end: ArrayLike, fraction: ArrayLike) -> FloatArray:
    """Poses (m, 3) a ``fraction`` (m,) of the way from ``start`` to ``end`` (m, 3) along the
    constant-twist motion between them (the SE(2) geodesic); fraction 0 gives ``start``
    exactly. Poses are (x, y, theta), theta continuous; the heading change must stay under
    2 pi."""
    start = np.asarray(start, dtype=float)
    u = np.asarray(fraction, dtype=float)
    d = se2.between(start, end)
    # The twist over the whole motion: (dx, dy) = M(dtheta) v with M = [[sinc, -cosc],
    # [cosc, sinc]], so v = M^-1 (dx, dy).
    f, g = sinc_family(d[:, 2], derivatives=False)
    norm = f * f + g * g
    vx, vy = (f * d[:, 0] + g * d[:, 1]) / norm, (f * d[:, 1] - g * d[:, 0]) / norm
    fu, gu = sinc_family(u * d[:, 2], derivatives=False)
    step = np.column_stack([u * (fu * vx - gu * vy), u * (gu * vx + fu * vy), u * d[:, 2]])
    return se2.compose(start, step)


class Recorder:
    """Accumulates the `Recording` of one run, segment by segment.

    Create it at the start of the run (the body pose and wheel angles there), then `add` the
    per-tick body poses and wheel angles of each segment (`SegmentOutcome.path`,
    `SegmentOutcome.wheel_path`), in order. The pose noise is drawn from ``rng`` alone.
    """

    def __init__(self, config: RecordingConfig, encoders: WheelEncoders, physics_hz: float,
                 sensor_pose: ArrayLike, rng: np.random.Generator, pose: ArrayLike,
                 wheel_angles: ArrayLike) -> None:
        self.config = config
        self.encoders = encoders
        self.physics_hz = float(physics_hz)
        self.sensor_pose = np.array(sensor_pose, dtype=float)
        self._sensor = RelativePoseSensor(config.sigma_xy, config.sigma_theta)
        self._rng = rng
        self._ticks = 0  # physics ticks recorded after the start
        self._wheels: list[FloatArray] = []
        self._pose_index: list[NDArray[np.int64]] = []  # pose sample numbers j
        self._true_poses: list[FloatArray] = []
        self._poses: list[FloatArray] = []
        start = np.asarray(pose, dtype=float)[None, :]
        self.add(start, np.asarray(wheel_angles, dtype=float)[None, :])

    def add(self, path: ArrayLike, wheel_path: ArrayLike) -> None:
        """Record a segment: body world poses (n + 1, 3) and absolute wheel angles (n + 1, 2)
        (rad) at its n + 1 physics ticks, the first being the end of the previous segment
        (at the start of the run: one row, the start itself)."""
        path = np.asarray(path, dtype=float)
        wheels = np.asarray(wheel_path, dtype=float)
        first = self._ticks  # the tick of path[0]
        self._wheels.append(wheels[1:] if self._wheels else wheels)
        self._ticks = first + len(path) - 1
        j_first = int(self._pose_index[-1][-1]) + 1 if self._pose_index else 0
        j_last = math.floor(self._ticks * self.config.pose_hz / self.physics_hz + _SNAP)
        j = np.arange(j_first, j_last + 1, dtype=np.int64)
        if not j.size:
            return
        position = j * self.physics_hz / self.config.pose_hz - first  # ticks after path[0]
        tick = np.minimum(np.floor(position + _SNAP), len(path) - 1).astype(np.int64)
        fraction = np.maximum(position - tick, 0.0)
        body = along_arc(path[tick], path[np.minimum(tick + 1, len(path) - 1)], fraction)
        truth = se2.compose(body, self.sensor_pose)
        self._pose_index.append(j)
        self._true_poses.append(truth)
        self._poses.append(self._sensor.absolute(truth, self._rng))

    def recording(self) -> Recording:
        """The run so far as a `Recording` (RuntimeError before the first segment)."""
        if not self._ticks:
            raise RuntimeError("nothing recorded yet: run a segment first")
        wheels = np.concatenate(self._wheels)
        angles = self.encoders.count(wheels) * self.encoders.resolution
        poses = np.concatenate(self._poses)
        tick_ns = np.rint(np.arange(len(wheels)) * (1e9 / self.physics_hz)).astype(np.int64)
        pose_ns = np.rint(np.concatenate(self._pose_index) * (1e9 / self.config.pose_hz)
                          ).astype(np.int64)
        series = TimeSeries((START_TIME_NS + tick_ns) * 1e-9, angles[:, 0], angles[:, 1],
                            (START_TIME_NS + pose_ns) * 1e-9, *poses.T,
                            source=("simulated encoders", "simulated poses"))
        return Recording(series, self.encoders.ticks_per_rev, self.sensor_pose.copy(),
                         self._sensor.sigma, np.concatenate(self._true_poses), wheels)
