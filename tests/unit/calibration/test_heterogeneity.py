"""The heterogeneity test: logs (or kinds of motion) whose r_L, r_R, b disagree beyond their
std are said so, with an estimate whose std covers the spread
(excite.calibration.heterogeneity, excite.stats.meta_analysis)."""

import dataclasses

import numpy as np
import pytest
from scipy import stats
from scipy.linalg import block_diag

from excite import Params, Segments, calibrate, save_segments
from excite.calibration.heterogeneity import LEVEL
from excite.calibration.logs import calibrate_logs
from excite.calibration.motion_kinds import motion_kinds
from excite.logs.synthetic import lesson_dataset, scrubbed_increment
from excite.stats.chi2 import chi2_quantile
from excite.stats.meta_analysis import leave_one_out, pool
from tests.conftest import TRUTH, exact_segments, spin_segments

SIGMA = (2e-3, 2e-3, 1e-3)


def _maneuver(rng, kind: str, n: int = 100, params: Params = TRUTH, scrub: float = 0.0,
              sigma=SIGMA) -> Segments:
    """Segments of tight turning (mostly opposite wheel turns) or of wide arcs (mostly equal
    wheel turns), of a robot whose effective track grows with the turn by ``scrub``."""
    travel, difference = {"tight": (0.15, 0.4), "wide": (0.5, 0.04)}[kind]
    m, d = rng.normal(0, travel, n), rng.normal(0, difference, n)
    dphi_L, dphi_R = m - d, m + d
    truth = np.column_stack(scrubbed_increment(dphi_L, dphi_R, params, scrub))
    measured = truth + rng.normal(size=truth.shape) * np.asarray(sigma)
    return Segments(dphi_L, dphi_R, *measured.T)


def _files(tmp_path, named_segments) -> list[str]:
    paths = []
    for name, seg in named_segments:
        path = tmp_path / name
        save_segments(path, seg)
        paths.append(str(path))
    return paths


# --- the statistics -------------------------------------------------------------------------


def test_one_parameter_is_cochran_q_and_dersimonian_laird():
    y = np.array([1.0, 2.0, 4.0, 0.5])
    v = np.array([0.5, 1.0, 0.8, 0.3])
    w = 1 / v
    mean = np.sum(w * y) / np.sum(w)
    q = np.sum(w * (y - mean) ** 2)
    tau2 = max(0.0, (q - 3) / (np.sum(w) - np.sum(w**2) / np.sum(w)))
    w_star = 1 / (v + tau2)
    pooled = pool(y[:, None], np.diag(v))
    assert pooled.statistic == pytest.approx(q, rel=1e-12)
    assert pooled.dof == 3
    assert pooled.between[0, 0] == pytest.approx(tau2, rel=1e-10)
    assert pooled.fixed_mean[0] == pytest.approx(mean, rel=1e-12)
    assert pooled.random_mean[0] == pytest.approx(np.sum(w_star * y) / np.sum(w_star),
                                                  rel=1e-10)
    assert pooled.random_covariance[0, 0] == pytest.approx(1 / np.sum(w_star), rel=1e-10)
    # Knapp-Hartung, never narrower, at the 95% quantile of t with 3 dof
    mean_star = np.sum(w_star * y) / np.sum(w_star)
    q_star = max(1.0, np.sum(w_star * (y - mean_star) ** 2) / 3)
    t3, z = 3.182446305284263, 1.959963984540054
    assert pooled.adjusted_covariance[0, 0] == pytest.approx(
        q_star * (t3 / z) ** 2 / np.sum(w_star), rel=1e-8)
    # the fixed-effects mean as an estimate of the mean over groups: its weights carry tau2
    q_fixed = max(1.0, np.sum(w_star * (y - mean) ** 2) / 3)
    spread = tau2 * np.sum(w**2) / np.sum(w) ** 2
    assert pooled.fixed_spread[0, 0] == pytest.approx(
        q_fixed * (t3 / z) ** 2 * spread, rel=1e-8)
    # with noise levels estimated on 20 degrees of freedom: Q / 3 against F(3, 20)
    f_tail = stats.f.sf(q / 3, 3, 20)
    assert pool(y[:, None], np.diag(v), residual_dof=20).p_value == pytest.approx(f_tail,
                                                                                   rel=1e-8)
    assert pooled.p_value == pytest.approx(stats.chi2.sf(q, 3), rel=1e-10)


