"""The ``excite`` command line: the one place that wires every layer together.

Heavy layers (gymnasium, pymunk, torch, matplotlib) are imported lazily inside the
subcommands that need them. Exit status: 0 success; 2 bad input or usage (one line
``excite: error: ...`` on stderr); 3 when ``calibrate`` finds the data cannot determine all
the parameters, 4 when the model does not fit the data (the report is still printed, with
the reason in words). A closed stdout (``| head``) is a normal end.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from excite import __version__
from excite.errors import DataError, ExciteError
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID

EXIT_OK, EXIT_FAILURE, EXIT_USAGE, EXIT_UNIDENTIFIABLE, EXIT_MISFIT = 0, 1, 2, 3, 4


class UsageError(ExciteError):
    """Bad input or usage: reported as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage dump
        raise UsageError(message)


def _floats(text: str, names: Sequence[str], what: str) -> tuple[float, ...]:
    parts = text.split(",")
    if len(parts) != len(names):
        raise UsageError(f"{what} needs {len(names)} comma-separated values "
                         f"({','.join(names)}), got {text!r}")
    values = []
    for name, part in zip(names, parts, strict=True):
        try:
            value = float(part)
        except ValueError:
            raise UsageError(f"{what}: {name} is not a number: {part!r}") from None
        if not (value > 0 and value < float("inf")):
            raise UsageError(f"{what}: {name} must be positive and finite, got {part!r}")
        values.append(value)
    return tuple(values)


def _sigma_arg(text: str) -> tuple[float, ...]:
    return _floats(text, ("SX", "SY", "STH"), "--sigma")


def _params_arg(text: str):
    from excite.kinematics import Params

    return Params(*_floats(text, ("RL", "RR", "B"), "--init"))


def _sensor_pose_arg(text: str):
    """--sensor-pose: auto, axle, estimate, or X,Y,THETA (m, m, rad) in the body frame."""
    from excite.models import SensorPose

    if text in ("auto", "axle", "estimate"):
        return text
    parts = text.split(",")
    if len(parts) != 3:
        raise UsageError(f"--sensor-pose must be auto, axle, estimate or X,Y,THETA "
                         f"(m, m, rad), got {text!r}")
    try:
        return SensorPose(*map(float, parts))
    except ValueError:
        raise UsageError(f"--sensor-pose: X,Y,THETA must be finite numbers, got {text!r}"
                         ) from None


def _fraction_arg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value < 0.5:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 0.5), got {text!r}")
    return value


def cmd_calibrate(args: argparse.Namespace) -> int:
    from excite.calibration import calibrate
    from excite.data import load_segment_files
    from excite.export import static_transform_command, write_ros2_yaml

    sigma = _sigma_arg(args.sigma) if args.sigma else None
    initial = _params_arg(args.init) if args.init else None
    sensor_pose = _sensor_pose_arg(args.sensor_pose)
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


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _env_id(text: str) -> str:
    """An environment id registered with excite's environment class (its own or a user's)."""
    import gymnasium

    from excite.registration import ENTRY_POINT

    ours = [k for k, spec in gymnasium.registry.items() if spec.entry_point == ENTRY_POINT]
    if text not in ours:
        raise UsageError(f"unknown environment {text!r}; use one of {', '.join(ours)}")
    return text


def _robot_preset(text: str) -> str:
    from envs.robot import PRESETS

    if text not in PRESETS:
        raise UsageError(f"unknown robot preset {text!r}; choose from {', '.join(PRESETS)}")
    return text


def _protocol_names(text: str | None, policy: str | None) -> list[str]:
    from agents.catalog import PROTOCOL_NAMES, default_protocols

    if text is None:
        return default_protocols(policy)
    names = [n.strip() for n in text.split(",") if n.strip()]
    for name in names:
        if name not in PROTOCOL_NAMES:
            raise UsageError(f"unknown protocol {name!r}; choose from {', '.join(PROTOCOL_NAMES)}")
    if not names or len(set(names)) != len(names):
        raise UsageError(f"--protocols needs distinct comma-separated names, got {text!r}")
    return names


