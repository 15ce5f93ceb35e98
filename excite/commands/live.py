"""``excite live``: drive a robot over ROS 2 with a protocol's maneuvers until the calibration
reaches the target (:mod:`excite.live`)."""

from __future__ import annotations

import argparse
import json
import re
import signal
from pathlib import Path

from excite.commands.args import (
    PARAMS_VALUES,
    POSE_VALUES,
    UsageError,
    check_writable,
    floats,
    params_arg,
    positive_number,
    robot_preset,
    sensor_pose_arg,
    time_offset_arg,
)
from excite.commands.exit_status import (
    EXIT_ABORTED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_OUT_OF_TIME,
    calibration_status,
)
from excite.commands.options import add_result_options, add_seed_option

#: The protocol a live session drives by default: the strongest planner of the time-to-target
#: comparison (BENCHMARKS.md).
DEFAULT_PROTOCOL = "slip_aware"

DESCRIPTION = """Drive a differential-drive robot over ROS 2 with a protocol's maneuvers until the
stopping rule says its wheel radii and separation (and the pose sensor's mounting) are within the
target, then calibrate the whole session offline and report it as excite calibrate does. Subscribes
the wheel joints (JointState) and an external pose (PoseStamped, PoseWithCovarianceStamped,
TransformStamped or Odometry), publishes the command (TwistStamped or Twist) at --rate Hz, keeps
the robot inside the safe area, and stops it on every way out. Exit status 0 when done, 5 when the
time ran out first, 6 when the session was aborted (a stream silent too long, wheels that do not
follow the command), 130 when interrupted, 2 for bad input. Needs the ros2 extra: pip install
'excite[ros2]'."""


#: Hz, the command rates a session runs at: a controller's command timeout is often 0.5 s, and
#: a timer faster than a kilohertz only loads the computer.
MIN_RATE, MAX_RATE = 20.0, 1000.0


def _default(cls_name: str, name: str):
    """A field's default of LiveSettings or LiveTopics (each default defined once)."""
    from dataclasses import fields

    from excite.live import settings

    return next(f.default for f in fields(getattr(settings, cls_name)) if f.name == name)


