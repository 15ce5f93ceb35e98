"""The driving tests of the fit (excite.calibration.slip_tests): their size on data the noise
model describes, what they measure, and the parameters that change with the driving."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from excite import calibrate
from excite.calibration.fit_tests import ONE_ARC_WORDS, _with_driving_tests, pooled_over_kinds
from excite.calibration.heterogeneity import Heterogeneity
from excite.calibration.result import FitTest
from excite.calibration.slip_tests import DRIVING, FAMILY_LEVEL, DrivingTest, driving_measures
from excite.core.kinematics import Params, predict_increment
from excite.core.models import SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.segments import Segments
from excite.logs.synthetic import lesson_dataset, synthetic_log
from excite.stats.chi2 import chi2_quantile

TRUTH = Params(0.050, 0.051, 0.300)


def test_the_measures_come_from_the_wheels_at_the_fitted_parameters():
    """Turn rate |r_R dphi_R - r_L dphi_L| / (b T), wheel speed max |r dphi| / T and, without
    sub-steps, the change of the wheel speeds from the previous segment (the first gets the
    median of the others); the measured poses play no part."""
    seg = Segments(np.array([1.0, 2.0, -1.0]), np.array([1.0, 0.0, 1.0]), np.zeros(3),
                   np.zeros(3), np.zeros(3), t_start=np.array([0.0, 2.0, 4.0]),
                   t_end=np.array([2.0, 4.0, 5.0]))
    measures = driving_measures(seg, np.array([0.05, 0.1, 0.5]))
    assert tuple(measures) == DRIVING
    np.testing.assert_allclose(measures["turn rate"], [0.05 / 0.5 / 2, 0.1 / 0.5 / 2,
                                                       0.15 / 0.5])
    np.testing.assert_allclose(measures["wheel speed"], [0.05, 0.05, 0.1])
    change = [abs(1.0 - 0.5) + abs(0.0 - 0.5), abs(-1.0 - 1.0) + abs(1.0 - 0.0)]
    np.testing.assert_allclose(measures["acceleration"], [np.median(change), *change])
    moved = Segments(seg.dphi_L, seg.dphi_R, np.ones(3), np.ones(3), np.ones(3),
                     t_start=seg.t_start, t_end=seg.t_end)
    for name, values in driving_measures(moved, np.array([0.05, 0.1, 0.5])).items():
        np.testing.assert_array_equal(values, measures[name])
    # of some segments only: the same values, each change still from the segment before
    for name, values in driving_measures(seg, np.array([0.05, 0.1, 0.5]),
                                         np.array([1, 2])).items():
        np.testing.assert_allclose(values, measures[name][1:])


@pytest.mark.slow
@pytest.mark.statistical
def test_size_on_independent_segments_the_model_describes():
    """The lesson's data sets (30 segments, exact kinematics, Gaussian noise): each driving
    test's score statistic is chi-square with its dof when nothing changes with the driving.
    Over 40 data sets x 3 tests (120 draws) the share above the 90% quantile is 0.1 (binomial
    std 0.027: within 0.03-0.2), the mean of statistic / dof near 1 (std of the mean about
    0.1: within 0.7-1.3), and the fit is failed by a driving test in at most 3 of the 40
    (the family at 1 - DRIVING_TEST_LEVEL = 1%: P(4 or more) ~ 7e-4)."""
    above, ratios, failed = [], [], 0
    for seed in range(40):
        result = calibrate(lesson_dataset(np.random.default_rng([seed, 12]), n=30))
        tests = result.fit.driving_tests
        assert tests is not None and [t.driving for t in tests] == list(DRIVING)
        for t in tests:
            above.append(t.statistic > chi2_quantile(0.9, t.dof))
            ratios.append(t.statistic / t.dof)
            assert t.threshold == pytest.approx(chi2_quantile(FAMILY_LEVEL, t.dof))
        failed += any(t.failed for t in tests)
    assert 0.03 <= np.mean(above) <= 0.2
    assert 0.7 <= np.mean(ratios) <= 1.3
    assert failed <= 3


@pytest.mark.slow
@pytest.mark.statistical
def test_size_on_logs_the_model_describes():
    """Synthetic time-series logs (pose noise, random wheel slip the noise model describes,
    an off-axle sensor): 12 logs of 40 s x 3 tests (36 draws): the share of statistics above
    the 90% quantile within 0-0.3 (binomial, mean 0.1, std 0.05), the growth p-values above
    0.1 in most (share of p < 0.1 at most 0.35: its mean is at most 0.1), and no fit failed
    by a driving test."""
    above, growth_small = [], []
    for seed in range(12):
        log = synthetic_log(np.random.default_rng([seed, 34]), 40.0, TRUTH,
                            SensorPose(0.1, -0.03, 0.2), pose_noise=(0.002, 0.002),
                            slip=0.01 * (seed % 2))
        result = calibrate(segment_timeseries(log.series).segments)
        assert result.fit.ok, result.fit.message
        for t in result.fit.driving_tests or ():
            above.append(t.statistic > chi2_quantile(0.9, t.dof))
            growth_small.append(t.growth < 0.1)
    assert len(above) == 36
    assert np.mean(above) <= 0.3
    assert np.mean(growth_small) <= 0.35


def _slipping_segments(rng: np.random.Generator, n: int) -> Segments:
    """Independent segments whose wheels lose a share of their turn that grows with the turn
    rate (up to 8% in the hardest turns), with noise that grows with it too: slip in turns."""
    mean = rng.normal(0.0, 1.0, n)
    diff = rng.normal(0.0, 0.6, n) * rng.choice([0.2, 3.0], n)
    dphi_L, dphi_R = mean - diff, mean + diff
    turn = np.abs(diff) / 3.0
    lost = 1.0 - 0.08 * np.minimum(turn, 1.0)
    moved = np.column_stack(predict_increment(dphi_L * lost, dphi_R * lost, TRUTH))
    noise = rng.normal(size=(n, 3)) * np.array([2e-3, 2e-3, 1e-3]) * (1.0 + 4.0 * turn)[:, None]
    return Segments(dphi_L, dphi_R, *(moved + noise).T)


def test_slip_in_turns_fails_the_fit_with_the_reason():
    """Wheels that lose more of their turn the harder they turn, with residuals that grow:
    the turn-rate test finds the parameters changing with the turn rate and the residuals
    growing (slipping), and fails the fit in words."""
    result = calibrate(_slipping_segments(np.random.default_rng(5), 200))
    turn = next(t for t in result.fit.driving_tests if t.driving == "turn rate")
    assert turn.failed and turn.slipping and turn.statistic > turn.threshold
    assert not result.fit.ok
    assert "calibrate on gentler driving" in result.fit.message
    assert "turn" in result.fit.message or "accelerate" in result.fit.message


def _driving(driving: str, slipping: bool) -> DrivingTest:
    """A failed driving test of the turn rate or wheel speed (its numbers illustrative)."""
    return DrivingTest(driving, 40.0, 3, 18.6, 5.0, ("r_L", "b"), 0.5 if not slipping else 1e-9,
                       np.array([1.0, 1.2, 3.0]), None, None, True, slipping)


@pytest.mark.parametrize("slipping, by, lifted", [(False, "motion", True),
                                                  (True, "motion", False),
                                                  (False, "logs", False)])
def test_a_pool_over_kinds_of_motion_covers_a_change_that_is_not_slip(slipping, by, lifted):
    """A driving test that failed the fit only by the parameters changing with the turn rate
    (the residuals fitting gentle and hard turns alike) is what the std widened by the log's
    kinds of motion's spread cover: the fit passes, saying so. A slipping one (residuals
    growing) still fails; a pool over logs (their own fit tests apply) changes nothing."""
    result = calibrate(lesson_dataset(np.random.default_rng(3), n=60))
    tests = (_driving("turn rate", slipping),)
    failed = _with_driving_tests(FitTest(True, "no alternative to test against"), tests,
                                 one_arc=False)
    assert not failed.ok and "with the turn rate" in failed.message
    assert "no arcs" not in failed.message
    one_arc = _with_driving_tests(FitTest(True, "no alternative to test against"), tests,
                                  one_arc=True)
    assert one_arc.message == failed.message + ONE_ARC_WORDS
    assert ("the residuals grow" in failed.message) == slipping
    pool = Heterogeneity(by, True, 30.0, 3, 1e-5, (), np.zeros(3), "random effects", (), "",
                         result.params.as_array(), result.covariance, np.zeros((3, 3)),
                         np.eye(6))
    out = pooled_over_kinds(replace(result, fit=failed, heterogeneity=pool))
    assert out.fit.ok == lifted
    if lifted:
        assert "kinds of motion differ, which the std cover" in out.fit.message
    else:
        assert out.fit == failed


def test_many_independent_segments_are_tested_on_an_evenly_spaced_share():
    """Beyond MAX_TESTED independent segments the tests use MAX_TESTED of them (the cost
    bounded): the lesson's data set of MAX_TESTED + 5000 segments is tested and passes."""
    from excite.calibration.slip_tests import MAX_TESTED

    result = calibrate(lesson_dataset(np.random.default_rng(4), n=MAX_TESTED + 5000))
    tests = result.fit.driving_tests
    assert tests is not None and len(tests) == 3 and result.fit.ok
