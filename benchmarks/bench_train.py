"""PPO end-to-end training throughput (issue 12, acceptance 3): the shipped policy's old setup
(main's ppo.yaml before issue 12: 4 single envs in a DummyVecEnv, n_steps 512, batch 256,
10 epochs, MLP 128x128) against the current agents/configs/ppo.yaml, side by side in
alternating rounds of one run (a shared 2-core machine moves absolute times by 2x or more).

Each round trains a fresh model of each setup for ``--steps`` environment steps (model.learn,
no callbacks) and splits its wall time into rollout collection (env steps, policy forward
passes, normalization) and PPO's update. Printed: per setup the median steps/s over the
rounds with the rollout / update shares, and the median over rounds of the per-round ratio
new / old.

Usage: python benchmarks/bench_train.py [--steps 50000] [--rounds 3] [--config FILE.yaml]
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import torch
from tqdm import tqdm

from agents.train import load_config, make_model, make_training_env

#: main's ppo.yaml before issue 12 (the shipped policy of issue 5 was trained with it).
OLD_SETUP = {"n_envs": 4, "vec_env": "dummy", "n_steps": 512, "batch_size": 256, "n_epochs": 10,
             "net_arch": [128, 128]}


def old_config(config: dict) -> dict:
    """``config`` with the old setup's vectorisation, rollout, update and network."""
    old = copy.deepcopy(config)
    old.update(n_envs=OLD_SETUP["n_envs"], vec_env=OLD_SETUP["vec_env"], torch_threads=1)
    old["hyperparams"].update({k: OLD_SETUP[k] for k in ("n_steps", "batch_size", "n_epochs")})
    old["policy_kwargs"] = dict(old.get("policy_kwargs") or {}, net_arch=OLD_SETUP["net_arch"])
    return old


def time_training(config: dict, steps: int, seed: int = 0) -> dict:
    """Wall time (s) of model.learn(steps) on a fresh model, split into rollout and update."""
    torch.set_num_threads(config.get("torch_threads", 1))
    venv = make_training_env(config, config["n_envs"], seed)
    model = make_model(config, venv, seed)
    spent = {"rollout": 0.0, "update": 0.0}
    collect, update = model.collect_rollouts, model.train

    def timed_collect(*args, **kwargs):
        start = time.perf_counter()
        result = collect(*args, **kwargs)
        spent["rollout"] += time.perf_counter() - start
        return result

    def timed_update() -> None:
        start = time.perf_counter()
        update()
        spent["update"] += time.perf_counter() - start

    model.collect_rollouts, model.train = timed_collect, timed_update
    start = time.perf_counter()
    model.learn(total_timesteps=steps)
    wall = time.perf_counter() - start
    venv.close()
    return {"steps": model.num_timesteps, "wall_s": wall, **spent,
            "steps_per_s": model.num_timesteps / wall}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--config", default=None,
                        help="new setup (default: agents/configs/ppo.yaml)")
    args = parser.parse_args(argv)
    new = dict(load_config("ppo", args.config), algo="ppo")
    setups = {"old (issue 5)": old_config(new), "new (ppo.yaml)": new}
    runs: dict[str, list[dict]] = {name: [] for name in setups}
    for _ in tqdm(range(args.rounds), desc="rounds"):
        for name, config in setups.items():
            runs[name].append(time_training(config, args.steps))
    print(f"PPO {args.steps} steps per run, {args.rounds} alternating rounds")
    print("| setup | envs | n_steps | batch | epochs | net | steps/s (median) | rollout | update |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, config in setups.items():
        hp, rows = config["hyperparams"], runs[name]
        rollout = sum(r["rollout"] for r in rows) / sum(r["wall_s"] for r in rows)
        update = sum(r["update"] for r in rows) / sum(r["wall_s"] for r in rows)
        net = "x".join(map(str, config["policy_kwargs"]["net_arch"]))
        print(f"| {name} | {config['n_envs']} {config['vec_env']} | {hp['n_steps']} | "
              f"{hp['batch_size']} | {hp['n_epochs']} | {net} | "
              f"{statistics.median(r['steps_per_s'] for r in rows):,.0f} | {rollout:.0%} | "
              f"{update:.0%} |")
    old_name, new_name = setups
    ratios = [n["steps_per_s"] / o["steps_per_s"]
              for o, n in zip(runs[old_name], runs[new_name], strict=True)]
    print("per-round ratio new / old: " + ", ".join(f"{r:.2f}" for r in ratios)
          + f"; median {statistics.median(ratios):.2f}x")
    return {"runs": runs, "ratios": ratios}


if __name__ == "__main__":
    main()
