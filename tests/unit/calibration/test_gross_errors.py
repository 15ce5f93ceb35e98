"""The gross-error screen of loss="auto" (excite.calibration.gross_errors) on segment data."""

import json

import numpy as np
import pytest

from excite import Segments, calibrate, save_segments
from excite.calibration.gross_errors import (
    DRIVING_TEST_LEVEL,
    GROSS_TEST_LEVEL,
    MAX_SHARE,
    _rank_sum_z,
)
from excite.core.kinematics import Params
from excite.core.models import SENSOR_POSE
from excite.logs.synthetic import lesson_dataset
from excite.stats.chi2 import chi2_quantile
from tests.conftest import TRUTH, run_cli

SIGMA = np.array([2e-3, 2e-3, 1e-3])
POSE = np.array([0.05, -0.03, 1.8])


def _with_gross(seg: Segments, rows: np.ndarray, rng: np.random.Generator) -> Segments:
    """``seg`` with errors uniform within +-0.1 m, +-0.1 m, +-0.3 rad added at ``rows``, each
    at least 0.05 m or 0.15 rad in some channel (far beyond the noise)."""
    a = seg.as_array().copy()
    error = rng.uniform(-1.0, 1.0, (rows.size, 3)) * np.array([0.1, 0.1, 0.3])
    error[:, 2] = np.where(np.abs(error[:, 2]) < 0.15, 0.15 * np.sign(error[:, 2] + 1e-12),
                           error[:, 2])
    a[rows, 2:] += error
    return Segments.from_array(a)


def _sensor_dataset(rng: np.random.Generator, n: int) -> Segments:
    """Random arcs seen by an off-axle, rotated sensor (Gaussian noise SIGMA)."""
    theta = np.append(TRUTH.as_array(), POSE)
    phi_L, phi_R = rng.normal(0.0, 2.0, n), rng.normal(0.0, 2.0, n)
    measured = SENSOR_POSE.predict(phi_L, phi_R, theta) + rng.normal(size=(n, 3)) * SIGMA
    return Segments(phi_L, phi_R, *measured.T)


@pytest.mark.parametrize("sigma", [None, SIGMA])
def test_the_flagged_segments_are_the_injected_ones(rng, sigma):
    seg = lesson_dataset(rng, 200, TRUTH, sigma=SIGMA)
    bad = np.array([3, 17, 60, 61, 120, 199])
    result = calibrate(_with_gross(seg, bad, rng), sigma=sigma)
    gross = result.gross_errors
    np.testing.assert_array_equal(gross.segments, bad)
    assert gross.detected and gross.declined is None
    assert result.n_segments == 200 - bad.size
    assert gross.t_start is None and gross.t_end is None
    # the gross errors left out: as if they had never been there
    clean = calibrate(seg[np.setdiff1d(np.arange(200), bad)], sigma=sigma, loss="linear")
    np.testing.assert_allclose(result.params.as_array(), clean.params.as_array(), rtol=1e-9)
    np.testing.assert_allclose(result.full_covariance, clean.full_covariance, rtol=1e-6)


def test_swapped_increments_are_flagged_in_pairs(rng):
    seg = lesson_dataset(rng, 200, TRUTH, sigma=SIGMA)
    a = seg.as_array().copy()
    pairs = np.array([[5, 90], [40, 150]])
    for i, j in pairs:
        a[[i, j], 2:] = a[[j, i], 2:]
    result = calibrate(Segments.from_array(a))
    np.testing.assert_array_equal(result.gross_errors.segments, np.sort(pairs.ravel()))


def test_clean_data_are_fitted_bit_for_bit_as_with_the_linear_loss(rng):
    seg = lesson_dataset(rng, 200, TRUTH, sigma=SIGMA)
    auto, linear = calibrate(seg), calibrate(seg, loss="linear")
    assert auto.gross_errors is not None and not auto.gross_errors.detected
    assert auto.gross_errors.statistic <= auto.gross_errors.threshold
    assert auto.loss == "auto" and linear.loss == "linear" and linear.gross_errors is None
    a, b = auto.to_dict(), linear.to_dict()
    for key in ("loss", "outliers", "outlier_times", "gross_errors"):
        a.pop(key), b.pop(key)
    assert json.dumps(a) == json.dumps(b)  # every number to the last bit
    np.testing.assert_array_equal(auto.residuals, linear.residuals)


