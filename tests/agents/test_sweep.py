"""excite sweep: Ray Tune over training seeds and hyperparameter ranges, on the session's
local Ray (tiny trials), resumed after a kill; bad configs."""

import csv
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml

from agents.sweep import TRIAL_COLUMNS, load_sweep_config
from agents.train import CONFIG_DIR
from tests.conftest import assert_one_line_error, run_cli

TINY = {
    "algo": "ppo",
    "timesteps": 512,
    "seeds": [0, 1],
    "samples": 2,
    "set": {"n_envs": 1, "env_kwargs.budget": 10, "hyperparams.n_steps": 64,
            "hyperparams.batch_size": 32, "hyperparams.n_epochs": 1, "eval.freq": 128,
            "eval.episodes": 1, "checkpoint_freq": 128},
    "space": {"hyperparams.learning_rate": {"loguniform": [1.0e-4, 1.0e-3]}},
    "asha": {"grace_period": 128, "reduction_factor": 2},
}


def _config(tmp_path, document, name="sweep.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(document) if isinstance(document, dict) else document)
    return path


def _table(out):
    with open(out / "trials.csv", newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
@pytest.mark.xdist_group("ray")
def test_sweep_of_four_tiny_trials_writes_the_table_and_a_loadable_best_policy(
        ray_cluster, tmp_path, capsys):
    out = tmp_path / "out"
    code, printed, _ = run_cli(capsys, "sweep", _config(tmp_path, TINY), "--out", out)
    assert code == 0 and "best reward" in printed
    table = _table(out)
    assert len(table) == 4 and set(TRIAL_COLUMNS) <= set(table[0])
    assert sorted(int(r["seed"]) for r in table) == [0, 0, 1, 1]
    assert all(r["status"] == "done" for r in table)
    for row in table:  # each trial trained with its sampled value, for its reported steps
        trained = yaml.safe_load((out / "trials" / row["trial_id"] / "config.yaml").read_text())
        assert trained["hyperparams"]["learning_rate"] == float(
            row["hyperparams.learning_rate"])
        assert trained["seed"] == int(row["seed"])
        assert 128 <= int(row["timesteps"]) <= 512
        assert (row["stopped_early"] == "True") == (int(row["timesteps"]) < 512)
    rates = [float(r["hyperparams.learning_rate"]) for r in table]
    assert len(set(rates)) == 4 and all(1e-4 <= r <= 1e-3 for r in rates)  # a draw per trial
    best = max(table, key=lambda r: float(r["best_eval_reward"]))
    assert (out / "best_model.zip").read_bytes() == (
        out / "trials" / best["trial_id"] / "best_model.zip").read_bytes()
    code, printed, _ = run_cli(capsys, "compare", "--protocols", "learned,spin", "--policy",
                               out / "best_model.zip", "--episodes", "1", "--segments", "10",
                               "--workers", "1", "--out", tmp_path / "cmp")
    assert code == 0 and "learned" in printed


@pytest.mark.slow
@pytest.mark.xdist_group("ray")
def test_killed_sweep_resumes_its_trials(ray_cluster, tmp_path):
    """SIGKILL `excite sweep` (joined to the session's Ray) once a trial has finished; the
    same command restores the Tune experiment: the finished trial is kept, not retrained."""
    out = tmp_path / "out"
    # One trial at a time (2 CPUs each on the 2-CPU session Ray), each long enough that the
    # later ones are still to run when the first has ended, however fast the machine.
    serial = {**TINY, "timesteps": 2048, "cpus_per_trial": 2}
    cmd = [sys.executable, "-m", "excite.cli", "sweep", str(_config(tmp_path, serial)),
           "--out", str(out), "--backend", "ray", "--address", ray_cluster]
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, env=env)
    deadline, finished = time.time() + 150, []
    while time.time() < deadline and not finished:  # a trial ended, and Tune saved after
        ended = [p.stat().st_mtime for p in (out / "trials").glob("*/checkpoints/"
                                                                   "ckpt_2048_steps.zip")]
        saved = [p.stat().st_mtime for p in (out / "tune").glob("experiment_state-*.json")]
        if ended and saved and max(saved) > min(ended):
            finished = list((out / "trials").glob("*/checkpoints/ckpt_2048_steps.zip"))
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert finished, "no trial finished within the deadline"
    assert not (out / "trials.csv").exists()
    kept = finished[0].parent.parent
    stamp = kept.joinpath("best_model.zip").stat().st_mtime_ns
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    table = _table(out)
    assert len(table) == 4 and all(r["status"] == "done" for r in table)
    assert kept.name in {r["trial_id"] for r in table}
    assert kept.joinpath("best_model.zip").stat().st_mtime_ns == stamp
    assert len(list((out / "trials").iterdir())) == 4


BAD = [
    ("algo: ppo\ntimesteps: [1\n", "not valid YAML (line 3)"),
    ("algo: ppo\ntimesteps: 10\nalgo: sac\n", "not valid YAML (line 3): duplicate key 'algo'"),
    ("- 1\n- 2\n", "a sweep config is a mapping"),
    ({**TINY, "timestep": 5}, "timestep: unknown key"),
    ({k: v for k, v in TINY.items() if k != "timesteps"}, "timesteps: required"),
    ({**TINY, "timesteps": 0}, "timesteps: must be a whole number >= 1"),
    ({**TINY, "algo": "dqn"}, "algo: unknown algorithm 'dqn'"),
    ({**TINY, "seeds": [0, 0]}, "seeds: repeats a seed"),
    ({**TINY, "seeds": "0"}, "seeds: must be a list"),
    ({**TINY, "samples": -1}, "samples: must be a whole number >= 1"),
    ({**TINY, "config": "missing.yaml"}, "config: cannot read training config"),
    ({**TINY, "space": {"hyperparams.learnign_rate": {"uniform": [0, 1]}}},
     "space.hyperparams.learnign_rate: not an argument of PPO"),
    ({**TINY, "space": {"hyperparms.gamma": {"uniform": [0, 1]}}},
     "space.hyperparms.gamma: 'hyperparms' is not a key of the training config"),
    ({**TINY, "space": {"hyperparams.gamma": {"normal": [0, 1]}}},
     "space.hyperparams.gamma: needs one distribution"),
    ({**TINY, "space": {"hyperparams.gamma": {"uniform": [1, 0]}}},
     "space.hyperparams.gamma: uniform needs [LOW, HIGH]"),
    ({**TINY, "space": {"hyperparams.learning_rate": {"loguniform": [0, 1]}}},
     "loguniform needs LOW > 0"),
    ({**TINY, "space": {"hyperparams.n_epochs": {"randint": [1.5, 4]}}},
     "randint needs whole numbers"),
    ({**TINY, "space": {"hyperparams.n_epochs": {"choice": []}}}, "choice needs a list"),
    ({**TINY, "set": {"eval..freq": 3}}, "set.eval..freq: keys are dotted names"),
    ({**TINY, "asha": {"grace": 3}}, "asha.grace: unknown key"),
    ({**TINY, "asha": {"reduction_factor": 1}}, "asha.reduction_factor: must be a whole"),
    ({**TINY, "cpus_per_trial": 0}, "cpus_per_trial: must be a positive number"),
    ({**TINY, "timesteps": 100, "asha": {"grace_period": 64}},
     "set.eval.freq: trials report an evaluation every"),
    ({**TINY, "asha": {"grace_period": 1024}},
     "asha.grace_period: must be at most timesteps=512"),
    # the base config with set and space applied is checked as excite train checks it
    ({**TINY, "set": {**TINY["set"], "n_envs": -3}},
     "set: n_envs: must be a whole number >= 1, got -3"),
    ({**TINY, "set": {**TINY["set"], "env_kwargs.bogus": 1}},
     "env_id/env_kwargs/robots: unknown config key 'bogus'"),
    ({**TINY, "space": {"hyperparams.n_steps": {"choice": [64, "lots"]}}},
     "space: hyperparams.n_steps: must be a number, got 'lots'"),
    ({**TINY, "config": str(CONFIG_DIR / "sac.yaml")},
     "config: " + str(CONFIG_DIR / "sac.yaml") + ": algo: the config is for 'sac', not 'ppo'"),
]


@pytest.mark.parametrize("document,fragment", BAD)
def test_bad_sweep_config_is_a_one_line_error_naming_file_and_key(tmp_path, capsys,
                                                                  document, fragment):
    path = _config(tmp_path, document, "bad.yaml")
    code, _, err = run_cli(capsys, "sweep", path, "--out", tmp_path / "out")
    assert_one_line_error(code, err, str(path), fragment)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "argv,fragment",
    [
        (["sweep", "{cfg}", "--out", "o", "--address", "auto"], "--address needs --backend ray"),
        (["sweep", "{cfg}"], "required: --out"),
        (["sweep", "nonexistent.yaml", "--out", "o"], "cannot read sweep config"),
        (["sweep", "{cfg}", "--out", "{cfg}"], "is a file, not a folder"),
        (["sweep", "{cfg}", "--out", "o", "--backend", "dask"], "invalid choice: 'dask'"),
    ],
)
def test_bad_sweep_options(tmp_path, capsys, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    cfg = str(_config(tmp_path, TINY))
    code, _, err = run_cli(capsys, *[a.replace("{cfg}", cfg) for a in argv])
    assert_one_line_error(code, err, fragment)


@pytest.mark.slow
def test_another_config_in_the_same_folder_is_refused_once_a_trial_ran(tmp_path):
    """A sweep that fails while starting (here: no Ray at --address) leaves DIR/sweep.yaml
    but nothing ran, so another config may use the folder; once a trial folder exists, the
    folder belongs to its sweep. (Subprocesses: this test process may hold a Ray already.)"""
    from agents.sweep import SweepError, run_sweep

    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.getcwd()}

    def sweep(config):
        done = subprocess.run([sys.executable, "-m", "excite.cli", "sweep", str(config),
                               "--out", str(out), "--backend", "ray", "--address",
                               "127.0.0.1:9"], capture_output=True, text=True, env=env)
        return done.returncode, done.stderr

    first = _config(tmp_path, TINY, "first.yaml")
    second = _config(tmp_path, {**TINY, "samples": 3}, "second.yaml")
    assert_one_line_error(*sweep(first), "cannot connect to Ray at 127.0.0.1:9")
    assert yaml.safe_load((out / "sweep.yaml").read_text()) == TINY
    assert_one_line_error(*sweep(second), "cannot connect to Ray at 127.0.0.1:9")
    assert yaml.safe_load((out / "sweep.yaml").read_text())["samples"] == 3
    (out / "trials" / "a_trial").mkdir(parents=True)
    with pytest.raises(SweepError, match="holds a sweep of another config"):
        run_sweep(first, out)  # refused before Ray is touched


def test_shipped_example_config_is_valid():
    sweep = load_sweep_config(CONFIG_DIR / "sweep_example.yaml")
    assert sweep.base["n_envs"] == 4 and sweep.base["eval"]["freq"] == 10000
    assert sweep.timesteps > sweep.grace_period


def test_set_may_name_any_training_key_not_only_the_base_configs(tmp_path):
    """ppo.yaml has no robots: a sweep may still set it (a key of the training config)."""
    sweep = load_sweep_config(_config(tmp_path, {**TINY, "set": {**TINY["set"],
                                                                 "robots": ["default"]}}))
    assert sweep.base["robots"] == ["default"]
