"""The batched environment: make_vec, equivalence with the single env, autoreset, budget."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from scipy import stats

import envs.env as env_module
import excite  # noqa: F401  (registers the ids)
from envs.robot import robot_distribution
from envs.simulation import BatchSimulation, Simulation, SimulationConfig
from envs.vector_env import DiffDriveCalibVectorEnv
from excite.core.information import information_matrices, information_matrix
from excite.core.models import AXLE, SENSOR_POSE
from excite.estimators.online import BatchOnlineEstimator

IDEAL, SLIP, SENSOR = ("excite/DiffDriveCalibIdeal-v0", "excite/DiffDriveCalib-v0",
                       "excite/DiffDriveCalibSensor-v0")


@pytest.mark.parametrize("mode", [None, "vector_entry_point"])
def test_make_vec_returns_the_native_vector_env(mode):
    venv = gym.make_vec(SLIP, num_envs=3, vectorization_mode=mode, budget=4)
    assert isinstance(venv.unwrapped, DiffDriveCalibVectorEnv)
    assert venv.num_envs == 3 and venv.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert venv.observation_space.shape == (3, 16) and venv.action_space.shape == (3, 2)
    assert venv.single_observation_space == gym.make(SLIP).observation_space
    obs, info = venv.reset(seed=0)
    assert obs.dtype == np.float32 and obs in venv.observation_space
    obs, reward, terminated, truncated, info = venv.step(venv.action_space.sample())
    assert obs in venv.observation_space
    assert reward.shape == terminated.shape == truncated.shape == (3,)
    assert terminated.dtype == truncated.dtype == bool
    assert set(info["reward_terms"]) == {"information", "collision", "effort", "time",
                                         "accuracy", "error", "stop"}
    np.testing.assert_allclose(sum(info["reward_terms"].values()), reward)


@pytest.mark.parametrize("make", [gym.make, gym.make_vec])
def test_the_env_owns_its_budget(make):
    env = make(IDEAL, budget=7)
    env.reset(seed=1)
    vector = make is gym.make_vec
    for step in range(1, 8):
        action = np.zeros((1, 2)) if vector else np.zeros(2)
        *_, truncated, _ = env.step(action + 0.3)
        assert bool(np.all(truncated)) == (step == 7)


def run_pair(env_id, n, seed, steps, actions_seed=0, **config):
    """make_vec with n robots and n single envs seeded seed + i, driven by the same actions;
    returns the per-step (vector, single) observations, rewards, rows and ends."""
    venv = gym.make_vec(env_id, num_envs=n, **config)
    singles = [gym.make(env_id, **config) for _ in range(n)]
    obs, _ = venv.reset(seed=seed)
    single_obs = np.array([env.reset(seed=seed + i)[0] for i, env in enumerate(singles)])
    out = [(obs, single_obs, None, None, None, None)]
    ended = np.zeros(n, dtype=bool)
    rng = np.random.default_rng(actions_seed)
    for _ in range(steps):
        actions = rng.uniform(-1, 1, (n, 2))
        obs, reward, terminated, truncated, info = venv.step(actions)
        s_obs, s_reward, s_rows = [], [], []
        for i, env in enumerate(singles):
            if ended[i]:  # NEXT_STEP: this step resets robot i
                s_obs.append(env.reset()[0])
                s_reward.append(0.0)
                s_rows.append(np.zeros(5))
                assert info["n_segments"][i] == 0 and reward[i] == 0.0
                continue
            o, r, te, tr, inf = env.step(actions[i])
            assert (te, tr) == (terminated[i], truncated[i])
            s_obs.append(o)
            s_reward.append(r)
            s_rows.append(inf["measurement"])
        out.append((obs, np.array(s_obs), reward, np.array(s_reward), info["measurement"],
                    np.array(s_rows)))
        ended = terminated | truncated
    return out


@pytest.mark.parametrize("batch_estimator", [False, True])
@pytest.mark.parametrize("env_id", [IDEAL, SLIP])
def test_robot_i_is_the_single_env_with_seed_plus_i(env_id, batch_estimator, monkeypatch):
    """Identical segments (bit for bit) across an autoreset, wall contacts and slip included;
    observations and rewards equal up to rounding: the eigen-solvers' (LAPACK's eigh here,
    the closed form in the single env: an eigenvalue near 0 is known to eps * ||F|| (||F|| <
    1e8 here), so sigma_min to sqrt(1e-16 * 1e8) = 1e-4 and the reward (sigma_min / 100) to
    1e-6) and, with the estimators batched (as from BATCH_ESTIMATOR_MIN robots), the
    filter's (the unrolled one orders its arithmetic differently: estimates within ~1e-9)."""
    monkeypatch.setattr(env_module, "BATCH_ESTIMATOR_MIN", 1 if batch_estimator else 10**9)
    estimators = gym.make_vec(env_id, num_envs=3).unwrapped.estimators
    assert isinstance(estimators, BatchOnlineEstimator) == batch_estimator
    out = run_pair(env_id, 3, seed=40, steps=25, budget=12, error_weight=0.01)
    collisions = 0
    for obs, s_obs, reward, s_reward, rows, s_rows in out:
        np.testing.assert_allclose(obs, s_obs, atol=1e-6)
        if rows is not None:
            np.testing.assert_array_equal(rows, s_rows)
            np.testing.assert_allclose(reward, s_reward, rtol=1e-9, atol=1e-6)
            collisions += np.sum(s_reward <= -0.5)  # the collision penalty is 1
    assert collisions >= 2, "the random actions must reach the walls"


