"""The search of the REML noise levels (excite.calibration.reml_search): its average
information against the formula written out with dense matrices, and its minimum against
L-BFGS-B's from several starts."""

import numpy as np
import pytest
from scipy.optimize import minimize

from excite.calibration.noise import LevelBands, NoiseLevels, WheelNoise, chain_band, stacked
from excite.calibration.reml import level_bounds
from excite.calibration.reml_search import (
    DEVIANCE_TOLERANCE,
    RestrictedDeviance,
    newton_search,
)
from excite.core.banded import dense
from excite.core.models import SENSOR_POSE, SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.synthetic import synthetic_log

SENSOR = SensorPose(0.1, -0.03, 0.4)
THETA = np.array([0.05, 0.051, 0.3, *SENSOR.as_array()])


def _problem(seed: int, levels: NoiseLevels, duration: float = 12.0):
    """Segments cut from a short log, with wheel-space noise, and residuals drawn from the
    chain covariance at ``levels`` (so the levels are the truth of the REML problem), with
    random Jacobian rows of four fitted directions."""
    log = synthetic_log(np.random.default_rng(seed), duration, sensor_pose=SENSOR,
                        pose_noise=(0.002, 0.002))
    seg = segment_timeseries(log.series).segments
    wheels = WheelNoise.of(SENSOR_POSE, seg, THETA, 2 * np.pi / 4096)
    rng = np.random.default_rng(seed + 100)
    cov = dense(chain_band(seg, levels, wheels))
    draw = np.linalg.cholesky(cov) @ rng.normal(size=cov.shape[0])
    jac = rng.normal(size=(3, 4, len(seg))) * np.array([3e-3, 3e-3, 1e-2])[:, None, None]
    residual = draw.reshape(len(seg), 3).T + np.einsum("p,cpn->cn", rng.normal(size=4), jac)
    return seg, wheels, residual, jac


LEVELS = NoiseLevels(np.array([4e-4, 3e-4, 2e-4]), np.array([2e-3, 2e-3]), 0.01, 0.0)


def test_the_average_information_is_y_p_ui_p_uj_p_y():
    seg, wheels, residual, jac = _problem(1, LEVELS)
    bands = LevelBands(seg, wheels, 7)
    objective = RestrictedDeviance(bands, stacked(residual, jac))
    u = np.log(np.array([5e-4, 2e-4, 3e-4, 1.5e-3, 2.5e-3, 0.02, 1e-3]))
    levels = np.exp(u)
    c = dense(bands.at(levels))
    j = stacked(residual, jac)[:, 1:]
    y = stacked(residual)[:, 0]
    ci = np.linalg.inv(c)
    p = ci - ci @ j @ np.linalg.solve(j.T @ ci @ j, j.T @ ci)
    moved = [p @ dense(unit) @ p @ y for unit in bands.units]  # P U_i P y
    expected = np.array([[y @ p @ dense(ui) @ mj for mj in moved] for ui in bands.units])
    got = objective.information(u)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())


def test_the_estimated_levels_term_is_kenward_and_rogers_lambda():
    """Lambda = Phi (sum_ij W_ij (Q_ij - P_i Phi P_j)) Phi, W = 2 H^-1 over the free levels,
    written out with dense matrices in Kenward and Roger's notation (P_i = J^T dC^-1/dv_i J,
    Q_ij = J^T dC^-1/dv_i C dC^-1/dv_j J)."""
    seg, wheels, residual, jac = _problem(5, LEVELS)
    bands = LevelBands(seg, wheels, 7)
    objective = RestrictedDeviance(bands, stacked(residual, jac))
    u = np.log(np.array([5e-4, 2e-4, 3e-4, 1.5e-3, 2.5e-3, 0.02, 1e-3]))
    free = np.array([True, False, True, True, True, True, False])
    c = dense(bands.at(np.exp(u)))
    ci = np.linalg.inv(c)
    j = stacked(residual, jac)[:, 1:]
    phi = np.linalg.inv(j.T @ ci @ j)
    d_inv = [-ci @ dense(bands.units[i]) @ ci for i in np.flatnonzero(free)]  # dC^-1 / dv_i
    p = [j.T @ d @ j for d in d_inv]
    q = [[j.T @ di @ c @ dj @ j for dj in d_inv] for di in d_inv]
    w = 2.0 * np.linalg.inv(objective.information(u)[np.ix_(free, free)])
    middle = sum(w[a, b] * (q[a][b] - p[a] @ phi @ p[b])
                 for a in range(len(p)) for b in range(len(p)))
    expected = phi @ middle @ phi
    got = objective.estimated_levels_term(u, free)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())
    # positive semi-definite: estimating the levels never makes the estimate more precise
    assert np.linalg.eigvalsh(got).min() > -1e-12 * np.abs(got).max()


@pytest.mark.parametrize("seed, levels", [
    (2, LEVELS),
    (3, NoiseLevels(np.array([1e-6, 1e-6, 1e-6]), np.array([2e-3, 2e-3]), 0.0, 0.0)),
    (4, NoiseLevels(np.array([1e-3, 1e-3, 5e-4]), np.array([5e-4, 5e-3]), 0.0, 0.0)),
])
def test_the_newton_search_reaches_the_minimum_of_l_bfgs_b_from_several_starts(seed, levels):
    """White segment noise and slip at 0 put levels on their floors (held there by the
    bounds); the timing level is held at 0 as reml_noise does, the other six are free."""
    seg, wheels, residual, jac = _problem(seed, levels)
    objective = RestrictedDeviance(LevelBands(seg, wheels, 7), stacked(residual, jac))
    floor = 1e-8 * np.array([0.01, 0.01, 0.01])
    lower, upper = level_bounds(residual, floor, wheels)
    free = np.ones(7, dtype=bool)
    free[6] = False
    rms = np.sqrt(np.mean(residual**2))
    best = np.inf
    for k, fraction in enumerate((1.0, 0.1, 0.01)):
        u0 = np.clip(np.log(np.full(7, fraction * rms)), lower, upper)
        u0[5] = np.clip(np.log(fraction * 0.01), lower[5], upper[5])
        u0[6] = -np.inf

        def partial(v, u0=u0):
            full = u0.copy()
            full[:6] = v
            return objective(full)

        result = minimize(partial, u0[:6], method="L-BFGS-B",
                          bounds=list(zip(lower[:6], upper[:6], strict=True)))
        best = min(best, float(result.fun))
        if k == 0:
            u, value, converged = newton_search(objective, objective.information, u0,
                                                objective(u0), free, lower, upper)
    assert converged
    assert value <= best + 10 * DEVIANCE_TOLERANCE
    assert np.all(u[:6] >= lower[:6]) and np.all(u[:6] <= upper[:6])
    assert u[6] == -np.inf
