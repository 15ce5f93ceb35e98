"""Batch calibration of (r_L, r_R, b), and of the pose of the external sensor, by weighted
maximum likelihood: :func:`calibrate`, a recipe of named stages.

No initial guess and no noise levels are needed. The stages, in order, each in its module:

1. :func:`~excite.calibration.options.checked_inputs`: the inputs and options checked,
   with the wiring (:mod:`excite.calibration.wiring`).
2. :func:`~excite.calibration.starts.first_estimates`: closed-form starts of the model asked
   for and of the axle model.
3. :func:`~excite.calibration.trimming.trimmed`: the outliers dropped (``trim``).
4. :func:`~excite.calibration.noise_rounds.estimated_noise`: the noise levels of segments that
   share pose samples, estimated with the parameters (none otherwise: per-channel sigma,
   given or estimated within each fit, :mod:`excite.calibration.solver`).
5. :func:`~excite.calibration.model_choice.fit_candidates`: each candidate model fitted under
   those noise levels (:mod:`excite.calibration.model_fit`).
5a. :func:`~excite.calibration.gross_errors.without_gross_errors`: under ``loss="auto"`` (no
   trimming), the gross errors found at the primary model's fit (bad pose samples of
   segments that share them, :mod:`excite.calibration.gross_samples`); when any, stages 2, 4
   and 5 again without them.
6. :func:`~excite.calibration.model_choice.choose_model`: the axle or the sensor-pose model
   (under "auto" with estimated noise levels, the axle model alone from too few segments for
   the sensor pose: :func:`~excite.calibration.model_choice.fitted_option`).
7. :func:`~excite.calibration.fit_tests.fit_verdict`: whether the chosen model fits the data.
8. :func:`~excite.calibration.covariance.reported_covariance`: the covariance under a
   wandering heading error and widened for serially correlated residuals.
   8a. :func:`~excite.calibration.motion_kinds.motion_heterogeneity`: whether r_L, r_R, b
   differ between kinds of motion.
9. :func:`~excite.calibration.result.build_result`: the
   :class:`~excite.calibration.result.CalibrationResult`.
10. :func:`~excite.calibration.heterogeneity.applied`: when the kinds of motion disagree,
    the common fit's r_L, r_R, b with the kinds' spread in their std (random effects; or the
    fit failed, ``heterogeneity="common"``).
11. :func:`~excite.calibration.fit_tests.pooled_over_kinds`: when the std were widened so, a
    driving test that is not slipping no longer fails the fit (the std cover it).
"""

from __future__ import annotations

from dataclasses import replace

from numpy.typing import ArrayLike

from excite.calibration.covariance import reported_covariance
from excite.calibration.fit_tests import fit_verdict, pooled_over_kinds
from excite.calibration.gross_errors import Fits, GrossErrors, without_gross_errors
from excite.calibration.heterogeneity import HeterogeneityOption, applied, check_option
from excite.calibration.model_choice import (
    choose_model,
    fit_candidates,
    fitted_option,
    too_few_for_the_pose,
)
from excite.calibration.model_fit import UNIT_SIGMA, Fitter
from excite.calibration.motion_kinds import motion_heterogeneity
from excite.calibration.noise_rounds import estimated_noise
from excite.calibration.options import (
    DEFAULT_MAX_RELATIVE_STD,
    CalibrationLoss,
    FitOptions,
    SensorPoseOption,
    checked_inputs,
    solver_loss,
)
from excite.calibration.result import CalibrationResult, build_result
from excite.calibration.starts import Starts, first_estimates
from excite.calibration.trimming import trimmed
from excite.core.kinematics import Params
from excite.logs.segments import Segments

__all__ = ["calibrate"]


