"""Batch calibration of (r_L, r_R, b), and of the pose of the external sensor, by weighted
maximum likelihood.

``calibrate(segments)`` needs no initial guess (closed-form starts,
:mod:`excite.calibration.starts`) and
no noise levels (per-channel sigmas are estimated jointly with the parameters,
:mod:`excite.calibration.solver`). It chooses between the axle model and the sensor-pose model
(``sensor_pose="auto"``: a likelihood-ratio test at the 99.9% level, when the data determine
the sensor pose), tests whether the chosen model fits the data, and returns a
:class:`CalibrationResult` with the covariance (inverse Fisher information at the solution),
an identifiability verdict in words and the fit verdict in words.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from excite.calibration.noise import (
    ChainWhitener,
    NoiseLevels,
    WheelNoise,
    chi2_quantile,
    chi2_survival,
    moment_noise,
    reml_noise,
)
from excite.calibration.solver import (
    Evaluation,
    Fit,
    Loss,
    Problem,
    complement,
    levenberg_marquardt,
    normal_system,
)
from excite.calibration.starts import (
    DEFAULT_NOMINAL,
    body_frame_estimate,
    initial_estimate,
    sensor_pose_estimate,
)
from excite.calibration.wander import HeadingWander, estimate_wander, wander_covariance
from excite.calibration.wiring import check_wiring
from excite.core.information import as_sigma, inverse_information
from excite.core.kinematics import Params
from excite.core.models import AXLE, SENSOR_POSE, FixedSensorPoseModel, SegmentModel, SensorPose
from excite.errors import DataError
from excite.logs.segments import Segments
from excite.logs.timeseries import tick_angle
from excite.stats.autocorrelation import (
    LjungBox,
    at_least,
    ljung_box,
    long_run_covariance,
    runs_of,
)

__all__ = ["CalibrationResult", "FitTest", "calibrate", "initial_estimate", "DEFAULT_NOMINAL",
           "chi2_quantile"]

FloatArray = NDArray[np.float64]
SensorPoseOption = Literal["auto", "axle", "estimate"] | SensorPose

#: A segment is an outlier when its whitened squared residual exceeds this chi2(3) quantile.
OUTLIER_QUANTILE = 0.999
#: Level of the likelihood-ratio test of the axle model against the sensor-pose model, and of
#: the goodness-of-fit test against given noise levels.
TEST_LEVEL = 0.999
#: Data determine the parameters when the worst-direction relative std 1/sigma_min is at most
#: this.
DEFAULT_MAX_RELATIVE_STD = 0.1
#: Each trimming pass drops at most this fraction of the segments (Censi et al. drop 1%).
TRIM_PASS = 0.01
#: Whitened residuals correlate with |dtheta| "significantly" above this z value.
_TREND_Z = 3.0
_CHANNELS = ("x", "y", "theta")
#: Most rounds of (estimate the noise levels, refit) for segments that share pose samples.
NOISE_ROUNDS = 8
#: The noise levels have settled when no level moves by more than this fraction.
NOISE_RTOL = 0.01
_UNIT_SIGMA = np.ones(3)
#: Segments that share pose samples have their noise levels (five; seven with wheel slip and
#: encoder timing)
#: estimated by REML from the residuals; that needs at least this many residual degrees of
#: freedom (3 N - parameters) per level. Fewer, and the levels collapse to fit the few
#: residuals (noise ~1e-10 on 4 segments of a slipping log: r_R 45% off at z = -157).
MIN_NOISE_DOF_PER_LEVEL = 5


@dataclass(frozen=True)
class FitTest:
    """Whether the chosen model fits the data, in numbers and words.

    ok: the verdict. message: the reason in words. noise_ratio: per channel (x, y, theta), the
    residual std of the chosen model over the reference noise level (the given sigma, or the
    residual std of the sensor-pose alternative); None when there is no reference.
    statistic / statistic_name / threshold: the test of the model against the sensor-pose
    alternative ("likelihood ratio" when both were fitted, as ``auto`` does; "score" (Rao's
    test at the chosen model's estimate, one evaluation) when a model was imposed, the
    alternative then fitted only to describe a misfit); None when not tested; the threshold is
    the 99.9% chi-square quantile with 3 degrees of freedom. turn_trend_z: the
    z value of the correlation between the position residuals and |dtheta| (> 3: the residuals
    grow with the turn rate, the signature of an off-axle sensor). serial_correlation: for
    segments cut from a log (noise levels estimated, linear loss), the Ljung-Box test of the
    whitened residuals over lags of 1..10 segments (:mod:`excite.stats.autocorrelation`; None when
    not tested; logs of fewer than 50 segments are not tested). When it rejects "no serial
    correlation" at the 99.9% level and the model passes its own test (``ok``), the reported
    covariance is widened to the Newey-West covariance where that is larger (over
    ``long_run_bandwidth`` segments) and the message says so; the verdict ``ok`` is not
    changed by it. driving_statistic / driving_dof: for segments cut from a log (noise levels
    estimated), Rao's score test that r_L, r_R and b are the same in the segments whose wheels
    speed up or slow down the most (above the median change of wheel speed) as in the others
    (:func:`_driving_score`); slip that grows with acceleration makes them differ, and a
    statistic above the 99.9% chi-square quantile fails the fit (``ok`` False) when the
    difference also exceeds the parameters' own std; None when not tested. heading_wander: for
    segments with times that share pose samples (noise levels estimated, linear loss, at
    least 50 segments, the model passing its own test), the pose samples' heading error
    that wanders over seconds (a first-order Gauss-Markov error, std in rad, correlation time
    in s, :class:`excite.calibration.wander.HeadingWander`) when a likelihood-ratio test at the 5%
    level finds
    one; the reported covariance is then the fit's under the model with it (an estimated
    mounting angle carries the log's mean heading error) and the message says so; None when
    not found or not tested.
    """

    ok: bool
    message: str
    noise_ratio: FloatArray | None = None
    statistic: float | None = None
    statistic_name: str | None = None
    threshold: float | None = None
    turn_trend_z: float | None = None
    serial_correlation: LjungBox | None = None
    long_run_bandwidth: int | None = None
    driving_statistic: float | None = None
    driving_dof: int | None = None
    heading_wander: HeadingWander | None = None

    def to_dict(self) -> dict:
        ratio = None if self.noise_ratio is None else dict(
            zip(_CHANNELS, map(float, self.noise_ratio), strict=True))
        return {"ok": self.ok, "message": self.message, "noise_ratio": ratio,
                "statistic": self.statistic, "statistic_name": self.statistic_name,
                "threshold": self.threshold,
                "turn_trend_z": self.turn_trend_z,
                "serial_correlation": None if self.serial_correlation is None
                else asdict(self.serial_correlation),
                "long_run_bandwidth": self.long_run_bandwidth,
                "driving_statistic": self.driving_statistic, "driving_dof": self.driving_dof,
                "heading_wander": None if self.heading_wander is None else {
                    "std": self.heading_wander.std,
                    "correlation_time": self.heading_wander.correlation_time,
                    "statistic": self.heading_wander.statistic,
                    "at_bound": self.heading_wander.at_bound}}


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`calibrate` (modelled on scipy's OptimizeResult).

    params: wheel parameters (m). covariance: their 3x3 covariance (m^2), inverse Fisher
    information at the estimate, inf along directions the data do not determine.
    std: sqrt(diag(covariance)) (m). model: "axle" or "sensor_pose". sensor_pose: the sensor's
    pose in the body frame (estimated or given), None for the axle model; sensor_pose_std
    (m, m, rad) when estimated. parameter_names / full_covariance: every estimated parameter
    and their joint covariance (6x6 with the sensor pose estimated). model_choice: why this
    model, in words. fit: :class:`FitTest`. singular_values, condition_number: of the whitened,
    relatively scaled Jacobian over all estimated parameters (docs/conventions.md), descending.
    identifiable: whether 1/sigma_min <= max_relative_std (both judge the model's information,
    what the driving determines; a covariance widened for serially correlated residuals, see
    :class:`FitTest`, can be wider than 1/sigma_min says). unidentifiable_direction: None, or
    what is not determined, in words. sigma: noise std per channel (m, m, rad), given or
    estimated. pose_sigma: for segments cut from a log that share pose samples, the noise std
    of each pose sample (xy [m], theta [rad]) estimated with sigma (then sigma is the noise of
    each segment's own, e.g. slip), the covariance accounting for the shared samples; else
    None. slip: for segments cut from a log (with sub-steps), the estimated wheel slip
    intensity (rad / sqrt(s): each wheel's random walk against its encoder, modelled through
    the wheels, :class:`excite.calibration.noise.WheelNoise`); else None. slip_share: with slip,
    how large
    it is against the driving: the median over moving segments of slip sqrt(duration) / the
    larger wheel turn (rad / rad). The random walk's part of the std shrinks as the log grows;
    slip that depends on the driving (speed, turns) instead biases the parameters by up to
    about this fraction, which the model does not state (calibrate on gentle driving when it is
    large against the std). timing: for segments cut from a log, the estimated std of each
    encoder sample's time against the pose stream (s; 0 unless the data show one,
    :func:`excite.calibration.noise.reml_noise`); else None. timing_at_bound: whether it sits at its
    bound, a quarter of the encoder period
    (:attr:`excite.calibration.noise.WheelNoise.timing_bound`;
    larger errors are not described, the std are then too narrow); None without timing.
    rms_residual: raw residual RMS
    per channel. n_outliers: segments whose whitened
    squared residual exceeds the 99.9% chi2(3) quantile; n_trimmed: segments dropped by
    trimming.
    """

    params: Params
    covariance: FloatArray
    std: FloatArray
    model: str
    sensor_pose: SensorPose | None
    sensor_pose_std: FloatArray | None
    parameter_names: tuple[str, ...]
    full_covariance: FloatArray
    model_choice: str
    fit: FitTest
    singular_values: FloatArray
    condition_number: float
    identifiable: bool
    unidentifiable_direction: str | None
    unidentifiable_vector: FloatArray | None
    n_segments: int
    n_outliers: int
    n_trimmed: int
    rms_residual: FloatArray
    sigma: FloatArray
    sigma_estimated: bool
    pose_sigma: FloatArray | None
    slip: float | None
    slip_share: float | None
    timing: float | None
    timing_at_bound: bool | None
    loss: str
    converged: bool
    iterations: int
    message: str
    residuals: FloatArray = field(repr=False)

    @property
    def sigma_min(self) -> float:
        return float(self.singular_values[-1])

    def to_dict(self) -> dict:
        """JSON-ready dict (the ``excite calibrate --json`` object); inf becomes None."""

        def finite(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        def named(values, names) -> dict:
            return {n: finite(v) for n, v in zip(names, values, strict=True)}

        pose = self.sensor_pose
        return {
            "params": named(self.params.as_array(), AXLE.names),
            "std": named(self.std, AXLE.names),
            "covariance": [[finite(v) for v in row] for row in self.covariance],
            "singular_values": [float(s) for s in self.singular_values],
            "condition_number": finite(self.condition_number),
            "identifiable": bool(self.identifiable),
            "unidentifiable_direction": self.unidentifiable_direction,
            "n_segments": self.n_segments,
            "n_outliers": self.n_outliers,
            "n_trimmed": self.n_trimmed,
            "rms_residual": named(self.rms_residual, _CHANNELS),
            "sigma": named(self.sigma, _CHANNELS),
            "sigma_estimated": self.sigma_estimated,
            "pose_sigma": (None if self.pose_sigma is None
                           else dict(zip(("xy", "theta"), map(float, self.pose_sigma),
                                         strict=True))),
            "slip": self.slip,
            "slip_share": self.slip_share,
            "timing": self.timing,
            "timing_at_bound": self.timing_at_bound,
            "loss": self.loss,
            "converged": bool(self.converged),
            "iterations": self.iterations,
            "model": self.model,
            "model_choice": self.model_choice,
            "sensor_pose": None if pose is None else named(pose.as_array(), _CHANNELS),
            "sensor_pose_std": (None if self.sensor_pose_std is None
                                else named(self.sensor_pose_std, _CHANNELS)),
            "parameters": list(self.parameter_names),
            "full_covariance": [[finite(v) for v in row] for row in self.full_covariance],
            "fit": self.fit.to_dict(),
        }

    def summary(self) -> str:
        """Human-readable report."""
        p = self.params.as_array()
        lines = [f"excite calibration: {self.n_segments} segments, loss={self.loss}, "
                 f"model={self.model}"]
        for name, value, s in zip(AXLE.names, p, self.std, strict=True):
            rel = f"({100 * s / value:.3f}%)" if np.isfinite(s) else "(undetermined)"
            lines.append(f"  {name:<4}= {value:.6f} m  ± {s:.2e} m {rel}")
        if self.sensor_pose is not None:
            pose = self.sensor_pose.as_array()
            std = self.sensor_pose_std
            how = "given" if std is None else "estimated"
            for name, unit, value, i in (("x", "m", pose[0], 0), ("y", "m", pose[1], 1),
                                         ("theta", "rad", pose[2], 2)):
                spread = "" if std is None else (
                    f"  ± {std[i]:.2e} {unit}" if np.isfinite(std[i]) else "  (undetermined)")
                extra = f" ({math.degrees(value):.2f} deg)" if name == "theta" else ""
                lines.append(f"  sensor {name:<6}= {value:+.6f} {unit}{extra}{spread} ({how})")
        sv = ", ".join(f"{s:.4g}" for s in self.singular_values)
        lines += [
            f"  model choice    = {self.model_choice}",
            f"  sigma_min       = {self.sigma_min:.4g}  (worst-direction relative std "
            f"{_inverse_or_inf(self.sigma_min):.3g})",
            f"  singular values = {sv};  condition number = {self.condition_number:.4g}",
            f"  identifiable    = {'yes' if self.identifiable else 'NO'}"
            + (f": {self.unidentifiable_direction}" if self.unidentifiable_direction else ""),
            f"  fit             = {'ok' if self.fit.ok else 'NO'}: {self.fit.message}",
            "  residual RMS    = x {:.3e} m, y {:.3e} m, theta {:.3e} rad".format(
                *self.rms_residual),
            "  noise sigma     = x {:.3e} m, y {:.3e} m, theta {:.3e} rad ({})".format(
                *self.sigma, "estimated" if self.sigma_estimated else "given")
            + ("" if self.pose_sigma is None else " per segment; pose samples: xy "
               "{:.3e} m, theta {:.3e} rad (shared by consecutive segments)".format(
                   *self.pose_sigma))
            + ("" if self.slip is None else f"; wheel slip {self.slip:.3e} rad/sqrt(s)")
            + ("" if self.slip_share is None
               else f" ({100 * self.slip_share:.2g}% of a segment's wheel turn)")
            + ("" if not self.timing else f"; encoder timing {1e3 * self.timing:.2g} ms")
            + (" (at its bound, a quarter of the encoder period: larger timing errors are not "
               "described and the std are too narrow)" if self.timing_at_bound else ""),
            f"  outliers        = {self.n_outliers}"
            + (f"; trimmed {self.n_trimmed}" if self.n_trimmed else ""),
            f"  converged       = {self.converged} after {self.iterations} iterations"
            f" ({self.message})",
        ]
        return "\n".join(lines)


def _inverse_or_inf(x: float) -> float:
    return 1.0 / x if x > 0 else float("inf")


def _as_segments(segments: Segments | ArrayLike) -> Segments:
    if isinstance(segments, Segments):
        return segments
    return Segments.from_array(segments)


@dataclass
class _ModelFit:
    """A fitted model on one data set: the LM outcome, the relative information and the
    verdict on what the data determine."""

    model: SegmentModel
    problem: Problem
    fit: Fit
    weak: FloatArray  # (P, k) relative directions the data do not determine

    @property
    def theta(self) -> FloatArray:
        return self.fit.theta

    @property
    def identifiable(self) -> bool:
        return self.weak.shape[1] == 0

    @cached_property
    def unwhitened(self) -> Evaluation:
        """The evaluation at the fit, not whitened: raw residuals and relative Jacobian rows
        (the driving test and the wandering heading error whiten or weight them their own
        way)."""
        return self.problem.evaluate(self.theta, whiten=False)

    @property
    def channel_std(self) -> FloatArray:
        """The noise level per channel the fit implies: its sigma, or with correlated noise
        (whitened, sigma = 1) the residual RMS."""
        if self.problem.whitener is None:
            return self.fit.sigma
        return np.sqrt(np.mean(self.fit.ev.residual**2, axis=1))


def _fit_model(model: SegmentModel, seg: Segments, start: FloatArray,
               sigma: FloatArray | None, loss: Loss, max_iterations: int, tol: float,
               max_relative_std: float, whitener: ChainWhitener | None = None) -> _ModelFit:
    """LM from ``start``; directions the data cannot determine are then held at the start
    instead of drifting to chase noise. With a whitener, sigma must be ones."""
    problem = Problem(model, seg, whitener)
    determined = 1.0 / max_relative_std
    fit = levenberg_marquardt(problem, start, sigma, loss, max_iterations, tol,
                              determined=determined)
    lam, vec = np.linalg.eigh(fit.system.information)
    weak = lam * max_relative_std**2 < 1.0
    if np.any(weak):
        refit = levenberg_marquardt(problem, start, fit.sigma, loss, max_iterations, tol,
                                    frozen=vec[:, weak], determined=determined)
        refit.iterations += fit.iterations
        fit = refit
    return _ModelFit(model, problem, fit, vec[:, weak])


def _likelihood_ratio(small: _ModelFit, large: _ModelFit, sigma_given: bool,
                      loss: Loss) -> float:
    """2 log(L_large / L_small) >= 0 of two nested fits on the same data: with estimated
    noise levels (linear loss) the profile likelihood N sum_c log(RSS_c,small / RSS_c,large);
    otherwise the difference of the whitened costs at the larger model's noise levels."""
    if loss == "linear" and not sigma_given:
        rss_small = small.fit.ev.unit_system()[2]
        rss_large = large.fit.ev.unit_system()[2]
        floor = large.problem.sigma_floor**2
        ratio = np.maximum(rss_small, floor) / np.maximum(rss_large, floor)
        return max(float(small.problem.n * np.sum(np.log(ratio))), 0.0)
    sigma = large.fit.sigma
    cost_small = normal_system(small.fit.ev, sigma, loss).cost
    cost_large = normal_system(large.fit.ev, sigma, loss).cost
    return max(2.0 * (cost_small - cost_large), 0.0)


def _turn_trend_z(mf: _ModelFit) -> float:
    """z value of the correlation between |dtheta| and the squared position residuals."""
    turn = np.abs(mf.problem.measured[2])
    raw = mf.fit.ev.residual
    size = raw[0] ** 2 + raw[1] ** 2
    if turn.std() == 0 or size.std() == 0:
        return 0.0
    corr = float(np.corrcoef(turn, size)[0, 1])
    return corr * math.sqrt(mf.problem.n)


def _noise_ratio(mf: _ModelFit, reference: FloatArray) -> FloatArray:
    rss = mf.fit.ev.unit_system()[2]
    return np.sqrt(rss / mf.problem.n) / reference


def _goodness_of_fit(mf: _ModelFit, sigma: FloatArray) -> tuple[bool, FloatArray]:
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


def _fit_test(chosen: _ModelFit, alternative: _ModelFit | None, statistic: float | None,
              statistic_name: str | None, threshold: float, sigma_given: FloatArray | None,
              loss: Loss, forced: str) -> FitTest:
    """The fit verdict of the chosen model (see :class:`FitTest`). ``forced`` names what the
    user imposed: "axle", "pose" (a given sensor pose) or "" (nothing)."""
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


def _moving_segments(seg: Segments, sigma: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Masks of the segments that turn (|dtheta| > 3 sigma_theta) and whose body translates
    (the wheels move together: |dphi_L + dphi_R| > |dphi_R - dphi_L| / 10)."""
    turning = np.abs(seg.dtheta) > 3.0 * sigma[2]
    together = np.abs(seg.dphi_L + seg.dphi_R)
    translating = together > 0.1 * np.abs(seg.dphi_R - seg.dphi_L) + 1e-12
    return turning, translating


def _describe_weak(weak: FloatArray, theta: FloatArray, seg: Segments,
                   sigma: FloatArray) -> str:
    """Words for the relative-parameter directions the data do not determine (the columns of
    ``weak``, orthonormal): every named group of parameters that lies in them, with why."""
    p = weak.shape[0]
    turning, translating = _moving_segments(seg, sigma)
    no_turn = "no segment turns" if not turning.any() else "the turns do not separate it"
    no_move = ("no segment translates" if not translating.any()
               else "the translations do not separate it")
    scale = np.zeros(p)
    scale[:3] = 1.0
    if p == 6:  # a common scale of every length leaves the measurements unchanged
        scale[3:5] = theta[3:5] / theta[2]
    groups = [("b", [np.eye(p)[2]], no_turn),
              ("the common scale of r_L, r_R and b", [scale], "no segment translates"),
              ("the ratio r_L/r_R", [np.eye(p)[0] - np.eye(p)[1]],
               "every segment has the same wheel-speed ratio")]
    if p == 6:
        groups = [("sensor x, y", [np.eye(p)[3], np.eye(p)[4]], no_turn),
                  ("sensor theta", [np.eye(p)[5]], no_move)] + groups
    words = []
    for name, directions, why in groups:
        inside = [float(np.sum((weak.T @ (d / np.linalg.norm(d))) ** 2)) for d in directions]
        if min(inside) > 0.9:
            words.append(f"{name}: {why}")
    if words:
        return "; ".join(words)
    v = weak[:, 0] if weak[np.argmax(np.abs(weak[:, 0])), 0] > 0 else -weak[:, 0]
    names = SENSOR_POSE.names if p == 6 else AXLE.names
    terms = " ".join(f"{c:+.2f}*{n}" for c, n in zip(v, names, strict=True))
    return f"the relative combination {terms}"


def _trimmed(seg: Segments, model: SegmentModel, start: FloatArray, sigma: FloatArray | None,
             loss: Loss, trim: float, max_iterations: int, tol: float,
             max_relative_std: float) -> FloatArray:
    """Mask of the segments kept after dropping the fraction ``trim`` with the largest
    whitened residuals, at most 1% per pass with a refit after each (Censi et al.)."""
    keep = np.ones(len(seg), dtype=bool)
    target = int(round(trim * len(seg)))
    theta = start
    while (dropped := int(np.sum(~keep))) < target:
        fit = levenberg_marquardt(Problem(model, seg[keep]), theta, sigma, loss,
                                  max_iterations, tol, determined=1.0 / max_relative_std)
        theta = fit.theta
        z2 = np.sum((fit.ev.raw / fit.sigma[:, None]) ** 2, axis=0)
        count = min(max(1, int(math.ceil(TRIM_PASS * len(seg)))), target - dropped)
        kept = np.flatnonzero(keep)
        keep[kept[np.argsort(z2)[::-1][:count]]] = False
    return keep


def calibrate(
    segments: Segments | ArrayLike,
    initial: Params | ArrayLike | None = None,
    sigma: ArrayLike | None = None,
    loss: Loss = "linear",
    *,
    sensor_pose: SensorPoseOption = "auto",
    trim: float = 0.0,
    max_iterations: int = 100,
    tol: float = 1e-8,
    max_relative_std: float = DEFAULT_MAX_RELATIVE_STD,
    ticks_per_rev: float | None = None,
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
    loss: "linear" (Gaussian maximum likelihood) or "huber" (robust to slip outliers; the
        threshold is 1.345 whitened standard deviations).
    sensor_pose: "auto" (default: estimate the sensor pose when the data determine it and it
        improves the fit significantly, a likelihood-ratio test at the 99.9% level; else the
        axle model), "axle" (the sensor is on the axle midpoint, facing forward), "estimate"
        (always estimate it), or a :class:`SensorPose` (known mounting).
    trim: fraction of segments to drop as outliers (largest whitened residuals), at most 1%
        per pass with a refit after each; 0 keeps all.
    max_relative_std: identifiability threshold on 1/sigma_min.
    ticks_per_rev: the encoder resolution of the log the segments were cut from (ticks per
        wheel revolution; None: angles not quantised): each angle sample's rounding error
        (variance (2 pi / ticks_per_rev)^2 / 12) is then part of the noise model of segments
        that share samples (:class:`excite.calibration.noise.WheelNoise`).
    """
    seg = _as_segments(segments)
    if len(seg) < 3:
        raise DataError(f"{len(seg)} segment(s); at least 3 are needed")
    if loss not in ("linear", "huber"):
        raise ValueError(f"loss must be 'linear' or 'huber', got {loss!r}")
    if not (isinstance(sensor_pose, SensorPose) or sensor_pose in ("auto", "axle", "estimate")):
        raise ValueError("sensor_pose must be 'auto', 'axle', 'estimate' or a SensorPose, "
                         f"got {sensor_pose!r}")
    if not 0.0 <= trim < 0.5:
        raise ValueError(f"trim must be a fraction in [0, 0.5), got {trim}")
    if not np.any(seg.dphi_L) and not np.any(seg.dphi_R):
        raise DataError("no segment moves: every wheel increment is 0")
    check_wiring(seg)
    given = None if sigma is None else as_sigma(sigma)
    fallback = DEFAULT_NOMINAL
    if initial is not None:
        fallback = initial if isinstance(initial, Params) else Params.from_array(initial)
    axle_start = (initial_estimate(seg) if initial is None else fallback).as_array()
    settings = (loss, max_iterations, tol)

    if isinstance(sensor_pose, SensorPose):
        primary: SegmentModel = FixedSensorPoseModel(sensor_pose)
        start = (body_frame_estimate(seg, sensor_pose, fallback) if initial is None
                 else fallback).as_array()
    elif sensor_pose == "axle":
        primary, start = AXLE, axle_start
    else:
        primary = SENSOR_POSE
        wheels, pose = sensor_pose_estimate(seg, fallback)
        start = np.append(wheels.as_array(), pose.as_array())
    keep = (_trimmed(seg, primary, start, given, loss, trim, max_iterations, tol,
                     max_relative_std) if trim
            else np.ones(len(seg), dtype=bool))
    data = seg[keep] if trim else seg
    levels, whitener = None, None
    if given is None and data.chained is not None and data.chained.any():
        _refuse_too_few_for_noise(data, start.size)
        tick = None if ticks_per_rev is None else tick_angle(ticks_per_rev)
        levels, whitener, start = _correlated_noise(primary, data, start, loss,
                                                    max_iterations, tol, max_relative_std,
                                                    tick)
    fit_sigma = _UNIT_SIGMA if whitener is not None else given

    def fit(model: SegmentModel, theta0: FloatArray) -> _ModelFit:
        return _fit_model(model, data, theta0, fit_sigma, *settings, max_relative_std,
                          whitener)

    threshold = chi2_quantile(TEST_LEVEL, 3)
    chosen = fit(primary, start)
    alternative, statistic, name, choice = None, None, None, ""
    if primary is SENSOR_POSE:
        sensor_fit = chosen
        axle_fit = fit(AXLE, axle_start) if sensor_pose == "auto" else None
        if axle_fit is not None:
            statistic = _likelihood_ratio(axle_fit, sensor_fit, fit_sigma is not None, loss)
            name = "likelihood ratio"
            if not sensor_fit.identifiable:
                chosen, choice = axle_fit, (
                    "axle: the data do not determine the sensor pose ("
                    + _describe_weak(sensor_fit.weak, sensor_fit.theta, data,
                                     sensor_fit.channel_std) + ")")
            elif statistic <= threshold:
                chosen, choice = axle_fit, (
                    f"axle: the sensor-pose model does not fit significantly better "
                    f"(likelihood ratio {statistic:.3g} <= {threshold:.3g})")
            else:
                choice = (f"sensor_pose: it fits significantly better than the axle model "
                          f"(likelihood ratio {statistic:.3g} > {threshold:.3g})")
            if chosen is axle_fit:
                alternative = sensor_fit if sensor_fit.identifiable else None
                statistic = statistic if sensor_fit.identifiable else None
        else:
            choice = "sensor_pose: estimated, as asked"
    else:
        choice = ("axle: as asked" if primary is AXLE
                  else "sensor_pose: at the given pose, as asked")
        pose = np.zeros(3) if primary is AXLE else primary.pose.as_array()
        statistic = _score_statistic(data, np.append(chosen.theta, pose),
                                     chosen.fit.sigma, loss, whitener)
        name = "score"
        if statistic > threshold:  # describe the misfit: where the data put the sensor
            sensor_wheels, sensor_start = sensor_pose_estimate(data, fallback)
            alternative = fit(SENSOR_POSE, np.append(sensor_wheels.as_array(),
                                                     sensor_start.as_array()))
    forced = "" if sensor_pose in ("auto", "estimate") else (
        "axle" if sensor_pose == "axle" else "pose")
    test = _fit_test(chosen, alternative, statistic, name, threshold, given, loss, forced)
    if whitener is not None and loss == "linear":
        test = replace(test, serial_correlation=ljung_box(
            chosen.fit.ev.raw.T, runs_of(data.chained, len(data))))
        test = _driving_test(test, data, chosen, whitener)
        if test.ok:  # a misfit would be taken for a wander
            assert levels is not None
            test = replace(test, heading_wander=_heading_wander(data, chosen, levels,
                                                                whitener))
    return _result(data, chosen, given is None, loss, max_relative_std, choice, test,
                   len(seg) - len(data), levels, whitener)


def _driving_score(data: Segments, mf: _ModelFit, whitener: ChainWhitener
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
    if not _cut_from_log(data) or count is None or len(data) < 8:
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
    # stationary along the directions it holds at their start, _fit_model's weak directions)
    full = np.linalg.pinv(information, hermitian=True)
    restricted = np.linalg.pinv(information[:p, :p], hermitian=True)
    statistic = float(gradient @ full @ gradient - gradient[:p] @ restricted @ gradient[:p])
    shift = -(full @ gradient)[p:]  # one Gauss-Newton step of the extra (relative) parameters
    return statistic, dof, shift


def _driving_test(test: FitTest, data: Segments, mf: _ModelFit,
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


def _heading_wander(data: Segments, mf: _ModelFit, levels: NoiseLevels,
                    whitener: ChainWhitener) -> HeadingWander | None:
    """The pose samples' wandering heading error
    (:func:`excite.calibration.wander.estimate_wander`) from
    the fit's unwhitened residuals, in the directions the data determine."""
    ev = mf.unwhitened
    free = np.einsum("cpn,pm->cmn", ev.jac, complement(mf.weak))
    return estimate_wander(data, ev.raw, free, levels, mf.problem.sigma_floor,
                           whitener.wheels)


def _wandering(seg: Segments, mf: _ModelFit, covariance: FloatArray, test: FitTest,
               whitener: ChainWhitener | None) -> tuple[FloatArray, FitTest]:
    """The relative covariance of the fit when the pose heading error wanders
    (``test.heading_wander``, :func:`excite.calibration.wander.wander_covariance`), and the message
    saying so; unchanged without one or when a direction is undetermined."""
    wander = test.heading_wander
    if wander is None or whitener is None:
        return covariance, test
    bound = (" (or slower: at its bound, the log's longest unbroken stretch)" if wander.at_bound
             else "")
    found = (f"{test.message}; the pose heading error wanders (std {wander.std:.2g} rad over "
             f"{wander.correlation_time:.3g} s{bound}, likelihood ratio "
             f"{wander.statistic:.3g})")
    if not np.all(np.isfinite(covariance)):
        return covariance, replace(test, message=f"{found}; std not changed (a direction is "
                                   "undetermined)")
    wider = wander_covariance(seg, whitener, mf.unwhitened.jac, covariance, wander)
    why = (" (the sensor's mounting angle carries the log's mean heading error)"
           if mf.model is SENSOR_POSE else "")
    return wider, replace(test, message=f"{found}: the std are the fit's under a model with "
                          f"it{why}")


def _cut_from_log(data: Segments) -> bool:
    """Whether segments were cut from a log (sub-steps and times): their noise enters through
    the wheels too (:class:`excite.calibration.noise.WheelNoise`, the slip level)."""
    return data.sub_dphi_L is not None and data.t_start is not None


def _slip_share(seg: Segments, slip: float) -> float | None:
    """CalibrationResult.slip_share: the median over moving segments of slip sqrt(duration)
    / max(|dphi_L|, |dphi_R|); None without segment times or moving segments."""
    if seg.t_start is None or seg.t_end is None:
        return None
    turn = np.maximum(np.abs(seg.dphi_L), np.abs(seg.dphi_R))
    moving = turn > 0
    if not moving.any():
        return None
    duration = (seg.t_end - seg.t_start)[moving]
    return float(np.median(slip * np.sqrt(duration) / turn[moving]))


def _refuse_too_few_for_noise(data: Segments, n_parameters: int) -> None:
    """DataError unless the segments leave MIN_NOISE_DOF_PER_LEVEL residual degrees of freedom
    per noise level to estimate (five levels; seven for segments cut from a log, with slip
    and encoder timing)."""
    n_levels = 7 if _cut_from_log(data) else 5
    dof = 3 * len(data) - n_parameters
    needed = MIN_NOISE_DOF_PER_LEVEL * n_levels
    if dof < needed:
        segments = math.ceil((needed + n_parameters) / 3)
        raise DataError(f"{len(data)} segments leave {dof} residual degrees of freedom to "
                        f"estimate {n_levels} noise levels from; at least {needed} are needed "
                        f"(about {segments} segments for {n_parameters} parameters): a longer "
                        "log, a shorter window, or given noise levels (sigma, --sigma)")


def _serially_correlated(test: FitTest) -> bool:
    lb = test.serial_correlation
    return lb is not None and lb.p_value < 1.0 - TEST_LEVEL


def _long_run(mf: _ModelFit, inverse: FloatArray, covariance: FloatArray, test: FitTest,
              runs: NDArray[np.int64]) -> tuple[FloatArray, FitTest]:
    """The relative covariance ``covariance`` widened for serial correlation of the whitened
    residuals (of segments in ``runs``, :func:`excite.stats.autocorrelation.runs_of`) to the
    Newey-West covariance around the model's inverse information ``inverse``, and the fit
    test saying so (the covariance unchanged when the residuals pass the test, the model
    fails its own test or a direction is undetermined)."""
    if not _serially_correlated(test):
        return covariance, test
    lb = test.serial_correlation
    if not test.ok:  # the misfit already explains it; widening a wrong model's std is moot
        return covariance, replace(test, message=f"{test.message} (the residuals are also "
                                   "correlated over time, as a misfit leaves them)")
    found = (f"{test.message}; residuals correlated over time (Ljung-Box p "
             f"{lb.p_value:.1e}: errors that persist, e.g. a wandering pose source)")
    if not np.all(np.isfinite(covariance)):
        return covariance, replace(test, message=f"{found}; std not widened (a direction is "
                                   "undetermined)")
    ev = mf.fit.ev
    scores = np.einsum("cpk,ck->kp", ev.jac, ev.raw)  # each segment's share of the gradient
    wider = at_least(covariance, long_run_covariance(scores, inverse, runs, lb.lags))
    message = f"{found}: std widened (Newey-West, {lb.lags} segments)"
    return wider, replace(test, message=message, long_run_bandwidth=lb.lags)


def _correlated_noise(model: SegmentModel, data: Segments, start: FloatArray, loss: Loss,
                      max_iterations: int, tol: float, max_relative_std: float,
                      tick: float | None) -> tuple[NoiseLevels, ChainWhitener, FloatArray]:
    """Noise levels of segments that share pose samples (:mod:`excite.calibration.noise`),
    estimated with
    the parameters: a fit with independent per-channel noise gives the moment estimates, then
    rounds of (restricted maximum likelihood of the levels at the fit, linearised; refit
    whitened) until the levels settle. Segments cut from a log (with sub-steps) also carry
    wheel-space noise: slip (its level estimated with the others, started where it explains
    the heading's segment noise), encoder timing (kept when the data show it) and, with
    ``tick`` (rad), encoder quantization; its geometry
    follows the parameters from round to round. Returns the levels, their whitener and the
    last fit's parameters (the start of the final fit)."""
    settings = (loss, max_iterations, tol, max_relative_std)
    mf = _fit_model(model, data, start, None, *settings)
    floor = mf.problem.sigma_floor
    levels = moment_noise(data, mf.fit.ev.residual, model.size, floor)
    in_wheels = _cut_from_log(data)

    def wheels_at(theta: FloatArray) -> WheelNoise | None:
        return WheelNoise.of(model, data, theta, tick) if in_wheels else None

    wheels = wheels_at(mf.theta)
    if wheels is not None:
        heading_unit = math.sqrt(max(float(np.mean(wheels.slip[:, 2, 2])), 1e-300))
        levels = NoiseLevels(levels.sigma, levels.pose, float(levels.sigma[2]) / heading_unit)
    plain = Problem(model, data)
    for _ in range(NOISE_ROUNDS):
        ev = plain.evaluate(mf.theta)
        free = complement(mf.weak)
        new = reml_noise(data, ev.raw, np.einsum("cpn,pm->cmn", ev.jac, free), levels, floor,
                         wheels=wheels)
        settled = (new.close_to(levels, NOISE_RTOL) if wheels is None else
                   new.close_to(levels, NOISE_RTOL, wheels.scale, wheels.timing_scale))
        levels = new
        mf = _fit_model(model, data, mf.theta, _UNIT_SIGMA, *settings,
                        ChainWhitener(data, levels, wheels))
        wheels = wheels_at(mf.theta)
        if settled:
            break
    return levels, ChainWhitener(data, levels, wheels), mf.theta


def _result(seg: Segments, mf: _ModelFit, sigma_estimated: bool, loss: Loss,
            max_relative_std: float, choice: str, test: FitTest,
            n_trimmed: int, levels: NoiseLevels | None = None,
            whitener: ChainWhitener | None = None) -> CalibrationResult:
    fit = mf.fit
    theta, info_rel = fit.theta, fit.system.information
    lam, vec = np.linalg.eigh(info_rel)
    singular = np.sqrt(np.maximum(lam[::-1], 0.0))
    s_min = singular[-1]
    condition = singular[0] / s_min if s_min > 0 else float("inf")
    scale = fit.ev.scale
    inverse = inverse_information(info_rel)
    relative, test = _wandering(seg, mf, inverse, test, whitener)
    relative, test = _long_run(mf, inverse, relative, test, runs_of(seg.chained, len(seg)))
    full = relative * np.outer(scale, scale)
    identifiable = bool(s_min > 0 and 1.0 / s_min <= max_relative_std)
    direction = vector = None
    if not identifiable:
        vector = vec[:, 0]
        weak = vec[:, lam * max_relative_std**2 < 1.0]
        direction = _describe_weak(weak, theta, seg, mf.channel_std)
    params, pose = mf.model.split(theta)
    pose_std = np.sqrt(np.diag(full)[3:6]) if mf.model is SENSOR_POSE else None
    wheels = None if whitener is None else whitener.wheels
    # the levels through the wheels (None where the segments carry no wheel-space noise)
    slip = timing = at_bound = None
    if wheels is not None and levels is not None:
        slip, timing, at_bound = levels.slip, levels.timing, wheels.at_timing_bound(levels.timing)
    raw = fit.ev.residual.T
    z = fit.ev.raw.T / fit.sigma
    outliers = int(np.sum(np.sum(z * z, axis=1) > chi2_quantile(OUTLIER_QUANTILE, 3)))
    return CalibrationResult(
        params=params,
        covariance=full[:3, :3],
        std=np.sqrt(np.diag(full)[:3]),
        model="axle" if mf.model is AXLE else "sensor_pose",
        sensor_pose=pose,
        sensor_pose_std=pose_std,
        parameter_names=mf.model.names,
        full_covariance=full,
        model_choice=choice,
        fit=test,
        singular_values=singular,
        condition_number=float(condition),
        identifiable=identifiable,
        unidentifiable_direction=direction,
        unidentifiable_vector=vector,
        n_segments=len(seg),
        n_outliers=outliers,
        n_trimmed=n_trimmed,
        rms_residual=np.sqrt(np.mean(raw * raw, axis=0)),
        sigma=fit.sigma if levels is None else levels.sigma,
        sigma_estimated=sigma_estimated,
        pose_sigma=None if levels is None else levels.pose,
        slip=slip,
        slip_share=None if slip is None else _slip_share(seg, slip),
        timing=timing,
        timing_at_bound=at_bound,
        loss=loss,
        converged=fit.converged,
        iterations=fit.iterations,
        message=fit.message,
        residuals=raw,
    )
