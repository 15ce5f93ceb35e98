"""Smoke training (a few thousand steps), save, load, evaluate, resume; bad policy files."""

import json
import warnings
import zipfile

import numpy as np
import pytest
import yaml

from agents.catalog import ProtocolError, ProtocolSpec, make_protocol
from agents.compare import make_env
from agents.train import CONFIG_DIR, TrainingError, normalization_path, train
from excite.cli import main
from tests.conftest import assert_one_line_error, run_cli


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


@pytest.mark.slow
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


@pytest.mark.slow
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


def test_a_policy_of_nan_weights_or_a_foreign_normalization_is_a_one_line_error(tmp_path):
    """A policy whose training diverged (NaN weights) or whose NAME.vecnormalize.pkl is
    garbage, another policy's or not a VecNormalize: named when loaded, never an internal
    error in the middle of a comparison (found by fuzzing)."""
    import pickle
    import shutil

    import torch
    from stable_baselines3 import PPO

    from agents.learned import SHIPPED_POLICY
    from agents.train import normalization_path

    policy = tmp_path / "p.zip"
    shutil.copy(SHIPPED_POLICY, policy)
    for content, fragment in [(b"garbage", "cannot load the observation normalization"),
                              (pickle.dumps({"a": 1}), "not the observation normalization")]:
        normalization_path(policy).write_bytes(content)
        with pytest.raises(ProtocolError, match=fragment):
            make_protocol(f"learned:policy={policy}")
    shutil.copy(normalization_path(SHIPPED_POLICY), normalization_path(policy))
    model = PPO.load(str(policy), device="cpu")
    with torch.no_grad():
        next(model.policy.parameters()).fill_(float("nan"))
    model.save(str(policy))
    with pytest.raises(ProtocolError, match="weights are not finite"):
        make_protocol(f"learned:policy={policy}")


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
    for i, info in enumerate(infos):  # plain Python numbers and row arrays, robot by robot
        assert isinstance(info["sigma_min"], float) and isinstance(info["collision"], bool)
        assert isinstance(info["n_segments"], int) and info["measurement"].shape == (5,)
        assert all(isinstance(v, float) for v in info["reward_terms"].values())
        assert sum(info["reward_terms"].values()) == pytest.approx(reward[i], abs=1e-6)
    assert not np.array_equal(infos[0]["measurement"], infos[1]["measurement"])


def test_native_training_envs_report_episode_statistics():
    """The native vector env reports what SB3's Monitor would: each ended episode's info
    carries its return (the sum of the raw rewards) and length, what SB3 logs as
    ep_rew_mean."""
    from agents.train import make_training_env

    config = {"env_id": "excite/DiffDriveCalibIdeal-v0", "env_kwargs": {"budget": 3},
              "vec_env": "native", "normalize": {"norm_reward": False}}
    venv = make_training_env(config, 2, seed=3)
    venv.reset()
    total = np.zeros(2)
    for _ in range(3):
        _, _, dones, infos = venv.step(np.full((2, 2), 0.4))
        total += venv.get_original_reward()
    assert dones.all()
    for i, info in enumerate(infos):
        assert info["episode"]["l"] == 3
        assert info["episode"]["r"] == pytest.approx(total[i], rel=1e-5)


def test_training_over_several_robots_splits_the_envs_and_seeds_them_in_order(tmp_path):
    """config robots: env i is its preset's single env seeded s + i (concatenated in order,
    actions routed to their part); evaluation gets one env per robot; bad splits are errors."""
    from agents.mixed_env import ConcatVecEnv
    from agents.train import make_training_env

    config = {"env_id": "excite/DiffDriveCalibIdeal-v0", "env_kwargs": {"budget": 3},
              "vec_env": "native", "robots": ["turtlebot3", {"preset": "husky"}]}
    venv = make_training_env(config, 4, seed=7).venv
    assert isinstance(venv, ConcatVecEnv) and venv.num_envs == 4
    obs = venv.reset()
    actions = np.random.default_rng(1).uniform(-1, 1, (2, 4, 2))
    for action in actions:
        stepped, *_ = venv.step(action)
    for i, preset in enumerate(["turtlebot3", "turtlebot3", "husky", "husky"]):
        single = make_env("excite/DiffDriveCalibIdeal-v0", 3, robot=preset)
        first, _ = single.reset(seed=7 + i)
        np.testing.assert_allclose(obs[i], first, atol=1e-6)
        for action in actions:
            last, *_ = single.step(action[i])
        np.testing.assert_allclose(stepped[i], last, atol=1e-6)
    nominal = venv.get_attr("single", [0, 3])
    assert [s.nominal.b for s in nominal] == [0.160, 0.555]

    evaluation = make_training_env(config, 1, seed=0, training=False)
    assert evaluation.num_envs == 2
    with pytest.raises(TrainingError, match="multiple of the 2 robots"):
        make_training_env(config, 3, seed=0)


