import math

import mpmath
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excite import Params, increment_jacobian, predict_increment
from excite.core import kinematics as K

# Heading changes spanning exactly zero, subnormal-tiny, the series/closed-form seam, half
# turns and several full turns, each with either sign.
dtheta_values = st.one_of(
    st.just(0.0),
    st.floats(1e-300, 1e-8),
    st.floats(1e-8, 1e-2),
    st.floats(0.5, 1.5),
    st.floats(1e-2, 4 * math.pi),
    st.floats(4 * math.pi, 30 * math.pi),
).flatmap(lambda x: st.sampled_from([x, -x]))
ds_values = st.one_of(st.just(0.0), st.floats(1e-9, 1e-4), st.floats(-3.0, 3.0))
params_values = st.builds(
    Params, st.floats(0.01, 0.3), st.floats(0.01, 0.3), st.floats(0.05, 1.5)
)


def wheels_for(ds: float, dtheta: float, p: Params) -> tuple[float, float]:
    """Encoder increments producing a given (ds, dtheta) on robot p."""
    return (ds - 0.5 * p.b * dtheta) / p.r_L, (ds + 0.5 * p.b * dtheta) / p.r_R


@settings(max_examples=400, deadline=None)
@given(ds=ds_values, dtheta=dtheta_values, p=params_values)
def test_jacobian_matches_central_differences(ds, dtheta, p):
    phi_L, phi_R = wheels_for(ds, dtheta, p)
    x = p.as_array()
    jac = increment_jacobian(phi_L, phi_R, p)[0]

    def central(j: int, h: float) -> np.ndarray:
        up, down = x.copy(), x.copy()
        up[j] *= 1 + h
        down[j] *= 1 - h
        return (np.array(predict_increment(phi_L, phi_R, up))
                - np.array(predict_increment(phi_L, phi_R, down))) / (2 * h)

    value = np.abs(np.array(predict_increment(phi_L, phi_R, x)))
    # Absolute floor for entries that vanish analytically (e.g. at dtheta = 2 pi k): the
    # finite differences' own rounding, ~10 eps |travel| / h (travel: the wheel travel of the
    # segment, m for dx, dy; rad for dtheta), i.e. 4e-11 of the travel for h = 5e-5.
    wheel_travel = max(abs(p.r_L * phi_L), abs(p.r_R * phi_R))
    travel = np.array([wheel_travel, wheel_travel, wheel_travel / p.b])
    for j in range(3):
        # Richardson-extrapolated central differences: truncation O(h^4), rounding
        # O(eps |f| / h), both far below the tolerance for relative steps h = 1e-4.
        fd = (4 * central(j, 5e-5) - central(j, 1e-4)) / 3
        analytic = jac[:, j] * x[j]  # derivative with respect to the relative parameter
        # (+ the spacing of subnormal numbers, the resolution of values that small)
        rounding = 10 * (np.finfo(float).eps * travel + np.finfo(float).smallest_subnormal) / 5e-5
        tol = 1e-6 * np.maximum(np.abs(jac * x).max(axis=1), value) + rounding
        assert np.all(np.abs(fd - analytic) <= tol), (j, fd, analytic)


@settings(max_examples=300, deadline=None)
@given(ds=ds_values, dtheta=dtheta_values, p=params_values)
def test_no_nan_or_inf_anywhere(ds, dtheta, p):
    phi_L, phi_R = wheels_for(ds, dtheta, p)
    assert np.all(np.isfinite(predict_increment(phi_L, phi_R, p)))
    assert np.all(np.isfinite(increment_jacobian(phi_L, phi_R, p)))


def _closed_forms(u):
    s, c = np.sin(u), np.cos(u)
    omc = 2 * np.sin(u / 2) ** 2
    return s / u, omc / u, (u * c - s) / u**2, (u * s - omc) / u**2


def _series(u):
    u2 = u * u
    return (K._series(K._SINC, u2), u * K._series(K._COSC, u2),
            u * K._series(K._DSINC, u2), K._series(K._DCOSC, u2))


@pytest.mark.parametrize("u", [1.0, -1.0, np.nextafter(1.0, 0), 0.999, 1.001])
def test_series_and_closed_forms_agree_at_the_seam(u):
    for a, b in zip(_series(u), _closed_forms(u), strict=True):
        assert abs(a - b) <= 4e-16 * max(abs(a), 1e-300) + 1e-17


