"""The ``excite`` command line: builds the parser of every subcommand (one module each in
:mod:`excite.commands`) and runs the one asked for, turning every way a command ends into its
exit status (:mod:`excite.commands.exit_status`).

Heavy layers (gymnasium, pymunk, torch, matplotlib, rosbags) are imported inside a command's
``run``, so ``excite --version`` and the core commands stay light. A closed stdout (``| head``)
is a normal end. numpy's RuntimeWarnings (overflow, invalid values on the way to an error or a
rejected trial step) stay off stderr, so an error is one line; ``EXCITE_DEBUG=1`` shows them
and tracebacks.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import textwrap
import warnings
from collections.abc import Callable, Sequence

from excite import __version__
from excite.commands import (
    calibrate,
    compare,
    live,
    protocols,
    segment,
    sim_robot,
    simulate,
    sweep,
    train,
    tune,
    validate,
)
from excite.commands.args import UsageError
from excite.commands.exit_status import (
    EXIT_FAILURE,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    MEANINGS,
)
from excite.commands.parser import CommandsHelpFormatter, Parser
from excite.errors import ExciteError
from excite.signals import handled

__all__ = ["main", "build_parser"]

COMMANDS = (calibrate, segment, validate, simulate, protocols, compare, tune, train, sweep, live,
            sim_robot)

#: The optional extra that provides each third-party module a subcommand may import.
EXTRA_OF_MODULE = {"rosbags": "ros", "gymnasium": "sim", "pymunk": "sim", "matplotlib": "sim",
                   "tqdm": "sim", "yaml": "sim", "stable_baselines3": "rl", "torch": "rl",
                   "ray": "ray", "rclpy": "ros2", "geometry_msgs": "ros2",
                   "sensor_msgs": "ros2", "nav_msgs": "ros2", "rosgraph_msgs": "ros2"}

#: What ``excite --help`` says excite is.
DESCRIPTION = textwrap.fill(
    "Calibrate a differential-drive robot: estimate its wheel radii r_L, r_R and wheel "
    "separation b (m), and the pose of an external pose sensor on it, from wheel-encoder "
    "readings and the sensor's poses (segment files, time-series logs or ROS bags). In "
    "simulation, compare the maneuvers (protocols) that identify a robot fastest, tune them "
    "and train a policy that drives them.", 79)
#: The end of ``excite --help``: the exit statuses, the extras, where the options are.
EPILOG = "\n".join([
    "exit status:",
    *(textwrap.fill(meaning, 79, initial_indent=f"  {status:<5}", subsequent_indent=" " * 7)
      for status, meaning in MEANINGS.items()),
    "",
    textwrap.fill("simulate, compare, tune, train and sweep need the sim extra (pip install "
                  "'excite[sim]'), train and sweep also rl, sweep also ray; ROS bags need ros; "
                  "live needs ros2, sim-robot sim and ros2. "
                  "excite COMMAND --help describes a command and its options.", 79),
])


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="excite", description=DESCRIPTION, epilog=EPILOG,
                    formatter_class=CommandsHelpFormatter)
    parser.add_argument("--version", action="version", version=f"excite {__version__}",
                        help="print excite's version and exit")
    sub = parser.add_subparsers(dest="command", parser_class=Parser, metavar="COMMAND",
                                title="commands")
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def _missing_extra(exc: ModuleNotFoundError, command: str | None) -> str | None:
    top = (exc.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(top)
    if extra is None:
        return None
    return (f"excite {command or ''} needs the {extra} extra (module {top} is not installed): "
            f"pip install 'excite[{extra}]'").replace("excite  ", "excite ")


def _terminate_as_interrupt():
    """SIGTERM (a job scheduler, ``kill``) ends a command as Ctrl-C does: finished work kept,
    worker pools shut down, one line on stderr (in the main thread; restored afterwards)."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    return handled((signal.SIGTERM,), interrupt)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = None
    try:
        args = parser.parse_args(argv)
        handler: Callable[[argparse.Namespace], int] | None = getattr(args, "handler", None)
        if handler is None:
            names = ", ".join(c.__name__.rsplit(".", 1)[1].replace("_", "-") for c in COMMANDS)
            raise UsageError(f"a command is required ({names}); see excite --help")
        with warnings.catch_warnings(), _terminate_as_interrupt():
            if not os.environ.get("EXCITE_DEBUG"):
                warnings.simplefilter("ignore", RuntimeWarning)
            return handler(args)
    except ExciteError as exc:
        print(f"excite: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # stdout closed by the reader (| head): a normal end
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes at exit
        return EXIT_OK
    except KeyboardInterrupt:
        print("excite: interrupted (compare, tune and sweep keep finished work: re-run the "
              "same command to continue)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # never a traceback for users; EXCITE_DEBUG=1 shows it
        if isinstance(exc, ModuleNotFoundError) and (
                message := _missing_extra(exc, getattr(args, "command", None))):
            print(f"excite: error: {message}", file=sys.stderr)
            return EXIT_USAGE
        if os.environ.get("EXCITE_DEBUG"):
            raise
        if isinstance(exc, OSError) and exc.filename is not None:
            # a path the system refuses (no such folder, a name too long, a read-only
            # place): the user's input, not a bug
            print(f"excite: error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
            return EXIT_USAGE
        print(f"excite: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
