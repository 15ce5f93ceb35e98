"""Train an excitation policy with stable-baselines3 (``excite train``).

Layout of the output folder ``DIR``::

    DIR/config.yaml                   the effective configuration (algo, seed, hyperparameters)
    DIR/checkpoints/ckpt_<N>_steps.zip (+ ckpt_vecnormalize_<N>_steps.pkl)   every checkpoint_freq
    DIR/best_model.zip (+ best_model.vecnormalize.pkl)  best evaluation on held-out robots
    DIR/final_model.zip (+ final_model.vecnormalize.pkl)
    DIR/eval/evaluations.npz          the evaluations on held-out robots (EvalCallback)
    DIR/train_summary.json            timesteps, wall time, fps (of PPO), imitation (if any)
    DIR/tensorboard/                  when tensorboard is installed

DIR must be new or empty unless the run is resumed (``excite train`` refuses a used DIR, so
two runs never mix their checkpoints and best models); a run whose steps hold no evaluation
(``eval.freq`` beyond them) evaluates once at the end, so DIR/best_model.zip always exists.

A config (``agents/configs/ppo.yaml`` is the reference) is checked before anything is
written: only the keys of :data:`CONFIG_KEYS` and :data:`SECTION_KEYS` and the algorithm's
hyperparameters, with values of the right kind; an env or a model that does not build from
it is an error naming the file. ``extends: NAME`` merges NAME.yaml from the config's folder,
else from agents/configs. ``algo:`` in a config is used when ``--algo`` is not given; a
different ``--algo`` is an error.

A policy file is an SB3 zip with its observation normalization beside it
(``NAME.vecnormalize.pkl``); ``excite compare --policy DIR/best_model.zip`` evaluates it.
Policy files are pickled code: load only files you trust.
"""

from __future__ import annotations

import importlib.util
import inspect
import json
import math
import time
import warnings
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium
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
from agents.imitation import IMITATE_KEYS, imitate
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