def calibrate(
    segments: Segments | ArrayLike,
    initial: Params | ArrayLike | None = None,
    sigma: ArrayLike | None = None,
    loss: CalibrationLoss = "auto",
    *,
    sensor_pose: SensorPoseOption = "auto",
    trim: float = 0.0,
    max_iterations: int = 100,
    tol: float = 1e-8,
    max_relative_std: float = DEFAULT_MAX_RELATIVE_STD,
    ticks_per_rev: float | None = None,
    heterogeneity: HeterogeneityOption = "random",
) -> CalibrationResult:
    """Estimate p = (r_L, r_R, b), and the sensor pose, from segments by weighted maximum
    likelihood.

    segments: Segments or an (N, 5) array in CSV column order (N >= 3); (dx, dy, dtheta) is
        the external sensor's own motion in its frame at the segment's start.
    initial: starting Params; None finds its own start (closed form). The sensor-pose model
        always starts from Censi's closed form (any mounting angle).
    sigma: measurement noise std (sigma_x [m], sigma_y [m], sigma_theta [rad]) or
        (sigma_xy, sigma_theta); None estimates them from the residuals, re-weighting at
        every iteration until they settle. Segments cut from one log (sharing pose samples)
        then need MIN_NOISE_DOF_PER_LEVEL residual degrees of freedom per noise level (about
        14 segments with the sensor pose), else DataError.
    loss: "auto" (default: Gaussian maximum likelihood, with gross errors found by a
        contaminated-normal model, tested for at the 1% level and left out of the fits,
        :mod:`excite.calibration.gross_errors`; the result's ``gross_errors`` says what was
        found; independent segments without ``trim`` only; clean data are fitted exactly as
        with "linear"), "linear" (Gaussian maximum likelihood on every segment) or "huber"
        (robust to slip outliers; the threshold is 1.345 whitened standard deviations). The
        default was "linear" before "auto" existed.
    sensor_pose: "auto" (default: estimate the sensor pose when the data determine it and it
        improves the fit significantly, a likelihood-ratio test at the 99.9% level, or its
        Wald statistic when that is 100 times the threshold and the axle model is not fitted;
        else the axle model), "axle" (the sensor is on the axle midpoint, facing forward),
        "estimate" (always estimate it), or a :class:`SensorPose` (known mounting).
    trim: fraction of segments to drop as outliers (largest whitened residuals), at most 1%
        per pass with a refit after each; 0 keeps all.
    max_relative_std: identifiability threshold on 1/sigma_min.
    ticks_per_rev: the encoder resolution of the log the segments were cut from (ticks per
        wheel revolution; None: angles not quantised): each angle sample's rounding error
        (variance (2 pi / ticks_per_rev)^2 / 12) is then part of the noise model of segments
        that share samples (:class:`excite.calibration.noise.WheelNoise`).
    heterogeneity: "random" (default: test whether r_L, r_R, b differ between kinds of
        motion; when they do, widen the std by their spread), "common" (test, keep common
        parameters, which then fail the fit when they differ) or "off"
        (:mod:`excite.calibration.heterogeneity`).
    """
    check_option(heterogeneity)
    seg, given = checked_inputs(segments, sigma, loss, sensor_pose, trim)
    options = FitOptions(solver_loss(loss), max_iterations, tol, max_relative_std)
    fitted = fitted_option(sensor_pose, given is not None, seg)
    starts = first_estimates(seg, initial, fitted)
    data = trimmed(seg, starts, given, trim, options)
    n_trimmed = len(seg) - len(data)
    fits = _fitted(data, starts, given, ticks_per_rev, options, fitted)
    gross: GrossErrors | None = None
    if loss == "auto" and not trim:  # the calibration again, without the gross errors

        def refit(kept: Segments) -> Fits:
            return _fitted(kept, first_estimates(kept, initial, fitted), given,
                           ticks_per_rev, options, fitted)

        data, fits, gross = without_gross_errors(fits, refit, given, options)
    starts, noise, fitter, candidates = fits
    choice = choose_model(candidates, fitter)
    if fitted != sensor_pose:  # "auto" on too few segments: the axle model, untested
        choice = replace(choice, words=too_few_for_the_pose(len(seg)))
    test = fit_verdict(choice, fitter, starts, sensor_pose, given, noise)
    relative, test = reported_covariance(choice.chosen, test, fitter)
    kinds = (None if heterogeneity == "off"
             else motion_heterogeneity(choice.chosen, fitter, relative))
    result = build_result(data, choice, test, relative, given is None, n_trimmed, noise,
                          options, loss=loss, gross_errors=gross)
    return pooled_over_kinds(applied(result, kinds, heterogeneity))


def _fitted(data: Segments, starts: Starts, given, ticks_per_rev: float | None,
            options: FitOptions, sensor_pose: SensorPoseOption) -> Fits:
    """Stages 4 and 5 on ``data`` from ``starts``: the noise levels, the fits' noise model
    and the candidate models fitted under it."""
    noise = estimated_noise(data, starts, given, ticks_per_rev, options)
    # every fit from here on: whitened at the estimated levels, or per-channel sigma
    fitter = (Fitter(data, given, None, options) if noise is None
              else Fitter(data, UNIT_SIGMA, noise.whitener, options))
    return Fits(starts, noise, fitter, fit_candidates(fitter, starts, noise, sensor_pose))
