"""The noise levels of segments that share pose samples, estimated with the parameters: rounds
of (estimate the levels at the fit, refit whitened) until the levels settle.

The levels and their covariance model are :mod:`excite.calibration.noise`'s; each round's
estimate is :func:`excite.calibration.reml.reml_noise`, started from the moment estimates
(:func:`excite.calibration.reml.moment_noise`) of a fit with independent per-channel noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from excite.calibration.model_fit import UNIT_SIGMA, fit_model
from excite.calibration.noise import ChainWhitener, NoiseLevels, WheelNoise, cut_from_log
from excite.calibration.options import FitOptions
from excite.calibration.reml import moment_noise, reml_noise
from excite.calibration.solver import complement
from excite.calibration.starts import Starts
from excite.core.arrays import FloatArray
from excite.core.models import SegmentModel
from excite.errors import DataError
from excite.logs.segments import Segments
from excite.logs.timeseries import tick_angle

__all__ = ["MIN_NOISE_DOF_PER_LEVEL", "NOISE_ROUNDS", "NOISE_RTOL", "EstimatedNoise",
           "estimated_noise", "predicted"]

#: Most rounds of (estimate the noise levels, refit) for segments that share pose samples.
NOISE_ROUNDS = 8
#: The noise levels have settled when no level moves by more than this fraction.
NOISE_RTOL = 0.01
#: Segments that share pose samples have their noise levels (five; seven with wheel slip and
#: encoder timing) estimated by REML from the residuals; that needs at least this many
#: residual degrees of freedom (3 N - parameters) per level. Fewer, and the levels collapse
#: to fit the few residuals.
MIN_NOISE_DOF_PER_LEVEL = 5


@dataclass(frozen=True)
class EstimatedNoise:
    """The noise model of segments that share pose samples, estimated with the parameters.

    The calibration's fits then run at unit sigma, whitened by ``whitener``
    (:class:`excite.calibration.model_fit.Fitter`), the primary model started at ``theta``.

    Attributes
    ----------
    levels : NoiseLevels
        The estimated levels: segment sigma (m, m, rad), pose-sample std (m, rad), wheel
        slip (rad / sqrt(s)) and encoder timing (s).
    whitener : ChainWhitener
        The covariance of the stacked increments at those levels (with the wheel-space
        noise of segments cut from a log, at the last round's parameters).
    theta : ndarray, shape (P,)
        The last round's parameters: the start of the final fits.
    """

    levels: NoiseLevels
    whitener: ChainWhitener
    theta: FloatArray


def estimated_noise(data: Segments, starts: Starts, sigma: FloatArray | None,
                    ticks_per_rev: float | None, options: FitOptions) -> EstimatedNoise | None:
    """The noise levels of segments that share pose samples, estimated with the primary
    model's parameters (:func:`_correlated_noise`); None when the noise std ``sigma`` is
    given or no segment shares a pose sample. DataError when the segments leave too few
    residual degrees of freedom per level (:func:`_refuse_too_few_for_noise`)."""
    if sigma is not None or data.chained is None or not data.chained.any():
        return None
    _refuse_too_few_for_noise(data, starts.start.size)
    tick = None if ticks_per_rev is None else tick_angle(ticks_per_rev)
    return _correlated_noise(starts.primary, data, starts.start, options, tick)


def _refuse_too_few_for_noise(data: Segments, n_parameters: int) -> None:
    """DataError unless the segments leave MIN_NOISE_DOF_PER_LEVEL residual degrees of freedom
    per noise level to estimate (five levels; seven for segments cut from a log, with slip
    and encoder timing)."""
    n_levels = 7 if cut_from_log(data) else 5
    dof = 3 * len(data) - n_parameters
    needed = MIN_NOISE_DOF_PER_LEVEL * n_levels
    if dof < needed:
        segments = math.ceil((needed + n_parameters) / 3)
        raise DataError(f"{len(data)} segments leave {dof} residual degrees of freedom to "
                        f"estimate {n_levels} noise levels from; at least {needed} are needed "
                        f"(about {segments} segments for {n_parameters} parameters): a longer "
                        "log, a shorter window, or given noise levels (sigma, --sigma)")


def _correlated_noise(model: SegmentModel, data: Segments, start: FloatArray,
                      options: FitOptions, tick: float | None) -> EstimatedNoise:
    """Noise levels of segments that share pose samples, estimated with the parameters: a fit
    with independent per-channel noise gives the moment estimates, then rounds of (restricted
    maximum likelihood of the levels at the fit, linearised; refit whitened) until the levels
    settle. Segments cut from a log (with sub-steps) also carry wheel-space noise: slip (its
    level estimated with the others, started where it explains the heading's segment noise),
    encoder timing (kept when the data show it) and, with ``tick`` (rad), encoder
    quantization; its geometry follows the parameters from round to round."""
    mf = fit_model(model, data, start, None, options)
    floor = mf.problem.sigma_floor
    levels = moment_noise(data, mf.fit.ev.residual, model.size, floor)
    in_wheels = cut_from_log(data)

    built: dict[bytes, WheelNoise | None] = {}  # the last geometry, by its parameters

    def wheels_at(theta: FloatArray) -> WheelNoise | None:
        key = np.asarray(theta, dtype=float).tobytes()
        if key not in built:  # a fit that did not move keeps its geometry
            built.clear()
            built[key] = WheelNoise.of(model, data, theta, tick) if in_wheels else None
        return built[key]

    wheels = wheels_at(mf.theta)
    if wheels is not None:
        heading_unit = math.sqrt(max(float(np.mean(wheels.slip[:, 2, 2])), 1e-300))
        levels = NoiseLevels(levels.sigma, levels.pose, float(levels.sigma[2]) / heading_unit)
    for _ in range(NOISE_ROUNDS):
        ev = mf.unwhitened  # at the last levels' mean of the measured positions
        free = complement(mf.weak)
        geometry = predicted(model, data, mf.theta)
        new = reml_noise(geometry, ev.raw, np.einsum("cpn,pm->cmn", ev.jac, free), levels,
                         floor, wheels=wheels)
        settled = (new.close_to(levels, NOISE_RTOL) if wheels is None else
                   new.close_to(levels, NOISE_RTOL, wheels.scale, wheels.timing_scale))
        levels = new
        mf = fit_model(model, data, mf.theta, UNIT_SIGMA, options,
                       ChainWhitener(geometry, levels, wheels))
        wheels = wheels_at(mf.theta)
        if settled:
            break
    whitener = ChainWhitener(predicted(model, data, mf.theta), levels, wheels)
    return EstimatedNoise(levels, whitener, mf.theta)


def predicted(model: SegmentModel, data: Segments, theta: FloatArray) -> Segments:
    """``data`` with their increments (dx, dy, dtheta) replaced by the model's at ``theta``:
    where the chain covariance is linearised (:func:`excite.calibration.noise.chain_band`).
    The measured increments would tilt each heading lever arm along the very pose noise it
    weighs, a bias of the order sigma_theta^2 in the common scale of the wheels."""
    if data.sub_dphi_L is not None and data.sub_dphi_R is not None:
        increments, _ = model.evaluate(data.sub_dphi_L, data.sub_dphi_R, theta,
                                       jacobian=False, substeps=True)
    else:
        increments, _ = model.evaluate(data.dphi_L, data.dphi_R, theta, jacobian=False)
    return replace(data, dx=increments[0], dy=increments[1], dtheta=increments[2])