def test_configs_extend_others_and_bad_configs_are_errors(tmp_path):
    from agents.train import load_config
    from envs.robot import robot_distribution

    base = load_config("ppo")
    for name in ("ppo_robots.yaml", "ppo_sizes.yaml"):
        robots = load_config("ppo", CONFIG_DIR / name)
        assert robots["hyperparams"] == base["hyperparams"]
        assert robots["eval"]["seed_offset"] == base["eval"]["seed_offset"]
        assert robots["eval"]["episodes"] % len(robots["robots"]) == 0
        assert robots["n_envs"] % len(robots["robots"]) == 0
        for robot in robots["robots"]:
            robot_distribution(robot).nominal()  # every robot is valid
    child = tmp_path / "child.yaml"
    child.write_text("extends: missing\nn_envs: 2\n")
    with pytest.raises(TrainingError, match="missing.yaml"):
        load_config("ppo", child)
    child.write_text("- a list\n")
    with pytest.raises(TrainingError, match="must be a mapping"):
        load_config("ppo", child)


def _yaml(tmp_path, name, document):
    path = tmp_path / name
    if isinstance(document, bytes):
        path.write_bytes(document)
    else:
        path.write_text(document if isinstance(document, str) else yaml.safe_dump(document))
    return path


def test_training_without_an_evaluation_in_its_steps_evaluates_once_at_the_end(
        tmp_path, small_config, capsys):
    """eval.freq (1024) beyond --timesteps: one evaluation at the end, so the printed best
    policy exists and is loadable."""
    out = tmp_path / "run"
    code, printed, _ = run_cli(capsys, "train", "--config", small_config, "--timesteps", 256,
                               "--n-envs", 2, "--out", out)
    assert code == 0 and printed.strip().endswith(f"best policy: {out / 'best_model.zip'}")
    trained = json.loads((out / "train_summary.json").read_text())["timesteps"]
    assert trained < 1024  # whole rollouts: 512 steps
    assert np.load(out / "eval" / "evaluations.npz")["timesteps"].tolist() == [trained]
    assert normalization_path(out / "best_model.zip").exists()
    make_protocol(ProtocolSpec.of("learned", {"policy": str(out / "best_model.zip")}))


@pytest.mark.slow
def test_a_used_out_folder_needs_resume_and_resume_takes_no_new_settings(
        tmp_path, small_config, capsys):
    out = tmp_path / "run"
    assert run_cli(capsys, "train", "--config", small_config, "--timesteps", 1024,
                   "--n-envs", 2, "--out", out)[0] == 0
    before = {p.name: p.read_bytes() for p in out.glob("*.zip")}
    code, _, err = run_cli(capsys, "train", "--config", small_config, "--timesteps", 256,
                           "--n-envs", 2, "--seed", 4, "--out", out)
    assert_one_line_error(code, err, f"--out {out} is not empty", "--resume")
    assert {p.name: p.read_bytes() for p in out.glob("*.zip")} == before  # nothing mixed in
    code, _, err = run_cli(capsys, "train", "--config", small_config, "--timesteps", 2048,
                           "--out", out, "--resume")
    assert_one_line_error(code, err, "--resume continues the run", "drop --config")
    (tmp_path / "empty").mkdir()  # an empty folder is a new run's
    assert run_cli(capsys, "train", "--config", small_config, "--timesteps", 256,
                   "--n-envs", 2, "--out", tmp_path / "empty")[0] == 0


@pytest.mark.slow
def test_the_config_names_the_algorithm_unless_the_command_line_does(tmp_path, small_config):
    """A config's algo: is used without --algo (the shipped sac.yaml says sac); --algo against
    it is an error; a config without algo: but with SAC's hyperparameters is a PPO config with
    SAC's hyperparameters, named as such."""
    from agents.train import load_config

    sac = _yaml(tmp_path, "mine.yaml", "extends: sac\nalgo: sac\n")
    assert load_config(None, sac)["algo"] == "sac"
    assert load_config("sac", sac)["hyperparams"] == load_config("sac")["hyperparams"]
    with pytest.raises(TrainingError, match=r"mine.yaml: algo: the config is for 'sac', "
                                            r"not 'ppo'"):
        load_config("ppo", sac)
    assert load_config(None, CONFIG_DIR / "sac.yaml")["algo"] == "sac"
    sac_like = _yaml(tmp_path, "sac_like.yaml", "extends: ppo\nhyperparams:\n  buffer_size: 1000\n")
    with pytest.raises(TrainingError, match=r"sac_like.yaml: hyperparams.buffer_size: not an "
                                            r"argument of PPO .*give --algo sac"):
        load_config(None, sac_like)
    config = yaml.safe_load(small_config.read_text())
    config["env_kwargs"]["budget"] = 10
    tiny_sac = _yaml(tmp_path, "tiny_sac.yaml", {
        "extends": "sac", "algo": "sac", "env_kwargs": config["env_kwargs"],
        "hyperparams": {"learning_starts": 64, "batch_size": 32},
        "eval": {"freq": 128, "episodes": 1}})
    summary = train(tmp_path / "run", timesteps=256, config_path=tiny_sac, progress=False)
    assert summary["algo"] == "sac" and summary["n_envs"] == 2  # sac.yaml's n_envs
    assert yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["algo"] == "sac"


