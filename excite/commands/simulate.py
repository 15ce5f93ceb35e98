"""``excite simulate``: drive a simulated robot with a protocol and write its log, with the
hidden truth beside it (``NAME.truth.json``, see :func:`truth_path`; docs/formats.md describes
the log formats).
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

from excite.commands.args import (
    POSE_NOISE_VALUES,
    UsageError,
    check_output_file,
    check_parent_folder,
    env_id,
    pose_noise_arg,
    positive_int,
    robot_preset,
    seed_int,
)
from excite.commands.exit_status import EXIT_OK
from excite.commands.options import (
    add_robot_options,
    add_seed_option,
    add_tuned_option,
    tuned_specs,
)
from excite.logs.bag_paths import BAG_SUFFIXES
from excite.logs.bag_reader import JOINT_STATES
from excite.logs.bag_writer import LEFT_WHEEL, POSE_TOPIC, RIGHT_WHEEL, STORAGES
from excite.logs.segments import TUPLE_SUFFIX

FORMATS = ("segments", "timeseries", "bag")
#: What ``excite simulate --help`` says the command does.
DESCRIPTION = """Drive a simulated robot (a hidden robot drawn around --robot, with a hidden sensor
mounting for the Sensor env) with a protocol and write its log: the segment CSV, a time-series
CSV (encoder ticks at every physics tick, the sensor's noisy world pose at the recording's pose
rate) or a ROS bag of the same streams. The hidden truth goes beside the log, to NAME.truth.json
with NAME the log's name without its extension (log.csv: log.truth.json; run1.bag, or the rosbag2
directory run1: run1.truth.json): the robot and sensor mounting, the noise levels, the encoder
resolution and calibrate_args, the options excite calibrate needs to read the log. A protocol
written as tuned (umbmark, not umbmark:speed=0.5) drives with the settings excite compare would
give it (--tuned: by default those shipped for --env and --robot when tuned for these
segments); the output says which settings drove."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser("simulate", help="drive a simulated robot with a protocol, write its "
                         "log", description=DESCRIPTION)
    sim.add_argument("--protocol", required=True, metavar="NAME[:KEY=VALUE...]",
                     help="the protocol (required): one of %(protocols)s, or a user's "
                     "module:Class, with optional settings (see excite protocols)")
    sim.add_argument("--segments", type=positive_int, required=True, metavar="N",
                     help="segments to drive (required): actions of the protocol, each held "
                     "for the env's segment duration")
    add_seed_option(sim, "seed of the episode: hidden robot, sensor mounting, start, noise and "
                    "the protocol's draws (default %(default)s)")
    sim.add_argument("--robot-seed", type=seed_int, metavar="R",
                     help="drive the hidden robot and sensor mounting of seed R's episode "
                     "(default: --seed's): logs with other --seed and one --robot-seed are "
                     "logs of one robot (e.g. held-out logs for excite validate)")
    add_robot_options(sim)
    add_tuned_option(sim)
    sim.add_argument("--format", choices=FORMATS, default="segments",
                     help="segments (default): the segment CSV; timeseries: a time-series "
                     "CSV (encoder ticks, sensor poses); bag: a ROS bag of the same streams")
    sim.add_argument("--storage", choices=STORAGES,
                     help=f"bag storage (with --format bag): {STORAGES[0]} (default) or mcap "
                     "(rosbag2, FILE is a directory), ros1 (FILE is a .bag file)")
    sim.add_argument("--pose-noise", type=pose_noise_arg, metavar=POSE_NOISE_VALUES,
                     help="noise std of each recorded pose (m, rad; with --format timeseries "
                     "or bag; default: the env's record_sigma_xy, record_sigma_theta)")
    sim.add_argument("--out", required=True, metavar="FILE",
                     help="the log (required): a segment or time-series CSV, a ROS 1 .bag "
                     "file or a rosbag2 directory; the hidden truth goes to NAME.truth.json "
                     "beside it, NAME being FILE without its extension")
    # "--pose-noise -1,0" is a (bad) value, not an unknown option: argparse takes an argument
    # that starts with "-" for a value only when it matches this pattern (by default a single
    # number), and simulate has no option that looks like a number
    sim._negative_number_matcher = re.compile(r"^-\.?\d[\d.,eE+-]*$")
    sim.set_defaults(handler=run)


def _check_output(args: argparse.Namespace, out: Path) -> None:
    """One-line UsageError for options that do not fit the format, or an output that cannot
    be written."""
    if args.format == "bag":  # a rosbag2 bag is a folder (must not exist, checked below)
        check_parent_folder(out)
    else:
        check_output_file(out)
    check_output_file(truth_path(out))  # before the log is written: never one without it
    if args.format != "bag" and out.suffix.lower() in (*BAG_SUFFIXES, TUPLE_SUFFIX):
        raise UsageError(f"--format {args.format} writes a CSV; a {out.suffix} name would be "
                         "read as another format: name it .csv (or --format bag)")
    if args.storage is not None and args.format != "bag":
        raise UsageError("--storage applies to --format bag")
    if args.pose_noise is not None and args.format == "segments":
        raise UsageError("--pose-noise applies to --format timeseries or bag (a segment log's "
                         "noise is the env's sigma_xy, sigma_theta)")
    if args.format != "bag":
        return
    if out.exists():
        raise UsageError(f"{out} exists; a bag is never overwritten: remove it or choose "
                         "another --out")
    if args.storage == "ros1" and out.suffix.lower() != ".bag":
        raise UsageError(f"--storage ros1 writes a .bag file: give --out NAME.bag, got {out}")
    if args.storage != "ros1" and out.suffix.lower() in BAG_SUFFIXES:
        raise UsageError(f"--storage {args.storage or STORAGES[0]} writes a rosbag2 directory: "
                         f"give --out without the {out.suffix} suffix")