def test_vector_q_is_the_sum_of_mahalanobis_distances_from_the_weighted_mean():
    rng = np.random.default_rng(3)
    estimates = rng.normal(size=(4, 3))
    covariances = []
    for _ in range(4):
        a = rng.normal(size=(3, 3))
        covariances.append(a @ a.T + 0.5 * np.eye(3))
    weights = [np.linalg.inv(c) for c in covariances]
    pairs = list(zip(weights, estimates, strict=True))
    mean = np.linalg.solve(sum(weights), sum(w @ y for w, y in pairs))
    q = sum((y - mean) @ w @ (y - mean) for w, y in pairs)
    pooled = pool(estimates, block_diag(*covariances))
    assert pooled.statistic == pytest.approx(q, rel=1e-10)
    assert pooled.dof == 9
    np.testing.assert_allclose(pooled.fixed_mean, mean, rtol=1e-10)
    # Jackson, White & Thompson's moment equation: E[sum W_i d_i d_i'] = (k - 1) I + B T
    total = sum(weights)
    b = total - sum(w @ np.linalg.inv(total) @ w for w in weights)
    moments = sum(w @ np.outer(y - mean, y - mean) for w, y in pairs)
    expected = 3 * np.eye(3) + b @ pooled.between
    lam = np.linalg.eigvalsh(pooled.between)
    if lam[0] > 1e-9:  # not truncated: the symmetric part of the equation holds exactly
        np.testing.assert_allclose(0.5 * (expected + expected.T),
                                   0.5 * (moments + moments.T), atol=1e-8)


def test_leave_one_out_names_the_outlying_group():
    estimates = np.array([[0.0, 0.0], [0.1, -0.1], [-0.1, 0.05], [3.0, 0.0]])
    distances = leave_one_out(estimates, np.eye(8) * 0.04)
    assert int(np.argmax(distances)) == 3
    # one group against the others' mean (0, -0.0167), variance 0.04 + 0.04 / 3
    expected = (3.0**2 + (0.05 / 3) ** 2) / (0.04 + 0.04 / 3)
    assert distances[3] == pytest.approx(expected, rel=1e-10)


@pytest.mark.slow
@pytest.mark.statistical
def test_q_is_chi_square_for_correlated_groups_that_agree():
    """Size of the test on groups that share data (a dense joint covariance): 1200 draws;
    the 5% rejection rate lies within +-1.9% (3 binomial sigma) of 5%."""
    rng = np.random.default_rng(11)
    a = rng.normal(size=(9, 9))
    covariance = a @ a.T + np.eye(9)
    root = np.linalg.cholesky(covariance)
    mean = np.array([1.0, -2.0, 0.5])
    draws = np.tile(mean, 3) + (root @ rng.normal(size=(9, 1200))).T
    threshold = chi2_quantile(0.95, 6)
    rejected = np.mean([pool(y.reshape(3, 3), covariance).statistic > threshold
                        for y in draws])
    assert abs(rejected - 0.05) < 0.019


# --- the kinds of motion --------------------------------------------------------------------


def test_motion_kinds_follow_the_turn_radius_against_the_track():
    p = Params(0.05, 0.05, 0.3)
    # kappa b = 2 |s_R - s_L| / |s_R + s_L|: spin, 1.0, 0.2, 0, stationary
    seg = exact_segments([-1.0, 1.0, 1.0, 1.0, 0.0], [1.0, 3.0, 1.0 + 0.2 / 0.9, 1.0, 0.0],
                         p)
    assert motion_kinds(seg, p).tolist() == [0, 1, 2, 3, -1]


