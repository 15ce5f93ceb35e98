"""The driving tests: do the parameters, and the size of the residuals, change with how the
robot is driven? Wheels that slip count rotation that never became motion, more the harder
they are driven: a bias of r_L, r_R, b (and of the sensor pose they are fitted with) that no
noise level describes, so the estimates can lie many of their std from the truth while the
residuals look like noise of the estimated levels.

**The driving.** Three measures per segment, from the wheel increments only (never the
measured poses, so that they do not depend on the measurement noise), T the segment's
duration (s; without times each is per segment: rad, m):

* ``acceleration``: the change of the wheel speeds, |change of dphi_L / T| + |change of
  dphi_R / T| (rad/s per segment): with sub-steps, first to last sub-step within the
  segment; without them, from the previous segment (rows in the order of the data);
* ``turn rate``: |r_R dphi_R - r_L dphi_L| / (b T) at the fitted parameters (rad/s);
* ``wheel speed``: max(|r_L dphi_L|, |r_R dphi_R|) / T, the faster wheel's rim speed
  (m/s).

**The change of the parameters.** Rao's score test of "the parameters change linearly with
the driving", theta_k = theta + gamma z_k (z the measure standardised over the segments,
mean 0 and std 1), at the fitted parameters, with the Jacobian whitened by the fit's own
noise model: the efficient score s = sum_k s_k of the extra columns residualised on the
model's own, and the statistic s' V^+ s, chi-square with the extra directions the data
determine as degrees of freedom. V is the information of the extra columns; when the
residuals are serially correlated (the Ljung-Box test rejected), at least the Newey-West
covariance of the per-segment contributions s_k over as many lags (as the reported
covariance, :mod:`excite.calibration.covariance`). ``acceleration`` changes r_L, r_R and b
(3 extra parameters); ``turn rate`` and ``wheel speed`` every parameter of the model (the
sensor pose too: a sensor offset that appears only in the turns is slip, a mounting does
not move). The one-step estimate of gamma says how much: ``shift``, the largest over the
parameters of |gamma_i| / std_i, the change of a parameter over one std of the driving in
units of its own std.

**The mounting.** When the test changes the sensor pose too, the score test of the sensor
pose's part alone, the change of r_L, r_R and b a nuisance (``pose_statistic``, chi-square
with ``pose_dof``): a mounting does not move with the driving, and a sensor offset that
appears only in the turns is slip.

**The growth of the residuals.** After the step of gamma, each channel's squared whitened
residuals (over 1 - leverage) regressed on z: Koenker's studentised Breusch-Pagan statistic
N R^2, chi-square with 1 degree of freedom when their size does not depend on the driving;
``growth`` is the smallest p-value of the three channels times 3.

**The verdict.** A test fails the fit when its change is material (some parameter moves
by more than its own std over one std of the driving: on a long log a tiny effect is
significant and moves nothing) and significant, or the mounting's part of it is: the
sensor's pose would have to move with the driving, which no mounting does, so the change is
slip even where the wheels' share of it alone would not be significant. It is
``slipping`` when the change is one that slip makes and a difference of effective parameters
between kinds of driving does not: the residuals still grow with the driving after the
step, or the mounting changes with it.
Wheel parameters that differ between gentle and hard driving while the residuals fit both
and the mounting stays put may be the effective parameters of each driving (wheels that
scrub in turns): when the heterogeneity stage finds the kinds of motion disagreeing and
widens the std by their spread (:mod:`excite.calibration.heterogeneity`, random
effects), such a test no longer fails the fit (:func:`excite.calibration.fit_tests.
pooled_over_kinds`); a slipping one still does. The three tests are one family at
DRIVING_TEST_LEVEL (99%, below the other fit tests' 99.9%: a miss is a confident wrong
answer, a false alarm a gentler drive): each at 1 - (1 - DRIVING_TEST_LEVEL) / 3
(Bonferroni), the growth and mounting tests at the same level. More than MAX_TESTED
independent segments are tested on MAX_TESTED of them, evenly spaced (their whitened
residuals are independent: the level holds).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from excite.calibration.model_fit import ModelFit
from excite.calibration.noise import ChainWhitener
from excite.calibration.options import DRIVING_TEST_LEVEL, TEST_LEVEL
from excite.core.information import channel_gram, inverse_information
from excite.logs.segments import Segments
from excite.stats.autocorrelation import LjungBox, at_least, long_run_covariance, runs_of
from excite.stats.chi2 import chi2_quantile, chi2_survival

__all__ = ["DRIVING", "FAMILY_LEVEL", "MAX_TESTED", "DrivingTest", "driving_measures",
           "driving_tests", "fails_at"]

FloatArray = NDArray[np.float64]
#: The measures of the driving, in the order they are tested and reported.
DRIVING = ("acceleration", "turn rate", "wheel speed")
#: Each test's level: the family of the three at DRIVING_TEST_LEVEL (Bonferroni).
FAMILY_LEVEL = 1.0 - (1.0 - DRIVING_TEST_LEVEL) / len(DRIVING)
#: Fewer segments than this are not tested.
_MIN_SEGMENTS = 8
#: Independent segments beyond this many are tested on this many, evenly spaced (the tests'
#: cost bounded; their power is ample long before).
MAX_TESTED = 20_000
_CHANNELS = ("x", "y", "theta")

Whiten = Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]]


@dataclass(frozen=True)
class DrivingTest:
    """One driving test (module docstring).

    Attributes
    ----------
    driving : str
        "acceleration", "turn rate" or "wheel speed".
    statistic : float
        The score statistic of "the parameters change linearly with the driving"
        (dimensionless; chi-square with ``dof`` when they do not).
    dof : int
        Its degrees of freedom: the extra directions the data determine.
    threshold : float
        The chi-square quantile at FAMILY_LEVEL it is compared with.
    shift : float
        The largest change of a parameter over one std of the driving, in units of its own
        std (the one-step estimate).
    moved : tuple of str
        The parameters whose change exceeds their own std.
    growth : float
        The p-value of "the residuals' size does not depend on the driving" after the step of
        gamma (the smallest of the three channels' times 3).
    growth_ratio : ndarray, shape (3,)
        Per channel (x, y, theta), the residuals' RMS (whitened) in the segments above the
        median of the driving over that below it (1 where either is 0).
    pose_statistic : float or None
        The score statistic of "the sensor pose changes with the driving" beside a change of
        r_L, r_R and b (chi-square with ``pose_dof`` when it does not); None when the sensor
        pose is not estimated or the test changes the wheel parameters only.
    pose_dof : int or None
        Its degrees of freedom.
    failed : bool
        Whether this test fails the fit: the change is material, and significant or the
        mounting's part of it is (module docstring, "The verdict").
    slipping : bool
        Whether the residuals grow with the driving after the step (``growth`` below the
        test's level) or the mounting changes with it (``pose_statistic`` above its
        quantile): slip, which the kinds' spread in the std does not cover.
    """

    driving: str
    statistic: float
    dof: int
    threshold: float
    shift: float
    moved: tuple[str, ...]
    growth: float
    growth_ratio: FloatArray
    pose_statistic: float | None
    pose_dof: int | None
    failed: bool
    slipping: bool

    def to_dict(self) -> dict:
        """JSON-ready dict (an entry of ``fit.driving_tests`` of ``excite calibrate
        --json``)."""
        return {"driving": self.driving, "statistic": self.statistic, "dof": self.dof,
                "threshold": self.threshold, "shift": self.shift, "moved": list(self.moved),
                "growth_p_value": self.growth,
                "growth_ratio": dict(zip(_CHANNELS, map(float, self.growth_ratio),
                                         strict=True)),
                "pose_statistic": self.pose_statistic, "pose_dof": self.pose_dof,
                "failed": self.failed, "slipping": self.slipping}


def driving_measures(data: Segments, theta: FloatArray,
                     rows: NDArray[np.int64] | None = None) -> dict[str, FloatArray]:
    """The measures of the driving per segment (module docstring), by name of DRIVING, at
    the parameters ``theta`` (r_L, r_R, b first, m), of the segments ``rows`` (None: all)."""
    r_l, r_r, b = (float(v) for v in theta[:3])
    at = np.arange(len(data)) if rows is None else rows
    timed = data.t_start is not None and data.t_end is not None

    def durations(i: NDArray[np.int64]) -> FloatArray:
        return (np.maximum(data.t_end[i] - data.t_start[i], 1e-12)  # type: ignore[index]
                if timed else np.ones(i.size))

    duration = durations(at)
    rate_l, rate_r = data.dphi_L[at] / duration, data.dphi_R[at] / duration
    counts = data.substep_counts
    if counts is not None and data.sub_dphi_L is not None and data.sub_dphi_R is not None \
            and timed:
        last = counts[at] - 1
        change = (np.abs(data.sub_dphi_L[at, last] - data.sub_dphi_L[at, 0])
                  + np.abs(data.sub_dphi_R[at, last] - data.sub_dphi_R[at, 0])
                  ) * counts[at] / duration
    else:  # from the previous segment; a run's first segment gets the median of the others
        before = np.maximum(at - 1, 0)
        previous = durations(before)
        change = (np.abs(rate_l - data.dphi_L[before] / previous)
                  + np.abs(rate_r - data.dphi_R[before] / previous))
        first = at == 0
        if data.chained is not None:
            first |= ~data.chained[at]
        if (~first).any():
            change[first] = np.median(change[~first])
    turn = np.abs(r_r * rate_r - r_l * rate_l) / b
    speed = np.maximum(np.abs(r_l * rate_l), np.abs(r_r * rate_r))
    return dict(zip(DRIVING, (change, turn, speed), strict=True))


def driving_tests(data: Segments, mf: ModelFit, whitener: ChainWhitener | None,
                  serial: LjungBox | None) -> tuple[DrivingTest, ...]:
    """The driving tests of the fit ``mf`` on ``data`` (module docstring), whitened by
    ``whitener`` (segments that share pose samples) or by the fit's per-channel sigma;
    ``serial``: the Ljung-Box test of the fit's residuals (None: not tested), whose rejection
    makes the score's covariance at least Newey-West's. Empty with fewer than 8 segments;
    a measure that does not vary is not tested."""
    if len(data) < _MIN_SEGMENTS:
        return ()
    ev = mf.unwhitened
    raw, jac = ev.raw, ev.jac
    whiten = _whitening(mf, whitener)
    lags = serial.lags if serial is not None and serial.p_value < 1.0 - TEST_LEVEL else 0
    runs = runs_of(data.chained, len(data))
    rows = None
    if whitener is None and len(data) > MAX_TESTED:  # independent: evenly spaced ones
        # spaced by at least one: increasing, no repeats
        rows = np.linspace(0, len(data) - 1, MAX_TESTED).round().astype(np.int64)
        raw, jac, runs = raw[:, rows], jac[:, :, rows], runs[rows]
    white, own = whiten(raw, jac)
    own_system = _own_system(own)  # the same for every test
    tests = []
    for name, measure in driving_measures(data, mf.theta, rows).items():
        spread = measure.std()
        if not np.isfinite(spread) or spread <= 0:
            continue
        z = (measure - measure.mean()) / spread
        extra = [0, 1, 2] if name == "acceleration" else list(range(mf.theta.size))
        # per-channel whitening (no whitener) commutes with the scaling by z
        columns = (own[:, extra, :] * z if whitener is None
                   else whiten(raw, jac[:, extra, :] * z)[1])
        test = _driving_test(name, mf.model.names, own, own_system, columns, white, z, extra,
                             runs, lags)
        if test is not None:
            tests.append(test)
    return tuple(tests)


def _whitening(mf: ModelFit, whitener: ChainWhitener | None) -> Whiten:
    """Residuals (3, N) and Jacobian rows (3, P, N) whitened as the fit was: by the chain
    whitener, or by the fit's per-channel sigma."""
    if whitener is not None:
        return lambda raw, jac: whitener.whiten(raw, jac)  # type: ignore[return-value]
    sigma = mf.fit.sigma
    return lambda raw, jac: (raw / sigma[:, None], jac / sigma[:, None, None])


def _driving_test(name: str, names: tuple[str, ...], own: FloatArray,
                  own_system: tuple[FloatArray, FloatArray], columns: FloatArray,
                  white: FloatArray, z: FloatArray, extra: list[int],
                  runs: NDArray[np.int64], lags: int) -> DrivingTest | None:
    """One driving test: the score test of theta_k = theta + gamma z_k (gamma on the
    parameters ``extra``, whose whitened columns J_i z are ``columns`` (3, q, N) beside the
    model's own (3, P, N) and their information and its inverse ``own_system``
    (:func:`_own_system`), at the whitened residuals ``white``), its one-step gamma, the score
    test of the sensor pose's part alone and the growth of the residuals after that step;
    None when the data determine no extra direction."""
    base = _Score(own, columns, white, runs, lags, own_system)
    if base.dof <= 0:
        return None
    std = np.sqrt(np.diag(inverse_information(base.own_information)))[extra]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(std > 0, np.abs(base.gamma) / std, 0.0)
    moved = tuple(names[i] for i, r in zip(extra, ratio, strict=True) if r > 1.0)
    pose = pose_dof = None
    wheels = [k for k, i in enumerate(extra) if i < 3]
    if len(wheels) < len(extra):  # the sensor pose's change, beyond the wheels' change
        others = [k for k in range(len(extra)) if k not in wheels]
        mounting = _Score(np.concatenate([own, columns[:, wheels, :]], axis=1),
                          columns[:, others, :], white, runs, lags)
        if mounting.dof > 0:
            pose, pose_dof = mounting.statistic, mounting.dof
    after = white + np.matmul(base.gamma, base.rest)
    growth, growth_ratio = _growth(after, base.leverage(), z)
    threshold = chi2_quantile(FAMILY_LEVEL, base.dof)
    test = DrivingTest(name, base.statistic, base.dof, threshold,
                       float(ratio.max(initial=0.0)), moved, growth, growth_ratio, pose,
                       pose_dof, False, False)
    return replace(test, failed=fails_at(test, DRIVING_TEST_LEVEL), slipping=_slipping(test))


def fails_at(test: DrivingTest, level: float) -> bool:
    """Whether the driving test ``test`` fails the fit when the three tests are one family
    at ``level`` (each at 1 - (1 - level) / 3, Bonferroni): its change is material, and
    significant, or the mounting's part of it is (a mounting does not move with the
    driving). At DRIVING_TEST_LEVEL this is ``test.failed``; the stopping rule asks it at
    its own, stricter level (:mod:`excite.stopping`)."""
    each = (1.0 - level) / len(DRIVING)
    return bool(test.moved) and (chi2_survival(test.statistic, test.dof) < each
                                 or _mounting_moves(test, each))


def _mounting_moves(test: DrivingTest, each: float = 1.0 - FAMILY_LEVEL) -> bool:
    """Whether the score test of the sensor pose's part alone (``pose_statistic``) is
    significant at the level ``each`` (one test's; default FAMILY_LEVEL's): the mounting
    would have to change with the driving."""
    return (test.pose_statistic is not None and test.pose_dof is not None
            and chi2_survival(test.pose_statistic, test.pose_dof) < each)


def _slipping(test: DrivingTest) -> bool:
    """Whether the change is one that slip makes and a difference of effective parameters
    between kinds of driving does not: the residuals still grow with the driving, or the
    mounting changes with it."""
    return test.growth < 1.0 - FAMILY_LEVEL or _mounting_moves(test)


class _Score:
    """Rao's efficient score test of extra columns ``extra`` (3, q, N) beside the model's
    ``own`` (3, p, N), both whitened, at whitened residuals ``white`` (3, N): the extra columns
    residualised on the own (``rest``), the score s = rest . white, the statistic s' V^+ s
    over the directions the data determine (``dof``), V the information of ``rest`` or, with
    ``lags``, at least the Newey-West covariance of the per-segment shares of s within
    ``runs``; ``gamma`` the one Gauss-Newton step of the extra parameters."""

    def __init__(self, own: FloatArray, extra: FloatArray, white: FloatArray,
                 runs: NDArray[np.int64], lags: int,
                 own_system: tuple[FloatArray, FloatArray] | None = None):
        self.own_columns = own
        self.own_information, self.own_inverse = (_own_system(own) if own_system is None
                                                  else own_system)
        projection = self.own_inverse @ _gram(own, extra)
        self.rest = extra - np.matmul(projection.T, own)
        shares = (self.rest * white[:, None, :]).sum(axis=0).T  # each segment's share (N, q)
        score = shares.sum(axis=0)
        information = _gram(self.rest, self.rest)
        lam, vectors = np.linalg.eigh(information)
        basis = vectors[:, lam > max(lam[-1], 0.0) * 1e-10]  # the determined directions
        self.dof = basis.shape[1]
        self.statistic = 0.0
        self.inverse = np.linalg.pinv(information, hermitian=True)
        self.gamma = -self.inverse @ score
        if self.dof == 0:
            return
        covariance = basis.T @ information @ basis
        if lags:  # serially correlated residuals: at least the Newey-West covariance
            long_run = long_run_covariance(shares, np.eye(shares.shape[1]), runs, lags)
            covariance = at_least(covariance, basis.T @ long_run @ basis)
        projected = basis.T @ score
        self.statistic = float(projected @ np.linalg.solve(covariance, projected))

    def leverage(self) -> FloatArray:
        """Each whitened residual's leverage (3, N) in the model with the extra columns."""
        own = self.own_columns
        return ((own * np.matmul(self.own_inverse, own)).sum(axis=1)
                + (self.rest * np.matmul(self.inverse, self.rest)).sum(axis=1))


def _own_system(own: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The information (P, P) of whitened columns ``own`` (3, P, N) and its pseudo-inverse."""
    information = _gram(own, own)
    return information, np.linalg.pinv(information, hermitian=True)


def _gram(a: FloatArray, b: FloatArray) -> FloatArray:
    """sum over channels c and segments n of a[c, p, n] b[c, q, n]: (P, Q)."""
    return channel_gram(a, b).sum(axis=0)


def _growth(white: FloatArray, leverage: FloatArray, z: FloatArray
            ) -> tuple[float, FloatArray]:
    """Whether the whitened residuals (3, N) grow with the standardised driving z (N,):
    each channel's squared residuals over 1 - leverage regressed on z, Koenker's N R^2
    (chi-square(1) when their size does not depend on z); the smallest p-value times 3, and
    per channel the RMS above the median of z over that below it."""
    u = white**2 / np.maximum(1.0 - leverage, 1e-12)
    centred = u - u.mean(axis=1, keepdims=True)
    n = z.size
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = (centred @ z) ** 2 / (n * np.sum(centred**2, axis=1))  # z: mean 0, std 1
    p_values = [chi2_survival(float(n * r), 1) if np.isfinite(r) else 1.0 for r in r2]
    p_value = min(1.0, 3.0 * min(p_values))
    # above the median, or where ties make that one side, above the mean
    upper = next((side for side in (z > np.median(z), z > z.mean())
                  if side.any() and not side.all()), None)
    if upper is None:  # no two sides to compare
        return p_value, np.ones(u.shape[0])
    above = upper.astype(float)
    count = float(above.sum())
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.sqrt((u @ above) / count / ((u @ (1.0 - above)) / (z.size - count)))
    return p_value, np.where(np.isfinite(ratio), ratio, 1.0)
