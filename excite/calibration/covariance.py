"""The covariance the result reports, in relative units: the chosen fit's inverse Fisher
information, widened for noise levels estimated from the same data (the Kenward-Roger
covariance, :func:`_estimated_levels`), or under a wandering heading error of the pose
samples when the fit test found one (:func:`excite.calibration.wander.wander_covariance`),
and widened to the Newey-West covariance for serially correlated residuals
(:func:`excite.stats.autocorrelation.long_run_covariance`); the fit test's message says what
was done.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from excite.calibration.model_fit import Fitter, ModelFit
from excite.calibration.noise import ChainWhitener, LevelBands, stacked
from excite.calibration.options import TEST_LEVEL
from excite.calibration.reml import level_floors
from excite.calibration.reml_search import RestrictedDeviance
from excite.calibration.result import FitTest
from excite.calibration.wander import wander_covariance
from excite.core.information import inverse_information
from excite.core.models import SENSOR_POSE
from excite.stats.autocorrelation import at_least, long_run_covariance, runs_of

__all__ = ["reported_covariance"]

FloatArray = NDArray[np.float64]


def reported_covariance(chosen: ModelFit, test: FitTest, fitter: Fitter
                        ) -> tuple[FloatArray, FitTest]:
    """The relative covariance (P, P) of the chosen fit's parameters and the fit test with
    the message saying how it was adjusted: the inverse information, under the wandering
    heading error of ``test.heading_wander`` (:func:`_wandering`) or widened for the
    estimated noise levels (:func:`_estimated_levels`), then widened for serial correlation
    (:func:`_long_run`)."""
    data = fitter.data
    inverse = inverse_information(chosen.fit.system.information)
    relative, test = _wandering(chosen, inverse, test, fitter.whitener)
    if test.heading_wander is None:
        relative = _estimated_levels(chosen, relative, fitter.whitener)
    return _long_run(chosen, inverse, relative, test, runs_of(data.chained, len(data)))


#: A level counts as estimated (not held at its floor) above this multiple of its floor.
ABOVE_FLOOR = 2.0


def _estimated_levels(mf: ModelFit, covariance: FloatArray, whitener: ChainWhitener | None
                      ) -> FloatArray:
    """The relative covariance of a fit whose whitener's noise levels were estimated from
    the same residuals (by restricted maximum likelihood, :mod:`excite.calibration.reml`):
    Kenward and Roger's Phi + 2 Lambda
    (:meth:`excite.calibration.reml_search.RestrictedDeviance.estimated_levels_term`), over
    the levels above their floors. Phi alone treats the levels as known, and in short logs
    (tens of segments) the truth then falls outside the 95% ellipse about twice as often as
    it should. Unchanged without estimated levels or when a direction is undetermined."""
    if whitener is None or whitener.levels is None or whitener.geometry is None:
        return covariance
    if not np.all(np.isfinite(covariance)):
        return covariance
    levels = whitener.levels.vector(with_wheels=whitener.wheels is not None)
    free = levels > ABOVE_FLOOR * level_floors(mf.problem.sigma_floor, whitener.wheels)
    if not free.any():
        return covariance
    ev = mf.unwhitened
    deviance = RestrictedDeviance(LevelBands(whitener.geometry, whitener.wheels, levels.size),
                                  stacked(ev.raw, ev.jac))
    term = deviance.estimated_levels_term(np.log(np.maximum(levels, 1e-300)), free)
    return covariance + 2.0 * term


def _wandering(mf: ModelFit, covariance: FloatArray, test: FitTest,
               whitener: ChainWhitener | None) -> tuple[FloatArray, FitTest]:
    """The relative covariance of the fit when the pose heading error wanders
    (``test.heading_wander``, :func:`excite.calibration.wander.wander_covariance`), and the
    message saying so; unchanged without one or when a direction is undetermined."""
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
    assert whitener.geometry is not None
    wider = wander_covariance(whitener.geometry, whitener, mf.unwhitened.jac, covariance,
                              wander)
    why = (" (the sensor's mounting angle carries the log's mean heading error)"
           if mf.model is SENSOR_POSE else "")
    return wider, replace(test, message=f"{found}: the std are the fit's under a model with "
                          f"it{why}")


def _serially_correlated(test: FitTest) -> bool:
    lb = test.serial_correlation
    return lb is not None and lb.p_value < 1.0 - TEST_LEVEL


def _long_run(mf: ModelFit, inverse: FloatArray, covariance: FloatArray, test: FitTest,
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
