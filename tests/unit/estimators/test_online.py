import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excite import OnlineEstimator, Params, calibrate
from excite.core.information import fisher_information, scaled_jacobian, sigma_min
from excite.logs.synthetic import lesson_dataset
from tests.conftest import TRUTH

NOMINAL = Params(0.05, 0.05, 0.30)
SIGMA = (2e-3, 2e-3, 1e-3)


def run(est: OnlineEstimator, seg) -> OnlineEstimator:
    for row in seg.as_array():
        est.update(*row)
    return est


@pytest.mark.parametrize("sigma", [(2e-3, 2e-3, 1e-3), (5e-4, 5e-4, 1e-2), (5e-3, 5e-3, 2e-4)])
def test_agrees_with_batch_well_within_one_std(rng, sigma):
    seg = lesson_dataset(rng, 200, TRUTH, sigma=sigma)
    batch = calibrate(seg, sigma=sigma)
    online = run(OnlineEstimator(NOMINAL, sigma=sigma), seg)
    z = (online.params.as_array() - batch.params.as_array()) / batch.std
    assert np.all(np.abs(z) < 0.3), z  # the rest is the 10% prior
    # Posterior = batch information plus the prior's (10% of nominal by default).
    prior_information = np.diag(1 / (0.1 * NOMINAL.as_array()) ** 2)
    expected = np.linalg.inv(np.linalg.inv(batch.covariance) + prior_information)
    np.testing.assert_allclose(online.covariance, expected, rtol=0.05, atol=1e-3 * expected.max())


def test_information_and_sigma_min_follow_the_definition(rng):
    seg = lesson_dataset(rng, 300, TRUTH)
    online = run(OnlineEstimator(NOMINAL, sigma=SIGMA), seg)
    # The online information sums each segment's Jacobian at the estimate of its time;
    # at convergence it matches the batch information at the final estimate.
    batch_info = fisher_information(
        scaled_jacobian(seg.dphi_L, seg.dphi_R, online.params, SIGMA, scale=NOMINAL))
    np.testing.assert_allclose(online.information, batch_info, rtol=0.02)
    assert online.sigma_min == pytest.approx(sigma_min(batch_info), rel=0.02)


def test_no_motion_segments_change_nothing_and_never_nan():
    est = OnlineEstimator(NOMINAL, sigma=SIGMA)
    before = est.covariance.copy()
    for _ in range(100):
        est.update(0.0, 0.0, 1e-3, -2e-3, 5e-4)
    np.testing.assert_allclose(est.params.as_array(), NOMINAL.as_array(), rtol=1e-15)
    np.testing.assert_array_equal(est.covariance, before)
    assert est.sigma_min == 0.0
    assert est.n_segments == 100


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.tuples(*[st.floats(-1e3, 1e3)] * 5), min_size=1, max_size=20))
def test_never_produces_nan_or_non_physical_values(rows):
    est = OnlineEstimator(NOMINAL, sigma=SIGMA)
    for row in rows:
        est.update(*row)
        p = est.params.as_array()
        assert np.all(np.isfinite(p)) and np.all(p > 0)
        assert np.all(np.isfinite(est.covariance))


def test_wraps_heading_residuals():
    p = Params(0.05, 0.05, 0.3)
    a = OnlineEstimator(p, sigma=SIGMA)
    b = OnlineEstimator(p, sigma=SIGMA)
    a.update(-10.0, 10.0, 0.0, 0.0, 10.0 / 3.0)
    b.update(-10.0, 10.0, 0.0, 0.0, 10.0 / 3.0 - 2 * math.pi)
    np.testing.assert_allclose(a.params.as_array(), b.params.as_array(), rtol=1e-12)


def test_rejects_bad_input():
    with pytest.raises(ValueError, match="prior_std"):
        OnlineEstimator(NOMINAL, prior_std=-1.0)
    with pytest.raises(ValueError, match="sigma"):
        OnlineEstimator(NOMINAL, sigma=(0, 1, 1))
    with pytest.raises(ValueError, match="finite"):
        OnlineEstimator(NOMINAL).update(1.0, float("nan"), 0, 0, 0)


def test_pickles(rng):
    est = run(OnlineEstimator(NOMINAL, sigma=SIGMA), lesson_dataset(rng, 20, TRUTH))
    clone = pickle.loads(pickle.dumps(est))
    assert clone.params == est.params
    np.testing.assert_array_equal(clone.information, est.information)


def sensor_dataset(rng, n, theta, sigma=SIGMA):
    from excite import Segments
    from excite.core.models import SENSOR_POSE

    phi_L, phi_R = rng.normal(0.0, 0.4, n), rng.normal(0.0, 0.4, n)
    measured = SENSOR_POSE.predict(phi_L, phi_R, theta) + rng.normal(size=(n, 3)) * sigma
    return Segments(phi_L, phi_R, *measured.T)


