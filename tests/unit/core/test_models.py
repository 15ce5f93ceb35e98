"""The segment models: analytic Jacobians against finite differences over the whole domain,
the sensor-pose model against SE(2) composition, and the axle model as its l = 0 case."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excite.core.kinematics import Params, predict_increment
from excite.core.models import (
    AXLE,
    SENSOR_POSE,
    FixedSensorPoseModel,
    SensorPose,
    increment_jacobian,
    sensor_to_body,
)
from excite.core.se2 import compose, inverse
from tests.conftest import TRUTH

lengths = st.floats(0.01, 1.0)
wheel = st.one_of(st.floats(-60.0, 60.0), st.floats(-1e-6, 1e-6), st.just(0.0))
offset = st.floats(-0.5, 0.5)
angle = st.floats(-math.pi, math.pi, exclude_min=True)


def central_difference(model, phi_L, phi_R, theta, i, h):
    up, down = theta.copy(), theta.copy()
    up[i] += h
    down[i] -= h
    return (model.predict(phi_L, phi_R, up) - model.predict(phi_L, phi_R, down)) / (2 * h)


@settings(max_examples=300, deadline=None)
@given(r_L=lengths, r_R=lengths, b=lengths, phi_L=wheel, phi_R=wheel, l_x=offset, l_y=offset,
       l_t=angle)
def test_sensor_pose_jacobian_equals_finite_differences(r_L, r_R, b, phi_L, phi_R, l_x, l_y,
                                                        l_t):
    theta = np.array([r_L, r_R, b, l_x, l_y, l_t])
    phi_L, phi_R = np.array([phi_L]), np.array([phi_R])
    jac = SENSOR_POSE.jacobian(phi_L, phi_R, theta)[0]
    for i in range(6):
        h = 1e-6 * max(abs(theta[i]), 0.05)
        numeric = central_difference(SENSOR_POSE, phi_L, phi_R, theta, i, h)[0]
        # Central differences: error ~ h^2 * third derivative, plus rounding ~ eps * |s| / h.
        size = np.abs(SENSOR_POSE.predict(phi_L, phi_R, theta)[0]).max() + 1.0
        scale = max(abs(theta[i]), 0.05)
        tol = 1e-6 * size * (1.0 + (np.abs(phi_L) + np.abs(phi_R)).max() * max(r_L, r_R) / b) ** 3
        np.testing.assert_allclose(jac[:, i] * scale, numeric * scale, atol=tol, rtol=1e-5)


@settings(max_examples=200, deadline=None)
@given(r_L=lengths, r_R=lengths, b=lengths, phi_L=wheel, phi_R=wheel, l_x=offset, l_y=offset,
       l_t=angle)
def test_sensor_pose_prediction_is_se2_conjugation(r_L, r_R, b, phi_L, phi_R, l_x, l_y, l_t):
    o = np.array(predict_increment(phi_L, phi_R, Params(r_L, r_R, b)), dtype=float)
    l_pose = np.array([l_x, l_y, l_t])
    expected = compose(compose(inverse(l_pose), o), l_pose)
    got = SENSOR_POSE.predict(np.array([phi_L]), np.array([phi_R]),
                              np.array([r_L, r_R, b, l_x, l_y, l_t]))[0]
    np.testing.assert_allclose(got, expected, atol=1e-12 * (1 + np.abs(o).max()))
    back = sensor_to_body(got[None, :], SensorPose(l_x, l_y, l_t))[0]
    np.testing.assert_allclose(back, o, atol=1e-11 * (1 + np.abs(o).max()))


@settings(max_examples=100, deadline=None)
@given(r_L=lengths, r_R=lengths, b=lengths, phi_L=wheel, phi_R=wheel)
def test_sensor_pose_model_at_zero_is_the_axle_model(r_L, r_R, b, phi_L, phi_R):
    phi_L, phi_R = np.array([phi_L]), np.array([phi_R])
    p = np.array([r_L, r_R, b])
    axle = AXLE.jacobian(phi_L, phi_R, p)
    sensor = SENSOR_POSE.jacobian(phi_L, phi_R, np.append(p, [0.0, 0.0, 0.0]))
    np.testing.assert_allclose(sensor[..., :3], axle, rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(SENSOR_POSE.predict(phi_L, phi_R, np.append(p, [0, 0, 0])),
                               AXLE.predict(phi_L, phi_R, p), rtol=1e-13, atol=1e-300)


def test_axle_jacobian_is_the_public_increment_jacobian(rng):
    phi_L, phi_R = rng.normal(0, 5, 50), rng.normal(0, 5, 50)
    np.testing.assert_array_equal(increment_jacobian(phi_L, phi_R, TRUTH),
                                  AXLE.jacobian(phi_L, phi_R, TRUTH.as_array()))


def test_fixed_sensor_pose_model_is_the_first_three_columns(rng):
    pose = SensorPose(0.05, -0.03, 1.8)
    phi_L, phi_R = rng.normal(0, 5, 20), rng.normal(0, 5, 20)
    full = np.append(TRUTH.as_array(), pose.as_array())
    fixed = FixedSensorPoseModel(pose)
    np.testing.assert_array_equal(fixed.jacobian(phi_L, phi_R, TRUTH.as_array()),
                                  SENSOR_POSE.jacobian(phi_L, phi_R, full)[..., :3])
    assert fixed.split(TRUTH.as_array()) == (TRUTH, pose)


def test_models_are_batch_first(rng):
    """theta (B, P) with increments (B, N): robot b's rows equal the single-robot call."""
    thetas = np.column_stack([rng.uniform(0.04, 0.06, (4, 2)), rng.uniform(0.2, 0.4, 4),
                              rng.uniform(-0.1, 0.1, (4, 2)), rng.uniform(-3, 3, 4)])
    phi_L, phi_R = rng.normal(0, 8, (4, 7)), rng.normal(0, 8, (4, 7))
    batch = SENSOR_POSE.jacobian(phi_L, phi_R, thetas)
    assert batch.shape == (4, 7, 3, 6)
    for i in range(4):
        np.testing.assert_allclose(batch[i], SENSOR_POSE.jacobian(phi_L[i], phi_R[i], thetas[i]),
                                   rtol=1e-14, atol=1e-300)
    assert AXLE.predict(phi_L, phi_R, thetas[:, :3]).shape == (4, 7, 3)


