"""The options several subcommands share, each default defined once, and what their values
become: the simulated robot and the seed (``compare``, ``tune``, ``simulate``), the episodes
(``compare``, ``tune``), the tuned protocol settings (``compare``, ``simulate``), the backend
that runs them (``compare``, ``tune``, ``sweep``) and the folder of a training run (``train``,
``sweep``).

Help texts name registries through the fields of :mod:`excite.commands.parser`
(``%(protocols)s``, ``%(robot_presets)s``); heavy layers are imported inside the functions
that read the values.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from excite.commands.args import (
    UsageError,
    env_id,
    positive_int,
    robot_preset,
    seed_int,
)
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID, ENTRY_POINT, ENV_IDS
from excite.stopping import DEFAULT_CONFIDENCE

if TYPE_CHECKING:  # the heavy layers are imported inside the functions that run them
    from agents.catalog import ProtocolSpec
    from agents.compare import CompareSettings

__all__ = ["DEFAULT_ROBOT", "DEFAULT_SEED", "BACKENDS", "ENV_HELP", "TUNED_AUTO", "TUNED_NONE",
           "add_robot_options", "add_seed_option", "add_episode_options", "add_tuned_option",
           "add_backend_options", "add_run_folder", "check_backend_options", "run_folder",
           "episode_settings", "protocol_specs", "tuned_specs", "runnable",
           "TARGET_SEGMENTS", "add_target_options"]

#: The robot preset of --robot (a key of envs.robot.PRESETS).
DEFAULT_ROBOT = "default"
#: The seed of --seed in compare, tune and simulate.
DEFAULT_SEED = 0
#: --tuned values that are not files: the settings shipped for --env and --robot (default),
#: or the protocols' declared defaults.
TUNED_AUTO, TUNED_NONE = "auto", "none"
#: --backend's choices, the names of agents.backends.BACKENDS (not imported to build the
#: parser); the first is the default.
BACKENDS = ("local", "ray")
#: The segments of an episode with --target when --segments is not given: the env's budget
#: in target mode (envs.config.TARGET_BUDGET, not imported to build the parser).
TARGET_SEGMENTS = 150

#: The help of --env: every id excite registers, and a user's own.
ENV_HELP = ("gymnasium id of the simulated environment: "
            + ", ".join(f"{id_} (default)" if id_ == DEFAULT_ENV_ID else id_ for id_ in ENV_IDS)
            + f", or an id a user registered with excite's environment class ({ENTRY_POINT})")


def add_result_options(parser, nominal: str) -> None:
    """--json, --ros2-yaml OUT.yaml and --force-yaml: how calibrate and live give their
    result. ``nominal``: the option giving the nominal robot the multipliers are relative to
    (``--init``, ``--nominal``)."""
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object instead of the report")
    parser.add_argument("--ros2-yaml", metavar="OUT.yaml",
                        help=f"write diff_drive_controller parameters (nominal from {nominal}) "
                        "and the sensor's static transform when estimated; not written when "
                        "the model does not fit (exit status 4) or the data do not determine "
                        "every parameter (exit status 3), a note says so; default: none "
                        "written")
    parser.add_argument("--force-yaml", action="store_true",
                        help="write --ros2-yaml even when the calibration failed (exit status "
                        "3 or 4); the file then starts with a comment saying it is unsafe and "
                        "why")


def add_seed_option(parser: argparse.ArgumentParser, text: str) -> None:
    """--seed S, a whole number in [0, 2**32) (default DEFAULT_SEED); ``text`` is its help:
    what it seeds."""
    parser.add_argument("--seed", type=seed_int, default=DEFAULT_SEED, metavar="S",
                        help=text)


def add_robot_options(parser: argparse.ArgumentParser) -> None:
    """--env, --robot and --policy: the simulated robot, and the learned protocol's policy."""
    parser.add_argument("--env", default=DEFAULT_ENV_ID, metavar="ID", help=ENV_HELP)
    parser.add_argument("--robot", default=DEFAULT_ROBOT, metavar="PRESET",
                        help="robot preset the hidden robots are drawn around: "
                        "%(robot_presets)s (default %(default)r)")
    parser.add_argument("--policy", metavar="PATH",
                        help="stable-baselines3 policy file (.zip) of the learned protocol "
                        "(its policy setting); default: the policy shipped with excite")