def test_the_threshold_is_the_bonferroni_quantile(rng):
    result = calibrate(lesson_dataset(rng, 300, TRUTH, sigma=SIGMA))
    assert result.gross_errors.threshold == pytest.approx(
        chi2_quantile(1.0 - GROSS_TEST_LEVEL / 300, 3))


def test_linear_huber_and_trim_are_not_screened(rng):
    seg = _with_gross(lesson_dataset(rng, 200, TRUTH, sigma=SIGMA), np.array([1, 2, 3]), rng)
    for options in ({"loss": "linear"}, {"loss": "huber"}, {"trim": 0.02}):
        result = calibrate(seg, **options)
        assert result.gross_errors is None
        assert result.to_dict()["outliers"] == [] and result.to_dict()["gross_errors"] is None


def test_unknown_loss_is_refused(rng):
    with pytest.raises(ValueError, match="'auto', 'linear' or 'huber'"):
        calibrate(lesson_dataset(rng, 20, TRUTH), loss="cauchy")


def test_candidates_that_follow_the_driving_are_kept(rng):
    """Large residuals on the most turning segments (slip in turns) are a misfit, not gross
    errors: the rank-sum test of their turn rejects, and they stay in the fit."""
    seg = lesson_dataset(rng, 200, TRUTH, sigma=SIGMA)
    turning = np.sort(np.argsort(np.abs(seg.dphi_R - seg.dphi_L))[-12:])
    result = calibrate(_with_gross(seg, turning, rng))
    gross = result.gross_errors
    assert not gross.detected and gross.segments.size == 0
    np.testing.assert_array_equal(gross.candidates, turning)
    assert "mostly the segments that turn the most" in gross.declined
    assert "kept as they are" in gross.message
    assert result.n_segments == 200


def test_too_many_candidates_are_kept(rng):
    """(With the noise levels given: estimated, this many gross errors would inflate them and
    hide from the test.)"""
    seg = lesson_dataset(rng, 100, TRUTH, sigma=SIGMA)
    bad = np.sort(rng.choice(100, int(100 * MAX_SHARE) + 10, replace=False))
    gross = calibrate(_with_gross(seg, bad, rng), sigma=SIGMA).gross_errors
    assert not gross.detected and gross.candidates.size > MAX_SHARE * 100
    assert gross.declined.startswith("too many for gross errors")


def test_rank_sum_z_matches_scipy(rng):
    from scipy.special import ndtri
    from scipy.stats import mannwhitneyu

    values = np.round(rng.normal(size=80), 1)  # ties
    chosen = np.zeros(80, dtype=bool)
    chosen[rng.choice(80, 9, replace=False)] = True
    z = _rank_sum_z(values, chosen)
    p = mannwhitneyu(values[chosen], values[~chosen], use_continuity=False,
                     method="asymptotic").pvalue
    assert abs(z) == pytest.approx(float(ndtri(1.0 - p / 2.0)), rel=1e-9)
    assert _rank_sum_z(np.ones(10), chosen[:10]) == 0.0
    assert 0.0 < DRIVING_TEST_LEVEL < 0.01


def test_report_words_and_json_outliers_through_the_cli(capsys, tmp_path, rng):
    seg = lesson_dataset(rng, 200, TRUTH, sigma=SIGMA)
    bad = np.array([10, 11, 150])
    path = tmp_path / "gross.csv"
    save_segments(path, _with_gross(seg, bad, rng))
    code, out, _ = run_cli(capsys, "calibrate", path)
    assert code == 0
    assert "3 of 200 segments (1.5%) are gross errors (residuals " in out
    assert "the noise level): left out of the fit; --loss linear to keep them" in out
    assert "excite calibration: 197 segments, loss=auto" in out
    code, out, _ = run_cli(capsys, "calibrate", path, "--json")
    d = json.loads(out)
    assert code == 0 and d["outliers"] == bad.tolist() and d["outlier_times"] is None
    assert d["gross_errors"]["detected"] and d["gross_errors"]["candidates"] == bad.tolist()
    assert d["loss"] == "auto" and d["n_segments"] == 197
    code, out, _ = run_cli(capsys, "calibrate", path, "--json", "--loss", "linear")
    d = json.loads(out)
    assert d["outliers"] == [] and d["gross_errors"] is None and d["n_segments"] == 200


