"""The statistical tests of the chosen model: does it fit the data?

* against the sensor-pose alternative: the likelihood ratio of the model choice, or for an
  imposed model Rao's score test at its estimate (the alternative then fitted only to say
  where the data put the sensor);
* against given noise levels (linear loss): each channel's residual sum of squares against
  its chi-square quantile (Bonferroni over the channels);
* for segments that share pose samples (noise levels estimated, linear loss): the Ljung-Box
  test of serial correlation of the whitened residuals, the driving test (do r_L, r_R and b
  differ where the wheels speed up or slow down?) and, when the model passes, the search for
  a wandering heading error of the pose samples (:mod:`excite.calibration.wander`).

Every test is at TEST_LEVEL (99.9%) except the wander's (5%, its own module).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from excite.calibration.model_choice import ModelChoice
from excite.calibration.model_fit import Fitter, ModelFit
from excite.calibration.noise import ChainWhitener, NoiseLevels, cut_from_log
from excite.calibration.noise_rounds import EstimatedNoise
from excite.calibration.options import TEST_LEVEL, SensorPoseOption
from excite.calibration.result import FitTest
from excite.calibration.solver import Loss, Problem, complement, normal_system
from excite.calibration.starts import Starts, sensor_pose_estimate
from excite.calibration.wander import HeadingWander, estimate_wander
from excite.core.information import inverse_information
from excite.core.models import AXLE, SENSOR_POSE
from excite.logs.segments import Segments
from excite.stats.autocorrelation import ljung_box, runs_of
from excite.stats.chi2 import chi2_quantile, chi2_survival

__all__ = ["fit_verdict"]

FloatArray = NDArray[np.float64]
#: Whitened residuals correlate with |dtheta| "significantly" above this z value.
_TREND_Z = 3.0


def fit_verdict(choice: ModelChoice, fitter: Fitter, starts: Starts,
                sensor_pose: SensorPoseOption, sigma: FloatArray | None,
                noise: EstimatedNoise | None) -> FitTest:
    """The fit test of the chosen model (:class:`excite.calibration.result.FitTest`):
    against the sensor-pose alternative (the model choice's likelihood ratio, or the score
    test of an imposed model), against the given noise std ``sigma`` (m, m, rad; None:
    estimated), and, for segments that share pose samples (``noise`` estimated, linear loss),
    for serial correlation, slip that grows with acceleration and a wandering heading
    error."""
    data, loss = fitter.data, fitter.options.loss
    chosen = choice.chosen
    alternative, statistic, name = choice.alternative, choice.statistic, choice.statistic_name
    threshold = chi2_quantile(TEST_LEVEL, 3)
    forced = "" if sensor_pose in ("auto", "estimate") else (
        "axle" if sensor_pose == "axle" else "pose")
    if forced:
        pose = np.zeros(3) if chosen.model is AXLE else chosen.model.pose.as_array()
        statistic = _score_statistic(data, np.append(chosen.theta, pose), chosen.fit.sigma,
                                     loss, fitter.whitener)
        name = "score"
        if statistic > threshold:  # describe the misfit: where the data put the sensor
            sensor_wheels, sensor_start = sensor_pose_estimate(data, starts.fallback)
            alternative = fitter.fit(SENSOR_POSE, np.append(sensor_wheels.as_array(),
                                                            sensor_start.as_array()))
    test = _model_test(chosen, alternative, statistic, name, threshold, sigma, loss, forced)
    if noise is not None and loss == "linear":
        test = replace(test, serial_correlation=ljung_box(
            chosen.fit.ev.raw.T, runs_of(data.chained, len(data))))
        test = _driving_test(test, data, chosen, noise.whitener)
        if test.ok:  # a misfit would be taken for a wander
            test = replace(test, heading_wander=_heading_wander(data, chosen, noise.levels,
                                                                noise.whitener))
    return test


def _turn_trend_z(mf: ModelFit) -> float:
    """z value of the correlation between |dtheta| and the squared position residuals."""
    turn = np.abs(mf.problem.measured[2])
    raw = mf.fit.ev.residual
    size = raw[0] ** 2 + raw[1] ** 2
    if turn.std() == 0 or size.std() == 0:
        return 0.0
    corr = float(np.corrcoef(turn, size)[0, 1])
    return corr * math.sqrt(mf.problem.n)


def _noise_ratio(mf: ModelFit, reference: FloatArray) -> FloatArray:
    rss = mf.fit.ev.unit_system()[2]
    return np.sqrt(rss / mf.problem.n) / reference


def _goodness_of_fit(mf: ModelFit, sigma: FloatArray) -> tuple[bool, FloatArray]:
    """Residuals against given noise levels: per channel RSS / sigma^2 ~ chi2(N - h_c); fails
    when any channel exceeds its quantile at the test level (Bonferroni over 3 channels)."""
    system = normal_system(mf.fit.ev, sigma, "linear")
    inverse = np.linalg.pinv(system.information, hermitian=True)
    dof = mf.problem.n - np.einsum("ij,cji->c", inverse, system.channel_information)
    statistic = mf.fit.ev.unit_system()[2] / sigma**2
    survival = np.array([chi2_survival(s, d) for s, d in zip(statistic, dof, strict=True)])
    ratio = np.sqrt(statistic / np.maximum(dof, 1.0))
    return bool(np.all(survival > (1.0 - TEST_LEVEL) / 3.0)), ratio


def _channels_in_words(ratio: FloatArray, worse: FloatArray) -> str:
    names = [n for n, bad in zip(("x", "y", "theta"), worse, strict=True) if bad]
    names = names or ["x", "y", "theta"]
    largest = max(ratio[i] for i, n in enumerate(("x", "y", "theta")) if n in names)
    return f"{largest:.1f}x the noise level in {', '.join(names)}"


def _score_statistic(data: Segments, theta: FloatArray, sigma: FloatArray, loss: Loss,
                     whitener: ChainWhitener | None) -> float:
    """Rao's score statistic g^T F^-1 g of the sensor-pose model at ``theta`` (the imposed
    model's estimate, with its sensor pose): chi-square with 3 degrees of freedom when the
    imposed model is right."""
    system = normal_system(Problem(SENSOR_POSE, data, whitener).evaluate(theta), sigma, loss)
    gradient = system.gradient
    return float(gradient @ np.linalg.pinv(system.information, hermitian=True) @ gradient)


def _model_test(chosen: ModelFit, alternative: ModelFit | None, statistic: float | None,
                statistic_name: str | None, threshold: float, sigma_given: FloatArray | None,
                loss: Loss, forced: str) -> FitTest:
    """The verdict of the chosen model against the sensor-pose alternative or the given noise
    levels (see :class:`excite.calibration.result.FitTest`). ``forced`` names what the user
    imposed: "axle", "pose" (a given sensor pose) or "" (nothing)."""
    trend = _turn_trend_z(chosen)
    numbers = (statistic, statistic_name, threshold, trend)
    if alternative is not None and statistic is not None and statistic > threshold:
        if sigma_given is None:
            ratio = chosen.channel_std / alternative.channel_std
        else:
            ratio = _noise_ratio(chosen, sigma_given)
        grows = " and grow with the turn rate" if trend > _TREND_Z else ""
        words = _channels_in_words(ratio, ratio > 1.5)
        _, pose = alternative.model.split(alternative.theta)
        where = f"(x {pose.x:+.4f} m, y {pose.y:+.4f} m, theta {pose.theta:+.4f} rad)"
        if forced == "axle":
            verdict = (f"the residuals are {words}{grows}: the sensor is not on the axle "
                       f"(the sensor-pose model puts it at {where}); "
                       "try --sensor-pose estimate")
        else:
            verdict = (f"the residuals are {words}{grows}: the sensor is not at the given "
                       f"pose (the data put it at {where}); try --sensor-pose estimate")
        return FitTest(False, verdict, ratio, *numbers)
    if sigma_given is not None and loss == "linear":
        ok, ratio = _goodness_of_fit(chosen, sigma_given)
        if not ok:
            grows = " and grow with the turn rate" if trend > _TREND_Z else ""
            hint = ("; the sensor may be off the axle: try --sensor-pose estimate"
                    if grows and chosen.model is AXLE else "")
            return FitTest(False, f"the residuals are {_channels_in_words(ratio, ratio > 1.2)}"
                           f" given{grows}: the model or the given noise levels are wrong"
                           f"{hint}", ratio, *numbers)
        return FitTest(True, "the residuals match the given noise levels", ratio, *numbers)
    if statistic is not None and chosen.model is not SENSOR_POSE:
        return FitTest(True, f"the sensor-pose alternative does not fit significantly better "
                       f"({statistic_name} {statistic:.3g} <= {threshold:.3g})", None,
                       *numbers)
    if statistic is not None:
        return FitTest(True, "the sensor-pose model is the largest model: nothing to test it "
                       "against (noise levels estimated)", None, *numbers)
    return FitTest(True, "no alternative to test against (noise levels estimated)", None,
                   *numbers)



def _driving_score(data: Segments, mf: ModelFit, whitener: ChainWhitener
                   ) -> tuple[float, int, FloatArray] | None:
    """Rao's score statistic (and its degrees of freedom) of the alternative "r_L, r_R, b
    differ by a constant in the segments whose wheel speeds change the most" at the fitted
    parameters: the segments above the median of |change of each wheel's speed| summed over
    the wheels (first to last sub-step, rad/s) get three extra parameters, the score and
    information of the augmented model are whitened like the fit's; the efficient score
    statistic is chi-square with ``dof`` (the extra directions the data determine) when slip
    does not depend on the acceleration. Also the one-step estimate of the extra parameters
    (relative differences of r_L, r_R, b, changing minus steady). None without sub-steps or
    with too few segments to split."""
    count = data.sub_count
    if not cut_from_log(data) or count is None or len(data) < 8:
        return None
    assert data.sub_dphi_L is not None and data.sub_dphi_R is not None
    assert data.t_start is not None and data.t_end is not None
    rows = np.arange(len(data))
    last = np.maximum(count, 1) - 1
    change = (np.abs(data.sub_dphi_L[rows, last] - data.sub_dphi_L[:, 0])
              + np.abs(data.sub_dphi_R[rows, last] - data.sub_dphi_R[:, 0]))
    rate = change * np.maximum(count, 1) / np.maximum(data.t_end - data.t_start, 1e-12)
    changing = rate > np.median(rate)
    if not changing.any() or changing.all():
        return None
    ev = mf.unwhitened  # whiten the augmented rows
    augmented = np.concatenate([ev.jac, ev.jac[:, :3, :] * changing[None, None, :]], axis=1)
    white, jac = whitener.whiten(ev.raw, augmented)
    assert jac is not None
    gradient = np.einsum("cpn,cn->p", jac, white)
    information = np.einsum("cpn,cqn->pq", jac, jac)
    p = mf.theta.size

    def rank(a: FloatArray) -> int:
        lam = np.linalg.eigvalsh(a)
        return int(np.sum(lam > max(lam[-1], 0.0) * 1e-10))

    dof = rank(information) - rank(information[:p, :p])
    if dof <= 0:
        return None
    # the efficient score: what the fitted parameters cannot explain (the fit is not exactly
    # stationary along the directions it holds at their start, fit_model's weak directions)
    full = np.linalg.pinv(information, hermitian=True)
    restricted = np.linalg.pinv(information[:p, :p], hermitian=True)
    statistic = float(gradient @ full @ gradient - gradient[:p] @ restricted @ gradient[:p])
    shift = -(full @ gradient)[p:]  # one Gauss-Newton step of the extra (relative) parameters
    return statistic, dof, shift


def _driving_test(test: FitTest, data: Segments, mf: ModelFit,
                  whitener: ChainWhitener) -> FitTest:
    """The fit test with :func:`_driving_score` added; a rejection fails the fit."""
    score = _driving_score(data, mf, whitener)
    if score is None:
        return test
    statistic, dof, shift = score
    test = replace(test, driving_statistic=statistic, driving_dof=dof)
    threshold = chi2_quantile(TEST_LEVEL, dof)
    if not test.ok or statistic <= threshold:
        return test
    # material, not only significant: the difference exceeds the wheel parameters' own std
    # (on a long log a tiny effect is significant and moves nothing)
    relative_std = np.sqrt(np.diag(inverse_information(mf.fit.system.information))[:3])
    if not np.any(np.abs(shift) > relative_std):
        return test
    return replace(test, ok=False, message=(
        f"r_L, r_R and b differ between the segments whose wheels speed up or slow down and "
        f"the steadier ones (score {statistic:.3g} > {threshold:.3g}, {dof} dof): the wheels "
        "slip more when they accelerate, which biases the estimates beyond their std; "
        "calibrate on gentler driving (smaller steps of the wheel speeds)"))


def _heading_wander(data: Segments, mf: ModelFit, levels: NoiseLevels,
                    whitener: ChainWhitener) -> HeadingWander | None:
    """The pose samples' wandering heading error
    (:func:`excite.calibration.wander.estimate_wander`) from the fit's unwhitened residuals,
    in the directions the data determine."""
    ev = mf.unwhitened
    free = np.einsum("cpn,pm->cmn", ev.jac, complement(mf.weak))
    return estimate_wander(data, ev.raw, free, levels, mf.problem.sigma_floor,
                           whitener.wheels)
