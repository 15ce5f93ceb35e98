"""The noise levels of segments cut from a log (:mod:`excite.calibration.noise`), estimated
from a fit's residuals: by moments (:func:`moment_noise`, the start) and by restricted maximum
likelihood (:func:`reml_noise`: the likelihood of the residuals with the fitted parameters
integrated out, so the levels are not biased low by the fit), with the log-determinant of the
covariance from the whitener's banded factor.

A segment noise that is truly 0 (a log without slip) is visible only at the lowest
frequencies, where the pose noise telescopes away, so its unconstrained REML levels are often
well above 0, and a spurious segment level then outweighs the pose noise over long stretches.
:func:`reml_noise` therefore tests the hypothesis "no segment noise" (all three segment levels
0, the pose noise alone) by the restricted likelihood ratio; three variance components on the
boundary of their space have a chi-bar-square null distribution, sum_k binom(3, k) / 8
chi2(k) for k = 0..3 (Self & Liang 1987). Unless the data reject it (at
SEGMENT_NOISE_TEST_LEVEL), the segment levels are held at their floor. In small samples this
null is conservative (fewer rejections than nominal). The test is joint, not per channel: slip
enters through the wheels, so when any channel shows it, the others carry it too.

With wheel-space noise (:class:`excite.calibration.noise.WheelNoise`) the REML levels are seven
(white x, y, theta; pose xy, theta; slip; timing) and the tests nest, the timing level held at
0: first "no segment noise" against white segment noise (three components, as above: the
pose-only logs keep the behaviour of the white model), then, if rejected, "slip alone" against
slip plus white (three components): slip through the wheels is kept unless the white levels are
needed too; last, "no timing error" against the chosen levels with a free timing level (one
component). The segment levels are not tested again once a timing level is kept. Every search
also starts the segment levels at fractions of the residuals' RMS (START_FRACTIONS), because a
level at its floor has no slope in the deviance and would stay there.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from excite.calibration.noise import (
    LevelBands,
    NoiseLevels,
    WheelNoise,
    chained_mask,
    perpendicular,
    stacked,
)
from excite.calibration.reml_search import RestrictedDeviance, newton_search
from excite.logs.segments import Segments
from excite.stats.chi2 import chi_bar_square_quantile

__all__ = ["at_floor", "level_bounds", "level_floors", "moment_noise", "reml_noise",
           "FLOOR_TOLERANCE", "SEGMENT_NOISE_TEST_LEVEL",
           "START_FRACTIONS"]

FloatArray = NDArray[np.float64]
#: Level of the test of "no segment noise" (:func:`reml_noise`): the segment levels are held
#: at their floor unless the data reject that hypothesis at this level.
SEGMENT_NOISE_TEST_LEVEL = 0.05
#: Further starts of the REML search (:func:`reml_noise`): the segment levels at these
#: fractions of the residuals' RMS (a level started far below where it matters stays there).
START_FRACTIONS = (0.3, 0.03, 0.003)


def moment_noise(segments: Segments, residual: FloatArray, n_parameters: int,
                 floor: FloatArray) -> NoiseLevels:
    """The five noise levels from residuals (3, N) of a fit (predicted - measured), by moments:
    lag-1 products over chained pairs give the pose-sample levels (E r_th,k-1 r_th,k =
    -sth^2; E r_xy,k-1^T R(Delta_k-1) r_xy,k = -2 sxy^2), the lag-0 moments the rest; the
    lag-0 moments are scaled by 3N / (3N - P) for the fitted parameters. Levels are >= 0;
    segment levels at least ``floor`` (3,)."""
    n = residual.shape[1]
    inflate = 3 * n / max(3 * n - n_parameters, 1)
    chained = np.flatnonzero(chained_mask(segments))
    pxy2 = pth2 = 0.0
    if chained.size:
        prev, cur = chained - 1, chained
        pth2 = max(0.0, -float(np.mean(residual[2, prev] * residual[2, cur])))
        c, s = np.cos(segments.dtheta[prev]), np.sin(segments.dtheta[prev])
        ax, ay = residual[0, prev], residual[1, prev]
        bx, by = residual[0, cur], residual[1, cur]
        rotated = ax * (c * bx - s * by) + ay * (s * bx + c * by)  # a^T R(Delta) b
        pxy2 = max(0.0, -0.5 * float(np.mean(rotated)))
    jx, jy = perpendicular(segments)
    lag0 = inflate * np.mean(residual**2, axis=1)
    seg2 = lag0 - np.array([2 * pxy2 + pth2 * np.mean(jx * jx),
                            2 * pxy2 + pth2 * np.mean(jy * jy), 2 * pth2])
    sigma = np.maximum(np.sqrt(np.maximum(seg2, 0.0)), floor)
    return NoiseLevels(sigma, np.sqrt(np.array([pxy2, pth2])))


#: A level within this fraction above its floor counts as held there (not found in the data).
FLOOR_TOLERANCE = 1e-6


def level_floors(floor: FloatArray, wheels: WheelNoise | None = None) -> FloatArray:
    """The floor of each noise level, in the order of :meth:`NoiseLevels.vector` (five, seven
    with ``wheels``): ``floor`` (3,) = (position, position, heading) for the segment levels,
    (position, heading) for the pose levels; the slip and timing floors are the heading
    floor over their scales (:attr:`WheelNoise.scale`, :attr:`WheelNoise.timing_scale`)."""
    floors = np.concatenate([floor, floor[[0, 2]]])
    if wheels is None:
        return floors
    units = np.maximum([wheels.scale, wheels.timing_scale], 1e-300)
    return np.append(floors, floor[2] / units)


def at_floor(levels: FloatArray, floors: FloatArray) -> NDArray[np.bool_]:
    """Which of ``levels`` are held at their ``floors`` (within FLOOR_TOLERANCE)."""
    return levels <= floors * (1.0 + FLOOR_TOLERANCE)


def level_bounds(residual: FloatArray, floor: FloatArray, wheels: WheelNoise | None = None
                 ) -> tuple[FloatArray, FloatArray]:
    """The bounds of the logs of the noise levels a REML search moves in: each level at
    least its floor (``floor`` (3,) = (position, position, heading) floors the segment
    levels, (position, heading) the pose levels; the slip and timing floors are the heading
    floor over their scales, :attr:`WheelNoise.scale` and :attr:`WheelNoise.timing_scale`)
    and at most 10 times the largest residual (3, N), or the floor when that is lower (over
    their scales for slip and timing; the timing level also at most
    :attr:`WheelNoise.timing_bound`).
    Five levels, seven with ``wheels``."""
    spread = float(np.max(np.abs(residual))) if residual.size else 1.0
    lower = np.log(level_floors(floor, wheels))
    upper = np.full(5, np.log(max(10.0 * spread, 1e-300)))
    if wheels is not None:
        units = np.maximum([wheels.scale, wheels.timing_scale], 1e-300)
        upper = np.append(upper, np.log(np.maximum(10.0 * spread / units, 1e-300)))
        upper[6] = min(upper[6], math.log(max(wheels.timing_bound, 1e-300)))
        lower[6] = min(lower[6], upper[6])
    # Residuals below the floors (a noise-free log): every level sits at its floor.
    return lower, np.maximum(upper, lower)


def reml_noise(segments: Segments, residual: FloatArray, jac: FloatArray,
               start: NoiseLevels, floor: FloatArray,
               test_level: float = SEGMENT_NOISE_TEST_LEVEL,
               wheels: WheelNoise | None = None) -> NoiseLevels:
    """The noise levels maximising the restricted likelihood of the residuals (3, N)
    (predicted - measured) of a fit whose Jacobian rows (3, P, N) span the fitted directions
    (only the directions the data determine): the five of :mod:`excite.calibration.noise` and, with
    ``wheels``, the slip and encoder timing levels (its quantization is known, not
    estimated). Optimised over the logs of the levels from ``start`` (the projected Newton
    search of :mod:`excite.calibration.reml_search`); each level
    at least its floor: ``floor`` (3,) is (position, position, heading) and floors the
    segment levels and (position, heading) the pose levels; the slip and timing floors are
    the heading floor over their scales.

    Then the hypothesis "no segment noise" is tested (see the module doc): the restricted
    deviance with the segment levels (and slip) at their floor (the pose levels
    re-optimised) minus that of white segment noise (slip at its floor), against the
    (1 - ``test_level``)-quantile of the chi-bar-square distribution of three boundary
    components; if the data do not reject it, those levels are returned. With ``wheels``, if
    it is rejected, "slip alone, no white segment noise" is tested against the full optimum
    the same way (three components), and slip alone is kept unless rejected. All of this
    holds the timing level at 0; last, "no timing error" is tested against the
    chosen levels with a free timing level (one boundary component), and the timing level
    kept only if rejected (else it is 0).
    """
    from scipy.optimize import minimize

    lower, upper = level_bounds(residual, floor, wheels)
    first = start.vector(with_wheels=wheels is not None)
    segment = [0, 1, 2]  # the levels of segment noise (tested together)
    if wheels is not None:
        units = np.maximum([wheels.scale, wheels.timing_scale], 1e-300)
        segment.append(5)
    u0 = np.minimum(np.maximum(np.log(np.maximum(first, 1e-300)), lower), upper)
    # where a level is held: the segment levels and slip at their floor, the timing level at
    # 0 (not its floor: where every level sits at its floor, as in noise-free simulated logs,
    # one more floor-sized term would change the fit)
    held_at = lower.copy()
    held_at[6:] = -np.inf

    def levels_of(u: FloatArray) -> NoiseLevels:
        return NoiseLevels.from_vector(np.exp(u))

    deviance = RestrictedDeviance(LevelBands(segments, wheels, u0.size),
                                  stacked(residual, jac))

    def optimum(start_u: FloatArray, fixed: NDArray[np.bool_],
                start_value: float | None = None) -> tuple[FloatArray, float]:
        """The minimum of the deviance over the levels not ``fixed`` at their floor
        (``start_value``: the deviance at the start, when known): the Newton search of
        :mod:`excite.calibration.reml_search`, L-BFGS-B from where it stopped when it did
        not converge."""
        u = np.where(fixed, held_at, start_u)
        if start_value is None:
            start_value = deviance(u)
        u, value, converged = newton_search(deviance, deviance.information, u, start_value,
                                            ~fixed, lower, upper)
        if converged:
            return u, value
        free = np.flatnonzero(~fixed)

        def partial(v: FloatArray) -> float:
            full = u.copy()
            full[free] = v
            return deviance(full)

        result = minimize(partial, u[free], method="L-BFGS-B",
                          bounds=list(zip(lower[free], upper[free], strict=True)))
        if result.fun > value:
            return u, value
        u = u.copy()
        u[free] = result.x
        return u, float(result.fun)

    # A level far below where it matters has no slope in the deviance: each search also
    # starts the free segment levels at fractions of the residuals' size (the best start is
    # kept), so that a level held at its floor in one model can rise in the next.
    rms = np.sqrt(np.mean(residual**2, axis=1)) if residual.size else np.ones(3)

    def search(start_u: FloatArray, fixed: NDArray[np.bool_]) -> tuple[FloatArray, float]:
        candidates = [np.minimum(np.maximum(start_u, lower), upper)]
        for fraction in START_FRACTIONS:
            u = start_u.copy()
            u[:3] = np.maximum(np.log(np.maximum(fraction * rms, 1e-300)), start_u[:3])
            if wheels is not None:
                u[5:] = np.maximum(np.log(max(fraction * float(np.max(rms)), 1e-300) / units),
                                   start_u[5:])
            candidates.append(np.minimum(np.maximum(u, lower), upper))
        values = [deviance(np.where(fixed, held_at, u)) for u in candidates]
        best = int(np.argmin(values))
        return optimum(candidates[best], fixed, values[best])

    timing = np.zeros(u0.size, dtype=bool)  # the timing level (tested last)
    timing[6:] = True
    u, fixed, value = _segment_noise(search, optimum, u0, timing, lower, segment,
                                     chi_bar_square_quantile(1.0 - test_level, 3))
    if wheels is None:
        return levels_of(u)
    u_timing, with_timing = search(u, fixed & ~timing)
    kept = value - with_timing > chi_bar_square_quantile(1.0 - test_level, 1)
    return levels_of(u_timing if kept else u)


Search = Callable[[FloatArray, NDArray[np.bool_]], tuple[FloatArray, float]]


def _segment_noise(search: Search, optimum: Search, u0: FloatArray, held: NDArray[np.bool_],
                   lower: FloatArray, segment: list[int], quantile: float
                   ) -> tuple[FloatArray, NDArray[np.bool_], float]:
    """:func:`reml_noise`'s tests of segment noise (its doc) with the levels ``held`` held
    throughout (where ``search`` and ``optimum`` hold levels: the timing level at 0): the
    chosen log-levels, the levels its model holds and its deviance."""
    u_hat, best = search(u0, held)
    if not np.any(u_hat[segment] > lower[segment]):
        return u_hat, held, best
    white = held.copy()
    white[:3] = True
    no_slip = held.copy()
    no_slip[segment[3:]] = True
    with_wheels = len(segment) > 3
    # 1. Is there segment noise at all? "None" against white segment noise (slip held at its
    # floor): three boundary components.
    _, best_white = search(u_hat, no_slip) if with_wheels else (u_hat, best)
    u_null, null = optimum(u_hat, white | no_slip)
    if null - best_white < quantile:
        return u_null, white | no_slip, null
    if not with_wheels:
        return u_hat, held, best
    # 2. There is: does slip through the wheels explain it, without white segment noise?
    u_slip, only_slip = search(u_hat, white)
    if only_slip - best < quantile:
        return u_slip, white, only_slip
    return u_hat, held, best
