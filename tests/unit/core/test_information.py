"""The fast information paths against the Jacobian they summarise, and the 3x3 eigensolver
against LAPACK."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excite import Params
from excite.core import information as I

# Wheel increments (rad) giving heading changes from exactly 0 through tiny, the series seam
# and several turns, including straight segments (equal increments) and spins.
increments = st.one_of(st.just(0.0), st.floats(-1e-6, 1e-6), st.floats(-400.0, 400.0))
segments = st.lists(st.tuples(increments, increments), min_size=1, max_size=80)
params_values = st.builds(
    Params, st.floats(0.02, 0.2), st.floats(0.02, 0.2), st.floats(0.1, 1.0)
)
TINY = 1e-300  # below the normal range (products of increments ~1e-150 land there)
sigmas = st.one_of(
    st.builds(lambda xy, th: (xy, xy, th), st.floats(1e-6, 1.0), st.floats(1e-6, 3.0)),
    st.sampled_from([(2e-3, 2e-3, 1e-3), (2e-3, 5e-3, 1e-3)]),  # the last: sigma_x != sigma_y
)


def _reference(phi: np.ndarray, p: Params, sigma, scale: Params) -> np.ndarray:
    return I.fisher_information(I.scaled_jacobian(phi[:, 0], phi[:, 1], p, sigma, scale))


@settings(max_examples=300, deadline=None)
@given(segs=segments, p=params_values, sigma=sigmas)
def test_information_matrix_equals_the_sum_of_jacobian_products(segs, p, sigma):
    """Both paths (pure-Python moments up to _LOOP_MAX segments, vectorized rows above; the
    Jacobian itself when sigma_x != sigma_y)."""
    phi = np.array(segs)
    scale = Params(0.05, 0.05, 0.3)
    expected = _reference(phi, p, sigma, scale)
    got = I.information_matrix(phi[:, 0], phi[:, 1], p, sigma, scale)
    # Rounding: a few eps of the largest entry (the sums are of positive terms of that size),
    # or the subnormal range where products of tiny increments lose their precision.
    np.testing.assert_allclose(got, expected, rtol=0,
                               atol=1e-13 * np.abs(expected).max() + TINY)


@settings(max_examples=200, deadline=None)
@given(segs=segments, p=params_values, sigma=sigmas)
def test_segment_information_equals_each_jacobian_product(segs, p, sigma):
    phi = np.array(segs)
    jac = I.scaled_jacobian(phi[:, 0], phi[:, 1], p, sigma)
    expected = np.einsum("nki,nkj->nij", jac, jac)
    got = I.segment_information(phi[:, 0], phi[:, 1], p, sigma)
    size = np.abs(expected).max(axis=(1, 2))[:, None, None]
    assert np.all(np.abs(got - expected) <= 1e-13 * size + TINY)


def test_information_matrix_rejects_bad_sigma():
    with pytest.raises(ValueError, match="sigma"):
        I.information_matrix([1.0], [2.0], Params(0.05, 0.05, 0.3), (2e-3, 0.0, 1e-3))
    with pytest.raises(ValueError, match="sigma"):
        I.information_matrix([1.0], [2.0], Params(0.05, 0.05, 0.3), (2e-3, np.nan, 1e-3))


def _random_symmetric(rng: np.random.Generator, eigenvalues) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    f = (q * np.asarray(eigenvalues, dtype=float)) @ q.T
    return 0.5 * (f + f.T)


def _eigen_cases(rng: np.random.Generator):
    for _ in range(400):
        yield _random_symmetric(rng, rng.uniform(0, 1, 3))
        yield _random_symmetric(rng, 10.0 ** rng.uniform(-12, 10, 3))  # ill-conditioned
        big = 10.0 ** rng.uniform(-6, 8)
        small = 10.0 ** rng.uniform(-6, 8)
        yield _random_symmetric(rng, [big, big * (1 + 1e-9 * rng.normal()), small])
        yield _random_symmetric(rng, [0.0, 0.0, rng.uniform()])  # rank one
        yield _random_symmetric(rng, [1.0, 1.0, 1.0 + 1e-12])  # nearly a multiple of I
    yield from (np.zeros((3, 3)), np.eye(3), np.diag([3.0, 1.0, 2.0]),
                np.diag([3.0, 3.0, 1.0]), np.diag([1.0, 3.0, 3.0]), np.diag([0.0, 0.0, 1.0]))


def test_eigen_3x3_matches_lapack():
    eps = np.finfo(float).eps
    for f in _eigen_cases(np.random.default_rng(2)):
        (low, mid, high), v = I.eigen_3x3(f)
        lam, vec = np.linalg.eigh(f)
        size = max(np.abs(lam).max(), 1e-300)
        assert np.all(np.abs(np.array([low, mid, high]) - lam) <= 20 * eps * size), (f, lam)
        v = np.array(v)
        assert abs(np.linalg.norm(v) - 1.0) <= 10 * eps
        # An eigenvector of the smallest eigenvalue: residual of order eps * ||F||, and the
        # same direction as LAPACK's where the eigenvalue is well separated.
        assert np.linalg.norm(f @ v - low * v) <= 20 * eps * size, f
        if lam[1] - lam[0] > 1e-6 * size:
            assert 1.0 - abs(v @ vec[:, 0]) <= 1e-12


def test_eigen_3x3_of_environment_like_information():
    """F of real segment sets at every length, conditioning from rank-deficient up."""
    rng = np.random.default_rng(3)
    p = Params(0.05, 0.051, 0.3)
    for n in range(1, 40):
        phi = rng.uniform(-30, 30, (n, 2))
        f = I.information_matrix(phi[:, 0], phi[:, 1], p, (2e-3, 2e-3, 1e-3))
        lam, _ = np.linalg.eigh(f)
        got, _ = I.eigen_3x3(f)
        tol = 50 * np.finfo(float).eps * lam[-1]
        assert np.allclose(got, lam, rtol=0, atol=tol)
        # |sqrt(a) - sqrt(b)| <= sqrt(|a - b|): sigma_min is known to sqrt(tol) where the
        # smallest eigenvalue sits at the rounding level (a single segment: rank 2).
        assert math.sqrt(max(got[0], 0.0)) == pytest.approx(I.sigma_min(f), rel=1e-9,
                                                            abs=math.sqrt(tol))


def test_increments_broadcast_like_the_jacobian():
    p, sigma = Params(0.05, 0.051, 0.3), (2e-3, 2e-3, 1e-3)
    right = np.linspace(-20, 20, 40)
    expected = _reference(np.column_stack([np.full(40, 3.0), right]), p, sigma, p)
    for n in (5, 40):  # both summation paths
        np.testing.assert_allclose(
            I.information_matrix(3.0, right[:n], p, sigma),
            _reference(np.column_stack([np.full(n, 3.0), right[:n]]), p, sigma, p), rtol=1e-13)
    np.testing.assert_allclose(I.segment_information(3.0, right, p, sigma).sum(axis=0),
                               expected, rtol=1e-13)


def test_straight_segments_leave_b_entries_exact_and_f_psd():
    """The b entries come from sums of v = dtheta / 2 itself, not from an expansion in the
    wheel increments that would cancel for straight segments: exactly straight segments give
    exactly zero b entries, nearly straight ones a non-negative F[2, 2] that agrees with the
    Jacobian's up to the conditioning of dtheta = (r_R dphi_R - r_L dphi_L) / b itself."""
    rng = np.random.default_rng(4)
    p, sigma = Params(0.05, 0.05, 0.3), (2e-3, 2e-3, 1e-3)
    eps = np.finfo(float).eps
    for _ in range(300):
        n = int(rng.integers(1, I._LOOP_MAX + 1))
        left = rng.uniform(-40, 40, n)
        straight = I.information_matrix(left, left, p, sigma)
        assert np.all(straight[2] == 0.0) and np.all(straight[:, 2] == 0.0)
        right = left * (1.0 + rng.choice([1e-12, 1e-8, 1e-4], n))
        f = I.information_matrix(left, right, p, sigma)
        expected = _reference(np.column_stack([left, right]), p, sigma, p)
        assert f[2, 2] >= 0.0
        travel = p.r_L * np.abs(left) + p.r_R * np.abs(right)
        kappa = np.max(travel / np.abs(p.r_R * right - p.r_L * left))  # of dtheta
        tol = (1e-13 + 10 * eps * kappa) * np.abs(expected)
        assert np.all(np.abs(f - expected) <= tol + TINY), (f, expected)


