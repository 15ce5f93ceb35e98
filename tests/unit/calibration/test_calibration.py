import json
import warnings

import numpy as np
import pytest

from excite import DataError, Params, calibrate
from excite.calibration.starts import initial_estimate
from excite.core.information import crlb_relative_std, fisher_information, scaled_jacobian
from excite.logs.synthetic import lesson_dataset
from excite.stats.chi2 import chi2_quantile
from tests.conftest import TRUTH, exact_segments, spin_segments, straight_segments


def test_noiseless_data_recover_truth_without_a_guess(rng):
    seg = exact_segments(rng.normal(0, 0.4, 100), rng.normal(0, 0.4, 100))
    result = calibrate(seg, sigma=(1e-3, 1e-3, 1e-3))
    np.testing.assert_allclose(result.params.as_array(), TRUTH.as_array(), rtol=1e-10)
    assert result.converged and result.identifiable


def test_linear_first_estimate_is_close_on_good_data(rng):
    p0 = initial_estimate(lesson_dataset(rng, 200, TRUTH))
    np.testing.assert_allclose(p0.as_array(), TRUTH.as_array(), rtol=0.03)


@pytest.mark.parametrize("factor", [2.0, 0.5])
@pytest.mark.parametrize("sigma", [(2e-3, 2e-3, 1e-3), None])
def test_converges_from_a_guess_two_times_off(rng, factor, sigma):
    seg = lesson_dataset(rng, 200, TRUTH)
    reference = calibrate(seg, sigma=sigma)
    guess = Params(*(TRUTH.as_array() * factor))
    result = calibrate(seg, initial=guess, sigma=sigma)
    assert result.converged
    difference = result.params.as_array() - reference.params.as_array()
    assert np.all(np.abs(difference) < 1e-3 * reference.std)


def test_estimated_sigma_recovers_the_noise_levels(rng):
    sigma = np.array([5e-4, 3e-3, 2e-4])
    seg = lesson_dataset(rng, 2000, TRUTH, sigma=sigma)
    result = calibrate(seg)
    np.testing.assert_allclose(result.sigma, sigma, rtol=0.06)
    assert result.sigma_estimated


@pytest.mark.slow
@pytest.mark.statistical
@pytest.mark.parametrize("sigma_known", [True, False])
def test_monte_carlo_rmse_reaches_the_cramer_rao_bound(sigma_known):
    """Efficiency in the regime where the unweighted lesson estimator is ~2.5x the bound.

    300 datasets give the RMSE to about +-4% (1 sigma); the precise 1,000-dataset figures
    are in BENCHMARKS.md (benchmarks/bench_calibration.py).
    """
    sigma = np.array([5e-4, 5e-4, 1e-2])
    rng = np.random.default_rng(2024)
    errors, crlb = [], []
    for _ in range(300):
        seg = lesson_dataset(rng, 200, TRUTH, sigma=sigma)
        result = calibrate(seg, sigma=sigma if sigma_known else None)
        errors.append(result.params.as_array() / TRUTH.as_array() - 1)
        fisher = fisher_information(scaled_jacobian(seg.dphi_L, seg.dphi_R, TRUTH, sigma))
        crlb.append(crlb_relative_std(fisher))
    rmse = np.sqrt(np.mean(np.square(errors), axis=0))
    bound = np.sqrt(np.mean(np.square(crlb), axis=0))
    ratio = rmse / bound
    assert np.all(ratio < 1.15), ratio
    assert np.all(ratio > 0.85), ratio


def test_covariance_is_inverse_fisher_information(rng):
    seg = lesson_dataset(rng, 200, TRUTH)
    result = calibrate(seg, sigma=(2e-3, 2e-3, 1e-3))
    p = result.params.as_array()
    rel = result.covariance / np.outer(p, p)
    s = np.linalg.svd(np.linalg.inv(rel), compute_uv=False)
    np.testing.assert_allclose(np.sqrt(s), result.singular_values, rtol=1e-8)
    np.testing.assert_allclose(result.std, np.sqrt(np.diag(result.covariance)))
    assert result.condition_number == pytest.approx(s.max() ** 0.5 / s.min() ** 0.5)


