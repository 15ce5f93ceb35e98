"""Serial correlation of whitened residuals (excite.stats.autocorrelation): the Ljung-Box test's
size
and power by Monte Carlo, the Newey-West covariance against the Monte-Carlo covariance of a
least-squares fit with autocorrelated errors, the Loewner bound, and calibrate's use of them
on logs whose pose error wanders (synthetic_log's pose_noise_time)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from excite.calibration import covariance, fit_tests
from excite.calibration.options import TEST_LEVEL
from excite.calibration.pipeline import calibrate
from excite.core.models import SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.segments import Segments
from excite.logs.synthetic import synthetic_log
from excite.stats.autocorrelation import (
    LJUNG_BOX_LAGS,
    at_least,
    ljung_box,
    long_run_covariance,
    runs_of,
)


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], rho: float) -> np.ndarray:
    """Stationary AR(1) series along axis -2, unit variance."""
    white = rng.normal(size=shape)
    out = np.empty(shape)
    out[..., 0, :] = white[..., 0, :]
    for k in range(1, shape[-2]):
        out[..., k, :] = rho * out[..., k - 1, :] + np.sqrt(1 - rho**2) * white[..., k, :]
    return out


def test_ljung_box_has_its_size_on_white_residuals_and_power_on_correlated_ones():
    """2000 white (120, 3) residual sets: rejections at 5% within the binomial 99.9% interval
    of 5% (70-132); AR(1) with rho 0.5 is rejected at 0.1% nearly always."""
    rng = np.random.default_rng(0)
    p_white = np.array([ljung_box(w).p_value for w in rng.normal(size=(2000, 120, 3))])
    assert 70 <= np.sum(p_white < 0.05) <= 132
    p_ar = np.array([ljung_box(w).p_value for w in _ar1(rng, (200, 120, 3), 0.5)])
    assert np.mean(p_ar < 1.0 - TEST_LEVEL) > 0.95


def test_ljung_box_of_one_run_is_ljung_and_boxs_statistic():
    """n (n + 2) sum_h rho_h^2 / (n - h), rho_h = sum c_k c_(k+h) / sum c_k^2, per channel."""
    w = np.random.default_rng(2).normal(size=(80, 3))
    c = w - w.mean(axis=0)
    n = len(c)
    reference = sum(n * (n + 2) * np.sum((np.sum(c[h:] * c[:-h], axis=0)
                                          / np.sum(c * c, axis=0)) ** 2) / (n - h)
                    for h in range(1, LJUNG_BOX_LAGS + 1))
    lb = ljung_box(w)
    assert np.isclose(lb.statistic, reference) and lb.dof == 3 * LJUNG_BOX_LAGS


def test_pairs_across_a_gap_are_not_neighbours():
    """Runs of 3 white segments where each run starts with a copy of the previous run's last
    residual: correlated only across the run boundaries. As one run the test rejects; with
    the runs (from the chained flags) it sees lags 1 and 2 inside runs only and does not."""
    rng = np.random.default_rng(3)
    w = rng.normal(size=(600, 3))
    w[3::3] = w[2:-1:3]
    chained = np.ones(600, dtype=bool)
    chained[::3] = False
    runs = runs_of(chained, 600)
    assert ljung_box(w).p_value < 1e-6
    inside = ljung_box(w, runs)
    assert inside.dof == 3 * 2 and inside.p_value > 1e-3
    scores = w[:, :2]
    one_run = long_run_covariance(scores, np.eye(2))
    assert np.allclose(long_run_covariance(scores, np.eye(2), runs_of(np.zeros(600, bool), 600)),
                       scores.T @ scores)  # no two segments in one run: no lag terms
    assert not np.allclose(one_run, scores.T @ scores)


def test_ljung_box_is_not_run_on_logs_too_short_or_flat():
    assert ljung_box(np.ones((5 * LJUNG_BOX_LAGS - 1, 3))) is None
    assert ljung_box(np.zeros((100, 3))) is None


def test_newey_west_matches_the_monte_carlo_covariance_under_autocorrelated_errors():
    """Least squares y = X beta + e, e AR(1) with rho 0.5 (true long-run variance 3x the white
    one): the mean Newey-West variance over 400 fits is within 25% of the Monte-Carlo variance
    of beta-hat (its sampling error is 7% (1 sigma); the Bartlett kernel over 20 lags is 6%
    low for this AR(1), and fitted residuals a little lower still), while the information
    alone under-states it by more than 2x."""
    rng = np.random.default_rng(1)
    n, fits = 1000, 400
    x = np.column_stack([np.ones(n), np.sin(np.arange(n) / 40.0)])
    information = x.T @ x
    inverse = np.linalg.inv(information)
    errors = _ar1(rng, (fits, n, 1), 0.5)[..., 0]
    estimates, variances = [], []
    for e in errors:
        beta = inverse @ x.T @ e
        residual = e - x @ beta
        estimates.append(beta)
        variances.append(np.diag(long_run_covariance(x * residual[:, None], inverse, bandwidth=20)))
    monte_carlo = np.var(estimates, axis=0)
    assert np.allclose(np.mean(variances, axis=0), monte_carlo, rtol=0.25)
    assert np.all(np.diag(inverse) < 0.5 * monte_carlo)


@st.composite
def _spd(draw):
    a = draw(arrays(np.float64, (4, 4), elements=st.floats(-2, 2)))
    return a @ a.T + 1e-3 * np.eye(4)


@settings(max_examples=200, deadline=None)
@given(_spd(), _spd())
def test_at_least_is_above_both_and_leaves_a_larger_covariance_alone(a, b):
    wider = at_least(a, b)
    assert np.linalg.eigvalsh(wider - a).min() > -1e-9 * np.abs(b).max()
    assert np.linalg.eigvalsh(wider - b).min() > -1e-9 * np.abs(b).max()
    assert np.allclose(at_least(a + b, b), a + b)


def _log(seed: int, correlation_time: float):
    log = synthetic_log(np.random.default_rng(seed), 120.0,
                        sensor_pose=SensorPose(0.1, -0.03, 0.4), pose_noise=(0.002, 0.002),
                        pose_noise_time=correlation_time)
    return segment_timeseries(log.series).segments


@pytest.mark.slow
def test_calibrate_widens_the_covariance_only_when_the_residuals_are_correlated(monkeypatch):
    """Pose noise wandering over 20 s (benchmarks: flagged in ~40% of logs): of 8 logs at
    least one is flagged, and each flagged one reports the test and the Newey-West window, and
    its std are no narrower than its model's and wider for some parameter; a log of white
    pose noise keeps the model's covariance."""
    flagged = 0
    for seed in range(8):
        result = calibrate(_log(seed, 20.0), sensor_pose="estimate")
        lb = result.fit.serial_correlation
        assert lb is not None and lb.lags == LJUNG_BOX_LAGS
        if lb.p_value < 1.0 - TEST_LEVEL:
            flagged += 1
            assert result.fit.long_run_bandwidth == LJUNG_BOX_LAGS
            assert "correlated over time" in result.fit.message
            assert result.fit.ok  # widened, not a misfit
            with monkeypatch.context() as m:  # the same fit without the widening
                m.setattr(covariance, "_long_run",
                          lambda mf, inverse, covariance, test, runs: (covariance, test))
                model = calibrate(_log(seed, 20.0), sensor_pose="estimate")
            assert np.all(np.diag(result.full_covariance)
                          >= np.diag(model.full_covariance) * (1 - 1e-9))
            assert np.any(np.diag(result.full_covariance) > np.diag(model.full_covariance))
        else:
            assert result.fit.long_run_bandwidth is None
    assert flagged >= 1
    white = calibrate(_log(100, 0.0), sensor_pose="estimate")
    assert white.fit.serial_correlation.p_value >= 1.0 - TEST_LEVEL
    assert white.fit.long_run_bandwidth is None
    assert "correlated over time" not in white.fit.message