@pytest.mark.slow
@pytest.mark.statistical
def test_clean_data_sets_are_almost_never_flagged():
    """The test of "no gross error" at GROSS_TEST_LEVEL (1%) over 200 clean data sets of the
    lesson's kind: at most 7 with a candidate (P(X >= 8) = 0.001 for Binomial(200, 0.01);
    the test's level is at most 1%)."""
    flagged = 0
    for seed in range(200):
        seg = lesson_dataset(np.random.default_rng(50_000 + seed), 200, TRUTH, sigma=SIGMA)
        flagged += calibrate(seg).gross_errors.candidates.size > 0
    assert flagged <= 7


@pytest.mark.slow
@pytest.mark.statistical
def test_truth_in_the_95_percent_ellipse_with_gross_errors():
    """60 data sets of 200 segments seen by an off-axle sensor, 3% gross errors: every gross
    error flagged, no clean segment flagged, and the truth inside the reported 95% ellipse of
    the six parameters in at least 51 (P(X <= 50) = 0.0007 for Binomial(60, 0.95))."""
    truth = np.append(TRUTH.as_array(), POSE)
    inside = 0
    bound = chi2_quantile(0.95, 6)
    for seed in range(60):
        rng = np.random.default_rng(60_000 + seed)
        bad = np.sort(rng.choice(200, 6, replace=False))
        result = calibrate(_with_gross(_sensor_dataset(rng, 200), bad, rng))
        np.testing.assert_array_equal(result.gross_errors.segments, bad)
        theta = np.append(result.params.as_array(), result.sensor_pose.as_array())
        d = theta - truth
        inside += float(d @ np.linalg.solve(result.full_covariance, d)) <= bound
    assert inside >= 51


# --- segments that share pose samples (cut from a log) -----------------------------------

def _chain(poses: np.ndarray, rng: np.random.Generator) -> Segments:
    """Chained segments between consecutive poses (n + 1, 3), with times, 3 sub-steps each."""
    from excite.core import se2

    n = poses.shape[0] - 1
    sub_L, sub_R = rng.normal(0.1, 0.05, (n, 3)), rng.normal(0.1, 0.05, (n, 3))
    measured = se2.between(poses[:-1], poses[1:])
    return Segments(sub_L.sum(1), sub_R.sum(1), *measured.T, t_start=np.arange(n) * 1.0,
                    t_end=np.arange(1, n + 1) * 1.0, chained=np.arange(n) > 0,
                    sub_dphi_L=sub_L, sub_dphi_R=sub_R)


def test_merging_a_run_removes_its_inner_samples_exactly(rng):
    from excite.calibration.gross_samples import merged
    from excite.core import se2

    poses = np.cumsum(rng.normal(0.0, 0.2, (9, 3)), axis=0)
    seg = _chain(poses, rng)
    flagged = np.zeros(8, dtype=bool)
    flagged[[2, 3, 4]] = True  # samples 3 and 4 bad: segments 2..4 become one
    flagged[6] = True  # a segment on its own: left out
    repaired, parts = merged(seg, flagged)
    assert [p.tolist() for p in parts] == [[0], [1], [2, 3, 4], [5], [7]]
    np.testing.assert_allclose(repaired.measured[2], se2.between(poses[2], poses[5]),
                               atol=1e-12)
    assert repaired.dphi_L[2] == pytest.approx(seg.dphi_L[2:5].sum())
    np.testing.assert_array_equal(repaired.sub_dphi_L[2, :9], seg.sub_dphi_L[2:5].ravel())
    np.testing.assert_array_equal(repaired.substep_counts, [3, 3, 9, 3, 3])
    np.testing.assert_array_equal(repaired.chained, [False, True, True, True, False])
    np.testing.assert_array_equal(repaired.t_start, [0, 1, 2, 5, 7])
    np.testing.assert_array_equal(repaired.t_end, [1, 2, 5, 6, 8])
    np.testing.assert_array_equal(repaired.sub_dphi_L[0], np.pad(seg.sub_dphi_L[0], (0, 6)))
    # a run still gross once merged (its end sample bad too) is left out whole; the segment
    # after it starts a new chain
    left_out = np.zeros(8, dtype=bool)
    left_out[[2, 3, 4]] = True
    repaired, parts = merged(seg, flagged, left_out)
    assert [p.tolist() for p in parts] == [[0], [1], [5], [7]]
    np.testing.assert_array_equal(repaired.chained, [False, True, False, False])


