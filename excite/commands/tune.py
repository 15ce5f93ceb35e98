"""``excite tune``: choose each protocol's settings on tuning episodes, for ``compare --tuned``
(:mod:`agents.tuning` holds the method)."""

from __future__ import annotations

import argparse
from pathlib import Path

from excite.commands.args import UsageError, check_output_file
from excite.commands.exit_status import EXIT_OK
from excite.commands.options import (
    add_episode_options,
    check_backend_options,
    episode_settings,
    protocol_specs,
    runnable,
)

#: What ``excite tune --help`` says the command does.
DESCRIPTION = """Choose each protocol's settings for excite compare --tuned. Every candidate setting
(the values of each protocol's parameters marked tuned in excite protocols) runs on the same
tuning episodes, whose seeds never meet compare's; the setting with the lowest median final max
relative error wins. The episodes are kept in TUNED.tuning/ beside --out, so an interrupted run
re-run with the same command continues where it stopped."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    tune = sub.add_parser("tune", help="tune protocol settings on tuning episodes",
                          description=DESCRIPTION)
    add_episode_options(tune, episodes=50)
    tune.add_argument("--out", required=True, metavar="TUNED.json",
                      help="the tuned settings, a .json file (required); the episodes go to "
                      "the folder TUNED.tuning/ beside it")
    tune.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from agents.tables import format_tuning
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
    return EXIT_OK