def test_non_finite_increments_give_nan_like_the_jacobian():
    p, sigma = Params(0.05, 0.05, 0.3), (2e-3, 2e-3, 1e-3)
    for bad in (np.inf, -np.inf, np.nan):
        for n in (3, I._LOOP_MAX + 3):  # both summation paths
            left = np.ones(n)
            left[1] = bad
            with np.errstate(invalid="ignore"):
                assert np.isnan(I.information_matrix(left, np.ones(n), p, sigma)).any()


def test_mismatched_increment_shapes_are_rejected_like_the_jacobian():
    p, sigma = Params(0.05, 0.05, 0.3), (2e-3, 2e-3, 1e-3)
    for function in (I.information_matrix, I.segment_information, I.scaled_jacobian):
        with pytest.raises(ValueError):
            function(np.ones((2, 3)), np.ones((3, 2)), p, sigma)


@pytest.mark.parametrize("scale", [1e-300, 1e-200, 1e-100, 1.0, 1e100, 1e200, 1e300])
def test_eigen_3x3_at_any_scale(scale):
    rng = np.random.default_rng(5)
    for f in (np.diag([1.0, 2.0, 3.0]), np.eye(3) + 1e-100 * (1 - np.eye(3)),
              np.eye(3) + 1e-160 * (1 - np.eye(3)), _random_symmetric(rng, [1e-8, 0.5, 1.0])):
        (low, mid, high), v = I.eigen_3x3(f * scale)
        lam, vec = np.linalg.eigh(f)
        np.testing.assert_allclose(np.array([low, mid, high]) / scale, lam, rtol=0,
                                   atol=20 * np.finfo(float).eps * lam[-1])
        assert abs(np.linalg.norm(v) - 1.0) <= 1e-15