def test_sensor_pose_model_online_agrees_with_batch(rng):
    from excite.core.models import SENSOR_POSE

    truth = np.array([0.050, 0.051, 0.300, 0.05, -0.03, 0.3])
    nominal = np.array([0.05, 0.05, 0.30, 0.04, -0.02, 0.2])
    seg = sensor_dataset(rng, 400, truth)
    batch = calibrate(seg, sigma=SIGMA, sensor_pose="estimate")
    online = run(OnlineEstimator(nominal, sigma=SIGMA, model=SENSOR_POSE), seg)
    batch_theta = np.append(batch.params.as_array(), batch.sensor_pose.as_array())
    z = (online.theta - batch_theta) / np.sqrt(np.diag(batch.full_covariance))
    assert np.all(np.abs(z) < 0.3), z
    assert online.covariance.shape == (6, 6) and online.information.shape == (6, 6)
    expected = sigma_min(fisher_information(scaled_jacobian(
        seg.dphi_L, seg.dphi_R, online.theta, SIGMA, scale=nominal, model=SENSOR_POSE)))
    assert online.sigma_min == pytest.approx(expected, rel=0.05)
    assert online.sensor_pose is not None and online.params.b == pytest.approx(0.3, rel=0.05)


def _batch_rows(rng, model, nominal, n, k):
    """k segments for each of n robots with hidden parameters near ``nominal``, (n, k, 5)."""
    truth = nominal * rng.uniform(0.97, 1.03, (n, model.size))
    phi = rng.uniform(-15, 15, (n, k, 2))
    measured = np.stack([model.predict(phi[i, :, 0], phi[i, :, 1], truth[i])
                         for i in range(n)]) + rng.normal(size=(n, k, 3)) * SIGMA
    return np.concatenate([phi, measured], axis=2)


@pytest.mark.parametrize("model_name", ["axle", "sensor_pose"])
def test_batched_filters_are_the_single_filter_each(rng, model_name):
    """Filter i of BatchOnlineEstimator fed its own segments (some robots skipping some steps,
    one restarted midway) is OnlineEstimator fed the same, to 1e-10 relative: the single
    filter's one-robot specialisations (pure-Python model, unrolled on the axle) order their
    arithmetic differently and take Python's exp, the batch numpy's: the last bits differ,
    and 30 updates grow that to a few 1e-12, a millionth of the estimates' std."""
    from excite.core.models import AXLE, SENSOR_POSE
    from excite.estimators.online import BatchOnlineEstimator

    model = AXLE if model_name == "axle" else SENSOR_POSE
    nominal = np.array([0.05, 0.05, 0.30, 0.04, -0.02, 0.2])[:model.size]
    n, k = 7, 30
    rows = _batch_rows(rng, model, nominal, n, k)
    batch = BatchOnlineEstimator(n, nominal, sigma=SIGMA, model=model)
    singles = [OnlineEstimator(nominal, sigma=SIGMA, model=model) for _ in range(n)]
    for j in range(k):
        mask = rng.uniform(size=n) < 0.8
        if j == 12:
            restart = np.arange(n) == 3
            batch.reset(restart)
            singles[3] = OnlineEstimator(nominal, sigma=SIGMA, model=model)
        batch.update(rows[:, j], mask)
        for i in np.flatnonzero(mask):
            singles[i].update(*rows[i, j])
    expected_theta = np.array([s.theta for s in singles])
    expected_information = np.array([s.information for s in singles])
    assert batch.n_segments.tolist() == [s.n_segments for s in singles]
    assert not np.allclose(batch.theta, nominal, rtol=1e-3)  # the filters moved
    rtol = 1e-10
    np.testing.assert_allclose(batch.theta, expected_theta, rtol=rtol, atol=0)
    np.testing.assert_allclose(batch.information, expected_information, rtol=100 * rtol,
                               atol=1e-9 * np.abs(expected_information).max())


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.lists(st.tuples(*[st.floats(-1e3, 1e3)] * 5), min_size=3, max_size=3),
       st.integers(1, 6))
def test_batched_filters_never_produce_nan_or_non_physical_values(rows, repeats):
    """Wild segments (the trust region, no motion, huge increments) in a batch of three, each
    repeated: every filter stays finite and positive. (Agreement with the single filter is
    tested on real segments above: on segments the model cannot fit, the wrapped heading
    residual makes the update discontinuous, so last-bit differences may pick another
    branch.)"""
    from excite.estimators.online import BatchOnlineEstimator

    batch = BatchOnlineEstimator(3, NOMINAL, sigma=SIGMA)
    for _ in range(repeats):
        batch.update(np.array(rows), np.ones(3, dtype=bool))
        assert np.all(np.isfinite(batch.theta)) and np.all(batch.theta > 0)
        assert np.all(np.isfinite(batch.information))


def test_batched_filters_reject_non_finite_segments_and_solve_around_singular_systems():
    from excite.estimators.online import BatchOnlineEstimator, _solve_each

    batch = BatchOnlineEstimator(2, NOMINAL, sigma=SIGMA)
    with pytest.raises(ValueError, match="finite"):
        batch.update(np.array([[1.0, 1.0, 0.0, 0.0, 0.0], [np.nan, 1.0, 0.0, 0.0, 0.0]]),
                     np.ones(2, dtype=bool))
    # a masked-out robot's row is not read
    batch.update(np.array([[1.0, 1.0, 0.05, 0.0, 0.0], [np.nan] * 5]),
                 np.array([True, False]))
    assert batch.n_segments.tolist() == [1, 0]
    m = np.array([np.eye(3), np.zeros((3, 3)), 2 * np.eye(3)])
    out = _solve_each(m, np.ones((3, 3, 1)))
    np.testing.assert_array_equal(out[[0, 2], :, 0], [[1.0] * 3, [0.5] * 3])
    assert np.isnan(out[1]).all()
