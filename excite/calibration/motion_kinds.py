"""Do r_L, r_R and b differ between kinds of motion within one log? The groups and the
test's inputs of :mod:`excite.calibration.heterogeneity` for one input (docs/method.md,
"Logs that disagree").

Each segment's kind of motion comes from the wheels only, never from the measured poses, so
the grouping does not depend on the measurement noise: the turn radius against the track,
kappa b = 2 |s_R - s_L| / |s_R + s_L| from the wheels' travel s = r dphi (kappa = |dtheta| /
distance): spins (kappa b > 2, the wheels turn opposite ways), tight turns (0.5 < kappa b <=
2), wide arcs (0.05 < kappa b <= 0.5), straight runs (kappa b <= 0.05). A kind with fewer
than MIN_KIND_SEGMENTS segments, or that does not determine r_L, r_R and b alone (a
worst-direction relative std above the calibration's ``max_relative_std``: straight runs do
not determine b, spins not the common scale), is merged with the next kind in that order (the
last with the one before): "spins and tight turns". Fewer than two groups: not tested.

The groups' r_L, r_R, b are one Gauss-Newton step from the common fit of the model with
r_L, r_R, b per group and the sensor pose shared, with the fit's own noise model and loss
(segments that share pose samples stay correlated across groups) and its information; their
covariance is scaled up by the largest ratio of the reported covariance to the information's
inverse (a Newey-West widening or a wandering heading error), so the test stays conservative.
Units: relative (the model's column scales) inside, m outside.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from excite.calibration.heterogeneity import Comparison, Heterogeneity, assessed
from excite.calibration.model_fit import Fitter, ModelFit
from excite.calibration.solver import Evaluation, normal_system
from excite.core.information import inverse_information
from excite.core.kinematics import Params
from excite.logs.segments import Segments

__all__ = ["MIN_KIND_SEGMENTS", "KINDS", "KIND_BOUNDS", "motion_kinds",
           "motion_heterogeneity"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
#: A kind of motion is a group of its own with at least this many segments.
MIN_KIND_SEGMENTS = 20
#: The kinds of motion, from the tightest turns to the straightest runs.
KINDS = ("spins", "tight turns", "wide arcs", "straight runs")
#: kappa b above which a moving segment is a spin, a tight turn, a wide arc (else straight).
KIND_BOUNDS = (2.0, 0.5, 0.05)


def motion_kinds(seg: Segments, params: Params) -> IntArray:
    """Each segment's kind of motion, an index into KINDS from kappa b (module docstring),
    or -1 for a segment whose wheels do not move."""
    left, right = params.r_L * seg.dphi_L, params.r_R * seg.dphi_R
    turn, travel = 2.0 * np.abs(right - left), np.abs(right + left)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(travel > 0, turn / np.where(travel > 0, travel, 1.0), np.inf)
    kinds = np.full(len(seg), len(KINDS) - 1, dtype=np.int64)
    for kind, bound in reversed(list(enumerate(KIND_BOUNDS))):
        kinds[ratio > bound] = kind
    kinds[(left == 0) & (right == 0)] = -1
    return kinds


def _merged_kinds(counts: IntArray, block: Callable[[list[int]], FloatArray],
                  max_relative_std: float) -> list[list[int]]:
    """The kinds (indices) merged into groups (module docstring): a group closes once it has
    MIN_KIND_SEGMENTS segments and its information ``block(kinds)`` (3 x 3, relative)
    determines r_L, r_R, b; what is left at the end joins the last group."""
    groups: list[list[int]] = []
    current: list[int] = []
    for kind in range(len(KINDS)):
        if counts[kind] == 0:
            continue
        current.append(kind)
        enough = sum(int(counts[k]) for k in current) >= MIN_KIND_SEGMENTS
        if enough and np.linalg.eigvalsh(block(current))[0] * max_relative_std**2 >= 1.0:
            groups.append(current)
            current = []
    if current and groups:
        groups[-1] = groups[-1] + current
    return groups


def _widening(relative: FloatArray, information: FloatArray) -> float:
    """The largest ratio (>= 1) of the reported covariance of r_L, r_R, b to the
    information's inverse, over directions."""
    plain = inverse_information(information)[:3, :3]
    root = np.linalg.cholesky(plain)
    ratio = np.linalg.solve(root, np.linalg.solve(root, relative[:3, :3]).T)
    return max(1.0, float(np.linalg.eigvalsh(0.5 * (ratio + ratio.T))[-1]))