def test_straight_only_names_b(rng):
    result = calibrate(straight_segments(rng))
    assert not result.identifiable
    assert result.unidentifiable_direction.startswith("b: no segment turns")
    assert np.isinf(result.std[2]) and np.all(np.isfinite(result.std[:2]))
    np.testing.assert_allclose(result.params.as_array()[:2], TRUTH.as_array()[:2], rtol=1e-3)
    assert 0.1 < result.params.b < 1.0  # held at the start, not driven away by noise


def test_a_parameter_the_data_barely_determine_has_an_infinite_std(rng):
    """Turns of a few milliradians: b's relative std is 40%, beyond what the identifiability
    rule calls determined. Its std is inf, not the finite spread given the others (which a
    user would take for an estimate's); the radii, determined, keep theirs."""
    phi_L = rng.uniform(5, 20, 30)
    phi_R = phi_L * TRUTH.r_L / TRUTH.r_R * (1 + rng.normal(0, 2e-4, 30))
    result = calibrate(exact_segments(phi_L, phi_R, TRUTH, (2e-3, 2e-3, 1e-3), rng))
    assert not result.identifiable
    assert np.isinf(result.std[2]) and np.isfinite(result.covariance[2, 2])
    np.testing.assert_allclose(result.std[:2], np.sqrt(np.diag(result.covariance)[:2]))
    assert np.all(result.std[:2] < 1e-4)


def test_spin_only_names_common_scale(rng):
    result = calibrate(spin_segments(rng))
    assert not result.identifiable
    assert "common scale of r_L, r_R and b" in result.unidentifiable_direction
    p = result.params.as_array()
    # The ratios r/b are determined even though the scale is not.
    np.testing.assert_allclose(p[:2] / p[2], TRUTH.as_array()[:2] / TRUTH.b, rtol=1e-3)


def test_huber_resists_slip_outliers(rng):
    seg = lesson_dataset(rng, 200, TRUTH)
    rows = seg.as_array()
    slipped = rng.choice(200, 15, replace=False)
    rows[slipped, 2] *= 0.8  # wheels spun but the robot went 20% less far
    rows[slipped, 4] += rng.choice([-0.3, 0.3], 15)
    robust = calibrate(rows, loss="huber")
    plain = calibrate(rows, loss="linear")
    robust_err = np.abs(robust.params.as_array() / TRUTH.as_array() - 1).max()
    plain_err = np.abs(plain.params.as_array() / TRUTH.as_array() - 1).max()
    assert robust_err < 0.3 * plain_err
    assert robust_err < 4 * np.max(robust.std / TRUTH.as_array())
    assert 12 <= robust.n_outliers <= 18


def test_to_dict_is_json_with_the_contract_keys(rng):
    result = calibrate(straight_segments(rng))
    d = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    for key in ("params", "std", "covariance", "singular_values", "condition_number",
                "identifiable", "unidentifiable_direction", "n_segments", "n_outliers",
                "rms_residual", "sigma", "converged", "iterations"):
        assert key in d
    assert d["std"]["b"] is None and d["identifiable"] is False


def test_rejects_bad_arguments(rng):
    seg = lesson_dataset(rng, 10)
    with pytest.raises(ValueError, match="loss"):
        calibrate(seg, loss="cauchy")
    with pytest.raises(ValueError, match="sigma"):
        calibrate(seg, sigma=(1e-3, -1, 1))
    with pytest.raises(ValueError, match="at least 3"):
        calibrate(seg.as_array()[:2])


# -- the sensor pose -------------------------------------------------------------------------
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from excite import Segments, SensorPose  # noqa: E402
from excite.core.models import SENSOR_POSE  # noqa: E402

OFF_AXLE = np.array([0.05, -0.03, 1.8])


def sensor_segments(rng, n=200, pose=OFF_AXLE, sigma=(2e-3, 2e-3, 1e-3), wheel_std=2.0,
                    phi=None):
    phi_L, phi_R = phi if phi is not None else rng.normal(0.0, wheel_std, (2, n))
    theta = np.append(TRUTH.as_array(), pose)
    measured = SENSOR_POSE.predict(phi_L, phi_R, theta)
    measured = measured + rng.normal(size=measured.shape) * np.asarray(sigma)
    return Segments(phi_L, phi_R, *measured.T)


