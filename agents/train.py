"""Train an excitation policy with stable-baselines3 (``excite train``).

Layout of the output folder ``DIR``::

    DIR/config.yaml                   the effective configuration (algo, seed, hyperparameters)
    DIR/checkpoints/ckpt_<N>_steps.zip (+ ckpt_vecnormalize_<N>_steps.pkl)   every checkpoint_freq
    DIR/best_model.zip (+ best_model.vecnormalize.pkl)  best evaluation on held-out robots
    DIR/final_model.zip (+ final_model.vecnormalize.pkl)
    DIR/monitor/                      Monitor episode logs;  DIR/eval/evaluations.npz
    DIR/train_summary.json            timesteps, wall time, fps
    DIR/tensorboard/                  when tensorboard is installed

A policy file is an SB3 zip with its observation normalization beside it
(``NAME.vecnormalize.pkl``); ``excite compare --policy DIR/best_model.zip`` evaluates it.
Policy files are pickled code: load only files you trust.
"""

from __future__ import annotations

import importlib.util
import json
import time
from pathlib import Path
from typing import Any

import torch
import yaml
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.callbacks import (
    BaseCallback,
    CallbackList,
    CheckpointCallback,
    EvalCallback,
)
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecNormalize
from tqdm import tqdm

import excite  # noqa: F401  (registers the environment ids)
from agents.mixed_env import ConcatVecEnv
from agents.vec_env import NativeVecEnv
from excite.errors import ExciteError

ALGOS = {"ppo": PPO, "sac": SAC}
CONFIG_DIR = Path(__file__).parent / "configs"
#: native: all envs in one process, stepped together (envs.vector_env); subproc / dummy: one
#: single env per worker process / in a loop.
VEC_ENVS = ("native", "subproc", "dummy")


class TrainingError(ExciteError, ValueError):
    """Bad training settings, or nothing to resume from."""


def normalization_path(policy_path: Path) -> Path:
    """Where a policy file's observation normalization lives."""
    return policy_path.with_name(policy_path.stem + ".vecnormalize.pkl")