def test_a_bad_sample_makes_a_pair_of_candidates(rng):
    """Runs are repaired as they are; a single candidate only when significant on its own,
    then with its neighbour of the larger z^2, or alone at the end of a chain."""
    from excite.calibration.gross_samples import _attributed

    seg = _chain(np.cumsum(rng.normal(0.0, 0.2, (11, 3)), axis=0), rng)
    z2 = np.ones(10)
    z2[[1, 2]] = 50.0  # a pair
    z2[4], z2[5] = 30.0, 8.0  # alone, significant: with its larger neighbour 5
    z2[7] = 5.0  # alone, not significant: a false alarm
    z2[9] = 40.0  # alone at the end of the chain
    chosen = np.array([1, 2, 4, 7, 9])
    np.testing.assert_array_equal(_attributed(seg, chosen, z2, 20.0), [1, 2, 4, 5, 9])


def _log_with_bad_samples(seed: int, times: list[float]):
    """A 90 s synthetic log (2 mm / 2 mrad pose noise, off-axle sensor) and the same with the
    pose samples at ``times`` (s, segment boundaries of 1 s windows) moved by 5 cm and
    0.2 rad."""
    from excite.core.models import SensorPose
    from excite.logs.synthetic import synthetic_log
    from excite.logs.timeseries import TimeSeries

    log = synthetic_log(np.random.default_rng(seed), 90.0,
                        sensor_pose=SensorPose(0.1, -0.03, 0.4), pose_noise=(2e-3, 2e-3))
    ts = log.series
    index = np.searchsorted(ts.t_pose, times)
    x, y, theta = ts.x.copy(), ts.y.copy(), ts.theta.copy()
    x[index] += 0.05
    y[index] -= 0.03
    theta[index] += 0.2
    bad = TimeSeries(ts.t_enc, ts.phi_L, ts.phi_R, ts.t_pose, x, y, theta, source=ts.source)
    return log, bad


@pytest.mark.slow
def test_a_bad_pose_sample_is_flagged_not_its_two_segments(capsys, tmp_path):
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.timeseries_csv import write_timeseries

    times = [20.0, 47.0, 71.0]
    log, bad = _log_with_bad_samples(3, times)
    seg = segment_timeseries(bad).segments
    result = calibrate(seg)
    gross = result.gross_errors
    np.testing.assert_array_equal(gross.samples, times)
    flagged = gross.segments
    np.testing.assert_array_equal(np.sort(np.concatenate([seg.t_end[flagged[0::2]],
                                                          seg.t_start[flagged[1::2]]])),
                                  np.repeat(times, 2))
    assert gross.dropped == 0 and result.n_segments == len(seg) - len(times)
    assert "3 pose samples (at t = 20, 47, 71 s) are gross errors" in gross.message
    clean = calibrate(segment_timeseries(log.series).segments)
    # as precise as the clean log (the merged segments lose only the bad samples)
    assert np.all(result.std < 1.05 * clean.std)
    path = tmp_path / "bad.csv"
    write_timeseries(path, bad)
    code, out, _ = run_cli(capsys, "calibrate", path, "--json")
    d = json.loads(out)
    assert code == 0 and d["gross_errors"]["samples"] == times
    assert d["outliers"] == flagged.tolist()
    assert d["outlier_times"] == [[a, b] for a, b in zip(seg.t_start[flagged],
                                                           seg.t_end[flagged], strict=True)]


@pytest.mark.slow
def test_two_bad_samples_in_a_row_keep_the_chain_whole():
    """Two consecutive bad samples, one small: the first pass merges the pair around the
    large one, whose merged segment is then a candidate again with its neighbour (its end
    sample is the small bad one). The runs join, and the chain stays whole: leaving the run
    out would break it, which halves the precision of a log whose white pose noise makes the
    long chain the information (std 2x on this log before)."""
    from excite.core.models import SensorPose
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log
    from excite.logs.timeseries import TimeSeries

    log = synthetic_log(np.random.default_rng(0), 90.0, sensor_pose=SensorPose(0.1, -0.03, 0.4),
                        pose_noise=(5e-3, 5e-4))
    ts = log.series
    x, theta = ts.x.copy(), ts.theta.copy()
    i, j = np.searchsorted(ts.t_pose, [45.0, 46.0])
    x[i] += 0.05
    theta[i] += 0.2
    x[j] -= 0.01
    theta[j] += 0.01
    bad = TimeSeries(ts.t_enc, ts.phi_L, ts.phi_R, ts.t_pose, x, ts.y, theta,
                     source=ts.source)
    result = calibrate(segment_timeseries(bad).segments)
    gross = result.gross_errors
    np.testing.assert_array_equal(gross.samples, [45.0, 46.0])
    assert gross.dropped == 0 and gross.declined is None
    clean = calibrate(segment_timeseries(ts).segments)
    assert np.all(result.std < 1.05 * clean.std)