@pytest.mark.parametrize("batch_estimator", [False, True])
def test_sensor_id_draws_the_same_robots_mountings_and_noise(batch_estimator, monkeypatch):
    """Same rows; same observations except the weakest eigenvector (indices 12-17), which is
    arbitrary within the null space of F while fewer segments than parameters are in."""
    monkeypatch.setattr(env_module, "BATCH_ESTIMATOR_MIN", 1 if batch_estimator else 10**9)
    out = run_pair(SENSOR, 2, seed=3, steps=3, budget=8, ideal=True)
    keep = np.r_[0:12, 18:25]
    for obs, s_obs, _, _, rows, s_rows in out:
        if rows is not None:
            np.testing.assert_array_equal(rows, s_rows)
        np.testing.assert_allclose(obs[:, keep], s_obs[:, keep], atol=1e-5)


def test_slip_physics_kernel_is_shared_bit_for_bit():
    """In a large arena (no walls reached) robot i of the batch and a single Simulation give
    the same rows bit for bit, slipping included (one compiled kernel on 5 robots or on 1)."""
    config = SimulationConfig(arena_width=60.0, arena_height=60.0)
    batch, single, slipped = _batch_and_single_rows(config, n=5, segments=12)
    assert slipped, "the commands must make the wheels slip"
    np.testing.assert_array_equal(batch, single)


def _batch_and_single_rows(config, n, segments):
    distribution = robot_distribution({})
    batch = BatchSimulation(config, n)
    singles = []
    for i in range(n):
        robot = distribution.sample(np.random.default_rng(i))
        batch.reset(i, robot, np.random.default_rng(50 + i), pose=(0.0, 0.0, 0.3 * i))
        single = Simulation(config)
        single.reset(robot, np.random.default_rng(50 + i), pose=(0.0, 0.0, 0.3 * i))
        singles.append(single)
    commands = np.random.default_rng(9).uniform(-20, 20, (segments, n, 2))  # full speed: slip
    batch_rows, single_rows = [], []
    slipped = False
    for command in commands:
        batch_rows.append(batch.run_segment(command, 1.0).measurement)
        outcomes = [s.run_segment(*c, 1.0) for s, c in zip(singles, command, strict=True)]
        single_rows.append([o.measurement for o in outcomes])
        # slip: the wheels turned more or less than the body's arc
        slipped |= any(abs(o.true_dphi[0] * s.robot.r_L + o.true_dphi[1] * s.robot.r_R) / 2
                       > 1.05 * abs(o.true_increment[0]) + 0.05
                       for o, s in zip(outcomes, singles, strict=True))
    return np.array(batch_rows), np.array(single_rows), slipped