def test_extends_looks_next_to_the_config_then_in_the_shipped_configs(tmp_path):
    from agents.train import load_config

    mine = _yaml(tmp_path, "mine.yaml", "extends: ppo\nn_envs: 4\n")
    assert load_config(None, mine) == {**load_config("ppo"), "n_envs": 4}
    _yaml(tmp_path, "ppo.yaml", "extends: sac\nalgo: sac\n")  # a user's own ppo.yaml wins
    assert load_config(None, mine)["algo"] == "sac"
    missing = _yaml(tmp_path, "missing.yaml", "extends: nowhere\n")
    with pytest.raises(TrainingError, match=f"extends: no nowhere.yaml in {tmp_path} or "
                                            f"{CONFIG_DIR}"):
        load_config(None, missing)


BAD_CONFIGS = [
    ("foo: 1\n", "foo: unknown key; the keys are algo, seed"),
    ("n_envs: -3\n", "n_envs: must be a whole number >= 1, got -3"),
    ("n_envs: two\n", "n_envs: must be a whole number, got 'two'"),
    ("vec_env: fancy\n", "vec_env: unknown 'fancy'"),
    ("env_kwargs: [1]\n", "env_kwargs: must be a mapping"),
    ("eval: {freq: 0}\n", "eval.freq: must be a whole number >= 1, got 0"),
    ("eval: {frequency: 5}\n", "eval.frequency: unknown key"),
    ("normalize: {norm_obs: 3}\n", "normalize.norm_obs: must be true or false"),
    ("hyperparams: {n_stepz: 64}\n", "hyperparams.n_stepz: not an argument of PPO"),
    ("hyperparams: {n_steps: lots}\n", "hyperparams.n_steps: must be a number, got 'lots'"),
    ("hyperparams: {n_steps: 64.5}\n", "hyperparams.n_steps: must be a whole number"),
    ("hyperparams: {learning_rate: -1}\n", "hyperparams.learning_rate: must be a positive"),
    ("hyperparams: {n_epochs: 0}\n", "hyperparams.n_epochs: must be a whole number >= 1, got 0"),
    ("hyperparams: {gae_lambda: .nan}\n", "hyperparams.gae_lambda: must be finite, got nan"),
    ("hyperparams: {learning_rate: .inf}\n", "hyperparams.learning_rate: must be finite"),
    ("policy_kwargs: {log_std_init: .nan}\n", "policy_kwargs.log_std_init: must be finite"),
    ("algo: sac\n", "hyperparams.n_epochs: not an argument of SAC (algo: sac; a ppo config?"),
    ("algo: dqn\n", "algo: unknown algorithm 'dqn'"),
    ("env_id: excite/Nope-v0\n", "env_id/env_kwargs/robots: Environment `Nope` doesn't exist"),
    ("env_kwargs: {bogus: 3}\n", "env_id/env_kwargs/robots: unknown config key 'bogus'"),
    ("robots: [marsrover]\n", "env_id/env_kwargs/robots: unknown robot preset 'marsrover'"),
    ("robots: []\n", "robots: must list at least one robot"),
    ("policy: NopePolicy\n", "policy/policy_kwargs/hyperparams: Policy NopePolicy unknown"),
    ("policy_kwargs: {net_arch: big}\n", "policy/policy_kwargs/hyperparams: "),
    ("imitate: {episodes: 10}\n", "imitate.protocol: required: the protocol to imitate"),
    ("imitate: {protocol: teleport}\n", "imitate.protocol: unknown protocol 'teleport'"),
    ("imitate: {protocol: slip_aware, epochs: 0}\n",
     "imitate.epochs: must be a whole number >= 1, got 0"),
    ("imitate: {protocol: slip_aware, teacher: me}\n", "imitate.teacher: unknown key"),
]