def test_eigen_3x3_propagates_nan_and_inf():
    for bad in (np.nan, np.inf):
        f = np.eye(3)
        f[0, 1] = f[1, 0] = bad
        values, vector = I.eigen_3x3(f)
        assert np.isnan(values).all() and np.isnan(vector).all()


def test_inverse_information_keeps_weak_but_determined_directions():
    """Exact data: a heading known to 1e-11 rad beside lengths known to 1e-5 make F's
    eigenvalues span 14 orders of magnitude; every direction is still determined, so the
    variances are finite and F^-1's. A direction null up to rounding stays inf."""
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    f = basis @ np.diag([1.2e22, 5.9e20, 5.8e8]) @ basis.T
    inverse = I.inverse_information(f)
    assert np.all(np.isfinite(inverse))
    exact = basis @ np.diag(1.0 / np.array([1.2e22, 5.9e20, 5.8e8])) @ basis.T
    np.testing.assert_allclose(inverse, exact, rtol=2e-2)  # rounding: eps x condition
    null = basis @ np.diag([1.2e22, 5.9e20, 1e22 * 1e-17]) @ basis.T
    undetermined = np.isinf(np.diag(I.inverse_information(null)))
    np.testing.assert_array_equal(undetermined, basis[:, 2] ** 2 > 1e-2)  # those in it