def add_episode_options(parser: argparse.ArgumentParser, episodes: int,
                        target: bool = False) -> None:
    """The options ``compare`` and ``tune`` share: which protocols, on which episodes, where
    they run. ``target``: the command has --target (:func:`add_target_options`), which
    changes the default of --segments."""
    parser.add_argument("--protocols", metavar="A,B:KEY=VALUE,...",
                        help="protocols, each NAME[:KEY=VALUE...] with NAME one of "
                        "%(protocols)s, or a user's module:Class[:KEY=VALUE...] (see excite "
                        "protocols); default: every protocol available (learned if a policy "
                        "exists)")
    parser.add_argument("--episodes", type=positive_int, default=episodes, metavar="N",
                        help="episodes (hidden robots) per protocol (default %(default)s)")
    parser.add_argument("--segments", type=positive_int,
                        default=None if target else DEFAULT_BUDGET, metavar="K",
                        help="segments per episode, each one action held for the env's "
                        f"segment duration (default {DEFAULT_BUDGET}"
                        + (f"; with --target the budget, default {TARGET_SEGMENTS})" if target
                           else ")"))
    add_seed_option(parser, "seed of the episodes' seeds (compare draws evaluation seeds, tune "
                    "tuning seeds: the two never meet; default %(default)s)")
    add_robot_options(parser)
    parser.add_argument("--workers", type=positive_int, default=None, metavar="W",
                        help="worker processes of the local backend (default: all cores)")
    add_backend_options(parser)


def add_tuned_option(parser: argparse.ArgumentParser) -> None:
    """--tuned TUNED.json|auto|none: the settings of the protocols written as tuned, read by
    :func:`tuned_specs`."""
    parser.add_argument("--tuned", default=TUNED_AUTO, metavar="TUNED.json",
                        help="settings from excite tune for the protocols written as tuned; "
                        f"{TUNED_AUTO} (default): those shipped for --env and --robot if tuned "
                        f"for these segments; {TUNED_NONE}: the declared defaults")


