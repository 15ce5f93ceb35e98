"""``excite compare``: run calibration protocols on the same hidden robots and report.

Protocols are written ``NAME[:KEY=VALUE...]`` (``excite protocols`` lists names and
parameters; a user's protocol is ``module:Class``). ``--estimators`` adds a second axis:
every protocol runs with every estimator (``online``, ``ekf``, ``window``, with
``:KEY=VALUE`` settings, or a user's ``module:factory``) on the same episodes. Settings
tuned by ``excite tune`` apply to the protocols written as they were tuned (``--tuned``); by
default the settings the package ships for ``--env`` and ``--robot`` (when tuned for the same
segments).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from excite.commands.args import (
    UsageError,
    env_id,
    nonnegative_int,
    output_folder,
    positive_int,
    robot_preset,
)
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID

if TYPE_CHECKING:  # the heavy layers are imported inside the functions that run them
    from agents.catalog import ProtocolSpec
    from agents.compare import CompareSettings
    from excite.estimators import EstimatorSpec

#: --tuned values that are not files.
TUNED_AUTO, TUNED_NONE = "auto", "none"


def add_episode_options(parser: argparse.ArgumentParser, episodes: int) -> None:
    """The options ``compare`` and ``tune`` share: which protocols, on which episodes."""
    parser.add_argument("--protocols", metavar="A,B:KEY=VALUE,...",
                        help="protocols, each NAME[:KEY=VALUE...] or module:Class[:KEY=VALUE"
                        "...] (see excite protocols); default: every protocol available "
                        "(learned if a policy exists)")
    parser.add_argument("--episodes", type=positive_int, default=episodes, metavar="N",
                        help=f"episodes (hidden robots) per protocol (default {episodes})")
    parser.add_argument("--segments", type=positive_int, default=DEFAULT_BUDGET, metavar="K",
                        help=f"segments per episode (default {DEFAULT_BUDGET})")
    parser.add_argument("--seed", type=nonnegative_int, default=0, metavar="S",
                        help="seed of the episodes' seeds (compare draws evaluation seeds, "
                        "tune tuning seeds: the two never meet)")
    parser.add_argument("--env", default=DEFAULT_ENV_ID, metavar="ID")
    parser.add_argument("--workers", type=positive_int, default=None, metavar="W",
                        help="worker processes of the local backend (default: all cores)")
    add_backend_options(parser)
    parser.add_argument("--policy", metavar="PATH",
                        help="policy file of the learned protocol (its policy setting)")
    parser.add_argument("--robot", default="default", metavar="PRESET",
                        help="robot preset: default, turtlebot3, jackal, husky")


def add_backend_options(parser: argparse.ArgumentParser,
                        local: str = "worker processes on this machine") -> None:
    """--backend local|ray and --address (where the episodes or trials run); ``local`` says
    what the local backend is."""
    parser.add_argument("--backend", choices=("local", "ray"), default="local",
                        help=f"local: {local} (default); ray: the Ray cluster of --address")
    parser.add_argument("--address", metavar="ADDR",
                        help="the Ray cluster (HOST:PORT of its head, or auto); default: "
                        "RAY_ADDRESS, else the latest `ray start` cluster of this machine, "
                        "else a new local Ray")


def check_backend_options(args: argparse.Namespace) -> None:
    """A one-line error (BackendError) before any work when --backend and --address do not
    fit together."""
    from agents.backends import check_backend

    check_backend(args.backend, args.address)


def add_parser(sub: argparse._SubParsersAction) -> None:
    cmp_ = sub.add_parser("compare", help="compare calibration protocols on the same robots")
    add_episode_options(cmp_, episodes=20)
    cmp_.add_argument("--estimators", default=None, metavar="E,F:KEY=VALUE,...",
                      help="estimators, each online, ekf, window (with :KEY=VALUE settings) "
                      "or module:factory; every protocol runs with each on the same "
                      "episodes (default: online)")
    cmp_.add_argument("--tuned", default=TUNED_AUTO, metavar="TUNED.json",
                      help="settings from excite tune for the protocols written as tuned; "
                      "auto (default): those shipped for --env and --robot if tuned for these "
                      "segments; none: the declared defaults")
    cmp_.add_argument("--out", type=output_folder, default="excite_compare", metavar="DIR",
                      help="the results folder (made if missing; re-run with the same "
                      "settings to finish an interrupted comparison)")
    cmp_.set_defaults(handler=run)


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


def estimator_specs(args: argparse.Namespace) -> list[EstimatorSpec]:
    """The estimators of ``--estimators`` (default: the env's default, ``online``)."""
    from excite.estimators import DEFAULT_ESTIMATOR, parse_estimators

    return parse_estimators(DEFAULT_ESTIMATOR if args.estimators is None else args.estimators)


def check_estimators(estimators: list[EstimatorSpec], settings: CompareSettings) -> None:
    """Make each estimator once in the env (a reset): a factory that fails there (a user's
    ``module:factory`` with another signature, ...) is a one-line usage error before any
    episode runs."""
    from agents.compare import make_env

    for spec in estimators:
        probe = make_env(settings.env_id, settings.segments, settings.robot,
                         estimator_factory=spec)
        try:
            probe.reset(seed=0)  # a user's factory failing is an EstimatorError (named)
        finally:
            probe.close()


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


def tuned_specs(specs: list[ProtocolSpec], tuned: str, settings: CompareSettings,
                episodes: int) -> tuple[list[ProtocolSpec], dict[str, Any]]:
    """The protocols with the settings ``--tuned`` gives them, and what was applied (the
    summary's ``tuned`` entry: file, tuning episodes, protocols left at their defaults)."""
    from agents.catalog import check_distinct
    from agents.tuning import apply_tuned, check_disjoint, load_tuned, mismatch, shipped_path

    def defaults(why: str) -> tuple[list[ProtocolSpec], dict[str, Any]]:
        return specs, {"file": None, "note": f"declared defaults ({why})", "untuned": []}

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
    specs, untuned = apply_tuned(specs, document, str(path))
    note = (f"tuned by excite tune on {len(document['tuning_seeds'])} tuning episodes "
            f"(seeds disjoint from these): {path}")
    if untuned:
        note += f"; not tuned there, at their defaults: {', '.join(untuned)}"
    return check_distinct(specs), {"file": str(path), "note": note, "untuned": untuned}


def run(args: argparse.Namespace) -> int:
    from agents.compare import columns_of, run_comparison
    from agents.report import format_table, plot_comparison, summarize

    check_backend_options(args)
    settings = episode_settings(args)
    estimators = estimator_specs(args)
    specs, tuned = tuned_specs(protocol_specs(args), args.tuned, settings, args.episodes)
    specs, arena_size = runnable(specs, settings)
    check_estimators(estimators, settings)
    out = args.out
    for name in ("config.json", "segments.csv", "summary.json"):  # before any episode runs
        if (out / name).is_dir():
            raise UsageError(f"cannot write {out / name}: it is a folder; remove it or choose "
                             "another --out")
    try:
        rows = run_comparison(out, specs, args.episodes, settings, args.workers,
                              estimators=estimators, backend=args.backend,
                              address=args.address)
    except OSError as exc:
        raise UsageError(f"cannot write to {exc.filename or out}: {exc.strerror}") from None
    columns = columns_of(rows)
    summary = summarize(columns, seed=args.seed)
    summary["settings"] = {"env": settings.env_id, "segments": args.segments, "seed": args.seed,
                           "episodes": args.episodes,
                           "protocols": [spec.label for spec in specs],
                           "estimators": [spec.label for spec in estimators],
                           "robot": settings.robot, "tuned": tuned}
    summary["protocol_settings"] = {spec.label: spec.resolved() for spec in specs}
    try:
        (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
        plots = plot_comparison(columns, out, arena_size=arena_size)
    except OSError as exc:
        raise UsageError(f"cannot write {exc.filename or out}: {exc.strerror}") from None
    print(format_table(summary))
    print(f"settings: {tuned['note']}")
    print(f"\nresults: {out / 'segments.csv'}, {out / 'summary.json'}")
    print("plots:   " + ", ".join(str(p) for p in plots))
    return 0