@settings(max_examples=40, deadline=None)
@given(l_x=st.floats(-0.3, 0.3), l_y=st.floats(-0.3, 0.3),
       l_t=st.floats(-np.pi, np.pi, exclude_min=True), seed=st.integers(0, 2**32 - 1))
def test_exact_data_give_the_exact_sensor_pose_for_any_mounting_without_a_guess(l_x, l_y, l_t,
                                                                              seed):
    rng = np.random.default_rng(seed)
    seg = sensor_segments(rng, 60, (l_x, l_y, l_t), sigma=(0.0, 0.0, 0.0))
    result = calibrate(seg, sensor_pose="estimate")
    np.testing.assert_allclose(result.params.as_array(), TRUTH.as_array(), rtol=1e-7)
    np.testing.assert_allclose(result.sensor_pose.as_array()[:2], [l_x, l_y], atol=1e-8)
    assert abs(np.angle(np.exp(1j * (result.sensor_pose.theta - l_t)))) < 1e-8
    assert result.identifiable and result.fit.ok


def test_auto_estimates_an_off_axle_sensor_and_says_why(rng):
    result = calibrate(sensor_segments(rng))
    assert result.model == "sensor_pose" and result.sensor_pose_std is not None
    # so far from the axle that the axle model is not fitted: the Wald statistic decides
    assert "the axle model is far from fitting" in result.model_choice
    z = (result.sensor_pose.as_array() - OFF_AXLE) / result.sensor_pose_std
    assert np.all(np.abs(z) < 4), z
    assert result.full_covariance.shape == (6, 6) and result.singular_values.size == 6
    d = result.to_dict()
    assert d["model"] == "sensor_pose" and set(d["sensor_pose"]) == {"x", "y", "theta"}
    assert d["fit"]["ok"] is True
    assert f"Wald statistic {result.model_statistic:.3g} >" in result.model_choice
    assert d["model_statistic"] == result.model_statistic > 100 * chi2_quantile(0.999, 3)
    assert result.fit.statistic_name == "Wald statistic"


def test_a_sensor_near_the_axle_is_chosen_by_the_likelihood_ratio(rng, monkeypatch):
    """Within 100 times the threshold both models are fitted and the likelihood ratio
    decides; far beyond it, fitting the axle model too would decide the same."""
    from excite.calibration import model_choice

    threshold = chi2_quantile(0.999, 3)
    result = calibrate(sensor_segments(rng, pose=(0.005, 0.0, 0.0)))
    assert result.model == "sensor_pose" and result.fit.statistic_name == "likelihood ratio"
    assert f"likelihood ratio {result.model_statistic:.3g} >" in result.model_choice
    assert threshold < result.model_statistic < model_choice.NEAR_AXLE * threshold
    far = sensor_segments(rng)
    assert "far from fitting" in calibrate(far).model_choice
    monkeypatch.setattr(model_choice, "NEAR_AXLE", np.inf)
    both = calibrate(far)
    assert both.model == "sensor_pose" and both.fit.statistic_name == "likelihood ratio"
    assert both.model_statistic > 100 * threshold


def test_auto_keeps_the_axle_model_on_axle_data(rng):
    seg = lesson_dataset(rng, 200, TRUTH)
    result = calibrate(seg)
    assert result.model == "axle" and result.sensor_pose is None
    assert "does not fit significantly better" in result.model_choice and result.fit.ok
    assert f"likelihood ratio {result.model_statistic:.3g} <=" in result.model_choice
    assert calibrate(seg, sensor_pose="axle").model_statistic is None


def test_few_segments_keep_the_model_choice_at_its_level():
    """With the noise levels estimated, the likelihood ratio counts each channel's residual
    degrees of freedom (N - h_c), not N: on 8 segments of axle data, N itself chose the
    sensor-pose model 15 times in 2000 (0.75%) where the test's level allows 0.1%. The
    sensor of a few centimetres off the axle is still found from 8 segments."""
    chosen = sum(calibrate(lesson_dataset(np.random.default_rng([8, r]), 8, TRUTH,
                                          dphi_std=2.0)).model == "sensor_pose"
                 for r in range(1000))
    assert chosen <= 4  # P(Binomial(1000, 0.001) > 4) = 0.004
    found = sum(calibrate(sensor_segments(np.random.default_rng([8, r]), 8,
                                          (0.02, 0.01, 0.02))).model == "sensor_pose"
                for r in range(100))
    assert found >= 90


