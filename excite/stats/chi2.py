"""Chi-square quantiles and tail probabilities, and the chi-bar-square quantile of variance
components on the boundary of their space.

scipy's special functions are imported on first use (scipy.stats is too slow to import).
"""

from __future__ import annotations

import math

__all__ = ["chi2_quantile", "chi2_survival", "chi_bar_square_quantile"]


def chi2_quantile(q: float, dof: float) -> float:
    """The q-quantile of the chi-square distribution with ``dof`` degrees of freedom."""
    from scipy.special import chdtri

    return float(chdtri(dof, 1.0 - q))


def chi2_survival(x: float, dof: float) -> float:
    """P(X > x) for X chi-square with ``dof`` degrees of freedom."""
    from scipy.special import chdtrc

    return float(chdtrc(dof, x))


def chi_bar_square_quantile(q: float, components: int) -> float:
    """The q-quantile (2^-n < q < 1) of the chi-bar-square distribution of the likelihood ratio
    for n = ``components`` orthogonal variance components on the boundary: the mixture
    sum_k binom(n, k) / 2^n chi2(k), k = 0..n (chi2(0) a point mass at 0; Self & Liang
    1987)."""
    from scipy.optimize import brentq

    weights = [math.comb(components, k) / 2**components for k in range(1, components + 1)]

    def excess(x: float) -> float:
        return sum(w * chi2_survival(x, k) for k, w in enumerate(weights, start=1)) - (1.0 - q)

    return float(brentq(excess, 0.0, chi2_quantile(q, components)))