def test_column_scale_and_step_follow_the_transforms():
    theta = np.array([0.05, 0.051, 0.3, 0.0, -0.02, 3.1])
    scale = SENSOR_POSE.column_scale(theta)
    np.testing.assert_array_equal(scale, [0.05, 0.051, 0.3, 0.3, 0.3, 1.0])
    moved = SENSOR_POSE.step(theta, np.array([0.1, 0, 0, 0.1, 0, 0.1]), scale)
    np.testing.assert_allclose(moved[:5], [0.05 * math.exp(0.1), 0.051, 0.3, 0.03, -0.02])
    assert moved[5] == pytest.approx(3.2 - 2 * math.pi)  # wrapped


def test_sensor_pose_rejects_non_finite_values():
    with pytest.raises(ValueError, match="finite"):
        SensorPose(0.0, float("nan"), 0.0)
    assert SensorPose(0, 0, 3 * math.pi).theta == pytest.approx(math.pi)


# --------------------------------------------------------------------------- sub-steps

substep_wheel = st.lists(st.floats(-8.0, 8.0), min_size=1, max_size=5)


def substep_prediction(model, sub_L, sub_R, theta):
    prediction, _ = model.evaluate(sub_L, sub_R, theta, jacobian=False, substeps=True)
    return prediction[:, 0]


@settings(max_examples=200, deadline=None)
@given(r_L=lengths, r_R=lengths, b=lengths, left=substep_wheel, right=substep_wheel,
       l_x=offset, l_y=offset, l_t=angle)
def test_substep_jacobian_equals_finite_differences(r_L, r_R, b, left, right, l_x, l_y, l_t):
    k = min(len(left), len(right))
    sub_L, sub_R = np.array([left[:k]]), np.array([right[:k]])
    theta = np.array([r_L, r_R, b, l_x, l_y, l_t])
    _, jac = SENSOR_POSE.evaluate(sub_L, sub_R, theta, substeps=True)
    for i in range(6):
        # the five-point stencil (error O(h^4)): with b = 0.01 m and turns of hundreds of rad
        # per sub-step, the central difference's O(h^2) error alone exceeded the tolerance
        h = 1e-6 * max(abs(theta[i]), 0.05)
        at = [substep_prediction(SENSOR_POSE, sub_L, sub_R, theta + j * h * np.eye(6)[i])
              for j in (-2, -1, 1, 2)]
        numeric = (at[0] - 8 * at[1] + 8 * at[2] - at[3]) / (12 * h)
        scale = max(1.0, float(np.abs(jac[:, i, 0]).max()))
        np.testing.assert_allclose(jac[:, i, 0], numeric, atol=2e-5 * scale)


