"""``excite calibrate``: estimate r_L, r_R, b (and the sensor pose) from segment files."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, get_args

from excite.calibration.options import CalibrationLoss
from excite.commands.args import (
    PARAMS_VALUES,
    POSE_VALUES,
    SIGMA_VALUES,
    UsageError,
    check_not_an_input,
    check_output_file,
    fraction_arg,
    params_arg,
    sensor_pose_arg,
    sigma_arg,
)
from excite.commands.exit_status import EXIT_OK, calibration_status
from excite.commands.logs import LOG_FILES, add_log_options
from excite.commands.options import add_result_options, add_target_options

if TYPE_CHECKING:
    from excite.calibration.logs import LogCalibration
    from excite.calibration.result import CalibrationResult
    from excite.core.kinematics import Params
    from excite.stopping import StopDecision

#: What ``excite calibrate --help`` says the command does.
DESCRIPTION = """Estimate the wheel radii r_L, r_R and the wheel separation b (m), and the external
sensor's pose on the robot, by weighted maximum likelihood from the encoder increments and the
sensor's poses; report them with their uncertainty, whether the data determine them (exit status
3 if not) and whether the model fits (exit status 4 if not)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    cal = sub.add_parser("calibrate", help="estimate r_L, r_R, b and the sensor pose from logs",
                         description=DESCRIPTION)
    cal.add_argument("files", nargs="+", metavar="FILE",
                     help=f"segment CSV, Censi tuple file (*.tuple), {LOG_FILES}; all of them "
                     "are one data set")
    cal.add_argument("--sigma", metavar=SIGMA_VALUES,
                     help="noise std of dx, dy (m) and dtheta (rad); default: estimated")
    cal.add_argument("--loss", choices=get_args(CalibrationLoss), default="auto",
                     help="auto (default): Gaussian maximum likelihood, with gross errors "
                     "(residuals far beyond the noise level) found, reported and left out; "
                     "linear: Gaussian maximum likelihood on every segment; huber: robust "
                     "to slip outliers (Huber loss on the whitened residuals)")
    cal.add_argument("--init", metavar=PARAMS_VALUES,
                     help="initial guess / nominal robot: wheel radii and separation (m); "
                     "default: found from the data")
    cal.add_argument("--sensor-pose", default="auto", metavar=f"auto|axle|estimate|{POSE_VALUES}",
                     help="pose sensor mounting: auto (default: estimated when the data "
                     "determine it and it fits significantly better), axle, estimate, or a "
                     "known pose in the body frame (m, m, rad)")
    cal.add_argument("--trim", type=fraction_arg, default=0.0, metavar="FRACTION",
                     help="drop this fraction (below 0.5) of segments with the largest "
                     "residuals, 1%% per pass with a refit after each (default %(default)g)")
    add_result_options(cal, "--init")
    cal.add_argument("--holdout", type=fraction_arg, default=0.0, metavar="FRACTION",
                     help="keep back this fraction (below 0.5) of the logs (whole logs, the "
                     "last ones; at least one) and validate the calibration on them against "
                     "the nominal robot (--init) as excite validate does (default %(default)g: "
                     "none)")
    cal.add_argument("--common-params", action="store_true",
                     help="one set of r_L, r_R, b for every input (and kind of motion) even when "
                     "they disagree beyond their std; the fit then fails (exit status 4). "
                     "Default: when they disagree, report std that cover the spread (random "
                     "effects)")
    add_target_options(cal, judged="calibration")
    add_log_options(cal)
    cal.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from excite.calibration.export import static_transform_command
    from excite.calibration.logs import calibrate_logs
    from excite.commands.logs import log_options, print_note

    if args.force_yaml and not args.ros2_yaml:
        raise UsageError("--force-yaml needs --ros2-yaml OUT.yaml")
    if args.ros2_yaml:
        check_output_file(Path(args.ros2_yaml))
        check_not_an_input(args.ros2_yaml, args.files, "--ros2-yaml")
    if args.target_confidence is not None and args.target is None:
        raise UsageError("--target-confidence needs --target")
    sigma = sigma_arg(args.sigma) if args.sigma else None
    initial = params_arg(args.init) if args.init else None
    sensor_pose = sensor_pose_arg(args.sensor_pose)
    calibration = calibrate_logs(args.files, log_options(args), initial=initial, sigma=sigma,
                                 loss=args.loss, sensor_pose=sensor_pose, trim=args.trim,
                                 holdout=args.holdout, on_note=print_note,
                                 heterogeneity="common" if args.common_params else "random")
    result, validation = calibration.result, calibration.holdout
    _refuse_implausible(args.files, result, calibration, initial)
    estimated_pose = result.sensor_pose if result.sensor_pose_std is not None else None
    done = None if args.target is None else _judged(args, calibration)
    status = calibration_status(result)
    if args.json:
        report = result.to_dict()
        if done is not None:
            report["target"] = {"value": args.target, "confidence": done[0],
                                "decision": done[1].to_dict()}
        report["inputs"] = [part.describe() for part in calibration.parts]
        report["notes"] = list(calibration.notes)
        if initial is not None:
            report["nominal"] = dict(zip(("r_L", "r_R", "b"), initial.as_array().tolist(),
                                         strict=True))
        if validation is not None:
            report["holdout"] = validation.result.to_dict()
        print(json.dumps(report, indent=2))
    else:
        for part in calibration.parts:
            print(part.describe())
        if status != EXIT_OK:
            for line in _clock_doubts(calibration, args.max_time_offset):
                print(line)
        print(result.summary(initial))
        if estimated_pose is not None and status == EXIT_OK:  # as --ros2-yaml: usable only
            print(f"  sensor transform: {static_transform_command(estimated_pose)}")
        if done is not None:
            print(_done_line(args.target, *done))
        if validation is not None:
            print(f"\nheld-out logs ({len(validation.result.logs)}), nominal (--init) vs "
                  "calibrated:")
            print(validation.result.summary())
    if args.ros2_yaml:
        export_yaml(args, result, initial, status)
    return status


