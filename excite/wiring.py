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
- the heading never changes at all: the pose source measures no orientation.

A ratio counts as negative only when it is below zero beyond doubt (as unlikely as
``WIRING_Z`` normal standard errors, by the regression's Student t), so noise or slip never
trips the check on a robot wired as assumed (whose ratios are hundreds of standard errors above
zero). Each ratio is tested when both are determined, and so is the best-determined
combination of the two when it weighs both positively (spins, where it is known far better
than either ratio); driving straight determines r_R/b - r_L/b-like combinations whose sign
depends on the robot, which are not tested. Fitted anyway,
such data give plausible-looking but wrong parameters whose estimated noise levels absorb the
misfit.
"""

from __future__ import annotations

import numpy as np

from excite.data import Segments
from excite.errors import DataError

__all__ = ["WIRING_Z", "check_wiring"]

#: Standard errors below zero at which a wheel ratio counts as negative.
WIRING_Z = 5.0
#: Eigenvalues of the regression's X^T X below this fraction of the largest are null (rank).
_RANK_RTOL = 1e-12
#: A determined combination of the two ratios counts as positive-weighted when its smaller
#: weight is at least this fraction of the larger.
_SAME_SIGN = 0.1

_HINT = "check the wheel names / columns (left vs right) and signs"


def check_wiring(segments: Segments, source: str = "the data") -> None:
    """Raise :class:`~excite.errors.DataError` naming ``source`` when the heading changes
    contradict a differential drive with positive radii (see the module doc); return quietly
    when they agree or cannot tell (too few segments, no turning)."""
    from scipy.special import ndtr, stdtrit  # not at import: excite imports no scipy

    phi_L, phi_R, dtheta = segments.dphi_L, segments.dphi_R, segments.dtheta
    if len(segments) < 4:
        return
    design = np.stack([phi_R, -phi_L], axis=1)  # dtheta = design @ (r_R/b, r_L/b)
    lam, vec = np.linalg.eigh(design.T @ design)
    if lam[-1] <= 0.0:
        return
    rank = int(np.sum(lam > lam[-1] * _RANK_RTOL))
    if not np.any(dtheta != 0.0):
        if rank == 2:  # the wheels' ratio changes (the robot must turn), the heading does not
            raise DataError(f"{source}: the pose heading never changes over {len(segments)} "
                            "segments while the wheels turn at changing ratios; excite needs "
                            "the sensor's orientation (a position-only source such as UWB, GPS "
                            "or a single marker cannot be used)")
        return  # straight driving at one wheel ratio: nothing to tell
    inverse = (vec[:, -rank:] / lam[-rank:]) @ vec[:, -rank:].T  # (X^T X)^+
    ratios = inverse @ (design.T @ dtheta)
    residual = dtheta - design @ ratios
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
