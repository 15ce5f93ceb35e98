"""The stopping rule's screen for segments that share pose samples (a growing log): the
parameters' standard deviations of the data so far at an earlier look's noise model, updated
without calibrating again.

The batch calibration of segments cut from a log estimates its noise levels by restricted
maximum likelihood (REML, :func:`excite.calibration.reml.reml_noise`: several searches, the
tests of segment noise and timing, rounds with refits), the bulk of its cost. Between two
looks of a growing log the levels change little, so the screen starts from the earlier look's
levels and parameters (its *reference*, a
:class:`~excite.calibration.result.CalibrationResult` of a prefix of the segments) and, for
all the segments so far:

1. the residuals r and Jacobian J, at the reference's parameters, of the model the
   calibration estimates the levels with (the sensor-pose model under "auto" and
   "estimate"; the wheel-space noise of segments cut from a log at those parameters too);
2. the levels by groups: white segment noise (x, y, theta), each pose-sample level (xy;
   theta) and the noise through the wheels (slip, timing), each group's levels scaled by
   one factor, the factors maximising the restricted likelihood of r (a few Newton steps
   from the reference's levels; C is linear in the variances, so each level's part of its
   band is built once). Under every outcome of the calibration's tests of segment noise,
   whichever the reference took: segment noise *held* at its floor (the pose-sample levels
   followed), *free* (every group followed; a group the reference holds at its floor
   starts at a fraction of the residuals' RMS) and, for segments cut from a log, *slip
   alone* (the white segment noise held): a test that flips between looks changes the
   levels more than the data do;
3. for each model the calibration could report (the reference's; under
   ``sensor_pose="auto"`` also the axle model unless the reference chose the sensor-pose
   model by a wide margin, :data:`CLEAR_CHOICE`) and each hypothesis, the whitened
   Jacobian A = L^-1 J (C = L L^T) and its inverse information (A^T A)^-1;
4. a robustness factor s <= 1: the Huber scale (:data:`CLIP`) of the whitened residuals
   with the fitted directions projected out, e = (I - A (A^T A)^-1 A^T) L^-1 r, over their
   plain scale (about 1; below 1 where a gross error, which the calibration leaves out,
   inflates the restricted-likelihood levels);
5. each parameter's std: s sqrt(diag((A^T A)^-1)), in its unit.

These are the batch calibration's standard deviations before its widenings (the estimated
levels' share, a wandering heading error, serially correlated residuals, the spread of kinds
of motion that disagree: each only widens), at levels that follow the data between looks by
a factor per group instead of the full REML. The stopping rule
(:class:`excite.stopping.StoppingRule`) turns them into its statistic, the smallest over the
models and hypotheses, and says *not yet* without calibrating only when that is clearly above
1; the batch calibration decides everything else. Its cost is O(N): about a hundred
evaluations of the restricted deviance, each a banded Cholesky factorisation, ten-odd ms for
60 segments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from excite.calibration.noise import (
    ChainWhitener,
    LevelBands,
    NoiseLevels,
    WheelNoise,
    cut_from_log,
    stacked,
)
from excite.calibration.options import TEST_LEVEL, SensorPoseOption
from excite.calibration.reml import START_FRACTIONS, at_floor, level_floors
from excite.calibration.reml_search import restricted_deviance
from excite.calibration.result import CalibrationResult
from excite.calibration.solver import Evaluation, Problem
from excite.core.arrays import FloatArray
from excite.core.models import AXLE, SENSOR_POSE, FixedSensorPoseModel, SegmentModel, SensorPose
from excite.logs.segments import Segments
from excite.logs.timeseries import tick_angle
from excite.stats.chi2 import chi2_quantile

__all__ = ["CLEAR_CHOICE", "CLIP", "Screened", "screened_std"]

#: Whitened residuals count at most this many standard deviations in the robustness factor
#: (a Huber scale; under normal noise within about 1% of the plain scale).
CLIP = 3.5
#: The group factors of the noise levels (:func:`_fitted_band`): Newton steps, the step of
#: the differences, the range of their logs, and the fall of the restricted deviance below
#: which they have settled.
GROUP_ITERATIONS = 4
GROUP_STEP = 0.05
GROUP_RANGE = 3.0
GROUP_TOLERANCE = 0.05
#: A segment group the reference holds at its floor starts the *free* hypothesis at this
#: fraction of the residuals' RMS: the largest of the REML search's starts.
START_FRACTION = max(START_FRACTIONS)
#: Under ``sensor_pose="auto"``, a reference that chose the sensor-pose model with a
#: statistic (its likelihood ratio, or Wald statistic far from the axle) below this multiple
#: of the test's threshold has the axle model screened too (the next look may choose it,
#: with fewer parameters and smaller std).
CLEAR_CHOICE = 2.0


@dataclass(frozen=True)
class Screened:
    """The screened standard deviations under one model and one outcome of the tests of
    segment noise.

    Attributes
    ----------
    std : dict of str to float
        Each estimated parameter's std by the stopping rule's names (r_L, r_R, b and, with
        the sensor pose estimated, x, y, theta), in its unit (m or rad).
    n_parameters : int
        The parameters the model estimates (3 or 6).
    scale : float
        The robustness factor s (dimensionless, <= 1; the module doc, step 4).
    """

    std: dict[str, float]
    n_parameters: int
    scale: float


def screened_std(segments: Segments, reference: CalibrationResult,
                 sensor_pose: SensorPoseOption, ticks_per_rev: float | None
                 ) -> list[Screened] | None:
    """The screen of the module doc: for each outcome of the tests of segment noise (held at
    its floor, free, slip alone) and each model the calibration of ``segments`` could report,
    its parameters' std at the noise model of ``reference`` (the batch calibration of a
    prefix of ``segments`` with ``sensor_pose`` and ``ticks_per_rev``) followed to
    ``segments``.
    None where the screen does not apply: independent segments, a reference without
    estimated pose-sample noise or whose parameters the data did not determine, or a
    covariance or information that is not positive definite."""
    if (segments.chained is None or not segments.chained.any() or reference.pose_sigma is None
            or not reference.identifiable or len(segments) < reference.n_segments):
        return None
    models = _models(reference, sensor_pose)
    levels = NoiseLevels(np.asarray(reference.sigma, dtype=float),
                         np.asarray(reference.pose_sigma, dtype=float),
                         reference.slip or 0.0, reference.timing or 0.0)
    model, theta = _primary(reference, sensor_pose)
    screened = []
    try:
        wheels = None
        if cut_from_log(segments):
            tick = None if ticks_per_rev is None else tick_angle(ticks_per_rev)
            wheels = WheelNoise.of(model, segments, theta, tick)
        problem = Problem(model, segments)
        primary = problem.evaluate(theta)
        evaluations = [primary if m is model and np.array_equal(t, theta)
                       else Problem(m, segments).evaluate(t) for m, t in models]
        bands = LevelBands(segments, wheels, 7 if wheels is not None else 5)
        for base, groups in _hypotheses(levels, primary, wheels, problem.sigma_floor,
                                        reference.levels_at_floor):
            whitener = ChainWhitener.from_band(_fitted_band(bands, primary, base, groups))
            out = whitener.whiten_stacked(stacked(primary.raw, primary.jac))
            robust = _robust_factor(out[:, 0], out[:, 1:])
            for ev in evaluations:
                a = (out[:, 1:] if ev is primary
                     else whitener.whiten_stacked(stacked(ev.raw, ev.jac))[:, 1:])
                screened.append(_screened(a, ev.scale, robust))
    except np.linalg.LinAlgError:
        return None
    return None if any(s is None for s in screened) else screened


def _hypotheses(levels: NoiseLevels, ev: Evaluation, wheels: WheelNoise | None,
                floor: FloatArray, held_names: tuple[str, ...] = ()
                ) -> list[tuple[FloatArray, list[list[int]]]]:
    """The starting levels (5 or 7) and the groups followed, of the outcomes of
    :func:`excite.calibration.reml.reml_noise`'s tests of segment noise: *held* (white
    segment noise and slip at their floor (``floor`` (3,), the heading's over the wheels'
    scale for slip), timing 0; the pose-sample levels followed), *free* (every group
    followed; a segment group the reference holds at its floor starts at START_FRACTION of
    the residuals' RMS, like the REML search) and, with ``wheels``, *slip alone* (free, the
    white segment noise held). Groups: white segment noise (x, y, theta), pose-sample noise
    (xy, theta), noise through the wheels (slip, timing). A level is held at its floor when
    the reference says so (``held_names``: :attr:`CalibrationResult.levels_at_floor`) or it
    is at its floor (:func:`excite.calibration.reml.at_floor`). The two pose-sample levels
    are followed apart (their ratio moves with the segment noise)."""
    with_wheels = wheels is not None
    base = levels.vector(with_wheels)
    lowest = level_floors(floor, wheels)
    white, pose, through = [0, 1, 2], [3, 4], [5, 6]
    if with_wheels:
        unit = max(wheels.scale, 1e-300)
        lowest[6] = 0.0  # the timing level is held at 0, as the REML search holds it
    names = ("x", "y", "theta", "pose_xy", "pose_theta", "slip", "timing")[:base.size]
    floored = np.array([name in held_names for name in names]) | at_floor(base, lowest)
    held = base.copy()
    held[white] = lowest[white]
    free = base.copy()
    rms = np.sqrt(np.mean(ev.raw**2, axis=1)) if ev.raw.size else np.ones(3)
    if np.all(floored[white]):
        free[white] = np.maximum(START_FRACTION * rms, lowest[white])
    groups = [white, pose[:1], pose[1:]]
    if with_wheels:
        held[through] = lowest[through]
        if floored[5]:
            free[5] = max(START_FRACTION * float(np.max(rms)) / unit, lowest[5])
        groups.append(through)
    hypotheses = [held, free]
    if with_wheels:  # slip alone: the white segment noise held
        slip_alone = free.copy()
        slip_alone[white] = lowest[white]
        hypotheses.append(slip_alone)
    return [(start, [g for g in groups if not np.all(at_floor(start[g], lowest[g]))])
            for start in hypotheses]


def _fitted_band(bands: LevelBands, ev: Evaluation, base: FloatArray,
                 groups: list[list[int]]) -> FloatArray:
    """The covariance band at ``base`` (5 or 7 levels) with each of ``groups`` scaled by the
    factor that maximises the restricted likelihood of the residuals and Jacobian ``ev``
    (unwhitened, at the reference's parameters): Newton steps on the log factors from 0 (at
    most GROUP_ITERATIONS, until one lowers it by less than GROUP_TOLERANCE; the derivatives by
    differences of GROUP_STEP; each factor's log within +-GROUP_RANGE), each (or else its
    half) kept only when it lowers the deviance."""
    deviance = _GroupDeviance(bands, ev, base, groups)
    u = np.zeros(len(groups))
    if groups:
        value = deviance(u)
        for _ in range(GROUP_ITERATIONS):
            step = _newton_step(deviance, u, value)
            for _ in range(2):  # the step, else half of it
                trial = np.clip(u + step, -GROUP_RANGE, GROUP_RANGE)
                trial_value = deviance(trial)
                if trial_value < value:
                    break
                step = 0.5 * step
            else:
                break
            settled = value - trial_value < GROUP_TOLERANCE
            u, value = trial, trial_value
            if settled:
                break
    return deviance.band(u)


def _models(reference: CalibrationResult, sensor_pose: SensorPoseOption
            ) -> list[tuple[SegmentModel, FloatArray]]:
    """The models to screen, each with the reference's parameters (P,); the reference's
    model first."""
    wheels = reference.params.as_array()
    if isinstance(sensor_pose, SensorPose):
        return [(FixedSensorPoseModel(sensor_pose), wheels)]
    if reference.model == "axle" or reference.sensor_pose is None:
        return [(AXLE, wheels)]
    if reference.sensor_pose_std is None:  # at a given pose
        return [(FixedSensorPoseModel(reference.sensor_pose), wheels)]
    models = [(SENSOR_POSE, np.append(wheels, reference.sensor_pose.as_array()))]
    if sensor_pose == "auto" and not _clearly_chosen(reference):
        models.append((AXLE, wheels))
    return models


def _primary(reference: CalibrationResult, sensor_pose: SensorPoseOption
             ) -> tuple[SegmentModel, FloatArray]:
    """The model the calibration estimates the noise levels with, at the reference's
    parameters: the sensor-pose model under "auto" and "estimate" (the sensor at the axle
    midpoint, facing forward, when the reference reports the axle model), else the one
    model asked for."""
    wheels = reference.params.as_array()
    if isinstance(sensor_pose, SensorPose):
        return FixedSensorPoseModel(sensor_pose), wheels
    if sensor_pose == "axle":
        return AXLE, wheels
    pose = (np.zeros(3) if reference.sensor_pose is None
            else reference.sensor_pose.as_array())
    return SENSOR_POSE, np.append(wheels, pose)


def _clearly_chosen(reference: CalibrationResult) -> bool:
    """Whether "auto" chose the sensor-pose model with a statistic (``model_statistic``) of
    at least CLEAR_CHOICE times its threshold."""
    ratio = reference.model_statistic
    return ratio is not None and ratio >= CLEAR_CHOICE * chi2_quantile(TEST_LEVEL, 3)


def _newton_step(deviance: _GroupDeviance, u: FloatArray, value: float) -> FloatArray:
    """The Newton step of ``deviance`` at ``u`` (its value ``value``), gradient and Hessian by
    differences of GROUP_STEP; where the Hessian is not positive definite, the gradient step
    scaled by the Hessian's diagonal, at most 1 per factor."""
    h, k = GROUP_STEP, u.size
    unit = np.eye(k) * h
    plus = np.array([deviance(u + unit[i]) for i in range(k)])
    minus = np.array([deviance(u - unit[i]) for i in range(k)])
    gradient = (plus - minus) / (2.0 * h)
    hessian = np.diag((plus - 2.0 * value + minus) / (h * h))
    for i in range(k):
        for j in range(i):
            both = deviance(u + unit[i] + unit[j])
            hessian[i, j] = hessian[j, i] = (both - plus[i] - plus[j] + value) / (h * h)
    try:
        np.linalg.cholesky(hessian)
    except np.linalg.LinAlgError:  # not convex here: a scaled gradient step of at most 1
        scale = np.maximum(np.abs(np.diag(hessian)), np.abs(gradient))
        return np.divide(-gradient, scale, out=np.zeros_like(gradient), where=scale > 0)
    return -np.linalg.solve(hessian, gradient)


