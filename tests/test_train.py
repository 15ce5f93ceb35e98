"""Smoke training (a few thousand steps), save, load, evaluate, resume; bad policy files."""

import json
import zipfile

import numpy as np
import pytest
import yaml

from agents.catalog import ProtocolError, ProtocolSpec, make_protocol
from agents.compare import make_env
from agents.train import CONFIG_DIR, TrainingError, normalization_path, train
from excite.cli import main


@pytest.fixture
def small_config(tmp_path):
    config = yaml.safe_load((CONFIG_DIR / "ppo.yaml").read_text())
    config["env_kwargs"]["budget"] = 10
    config["hyperparams"].update(n_steps=256, batch_size=64, n_epochs=2)
    config["eval"].update(freq=1024, episodes=2)
    config["checkpoint_freq"] = 1024
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_smoke_train_save_load_evaluate_and_resume(tmp_path, small_config, capsys):
    out = tmp_path / "run"
    summary = train(out, "ppo", 2048, n_envs=2, seed=3, config_path=small_config,
                    progress=False)
    assert summary["timesteps"] == 2048
    for name in ("config.yaml", "best_model.zip", "final_model.zip", "train_summary.json"):
        assert (out / name).exists(), name
    assert normalization_path(out / "best_model.zip").exists()
    assert list((out / "checkpoints").glob("ckpt_*_steps.zip"))

    policy = make_protocol(ProtocolSpec.of("learned", {"policy": str(out / "best_model.zip")}))
    env = make_env("excite/DiffDriveCalib-v0", 10)
    env.reset(seed=0)
    policy.reset(np.random.default_rng(0))
    actions = [policy.act(env.unwrapped.knowledge()) for _ in range(3)]
    assert all(a.shape == (2,) and np.all(np.abs(a) <= 1) for a in actions)

    resumed = train(out, timesteps=4096, resume=True, progress=False)
    assert resumed["resumed_from"] == 2048 and resumed["timesteps"] == 4096
    assert json.loads((out / "train_summary.json").read_text())["timesteps"] == 4096

    code = main(["compare", "--protocols", "learned,umbmark", "--policy",
                 str(out / "final_model.zip"), "--episodes", "2", "--segments", "10",
                 "--workers", "1", "--out", str(tmp_path / "cmp")])
    assert code == 0 and "learned" in capsys.readouterr().out


def test_training_is_reproducible_under_a_seed(tmp_path, small_config):
    params = []
    for run in ("a", "b"):
        train(tmp_path / run, "ppo", 1024, n_envs=2, seed=5, config_path=small_config,
              progress=False)
        with zipfile.ZipFile(tmp_path / run / "final_model.zip") as archive:
            params.append(archive.read("policy.pth"))
    assert params[0] == params[1]


def test_resume_needs_a_run(tmp_path):
    with pytest.raises(TrainingError, match="nothing to resume"):
        train(tmp_path / "empty", resume=True, progress=False)


def test_bad_policy_files_are_one_line_errors(tmp_path, capsys):
    junk = tmp_path / "junk.zip"
    junk.write_bytes(b"not a zip at all")
    with pytest.raises(ProtocolError, match="not a stable-baselines3 policy"):
        make_protocol(f"learned:policy={junk}")
    code = main(["compare", "--protocols", "learned", "--policy", str(junk), "--episodes", "1",
                 "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "not a stable-baselines3 policy" in err[0]
    code = main(["train", "--algo", "dqn", "--out", str(tmp_path / "t")])
    assert code == 2 and "invalid choice: 'dqn'" in capsys.readouterr().err


def test_native_vec_env_adapter_resets_in_the_same_step():
    """SB3's conventions on the native vector env: the step that ends an episode returns the
    next episode's first observation, the last one in terminal_observation, and marks the
    budget's end TimeLimit.truncated; env i seeded s + i is the single env seeded s + i."""
    from agents.vec_env import NativeVecEnv

    budget = 3
    venv = NativeVecEnv("excite/DiffDriveCalibIdeal-v0", 2, {"budget": budget})
    venv.seed(11)
    obs = venv.reset()
    single = make_env("excite/DiffDriveCalibIdeal-v0", budget, robot="default")
    first, _ = single.reset(seed=12)
    np.testing.assert_allclose(obs[1], first, atol=1e-6)
    actions = np.random.default_rng(0).uniform(-1, 1, (budget, 2, 2))
    for k, action in enumerate(actions):
        obs, reward, dones, infos = venv.step(action)
        last, single_reward, *_ = single.step(action[1])
        assert reward.dtype == np.float32 and dones.tolist() == [k == budget - 1] * 2
    assert all(info["TimeLimit.truncated"] for info in infos)
    np.testing.assert_allclose(infos[1]["terminal_observation"], last, atol=1e-6)
    np.testing.assert_allclose(reward[1], single_reward, atol=1e-6)
    assert (obs[:, -1] == 0).all()  # the new episodes' budget used
    assert set(infos[0]["reward_terms"]) >= {"information", "collision"}
