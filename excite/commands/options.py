"""The options several subcommands share, each default defined once, and what their values
become: the simulated robot and the seed (``compare``, ``tune``, ``simulate``), the episodes
(``compare``, ``tune``), the backend that runs them (``compare``, ``tune``, ``sweep``) and the
folder of a training run (``train``, ``sweep``).

Help texts name registries through the fields of :mod:`excite.commands.parser`
(``%(protocols)s``, ``%(robot_presets)s``); heavy layers are imported inside the functions
that read the values.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from excite.commands.args import (
    UsageError,
    env_id,
    nonnegative_int,
    positive_int,
    robot_preset,
)
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID, ENTRY_POINT, ENV_IDS

if TYPE_CHECKING:  # the heavy layers are imported inside the functions that run them
    from agents.catalog import ProtocolSpec
    from agents.compare import CompareSettings

__all__ = ["DEFAULT_ROBOT", "DEFAULT_SEED", "BACKENDS", "ENV_HELP", "add_robot_options",
           "add_seed_option", "add_episode_options", "add_backend_options", "add_run_folder",
           "check_backend_options", "run_folder", "episode_settings", "protocol_specs", "runnable"]

#: The robot preset of --robot (a key of envs.robot.PRESETS).
DEFAULT_ROBOT = "default"
#: The seed of --seed in compare, tune and simulate.
DEFAULT_SEED = 0
#: --backend's choices, the names of agents.backends.BACKENDS (not imported to build the
#: parser); the first is the default.
BACKENDS = ("local", "ray")

#: The help of --env: every id excite registers, and a user's own.
ENV_HELP = ("gymnasium id of the simulated environment: "
            + ", ".join(f"{id_} (default)" if id_ == DEFAULT_ENV_ID else id_ for id_ in ENV_IDS)
            + f", or an id a user registered with excite's environment class ({ENTRY_POINT})")


def add_seed_option(parser: argparse.ArgumentParser, text: str) -> None:
    """--seed S, a whole number >= 0 (default DEFAULT_SEED); ``text`` is its help: what it
    seeds."""
    parser.add_argument("--seed", type=nonnegative_int, default=DEFAULT_SEED, metavar="S",
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


def add_episode_options(parser: argparse.ArgumentParser, episodes: int) -> None:
    """The options ``compare`` and ``tune`` share: which protocols, on which episodes, where
    they run."""
    parser.add_argument("--protocols", metavar="A,B:KEY=VALUE,...",
                        help="protocols, each NAME[:KEY=VALUE...] with NAME one of "
                        "%(protocols)s, or a user's module:Class[:KEY=VALUE...] (see excite "
                        "protocols); default: every protocol available (learned if a policy "
                        "exists)")
    parser.add_argument("--episodes", type=positive_int, default=episodes, metavar="N",
                        help="episodes (hidden robots) per protocol (default %(default)s)")
    parser.add_argument("--segments", type=positive_int, default=DEFAULT_BUDGET, metavar="K",
                        help="segments per episode, each one action held for the env's "
                        "segment duration (default %(default)s)")
    add_seed_option(parser, "seed of the episodes' seeds (compare draws evaluation seeds, tune "
                    "tuning seeds: the two never meet; default %(default)s)")
    add_robot_options(parser)
    parser.add_argument("--workers", type=positive_int, default=None, metavar="W",
                        help="worker processes of the local backend (default: all cores)")
    add_backend_options(parser)


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
    """The folder of :func:`add_run_folder`; UsageError when it is a file."""
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
    """The CompareSettings of the command line (env, segments, seed, robot), checked."""
    from agents.compare import CompareSettings

    return CompareSettings(env_id=env_id(args.env), segments=args.segments, seed=args.seed,
                           robot=robot_preset(args.robot))


def protocol_specs(args: argparse.Namespace) -> list[ProtocolSpec]:
    """The protocols of ``--protocols`` (or every available one), with ``--policy``."""
    from agents.catalog import default_protocols, parse_protocols, with_policy

    if args.policy and not Path(args.policy).is_file():
        raise UsageError(f"--policy: no such file {args.policy}")
    if args.protocols is None:
        return default_protocols(args.policy)
    return with_policy(parse_protocols(args.protocols), args.policy)


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
