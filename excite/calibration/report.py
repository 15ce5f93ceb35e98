"""The human-readable report of a :class:`~excite.calibration.result.CalibrationResult`:
presentation only (the numbers are computed where the result is built).

The report starts with what a user can act on, then the statistics:

1. ``excite calibration: N segments, loss=..., model=...``;
2. the verdict in one sentence (:func:`verdict`): calibrated (set the multipliers), not
   determined (what to drive), or the model does not fit (the reason);
3. each wheel parameter with its relative std and, given the nominal robot, how far it is from
   the nominal value in % ("1.8% smaller than nominal"); the ``diff_drive_controller``
   multipliers to set (:func:`excite.calibration.export.ros2_diff_drive_parameters`); the
   sensor mounting in words (cm ahead of or behind the axle midpoint, cm to the left or right,
   degrees turned, in the body frame of docs/conventions.md); the gross errors found, when
   any, and what was done with them (:attr:`~excite.calibration.gross_errors.GrossErrors.message`);
4. ``statistics:``, the numbers behind it (:func:`statistics`), with every noise level held
   at its floor (not found in the data, ``CalibrationResult.levels_at_floor``) printed as
   ``none``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from excite.calibration.options import MIN_RESIDUAL_DOF
from excite.core.kinematics import Params
from excite.core.models import AXLE

if TYPE_CHECKING:
    from excite.calibration.result import CalibrationResult

__all__ = ["report", "verdict", "unsafe_reason", "plain_summary", "statistics",
           "within_std"]

#: A parameter this many of its std or fewer from the nominal value is "within N std" of it.
WITHIN_STD = 2.0
_WORDS = ("left wheel radius", "right wheel radius", "wheel separation")


def unsafe_reason(result: CalibrationResult) -> str | None:
    """Why the result must not be set on a robot, in words (the model does not fit the data,
    or the data do not determine every parameter); None when it can be."""
    if not result.fit.ok:
        return f"the model does not fit the data: {result.fit.message}"
    if not result.identifiable:
        return ("the data do not determine every parameter: "
                f"{result.unidentifiable_direction or 'see the report'}")
    return None


def verdict(result: CalibrationResult, nominal: Params | None = None) -> str:
    """What to do with the result, in one sentence: the model does not fit (exit status 4),
    not determined (exit status 3), or calibrated (from too few segments to trust the
    estimated noise levels: MIN_RESIDUAL_DOF)."""
    if not result.fit.ok:
        return (f"the model does not fit the data, do not use these values: "
                f"{result.fit.message}")
    if not result.identifiable and result.sigma_estimated and result.residual_dof < 1:
        return (f"not determined ({result.unidentifiable_direction}), do not use these "
                "values: drive more, or give the sensor's noise (--sigma)")
    if not result.identifiable:
        return (f"not determined ({result.unidentifiable_direction}), do not use these "
                "values: drive so that the data determine it (turns both ways, straight "
                "runs, arcs of several radii) and calibrate again")
    if not result.converged:
        return (f"calibrated, but the solver did not converge ({result.message}): check the "
                "values before setting them")
    dof = result.residual_dof
    if result.sigma_estimated and dof < MIN_RESIDUAL_DOF:
        return (f"calibrated from few segments: the noise levels, and the std with them, rest "
                f"on {dof} residual degree{'s' if dof != 1 else ''} of freedom per channel "
                f"(at least {MIN_RESIDUAL_DOF} are needed to trust them): drive more before "
                "setting these values, or give the sensor's noise (--sigma)")
    if nominal is None:
        return ("calibrated: use these values (with the robot's nominal values, --init "
                "RL,RR,B, the report gives the diff_drive_controller multipliers to set)")
    return "calibrated: set these diff_drive_controller multipliers"


def within_std(value: float, nominal: float, std: float) -> bool:
    """Whether ``value`` is within :data:`WITHIN_STD` of its ``std`` from ``nominal``."""
    return bool(np.isfinite(std) and abs(value - nominal) <= WITHIN_STD * std)


def _parameter_line(words: str, value: float, std: float, nominal: float | None) -> str:
    spread = f"± {100 * std / value:.3g}%" if np.isfinite(std) else "undetermined"
    line = f"  {words:<19} {value:.6f} m {spread}"
    if nominal is None or not np.isfinite(std):
        return line
    change = 100 * (value - nominal) / nominal
    near = f", within {WITHIN_STD:g} std" if within_std(value, nominal, std) else ""
    if abs(change) < 0.01:
        return f"{line}: as nominal to 0.01% ({nominal:.6g} m{near})"
    how = "larger" if change > 0 else "smaller"
    return f"{line}: {abs(change):.3g}% {how} than nominal ({nominal:.6g} m{near})"


def _mounting(result: CalibrationResult) -> str:
    """The sensor's mounting in words (body frame: x forward, y left, theta
    counter-clockwise)."""
    pose = result.sensor_pose
    if pose is None:
        return "on the axle midpoint, facing forward (the axle model)"
    std = result.sensor_pose_std
    x, y, theta = pose.as_array()

    def spread(i: int, factor: float) -> str:
        if std is None:
            return ""
        return f" ± {factor * std[i]:.2g}" if np.isfinite(std[i]) else " (undetermined)"

    ahead = "ahead of" if x >= 0 else "behind"
    side = "left" if y >= 0 else "right"
    turn = "counter-clockwise" if theta >= 0 else "clockwise"
    how = "given" if std is None else "estimated"
    return (f"{100 * abs(x):.2f}{spread(0, 100)} cm {ahead} the axle midpoint, "
            f"{100 * abs(y):.2f}{spread(1, 100)} cm to the {side}, turned "
            f"{abs(math.degrees(theta)):.2f}{spread(2, math.degrees(1.0))} deg {turn} "
            f"({how})")


def plain_summary(result: CalibrationResult, nominal: Params | None = None) -> list[str]:
    """The lines a user acts on: the verdict, each wheel parameter against nominal, the
    multipliers, the sensor mounting."""
    from excite.calibration.export import ros2_diff_drive_parameters

    lines = [f"verdict: {verdict(result, nominal)}"]
    nominal_values = (None,) * 3 if nominal is None else nominal.as_array()
    for words, value, std, nom in zip(_WORDS, result.params.as_array(), result.std,
                                      nominal_values, strict=True):
        lines.append(_parameter_line(words, float(value), float(std),
                                     None if nom is None else float(nom)))
    if nominal is not None:
        parameters = ros2_diff_drive_parameters(result.params, nominal)
        multipliers = ", ".join(f"{key} {value:.6g}" for key, value in parameters.items()
                                if key.endswith("multiplier"))
        lines.append(f"  {'multipliers':<19} {multipliers} (with wheel_radius "
                     f"{parameters['wheel_radius']:.6g} m, wheel_separation "
                     f"{parameters['wheel_separation']:.6g} m)")
    lines.append(f"  {'sensor mounting':<19} {_mounting(result)}")
    gross = result.gross_errors
    if gross is not None and gross.candidates.size:
        lines.append(f"  {'gross errors':<19} {gross.message}")
    return lines


def _level(value: float, unit: str, name: str, result: CalibrationResult) -> str:
    """A noise level, or ``none`` when it sits at its floor (not found in the data)."""
    return "none" if name in result.levels_at_floor else f"{value:.3e} {unit}"


def _noise_line(result: CalibrationResult) -> str:
    sigma = ", ".join(f"{c} {_level(v, u, c, result)}"
                      for c, v, u in zip(("x", "y", "theta"), result.sigma, ("m", "m", "rad"),
                                         strict=True))
    line = (f"  noise sigma     = {sigma} "
            f"({'estimated' if result.sigma_estimated else 'given'})")
    if result.pose_sigma is not None:
        xy, theta = result.pose_sigma
        line += (f" per segment; pose samples: xy {_level(xy, 'm', 'pose_xy', result)}, "
                 f"theta {_level(theta, 'rad', 'pose_theta', result)} (shared by consecutive "
                 "segments)")
    if result.slip is not None:
        if "slip" in result.levels_at_floor:
            line += "; wheel slip none"
        else:
            line += f"; wheel slip {result.slip:.3e} rad/sqrt(s)"
            if result.slip_share is not None:
                line += f" ({100 * result.slip_share:.2g}% of a segment's wheel turn)"
    if result.timing:
        line += f"; encoder timing {1e3 * result.timing:.2g} ms"
    if result.timing_at_bound:
        line += (" (at its bound, a quarter of the encoder period: larger timing errors are "
                 "not described and the std are too narrow)")
    return line


def _inverse_or_inf(x: float) -> float:
    return 1.0 / x if x > 0 else float("inf")


def statistics(result: CalibrationResult) -> list[str]:
    """The numbers behind the verdict: every estimate with its std, the model choice,
    identifiability, the fit test, residuals, noise levels, outliers, the solver's end."""
    lines = []
    for name, value, s in zip(AXLE.names, result.params.as_array(), result.std, strict=True):
        rel = f"({100 * s / value:.3f}%)" if np.isfinite(s) else "(undetermined)"
        lines.append(f"  {name:<4}= {value:.6f} m  ± {s:.2e} m {rel}")
    if result.sensor_pose is not None:
        pose = result.sensor_pose.as_array()
        std = result.sensor_pose_std
        how = "given" if std is None else "estimated"
        for name, unit, value, i in (("x", "m", pose[0], 0), ("y", "m", pose[1], 1),
                                     ("theta", "rad", pose[2], 2)):
            spread = "" if std is None else (
                f"  ± {std[i]:.2e} {unit}" if np.isfinite(std[i]) else "  (undetermined)")
            extra = f" ({math.degrees(value):.2f} deg)" if name == "theta" else ""
            lines.append(f"  sensor {name:<6}= {value:+.6f} {unit}{extra}{spread} ({how})")
    sv = ", ".join(f"{s:.4g}" for s in result.singular_values)
    lines += [
        f"  model choice    = {result.model_choice}",
        f"  sigma_min       = {result.sigma_min:.4g}  (worst-direction relative std "
        f"{_inverse_or_inf(result.sigma_min):.3g})",
        f"  singular values = {sv};  condition number = {result.condition_number:.4g}",
        f"  identifiable    = {'yes' if result.identifiable else 'NO'}"
        + (f": {result.unidentifiable_direction}" if result.unidentifiable_direction else ""),
        f"  fit             = {'ok' if result.fit.ok else 'NO'}: {result.fit.message}",
        "  residual RMS    = x {:.3e} m, y {:.3e} m, theta {:.3e} rad".format(
            *result.rms_residual),
        _noise_line(result),
        *([] if result.gross_errors is None
          else [f"  gross errors    = {result.gross_errors.message}"]),
        f"  outliers        = {result.n_outliers}"
        + (f"; trimmed {result.n_trimmed}" if result.n_trimmed else ""),
        f"  converged       = {result.converged} after {result.iterations} iterations"
        f" ({result.message})",
    ]
    return lines


def report(result: CalibrationResult, nominal: Params | None = None) -> str:
    """The whole report (module docstring); ``nominal``: the robot's nominal wheel
    parameters (m), for the comparison in % and the multipliers."""
    lines = [f"excite calibration: {result.n_segments} segments, loss={result.loss}, "
             f"model={result.model}"]
    lines += plain_summary(result, nominal)
    agreement = result.heterogeneity  # its lines: excite.calibration.heterogeneity
    lines += [] if agreement is None else agreement.plain_lines()
    lines.append("statistics:")
    lines += statistics(result)
    lines += [] if agreement is None else agreement.summary_lines()
    return "\n".join(lines)