def _settings_text(settings: dict[str, Any]) -> str:
    """A protocol's resolved settings in words: ``(speed 0.16, speed_margin 0.35)``."""
    return "(" + ", ".join(f"{key} {value}" for key, value in settings.items()) + ")"


def truth_path(out: Path) -> Path:
    """Where the hidden truth of the log ``out`` goes: NAME.truth.json beside it, NAME being
    the log's name without its extension (log.csv, run1.bag, run1.mcap and the rosbag2
    directory run1 give log.truth.json, run1.truth.json)."""
    return out.with_name(out.stem + ".truth.json")


def _write_log(args: argparse.Namespace, out: Path, base: Any) -> tuple[dict[str, Any], str]:
    """Write the log of the finished episode; returns the truth keys of the format and what
    was written, in words."""
    if args.format == "segments":
        from excite.logs.segments import save_segments

        save_segments(out, base.segments)
        return {"calibrate_args": []}, f"{len(base.segments)} segments"
    recording = base.recording
    series = recording.series
    truth = {"pose_noise": {"xy": float(recording.sigma[0]), "theta": float(recording.sigma[2])},
             "pose_rate": base.recording_config.pose_hz}
    if args.format == "timeseries":
        from excite.logs.timeseries_csv import write_timeseries

        write_timeseries(out, series, ticks_per_rev=recording.ticks_per_rev)
        calibrate_args = ["--ticks-per-rev", str(recording.ticks_per_rev)]
    else:
        from excite.logs.bag_writer import write_bag

        storage = args.storage or STORAGES[0]
        write_bag(out, series, storage=storage)
        truth["storage"] = storage
        calibrate_args = ["--joint-states", JOINT_STATES, "--left-wheel", LEFT_WHEEL,
                          "--right-wheel", RIGHT_WHEEL, "--pose-topic", POSE_TOPIC]
    duration = series.t_enc[-1] - series.t_enc[0]
    what = (f"a {duration:.6g} s log ({series.t_enc.size} encoder samples, {series.t_pose.size} "
            f"sensor poses)")
    return {**truth, "calibrate_args": calibrate_args}, what


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from agents.catalog import make_protocol, parse_protocol, with_policy
    from agents.compare import CompareSettings, make_env, run_protocol_episode

    env = env_id(args.env)
    robot = robot_preset(args.robot)
    out = Path(args.out)
    _check_output(args, out)
    [spec] = with_policy([parse_protocol(args.protocol)], args.policy)
    # the settings compare would drive with (no evaluation episodes: 0)
    [spec], tuned = tuned_specs([spec], args.tuned, CompareSettings(
        env_id=env, segments=args.segments, seed=args.seed, robot=robot), 0)
    protocol = make_protocol(spec)
    recording: dict[str, Any] = {}
    if args.format != "segments":
        recording["record"] = True
        if args.pose_noise is not None:
            recording["record_sigma_xy"], recording["record_sigma_theta"] = args.pose_noise
    env_ = make_env(env, args.segments, robot, **recording)
    base = env_.unwrapped
    options = None
    if args.robot_seed not in (None, args.seed):  # that seed's episode's robot and mounting
        env_.reset(seed=args.robot_seed)
        options = {"robot": base.robot, "sensor_pose": base.true_sensor_pose}
    records = run_protocol_episode(env_, protocol, args.seed, options, label=spec.label)
    written, what = _write_log(args, out, base)
    mount = base.true_sensor_pose
    truth = {**dict(zip(("r_L", "r_R", "b"), base.true_params.as_array().tolist(), strict=True)),
             "robot": {k: float(v) for k, v in vars(base.robot).items()},
             "sigma": dict(zip(("x", "y", "theta"), base.sigma.tolist(), strict=True)),
             "env": env, "protocol": spec.label, "protocol_settings": spec.resolved(),
             "tuned": {"file": tuned["file"], "note": tuned["note"]},
             "seed": args.seed,
             "robot_seed": args.seed if args.robot_seed is None else args.robot_seed,
             "segments": len(records),
             "collisions": int(np.sum([r["collision"] for r in records])),
             "format": args.format,
             "sensor_pose": dict(zip(("x", "y", "theta"), [0.0, 0.0, 0.0] if mount is None
                                     else mount.as_array().tolist(), strict=True)),
             "ticks_per_rev": base.sim.encoders.ticks_per_rev,
             **written}
    truth_file = truth_path(out)
    truth_file.write_text(json.dumps(truth, indent=2) + "\n")
    print(f"wrote {what} to {out} and the hidden truth to {truth_file}")
    print(f"settings: {spec.label} {_settings_text(spec.resolved())}, {tuned['note']}")
    return EXIT_OK
