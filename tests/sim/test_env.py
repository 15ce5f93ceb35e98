import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import excite  # noqa: F401  (registers the ids)
from envs.env import DiffDriveCalibEnv
from envs.estimator_check import assert_consistent, check_estimator
from excite import OnlineEstimator, Params, calibrate

IDS = ["excite/DiffDriveCalib-v0", "excite/DiffDriveCalibIdeal-v0",
       "excite/DiffDriveCalibSensor-v0"]


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_and_sb3_check_env_without_warnings(env_id):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(gym.make(env_id).unwrapped)
        sb3_check_env(gym.make(env_id).unwrapped)
    assert [str(w.message) for w in caught] == []


@pytest.mark.slow
def test_both_registration_orders_work():
    import subprocess
    import sys

    for code in ("import excite, gymnasium as g; g.make('excite/DiffDriveCalib-v0')",
                 "import gymnasium as g, excite; g.make('excite/DiffDriveCalibIdeal-v0')",
                 "import gymnasium as g; g.make('excite:excite/DiffDriveCalib-v0')"):
        subprocess.run([sys.executable, "-c", code], check=True)



def rollout(env, seed, n=12):
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    out = [obs]
    for _ in range(n):
        obs, reward, *_ , info = env.step(env.action_space.sample())
        out += [obs, np.array([reward]), info["measurement"]]
    return np.concatenate(out)