def test_segments_too_few_for_the_noise_levels_are_not_determined(rng):
    """Six segments or fewer cannot estimate the sensor pose with the noise levels (the
    sensor-pose model would fit them exactly): "auto" fits the axle model and says why; and
    as many segments as parameters determine nothing at all (exit status 3), however well
    the parameters themselves seem to fit."""
    few = calibrate(sensor_segments(rng, 5, (0.0, 0.0, 0.0)))
    assert few.model == "axle" and few.identifiable and few.residual_dof == 2
    assert few.model_choice == ("axle: 5 segments are too few to estimate the sensor pose "
                                "with the noise levels (at least 7 are needed)")
    three = calibrate(lesson_dataset(rng, 3, TRUTH, dphi_std=2.0))
    assert not three.identifiable and np.all(np.isinf(three.std))
    assert three.unidentifiable_direction == (
        "3 segments cannot determine 3 parameters and the noise levels: at least 4 are "
        "needed, 13 to trust the std")
    given = calibrate(lesson_dataset(np.random.default_rng(1), 3, TRUTH, dphi_std=2.0),
                      sigma=(2e-3, 2e-3, 1e-3))
    assert given.identifiable and np.all(np.isfinite(given.std))
    assert calibrate(sensor_segments(rng, 6), sensor_pose="estimate").identifiable is False


def test_forcing_the_axle_model_on_an_off_axle_sensor_is_a_misfit_in_words(rng):
    result = calibrate(sensor_segments(rng), sensor_pose="axle")
    assert not result.fit.ok
    assert "the sensor is not on the axle" in result.fit.message
    assert "try --sensor-pose estimate" in result.fit.message
    assert result.fit.noise_ratio[:2].max() > 3 and result.fit.statistic > 100
    assert result.fit.statistic_name == "score"


def test_a_wrong_given_sensor_pose_is_a_misfit_and_the_right_one_fits(rng):
    seg = sensor_segments(rng)
    wrong = calibrate(seg, sensor_pose=SensorPose(0.0, 0.0, 1.8))
    assert not wrong.fit.ok and "not at the given pose" in wrong.fit.message
    right = calibrate(seg, sensor_pose=SensorPose(*OFF_AXLE), sigma=(2e-3, 2e-3, 1e-3))
    assert right.fit.ok and right.model == "sensor_pose" and right.sensor_pose_std is None
    assert np.all(np.abs(right.params.as_array() / TRUTH.as_array() - 1) < 5 * right.std
                  / TRUTH.as_array())


def test_given_noise_levels_that_are_too_small_fail_the_fit(rng):
    seg = lesson_dataset(rng, 200, TRUTH)
    result = calibrate(seg, sigma=(2e-4, 2e-4, 1e-4), sensor_pose="axle")
    assert not result.fit.ok and "noise level" in result.fit.message


def test_given_noise_levels_far_too_large_are_said_to_be(rng):
    """Levels 100x the truth: the fit is not failed (the std are too wide, not too narrow)
    but its words say so, naming the channels; the true levels and 1.1 times them match."""
    seg = lesson_dataset(rng, 200, TRUTH)
    large = calibrate(seg, sigma=(0.2, 0.2, 0.1), sensor_pose="axle").fit
    factor = float(large.message.split("up to ")[1].split("x ")[0])
    assert large.ok and 80 < factor < 120 and large.message.startswith("the residuals are up")
    assert large.message.endswith("x smaller than the given noise level in x, y, theta: the "
                                  "given levels are too large and the std as much too wide; "
                                  "omit --sigma to estimate them")
    theta = calibrate(seg, sigma=(2e-3, 2e-3, 0.05), sensor_pose="axle").fit.message
    assert "smaller than the given noise level in theta:" in theta
    for factor in (1.0, 1.1):
        fit = calibrate(seg, sigma=factor * np.array([2e-3, 2e-3, 1e-3]), sensor_pose="axle").fit
        assert fit.message == "the residuals match the given noise levels", factor