def _open_unit(option: str, what: str):
    """An argparse type: a number strictly between 0 and 1 (``what`` it is, in words)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not 0.0 < value < 1.0:
            raise argparse.ArgumentTypeError(f"must be {what} strictly between 0 and 1, "
                                             f"got {text!r}")
        return value

    parse.__name__ = option  # argparse names the type in its messages
    return parse


#: What --target does, by command: compare runs every episode to it, calibrate judges its
#: calibration against it.
_TARGET_HELP = {
    "episodes": "run every episode until the stopping rule (the batch calibration of the "
    "segments so far) says r_L, r_R and b are within relative error T (0.005 = 0.5%%; sensor x, "
    "y within T x b, its angle within T rad) or the budget ends it, and report the time to "
    "target, the false stops and the error at the stop; in (0, 1), dimensionless (default: "
    "off, fixed --segments)",
    "calibration": "say whether the calibration is good enough: r_L, r_R and b within relative "
    "error T (0.002 = 0.2%%; sensor x, y within T x b, its angle within T rad) at "
    "--target-confidence, by the stopping rule of excite live; if not yet, how many more "
    "segments (and seconds) of driving like this would get there (default: off)",
}


def add_target_options(parser: argparse.ArgumentParser, judged: str = "episodes") -> None:
    """--target T and --target-confidence C: with ``judged`` "episodes" (compare, tune) every
    episode runs until the stopping rule says the calibration is within T (the env's target
    mode); with "calibration" (calibrate) the stopping rule judges the calibration made
    (:meth:`excite.stopping.StoppingRule.judge`)."""
    parser.add_argument("--target", type=_open_unit("--target", "a relative error"),
                        default=None, metavar="T", help=_TARGET_HELP[judged])
    parser.add_argument("--target-confidence", type=_open_unit("--target-confidence",
                                                              "a confidence"),
                        default=None, metavar="C",
                        help="the stopping rule's confidence that every parameter is within "
                        f"the target, in (0, 1) (default {DEFAULT_CONFIDENCE}; only with "
                        "--target)")


def add_backend_options(parser: argparse.ArgumentParser,
                        local: str = "worker processes on this machine") -> None:
    """--backend local|ray and --address (where the episodes or trials run); ``local`` says
    what the local backend is."""
    parser.add_argument("--backend", choices=BACKENDS, default=BACKENDS[0],
                        help=f"where the work runs: local: {local} (default); ray: the Ray "
                        "cluster of --address")
    parser.add_argument("--address", metavar="ADDR",
                        help="the Ray cluster (HOST:PORT of its head, or auto; with --backend "
                        "ray); default: RAY_ADDRESS, else the latest `ray start` cluster of "
                        "this machine, else a new local Ray")


def add_run_folder(parser: argparse.ArgumentParser, text: str) -> None:
    """--out DIR (required): the folder of a training run or a sweep, read by
    :func:`run_folder`; ``text`` is its help."""
    parser.add_argument("--out", required=True, metavar="DIR", help=text)


def run_folder(args: argparse.Namespace) -> Path:
    """The folder of :func:`add_run_folder`; UsageError when it is empty or a file."""
    if not args.out.strip():  # Path("") is the working folder
        raise UsageError("--out is empty; give a folder")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file, not a folder")
    return out


def check_backend_options(args: argparse.Namespace) -> None:
    """A one-line error (BackendError) before any work when --backend and --address do not
    fit together."""
    from agents.backends import check_backend

    check_backend(args.backend, args.address)


def episode_settings(args: argparse.Namespace) -> CompareSettings:
    """The CompareSettings of the command line (env, segments, seed, robot; the target and
    its confidence where the command has --target), checked."""
    from agents.compare import CompareSettings

    target = getattr(args, "target", None)
    confidence = getattr(args, "target_confidence", None)
    if confidence is not None and target is None:
        raise UsageError("--target-confidence needs --target")
    segments = args.segments
    if segments is None:
        segments = DEFAULT_BUDGET if target is None else TARGET_SEGMENTS
    return CompareSettings(env_id=env_id(args.env), segments=segments, seed=args.seed,
                           robot=robot_preset(args.robot), target=target,
                           target_confidence=(DEFAULT_CONFIDENCE if confidence is None
                                              else confidence))


def protocol_specs(args: argparse.Namespace) -> list[ProtocolSpec]:
    """The protocols of ``--protocols`` (or every available one), with ``--policy``."""
    from agents.catalog import default_protocols, parse_protocols, with_policy

    if args.policy and not Path(args.policy).is_file():
        raise UsageError(f"--policy: no such file {args.policy}")
    if args.protocols is None:
        return default_protocols(args.policy)
    return with_policy(parse_protocols(args.protocols), args.policy)


def tuned_specs(specs: list[ProtocolSpec], tuned: str, settings: CompareSettings,
                episodes: int) -> tuple[list[ProtocolSpec], dict[str, Any]]:
    """The protocols with the settings ``--tuned`` gives them, and what was applied (the
    summary's ``tuned`` entry: file, tuning episodes, protocols left at their defaults).
    ``episodes``: the evaluation episodes of ``settings`` that must not be tuning episodes
    (0 for a run that evaluates nothing, as ``simulate``)."""
    from agents.catalog import check_distinct
    from agents.tuning import apply_tuned, check_disjoint, load_tuned, mismatch, shipped_path

    def defaults(why: str) -> tuple[list[ProtocolSpec], dict[str, Any]]:
        written = [spec.label for spec in specs if spec.settings]
        note = (f"declared defaults ({why})" if not written else
                f"as written ({', '.join(written)}), else declared defaults ({why})")
        return specs, {"file": None, "note": note, "untuned": []}

    if tuned == TUNED_NONE:
        return defaults("--tuned none")
    path = shipped_path(settings.env_id, settings.robot) if tuned == TUNED_AUTO else Path(tuned)
    if tuned == TUNED_AUTO and not path.exists():
        return defaults(f"no tuned settings are shipped for {settings.env_id} and the "
                        f"{settings.robot} robot")
    document = load_tuned(path)
    if reason := mismatch(document, settings):
        if tuned != TUNED_AUTO:
            raise UsageError(f"--tuned {path}: {reason}; run excite tune for these settings "
                             "or give --tuned none")
        return defaults(f"the shipped settings were {reason}")
    check_disjoint(document, settings, episodes)
    written = {spec.label for spec in specs if spec.settings}
    specs, missing = apply_tuned(specs, document, str(path))
    untuned = [label for label in missing if label not in written]
    written_only = [label for label in missing if label in written]
    parts = [f"as written ({', '.join(written_only)})"] if written_only else []
    if len(missing) < len(specs):
        parts.append(f"tuned by excite tune on {len(document['tuning_seeds'])} tuning episodes"
                     + (" (seeds disjoint from these)" if episodes else "") + f": {path}")
    if untuned:
        parts.append(f"not tuned there, at their defaults: {', '.join(untuned)}")
    note = "; ".join(parts)
    return check_distinct(specs), {"file": str(path), "note": note, "untuned": untuned}


def runnable(specs: list[ProtocolSpec],
             settings: CompareSettings) -> tuple[list[ProtocolSpec], float]:
    """The protocols that can run on the env (the others skipped, each with a one-line note
    on stderr) and the env's arena size (m)."""
    from agents.compare import incompatible_protocols, make_env

    probe = make_env(settings.env_id, settings.segments, settings.robot)
    shape, arena_size = probe.observation_space.shape, float(probe.unwrapped.config["arena_size"])
    probe.close()
    skipped = incompatible_protocols(specs, shape)
    for label, reason in skipped.items():
        print(f"excite: skipping {label}: {reason}", file=sys.stderr)
    specs = [spec for spec in specs if spec.label not in skipped]
    if not specs:
        raise UsageError("no protocol can run on this environment")
    return specs, arena_size
