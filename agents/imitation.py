"""A policy's start from imitation of a planner (the ``imitate`` section of a training config).

Reinforcement learning from a random policy finds, on every robot preset at once, a policy
that drives well on the default robot and poorly on others (``BENCHMARKS.md``, "Training").
Starting from a copy of a planner that already drives every preset well gives PPO a start in
the right region; PPO then improves on it with the env's reward. Three stages, before the
first PPO update:

1. :func:`demonstrations`: the planner (a protocol spec, e.g. ``slip_aware``) drives
   ``episodes`` hidden robots of each of the config's robots in the training env (seeds
   ``seed + DEMONSTRATION_SEEDS + ...``: neither the training envs' nor the evaluation's);
   each segment gives the observation the policy would see and the action the planner took
   (after its wall guard, in the env's action units: fractions of the motor limit).
2. :func:`clone`: the observation normalization set to the demonstrations' mean and
   variance, then ``epochs`` passes of behaviour cloning: the policy's log-likelihood of the
   planner's actions, maximised with Adam in minibatches of CLONE_BATCH; the policy's action
   std then set back to the config's start (``policy_kwargs.log_std_init``), so that PPO
   explores around the cloned actions as it would around its own.
3. :func:`train_critic`: ``critic_steps`` PPO steps with the actor frozen, so that the first
   policy updates use a value function fitted to the cloned policy's returns (an untrained
   critic's advantages would move the policy away from the copy at random).

    imitate:
      protocol: slip_aware
      episodes: 400          # per robot of the config
      epochs: 60
      critic_steps: 150000
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from agents.catalog import make_protocol
from agents.compare import run_protocol_episode

#: Added to the training seed for the demonstrations' robots (the training envs use seed + i,
#: the evaluation seed + eval.seed_offset, 1e6 by default).
DEMONSTRATION_SEEDS = 2_000_000
#: Demonstration pairs per step of behaviour cloning.
CLONE_BATCH = 256
#: Adam's step size of behaviour cloning.
CLONE_LEARNING_RATE = 1e-3
#: The ``imitate`` keys and their smallest values (``protocol``: a protocol spec).
IMITATE_KEYS: dict[str, int | None] = {"protocol": None, "episodes": 1, "epochs": 1,
                                       "critic_steps": 0}
#: The defaults of the ``imitate`` keys other than ``protocol``.
IMITATE_DEFAULTS = {"episodes": 400, "epochs": 60, "critic_steps": 150_000}


def demonstrations(env_id: str, env_kwargs: dict, robots: list, protocol: str, episodes: int,
                   seed: int, progress: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The observations (M, D) and actions (M, 2) of ``protocol`` driving ``episodes`` hidden
    robots of each of ``robots`` (env ``robot`` values; None: the env's own) in ``env_id``
    with ``env_kwargs``, robot k's episode e seeded seed + DEMONSTRATION_SEEDS +
    k * episodes + e."""
    observations: list[np.ndarray] = []
    actions: list[np.ndarray] = []
    bar = tqdm(total=episodes * len(robots), desc=f"imitate: {protocol} drives",
               unit="episode", disable=not progress)
    for k, robot in enumerate(robots):
        kwargs = dict(env_kwargs) | ({} if robot is None else {"robot": robot})
        env = gym.make(env_id, **kwargs)
        planner = make_protocol(protocol)
        planner.act = _recording(planner.act, observations, actions)  # type: ignore[method-assign]
        for e in range(episodes):
            run_protocol_episode(env, planner, seed + DEMONSTRATION_SEEDS + k * episodes + e)
            bar.update()
        env.close()
    bar.close()
    return np.array(observations, dtype=np.float64), np.array(actions, dtype=np.float32)


def _recording(act: Callable, observations: list, actions: list) -> Callable:
    """``act`` that also appends each observation and the action it returned."""
    def recorded(knowledge):
        action = act(knowledge)
        observations.append(np.array(knowledge.observation, dtype=np.float64))
        actions.append(np.array(action, dtype=np.float32))
        return action
    return recorded


def clone(model, venv, observations: np.ndarray, actions: np.ndarray, epochs: int,
          log_std_init: float, seed: int, progress: bool = True) -> float:
    """Behaviour cloning of ``actions`` (M, 2) from ``observations`` (M, D) into the PPO
    ``model``'s policy, through ``venv``'s observation normalization (a VecNormalize, set to
    the demonstrations' statistics); returns the RMS of the cloned actions' error on the
    pairs (env action units). The action std is then ``exp(log_std_init)``."""
    import torch

    venv.obs_rms.mean = observations.mean(axis=0)
    venv.obs_rms.var = observations.var(axis=0)
    venv.obs_rms.count = float(len(observations))
    inputs = torch.as_tensor(venv.normalize_obs(observations), dtype=torch.float32)
    targets = torch.as_tensor(actions)
    policy = model.policy
    optimizer = torch.optim.Adam(policy.parameters(), lr=CLONE_LEARNING_RATE)
    rng = np.random.default_rng(seed)
    for _ in tqdm(range(epochs), desc="imitate: cloning", unit="epoch", disable=not progress):
        order = torch.as_tensor(rng.permutation(len(inputs)))
        for start in range(0, len(inputs), CLONE_BATCH):
            batch = order[start:start + CLONE_BATCH]
            loss = -policy.get_distribution(inputs[batch]).log_prob(targets[batch]).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    with torch.no_grad():
        policy.log_std.fill_(log_std_init)
        cloned = policy.get_distribution(inputs).distribution.mean
        return float(torch.sqrt(((cloned - targets) ** 2).mean()))


def train_critic(model, steps: int) -> None:
    """``steps`` PPO steps of ``model`` with its actor frozen (the value network learns)."""
    if steps <= 0:
        return
    actor = [p for name, p in model.policy.named_parameters()
             if not name.startswith(("mlp_extractor.value", "value_net"))]
    for p in actor:
        p.requires_grad_(False)
    try:
        model.learn(total_timesteps=steps)
    finally:
        for p in actor:
            p.requires_grad_(True)


def imitate(config: dict, robots: list, model, venv, seed: int, progress: bool = True) -> dict:
    """The three stages (module doc) for a checked training ``config`` with an ``imitate``
    section, on the training envs' ``robots`` (env ``robot`` values), its new ``model`` and
    training ``venv``; what was done, for the training summary."""
    settings = IMITATE_DEFAULTS | config["imitate"]
    observations, actions = demonstrations(config["env_id"], config.get("env_kwargs", {}), robots,
                                           settings["protocol"], settings["episodes"], seed,
                                           progress)
    log_std_init = config.get("policy_kwargs", {}).get("log_std_init", 0.0)
    rms = clone(model, venv, observations, actions, settings["epochs"], log_std_init, seed,
                progress)
    train_critic(model, settings["critic_steps"])
    return {"protocol": settings["protocol"], "episodes_per_robot": settings["episodes"],
            "pairs": len(observations), "epochs": settings["epochs"],
            "cloned_action_rms": rms, "critic_steps": settings["critic_steps"]}
