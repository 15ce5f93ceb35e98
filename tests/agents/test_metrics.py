"""Decision metrics: hand-computable cases and properties."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.metrics import MetricError, error_time_area, paired_ratio, time_to_accuracy
from excite import ExciteError
from excite.stats.consistency import anees, anees_bounds, nees

# -- consistency ----------------------------------------------------------------------------


def test_nees_by_hand():
    assert nees([1.0, 2.0, 0.0], np.diag([1.0, 4.0, 9.0])) == pytest.approx(2.0)
    # [[2, 1], [1, 2]]^-1 (1, 1) = (1/3, 1/3)
    assert nees([1.0, 1.0], [[2.0, 1.0], [1.0, 2.0]]) == pytest.approx(2.0 / 3.0)


def test_nees_is_nan_where_the_covariance_says_nothing():
    errors = np.ones((3, 2))
    covariances = np.array([np.eye(2), [[1.0, 1.0], [1.0, 1.0]], [[np.inf, 0.0], [0.0, 1.0]]])
    values = nees(errors, covariances)
    assert values[0] == pytest.approx(2.0)
    assert np.isnan(values[1]) and np.isnan(values[2])


def test_anees_averages_over_episodes_per_segment():
    # 2 episodes x 2 segments x 1 parameter, unit variances: NEES = error^2.
    errors = np.array([[[1.0], [2.0]], [[3.0], [0.0]]])
    covariances = np.ones((2, 2, 1, 1))
    np.testing.assert_allclose(anees(errors, covariances), [5.0, 2.0])
    with pytest.raises(MetricError, match="shaped"):
        anees(np.zeros((2, 3)), np.zeros((2, 3, 3)))


def test_anees_bounds_are_the_chi_square_table():
    # chi-square with 1 degree of freedom: 2.5% point 0.000982, 97.5% point 5.024.
    low, high = anees_bounds(1, 1)
    assert low == pytest.approx(0.000982, rel=1e-3) and high == pytest.approx(5.024, rel=1e-3)
    # 10 episodes x 2 parameters: chi2(20) 2.5% and 97.5% points 9.591 and 34.170, / 10.
    low, high = anees_bounds(10, 2)
    assert low == pytest.approx(0.9591, rel=1e-3) and high == pytest.approx(3.4170, rel=1e-3)


def test_a_consistent_estimator_is_inside_the_bounds_95_percent_of_the_time():
    """Errors drawn from the reported covariance: M x ANEES is chi-square(M P), so 95% of
    independent Monte Carlo runs fall inside the bounds."""
    rng = np.random.default_rng(7)
    runs, episodes, p = 4000, 20, 3
    a = rng.normal(size=(p, p))
    covariance = a @ a.T + p * np.eye(p)
    # (episodes, runs, p): the runs stand where the segments usually are
    errors = rng.multivariate_normal(np.zeros(p), covariance, size=(episodes, runs))
    values = anees(errors, np.broadcast_to(covariance, (episodes, runs, p, p)))
    low, high = anees_bounds(episodes, p)
    inside = np.mean((values >= low) & (values <= high))
    assert abs(inside - 0.95) < 4 * np.sqrt(0.95 * 0.05 / runs), inside


@settings(deadline=None)
@given(st.integers(1, 500), st.integers(1, 6), st.floats(0.5, 0.99))
def test_anees_bounds_bracket_the_expected_value_and_narrow_with_episodes(m, p, confidence):
    low, high = anees_bounds(m, p, confidence)
    assert 0 < low < p < high
    wider_low, wider_high = anees_bounds(m, p, min(confidence + 0.005, 0.999))
    assert wider_low <= low and high <= wider_high
    more_low, more_high = anees_bounds(m + 10, p, confidence)
    assert low <= more_low and more_high <= high


def test_anees_bounds_reject_nonsense():
    with pytest.raises(MetricError):
        anees_bounds(0, 3)
    with pytest.raises(MetricError, match="confidence"):
        anees_bounds(10, 3, confidence=1.0)
    assert issubclass(MetricError, ExciteError)


# -- time to accuracy -----------------------------------------------------------------------

ERRORS = [0.1, 0.004, 0.006, 0.003, 0.001]
TIME = [1.0, 2.0, 3.0, 4.0, 5.0]
DISTANCE = [0.5, 0.5, 1.5, 2.5, 2.5]  # the robot stood still in segments 2 and 5


def test_time_to_accuracy_by_hand():
    reached = time_to_accuracy(ERRORS, 0.005, TIME, DISTANCE)
    # below from index 3 on (index 2 is 0.006): 4 segments, 4 s, 2.5 m
    assert (reached.segments, reached.seconds, reached.metres) == (4.0, 4.0, 2.5)
    assert not reached.censored
    assert time_to_accuracy(ERRORS, 0.01, TIME).segments == 2.0
    assert time_to_accuracy(ERRORS, 0.2).segments == 1.0
    never = time_to_accuracy(ERRORS, 0.001, TIME, DISTANCE)  # the last is 0.001: not below
    assert never.censored
    assert never.segments == never.seconds == never.metres == np.inf
    assert time_to_accuracy(ERRORS, 0.005).seconds is None


def test_time_to_accuracy_per_episode_and_nan_is_not_accurate():
    errors = np.array([ERRORS, [0.1, 0.001, np.nan, 0.001, 0.001], [0.1] * 5])
    result = time_to_accuracy(errors, 0.005, np.tile(TIME, (3, 1)))
    np.testing.assert_array_equal(result.segments, [4.0, 4.0, np.inf])
    np.testing.assert_array_equal(result.censored, [False, False, True])
    with pytest.raises(MetricError, match="time must be shaped"):
        time_to_accuracy(errors, 0.005, TIME)
    with pytest.raises(MetricError, match="threshold"):
        time_to_accuracy(errors, 0.0)


errors_strategy = st.lists(st.floats(0.0, 0.02), min_size=1, max_size=30)


@given(errors_strategy, st.floats(1e-4, 0.02))
def test_time_to_accuracy_definition(errors, threshold):
    errors = np.array(errors)
    result = time_to_accuracy(errors, threshold, np.cumsum(np.ones_like(errors)))
    assert bool(result.censored) == (errors[-1] >= threshold)
    if result.censored:
        assert result.segments == result.seconds == np.inf
    else:
        k = int(result.segments) - 1
        assert np.all(errors[k:] < threshold)
        assert k == 0 or errors[k - 1] >= threshold
        assert result.seconds == k + 1


@given(errors_strategy, st.floats(1e-4, 0.02), st.floats(1e-4, 0.02))
def test_a_stricter_threshold_takes_at_least_as_long(errors, a, b):
    strict, loose = sorted((a, b))
    time = np.cumsum(np.full(len(errors), 0.5))
    slow = time_to_accuracy(errors, strict, time)
    fast = time_to_accuracy(errors, loose, time)
    assert slow.segments >= fast.segments and slow.seconds >= fast.seconds
    assert fast.censored <= slow.censored  # censored at the loose threshold: also strict


# -- error-time area ------------------------------------------------------------------------


def test_error_time_area_by_hand():
    assert error_time_area([0.01, 0.01, 0.01], [0.0, 1.0, 3.0]) == pytest.approx(0.03)
    # a triangle: 0.02 falling to 0 over 2 s, then 0 for a second
    assert error_time_area([0.02, 0.0, 0.0], [1.0, 3.0, 4.0]) == pytest.approx(0.02)
    np.testing.assert_allclose(error_time_area([[1.0, 1.0], [2.0, 0.0]], [[0, 2], [0, 1]]),
                               [2.0, 1.0])
    with pytest.raises(MetricError, match="time must be shaped"):
        error_time_area([1.0, 2.0], [1.0])


@given(st.lists(st.tuples(st.floats(0.0, 1.0, allow_subnormal=False), st.floats(0.01, 10.0)),
                min_size=2, max_size=30))
def test_error_time_area_lies_between_the_extremes_times_the_span(samples):
    errors, steps = np.array(samples).T
    time = np.cumsum(steps)
    span = time[-1] - time[0]
    area = error_time_area(errors, time)
    assert errors.min() * span * (1 - 1e-12) <= area <= errors.max() * span * (1 + 1e-12)


# -- paired ratio ---------------------------------------------------------------------------


def test_paired_ratio_by_hand():
    rng = np.random.default_rng(0)
    base = np.array([0.01, 0.03, 0.02, 0.05])
    same = paired_ratio(base, base, rng)
    assert same.ratio == 1.0 and same.ci == (1.0, 1.0)  # every resample is 1
    half = paired_ratio(base / 2, base, rng)
    assert half.ratio == pytest.approx(0.5) and half.ci == pytest.approx((0.5, 0.5))
    # medians 2.5 and 25 (unpaired orders do not matter for the point estimate)
    assert paired_ratio([1, 2, 3, 4], [40, 30, 20, 10], rng).ratio == pytest.approx(0.1)
    assert (same.confidence, same.n_boot) == (0.95, 2000)


def test_paired_ratio_with_censored_times():
    rng = np.random.default_rng(0)
    never = np.full(5, np.inf)
    beaten = paired_ratio([3.0, 4.0, 5.0, 6.0, 7.0], never, rng)
    assert beaten.ratio == 0.0 and beaten.ci == (0.0, 0.0)
    assert paired_ratio(never, [3.0, 4.0, 5.0, 6.0, 7.0], rng).ratio == np.inf
    assert np.isnan(paired_ratio(never, never, rng).ratio)


def test_paired_ratio_is_reproducible_and_rejects_bad_input():
    a, b = np.arange(1.0, 11.0), np.arange(2.0, 22.0, 2.0)[::-1]
    one = paired_ratio(a, b, np.random.default_rng(3), n_boot=500)
    two = paired_ratio(a, b, np.random.default_rng(3), n_boot=500)
    assert one == two
    with pytest.raises(MetricError, match="equal-length"):
        paired_ratio([1.0, 2.0], [1.0], np.random.default_rng(0))
    with pytest.raises(MetricError, match="n_boot"):
        paired_ratio([1.0], [1.0], np.random.default_rng(0), n_boot=0)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.floats(1e-6, 1e3), st.floats(1e-6, 1e3)), min_size=1,
                max_size=15), st.integers(0, 2**32 - 1))
def test_the_interval_contains_the_point_estimate(pairs, seed):
    numerator, denominator = np.array(pairs).T
    result = paired_ratio(numerator, denominator, np.random.default_rng(seed), n_boot=200)
    assert result.ci[0] <= result.ratio <= result.ci[1]


def test_the_interval_covers_the_true_ratio_about_95_percent_of_the_time():
    """Episodes of two log-normal metrics with true medians 1 and 2 (ratio 0.5), correlated
    through the shared robot: percentile intervals of 40 episodes cover 0.5 in about 95% of
    repetitions (the percentile bootstrap of a median is approximate and a little
    conservative at this size: within 90-99.5%)."""
    rng = np.random.default_rng(11)
    covered = []
    for _ in range(300):
        robot = rng.normal(size=40)
        numerator = np.exp(0.5 * robot + 0.3 * rng.normal(size=40))
        denominator = 2.0 * np.exp(0.5 * robot + 0.3 * rng.normal(size=40))
        low, high = paired_ratio(numerator, denominator, rng, n_boot=400).ci
        covered.append(low <= 0.5 <= high)
    assert 0.90 <= np.mean(covered) <= 0.995, np.mean(covered)
