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
zero). When only one combination of the ratios is determined (spins only, or straight only),
it is tested only if it weighs both positively (spins): driving straight determines
r_R/b - r_L/b-like combinations whose sign depends on the robot. Fitted anyway,
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
#: Largest condition number of the 2x2 regression for which the two ratios are told apart.
_MAX_CONDITION = 1e8
#: A determined combination of the two ratios counts as positive-weighted when its smaller
#: weight is at least this fraction of the larger.
_SAME_SIGN = 0.1

_HINT = "check the wheel names / columns (left vs right) and signs"


def check_wiring(segments: Segments, source: str = "the data") -> None:
    """Raise :class:`~excite.errors.DataError` naming ``source`` when the heading changes
    contradict a differential drive with positive radii (see the module doc); return quietly
    when they agree or cannot tell (too few segments, no turning)."""
    phi_L, phi_R, dtheta = segments.dphi_L, segments.dphi_R, segments.dtheta
    moved = np.any(phi_L != 0.0) or np.any(phi_R != 0.0)
    if moved and not np.any(dtheta != 0.0):
        raise DataError(f"{source}: the pose heading never changes over {len(segments)} "
                        "segments while the wheels turn; excite needs the sensor's orientation "
                        "(a position-only source such as UWB, GPS or a single marker cannot "
                        "be used)")
    if len(segments) < 4:
        return
    design = np.stack([phi_R, -phi_L], axis=1)  # dtheta = design @ (r_R/b, r_L/b)
    lam, vec = np.linalg.eigh(design.T @ design)
    if lam[-1] <= 0.0:
        return
    if lam[0] > lam[-1] / _MAX_CONDITION:
        ratios, below = _regression(design, dtheta)
        right, left = below
        if right and left:
            raise DataError(f"{source}: the heading turns against the wheels (r_R/b "
                            f"{ratios[0]:.3g}, r_L/b {ratios[1]:.3g}, both negative): the left "
                            "and right wheels look swapped, or both run backwards, or the pose "
                            f"frame turns clockwise; {_HINT}")
        if right or left:
            side, name, ratio = (("right", "r_R", ratios[0]) if right
                                 else ("left", "r_L", ratios[1]))
            raise DataError(f"{source}: the {side} wheel's angle runs backwards ({name}/b "
                            f"{ratio:.3g} < 0 from the heading changes): its sign looks "
                            f"reversed; {_HINT}")
        return
    # One combination u . (r_R/b, r_L/b) is determined. With u's components of one sign (e.g.
    # spins, u ~ (1, 1)) it is positive for any robot; otherwise (e.g. driving straight, u ~
    # (1, -1)) its sign says nothing about the wiring.
    u = vec[:, -1] * np.sign(vec[:, -1].sum())
    if u.min() > _SAME_SIGN * u.max():
        rate, below = _regression(design @ u[:, None], dtheta)
        if below[0]:
            raise DataError(f"{source}: the heading turns against the wheels (it turns "
                            f"{rate[0]:.3g} rad per rad the wheels turn apart, < 0): the left and "
                            "right wheels look swapped, or both run backwards, or the pose frame "
                            f"turns clockwise; {_HINT}")


def _regression(design: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares coefficients of y ~ design, and which are negative beyond doubt: a
    t-statistic (coefficient / standard error from the residuals) below the Student-t
    quantile whose one-sided probability is that of WIRING_Z normal standard errors."""
    from scipy.stats import norm, t

    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    dof = len(y) - design.shape[1]
    residual = y - design @ coef
    se = np.sqrt(float(residual @ residual) / dof
                 * np.diag(np.linalg.inv(design.T @ design)))
    limit = float(t.isf(norm.sf(WIRING_Z), dof))
    return coef, coef < -limit * se
