"""The candidate models of one calibration, and the choice between them.

``sensor_pose="auto"`` fits the sensor-pose model and the axle model and keeps the
sensor-pose model when the data determine the sensor pose and it fits significantly better:
a likelihood-ratio test (3 degrees of freedom) at TEST_LEVEL. When the sensor-pose fit puts
the sensor so far from the axle that the test's outcome is not in question (the sensor pose's
Wald statistic above NEAR_AXLE times the test's threshold), the axle model is not fitted:
the Wald statistic decides (the two statistics agree near the axle, and far from it both are
far beyond the threshold; a misfitting axle model takes many iterations to reach an optimum
that changes no decision). With the noise levels estimated, "auto" fits the axle model
alone when the segments are too few to leave the sensor-pose model a residual degree of
freedom per channel (:func:`fitted_option`). ``"estimate"``, ``"axle"`` and a given
SensorPose fit the one model asked for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from excite.calibration.identifiability import describe_weak
from excite.calibration.model_fit import Fitter, ModelFit
from excite.calibration.noise_rounds import EstimatedNoise
from excite.calibration.options import TEST_LEVEL, SensorPoseOption
from excite.calibration.solver import Loss, normal_system, solve_psd
from excite.calibration.starts import Starts
from excite.core.arrays import FloatArray
from excite.core.models import AXLE, SENSOR_POSE
from excite.logs.segments import Segments
from excite.stats.chi2 import chi2_quantile

__all__ = ["Candidates", "ModelChoice", "choose_model", "fit_candidates", "fitted_option",
           "too_few_for_the_pose"]


@dataclass(frozen=True)
class Candidates:
    """The models fitted to choose from.

    Attributes
    ----------
    primary : ModelFit
        The model asked for (the sensor-pose model under "auto" and "estimate").
    axle : ModelFit or None
        The axle model, fitted under "auto" only, unless the sensor is far from the axle.
    wald : float or None
        Under "auto", when the data determine the sensor pose: its Wald statistic
        (dimensionless, chi-square with 3 degrees of freedom on the axle); else None.
    """

    primary: ModelFit
    axle: ModelFit | None
    wald: float | None = None


@dataclass(frozen=True)
class ModelChoice:
    """The model chosen, why, and the test behind the choice.

    Attributes
    ----------
    chosen : ModelFit
        The model the result reports.
    words : str
        Why this model, in words (:attr:`CalibrationResult.model_choice`).
    alternative : ModelFit or None
        The sensor-pose fit when "auto" kept the axle model although the data determine the
        sensor pose (the fit test measures the axle model's misfit against it); else None.
    statistic : float or None
        The likelihood ratio 2 log(L_sensor-pose / L_axle) (dimensionless) of "auto"'s test
        when the data determine the sensor pose (the sensor pose's Wald statistic when the
        sensor is far from the axle and the axle model was not fitted); else None.
    statistic_name : str or None
        "likelihood ratio" (or "Wald statistic") under "auto" (also when ``statistic`` is
        None); else None.
    """

    chosen: ModelFit
    words: str
    alternative: ModelFit | None = None
    statistic: float | None = None
    statistic_name: str | None = None


def fitted_option(sensor_pose: SensorPoseOption, sigma_given: bool, segments: Segments
                  ) -> SensorPoseOption:
    """The sensor-pose option the fits run under: "axle" for "auto" when the noise levels
    are estimated and the independent ``segments`` are too few to leave the sensor-pose
    model a residual degree of freedom per channel (its parameters and the noise levels
    would fit the data exactly, and the likelihood ratio would choose it on noise); else
    ``sensor_pose``. Segments that share pose samples have their own minimum
    (:func:`excite.calibration.noise_rounds.estimated_noise`)."""
    chained = segments.chained is not None and bool(segments.chained.any())
    if (sensor_pose == "auto" and not sigma_given and not chained
            and len(segments) <= len(SENSOR_POSE.names)):
        return "axle"
    return sensor_pose


def too_few_for_the_pose(n_segments: int) -> str:
    """The model choice's words when :func:`fitted_option` kept the axle model."""
    return (f"axle: {n_segments} segments are too few to estimate the sensor pose with the "
            f"noise levels (at least {len(SENSOR_POSE.names) + 1} are needed)")


def fit_candidates(fitter: Fitter, starts: Starts, noise: EstimatedNoise | None,
                   sensor_pose: SensorPoseOption) -> Candidates:
    """The primary model fitted from its start (the noise rounds' last parameters when the
    noise levels were estimated with them) and, under "auto", the axle model
    (from :func:`_axle_start`)."""
    start = starts.start if noise is None else noise.theta
    primary = fitter.fit(starts.primary, start)
    if starts.primary is not SENSOR_POSE or sensor_pose != "auto":
        return Candidates(primary, None)
    wald = _pose_wald(primary)
    if wald is None:
        return Candidates(primary, fitter.fit(AXLE, starts.axle))
    if wald > NEAR_AXLE * chi2_quantile(TEST_LEVEL, 3):
        return Candidates(primary, None, wald)
    return Candidates(primary, fitter.fit(AXLE, _axle_start(primary)), wald)


#: The sensor is near the axle when the sensor pose's Wald statistic is within this many times
#: the model choice's chi-square(3) threshold: the axle model then starts from the
#: sensor-pose fit's wheels (the two models' wheels are close). Beyond it the axle model is not
#: fitted (module docstring): a likelihood ratio of thousands decides as surely as one of
#: millions.
NEAR_AXLE = 100.0


def _pose_wald(primary: ModelFit) -> float | None:
    """The sensor pose's Wald statistic (dimensionless) of the sensor-pose fit, the wheels
    profiled out; None when the data do not determine that fit."""
    info = primary.fit.system.information
    if not primary.identifiable or not np.all(np.isfinite(info)):
        return None
    pose = primary.theta[3:] / primary.fit.ev.scale[3:]  # relative units
    # the sensor pose's information with the wheels profiled out (the Schur complement)
    schur = info[3:, 3:] - info[3:, :3] @ solve_psd(info[:3, :3], info[:3, 3:])
    return float(pose @ schur @ pose)


def _axle_start(primary: ModelFit) -> FloatArray:
    """The axle fit's start (r_L, r_R, b in m) for a sensor near the axle: the sensor-pose
    fit's wheels, moved as its linearisation moves them when the sensor is put on the axle.
    Only where the fit starts depends on it, not where it ends."""
    info = primary.fit.system.information
    pose = primary.theta[3:] / primary.fit.ev.scale[3:]  # relative units
    wheels = -solve_psd(info[:3, :3], primary.fit.system.gradient[:3] - info[:3, 3:] @ pose)
    return primary.model.step(primary.theta, np.append(wheels, -pose),
                              primary.fit.ev.scale)[:3]


def choose_model(candidates: Candidates, fitter: Fitter) -> ModelChoice:
    """The model to report: the one asked for, or under "auto" the sensor-pose model when the
    data determine its sensor pose and the likelihood ratio (or, the sensor far from the
    axle, the Wald statistic) exceeds the chi-square(3) quantile at TEST_LEVEL, else the axle
    model."""
    primary, axle = candidates.primary, candidates.axle
    if primary.model is not SENSOR_POSE:
        return ModelChoice(primary, "axle: as asked" if primary.model is AXLE
                           else "sensor_pose: at the given pose, as asked")
    threshold = chi2_quantile(TEST_LEVEL, 3)
    if axle is None and candidates.wald is not None:
        return ModelChoice(primary, "sensor_pose: the axle model is far from fitting (the "
                           f"sensor pose's Wald statistic {candidates.wald:.3g} > {NEAR_AXLE:g} "
                           f"x {threshold:.3g}; the axle model was not fitted)", None,
                           candidates.wald, "Wald statistic")
    if axle is None:
        return ModelChoice(primary, "sensor_pose: estimated, as asked")
    name = "likelihood ratio"
    if not primary.identifiable:
        return ModelChoice(axle, "axle: the data do not determine the sensor pose ("
                           + describe_weak(primary.weak, primary.theta, fitter.data,
                                           primary.channel_std) + ")", statistic_name=name)
    statistic = _likelihood_ratio(axle, primary, fitter.sigma is not None, fitter.options.loss)
    if statistic <= threshold:
        return ModelChoice(axle, f"axle: the sensor-pose model does not fit significantly "
                           f"better (likelihood ratio {statistic:.3g} <= {threshold:.3g})",
                           primary, statistic, name)
    return ModelChoice(primary, f"sensor_pose: it fits significantly better than the axle "
                       f"model (likelihood ratio {statistic:.3g} > {threshold:.3g})",
                       None, statistic, name)


def _likelihood_ratio(small: ModelFit, large: ModelFit, sigma_given: bool,
                      loss: Loss) -> float:
    """2 log(L_large / L_small) >= 0 of two nested fits on the same data: with estimated
    noise levels (linear loss) the profile likelihood N sum_c log(RSS_c,small / RSS_c,large);
    otherwise the difference of the whitened costs at the larger model's noise levels. With
    estimated levels each channel's N is taken as the larger model's residual degrees of
    freedom in it, N - h_c with h_c = tr(F^-1 F_c) the share of its parameters the channel
    carries (:meth:`excite.calibration.solver.System.channel_dof`; at least 1): the
    small-sample form of the statistic (as an F test's denominator), which with N itself
    chooses the larger model on noise more often than TEST_LEVEL says when N is a few times
    the parameters; the same for large N."""
    if loss == "linear" and not sigma_given:
        rss_small = small.fit.ev.unit_system()[2]
        rss_large = large.fit.ev.unit_system()[2]
        floor = large.problem.sigma_floor**2
        ratio = np.maximum(rss_small, floor) / np.maximum(rss_large, floor)
        dof = large.problem.n - large.fit.system.channel_dof()
        return max(float(np.sum(np.maximum(dof, 1.0) * np.log(ratio))), 0.0)
    sigma = large.fit.sigma
    cost_small = normal_system(small.fit.ev, sigma, loss).cost
    cost_large = normal_system(large.fit.ev, sigma, loss).cost
    return max(2.0 * (cost_small - cost_large), 0.0)