@pytest.mark.parametrize("lines,fragment", BAD_CONFIGS)
def test_bad_training_config_is_a_one_line_error_naming_file_and_key(tmp_path, capsys,
                                                                     lines, fragment):
    path = _yaml(tmp_path, "bad.yaml", "extends: ppo\n" + lines)
    with warnings.catch_warnings(record=True) as printed:  # on stderr too, outside pytest
        warnings.simplefilter("always")
        code, _, err = run_cli(capsys, "train", "--config", path, "--timesteps", 128,
                               "--n-envs", 2, "--out", tmp_path / "out")
    assert_one_line_error(code, err, f"{path}: {fragment}")
    assert not printed, [str(w.message) for w in printed]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "document,fragment",
    [
        ("extends: bad\n", "bad.yaml: extends: {tmp}/bad.yaml is already in the chain"),
        ("extends: ppo\nhyperparams: [1, 2\n", "bad.yaml: not valid YAML (line 3)"),
        ("extends: ppo\nhyperparams:\n  gamma: 0.9\n  gamma: 0.99\n",
         "bad.yaml: not valid YAML (line 4): duplicate key 'gamma'"),
        ("- a list\n", "training config {tmp}/bad.yaml must be a mapping"),
        (b"\x80\x81\xfe binary", "bad.yaml: not a text file (a training config is YAML text)"),
        ("", "bad.yaml: env_id: required"),
    ],
)
def test_broken_config_files_are_one_line_errors(tmp_path, capsys, document, fragment):
    path = _yaml(tmp_path, "bad.yaml", document)
    code, _, err = run_cli(capsys, "train", "--config", path, "--out", tmp_path / "out")
    assert_one_line_error(code, err, fragment.replace("{tmp}", str(tmp_path)))


def test_bad_train_options_are_one_line_errors(tmp_path, capsys):
    afile = _yaml(tmp_path, "afile", "x")
    code, _, err = run_cli(capsys, "train", "--seed", "-1", "--out", tmp_path / "o")
    assert_one_line_error(code, err, "--seed: must be at least 0")
    for command in ("train", "compare", "simulate"):  # numpy's legacy seeding takes 32 bits
        code, _, err = run_cli(capsys, command, "--seed", str(2**32), "--out", tmp_path / "o")
        assert_one_line_error(code, err, "--seed: must be below 2**32")
    code, _, err = run_cli(capsys, "train", "--out", afile)
    assert_one_line_error(code, err, f"--out {afile} is a file, not a folder")
    code, _, err = run_cli(capsys, "train", "--out", tmp_path / "o", "--resume")
    assert_one_line_error(code, err, "nothing to resume")
    with pytest.raises(TrainingError, match="seed must be a whole number >= 0"):
        train(tmp_path / "o", seed=-1, progress=False)


def test_imitation_clones_the_planner_and_training_starts_from_it(tmp_path, small_config):
    """Demonstrations of slip_aware in the training env, behaviour cloning into the PPO policy
    (its cloned actions much closer to the planner's than the untrained policy's), the critic
    trained with the actor frozen, then PPO; the summary says what imitation did."""
    from agents.imitation import clone, demonstrations, train_critic
    from agents.train import build, load_config

    config = load_config(None, small_config)
    observations, actions = demonstrations(config["env_id"], config["env_kwargs"], [None],
                                           "slip_aware", 3, seed=5, progress=False)
    assert observations.shape == (30, 16) and actions.shape == (30, 2)
    assert np.all(np.abs(actions) <= 1.0) and np.ptp(actions, axis=0).min() > 0.1
    venv, _, model = build(config, 2, 5, small_config)
    import torch

    def rms() -> float:
        inputs = torch.as_tensor(venv.normalize_obs(observations), dtype=torch.float32)
        with torch.no_grad():
            mean = model.policy.get_distribution(inputs).distribution.mean.numpy()
        return float(np.sqrt(np.mean((mean - actions) ** 2)))

    venv.obs_rms.mean, venv.obs_rms.var = observations.mean(0), observations.var(0)
    before = rms()
    after = clone(model, venv, observations, actions, 40, -1.0, seed=5, progress=False)
    assert after == pytest.approx(rms()) and after < 0.5 * before, (before, after)
    assert np.allclose(model.policy.log_std.detach().numpy(), -1.0)
    actor = {n: p.detach().clone() for n, p in model.policy.named_parameters()
             if n.startswith(("mlp_extractor.policy", "action_net", "log_std"))}
    critic = model.policy.value_net.weight.detach().clone()
    train_critic(model, 512)
    for name, p in model.policy.named_parameters():
        if name in actor:
            assert torch.equal(p, actor[name]), name
    assert not torch.equal(model.policy.value_net.weight, critic)

    config["imitate"] = {"protocol": "slip_aware", "episodes": 1, "epochs": 2,
                         "critic_steps": 256}
    path = tmp_path / "imitate.yaml"
    path.write_text(yaml.safe_dump(config))
    summary = train(tmp_path / "run", "ppo", 512, n_envs=2, seed=3, config_path=path,
                    progress=False)
    assert summary["timesteps"] == 512
    assert summary["imitation"]["protocol"] == "slip_aware"
    assert summary["imitation"]["pairs"] == 10 and summary["imitation"]["critic_steps"] == 256