#: The keys of a training config (``extends: NAME`` is merged first) and their types.
#: ``algo``, ``seed`` and ``n_envs`` may also come from the command line (see :func:`train`).
CONFIG_KEYS: dict[str, type] = {
    "algo": str, "seed": int, "env_id": str, "env_kwargs": dict, "robots": list,
    "n_envs": int, "vec_env": str, "torch_threads": int, "normalize": dict, "policy": str,
    "policy_kwargs": dict, "hyperparams": dict, "eval": dict, "checkpoint_freq": int,
    "imitate": dict,
}
#: The keys of the config's sections that train reads itself, with their smallest value
#: (None: a flag).
SECTION_KEYS: dict[str, dict[str, int | None]] = {
    "normalize": {"norm_obs": None, "norm_reward": None, "gamma": 0},
    "eval": {"freq": 1, "episodes": 1, "seed_offset": 0},
    "imitate": {key: value for key, value in IMITATE_KEYS.items() if key != "protocol"},
}
_WHOLE_KEYS = {"seed": 0, "n_envs": 1, "torch_threads": 1, "checkpoint_freq": 1}
_TYPE_NAMES = {str: "a name", dict: "a mapping", list: "a list", int: "a whole number"}
#: make_model's own arguments of the algorithm classes (not hyperparameters).
_MODEL_ARGS = {"self", "policy", "env", "seed", "device", "policy_kwargs", "verbose",
               "tensorboard_log", "_init_setup_model"}


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, except that a key given twice in one mapping is an error (the
    safe loader keeps the last value silently, so a config's earlier setting is lost)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def read_yaml(path: Path, what: str, error: type[ExciteError]) -> Any:
    """The YAML document of ``path``; ``error`` with one line naming the file (and the line
    of a syntax error or of a key given twice) when it cannot be read."""
    try:
        return yaml.load(path.read_text(), Loader=_UniqueKeyLoader)  # noqa: S506 (safe)
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not a text file (a {what} is YAML text)") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or ""
        detail = f": {problem}" if problem.startswith("duplicate key") else ""
        raise error(f"{path}: not valid YAML{where}{detail}") from None


def hyperparameter_names(algo: str) -> set[str]:
    """The arguments of the algorithm's class that a config's ``hyperparams`` may set."""
    return set(inspect.signature(ALGOS[algo].__init__).parameters) - _MODEL_ARGS


def _is_whole(value: Any, minimum: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= minimum


def check_config(config: Mapping[str, Any], source: Path | str) -> None:
    """TrainingError (one line naming ``source`` and the key) unless ``config`` has only
    known keys (CONFIG_KEYS, SECTION_KEYS, the algorithm's hyperparameters) with values of
    the right kind. Values the env and the algorithm check themselves (env_kwargs, robots,
    policy) are checked when they are built (:func:`check_buildable`)."""
    def fail(key: str, message: str) -> TrainingError:
        return TrainingError(f"{source}: {key}: {message}")

    for key, value in config.items():
        kind = CONFIG_KEYS.get(key)
        if kind is None:
            raise fail(str(key), f"unknown key; the keys are {', '.join(CONFIG_KEYS)}")
        if isinstance(value, bool) or not isinstance(value, kind):
            raise fail(key, f"must be {_TYPE_NAMES[kind]}, got {value!r}")
        if key in _WHOLE_KEYS and not _is_whole(value, _WHOLE_KEYS[key]):
            raise fail(key, f"must be a whole number >= {_WHOLE_KEYS[key]}, got {value!r}")
    if "env_id" not in config:
        raise fail("env_id", "required (the environment to train on)")
    algo = config.get("algo", "ppo")
    if algo not in ALGOS:
        raise fail("algo", f"unknown algorithm {algo!r}; choose from {', '.join(ALGOS)}")
    if config.get("vec_env", "native") not in VEC_ENVS:
        raise fail("vec_env", f"unknown {config['vec_env']!r}; choose from {', '.join(VEC_ENVS)}")
    if "robots" in config and not config["robots"]:
        raise fail("robots", "must list at least one robot")
    if "imitate" in config:
        _check_imitate(config["imitate"], algo, fail)
    for section, keys in SECTION_KEYS.items():
        for key, value in config.get(section, {}).items():
            if section == "imitate" and key == "protocol":
                continue  # checked above
            name = f"{section}.{key}"
            if key not in keys:
                raise fail(name, f"unknown key; the keys are {', '.join(keys)}")
            minimum = keys[key]
            if minimum is None and not isinstance(value, bool):
                raise fail(name, f"must be true or false, got {value!r}")
            if key == "gamma" and not (_is_number(value) and 0 <= value <= 1):
                raise fail(name, f"must be a number in [0, 1], got {value!r}")
            if minimum is not None and key != "gamma" and not _is_whole(value, minimum):
                raise fail(name, f"must be a whole number >= {minimum}, got {value!r}")
    accepted = inspect.signature(ALGOS[algo].__init__).parameters
    names = hyperparameter_names(algo)
    for key, value in config.get("hyperparams", {}).items():
        name = f"hyperparams.{key}"
        if key not in names:
            other = [a for a in ALGOS if a != algo and key in hyperparameter_names(a)]
            hint = f"; a {other[0]} config? give --algo {other[0]}" if other else ""
            raise fail(name, f"not an argument of {ALGOS[algo].__name__} (algo: {algo}{hint})")
        default = accepted[key].default
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise fail(name, f"must be true or false, got {value!r}")
        elif _is_number(default) and isinstance(value, str | bool):
            raise fail(name, f"must be a number, got {value!r}")
        elif isinstance(default, int) and isinstance(value, float):
            raise fail(name, f"must be a whole number, got {value!r}")
        if key == "learning_rate" and not (_is_number(value) and value > 0):
            raise fail(name, f"must be a positive number, got {value!r}")
        if key in _AT_LEAST_ONE and not _is_whole(value, 1):
            raise fail(name, f"must be a whole number >= 1, got {value!r}")
    for section in ("hyperparams", "policy_kwargs"):
        for key, value in config.get(section, {}).items():
            if not _finite(value):
                raise fail(f"{section}.{key}", f"must be finite, got {value!r}")


def _check_imitate(section: Mapping[str, Any], algo: str, fail) -> None:
    """The ``imitate`` section's protocol: required, a protocol spec that parses; PPO only
    (the cloned policy is a Gaussian's mean and std)."""
    from agents.catalog import parse_protocol
    from agents.protocols import ProtocolError

    if algo != "ppo":
        raise fail("imitate", f"imitation starts PPO's policy only (algo: {algo})")
    protocol = section.get("protocol")
    if not isinstance(protocol, str):
        raise fail("imitate.protocol", "required: the protocol to imitate (e.g. slip_aware), "
                   f"got {protocol!r}")
    try:
        parse_protocol(protocol)
    except (ProtocolError, ValueError) as exc:
        raise fail("imitate.protocol", str(exc)) from None


#: Hyperparameters that count something every update needs at least one of.
_AT_LEAST_ONE = frozenset({"n_steps", "batch_size", "n_epochs", "train_freq"})


def _finite(value: Any) -> bool:
    """Whether every number in ``value`` (nested lists and mappings too) is finite: a NaN
    or an infinite hyperparameter trains a policy of NaN weights without an error."""
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, Mapping):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list | tuple):
        return all(_finite(v) for v in value)
    return True


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _find_base(source: Path, base: Any) -> Path:
    """The file of ``extends: NAME``: NAME.yaml next to ``source``, else in CONFIG_DIR."""
    if not isinstance(base, str) or not base:
        raise TrainingError(f"{source}: extends: must name a config, got {base!r}")
    folders = list(dict.fromkeys([source.parent, CONFIG_DIR]))
    for folder in folders:
        if (folder / f"{base}.yaml").is_file():
            return folder / f"{base}.yaml"
    raise TrainingError(f"{source}: extends: no {base}.yaml in "
                        f"{' or '.join(str(f) for f in folders)}")