def cmd_simulate(args: argparse.Namespace) -> int:
    import numpy as np

    from agents.catalog import ProtocolError, make_protocol
    from agents.compare import make_env, run_protocol_episode
    from excite.data import save_segments

    env_id = _env_id(args.env)
    robot = _robot_preset(args.robot)
    try:
        protocol = make_protocol(args.protocol, args.policy)
    except ProtocolError as exc:
        raise UsageError(str(exc)) from None
    out = Path(args.out)
    if not out.parent.is_dir():
        raise UsageError(f"cannot write {out}: no such directory {out.parent}")
    env = make_env(env_id, args.segments, robot)
    records = run_protocol_episode(env, protocol, args.seed)
    base = env.unwrapped
    save_segments(out, base.segments)
    truth = {**dict(zip(("r_L", "r_R", "b"), base.true_params.as_array().tolist(), strict=True)),
             "robot": {k: float(v) for k, v in vars(base.robot).items()},
             "sigma": dict(zip(("x", "y", "theta"), base.sigma.tolist(), strict=True)),
             "env": env_id, "protocol": args.protocol, "seed": args.seed,
             "segments": len(records),
             "collisions": int(np.sum([r["collision"] for r in records]))}
    truth_path = out.with_name(out.stem + ".truth.json") if out.suffix == ".csv" else Path(
        f"{out}.truth.json")
    truth_path.write_text(json.dumps(truth, indent=2) + "\n")
    print(f"wrote {len(records)} segments to {out} and the hidden truth to {truth_path}")
    return EXIT_OK


def cmd_compare(args: argparse.Namespace) -> int:
    import numpy as np

    from agents.catalog import ProtocolError
    from agents.compare import (
        COLUMNS,
        CompareError,
        CompareSettings,
        incompatible_protocols,
        make_env,
        run_comparison,
    )
    from agents.report import format_table, plot_comparison, summarize

    env_id = _env_id(args.env)
    if args.policy and not Path(args.policy).is_file():
        raise UsageError(f"--policy: no such file {args.policy}")
    protocols = _protocol_names(args.protocols, args.policy)
    settings = CompareSettings(env_id=env_id, segments=args.segments, seed=args.seed,
                               robot=_robot_preset(args.robot))
    env = make_env(env_id, args.segments, settings.robot)
    shape, arena_size = env.observation_space.shape, float(env.unwrapped.config["arena_size"])
    env.close()
    try:
        skipped = incompatible_protocols(protocols, shape, args.policy)
    except ProtocolError as exc:
        raise UsageError(str(exc)) from None
    for name, reason in skipped.items():
        print(f"excite: skipping {name}: {reason}", file=sys.stderr)
    protocols = [name for name in protocols if name not in skipped]
    if not protocols:
        raise UsageError("no protocol can run on this environment")
    try:
        rows = run_comparison(args.out, protocols, args.episodes, settings, args.workers,
                              args.policy)
    except (ProtocolError, CompareError) as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot write to {args.out}: {exc.strerror}") from None
    columns = {k: np.array([r[k] for r in rows]) for k in COLUMNS}
    summary = summarize(columns, seed=args.seed)
    summary["settings"] = {"env": env_id, "segments": args.segments, "seed": args.seed,
                           "episodes": args.episodes, "protocols": protocols,
                           "robot": settings.robot}
    out = Path(args.out)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    plots = plot_comparison(columns, out, arena_size=arena_size)
    print(format_table(summary))
    print(f"\nresults: {out / 'segments.csv'}, {out / 'summary.json'}")
    print("plots:   " + ", ".join(str(p) for p in plots))
    return EXIT_OK


