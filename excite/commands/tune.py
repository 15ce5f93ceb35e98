"""``excite tune``: choose each protocol's settings on tuning episodes, for ``compare --tuned``.

Every candidate setting (the grid of each protocol's tunable parameters, ``excite protocols``)
runs on the same tuning episodes, whose seeds are disjoint from every evaluation seed; the
setting with the lowest median final max error wins (:mod:`agents.tuning`). The episodes are
kept in ``TUNED.tuning/`` beside the output, so an interrupted run re-run with the same
command continues where it stopped.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from excite.commands.args import UsageError, check_output_file
from excite.commands.compare import (
    add_episode_options,
    check_backend_options,
    episode_settings,
    protocol_specs,
    runnable,
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    tune = sub.add_parser("tune", help="tune protocol settings on tuning episodes")
    add_episode_options(tune, episodes=50)
    tune.add_argument("--out", required=True, metavar="TUNED.json",
                      help="the tuned settings (JSON); the episodes go to TUNED.tuning/")
    tune.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from agents.report import format_tuning
    from agents.tuning import run_tuning, work_dir

    out = Path(args.out)
    if out.suffix != ".json":
        raise UsageError(f"--out must name a .json file, got {out}")
    check_output_file(out)
    check_backend_options(args)
    settings = episode_settings(args)
    specs, _ = runnable(protocol_specs(args), settings)
    try:
        document = run_tuning(out, specs, args.episodes, settings, args.workers,
                              backend=args.backend, address=args.address)
    except OSError as exc:
        raise UsageError(f"cannot write {out} or {work_dir(out)}: {exc.strerror}") from None
    print(format_tuning(document))
    print(f"\ntuned settings: {out} (episodes: {work_dir(out)}); use them with "
          f"excite compare --tuned {out}")
    return 0