class _GroupDeviance:
    """The restricted deviance (:func:`excite.calibration.reml_search.restricted_deviance`) as a
    function of the log factors u of the groups of levels: C = sum_g exp(2 u_g) C_g + C_0,
    C_g the band of group g's levels at ``base``, C_0 that of the rest
    (:class:`excite.calibration.noise.LevelBands`)."""

    def __init__(self, bands: LevelBands, ev: Evaluation, base: FloatArray,
                 groups: list[list[int]]):
        self.base, self.groups = base, groups
        rest = base.copy()
        for group in groups:
            rest[group] = 0.0
        self.rest = bands.at(rest)
        self.bands = []
        for group in groups:
            alone = np.zeros_like(base)
            alone[group] = base[group]
            self.bands.append(bands.at(alone) - bands.zero)
        self.rhs = stacked(ev.raw, ev.jac)

    def band(self, u: FloatArray) -> FloatArray:
        """The band of C at log factors ``u``."""
        band = self.rest.copy()
        for factor, part in zip(np.exp(2.0 * np.asarray(u)), self.bands, strict=True):
            band += factor * part
        return band

    def __call__(self, u: FloatArray) -> float:
        try:
            return restricted_deviance(self.band(u), self.rhs)
        except np.linalg.LinAlgError:  # not positive definite at the bounds
            return 1e300