def test_substeps_compose_the_arcs_and_zero_padding_is_the_identity(rng):
    """The composition of the sub-steps' arcs, each with the lateral term of its change of
    curvature (excite.core.models.curvature_change), written out here one sub-step at a
    time; padding changes nothing, and one sub-step is the arc."""
    sub_L, sub_R = rng.normal(0, 3, (7, 4)), rng.normal(0, 3, (7, 4))
    theta = np.array([0.05, 0.051, 0.3, 0.1, -0.05, 0.4])
    arcs = AXLE.predict(sub_L, sub_R, theta[:3])  # (7, 4, 3)
    ds = 0.5 * (theta[0] * sub_L + theta[1] * sub_R)
    dth = (theta[1] * sub_R - theta[0] * sub_L) / theta[2]
    for k in range(4):
        before = (ds[:, k - 1], dth[:, k - 1]) if k > 0 else (0.0, 0.0)
        after = (ds[:, k + 1], dth[:, k + 1]) if k < 3 else (0.0, 0.0)
        arcs[:, k, 1] += ((after[0] - before[0]) * dth[:, k]
                          - ds[:, k] * (after[1] - before[1])) / 24.0
    body = arcs[:, 0]
    for k in range(1, 4):
        body = compose(body, arcs[:, k])
    pose = theta[3:]
    sensor = compose(compose(inverse(pose), body), pose)
    prediction, _ = SENSOR_POSE.evaluate(sub_L, sub_R, theta, jacobian=False, substeps=True)
    np.testing.assert_allclose(prediction.T, sensor, atol=1e-12)
    padded = [np.pad(a, ((0, 0), (0, 3))) for a in (sub_L, sub_R)]
    again, _ = SENSOR_POSE.evaluate(*padded, theta, jacobian=False, substeps=True)
    np.testing.assert_allclose(again, prediction, atol=1e-15)
    one, _ = AXLE.evaluate(sub_L[:, :1], sub_R[:, :1], theta[:3], substeps=True)
    arc, _ = AXLE.evaluate(sub_L[:, 0], sub_R[:, 0], theta[:3])
    np.testing.assert_array_equal(one, arc)
    batch, batch_jac = SENSOR_POSE.evaluate(sub_L, sub_R, np.stack([theta, theta]),
                                            substeps=True)
    assert batch.shape == (3, 2, 7) and batch_jac.shape == (3, 6, 2, 7)
    np.testing.assert_allclose(batch[:, 1], prediction, atol=1e-15)


# --------------------------------------------------------------------------- wheel Jacobian


def _five_point(f, x: np.ndarray, index: tuple, h: float) -> np.ndarray:
    """d f / d x[index] by the five-point stencil (error O(h^4))."""
    values = []
    for j in (-2, -1, 1, 2):
        moved = x.copy()
        moved[index] += j * h
        values.append(f(moved))
    return (values[0] - 8 * values[1] + 8 * values[2] - values[3]) / (12 * h)


@settings(max_examples=200, deadline=None)
@given(r_L=lengths, r_R=lengths, b=lengths, left=substep_wheel, right=substep_wheel,
       l_x=offset, l_y=offset, l_t=angle)