def _kind_system(chosen: ModelFit, fitter: Fitter, kinds: IntArray, counts: IntArray
                 ) -> tuple[FloatArray, FloatArray]:
    """The information and gradient (relative units) of the model with r_L, r_R, b per kind
    of motion (3 columns per kind of KINDS, then the sensor pose's; ``counts``: each kind's
    segments), at the common fit, with its noise model and loss. Independent segments:
    assembled from each kind's own normal system (kinds share no noise), the most frequent
    kind's as the fit's system less the others' (a segment whose wheels do not move has no
    Jacobian); segments that share pose samples: the augmented Jacobian whitened as the
    fit's."""
    sigma, loss = chosen.fit.sigma, fitter.options.loss
    if fitter.whitener is None:
        ev = chosen.fit.ev  # not whitened: raw residuals and relative Jacobian rows
        size = 3 * len(KINDS) + ev.jac.shape[1] - 3
        information, gradient = np.zeros((size, size)), np.zeros(size)

        def add(k: int, info: FloatArray, grad: FloatArray) -> None:
            rows = np.r_[3 * k:3 * k + 3, 3 * len(KINDS):size]
            information[np.ix_(rows, rows)] += info
            gradient[rows] += grad

        largest = int(np.argmax(counts))
        rest_information = chosen.fit.system.information.copy()
        rest_gradient = chosen.fit.system.gradient.copy()
        for k in np.flatnonzero(counts):
            if k == largest:
                continue
            members = np.flatnonzero(kinds == k)
            system = normal_system(Evaluation(ev.theta, ev.scale, ev.raw[:, members],
                                              ev.jac[:, :, members]), sigma, loss)
            add(int(k), system.information, system.gradient)
            rest_information -= system.information
            rest_gradient -= system.gradient
        add(largest, rest_information, rest_gradient)
        return information, gradient
    ev = chosen.unwhitened
    columns = [ev.jac[:, :3, :] * (kinds == k)[None, None, :] for k in range(len(KINDS))]
    raw, jac = fitter.whitener.whiten(ev.raw, np.concatenate(columns + [ev.jac[:, 3:, :]],
                                                              axis=1))
    assert jac is not None
    system = normal_system(Evaluation(ev.theta, ev.scale, raw, jac), sigma, loss)
    return system.information, system.gradient


def motion_heterogeneity(chosen: ModelFit, fitter: Fitter, relative: FloatArray
                         ) -> Heterogeneity | None:
    """The test between kinds of motion of the chosen fit's segments, with the fit's noise
    model and loss (module docstring); ``relative`` is the reported relative covariance.
    None when not tested (a direction undetermined, fewer than two groups)."""
    data = fitter.data
    if (not chosen.identifiable or not np.all(np.isfinite(relative))
            or len(data) < 2 * MIN_KIND_SEGMENTS):
        return None
    theta = chosen.theta
    kinds = motion_kinds(data, Params(*theta[:3]))
    counts = np.bincount(kinds[kinds >= 0], minlength=len(KINDS))
    if np.count_nonzero(counts >= MIN_KIND_SEGMENTS) < 1:
        return None
    information, gradient = _kind_system(chosen, fitter, kinds, counts)
    k3 = 3 * len(KINDS)

    def block(group: list[int]) -> FloatArray:
        rows = np.concatenate([np.arange(3 * k, 3 * k + 3) for k in group])
        sub = information[np.ix_(rows, rows)]
        return sub.reshape(len(group), 3, len(group), 3).sum(axis=(0, 2))

    merged = _merged_kinds(counts, block, fitter.options.max_relative_std)
    if len(merged) < 2:
        return None
    extra = information.shape[0] - k3  # the sensor pose, shared
    mapping = np.zeros((information.shape[0], 3 * len(merged) + extra))
    for g, group in enumerate(merged):
        for k in group:
            mapping[3 * k:3 * k + 3, 3 * g:3 * g + 3] = np.eye(3)
    mapping[k3:, 3 * len(merged):] = np.eye(extra)
    grouped = mapping.T @ information @ mapping
    inverse = np.linalg.pinv(grouped, hermitian=True)
    step = -(inverse @ (mapping.T @ gradient))  # one Gauss-Newton step, relative units
    g3 = 3 * len(merged)
    covariance = inverse[:g3, :g3] * _widening(relative, chosen.fit.system.information)
    names = tuple(" and ".join(KINDS[k] for k in group) for group in merged)
    given = fitter.whitener is None and fitter.sigma is not None
    comparison = Comparison("motion", names,
                             tuple(int(sum(counts[k] for k in group)) for group in merged),
                             theta[:3].copy(), chosen.fit.ev.scale[:3].copy(),
                             step[:g3].reshape(-1, 3), covariance,
                             math.inf if given else 3 * len(data) - grouped.shape[0])
    return assessed(comparison)
