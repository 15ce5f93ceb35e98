"""Is the data wired the way the model assumes? A check before any fit.

A rigid body turns by the same angle at every point, so wherever the pose sensor sits, its
heading change obeys dtheta_k = (r_R/b) dphi_R,k - (r_L/b) dphi_L,k (plus noise) with both
ratios positive. Their least-squares estimates (a, c) from the heading changes alone therefore
tell, before any fit and whatever the sensor pose, when the inputs break the model's
conventions (body x forward, y left, counter-clockwise heading, wheel angles increasing when
the robot drives forward):

- a < 0 and c < 0: the heading turns against the wheels: left and right swapped, both wheels'
  signs reversed, or a clockwise (upside-down) pose frame;
- exactly one negative: that wheel's angle runs backwards (a motor mounted mirrored and not
  flipped by the driver);
- the heading never changes at all: the pose source measures no orientation;
- both ratios above MAX_RADIUS_TO_TRACK beyond doubt: no differential drive turns that fast
  (its wheels are smaller than its track): most often headings in degrees.

A ratio counts as negative only when it is below zero beyond doubt (as unlikely as
``WIRING_Z`` normal standard errors, by the regression's Student t), so noise or slip never
trips the check on a robot wired as assumed (whose ratios are hundreds of standard errors above
zero). Each ratio is tested when both are determined, and so is the best-determined
combination of the two when it weighs both positively (spins, where it is known far better
than either ratio); driving straight determines r_R/b - r_L/b-like combinations whose sign
depends on the robot, which are not tested. Fitted anyway,
such data give plausible-looking but wrong parameters whose estimated noise levels absorb the
misfit.

The same regression tells when the poses are not external at all: heading changes that the
wheel increments explain exactly (to ``DERIVED_RTOL`` of their size; a real sensor's heading
noise is at least ~1e-5 of a segment's turn) were computed from the wheel angles, as wheel
odometry (``/odom``, TF ``odom -> base_link``) is. Such poses give back the parameters the
odometry was computed with, with a tiny std (:func:`check_pose_source`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from excite.core.kinematics import MAX_RADIUS_TO_TRACK
from excite.errors import DataError
from excite.logs.segments import Segments

__all__ = ["DERIVED_RTOL", "WIRING_Z", "check_pose_source",
           "check_wiring"]

#: Standard errors below zero at which a wheel ratio counts as negative.
WIRING_Z = 5.0
#: Eigenvalues of the regression's X^T X below this fraction of the largest are null (rank).
_RANK_RTOL = 1e-12
#: A determined combination of the two ratios counts as positive-weighted when its smaller
#: weight is at least this fraction of the larger.
_SAME_SIGN = 0.1

#: Heading changes explained by the wheel increments to this fraction of their RMS come from
#: the wheel angles, not from an external sensor.
DERIVED_RTOL = 1e-7

_HINT = "check the wheel names / columns (left vs right) and signs"


class _Fit(NamedTuple):
    """The least-squares fit of dtheta_k = a dphi_R,k - c dphi_L,k."""

    design: np.ndarray  # X (N, 2): dtheta = X @ (a, c)
    lam: np.ndarray  # eigenvalues of X^T X, ascending
    vec: np.ndarray  # their eigenvectors (columns)
    rank: int
    inverse: np.ndarray  # (X^T X)^+
    ratios: np.ndarray  # (a, c) = (r_R/b, r_L/b)
    residual: np.ndarray  # (N,) rad


def _regression(segments: Segments) -> _Fit | None:
    """The fit of the heading changes on the wheel increments, or None when the wheels never
    turn."""
    phi_L, phi_R, dtheta = segments.dphi_L, segments.dphi_R, segments.dtheta
    design = np.stack([phi_R, -phi_L], axis=1)  # dtheta = design @ (r_R/b, r_L/b)
    lam, vec = np.linalg.eigh(design.T @ design)
    if lam[-1] <= 0.0:
        return None
    rank = int(np.sum(lam > lam[-1] * _RANK_RTOL))
    inverse = (vec[:, -rank:] / lam[-rank:]) @ vec[:, -rank:].T  # (X^T X)^+
    ratios = inverse @ (design.T @ dtheta)
    return _Fit(design, lam, vec, rank, inverse, ratios, dtheta - design @ ratios)


def check_pose_source(segments: Segments, source: str = "the data",
                      nominal: tuple[float, float, float] | None = None) -> str | None:
    """A one-line note when the heading changes are an exact linear function of the wheel
    increments (to DERIVED_RTOL of their RMS, at least 4 segments, the robot turning at
    changing wheel ratios): poses computed from these wheel angles (wheel odometry), or
    simulated ones with exact encoder angles; None otherwise.

    nominal: the robot (r_L, r_R, b; m) the user starts from. When the exact ratios are its
    r_R/b and r_L/b (to 1e-6), the poses are its dead reckoning and cannot calibrate it:
    :class:`~excite.errors.DataError` naming ``source``."""
    if len(segments) < 4 or not np.any(segments.dtheta != 0.0):
        return None
    fit = _regression(segments)
    if fit is None or fit.rank < 2:
        return None
    ratios, residual = fit.ratios, fit.residual
    rms = float(np.sqrt(np.mean(residual**2)))
    if rms > DERIVED_RTOL * float(np.sqrt(np.mean(segments.dtheta**2))):
        return None
    what = (f"the pose headings follow the wheel angles exactly (RMS residual {rms:.2g} rad "
            f"over {len(segments)} segments, r_R/b {ratios[0]:.9g}, r_L/b {ratios[1]:.9g})")
    if nominal is not None:
        r_L, r_R, b = nominal
        if np.allclose(ratios, (r_R / b, r_L / b), rtol=1e-6, atol=0.0):
            raise DataError(f"{source}: {what}, with the nominal robot's ratios: the poses are "
                            "its dead reckoning (wheel odometry, or a noise-free kinematic "
                            "simulation of this very robot), which gives back the nominal "
                            "parameters; use an external pose source (motion capture, a scan "
                            "matcher), not /odom or odom -> base_link")
    return (f"{source}: {what}: poses computed from these encoders (wheel odometry such as "
            "/odom or odom -> base_link) give back the parameters they were computed with, "
            "whatever the robot's true ones; an external pose source is needed (simulated "
            "ground truth with exact encoder angles also fits exactly)")


def check_wiring(segments: Segments, source: str = "the data") -> None:
    """Raise :class:`~excite.errors.DataError` naming ``source`` when the heading changes
    contradict a differential drive with positive radii (see the module doc); return quietly
    when they agree or cannot tell (too few segments, no turning)."""
    from scipy.special import ndtr, stdtrit  # not at import: excite imports no scipy

    dtheta = segments.dtheta
    if len(segments) < 4:
        return
    fit = _regression(segments)
    if fit is None:
        return
    design, lam, vec, rank, inverse, ratios, residual = fit
    if not np.any(dtheta != 0.0):
        if rank == 2:  # the wheels' ratio changes (the robot must turn), the heading does not
            raise DataError(f"{source}: the pose heading never changes over {len(segments)} "
                            "segments while the wheels turn at changing ratios; excite needs "
                            "the sensor's orientation (a position-only source such as UWB, GPS "
                            "or a single marker cannot be used)")
        return  # straight driving at one wheel ratio: nothing to tell
    dof = len(segments) - rank
    variance = float(residual @ residual) / dof
    limit = float(stdtrit(dof, ndtr(-WIRING_Z)))  # < 0: the one-sided Student-t quantile
    wrapped = (" (or dtheta is wrapped: segment increments must be continuous)"
               if np.any(np.abs(dtheta) > 0.5 * np.pi) else "")
    swapped = ("the left and right wheels look swapped, or both run backwards, or the pose "
               f"frame turns clockwise{wrapped}; {_HINT}")
    # Each ratio on its own (when both are determined): below, or above, zero beyond doubt.
    se = np.sqrt(variance * np.diag(inverse))
    below = ratios < limit * se if rank == 2 else np.zeros(2, dtype=bool)
    above = ratios > -limit * se if rank == 2 else np.zeros(2, dtype=bool)
    # The best-determined combination u . (r_R/b, r_L/b) (spins: u ~ (1, 1)), far better known
    # than either ratio when the wheels mostly turn opposite ways. With u's components of one
    # sign it is positive for any robot; otherwise (driving straight, u ~ (1, -1)) its sign
    # says nothing about the wiring.
    u = vec[:, -1] * np.sign(vec[:, -1].sum())
    turn = float(u @ ratios)
    against = (u.min() > _SAME_SIGN * u.max()
               and turn < limit * np.sqrt(variance / lam[-1]))
    if below.all():
        raise DataError(f"{source}: the heading turns against the wheels (r_R/b "
                        f"{ratios[0]:.3g}, r_L/b {ratios[1]:.3g}, both negative): {swapped}")
    if below.any() and (above.any() or not against):
        side, name, ratio = (("right", "r_R", ratios[0]) if below[0]
                             else ("left", "r_L", ratios[1]))
        raise DataError(f"{source}: the {side} wheel's angle runs backwards ({name}/b "
                        f"{ratio:.3g} < 0 from the heading changes): its sign looks "
                        f"reversed{wrapped}; {_HINT}")
    if against:
        raise DataError(f"{source}: the heading turns against the wheels (it turns "
                        f"{turn:.3g} rad per rad the wheels turn apart, < 0): {swapped}")
    if rank == 2 and np.all(ratios - MAX_RADIUS_TO_TRACK > -limit * se):
        raise DataError(f"{source}: the heading turns {ratios[0]:.3g} and {ratios[1]:.3g} rad "
                        "per radian of the right and left wheel (r_R/b, r_L/b), more than any "
                        f"differential drive (r/b < {MAX_RADIUS_TO_TRACK:g}: wheels smaller "
                        "than the track): headings in degrees, or wheel angles in "
                        "revolutions? (theta and the wheel angles are in rad)")