@pytest.mark.slow
def test_wheel_jacobian_equals_finite_differences(r_L, r_R, b, left, right, l_x, l_y, l_t):
    """d(measured increment)/d(each wheel sub-increment) of the three models, with sub-steps
    and (the first sub-step alone) without, against five-point differences."""
    k = min(len(left), len(right))
    wheels = np.array([left[:k], right[:k]])[:, None, :]  # (2 wheels, 1 segment, K)
    pose = SensorPose(l_x, l_y, l_t)
    models = ((AXLE, np.array([r_L, r_R, b])),
              (SENSOR_POSE, np.array([r_L, r_R, b, l_x, l_y, l_t])),
              (FixedSensorPoseModel(pose), np.array([r_L, r_R, b])))
    for model, theta in models:
        jac = model.wheel_jacobian(wheels[0], wheels[1], theta, substeps=True)[0]  # (K, 3, 2)
        single = model.wheel_jacobian(wheels[0, :, 0], wheels[1, :, 0], theta)[0]  # (3, 2)
        assert jac.shape == (k, 3, 2)

        def composed(w, model=model, theta=theta):
            return substep_prediction(model, w[0], w[1], theta)

        def one_arc(w, model=model, theta=theta):
            return model.predict(w[0], w[1], theta)[0]

        for wheel_index in range(2):
            for j in range(k):
                h = 1e-6 * max(abs(wheels[wheel_index, 0, j]), 1.0)
                numeric = _five_point(composed, wheels, (wheel_index, 0, j), h)
                scale = max(1.0, float(np.abs(jac[j, :, wheel_index]).max()))
                np.testing.assert_allclose(jac[j, :, wheel_index], numeric, atol=2e-5 * scale)
            first = wheels[:, :, :1].copy()
            h = 1e-6 * max(abs(first[wheel_index, 0, 0]), 1.0)
            numeric = _five_point(lambda w: one_arc(w[:, :, 0]), first, (wheel_index, 0, 0), h)
            scale = max(1.0, float(np.abs(single[:, wheel_index]).max()))
            np.testing.assert_allclose(single[:, wheel_index], numeric, atol=2e-5 * scale)


def test_wheel_jacobian_is_batch_first(rng):
    """theta (B, P) with sub-increments (B, N, K): robot b's rows equal its own call."""
    thetas = np.column_stack([rng.uniform(0.04, 0.06, (3, 2)), rng.uniform(0.2, 0.4, 3),
                              rng.uniform(-0.1, 0.1, (3, 2)), rng.uniform(-3, 3, 3)])
    sub_L, sub_R = rng.normal(0, 2, (3, 5, 4)), rng.normal(0, 2, (3, 5, 4))
    batch = SENSOR_POSE.wheel_jacobian(sub_L, sub_R, thetas, substeps=True)
    assert batch.shape == (3, 5, 4, 3, 2)
    for i in range(3):
        np.testing.assert_allclose(
            batch[i], SENSOR_POSE.wheel_jacobian(sub_L[i], sub_R[i], thetas[i], substeps=True),
            rtol=1e-13, atol=1e-300)


def test_substeps_with_changing_curvature_are_dead_reckoning_to_third_order():
    """Wheels whose speeds change smoothly over a 1 s segment: the composition of 50
    sub-steps (20 ms) against that of 4000 (0.25 ms, the limit to 1e-9 m). One arc per
    sub-step erred by O(h^2) (about 1e-5 m); with the curvature-change term the error is
    O(h^3), below a twentieth of that."""
    theta = np.array([0.05, 0.051, 0.3])
    t = np.linspace(0.0, 1.0, 4001)
    left = 8.0 + 6.0 * np.sin(2.1 * t + 0.3)  # rad/s
    right = 10.0 - 7.0 * np.cos(3.3 * t)
    angle_L = np.concatenate([[0.0], np.cumsum(0.5 * (left[1:] + left[:-1]) * np.diff(t))])
    angle_R = np.concatenate([[0.0], np.cumsum(0.5 * (right[1:] + right[:-1]) * np.diff(t))])

    def composed(every: int) -> np.ndarray:
        sub_L, sub_R = np.diff(angle_L[::every])[None], np.diff(angle_R[::every])[None]
        return AXLE.evaluate(sub_L, sub_R, theta, jacobian=False, substeps=True)[0][:, 0]

    limit, coarse = composed(1), composed(80)
    arcs = AXLE.predict(np.diff(angle_L[::80]), np.diff(angle_R[::80]), theta)
    plain = arcs[0]
    for k in range(1, len(arcs)):
        plain = compose(plain, arcs[k])
    uncorrected = np.hypot(*(plain[:2] - limit[:2]))
    assert uncorrected > 1e-6  # the case is one the term matters for
    assert np.hypot(*(coarse[:2] - limit[:2])) < uncorrected / 20
    np.testing.assert_allclose(coarse[2], limit[2], atol=1e-12)
