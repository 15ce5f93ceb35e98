"""Target mode (config keys target, target_confidence, target_bonus): the episode terminates
when the stopping rule says done, the single and the vector env agree, both pass gymnasium's
and stable-baselines3's env checkers, and the mode is off by default."""

import gymnasium as gym
import numpy as np
import pytest

import excite  # noqa: F401  (registers the ids)
from envs.target import ENCODER_READINGS
from envs.vector_env import DiffDriveCalibVectorEnv

IDEAL = "excite/DiffDriveCalibIdeal-v0"
SLIP = "excite/DiffDriveCalib-v0"
#: Gentle arcs both ways and spins: a drive that determines r_L, r_R and b.
DRIVE = [np.array(a) for a in ([0.3, 0.15], [0.15, 0.3], [-0.2, 0.2], [0.2, -0.2],
                               [-0.3, -0.15], [-0.15, -0.3])]


def test_off_by_default():
    env = gym.make(IDEAL)
    assert env.unwrapped.budget == 30
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(DRIVE[0])
    assert "stop" not in info and not terminated
    assert info["reward_terms"]["stop"] == 0.0
    assert reward == pytest.approx(sum(info["reward_terms"].values()))


def test_the_episode_ends_when_the_rule_says_done():
    env = gym.make(IDEAL, target=0.01, target_bonus=2.0)
    assert env.unwrapped.budget == 150  # the longer default budget of target mode
    env.reset(seed=1)
    for k in range(150):
        _, reward, terminated, truncated, info = env.step(DRIVE[k % len(DRIVE)])
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
        stop = info["stop"]
        assert stop["n_segments"] == k + 1
        if terminated or truncated:
            break
        assert not stop["done"] and info["reward_terms"]["stop"] == 0.0
    assert terminated and not truncated and k + 1 < 150
    assert stop["done"] and stop["statistic"] <= 1.0
    assert info["reward_terms"]["stop"] == 2.0
    truth = env.unwrapped.true_params.as_array()
    decided = env.unwrapped.rule_segments  # the log with each segment's encoder readings
    assert len(decided) == k + 1 and np.all(np.isfinite(truth))
    assert decided.sub_dphi_L.shape == (k + 1, ENCODER_READINGS)
    np.testing.assert_allclose(decided.sub_dphi_L.sum(axis=1), decided.dphi_L, rtol=1e-12)
    np.testing.assert_allclose(decided.sub_dphi_R.sum(axis=1), decided.dphi_R, rtol=1e-12)


def test_a_spin_only_drive_never_stops():
    env = gym.make(IDEAL, target=0.05, budget=25)
    env.reset(seed=2)
    for _ in range(25):
        _, _, terminated, truncated, info = env.step(np.array([-0.2, 0.2]))
        assert not terminated
    assert truncated and not info["stop"]["done"]


@pytest.mark.parametrize("ideal", [True, False])
def test_the_vector_env_decides_as_the_single_env(ideal):
    """The same decisions on the same segments and encoder readings (the pymunk drive's
    readings come from the kernel's per-tick path, the single and the batch drive's alike)."""
    kwargs = {"target": 0.01, "budget": 40, "ideal": ideal}
    venv = DiffDriveCalibVectorEnv(num_envs=2, **kwargs)
    venv.reset(seed=[3, 4])
    singles = [gym.make(IDEAL if ideal else SLIP, target=0.01, budget=40).unwrapped
               for _ in range(2)]
    for i, single in enumerate(singles):
        single.reset(seed=3 + i)
    ended = [False, False]
    for k in range(40):
        action = DRIVE[k % len(DRIVE)]
        _, reward, terminated, truncated, info = venv.step(np.tile(action, (2, 1)))
        for i, single in enumerate(singles):
            if ended[i]:
                continue
            _, r, t, tr, single_info = single.step(action)
            assert terminated[i] == t and truncated[i] == tr
            assert info["stop"][i]["done"] == single_info["stop"]["done"]
            assert info["stop"][i]["statistic"] == single_info["stop"]["statistic"]
            assert reward[i] == pytest.approx(r, abs=1e-6)  # sigma_min of rank 2: rounding
            ended[i] = t or tr
        if all(ended):
            break
    assert all(ended)


def test_bad_target_settings_are_refused():
    for key, value in (("target", 1.5), ("target", 0.0), ("target_confidence", 1.0)):
        with pytest.raises(ValueError, match=key):
            gym.make(IDEAL, **{key: value})


@pytest.mark.slow
def test_target_mode_passes_the_env_checkers():
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = gym.make(IDEAL, target=0.01, budget=20)
    gym_check(env.unwrapped, skip_render_check=True)
    sb3_check(gym.make(IDEAL, target=0.01, budget=20).unwrapped)