def _read_config(source: Path, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The mapping of ``source`` with its ``extends`` chain merged (unchecked)."""
    config = read_yaml(source, "training config", TrainingError)
    if config is None:
        config = {}
    if not isinstance(config, dict):
        raise TrainingError(f"training config {source} must be a mapping")
    chain = (*chain, source.resolve())
    if "extends" not in config:
        return config
    base = _find_base(source, config.pop("extends"))
    if base.resolve() in chain:
        raise TrainingError(f"{source}: extends: {base} is already in the chain (a cycle)")
    # This config's keys replace the base's keys, its mappings (env_kwargs, hyperparams,
    # ...) merged one level down.
    merged = _read_config(base, chain)
    for key, value in config.items():
        both = isinstance(value, dict) and isinstance(merged.get(key), dict)
        merged[key] = {**merged[key], **value} if both else value
    return merged


def load_config(algo: str | None = None, path: str | Path | None = None) -> dict[str, Any]:
    """The checked training config of ``path`` (default: agents/configs/ALGO.yaml), with its
    ``extends`` chain merged and ``algo`` set: ``algo`` or the config's own ``algo`` (an
    error when they differ), else ppo. ``extends: NAME`` names NAME.yaml next to the file,
    else the shipped one in agents/configs."""
    if algo is not None and algo not in ALGOS:
        raise TrainingError(f"unknown algorithm {algo!r}; choose from {', '.join(ALGOS)}")
    source = Path(path) if path else CONFIG_DIR / f"{algo or 'ppo'}.yaml"
    config = _read_config(source)
    if algo is not None and config.get("algo", algo) != algo:
        raise TrainingError(f"{source}: algo: the config is for {config['algo']!r}, not "
                            f"{algo!r}")
    config["algo"] = algo or config.get("algo", "ppo")
    check_config(config, source)
    return config


def make_training_env(config: dict, n_envs: int, seed: int, training: bool = True):
    """Vectorized, monitored, normalized env: several envs as config ``vec_env`` says
    (default native, one process), one env as a DummyVecEnv. Worker processes import excite
    through the "excite:" id prefix.

    With config ``robots`` (a list of env ``robot`` values: preset names or override
    mappings) the envs are split evenly over those robots (n_envs a multiple of their number;
    one env per robot when n_envs is 1, as for evaluation), env i seeded seed + i."""
    robots = config_robots(config)
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


def config_robots(config: dict) -> list:
    """The env ``robot`` values a config's envs are split over: its ``robots``, else its
    env's own robot (None: the env's default)."""
    return config.get("robots") or [config.get("env_kwargs", {}).get("robot")]


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


#: What building an env or a model raises for settings it does not accept.
_BUILD_ERRORS = (ExciteError, TypeError, ValueError, KeyError, AssertionError,
                 gymnasium.error.Error)


@contextmanager
def _config_errors(source: Path, keys: str) -> Iterator[None]:
    """Turns an error building the config's env or model into one line naming the file."""
    try:
        yield
    except _BUILD_ERRORS as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        raise TrainingError(f"{source}: {keys}: {message}") from None


