"""What :func:`excite.calibration.pipeline.calibrate` returns: :class:`CalibrationResult`
with its :class:`FitTest`, their JSON form and report, and :func:`build_result`, the one
place a result is built.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import NDArray

from excite.calibration.gross_errors import GrossErrors
from excite.calibration.heterogeneity import Heterogeneity
from excite.calibration.identifiability import describe_weak
from excite.calibration.model_choice import ModelChoice
from excite.calibration.model_fit import weak_directions
from excite.calibration.noise_rounds import EstimatedNoise
from excite.calibration.options import MIN_RESIDUAL_DOF, FitOptions
from excite.calibration.reml import at_floor, level_floors
from excite.calibration.slip_tests import DrivingTest
from excite.calibration.wander import HeadingWander
from excite.core.kinematics import Params
from excite.core.models import AXLE, SENSOR_POSE, SensorPose
from excite.logs.segments import Segments
from excite.stats.autocorrelation import LjungBox
from excite.stats.chi2 import chi2_quantile

__all__ = ["OUTLIER_QUANTILE", "CalibrationResult", "FitTest", "build_result"]

FloatArray = NDArray[np.float64]
#: A segment is an outlier when its whitened squared residual exceeds this chi2(3) quantile.
OUTLIER_QUANTILE = 0.999
_CHANNELS = ("x", "y", "theta")


@dataclass(frozen=True)
class FitTest:
    """Whether the chosen model fits the data, in numbers and words.

    Attributes
    ----------
    ok : bool
        The verdict: whether the chosen model fits the data.
    message : str
        The reason in words, with what the reported covariance allows for (a wandering
        heading error, serial correlation).
    noise_ratio : ndarray, shape (3,), or None
        Per channel (x, y, theta), the residual std of the chosen model over the reference
        noise level (dimensionless): the given sigma, or the residual std of the sensor-pose
        alternative; None when there is no reference.
    statistic : float or None
        The test of the chosen model against the sensor-pose alternative (dimensionless,
        chi-square with 3 degrees of freedom when the chosen model is right); None when not
        tested.
    statistic_name : str or None
        "likelihood ratio" when both models were fitted, as ``sensor_pose="auto"`` does
        ("Wald statistic" when it did not fit the axle model, the sensor far from the axle);
        "score" (Rao's test at the chosen model's estimate, one evaluation) when a model was
        imposed, the alternative then fitted only to describe a misfit.
    threshold : float
        The chi-square quantile with 3 degrees of freedom at
        :data:`excite.calibration.options.TEST_LEVEL` (99.9%) that ``statistic`` is
        compared with.
    turn_trend_z : float
        The z value of the correlation between the squared position residuals and |dtheta|
        (> 3: the residuals grow with the turn rate, the signature of an off-axle sensor).
    serial_correlation : LjungBox or None
        For segments that share pose samples (noise levels estimated, linear loss), the
        Ljung-Box test of the whitened residuals over lags of 1..10 segments
        (:mod:`excite.stats.autocorrelation`); None when not tested (fewer than 50 segments,
        given noise levels, Huber loss).
    long_run_bandwidth : int or None
        When ``serial_correlation`` rejects "no serial correlation" at TEST_LEVEL and the
        model passes its own test (``ok``), the reported covariance is widened to the
        Newey-West covariance where that is larger, over this many segments, and the
        message says so (``ok`` is not changed by it); else None.
    driving_statistic : float or None
        With the noise levels estimated (linear loss), the acceleration's driving test: Rao's
        score statistic of "r_L, r_R and b change with the change of the wheel speeds"
        (dimensionless; :mod:`excite.calibration.slip_tests`); None when not tested.
    driving_dof : int or None
        The degrees of freedom of ``driving_statistic`` (the extra directions the data
        determine).
    driving_tests : tuple of DrivingTest, or None
        With the noise levels estimated (linear loss, at least 8 segments), the driving tests
        of the acceleration, the turn rate and the wheel speed
        (:class:`excite.calibration.slip_tests.DrivingTest`): slip, whose failing test fails
        the fit (``ok`` False) with its reason; None when not tested.
    heading_wander : HeadingWander or None
        For segments with times that share pose samples (noise levels estimated, linear loss,
        at least 50 segments, the model passing its own test), the pose samples' heading
        error that wanders over seconds (first-order Gauss-Markov: std in rad, correlation
        time in s, :class:`excite.calibration.wander.HeadingWander`) when a likelihood-ratio
        test at the 5% level finds one; the reported covariance is then the fit's under the
        model with it (an estimated mounting angle carries the log's mean heading error) and
        the message says so; None when not found or not tested.
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
    driving_tests: tuple[DrivingTest, ...] | None = None

    def to_dict(self) -> dict:
        """JSON-ready dict (the ``fit`` object of ``excite calibrate --json``)."""
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
                    "at_bound": self.heading_wander.at_bound},
                "driving_tests": None if self.driving_tests is None else [
                    t.to_dict() for t in self.driving_tests]}


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`excite.calibration.pipeline.calibrate` (modelled on scipy's
    OptimizeResult).

    P is the number of estimated parameters: 3 (r_L, r_R, b) or 6 with the sensor pose
    estimated (and its x, y, theta in the body frame). Relative units are those of
    docs/conventions.md.

    Attributes
    ----------
    params : Params
        The wheel parameters r_L, r_R, b (m).
    covariance : ndarray, shape (3, 3)
        Their covariance (m^2): the inverse Fisher information at the estimate (for segments
        that share pose samples, plus the estimated noise levels' share: Kenward and Roger's
        covariance; widened as ``fit`` says for a wandering heading error or serially
        correlated residuals), inf along directions the data do not determine.
    std : ndarray, shape (3,)
        sqrt(diag(covariance)) (m); inf for a parameter the data do not determine (not
        ``identifiable``: one with a share above UNDETERMINED_SHARE of the undetermined
        directions, whose covariance entries are its spread given the others).
    model : str
        "axle" or "sensor_pose".
    sensor_pose : SensorPose or None
        The sensor's pose in the body frame (x, y in m, theta in rad), estimated or given;
        None for the axle model.
    sensor_pose_std : ndarray, shape (3,), or None
        Its std (m, m, rad) when estimated (inf where not determined, as ``std``); else
        None.
    parameter_names : tuple of str
        Every estimated parameter, in the order of ``full_covariance``.
    full_covariance : ndarray, shape (P, P)
        The joint covariance of every estimated parameter (m^2, m rad, rad^2).
    model_choice : str
        Why this model, in words.
    model_statistic : float or None
        The likelihood ratio 2 log(L_sensor-pose / L_axle) (dimensionless) behind
        ``sensor_pose="auto"``'s choice, against the chi-square(3) quantile at the test level
        (the sensor pose's Wald statistic when it is above 100 times that quantile: the axle
        model is then not fitted); None when the choice was not tested (the model asked
        for, or a sensor pose the data do not determine).
    fit : FitTest
        Whether the chosen model fits the data.
    singular_values : ndarray, shape (P,)
        Of the whitened, relatively scaled Jacobian over all estimated parameters,
        descending (dimensionless).
    condition_number : float
        The largest singular value over the smallest (inf when the smallest is 0).
    identifiable : bool
        Whether 1/sigma_min <= max_relative_std. Both judge the model's information, what the
        driving determines; a covariance widened for serially correlated residuals
        (:class:`FitTest`) can be wider than 1/sigma_min says.
    unidentifiable_direction : str or None
        What the data do not determine, in words; None when identifiable.
    unidentifiable_vector : ndarray, shape (P,), or None
        The relative direction of the smallest singular value when not identifiable; else
        None.
    n_segments : int
        Segments fitted (after trimming).
    n_outliers : int
        Segments whose whitened squared residual exceeds the 99.9% chi2(3) quantile
        (OUTLIER_QUANTILE).
    n_trimmed : int
        Segments dropped by trimming.
    rms_residual : ndarray, shape (3,)
        The raw residual RMS per channel (m, m, rad).
    sigma : ndarray, shape (3,)
        The noise std per channel (m, m, rad), given or estimated; with ``pose_sigma``, the
        noise of each segment's own (e.g. slip).
    sigma_estimated : bool
        Whether ``sigma`` was estimated (not given).
    pose_sigma : ndarray, shape (2,), or None
        For segments cut from a log that share pose samples, the noise std of each pose
        sample (xy in m, theta in rad) estimated with ``sigma``, the covariance accounting for
        the shared samples; else None.
    slip : float or None
        For segments cut from a log (with sub-steps), the estimated wheel slip intensity
        (rad / sqrt(s): each wheel's random walk against its encoder, modelled through the
        wheels, :class:`excite.calibration.noise.WheelNoise`); else None.
    slip_share : float or None
        With slip, how large it is against the driving: the median over moving segments of
        slip sqrt(duration) / the larger wheel turn (rad / rad). The random walk's part of
        the std shrinks as the log grows; slip that depends on the driving (speed, turns)
        instead biases the parameters by up to about this fraction, which the model does not
        state (calibrate on gentle driving when it is large against the std). None without
        slip, segment times or moving segments.
    timing : float or None
        For segments cut from a log, the estimated std of each encoder sample's time against
        the pose stream (s; 0 unless the data show one,
        :func:`excite.calibration.reml.reml_noise`); else None.
    timing_at_bound : bool or None
        Whether ``timing`` sits at its bound, a quarter of the encoder period
        (:attr:`excite.calibration.noise.WheelNoise.timing_bound`; larger errors are not
        described, the std are then too narrow); None without timing.
    loss : str
        The loss asked for: "auto" (least squares with the gross-error screen), "linear" or
        "huber".
    converged : bool
        Whether the final fit converged.
    iterations : int
        Levenberg-Marquardt iterations of the final fit (with its refit when directions the
        data do not determine are held).
    message : str
        Why the final fit stopped.
    residuals : ndarray, shape (N, 3)
        The raw residuals, predicted - measured, per segment (m, m, rad).
    levels_at_floor : tuple of str
        The estimated noise levels held at their floor, i.e. not found in the data (the
        report prints them as "none"): any of "x", "y", "theta" (``sigma``), "pose_xy",
        "pose_theta" (``pose_sigma``), "slip"; empty when ``sigma`` is given.
    gross_errors : GrossErrors or None
        Under ``loss="auto"`` (no trimming), what the gross-error screen found
        (:class:`excite.calibration.gross_errors.GrossErrors`): the flagged segments' indices
        (left out of the fit or, around a bad pose sample of a log, merged; not counted in
        ``n_segments``), their times and the bad samples', the test and the words; None when
        not screened.
    heterogeneity : Heterogeneity or None
        The test of agreement of r_L, r_R, b between the logs, or between kinds of motion
        within one log (:class:`excite.calibration.heterogeneity.Heterogeneity`): each group's
        estimate, the statistic and the words. When they disagree, ``params``, ``covariance``,
        ``std`` and the wheel block of ``full_covariance`` cover their spread (between logs
        the random-effects pool; within one log the common fit, its std widened; unless
        common parameters were forced: then ``fit`` fails). None when not tested.
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
    model_statistic: float | None
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
    levels_at_floor: tuple[str, ...] = ()
    gross_errors: GrossErrors | None = None
    heterogeneity: Heterogeneity | None = None

    @property
    def residual_dof(self) -> int:
        """The residual degrees of freedom of one noise channel: the segments fitted less
        the estimated parameters (what estimated noise levels rest on:
        :data:`excite.calibration.options.MIN_RESIDUAL_DOF`)."""
        return self.n_segments - len(self.parameter_names)

    @property
    def sigma_min(self) -> float:
        """The smallest singular value (dimensionless): 1/sigma_min is the worst-direction
        relative std."""
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
            "model_statistic": self.model_statistic,
            "sensor_pose": None if pose is None else named(pose.as_array(), _CHANNELS),
            "sensor_pose_std": (None if self.sensor_pose_std is None
                                else named(self.sensor_pose_std, _CHANNELS)),
            "parameters": list(self.parameter_names),
            "full_covariance": [[finite(v) for v in row] for row in self.full_covariance],
            "fit": self.fit.to_dict(),
            "levels_at_floor": list(self.levels_at_floor),
            **_outliers_dict(self.gross_errors),
            "heterogeneity": (None if self.heterogeneity is None
                              else self.heterogeneity.to_dict()),
        }

    def summary(self, nominal: Params | None = None) -> str:
        """Human-readable report (:func:`excite.calibration.report.report`); ``nominal``: the
        robot's nominal wheel parameters (m), for the comparison in % and the multipliers."""
        from excite.calibration.report import report

        return report(self, nominal)


