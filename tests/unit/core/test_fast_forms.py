"""Every fast form against its reference form, one case per pair (the single test at the end).

A fast form is kept only where a benchmark shows it pays; it sits beside its reference in the
same module. Each case draws random inputs that reach every branch (exactly zero, the
small-angle series, the seams between series and closed forms, many turns) and returns
(fast, reference, rtol, atol) over all draws; rtol None means equal bit for bit.
"""

import math

import numpy as np
import pytest

from excite.calibration.solver import (
    Problem,
    complement,
    damped_step,
    damped_step_svd,
    normal_system,
)
from excite.core import information as I
from excite.core import se2
from excite.core.kinematics import TINY_THRESHOLD, sinc_family, sinc_family_scalar
from excite.core.models import AXLE, SENSOR_POSE, FixedSensorPoseModel, SensorPose
from excite.estimators.online import (
    FilterChart,
    update_axle_scalar,
    update_batch,
    update_scalar,
)
from excite.logs.segments import Segments

EPS = np.finfo(float).eps
SUBNORMAL = np.finfo(float).smallest_subnormal
DRAWS = 1000
AXLE_NOMINAL = np.array([0.05, 0.05, 0.30])
SENSOR_NOMINAL = np.array([0.05, 0.05, 0.30, 0.04, -0.02, 0.2])


