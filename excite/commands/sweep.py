"""``excite sweep``: train policies over seeds and hyperparameter ranges with Ray Tune.

The config format is documented in :mod:`agents.sweep` (example:
``agents/configs/sweep_example.yaml``). Re-running the same command with the same ``--out``
resumes the sweep.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from excite.commands.args import UsageError
from excite.commands.compare import add_backend_options, check_backend_options


def add_parser(sub: argparse._SubParsersAction) -> None:
    swp = sub.add_parser("sweep", help="train over seeds and hyperparameter ranges (Ray Tune, "
                         "ASHA early stopping)")
    swp.add_argument("config", metavar="CONFIG.yaml",
                     help="seeds, ranges and budget (see agents/configs/sweep_example.yaml)")
    swp.add_argument("--out", required=True, metavar="DIR",
                     help="trials, trials.csv and best_model.zip; re-run to resume")
    add_backend_options(swp, local="a new Ray on this machine")
    swp.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    check_backend_options(args)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file, not a folder")
    from agents.sweep import run_sweep, summary_lines

    rows = run_sweep(args.config, out, args.backend, args.address)
    print("\n".join(summary_lines(rows)))
    print(f"\ntrials: {out / 'trials.csv'}; best policy: {out / 'best_model.zip'} (use it with "
          f"excite compare --protocols learned --policy {out / 'best_model.zip'})")
    return 0
