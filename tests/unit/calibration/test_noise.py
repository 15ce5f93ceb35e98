"""Correlated noise of segments cut from a log (excite.calibration.noise): the banded covariance
against a
Monte Carlo of perturbed pose samples, the chi-bar-square quantile, and the test of "no segment
noise" in the REML noise levels (held at the floor without slip, found with slip), which is
what makes calibration from logs without slip as efficient as the GLS at the true levels."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from excite.calibration.noise import ChainWhitener, NoiseLevels, WheelNoise
from excite.calibration.pipeline import calibrate
from excite.calibration.reml import SEGMENT_NOISE_TEST_LEVEL
from excite.calibration.solver import Problem, levenberg_marquardt
from excite.core import se2
from excite.core.models import SENSOR_POSE, SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.segments import Segments
from excite.logs.synthetic import synthetic_log
from excite.stats.chi2 import chi2_quantile, chi_bar_square_quantile

SENSOR = SensorPose(0.1, -0.03, 0.4)


def increments(poses: np.ndarray) -> np.ndarray:
    """(..., N, 3) increments (-P_k) (+) P_(k+1) of chained world poses (..., N + 1, 3)."""
    return se2.between(poses[..., :-1, :], poses[..., 1:, :])


def test_whitener_covariance_is_the_covariance_of_perturbed_pose_samples():
    """C = L L^T of the whitener against the empirical covariance of the increments of pose
    samples with independent noise plus independent segment noise (noise small enough for the
    linearisation; 40000 draws: 2% sampling error on the variances)."""
    rng = np.random.default_rng(7)
    steps = np.array([[0.3, 0.02, 0.4], [0.25, -0.05, -0.7], [0.1, 0.0, 1.2], [0.4, 0.1, 0.1]])
    poses = se2.compose(np.array([0.5, -1.0, 0.3]), se2.accumulate(*steps.T))
    exact = increments(poses)
    levels = NoiseLevels(np.array([2e-4, 1e-4, 3e-4]), np.array([1e-4, 2e-4]))
    draws = 40_000
    noisy = poses + rng.normal(size=(draws, *poses.shape)) * np.array([1e-4, 1e-4, 2e-4])
    measured = increments(noisy) + rng.normal(size=(draws, *exact.shape)) * levels.sigma
    segments = Segments(np.ones(4), np.ones(4), *exact.T,
                        chained=np.array([False, True, True, True]))
    n = 3 * len(segments)
    inverse = ChainWhitener(segments, levels).whiten(
        np.zeros((3, 4)), np.eye(n).reshape(4, 3, n).transpose(1, 2, 0))[1]
    inverse = inverse.transpose(2, 0, 1).reshape(n, n)  # L^-1
    model = np.linalg.inv(inverse.T @ inverse)  # C = L L^T
    empirical = np.cov((measured - exact).reshape(draws, n), rowvar=False)
    scale = np.sqrt(np.diag(model))
    np.testing.assert_allclose(np.diag(empirical) / scale**2, 1.0, atol=0.04)
    np.testing.assert_allclose(empirical / np.outer(scale, scale),
                               model / np.outer(scale, scale), rtol=0, atol=0.03)
    # the shared samples matter: the lag-1 blocks are far from 0
    assert np.abs(model[3:6, 0:3] / np.outer(scale[3:6], scale[0:3])).max() > 0.2


def test_chi_bar_square_quantile():
    # one component: the mixture 0.5 chi2(0) + 0.5 chi2(1) has the chi2(1) tail halved
    assert chi_bar_square_quantile(0.95, 1) == pytest.approx(chi2_quantile(0.90, 1), rel=1e-9)
    # three: against a Monte Carlo of the mixture (a binomial number of chi2(1) terms)
    rng = np.random.default_rng(3)
    k = rng.binomial(3, 0.5, 400_000)
    draws = np.where(np.arange(3) < k[:, None], rng.normal(size=(k.size, 3)) ** 2, 0).sum(1)
    q = chi_bar_square_quantile(0.95, 3)
    assert np.mean(draws > q) == pytest.approx(0.05, abs=0.002)
    assert chi2_quantile(0.90, 1) < q < chi2_quantile(0.95, 3)


def log_segments(seed: int, slip: float) -> tuple[Segments, np.ndarray]:
    log = synthetic_log(np.random.default_rng(seed), 120.0, sensor_pose=SENSOR,
                        pose_noise=(2e-3, 2e-3), slip=slip)
    truth = np.append(log.params.as_array(), SENSOR.as_array())
    return segment_timeseries(log.series).segments, truth


@pytest.mark.slow
@pytest.mark.statistical
def test_no_segment_noise_is_found_on_logs_without_slip():
    """Pose noise only: the segment levels stay at their floor unless the test rejects (at
    most its level, 5%, of the logs; at 30 logs, more than 5 would be p < 0.01); the pose
    levels are unbiased (their mean over the logs within 5%: ~3 standard errors)."""
    found, pose = 0, []
    for seed in range(30):
        segments, _ = log_segments(seed, slip=0.0)
        result = calibrate(segments, sensor_pose="estimate")
        pose.append(result.pose_sigma)
        found += bool(np.any(result.sigma > 1e-6))
    assert SEGMENT_NOISE_TEST_LEVEL == 0.05 and found <= 5
    assert np.mean(pose, axis=0) == pytest.approx([2e-3, 2e-3], rel=0.05)


@pytest.mark.slow
@pytest.mark.statistical
def test_reml_recovers_a_known_slip_level():
    """Random-walk wheel slip of 0.01 rad/sqrt(s) per wheel, with pose noise: the slip level
    estimated by REML through the wheels is within 25% of the truth in every log (its
    relative standard error over ~120 segments is ~7%), and the white segment levels are
    not needed (the nested test keeps them at the floor in most logs)."""
    white = 0
    for seed in range(5):
        segments, _ = log_segments(seed, slip=0.01)
        result = calibrate(segments, sensor_pose="estimate")
        assert result.slip == pytest.approx(0.01, rel=0.25)
        white += bool(np.any(result.sigma > 1e-6))
    assert white <= 2


@pytest.mark.slow
@pytest.mark.statistical
def test_slip_level_is_found_without_pose_noise():
    """Slip only (noise-free poses): the slip level within 15%, the white levels at the
    floor in at least 4 of 5 logs, and the pose levels (free, not tested) under 1e-4 (the
    slip moves a 1 s segment's end by ~5e-4 m)."""
    quiet = 0
    for seed in range(5):
        log = synthetic_log(np.random.default_rng(100 + seed), 120.0, sensor_pose=SENSOR,
                            slip=0.01)
        result = calibrate(segment_timeseries(log.series).segments, sensor_pose="estimate")
        assert result.slip == pytest.approx(0.01, rel=0.15)
        quiet += bool(np.all(result.sigma < 1e-6))
        assert np.all(result.pose_sigma < 1e-4)
    assert quiet >= 4


@pytest.mark.slow
@pytest.mark.statistical
def test_estimated_levels_are_as_efficient_as_the_true_levels():
    """On logs with pose noise only (the encoders' resolution given), the test of "no
    segment noise" keeps the segment levels at their floor in all but a few logs (at its 5%
    level: more than 3 of 20 has probability 1.6%), and on those logs the calibration with
    estimated noise levels has the squared errors of the GLS at the true levels (summed, within
    10%); with the unconstrained REML estimate (spurious segment levels everywhere) the ratios
    were 1.4-1.9 here. A log where the test rejects at 5% (seed 1010 here) loses efficiency:
    its spurious segment level outweighs the pose noise at low frequencies."""
    from agents.compare import make_env, run_protocol_episode
    from agents.protocols import Arcs
    from excite.registration import SENSOR_MOUNTING

    estimated, known, clean = [], [], []
    for seed in range(20):
        env = make_env("excite/DiffDriveCalibIdeal-v0", 120, record=True,
                       sensor_pose=SENSOR_MOUNTING)
        run_protocol_episode(env, Arcs(speed=0.2), 1000 + seed)
        base = env.unwrapped
        truth = np.append(base.true_params.as_array(), base.true_sensor_pose.as_array())
        scale = np.append(truth[:3], [truth[2], truth[2], 1.0])
        segments = segment_timeseries(base.recording.series).segments
        result = calibrate(segments, sensor_pose="estimate",
                           ticks_per_rev=base.recording.ticks_per_rev)
        clean.append(bool(np.all(result.sigma < 1e-6) and result.slip < 1e-6))
        theta = np.append(result.params.as_array(), result.sensor_pose.as_array())
        sigma = base.recording.sigma
        whitener = ChainWhitener(segments, NoiseLevels(np.full(3, 1e-9), sigma[[0, 2]]))
        fit = levenberg_marquardt(Problem(SENSOR_POSE, segments, whitener), theta,
                                  np.ones(3), "linear")
        estimated.append((theta - truth) / scale)
        known.append((fit.theta - truth) / scale)
    assert sum(clean) >= 17
    ratio = (np.sum(np.square(estimated)[clean], axis=0)
             / np.sum(np.square(known)[clean], axis=0))
    assert np.all(ratio[:3] < 1.1), ratio


# --------------------------------------------------------------------------- wheel-space noise


def dense_covariance(segments: Segments, levels: NoiseLevels, wheels: WheelNoise) -> np.ndarray:
    """C = L L^T (3N, 3N) of the whitener, segment-major."""
    n = 3 * len(segments)
    inverse = ChainWhitener(segments, levels, wheels).whiten(
        np.zeros((3, len(segments))), np.eye(n).reshape(len(segments), 3, n).transpose(1, 2, 0))[1]
    inverse = inverse.transpose(2, 0, 1).reshape(n, n)
    return np.linalg.inv(inverse.T @ inverse)


def chained_substeps(rng: np.random.Generator, n: int, k: int, sub: np.ndarray | None = None
                     ) -> tuple[Segments, np.ndarray, np.ndarray]:
    """n chained segments of k sub-steps of 0.05 s each (sub-increments ``sub`` (2, n, k),
    default ~ 0.3 +- 0.3 rad) at the sensor-pose model's truth; returns them, theta and the
    sub-increments."""
    theta = np.array([0.05, 0.051, 0.3, 0.1, -0.03, 0.4])
    if sub is None:
        sub = rng.normal(0.3, 0.3, (2, n, k))
    exact = SENSOR_POSE.evaluate(sub[0], sub[1], theta, jacobian=False, substeps=True)[0]
    t = 0.05 * k * np.arange(n + 1)
    segments = Segments(sub[0].sum(1), sub[1].sum(1), *exact, t_start=t[:-1], t_end=t[1:],
                        chained=np.arange(n) > 0, sub_dphi_L=sub[0], sub_dphi_R=sub[1])
    return segments, theta, sub


def test_slip_covariance_is_the_covariance_of_slipping_wheels():
    """Each wheel's sub-increments perturbed by a random walk in time (variance slip^2 dt):
    the increments' empirical covariance over 40000 draws equals k^2 sum_j dt G_j G_j^T of
    WheelNoise (linearised; slip small enough), within the sampling error."""
    rng = np.random.default_rng(11)
    segments, theta, sub = chained_substeps(rng, 3, 6)
    slip, draws = 0.002, 40_000
    noisy = sub + slip * np.sqrt(0.05) * rng.normal(size=(draws, *sub.shape))
    measured = SENSOR_POSE.evaluate(noisy[:, 0], noisy[:, 1], theta, jacobian=False,
                                    substeps=True)[0]  # (3, draws, n)
    exact = np.stack([segments.dx, segments.dy, segments.dtheta])
    deviation = (measured - exact[:, None, :]).transpose(1, 2, 0).reshape(draws, -1)
    wheels = WheelNoise.of(SENSOR_POSE, segments, theta, None)
    model = dense_covariance(segments, NoiseLevels(np.full(3, 1e-12), np.full(2, 1e-12), slip),
                             wheels)
    empirical = np.cov(deviation, rowvar=False)
    scale = np.sqrt(np.diag(model))
    np.testing.assert_allclose(empirical / np.outer(scale, scale),
                               model / np.outer(scale, scale), rtol=0, atol=0.03)
    # segments do not share slip
    assert np.abs(model[3:6, 0:3]).max() < 1e-6 * scale.max() ** 2


def test_slip_accrues_only_while_a_wheel_turns():
    """A 1 s segment of ten 0.1 s sub-steps that moves for 0.5 s and then stands still has
    the slip covariance of the same motion as a 0.5 s segment of five sub-steps (slip is a
    random walk in the time a wheel turns), though both are padded to ten sub-steps."""
    rng = np.random.default_rng(3)
    theta = np.array([0.05, 0.051, 0.3, 0.1, -0.03, 0.4])
    motion = rng.normal(0.3, 0.1, (2, 5))
    sub = np.zeros((2, 2, 10))
    sub[:, 0, :5] = sub[:, 1, :5] = motion
    exact = SENSOR_POSE.evaluate(sub[0], sub[1], theta, jacobian=False, substeps=True)[0]
    segments = Segments(sub[0].sum(1), sub[1].sum(1), *exact, t_start=np.array([0.0, 2.0]),
                        t_end=np.array([1.0, 2.5]), chained=np.array([False, False]),
                        sub_dphi_L=sub[0], sub_dphi_R=sub[1], sub_count=np.array([10, 5]))
    wheels = WheelNoise.of(SENSOR_POSE, segments, theta, None)
    np.testing.assert_allclose(wheels.slip[0], wheels.slip[1], rtol=1e-12, atol=0)
    assert np.all(np.diagonal(wheels.slip[0]) > 0)


def test_quantization_covariance_of_rounded_encoder_samples():
    """Independent rounding errors (uniform over one tick) on every encoder sample, the
    sub-steps' boundaries: the increments' empirical covariance equals the boundary terms
    (shared by chained segments) plus the inner samples' sum_j D_j D_j^T; WheelNoise's inner
    term is the bound for fully correlated errors, (K - 1) times that, so its covariance
    exceeds the empirical one (positive semidefinite difference)."""
    rng = np.random.default_rng(12)
    k, n = 6, 3
    segments, theta, sub = chained_substeps(rng, n, k)
    tick, draws = 2 * np.pi / 4096, 40_000
    samples = rng.uniform(-0.5, 0.5, (draws, 2, n * k + 1)) * tick  # one clock, all samples
    errors = np.diff(samples, axis=2).reshape(draws, 2, n, k)
    noisy = sub + errors
    measured = SENSOR_POSE.evaluate(noisy[:, 0], noisy[:, 1], theta, jacobian=False,
                                    substeps=True)[0]
    exact = np.stack([segments.dx, segments.dy, segments.dtheta])
    deviation = (measured - exact[:, None, :]).transpose(1, 2, 0).reshape(draws, -1)
    empirical = np.cov(deviation, rowvar=False)
    levels = NoiseLevels(np.full(3, 1e-12), np.full(2, 1e-12))
    wheels = WheelNoise.of(SENSOR_POSE, segments, theta, tick)
    assert wheels.quantization == pytest.approx(tick**2 / 12)
    independent = dataclasses.replace(wheels, inner=wheels.inner / (k - 1))
    model = dense_covariance(segments, levels, independent)
    scale = np.sqrt(np.diag(model))
    np.testing.assert_allclose(empirical / np.outer(scale, scale),
                               model / np.outer(scale, scale), rtol=0, atol=0.03)
    assert np.abs(model[3:6, 0:3] / np.outer(scale[3:6], scale[0:3])).max() > 0.2  # shared
    excess = dense_covariance(segments, levels, wheels) - empirical
    lowest = np.linalg.eigvalsh(excess / np.outer(scale, scale))[0]
    assert lowest > -0.03


def slip_log(seed: int) -> tuple[Segments, np.ndarray]:
    log = synthetic_log(np.random.default_rng(seed), 120.0, sensor_pose=SENSOR, slip=0.01)
    return segment_timeseries(log.series).segments, np.append(log.params.as_array(),
                                                               SENSOR.as_array())


def test_wheel_noise_whitens_the_residuals_of_slipping_logs_at_the_truth():
    """Synthetic logs whose only noise is random-walk wheel slip (0.01 rad/sqrt(s)): their
    residuals at the truth, whitened by the wheel-space covariance at the true slip level,
    have unit variance per channel (20 logs, 2400 values per channel: 3% sampling error)."""
    white = []
    for seed in range(20):
        segments, truth = slip_log(2000 + seed)
        raw = Problem(SENSOR_POSE, segments).evaluate(truth).raw
        wheels = WheelNoise.of(SENSOR_POSE, segments, truth, None)
        levels = NoiseLevels(np.full(3, 1e-12), np.full(2, 1e-12), 0.01)
        white.append(ChainWhitener(segments, levels, wheels).whiten(raw, None)[0])
    mean_square = np.mean(np.concatenate(white, axis=1) ** 2, axis=1)
    np.testing.assert_allclose(mean_square, 1.0, atol=0.1)


@pytest.mark.slow
@pytest.mark.statistical
def test_calibration_is_consistent_on_slipping_logs():
    """The calibrated estimate of 40 slip-only logs against the truth: the mean normalised
    squared error e^T C^-1 e over the six parameters is that of chi2(6), 6 +- 1.6 (3 standard
    errors of the mean of 40); with white segment noise instead of slip through the wheels
    (1bdde93) it was 7.9 on these logs (6.3 now)."""
    distances = []
    for seed in range(40):
        segments, truth = slip_log(3000 + seed)
        result = calibrate(segments, sensor_pose="estimate")
        error = np.append(result.params.as_array(), result.sensor_pose.as_array()) - truth
        distances.append(error @ np.linalg.solve(result.full_covariance, error))
    assert 6.0 - 1.6 < np.mean(distances) < 6.0 + 1.6, np.mean(distances)


def test_timing_covariance_of_late_encoder_samples():
    """Every encoder sample read at its stamp plus a Gaussian time error (both wheels at once)
    on wheels that turn at a constant rate per sub-step (the segment model's assumption) and
    speed up and slow down smoothly from sub-step to sub-step (a real wheel's inertia): the
    increments' empirical second moments over 40000 draws equal WheelNoise's timing terms
    (the shared boundary samples, each sample at the rate of the sub-step before it when read
    early and after it when read late, and the inner samples), within the sampling error."""
    rng = np.random.default_rng(13)
    k, n = 6, 3
    j = np.arange(n * k)
    smooth = 0.05 * np.stack([6.0 + 3.0 * np.sin(0.4 * j), 5.0 + 3.0 * np.cos(0.3 * j)])
    segments, theta, sub = chained_substeps(rng, n, k, smooth.reshape(2, n, k))
    timing, draws = 2e-4, 40_000
    rate = sub.reshape(2, n * k) / 0.05  # rad/s of every sub-step, one clock
    before = np.concatenate([rate[:, :1], rate], axis=1)  # of each of the n k + 1 samples
    after = np.concatenate([rate, rate[:, -1:]], axis=1)
    late = timing * rng.normal(size=(draws, 1, n * k + 1))
    errors = np.where(late > 0, after, before) * late  # (draws, 2, samples)
    noisy = sub + np.diff(errors, axis=2).reshape(draws, 2, n, k)
    measured = SENSOR_POSE.evaluate(noisy[:, 0], noisy[:, 1], theta, jacobian=False,
                                    substeps=True)[0]
    exact = np.stack([segments.dx, segments.dy, segments.dtheta])
    deviation = (measured - exact[:, None, :]).transpose(1, 2, 0).reshape(draws, -1)
    empirical = deviation.T @ deviation / draws  # second moments: a late read's mean is not 0
    levels = NoiseLevels(np.full(3, 1e-12), np.full(2, 1e-12), 0.0, timing)
    model = dense_covariance(segments, levels, WheelNoise.of(SENSOR_POSE, segments, theta, None))
    scale = np.sqrt(np.diag(model))
    np.testing.assert_allclose(empirical / np.outer(scale, scale),
                               model / np.outer(scale, scale), rtol=0, atol=0.03)
    assert np.abs(model[3:6, 0:3] / np.outer(scale[3:6], scale[0:3])).max() > 0.2  # shared


def jittered_log(seed: int, jitter: float) -> tuple[Segments, np.ndarray]:
    """A synthetic 120 s log with motion-capture pose noise (0.1 mm, 0.1 mrad), 4096-tick
    encoders at 100 Hz whose samples are read ``jitter`` (s, std) off their stamps."""
    log = synthetic_log(np.random.default_rng(seed), 120.0, sensor_pose=SENSOR,
                        pose_noise=(1e-4, 1e-4), ticks_per_rev=4096, encoder_jitter=jitter)
    return segment_timeseries(log.series).segments, np.append(log.params.as_array(),
                                                               SENSOR.as_array())


@pytest.mark.slow
@pytest.mark.statistical
def test_calibration_estimates_the_encoder_timing_and_stays_consistent():
    """Logs whose encoder samples are read 2 ms (std) off their stamps: the estimated timing
    level is the truth within 15% (median of 12 logs), the truth is inside the 95% ellipse
    in at least 11 of 12; on the same logs without the jitter no timing level is kept (0) in
    at least 10 of 12 (the test's level is 5%)."""
    timings, inside, clean = [], 0, 0
    for seed in range(12):
        segments, truth = jittered_log(4000 + seed, 0.002)
        result = calibrate(segments, sensor_pose="estimate", ticks_per_rev=4096)
        timings.append(result.timing)
        error = np.append(result.params.as_array(), result.sensor_pose.as_array()) - truth
        inside += error @ np.linalg.solve(result.full_covariance, error) < chi2_quantile(0.95, 6)
        segments, _ = jittered_log(4000 + seed, 0.0)
        clean += calibrate(segments, sensor_pose="estimate", ticks_per_rev=4096).timing == 0
    assert np.median(timings) == pytest.approx(0.002, rel=0.15), timings
    assert inside >= 11
    assert clean >= 10


def test_timing_at_a_shared_sample_takes_the_rates_on_either_side():
    """Two chained segments whose wheels turn at different constant rates: the sample they
    share errs by w_b dt when read early and w_a dt when late (w_b: the first segment's rate,
    w_a: the second's), so the block between them is -timing^2 G_start,1 S G_end,0^T with
    S = (w_b w_b^T + w_a w_a^T) / 2, not the product of the halves crossed nor of one mean
    rate; a chain's first and last sample use their own rate."""
    rate_b, rate_a = np.array([4.0, 6.0]), np.array([7.0, 2.0])  # rad/s
    k = 5
    sub = np.stack([np.full((2, k), 0.05) * rate_b[:, None], np.full((2, k), 0.05)
                    * rate_a[:, None]], axis=1)  # (2 wheels, 2 segments, k)
    segments, theta, _ = chained_substeps(np.random.default_rng(0), 2, k, sub)
    timing = 1e-3
    wheels = WheelNoise.of(SENSOR_POSE, segments, theta, None)
    # the timing part of C: the whole minus the pose noise alone (which keeps C invertible)
    pose = np.full(2, 1e-4)
    model = (dense_covariance(segments, NoiseLevels(np.zeros(3), pose, 0.0, timing), wheels)
             - dense_covariance(segments, NoiseLevels(np.zeros(3), pose), wheels))
    jac = SENSOR_POSE.wheel_jacobian(segments.sub_dphi_L, segments.sub_dphi_R, theta,
                                     substeps=True)  # (2, k, 3, 2)
    g_end, g_start = jac[0, -1], jac[1, 0]
    s = 0.5 * (np.outer(rate_b, rate_b) + np.outer(rate_a, rate_a))
    np.testing.assert_allclose(model[3:6, 0:3], -timing**2 * g_start @ s @ g_end.T,
                               rtol=1e-6, atol=1e-14)
    first, last = jac[0, 0] @ rate_b, jac[1, -1] @ rate_a  # the chain's ends: own rate
    np.testing.assert_allclose(timing**2 * (np.outer(first, first) + g_end @ s @ g_end.T)
                               + timing**2 * wheels.rate_inner[0], model[0:3, 0:3],
                               rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(timing**2 * (g_start @ s @ g_start.T + np.outer(last, last))
                               + timing**2 * wheels.rate_inner[1], model[3:6, 3:6],
                               rtol=1e-6, atol=1e-14)


@pytest.mark.slow
@pytest.mark.statistical
def test_a_log_whose_heading_noise_dominates_is_covered():
    """Pose samples with 0.5 mm and 10 mrad of noise: the start sample's heading error turns
    each measured position increment (its mean shrinks by exp(-sth^2 / 2)) and, were the
    covariance linearised at the measured increments, tilts the very lever arm that weighs
    it. Both bias the wheels' common scale by about sth^2 / 2 (several of its std here: the
    95% ellipse covered the truth in 6 of these logs, mean NEES 43). 16 logs of 120 s: the
    ellipse covers the truth in at least 12 (95% expected; P(11 or fewer) is 0.1%)."""
    sensor = SensorPose(0.1, -0.03, 0.4)
    covered = 0
    for seed in range(16):
        log = synthetic_log(np.random.default_rng([seed, 27]), 120.0, sensor_pose=sensor,
                            pose_noise=(5e-4, 1e-2))
        result = calibrate(segment_timeseries(log.series).segments, sensor_pose="estimate")
        error = np.append(result.params.as_array() - log.params.as_array(),
                          result.sensor_pose.as_array() - sensor.as_array())
        error[5] = (error[5] + np.pi) % (2 * np.pi) - np.pi
        nees = float(error @ np.linalg.solve(result.full_covariance, error))
        covered += nees <= chi2_quantile(0.95, 6)
    assert covered >= 12


def test_positions_far_more_precise_than_the_heading_s_lever_arm_still_factorize():
    """Pose samples with 1 um of position noise and 5 mrad of heading noise: the pose
    position level falls to its floor, ten decades below the heading's share of the same
    covariance, whose banded factorization then failed by rounding on this log (a numpy
    LinAlgError out of calibrate). The covariance is positive semi-definite by construction;
    the calibration now ends, its estimates within 4 of their std."""
    log = synthetic_log(np.random.default_rng(8010140), 120.0, sensor_pose=SENSOR,
                        pose_noise=(1e-6, 5e-3))
    result = calibrate(segment_timeseries(log.series).segments)
    truth = np.append(log.params.as_array(), SENSOR.as_array())[:len(result.parameter_names)]
    estimate = result.params.as_array()
    if result.sensor_pose_std is not None:
        estimate = np.append(estimate, result.sensor_pose.as_array())
    assert np.all(np.abs(estimate - truth) <= 4 * np.sqrt(np.diag(result.full_covariance)))