@pytest.mark.slow
def test_calibrate_counts_neighbours_only_inside_each_log(monkeypatch):
    """Two logs calibrated as one data set (flagged and widened): the test and Newey-West see
    two runs."""
    seen = []
    real_ljung_box, real_long_run = fit_tests.ljung_box, covariance.long_run_covariance

    def ljung_box_spy(white, runs=None, *args):
        seen.append(("test", np.unique(runs).size))
        return real_ljung_box(white, runs, *args)

    def long_run_spy(scores, inverse, runs=None, *args):
        seen.append(("widening", np.unique(runs).size))
        return real_long_run(scores, inverse, runs, *args)

    monkeypatch.setattr(fit_tests, "ljung_box", ljung_box_spy)
    monkeypatch.setattr(covariance, "long_run_covariance", long_run_spy)
    both = Segments.concatenate([_log(4, 20.0), _log(5, 20.0)])  # each flagged alone
    result = calibrate(both, sensor_pose="estimate")
    assert ("test", 2) in seen
    assert result.fit.long_run_bandwidth is not None and ("widening", 2) in seen


def test_a_misfit_is_not_blamed_on_serial_correlation():
    """The axle model forced on an off-axle sensor: its residuals are correlated over time
    because the model is wrong; the verdict says the model is wrong, the std are not widened,
    and the message does not suggest a wandering pose source."""
    result = calibrate(_log(0, 0.0), sensor_pose="axle")
    assert not result.fit.ok
    assert result.fit.serial_correlation.p_value < 1.0 - TEST_LEVEL
    assert result.fit.long_run_bandwidth is None
    assert "as a misfit leaves them" in result.fit.message
    assert "wandering" not in result.fit.message


@pytest.mark.slow
def test_the_report_carries_the_test():
    """--json's fit: the test's numbers and the Newey-West window (JSON-clean)."""
    import json

    fit = calibrate(Segments.concatenate([_log(4, 20.0), _log(5, 20.0)]),
                    sensor_pose="estimate").fit.to_dict()
    assert set(fit["serial_correlation"]) == {"statistic", "lags", "dof", "p_value"}
    assert fit["serial_correlation"]["p_value"] < 1.0 - TEST_LEVEL
    assert fit["long_run_bandwidth"] == LJUNG_BOX_LAGS
    json.loads(json.dumps(fit, allow_nan=False))