def _robust_factor(w: FloatArray, a: FloatArray) -> float:
    """The Huber scale (:func:`_huber_scale`) of the whitened residuals ``w`` (3N,) with the
    fitted directions of ``a`` (3N, P) projected out, over their plain scale, at most 1: below
    1 where a few residuals are far out (a gross error, which the calibration leaves out and
    which inflates the restricted-likelihood levels), about 1 otherwise."""
    p = a.shape[1]
    factor = np.linalg.cholesky(a.T @ a)  # LinAlgError when not positive definite
    e = w - a @ np.linalg.solve(factor.T, np.linalg.solve(factor, a.T @ w))
    plain = math.sqrt(float(e @ e) / max(e.size - p, 1))
    return min(1.0, _huber_scale(e, e.size - p) / plain) if plain > 0 else 1.0


def _screened(a: FloatArray, column_scale: FloatArray, robust: float) -> Screened | None:
    """The std of one model from its whitened relative Jacobian ``a`` (3N, P) and the robust
    factor (the module doc, steps 4 and 5); None when its information is not positive
    definite."""
    p = a.shape[1]
    factor = np.linalg.cholesky(a.T @ a)  # LinAlgError when not positive definite
    root = np.linalg.inv(factor)  # (A^T A)^-1 = G^-T G^-1: diag = column sums of G^-1 squared
    std = np.sqrt(np.sum(root * root, axis=0)) * column_scale * robust
    if p not in (3, 6) or not np.all(np.isfinite(std)):
        return None
    names = ("r_L", "r_R", "b", "x", "y", "theta")[:p]
    return Screened(dict(zip(names, map(float, std), strict=True)), p, robust)


def _huber_scale(residual: FloatArray, dof: int, iterations: int = 3) -> float:
    """The noise scale s of whitened residuals: s^2 = sum min(e^2, (CLIP s)^2) /
    (dof E[min(z^2, CLIP^2)]), z standard normal, by a few fixed-point steps from the plain
    |e|^2 / dof."""
    from scipy.stats import norm

    clip2 = CLIP * CLIP
    tail = float(norm.sf(CLIP))
    expected = (1.0 - 2.0 * tail - 2.0 * CLIP * float(norm.pdf(CLIP))) + 2.0 * clip2 * tail
    e2 = residual * residual
    s2 = float(np.sum(e2)) / max(dof, 1)
    for _ in range(iterations):
        s2 = float(np.sum(np.minimum(e2, clip2 * s2))) / (max(dof, 1) * expected)
    return math.sqrt(max(s2, 0.0))