def test_sensor_pose_identifiability_in_words(rng):
    straight = sensor_segments(rng, 60, phi=np.repeat(rng.uniform(5, 20, (1, 60)), 2, axis=0)
                               * np.array([[TRUTH.r_R], [TRUTH.r_L]]) / TRUTH.r_L)
    result = calibrate(straight, sensor_pose="estimate")
    assert not result.identifiable
    assert "sensor x, y: no segment turns" in result.unidentifiable_direction
    turns = rng.uniform(-20, 20, 60)
    spins = sensor_segments(rng, 60, phi=np.stack([-turns * TRUTH.r_R / TRUTH.r_L, turns]))
    result = calibrate(spins, sensor_pose="estimate")
    assert not result.identifiable
    assert "sensor theta: no segment translates" in result.unidentifiable_direction
    auto = calibrate(spins)
    assert auto.model == "axle" and "do not determine the sensor pose" in auto.model_choice


def test_trimming_drops_the_worst_segments_one_percent_per_pass(rng):
    seg = lesson_dataset(rng, 300, TRUTH)
    rows = seg.as_array()
    rows[:6, 2] += 0.5  # six gross outliers
    result = calibrate(rows, trim=0.02, sensor_pose="axle")
    assert result.n_trimmed == 6 and result.n_segments == 294
    assert np.all(np.abs(result.params.as_array() / TRUTH.as_array() - 1) < 4 * result.std
                  / TRUTH.as_array())


def test_all_zero_data_and_exact_data(rng):
    with pytest.raises(DataError, match="no segment moves"):
        calibrate(np.zeros((10, 5)))
    seg = exact_segments(rng.normal(0, 0.4, 50), rng.normal(0, 0.4, 50))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = calibrate(seg)  # sigma estimated as (almost) zero: a floor, not a division
    np.testing.assert_allclose(result.params.as_array(), TRUTH.as_array(), rtol=1e-9)
    assert result.converged and result.identifiable


@pytest.mark.parametrize("sensor", [None, SensorPose(0.1, -0.03, 0.4)])
def test_a_noise_free_log_is_fitted_to_the_truth(sensor):
    """A log without noise (simulation ground truth, unquantised joints) makes the heading
    channel ~1e10 times more precise than the lengths: every determined direction must still
    step (the relative SVD cut alone froze the common scale at the closed-form start, 0.17%
    off with std 1e-6) and the damping must be able to vanish (it crawled along the scale)."""
    from excite.logs.segmentation import segment_timeseries
    from excite.logs.synthetic import synthetic_log

    log = synthetic_log(np.random.default_rng(5), 60, TRUTH, sensor)
    result = calibrate(segment_timeseries(log.series).segments)
    assert result.identifiable and np.all(np.isfinite(result.std))
    np.testing.assert_allclose(result.params.as_array(), TRUTH.as_array(), rtol=1e-5)


def test_data_that_determine_nothing_are_reported_not_a_crash():
    """Small noisy motions: every direction is weak, all are frozen in the refit (an empty
    step basis), and the result says so instead of failing inside the solver."""
    from excite.core.kinematics import predict_increment

    rng = np.random.default_rng(0)
    phi_L, phi_R = rng.uniform(-0.2, 0.2, 10), rng.uniform(-0.2, 0.2, 10)
    measured = np.column_stack(predict_increment(phi_L, phi_R, TRUTH))
    measured += rng.normal(0.0, 0.02, measured.shape)
    result = calibrate(Segments(phi_L, phi_R, *measured.T))
    assert not result.identifiable and result.unidentifiable_direction


