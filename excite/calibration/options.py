"""What :func:`excite.calibration.pipeline.calibrate` is asked to do: its inputs checked, the
settings every fit shares, and the levels of its tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from excite.calibration.solver import Loss
from excite.calibration.wiring import check_wiring
from excite.core.arrays import FloatArray
from excite.core.information import as_sigma
from excite.core.models import SensorPose
from excite.errors import DataError
from excite.logs.segment_bounds import first_impossible
from excite.logs.segments import Segments

__all__ = ["DEFAULT_MAX_RELATIVE_STD", "MIN_RESIDUAL_DOF", "TEST_LEVEL", "CalibrationLoss",
           "FitOptions", "SensorPoseOption", "checked_inputs", "solver_loss"]

#: How the sensor pose is treated: "auto" (estimated when the data determine it and it fits
#: significantly better than the axle model), "axle", "estimate", or a known SensorPose.
SensorPoseOption = Literal["auto", "axle", "estimate"] | SensorPose
#: The loss a calibration is asked for: "auto" (least squares, with gross errors found and
#: left out, :mod:`excite.calibration.gross_errors`), "linear" (plain least squares) or
#: "huber" (the Huber loss).
CalibrationLoss = Literal["auto", "linear", "huber"]

#: Data determine the parameters when the worst-direction relative std 1/sigma_min is at most
#: this.
DEFAULT_MAX_RELATIVE_STD = 0.1
#: The fewest residual degrees of freedom per noise channel (segments less the estimated
#: parameters) on which estimated noise levels, and the std with them, are to be trusted:
#: from fewer residuals a level can be near zero by chance (a channel fitted almost exactly).
#: Below it the report says so, and the stopping rule (:mod:`excite.stopping`) never says done.
MIN_RESIDUAL_DOF = 10
#: Level of the likelihood-ratio test of the axle model against the sensor-pose model, of the
#: score test of an imposed model, of the goodness-of-fit test against given noise levels and
#: of the test of serial correlation.
TEST_LEVEL = 0.999
#: Level of the family of driving tests (:mod:`excite.calibration.slip_tests`): lower than
#: TEST_LEVEL because they are what stands between slipping data and a confident wrong answer,
#: which the estimated noise levels otherwise absorb. Their false alarm (exit 4 on a log the
#: model fits, or *not yet* for one more look of the stopping rule) costs a user a gentler
#: drive; their miss costs a calibration several std off, reported as fine.
DRIVING_TEST_LEVEL = 0.99


@dataclass(frozen=True)
class FitOptions:
    """The settings every Levenberg-Marquardt fit of one calibration shares.

    :func:`excite.calibration.pipeline.calibrate` makes them once from its arguments (its
    ``loss`` through :func:`solver_loss`) and hands them to every stage that fits.

    Attributes
    ----------
    loss : {"linear", "huber"}
        "linear": Gaussian maximum likelihood; "huber": robust to slip outliers (threshold
        :data:`excite.calibration.solver.HUBER_K` whitened standard deviations).
    max_iterations : int
        Most iterations of one fit.
    tol : float
        A fit has converged when its largest relative step is below this (relative units of
        the model's ``column_scale``), or when the Gauss-Newton step would move the estimate
        by less than :data:`excite.calibration.solver.STEP_IN_STD` of its std.
    max_relative_std : float
        Identifiability threshold on 1/sigma_min (relative std, dimensionless): relative
        directions of the parameters whose std would exceed it are not determined by the data
        and are held at their start.
    """

    loss: Loss
    max_iterations: int
    tol: float
    max_relative_std: float


def solver_loss(loss: CalibrationLoss) -> Loss:
    """The loss of every fit: "huber" for "huber", else "linear" (the gross-error screen of
    "auto" works on least-squares fits)."""
    return "huber" if loss == "huber" else "linear"


def checked_inputs(segments: Segments | ArrayLike, sigma: ArrayLike | None,
                   loss: CalibrationLoss,
                   sensor_pose: SensorPoseOption, trim: float
                   ) -> tuple[Segments, FloatArray | None]:
    """The segments (an (N, 5) array in CSV column order becomes :class:`Segments`) and the
    given noise std (sigma_x [m], sigma_y [m], sigma_theta [rad]; None: to be estimated),
    after checking the inputs in this order: at least 3 segments (DataError), the loss, the
    sensor-pose option and the trim fraction (ValueError), some wheel moves (DataError), no
    segment that no robot drives (:mod:`excite.logs.segment_bounds`, DataError), the
    wiring (:func:`excite.calibration.wiring.check_wiring`, DataError), sigma (ValueError)."""
    seg = segments if isinstance(segments, Segments) else Segments.from_array(segments)
    if len(seg) < 3:
        raise DataError(f"{len(seg)} segment(s); at least 3 are needed")
    if loss not in ("auto", "linear", "huber"):
        raise ValueError(f"loss must be 'auto', 'linear' or 'huber', got {loss!r}")
    if not (isinstance(sensor_pose, SensorPose) or sensor_pose in ("auto", "axle", "estimate")):
        raise ValueError("sensor_pose must be 'auto', 'axle', 'estimate' or a SensorPose, "
                         f"got {sensor_pose!r}")
    if not 0.0 <= trim < 0.5:
        raise ValueError(f"trim must be a fraction in [0, 0.5), got {trim}")
    if not np.any(seg.dphi_L) and not np.any(seg.dphi_R):
        raise DataError("no segment moves: every wheel increment is 0")
    timed = seg.t_start is not None and seg.t_end is not None
    impossible = first_impossible(seg.dphi_L, seg.dphi_R, seg.dx, seg.dy, seg.dtheta,
                                  seg.t_end - seg.t_start if timed else None)
    if impossible is not None:
        raise DataError(f"segment {impossible[0]}: {impossible[1]}")
    check_wiring(seg)
    return seg, None if sigma is None else as_sigma(sigma)
