"""The Gymnasium environment: plan calibration maneuvers for a robot with hidden wheels."""

from __future__ import annotations

import copy
import inspect
import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.config import (
    check_config,
    config_reference,
    episode_budget,
    make_config,
    sensor_ranges,
)
from envs.config import default_config as _default_config
from envs.observation import (
    eigen,
    measure_poses,
    observation,
    observation_space,
    read_estimate,
    sense_increments,
)
from envs.recording import Recorder, Recording, RecordingConfig
from envs.reward import reward_terms, uses_error
from envs.robot import RobotSpec, robot_distribution, traction_of
from envs.simulation import Simulation, SimulationConfig
from envs.target import ENCODER_READINGS, decide, rule_segments, stopping_rule
from excite.contracts import Estimator, EstimatorFactory, RobotKnowledge
from excite.core.information import information_matrix
from excite.core.kinematics import Params
from excite.core.models import AXLE, SENSOR_POSE, SegmentModel, SensorPose
from excite.estimators import (
    DEFAULT_ESTIMATOR,
    EstimatorSpec,
    check_contract,
    estimator_factory,
)
from excite.estimators.online import BatchOnlineEstimator
from excite.logs.segments import Segments
from excite.stopping import StopDecision

#: The environment's estimator factory given none: the built-in of
#: :data:`excite.estimators.DEFAULT_ESTIMATOR` (:class:`excite.OnlineEstimator` started at the
#: nominal robot, and sensor pose on the sensor-pose model, with the sensor's noise levels).
default_estimator = estimator_factory(DEFAULT_ESTIMATOR)


#: Robots from which the vector env updates the built-in filter of every robot in one pass
#: of array code (below, one by one: the one-robot update is microseconds of pure Python,
#: the array pass a fixed ~0.2 ms). Measured on the ideal id (axle model), CPU us per
#: robot-step one by one vs in one pass: 66 vs 76 at 8 robots, 44 vs 46 at 16, 37 vs 35 at
#: 24, 33 vs 30 at 32. (The sensor-pose model's one-robot update is slower, ~90 us, so its
#: crossover is lower; one threshold keeps the rule simple.)
BATCH_ESTIMATOR_MIN = 20