def _turns(rng, n: int, low: float, high: float) -> Segments:
    """Segments whose kappa b is uniform in [low, high], of either sign and direction."""
    travel = rng.uniform(0.02, 0.1, n) * rng.choice([-1, 1], n)  # m, the midpoint's
    half = 0.5 * rng.uniform(low, high, n) * np.abs(travel) * rng.choice([-1, 1], n)
    return exact_segments((travel - half) / TRUTH.r_L, (travel + half) / TRUTH.r_R, TRUTH,
                          SIGMA, rng)


def test_a_kind_that_cannot_determine_the_parameters_alone_is_merged(rng):
    spins = spin_segments(rng, 60)  # no translation: the common scale is undetermined
    seg = Segments.concatenate([spins, _turns(rng, 60, 0.6, 1.9), _turns(rng, 80, 0.06, 0.45)])
    result = calibrate(seg, sigma=SIGMA)
    h = result.heterogeneity
    assert [group.name for group in h.groups] == ["spins and tight turns", "wide arcs"]
    assert [group.n_segments for group in h.groups] == [120, 80]
    assert h.dof == 3


@pytest.mark.parametrize("loss", ["linear", "huber"])
def test_each_kinds_blocks_are_its_own_segments_normal_system(rng, loss):
    """The kinds' information and gradient, the most frequent kind's taken as the fit's less
    the others', equal each kind's normal system on its own segments (still ones included)."""
    from excite.calibration.model_fit import Fitter
    from excite.calibration.motion_kinds import KINDS, _kind_system
    from excite.calibration.options import FitOptions
    from excite.calibration.solver import Evaluation, normal_system
    from excite.core.models import SENSOR_POSE

    seg = Segments.concatenate([spin_segments(rng, 30), _turns(rng, 40, 0.6, 1.9),
                                _turns(rng, 200, 0.06, 0.45), _turns(rng, 50, 0.0, 0.04),
                                exact_segments(np.zeros(5), np.zeros(5), TRUTH, SIGMA, rng)])
    fitter = Fitter(seg, None, None, FitOptions(loss, 100, 1e-10, 0.05))
    chosen = fitter.fit(SENSOR_POSE, np.r_[TRUTH.as_array(), 0.01, -0.02, 0.1])
    kinds = motion_kinds(seg, Params(*chosen.theta[:3]))
    assert np.bincount(kinds + 1).tolist() == [5, 30, 40, 200, 50]
    information, gradient = _kind_system(chosen, fitter, kinds,
                                         np.bincount(kinds[kinds >= 0], minlength=4))
    ev, sigma, k3 = chosen.fit.ev, chosen.fit.sigma, 3 * len(KINDS)
    for k in range(len(KINDS)):
        own = np.flatnonzero(kinds == k)
        system = normal_system(Evaluation(ev.theta, ev.scale, ev.raw[:, own], ev.jac[:, :, own]),
                               sigma, loss)
        rows = np.r_[3 * k:3 * k + 3, k3:k3 + 3]
        scale = np.abs(system.information).max()
        np.testing.assert_allclose(information[np.ix_(rows[:3], rows[:3])],
                                   system.information[:3, :3], rtol=0, atol=1e-10 * scale)
        np.testing.assert_allclose(gradient[rows[:3]], system.gradient[:3], rtol=0,
                                   atol=1e-10 * np.abs(system.gradient).max())


def test_spins_and_straight_runs_alone_are_not_tested(rng):
    from tests.conftest import straight_segments

    seg = Segments.concatenate([spin_segments(rng, 60), straight_segments(rng, 60)])
    assert calibrate(seg).heterogeneity is None


# --- detection, the pool, the words ---------------------------------------------------------


def test_agreeing_motion_kinds_leave_the_result_bit_identical(rng):
    seg = lesson_dataset(rng, 300, TRUTH)
    tested = calibrate(seg)
    untested = calibrate(seg, heterogeneity="off")
    assert tested.heterogeneity is not None and not tested.heterogeneity.detected
    assert untested.heterogeneity is None
    for field in ("covariance", "std", "full_covariance", "residuals"):
        assert np.array_equal(getattr(tested, field), getattr(untested, field))
    assert tested.params == untested.params
    assert tested.fit.to_dict() == untested.fit.to_dict()