#: The numeric options of the robot: (flag, LiveSettings field of the default or None,
#: metavar, help).
_ROBOT_NUMBERS = (
    ("--max-wheel-speed", None, "RAD/S",
     "the wheels' speed limit (rad/s); required with --nominal, the preset's with --robot"),
    ("--speed-fraction", "speed_fraction", "F",
     "the share of --max-wheel-speed the protocol may command, in (0, 1] (default "
     "%(default)g)"),
    ("--max-wheel-accel", "max_wheel_acceleration", "RAD/S2",
     "the largest change of a wheel's commanded speed (rad/s^2; default: none, the "
     "controller's limits apply)"),
    ("--motor-tau", None, "S", "the motors' time constant (s), for planners that plan around "
     "slip (the preset's with --robot)"),
    ("--grip", None, "M/S2", "the largest acceleration the floor gives a wheel before it "
     "slides, mu g (m/s^2) (the preset's with --robot)"),
)
#: The numeric options of a session: (flag, LiveSettings field, metavar, help).
_SESSION_NUMBERS = (
    ("--segment-duration", "segment_duration", "S",
     "how long each maneuver is held (s), also the calibration window"),
    ("--target", "target", "T", "stop when r_L, r_R, b are within relative error T (sensor x, "
     "y within T x b, angle within T rad)"),
    ("--target-confidence", "confidence", "C", "at this confidence"),
    ("--max-time", "max_time", "S", "give up after this long (s; exit status 5)"),
    ("--silence-timeout", "silence_timeout", "S",
     "stop the robot while the poses or the wheel angles are silent this long (s)"),
    ("--abort-timeout", "abort_timeout", "S", "abort when a silence lasts this long (s)"),
    ("--response-time", "response_time", "S", "how long the controller and motors take to "
     "follow a command (s; the wheels are judged against the command after it)"),
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("live", help="drive a robot over ROS 2 until it is calibrated",
                       description=DESCRIPTION)
    topics = p.add_argument_group("topics")
    topics.add_argument("--left-wheel", required=True, metavar="JOINT",
                        help="the left wheel's joint name in the JointState messages")
    topics.add_argument("--right-wheel", required=True, metavar="JOINT",
                        help="the right wheel's joint name")
    topics.add_argument("--joint-states", default=_default("LiveTopics", "joint_states"),
                        metavar="TOPIC", help="the JointState topic (default %(default)s)")
    topics.add_argument("--pose-topic", required=True, metavar="TOPIC",
                        help="the external pose: PoseStamped, PoseWithCovarianceStamped, "
                        "TransformStamped or Odometry, reliable or best effort")
    topics.add_argument("--cmd-vel", default=_default("LiveTopics", "cmd_vel"),
                        metavar="TOPIC", help="the command topic (default %(default)s)")
    topics.add_argument("--cmd-type", choices=("twist_stamped", "twist"),
                        default=_default("LiveTopics", "cmd_type"),
                        help="geometry_msgs TwistStamped (default, diff_drive_controller's "
                        "since Jazzy) or Twist")
    topics.add_argument("--rate", type=positive_number, metavar="HZ",
                        default=_default("LiveTopics", "rate"),
                        help=f"command rate, {MIN_RATE:g} to {MAX_RATE:g} (default "
                        "%(default)g)")
    topics.add_argument("--use-sim-time", action="store_true",
                        help="follow /clock (a simulator's time) instead of the wall clock")
    topics.add_argument("--wait", type=positive_number, metavar="S",
                        default=_default("LiveTopics", "wait"),
                        help="how long to wait for the topics at the start (default "
                        "%(default)g s)")
    robot = p.add_argument_group("robot")
    robot.add_argument("--nominal", metavar=PARAMS_VALUES,
                       help="the nominal wheel radii and separation (m), as the controller "
                       "is configured")
    robot.add_argument("--robot", type=robot_preset, metavar="PRESET",
                       help="a preset's nominal robot, speed limit, traction and footprint: "
                       "%(robot_presets)s")
    for flag, field, metavar, text in _ROBOT_NUMBERS:
        default = None if field is None else _default("LiveSettings", field)
        robot.add_argument(flag, type=positive_number, metavar=metavar, default=default,
                           help=text)
    robot.add_argument("--sensor-pose", default=_default("LiveSettings", "sensor_pose"),
                       metavar=f"auto|axle|estimate|{POSE_VALUES}",
                       help="the pose sensor's mounting (as excite calibrate; default "
                       "%(default)s)")
    session = p.add_argument_group("session")
    session.add_argument("--protocol", default=DEFAULT_PROTOCOL, metavar="NAME[:KEY=VALUE]",
                         help="the maneuvers: %(protocols)s, or module:Class (default "
                         "%(default)s)")
    session.add_argument("--area", metavar="X0,Y0,X1,Y1",
                         help="the rectangle (m, the pose frame) the robot never leaves")
    session.add_argument("--radius", type=positive_number, metavar="R",
                         help="instead of --area: stay within R m of the start; default: a "
                         "square of the simulated arena's size for the robot, centred on "
                         "the start")
    for flag, field, metavar, text in _SESSION_NUMBERS:
        session.add_argument(flag, dest=field, type=positive_number, metavar=metavar,
                             default=_default("LiveSettings", field),
                             help=f"{text} (default %(default)g)")
    session.add_argument("--time-offset", type=time_offset_arg, metavar="S|estimate",
                         default=_default("LiveSettings", "time_offset"),
                         help="pose time + S = wheel time (s), as excite calibrate "
                         "--time-offset: the session's log is cut with it (a pose source's "
                         "stamp latency); 'estimate' estimates it from the log at every look "
                         "(default %(default)s)")
    add_seed_option(session, "seed of the protocol's random choices (default %(default)s)")
    out = p.add_argument_group("output")
    add_result_options(out, "--nominal or --robot")
    out.add_argument("--out", type=Path, metavar="RESULT.json",
                     help="also write the JSON object (excite calibrate --json's, with a live "
                     "section) to a file")
    out.add_argument("--record", type=Path, metavar="SESSION.mcap",
                     help="record the session (joint states, poses, commands) as a rosbag2 "
                     "(mcap; sqlite3 for another name) that excite calibrate reads")
    p.set_defaults(handler=run)


def _robot(args: argparse.Namespace):
    """The nominal Params, wheel speed limit, traction, footprint and default area side."""
    from excite.contracts import Traction
    from excite.core.arena import DEFAULT_CHASSIS

    if args.nominal is not None and args.robot is not None:
        raise UsageError("give --nominal or --robot, not both (--robot sets the nominal robot)")
    if args.nominal is None and args.robot is None:
        raise UsageError("give the nominal robot: --nominal RL,RR,B (with --max-wheel-speed) "
                         "or --robot PRESET")
    if args.robot is not None:
        from envs.robot import PRESETS, traction_of
        from excite.core.kinematics import Params

        dist = PRESETS[args.robot]
        spec = dist.nominal()
        nominal = Params(*spec.kinematic_params())
        traction = traction_of(spec)
        speed = args.max_wheel_speed or spec.max_wheel_speed
        chassis = spec.chassis
        side = dist.arena_size(args.segment_duration)
        if args.motor_tau or args.grip:
            traction = Traction(args.motor_tau or traction.motor_tau,
                                args.grip or traction.grip, traction.spin_inertia)
        return nominal, speed, traction, chassis, side
    nominal = params_arg(args.nominal, "--nominal")
    if args.max_wheel_speed is None:
        raise UsageError("--nominal needs --max-wheel-speed RAD/S (the wheels' limit)")
    traction = (Traction(args.motor_tau, args.grip) if args.motor_tau and args.grip else None)
    if bool(args.motor_tau) != bool(args.grip):
        raise UsageError("--motor-tau and --grip go together")
    from envs.robot import arena_side

    side = arena_side(float(nominal.as_array()[:2].mean()) * args.max_wheel_speed,
                      DEFAULT_CHASSIS, args.segment_duration)
    return nominal, args.max_wheel_speed, traction, DEFAULT_CHASSIS, side


def settings_from(args: argparse.Namespace):
    """The session's LiveSettings from the command line (UsageError on bad values)."""
    from excite.live import Area, LiveSettings

    nominal, speed, traction, chassis, side = _robot(args)
    area = None
    if args.area is not None and args.radius is not None:
        raise UsageError("give --area or --radius, not both")
    if args.area is not None:
        area = floats(args.area, "X0,Y0,X1,Y1", "--area", positive=False)
    if not MIN_RATE <= args.rate <= MAX_RATE:
        raise UsageError(f"--rate must be {MIN_RATE:g} to {MAX_RATE:g} Hz, got {args.rate:g}")
    try:
        if area is not None:
            area = Area(*area)
        return LiveSettings(
            nominal=nominal, max_wheel_speed=speed, speed_fraction=args.speed_fraction,
            area=area, radius=args.radius, area_size=side, chassis=chassis, traction=traction,
            max_wheel_acceleration=args.max_wheel_accel,
            sensor_pose=sensor_pose_arg(args.sensor_pose), time_offset=args.time_offset,
            **{field: getattr(args, field) for _, field, _, _ in _SESSION_NUMBERS})
    except ValueError as exc:  # named as the options that set the fields
        message = str(exc)
        for field, flag in _OPTION_OF.items():
            message = re.sub(rf"\b{field}\b", flag, message)
        raise UsageError(message) from None


#: The option that sets each field of LiveSettings, for its errors.
_OPTION_OF = {field: flag for flag, field, _, _ in _SESSION_NUMBERS} | {
    "speed_fraction": "--speed-fraction", "max_wheel_acceleration": "--max-wheel-accel",
    "max_wheel_speed": "--max-wheel-speed", "radius": "--radius"}


def _protocol(text: str, settings):
    """The protocol, checked against what the session knows (traction for slip_aware), and
    the observation a learned policy reads (None for the others)."""
    from agents.catalog import Checked, make_protocol, parse_protocol

    spec = parse_protocol(text)
    if spec.name == "slip_aware" and settings.traction is None:
        raise UsageError("slip_aware needs the motors' lag and the grip: --motor-tau S and "
                         "--grip M/S2, or --robot PRESET (or another --protocol)")
    protocol, observe = make_protocol(spec), None
    if spec.name == "learned":
        from envs.observation import observer_for

        observe = observer_for(protocol.observation_shape)
    return Checked(protocol, spec.label), observe


def run(args: argparse.Namespace) -> int:
    from excite.live import LiveSession
    from excite.live.report import status_line

    settings = settings_from(args)
    protocol, observe = _protocol(args.protocol, settings)
    for path in (args.out, Path(args.ros2_yaml) if args.ros2_yaml else None):
        if path is not None:  # before the robot moves: the results come after the drive
            check_writable(path)
    if args.record is not None and args.record.exists():
        raise UsageError(f"cannot record to {args.record}: it exists")
    if args.record is not None and not args.record.parent.is_dir():
        raise UsageError(f"cannot record to {args.record}: no such directory "
                         f"{args.record.parent}")
    if args.force_yaml and not args.ros2_yaml:
        raise UsageError("--force-yaml needs --ros2-yaml OUT.yaml")
    _check_names(args)
    from excite.live.ros2 import INTERRUPTED, SessionFailed, run_live
    from excite.live.settings import LiveTopics

    topics = LiveTopics(joint_states=args.joint_states, left_wheel=args.left_wheel,
                        right_wheel=args.right_wheel, pose_topic=args.pose_topic,
                        cmd_vel=args.cmd_vel, cmd_type=args.cmd_type, rate=args.rate,
                        use_sim_time=args.use_sim_time, wait=args.wait)
    session = LiveSession(settings, protocol, seed=args.seed, observe=observe)

    def on_status(status) -> None:
        if not args.json:
            print(status_line(status), flush=True)

    recorder = _recorder(args.record)
    failure = None
    try:
        result = run_live(session, topics, recorder, on_status)
    except SessionFailed as failed:  # the robot stopped: report what was recorded, then fail
        result, failure = failed.result, failed.__cause__
    finally:
        if recorder is not None:
            recorder.__exit__(None, None, None)
            if not session.started:  # nothing of a drive: no bag to refuse the next --record
                _remove(args.record)
    with _signals_held():  # the robot is stopped; the report and files take a moment
        unwritten = _report(args, result, settings)
    if failure is not None:
        raise failure
    if unwritten is not None:
        raise unwritten
    return {"done": EXIT_OK, "out_of_time": EXIT_OUT_OF_TIME}.get(
        result.outcome, EXIT_INTERRUPTED if result.reason == INTERRUPTED else EXIT_ABORTED)


def _check_names(args: argparse.Namespace) -> None:
    """UsageError before anything connects: the wheels name one joint; a topic name ROS 2
    refuses; --out, --record and --ros2-yaml naming one file."""
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_topic_name import validate_topic_name

    if args.left_wheel == args.right_wheel:
        raise UsageError(f"--left-wheel and --right-wheel name the same joint "
                         f"{args.left_wheel!r}")
    for option, name in (("--joint-states", args.joint_states),
                         ("--pose-topic", args.pose_topic), ("--cmd-vel", args.cmd_vel)):
        try:
            validate_topic_name(name)
        except InvalidTopicNameException as exc:
            reason = str(exc).splitlines()[0].removeprefix("Invalid topic name: ").rstrip(":")
            raise UsageError(f"{option} {name!r}: not a ROS 2 topic name ({reason})") from None
    files = {"--out": args.out, "--record": args.record,
             "--ros2-yaml": Path(args.ros2_yaml) if args.ros2_yaml else None}
    given = [(option, path.resolve()) for option, path in files.items() if path is not None]
    for k, (option, path) in enumerate(given):
        for other, same in given[k + 1:]:
            if path == same:
                raise UsageError(f"{option} and {other} name the same file {path}")


def _report(args: argparse.Namespace, result, settings) -> UsageError | None:
    """A finished session's result: the JSON file and output, the closing lines and the
    calibration's report, the note on the recorded bag, the ROS 2 parameter file; the error
    when the JSON file could not be written (all the rest is shown all the same)."""
    from excite.commands.logs import print_note
    from excite.live.report import closing_lines, result_dict

    report = result_dict(result, settings.nominal)
    unwritten = None  # the report is printed and the parameters written all the same
    if args.out is not None:
        try:
            args.out.write_text(json.dumps(report, indent=2) + "\n")
        except OSError as exc:
            unwritten = UsageError(f"cannot write {args.out}: {exc.strerror or exc} (the "
                                   "session's report is printed above)")
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        for line in closing_lines(result):
            print(line)
        if result.calibration is not None:
            print(result.calibration.summary(settings.nominal))
        if args.record is not None:
            joint_states = ("" if args.joint_states == _default("LiveTopics", "joint_states")
                            else f" --joint-states {args.joint_states}")
            pose = ("" if args.sensor_pose == _default("LiveSettings", "sensor_pose")
                    else f" --sensor-pose={args.sensor_pose}")
            nominal = ",".join(f"{value:.9g}" for value in settings.nominal.as_array())
            print_note(f"session recorded in {args.record}: excite calibrate {args.record} "
                       f"--left-wheel {args.left_wheel} --right-wheel {args.right_wheel}"
                       f"{joint_states} --pose-topic {args.pose_topic}{pose} --init {nominal} "
                       "--split-at-gaps"
                       + (f" --window {args.segment_duration:g}"
                          if args.segment_duration != 1.0 else "")
                       + (f" --time-offset {result.time_offset!r}"
                          if result.time_offset is not None else "")
                       + (f" --start {result.calibrated_from!r}"
                          if result.calibrated_from is not None else ""))
    if args.ros2_yaml and result.calibration is not None:
        from excite.commands.calibrate import export_yaml

        export_yaml(args, result.calibration, settings.nominal,
                    calibration_status(result.calibration))
    elif args.ros2_yaml:
        print_note(f"{args.ros2_yaml} not written: the session has no calibration "
                   f"({result.calibration_error or result.reason})")
    return unwritten


def _signals_held():
    """While inside (in the main thread): SIGINT and SIGTERM ignored, so that a second
    Ctrl-C after the session ended cannot cut its report and files short (the robot is
    stopped by then); the handlers restored on the way out."""
    from excite.signals import handled

    return handled((signal.SIGINT, signal.SIGTERM), signal.SIG_IGN)


def _remove(path: Path) -> None:
    """Remove a bag that holds nothing of the robot (a rosbag2 folder, or a ROS 1 file)."""
    import shutil

    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _recorder(path: Path | None):
    """An open BagWriter at ``path`` (mcap for a .mcap name), or None."""
    if path is None:
        return None
    from excite.logs.bag_writer import BagWriter

    writer = BagWriter(path, storage="mcap" if path.suffix == ".mcap" else "sqlite3")
    return writer.__enter__()
