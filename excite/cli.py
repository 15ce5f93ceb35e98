"""The ``excite`` command line: the one place that wires every layer together.

Heavy layers (gymnasium, pymunk, torch, matplotlib) are imported lazily inside the
subcommands that need them. Exit status: 0 success; 2 bad input or usage (one line
``excite: error: ...`` on stderr); 3 when ``calibrate`` finds the data cannot determine all
three parameters (the report is still printed).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence

from excite import __version__
from excite.data import DataError

EXIT_OK, EXIT_FAILURE, EXIT_USAGE, EXIT_UNIDENTIFIABLE = 0, 1, 2, 3


class UsageError(Exception):
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


def cmd_calibrate(args: argparse.Namespace) -> int:
    from excite.calibration import calibrate
    from excite.data import load_segments
    from excite.export import write_ros2_yaml

    segments = load_segments(args.file)
    sigma = _sigma_arg(args.sigma) if args.sigma else None
    initial = _params_arg(args.init) if args.init else None
    result = calibrate(segments, initial=initial, sigma=sigma, loss=args.loss)
    if args.json:
        print(json.dumps(result.to_dict(), indent=2))
    else:
        print(result.summary())
    if args.ros2_yaml:
        try:
            write_ros2_yaml(args.ros2_yaml, result.params, nominal=initial)
        except OSError as exc:
            raise UsageError(f"cannot write {args.ros2_yaml}: {exc.strerror}") from None
        if not args.json:
            print(f"wrote ROS 2 diff_drive_controller parameters to {args.ros2_yaml}")
    return EXIT_OK if result.identifiable else EXIT_UNIDENTIFIABLE


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="excite", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"excite {__version__}")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser, metavar="COMMAND")

    cal = sub.add_parser("calibrate", help="estimate r_L, r_R, b from a segment CSV")
    cal.add_argument("file", metavar="FILE.csv")
    cal.add_argument("--json", action="store_true", help="print one JSON object")
    cal.add_argument("--sigma", metavar="SX,SY,STH",
                     help="noise std of dx, dy (m) and dtheta (rad); default: estimated")
    cal.add_argument("--loss", choices=("linear", "huber"), default="linear")
    cal.add_argument("--init", metavar="RL,RR,B",
                     help="initial guess / nominal robot in meters; default: found from data")
    cal.add_argument("--ros2-yaml", metavar="OUT.yaml",
                     help="write diff_drive_controller parameters (nominal from --init)")
    cal.set_defaults(handler=cmd_calibrate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        handler: Callable[[argparse.Namespace], int] | None = getattr(args, "handler", None)
        if handler is None:
            raise UsageError("a command is required (calibrate); see excite --help")
        return handler(args)
    except (UsageError, DataError) as exc:
        print(f"excite: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("excite: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # never a traceback for users; EXCITE_DEBUG=1 shows it
        if os.environ.get("EXCITE_DEBUG"):
            raise
        print(f"excite: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
