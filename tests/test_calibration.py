import json

import numpy as np
import pytest

from excite import Params, calibrate
from excite.calibration import initial_estimate
from excite.information import crlb_relative_std, fisher_information, scaled_jacobian
from excite.synthetic import lesson_dataset

from .conftest import TRUTH, exact_segments, spin_segments, straight_segments


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
    plain = calibrate(rows)
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
