"""Synthetic data for demos, tests and benchmarks: segment datasets of the lesson's kind and
time-series logs of a robot driving smooth curves (numpy only, exact kinematics)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.core.information import DEFAULT_SIGMA, as_sigma
from excite.core.kinematics import Arc, Params, predict_increment
from excite.core.models import SensorPose
from excite.logs.segments import Segments
from excite.logs.timeseries import TimeSeries, tick_angle

__all__ = ["LESSON_TRUTH", "lesson_dataset", "SyntheticLog", "synthetic_log", "scrubbed_increment"]

#: The robot of the lesson's synthetic example (m).
LESSON_TRUTH = Params(0.050, 0.051, 0.300)


def scrubbed_increment(dphi_L: ArrayLike, dphi_R: ArrayLike, params: Params, scrub: float
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The body-frame increment (dx [m], dy [m], dtheta [rad]) of a robot whose effective
    track grows with the turn: b (1 + scrub min(kappa b / 2, 1)), kappa b = 2 |s_R - s_L| /
    |s_R + s_L| from the wheels' travel s = r dphi (b at straight runs, b (1 + scrub) at
    spins and turns tighter than half the track: wheels that scrub in turns). scrub = 0 is
    :func:`~excite.core.kinematics.predict_increment`."""
    phi_L, phi_R = np.asarray(dphi_L, dtype=float), np.asarray(dphi_R, dtype=float)
    left, right = params.r_L * phi_L, params.r_R * phi_R
    travel = np.abs(right + left)
    with np.errstate(divide="ignore", invalid="ignore"):
        turn = np.where(travel > 0, 2.0 * np.abs(right - left) / np.where(travel > 0, travel,
                                                                           1.0), np.inf)
    track = params.b * (1.0 + scrub * np.minimum(turn / 2.0, 1.0))
    arc = Arc(phi_L, phi_R, params.r_L, params.r_R, track, derivatives=False)
    return arc.dx, arc.dy, arc.dtheta


def lesson_dataset(
    rng: np.random.Generator,
    n: int = 200,
    params: Params = LESSON_TRUTH,
    sigma: ArrayLike = DEFAULT_SIGMA,
    dphi_std: float = 0.4,
    *,
    scrub: float = 0.0,
) -> Segments:
    """The lesson's synthetic experiment: wheel increments ~ N(0, dphi_std^2) rad, exact
    kinematics at ``params``, plus Gaussian noise of std ``sigma`` = (sx [m], sy [m], sth [rad])
    on the measured increment. ``scrub``: the effective track grows with the turn
    (:func:`scrubbed_increment`; 0: constant)."""
    s = as_sigma(sigma)
    dphi_L = rng.normal(0.0, dphi_std, n)
    dphi_R = rng.normal(0.0, dphi_std, n)
    truth = np.column_stack(predict_increment(dphi_L, dphi_R, params) if not scrub
                            else scrubbed_increment(dphi_L, dphi_R, params, scrub))
    measured = truth + rng.normal(size=(n, 3)) * s
    return Segments(dphi_L, dphi_R, *measured.T)


@dataclass(frozen=True)
class SyntheticLog:
    """A synthetic time-series log and its truth: ``series`` (what a robot would record),
    ``params`` and ``sensor_pose`` (the hidden robot), ``t`` (s, the fine simulation grid on
    the encoder clock) and ``body`` (n, 3), the true body poses there (m, m, rad)."""

    series: TimeSeries
    params: Params
    sensor_pose: SensorPose
    t: NDArray[np.float64]
    body: NDArray[np.float64]


def _smooth_signal(rng: np.random.Generator, t: NDArray[np.float64], mean: float,
                   amplitude: float, periods: tuple[float, ...]) -> NDArray[np.float64]:
    """mean + amplitude * a sum of sinusoids with the given periods (s), random phases and
    weights, normalised to peak amplitude at most ``amplitude``."""
    weights = rng.uniform(0.5, 1.0, len(periods))
    weights /= weights.sum()
    phases = rng.uniform(0.0, 2.0 * np.pi, len(periods))
    wave = sum(w * np.sin(2.0 * np.pi * t / p + ph)
               for w, p, ph in zip(weights, periods, phases, strict=True))
    return mean + amplitude * wave


def _pose_noise(rng: np.random.Generator, t: NDArray[np.float64],
                correlation_time: float) -> NDArray[np.float64]:
    """Unit-variance noise (len(t), 3) at times ``t`` (s): white, or first-order Gauss-Markov
    with ``correlation_time`` (s) when it is > 0 (stationary from the first sample)."""
    white = rng.normal(size=(len(t), 3))
    if correlation_time <= 0.0:
        return white
    a = np.exp(-np.diff(t) / correlation_time)
    gain = np.sqrt(1.0 - a**2)
    noise = np.empty_like(white)
    noise[0] = white[0]
    for k in range(1, len(t)):
        noise[k] = a[k - 1] * noise[k - 1] + gain[k - 1] * white[k]
    return noise


