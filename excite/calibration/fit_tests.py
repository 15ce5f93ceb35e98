"""The statistical tests of the chosen model: does it fit the data?

* against the sensor-pose alternative: the likelihood ratio of the model choice, or for an
  imposed model Rao's score test at its estimate (the alternative then fitted only to say
  where the data put the sensor);
* against given noise levels (linear loss): each channel's residual sum of squares against
  its chi-square quantile (Bonferroni over the channels);
* with the noise levels estimated (linear loss): the driving tests (do the parameters, and
  the residuals, change with the acceleration, the turn rate or the wheel speed? slip,
  :mod:`excite.calibration.slip_tests`) and, for segments that share pose samples, the
  Ljung-Box test of serial correlation of the whitened residuals and, when the model passes,
  the search for a wandering heading error of the pose samples
  (:mod:`excite.calibration.wander`).

Every test is at TEST_LEVEL (99.9%) except the wander's (5%, its own module) and the three
driving tests, one family at DRIVING_TEST_LEVEL (99%: :mod:`excite.calibration.slip_tests`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from excite.calibration.model_choice import ModelChoice
from excite.calibration.model_fit import Fitter, ModelFit
from excite.calibration.noise import ChainWhitener, NoiseLevels
from excite.calibration.noise_rounds import EstimatedNoise
from excite.calibration.options import TEST_LEVEL, SensorPoseOption
from excite.calibration.result import CalibrationResult, FitTest
from excite.calibration.slip_tests import FAMILY_LEVEL, DrivingTest, driving_tests, fails_at
from excite.calibration.solver import Loss, Problem, complement, normal_system
from excite.calibration.starts import Starts, sensor_pose_estimate
from excite.calibration.wander import HeadingWander, estimate_wander
from excite.core.models import AXLE, SENSOR_POSE
from excite.logs.segments import Segments
from excite.stats.autocorrelation import ljung_box, runs_of
from excite.stats.chi2 import chi2_quantile, chi2_survival

__all__ = ["driving_misfit", "fit_verdict", "pooled_over_kinds"]

FloatArray = NDArray[np.float64]
#: Whitened residuals correlate with |dtheta| "significantly" above this z value.
_TREND_Z = 3.0
#: How the fit line of the sensor-pose model chosen with estimated noise levels starts.
_LARGEST = "the sensor-pose model is the largest model"


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
    if sigma is None and loss == "linear":
        if noise is not None:
            test = replace(test, serial_correlation=ljung_box(
                chosen.fit.ev.raw.T, runs_of(data.chained, len(data))))
        test = _with_driving_tests(test, driving_tests(
            data, chosen, None if noise is None else noise.whitener, test.serial_correlation),
            one_arc=data.sub_dphi_L is None)
        if noise is not None and test.ok:  # a misfit would be taken for a wander
            test = replace(test, heading_wander=_heading_wander(chosen, noise.levels,
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


def _against_given(mf: ModelFit, sigma: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Per channel RSS_c / sigma_c^2, chi-square with N - h_c degrees of freedom when the
    given levels ``sigma`` are right (h_c the degrees of freedom the fit takes from channel
    c), and those degrees of freedom."""
    system = normal_system(mf.fit.ev, sigma, "linear")
    return mf.fit.ev.unit_system()[2] / sigma**2, mf.problem.n - system.channel_dof()


def _goodness_of_fit(statistic: FloatArray, dof: FloatArray) -> tuple[bool, FloatArray]:
    """Residuals against given noise levels (:func:`_against_given`'s ``statistic`` and
    ``dof``): fails when any channel exceeds its quantile at the test level (Bonferroni over 3
    channels); and each channel's residual RMS over its given level."""
    survival = np.array([chi2_survival(s, d) for s, d in zip(statistic, dof, strict=True)])
    ratio = np.sqrt(statistic / np.maximum(dof, 1.0))
    return bool(np.all(survival > (1.0 - TEST_LEVEL) / 3.0)), ratio