def cmd_train(args: argparse.Namespace) -> int:
    from agents.train import TrainingError, train

    try:
        summary = train(args.out, algo=args.algo, timesteps=args.timesteps, n_envs=args.n_envs,
                        seed=args.seed, resume=args.resume, config_path=args.config)
    except TrainingError as exc:
        raise UsageError(str(exc)) from None
    print(f"trained {summary['algo']} to {summary['timesteps']} steps in "
          f"{summary['wall_time_s']:.0f} s ({summary['fps'] or 0:.0f} steps/s); "
          f"best policy: {Path(args.out) / 'best_model.zip'}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="excite", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"excite {__version__}")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser, metavar="COMMAND")

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
    cal.add_argument("--trim", type=_fraction_arg, default=0.0, metavar="FRACTION",
                     help="drop this fraction of segments with the largest residuals "
                     "(1%% per pass)")
    cal.add_argument("--ros2-yaml", metavar="OUT.yaml",
                     help="write diff_drive_controller parameters (nominal from --init) and "
                     "the sensor's static transform when estimated")
    cal.set_defaults(handler=cmd_calibrate)

    sim = sub.add_parser("simulate", help="drive a simulated robot with a protocol, write its log")
    sim.add_argument("--protocol", required=True, metavar="NAME")
    sim.add_argument("--segments", type=_positive_int, required=True, metavar="N")
    sim.add_argument("--seed", type=int, default=0, metavar="S")
    sim.add_argument("--env", default=DEFAULT_ENV_ID, metavar="ID")
    sim.add_argument("--policy", metavar="PATH", help="policy file for --protocol learned")
    sim.add_argument("--robot", default="default", metavar="PRESET",
                     help="robot preset: default, turtlebot3, jackal, husky")
    sim.add_argument("--out", required=True, metavar="FILE.csv",
                     help="segment CSV; the hidden truth goes to FILE.truth.json")
    sim.set_defaults(handler=cmd_simulate)

    cmp_ = sub.add_parser("compare", help="compare calibration protocols on the same robots")
    cmp_.add_argument("--protocols", metavar="A,B,...",
                      help="default: every protocol available (learned if a policy exists)")
    cmp_.add_argument("--episodes", type=_positive_int, default=20, metavar="N")
    cmp_.add_argument("--segments", type=_positive_int, default=DEFAULT_BUDGET, metavar="K")
    cmp_.add_argument("--seed", type=int, default=0, metavar="S")
    cmp_.add_argument("--env", default=DEFAULT_ENV_ID, metavar="ID")
    cmp_.add_argument("--workers", type=_positive_int, default=None, metavar="W",
                      help="worker processes (default: all cores)")
    cmp_.add_argument("--out", default="excite_compare", metavar="DIR")
    cmp_.add_argument("--policy", metavar="PATH", help="policy file for the learned protocol")
    cmp_.add_argument("--robot", default="default", metavar="PRESET",
                      help="robot preset: default, turtlebot3, jackal, husky")
    cmp_.set_defaults(handler=cmd_compare)

    trn = sub.add_parser("train", help="train an excitation policy (stable-baselines3)")
    trn.add_argument("--algo", choices=("ppo", "sac"), default="ppo")
    trn.add_argument("--timesteps", type=_positive_int, default=1_000_000, metavar="N")
    trn.add_argument("--n-envs", type=_positive_int, default=None, metavar="E",
                     help="parallel environments (default: from the config)")
    trn.add_argument("--seed", type=int, default=0, metavar="S")
    trn.add_argument("--config", metavar="FILE.yaml",
                     help="hyperparameters (default: agents/configs/ALGO.yaml)")
    trn.add_argument("--out", required=True, metavar="DIR")
    trn.add_argument("--resume", action="store_true",
                     help="continue from the last checkpoint in DIR (same settings)")
    trn.set_defaults(handler=cmd_train)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        handler: Callable[[argparse.Namespace], int] | None = getattr(args, "handler", None)
        if handler is None:
            raise UsageError("a command is required (calibrate, simulate, compare, train); "
                             "see excite --help")
        return handler(args)
    except (UsageError, DataError) as exc:
        print(f"excite: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # stdout closed by the reader (| head): a normal end
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes at exit
        return EXIT_OK
    except KeyboardInterrupt:
        print("excite: interrupted (compare keeps finished episodes: re-run the same command "
              "to continue)", file=sys.stderr)
        return 130
    except Exception as exc:  # never a traceback for users; EXCITE_DEBUG=1 shows it
        if os.environ.get("EXCITE_DEBUG"):
            raise
        print(f"excite: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