@pytest.mark.slow
def test_a_step_of_the_pose_source_is_left_out_not_joined():
    """A relocalisation that stays (x + 5 cm from 90 s on): one segment's error that no bad
    sample explains. The runs around it may join while they are candidates, but a joined
    run that still does not agree is left out: the fit holds, the estimates are right."""
    from excite.core.models import SensorPose
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log
    from excite.logs.timeseries import TimeSeries

    truth = Params(0.050, 0.0512, 0.300)
    log = synthetic_log(np.random.default_rng(41), 180.0, truth,
                        SensorPose(0.05, -0.03, 0.3), pose_noise=(1e-3, 1e-3))
    ts = log.series
    stepped = TimeSeries(ts.t_enc, ts.phi_L, ts.phi_R, ts.t_pose,
                         np.where(ts.t_pose > 90.0, ts.x + 0.05, ts.x), ts.y, ts.theta,
                         source=ts.source)
    seg = segment_timeseries(stepped).segments
    result = calibrate(seg)
    gross = result.gross_errors
    assert result.fit.ok and gross.declined is None and gross.dropped >= 1
    step = np.flatnonzero((seg.t_start <= 90.0) & (seg.t_end > 90.0))
    assert np.isin(step, gross.segments).all()
    z = (result.params.as_array() - truth.as_array()) / result.std
    assert np.all(np.abs(z) < 3.0)


def _fastest_boundaries(seg: Segments, count: int) -> np.ndarray:
    """The pose samples (s) that end the ``count`` segments travelling farthest and start a
    chained next one."""
    travel = np.abs(seg.dphi_L + seg.dphi_R)[:-1]
    inner = np.flatnonzero(seg.chained[1:])
    fastest = inner[np.argsort(-travel[inner])[:count]]
    return np.sort(seg.t_end[fastest])


@pytest.mark.slow
def test_swapped_samples_on_the_fastest_segments_are_bad_samples():
    """A swapped pose sample errs by the speed times the lag, so the candidates travel the
    farthest; their pairs cancel when composed, which slip does not: repaired, not taken
    for a misfit that follows the driving."""
    from excite.core.models import SensorPose
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log
    from excite.logs.timeseries import TimeSeries

    log = synthetic_log(np.random.default_rng(11), 120.0,
                        sensor_pose=SensorPose(0.1, -0.03, 0.4), pose_noise=(2e-3, 2e-3))
    ts = log.series
    times = _fastest_boundaries(segment_timeseries(ts).segments, 8)
    index = np.searchsorted(ts.t_pose, times)
    poses = np.column_stack([ts.x, ts.y, ts.theta])
    poses[index] = poses[index + 5]  # the pose 0.1 s later
    bad = TimeSeries(ts.t_enc, ts.phi_L, ts.phi_R, ts.t_pose, *poses.T, source=ts.source)
    seg = segment_timeseries(bad).segments
    gross = calibrate(seg).gross_errors
    assert gross.declined is None and gross.detected
    np.testing.assert_array_equal(gross.samples, times)


@pytest.mark.slow
def test_a_misfit_of_the_most_turning_segments_of_a_log_is_kept():
    """Errors of the most turning segments' own wheel increments (slip in turns: each
    segment alone, nothing cancels between neighbours) are not bad samples: kept, with the
    reason."""
    from excite.core.models import SensorPose
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log
    from excite.logs.timeseries import TimeSeries

    log = synthetic_log(np.random.default_rng(12), 120.0,
                        sensor_pose=SensorPose(0.1, -0.03, 0.4), pose_noise=(2e-3, 2e-3))
    ts = log.series
    seg = segment_timeseries(ts).segments
    turning = np.argsort(-np.abs(seg.dphi_R - seg.dphi_L))[:10]
    phi_L = ts.phi_L.copy()
    for k in turning:  # the left wheel slips 1 rad in the middle of the segment
        middle = 0.5 * (seg.t_start[k] + seg.t_end[k])
        phi_L[ts.t_enc >= middle] -= 1.0
    slipping = TimeSeries(ts.t_enc, phi_L, ts.phi_R, ts.t_pose, ts.x, ts.y, ts.theta,
                          source=ts.source)
    gross = calibrate(segment_timeseries(slipping).segments).gross_errors
    assert not gross.detected and gross.segments.size == 0
    assert "mostly the segments that turn the most" in gross.declined