def _angles(rng: np.random.Generator, n: int = DRAWS) -> np.ndarray:
    """Arguments of sinc and friends: exact zeros, subnormal to tiny (both sides of the
    small-angle threshold), both sides of the series seam at 1, up to many turns."""
    magnitude = np.concatenate([
        [0.0, SUBNORMAL, 1e-300, TINY_THRESHOLD, np.nextafter(TINY_THRESHOLD, 0.0), 1.0,
         np.nextafter(1.0, 0.0)],
        10.0 ** rng.uniform(-300, -4, n // 5), TINY_THRESHOLD * rng.uniform(0.5, 2.0, n // 5),
        rng.uniform(0.9, 1.1, n // 5), rng.uniform(0, 4 * math.pi, n // 5),
        10.0 ** rng.uniform(1, 8, n // 5)])
    return magnitude * rng.choice([-1.0, 1.0], magnitude.size)


def _wheels(rng: np.random.Generator, size) -> np.ndarray:
    """Wheel increments (rad): zero, tiny (nearly straight or nearly still) and large."""
    kind = rng.integers(0, 3, size)
    return np.where(kind == 0, 0.0, np.where(kind == 1, rng.uniform(-1e-6, 1e-6, size),
                                             rng.uniform(-60.0, 60.0, size)))


def _sinc_family_scalar(rng):
    """kinematics.sinc_family_scalar against sinc_family: two closed forms (sin and cos of
    u/2 by math; tan of u/2 by numpy), each within 4 eps of exact
    (test_kinematics.test_sinc_family_is_accurate_everywhere), so within 8 eps of each other."""
    u = _angles(rng)
    reference = np.stack(sinc_family(u))
    fast = np.array([sinc_family_scalar(x) for x in u.tolist()]).T
    size = np.maximum(1.0 / np.maximum(np.abs(u), 1.0), np.abs(reference))  # ~1/|u| far out
    return fast, reference, 0.0, 8 * EPS * size


def _traction_kernel_sinc_cosc(rng):
    """The physics kernel's compiled sinc_cosc against sinc_family_scalar, bit for bit (the
    kernel's copy of the branches and of TINY_THRESHOLD)."""
    pytest.importorskip("numba")
    from envs.traction_kernel import sinc_cosc

    u = _angles(rng).tolist()
    fast = np.array([sinc_cosc(x) for x in u])
    reference = np.array([sinc_family_scalar(x, False) for x in u])
    return fast, reference, None, None


def _models():
    pose = SensorPose(0.04, -0.03, 0.3)
    return ((AXLE, 3), (SENSOR_POSE, 6), (FixedSensorPoseModel(pose), 3))


def _evaluate_scalar(rng):
    """SegmentModel.evaluate_scalar (pure Python, one segment) against evaluate, for the three
    models: the prediction and the Jacobian rows."""
    fast, reference, scale = [], [], []
    for model, size in _models():
        for _ in range(DRAWS // 3):
            theta = np.concatenate([rng.uniform(0.01, 1.0, 3), rng.uniform(-0.5, 0.5, 2),
                                    rng.uniform(-math.pi, math.pi, 1)])[:size]
            phi_L, phi_R = _wheels(rng, 2).tolist()
            prediction, rows = model.evaluate_scalar(phi_L, phi_R, tuple(theta.tolist()))
            expected, jac = model.evaluate(np.array([phi_L]), np.array([phi_R]), theta)
            fast.append(np.concatenate([prediction, np.ravel(rows)]))
            reference.append(np.concatenate([expected[:, 0], np.ravel(jac[:, :, 0])]))
            # each row's size: the sensor's rotation of the body's rows may cancel
            scale += [np.abs(expected[:, 0]).max()] * 3
            scale += np.repeat(np.abs(jac[:, :, 0]).max(axis=1), size).tolist()
    return (np.concatenate(fast), np.concatenate(reference), 0.0,
            1e-13 * np.array(scale) + SUBNORMAL)


def _information_case(rng, n_segments: int):
    """Random wheel increments (n_segments), parameters, nominal scale and sigma_x = sigma_y."""
    phi = _wheels(rng, (n_segments, 2))
    params = rng.uniform(0.02, 0.2, 3) * np.array([1.0, 1.0, 5.0])
    scale = rng.uniform(0.02, 0.2, 3) * np.array([1.0, 1.0, 5.0])
    sigma_xy, sigma_theta = 10.0 ** rng.uniform(-6, 0), 10.0 ** rng.uniform(-6, 0.5)
    return phi, params, scale, np.array([sigma_xy, sigma_xy, sigma_theta])


def _reference_information(phi, params, scale, sigma) -> np.ndarray:
    """J_k^T J_k of each segment (..., N, 3, 3) from the whitened, scaled Jacobian."""
    jac = I.scaled_jacobian(phi[..., 0], phi[..., 1], params, sigma, scale)
    return np.einsum("...nki,...nkj->...nij", jac, jac)


def _chord_rows(rng):
    """information._chord_rows (the Jacobian's rows turned onto each arc's chord, array code,
    batch-first with one robot's coefficients per leading index) against J_k^T J_k."""
    fast, reference, size = [], [], []
    for _ in range(DRAWS // 20):
        robots = [_information_case(rng, 20) for _ in range(3)]
        phi = np.stack([r[0] for r in robots])
        params, scale = np.stack([r[1] for r in robots]), np.stack([r[2] for r in robots])
        sigma = robots[0][3]
        coefficients = I._chord_coefficients(params.T[..., None], scale.T[..., None], sigma[0])
        rows = I._chord_rows(phi[..., 0], phi[..., 1], coefficients, sigma[2])
        got = np.einsum("irmn,jrmn->mnij", rows, rows)
        expected = _reference_information(phi, params, scale, sigma)
        fast.append(got.ravel())
        reference.append(expected.ravel())
        size.append(np.repeat(np.abs(expected).max(axis=(2, 3)).ravel(), 9))
    return (np.concatenate(fast), np.concatenate(reference), 0.0,
            1e-13 * np.concatenate(size) + 1e-300)


def _chord_information_scalar(rng):
    """information._chord_information_scalar (one pure-Python pass over up to _LOOP_MAX
    segments) against the sum of J_k^T J_k."""
    fast, reference, size = [], [], []
    for _ in range(DRAWS // 10):
        phi, params, scale, sigma = _information_case(rng, int(rng.integers(1, I._LOOP_MAX + 1)))
        coefficients = I._chord_coefficients(tuple(params.tolist()), tuple(scale.tolist()),
                                             float(sigma[0]))
        got = I._chord_information_scalar(phi[:, 0].tolist(), phi[:, 1].tolist(),
                                          coefficients, float(sigma[2]))
        expected = _reference_information(phi, params, scale, sigma).sum(axis=0)
        fast.append(got.ravel())
        reference.append(expected.ravel())
        size.append(np.full(9, np.abs(expected).max()))
    return (np.concatenate(fast), np.concatenate(reference), 0.0,
            1e-13 * np.concatenate(size) + 1e-300)


def _to_theta_scalar(rng):
    """FilterChart.to_theta_scalar (math's exp, one filter) against to_theta (numpy's)."""
    chart = FilterChart(SENSOR_POSE, SENSOR_NOMINAL, 0.1 * SENSOR_POSE.column_scale(
        SENSOR_NOMINAL), np.array([2e-3, 2e-3, 1e-3]), 2)
    q = chart.start + rng.normal(0.0, 0.5, (DRAWS, SENSOR_NOMINAL.size))
    fast = np.array([chart.to_theta_scalar(row) for row in q.tolist()])
    return fast, chart.to_theta(q), 2 * EPS, 0.0


def _filter_states(rng, model, nominal: np.ndarray):
    """A chart at ``nominal`` and a filter state after a few segments of a robot near it (run
    by the reference), with the next segment (dphi_L, dphi_R, dx, dy, dtheta)."""
    sigma = np.array([2e-3, 2e-3, 1e-3]) * 10.0 ** rng.uniform(-1, 1)
    chart = FilterChart(model, nominal, 0.1 * model.column_scale(nominal), sigma,
                        int(rng.integers(1, 4)))
    truth = nominal * rng.uniform(0.95, 1.05, nominal.size)
    phi = np.concatenate([rng.uniform(-15, 15, (6, 2)), _wheels(rng, (1, 2))])
    measured = model.predict(phi[:, 0], phi[:, 1], truth) + rng.normal(size=(7, 3)) * sigma
    rows = np.column_stack([phi, measured])
    q, info = chart.start[None], chart.prior[None]
    for row in rows[:int(rng.integers(0, 6))]:
        q, info = update_batch(chart, q, info, row[None])
    return chart, q[0], info[0], rows[-1]


def _updates(rng, model, nominal, fast_update, solve_exponent: float = 1.0):
    """A one-filter update against update_batch from random states: the new q and information.
    Beyond rounding (1e-13 of each), the solve's error: eps cond^e of the step (e = 1 for
    LAPACK's solve; 1.5 for the unrolled form's Cramer's rule, which is not backward stable),
    cond the condition number of the new information."""
    fast, reference, tolerance = [], [], []
    for _ in range(DRAWS // 10):
        chart, q, info, row = _filter_states(rng, model, nominal * rng.uniform(0.8, 1.2))
        new_q, new_info = update_batch(chart, q[None], info[None], row[None])
        got_q, got_info = fast_update(chart, q.tolist(), info.tolist(), *row.tolist())
        fast.append(np.concatenate([got_q, np.ravel(got_info)]))
        reference.append(np.concatenate([new_q[0], new_info[0].ravel()]))
        solve = 50 * EPS * np.linalg.cond(new_info[0]) ** solve_exponent * np.abs(
            new_q[0] - q).max()
        size = np.abs(new_info[0]).max()
        tolerance.append(np.concatenate([(1e-13 + solve) * (np.abs(new_q[0]) + 1.0),
                                         np.full(new_info[0].size, (1e-13 + solve) * size)]))
    return np.concatenate(fast), np.concatenate(reference), 0.0, np.concatenate(tolerance)


def _between_scalar(rng):
    """se2.between_scalar (math's cos and sin) against se2.between, bit for bit."""
    starts = rng.uniform(-50, 50, (DRAWS, 3))
    ends = starts + rng.normal(0, 2, (DRAWS, 3))
    fast = np.array([se2.between_scalar(a, b) for a, b in zip(starts, ends, strict=True)])
    return fast, se2.between(starts, ends), None, None


def _damped_step(rng):
    """solver.damped_step (the damped normal equations, when well conditioned) against
    damped_step_svd (the SVD of the weighted Jacobian), at random sensor-pose problems, noise
    levels, losses, dampings and frozen directions. Beyond rounding, the normal equations'
    error: eps cond of the step (cond the damped information's condition number)."""
    fast, reference, tolerance = [], [], []
    for k in range(DRAWS // 10):
        truth = SENSOR_NOMINAL * rng.uniform(0.8, 1.2, SENSOR_NOMINAL.size)
        phi = rng.normal(0.0, 3.0, (int(rng.integers(8, 200)), 2))
        sigma = np.array([2e-3, 2e-3, 1e-3]) * 10.0 ** rng.uniform(-2, 1, 3)
        measured = SENSOR_POSE.predict(phi[:, 0], phi[:, 1], truth) + rng.normal(
            size=(len(phi), 3)) * sigma * rng.choice([1.0, 30.0], size=(len(phi), 1),
                                                     p=[0.9, 0.1])
        problem = Problem(SENSOR_POSE, Segments(phi[:, 0], phi[:, 1], *measured.T))
        ev = problem.evaluate(truth * rng.uniform(0.98, 1.02, truth.size))
        loss = ("linear", "huber")[k % 2]
        lam = 10.0 ** rng.uniform(-8, 2)
        basis = None if k % 3 else complement(np.linalg.qr(rng.normal(size=(6, k % 4)))[0])
        system = normal_system(ev, sigma, loss)
        got = damped_step(ev, system, sigma, loss, lam, basis)
        diagonal = np.diag(system.information)
        want = damped_step_svd(ev, sigma, loss, lam, diagonal, basis)
        gram = system.information + lam * np.diag(diagonal)
        if basis is not None:
            gram = basis.T @ gram @ basis
        fast.append(got)
        reference.append(want)
        tolerance.append(np.full(6, 1e-13 + 50 * EPS * np.linalg.cond(gram)
                                 * np.abs(want).max()))
    return (np.concatenate(fast), np.concatenate(reference), 1e-12,
            np.concatenate(tolerance))


def _channel_gram(rng):
    """information.channel_gram's dot products of long rows against numpy's product, for
    rows with and without a second factor. Summation orders differ: error below
    N eps of the products of the rows' norms."""
    fast, reference, tolerance = [], [], []
    for _ in range(10):
        n = I.LONG_ROWS + int(rng.integers(0, 5000))
        a = rng.normal(size=(3, int(rng.integers(1, 7)), n)) * 10.0 ** rng.uniform(-3, 3)
        b = rng.normal(size=(3, int(rng.integers(1, 4)), n))
        for second in (None, b):
            other = a if second is None else second
            fast.append(I.channel_gram(a, second).ravel())
            reference.append(np.matmul(a, other.transpose(0, 2, 1)).ravel())
            norms = np.linalg.norm(a, axis=2)[:, :, None] * np.linalg.norm(other, axis=2)[
                :, None, :]
            tolerance.append((n * EPS * norms).ravel())
    return np.concatenate(fast), np.concatenate(reference), 0.0, np.concatenate(tolerance)


CASES = {
    "information.channel_gram": _channel_gram,
    "solver.damped_step": _damped_step,
    "kinematics.sinc_family_scalar": _sinc_family_scalar,
    "traction_kernel.sinc_cosc": _traction_kernel_sinc_cosc,
    "models.evaluate_scalar": _evaluate_scalar,
    "information._chord_rows": _chord_rows,
    "information._chord_information_scalar": _chord_information_scalar,
    "online.FilterChart.to_theta_scalar": _to_theta_scalar,
    "online.update_scalar (sensor pose)":
        lambda rng: _updates(rng, SENSOR_POSE, SENSOR_NOMINAL, update_scalar),
    "online.update_scalar (axle)": lambda rng: _updates(rng, AXLE, AXLE_NOMINAL, update_scalar),
    "online.update_axle_scalar":
        lambda rng: _updates(rng, AXLE, AXLE_NOMINAL, update_axle_scalar, 1.5),
    "se2.between_scalar": _between_scalar,
}


@pytest.mark.parametrize("name", list(CASES))
def test_fast_form_equals_its_reference(name):
    fast, reference, rtol, atol = CASES[name](np.random.default_rng(sorted(CASES).index(name)))
    assert fast.shape == reference.shape
    if rtol is None:
        np.testing.assert_array_equal(np.asarray(fast, dtype=float).view(np.int64),
                                      np.asarray(reference, dtype=float).view(np.int64))
    else:
        bad = np.abs(fast - reference) > atol + rtol * np.abs(reference)
        assert not bad.any(), (fast[bad][:5], reference[bad][:5])