def _below_given(statistic: FloatArray, dof: FloatArray) -> NDArray[np.bool_]:
    """The channels whose residuals are far below the given noise levels: the statistic of
    :func:`_against_given` below its lower quantile at the test level (Bonferroni over 3
    channels), the given level then too large (the std too wide by as much)."""
    return np.array([d >= 1 and 1.0 - chi2_survival(s, d) < (1.0 - TEST_LEVEL) / 3.0
                     for s, d in zip(statistic, dof, strict=True)])


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
        statistic_given, dof = _against_given(chosen, sigma_given)
        ok, ratio = _goodness_of_fit(statistic_given, dof)
        if not ok:
            grows = " and grow with the turn rate" if trend > _TREND_Z else ""
            hint = ("; the sensor may be off the axle: try --sensor-pose estimate"
                    if grows and chosen.model is AXLE else "")
            return FitTest(False, f"the residuals are {_channels_in_words(ratio, ratio > 1.2)}"
                           f" given{grows}: the model or the given noise levels are wrong"
                           f"{hint}", ratio, *numbers)
        small = _below_given(statistic_given, dof)
        if small.any():
            names = [n for n, low in zip(("x", "y", "theta"), small, strict=True) if low]
            return FitTest(True, f"the residuals are up to {1.0 / ratio[small].min():.1f}x smaller "
                           f"than the given noise level in {', '.join(names)}: the given "
                           "levels are too large and the std as much too wide; omit --sigma "
                           "to estimate them", ratio, *numbers)
        return FitTest(True, "the residuals match the given noise levels", ratio, *numbers)
    if statistic is not None and chosen.model is not SENSOR_POSE:
        return FitTest(True, f"the sensor-pose alternative does not fit significantly better "
                       f"({statistic_name} {statistic:.3g} <= {threshold:.3g})", None,
                       *numbers)
    if statistic is not None:
        return FitTest(True, f"{_LARGEST}: nothing to test it against (noise levels "
                       "estimated)", None, *numbers)
    return FitTest(True, "no alternative to test against (noise levels estimated)", None,
                   *numbers)


def _with_driving_tests(test: FitTest, tests: tuple[DrivingTest, ...], one_arc: bool
                        ) -> FitTest:
    """The fit test with the driving tests (:mod:`excite.calibration.slip_tests`) added; a
    failing one (:func:`_reported`) fails the fit with its reason in words. ``one_arc``:
    the segments have no encoder readings within them (each is taken for one arc), so the
    words add ONE_ARC_WORDS: segments cut from a continuous drive bend where the wheel speeds
    change within them, which the tests see as slip."""
    if not tests:
        return test
    acceleration = next((t for t in tests if t.driving == "acceleration"), None)
    test = replace(test, driving_tests=tests,
                   driving_statistic=None if acceleration is None else acceleration.statistic,
                   driving_dof=None if acceleration is None else acceleration.dof)
    worst = _reported(tests)
    if not test.ok or worst is None:
        if test.ok and test.message.startswith(_LARGEST):
            return replace(test, message=f"{_LARGEST}; the driving tests find no slip (the "
                           "parameters do not change with the acceleration, turn rate or "
                           "wheel speed)")
        return test
    return replace(test, ok=False, message=_driving_words(worst) + (ONE_ARC_WORDS if one_arc
                                                                   else ""))


#: Added to a driving test's words for segments without encoder readings within them.
ONE_ARC_WORDS = ("; or, if the segments were cut from a continuous drive, they are no arcs "
                 "where the wheel speeds change within them (the motors lag the commands): "
                 "calibrate the time-series log itself, which keeps the encoder readings")


def _reported(tests: tuple[DrivingTest, ...]) -> DrivingTest | None:
    """The failing driving test the fit's words give (:func:`_first_of`)."""
    return _first_of([t for t in tests if t.failed])


def _first_of(failed: list[DrivingTest]) -> DrivingTest | None:
    """Of the failing driving tests ``failed``, the one to report: the acceleration's, else
    a slipping one (whose residuals grow the most), else the most significant; None when
    there is none."""
    if not failed:
        return None
    for t in failed:
        if t.driving == "acceleration":
            return t
    slipping = [t for t in failed if t.slipping]
    if slipping:
        return max(slipping, key=lambda t: float(np.max(t.growth_ratio)))
    return max(failed, key=lambda t: t.statistic / t.threshold)


