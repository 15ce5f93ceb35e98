"""Pooling estimates of one parameter vector from several groups (multivariate
meta-analysis): the fixed-effects (common) estimate and its heterogeneity statistic, the
method-of-moments between-group covariance, and the random-effects estimate.

The groups' estimates y_g (G groups, p parameters each) have a joint covariance V (G p x G p;
block diagonal for independent groups, dense when groups share data). The model is
y_g = mu + u_g + e_g, with e ~ N(0, V) and independent between-group effects u_g ~ N(0, T):

* **Fixed effects** (T = 0): mu_FE = (X' W X)^-1 X' W y with W = V^-1, X = 1_G (x) I_p.
  The heterogeneity statistic Q = (y - X mu_FE)' W (y - X mu_FE), Cochran's Q generalised to
  vectors and correlated groups, is chi-square with (G - 1) p degrees of freedom when T = 0.
* **The between-group covariance** T by the method of moments (Jackson, White & Thompson,
  Stat. Med. 2010, generalised to correlated groups): the matrix
  Q_M = sum_g [W r]_g r_g' (r = y - X mu_FE) has expectation
  sum_g [P V]_gg + sum_g [P (I_G (x) T) P V]_gg, P = W - W X (X' W X)^-1 X' W, linear in T;
  T solves it in least squares and is truncated to its positive semi-definite part. For one
  parameter and independent groups it is DerSimonian & Laird's estimator.
* **Random effects**: mu_RE = (X' W* X)^-1 X' W* y with W* = (V + I_G (x) T)^-1, covariance
  (X' W* X)^-1: the estimate of the mean over groups, its std covering the groups' spread.
  From few groups T is itself uncertain and that covariance too narrow; the adjusted
  covariance is Knapp & Hartung's (Stat. Med. 2003), multivariate and never narrower: scaled
  by max(1, Q* / ((G - 1) p)), Q* the residuals' quadratic form under V + I (x) T, and by
  p F_(p, (G-1)p)(0.95) / chi2_p(0.95), so that its 95% chi-square ellipse is the F-based one.
* **The fixed-effects estimate under random effects**: mu_FE = A y, A = (X' W X)^-1 X' W,
  as an estimate of mu has the covariance (X' W X)^-1 + A (I_G (x) T) A': the groups' spread
  carried through its weights adds the second term, which depends on the estimated T and is
  adjusted for few groups as above (Q* at mu_FE). When the groups are parts of one data set
  that share information (dense V), mu_FE keeps the information the groups share, which
  mu_RE, weighting with V + I (x) T, gives away.
* **Estimated noise levels.** When V comes from noise levels estimated with nu residual
  degrees of freedom, Q / ((G - 1) p) is compared with F((G - 1) p, nu) rather than
  Q with chi-square (the Wald test's small-sample form); nu = inf is the chi-square test.

Units: whatever the estimates' (the covariances in their squares); callers pass relative
units so that the matrices are well conditioned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.stats.chi2 import chi2_quantile, chi2_survival

__all__ = ["Pooled", "pool", "leave_one_out", "pairwise_z"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Pooled:
    """The pooled estimates of G groups' p parameters.

    fixed_mean (p,), fixed_covariance (p, p): the fixed-effects (common) estimate.
    statistic: the heterogeneity statistic Q; dof: (G - 1) p; p_value: P(chi2(dof) > Q).
    between (p, p): the method-of-moments between-group covariance T (positive semi-definite;
    zero when the groups agree). random_mean (p,), random_covariance (p, p): the
    random-effects estimate (the fixed-effects one when T = 0). adjusted_covariance (p, p):
    its covariance adjusted for few groups (Knapp-Hartung, module docstring).
    fixed_spread (p, p): what the groups' spread adds to the covariance of fixed_mean as an
    estimate of the mean over groups, A (I (x) T) A' adjusted for few groups (module
    docstring; zero when T = 0).
    """

    fixed_mean: FloatArray
    fixed_covariance: FloatArray
    statistic: float
    dof: int
    p_value: float
    between: FloatArray
    random_mean: FloatArray
    random_covariance: FloatArray
    adjusted_covariance: FloatArray
    fixed_spread: FloatArray


def _design(groups: int, p: int) -> FloatArray:
    """X = 1_G (x) I_p: every group's parameters are the common ones."""
    return np.tile(np.eye(p), (groups, 1))


