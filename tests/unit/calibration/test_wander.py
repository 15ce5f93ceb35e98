"""The wandering heading error of the pose samples (excite.calibration.wander): its covariance
pieces
against dense matrices, the restricted likelihood's gradient against finite differences, the
sandwich covariance against its dense formula, and calibrate's use of it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excite.calibration import fit_tests
from excite.calibration.noise import ChainWhitener, NoiseLevels, WheelNoise, chain_band
from excite.calibration.pipeline import calibrate
from excite.calibration.solver import Problem
from excite.calibration.wander import (
    CHUNK_SEGMENTS,
    MAX_CHUNKS,
    HeadingWander,
    _Chunk,
    _chunk_ranges,
    _deviance,
    _longest_stretch,
    _Samples,
    _sandwiched,
    estimate_wander,
    wander_covariance,
)
from excite.core.banded import dense
from excite.core.models import SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.segments import Segments
from excite.logs.synthetic import synthetic_log

SENSOR = SensorPose(0.1, -0.03, 0.4)


def _log(seed: int, duration: float = 20.0, correlation_time: float = 0.0) -> Segments:
    log = synthetic_log(np.random.default_rng(seed), duration, sensor_pose=SENSOR,
                        pose_noise=(0.002, 0.002), pose_noise_time=correlation_time)
    return segment_timeseries(log.series).segments


def _dense_design(seg: Segments, samples: _Samples) -> np.ndarray:
    """A (3N, M) written out: x, y rows -J d at the first sample, theta -1 there, +1 at the
    last (the module doc's linearisation)."""
    n = len(seg)
    a = np.zeros((3 * n, len(samples.times)))
    for k in range(n):
        a[3 * k, samples.start[k]] += seg.dy[k]
        a[3 * k + 1, samples.start[k]] += -seg.dx[k]
        a[3 * k + 2, samples.start[k]] -= 1.0
        a[3 * k + 2, samples.end[k]] += 1.0
    return a


def _dense_correlation(samples: _Samples, time: float) -> np.ndarray:
    m = len(samples.times)
    r = np.zeros((m, m))
    for i in range(m):
        for j in range(m):
            if samples.clock[i] == samples.clock[j]:
                r[i, j] = np.exp(-abs(samples.times[i] - samples.times[j]) / time)
    return r


@st.composite
def _broken_segments(draw) -> Segments:
    """Segments of two logs (the second's clock starts again) with segments dropped: gaps,
    chained and unchained neighbours."""
    seed = draw(st.integers(0, 2**16))
    first = _log(seed, 12.0)
    second = _log(seed + 1, 8.0)
    keep_a = np.array(draw(st.lists(st.booleans(), min_size=len(first), max_size=len(first))))
    keep_b = np.array(draw(st.lists(st.booleans(), min_size=len(second),
                                    max_size=len(second))))
    keep_a[0] = keep_b[0] = True
    return Segments.concatenate([first[keep_a], second[keep_b]])


@settings(max_examples=25, deadline=None)
@given(_broken_segments(), st.floats(0.3, 50.0))
def test_the_pieces_of_the_heading_error_match_their_dense_matrices(seg, time):
    samples = _Samples.of(seg)
    # a sample is shared exactly where segments are chained; a new clock where times go back
    chained = seg.chained
    assert np.array_equal(samples.start[1:] == samples.end[:-1], chained[1:])
    a = _dense_design(seg, samples)
    r = _dense_correlation(samples, time)
    assert np.allclose(samples.correlation(time)[0], r)
    assert np.allclose(_sandwiched(samples.design(seg), r), a @ r @ a.T)
    rows = np.random.default_rng(0).normal(size=(3 * len(seg), 4))
    assert np.allclose(samples.transpose_design(seg, rows), a.T @ rows)
    h = a.T @ rows
    assert np.allclose(samples.apply_correlation(time, h), r @ h)


def test_samples_follow_the_clocks():
    """Two logs whose times overlap: the second log's samples are on a clock of their own
    (uncorrelated with the first's), even at equal times."""
    both = Segments.concatenate([_log(1, 10.0), _log(2, 10.0)])
    samples = _Samples.of(both)
    assert set(np.unique(samples.clock)) == {0, 1}
    r, _ = samples.correlation(5.0)
    assert np.all(r[np.ix_(samples.clock == 0, samples.clock == 1)] == 0.0)


def _chunks(seg: Segments, wheels: WheelNoise | None):
    """Two chunks of different sizes and timing, as a long log's."""
    rng = np.random.default_rng(3)
    p = 4
    e = rng.normal(scale=1e-3, size=3 * len(seg))
    j = rng.normal(size=(3 * len(seg), p))
    parts = _parts(seg)
    return [_Chunk.of(seg[part.start:part.stop],
                      None if wheels is None else wheels.take(np.asarray(part)),
                      e[3 * part.start:3 * part.stop], j[3 * part.start:3 * part.stop],
                      7 if wheels is not None else 5) for part in parts]


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(-9.0, -4.0), min_size=9, max_size=9), st.booleans())
def test_the_restricted_deviance_has_the_analytic_gradient(u_list, with_wheels):
    seg = _log(5, 15.0)
    wheels = None
    if with_wheels:
        from excite.core.models import SENSOR_POSE

        theta = np.array([0.05, 0.051, 0.3, *SENSOR.as_array()])
        wheels = WheelNoise.of(SENSOR_POSE, seg, theta, 2 * np.pi / 4096)
    n_levels = 7 if with_wheels else 5  # with the wheels: slip and encoder timing
    u = np.array(u_list[:n_levels] + [u_list[7], np.log(np.exp(u_list[8] + 9.0) + 0.5)])
    chunks = _chunks(seg, wheels)
    value, gradient, _ = _deviance(chunks, u, n_levels, True)
    step = 1e-6
    for i in range(u.size):
        up, down = u.copy(), u.copy()
        up[i] += step
        down[i] -= step
        numeric = (_deviance(chunks, up, n_levels, True)[0]
                   - _deviance(chunks, down, n_levels, True)[0]) / (2 * step)
        assert numeric == pytest.approx(gradient[i], rel=1e-4, abs=1e-4 * (1 + abs(value)))