def build(config: dict, n_envs: int, seed: int, source: Path,
          tensorboard: str | None = None, model: bool = True):
    """The training env, the evaluation env and (``model``) a new model of ``config``; an
    error of the env or the algorithm is a TrainingError naming ``source``."""
    with _config_errors(source, "env_id/env_kwargs/robots"):
        venv = make_training_env(config, n_envs, seed)
        eval_env = make_training_env(config, 1, seed + config.get("eval", {}).get(
            "seed_offset", 1_000_000), training=False)
    if not model:
        return venv, eval_env, None
    # SB3's advice (e.g. on the batch size) only once the model is built, not before an error
    with warnings.catch_warnings(record=True) as advice:
        warnings.simplefilter("always")
        with _config_errors(source, "policy/policy_kwargs/hyperparams"):
            built = make_model(config, venv, seed, tensorboard)
    for warning in advice:
        warnings.warn_explicit(warning.message, warning.category, warning.filename,
                               warning.lineno)
    return venv, eval_env, built


def check_buildable(config: dict, source: Path) -> None:
    """TrainingError naming ``source`` unless ``config``'s env and model can be built (one
    env; the config's own number of envs is checked by :func:`check_config`)."""
    with warnings.catch_warnings():  # SB3's batch-size advice is about this one env only
        warnings.simplefilter("ignore")
        venv, eval_env, _ = build(config, 1, 0, source)
    venv.close()
    eval_env.close()


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


