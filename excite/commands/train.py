"""``excite train``: train an excitation policy with stable-baselines3."""

from __future__ import annotations

import argparse
from pathlib import Path

from excite.commands.args import UsageError, nonnegative_int, positive_int


def add_parser(sub: argparse._SubParsersAction) -> None:
    trn = sub.add_parser("train", help="train an excitation policy (stable-baselines3)")
    trn.add_argument("--algo", choices=("ppo", "sac"), default=None,
                     help="default: the config's algo, else ppo")
    trn.add_argument("--timesteps", type=positive_int, default=1_000_000, metavar="N")
    trn.add_argument("--n-envs", type=positive_int, default=None, metavar="E",
                     help="parallel environments (default: from the config)")
    trn.add_argument("--seed", type=nonnegative_int, default=None, metavar="S",
                     help="default: the config's seed, else 0")
    trn.add_argument("--config", metavar="FILE.yaml",
                     help="hyperparameters (default: agents/configs/ALGO.yaml)")
    trn.add_argument("--out", required=True, metavar="DIR",
                     help="a new or empty folder (or, with --resume, the run to continue)")
    trn.add_argument("--resume", action="store_true",
                     help="continue from the last checkpoint in DIR (its own settings)")
    trn.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file, not a folder")
    if args.resume:
        given = [option for option, value in (("--algo", args.algo), ("--config", args.config),
                                              ("--seed", args.seed), ("--n-envs", args.n_envs))
                 if value is not None]
        if given:
            raise UsageError(f"--resume continues the run in {out} with its own settings "
                             f"({out / 'config.yaml'}); drop {', '.join(given)}")
    elif out.exists() and any(out.iterdir()):
        raise UsageError(f"--out {out} is not empty (another run?); use --resume to continue "
                         "it, or a new folder")
    from agents.train import train

    summary = train(out, algo=args.algo, timesteps=args.timesteps, n_envs=args.n_envs,
                    seed=args.seed, resume=args.resume, config_path=args.config)
    print(f"trained {summary['algo']} to {summary['timesteps']} steps in "
          f"{summary['wall_time_s']:.0f} s ({summary['fps'] or 0:.0f} steps/s); "
          f"best policy: {out / 'best_model.zip'}")
    return 0