def _read_times(rng: np.random.Generator, t: NDArray[np.float64], samples: slice, jitter: float
                ) -> NDArray[np.float64]:
    """The times (s) at which the samples ``samples`` of the grid ``t`` are taken when each
    errs from its stamp by an independent Gaussian time error of std ``jitter`` (s), kept
    within the grid."""
    stamps = t[samples]
    return np.clip(stamps + jitter * rng.normal(size=stamps.size), t[0], t[-1])


def synthetic_log(
    rng: np.random.Generator,
    duration: float = 60.0,
    params: Params = LESSON_TRUTH,
    sensor_pose: SensorPose | None = None,
    *,
    encoder_rate: float = 100.0,
    pose_rate: float = 50.0,
    pose_noise: tuple[float, float] = (0.0, 0.0),
    slip: float = 0.0,
    speed: float = 0.25,
    turn_rate: float = 1.0,
    ticks_per_rev: float | None = None,
    pose_noise_time: float = 0.0,
    encoder_jitter: float = 0.0,
    pose_jitter: float = 0.0,
    step: float = 1e-3,
    scrub: float = 0.0,
) -> SyntheticLog:
    """A robot driving smooth random curves (exact arcs on a fine grid of ``step`` s), recorded
    as a time-series log.

    Forward speed varies within speed * (0.4 .. 1.6) m/s and the turn rate within
    +-``turn_rate`` rad/s (random sinusoids of periods 3-11 s). Encoders: cumulative wheel
    angles at ``encoder_rate`` Hz (rad; floored to whole ticks when ``ticks_per_rev`` is
    given). Poses: the sensor's world pose at ``pose_rate`` Hz, each sample with Gaussian
    noise of std ``pose_noise`` = (sigma_xy [m], sigma_theta [rad]), independent between
    samples, or with ``pose_noise_time`` > 0 (s) correlated in time (first-order Gauss-Markov:
    correlation exp(-|dt| / pose_noise_time) between samples dt apart, like a scan matcher's
    or a visual odometry's slowly wandering error). ``slip``
    (rad / sqrt(s)): the wheels' ground contact differs from the encoders by a random walk of
    this intensity per wheel (independent noise on every segment's increments).
    ``encoder_jitter`` (s): each encoder sample is read at its stamp plus an independent
    Gaussian time error of this std (both wheels at once; a controller's or a serial link's
    timing), before its rounding. ``pose_jitter`` (s): each pose sample is taken at its stamp
    plus an independent Gaussian time error of this std (a motion-capture or network stamp),
    before its noise. ``scrub``: the effective track grows with the turn of each step of the
    grid (:func:`scrubbed_increment`; 0: constant). Rates should divide 1 / step so that
    samples fall on the grid.
    """
    from excite.core import se2
    pose = sensor_pose if sensor_pose is not None else SensorPose(0.0, 0.0, 0.0)
    n = int(round(duration / step))
    t = step * np.arange(n + 1)
    mid = t[:-1] + 0.5 * step
    v = _smooth_signal(rng, mid, speed, 0.6 * speed, (7.3, 11.0, 4.1))
    w = _smooth_signal(rng, mid, 0.0, turn_rate, (5.1, 2.9, 8.7))
    rate_L = (v - 0.5 * params.b * w) / params.r_L
    rate_R = (v + 0.5 * params.b * w) / params.r_R
    enc_L, enc_R = rate_L * step, rate_R * step
    ground_L = enc_L + slip * np.sqrt(step) * rng.normal(size=n)
    ground_R = enc_R + slip * np.sqrt(step) * rng.normal(size=n)
    start = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
    moves = (predict_increment(ground_L, ground_R, params) if not scrub
             else scrubbed_increment(ground_L, ground_R, params, scrub))
    body = se2.compose(start, se2.accumulate(*moves))
    phi_L = rng.uniform(-10, 10) + np.concatenate(([0.0], np.cumsum(enc_L)))
    phi_R = rng.uniform(-10, 10) + np.concatenate(([0.0], np.cumsum(enc_R)))
    e = slice(0, None, max(1, int(round(1.0 / (encoder_rate * step)))))
    p = slice(0, None, max(1, int(round(1.0 / (pose_rate * step)))))
    taken = body[p]
    if pose_jitter > 0:
        read = _read_times(rng, t, p, pose_jitter)
        taken = np.stack([np.interp(read, t, column) for column in body.T], axis=1)
    sensor = se2.compose(taken, pose.as_array())
    sensor += _pose_noise(rng, t[p], pose_noise_time) * np.array([pose_noise[0], pose_noise[0],
                                                                 pose_noise[1]])
    read_L, read_R = phi_L[e], phi_R[e]
    if encoder_jitter > 0:
        read = _read_times(rng, t, e, encoder_jitter)
        read_L, read_R = np.interp(read, t, phi_L), np.interp(read, t, phi_R)
    if ticks_per_rev is not None:
        tick = tick_angle(ticks_per_rev)
        read_L, read_R = np.floor(read_L / tick) * tick, np.floor(read_R / tick) * tick
    series = TimeSeries(t[e], read_L, read_R, t[p], *sensor.T,
                        source=("synthetic encoders", "synthetic poses"))
    return SyntheticLog(series, params, pose, t, body)
