"""The stopping rule: is the calibration of the data so far good enough?

A robot team drives until the calibration reaches a target, not for a fixed budget. The rule
decides from the batch calibration of the data so far (:func:`excite.calibrate`: noise levels
estimated from the data, the time-series GLS where segments share pose samples), never from an
online filter's covariance, and it is meant to be asked after every segment.

The target (docs/conventions.md for the relative scales):

- r_L, r_R, b: each within ``target`` relative error (0.002 = 0.2%);
- with the sensor pose estimated, its x and y within ``target`` x b (m) and its angle within
  ``target`` rad: the same relative scale as sigma_min.

*Done* when every parameter's half-width at the stated confidence is within its tolerance:

    q * std_i <= tolerance_i    for every parameter i,

with q a simultaneous (Bonferroni) quantile over the P parameters of Student's t with the
residual degrees of freedom of one noise channel, t_dof^{-1}(1 - (1 - confidence) / (2 P)),
dof = segments - P: the noise levels are estimated. At any one look the chance that some
parameter lies outside its tolerance while the rule says done is then at most
1 - confidence. Asking after every segment is optional stopping: the half-widths depend on
the driving and on the estimated noise levels, and a look at which the noise happens to look
small would stop early. The Bonferroni union over the parameters (conservative for correlated
estimates) and the residual degrees of freedom the rule waits for are the margin against
that; the false-stop rate with a look after every segment is measured by Monte Carlo (tests,
``benchmarks/bench_optional_stopping.py``, which compares this quantile with an upper bound
on the noise scale and with the normal quantile alone).

The rule also says *not yet* whenever the batch result cannot be trusted: parameters not
determined (exit 3 of ``excite calibrate``), a model that does not fit (exit 4), a driving
test that passes the calibration's level but not the rule's STOP_DRIVING_LEVEL, more than
MAX_GROSS_SHARE of the segments left out as gross errors, too few segments to estimate the
noise levels (fewer than MIN_RESIDUAL_DOF residual degrees of freedom per channel), or a
channel of independent segments fitted exactly (its noise level at its floor). It predicts
how many more segments the current way of driving needs from the growth of the information
so far (std ~ 1 / sqrt(segments)).

Asked after every segment of a growing log (:meth:`StoppingRule.session`, or
:meth:`StoppingRule.decide` with the previous decision), most looks skip the batch
calibration: for segments that share pose samples, a screen (:mod:`excite.calibration.screen`)
computes the std of the data so far at the last calibration's noise model, its levels
followed by a factor per group (a few ms instead of hundreds), and says *not yet* when the
statistic from them exceeds SCREEN_MARGIN. Every *done*, and every look the screen does not
rule out, is the batch calibration's, so a session stops where the rule alone first says done
unless the screen's statistic is above SCREEN_MARGIN where the calibration's is at most 1
(its levels then off by that much from the calibration's; ``benchmarks/bench_stopping.py
--sessions`` compares the first *done* of both on simulated logs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from excite.calibration.options import MIN_RESIDUAL_DOF, SensorPoseOption
from excite.core.kinematics import Params
from excite.errors import ExciteError
from excite.logs.segments import Segments

if TYPE_CHECKING:  # the calibration and scipy.stats are imported when a decision is asked:
    # the command line reads this module's defaults at every start
    from excite.calibration.result import CalibrationResult

__all__ = ["DEFAULT_CONFIDENCE", "DEFAULT_TARGET", "MAX_GROSS_SHARE", "REFERENCE_GROWTH",
           "SCREEN_MARGIN", "STOP_DRIVING_LEVEL", "StopDecision", "StoppingRule",
           "StoppingSession", "finite_or_none"]

#: The default target: the largest relative error of r_L, r_R, b (0.2%).
DEFAULT_TARGET = 0.002
#: The default confidence that every parameter is within the target when the rule stops.
DEFAULT_CONFIDENCE = 0.95
#: The level at which a *done* needs the driving tests passed (the three tests one family,
#: :func:`excite.calibration.slip_tests.fails_at`), stricter than the calibration's 99%: asked
#: after every segment, a test that fails at most looks still passes at some look (optional
#: stopping over the fit tests); a miss there is a false stop, a false alarm a few more
#: segments.
STOP_DRIVING_LEVEL = 0.95
#: The largest share of the segments a *done* may leave out as gross errors. A pose source
#: fails in a few percent of its samples (at 5%, more than a tenth of 60 segments with
#: probability 0.03); a larger share is more likely the model failing in the hardest driving
#: (slip), which down-weighting hides.
MAX_GROSS_SHARE = 0.1
#: The screen (:meth:`StoppingRule.decide` with ``previous``) says *not yet* without the batch
#: calibration only when its statistic exceeds this: its noise levels are an earlier look's
#: followed by a factor per group, not the calibration's own REML and tests, and the
#: calibration's statistic may be this much smaller.
SCREEN_MARGIN = 1.05
#: The screen uses an earlier look's calibration only while the segments have grown at most
#: this many times since it; the batch calibration runs again then and is the next reference.
REFERENCE_GROWTH = 1.25


@dataclass(frozen=True)
class StopDecision:
    """One decision of :class:`StoppingRule`.

    Attributes
    ----------
    done : bool
        Whether the calibration meets the target at the confidence.
    statistic : float
        The largest ratio of a parameter's half-width (q * std) to its tolerance
        (dimensionless; done when <= 1; inf when the data do not determine a parameter or
        the calibration failed).
    reason : str
        Why, in words.
    n_segments : int
        Segments the decision saw.
    quantile : float
        The simultaneous quantile q used (Student's t, Bonferroni; nan when no calibration).
    half_widths : dict of str to float
        Each parameter's half-width q * std, in its unit (m or rad); empty without a
        calibration.
    tolerances : dict of str to float
        Each parameter's tolerance, in its unit (m or rad).
    segments_to_go : float
        Predicted further segments the current driving needs (0 when done; inf when unknown).
    seconds_to_go : float or None
        The same in seconds, from the mean duration of the segments so far (inf when unknown;
        None without segment times).
    result : CalibrationResult or None
        The batch calibration the decision is based on (None when it failed); for a
        ``screened`` decision, the earlier look's calibration whose noise model the screen
        used (of ``result.n_segments`` < ``n_segments`` segments).
    screened : bool
        Whether the decision is the screen's *not yet* (:meth:`StoppingRule.decide` with
        ``previous``): ``statistic``, ``quantile``, ``half_widths`` and ``segments_to_go``
        are then the screen's (:mod:`excite.calibration.screen`), not a calibration's.
    """

    done: bool
    statistic: float
    reason: str
    n_segments: int
    quantile: float
    half_widths: dict[str, float]
    tolerances: dict[str, float]
    segments_to_go: float
    seconds_to_go: float | None
    result: CalibrationResult | None
    screened: bool = False

    @classmethod
    def not_yet(cls, n_segments: int, reason: str, tolerances: dict[str, float] | None = None,
                result: CalibrationResult | None = None) -> StopDecision:
        """A *not yet* without a judged calibration: ``reason`` says why (statistic and
        segments to go inf)."""
        return cls(False, math.inf, reason, n_segments, math.nan, {}, tolerances or {},
                   math.inf, None, result)

    def to_dict(self) -> dict:
        """JSON-ready dict (without the calibration result)."""
        return {"done": self.done, "statistic": finite_or_none(self.statistic),
                "reason": self.reason, "n_segments": self.n_segments,
                "quantile": finite_or_none(self.quantile),
                "half_widths": self.half_widths, "tolerances": self.tolerances,
                "segments_to_go": finite_or_none(self.segments_to_go),
                "seconds_to_go": None if self.seconds_to_go is None
                else finite_or_none(self.seconds_to_go), "screened": self.screened}


def finite_or_none(x: float) -> float | None:
    """x as a JSON number, None where it is not finite (inf: unknown)."""
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class StoppingRule:
    """Decides *done* or *not yet* for the data so far (see the module docstring).

    Attributes
    ----------
    target : float
        The largest relative error of r_L, r_R, b (dimensionless, > 0; 0.002 = 0.2%); with
        the sensor pose estimated, its x, y within target * b (m) and its angle within target
        (rad).
    confidence : float
        The confidence that every parameter is within its tolerance when done (in (0, 1)).
    sensor_pose : "auto", "axle", "estimate" or SensorPose
        Passed to :func:`excite.calibrate`.
    ticks_per_rev : float or None
        The encoders' resolution, for segments cut from a log (see :func:`excite.calibrate`).
    """

    target: float = DEFAULT_TARGET
    confidence: float = DEFAULT_CONFIDENCE
    sensor_pose: SensorPoseOption = "auto"
    ticks_per_rev: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.target, (int, float)) and 0.0 < self.target < 1.0):
            raise ValueError(f"target must be a relative error in (0, 1), got {self.target!r}")
        if not (isinstance(self.confidence, (int, float)) and 0.0 < self.confidence < 1.0):
            raise ValueError(f"confidence must be in (0, 1), got {self.confidence!r}")

    def decide(self, segments: Segments, nominal: Params | ArrayLike | None = None,
               previous: StopDecision | None = None) -> StopDecision:
        """The decision for ``segments`` (all the data so far), the batch calibration
        started at ``nominal`` (Params or (r_L, r_R, b) in m; None: its own start).

        ``previous``: this rule's decision at an earlier look of the same growing session
        (on a prefix of ``segments``; None: none, the batch calibration decides). For
        segments that share pose samples, the screen (:mod:`excite.calibration.screen`) then
        says *not yet* without calibrating when its statistic, at the noise model of the
        session's last batch calibration (``previous.result``, of at least
        1 / REFERENCE_GROWTH of the segments), exceeds SCREEN_MARGIN; the decision is
        ``screened``. Otherwise, and for every *done*, the batch calibration decides, exactly
        as without ``previous``. :meth:`session` passes it along."""
        if previous is not None:
            screened = self._screened(segments, previous)
            if screened is not None:
                return screened
        return self._calibrated(segments, nominal)

    def session(self, nominal: Params | ArrayLike | None = None) -> StoppingSession:
        """A :class:`StoppingSession`: this rule asked after every segment of one growing
        session, each look passing the previous decision (the screen)."""
        return StoppingSession(self, nominal)

    def _calibrated(self, segments: Segments, nominal: Params | ArrayLike | None
                    ) -> StopDecision:
        """The decision from the batch calibration of ``segments``."""
        try:
            from excite.calibration.pipeline import calibrate

            result = calibrate(segments, initial=nominal, sensor_pose=self.sensor_pose,
                               ticks_per_rev=self.ticks_per_rev)
        except ExciteError as exc:  # too few segments for the noise levels, no motion, ...
            return StopDecision.not_yet(len(segments), f"no calibration yet: {exc}")
        return self.judge(result, segments)

    def judge(self, result: CalibrationResult, segments: Segments | None = None
              ) -> StopDecision:
        """The decision for a calibration already made (``result``, e.g. of several logs by
        :func:`excite.calibration.logs.calibrate_logs`, whose std then include the logs'
        spread), by the conditions of :meth:`decide` (this rule's ``sensor_pose`` and
        ``ticks_per_rev`` are not used: the calibration's own are). ``segments``: the data
        it was made from (all of them, gross errors included: the count the rule reports and
        predicts from; without them, the calibration's count); their times give
        ``seconds_to_go`` (None without them)."""
        n = result.n_segments if segments is None else len(segments)
        tolerances = self._tolerances(result)
        unready = _unready(result)
        if unready is not None:
            return StopDecision.not_yet(n, unready, tolerances, result)
        quantile = self._quantile(result)
        half, ratios = _half_widths(_standard_deviations(result), quantile, tolerances)
        statistic = max(ratios.values())
        worst = max(ratios, key=ratios.get)
        done = bool(statistic <= 1.0)
        to_go = 0.0 if done else _segments_to_go(n, statistic)
        reason = (f"every parameter within its tolerance at {self.confidence:.0%} "
                  f"(the widest, {worst}, at {statistic:.2f} of it)" if done else
                  f"{worst} at {statistic:.2f} of its tolerance at {self.confidence:.0%}")
        seconds = None if segments is None else _seconds(segments, to_go)
        return StopDecision(done, statistic, reason, n, quantile, half, tolerances, to_go,
                            seconds, result)

    def _tolerances(self, result: CalibrationResult) -> dict[str, float]:
        """Each parameter's tolerance in its unit: target x value for r_L, r_R, b (m); with
        the sensor pose estimated, target x b for x, y (m) and target for theta (rad)."""
        p = result.params
        tol = {"r_L": self.target * abs(p.r_L), "r_R": self.target * abs(p.r_R),
               "b": self.target * abs(p.b)}
        if result.sensor_pose_std is not None:
            tol |= {"x": self.target * abs(p.b), "y": self.target * abs(p.b),
                    "theta": self.target}
        return tol

    def _screened(self, segments: Segments, previous: StopDecision) -> StopDecision | None:
        """The screen's *not yet* (see :meth:`decide`), or None when the batch calibration
        must decide: no usable reference, the screen does not apply, or its statistic (the
        smallest over the models the calibration could report and the outcomes of its tests
        of segment noise) is at most SCREEN_MARGIN."""
        reference, n = previous.result, len(segments)
        if (reference is None or previous.n_segments > n
                or n > REFERENCE_GROWTH * reference.n_segments):
            return None
        from excite.calibration.screen import screened_std

        found = screened_std(segments, reference, self.sensor_pose, self.ticks_per_rev)
        if not found:
            return None
        every = self._tolerances(reference)
        best = None
        for screened in found:
            quantile = self._quantile_of(n, screened.n_parameters)
            half, ratios = _half_widths(screened.std, quantile, every)
            statistic = max(ratios.values())
            if best is None or statistic < best[0]:
                best = (statistic, quantile, half, {k: every[k] for k in half}, ratios)
        statistic, quantile, half, tolerances, ratios = best
        if not statistic > SCREEN_MARGIN:
            return None
        worst = max(ratios, key=ratios.get)
        to_go = _segments_to_go(n, statistic)
        reason = (f"{worst} at about {statistic:.2f} of its tolerance at {self.confidence:.0%} "
                  f"(screened at the noise model of the calibration of "
                  f"{reference.n_segments} segments)")
        return StopDecision(False, statistic, reason, n, quantile, half, tolerances, to_go,
                            _seconds(segments, to_go), reference, screened=True)

    def _quantile(self, result: CalibrationResult) -> float:
        """:meth:`_quantile_of` the calibration's segments and estimated parameters."""
        return self._quantile_of(result.n_segments, len(result.parameter_names))

    def _quantile_of(self, n_segments: int, count: int) -> float:
        """The simultaneous (Bonferroni) two-sided quantile over the ``count`` estimated
        parameters of Student's t with the residual degrees of freedom of one noise channel
        (segments less the parameters)."""
        from scipy.stats import t

        dof = max(n_segments - count, 1)
        return float(t.ppf(1.0 - (1.0 - self.confidence) / (2 * count), dof))


def _unready(result: CalibrationResult) -> str | None:
    """Why a calibration cannot make a *done* whatever its std, in words (the parameters not
    determined, the model not fitting, a doubt of :func:`_doubt`, too few residual degrees of
    freedom, a channel fitted exactly); None when it can."""
    if not result.identifiable:
        return ("the data do not determine the parameters yet: "
                f"{result.unidentifiable_direction}")
    if not result.fit.ok:
        return f"the model does not fit the data: {result.fit.message}"
    doubt = _doubt(result)
    if doubt:
        return doubt
    dof = result.residual_dof
    if dof < MIN_RESIDUAL_DOF:
        return (f"{dof} residual degrees of freedom per noise channel; the noise levels need "
                f"at least {MIN_RESIDUAL_DOF}")
    exact = [c for c in ("x", "y", "theta") if c in result.levels_at_floor]
    if exact and result.pose_sigma is None:
        return (f"the {', '.join(exact)} residuals vanish (a channel fitted exactly): its "
                "noise level is not known yet")
    return None


def _doubt(result: CalibrationResult) -> str | None:
    """Why a fit that passed the calibration's tests is not yet enough for a *done*, in
    words: a driving test failing at STOP_DRIVING_LEVEL, or more than MAX_GROSS_SHARE of the
    segments left out as gross errors; None when neither."""
    from excite.calibration.fit_tests import driving_misfit
    from excite.stats.chi2 import chi2_survival

    test = driving_misfit(result, STOP_DRIVING_LEVEL)
    if test is not None:
        return (f"{', '.join(test.moved)} change with the {test.driving} (score "
                f"{test.statistic:.3g}, {test.dof} dof, p = "
                f"{chi2_survival(test.statistic, test.dof):.2g}): the driving tests pass the "
                f"calibration's level but not the rule's {STOP_DRIVING_LEVEL:.0%}; slip biases "
                "the estimates beyond their std")
    gross = result.gross_errors
    if gross is not None and gross.segments.size > MAX_GROSS_SHARE * gross.n_segments:
        return (f"{gross.segments.size} of {gross.n_segments} segments "
                f"({gross.segments.size / gross.n_segments:.0%}) left out as gross errors, more "
                f"than the rule's {MAX_GROSS_SHARE:.0%}: so many are more likely slip in the "
                "hardest driving than a pose source's failures")
    return None


class StoppingSession:
    """A :class:`StoppingRule` asked after every segment of one growing session (e.g. a log
    recorded on the robot): :meth:`decide` passes the previous decision to
    :meth:`StoppingRule.decide`, so that looks the screen answers skip the batch
    calibration. Every *done* is the batch calibration's, and the first comes at the look
    where the rule alone first says done unless the screen's statistic there exceeds
    SCREEN_MARGIN (see the module docstring).

    Attributes
    ----------
    rule : StoppingRule
        The rule asked.
    nominal : Params, (r_L, r_R, b) or None
        Where every batch calibration starts (m; None: its own start).
    last : StopDecision or None
        The latest decision (None before the first look).
    """

    def __init__(self, rule: StoppingRule, nominal: Params | ArrayLike | None = None):
        self.rule = rule
        self.nominal = nominal
        self.last: StopDecision | None = None

    def decide(self, segments: Segments) -> StopDecision:
        """The decision for ``segments``: all the data of the session so far (the segments
        of the previous look, and more)."""
        self.last = self.rule.decide(segments, self.nominal, previous=self.last)
        return self.last


def _standard_deviations(result: CalibrationResult) -> dict[str, float]:
    """The std of every estimated parameter, by name (m or rad)."""
    std = dict(zip(("r_L", "r_R", "b"), map(float, result.std), strict=True))
    if result.sensor_pose_std is not None:
        std |= dict(zip(("x", "y", "theta"), map(float, result.sensor_pose_std), strict=True))
    return std


def _half_widths(std: dict[str, float], quantile: float, tolerances: dict[str, float]
                 ) -> tuple[dict[str, float], dict[str, float]]:
    """Each parameter's half-width (quantile x std, in its unit) and its ratio to its
    tolerance, for the parameters of ``std``."""
    half = {name: float(quantile * s) for name, s in std.items()}
    return half, {name: half[name] / tolerances[name] for name in half}


def _segments_to_go(n: int, statistic: float) -> float:
    """Further segments for the statistic to fall to 1 when every std shrinks as
    1 / sqrt(segments) (the information grows linearly with the current driving)."""
    if not math.isfinite(statistic):
        return math.inf
    return float(max(math.ceil(n * statistic * statistic) - n, 1))


def _seconds(segments: Segments, to_go: float) -> float | None:
    """``to_go`` segments in seconds at the mean duration so far; None without times."""
    if segments.t_start is None or segments.t_end is None:
        return None
    return to_go * float(np.mean(segments.t_end - segments.t_start))
