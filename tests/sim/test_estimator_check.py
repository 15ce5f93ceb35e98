"""The environment's estimator check on every env id, the sensor-pose one included."""

import numpy as np
import pytest

from envs.estimator_check import check_estimator
from excite import OnlineEstimator, Params
from excite.stats.consistency import anees_bounds, estimate_error, nees, verdict


class _WheelsOnly:
    """A user's estimator that knows nothing of the sensor pose: 3 parameters, 3x3
    covariance, no theta (wraps the wheels-only OnlineEstimator)."""

    def __init__(self, nominal, sigma):
        self._inner = OnlineEstimator(Params(*np.asarray(
            nominal if isinstance(nominal, Params) else nominal[:3], float)), sigma=sigma)

    def update(self, *row):
        self._inner.update(*row)

    @property
    def params(self):
        return self._inner.params

    @property
    def covariance(self):
        return self._inner.covariance


def test_sensor_env_judges_all_six_parameters_of_a_sensor_pose_estimator():
    report = check_estimator("excite/DiffDriveCalibSensor-v0", episodes=4, budget=12)
    assert report.rmse.shape == (12, 6) and report.parameters == 6
    assert report.anees_bounds == anees_bounds(4, 6)
    assert np.all(np.isfinite(report.anees)) and report.nees_final.shape == (4,)
    assert "l_theta" in report.summary()
    assert report.verdict == verdict(report.anees[-1], report.anees_bounds)


def test_sensor_env_judges_a_wheels_only_estimator_on_the_wheels():
    report = check_estimator("excite/DiffDriveCalibSensor-v0", _WheelsOnly, episodes=3,
                             budget=8)
    assert report.rmse.shape == (8, 3)
    assert report.anees_bounds == anees_bounds(3, 3)


def test_estimate_error_takes_theta_and_the_marginal_block():
    class Six:
        params = Params(0.05, 0.051, 0.3)
        theta = np.array([0.05, 0.051, 0.3, 0.1, -0.02, 0.03])
        covariance = np.diag([1e-6, 2e-6, 3e-6, 1e-4, 1e-4, 1e-3])

    truth = np.array([0.0501, 0.0508, 0.301, 0.09, -0.01, 0.0])
    error, covariance = estimate_error(Six(), truth)
    np.testing.assert_allclose(error, Six.theta - truth)
    assert covariance.shape == (6, 6)
    error, covariance = estimate_error(Six(), truth[:3])  # an axle truth: wheels only
    np.testing.assert_allclose(error, Six.theta[:3] - truth[:3])
    np.testing.assert_array_equal(covariance, Six.covariance[:3, :3])
    expected = sum(e * e / v for e, v in zip(error, np.diag(Six.covariance)[:3], strict=True))
    assert nees(error, covariance) == pytest.approx(expected)


def test_verdict_sides():
    assert verdict(3.0, (2.5, 3.5)) == "consistent"
    assert verdict(3.5, (2.5, 3.5)) == "consistent"
    assert verdict(9.0, (2.5, 3.5)) == "over-confident"
    assert verdict(1.0, (2.5, 3.5)) == "under-confident"
    assert verdict(float("nan"), (2.5, 3.5)) == "undefined"