@pytest.mark.parametrize("env_id", IDS)
def test_deterministic_under_seed(env_id):
    a = rollout(gym.make(env_id), 7)
    b = rollout(gym.make(env_id), 7)
    c = rollout(gym.make(env_id), 8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_pickle_round_trip_continues_identically():
    env = gym.make("excite/DiffDriveCalib-v0")
    env.reset(seed=3)
    for _ in range(3):
        env.step(np.array([0.3, -0.2]))
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(3):
        o1, r1, *_ = env.step(np.array([0.5, 0.4]))
        o2, r2, *_ = clone.step(np.array([0.5, 0.4]))
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2


@pytest.mark.parametrize("vector_cls", [gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv])
def test_gymnasium_vector_envs(vector_cls):
    envs = vector_cls([lambda: gym.make("excite/DiffDriveCalibIdeal-v0", budget=5)] * 2)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (2, 16)
    for _ in range(6):
        obs, reward, terminated, truncated, _ = envs.step(envs.action_space.sample())
    assert reward.shape == (2,)
    envs.close()


@pytest.mark.slow
def test_sb3_subproc_vec_env():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    # Fresh worker processes have not imported excite: the "module:id" form imports it.
    venv = make_vec_env("excite:excite/DiffDriveCalib-v0", n_envs=2, seed=0,
                        vec_env_cls=SubprocVecEnv)
    venv.reset()
    for _ in range(3):
        obs, reward, done, info = venv.step(np.zeros((2, 2), dtype=np.float32))
    assert obs.shape == (2, 16) and "reward_terms" in info[0]
    venv.close()


def test_actions_validated_and_clipped():
    env = gym.make("excite/DiffDriveCalibIdeal-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="2 finite numbers"):
        env.step(np.array([0.1, 0.2, 0.3]))
    pose = env.sim.pose.copy()
    env.reset(seed=0, options={"pose": pose})
    *_, info_big = env.step(np.array([5.0, -5.0]))
    env.reset(seed=0, options={"pose": pose})
    *_, info_one = env.step(np.array([1.0, -1.0]))
    np.testing.assert_array_equal(info_big["measurement"][:2], info_one["measurement"][:2])


def test_reward_is_the_sum_of_named_terms_and_telescopes_to_sigma_min():
    env = gym.make("excite/DiffDriveCalibIdeal-v0", collision_penalty=0.0).unwrapped
    env.reset(seed=1)
    total = 0.0
    for _ in range(env.budget):
        _, reward, terminated, truncated, info = env.step(np.array([0.2, -0.1]))
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
        total += reward
    assert truncated and not terminated
    assert total == pytest.approx(info["sigma_min"] / env.config["information_scale"])


def test_error_and_accuracy_terms_over_an_episode():
    """error_weight w: each segment's term is -w * ln(e_t / e_0), e_t the max relative error
    after it and e_0 the nominal's; accuracy_weight a: the sum telescopes to -a * 100 *
    (final - nominal's)."""
    env = gym.make("excite/DiffDriveCalib-v0", error_weight=0.3, accuracy_weight=2.0).unwrapped
    env.reset(seed=4)
    start = env.max_relative_error
    errors, area, accuracy = [], 0.0, 0.0
    rng = np.random.default_rng(1)
    for _ in range(env.budget):
        _, reward, *_, info = env.step(rng.uniform(-0.5, 0.5, 2))
        errors.append(env.max_relative_error)
        area += info["reward_terms"]["error"]
        accuracy += info["reward_terms"]["accuracy"]
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
    assert 0 < errors[-1] < start
    assert area == pytest.approx(-0.3 * np.log(np.array(errors) / start).sum())
    assert accuracy == pytest.approx(-2.0 * 100 * (errors[-1] - start))


def test_error_term_is_finite_for_a_robot_without_spread():
    env = gym.make("excite/DiffDriveCalibIdeal-v0", error_weight=0.1,
                   robot={"radius_rel": 0.0, "separation_rel": 0.0}).unwrapped
    env.reset(seed=0)
    assert env.max_relative_error == 0.0
    _, reward, *_ = env.step(np.array([0.3, 0.1]))
    assert np.isfinite(reward)


def test_sigma_min_matches_batch_information_at_the_estimate():
    env = gym.make("excite/DiffDriveCalibIdeal-v0").unwrapped
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(20):
        *_, info = env.step(rng.uniform(-0.4, 0.4, 2))
    from excite.core.information import fisher_information, scaled_jacobian, sigma_min

    seg = env.segments
    expected = sigma_min(fisher_information(scaled_jacobian(
        seg.dphi_L, seg.dphi_R, env.estimate, env.sigma, scale=env.nominal)))
    assert info["sigma_min"] == pytest.approx(expected)


def test_target_sigma_min_terminates():
    env = gym.make("excite/DiffDriveCalibIdeal-v0", target_sigma_min=20.0).unwrapped
    env.reset(seed=0)
    for step in range(30):
        *_, terminated, truncated, info = env.step(np.array([0.3, -0.1 if step % 2 else 0.3]))
        if terminated:
            break
    assert terminated and info["sigma_min"] >= 20.0


def test_observation_never_contains_the_truth():
    """Two episodes with the same seed but different hidden robots observe the same
    quantities up to what the measurements reveal; the truth itself is not in the vector."""
    env = gym.make("excite/DiffDriveCalibIdeal-v0").unwrapped
    obs, _ = env.reset(seed=0)
    truth = env.true_params.as_array()
    for value in np.concatenate([truth, truth / env.nominal.as_array() - 1]):
        assert not np.any(np.isclose(obs, value, rtol=0, atol=1e-7))
    np.testing.assert_allclose(obs[:3], 0.0, atol=1e-6)  # before any segment: the nominal


def test_unknown_config_keys_and_bad_values_are_refused():
    with pytest.raises(ValueError, match="unknown config key 'buget'"):
        DiffDriveCalibEnv(buget=3)
    for budget in (0, 2.7, True):  # 2.7 was cut to 2 without a word
        with pytest.raises(ValueError, match="budget must be a whole number of segments"):
            DiffDriveCalibEnv(budget=budget)
    for key in ("sigma_xy", "sigma_theta"):  # 0 was taken, and reset failed
        with pytest.raises(ValueError, match=f"{key} must be a positive number"):
            DiffDriveCalibEnv(**{key: 0.0})
    for key in ("collision_penalty", "time_cost", "target_bonus"):  # NaN rewards
        with pytest.raises(ValueError, match=f"{key} must be a finite number"):
            DiffDriveCalibEnv(**{key: float("nan")})
    for scale in (0.0, -100.0, float("nan"), "2.0e2", None, True):
        with pytest.raises(ValueError, match="information_scale must be a positive number"):
            DiffDriveCalibEnv(information_scale=scale)


def test_collision_is_penalized_and_reported():
    env = gym.make("excite/DiffDriveCalibIdeal-v0").unwrapped
    env.reset(seed=0, options={"pose": np.array([1.2, 0.0, 0.0])})
    *_, info = env.step(np.array([1.0, 1.0]))  # 1 m/s towards the wall 0.8 m away
    assert info["collision"] and info["reward_terms"]["collision"] == -1.0


def test_rgb_array_render():
    env = gym.make("excite/DiffDriveCalib-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.array([0.5, 0.2]))
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.std() > 10  # not blank
    env.close()


def test_pluggable_estimator_and_ideal_env_batch_consistency():
    """Ideal env: the model is exact, so calibrate() on the episode log is unbiased and its
    covariance honest; and a user's estimator factory is used."""
    made = []

    def factory(nominal, sigma):
        made.append(OnlineEstimator(nominal, sigma=sigma, iterations=1))
        return made[-1]

    env = gym.make("excite/DiffDriveCalibIdeal-v0", estimator_factory=factory,
                   budget=60).unwrapped
    nees = []
    for seed in range(30):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        for _ in range(60):
            env.step(env.action_space.sample())
        result = calibrate(env.segments, sigma=env.sigma)
        error = result.params.as_array() - env.true_params.as_array()
        nees.append(error @ np.linalg.solve(result.covariance, error))
        assert env.estimator is made[-1]
    assert len(made) == 30
    # mean NEES of 30 draws of chi2(3): 95% interval about [2.2, 3.9]
    assert 2.0 < np.mean(nees) < 4.2, np.mean(nees)


@pytest.mark.slow
@pytest.mark.statistical
def test_estimator_harness_ideal_is_consistent_and_slip_is_not():
    ideal = check_estimator("excite/DiffDriveCalibIdeal-v0", episodes=40, budget=60)
    assert_consistent(ideal)
    assert ideal.rmse.shape == (60, 3) and ideal.rmse[-1].max() < ideal.rmse[5].max()
    slip = check_estimator("excite/DiffDriveCalib-v0", episodes=10, budget=30)
    assert not slip.consistent
    with pytest.raises(AssertionError, match="INCONSISTENT"):
        assert_consistent(slip)


def test_nominal_params_and_truth_access():
    env = gym.make("excite/DiffDriveCalib-v0").unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.true_params  # noqa: B018
    env.reset(seed=0)
    assert env.nominal == Params(0.05, 0.05, 0.30)
    rel = env.true_params.as_array() / env.nominal.as_array() - 1
    assert np.all(np.abs(rel) <= 0.05)


def test_sensor_env_measures_the_sensor_motion_with_a_hidden_mounting():
    """Ideal drive, fine encoders, tiny noise: every row is the sensor-pose model at the hidden
    truth; the six-parameter estimator and sigma_min run; the truth is never observed."""
    from excite.core.models import SENSOR_POSE
    from excite.registration import SENSOR_MOUNTING

    env = gym.make("excite/DiffDriveCalibIdeal-v0", sensor_pose=SENSOR_MOUNTING,
                   ticks_per_rev=2**30, sigma_xy=1e-9, sigma_theta=1e-9)
    obs, _ = env.reset(seed=4)
    base = env.unwrapped
    mount = base.true_sensor_pose
    assert obs.shape == (25,) and mount is not None and base.model is SENSOR_POSE
    for low_high, value in zip(np.array(list(SENSOR_MOUNTING.values())), mount.as_array(),
                               strict=True):
        assert low_high[0] <= value <= low_high[1]
    for action in ([0.3, 0.1], [-0.2, 0.25], [0.2, 0.2], [0.1, -0.3]):
        *_, info = env.step(np.array(action))
        row = info["measurement"]
        predicted = SENSOR_POSE.predict(row[:1], row[1:2], base.true_theta)[0]
        np.testing.assert_allclose(row[2:], predicted, atol=1e-6)
    assert info["estimate"].shape == (6,) and base.information_at(base.true_theta).shape == (6, 6)
    assert info["sigma_min"] > 0
    other = gym.make("excite/DiffDriveCalibIdeal-v0", sensor_pose=SENSOR_MOUNTING)
    other.reset(seed=5)
    assert other.unwrapped.true_sensor_pose != mount


def test_sensor_pose_config_is_validated():
    for bad in ({"x": (0.2, 0.1)}, {"z": (0, 1)}, {"theta": (-4.0, 0.0)}, [0, 1]):
        with pytest.raises(ValueError, match="sensor_pose"):
            gym.make("excite/DiffDriveCalib-v0", sensor_pose=bad)


@pytest.mark.parametrize("preset", ["turtlebot3", "jackal", "husky"])
def test_robot_presets_scale_the_arena_and_run(preset):
    from envs.robot import PRESETS

    env = gym.make("excite/DiffDriveCalib-v0", robot=preset)
    env.reset(seed=0)
    base = env.unwrapped
    assert base.config["arena_size"] == PRESETS[preset].arena_size()
    assert base.nominal.b == PRESETS[preset].separation
    assert base.knowledge().chassis == PRESETS[preset].nominal().chassis
    for _ in range(5):
        obs, *_ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)


def test_a_user_factory_whose_update_breaks_the_contract_is_a_one_line_error():
    """An estimator given straight to the env (not through a spec) whose update takes one
    argument: an EstimatorError naming what is wrong at reset, not a TypeError inside step."""
    from excite.errors import EstimatorError

    class OneArgument:
        params = np.array([0.05, 0.05, 0.3])
        covariance = np.eye(3)

        def update(self, segment):
            pass

    def factory(nominal, sigma):
        return OneArgument()

    env = gym.make("excite/DiffDriveCalibIdeal-v0", estimator_factory=factory)
    with pytest.raises(EstimatorError, match=r"estimator .*factory.*: its update\(segment\) does "
                                             r"not take the segment's five values"):
        env.reset(seed=0)
