"""Training sweeps with Ray Tune (``excite sweep CONFIG.yaml --out DIR``).

A sweep trains one policy per trial with :func:`agents.train.train`: ``samples`` trials per
training seed, each with its own draw of the hyperparameter space (Tune's random search,
reproducible under ``search_seed``; ``grid`` values multiply the trials). After each
evaluation on held-out robots (the training config's ``eval``) the trial reports its mean
evaluation reward to Tune, and ASHA stops the trials that trail at its milestones
(``timesteps``). The best trial's best policy is copied to ``DIR/best_model.zip`` (with
``DIR/best_model.vecnormalize.pkl``, so ``excite compare --policy DIR/best_model.zip``
evaluates it) and every trial is a row of ``DIR/trials.csv``. The best is chosen on the
training's own evaluation robots (``eval.seed_offset``), never on compare's episodes.

CONFIG.yaml (example: ``agents/configs/sweep_example.yaml``)::

    algo: ppo                  # ppo | sac (default: the base config's algo, else ppo)
    config: ppo.yaml           # base training config, relative to CONFIG.yaml
                               # (default: agents/configs/ALGO.yaml)
    timesteps: 200000          # per trial, at most (required)
    seeds: [0, 1]              # training seeds (default [0])
    samples: 4                 # trials (draws of the space) per seed (default 1)
    search_seed: 0             # seed of the draws (default 0)
    cpus_per_trial: 1          # default 1
    set:                       # fixed changes to the base config (dotted keys)
      eval.freq: 10000
    space:                     # the ranges (dotted keys into the training config)
      hyperparams.learning_rate: {loguniform: [1.0e-4, 1.0e-3]}
      hyperparams.n_epochs: {choice: [5, 10]}
      env_kwargs.accuracy_weight: {uniform: [1.0, 3.0]}
    asha:                      # early stopping (timesteps)
      grace_period: 20000      # no trial stops before this, <= timesteps (default
                               # timesteps / 8)
      reduction_factor: 3      # keep the best 1/3 at each milestone (default 3)

Distributions: ``uniform: [LOW, HIGH]``, ``loguniform: [LOW, HIGH]``, ``randint: [LOW,
HIGH]`` (HIGH excluded), ``choice: [A, B, ...]`` (sampled), ``grid: [A, B, ...]`` (every
value). Dotted keys name a key of the base config's sections (``hyperparams.X`` must be an
argument of the algorithm); the base config with ``set`` applied, and with each value (or
LOW and HIGH) of the space, is checked as ``excite train`` checks a config
(:func:`agents.train.check_config`), and its env and model are built once before Ray starts.

Layout of DIR::

    DIR/sweep.yaml           the sweep's config (a re-run with another config is refused
                             once a trial or Tune's experiment exists)
    DIR/tune/                Ray Tune's experiment (restored when the command is re-run)
    DIR/trials/<TRIAL_ID>/   each trial's training folder (see agents.train)
    DIR/trials.csv           one row per trial
    DIR/best_model.zip       the best policy (+ best_model.vecnormalize.pkl)

Resumable: re-running the same command restores the Tune experiment in DIR; finished trials
are kept, interrupted trials continue from their last training checkpoint
(``checkpoint_freq``).
"""

from __future__ import annotations

import copy
import csv
import json
import math
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from ray import tune
from ray.tune.schedulers import ASHAScheduler
from ray.tune.search import BasicVariantGenerator
from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

from agents.backends import LOCAL, RAY, check_backend, ray_session
from agents.train import (
    ALGOS,
    CONFIG_KEYS,
    check_buildable,
    check_config,
    hyperparameter_names,
    latest_checkpoint,
    load_config,
    normalization_path,
    read_yaml,
    train,
)
from excite.errors import ExciteError

#: The metric trials report to Tune: the mean evaluation reward on held-out robots.
METRIC = "eval_reward"
#: Tune's clock: environment steps trained.
TIME_ATTR = "timesteps"
DISTRIBUTIONS = ("uniform", "loguniform", "randint", "choice", "grid")
KEYS = ("algo", "config", "timesteps", "seeds", "samples", "search_seed", "cpus_per_trial",
        "set", "space", "asha")