class DiffDriveCalibEnv(gym.Env):
    """Excite a differential-drive robot so its wheel parameters become identifiable fast.

    A robot with hidden effective wheel radii r_L, r_R and wheel separation b (drawn per
    episode around the nominal robot) drives in a walled arena. Each step is one motion
    segment: the action holds two wheel-speed commands for ``segment_duration`` seconds
    (optionally followed by ``settle_time`` seconds of stop command: stop-and-go segments start
    and end at rest, which keeps the wheel-speed ratio, hence the curvature, constant); the
    encoders and an external pose sensor then give one calibration row
    (dphi_L, dphi_R, dx, dy, dtheta), which updates an online estimator. The reward is the
    information the segment added.

    On the slip id the robot drives continuously: the motors lag (first order) and the wheels
    push through friction-capped traction, so abrupt or fast maneuvers slip and curve
    differently from the constant-curvature model, while smooth, gentle ones follow it: the
    information a maneuver buys is traded against the bias it brings. The Ideal id rolls
    exactly along the model.

    ## Action space
    ``Box(-1, 1, (2,), float32)``: (left, right) wheel-speed commands as fractions of the
    motor limit (``robot["max_wheel_speed"]``, rad/s). Out-of-range actions are clipped;
    non-finite actions raise ``ValueError``.

    ## Observation space
    ``Box(float32, (3 P + 7,))`` for a model of P parameters (16 on the axle model, 25 with
    the sensor pose), only what a real robot could know (never the hidden truth):

    | index       | meaning |
    |-------------|---------|
    | 0 .. P-1    | estimate relative to nominal, clipped to [-1, 1] (*) |
    | P .. 2P-1   | log1p of the eigenvalues (ascending) of the information matrix F, / 10 |
    | 2P .. 3P-1  | eigenvector of F's smallest eigenvalue (the worst-known direction) |
    | 3P, 3P+1    | measured position x, y divided by the arena half-size |
    | 3P+2, 3P+3  | cos, sin of the measured heading |
    | 3P+4, 3P+5  | the previous action |
    | 3P+6        | fraction of the segment budget used |

    (*) r_L, r_R, b: estimate / nominal - 1; sensor l_x, l_y: (estimate - nominal) / nominal b;
    l_theta: estimate - nominal in rad. F is the whitened, relatively scaled Fisher information
    of all segments so far at the current estimate (docs/conventions.md); sigma_min =
    sqrt(lambda_min(F)).

    ## Sensor pose
    With ``sensor_pose`` set (the id ``excite/DiffDriveCalibSensor-v0``), the pose sensor is
    mounted at a hidden pose l = (l_x, l_y, l_theta) in the body frame, drawn uniformly per
    episode from the configured ranges; it measures its own motion in its own frame
    (docs/conventions.md,
    "Sensor pose"). The nominal mounting is the middle of the ranges. The default estimator and
    the reward then use the sensor-pose model: six parameters, sigma_min over all six.

    ## Reward
    A sum of named terms, each reported in ``info["reward_terms"]``:

    - ``information``: (sigma_min_t - sigma_min_{t-1}) / ``information_scale``; the episode's
      sum telescopes to the final sigma_min / information_scale;
    - ``collision``: -``collision_penalty`` when the chassis touched a wall;
    - ``effort``: -``effort_cost`` * mean(action^2); ``time``: -``time_cost`` per segment;
    - ``accuracy`` (privileged, for training in simulation only; 0 by default):
      -``accuracy_weight`` * 100 * (e_t - e_{t-1}), e the max relative error of the estimate
      against the hidden truth; the episode's sum telescopes to -accuracy_weight * 100 *
      (final error - nominal's error);
    - ``error`` (privileged, 0 by default): -``error_weight`` * ln(e_t / e_0), e_0 the
      nominal's error: the orders of magnitude gained so far, paid after every segment, so
      the episode's sum rewards accuracy reached early (the area between the log-error curve
      and its start), each halving of the error alike at 4% and at 0.1% (errors floored at
      1e-12, as a robot drawn without spread starts at 0).

    The observation never contains the truth.

    ## Episode end
    Truncated after ``budget`` segments (the env alone owns the budget: the ids register no
    ``max_episode_steps``). Terminated when ``target_sigma_min`` (if set) is reached.

    ## Evaluation
    ``env.unwrapped.true_params`` (hidden truth), ``env.unwrapped.segments`` (the episode's
    calibration log), ``env.unwrapped.estimator``; in target mode ``env.unwrapped.last_stop``,
    the stopping rule's last :class:`excite.stopping.StopDecision` with its batch calibration
    (None before the first segment and when target mode is off), and
    ``env.unwrapped.rule_segments``, the segments it decided on (each with its encoder
    readings: :mod:`envs.target`).

    ``reset(options={"robot": RobotSpec, "sensor_pose": SensorPose, "pose": (x, y, theta)})``
    fixes the hidden robot, the hidden sensor mounting (sensor-pose envs) and/or the start
    pose.

    ## Configuration
    The keys below, given as ``config={...}`` or keyword arguments, e.g.
    ``gymnasium.make("excite/DiffDriveCalib-v0", budget=50)``; an unknown key is a
    ``ValueError``. ``DiffDriveCalibEnv.default_config()`` returns the defaults.
    ``gymnasium.make_vec(id, num_envs=N)`` steps N robots in one process
    (:class:`envs.vector_env.DiffDriveCalibVectorEnv`). ``estimator_factory(nominal, sigma)``
    plugs in another estimator (default: :class:`excite.OnlineEstimator` at the nominal robot).
    """

    # The key table, rendered from the keys' one source (envs.config.CONFIG_KEYS); `or ""`:
    # python -OO strips docstrings.
    __doc__ = inspect.cleandoc(__doc__ or "") + "\n\n" + config_reference()

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}

    #: Every key with its default value (a new dict): :func:`envs.config.default_config`.
    default_config = staticmethod(_default_config)

    def __init__(
        self,
        render_mode: str | None = None,
        config: dict[str, Any] | None = None,
        estimator_factory: EstimatorFactory | None = None,
        **overrides: Any,
    ):
        cfg = make_config(config, overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        check_config(cfg)
        self.config = cfg
        self.render_mode = render_mode
        self.distribution = robot_distribution(cfg["robot"])
        if cfg["arena_size"] is None:
            cfg["arena_size"] = self.distribution.arena_size()
        nominal = self.distribution.nominal()
        self.nominal = Params(*nominal.kinematic_params())
        self.sensor_ranges = sensor_ranges(cfg["sensor_pose"])
        self.model: SegmentModel = AXLE if self.sensor_ranges is None else SENSOR_POSE
        self.nominal_theta = self.nominal.as_array()
        if self.sensor_ranges is not None:
            self.nominal_theta = np.append(self.nominal_theta, self.sensor_ranges.mean(axis=1))
        self.max_wheel_speed = nominal.max_wheel_speed
        self.chassis = nominal.chassis
        self.traction = traction_of(nominal)
        self.sim = Simulation(SimulationConfig(
            arena_width=cfg["arena_size"], arena_height=cfg["arena_size"],
            physics_hz=cfg["physics_hz"], ideal=bool(cfg["ideal"]),
            ticks_per_rev=cfg["ticks_per_rev"], sigma_xy=cfg["sigma_xy"],
            sigma_theta=cfg["sigma_theta"]))
        self.sigma = self.sim.pose_sensor.sigma
        self.segment_duration = float(cfg["segment_duration"])
        self.budget = episode_budget(cfg)
        self._rule = stopping_rule(cfg, self.model)
        self.estimator_factory = estimator_factory or default_estimator
        self.recording_config = RecordingConfig(
            cfg["record_pose_hz"], cfg["record_sigma_xy"], cfg["record_sigma_theta"]
        ) if cfg["record"] else None
        self._recorder: Recorder | None = None

        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = observation_space(self.model)
        self._renderer = None
        self._robot: RobotSpec | None = None

    # -- episode ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        robot, sim_rng, self._sensor_rng, self._mount = self.draw_episode(self.np_random,
                                                                          options)
        # the mounting as a batch of one (1, 3) for the batch-first sensor functions
        self._mounts = None if self._mount is None else self._mount.as_array()[None]
        self.sim.reset(robot, sim_rng, pose=options.get("pose"))
        self._robot = robot
        self.estimator = self.new_estimator()
        if self.recording_config is not None:  # its own noise stream, spawned: no draw taken
            self._recorder = Recorder(
                self.recording_config, self.sim.encoders, self.sim.config.physics_hz,
                np.zeros(3) if self._mount is None else self._mount.as_array(),
                sim_rng.spawn(1)[0], self.sim.pose, self.sim.wheel_angles)
        self._log = np.empty((self.budget, 5))  # calibration rows; grows if stepped past budget
        self._sub: list[np.ndarray] = []  # target mode: each row's encoder sub-increments
        self._n = 0
        self.last_stop: StopDecision | None = None
        self._paths: list[np.ndarray] = [self.sim.pose[None, :]]
        self._last_action = (0.0, 0.0)
        self._sigma_min = 0.0
        self._estimate = self.nominal
        self._theta = self.nominal_theta
        p = self.model.size
        self._information = np.zeros((p, p))
        self._eigen = ((0.0,) * p, (1.0,) + (0.0,) * (p - 1))  # eigenvalues, weakest direction
        self._measured_pose = self._measure_pose(self.sim.pose)
        self._error = self._start_error = self.max_relative_error
        if self.render_mode == "human":
            self.render()
        return self._observation(), {"sigma_min": 0.0, "n_segments": 0}

    def draw_episode(self, rng: np.random.Generator, options: dict[str, Any]) -> tuple[
            RobotSpec, np.random.Generator, np.random.Generator, SensorPose | None]:
        """An episode's draws from ``rng``, in this order: the hidden robot (unless
        ``options["robot"]``), the simulation's and the pose sensor's random streams, and the
        hidden sensor mounting (None on the axle model; unless ``options["sensor_pose"]``).
        The vector env draws each robot's episode here too, so robot i with seed s + i is the
        single env with seed s + i."""
        robot = options.get("robot") or self.distribution.sample(rng)
        sim_rng = np.random.default_rng(rng.integers(2**63))
        sensor_rng = np.random.default_rng(rng.integers(2**63))
        mount = options.get("sensor_pose")
        if mount is not None and self.sensor_ranges is None:
            raise ValueError("options['sensor_pose']: this env's pose sensor is on the axle "
                             "(config sensor_pose is None)")
        if mount is None and self.sensor_ranges is not None:
            mount = SensorPose(*rng.uniform(self.sensor_ranges[:, 0], self.sensor_ranges[:, 1]))
        return robot, sim_rng, sensor_rng, mount

    def new_estimator(self) -> Estimator:
        """A fresh estimator of ``estimator_factory`` at the nominal robot (and nominal sensor
        pose on the sensor-pose model), with the sensor's noise levels. A user's factory (not
        an :class:`~excite.estimators.EstimatorSpec`) is checked against the estimator
        contract: EstimatorError in one line instead of a TypeError inside ``step``."""
        factory = self.estimator_factory
        estimator = factory(
            self.nominal if self.model is AXLE else self.nominal_theta.copy(), self.sigma.copy())
        if not isinstance(factory, EstimatorSpec):  # a user's factory: its product checked
            check_contract(getattr(factory, "__qualname__", repr(factory)), estimator)
        return estimator

    def new_estimators(self, n: int) -> BatchOnlineEstimator | None:
        """``n`` estimators updated together
        (:class:`excite.estimators.online.BatchOnlineEstimator`, one
        pass of array code per segment) when ``estimator_factory`` is the built-in
        ``online`` (any settings) and ``n`` is at least ``BATCH_ESTIMATOR_MIN``; else None
        (one :meth:`new_estimator` per robot then: below the threshold the one-robot
        filter's pure-Python update is faster)."""
        factory = self.estimator_factory
        if not (isinstance(factory, EstimatorSpec) and factory.name == "online") or (
                n < BATCH_ESTIMATOR_MIN):
            return None
        return BatchOnlineEstimator(n, self.nominal_theta, sigma=self.sigma, model=self.model,
                                **dict(factory.settings))

    def step(self, action):
        if self._robot is None:
            raise RuntimeError("call reset() before step()")
        values = np.asarray(action, dtype=float).reshape(-1).tolist()
        if len(values) != 2 or not all(map(math.isfinite, values)):
            raise ValueError(f"action must be 2 finite numbers (left, right), got {action!r}")
        left, right = (min(max(v, -1.0), 1.0) for v in values)
        outcome = self.sim.run_segment(left * self.max_wheel_speed, right * self.max_wheel_speed,
                                       self.segment_duration, self.config["settle_time"])
        row = outcome.measurement
        if self._mount is not None:  # the sensor measures its own motion, in its own frame
            sensed = sense_increments(self.sim.pose_sensor, outcome.true_increment[None],
                                      [self._sensor_rng], self._mounts)
            row = np.concatenate([row[:2], sensed[0]])
        self.estimator.update(*row.tolist())
        if self._n == len(self._log):
            self._log = np.concatenate([self._log, np.empty_like(self._log)])
        self._log[self._n] = row
        if self._rule is not None:
            self._sub.append(self.sim.encoders.sub_increments(outcome.wheel_path,
                                                              ENCODER_READINGS))
        self._n += 1
        self._paths.append(outcome.path[1:])
        if self._recorder is not None:
            self._recorder.add(outcome.path, outcome.wheel_path)
        self._last_action = (left, right)
        previous, previous_error = self._sigma_min, self._error
        self._estimate, self._theta = self._read_estimate()
        self._measured_pose = self._measure_pose(outcome.pose_end)
        self._information = self.information_at(self._theta)
        self._eigen = eigen(self._information)
        self._sigma_min = math.sqrt(max(self._eigen[0][0], 0.0))
        n = self._n
        config = self.config
        target = config["target_sigma_min"]
        decision = None if self._rule is None else decide(
            self._rule, self._log[:n], np.stack(self._sub), self.nominal_theta)
        self.last_stop = decision
        done = decision is not None and decision.done
        terminated = (target is not None and self._sigma_min >= target) or done
        truncated = n >= self.budget and not terminated
        if uses_error(config):
            self._error = self.max_relative_error
        terms = reward_terms(config, self._sigma_min - previous, outcome.collision,
                             left * left + right * right,
                             (self._start_error, previous_error, self._error), done)
        info = {
            "reward_terms": terms,
            "sigma_min": self._sigma_min,
            "collision": bool(outcome.collision),
            "measurement": row,
            "estimate": self._theta.copy(),
            "n_segments": n,
        }
        if decision is not None:
            info["stop"] = decision.to_dict()
        if self.render_mode == "human":
            self.render()
        return self._observation(), float(sum(terms.values())), terminated, truncated, info

    # -- what the robot knows ------------------------------------------------------------------
    def _read_estimate(self) -> tuple[Params, np.ndarray]:
        return read_estimate(self.estimator, self.model, self.nominal_theta)

    def _measure_pose(self, body_pose: np.ndarray) -> np.ndarray:
        if self._mounts is None:  # on the axle: the sensor reads the body's pose
            return self.sim.pose_sensor.absolute(body_pose, self._sensor_rng)
        return measure_poses(self.sim.pose_sensor, body_pose[None], [self._sensor_rng],
                             self._mounts, self._theta[None])[0]

    @property
    def estimate(self) -> Params:
        """The estimator's estimate after the last segment."""
        return self._estimate

    @property
    def segments(self) -> Segments:
        """The calibration log of this episode so far."""
        return Segments.from_array(self._log[: self._n])

    @property
    def rule_segments(self) -> Segments:
        """Target mode: the segments the stopping rule decides on, the log so far with each
        segment's encoder sub-increments (:func:`envs.target.rule_segments`)."""
        if self._rule is None:
            raise RuntimeError("rule_segments is only kept in target mode")
        return rule_segments(self._log[: self._n], np.stack(self._sub))

    def information_at(self, theta: Params | np.ndarray) -> np.ndarray:
        """Relative Fisher information (P x P) of this episode's segments evaluated at
        ``theta`` (the model's parameters; Params on the axle model)."""
        if not self._n:
            return np.zeros((self.model.size,) * 2)
        log = self._log[: self._n]
        return information_matrix(log[:, 0], log[:, 1], theta, self.sigma,
                                  scale=self.nominal_theta, model=self.model)

    @property
    def sigma_min(self) -> float:
        return self._sigma_min

    def knowledge(self) -> RobotKnowledge:
        """What the robot knows now (for planners and scripted protocols)."""
        return RobotKnowledge(
            observation=self._observation(), estimate=self.estimate,
            information=self._information.copy(), log=self._log[: self._n].copy(),
            pose=self._measured_pose.copy(), nominal=self.nominal, sigma=self.sigma.copy(),
            max_wheel_speed=self.max_wheel_speed, segment_duration=self.segment_duration,
            arena_size=float(self.config["arena_size"]), budget=self.budget, model=self.model,
            chassis=self.chassis, theta=self._theta.copy(),
            nominal_theta=self.nominal_theta.copy(), traction=self.traction)

    def _observation(self) -> np.ndarray:
        eigenvalues, weakest = self._eigen
        return observation(self.model, self._theta.tolist(), self.nominal_theta.tolist(),
                           eigenvalues, weakest, self._measured_pose.tolist(),
                           self._last_action, self._n / self.budget,
                           self.config["arena_size"], self.observation_space)

    # -- evaluation only -------------------------------------------------------------------------
    @property
    def true_params(self) -> Params:
        """The hidden truth (for evaluation; never part of the observation)."""
        if self._robot is None:
            raise RuntimeError("call reset() first")
        return Params(*self._robot.kinematic_params())

    @property
    def true_sensor_pose(self) -> SensorPose | None:
        """The hidden sensor mounting (None: on the axle); for evaluation only."""
        if self._robot is None:
            raise RuntimeError("call reset() first")
        return self._mount

    @property
    def true_theta(self) -> np.ndarray:
        """All hidden model parameters (wheels, then the sensor pose); evaluation only."""
        theta = self.true_params.as_array()
        return theta if self._mount is None else np.append(theta, self._mount.as_array())

    @property
    def recording(self) -> Recording | None:
        """The time series recorded this episode, with its truth (config ``record``; None when
        recording is off). RuntimeError before the first step."""
        return None if self._recorder is None else self._recorder.recording()

    @property
    def robot(self) -> RobotSpec:
        if self._robot is None:
            raise RuntimeError("call reset() first")
        return self._robot

    @property
    def path(self) -> np.ndarray:
        """The true world poses (x, y, theta) of this episode at the physics rate (M, 3)."""
        return np.concatenate(self._paths)

    @property
    def last_segment_distance(self) -> float:
        """Path length (m) the robot travelled in the last segment (evaluation only)."""
        steps = self._paths[-1][:, :2] if len(self._paths) > 1 else np.zeros((1, 2))
        start = self._paths[-2][-1, :2] if len(self._paths) > 1 else steps[0]
        points = np.vstack([start, steps])
        return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))

    @property
    def max_relative_error(self) -> float:
        return float(np.max(np.abs(self.estimate.as_array() / self.true_params.as_array() - 1)))

    # -- rendering ---------------------------------------------------------------------------
    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode=...")
            return None
        if self._renderer is None:
            from envs.rendering import ArenaRenderer

            self._renderer = ArenaRenderer(self.config["arena_size"],
                                           human=self.render_mode == "human")
        frame = self._renderer.draw(
            path=self.path, pose=self.sim.pose, robot=self.robot,
            estimate=self.estimate, sigma_min=self._sigma_min, n_segments=self._n,
            budget=self.budget)
        return None if self.render_mode == "human" else frame

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self):
        state = copy.copy(self.__dict__)
        state["_renderer"] = None  # figures do not pickle; a new one is made on demand
        return state