@pytest.mark.parametrize("with_wheels", [False, True])
def test_the_average_information_is_its_dense_formula(with_wheels):
    """y^T P dC_i P dC_j P y in v = exp(2 u) (the levels', std^2's and time^2's), the chunks'
    C block diagonal and P coupling them through the common parameters, written out."""
    from scipy.linalg import block_diag

    seg = _log(6, 15.0)
    wheels = None
    if with_wheels:
        from excite.core.models import SENSOR_POSE

        theta = np.array([0.05, 0.051, 0.3, *SENSOR.as_array()])
        wheels = WheelNoise.of(SENSOR_POSE, seg, theta, 2 * np.pi / 4096)
    n_levels = 7 if with_wheels else 5
    chunks = _chunks(seg, wheels)
    u = np.append(np.log([2e-3, 2e-3, 1e-3, 1e-3, 2e-3, 5e-3, 1e-4][:n_levels]),
                  [np.log(3e-3), np.log(2.5)])
    _, _, information = _deviance(chunks, u, n_levels, True, with_information=True)
    std2, time = np.exp(2 * u[-2]), np.exp(u[-1])
    covariances, derivatives = [], [[] for _ in range(u.size)]
    for c, part in zip(chunks, _parts(seg), strict=True):
        a = _dense_design(seg[part.start:part.stop], c.samples)
        r = _dense_correlation(c.samples, time)
        lag = np.abs(c.samples.times[:, None] - c.samples.times[None, :])
        cov = dense(c.bands.at(np.exp(u[:n_levels]))) + std2 * a @ r @ a.T
        covariances.append(cov * (1.0 + 1e-10 * np.eye(len(cov))))
        for i, unit in enumerate(c.bands.units):
            derivatives[i].append(dense(unit))
        derivatives[-2].append(a @ r @ a.T)
        derivatives[-1].append(std2 * a @ (r * lag / time**2) @ a.T / (2.0 * time))
    inverse = np.linalg.inv(block_diag(*covariances))
    j = np.concatenate([c.jac for c in chunks])
    y = np.concatenate([c.residual for c in chunks])
    ci_j = inverse @ j
    p_matrix = inverse - ci_j @ np.linalg.solve(j.T @ ci_j, ci_j.T)
    py = p_matrix @ y
    w = np.column_stack([block_diag(*d) @ py for d in derivatives])
    expected = w.T @ p_matrix @ w
    assert np.allclose(information, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())


def _parts(seg: Segments) -> list[range]:
    """The two parts of ``seg`` that :func:`_chunks` makes chunks of."""
    cut = 2 * len(seg) // 5
    return [range(0, cut), range(cut, len(seg))]