def load_config(algo: str, path: str | Path | None = None) -> dict[str, Any]:
    if algo not in ALGOS:
        raise TrainingError(f"unknown algorithm {algo!r}; choose from {', '.join(ALGOS)}")
    source = Path(path) if path else CONFIG_DIR / f"{algo}.yaml"
    try:
        config = yaml.safe_load(source.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise TrainingError(f"cannot read training config {source}: {exc}") from None
    if not isinstance(config, dict):
        raise TrainingError(f"training config {source} must be a mapping")
    base = config.pop("extends", None)
    if base is None:
        return config
    # extends: another config (NAME.yaml, relative to this one's folder); this one's keys
    # replace its keys, its mappings (env_kwargs, hyperparams, ...) merged one level down.
    if not isinstance(base, str) or not base:
        raise TrainingError(f"{source}: extends must name a config, got {base!r}")
    merged = load_config(algo, source.parent / f"{base}.yaml")
    for key, value in config.items():
        both = isinstance(value, dict) and isinstance(merged.get(key), dict)
        merged[key] = {**merged[key], **value} if both else value
    return merged


def make_training_env(config: dict, n_envs: int, seed: int, training: bool = True):
    """Vectorized, monitored, normalized env: several envs as config ``vec_env`` says
    (default native, one process), one env as a DummyVecEnv. Worker processes import excite
    through the "excite:" id prefix.

    With config ``robots`` (a list of env ``robot`` values: preset names or override
    mappings) the envs are split evenly over those robots (n_envs a multiple of their number;
    one env per robot when n_envs is 1, as for evaluation), env i seeded seed + i."""
    robots = config.get("robots") or [config.get("env_kwargs", {}).get("robot")]
    per_robot = max(n_envs // len(robots), 1)
    if n_envs > 1 and per_robot * len(robots) != n_envs:
        raise TrainingError(f"n_envs {n_envs} must be a multiple of the {len(robots)} robots")
    parts = [_robot_env(config, robot, per_robot, seed + k * per_robot)
             for k, robot in enumerate(robots)]
    venv = parts[0] if len(parts) == 1 else ConcatVecEnv(parts)
    norm = config.get("normalize", {})
    return VecNormalize(venv, training=training,
                        norm_obs=norm.get("norm_obs", True),
                        norm_reward=norm.get("norm_reward", True) and training,
                        gamma=norm.get("gamma", 0.99))


def _robot_env(config: dict, robot: Any, n_envs: int, seed: int) -> VecEnv:
    """n_envs monitored envs of one robot distribution (env i seeded seed + i)."""
    kwargs = dict(config.get("env_kwargs", {}))
    if robot is not None:
        kwargs["robot"] = robot
    kind = config.get("vec_env", "native") if n_envs > 1 else "dummy"
    if kind not in VEC_ENVS:
        raise TrainingError(f"unknown vec_env {kind!r}; choose from {', '.join(VEC_ENVS)}")
    if kind == "native":
        venv = NativeVecEnv(config["env_id"], n_envs, kwargs)
        venv.seed(seed)
        return venv
    return make_vec_env("excite:" + config["env_id"], n_envs=n_envs, seed=seed,
                        vec_env_cls=DummyVecEnv if kind == "dummy" else SubprocVecEnv,
                        env_kwargs=kwargs)


def make_model(config: dict, venv, seed: int, tensorboard: str | None = None):
    """A new model of the config's algorithm, policy and hyperparameters on ``venv``, on CPU."""
    return ALGOS[config["algo"]](config.get("policy", "MlpPolicy"), venv, seed=seed,
                                 device="cpu", policy_kwargs=config.get("policy_kwargs"),
                                 verbose=0, tensorboard_log=tensorboard,
                                 **config.get("hyperparams", {}))


class _TqdmProgress(BaseCallback):
    """A tqdm bar over environment steps."""

    def __init__(self, total: int, initial: int):
        super().__init__()
        self.total, self.initial = total, initial

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.total, initial=self.initial, unit="step", desc="training")

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


class _SaveNormalizationOnBest(BaseCallback):
    """Keeps DIR/best_model.vecnormalize.pkl in step with best_model.zip."""

    def __init__(self, out: Path):
        super().__init__()
        self.out = out

    def _on_step(self) -> bool:
        normalization = self.model.get_vec_normalize_env()
        normalization.save(str(normalization_path(self.out / "best_model.zip")))
        return True


def latest_checkpoint(out: Path) -> tuple[Path, Path, int] | None:
    """The newest checkpoint in ``out``: (model zip, its normalization pickle, steps), or None
    when there is none with both files."""
    best = None
    for model in (out / "checkpoints").glob("ckpt_*_steps.zip"):
        steps = int(model.stem.split("_")[1])
        norm = model.with_name(f"ckpt_vecnormalize_{steps}_steps.pkl")
        if norm.exists() and (best is None or steps > best[2]):
            best = (model, norm, steps)
    return best


def train(
    out: str | Path,
    algo: str = "ppo",
    timesteps: int = 1_000_000,
    n_envs: int | None = None,
    seed: int = 0,
    resume: bool = False,
    config_path: str | Path | None = None,
    progress: bool = True,
    after_eval: BaseCallback | None = None,
) -> dict:
    """Train (or resume) a policy; returns the training summary (also in DIR).
    ``after_eval`` runs after every evaluation (its ``parent`` is the EvalCallback, with
    ``last_mean_reward``); returning False stops training."""
    out = Path(out)
    if resume:
        stored = out / "config.yaml"
        if not stored.exists():
            raise TrainingError(f"nothing to resume in {out} (no config.yaml)")
        config = yaml.safe_load(stored.read_text())
        algo, seed, n_envs = config["algo"], config["seed"], config["n_envs"]
    else:
        config = load_config(algo, config_path)
        config.update(algo=algo, seed=seed, n_envs=n_envs or config.get("n_envs", 1))
        out.mkdir(parents=True, exist_ok=True)
        (out / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        n_envs = config["n_envs"]
    algo_cls = ALGOS[algo]
    # Small MLPs on CPU: one torch thread is fastest, and several oversubscribe the cores the
    # environments need (2-core machines).
    torch.set_num_threads(config.get("torch_threads", 1))

    venv = make_training_env(config, n_envs, seed)
    eval_cfg = config.get("eval", {})
    eval_env = make_training_env(config, 1, seed + eval_cfg.get("seed_offset", 1_000_000),
                                 training=False)
    checkpoint = latest_checkpoint(out) if resume else None
    if resume and checkpoint is None:
        raise TrainingError(f"nothing to resume in {out} (no checkpoint yet)")
    tensorboard = str(out / "tensorboard") if importlib.util.find_spec("tensorboard") else None
    if checkpoint:
        model_path, norm_path, done_steps = checkpoint
        venv = VecNormalize.load(str(norm_path), venv.venv)
        model = algo_cls.load(str(model_path), env=venv, device="cpu",
                              tensorboard_log=tensorboard)
    else:
        done_steps = 0
        model = make_model(config, venv, seed, tensorboard)
    per_env = max(1, n_envs)
    callbacks = [
        CheckpointCallback(max(config.get("checkpoint_freq", 50_000) // per_env, 1),
                           str(out / "checkpoints"), name_prefix="ckpt",
                           save_vecnormalize=True),
        EvalCallback(eval_env, best_model_save_path=str(out), log_path=str(out / "eval"),
                     eval_freq=max(eval_cfg.get("freq", 20_000) // per_env, 1),
                     n_eval_episodes=eval_cfg.get("episodes", 20), deterministic=True,
                     callback_on_new_best=_SaveNormalizationOnBest(out),
                     callback_after_eval=after_eval),
    ]
    remaining = max(timesteps - done_steps, 0)
    if progress:
        callbacks.append(_TqdmProgress(timesteps, done_steps))
    started = time.perf_counter()
    model.learn(total_timesteps=remaining, callback=CallbackList(callbacks),
                reset_num_timesteps=not checkpoint)
    wall = time.perf_counter() - started
    model.save(str(out / "final_model.zip"))
    venv.save(str(normalization_path(out / "final_model.zip")))
    summary = {"algo": algo, "seed": seed, "n_envs": n_envs, "timesteps": int(model.num_timesteps),
               "steps_this_run": remaining, "wall_time_s": wall,
               "fps": remaining / wall if wall > 0 else None, "resumed_from": done_steps}
    (out / "train_summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    venv.close()
    eval_env.close()
    return summary