def test_logs_of_different_turning_are_detected_and_pooled_with_their_spread(tmp_path, rng):
    paths = _files(tmp_path, [("tight.csv", _maneuver(rng, "tight", 150, scrub=0.2)),
                              ("wide.csv", _maneuver(rng, "wide", 150, scrub=0.2))])
    result = calibrate_logs(paths).result
    common = calibrate_logs(paths, heterogeneity="common").result
    h = result.heterogeneity
    assert h.detected and h.by == "logs" and h.p_value < LEVEL
    assert h.pooling == "random effects" and set(h.most_different) == set(paths)
    assert "b from " in h.differences and "wheel scrub" in h.differences
    assert [g.n_segments for g in h.groups] == [150, 150]
    groups_b = np.array([g.params[2] for g in h.groups])
    # the pool's std covers the spread: each log's b within 2 of its std of the pooled b,
    # where the common fit's std covers neither
    assert np.all(np.abs(groups_b - result.params.b) <= 2 * result.std[2])
    assert np.max(np.abs(groups_b - common.params.b)) > 4 * common.std[2]
    assert result.std[2] > 3 * common.std[2]
    full = result.full_covariance
    np.testing.assert_allclose(full[:3, :3], result.covariance)
    assert np.all(np.linalg.eigvalsh(full) > -1e-12 * np.abs(full).max())
    # forced common parameters: the same test, the fit fails with the words
    assert common.heterogeneity.detected and common.heterogeneity.pooling == "common"
    assert not common.fit.ok and "--common-params" in common.fit.message
    assert "b from " in common.fit.message


def test_kinds_of_motion_that_disagree_keep_the_common_fit_with_their_spread_in_its_std(rng):
    """Within one input the kinds share the log's information: r_L, r_R, b stay the common
    fit's (the log's mix of driving), the std widen to cover the kinds' spread."""
    seg = Segments.concatenate([_maneuver(rng, "tight", 150, scrub=0.2),
                                _maneuver(rng, "wide", 150, scrub=0.2)])
    result = calibrate(seg)
    common = calibrate(seg, heterogeneity="common")
    h = result.heterogeneity
    assert h.detected and h.by == "motion" and h.pooling == "random effects"
    assert result.params == common.params
    groups_b = np.array([g.params[2] for g in h.groups])
    assert np.max(np.abs(groups_b - common.params.b)) > 4 * common.std[2]
    assert np.all(np.abs(groups_b - result.params.b) <= 2 * result.std[2])
    assert np.all(result.std > common.std)
    assert "fit the log's mix of driving" in "\n".join(h.summary_lines())


def _two_groups(by: str, q: float):
    """Two groups' estimates (identity covariance in relative units of 1e-4 of TRUTH) whose
    Cochran's Q is ``q`` (chi-square with 3 dof)."""
    from excite.calibration.heterogeneity import Comparison, assessed

    estimates = np.array([[np.sqrt(0.5 * q), 0.0, 0.0], [-np.sqrt(0.5 * q), 0.0, 0.0]])
    return assessed(Comparison(by, ("a", "b"), (100, 100), TRUTH.as_array(),
                               1e-4 * TRUTH.as_array(), estimates, np.eye(6), np.inf))


