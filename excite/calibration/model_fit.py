"""One segment model fitted to one data set, and the verdict on what the data determine.

* :func:`fit_model`: Levenberg-Marquardt from a start; relative directions the data do not
  determine (relative std above ``max_relative_std``) are then held at the start instead of
  drifting to chase noise, judged where the fit ends (a first fit can end where the
  information is weak while the data determine every direction at the estimate the held fit
  reaches: fitted free from there).
* :class:`Fitter`: the fits of one calibration, all on the same data under the same noise
  model (given or estimated per-channel sigma, or the whitener of correlated noise).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from excite.calibration.noise import ChainWhitener
from excite.calibration.options import FitOptions
from excite.calibration.solver import Evaluation, Fit, Problem, levenberg_marquardt
from excite.core.models import SegmentModel
from excite.logs.segments import Segments

__all__ = ["UNIT_SIGMA", "ModelFit", "Fitter", "fit_model", "weak_directions"]

FloatArray = NDArray[np.float64]
#: The per-channel sigma of a whitened fit (the whitener carries the noise levels).
UNIT_SIGMA = np.ones(3)


@dataclass
class ModelFit:
    """A fitted model on one data set: the Levenberg-Marquardt outcome and the verdict on
    what the data determine.

    Attributes
    ----------
    model : SegmentModel
        The model fitted.
    problem : Problem
        The data, the model and the whitener (None: independent segments).
    fit : Fit
        The solver's outcome at the estimate.
    weak : ndarray, shape (P, k)
        Orthonormal relative directions of the parameters the data do not determine (held at
        the start); k = 0 when the data determine every direction.
    """

    model: SegmentModel
    problem: Problem
    fit: Fit
    weak: FloatArray

    @property
    def theta(self) -> FloatArray:
        """The estimate (P,): r_L, r_R, b (m) and the model's sensor pose (m, m, rad)."""
        return self.fit.theta

    @property
    def identifiable(self) -> bool:
        """Whether the data determine every direction."""
        return self.weak.shape[1] == 0

    @cached_property
    def unwhitened(self) -> Evaluation:
        """The evaluation at the fit, not whitened: raw residuals and relative Jacobian rows
        (the driving test and the wandering heading error whiten or weight them their own
        way)."""
        if self.problem.whitener is None:  # the fit's own evaluation is not whitened
            return self.fit.ev
        return self.problem.evaluate(self.theta, whiten=False)

    @property
    def channel_std(self) -> FloatArray:
        """The noise level per channel the fit implies: its sigma, or with correlated noise
        (whitened, sigma = 1) the residual RMS (m, m, rad)."""
        if self.problem.whitener is None:
            return self.fit.sigma
        return np.sqrt(np.mean(self.fit.ev.residual**2, axis=1))


def fit_model(model: SegmentModel, seg: Segments, start: FloatArray, sigma: FloatArray | None,
              options: FitOptions, whitener: ChainWhitener | None = None) -> ModelFit:
    """LM from ``start``; directions the data cannot determine are then held at the start
    instead of drifting to chase noise, unless the data determine every direction at the
    estimate the held fit reaches and at the free fit from there (module docstring).
    ``sigma``: the per-channel noise std (m, m, rad), None to estimate it with the
    parameters; with a whitener, sigma must be ones."""
    max_relative_std = options.max_relative_std
    problem = Problem(model, seg, whitener)
    determined = 1.0 / max_relative_std
    fit = levenberg_marquardt(problem, start, sigma, options.loss, options.max_iterations,
                              options.tol, determined=determined)
    weak = weak_directions(fit.system.information, max_relative_std)
    if weak.shape[1]:
        refit = levenberg_marquardt(problem, start, fit.sigma, options.loss,
                                    options.max_iterations, options.tol, frozen=weak,
                                    determined=determined)
        refit.iterations += fit.iterations
        fit = refit
        if not weak_directions(fit.system.information, max_relative_std).shape[1]:
            # the data determine every direction at the estimate the held fit reached (the
            # first fit ended where they did not): fitted free from there, unless the free
            # fit ends where they do not again
            free = levenberg_marquardt(problem, fit.theta, fit.sigma, options.loss,
                                       options.max_iterations, options.tol,
                                       determined=determined)
            if not weak_directions(free.system.information, max_relative_std).shape[1]:
                free.iterations += fit.iterations
                fit, weak = free, weak[:, :0]
    return ModelFit(model, problem, fit, weak)


def weak_directions(information: FloatArray, max_relative_std: float) -> FloatArray:
    """Orthonormal relative directions (P, k) a relative information (P, P) does not
    determine (relative std above ``max_relative_std``): the calibration's identifiability
    rule."""
    lam, vec = np.linalg.eigh(information)
    return vec[:, lam * max_relative_std**2 < 1.0]


@dataclass(frozen=True)
class Fitter:
    """The fits of one calibration: every model on the same data under the same noise model.

    Attributes
    ----------
    data : Segments
        The segments fitted (after trimming).
    sigma : ndarray, shape (3,), or None
        The per-channel noise std of every fit (m, m, rad): the given one, UNIT_SIGMA with a
        whitener, or None (estimated with each fit's parameters).
    whitener : ChainWhitener or None
        The covariance of segments that share pose samples, at the estimated noise levels.
    options : FitOptions
        The settings every fit shares.
    """

    data: Segments
    sigma: FloatArray | None
    whitener: ChainWhitener | None
    options: FitOptions

    def fit(self, model: SegmentModel, start: FloatArray) -> ModelFit:
        """``model`` fitted from ``start`` (:func:`fit_model`)."""
        return fit_model(model, self.data, start, self.sigma, self.options, self.whitener)