class _EvalAtLeastOnce(EvalCallback):
    """SB3's EvalCallback, plus one evaluation at the end of training when DIR has no
    best_model.zip yet (eval.freq beyond the steps trained)."""

    def _on_training_end(self) -> None:
        if not (Path(self.best_model_save_path) / "best_model.zip").exists():
            every, self.eval_freq = self.eval_freq, 1  # _on_step evaluates every 1st call
            self._on_step()
            self.eval_freq = every


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
    algo: str | None = None,
    timesteps: int = 1_000_000,
    n_envs: int | None = None,
    seed: int | None = None,
    resume: bool = False,
    config_path: str | Path | None = None,
    progress: bool = True,
    after_eval: BaseCallback | None = None,
) -> dict:
    """Train (or resume) a policy; returns the training summary (also in DIR).

    ``algo`` (default: the config's ``algo``, else ppo), ``n_envs`` and ``seed`` (default:
    the config's, else 1 and 0) set the run; a resumed run keeps DIR/config.yaml's. When no
    evaluation ran (``eval.freq`` beyond the steps trained), one runs at the end, so DIR
    always has a best_model.zip. ``after_eval`` runs after every evaluation (its ``parent``
    is the EvalCallback, with ``last_mean_reward``); returning False stops training."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TrainingError(f"{out} is a file, not a folder")
    if resume:
        source = out / "config.yaml"
        if not source.exists():
            raise TrainingError(f"nothing to resume in {out} (no config.yaml)")
        config = load_config(None, source)
    else:
        config = load_config(algo, config_path)
        source = Path(config_path) if config_path else CONFIG_DIR / f"{config['algo']}.yaml"
        for key, value in (("seed", seed), ("n_envs", n_envs)):
            if value is not None and not _is_whole(value, _WHOLE_KEYS[key]):
                raise TrainingError(f"{key} must be a whole number >= {_WHOLE_KEYS[key]}, "
                                    f"got {value!r}")
        config.update(seed=config.get("seed", 0) if seed is None else seed,
                      n_envs=n_envs or config.get("n_envs", 1))
    algo, seed, n_envs = config["algo"], config["seed"], config["n_envs"]
    algo_cls = ALGOS[algo]
    # Small MLPs on CPU: one torch thread is fastest, and several oversubscribe the cores the
    # environments need (2-core machines).
    torch.set_num_threads(config.get("torch_threads", 1))

    checkpoint = latest_checkpoint(out) if resume else None
    if resume and checkpoint is None:
        raise TrainingError(f"nothing to resume in {out} (no checkpoint yet); start again in "
                            "a new or emptied folder")
    tensorboard = str(out / "tensorboard") if importlib.util.find_spec("tensorboard") else None
    venv, eval_env, model = build(config, n_envs, seed, source, tensorboard,
                                  model=not checkpoint)
    if checkpoint:
        model_path, norm_path, done_steps = checkpoint
        venv = VecNormalize.load(str(norm_path), venv.venv)
        model = algo_cls.load(str(model_path), env=venv, device="cpu",
                              tensorboard_log=tensorboard)
    else:
        done_steps = 0
        out.mkdir(parents=True, exist_ok=True)
        (out / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    eval_cfg = config.get("eval", {})
    per_env = max(1, n_envs)
    callbacks = [
        CheckpointCallback(max(config.get("checkpoint_freq", 50_000) // per_env, 1),
                           str(out / "checkpoints"), name_prefix="ckpt",
                           save_vecnormalize=True),
        _EvalAtLeastOnce(eval_env, best_model_save_path=str(out), log_path=str(out / "eval"),
                         eval_freq=max(eval_cfg.get("freq", 20_000) // per_env, 1),
                         n_eval_episodes=eval_cfg.get("episodes", 20), deterministic=True,
                         callback_on_new_best=_SaveNormalizationOnBest(out),
                         callback_after_eval=after_eval),
    ]
    remaining = max(timesteps - done_steps, 0)
    started = time.perf_counter()
    imitation = (imitate(config, config_robots(config), model, venv, seed, progress)
                 if config.get("imitate") and not checkpoint else None)
    if progress:
        callbacks.append(_TqdmProgress(timesteps, done_steps))
    learning = time.perf_counter()
    model.learn(total_timesteps=remaining, callback=CallbackList(callbacks),
                reset_num_timesteps=not checkpoint)
    wall, learn_wall = time.perf_counter() - started, time.perf_counter() - learning
    model.save(str(out / "final_model.zip"))
    venv.save(str(normalization_path(out / "final_model.zip")))
    summary = {"algo": algo, "seed": seed, "n_envs": n_envs, "timesteps": int(model.num_timesteps),
               "steps_this_run": remaining, "wall_time_s": wall,
               "fps": remaining / learn_wall if learn_wall > 0 else None,
               "resumed_from": done_steps,
               **({"imitation": imitation} if imitation else {})}
    (out / "train_summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    venv.close()
    eval_env.close()
    return summary