def test_slip_env_final_error_and_sigma_min_are_indistinguishable():
    """Independent episodes (different seeds) of make_vec and of the single env: two-sample
    Kolmogorov-Smirnov tests on the final max relative error and sigma_min."""
    n, budget = 24, 10
    venv = gym.make_vec(SLIP, num_envs=n, budget=budget).unwrapped
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (budget, n, 2))
    for a in actions[:-1]:
        venv.step(a)
    # the last step ends every episode; read the results before the next step resets them
    _, _, _, truncated, info = venv.step(actions[-1])
    assert truncated.all()
    vector = (venv.max_relative_errors, info["sigma_min"])
    env = gym.make(SLIP, budget=budget).unwrapped
    errors, sigmas = [], []
    for episode in range(n):
        env.reset(seed=10_000 + episode)
        for a in actions[:, episode]:
            *_, info = env.step(a)
        errors.append(env.max_relative_error)
        sigmas.append(info["sigma_min"])
    for a, b in ((vector[0], errors), (vector[1], sigmas)):
        assert stats.ks_2samp(a, b).pvalue > 0.001


def test_same_step_autoreset_reports_the_final_observation():
    kwargs = {"num_envs": 2, "budget": 3}
    next_step = gym.make_vec(IDEAL, **kwargs)
    same_step = gym.make_vec(IDEAL, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
    assert same_step.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    a, _ = next_step.reset(seed=5)
    b, _ = same_step.reset(seed=5)
    actions = np.random.default_rng(1).uniform(-1, 1, (3, 2, 2))
    for k, action in enumerate(actions):
        a, *_, a_trunc, _ = next_step.step(action)
        b, *_, b_trunc, b_info = same_step.step(action)
        assert (a_trunc == b_trunc).all() and a_trunc.all() == (k == 2)
    np.testing.assert_array_equal(b_info["final_obs"], a)
    assert b_info["_final_obs"].all()
    a, reward, *_ = next_step.step(np.zeros((2, 2)))  # NEXT_STEP resets now
    assert (reward == 0).all()
    np.testing.assert_array_equal(b, a)


def test_deterministic_under_seed_and_bad_input():
    def rollout(seed):
        venv = gym.make_vec(SLIP, num_envs=2, budget=4)
        obs, _ = venv.reset(seed=seed)
        rng = np.random.default_rng(0)
        out = [obs]
        for _ in range(5):
            obs, reward, *_ = venv.step(rng.uniform(-1, 1, (2, 2)))
            out += [obs.ravel(), reward]
        return np.concatenate([np.ravel(x) for x in out])

    np.testing.assert_array_equal(rollout(1), rollout(1))
    assert not np.array_equal(rollout(1), rollout(2))
    venv = gym.make_vec(SLIP, num_envs=2)
    with pytest.raises(RuntimeError):
        venv.step(np.zeros((2, 2)))
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        venv.step(np.array([[0.0, np.nan], [0.0, 0.0]]))
    with pytest.raises(ValueError, match="num_envs"):
        DiffDriveCalibVectorEnv(num_envs=0)
    with pytest.raises(ValueError, match="unknown config key"):
        DiffDriveCalibVectorEnv(num_envs=2, bogus=1)


@pytest.mark.parametrize("model", [AXLE, SENSOR_POSE])
def test_information_matrices_match_information_matrix(model):
    rng = np.random.default_rng(0)
    n, k = 4, 6
    theta = np.tile([0.05, 0.051, 0.3, 0.1, 0.0, 0.2][:model.size], (n, 1))
    theta *= rng.uniform(0.95, 1.05, theta.shape)
    phi = rng.uniform(-15, 15, (2, n, k))
    counts = [6, 3, 1, 0]
    for i, c in enumerate(counts):
        phi[:, i, c:] = 0.0  # padding
    nominal = theta[0]
    batch = information_matrices(phi[0], phi[1], theta, (2e-3, 2e-3, 1e-3), nominal, model)
    for i, c in enumerate(counts):
        expected = (information_matrix(phi[0, i, :c], phi[1, i, :c], theta[i],
                                       (2e-3, 2e-3, 1e-3), scale=nominal, model=model)
                    if c else np.zeros((model.size,) * 2))
        np.testing.assert_allclose(batch[i], expected, rtol=1e-10,
                                   atol=1e-10 * max(1.0, np.abs(expected).max()))


def test_a_batch_of_one_is_the_single_simulation_bit_for_bit_with_wall_contacts():
    """N = 1 runs the kernel on floats: the same rows as Simulation, collisions included."""
    config = SimulationConfig()
    robot = robot_distribution({}).sample(np.random.default_rng(3))
    batch, single = BatchSimulation(config, 1), Simulation(config)
    batch.reset(0, robot, np.random.default_rng(8))
    single.reset(robot, np.random.default_rng(8))
    collisions = 0
    for command in np.random.default_rng(4).uniform(-20, 20, (30, 2)):
        out = batch.run_segment(command[None], 1.0)
        expected = single.run_segment(*command, 1.0)
        np.testing.assert_array_equal(out.measurement[0], expected.measurement)
        assert out.collision[0] == expected.collision
        collisions += expected.collision
    assert collisions >= 3


def test_user_estimators_partial_resets_and_seed_lists():
    from excite import OnlineEstimator

    made = []

    def factory(nominal, sigma):
        made.append(OnlineEstimator(nominal, sigma=sigma, iterations=1))
        return made[-1]

    venv = DiffDriveCalibVectorEnv(num_envs=3, estimator_factory=factory, budget=5, ideal=True)
    obs, _ = venv.reset(seed=[4, None, 9])
    assert len(made) == 3 and venv.estimators == made
    single = gym.make(IDEAL, budget=5)
    np.testing.assert_allclose(obs[2], single.reset(seed=9)[0], atol=1e-6)
    venv.step(np.full((3, 2), 0.4))
    assert all(e.n_segments == 1 for e in made)
    obs, info = venv.reset(options={"reset_mask": np.array([False, True, False])})
    assert info["n_segments"].tolist() == [1, 0, 1] and len(made) == 4
    with pytest.raises(ValueError, match="seed"):
        venv.reset(seed=[1, 2])


@pytest.mark.parametrize("model", [AXLE, SENSOR_POSE])
def test_batched_observations_are_the_single_env_observation(model):
    """observations (the vector env's, batch-first) and observation (the single env's, on
    Python floats) give the same float32 numbers, clipping and the eigenvector's sign
    included (ties in magnitude: the first entry decides)."""
    from envs.env import DiffDriveCalibEnv
    from envs.observation import observation, observations

    env = DiffDriveCalibEnv(sensor_pose=None if model is AXLE else {"x": (0.0, 0.1)})
    rng = np.random.default_rng(0)
    n, p = 200, model.size
    nominal = env.nominal_theta
    theta = nominal * rng.uniform(0.0, 2.5, (n, p)) + rng.normal(0, 0.05, (n, p))
    eigenvalues = np.sort(rng.lognormal(3.0, 6.0, (n, p)), axis=1) * rng.choice([-1e-9, 1], (n, p))
    weakest = rng.normal(size=(n, p))
    weakest[:5, :2] = [[0.5, -0.5], [-0.5, 0.5], [0.0, 0.0], [-1.0, 1.0], [1.0, -1.0]]
    pose = rng.uniform(-4, 4, (n, 3)) * [1, 1, 3]
    actions = rng.uniform(-1, 1, (n, 2))
    used = rng.uniform(0, 1, n)
    batch = observations(model, theta, nominal, eigenvalues, weakest, pose, actions, used,
                         env.config["arena_size"], env.observation_space)
    assert batch.dtype == np.float32 and batch.shape == (n, 3 * p + 7)
    for i in range(n):
        one = observation(model, theta[i].tolist(), nominal.tolist(), eigenvalues[i].tolist(),
                          weakest[i].tolist(), pose[i].tolist(), actions[i].tolist(),
                          float(used[i]), env.config["arena_size"], env.observation_space)
        np.testing.assert_array_equal(batch[i], one)
    space = env.observation_space
    assert (batch == space.high).any() and (batch == space.low).any()  # clipped both ways


def test_batched_sensor_increments_and_poses_are_the_single_robots():
    """body_to_sensor with one mounting per increment, and measure_poses / sense_increments
    of N robots, are the one-robot computations bit for bit (each robot drawing its own
    noise)."""
    from envs.observation import measure_poses, sense_increments
    from envs.sensors import RelativePoseSensor
    from excite.core.models import SensorPose, body_to_sensor

    rng = np.random.default_rng(1)
    n = 9
    body = rng.normal(0, 0.5, (n, 3))
    mounts = rng.uniform(-0.2, 0.2, (n, 3)) * [1, 1, 10]
    each = body_to_sensor(body, mounts)
    for i in range(n):
        np.testing.assert_array_equal(each[i], body_to_sensor(body[i:i + 1],
                                                              SensorPose(*mounts[i]))[0])
    sensor = RelativePoseSensor()
    theta = np.column_stack([np.full((n, 3), 0.1), mounts + 0.01])

    def rngs(robots):
        return [np.random.default_rng(i) for i in robots]

    sensed = sense_increments(sensor, body, rngs(range(n)), mounts)
    poses = measure_poses(sensor, body, rngs(range(n)), mounts, theta)
    axle = measure_poses(sensor, body, rngs(range(n)), None, theta)
    for i in range(n):
        one = slice(i, i + 1)
        np.testing.assert_array_equal(
            sensed[i], sense_increments(sensor, body[one], rngs([i]), mounts[one])[0])
        np.testing.assert_array_equal(
            poses[i], measure_poses(sensor, body[one], rngs([i]), mounts[one], theta[one])[0])
        np.testing.assert_array_equal(axle[i], sensor.absolute(body[i], rngs([i])[0]))
    assert not np.array_equal(sensed, body) and not np.array_equal(axle, body)


def test_the_built_in_filter_keeps_its_settings_when_batched(monkeypatch):
    """estimator_factory "online:..." becomes one BatchOnlineEstimator with the spec's
    settings (the estimates follow the single env's filter with the same spec, far closer
    than the settings' effect); other built-ins stay one estimator per robot."""
    from excite.estimators import estimator_factory

    monkeypatch.setattr(env_module, "BATCH_ESTIMATOR_MIN", 1)
    spec = estimator_factory("online:iterations=1:prior_std=0.002")
    kwargs = {"budget": 6, "ideal": True}
    venv = DiffDriveCalibVectorEnv(num_envs=2, estimator_factory=spec, **kwargs)
    assert isinstance(venv.estimators, BatchOnlineEstimator)
    default = DiffDriveCalibVectorEnv(num_envs=2, **kwargs)
    singles = [gym.make(IDEAL, estimator_factory=spec, **kwargs).unwrapped for _ in range(2)]
    venv.reset(seed=7)
    default.reset(seed=7)
    for i, env in enumerate(singles):
        env.reset(seed=7 + i)
    for action in np.random.default_rng(2).uniform(-1, 1, (5, 2, 2)):
        *_, info = venv.step(action)
        *_, default_info = default.step(action)
        expected = [env.step(a)[-1]["estimate"] for env, a in zip(singles, action, strict=True)]
        np.testing.assert_allclose(info["estimate"], expected, rtol=1e-10)
    settings_effect = np.abs(info["estimate"] / default_info["estimate"] - 1).max()
    assert settings_effect > 1e-6
    ekf = DiffDriveCalibVectorEnv(num_envs=2, estimator_factory=estimator_factory("ekf"),
                                  **kwargs)
    assert isinstance(ekf.estimators, list)