def test_the_deviance_without_the_wander_is_the_chain_models():
    """With the heading error off, the dense deviance is the banded chain model's (the same
    likelihood as excite.calibration.noise's REML)."""
    from excite.calibration.noise import chain_band, stacked
    from excite.calibration.reml_search import restricted_deviance

    seg = _log(6, 15.0)
    levels = NoiseLevels(np.array([1e-4, 2e-4, 3e-4]), np.array([2e-3, 1e-3]))
    rng = np.random.default_rng(1)
    residual = rng.normal(scale=1e-3, size=(3, len(seg)))
    jac = rng.normal(size=(3, 4, len(seg)))
    chunk = _Chunk.of(seg, None, residual.T.reshape(-1),
                      jac.transpose(2, 0, 1).reshape(3 * len(seg), -1), 5)
    u = np.log(np.concatenate([levels.sigma, levels.pose]))
    value, _, _ = _deviance([chunk], u, 5, False)
    assert value == pytest.approx(restricted_deviance(chain_band(seg, levels),
                                                      stacked(residual, jac)), rel=1e-9)


def test_the_chunks_bands_side_by_side_give_the_dense_deviance_without_the_wander():
    """The test's null is searched on the chunks' bands side by side (block diagonal, one
    set of parameters): the same deviance as the dense chunks'."""
    from excite.calibration.noise import LevelBands
    from excite.calibration.reml_search import RestrictedDeviance
    from excite.core.models import SENSOR_POSE

    seg = _log(8, 15.0)
    theta = np.array([0.05, 0.051, 0.3, *SENSOR.as_array()])
    chunks = _chunks(seg, WheelNoise.of(SENSOR_POSE, seg, theta, 2 * np.pi / 4096))
    banded = RestrictedDeviance(
        LevelBands.side_by_side([c.bands for c in chunks]),
        np.column_stack([np.concatenate([c.residual for c in chunks]),
                         np.concatenate([c.jac for c in chunks])]))
    for u in (np.log([1e-4, 2e-4, 3e-4, 2e-3, 1e-3, 1e-2, 1e-3]),
              np.log([1e-6, 1e-6, 1e-6, 5e-3, 2e-3, 3e-2, 1e-4])):
        value, _, _ = _deviance(chunks, u, 7, False, with_gradient=False)
        assert banded(u) == pytest.approx(value, rel=1e-8)


def test_chunks_cover_short_logs_and_sample_long_ones():
    assert _chunk_ranges(120) == [range(0, 120)]
    assert _chunk_ranges(200) == [range(0, 100), range(100, 200)]
    long = _chunk_ranges(3600)
    assert len(long) == MAX_CHUNKS and long[0].start == 0 and long[-1].stop == 3600
    assert all(len(r) <= CHUNK_SEGMENTS for r in long)


def test_the_covariance_is_the_sandwich_of_the_dense_model():
    """wander_covariance = I^-1 J^T B^-1 (B' + s^2 A R A^T) B^-1 J I^-1 with dense matrices."""
    from excite.core.models import SENSOR_POSE

    seg = _log(7, 30.0)
    theta = np.array([0.05, 0.051, 0.3, *SENSOR.as_array()])
    levels = NoiseLevels(np.array([1e-4, 2e-4, 3e-4]), np.array([2e-3, 1e-3]), 1e-3)
    wheels = WheelNoise.of(SENSOR_POSE, seg, theta, None)
    whitener = ChainWhitener(seg, levels, wheels)
    jac = Problem(SENSOR_POSE, seg).evaluate(theta).jac
    j = jac.transpose(2, 0, 1).reshape(3 * len(seg), -1)
    b = dense(chain_band(seg, levels, wheels))
    information = j.T @ np.linalg.solve(b, j)
    covariance = np.linalg.inv(information)
    other = NoiseLevels(np.array([2e-4, 1e-4, 1e-5]), np.array([1e-3, 5e-4]), 5e-4)
    wander = HeadingWander(0.002, 6.0, 30.0, other)
    samples = _Samples.of(seg)
    a = _dense_design(seg, samples)
    c = dense(chain_band(seg, other, wheels)) + 0.002**2 * a @ _dense_correlation(
        samples, 6.0) @ a.T
    g = np.linalg.solve(b, j)
    expected = covariance @ g.T @ c @ g @ covariance
    assert np.allclose(wander_covariance(seg, whitener, jac, covariance, wander), expected,
                       rtol=1e-8, atol=0.0)


def _segments(seed: int, correlation_time: float) -> Segments:
    return _log(seed, 120.0, correlation_time)


