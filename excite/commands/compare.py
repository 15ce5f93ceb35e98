"""``excite compare``: run calibration protocols, each with each estimator, on the same hidden
robots and report (:mod:`agents.compare` runs the episodes, :mod:`agents.summary` sums them up).
"""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from excite.commands.args import UsageError, output_folder
from excite.commands.exit_status import EXIT_OK
from excite.commands.options import (
    add_episode_options,
    add_target_options,
    add_tuned_option,
    check_backend_options,
    episode_settings,
    protocol_specs,
    runnable,
    tuned_specs,
)
from excite.estimators import (
    DEFAULT_ESTIMATOR,
    ESTIMATORS,
    OPTIONS,
    EstimatorSpec,
    parse_estimators,
)

if TYPE_CHECKING:  # the heavy layers are imported inside the functions that run them
    from agents.compare import CompareSettings

#: What ``excite compare --help`` says the command does.
DESCRIPTION = (
    "Run calibration protocols on the same hidden robots (episodes) and report how fast each "
    "identifies them: a table, segments.csv, summary.json and plots in --out. Protocols are "
    "written NAME[:KEY=VALUE...] (excite protocols lists the names and parameters). "
    "--estimators adds a second axis: every protocol runs with every estimator on the same "
    "episodes. Settings tuned by excite tune apply to the protocols written as they were "
    "tuned (--tuned); by default the settings shipped for --env and --robot. --target runs "
    "every episode until the stopping rule says the calibration is within the target and "
    "reports how long that took, the false stops and the error at the stop.")
#: The settings each built-in estimator takes (``name:key=value``), for the help.
ESTIMATOR_SETTINGS = "; ".join(f"{name}: {', '.join(keys)}" for name, keys in OPTIONS.items())


def add_parser(sub: argparse._SubParsersAction) -> None:
    cmp_ = sub.add_parser("compare", help="compare calibration protocols on the same robots",
                          description=DESCRIPTION)
    add_episode_options(cmp_, episodes=20, target=True)
    add_target_options(cmp_)
    cmp_.add_argument("--estimators", default=None, metavar="E,F:KEY=VALUE,...",
                      help=f"estimators, each one of {', '.join(ESTIMATORS)} with optional "
                      f":KEY=VALUE settings ({ESTIMATOR_SETTINGS}), or a user's "
                      "module:factory; every protocol runs with each on the same episodes "
                      f"(default: {DEFAULT_ESTIMATOR})")
    add_tuned_option(cmp_)
    cmp_.add_argument("--out", type=output_folder, default="excite_compare", metavar="DIR",
                      help="the results folder (made if missing; default %(default)s); re-run "
                      "with the same settings to finish an interrupted comparison")
    cmp_.set_defaults(handler=run)


def estimator_specs(args: argparse.Namespace) -> list[EstimatorSpec]:
    """The estimators of ``--estimators`` (default: the env's default, ``online``)."""
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


def run(args: argparse.Namespace) -> int:
    from agents.compare import columns_of, run_comparison
    from agents.plots import plot_comparison
    from agents.summary import summarize
    from agents.tables import format_table

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
    if settings.target is not None:
        from agents.target_summary import add_target

        add_target(summary, columns, settings.target, settings.target_confidence,
                   settings.segments, seed=args.seed)
    summary["settings"] = {"env": settings.env_id, "segments": settings.segments,
                           "seed": args.seed,
                           "episodes": args.episodes,
                           "protocols": [spec.label for spec in specs],
                           "estimators": [spec.label for spec in estimators],
                           "robot": settings.robot, "tuned": tuned}
    if settings.target is not None:
        summary["settings"] |= {"target": settings.target,
                                "target_confidence": settings.target_confidence}
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
    return EXIT_OK
