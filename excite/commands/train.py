"""``excite train``: train an excitation policy with stable-baselines3."""

from __future__ import annotations

import argparse
from pathlib import Path

from excite.commands.args import positive_int


def add_parser(sub: argparse._SubParsersAction) -> None:
    trn = sub.add_parser("train", help="train an excitation policy (stable-baselines3)")
    trn.add_argument("--algo", choices=("ppo", "sac"), default="ppo")
    trn.add_argument("--timesteps", type=positive_int, default=1_000_000, metavar="N")
    trn.add_argument("--n-envs", type=positive_int, default=None, metavar="E",
                     help="parallel environments (default: from the config)")
    trn.add_argument("--seed", type=int, default=0, metavar="S")
    trn.add_argument("--config", metavar="FILE.yaml",
                     help="hyperparameters (default: agents/configs/ALGO.yaml)")
    trn.add_argument("--out", required=True, metavar="DIR")
    trn.add_argument("--resume", action="store_true",
                     help="continue from the last checkpoint in DIR (same settings)")
    trn.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from agents.train import train

    summary = train(args.out, algo=args.algo, timesteps=args.timesteps, n_envs=args.n_envs,
                    seed=args.seed, resume=args.resume, config_path=args.config)
    print(f"trained {summary['algo']} to {summary['timesteps']} steps in "
          f"{summary['wall_time_s']:.0f} s ({summary['fps'] or 0:.0f} steps/s); "
          f"best policy: {Path(args.out) / 'best_model.zip'}")
    return 0