def test_a_direction_the_damping_hides_is_still_fitted(rng):
    """Spins measured by a heading far more precise than the positions (1e-7 rad against
    1 mm): the ratios r/b are known 1e6 times better than the common scale (which the data
    still determine: relative std 0.6%), so the damping lam diag(F) shrinks a step along the
    scale far below the relative tolerance while the scale is 1% off. The fit must not stop
    there (it did, as converged: the 1-hour log's b ended 1.7 std from the optimum): the
    Gauss-Newton step decides."""
    from excite.calibration.solver import Problem, levenberg_marquardt
    from excite.core.models import AXLE

    n = 200
    turn = rng.uniform(2.0, 6.0, n) * rng.choice([-1, 1], n)
    seg = exact_segments(-turn + rng.normal(0, 0.5, n), turn)
    sigma = np.array([1e-3, 1e-3, 1e-7])
    fit = levenberg_marquardt(Problem(AXLE, seg), 1.01 * TRUTH.as_array(), sigma, "linear",
                              determined=20.0)
    assert fit.converged
    np.testing.assert_allclose(fit.theta, TRUTH.as_array(), rtol=1e-6)


def test_a_gauss_newton_step_that_only_rounds_the_cost_ends_the_fit():
    """Noisy spins as above, 60 segments: at the optimum the damped step is below the
    tolerance, the Gauss-Newton step just above it and rejected (its cost change is
    rounding). The fit must end there, converged, not alternate the two until the iteration
    limit (it did on 4 of these 80 seeds, ending "not converged" after 100 iterations)."""
    from excite.calibration.solver import Problem, levenberg_marquardt
    from excite.core.models import AXLE

    sigma = np.array([1e-3, 1e-3, 1e-7])
    for seed in range(80):
        rng = np.random.default_rng(seed)
        turn = rng.uniform(2.0, 6.0, 60) * rng.choice([-1, 1], 60)
        seg = exact_segments(-turn + rng.normal(0, 0.5, 60), turn, TRUTH, sigma, rng)
        fit = levenberg_marquardt(Problem(AXLE, seg), 1.01 * TRUTH.as_array(), sigma,
                                  "linear", determined=20.0)
        assert fit.converged and fit.iterations < 30, (seed, fit.iterations, fit.message)


def test_a_wild_step_that_underflows_a_length_is_damped_not_a_crash():
    """Levenberg-Marquardt from a wheel separation thousands of metres off, on straight runs
    that do not determine it (a stopping rule's early look at a back-and-forth drive, the two
    turning segments weighted 0 as gross errors): the SVD step of log b is about -1150, exp()
    underflows b to 0, and the trial must be rejected (more damping), not evaluated (it was a
    ZeroDivisionError in the arc)."""
    from excite.calibration.gross_errors import _Weights
    from excite.calibration.solver import Problem, levenberg_marquardt
    from excite.core.models import AXLE

    back, forth = -18.372487896506325, 18.372487896506325
    rows = np.array([
        [13.430001797938788, -19.185497714085713, 0.02902169923943009, 0.012755563221616036,
         -5.159671661949551],
        [19.75613856717917, forth, 0.5135580805794787, -0.6751338699831184, -1.021672171512282],
        [back, back, -0.5704819681122023, 0.0051778469052577505, 0.05591714786991142],
        [forth, forth, 0.573226526617462, 0.04398094616510296, 0.012201663523796799],
        [back, back, -0.570329541195666, 0.004489267618013162, 0.05686254056095785],
        [forth, forth, 0.5716099141157344, 0.04636400595886629, 0.013189053304776762],
        [back, back, -0.5707367392412538, 0.003087791989817349, 0.053483808575052125],
        [forth, forth, 0.5719986706781601, 0.045395726872194495, 0.009733891242796716],
        [back, back, -0.5723245479409277, 0.0001446589043173146, 0.05728388708744291],
        [forth, forth, 0.5665786964857306, 0.04784665572344586, 0.01114700519782991],
        [back, back, -0.5715936247979089, 0.002701413075902213, 0.05390340904953445]])
    weights = np.r_[0.0, 0.0, np.ones(9)]
    problem = Problem(AXLE, Segments(*rows.T), _Weights(weights))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit = levenberg_marquardt(
            problem, np.array([0.03186269350755853, 0.030303724654336804, 4346.585306891844]),
            np.array([0.0017959880508495879, 0.03073200543034573, 0.04440131963604238]),
            "linear", determined=10.0)
    assert np.all(np.isfinite(fit.theta)) and np.all(fit.theta > 0)
