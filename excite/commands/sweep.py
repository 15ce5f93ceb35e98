"""``excite sweep``: train policies over seeds and hyperparameter ranges with Ray Tune
(:mod:`agents.sweep` holds the sweep and documents its config format)."""

from __future__ import annotations

import argparse

from excite.commands.exit_status import EXIT_OK
from excite.commands.options import (
    add_backend_options,
    add_run_folder,
    check_backend_options,
    run_folder,
)

#: What ``excite sweep --help`` says the command does.
DESCRIPTION = """Train policies (as excite train does) over seeds and hyperparameter ranges with Ray
Tune, stopping poor trials early (ASHA), and keep the best policy. Re-running the same command
with the same --out resumes the sweep. Needs the rl and ray extras."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    swp = sub.add_parser("sweep", help="train over seeds and hyperparameter ranges (Ray Tune)",
                         description=DESCRIPTION)
    swp.add_argument("config", metavar="CONFIG.yaml",
                     help="the sweep: seeds, hyperparameter ranges and budget (example: "
                     "agents/configs/sweep_example.yaml)")
    add_run_folder(swp, "the sweep's folder (required): trials, trials.csv and best_model.zip; "
                   "re-run to resume")
    add_backend_options(swp, local="a new Ray on this machine")
    swp.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    check_backend_options(args)
    out = run_folder(args)
    from agents.sweep import run_sweep, summary_lines

    rows = run_sweep(args.config, out, args.backend, args.address)
    print("\n".join(summary_lines(rows)))
    print(f"\ntrials: {out / 'trials.csv'}; best policy: {out / 'best_model.zip'} (use it with "
          f"excite compare --protocols learned --policy {out / 'best_model.zip'})")
    return EXIT_OK
