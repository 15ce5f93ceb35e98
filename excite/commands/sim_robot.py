"""``excite sim-robot``: a simulated robot as a ROS 2 node, to rehearse ``excite live``
(:mod:`envs.ros2_robot`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from excite.commands.args import (
    POSE_NOISE_VALUES,
    POSE_VALUES,
    UsageError,
    check_output_file,
    floats,
    pose_noise_arg,
    positive_number,
    robot_preset,
)
from excite.commands.exit_status import EXIT_OK
from excite.commands.options import add_seed_option

DESCRIPTION = """A simulated robot with hidden wheel parameters, motor lag and slip (the
simulator's pymunk robot, drawn from a preset with --seed) as a ROS 2 node: it publishes /clock,
the wheel joints' JointState and the motion-capture pose (PoseStamped, best effort) of a rigid
body mounted off the axle, and obeys the command topic as diff_drive_controller does (nominal
geometry, the wheel speed limit, a 0.5 s command timeout). Runs --speed times faster than real
time (nodes with use_sim_time follow its clock). Writes its hidden truth with --truth. Needs the
sim and ros2 extras."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim-robot", help="a simulated robot as a ROS 2 node (rehearse excite "
                       "live)", description=DESCRIPTION)
    p.add_argument("--robot", type=robot_preset, default="default", metavar="PRESET",
                   help="the preset the hidden robot is drawn around: %(robot_presets)s "
                   "(default %(default)s)")
    add_seed_option(p, "seed of the hidden robot and the pose noise (default %(default)s)")
    p.add_argument("--mount", default="0.05,0.02,0.1", metavar=POSE_VALUES,
                   help="the motion-capture body's pose on the robot, body frame (m, m, "
                   "rad; default %(default)s)")
    p.add_argument("--pose-noise", type=pose_noise_arg, default="0.001,0.002",
                   metavar=POSE_NOISE_VALUES,
                   help="noise of each pose (m, rad; default %(default)s)")
    p.add_argument("--speed", type=positive_number, default=1.0, metavar="X",
                   help="times faster than real time (default %(default)g)")
    p.add_argument("--duration", type=positive_number, default=float("inf"),
                   metavar="S", help="simulated seconds to run (default: until stopped)")
    p.add_argument("--left-wheel", default="left_wheel_joint", metavar="JOINT",
                   help="the left wheel's joint name it publishes (default %(default)s)")
    p.add_argument("--right-wheel", default="right_wheel_joint", metavar="JOINT",
                   help="the right wheel's joint name (default %(default)s)")
    p.add_argument("--pose-topic", default="/pose", metavar="TOPIC",
                   help="where the motion-capture pose is published (default %(default)s)")
    p.add_argument("--cmd-vel", default="/cmd_vel", metavar="TOPIC",
                   help="the command topic it obeys (default %(default)s)")
    p.add_argument("--cmd-type", choices=("twist_stamped", "twist"), default="twist_stamped",
                   help="the command's type: TwistStamped (default) or Twist")
    p.add_argument("--fault", action="append", default=[],
                   choices=("ignore_commands", "swap_wheels", "mirror_left"),
                   help="rehearse a fault: the controller not running, swapped wheels, a "
                   "mirrored left motor (repeatable)")
    p.add_argument("--cut", action="append", default=[], metavar="STREAM:START:SECONDS",
                   help="silence the pose or joints stream from START s after the first "
                   "non-zero command for SECONDS (simulated time; repeatable)")
    p.add_argument("--truth", type=Path, metavar="TRUTH.json",
                   help="write the hidden r_L, r_R, b and mounting here on exit")
    p.add_argument("--log", type=Path, metavar="ROBOT.csv",
                   help="write the robot's own log (true pose, command in force) on exit")
    p.set_defaults(handler=run)


def _cuts(texts: list[str]):
    from envs.sim_robot import STREAMS, Cut

    cuts = []
    for text in texts:
        stream, _, rest = text.partition(":")
        if stream not in STREAMS:
            raise UsageError(f"--cut must be pose:START:SECONDS or joints:START:SECONDS, got "
                             f"{text!r}")
        start, seconds = floats(rest.replace(":", ","), "START,SECONDS", "--cut",
                                positive=False)
        try:
            cuts.append(Cut(stream, start, seconds))
        except ValueError as exc:
            raise UsageError(f"--cut {text}: {exc}") from None
    return tuple(cuts)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from envs.robot import PRESETS
    from envs.sim_robot import SimRobot

    mount = floats(args.mount, POSE_VALUES, "--mount", positive=False)
    noise = args.pose_noise
    for path in (args.truth, args.log):
        if path is not None:
            check_output_file(path)
    cuts = _cuts(args.cut)
    dist = PRESETS[args.robot]
    robot = SimRobot(dist.sample(np.random.default_rng(args.seed)),
                     dist.nominal().kinematic_params(), mount=mount, pose_sigma=noise,
                     faults=tuple(args.fault), seed=args.seed + 1)
    from envs.ros2_robot import SimTopics, run_sim_robot

    topics = SimTopics(left_wheel=args.left_wheel, right_wheel=args.right_wheel,
                       pose_topic=args.pose_topic, cmd_vel=args.cmd_vel,
                       cmd_type=args.cmd_type)
    run_sim_robot(robot, topics, speed=args.speed, duration=args.duration, cuts=cuts,
                  truth_out=args.truth, log_out=args.log,
                  on_ready=lambda: print("sim-robot ready", flush=True))
    return EXIT_OK