@pytest.mark.slow
def test_a_wandering_heading_error_is_found_and_widens_the_mounting_angle(monkeypatch):
    """Pose heading errors wandering over 8 s (2 mrad): found (time and std of the right
    order), the message and --json say so, and the mounting angle's std is wider than the
    chain model's alone."""
    seg = _segments(1003, 8.0)
    result = calibrate(seg, sensor_pose="estimate")
    wander = result.fit.heading_wander
    assert wander is not None
    assert 2.0 < wander.correlation_time < 40.0 and 0.5e-3 < wander.std < 8e-3
    assert not wander.at_bound
    assert "heading error wanders" in result.fit.message and result.fit.ok
    fit = json.loads(json.dumps(result.fit.to_dict(), allow_nan=False))
    assert set(fit["heading_wander"]) == {"std", "correlation_time", "statistic", "at_bound"}
    with monkeypatch.context() as m:  # the same fit without the wander
        m.setattr(fit_tests, "estimate_wander", lambda *args, **kwargs: None)
        chain = calibrate(seg, sensor_pose="estimate")
    assert np.allclose(result.params.as_array(), chain.params.as_array())
    assert result.sensor_pose_std[2] > 1.5 * chain.sensor_pose_std[2]


def test_white_pose_noise_keeps_the_chain_model():
    result = calibrate(_segments(100, 0.0), sensor_pose="estimate")
    assert result.fit.heading_wander is None
    assert "wanders" not in result.fit.message


def test_short_logs_are_not_searched():
    seg = _log(8, 40.0, 8.0)
    assert len(seg) < 50
    assert calibrate(seg, sensor_pose="estimate").fit.heading_wander is None
    rng = np.random.default_rng(0)
    assert estimate_wander(seg, rng.normal(size=(3, len(seg))),
                           rng.normal(size=(3, 6, len(seg))),
                           NoiseLevels(np.ones(3), np.ones(2)), np.full(3, 1e-9)) is None


@pytest.mark.slow
def test_joined_logs_reach_the_optimum():
    """Two 70 s logs joined (review: the search once stopped at a start where the dense
    covariance was singular, LR 20.6 at tau = 60 s): the optimum, LR about 49.6."""
    both = Segments.concatenate([_log(1, 70.0, 8.0), _log(2, 70.0, 8.0)])
    wander = calibrate(both, sensor_pose="estimate").fit.heading_wander
    assert wander is not None
    assert wander.statistic > 49.0 and 5.0 < wander.correlation_time < 30.0


def test_a_wander_that_the_quasi_newton_search_missed_is_found():
    """A 120 s log with a 20 s wander (2 mrad): L-BFGS-B, the search before the Newton one,
    stopped near its start and kept no wander (the likelihood ratio at its stop 0); the
    Newton search with the average information reaches the optimum, LR about 35, a time
    constant about 12 s."""
    log = synthetic_log(np.random.default_rng([2, 77]), 120.0, sensor_pose=SENSOR,
                        pose_noise=(0.002, 0.002), pose_noise_time=20.0)
    wander = calibrate(segment_timeseries(log.series).segments).fit.heading_wander
    assert wander is not None
    assert wander.statistic > 30.0 and 5.0 < wander.correlation_time < 40.0


def test_a_misfit_is_not_taken_for_a_wander():
    """The axle model forced on an off-axle sensor fails its test; no wander is searched
    and its std are the chain model's."""
    result = calibrate(_segments(1003, 8.0), sensor_pose="axle")
    assert not result.fit.ok
    assert result.fit.heading_wander is None and "wanders" not in result.fit.message


def test_the_time_constant_is_bounded_by_the_longest_unbroken_stretch():
    """Gaps and part boundaries break a stretch; idle time between them does not count
    (review: the bound once spanned the gaps)."""
    seg = _log(9, 30.0)
    assert _longest_stretch(seg) == pytest.approx(seg.t_end[-1] - seg.t_start[0])
    keep = np.ones(len(seg), dtype=bool)
    keep[10] = False  # a gap after the first 10 segments
    broken = seg[keep]
    expected = max(seg.t_end[9] - seg.t_start[0], seg.t_end[-1] - seg.t_start[11])
    assert _longest_stretch(broken) == pytest.approx(expected)
    later = Segments.concatenate([seg[:10], seg[11:]])
    assert _longest_stretch(later) == pytest.approx(expected)


def test_segments_with_times_but_no_sub_steps_are_searched_too(tmp_path, monkeypatch):
    """A segment CSV with time columns (no sub-steps: five noise levels, no slip) goes
    through the same search (the chain's five levels)."""
    from excite.calibration import wander as wander_module
    from excite.logs.segments import load_segments, save_segments

    path = tmp_path / "segments.csv"
    save_segments(path, _segments(1003, 8.0))
    seg = load_segments(path)
    assert seg.sub_dphi_L is None and seg.chained is not None and seg.chained[1:].all()
    seen = []
    real = wander_module._Chunk.of

    def spy(segments, wheels, *args):
        seen.append(wheels)
        return real(segments, wheels, *args)

    monkeypatch.setattr(wander_module._Chunk, "of", spy)
    calibrate(seg, sensor_pose="estimate")
    assert seen and all(w is None for w in seen)
