"""``excite calibrate``: estimate r_L, r_R, b (and the sensor pose) from segment files."""

from __future__ import annotations

import argparse
import json

from excite.commands.args import (
    UsageError,
    fraction_arg,
    params_arg,
    sensor_pose_arg,
    sigma_arg,
)

EXIT_OK, EXIT_UNIDENTIFIABLE, EXIT_MISFIT = 0, 3, 4


def add_parser(sub: argparse._SubParsersAction) -> None:
    cal = sub.add_parser("calibrate", help="estimate r_L, r_R, b (and the sensor pose) from "
                         "segment files (one data set)")
    cal.add_argument("files", nargs="+", metavar="FILE",
                     help="segment CSV or Censi tuple files (*.tuple)")
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
    cal.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from excite.calibration import calibrate
    from excite.data import load_segment_files
    from excite.export import static_transform_command, write_ros2_yaml

    sigma = sigma_arg(args.sigma) if args.sigma else None
    initial = params_arg(args.init) if args.init else None
    sensor_pose = sensor_pose_arg(args.sensor_pose)
    segments = load_segment_files(args.files)
    result = calibrate(segments, initial=initial, sigma=sigma, loss=args.loss,
                       sensor_pose=sensor_pose, trim=args.trim)
    estimated_pose = result.sensor_pose if result.sensor_pose_std is not None else None
    if args.json:
        print(json.dumps(result.to_dict(), indent=2))
    else:
        print(result.summary())
        if estimated_pose is not None:
            print(f"  sensor transform: {static_transform_command(estimated_pose)}")
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