def _levels_at_floor(sigma: FloatArray, pose: FloatArray | None, slip: float | None,
                     floor: FloatArray, wheels, estimated: bool) -> tuple[str, ...]:
    """CalibrationResult.levels_at_floor: the estimated levels at their floor
    (:func:`excite.calibration.reml.at_floor`; ``floor`` (3,) (m, m, rad) as
    :func:`excite.calibration.reml.level_floors` takes it)."""
    if not estimated:
        return ()
    floors = level_floors(floor, wheels)
    names = [c for c, held in zip(_CHANNELS, at_floor(sigma, floors[:3]), strict=True) if held]
    if pose is not None:
        names += [n for n, held in zip(("pose_xy", "pose_theta"), at_floor(pose, floors[3:5]),
                                       strict=True) if held]
    if slip is not None and wheels is not None and at_floor(np.array([slip]), floors[5:6])[0]:
        names.append("slip")
    return tuple(names)


def _outliers_dict(gross: GrossErrors | None) -> dict:
    """The ``outliers``, ``outlier_times`` and ``gross_errors`` keys of
    :meth:`CalibrationResult.to_dict`."""
    if gross is None:
        return {"outliers": [], "outlier_times": None, "gross_errors": None}
    times = None if gross.t_start is None or gross.t_end is None else [
        [float(a), float(b)] for a, b in zip(gross.t_start, gross.t_end, strict=True)]
    return {"outliers": [int(i) for i in gross.segments], "outlier_times": times,
            "gross_errors": gross.to_dict()}


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