def test_logs_below_the_pooling_level_are_pooled_with_random_effects(rng):
    """Between logs, p in [LEVEL, POOLING_LEVEL): not called different, but pooled with random
    effects (the fit test unchanged); above it, or between kinds of motion, the common fit."""
    from excite.calibration.heterogeneity import POOLING_LEVEL, applied

    q = chi2_quantile(1 - 0.5 * (LEVEL + POOLING_LEVEL), 3)  # p halfway between the levels
    h = _two_groups("logs", q)
    assert not h.detected and LEVEL < h.p_value < POOLING_LEVEL
    assert h.pooling == "random effects" and h.to_dict()["pooling_level"] == POOLING_LEVEL
    assert "pool them with random effects" in "\n".join(h.summary_lines())
    assert h.plain_lines() == []
    result = calibrate(lesson_dataset(rng, 200, TRUTH), sensor_pose="axle")
    pooled = applied(result, h, "random")
    np.testing.assert_array_equal(pooled.params.as_array(), h.random_params)
    np.testing.assert_array_equal(pooled.covariance, h.random_covariance)
    assert pooled.fit == result.fit
    forced = applied(result, h, "common")
    assert forced.params == result.params and forced.heterogeneity.pooling == "common"
    assert forced.fit == result.fit
    assert _two_groups("motion", q).pooling == "common"
    high = _two_groups("logs", chi2_quantile(1 - 0.5 * (1 + POOLING_LEVEL), 3))
    assert high.p_value > POOLING_LEVEL and high.pooling == "common"
    assert applied(result, high, "random").params == result.params


def test_two_robots_logs_name_the_file_that_disagrees(tmp_path):
    other = Params(TRUTH.r_L, TRUTH.r_R, 0.311)
    named = [(f"robot_a{i}.csv", lesson_dataset(np.random.default_rng(i), 120, TRUTH))
             for i in range(3)]
    named.append(("robot_b.csv", lesson_dataset(np.random.default_rng(9), 120, other)))
    paths = _files(tmp_path, named)
    h = calibrate_logs(paths).result.heterogeneity
    assert h.detected and h.most_different == (paths[3],)
    assert h.to_dict()["most_different"] == [paths[3]]
    assert f"from {paths[3]}" in h.differences


def test_json_keys_of_the_test(tmp_path, rng):
    paths = _files(tmp_path, [("a.csv", lesson_dataset(rng, 100, TRUTH)),
                              ("b.csv", lesson_dataset(rng, 100, TRUTH))])
    d = calibrate_logs(paths).result.to_dict()["heterogeneity"]
    assert {"detected", "statistic", "p_value", "groups"} <= set(d)
    assert d["dof"] == 3 and d["by"] == "logs" and d["level"] == LEVEL
    group = d["groups"][0]
    assert set(group) == {"name", "params", "std", "n_segments"}
    assert set(group["params"]) == {"r_L", "r_R", "b"} and group["n_segments"] == 100


@pytest.mark.slow
@pytest.mark.statistical
def test_false_alarms_on_logs_of_one_robot():
    """Size of the test between two segment files of one robot (tight and wide driving):
    60 pairs; at a level of 5%, 9 or more false alarms has probability 0.7% (binomial)."""
    alarms = 0
    for seed in range(60):
        rng = np.random.default_rng(seed)
        segments = [_maneuver(rng, kind) for kind in ("tight", "wide")]
        h = _logs_test(segments)
        alarms += bool(h is not None and h.detected)
    assert alarms <= 8


def _logs_test(segments: list[Segments]):
    """The test between segment sets without files (as calibrate_logs runs it)."""
    from excite.calibration.heterogeneity import across_logs

    pooled = calibrate(Segments.concatenate(segments), heterogeneity="off")
    return across_logs([(f"log{i}", s) for i, s in enumerate(segments)], pooled,
                       lambda seg, pose: calibrate(seg, sensor_pose=pose, heterogeneity="off"),
                       lambda text: None)


@pytest.mark.slow
@pytest.mark.statistical
def test_random_effects_pool_covers_the_mean_over_logs():
    """Logs whose effective track is drawn per log (a random effect of 0.4% of b) in sets of
    6: the random-effects 95% interval of b covers the mean track in 40 sets; under a
    coverage of 95% fewer than 34 has probability 0.5% (binomial; the pool's std comes from
    6 logs, so somewhat below 95% is expected)."""
    covered = 0
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        tracks = TRUTH.b * (1 + 0.004 * rng.normal(size=6))
        segments = [lesson_dataset(rng, 150, dataclasses.replace(TRUTH, b=float(b)))
                    for b in tracks]
        h = _logs_test(segments)
        assert h is not None
        params = h.random_params if h.detected else calibrate(
            Segments.concatenate(segments), heterogeneity="off").params.as_array()
        std = (np.sqrt(h.random_covariance[2, 2]) if h.detected else calibrate(
            Segments.concatenate(segments), heterogeneity="off").std[2])
        covered += abs(params[2] - TRUTH.b) <= 1.96 * std
    assert covered >= 34


