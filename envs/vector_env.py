"""N robots of :class:`envs.env.DiffDriveCalibEnv` stepped together in one process.

``gymnasium.make_vec("excite/DiffDriveCalib-v0", num_envs=N)`` returns
:class:`DiffDriveCalibVectorEnv` (every id registers it as its ``vector_entry_point``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.env import DiffDriveCalibEnv
from envs.observation import measure_poses, observations, read_estimate, sense_increments
from envs.reward import REWARD_TERMS, reward_terms, uses_error
from envs.simulation import BatchOutcome, BatchSimulation
from envs.target import ENCODER_READINGS, decide, stopping_rule
from excite.contracts import Estimator, EstimatorFactory
from excite.core.information import information_matrices
from excite.core.kinematics import Params
from excite.estimators.online import BatchOnlineEstimator
from excite.stopping import StopDecision


class DiffDriveCalibVectorEnv(VectorEnv):
    """``num_envs`` robots of :class:`envs.env.DiffDriveCalibEnv` in one process.

    Every robot lives in the same arena (one pymunk space; chassis never touch each other,
    only the walls) and is stepped by one batched physics call per segment
    (:class:`envs.simulation.BatchSimulation`, the single env's physics kernel on arrays).
    Everything after the physics is array code over the robots too: the sensor rows, the
    estimator updates (the default ``estimator_factory``, the built-in ``online``, becomes
    :class:`excite.estimators.online.BatchOnlineEstimator`, every robot's filter in one pass; any
    other
    factory gives one estimator per robot, updated in turn), the logs, the information
    matrices, their eigenvalues, the rewards and the observations. Each robot keeps its own
    random streams (its noise is drawn from them one robot at a time).

    Robot i reset with seed s draws exactly as the single env reset with seed s + i: the
    same hidden robot, start, sensor mounting and noise; given the single env's actions it
    produces the single env's segments bit for bit (the physics is the same kernel; tested).
    Estimates, observations and rewards agree to rounding: from ``BATCH_ESTIMATOR_MIN``
    robots the filter is :class:`excite.estimators.online.BatchOnlineEstimator` (the single env's
    unrolled filter orders its arithmetic differently: final estimates within ~1e-9
    relative), F comes from the batched chord rows (the single env's from pure-Python
    moments), and its eigen-decomposition is LAPACK's here and a closed form in the single
    env (sigma_min within ~1e-9 relative; benchmarks/bench_equivalence.py).

    Autoreset: ``autoreset_mode`` NEXT_STEP (default, gymnasium's documented convention: the
    step after an episode's end resets that robot and returns its first observation with
    reward 0) or SAME_STEP (the ended robot is reset in the same step; its last observation
    and info are in ``info["final_obs"]``, ``info["final_info"]``, masked by
    ``info["_final_obs"]``).

    Configuration: the single env's keys (:mod:`envs.config`, tabled in DiffDriveCalibEnv's
    docstring), as ``config={...}`` or keyword arguments; ``budget`` ends every robot's
    episode.
    ``reset(options={"robot": RobotSpec, "pose": (x, y, theta)})`` fixes every robot's hidden
    robot / start pose; ``options={"reset_mask": (N,) bool}`` resets only those robots.

    Info (arrays over robots): ``reward_terms`` (a dict of (N,) arrays), ``sigma_min``,
    ``collision``, ``n_segments``, ``measurement`` (N, 5), ``estimate`` (N, P). For evaluation:
    ``true_theta`` (N, P), ``true_params``, ``max_relative_errors`` (N,), ``segments_logged``;
    in target mode ``last_stops``, the stopping rule's decisions of the last step
    (:class:`excite.stopping.StopDecision` with its batch calibration; None for a robot that did
    not move). The estimators: ``estimators``, a
    :class:`excite.estimators.online.BatchOnlineEstimator` (its ``theta`` (N, P)) or a list of
    one estimator per robot.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 1,
        config: dict[str, Any] | None = None,
        estimator_factory: EstimatorFactory | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
        **overrides: Any,
    ):
        if not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if render_mode is not None:
            raise ValueError("the vector env does not render; render a single env instead")
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        if self.autoreset_mode is AutoresetMode.DISABLED:
            raise ValueError("autoreset_mode must be NEXT_STEP or SAME_STEP")
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        # One single env parses and validates the configuration: the same keys, spaces and
        # nominal robot, the same simulation settings.
        self.single = DiffDriveCalibEnv(config=config, estimator_factory=estimator_factory,
                                        **overrides)
        self.num_envs = int(num_envs)
        self.config = self.single.config
        self.single_observation_space = self.single.observation_space
        self.single_action_space = self.single.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self.sim = BatchSimulation(self.single.sim.config, self.num_envs)
        self.model = self.single.model
        self.budget = self.single.budget
        self._rule = stopping_rule(self.config, self.model)
        n, p = self.num_envs, self.model.size
        self._generators: list[np.random.Generator | None] = [None] * n
        self._sensor_rngs: list[np.random.Generator | None] = [None] * n  # set by reset
        #: the hidden sensor mountings (N, 3) (x, y in m, theta in rad); None on the axle
        self._mounts = None if self.single.sensor_ranges is None else np.zeros((n, 3))
        #: every robot's estimator: one batch of the built-in filter, or one per robot
        self.estimators: BatchOnlineEstimator | list[Estimator | None] = (
            self.single.new_estimators(n) or [None] * n)
        self._log = np.zeros((n, self.budget, 5))
        #: target mode: each row's encoder sub-increments (N, budget, K, 2), set at the first step
        self._sub: np.ndarray | None = None
        self._n = np.zeros(n, dtype=int)
        self._last_action = np.zeros((n, 2))
        self._sigma_min = np.zeros(n)
        self._theta = np.tile(self.single.nominal_theta, (n, 1))
        self._true_theta = np.tile(self.single.nominal_theta, (n, 1))
        self._eigenvalues = np.zeros((n, p))
        self._weakest = np.zeros((n, p))
        self._measured_pose = np.zeros((n, 3))
        self._error = np.zeros(n)
        self._start_error = np.zeros(n)
        self._ended = np.zeros(n, dtype=bool)  # NEXT_STEP: reset these on the next step
        self._started = False
        self.last_stops: list[StopDecision | None] = [None] * n

    # -- episodes --------------------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None):
        """Reset every robot (or those of ``options["reset_mask"]``); robot i takes seed
        ``seed + i`` (or ``seed[i]`` from a list)."""
        options = dict(options or {})
        mask = np.asarray(options.pop("reset_mask", np.ones(self.num_envs, dtype=bool)))
        if mask.shape != (self.num_envs,) or mask.dtype != bool:
            raise ValueError(f"reset_mask must be {self.num_envs} booleans")
        if seed is None or isinstance(seed, int | np.integer):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int or a list of {self.num_envs} seeds")
        self._reset_robots(mask, seeds, options)
        self._started = True
        obs = self._observations()
        info = {"sigma_min": self._sigma_min.copy(), "n_segments": self._n.copy()}
        return obs, info

    def _reset_robots(self, mask: np.ndarray, seeds: list[int | None],
                      options: dict[str, Any]) -> None:
        """Start new episodes for the robots of ``mask`` (N,): each robot's draws one by one
        (its own streams, in DiffDriveCalibEnv.reset's order), the rest for all at once."""
        robots = np.flatnonzero(mask)
        for i in robots:
            self._reset_robot(i, seeds[i], options)
        if isinstance(self.estimators, BatchOnlineEstimator):
            self.estimators.reset(mask)
        self._n[mask] = 0
        self._last_action[mask] = 0.0
        self._sigma_min[mask] = 0.0
        self._theta[mask] = self.single.nominal_theta
        self._eigenvalues[mask] = 0.0
        self._weakest[mask] = np.eye(1, self.model.size)
        self._measured_pose[robots] = measure_poses(
            self.sim.pose_sensor, self.sim.poses[robots], [self._sensor_rngs[i] for i in robots],
            None if self._mounts is None else self._mounts[robots], self._theta[robots])
        self._error[mask] = self._start_error[mask] = self.max_relative_errors[mask]
        self._ended[mask] = False

    def _reset_robot(self, i: int, seed: int | None, options: dict[str, Any]) -> None:
        """Robot i's draws, in DiffDriveCalibEnv.reset's order: the hidden robot, its start,
        its streams and sensor mounting."""
        single = self.single
        if seed is not None or self._generators[i] is None:
            self._generators[i], _ = seeding.np_random(seed)
        rng = self._generators[i]
        robot, sim_rng, self._sensor_rngs[i], mount = single.draw_episode(rng, options)
        self.sim.reset(i, robot, sim_rng, pose=options.get("pose"))
        truth = np.array(robot.kinematic_params())
        if mount is not None:
            self._mounts[i] = mount.as_array()
            truth = np.append(truth, self._mounts[i])
        self._true_theta[i] = truth
        if not isinstance(self.estimators, BatchOnlineEstimator):
            self.estimators[i] = single.new_estimator()

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, dtype=float).reshape(self.num_envs, -1)
        if actions.shape[1] != 2 or not np.isfinite(actions).all():
            raise ValueError(f"actions must be ({self.num_envs}, 2) finite numbers")
        actions = np.clip(actions, -1.0, 1.0)
        config, single = self.config, self.single
        resetting = self._ended.copy()
        moving = ~resetting
        n_robots = self.num_envs
        terms = {name: np.zeros(n_robots) for name in REWARD_TERMS}
        decisions: list[StopDecision | None] = [None] * n_robots
        done = np.zeros(n_robots, dtype=bool)
        collision = np.zeros(n_robots, dtype=bool)
        rows = np.zeros((n_robots, 5))
        if moving.any():
            outcome = self.sim.run_segment(actions * single.max_wheel_speed,
                                           single.segment_duration, config["settle_time"],
                                           wheels=self._rule is not None)
            collision = outcome.collision & moving
            previous, previous_error = self._sigma_min.copy(), self._error.copy()
            rows[moving] = self._record(moving, outcome, actions)
            self._update_information(moving)
            if uses_error(config):
                self._error = self.max_relative_errors
            decisions = self._stop_decisions(moving)
            done = np.array([d is not None and d.done for d in decisions])
            terms = {name: np.where(resetting, 0.0, value) for name, value in reward_terms(
                config, self._sigma_min - previous, collision, (actions**2).sum(axis=1),
                (self._start_error, previous_error, self._error), done).items()}
        target = config["target_sigma_min"]
        terminated = moving & (((target is not None) & (self._sigma_min >= (target or 0.0)))
                               | done)
        truncated = moving & (self._n >= self.budget) & ~terminated
        info = {
            "reward_terms": terms,
            "sigma_min": self._sigma_min.copy(),
            "collision": collision,
            "measurement": rows,
            "estimate": self._theta.copy(),
            "n_segments": self._n.copy(),
        }
        self.last_stops = decisions
        if self._rule is not None:  # target mode: each robot's decision (None: not moving)
            info["stop"] = [None if d is None else d.to_dict() for d in decisions]
        reward = sum(terms.values())
        ended = terminated | truncated
        if resetting.any():  # NEXT_STEP: the robots that ended last step start anew
            self._reset_robots(resetting, [None] * n_robots, {})
            info["sigma_min"][resetting] = 0.0
            info["n_segments"][resetting] = 0
        obs = self._observations()
        if self.autoreset_mode is AutoresetMode.SAME_STEP and ended.any():
            info["final_obs"] = np.where(ended[:, None], obs, 0.0).astype(obs.dtype)
            info["_final_obs"] = ended.copy()
            info["final_info"] = {key: value.copy() if hasattr(value, "copy") else value
                                  for key, value in info.items() if not key.startswith("final")}
            info["_final_info"] = ended.copy()
            self._reset_robots(ended, [None] * n_robots, {})
            obs = np.where(ended[:, None], self._observations(), obs)
        else:
            self._ended = ended
        return obs, reward, terminated, truncated, info

    def _stop_decisions(self, moving: np.ndarray) -> list[StopDecision | None]:
        """Target mode: the stopping rule's decision for each moving robot (mask (N,)) on its
        segments so far; None for the others and when target mode is off."""
        decisions: list[StopDecision | None] = [None] * self.num_envs
        if self._rule is not None:
            assert self._sub is not None  # set by _record, before the first decision
            for i in np.flatnonzero(moving):
                decisions[i] = decide(self._rule, self._log[i, :self._n[i]],
                                      self._sub[i, :self._n[i]],
                                      self.single.nominal_theta)
        return decisions

    def _record(self, moving: np.ndarray, outcome: BatchOutcome,
                actions: np.ndarray) -> np.ndarray:
        """The moving robots' (mask (N,)) segments: the sensor's rows, the estimator updates,
        the log, the measured poses (each robot's random draws in DiffDriveCalibEnv.step's
        order); returns their rows (M, 5)."""
        robots = np.flatnonzero(moving)
        rngs = [self._sensor_rngs[i] for i in robots]
        rows = outcome.measurement.copy()
        mounts = None if self._mounts is None else self._mounts[robots]
        if mounts is not None:  # the sensor measures its own motion, in its own frame
            rows[robots, 2:] = sense_increments(self.sim.pose_sensor,
                                                outcome.true_increment[robots], rngs, mounts)
        if isinstance(self.estimators, BatchOnlineEstimator):
            self.estimators.update(rows, moving)
            self._theta[robots] = self.estimators.theta[robots]
        else:
            for i in robots:
                self.estimators[i].update(*rows[i].tolist())
                _, self._theta[i] = read_estimate(self.estimators[i], self.model,
                                                  self.single.nominal_theta)
        rows = rows[robots]
        n = self._n[robots]  # < budget: an episode ends at the budget and autoresets
        self._log[robots, n] = rows
        if outcome.wheel_path is not None:
            sub = self.sim.encoders.sub_increments(outcome.wheel_path[:, robots],
                                                   ENCODER_READINGS).transpose(1, 0, 2)
            if self._sub is None:
                self._sub = np.zeros((self.num_envs, self.budget, *sub.shape[1:]))
            self._sub[robots, n] = sub
        self._n[robots] = n + 1
        self._last_action[robots] = actions[robots]
        self._measured_pose[robots] = measure_poses(self.sim.pose_sensor,
                                                    outcome.pose_end[robots], rngs, mounts,
                                                    self._theta[robots])
        return rows

    def _update_information(self, robots: np.ndarray) -> None:
        """F at each robot's estimate over its log, its eigen-decomposition and sigma_min."""
        k = int(self._n.max())
        log = self._log[:, :k]
        information = information_matrices(log[..., 0], log[..., 1], self._theta,
                                           self.single.sigma, self.single.nominal_theta,
                                           self.model)
        eigenvalues, vectors = np.linalg.eigh(information)
        self._eigenvalues[robots] = eigenvalues[robots]
        self._weakest[robots] = vectors[robots, :, 0]
        self._sigma_min[robots] = np.sqrt(np.maximum(eigenvalues[robots, 0], 0.0))

    def _observations(self) -> np.ndarray:
        """Every robot's observation (N, 3 P + 7) (:func:`envs.observation.observations`)."""
        return observations(self.model, self._theta, self.single.nominal_theta,
                            self._eigenvalues, self._weakest, self._measured_pose,
                            self._last_action, self._n / self.budget, self.config["arena_size"],
                            self.single_observation_space)

    # -- evaluation only ---------------------------------------------------------------------
    @property
    def true_theta(self) -> np.ndarray:
        """The hidden model parameters (N, P) of every robot (evaluation only)."""
        return self._true_theta.copy()

    @property
    def true_params(self) -> list[Params]:
        """The hidden wheel parameters of every robot (evaluation only)."""
        return [Params(*row[:3]) for row in self._true_theta]

    @property
    def max_relative_errors(self) -> np.ndarray:
        """Every robot's largest relative wheel-parameter error (N,) (evaluation only)."""
        return np.max(np.abs(self._theta[:, :3] / self._true_theta[:, :3] - 1.0), axis=1)

    @property
    def segments_logged(self) -> list[np.ndarray]:
        """Every robot's calibration rows of its current episode (n_i, 5)."""
        return [self._log[i, :n].copy() for i, n in enumerate(self._n)]

