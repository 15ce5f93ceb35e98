"""``excite calibrate``: estimate r_L, r_R, b (and the sensor pose) from segment files."""

from __future__ import annotations

import argparse
import json
import sys

from excite.commands.args import (
    UsageError,
    fraction_arg,
    params_arg,
    sensor_pose_arg,
    sigma_arg,
)
from excite.commands.logs import Input, add_log_options
from excite.logs.segments import MIN_SEGMENTS

EXIT_OK, EXIT_UNIDENTIFIABLE, EXIT_MISFIT = 0, 3, 4


def add_parser(sub: argparse._SubParsersAction) -> None:
    cal = sub.add_parser("calibrate", help="estimate r_L, r_R, b (and the sensor pose) from "
                         "segment files, time-series logs or ROS bags (one data set)")
    cal.add_argument("files", nargs="+", metavar="FILE",
                     help="segment CSV, Censi tuple file (*.tuple), time-series CSV (or a pair "
                     "of stream CSVs) or ROS bag")
    cal.add_argument("--json", action="store_true", help="print one JSON object")
    cal.add_argument("--sigma", metavar="SX,SY,STH",
                     help="noise std of dx, dy (m) and dtheta (rad); default: estimated")
    cal.add_argument("--loss", choices=("linear", "huber"), default="linear")
    cal.add_argument("--init", metavar="RL,RR,B",
                     help="initial guess / nominal robot in meters; default: found from data")
    cal.add_argument("--sensor-pose", default="auto", metavar="auto|axle|estimate|X,Y,THETA",
                     help="pose sensor mounting: auto (default: estimated when the data "
                     "determine it and it fits significantly better), axle, estimate, or a "
                     "known pose in the body frame (m, m, rad)")
    cal.add_argument("--trim", type=fraction_arg, default=0.0, metavar="FRACTION",
                     help="drop this fraction of segments with the largest residuals "
                     "(1%% per pass)")
    cal.add_argument("--ros2-yaml", metavar="OUT.yaml",
                     help="write diff_drive_controller parameters (nominal from --init) and "
                     "the sensor's static transform when estimated")
    cal.add_argument("--holdout", type=fraction_arg, default=0.0, metavar="FRACTION",
                     help="keep back this fraction of the logs (whole logs, the last ones; at "
                     "least one) and validate the calibration on them against the nominal "
                     "robot (--init) as excite validate does")
    add_log_options(cal)
    cal.set_defaults(handler=run)


def _split_holdout(inputs: list[Input], fraction: float) -> tuple[list[Input], list[Input]]:
    """(inputs to calibrate on, logs kept back): the last round(fraction * logs) logs, >= 1."""
    if not fraction:
        return inputs, []
    logs = [source for source in inputs if source.kind != "segments"]
    if len(logs) < 2:
        raise UsageError("--holdout keeps back whole logs: give at least 2 time-series logs "
                         "or bags")
    count = min(max(1, round(fraction * len(logs))), len(logs) - 1)
    held = logs[-count:]
    return [source for source in inputs if source not in held], held


def run(args: argparse.Namespace) -> int:
    from excite.calibration.export import static_transform_command, write_ros2_yaml
    from excite.calibration.pipeline import calibrate
    from excite.calibration.wiring import check_pose_source, check_wiring
    from excite.commands.logs import group_inputs, read_log, segment_inputs
    from excite.logs.segments import Segments

    sigma = sigma_arg(args.sigma) if args.sigma else None
    initial = params_arg(args.init) if args.init else None
    sensor_pose = sensor_pose_arg(args.sensor_pose)
    if args.holdout and initial is None:
        raise UsageError("--holdout compares with the nominal robot: give --init RL,RR,B (m)")
    used, held = _split_holdout(group_inputs(args.files), args.holdout)
    parts = segment_inputs(args, used)
    start = None if initial is None else tuple(initial.as_array().tolist())
    for part in parts:
        check_wiring(part.segments, part.source.name)
        note = (None if part.log is None  # a segment file: most often made, not recorded
                else check_pose_source(part.segments, part.source.name, start))
        if note is not None:
            print(f"excite: note: {note}", file=sys.stderr)
    segments = Segments.concatenate([part.segments for part in parts])
    if len(segments) < MIN_SEGMENTS:
        raise UsageError(f"{len(segments)} segment(s) in total; at least {MIN_SEGMENTS} are "
                         "needed")
    result = calibrate(segments, initial=initial, sigma=sigma, loss=args.loss,
                       sensor_pose=sensor_pose, trim=args.trim,
                       ticks_per_rev=args.ticks_per_rev)
    validation = None
    if held:
        from excite.validation.dead_reckoning import summarize, validate_log

        robot = (result.params, result.sensor_pose)
        nominal = (initial, result.sensor_pose)
        validation = summarize([validate_log(log.series, log.time_offset, robot, nominal,
                                             name=log.name)
                                for log in (read_log(args, source, whole=True)
                                            for source in held)])
    estimated_pose = result.sensor_pose if result.sensor_pose_std is not None else None
    if args.json:
        report = result.to_dict()
        report["inputs"] = [part.describe() for part in parts]
        if initial is not None:
            report["nominal"] = dict(zip(("r_L", "r_R", "b"), initial.as_array().tolist(),
                                         strict=True))
        if validation is not None:
            report["holdout"] = validation.to_dict()
        print(json.dumps(report, indent=2))
    else:
        for part in parts:
            print(part.describe())
        print(result.summary())
        if estimated_pose is not None:
            print(f"  sensor transform: {static_transform_command(estimated_pose)}")
        if validation is not None:
            print(f"\nheld-out logs ({len(held)}), nominal (--init) vs calibrated:")
            print(validation.summary())
    if args.ros2_yaml:
        try:
            write_ros2_yaml(args.ros2_yaml, result.params, nominal=initial,
                            sensor_pose=estimated_pose)
        except OSError as exc:
            raise UsageError(f"cannot write {args.ros2_yaml}: {exc.strerror}") from None
        if not args.json:
            print(f"wrote ROS 2 diff_drive_controller parameters to {args.ros2_yaml}")
    if not result.fit.ok:
        return EXIT_MISFIT
    return EXIT_OK if result.identifiable else EXIT_UNIDENTIFIABLE