TRIAL_COLUMNS = ("trial_id", "status", "seed", "best_eval_reward", "last_eval_reward",
                 "timesteps", "stopped_early")


class SweepError(ExciteError, ValueError):
    """A bad sweep config (the message names the file and key), or an output folder that
    holds another sweep."""


@dataclass(frozen=True)
class SweepConfig:
    """A checked CONFIG.yaml (see the module docstring; :func:`load_sweep_config` fills in
    the defaults)."""

    base: dict  # the base training config, with ``set`` applied
    algo: str
    timesteps: int
    seeds: tuple[int, ...]
    samples: int
    search_seed: int
    cpus_per_trial: float
    space: dict[str, dict[str, list]]  # dotted key -> {distribution: arguments}
    grace_period: int
    reduction_factor: int
    document: dict  # the file's content, as read


def _fail(path: Path, key: str, message: str) -> SweepError:
    return SweepError(f"{path}: {key}: {message}")


def _whole(path: Path, key: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise _fail(path, key, f"must be a whole number >= {minimum}, got {value!r}")
    return value


def _set_dotted(config: dict, dotted: str, value: Any) -> None:
    node = config
    *parents, last = dotted.split(".")
    for part in parents:
        node = node.setdefault(part, {})
    node[last] = value


def _check_dotted(path: Path, section: str, dotted: Any, algo: str) -> None:
    """A dotted key names a key of the training config (hyperparams: an algorithm
    argument)."""
    key = f"{section}.{dotted}"
    if not isinstance(dotted, str) or not dotted or any(not p for p in dotted.split(".")):
        raise _fail(path, key, "keys are dotted names such as hyperparams.learning_rate")
    top, *rest = dotted.split(".")
    if top not in CONFIG_KEYS:
        raise _fail(path, key, f"{top!r} is not a key of the training config (keys: "
                    f"{', '.join(CONFIG_KEYS)})")
    if top == "hyperparams":
        if len(rest) != 1 or rest[0] not in hyperparameter_names(algo):
            raise _fail(path, key, f"not an argument of {ALGOS[algo].__name__}")
    elif rest and CONFIG_KEYS[top] is not dict:
        raise _fail(path, key, f"{top!r} is not a section of the training config")


def _check_distribution(path: Path, key: str, spec: Any) -> dict[str, list]:
    if not (isinstance(spec, dict) and len(spec) == 1 and next(iter(spec)) in DISTRIBUTIONS):
        raise _fail(path, key, f"needs one distribution: {', '.join(DISTRIBUTIONS)} "
                    "(e.g. {loguniform: [1.0e-4, 1.0e-3]})")
    kind, args = next(iter(spec.items()))
    if not isinstance(args, list) or not args:
        raise _fail(path, key, f"{kind} needs a list of values")
    if kind in ("uniform", "loguniform", "randint"):
        numeric = all(isinstance(a, int | float) and not isinstance(a, bool) for a in args)
        if len(args) != 2 or not numeric or not args[0] < args[1]:
            raise _fail(path, key, f"{kind} needs [LOW, HIGH] numbers with LOW < HIGH, "
                        f"got {args!r}")
        if kind == "loguniform" and args[0] <= 0:
            raise _fail(path, key, f"loguniform needs LOW > 0, got {args[0]!r}")
        if kind == "randint" and not all(isinstance(a, int) for a in args):
            raise _fail(path, key, f"randint needs whole numbers, got {args!r}")
    return {kind: args}


def _checked(check, config: dict, where: Path | str) -> None:
    """Run a training-config check; its error as a SweepError (same one line)."""
    try:
        check(config, where)
    except ExciteError as exc:
        raise SweepError(str(exc)) from None


def load_sweep_config(path: str | Path) -> SweepConfig:
    """Read and check CONFIG.yaml; SweepError names the file and the key that is wrong."""
    path = Path(path)
    document = read_yaml(path, "sweep config", SweepError)
    if not isinstance(document, dict):
        raise SweepError(f"{path}: a sweep config is a mapping of keys ({', '.join(KEYS)})")
    unknown = [k for k in document if k not in KEYS]
    if unknown:
        raise _fail(path, str(unknown[0]), f"unknown key; the keys are {', '.join(KEYS)}")
    algo = document.get("algo")
    if algo is not None and algo not in ALGOS:
        raise _fail(path, "algo", f"unknown algorithm {algo!r}; choose from {', '.join(ALGOS)}")
    if "timesteps" not in document:
        raise _fail(path, "timesteps", "required (training steps per trial, at most)")
    timesteps = _whole(path, "timesteps", document["timesteps"], 1)
    base_file = document.get("config")
    if base_file is not None and not isinstance(base_file, str):
        raise _fail(path, "config", f"must be a file name, got {base_file!r}")
    try:
        base = load_config(algo, path.parent / base_file if base_file else None)
    except ExciteError as exc:
        raise _fail(path, "config", str(exc)) from None
    algo = base["algo"]
    seeds = document.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds:
        raise _fail(path, "seeds", f"must be a list of seeds, got {seeds!r}")
    seeds = [_whole(path, "seeds", s, 0) for s in seeds]
    if len(set(seeds)) != len(seeds):
        raise _fail(path, "seeds", f"repeats a seed: {seeds}")
    for section in ("set", "space", "asha"):
        if not isinstance(document.get(section, {}), dict):
            raise _fail(path, section, "must be a mapping")
    for dotted, value in document.get("set", {}).items():
        _check_dotted(path, "set", dotted, algo)
        _set_dotted(base, dotted, value)
    _checked(check_config, base, f"{path}: set")
    space = {}
    for dotted, spec in document.get("space", {}).items():
        _check_dotted(path, "space", dotted, algo)
        space[dotted] = _check_distribution(path, f"space.{dotted}", spec)
        for value in next(iter(space[dotted].values())):  # the values, or LOW and HIGH
            trial = copy.deepcopy(base)
            _set_dotted(trial, dotted, value)
            _checked(check_config, trial, f"{path}: space")
    asha = document.get("asha", {})
    unknown = [k for k in asha if k not in ("grace_period", "reduction_factor")]
    if unknown:
        raise _fail(path, f"asha.{unknown[0]}", "unknown key; the keys are grace_period, "
                    "reduction_factor")
    grace = _whole(path, "asha.grace_period",
                   asha.get("grace_period", max(timesteps // 8, 1)), 1)
    if grace > timesteps:
        raise _fail(path, "asha.grace_period", f"must be at most timesteps={timesteps} (no "
                    f"trial stops before it), got {grace}")
    freq = base.get("eval", {}).get("freq") if isinstance(base.get("eval"), dict) else None
    if not (isinstance(freq, int) and 0 < freq <= timesteps):
        raise _fail(path, "set.eval.freq", f"trials report an evaluation every eval.freq "
                    f"steps: it must be a whole number in [1, timesteps={timesteps}], got "
                    f"{freq!r}")
    cpus = document.get("cpus_per_trial", 1)
    if isinstance(cpus, bool) or not isinstance(cpus, int | float) or not cpus > 0:
        raise _fail(path, "cpus_per_trial", f"must be a positive number, got {cpus!r}")
    _checked(check_buildable, base, path)
    return SweepConfig(
        base=base, algo=algo, timesteps=timesteps, seeds=tuple(seeds),
        samples=_whole(path, "samples", document.get("samples", 1), 1),
        search_seed=_whole(path, "search_seed", document.get("search_seed", 0), 0),
        cpus_per_trial=float(cpus), space=space, grace_period=grace,
        reduction_factor=_whole(path, "asha.reduction_factor",
                                asha.get("reduction_factor", 3), 2),
        document=document)


def trial_config(sweep: SweepConfig, params: Mapping[str, Any]) -> dict:
    """The training config of one trial: the base config with the trial's sampled values
    (``params``: dotted keys of the space, and ``seed``)."""
    config = copy.deepcopy(sweep.base)
    for dotted in sweep.space:
        _set_dotted(config, dotted, params[dotted])
    return config


class ReportToTune(BaseCallback):
    """After each evaluation (``EvalCallback``'s ``callback_after_eval``): report the mean
    evaluation reward and the steps trained to Tune (ASHA may then end the trial).

    The best and the last report are kept in ``state`` (JSON), so a resumed trial keeps its
    best policy unless a later evaluation beats it (``best_model.zip`` stays the policy of
    the trial's best reported reward), and can repeat its last report when nothing is left
    to train."""

    def __init__(self, state: Path):
        super().__init__()
        self.state, self.reported = state, False

    def stored(self) -> dict | None:
        """The kept state (``best``, ``last``), None before the first report."""
        return json.loads(self.state.read_text()) if self.state.exists() else None

    def _init_callback(self) -> None:
        if (stored := self.stored()) is not None:
            self.parent.best_mean_reward = max(self.parent.best_mean_reward, stored["best"])

    def _on_step(self) -> bool:
        metrics = {METRIC: float(self.parent.last_mean_reward),
                   TIME_ATTR: int(self.num_timesteps)}
        self.state.write_text(json.dumps({"best": float(self.parent.best_mean_reward),
                                          "last": metrics}))
        self.reported = True
        tune.report(metrics)
        return True


def _run_trial(params: dict, sweep: SweepConfig, out: str) -> None:
    """One trial (runs in a Ray worker): train in DIR/trials/<TRIAL_ID>, continuing from its
    last checkpoint when the trial is resumed."""
    folder = Path(out) / "trials" / tune.get_context().get_trial_id()
    folder.mkdir(parents=True, exist_ok=True)
    config_path = folder / "trial_config.yaml"
    config_path.write_text(yaml.safe_dump(trial_config(sweep, params), sort_keys=False))
    report = ReportToTune(folder / "tune_report.json")
    train(folder, sweep.algo, sweep.timesteps, seed=int(params["seed"]),
          resume=latest_checkpoint(folder) is not None, config_path=config_path,
          progress=False, after_eval=report)
    if not report.reported and (stored := report.stored()) is not None:
        tune.report(stored["last"])  # resumed with nothing left to train


def _param_space(sweep: SweepConfig) -> dict:
    make = {"uniform": lambda a: tune.uniform(*a), "loguniform": lambda a: tune.loguniform(*a),
            "randint": lambda a: tune.randint(*a), "choice": tune.choice,
            "grid": tune.grid_search}
    space = {dotted: make[kind](args) for dotted, spec in sweep.space.items()
             for kind, args in spec.items()}
    return {"seed": tune.grid_search(list(sweep.seeds)), **space}


def _check_out(out: Path, sweep: SweepConfig) -> None:
    """Refuse an ``out`` that holds a sweep of another config; record this one in
    DIR/sweep.yaml. A folder where nothing ran yet (no trial, no Tune experiment: the sweep
    failed while starting) takes the new config."""
    stored = out / "sweep.yaml"
    started = (out / "trials").exists() or tune.Tuner.can_restore(str(out / "tune"))
    if stored.exists() and started:
        try:
            previous = yaml.safe_load(stored.read_text())
        except yaml.YAMLError:
            previous = None
        if previous != sweep.document:
            raise SweepError(f"{out} holds a sweep of another config ({stored}); use another "
                             "--out or the same config")
    else:
        out.mkdir(parents=True, exist_ok=True)
        stored.write_text(yaml.safe_dump(sweep.document, sort_keys=False))


class TrialProgress(tune.Callback):
    """A tqdm bar over finished trials."""

    def __init__(self, total: int, enabled: bool = True):
        self.total, self.enabled, self.bar = total, enabled, None

    def setup(self, **info) -> None:
        self.bar = tqdm(total=self.total, desc="trials", unit="trial", disable=not self.enabled)

    def on_trial_complete(self, iteration, trials, trial, **info) -> None:
        self.bar.update(1)

    on_trial_error = on_trial_complete

    def on_experiment_end(self, trials, **info) -> None:
        self.bar.close()


def run_sweep(config_path: str | Path, out: str | Path, backend: str = LOCAL,
              address: str | None = None, progress: bool = True) -> list[dict]:
    """Run (or resume) the sweep of ``config_path`` in ``out``; writes DIR/trials.csv and
    DIR/best_model.zip and returns the trials' rows (TRIAL_COLUMNS and the space's keys).
    ``backend`` local: a Ray on this machine; ray: the cluster of ``address`` (Ray's
    conventions, :func:`agents.backends.connect_ray`)."""
    check_backend(backend, address)
    sweep = load_sweep_config(config_path)
    out = Path(out).absolute()
    _check_out(out, sweep)
    with ray_session(address if backend == RAY else "local"):
        trainable = tune.with_resources(
            tune.with_parameters(_run_trial, sweep=sweep, out=str(out)),
            {"cpu": sweep.cpus_per_trial})
        experiment = out / "tune"
        total = sweep.samples * len(sweep.seeds) * math.prod(
            len(args) for spec in sweep.space.values() for kind, args in spec.items()
            if kind == "grid")
        callbacks = [TrialProgress(total, progress)]
        if tune.Tuner.can_restore(str(experiment)):
            tuner = tune.Tuner.restore(str(experiment), trainable, resume_unfinished=True,
                                       resume_errored=True, param_space=_param_space(sweep))
        else:
            tuner = tune.Tuner(
                trainable, param_space=_param_space(sweep),
                tune_config=tune.TuneConfig(
                    metric=METRIC, mode="max", num_samples=sweep.samples,
                    search_alg=BasicVariantGenerator(random_state=sweep.search_seed),
                    scheduler=ASHAScheduler(time_attr=TIME_ATTR, max_t=sweep.timesteps,
                                            grace_period=sweep.grace_period,
                                            reduction_factor=sweep.reduction_factor)),
                run_config=tune.RunConfig(name="tune", storage_path=str(out), verbose=0,
                                          callbacks=callbacks))
        results = tuner.fit()
    rows = [_trial_row(result, sweep) for result in results]
    rows.sort(key=lambda r: r["trial_id"])
    _write_trials(out / "trials.csv", rows, sweep)
    _copy_best(out, rows)
    return rows


def summary_lines(rows: list[dict]) -> list[str]:
    """The trials as text lines, best first (the sweep's printed summary)."""
    ranked = sorted(rows, key=lambda r: -math.inf if r["best_eval_reward"] is None
                    else r["best_eval_reward"], reverse=True)
    lines = [f"{'trial':<16} {'status':<7} {'seed':>4} {'best reward':>12} {'steps':>9}  "
             "stopped early"]
    for r in ranked:
        best = "-" if r["best_eval_reward"] is None else f"{r['best_eval_reward']:.3f}"
        lines.append(f"{r['trial_id']:<16} {r['status']:<7} {r['seed']:>4} {best:>12} "
                     f"{r['timesteps']:>9}  {'yes' if r['stopped_early'] else 'no'}")
    return lines


def _trial_row(result, sweep: SweepConfig) -> dict:
    """One trial of a Tune result grid as a row of trials.csv."""
    history = result.metrics_dataframe
    rewards = [] if history is None or METRIC not in history else list(history[METRIC])
    steps = int(history[TIME_ATTR].iloc[-1]) if rewards else 0
    row = {
        "trial_id": result.metrics.get("trial_id") or Path(result.path).name,
        "status": "error" if result.error else "done",
        "seed": result.config["seed"],
        "best_eval_reward": max(rewards) if rewards else None,
        "last_eval_reward": rewards[-1] if rewards else None,
        "timesteps": steps,
        "stopped_early": bool(rewards) and not result.error and steps < sweep.timesteps,
    }
    row.update({dotted: result.config[dotted] for dotted in sweep.space})
    return row


def _write_trials(path: Path, rows: list[dict], sweep: SweepConfig) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=[*TRIAL_COLUMNS, *sweep.space])
        writer.writeheader()
        writer.writerows(rows)


def _copy_best(out: Path, rows: list[dict]) -> None:
    """Copy the best trial's best policy (and its normalization) to DIR/best_model.zip."""
    scored = [r for r in rows if r["best_eval_reward"] is not None]
    if not scored:
        raise SweepError(f"no trial of the sweep in {out} reported an evaluation; see "
                         f"{out / 'trials.csv'} and {out / 'tune'}")
    best = max(scored, key=lambda r: r["best_eval_reward"])
    source = out / "trials" / best["trial_id"] / "best_model.zip"
    target = out / "best_model.zip"
    shutil.copyfile(source, target)
    shutil.copyfile(normalization_path(source), normalization_path(target))
