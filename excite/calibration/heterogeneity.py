"""Do r_L, r_R and b agree between logs, and between kinds of motion within one log?
(docs/method.md, "Logs that disagree").

A robot's effective wheel parameters depend on how it is driven (the wheels scrub in tight
turns), and files given together may come from different robots. The groups: several
inputs, each calibrated alone with its own noise levels (:func:`across_logs`); or one
input's segments by the kind of motion (:mod:`excite.calibration.motion_kinds`). Only r_L,
r_R, b are compared: the sensor mounting is shared by every group (between inputs, each
input's estimate is combined under one mounting by generalised least squares, so its
uncertainty is carried into the wheels'), after a test that the inputs' own mountings agree
(:class:`MountingTest`, at MOUNTING_LEVEL): mountings that differ fail the fit, and each
input's wheels are then compared with its own mounting. The test: Cochran's Q of the groups'
estimates, chi-square with 3 (G - 1) degrees of freedom under agreement (F with estimated
noise levels), at LEVEL (:mod:`excite.stats.meta_analysis`). When they disagree (:func:`applied`),
with ``heterogeneity="random"``, r_L, r_R, b and their covariance cover the spread under the
random-effects model (Knapp-Hartung's adjustment for few groups): between logs, the
random-effects pool; within one log, the common fit of the log's mix of driving, with the
kinds' spread carried through its weights added to its covariance (the kinds' segments are
scattered through the log and share pose samples, so the kinds alone hold a small part of
the log's information, which the random-effects pool would give away). With ``"common"``
the common fit fails its fit test. Between logs the pool is also used when p is below
POOLING_LEVEL without a disagreement said (the fit test unchanged); the words say which
parameters differ and how, and name the groups that disagree most.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from excite.calibration.options import SensorPoseOption
from excite.core.kinematics import Params
from excite.core.models import AXLE, SENSOR_POSE
from excite.errors import DataError
from excite.logs.segments import Segments
from excite.stats.meta_analysis import leave_one_out, pairwise_z, pool

if TYPE_CHECKING:
    from excite.calibration.result import CalibrationResult, FitTest

__all__ = ["LEVEL", "POOLING_LEVEL", "MOUNTING_LEVEL", "HeterogeneityOption", "Group",
           "Heterogeneity", "MountingTest", "Comparison", "check_option", "assessed",
           "across_logs", "applied"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
#: What to do about groups that disagree: "random" (test; when they disagree, std that cover
#: the spread under the random-effects model, module docstring), "common" (test; keep common
#: parameters, which then fail the fit) or "off".
HeterogeneityOption = Literal["random", "common", "off"]
#: The level of the heterogeneity test.
LEVEL = 0.05
#: Between logs, r_L, r_R, b are the random-effects pool whenever the test's p-value is below
#: this, even when the logs are not called different (p >= LEVEL): a pretest at the test's
#: own level leaves differences below its power out of the std, so that pooled estimates of
#: independent sets of logs disagree more often than their std say. 0.25 is Bancroft's pretest
#: level for "sometimes pool" estimators (Ann. Math. Stat. 1944).
POOLING_LEVEL = 0.25
_NAMES = AXLE.names
#: Two groups' estimates of a parameter this many combined std apart are named as differing.
_NAMED_Z = 2.0
#: The level of the test that the logs' sensor mountings agree (their own estimates, Cochran's
#: Q as for r_L, r_R, b): one mounting is the model, so a disagreement fails the fit, at the
#: fit tests' strictness (99.9%).
MOUNTING_LEVEL = 0.001


@dataclass(frozen=True)
class Group:
    """One group's own estimate: ``name`` (an input's name, or a kind of motion),
    ``params`` (3,) r_L, r_R, b (m), ``std`` (3,) (m), ``n_segments``."""

    name: str
    params: FloatArray
    std: FloatArray
    n_segments: int

    def to_dict(self) -> dict:
        return {"name": self.name,
                "params": dict(zip(_NAMES, map(float, self.params), strict=True)),
                "std": dict(zip(_NAMES, map(float, self.std), strict=True)),
                "n_segments": self.n_segments}


@dataclass(frozen=True)
class Heterogeneity:
    """The test of agreement between groups (module docstring).

    by: "logs" or "motion" (kinds of motion within one log). detected: whether the groups
    disagree beyond their std (p_value < LEVEL). statistic: Cochran's Q (dimensionless),
    chi-square with ``dof`` degrees of freedom under agreement; p_value: its tail probability
    (of Q / dof under F with estimated noise levels). groups: each group's
    estimate. between_std (3,): the std of r_L, r_R, b between groups (m, the square root of
    the diagonal of the method-of-moments between-group covariance). pooling: what the
    result's r_L, r_R, b are: "common" (the common fit: the groups agree, or common
    parameters were forced) or "random effects" (they disagree; or, between logs, p below
    POOLING_LEVEL). most_different: the groups that disagree
    most (the largest distance from the others' common estimate; both with two groups);
    empty when they agree. differences: which parameters differ and how, in words; empty when
    they agree. random_params (3,), random_covariance (3, 3): the random-effects pool (m,
    m^2; Knapp-Hartung's covariance for few groups), what a disagreement between logs
    reports. spread_covariance (3, 3): what the spread between kinds of motion adds to the
    common fit's covariance as an estimate of the mean over kinds, what a disagreement
    within one log reports (m^2; A (I (x) T) A', A the common fit's weights of the groups,
    adjusted for few groups: :mod:`excite.stats.meta_analysis`; zero between logs).
    group_covariance (3G, 3G): the
    joint covariance of the groups' estimates (m^2, group-major; the groups of one log are
    correlated). group_fits: between logs, each log's own fit test (ok, message), in the
    order of ``groups``; empty for kinds of motion. mounting: between logs whose sensor
    mounting is estimated, the test that their mountings agree (:class:`MountingTest`);
    None otherwise.
    """

    by: str
    detected: bool
    statistic: float
    dof: int
    p_value: float
    groups: tuple[Group, ...]
    between_std: FloatArray
    pooling: str
    most_different: tuple[str, ...]
    differences: str
    random_params: FloatArray
    random_covariance: FloatArray
    spread_covariance: FloatArray
    group_covariance: FloatArray
    group_fits: tuple[tuple[bool, str], ...] = ()
    mounting: MountingTest | None = None

    @property
    def what(self) -> str:
        """The groups in words ("the 3 logs", "the kinds of motion")."""
        return f"the {len(self.groups)} logs" if self.by == "logs" else "the kinds of motion"

    def to_dict(self) -> dict:
        """The ``heterogeneity`` object of ``excite calibrate --json``."""
        return {"detected": self.detected, "by": self.by, "statistic": self.statistic,
                "dof": self.dof, "p_value": self.p_value, "level": LEVEL,
                "pooling": self.pooling, "pooling_level": POOLING_LEVEL,
                "between_std": dict(zip(_NAMES, map(float, self.between_std), strict=True)),
                "most_different": list(self.most_different),
                "differences": self.differences,
                "groups": [group.to_dict() for group in self.groups],
                "mounting": None if self.mounting is None else self.mounting.to_dict()}

    def plain_lines(self) -> list[str]:
        """The report's line among what a user acts on: empty when the groups agree."""
        if not self.detected:
            return []
        how = ("the values above do not fit them all" if self.pooling != "random effects"
               else "the values above pool them, their std cover the spread" if self.by == "logs"
               else "the values above fit the log's mix of driving, their std cover the spread")
        return [f"  {'disagreement':<19} r_L, r_R, b differ between {self.what}: "
                f"{self.differences}; {how}"]

    def summary_lines(self) -> list[str]:
        """The report's lines among the statistics: the verdict, then each group's
        estimate."""
        numbers = f"Q {self.statistic:.3g}, {self.dof} dof, p {_p_text(self.p_value)}"
        if not self.detected:
            lines = [f"  agreement       = yes: {self.what} agree within their std "
                     f"({numbers})"]
            if self.pooling == "random effects":
                lines.append(f"                    p below {POOLING_LEVEL:g}: r_L, r_R, b above "
                             "pool them with random effects, their std covering a spread "
                             "the test cannot rule out")
        else:
            lines = [f"  agreement       = NO: r_L, r_R, b differ between {self.what} beyond "
                     f"their std ({numbers}); most different: {', '.join(self.most_different)}",
                     f"                    {self.differences}"]
            if self.pooling == "random effects":
                spread = ", ".join(f"{n} {1e3 * s:.2g} mm"
                                   for n, s in zip(_NAMES, self.between_std, strict=True))
                what = ("pool them with their spread" if self.by == "logs" else
                        "fit the log's mix of driving, with the kinds' spread")
                lines.append(f"                    r_L, r_R, b above {what} (random effects; "
                             f"between-group std {spread}): their std cover it; "
                             "--common-params forces one set")
            else:
                lines.append("                    common parameters forced (--common-params): "
                             "they do not fit every group")
        for group in self.groups:
            values = ", ".join(f"{n} {_millimetres(v, s)}"
                               for n, v, s in zip(_NAMES, group.params, group.std, strict=True))
            lines.append(f"    {group.name}: {values} ({group.n_segments} segments)")
        return lines


@dataclass(frozen=True)
class MountingTest:
    """Whether the logs' sensor mountings agree: each log's own estimate (l_x, l_y in m,
    l_theta in rad) against their common one, Cochran's Q (``statistic``, ``dof`` 3 (G - 1),
    ``p_value`` as for r_L, r_R, b) at MOUNTING_LEVEL. ``differ``: p_value < MOUNTING_LEVEL.
    ``words``: each log's mounting in words (theta in [-180, 180) deg), and with more than two
    logs the one most different from the others, when they differ (else "")."""

    statistic: float
    dof: int
    p_value: float
    differ: bool
    words: str

    def to_dict(self) -> dict:
        return {"differ": self.differ, "statistic": self.statistic, "dof": self.dof,
                "p_value": self.p_value, "level": MOUNTING_LEVEL}

    def fit_message(self) -> str:
        """The fit line's reason when the mountings differ."""
        return (f"the sensor mounting differs between the logs ({self.words}; Q "
                f"{self.statistic:.3g}, {self.dof} dof, p {_p_text(self.p_value)}): one "
                "mounting does not fit them (the sensor, or its rigid body, was moved or "
                "defined anew between them); calibrate each log alone")


def _p_text(p_value: float) -> str:
    """A p-value in the report: two significant digits, or "< 1e-15" below that."""
    return "< 1e-15" if p_value < 1e-15 else f"{p_value:.2g}"


def check_option(option: str) -> None:
    """ValueError unless ``option`` is a :data:`HeterogeneityOption`."""
    if option not in ("random", "common", "off"):
        raise ValueError(f"heterogeneity must be 'random', 'common' or 'off', got {option!r}")


@dataclass(frozen=True)
class Comparison:
    """Groups' estimates of r_L, r_R, b in relative units about ``center`` (3,) (m), with
    ``scale`` (3,) (m per relative unit): ``estimates`` (G, 3), ``covariance`` (3G, 3G);
    ``residual_dof``: the degrees of freedom of the noise levels behind it (inf: given)."""

    by: str
    names: tuple[str, ...]
    counts: tuple[int, ...]
    center: FloatArray
    scale: FloatArray
    estimates: FloatArray
    covariance: FloatArray
    residual_dof: float


def _relative(result: CalibrationResult, middle: FloatArray
              ) -> tuple[FloatArray, FloatArray] | None:
    """A log's estimate (P,) and covariance (P, P) in relative units about the parameters
    ``middle`` (P,) (the pooled fit's); None when the log does not determine them alone."""
    if not result.identifiable or not np.all(np.isfinite(result.full_covariance)):
        return None
    theta = _theta(result)
    if theta.size != middle.size:
        return None
    model = SENSOR_POSE if theta.size == 6 else AXLE
    scale = model.column_scale(middle)
    difference = theta - middle
    if theta.size == 6:
        difference[5] = math.remainder(difference[5], 2 * math.pi)
    return difference / scale, result.full_covariance / np.outer(scale, scale)


def _theta(result: CalibrationResult) -> FloatArray:
    """Every estimated parameter of a result, in the order of its full covariance."""
    wheels = result.params.as_array()
    if len(result.parameter_names) == 3:
        return wheels
    assert result.sensor_pose is not None
    return np.concatenate([wheels, result.sensor_pose.as_array()])


def _shared_mounting(estimates: list[FloatArray], covariances: list[FloatArray]
                     ) -> tuple[FloatArray, FloatArray]:
    """The logs' r_L, r_R, b (G, 3) and their joint covariance (3G, 3G) under one sensor
    mounting: generalised least squares of each log's (wheels, mounting) estimate with the
    wheels per log and the mounting shared (relative units)."""
    count = len(estimates)
    y = np.concatenate(estimates)
    weight = np.zeros((6 * count, 6 * count))
    design = np.zeros((6 * count, 3 * count + 3))
    for i, covariance in enumerate(covariances):
        weight[6 * i:6 * i + 6, 6 * i:6 * i + 6] = np.linalg.inv(covariance)
        design[6 * i:6 * i + 3, 3 * i:3 * i + 3] = np.eye(3)
        design[6 * i + 3:6 * i + 6, 3 * count:] = np.eye(3)
    joint = np.linalg.inv(design.T @ weight @ design)
    joint = 0.5 * (joint + joint.T)
    beta = joint @ (design.T @ weight @ y)
    return beta[:3 * count].reshape(count, 3), joint[:3 * count, :3 * count]


def across_logs(parts: Sequence[tuple[str, Segments]], pooled: CalibrationResult,
                fit_alone: Callable[[Segments, SensorPoseOption], CalibrationResult],
                note: Callable[[str], None], sensor_pose: SensorPoseOption = "auto"
                ) -> Heterogeneity | None:
    """The test between the inputs ``parts`` (name, segments) of the pooled fit ``pooled``:
    each calibrated alone by ``fit_alone(segments, sensor_pose)`` with the pooled fit's
    model (its sensor pose estimated again, or the given one, or the axle). A log that cannot
    be calibrated alone or does not determine the parameters alone is left out, with a note;
    None (with a note) when fewer than two logs are left. When the pooled fit does not
    determine the parameters, only the mountings are tested (mountings that differ can be
    why; each log calibrated alone with its mounting estimated, unless ``sensor_pose``, the
    pooled fit's option, gave it or the axle): None unless they differ."""
    if pooled.identifiable:
        pose: SensorPoseOption = (
            "axle" if pooled.model == "axle"
            else "estimate" if len(pooled.parameter_names) == 6
            else pooled.sensor_pose if pooled.sensor_pose is not None else "axle")
        middle: FloatArray | None = _theta(pooled)
    elif sensor_pose in ("auto", "estimate"):
        pose, middle = "estimate", None  # about the first log that determines them
    else:
        return None
    names, counts, estimates, covariances, fits, dofs = [], [], [], [], [], []
    for name, segments in parts:
        try:
            own = fit_alone(segments, pose)
            if middle is None and own.identifiable:
                middle = _theta(own)
            alone = None if middle is None else _relative(own, middle)
        except DataError as exc:
            note(f"{name}: left out of the logs' agreement test (cannot be calibrated alone: "
                 f"{exc})")
            continue
        if alone is None:
            note(f"{name}: left out of the logs' agreement test (it does not determine the "
                 "parameters alone)")
            continue
        names.append(name)
        fits.append((own.fit.ok, own.fit.message))
        dofs.append(3 * own.n_segments - len(own.parameter_names) if own.sigma_estimated
                    else math.inf)
        counts.append(len(segments))
        estimates.append(alone[0])
        covariances.append(alone[1])
    if len(names) < 2:
        note("the logs were not tested for agreement: fewer than two of them determine the "
             "parameters alone")
        return None
    assert middle is not None  # a log determined it
    mounting = None
    if estimates[0].size == 6:
        mounting = _mounting_test(names, estimates, covariances, middle, min(dofs))
    if not pooled.identifiable and (mounting is None or not mounting.differ):
        return None  # nothing to compare with; but mountings that differ can be why
    if mounting is not None and not mounting.differ:
        wheels, covariance = _shared_mounting(estimates, covariances)
    else:  # each log's wheels with its own mounting (the axle, or mountings that differ)
        wheels = np.stack([e[:3] for e in estimates])
        covariance = np.zeros((3 * len(names), 3 * len(names)))
        for i, c in enumerate(covariances):
            covariance[3 * i:3 * i + 3, 3 * i:3 * i + 3] = c[:3, :3]
    center = middle[:3]
    comparison = Comparison("logs", tuple(names), tuple(counts), center,
                             AXLE.column_scale(center), wheels, covariance, min(dofs))
    return replace(assessed(comparison), group_fits=tuple(fits), mounting=mounting)


def _mounting_test(names: list[str], estimates: list[FloatArray],
                   covariances: list[FloatArray], middle: FloatArray,
                   residual_dof: float) -> MountingTest:
    """The test that the logs' mountings agree (:class:`MountingTest`), from each log's own
    (wheels, mounting) estimate and covariance in the relative units about the pooled fit's
    parameters ``middle`` (6,)."""
    mountings = np.stack([e[3:] for e in estimates])
    covariance = np.zeros((3 * len(names), 3 * len(names)))
    for i, c in enumerate(covariances):
        covariance[3 * i:3 * i + 3, 3 * i:3 * i + 3] = c[3:, 3:]
    pooled = pool(mountings, covariance, residual_dof)
    differ = pooled.p_value < MOUNTING_LEVEL
    words = ""
    if differ:
        scale = SENSOR_POSE.column_scale(middle)[3:]
        values = middle[3:] + mountings * scale
        std = np.sqrt(np.einsum("gii->gi", np.stack([c[3:, 3:] for c in covariances]))) * scale
        values[:, 2] = np.remainder(values[:, 2] + math.pi, 2 * math.pi) - math.pi
        words = "; ".join(
            f"{name}: x {_with_std(100 * v[0], 100 * e[0], 'cm')}, y "
            f"{_with_std(100 * v[1], 100 * e[1], 'cm')}, theta "
            f"{_with_std(math.degrees(v[2]), math.degrees(e[2]), 'deg')}"
            for name, v, e in zip(names, values, std, strict=True))
        if len(names) > 2:
            odd = names[int(np.argmax(leave_one_out(mountings, covariance)))]
            words += f"; most different: {odd}"
    return MountingTest(pooled.statistic, pooled.dof, pooled.p_value, bool(differ), words)


def _millimetres(value: float, std: float) -> str:
    """``value ± std`` in mm, to the std's second significant digit."""
    return _with_std(1e3 * value, 1e3 * std, "mm")


def _with_std(value: float, std: float, unit: str) -> str:
    """``value ± std unit``, to the std's second significant digit."""
    digits = max(0, 1 - math.floor(math.log10(max(std, 1e-12))))
    return f"{value:.{digits}f} ± {std:.{digits}f} {unit}"


def _differences(c: Comparison, params: FloatArray, std: FloatArray) -> str:
    """Which parameters differ and how, in words: for each parameter whose most distant two
    groups are at least _NAMED_Z combined std apart (at least the most distant one), the two
    estimates; then the likely cause."""
    z = np.abs(pairwise_z(c.estimates, c.covariance))
    largest = z.reshape(-1, 3).max(axis=0)
    order = [j for j in np.argsort(-largest) if largest[j] >= _NAMED_Z] or [
        int(np.argmax(largest))]
    prefix = "" if c.by == "logs" else "the "
    parts = []
    for j in order:
        g, h = np.unravel_index(np.argmax(z[:, :, j]), z.shape[:2])
        low, high = (g, h) if params[g, j] <= params[h, j] else (h, g)
        parts.append(f"{_NAMES[j]} from {prefix}{c.names[low]} "
                     f"{_millimetres(params[low, j], std[low, j])}, from {prefix}"
                     f"{c.names[high]} {_millimetres(params[high, j], std[high, j])} "
                     f"({largest[j]:.2g} combined std apart)")
    differing = {_NAMES[j] for j in order}
    cause = ("the effective track depends on how the robot turns (wheel scrub)" if "b" in
             differing else "the effective wheel radii depend on the driving (load, speed, "
             "floor)")
    if c.by == "logs":
        cause += "; or the logs are of different robots, wheels or floors"
    return (f"{'; '.join(parts)}: {cause}; calibrate on driving like the robot's everyday "
            "driving")


def assessed(c: Comparison) -> Heterogeneity:
    """The test and the pools of a comparison (module docstring)."""
    pooled = pool(c.estimates, c.covariance, c.residual_dof)
    detected = pooled.p_value < LEVEL
    scale2 = np.outer(c.scale, c.scale)
    params = c.center + c.estimates * c.scale
    block = np.einsum("gigj->gij", c.covariance.reshape(len(c.names), 3, len(c.names), 3))
    std = np.sqrt(np.einsum("gii->gi", block)) * c.scale
    groups = tuple(Group(n, p, s, k)
                   for n, p, s, k in zip(c.names, params, std, c.counts, strict=True))
    most: tuple[str, ...] = ()
    words = ""
    if detected:
        distance = leave_one_out(c.estimates, c.covariance)
        most = (c.names if len(c.names) == 2
                else (c.names[int(np.argmax(distance))],))
        words = _differences(c, params, std)
    pooled_randomly = detected or (c.by == "logs" and pooled.p_value < POOLING_LEVEL)
    return Heterogeneity(
        by=c.by, detected=bool(detected), statistic=pooled.statistic, dof=pooled.dof,
        p_value=pooled.p_value, groups=groups,
        between_std=np.sqrt(np.diag(pooled.between)) * c.scale,
        pooling="random effects" if pooled_randomly else "common", most_different=most,
        differences=words, random_params=c.center + pooled.random_mean * c.scale,
        random_covariance=pooled.adjusted_covariance * scale2,
        spread_covariance=(np.zeros((3, 3)) if c.by == "logs"
                           else pooled.fixed_spread * scale2),
        group_covariance=c.covariance * np.tile(scale2, (len(c.names), len(c.names))))


def _carried_over(full: FloatArray, wheels: FloatArray) -> FloatArray:
    """The joint covariance ``full`` (P, P) with its r_L, r_R, b block replaced by
    ``wheels`` (3, 3), the correlations with the rest carried over: the congruence
    diag(S, I) full diag(S, I)^T with S = wheels^(1/2) A^(-1/2), A the old block (positive
    semi-definite whenever ``full`` is)."""
    def root(a: FloatArray, power: float) -> FloatArray:
        lam, vec = np.linalg.eigh(0.5 * (a + a.T))
        return (vec * np.maximum(lam, 1e-300) ** power) @ vec.T

    s = root(wheels, 0.5) @ root(full[:3, :3], -0.5)
    transform = np.eye(full.shape[0])
    transform[:3, :3] = s
    out = transform @ full @ transform.T
    out[:3, :3] = wheels
    return 0.5 * (out + out.T)


def _own_fits(fit: FitTest, heterogeneity: Heterogeneity) -> FitTest:
    """The fit test of logs that disagree: their own fits' (the common fit's test does not
    apply to parameters that differ between them); unchanged for kinds of motion."""
    if not heterogeneity.group_fits:
        return fit
    for group, (ok, message) in zip(heterogeneity.groups, heterogeneity.group_fits,
                                    strict=True):
        if not ok:
            return replace(fit, ok=False, message=f"{group.name} alone: {message}")
    return replace(fit, ok=True, message=(
        f"each of {heterogeneity.what} fits alone (their own fit tests); the common fit's "
        "test does not apply to logs whose parameters differ"))


def applied(result: CalibrationResult, heterogeneity: Heterogeneity | None,
            option: HeterogeneityOption) -> CalibrationResult:
    """The result with the test attached: unchanged without one; with ``option`` "random"
    and the pooling "random effects" (detected, or between logs p below POOLING_LEVEL):
    between logs r_L, r_R, b and their covariance from the random-effects pool, within one
    log the common fit's with ``spread_covariance`` added (module docstring); the sensor
    pose and the rest kept, the fit test the logs' own when they disagree. With "common" and
    ``detected``, the common fit failing its fit test. Logs whose sensor mountings differ
    fail the fit test whatever the option (:meth:`MountingTest.fit_message`)."""
    if heterogeneity is None:
        return result
    if heterogeneity.mounting is not None and heterogeneity.mounting.differ:
        fit = replace(result.fit, ok=False, message=heterogeneity.mounting.fit_message())
        return replace(_applied(result, heterogeneity, option), fit=fit)
    return _applied(result, heterogeneity, option)


def _applied(result: CalibrationResult, heterogeneity: Heterogeneity,
             option: HeterogeneityOption) -> CalibrationResult:
    """:func:`applied` but for mountings that differ."""
    if not heterogeneity.detected and (option == "common"
                                       or heterogeneity.pooling != "random effects"):
        return replace(result, heterogeneity=replace(heterogeneity, pooling="common"))
    if option == "common":
        heterogeneity = replace(heterogeneity, pooling="common")
        fit = replace(result.fit, ok=False, message=(
            f"r_L, r_R, b differ between {heterogeneity.what} beyond their std (Q "
            f"{heterogeneity.statistic:.3g}, {heterogeneity.dof} dof, p "
            f"{_p_text(heterogeneity.p_value)}): common parameters (--common-params) do not fit "
            f"them; {heterogeneity.differences}"))
        return replace(result, fit=fit, heterogeneity=heterogeneity)
    if heterogeneity.by == "logs":
        params, covariance = Params(*heterogeneity.random_params), heterogeneity.random_covariance
    else:
        params, covariance = result.params, result.covariance + heterogeneity.spread_covariance
    full = _carried_over(result.full_covariance, covariance)
    fit = _own_fits(result.fit, heterogeneity) if heterogeneity.detected else result.fit
    return replace(result, params=params, covariance=covariance, fit=fit,
                   std=np.sqrt(np.diag(covariance)), full_covariance=full,
                   heterogeneity=heterogeneity)