#: A parameter whose share of the directions the data do not determine (the norm of its row
#: of them, in relative units) is above this is not determined either: its std is inf (the
#: covariance's is the std given the others, honest only were they known).
UNDETERMINED_SHARE = 0.05


def too_few_segments(n_segments: int, n_parameters: int) -> str:
    """Why a calibration with estimated noise levels is not determined when its segments
    leave no residual degree of freedom per channel (the parameters and the noise levels
    would fit the data exactly), in words."""
    return (f"{n_segments} segments cannot determine {n_parameters} parameters and the "
            f"noise levels: at least {n_parameters + 1} are needed, "
            f"{n_parameters + MIN_RESIDUAL_DOF} to trust the std")


def build_result(data: Segments, choice: ModelChoice, test: FitTest, relative: FloatArray,
                 sigma_estimated: bool, n_trimmed: int, noise: EstimatedNoise | None,
                 options: FitOptions, loss: str | None = None,
                 gross_errors: GrossErrors | None = None) -> CalibrationResult:
    """The result of the chosen fit on ``data``: ``relative`` is the covariance of the
    parameters in relative units (:func:`excite.calibration.covariance.reported_covariance`),
    ``test`` the fit test, ``noise`` the estimated noise model (None: independent segments,
    sigma given or estimated per channel), ``loss`` the loss asked for (None: the fits'),
    ``gross_errors`` what the gross-error screen found (None: not screened)."""
    mf = choice.chosen
    fit = mf.fit
    theta, info_rel = fit.theta, fit.system.information
    lam, vec = np.linalg.eigh(info_rel)
    singular = np.sqrt(np.maximum(lam[::-1], 0.0))
    s_min = singular[-1]
    condition = singular[0] / s_min if s_min > 0 else float("inf")
    scale = fit.ev.scale
    full = relative * np.outer(scale, scale)
    max_relative_std = options.max_relative_std
    weak = weak_directions(fit.system.information, max_relative_std)
    identifiable = weak.shape[1] == 0
    direction = vector = None
    if not identifiable:
        vector = vec[:, 0]
        direction = describe_weak(weak, theta, data, mf.channel_std)
    params, pose = mf.model.split(theta)
    std = np.sqrt(np.diag(full))
    if not identifiable:  # moving along a direction the data do not determine: not determined
        std[np.linalg.norm(weak, axis=1) > UNDETERMINED_SHARE] = np.inf
    if sigma_estimated and len(data) <= len(mf.model.names):  # the noise levels fit exactly
        identifiable, std[:] = False, np.inf
        direction = too_few_segments(len(data), len(mf.model.names))
    pose_std = std[3:6] if mf.model is SENSOR_POSE else None
    levels = None if noise is None else noise.levels
    wheels = None if noise is None else noise.whitener.wheels
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
        std=std[:3],
        model="axle" if mf.model is AXLE else "sensor_pose",
        sensor_pose=pose,
        sensor_pose_std=pose_std,
        parameter_names=mf.model.names,
        full_covariance=full,
        model_choice=choice.words,
        model_statistic=choice.statistic,
        fit=test,
        singular_values=singular,
        condition_number=float(condition),
        identifiable=identifiable,
        unidentifiable_direction=direction,
        unidentifiable_vector=vector,
        n_segments=len(data),
        n_outliers=outliers,
        n_trimmed=n_trimmed,
        rms_residual=np.sqrt(np.mean(raw * raw, axis=0)),
        sigma=fit.sigma if levels is None else levels.sigma,
        sigma_estimated=sigma_estimated,
        pose_sigma=None if levels is None else levels.pose,
        slip=slip,
        slip_share=None if slip is None else _slip_share(data, slip),
        timing=timing,
        timing_at_bound=at_bound,
        loss=options.loss if loss is None else loss,
        converged=fit.converged,
        iterations=fit.iterations,
        message=fit.message,
        residuals=raw,
        levels_at_floor=_levels_at_floor(
            fit.sigma if levels is None else levels.sigma,
            None if levels is None else levels.pose, slip, mf.problem.sigma_floor, wheels,
            sigma_estimated),
        gross_errors=gross_errors,
    )
