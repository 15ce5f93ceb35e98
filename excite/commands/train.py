"""``excite train``: train an excitation policy with stable-baselines3 (:mod:`agents.train`
holds the training and the config format)."""

from __future__ import annotations

import argparse

from excite.commands.args import UsageError, positive_int, seed_int
from excite.commands.exit_status import EXIT_OK
from excite.commands.options import add_run_folder, run_folder

#: --algo's choices: the names of agents.train.ALGOS, which lives beside stable-baselines3 and
#: torch (not imported to build the parser).
ALGOS = ("ppo", "sac")
#: What ``excite train --help`` says the command does.
DESCRIPTION = """Train a policy that drives the simulated robot so that its wheel radii and
separation are identified fast (the learned protocol). DIR receives the effective config.yaml,
checkpoints, evaluations and best_model.zip (use it with excite compare --protocols learned
--policy DIR/best_model.zip). Needs the rl extra."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    trn = sub.add_parser("train", help="train an excitation policy (stable-baselines3)",
                         description=DESCRIPTION)
    trn.add_argument("--algo", choices=ALGOS, default=None,
                     help="reinforcement-learning algorithm: %(choices)s (default: the "
                     "config's algo, else ppo)")
    trn.add_argument("--timesteps", type=positive_int, default=1_000_000, metavar="N",
                     help="environment steps (segments) to train for, over all parallel "
                     "environments (default %(default)s)")
    trn.add_argument("--n-envs", type=positive_int, default=None, metavar="E",
                     help="parallel environments (default: the config's n_envs)")
    trn.add_argument("--seed", type=seed_int, default=None, metavar="S",
                     help="seed of the training (default: the config's seed, else 0)")
    trn.add_argument("--config", metavar="FILE.yaml",
                     help="training config: hyperparameters, environments, evaluation "
                     "(default: the shipped agents/configs/ALGO.yaml)")
    add_run_folder(trn, "the run's folder, new or empty (required; with --resume, the run to "
                   "continue)")
    trn.add_argument("--resume", action="store_true",
                     help="continue the run in DIR from its last checkpoint, with its own "
                     "settings (no --algo, --config, --seed or --n-envs)")
    trn.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    out = run_folder(args)
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
    return EXIT_OK