def _driving_words(t: DrivingTest) -> str:
    """Why the driving test ``t`` fails the fit, in words."""
    numbers = f"score {t.statistic:.3g} > {t.threshold:.3g}, {t.dof} dof"
    if t.driving == "acceleration":
        return (f"r_L, r_R and b differ between the segments whose wheels speed up or slow "
                f"down and the steadier ones ({numbers}): the wheels slip more when they "
                "accelerate, which biases the estimates beyond their std; calibrate on "
                "gentler driving (smaller steps of the wheel speeds)")
    gentler = "slower turns" if t.driving == "turn rate" else "lower speeds"
    where = "in turns" if t.driving == "turn rate" else "at speed"
    change = f"{_listed(t.moved)} {_verb(t.moved)} with the {t.driving}"
    by = _by(t)
    if not t.slipping:
        return (f"{change} ({by}): the wheels slip or scrub {where}, which biases the "
                f"estimates beyond their std; calibrate on gentler driving ({gentler}), or "
                "on driving like the robot's everyday driving")
    if t.growth < 1.0 - FAMILY_LEVEL:
        grown = [f"{c} {r:.2g}x" for c, r in zip(("x", "y", "theta"), t.growth_ratio,
                                                  strict=True) if r > 1.0]
        why = (f"the residuals grow with the {t.driving} ({', '.join(grown)} their size at "
               f"{gentler})" if grown else f"the residuals' size changes with the {t.driving}")
    else:
        why = (f"the sensor's pose would have to change with the {t.driving} (score "
               f"{t.pose_statistic:.3g} > {chi2_quantile(FAMILY_LEVEL, t.pose_dof):.3g}, "
               f"{t.pose_dof} dof), as a mounting does not")
    return (f"{why}, and {_listed(t.moved)} {_verb(t.moved)} with it ({by}): the wheels "
            f"slip {where}, which biases the estimates beyond their std; calibrate on "
            f"gentler driving ({gentler})")


def _listed(names: tuple[str, ...]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _verb(names: tuple[str, ...]) -> str:
    return "changes" if len(names) == 1 else "change"


def _by(t: DrivingTest) -> str:
    """How much and how sure: the largest change over one std of the driving and the
    score."""
    whose = "its" if len(t.moved) == 1 else "their"
    compared = ">" if t.statistic > t.threshold else "<="
    return (f"by up to {t.shift:.3g} of {whose} std per std of the {t.driving}; score "
            f"{t.statistic:.3g} {compared} {t.threshold:.3g}, {t.dof} dof")


def driving_misfit(result: CalibrationResult, level: float) -> DrivingTest | None:
    """The driving test of ``result``'s fit that fails when the three are one family at
    ``level`` (:func:`excite.calibration.slip_tests.fails_at`), of those the std do not
    cover (:func:`pooled_over_kinds`: a change that is not slip, where the std were widened
    by the kinds of motion's spread), chosen as the fit's words choose; None when none
    fails. The stopping rule asks it at its own level (:mod:`excite.stopping`)."""
    covered = _kinds_widened(result)
    return _first_of([t for t in result.fit.driving_tests or ()
                      if fails_at(t, level) and (t.slipping or not covered)])


def _kinds_widened(result: CalibrationResult) -> bool:
    """Whether the heterogeneity stage found the kinds of motion of one log disagreeing and
    widened the std to cover their spread (random effects)."""
    h = result.heterogeneity
    return (h is not None and h.detected and h.by == "motion"
            and h.pooling == "random effects")


def pooled_over_kinds(result: CalibrationResult) -> CalibrationResult:
    """The result with its fit test passing again when the heterogeneity stage found the
    kinds of motion of one log disagreeing and widened the std to cover their spread
    (random effects) and the fit failed only by a driving test that is not slipping: the
    change of the parameters with the driving is the kinds' difference the std cover
    (:mod:`excite.calibration.slip_tests`, "The verdict"). Unchanged otherwise."""
    fit = result.fit
    if fit.ok or not _kinds_widened(result) or not fit.driving_tests:
        return result
    worst = _reported(fit.driving_tests)
    if worst is None or any(t.failed and t.slipping for t in fit.driving_tests) \
            or not fit.message.startswith(_driving_words(worst)):
        return result
    return replace(result, fit=replace(fit, ok=True, message=(
        f"{_listed(worst.moved)} {_verb(worst.moved)} with the {worst.driving} "
        f"({_by(worst)}) as the kinds of motion differ, which the std cover; the "
        "residuals do not grow with the driving and the mounting does not move with it")))


def _heading_wander(mf: ModelFit, levels: NoiseLevels,
                    whitener: ChainWhitener) -> HeadingWander | None:
    """The pose samples' wandering heading error
    (:func:`excite.calibration.wander.estimate_wander`) from the fit's unwhitened residuals,
    in the directions the data determine, at the whitener's geometry."""
    ev = mf.unwhitened
    free = np.einsum("cpn,pm->cmn", ev.jac, complement(mf.weak))
    assert whitener.geometry is not None
    return estimate_wander(whitener.geometry, ev.raw, free, levels, mf.problem.sigma_floor,
                           whitener.wheels)