def _gls(y: FloatArray, weight: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The generalised least-squares mean (X' W X)^-1 X' W y and its covariance."""
    covariance = np.linalg.inv(x.T @ weight @ x)
    covariance = 0.5 * (covariance + covariance.T)
    return covariance @ (x.T @ weight @ y), covariance


def _block_diagonal_sum(a: FloatArray, groups: int, p: int) -> FloatArray:
    """sum_g of the g-th p x p diagonal block of a (G p x G p)."""
    return np.einsum("gigj->ij", a.reshape(groups, p, groups, p))


def _between(y: FloatArray, covariance: FloatArray, weight: FloatArray, x: FloatArray,
             groups: int, p: int) -> FloatArray:
    """The method-of-moments between-group covariance T (module docstring), PSD part."""
    mean, _ = _gls(y, weight, x)
    residual = y - x @ mean
    projector = weight - weight @ x @ np.linalg.solve(x.T @ weight @ x, x.T @ weight)
    moments = np.einsum("gi,gj->ij", (weight @ residual).reshape(groups, p),
                        residual.reshape(groups, p))
    moments = 0.5 * (moments + moments.T)
    offset = _block_diagonal_sum(projector @ covariance, groups, p)
    offset = 0.5 * (offset + offset.T)
    unknowns = [(a, b) for a in range(p) for b in range(a, p)]
    columns = []
    for a, b in unknowns:
        basis = np.zeros((p, p))
        basis[a, b] = basis[b, a] = 1.0
        effect = _block_diagonal_sum(
            projector @ np.kron(np.eye(groups), basis) @ projector @ covariance, groups, p)
        columns.append((0.5 * (effect + effect.T))[np.triu_indices(p)])
    lhs = np.column_stack(columns)
    rhs = (moments - offset)[np.triu_indices(p)]
    solution = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    between = np.zeros((p, p))
    for value, (a, b) in zip(solution, unknowns, strict=True):
        between[a, b] = between[b, a] = value
    lam, vec = np.linalg.eigh(between)
    return (vec * np.maximum(lam, 0.0)) @ vec.T


def _f_quantile(q: float, dof: float, dof2: float) -> float:
    """The q-quantile of the F distribution (chi-square's over dof when dof2 is inf)."""
    from scipy.special import fdtri

    return chi2_quantile(q, dof) / dof if math.isinf(dof2) else float(fdtri(dof, dof2, q))


def _f_survival(x: float, dof: float, dof2: float) -> float:
    """P(F > x) for F with (dof, dof2) degrees of freedom (chi-square's over dof when dof2
    is inf)."""
    from scipy.special import fdtrc

    return chi2_survival(x * dof, dof) if math.isinf(dof2) else float(fdtrc(dof, dof2, x))


def pool(estimates: ArrayLike, covariance: ArrayLike, residual_dof: float = math.inf
         ) -> Pooled:
    """The fixed- and random-effects pooled estimates of ``estimates`` (G, p), whose joint
    covariance is ``covariance`` (G p, G p), positive definite, in the stacked order
    (group-major); ``residual_dof``: the degrees of freedom of the noise levels behind the
    covariance (inf: known); see the module docstring. Needs G >= 2."""
    y_groups = np.asarray(estimates, dtype=float)
    groups, p = y_groups.shape
    if groups < 2:
        raise ValueError("pooling needs at least two groups")
    y = y_groups.reshape(-1)
    v = np.asarray(covariance, dtype=float)
    v = 0.5 * (v + v.T)
    weight = np.linalg.inv(v)
    x = _design(groups, p)
    fixed_mean, fixed_covariance = _gls(y, weight, x)
    residual = y - x @ fixed_mean
    statistic = float(residual @ weight @ residual)
    dof = (groups - 1) * p
    between = _between(y, v, weight, x, groups, p)
    spread_between = np.kron(np.eye(groups), between)
    random_weight = np.linalg.inv(v + spread_between)
    random_mean, random_covariance = _gls(y, random_weight, x)
    few = p * _f_quantile(0.95, p, dof) / chi2_quantile(0.95, p)

    def knapp_hartung(mean: FloatArray) -> float:
        spread = y - x @ mean
        return few * max(1.0, float(spread @ random_weight @ spread) / dof)

    gain = fixed_covariance @ x.T @ weight  # fixed_mean = gain @ y
    fixed_spread = gain @ spread_between @ gain.T
    fixed_spread = 0.5 * (fixed_spread + fixed_spread.T)
    return Pooled(fixed_mean, fixed_covariance, statistic, dof,
                  _f_survival(statistic / dof, dof, residual_dof), between, random_mean,
                  random_covariance, knapp_hartung(random_mean) * random_covariance,
                  knapp_hartung(fixed_mean) * fixed_spread)


def leave_one_out(estimates: ArrayLike, covariance: ArrayLike) -> FloatArray:
    """For each group g, the squared Mahalanobis distance (dimensionless) of its estimate
    from the fixed-effects estimate of the other groups, with the covariance of their
    difference (correlations between groups included): chi-square with p degrees of freedom
    when the groups agree. Needs G >= 2 (with two groups both distances are the same)."""
    y_groups = np.asarray(estimates, dtype=float)
    groups, p = y_groups.shape
    y = y_groups.reshape(-1)
    v = np.asarray(covariance, dtype=float)
    distances = np.empty(groups)
    for g in range(groups):
        own = np.arange(g * p, (g + 1) * p)
        rest = np.setdiff1d(np.arange(groups * p), own)
        weight = np.linalg.inv(v[np.ix_(rest, rest)])
        x = _design(groups - 1, p)
        gain = np.linalg.solve(x.T @ weight @ x, x.T @ weight)  # mu_rest = gain @ y[rest]
        a = np.zeros((p, groups * p))
        a[:, own] = np.eye(p)
        a[:, rest] -= gain
        difference = a @ y
        distances[g] = float(difference @ np.linalg.solve(a @ v @ a.T, difference))
    return distances


def pairwise_z(estimates: ArrayLike, covariance: ArrayLike) -> FloatArray:
    """(G, G, p): for each pair of groups and each parameter, the difference of the two
    estimates over its std (correlations between groups included); 0 on the diagonal."""
    y_groups = np.asarray(estimates, dtype=float)
    groups, p = y_groups.shape
    v = np.asarray(covariance, dtype=float).reshape(groups, p, groups, p)
    var = np.einsum("gigi->gi", v)
    cross = np.einsum("gihi->ghi", v)
    difference = y_groups[:, None, :] - y_groups[None, :, :]
    spread = var[:, None, :] + var[None, :, :] - 2.0 * cross
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(spread > 0, difference / np.sqrt(np.maximum(spread, 1e-300)), 0.0)
    return z