@pytest.mark.slow
def test_a_clean_log_is_fitted_bit_for_bit_as_with_the_linear_loss():
    from excite.core.models import SensorPose
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log

    log = synthetic_log(np.random.default_rng(4), 60.0, sensor_pose=SensorPose(0.1, 0.0, 0.3),
                        pose_noise=(2e-3, 2e-3))
    seg = segment_timeseries(log.series).segments
    auto, linear = calibrate(seg), calibrate(seg, loss="linear")
    assert not auto.gross_errors.detected and auto.gross_errors.candidates.size == 0
    a, b = auto.to_dict(), linear.to_dict()
    for key in ("loss", "outliers", "outlier_times", "gross_errors"):
        a.pop(key), b.pop(key)
    assert json.dumps(a) == json.dumps(b)


def _deleted_statistic(fits, k: int) -> float:
    """The chi-square statistic of segment k's increment against its prediction from the
    other segments, by the dense GLS without it: the parameters fitted on the others, the
    prediction with the conditional mean of its noise given theirs (dense C)."""
    from excite.calibration.noise import stacked
    from excite.calibration.solver import complement

    primary = fits.candidates.primary
    raw = primary.unwhitened
    free = complement(primary.weak)
    rows = stacked(raw.raw, np.einsum("cpn,pm->cmn", raw.jac, free))
    d, jac = -rows[:, 0], rows[:, 1:]
    inverse_factor = fits.noise.whitener.whiten_stacked(np.eye(rows.shape[0]))  # L^-1
    factor = np.linalg.inv(inverse_factor)
    cov = factor @ factor.T
    own = np.arange(3 * k, 3 * k + 3)
    others = np.setdiff1d(np.arange(rows.shape[0]), own)
    c_oo = cov[np.ix_(others, others)]
    gain = np.linalg.solve(c_oo, cov[np.ix_(others, own)]).T  # C_ko C_oo^-1
    weighted = np.linalg.solve(c_oo, jac[others])
    information = jac[others].T @ weighted
    delta = np.linalg.solve(information, weighted.T @ d[others])
    error = d[own] - jac[own] @ delta - gain @ (d[others] - jac[others] @ delta)
    lever = jac[own] - gain @ jac[others]
    variance = (cov[np.ix_(own, own)] - gain @ cov[np.ix_(others, own)]
                + lever @ np.linalg.solve(information, lever.T))
    return float(error @ np.linalg.solve(variance, error))


@pytest.mark.slow
@pytest.mark.parametrize("batch", [64, 2])
def test_the_shift_statistic_is_the_test_of_a_segment_against_the_others(monkeypatch, batch):
    """A merged segment is explained when its increment agrees with its prediction from the
    other segments (not merely with a fit it may dominate): the mean-shift statistic equals
    the deletion test by dense GLS (the shared pose samples' correlation included)."""
    from excite.calibration import gross_samples
    from excite.calibration.gross_samples import shift_statistics
    from excite.calibration.options import DEFAULT_MAX_RELATIVE_STD, FitOptions
    from excite.calibration.pipeline import _fitted
    from excite.calibration.starts import first_estimates
    from excite.core.models import SensorPose
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log

    log = synthetic_log(np.random.default_rng(21), 40.0, sensor_pose=SensorPose(0.1, -0.03, 0.4),
                        pose_noise=(2e-3, 2e-3), slip=0.01)
    seg = segment_timeseries(log.series).segments
    options = FitOptions("linear", 100, 1e-8, DEFAULT_MAX_RELATIVE_STD)
    fits = _fitted(seg, first_estimates(seg, None, "auto"), None, None, options, "auto")
    monkeypatch.setattr(gross_samples, "SHIFT_BATCH", batch)  # the batches change nothing
    chosen = [0, 7, len(seg) - 1]
    found = shift_statistics(fits, chosen)
    expected = [_deleted_statistic(fits, k) for k in chosen]
    np.testing.assert_allclose(found, expected, rtol=1e-6)
    assert np.all(found > 0)