def test_series_match_closed_forms_where_the_latter_are_accurate():
    u = np.linspace(0.3, 0.999, 50)
    for a, b in zip(_series(u), _closed_forms(u), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-13)


def test_limits_at_zero():
    f, g, fp, gp = K.sinc_family(np.array([0.0, -0.0]))
    np.testing.assert_array_equal(f, 1.0)
    np.testing.assert_array_equal(g, 0.0)
    np.testing.assert_array_equal(fp, 0.0)
    np.testing.assert_array_equal(gp, 0.5)


def test_sinc_family_is_accurate_everywhere():
    """Against 50-digit arithmetic, in units of the functions' natural size."""
    rng = np.random.default_rng(1)
    u = np.concatenate([[0.0, -0.0, 5e-324, 1e-300, 1e-9, -1e-5, 0.999999, 1.0],
                        rng.uniform(-1.2, 1.2, 400), rng.uniform(-60, 60, 400)])

    def exact(x: float) -> tuple[float, float, float, float]:
        if x == 0.0:
            return 1.0, 0.0, 0.0, 0.5
        # 1 - cos(x) ~ x^2 / 2 cancels: twice the digits of x's exponent more
        with mpmath.workdps(50 + 2 * max(0, -math.floor(math.log10(abs(x))))):
            m = mpmath.mpf(x)
            s, c = mpmath.sin(m), mpmath.cos(m)
            return (float(s / m), float((1 - c) / m), float((m * c - s) / m**2),
                    float((m * s - (1 - c)) / m**2))

    ref = np.array([exact(x) for x in u]).T
    size = np.maximum(1.0 / np.maximum(np.abs(u), 1.0), np.abs(ref[0]))  # ~1/|u| far out
    scalar = np.array([K.sinc_family_scalar(x) for x in u.tolist()]).T
    for form in (K.sinc_family(u), scalar):
        for got, expected in zip(form, ref, strict=True):
            assert np.all(np.abs(got - expected) <= 4 * np.finfo(float).eps * size)


def test_straight_spin_and_full_circle():
    p = Params(0.05, 0.05, 0.3)
    dx, dy, dth = predict_increment(10.0, 10.0, p)
    assert (dx, dy, dth) == (pytest.approx(0.5), 0.0, 0.0)
    dx, dy, dth = predict_increment(-4.0, 4.0, p)
    assert dx == 0.0 and dy == 0.0 and dth == pytest.approx(0.4 / 0.3)
    phi_L, phi_R = wheels_for(1.0, 2 * math.pi, p)
    dx, dy, dth = predict_increment(phi_L, phi_R, p)
    assert abs(dx) < 1e-15 and abs(dy) < 1e-15 and dth == pytest.approx(2 * math.pi)


@pytest.mark.parametrize("ds,dtheta", [(1.0, 0.7), (0.4, -2.5), (0.8, 7.0), (-0.6, 0.2)])
def test_increment_matches_integrated_unicycle(ds, dtheta):
    """Independent check of the closed form: integrate x' = v cos th, y' = v sin th."""
    p = Params(0.05, 0.052, 0.31)
    phi_L, phi_R = wheels_for(ds, dtheta, p)
    n = 200_000
    th = (np.arange(n) + 0.5) / n * dtheta  # midpoint rule
    expected = (ds / n * np.cos(th).sum(), ds / n * np.sin(th).sum(), dtheta)
    np.testing.assert_allclose(predict_increment(phi_L, phi_R, p), expected, atol=1e-9)


def test_vectorized_shapes_and_sign_convention():
    p = Params(0.05, 0.05, 0.3)
    jac = increment_jacobian(np.zeros(7), np.ones(7), p)
    assert jac.shape == (7, 3, 3)
    # Right wheel forward, left still: the robot turns left (counter-clockwise, +y).
    dx, dy, dth = predict_increment(0.0, 1.0, p)
    assert dth > 0 and dy > 0 and dx > 0


@pytest.mark.parametrize("bad", [(0.0, 0.05, 0.3), (0.05, -1.0, 0.3), (0.05, 0.05, np.nan),
                                 (0.05, 0.05, np.inf)])
def test_params_reject_non_physical_values(bad):
    with pytest.raises(ValueError, match="positive finite"):
        Params(*bad)


def test_params_immutable_and_array():
    p = Params(0.05, 0.06, 0.3)
    np.testing.assert_array_equal(p.as_array(), [0.05, 0.06, 0.3])
    with pytest.raises(AttributeError):
        p.b = 1.0  # type: ignore[misc]