def _mounted(rng, mounting, n: int = 150) -> Segments:
    """Lesson-like segments of TRUTH's wheels seen by a sensor at ``mounting`` (x, y in m,
    theta in rad) in the body frame, with SIGMA's noise."""
    from excite.core.models import SENSOR_POSE

    dphi_L, dphi_R = rng.normal(0.0, 2.0, n), rng.normal(0.0, 2.0, n)
    theta = np.concatenate([TRUTH.as_array(), mounting])
    truth, _ = SENSOR_POSE.evaluate(dphi_L, dphi_R, theta, jacobian=False)
    measured = truth.T + rng.normal(size=(n, 3)) * np.asarray(SIGMA)
    return Segments(dphi_L, dphi_R, *measured.T)


def test_logs_whose_sensor_mountings_differ_fail_the_fit_and_name_them(tmp_path):
    """One robot's wheels, the sensor mounted anew between two logs (found by fuzzing: one
    mounting forced on both, 17 std from either, a b difference blamed on scrub, fit ok):
    the fit fails naming both mountings, and the wheels, each with its own mounting, agree."""
    rng = np.random.default_rng(3)
    paths = _files(tmp_path, [("a.csv", _mounted(rng, (0.10, -0.03, 0.40))),
                              ("b.csv", _mounted(rng, (0.07, 0.00, 0.10)))])
    result = calibrate_logs(paths).result
    h = result.heterogeneity
    assert h.mounting is not None and h.mounting.differ and h.mounting.dof == 3
    assert not result.fit.ok
    assert result.fit.message.startswith("the sensor mounting differs between the logs (")
    import re

    thetas = [(float(v), float(e)) for v, e in
              re.findall(r"theta (-?[\d.]+) ± ([\d.]+) deg", result.fit.message)]
    assert len(thetas) == 2 and all(f"{p}: x " in result.fit.message for p in paths)
    for (value, std), truth in zip(thetas, (0.40, 0.10), strict=True):
        assert abs(value - np.degrees(truth)) < 4 * std
    assert not h.detected  # the wheels agree when each log keeps its own mounting
    for group in h.groups:
        assert np.all(np.abs(group.params - TRUTH.as_array()) < 4 * group.std)
    assert h.to_dict()["mounting"]["differ"] is True


def test_logs_of_one_mounting_rarely_differ():
    """40 pairs of logs of one robot and one mounting: at the test's level of 0.001, two or
    more said to differ has probability 8e-4 (binomial)."""
    differ = 0
    for seed in range(40):
        rng = np.random.default_rng(500 + seed)
        h = _logs_test([_mounted(rng, (0.10, -0.03, 0.40)) for _ in range(2)])
        assert h is not None and h.mounting is not None
        differ += h.mounting.differ
    assert differ <= 1


def test_a_mounting_turned_round_in_one_log_is_named_though_the_pooled_fit_is_undetermined(
        tmp_path):
    """Three logs of one robot, the sensor turned round (178 deg) in the third: one mounting
    for all of them determines nothing, and the result said "not determined, no segment
    translates" (exit 3). Each log alone determines its mounting: they differ, the fit fails
    naming the odd log."""
    rng = np.random.default_rng(5)
    mountings = [(0.10, -0.03, 0.40), (0.10, -0.03, 0.40), (0.07, 0.00, -3.1)]
    paths = _files(tmp_path, [(f"c{i}.csv", _mounted(rng, m)) for i, m in enumerate(mountings)])
    result = calibrate_logs(paths).result
    mounting = result.heterogeneity.mounting
    assert mounting.differ and mounting.dof == 6 and not result.fit.ok
    assert f"most different: {paths[2]}" in result.fit.message
    assert "theta -177." in result.fit.message  # wrapped to [-180, 180)
