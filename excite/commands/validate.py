"""``excite validate``: does the calibration help? Dead-reckon held-out logs with the nominal
and the calibrated robot and compare both with the external poses
(:mod:`excite.validation.dead_reckoning`
holds the method and the metrics)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from excite.commands.args import (
    PARAMS_VALUES,
    POSE_VALUES,
    UsageError,
    check_not_an_input,
    params_arg,
    plausible_params,
    sensor_pose_arg,
)
from excite.commands.exit_status import EXIT_OK, EXIT_USAGE, EXIT_WORSE
from excite.commands.logs import LOG_FILES, add_log_options
from excite.core.plausible import implausible_mounting
from excite.validation.verdict import MARGIN

#: The image formats --plot writes, by its suffix.
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg")

#: What ``excite validate --help`` says the command does.
DESCRIPTION = """Dead-reckon each log's encoders (the calibration's model: arcs between encoder
samples with the change of curvature, from the log's first external pose) with the nominal
and with the calibrated robot, and report per log and overall (mean over logs, ratio of the
means): end-point position error (m), end-point heading error (rad), RMS path error (m) and the
ratio calibrated / nominal; UMBmark's E_max,syst (m) when a log is a bidirectional square.
Validation uses every pose sample (no segmentation). The report ends with a verdict per log
and overall: better, no better or worse than nominal."""

#: The epilog of ``excite validate --help``: the verdict's rule and the exit statuses.
EPILOG = f"""Verdict: on the RMS path error, calibrated / nominal at most 1/{MARGIN:g} is better, at
least {MARGIN:g} worse, in between no better (overall: the ratio of the means over the logs).
Exit status: {EXIT_OK} when the calibrated robot is better or no better than the nominal one
overall, {EXIT_WORSE} when it is worse, {EXIT_USAGE} for bad input."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    val = sub.add_parser("validate", help="does the calibration help? dead-reckon held-out logs",
                         description=DESCRIPTION, epilog=EPILOG)
    val.add_argument("logs", nargs="+", metavar="LOG",
                     help=f"{LOG_FILES}, not used for the calibration")
    val.add_argument("--params", required=True, metavar="RESULT.json",
                     help="the calibration (required): the output of excite calibrate --json "
                     "(params, sensor_pose, and optionally nominal)")
    val.add_argument("--nominal", metavar=PARAMS_VALUES,
                     help="nominal wheel radii and separation (m); default: the params file's "
                     "\"nominal\" key")
    val.add_argument("--nominal-sensor-pose", metavar=POSE_VALUES,
                     help="the nominal robot's sensor pose in the body frame (m, m, rad); "
                     "default: the calibrated one, so that the comparison measures the wheel "
                     "calibration")
    val.add_argument("--plot", metavar="OUT.png",
                     help="write an overlay of the measured, nominal and calibrated paths, "
                     "as .png, .pdf, .svg or .jpg by the suffix (needs the sim extra: "
                     "matplotlib); default: no plot")
    val.add_argument("--json", action="store_true",
                     help="print one JSON object instead of the report")
    add_log_options(val, segmentation=False)
    val.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from excite.calibration.logs import validate_logs
    from excite.commands.logs import log_options, print_note
    from excite.validation.dead_reckoning import read_params_file

    result_file = read_params_file(args.params)
    used = [("params", result_file.params)] + ([] if args.nominal else
                                               [("nominal", result_file.nominal)])
    for key, params in used:
        if params is not None:  # as --init and --nominal are checked
            values = tuple(float(v) for v in params.as_array())
            plausible_params(values, ",".join(f"{v:g}" for v in values),
                             f'{args.params}: "{key}"')
    pose = result_file.sensor_pose
    what = None if pose is None else implausible_mounting(pose.x, pose.y)
    if what is not None:
        raise UsageError(f'{args.params}: "sensor_pose": {what} is implausible')
    if args.plot is not None:
        if Path(args.plot).suffix.lower() not in PLOT_SUFFIXES:
            raise UsageError(f"--plot {args.plot!r}: name a {', '.join(PLOT_SUFFIXES)} file "
                             "(the suffix sets the format)")
        check_not_an_input(args.plot, [*args.logs, args.params], "--plot")
    nominal_params = (params_arg(args.nominal, "--nominal") if args.nominal
                      else result_file.nominal)
    if nominal_params is None:
        raise UsageError(f"{args.params}: no \"nominal\" parameters; give --nominal "
                         f"{PARAMS_VALUES} (m)")
    nominal_pose = result_file.sensor_pose
    if args.nominal_sensor_pose:
        nominal_pose = sensor_pose_arg(args.nominal_sensor_pose, "--nominal-sensor-pose")
    calibrated = (result_file.params, result_file.sensor_pose)
    result = validate_logs(args.logs, calibrated, (nominal_params, nominal_pose),
                           log_options(args), on_note=print_note).result
    if args.plot is not None:
        from excite.validation.plot import plot_validation

        try:
            plot_validation(result, args.plot)
        except OSError as exc:
            raise UsageError(f"cannot write {args.plot}: {exc.strerror or exc}") from None
    if args.json:
        print(json.dumps(result.to_dict(), indent=2))
    else:
        print(result.summary())
        if args.plot is not None:
            print(f"wrote the path overlay to {args.plot}")
    return EXIT_WORSE if result.verdict == "worse" else EXIT_OK