def _clock_doubts(calibration: LogCalibration, max_offset: float) -> list[str]:
    """For a calibration that failed: each log whose clocks the data say are offset while 0
    was used (beyond the search range, or a best lag the test of a zero offset did not
    confirm), first in the report, since that alone spoils the fit whatever the driving."""
    from excite.logs.time_offset import untested_offset

    lines = []
    for part in calibration.parts:
        log = part.log
        if log is None or log.offset_source != "default":
            continue
        if log.hint is not None:
            lines.append(f"clocks first: {log.name}: 0 was used for the clock offset, but "
                         f"{log.hint.text()}; an offset alone can make the fit fail or "
                         "determine nothing, whatever the driving")
            continue
        best = untested_offset(log.series, max_offset)
        if best is not None:
            lines.append(f"clocks first: {log.name}: 0 was used for the clock offset, but the "
                         f"wheel rates explain the heading rate best at {best:+.4f} s (the "
                         "test of a zero offset did not reject it, which it may miss on this "
                         "driving); an offset alone can make the fit fail: try --time-offset "
                         "estimate")
    return lines


def _refuse_implausible(files: list[str], result: CalibrationResult,
                        calibration: LogCalibration, initial: Params | None) -> None:
    """UsageError when the data determine wheel parameters no real robot has (a log in other
    units than excite reads), or wheel radii far from the nominal ones (``initial``; wheel
    angles in other units or behind a gearbox), naming the likely units, or that the robot
    never turned."""
    from excite.core.plausible import far_from_nominal, implausible, log_unit_hint

    values = result.params.as_array()
    what = implausible(*values) if result.identifiable else None
    if what is None and initial is not None and result.identifiable:
        far = far_from_nominal((values[0], values[1]), (initial.r_L, initial.r_R))
        if far is not None:
            raise UsageError(f"{', '.join(files)}: the calibration gives {far}")
    if what is None:
        return
    if not any(part.segments.dtheta.any() for part in calibration.parts):
        count = sum(len(part.segments) for part in calibration.parts)
        raise UsageError(f"{', '.join(files)}: the robot never turned (the pose heading never "
                         f"changes over {count} segments), so nothing determines the wheel "
                         "separation; drive turns (spins, arcs)")
    hint = log_unit_hint(*values) or ("positions in m, headings and wheel angles in rad? "
                                      "docs/formats.md")
    raise UsageError(f"{', '.join(files)}: the calibration gives {what}, which no real "
                     f"robot has: {hint}")


def _judged(args: argparse.Namespace, calibration: LogCalibration
            ) -> tuple[float, StopDecision]:
    """--target: the confidence and the stopping rule's decision on the calibration."""
    from excite.logs.segments import Segments
    from excite.stopping import DEFAULT_CONFIDENCE, StoppingRule

    confidence = (DEFAULT_CONFIDENCE if args.target_confidence is None
                  else args.target_confidence)
    segments = Segments.concatenate([part.segments for part in calibration.parts])
    return confidence, StoppingRule(args.target, confidence).judge(calibration.result,
                                                                   segments)


def _done_line(target: float, confidence: float, decision: StopDecision) -> str:
    """The report's line for --target: done, or not yet with how much more driving."""
    head = f"target {target:.3g} at {confidence:.0%}: "
    if decision.done:
        return f"{head}done: {decision.reason}"
    more = ""
    if math.isfinite(decision.segments_to_go):
        seconds = ("" if decision.seconds_to_go is None
                   else f" (about {decision.seconds_to_go:.0f} s)")
        more = (f"; about {decision.segments_to_go:.0f} more segments{seconds} of driving like "
                "this would get there")
    return f"{head}not yet: {decision.reason}{more}"


def export_yaml(args: argparse.Namespace, result: CalibrationResult, initial: Params | None,
                status: int) -> None:
    """--ros2-yaml: written when the calibration succeeded (exit status 0); otherwise only
    with --force-yaml, marked unsafe with the reason, else a note says it was not written
    (``args``: ros2_yaml, force_yaml, json)."""
    from excite.calibration.export import write_ros2_yaml
    from excite.calibration.report import unsafe_reason
    from excite.commands.logs import print_note

    estimated_pose = result.sensor_pose if result.sensor_pose_std is not None else None

    reason = unsafe_reason(result)
    if reason is not None and not args.force_yaml:
        print_note(f"{args.ros2_yaml} not written (exit status {status}): {reason}; "
                   "--force-yaml writes it anyway, marked unsafe")
        return
    unsafe = None if reason is None else (f"{reason} (exit status {status}; written only "
                                          "because of --force-yaml)")
    try:
        write_ros2_yaml(args.ros2_yaml, result.params, nominal=initial,
                        sensor_pose=estimated_pose, unsafe=unsafe)
    except OSError as exc:
        raise UsageError(f"cannot write {args.ros2_yaml}: {exc.strerror}") from None
    if not args.json:
        print(f"wrote ROS 2 diff_drive_controller parameters to {args.ros2_yaml}"
              + ("" if unsafe is None else ", marked unsafe"))
